"""End-to-end generation cost: seconds per sequence, split into prepare / simulate / render / write.

The issue's reference sequence: a ``pile`` of 5 objects (the shipped scenario's soft objects dropped onto one
spot), 2 s at 25 FPS, 256x256, ``standard`` preset, on this machine; the ``draft`` preset on the same draws is
the baseline measured in the same run. Each preset runs its draws twice:

- ``cold``: a fresh, empty skinning cache: every deformable object trains its basis (about 2 s each at
  ``standard``; 7-15 s before the held-out early stop);
- ``warm``: the same draws again with the bases of the cold pass cached (the simulation alone, as when a run is
  repeated with the same seeds);
- ``new``: as many new draws (other seeds) with that cache, which is what a generation run pays per draw: each
  draw's bases are trained on its own random particles with its own seed, so a new draw hits no cached basis.

``simulate_s`` includes the simulator's set-up (``sim_setup_s``: skinning bases, cubature, contact spheres).
Prints a table and writes bench/results/generate.json (generate_<scenario>.json for other scenarios).

    python bench/bench_generate.py                   # pile, 5 objects, 50 frames, 256^2, 2 draws per preset
    python bench/bench_generate.py --scenario drop   # the drop scenario instead
    python bench/bench_generate.py --quick           # 3 objects, 12 frames, 128^2, 1 draw per preset
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

import numpy as np

from data_gen.configs import render_settings, scenario_config
from data_gen.pipeline import SequenceRejected, generate_sequence
from data_gen.scenario import sample_scenario
from data_gen.sim.presets import load_preset
from newtphys.shards import ShardWriter

ROOT = Path(__file__).resolve().parents[1]


def _scenario_config(name: str, n_obj: int):
    """The shipped scenario on one floor with ``n_obj`` objects (drop: the sizes and camera of earlier runs)."""
    if name == "drop":
        return scenario_config("drop", scenes=("empty_floor",), num_objects=(n_obj, n_obj), size_m=(0.12, 0.2),
                               camera_distance_m=(0.9, 1.1))  # fmt: skip
    return scenario_config(name, scenes=("empty_floor",), num_objects=(n_obj, n_obj))


def _run_pass(cfg, preset, settings, frames: int, size: int, reps: int, cache_dir: str, label: str,
              rejected: list[dict], first: int = 0) -> dict[str, float]:  # fmt: skip
    """Mean stage times (s) of ``reps`` accepted draws from draw number ``first`` on (a rejected draw, as in
    generate.py, is logged and replaced by the next seed) with skinning bases in ``cache_dir``; ``bases_trained``:
    the bases this pass added to the cache."""
    totals: dict[str, list[float]] = {}
    before = len(list(Path(cache_dir).glob("*.pt")))
    rep, attempt = first, 0
    while rep < first + reps:
        scenario = sample_scenario(cfg, f"bench-{rep:06d}", 1000 + rep + 100 * attempt, "train", "earth", frames,
                                   25.0, (size, size))  # fmt: skip
        t0 = time.perf_counter()
        try:
            seq, timings = generate_sequence(scenario, preset, settings, skinning_cache_dir=cache_dir)
        except SequenceRejected as err:
            print(f"{label}: draw {rep} attempt {attempt} rejected: {err}")
            rejected.append({"run": label, "scenario": rep, "attempt": attempt, "reason": str(err)})
            attempt += 1
            continue
        rep, attempt = rep + 1, 0
        timings["total_s"] = time.perf_counter() - t0
        with tempfile.TemporaryDirectory() as tmp:
            t1 = time.perf_counter()
            with ShardWriter(tmp, "train", 0) as w:
                w.add_sequence(seq.world_state.sequence_id, seq.maps, seq.K, seq.world_to_camera, seq.world_state)
            timings["write_s"] = time.perf_counter() - t1
        timings["total_s"] += timings["write_s"]
        for k, v in timings.items():
            totals.setdefault(k, []).append(v)
        print(f"{label}: draw {rep - 1}: " + ", ".join(f"{k} {v:.2f}" for k, v in timings.items()), flush=True)
    out = {k: float(np.mean(v)) for k, v in totals.items()}
    out["bases_trained"] = float(len(list(Path(cache_dir).glob("*.pt"))) - before)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--presets", default="draft,standard")
    ap.add_argument("--scenario", default="pile", choices=["pile", "drop"])
    args = ap.parse_args()
    n_obj, frames, size, reps = (3, 12, 128, 1) if args.quick else (5, 50, 256, 2)
    cfg = _scenario_config(args.scenario, n_obj)
    settings = render_settings()
    rows = []
    rejected: list[dict] = []
    for preset_name in args.presets.split(","):
        preset = load_preset(preset_name)
        with tempfile.TemporaryDirectory() as cache:  # a fresh skinning cache per preset
            for temperature, first in (("cold", 0), ("warm", 0), ("new", reps)):
                label = f"{preset_name}/{temperature}"
                rows.append((label, _run_pass(cfg, preset, settings, frames, size, reps, cache, label, rejected,
                                              first)))  # fmt: skip
    keys = ["prepare_s", "sim_setup_s", "simulate_s", "render_s", "write_s", "total_s"]
    print(f"{args.scenario}: {n_obj} objects, {frames} frames at 25 FPS ({frames / 25:.2f} s), {size}x{size}, mean of "
          f"{reps} draw(s); machine: {platform.processor() or platform.machine()}")  # fmt: skip
    print(f"{'preset':<16}" + "".join(f"{k:>12}" for k in keys) + f"{'bases':>7}{'x baseline':>12}")
    base = rows[0][1]["total_s"]
    for name, t in rows:
        print(f"{name:<16}" + "".join(f"{t[k]:>12.2f}" for k in keys) + f"{int(t['bases_trained']):>7}"
              f"{t['total_s'] / base:>12.2f}")  # fmt: skip
    stem = "generate" if args.scenario == "pile" else f"generate_{args.scenario}"
    out = ROOT / "bench" / "results" / f"{stem}{'_quick' if args.quick else ''}.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"scenario": args.scenario, "objects": n_obj, "frames": frames, "image_size": size,
                               "reps": reps, "seconds_per_sequence": dict(rows), "baseline": rows[0][0],
                               "bases_trained": "bases each pass added to its preset's cache",
                               "rejected": rejected}, indent=1))  # fmt: skip
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
