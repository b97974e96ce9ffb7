"""The fused Newton kernel against the batched minimiser on the same recorded solves, in the same run.

The sub-step solves of a bench pile (``bench_peers.py``'s scenes: stiff boxes, one affine handle each) are
recorded from a run on the batched path (``Simulator(fused_newton=False)``); each recorded objective gets a
workspace of its own, then every solve is timed (CPU time, fastest of ``--repeat``) with
:func:`data_gen.sim.newton.minimise` and with :class:`data_gen.sim.fused_newton.FusedNewton`, from the same
start. Printed per scene and island size: solves, Newton iterations per solve (equal on both paths, checked),
CPU ms per solve of each path and the ratio; written to bench/results/fused_newton.json.

    python bench/bench_fused_newton.py                       # stiff_10 and stiff_50, 1 s each
    python bench/bench_fused_newton.py --scenes stiff_10 --quick
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_peers as peers  # noqa: E402
from sim_bench_scenes import QUICK_TRAINING, _box  # noqa: E402

import data_gen.sim.solver as solver_module  # noqa: E402
from data_gen.sim.newton import minimise  # noqa: E402
from data_gen.sim.static_scene import StaticScene  # noqa: E402
from data_gen.sim.step_objective import StepObjective  # noqa: E402
from data_gen.sim.world import Simulator  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"


def record_solves(scene: peers.PeerScene, frames: int) -> list[tuple]:
    """The batched path's solves of ``scene`` (objective with its own workspace, q0, scale, trust, settings)."""
    captured = []
    original = solver_module.minimise

    def capture(objective, q0, scale, trust, settings, **kwargs):
        o = objective
        own = StepObjective(o.model, o.layout, o.scene, o.gravity, o.tm_n, (o.tm_pred - o.tm_n) / o.h, o.h,
                            float(o.scene_stiffness_n_m[0] * o.h2 / o.model.mass_kg[0]), o.smoothing_m, o.pairs)  # fmt: skip
        captured.append((own, q0.clone(), scale.clone(), trust.clone(), settings))
        return original(objective, q0, scale, trust, settings, **kwargs)

    specs = [
        _box(f"box_{k}", peers.HALF_M, scene.young_pa, pos, seed=10, training=QUICK_TRAINING, rho=peers.DENSITY)
        for k, pos in enumerate(peers.placements(scene.count))
    ]
    solver_module.minimise = capture
    try:
        Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), scene.quality, seed=0, num_threads=1,
                  fused_newton=False).run(frames, fps=peers.FPS)  # fmt: skip
    finally:
        solver_module.minimise = original
    return captured


def cpu_ms(fn, repeat: int) -> float:
    """Fastest CPU time of ``repeat`` calls, ms."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        best = min(best, time.process_time() - t0)
    return 1e3 * best


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=["stiff_10", "stiff_50"], choices=list(peers.SCENES))
    parser.add_argument("--repeat", type=int, default=3, help="timed calls per solve and path (fastest kept)")
    parser.add_argument("--quick", action="store_true", help="0.4 s of each scene instead of 1 s")
    parser.add_argument("--out", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.repeat < 1:
        parser.error(f"--repeat {args.repeat}: must be >= 1")
    frames = int(round((0.4 if args.quick else peers.DURATION_S) * peers.FPS)) + 1
    torch.set_num_threads(1)
    rows = []
    for name in args.scenes:
        scene = peers.SCENES[name]
        if scene.young_pa < 1e8:
            raise SystemExit(f"scene {name!r}: soft boxes are not solved by the fused kernel; pick stiff scenes")
        by_size: dict[int, dict[str, float]] = defaultdict(lambda: defaultdict(float))
        for objective, q0, scale, trust, settings in record_solves(scene, frames):
            fused = objective.workspace.fused
            if fused is None:  # a group beyond the kernel's size caps
                continue
            ref = minimise(objective, q0, scale, trust, settings)
            out = fused.solve(objective, q0, scale, trust, settings)
            if out is None or not torch.equal(out.iterations, ref.iterations):
                raise SystemExit(f"scene {name!r}: the fused solve took another path than minimise")
            row = by_size[int(q0.shape[1])]
            row["solves"] += 1
            row["iterations"] += float(ref.iterations.max())
            row["minimise_ms"] += cpu_ms(lambda: minimise(objective, q0, scale, trust, settings), args.repeat)
            row["fused_ms"] += cpu_ms(lambda: fused.solve(objective, q0, scale, trust, settings), args.repeat)
        for size, row in sorted(by_size.items()):
            n = row["solves"]
            rows.append({
                "scene": name, "island_unknowns": size, "solves": int(n), "iterations_per_solve": row["iterations"] / n,
                "minimise_ms_per_solve": row["minimise_ms"] / n, "fused_ms_per_solve": row["fused_ms"] / n,
                "speedup": row["minimise_ms"] / row["fused_ms"],
            })  # fmt: skip
    print("| scene | island unknowns (largest) | solves | Newton iterations per solve | minimise CPU ms per solve | "
          "fused CPU ms per solve | speed-up |")
    print("|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['island_unknowns']} | {r['solves']} | {r['iterations_per_solve']:.1f} | "
              f"{r['minimise_ms_per_solve']:.2f} | {r['fused_ms_per_solve']:.2f} | {r['speedup']:.1f}x |")  # fmt: skip
    out = args.out or RESULTS / ("fused_newton_quick.json" if args.quick else "fused_newton.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"frames": frames, "repeat": args.repeat, "rows": rows}, indent=2))
    print(f"wrote {out}")
    return {"rows": rows}


if __name__ == "__main__":
    main()
