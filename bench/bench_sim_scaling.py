"""How the simulator's cost scales: time per step vs cubature points, contact spheres, handles, objects,
rendered particles.

Each sweep reports the wall time per (25 FPS frame) step and the share of each part (Newton = assembly +
line search + dense solve, broad phase = hash grid, forces = per-point contact-force recording,
recording = per-frame outputs).  The particle sweep times ``deform`` (what the renderer calls to move
surface Gaussians every frame).  A ratio column compares each row with the first row of its sweep.
Writes bench/results/sim_scaling.json and sim_scaling.png.

    python bench/bench_sim_scaling.py --quick
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sim_bench_scenes import QUICK_TRAINING, box_points  # noqa: E402

from data_gen.sim.contact_points import box_surface  # noqa: E402
from data_gen.sim.material import Material  # noqa: E402
from data_gen.sim.presets import load_preset  # noqa: E402
from data_gen.sim.reduced import PointDeformer, deform  # noqa: E402
from data_gen.sim.skinning import train_skinning_basis  # noqa: E402
from data_gen.sim.static_scene import StaticScene  # noqa: E402
from data_gen.sim.world import SimObjectSpec, Simulator  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
FPS = 25.0
HALF = (0.08, 0.08, 0.08)


def timed_run(specs, preset, frames: int) -> dict:
    sim = Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), preset, seed=0)
    res = sim.run(num_frames=frames + 1, fps=FPS)
    steps = frames  # one frame = substeps_per_frame steps; report per frame
    parts = {k: v / steps for k, v in res.info.timings_s.items() if k != "setup"}
    return {
        "wall_per_frame_s": res.info.wall_time_s / steps,
        "parts_per_frame_s": parts,
        "newton_iterations_per_frame": res.info.newton_iterations / steps,
        "cubature_total": int(sum(tr.points_rest_m.shape[0] for tr in res.objects)),
        "handles": [tr.num_handles for tr in res.objects],
        "setup_s": res.info.timings_s["setup"],
    }


def soft_box(name, pos, young=1e5, handles=None, points=3000, seed=0):
    pts = box_points(HALF, points, seed)
    return SimObjectSpec(
        name,
        pts,
        float(np.prod(2 * np.asarray(HALF))),
        Material(young, 0.3, 1000.0),
        position_m=pos,
        num_handles=handles,
        skinning_settings=QUICK_TRAINING,
        surface=box_surface(HALF, 4000, seed),
    )


def sweep_cubature(preset, frames, counts):
    rows = []
    for n in counts:
        p = preset.replace(num_cubature_points=n, sleep_speed_m_s=0.0)
        rows.append(
            {"cubature_points": n, **timed_run([soft_box("box", (0.0, 0.0, 0.2), handles=4)], p, frames)}
        )
    return rows


def sweep_contacts(preset, frames, counts):
    rows = []
    for n in counts:
        p = preset.replace(num_cubature_points=128, num_contact_points=n, sleep_speed_m_s=0.0)
        rows.append(
            {"contact_points": n, **timed_run([soft_box("box", (0.0, 0.0, 0.2), handles=4)], p, frames)}
        )
    return rows


def sweep_handles(preset, frames, handles):
    rows = []
    for h in handles:
        p = preset.replace(num_cubature_points=128, max_handles=max(handles), sleep_speed_m_s=0.0)
        rows.append({**timed_run([soft_box("box", (0.0, 0.0, 0.2), handles=h)], p, frames), "num_handles": h})
    return rows


def sweep_objects(preset, frames, counts):
    rows = []
    for n in counts:
        side = int(np.ceil(np.sqrt(n)))
        specs = [
            soft_box(f"box{k}", (0.25 * (k % side), 0.25 * (k // side), 0.2), young=1e9, seed=k)
            for k in range(n)
        ]
        p = preset.replace(num_cubature_points=64, sleep_speed_m_s=0.0)
        rows.append({"objects": n, **timed_run(specs, p, frames)})
    return rows


def sweep_particles(counts):
    pts = torch.from_numpy(box_points(HALF, 2000, 0))
    basis = train_skinning_basis(pts, 6, 0.3, settings=QUICK_TRAINING, seed=0)
    z = 0.01 * torch.randn(72, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    rows = []
    for n in counts:
        x0 = torch.from_numpy(box_points(HALF, n, 1))
        t0 = time.perf_counter()
        weights, grads = basis.evaluate(x0)
        t1 = time.perf_counter()
        deformer = PointDeformer(x0, weights, grads)
        t2 = time.perf_counter()
        reps = 3
        for _ in range(reps):
            deformer.positions(z)
        t3 = time.perf_counter()
        for _ in range(reps):
            deformer.deformation_gradients(z)
        t4 = time.perf_counter()
        deform(x0, weights, grads, z)  # the one-shot function (rebuilds the bases every call)
        t5 = time.perf_counter()
        rows.append(
            {
                "particles": n,
                "basis_evaluate_s": t1 - t0,
                "precompute_s": t2 - t1,
                "positions_per_frame_s": (t3 - t2) / reps,
                "gradients_per_frame_s": (t4 - t3) / reps,
                "one_shot_deform_s": t5 - t4,
            }
        )
    return rows


def big_scene(preset, seconds):
    """The issue's target: 5 objects, ~10^4 cubature points in total, 25 FPS."""
    specs = [
        soft_box(
            f"box{k}",
            (0.3 * k, 0.0, 0.2 + 0.05 * k),
            young=[1e5, 1e9, 1e6, 1e10, 2e5][k],
            points=4000,
            seed=k,
        )
        for k in range(5)
    ]
    p = preset.replace(num_cubature_points=2000)
    frames = int(round(seconds * FPS))
    t0 = time.perf_counter()
    row = timed_run(specs, p, frames)
    row["total_wall_s_incl_setup"] = time.perf_counter() - t0
    row["seconds_simulated"] = seconds
    row["extrapolated_wall_for_2s_s"] = row["wall_per_frame_s"] * 50 + row["setup_s"]
    return row


