"""End-to-end generation cost: seconds per sequence, split into prepare / simulate / render / write.

The issue's reference sequence: 5 objects, 2 s at 25 FPS, 256x256, ``standard`` preset, on this
machine; the ``draft`` preset on the same scenarios is the baseline measured in the same run.
Prints a table and writes bench/results/generate.json.

    python bench/bench_generate.py            # 5 objects, 50 frames, 256^2, 2 scenarios per preset
    python bench/bench_generate.py --quick    # 3 objects, 12 frames, 128^2, 1 scenario per preset
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--presets", default="draft,standard")
    args = ap.parse_args()
    n_obj, frames, size, reps = (3, 12, 128, 1) if args.quick else (5, 50, 256, 2)
    # the shipped drop scenario and render settings (what generate.py runs), on one floor with n objects
    cfg = scenario_config("drop", scenes=("empty_floor",), num_objects=(n_obj, n_obj), size_m=(0.12, 0.2),
                          camera_distance_m=(0.9, 1.1))
    settings = render_settings()
    rows = []
    rejected: list[dict] = []
    for preset_name in args.presets.split(","):
        preset = load_preset(preset_name)
        totals: dict[str, list[float]] = {}
        rep, attempt = 0, 0
        while rep < reps:  # a rejected draw (as in generate.py) is logged and replaced by the next seed
            scenario = sample_scenario(cfg, f"bench-{rep:06d}", 1000 + rep + 100 * attempt, "train", "earth", frames,
                                       25.0, (size, size))
            t0 = time.perf_counter()
            try:
                seq, timings = generate_sequence(scenario, preset, settings)
            except SequenceRejected as err:
                print(f"{preset_name}: scenario {rep} attempt {attempt} rejected: {err}")
                rejected.append({"preset": preset_name, "scenario": rep, "attempt": attempt, "reason": str(err)})
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
        rows.append((preset_name, {k: float(np.mean(v)) for k, v in totals.items()}))
    keys = ["prepare_s", "simulate_s", "render_s", "write_s", "total_s"]
    print(f"{n_obj} objects, {frames} frames at 25 FPS ({frames / 25:.2f} s), {size}x{size}, mean of {reps} "
          f"scenario(s); machine: {platform.processor() or platform.machine()}")
    print(f"{'preset':<10}" + "".join(f"{k:>12}" for k in keys) + f"{'x baseline':>12}")
    base = rows[0][1]["total_s"]
    for name, t in rows:
        print(f"{name:<10}" + "".join(f"{t[k]:>12.2f}" for k in keys) + f"{t['total_s'] / base:>12.2f}")
    out = ROOT / "bench" / "results" / "generate.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"objects": n_obj, "frames": frames, "image_size": size, "reps": reps,
                               "seconds_per_sequence": dict(rows), "baseline": rows[0][0],
                               "rejected": rejected}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
