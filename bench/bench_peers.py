"""NewtPhys against a rigid-body engine on the same scenes, measured in the same run.

The peer is PyBullet (the engine Kubric uses; ``pip install -e .[bench]``) at 240 Hz, the boxes as rigid
bodies of the same size, mass and friction on a ground plane. NewtPhys runs the same boxes (stiff boxes
become one affine handle each; soft boxes are deformable) at the named quality preset, one thread.
Scenes (``soft_pile_ten`` geometry of ``bench/sim_bench_scenes.py``: a staggered column; more boxes
stand in several such columns), 1 s at 25 FPS:

* ``stiff_10``: 10 boxes, E = 1e9 Pa, ``standard``;
* ``soft_5``: 5 boxes, E = 1e5 Pa, ``draft`` (PyBullet simulates them rigid);
* ``stiff_20`` / ``stiff_50``: 20 / 50 stiff boxes piling, ``standard``.

Printed per scene: simulation wall time (and CPU time, steadier on a shared machine) of each engine (set-up excluded: skinning training and cubature
sampling are cached per object), the ratio, NewtPhys's cost per object, and checks that nothing tunnelled
(every box centre above the ground by at least 80 % of its half height at the end, in both engines) and
that the resting pile heights agree. Writes bench/results/peers.json and peers.png.

    python bench/bench_peers.py            # all scenes
    python bench/bench_peers.py --scenes stiff_10 soft_5
    python bench/bench_peers.py --repeat 3    # 3 interleaved runs per engine and scene: the fastest of each, and
                                              # each repeat's own ratio (how far the machine's phases move it);
                                              # every scene first runs once untimed (kernel loading); each
                                              # PyBullet "run" is the fastest of --peer-runs (10) back to back
    python bench/bench_peers.py --batched     # also NewtPhys without the fused Newton kernel, side by side
    python bench/bench_peers.py --device-newton [--device cuda]   # also the device schedule (DeviceNewton), side by side
    python bench/bench_peers.py --quick       # stiff_10 and soft_5 only (make bench)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sim_bench_scenes import QUICK_TRAINING, _box  # noqa: E402

from data_gen.sim.static_scene import StaticScene  # noqa: E402
from data_gen.sim.world import Simulator  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
HALF_M = (0.07, 0.07, 0.05)
DENSITY = 1000.0
FRICTION = 0.5
FPS = 25.0
DURATION_S = 1.0
PEER_HZ = 240.0
COLUMN = 10  # boxes per staggered column
COLUMN_SPACING_M = 0.3


@dataclass(frozen=True)
class PeerScene:
    name: str
    count: int
    young_pa: float
    quality: str


# the targets: NewtPhys CPU time at most this many times PyBullet's (None: no ratio target)
TARGET_CPU_RATIO = {"stiff_10": 50.0, "soft_5": 100.0, "stiff_20": None, "stiff_50": None}

SCENES = {
    "stiff_10": PeerScene("stiff_10", 10, 1e9, "standard"),
    "soft_5": PeerScene("soft_5", 5, 1e5, "draft"),
    "stiff_20": PeerScene("stiff_20", 20, 1e9, "standard"),
    "stiff_50": PeerScene("stiff_50", 50, 1e9, "standard"),
}


def placements(count: int) -> list[tuple[float, float, float]]:
    """Box centres (m): the staggered column of ``soft_pile_ten``, repeated in columns along y."""
    out = []
    for k in range(count):
        column, level = divmod(k, COLUMN)
        x = 0.05 * ((level % 3) - 1)
        y = 0.04 * ((level % 2) - 0.5) + COLUMN_SPACING_M * (column - (count - 1) // COLUMN / 2.0)
        out.append((x, y, 0.08 + 0.13 * level))
    return out


def newtphys_simulator(scene: PeerScene, seed: int = 0, fused_newton: bool = True, device: str = "cpu",
                       device_newton: bool = False) -> Simulator:  # fmt: skip
    """NewtPhys's simulator of ``scene``: its boxes, preset and seed, one thread; ``device`` and ``device_newton``
    as :class:`Simulator`'s (``bench_cuda.py`` runs the one-handle islands' solves on a GPU)."""
    specs = [
        _box(f"box_{k}", HALF_M, scene.young_pa, pos, seed=10, training=QUICK_TRAINING, rho=DENSITY)
        for k, pos in enumerate(placements(scene.count))
    ]
    return Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), scene.quality, seed=seed, num_threads=1,
                     fused_newton=fused_newton, device=device, device_newton=device_newton)  # fmt: skip


def run_newtphys(scene: PeerScene, seed: int = 0, fused_newton: bool = True, device: str = "cpu",
                 device_newton: bool = False) -> dict:  # fmt: skip
    sim = newtphys_simulator(scene, seed, fused_newton, device, device_newton)
    frames = int(round(DURATION_S * FPS)) + 1
    t0, c0 = time.perf_counter(), time.process_time()
    res = sim.run(frames, fps=FPS)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    com = np.stack([tr.com_m[-1] for tr in res.objects])
    return {
        "wall_s": wall,
        "cpu_s": cpu,
        "setup_s": sim.setup_time_s,
        "final_com_m": com.tolist(),
        "newton_iterations": int(res.info.newton_iterations),
        "timings_s": res.info.timings_s,
        "counters": res.info.counters,
    }


def run_pybullet(scene: PeerScene) -> dict:
    import pybullet as p

    client = p.connect(p.DIRECT)
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=client)
        p.setTimeStep(1.0 / PEER_HZ, physicsClientId=client)
        plane = p.createCollisionShape(p.GEOM_PLANE, physicsClientId=client)
        ground = p.createMultiBody(0, plane, physicsClientId=client)
        p.changeDynamics(ground, -1, lateralFriction=FRICTION, physicsClientId=client)
        shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=HALF_M, physicsClientId=client)
        mass = DENSITY * 8.0 * float(np.prod(HALF_M))
        bodies = []
        for pos in placements(scene.count):
            body = p.createMultiBody(mass, shape, basePosition=pos, physicsClientId=client)
            p.changeDynamics(body, -1, lateralFriction=FRICTION, physicsClientId=client)
            bodies.append(body)
        steps = int(round(DURATION_S * PEER_HZ))
        t0, c0 = time.perf_counter(), time.process_time()
        for _ in range(steps):
            p.stepSimulation(physicsClientId=client)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        com = np.array([p.getBasePositionAndOrientation(b, physicsClientId=client)[0] for b in bodies])
    finally:
        p.disconnect(client)
    return {"wall_s": wall, "cpu_s": cpu, "final_com_m": com.tolist()}


def pile_checks(com_m: np.ndarray) -> dict:
    z = np.sort(com_m[:, 2])
    return {
        "min_centre_height_m": float(z[0]),
        "tunnelled": bool(z[0] < 0.8 * HALF_M[2]),
        "mean_centre_height_m": float(z.mean()),
        "max_centre_height_m": float(z[-1]),
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--out", type=Path, default=None,
                        help="results JSON (and its .png); default bench/results/peers.json, peers_quick.json with --quick")  # fmt: skip
    parser.add_argument("--batched", action="store_true",
                        help="also run NewtPhys without the fused Newton kernel (Simulator(fused_newton=False)) in the "
                             "same run: the kernel's own speed-up, measured side by side")  # fmt: skip
    parser.add_argument("--device-newton", action="store_true",
                        help="also run NewtPhys with its Newton solves as the device schedule (Simulator(device_newton="
                             "True), on --device) in the same run, with its final centres against the fused path's")  # fmt: skip
    parser.add_argument("--device", default="cpu", help="the device of --device-newton (cpu, cuda)")
    parser.add_argument("--repeat", type=int, default=1,
                        help="run each engine this many times per scene and keep the fastest (CPU time) run of each: "
                             "the machines are noisy")  # fmt: skip
    parser.add_argument("--peer-runs", type=int, default=10,
                        help="PyBullet runs back to back per repeat, the fastest (CPU time) kept: its second of "
                             "simulation takes 10-130 ms, where one descheduling moves the ratio by tens of percent")  # fmt: skip
    parser.add_argument("--quick", action="store_true",
                        help="the two scenes with targets only (stiff_10, soft_5), one run each: what `make bench` runs")  # fmt: skip
    args = parser.parse_args(argv)
    if args.quick:
        args.scenes = [name for name in args.scenes if TARGET_CPU_RATIO[name] is not None]
    if args.out is None:
        args.out = RESULTS / ("peers_quick.json" if args.quick else "peers.json")
    if args.repeat < 1:
        parser.error(f"--repeat {args.repeat}: must be >= 1")
    if args.peer_runs < 1:
        parser.error(f"--peer-runs {args.peer_runs}: must be >= 1")
    rows = []
    for name in args.scenes:
        scene = SCENES[name]
        peers, ours_runs, batched_runs, device_runs = [], [], [], []
        on_device = dict(device=args.device, device_newton=True)
        # untimed warm-up: a process's first run loads (on a fresh machine: compiles, tens of seconds) warp's kernels
        run_newtphys(scene, fused_newton=True)
        if args.batched:
            run_newtphys(scene, fused_newton=False)
        if args.device_newton:
            run_newtphys(scene, **on_device)
        for _ in range(args.repeat):  # interleaved: a slower or faster phase of the machine meets both engines
            peers.append(min((run_pybullet(scene) for _ in range(args.peer_runs)), key=lambda r: r["cpu_s"]))
            ours_runs.append(run_newtphys(scene))
            if args.batched:
                batched_runs.append(run_newtphys(scene, fused_newton=False))
            if args.device_newton:
                device_runs.append(run_newtphys(scene, **on_device))
        peer, ours = (min(runs, key=lambda r: r["cpu_s"]) for runs in (peers, ours_runs))
        batched = min(batched_runs, key=lambda r: r["cpu_s"]) if args.batched else None
        device_run = min(device_runs, key=lambda r: r["wall_s"]) if args.device_newton else None
        # each repeat's own ratio (its two runs minutes apart at most): how far the machine's phases move the ratio
        paired = sorted(o["cpu_s"] / max(p["cpu_s"], 1e-9) for o, p in zip(ours_runs, peers))
        rows.append({
            "scene": name, "boxes": scene.count, "young_pa": scene.young_pa, "quality": scene.quality,
            "newtphys": ours, "pybullet": peer, "ratio": ours["wall_s"] / peer["wall_s"],
            "cpu_ratio": ours["cpu_s"] / max(peer["cpu_s"], 1e-9),
            "paired_cpu_ratios": paired,
            "newtphys_per_object_s": ours["wall_s"] / scene.count,
            "newtphys_cpu_per_object_s": ours["cpu_s"] / scene.count,
            "target_cpu_ratio": TARGET_CPU_RATIO[name],
            "newtphys_batched": batched,
            "newtphys_device": device_run,
            "checks": {"newtphys": pile_checks(np.array(ours["final_com_m"])),
                       "pybullet": pile_checks(np.array(peer["final_com_m"]))},
        })  # fmt: skip
        r = rows[-1]
        print(
            f"{name:9s} {scene.count:3d} boxes  NewtPhys {ours['wall_s']:8.2f} s  PyBullet {peer['wall_s']:7.4f} s  "
            f"ratio {r['ratio']:8.0f}x (CPU time {r['cpu_ratio']:.0f}x)  per object {r['newtphys_per_object_s']:.3f} s  "
            f"tunnelled: ours {r['checks']['newtphys']['tunnelled']} / peer {r['checks']['pybullet']['tunnelled']}  "
            f"mean centre height ours {r['checks']['newtphys']['mean_centre_height_m']:.3f} m / "
            f"peer {r['checks']['pybullet']['mean_centre_height_m']:.3f} m",
            flush=True,
        )
    print("\n| scene | boxes | quality | NewtPhys wall (s) | NewtPhys CPU (s) | PyBullet 240 Hz CPU (s) | CPU-time ratio "
          "| repeats' own ratios (min / median / max) | target | evaluations | CPU ms per evaluation "
          "| NewtPhys CPU per object (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        ours, target = r["newtphys"], TARGET_CPU_RATIO[r["scene"]]
        evaluations = ours["counters"]["evaluations"] + ours["counters"]["evaluations_with_derivatives"]
        met = "-" if target is None else f"<= {target:.0f}x ({'met' if r['cpu_ratio'] <= target else 'not met'})"
        print(f"| {r['scene']} | {r['boxes']} | {r['quality']} | {ours['wall_s']:.2f} | {ours['cpu_s']:.2f} | "
              f"{r['pybullet']['cpu_s']:.4f} | {r['cpu_ratio']:.0f}x | {_spread(r['paired_cpu_ratios'])} | {met} | "
              f"{evaluations} | "
              f"{1e3 * ours['cpu_s'] / max(evaluations, 1):.2f} | {ours['cpu_s'] / r['boxes']:.3f} |")  # fmt: skip
    if args.batched:
        print("\n| scene | NewtPhys CPU (s), fused Newton kernel | without it (s) | kernel speed-up | PyBullet ratio "
              "without it |")
        print("|---|---|---|---|---|")
        for r in rows:
            fused_cpu, batched_cpu = r["newtphys"]["cpu_s"], r["newtphys_batched"]["cpu_s"]
            print(f"| {r['scene']} | {fused_cpu:.2f} | {batched_cpu:.2f} | {batched_cpu / fused_cpu:.2f}x | "
                  f"{batched_cpu / max(r['pybullet']['cpu_s'], 1e-9):.0f}x |")  # fmt: skip
    if args.device_newton:
        print(f"\n| scene | NewtPhys wall (s), fused kernel | device schedule on {args.device}, wall (s) | its Newton "
              "iterations (fused) | solves on the schedule / handed back | final centres apart (m) |")
        print("|---|---|---|---|---|---|")
        for r in rows:
            ours, dev = r["newtphys"], r["newtphys_device"]
            apart = float(np.abs(np.array(dev["final_com_m"]) - np.array(ours["final_com_m"])).max())
            print(f"| {r['scene']} | {ours['wall_s']:.2f} | {dev['wall_s']:.2f} | {dev['newton_iterations']} "
                  f"({ours['newton_iterations']}) | {dev['counters']['device_island_solves']} / "
                  f"{dev['counters']['device_handed_back']} | {apart:.3g} |")  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"duration_s": DURATION_S, "fps": FPS, "repeat": args.repeat,
                                    "peer_runs": args.peer_runs, "rows": rows}, indent=2))  # fmt: skip
    _plot(rows, args.out.with_suffix(".png"))
    return {"rows": rows}


def _spread(ratios: list[float]) -> str:
    """``min / median / max`` of sorted per-repeat ratios (one value when there is one repeat)."""
    if len(ratios) == 1:
        return f"{ratios[0]:.0f}x"
    return f"{ratios[0]:.0f}x / {float(np.median(ratios)):.0f}x / {ratios[-1]:.0f}x"


def _plot(rows: list[dict], path: Path) -> None:
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 3.5))
    ax = fig.add_subplot(1, 1, 1)
    names = [r["scene"] for r in rows]
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["newtphys"]["wall_s"] for r in rows], 0.4, label="NewtPhys")
    ax.bar(x + 0.2, [r["pybullet"]["wall_s"] for r in rows], 0.4, label="PyBullet (240 Hz)")
    for k, r in enumerate(rows):
        ax.annotate(f"{r['ratio']:.0f}x", (k, r["newtphys"]["wall_s"]), ha="center", va="bottom", fontsize=8)
    ax.set_yscale("log")
    ax.set_xticks(x, names)
    ax.set_ylabel(f"wall time for {DURATION_S:g} s simulated (s)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
