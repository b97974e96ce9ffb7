"""Skinning training: seconds per trained basis, and subspace energy vs baselines, before/after.

On a 0.4 x 0.1 x 0.1 m beam (2000 uniform particles, nu = 0.3) this measures, in one run:

* seconds per trained basis (no cache, one torch thread) vs number of handles H at the
  default settings, and vs the number of Adam steps at H = 6;
* the elastic energy per unit perturbation of each subspace (E = 1, lower is better), both
  the Monte-Carlo ``perturbation_energy`` (128 draws, the measure of the previous run) and
  its closed form ``expected_perturbation_energy``, for: the shipped basis, a
  linear-blend-skinning baseline (H Gaussian RBF weights normalised to a partition of
  unity, centres from ``sample_cubature``, width (V / H)^(1/3); the same baseline as the
  previous run), the training guard's own blend baseline (``blend_basis``) and the
  random-init MLP;
* the closed-form energy on 2000 held-out points of the same beam (generalisation: the
  basis is evaluated, not retrained, there; the LBS keeps its centres);
* checkpoint selection, in the same run: on 20 % held-out points with an early stop (the
  default since skinning format v5) against on the training points for every step (before),
  on the beam (vs steps) and on every deformable object of ``--pile-draws`` ``pile`` draws
  (the pipeline's ~1,000 particles, handle counts and ``standard``'s 500 steps), each
  scored on 8,000 fresh interior points of its shape;
* the "before" columns: the numbers this bench measured with skinning format v3
  (Monte-Carlo loss, Cholesky-mixed batches; bench/results/skinning.json of that run).

Prints a table with the ratio shipped / LBS (both measured in this run), writes
bench/results/skinning.json and bench/results/skinning.png.

    python bench/bench_skinning.py            # default settings (~2 minutes)
    python bench/bench_skinning.py --quick    # 100 steps, fewer handle counts
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import torch

from data_gen.sim.cubature import sample_cubature
from data_gen.sim.skinning import (
    BlendWeights,
    SkinningBasis,
    SkinningMLP,
    SkinningTrainingSettings,
    blend_basis,
    expected_perturbation_energy,
    normalised_frame,
    perturbation_energy,
    train_skinning_basis,
)
from data_gen.sim.threads import torch_threads

RESULTS = Path(__file__).resolve().parent / "results"
NU = 0.3
BEAM_M = (0.4, 0.1, 0.1)
MC_DRAWS = 128

# Measured by this bench with skinning format v3 (500 steps at lr 1e-2, Monte-Carlo loss), same
# beam, points and seeds: Monte-Carlo energy (128 draws) of the learned basis and seconds per basis.
BEFORE_BY_HANDLES = {2: (15.62, 17.50), 4: (180.28, 15.03), 6: (626.42, 10.90), 8: (1290.56, 11.76),
                     12: (3748.72, 8.91)}
BEFORE_BY_STEPS = {100: (616.17, 1.45), 250: (656.29, 5.50), 500: (626.42, 10.67), 1000: (649.48, 20.94)}


def beam_points(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor(BEAM_M, dtype=torch.float64)


def lbs_weights(points: torch.Tensor, num_handles: int, seed: int) -> BlendWeights:
    """Linear blend skinning: H normalised Gaussian RBFs at ``sample_cubature`` centres, width (V / H)^(1/3)."""
    volume = BEAM_M[0] * BEAM_M[1] * BEAM_M[2]
    centres = sample_cubature(points, num_handles, seed=seed, volume_m3=volume).positions  # (H, 3)
    sigma = (volume / num_handles) ** (1.0 / 3.0)
    return BlendWeights(centres, sigma, torch.eye(num_handles, dtype=torch.float64))


def random_init_basis(points: torch.Tensor, num_handles: int, settings: SkinningTrainingSettings, seed: int):
    center, half, _ = normalised_frame(points)
    mlp = SkinningMLP(num_handles - 1, settings.hidden_layers, settings.width)
    mlp.reset_parameters(torch.Generator().manual_seed(seed))
    return SkinningBasis(num_handles, mlp, center, half)


def energies(evaluate, x: torch.Tensor, x_test: torch.Tensor) -> dict[str, float]:
    """Monte-Carlo and closed-form energy on the training points, closed form on held-out points."""
    w, g = evaluate(x)
    wt, gt = evaluate(x_test)
    return {"mc": perturbation_energy(w, g, x, NU, num_perturbations=MC_DRAWS, seed=1),
            "exact": expected_perturbation_energy(w, g, x, NU),
            "exact_heldout": expected_perturbation_energy(wt, gt, x_test, NU)}


def training_selection(settings: SkinningTrainingSettings) -> SkinningTrainingSettings:
    """The selection before held-out points: checkpoints scored on the points trained on, no early stop."""
    return dataclasses.replace(settings, validation_fraction=0.0, patience=10**9)


def pile_objects(num_draws: int, fresh_points: int = 8000) -> list[dict]:
    """Each deformable object of ``num_draws`` ``pile`` draws (the pipeline's particles and handle count,
    ``standard``'s 500 steps) trained with held-out selection and with selection on its training points; both
    scored by the expected energy on ``fresh_points`` new interior points of the same shape."""
    import numpy as np

    from data_gen.configs import render_settings, scenario_config
    from data_gen.pipeline import build_objects
    from data_gen.scenario import sample_scenario
    from data_gen.sim.presets import load_preset
    from data_gen.sim.world import object_handle_count

    preset = load_preset("standard")
    settings = SkinningTrainingSettings(steps=preset.skinning_training_steps)
    cfg = scenario_config("pile", scenes=("empty_floor",), num_objects=(5, 5))
    rows = []
    print(f"\npile objects ({num_draws} draws, standard, {settings.steps} steps at most), energy on {fresh_points} "
          f"fresh points:\n{'draw':>4} {'object':>14} {'H':>2} {'held-out sel.':>13} {'s':>6} {'run':>4} | "
          f"{'training sel.':>13} {'s':>6} | ratio")
    for draw in range(num_draws):
        scenario = sample_scenario(cfg, f"skin-{draw}", 5000 + draw, "train", "earth", 50, 25.0, (64, 64))
        for obj in build_objects(scenario, render_settings()):
            x = torch.as_tensor(obj.interior_points_m, dtype=torch.float64)
            h = object_handle_count(obj.interior_points_m, obj.material, preset.max_handles)  # the Simulator's count
            if h == 1:
                continue
            spacing = (obj.volume_m3 / fresh_points) ** (1.0 / 3.0)
            fresh = torch.as_tensor(obj.asset.interior_points(spacing, np.random.default_rng(123)), dtype=torch.float64)
            row = {"draw": draw, "object": obj.asset.name, "num_handles": h, "points": len(x), "fresh": len(fresh)}
            for key, s in (("held_out", settings), ("training", training_selection(settings))):
                seconds, basis = train_timed(x, h, s, seed=7 + draw)
                row[key] = {"seconds": seconds, "fresh_energy": expected_perturbation_energy(*basis.evaluate(fresh),
                            fresh, NU), "steps_kept": basis.metadata.get("steps_kept"),
                            "steps_run": basis.metadata.get("steps_run")}  # fmt: skip
            row["ratio"] = row["held_out"]["fresh_energy"] / row["training"]["fresh_energy"]
            rows.append(row)
            a, b = row["held_out"], row["training"]
            print(f"{draw:>4} {obj.asset.name:>14} {h:>2} {a['fresh_energy']:>13.2f} {a['seconds']:>6.2f} "
                  f"{a['steps_run']:>4} | {b['fresh_energy']:>13.2f} {b['seconds']:>6.2f} | {row['ratio']:.3f}", flush=True)
    if rows:
        ratios = sorted(r["ratio"] for r in rows)
        secs = [(r["held_out"]["seconds"], r["training"]["seconds"]) for r in rows]
        print(f"{len(rows)} objects: fresh-point energy held-out / training selection: median "
              f"{ratios[len(ratios) // 2]:.3f}, min {ratios[0]:.3f}, max {ratios[-1]:.3f}; seconds per basis "
              f"{sum(a for a, _ in secs) / len(secs):.2f} vs {sum(b for _, b in secs) / len(secs):.2f}")
    return rows


def train_timed(points, num_handles, settings, seed) -> tuple[float, SkinningBasis]:
    with tempfile.TemporaryDirectory() as cache:  # a fresh cache: always a miss
        t0 = time.perf_counter()
        basis = train_skinning_basis(points, num_handles, NU, settings, seed=seed, cache_dir=cache)
        seconds = time.perf_counter() - t0
    return seconds, basis


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--pile-draws", type=int, default=None,
                    help="pile draws whose deformable objects train both ways (default 4; --quick 1)")
    args = ap.parse_args()
    if args.pile_draws is None:
        args.pile_draws = 1 if args.quick else 4
    default = SkinningTrainingSettings()
    if args.quick:
        default = dataclasses.replace(default, steps=100)
    handle_counts = [2, 4, 6] if args.quick else [2, 4, 6, 8, 12]
    step_counts = [1, 25, 100] if args.quick else [1, 100, 250, 500, 1000]
    x = beam_points(2000, seed=0)
    x_test = beam_points(2000, seed=99)
    rows = []
    print(f"{'H':>3} {'s/basis':>8} {'before':>7} {'E before':>9} {'E shipped':>10} {'E LBS':>8} {'E rand':>8} "
          f"{'shipped/LBS':>12} {'exact shp':>10} {'exact LBS':>10} {'exact blend':>11} "
          f"{'held shp':>9} {'held LBS':>9}  source")
    with torch_threads(1):
        for h in handle_counts:
            seconds, basis = train_timed(x, h, default, seed=0)
            e = energies(basis.evaluate, x, x_test)
            e_lbs = energies(lbs_weights(x, h, seed=0).evaluate, x, x_test)
            e_blend = energies(blend_basis(x, h, seed=0).evaluate, x, x_test)
            e_rand = energies(random_init_basis(x, h, default, seed=0).evaluate, x, x_test)
            before_e, before_s = BEFORE_BY_HANDLES.get(h, (float("nan"), float("nan")))
            rows.append({"num_handles": h, "steps": default.steps, "seconds": seconds,
                         "seconds_before": before_s, "energy_learned_before": before_e,
                         "energy_learned": e["mc"], "energy_lbs": e_lbs["mc"], "energy_random_init": e_rand["mc"],
                         "ratio_learned_over_lbs": e["mc"] / e_lbs["mc"],
                         "ratio_learned_over_lbs_before": before_e / e_lbs["mc"],
                         "exact_learned": e["exact"], "exact_lbs": e_lbs["exact"], "exact_blend": e_blend["exact"],
                         "exact_random_init": e_rand["exact"],
                         "heldout_exact_learned": e["exact_heldout"], "heldout_exact_lbs": e_lbs["exact_heldout"],
                         "source": basis.metadata["source"], "steps_kept": basis.metadata.get("steps_kept")})
            print(f"{h:>3} {seconds:>8.2f} {before_s:>7.2f} {before_e:>9.1f} {e['mc']:>10.1f} {e_lbs['mc']:>8.1f} "
                  f"{e_rand['mc']:>8.1f} {e['mc'] / e_lbs['mc']:>12.3f} {e['exact']:>10.1f} {e_lbs['exact']:>10.1f} "
                  f"{e_blend['exact']:>11.1f} {e['exact_heldout']:>9.1f} {e_lbs['exact_heldout']:>9.1f}  "
                  f"{basis.metadata['source']}", flush=True)
        step_rows = []
        print(f"\n{'steps':>6} {'s/basis':>8} {'before s':>9} {'E before':>9} {'E shipped':>10} {'exact':>8} "
              f"{'held-out':>9} {'run':>5} | selected on training points: {'s/basis':>8} {'exact':>8} "
              f"{'held-out':>9}   (H = 6)")
        for steps in step_counts:
            seconds, basis = train_timed(x, 6, dataclasses.replace(default, steps=steps), seed=0)
            e = energies(basis.evaluate, x, x_test)
            seconds_t, basis_t = train_timed(x, 6, training_selection(dataclasses.replace(default, steps=steps)), seed=0)
            e_t = energies(basis_t.evaluate, x, x_test)
            before_e, before_s = BEFORE_BY_STEPS.get(steps, (float("nan"), float("nan")))
            step_rows.append({"num_handles": 6, "steps": steps, "seconds": seconds, "energy_learned": e["mc"],
                              "exact_learned": e["exact"], "heldout_exact_learned": e["exact_heldout"],
                              "seconds_before": before_s, "energy_learned_before": before_e,
                              "steps_kept": basis.metadata.get("steps_kept"), "steps_run": basis.metadata.get("steps_run"),
                              "training_selection": {"seconds": seconds_t, "exact_learned": e_t["exact"],
                                                     "heldout_exact_learned": e_t["exact_heldout"],
                                                     "steps_kept": basis_t.metadata.get("steps_kept")}})
            print(f"{steps:>6} {seconds:>8.2f} {before_s:>9.2f} {before_e:>9.1f} {e['mc']:>10.1f} {e['exact']:>8.1f} "
                  f"{e['exact_heldout']:>9.1f} {basis.metadata.get('steps_run'):>5} | {seconds_t:>8.2f} "
                  f"{e_t['exact']:>8.1f} {e_t['exact_heldout']:>9.1f}", flush=True)
        pile_rows = pile_objects(args.pile_draws)

    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {
        "bench": "skinning", "quick": args.quick, "shape_m": BEAM_M, "num_points": 2000, "poisson_ratio": NU,
        "settings": dataclasses.asdict(default), "torch_threads": 1, "by_handles": rows, "by_steps": step_rows,
        "pile_objects": pile_rows,
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                    "load_avg_1min": os.getloadavg()[0], "torch": torch.__version__},
        "energy_metric": f"perturbation_energy: mean stable neo-Hookean energy density (E=1, lengths / longest side) "
                         f"of {MC_DRAWS} random perturbations T~0.01 N(0,1) of orthonormalised non-constant handles, "
                         f"/ 0.01^2; exact_*: its closed-form small-perturbation expectation "
                         f"(expected_perturbation_energy); heldout_*: closed form on 2000 other points of the beam",
        "before": "format v3 numbers measured by this bench in the previous run (Monte-Carlo loss, lr 1e-2, "
                  "500 steps): energy_learned_before (MC, 128 draws) and seconds_before",
    }
    (RESULTS / "skinning.json").write_text(json.dumps(out, indent=2))
    _plot(rows, step_rows)
    print(f"\nwrote {RESULTS / 'skinning.json'}")


def _plot(rows: list[dict], step_rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    hs = [r["num_handles"] for r in rows]
    for key, label, style in (("energy_learned_before", "learned, before (v3)", "s--"),
                              ("energy_learned", "shipped, after (v4)", "o-"),
                              ("energy_lbs", "LBS (RBF) baseline", "^-"),
                              ("energy_random_init", "random-init MLP", "x:")):
        a.plot(hs, [r[key] for r in rows], style, label=label)
    a.set_xlabel("handles H")
    a.set_ylabel("energy per unit perturbation (E=1, MC 128 draws)")
    a.set_yscale("log")
    a.set_title("beam 0.4x0.1x0.1 m, 2000 points, default settings")
    a.legend()
    steps = [r["steps"] for r in step_rows]
    b.plot(steps, [r["energy_learned_before"] for r in step_rows], "s--", label="before (v3), MC")
    b.plot(steps, [r["energy_learned"] for r in step_rows], "o-", label="after (v4), MC")
    b.plot(steps, [r["exact_learned"] for r in step_rows], "d-", label="after (v4), closed form")
    b.plot(steps, [r["heldout_exact_learned"] for r in step_rows], "v-.", label="after (v4), closed form, held-out")
    b.set_xscale("log")
    b.set_xlabel("Adam steps (H = 6)")
    b.set_ylabel("energy per unit perturbation (E=1)")
    b.legend(loc="upper left")
    t = b.twinx()
    t.plot(steps, [r["seconds"] for r in step_rows], "k.:", label="s/basis (after)")
    t.set_ylabel("seconds per basis (1 thread)")
    t.legend(loc="upper right")
    fig.tight_layout()
    fig.savefig(RESULTS / "skinning.png", dpi=100)


if __name__ == "__main__":
    main()
