"""Speed vs accuracy of the simulator quality presets, measured against the `reference` preset.

For each fixed scene (1 rigid object dropping, 5 mixed objects colliding, 10 soft objects piling) and
each preset: wall time per simulated second, centre-of-mass trajectory RMS error (m and % of the
distance travelled), per-point displacement RMS error relative to the motion (probe points deformed
with each run's own skinning basis and handle transforms), max penetration of a contact sphere into
the ground (m), Newton iterations.  Prints a table, writes bench/results/sim_quality.json and a PNG.

Floors: the scenes tumble and collide, so trajectories diverge from small differences.  Two extra
reference runs measure how well the outcome is determined at all:
* ``reference+0.1mm``: every object's initial position shifted by 0.1 mm (sensitivity to the state);
* ``reference_seed1``: the same preset with another seed, i.e. other cubature points and another
  training run of each skinning basis (sensitivity to the discretisation at the reference's own
  resolution; the contact spheres are the same, farthest-point sampling is deterministic);
* ``reference_contact+25%``: the reference with 25 % more contact spheres (sensitivity to the contact
  geometry: spheres of radius r round edges and corners by about r, and where a tumbling object lands
  on an edge decides its bounce).
A preset whose error is near these floors is as accurate as the scene allows this comparison to show.
Two more rows: ``draft_exact_matrix`` is ``draft`` with ``lagged_elastic_hessian=False`` (the time and error
of the lagged elastic Newton matrix against the exact one, side by side), ``draft_formed_matrix`` is ``draft``
with ``elastic_hessian_reuse=0`` (the kept matrix formed at every (sub)step, not reused across them).

Scenes with several variants (``SCENE_VARIANTS``: the rigid drop is repeated with 5 spins and
orientations) report the mean over variants, with the per-variant errors in the JSON.

    python bench/bench_sim_quality.py            # full: 2 s per scene, every preset
    python bench/bench_sim_quality.py --quick    # a few minutes on 2 CPU cores (shorter, coarser reference)
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from sim_bench_scenes import QUICK_TRAINING, SCENE_VARIANTS, SCENES  # noqa: E402

from data_gen.sim.presets import QualityPreset, load_preset  # noqa: E402
from data_gen.sim.reduced import deform  # noqa: E402
from data_gen.sim.world import Simulator  # noqa: E402

RESULTS = Path(__file__).resolve().parent / "results"
PRESETS = ["draft", "standard", "high", "reference"]
# draft as it would run with an exact elastic Newton matrix at every iteration (``lagged_elastic_hessian=False``)
EXACT_DRAFT = "draft_exact_matrix"
# draft with its kept elastic matrix formed at every (sub)step (``elastic_hessian_reuse=0``)
FORMED_DRAFT = "draft_formed_matrix"
FPS = 25.0
GRAVITY = (0.0, 0.0, -9.81)


def probe_positions(result, specs, num_probe: int = 200) -> np.ndarray:
    """World positions (T, objects * num_probe, 3) of fixed rest points of every object."""
    out = []
    for k, (track, spec) in enumerate(zip(result.objects, specs)):
        pts = np.asarray(spec.points_rest_m)
        idx = np.random.default_rng(k).choice(len(pts), size=min(num_probe, len(pts)), replace=False)
        x0 = torch.from_numpy(pts[idx])
        weights, grads = track.basis.evaluate(x0)
        frames = [deform(x0, weights, grads, torch.from_numpy(z))[0].numpy() for z in track.handle_transforms]
        out.append(np.stack(frames))
    return np.concatenate(out, axis=1)


CHAOS_SHIFT_M = 1e-4  # initial position shift of the chaos-floor run
CONTACT_FLOOR_FACTOR = 1.25  # contact-sphere count factor of the contact-geometry floor run
MEAN_KEYS = ("com_rms_m", "com_rms_rel_travelled", "point_rms_m", "point_rms_rel_motion")


def run_one(
    scene_name: str,
    preset: QualityPreset,
    seconds: float,
    training,
    seed: int = 0,
    shift_m: float = 0.0,
    label: str | None = None,
    variant: int = 0,
) -> dict:
    scene, specs = SCENES[scene_name](training, variant)
    if shift_m:
        specs = [
            dataclasses.replace(s, position_m=tuple(np.asarray(s.position_m) + (shift_m, 0.0, 0.0))) for s in specs
        ]
    t0 = time.perf_counter()
    sim = Simulator(scene, specs, GRAVITY, preset, seed=seed)
    setup = time.perf_counter() - t0
    result = sim.run(num_frames=int(round(seconds * FPS)) + 1, fps=FPS)
    com = np.stack([tr.com_m for tr in result.objects], axis=1)  # (T, N, 3)
    penetration = max(
        float((tr.contact_radius_m[None] - tr.contact_positions_m[:, :, 2]).max()) for tr in result.objects
    )
    return {
        "scene": scene_name,
        "preset": label or preset.name,
        "seconds": seconds,
        "setup_s": setup,
        "wall_s": result.info.wall_time_s,
        "wall_per_sim_s": result.info.wall_time_s / seconds,
        "newton_iterations": result.info.newton_iterations,
        "steps": result.info.num_steps,
        "awake_fraction": result.info.awake_object_steps / max(1, result.info.object_steps),
        "max_ground_penetration_m": max(0.0, penetration),
        "contact_radius_m": float(min(tr.contact_radius_m.min() for tr in result.objects)),
        "events": len(result.collisions),
        "island_solves": result.info.counters["island_solves"],
        "unconverged_solves": result.info.counters["unconverged_solves"],
        "timings_s": result.info.timings_s,
        "_com": com,
        "_probe": probe_positions(result, specs),
    }


def compare(run: dict, ref: dict) -> dict:
    com, com_ref = run["_com"], ref["_com"]
    err = np.linalg.norm(com - com_ref, axis=2)  # (T, N)
    travelled = np.linalg.norm(np.diff(com_ref, axis=0), axis=2).sum(axis=0)  # path length per object
    probe, probe_ref = run["_probe"], ref["_probe"]
    motion = np.sqrt(np.mean(np.sum((probe_ref - probe_ref[:1]) ** 2, axis=2)))
    point_rms = np.sqrt(np.mean(np.sum((probe - probe_ref) ** 2, axis=2)))
    return {
        "com_rms_m": float(np.sqrt(np.mean(err**2))),
        "com_rms_rel_travelled": float(np.sqrt(np.mean(err**2)) / max(travelled.mean(), 1e-12)),
        "point_rms_m": float(point_rms),
        "point_rms_rel_motion": float(point_rms / max(motion, 1e-12)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true", help="short runs and a coarser reference (minutes)")
    parser.add_argument("--scenes", nargs="*", default=list(SCENES))
    parser.add_argument("--seconds", type=float, default=None)
    parser.add_argument("--out", default="sim_quality", help="results name: bench/results/<out>.json/.png")
    args = parser.parse_args()
    torch.set_num_threads(1)
    seconds = args.seconds or (0.6 if args.quick else 2.0)
    presets = {name: load_preset(name) for name in PRESETS}
    if args.quick:
        # the quick reference keeps the reference's time step and tolerance but caps cubature/handles
        presets["reference"] = presets["reference"].replace(num_cubature_points=256, max_handles=6)
    training = QUICK_TRAINING
    RESULTS.mkdir(parents=True, exist_ok=True)
    meta = {
        "quick": args.quick,
        "seconds": seconds,
        "fps": FPS,
        "torch_threads": 1,
        "reference_preset": presets["reference"].__dict__,
        "note": "wall times on a shared 2-core CPU",
    }
    rows = []
    ref = presets["reference"]
    floor_name = f"reference+{CHAOS_SHIFT_M * 1e3:g}mm"
    contact_name = f"reference_contact+{round(100 * (CONTACT_FLOOR_FACTOR - 1))}%"
    contact_ref = ref.replace(num_contact_points=int(round(CONTACT_FLOOR_FACTOR * ref.num_contact_points)))
    for scene_name in args.scenes:
        per_variant: dict[str, list[dict]] = {}
        for variant in range(SCENE_VARIANTS[scene_name]):
            runs = {
                name: run_one(scene_name, preset, seconds, training, variant=variant)
                for name, preset in presets.items()
            }
            runs[floor_name] = run_one(
                scene_name, ref, seconds, training, shift_m=CHAOS_SHIFT_M, label=floor_name, variant=variant
            )
            runs["reference_seed1"] = run_one(
                scene_name, ref, seconds, training, seed=1, label="reference_seed1", variant=variant
            )
            runs[contact_name] = run_one(scene_name, contact_ref, seconds, training, label=contact_name, variant=variant)
            # the lagged elastic matrix's trade: draft with the exact matrix at every Newton iteration
            exact = presets["draft"].replace(lagged_elastic_hessian=False, elastic_hessian_reuse=0.0)
            runs[EXACT_DRAFT] = run_one(scene_name, exact, seconds, training, label=EXACT_DRAFT, variant=variant)
            # ... and the reuse's trade: draft with the kept matrix formed at every (sub)step
            formed = presets["draft"].replace(elastic_hessian_reuse=0.0)
            runs[FORMED_DRAFT] = run_one(scene_name, formed, seconds, training, label=FORMED_DRAFT, variant=variant)
            for name, run in runs.items():
                row = {k: v for k, v in run.items() if not k.startswith("_")}
                row.update(compare(run, runs["reference"]))
                row["speedup_vs_reference"] = runs["reference"]["wall_s"] / run["wall_s"]
                per_variant.setdefault(name, []).append(row)
        merged = {name: _mean_over_variants(variant_rows) for name, variant_rows in per_variant.items()}
        for name in PRESETS + [floor_name, "reference_seed1", contact_name, EXACT_DRAFT, FORMED_DRAFT]:
            row = merged[name]
            row["speedup_vs_reference"] = merged["reference"]["wall_s"] / row["wall_s"]
            rows.append(row)
            print(
                f"{scene_name:14s} {name:17s} wall/sim-s {row['wall_per_sim_s']:8.2f} s  "
                f"x{row['speedup_vs_reference']:6.1f} vs ref  COM err {100 * row['com_rms_rel_travelled']:6.2f} % "
                f"({row['com_rms_m'] * 1e3:7.2f} mm)  point err {100 * row['point_rms_rel_motion']:6.2f} %  "
                f"pen {row['max_ground_penetration_m'] * 1e3:6.2f} mm (r {row['contact_radius_m'] * 1e3:5.1f})  "
                f"newton {row['newton_iterations']:5d} (unconverged {row['unconverged_solves']}/"
                f"{row['island_solves']})  setup {row['setup_s']:6.1f} s",
                flush=True,
            )
        # written after every scene, so a long run leaves its finished scenes behind
        (RESULTS / f"{args.out}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=2))
    plot(rows, RESULTS / f"{args.out}.png")
    print(f"wrote {RESULTS / args.out}.json and .png")


def _mean_over_variants(variant_rows: list[dict]) -> dict:
    """One row for a preset on a scene: wall times summed over variants (so per-sim-s figures and the
    speed-up stay ratios of totals), errors averaged, maxima kept, per-variant errors listed."""
    row = dict(variant_rows[0])
    if len(variant_rows) == 1:
        return row
    total = sum(r["wall_s"] for r in variant_rows)
    seconds = sum(r["seconds"] for r in variant_rows)
    row.update(
        variants=len(variant_rows),
        seconds=seconds,
        wall_s=total,
        wall_per_sim_s=total / seconds,
        setup_s=sum(r["setup_s"] for r in variant_rows),
        newton_iterations=sum(r["newton_iterations"] for r in variant_rows),
        steps=sum(r["steps"] for r in variant_rows),
        events=sum(r["events"] for r in variant_rows),
        island_solves=sum(r["island_solves"] for r in variant_rows),
        unconverged_solves=sum(r["unconverged_solves"] for r in variant_rows),
        max_ground_penetration_m=max(r["max_ground_penetration_m"] for r in variant_rows),
        contact_radius_m=min(r["contact_radius_m"] for r in variant_rows),
        awake_fraction=float(np.mean([r["awake_fraction"] for r in variant_rows])),
        timings_s={k: sum(r["timings_s"].get(k, 0.0) for r in variant_rows) for k in variant_rows[0]["timings_s"]},
    )
    for key in MEAN_KEYS:
        row[key] = float(np.mean([r[key] for r in variant_rows]))
        row[f"{key}_per_variant"] = [r[key] for r in variant_rows]
    return row


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 4.5))
    for scene in sorted({r["scene"] for r in rows}):
        sel = [r for r in rows if r["scene"] == scene and r["preset"] in PRESETS[:-1]]
        (line,) = ax.plot(
            [r["wall_per_sim_s"] for r in sel],
            [100 * max(r["com_rms_rel_travelled"], 1e-6) for r in sel],
            "o-",
            label=scene,
        )
        for r in sel:
            ax.annotate(
                r["preset"], (r["wall_per_sim_s"], 100 * max(r["com_rms_rel_travelled"], 1e-6)), fontsize=7
            )
        floors = [
            r["com_rms_rel_travelled"]
            for r in rows
            if r["scene"] == scene and (r["preset"] == "reference_seed1" or r["preset"].startswith("reference_contact"))
        ]
        if floors:  # the larger of the discretisation floors (seed, contact geometry)
            ax.axhline(100 * max(max(floors), 1e-6), color=line.get_color(), lw=0.8, ls=":")
        for r in rows:  # draft with the exact elastic matrix: a hollow marker beside draft
            if r["scene"] == scene and r["preset"] == EXACT_DRAFT:
                xy = (r["wall_per_sim_s"], 100 * max(r["com_rms_rel_travelled"], 1e-6))
                ax.plot(*xy, "o", mfc="none", color=line.get_color())
                ax.annotate("draft, exact matrix", xy, fontsize=7)
    ax.set_xscale("log")
    ax.set_yscale("log")
    ax.set_xlabel("wall time per simulated second (s, 1 CPU thread)")
    ax.set_ylabel("COM RMS error vs reference (% of distance travelled)")
    ax.axhline(5.0, color="grey", lw=0.8, ls="--", label="5 % target")
    ax.legend()
    ax.set_title(
        "Speed vs accuracy per preset (dotted: reference vs itself with another seed or\n25 % more contact "
        "spheres, the larger; rigid drop: mean of 5 drops)",
        fontsize=8,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=120)


if __name__ == "__main__":
    main()