def print_sweep(title, key, rows):
    print(f"\n== {title}")
    base = rows[0]["wall_per_frame_s"]
    for r in rows:
        parts = r["parts_per_frame_s"]
        total = sum(parts.values()) or 1.0
        share = "  ".join(f"{k} {100 * v / total:4.1f}%" for k, v in parts.items())
        print(
            f"{key}={str(r[key]):>5s}  {1e3 * r['wall_per_frame_s']:9.1f} ms/frame  x{r['wall_per_frame_s'] / base:5.2f}"
            f"  newton it/frame {r['newton_iterations_per_frame']:5.1f}  {share}",
            flush=True,
        )


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--preset", default="standard")
    parser.add_argument("--skip-big", action="store_true", help="skip the 5-object / 10^4 cubature scene")
    args = parser.parse_args()
    torch.set_num_threads(1)
    preset = load_preset(args.preset)
    frames = 5 if args.quick else 25
    out = {
        "meta": {
            "preset": args.preset,
            "frames": frames,
            "fps": FPS,
            "quick": args.quick,
            "torch_threads": 1,
            "note": "wall times on a shared 2-core CPU; per 25 FPS frame",
        }
    }
    out["cubature"] = sweep_cubature(preset, frames, [32, 64, 128, 256, 512] + ([] if args.quick else [1024]))
    print_sweep("cubature points (1 soft object, 4 handles)", "cubature_points", out["cubature"])
    out["contacts"] = sweep_contacts(preset, frames, [64, 128, 256, 512] + ([] if args.quick else [1024]))
    print_sweep("contact spheres (1 soft object landing and resting, 4 handles, 128 cubature)", "contact_points", out["contacts"])
    out["handles"] = sweep_handles(preset, frames, [1, 2, 4, 8])
    print_sweep("handles (1 object, 128 cubature points)", "num_handles", out["handles"])
    out["objects"] = sweep_objects(preset, frames, [1, 2, 5, 10] + ([] if args.quick else [20]))
    print_sweep("objects (stiff boxes, 64 cubature points each)", "objects", out["objects"])
    out["particles"] = sweep_particles([10**3, 10**4, 10**5] + ([] if args.quick else [10**6]))
    print("\n== rendered particles (deform with 6 handles)")
    for r in out["particles"]:
        print(
            f"particles={r['particles']:>8d}  basis evaluate {1e3 * r['basis_evaluate_s']:8.1f} ms + precompute "
            f"{1e3 * r['precompute_s']:7.1f} ms (once)  positions {1e3 * r['positions_per_frame_s']:8.2f} ms/frame  "
            f"F {1e3 * r['gradients_per_frame_s']:8.2f} ms/frame  (one-shot deform {1e3 * r['one_shot_deform_s']:8.1f} ms)"
        )
    if not args.skip_big:
        out["big_scene"] = big_scene(preset, 0.2 if args.quick else 2.0)
        b = out["big_scene"]
        print(
            f"\n== 5 objects, {b['cubature_total']} cubature points, handles {b['handles']}: "
            f"{b['wall_per_frame_s']:.2f} s/frame, setup {b['setup_s']:.1f} s, "
            f"2 s at 25 FPS -> {b['extrapolated_wall_for_2s_s']:.0f} s "
            f"({'measured' if not args.quick else 'extrapolated from ' + str(b['seconds_simulated']) + ' s'})"
        )
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "sim_scaling.json").write_text(json.dumps(out, indent=2))
    plot(out, RESULTS / "sim_scaling.png")
    print(f"wrote {RESULTS / 'sim_scaling.json'}")


def plot(out: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sweeps = [
        ("cubature", "cubature_points"),
        ("contacts", "contact_points"),
        ("handles", "num_handles"),
        ("objects", "objects"),
    ]
    sweeps = [s for s in sweeps if s[0] in out]
    fig, axes = plt.subplots(1, len(sweeps), figsize=(4 * len(sweeps), 3.6))
    for ax, (key, label) in zip(axes, sweeps):
        rows = out[key]
        xs = [r[label] for r in rows]
        ax.plot(xs, [1e3 * r["wall_per_frame_s"] for r in rows], "o-", label="total")
        ax.plot(xs, [1e3 * r["parts_per_frame_s"].get("newton", 0.0) for r in rows], "s--", label="newton")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(label)
        ax.set_ylabel("ms per frame")
        ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
