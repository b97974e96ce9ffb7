"""Skinning training: seconds per trained basis, and subspace energy vs baselines.

On a 0.4 x 0.1 x 0.1 m beam (2000 uniform particles, nu = 0.3) this measures, in one run:

* seconds per trained basis (no cache) vs number of handles H at the default
  settings, and vs the number of Adam steps at H = 6;
* the elastic energy per unit perturbation of each subspace
  (``perturbation_energy``: columns orthonormalised, E = 1, lower is better) for
  the learned basis, a linear-blend-skinning baseline (H Gaussian RBF weights
  normalised to a partition of unity, centres spread by ``sample_cubature``,
  width = their spacing) and the random-init MLP the training starts from.

Prints a table with the ratio learned / LBS, writes bench/results/skinning.json
and bench/results/skinning.png.

    python bench/bench_skinning.py            # default settings (a few minutes on 2 cores)
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
    SkinningBasis,
    SkinningMLP,
    SkinningTrainingSettings,
    normalised_frame,
    perturbation_energy,
    train_skinning_basis,
)

RESULTS = Path(__file__).resolve().parent / "results"
NU = 0.3
BEAM_M = (0.4, 0.1, 0.1)


def beam_points(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor(BEAM_M, dtype=torch.float64)


def lbs_basis(points: torch.Tensor, num_handles: int, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Linear blend skinning: H normalised Gaussian RBF weights; returns [1, w_1..w_{H-1}] and gradients (1/m).

    The H blend weights sum to 1, so the constant column plus H - 1 of them span the same space.
    """
    volume = BEAM_M[0] * BEAM_M[1] * BEAM_M[2]
    centres = sample_cubature(points, num_handles, seed=seed, volume_m3=volume).positions  # (H, 3)
    sigma = (volume / num_handles) ** (1.0 / 3.0)
    diff = points[:, None, :] - centres[None]  # (n, H, 3)
    g = torch.exp(-0.5 * (diff**2).sum(-1) / sigma**2)  # (n, H)
    dg = -g[:, :, None] * diff / sigma**2
    total, dtotal = g.sum(1), dg.sum(1)
    w = g / total[:, None]
    dw = (dg * total[:, None, None] - g[:, :, None] * dtotal[:, None, :]) / total[:, None, None] ** 2
    ones, zeros = torch.ones(len(points), 1, dtype=torch.float64), torch.zeros(len(points), 1, 3, dtype=torch.float64)
    return torch.cat((ones, w[:, 1:]), 1), torch.cat((zeros, dw[:, 1:]), 1)


def random_init_basis(points: torch.Tensor, num_handles: int, settings: SkinningTrainingSettings, seed: int):
    center, half, _ = normalised_frame(points)
    mlp = SkinningMLP(num_handles - 1, settings.hidden_layers, settings.width)
    mlp.reset_parameters(torch.Generator().manual_seed(seed))
    return SkinningBasis(num_handles, mlp, center, half).evaluate(points)


def train_timed(points, num_handles, settings, seed) -> tuple[float, float]:
    with tempfile.TemporaryDirectory() as cache:  # a fresh cache: always a miss
        t0 = time.perf_counter()
        basis = train_skinning_basis(points, num_handles, NU, settings, seed=seed, cache_dir=cache)
        seconds = time.perf_counter() - t0
    w, g = basis.evaluate(points)
    return seconds, perturbation_energy(w, g, points, NU, num_perturbations=128, seed=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    default = SkinningTrainingSettings()
    if args.quick:
        default = dataclasses.replace(default, steps=100)
    handle_counts = [2, 4, 6] if args.quick else [2, 4, 6, 8, 12]
    step_counts = [25, 100] if args.quick else [100, 250, 500, 1000]
    x = beam_points(2000, seed=0)
    rows = []
    print(f"{'H':>3} {'steps':>6} {'s/basis':>8} {'E learned':>10} {'E LBS':>9} {'E rand':>9} {'learned/LBS':>12}")
    for h in handle_counts:
        seconds, e_learned = train_timed(x, h, default, seed=0)
        w, g = lbs_basis(x, h, seed=0)
        e_lbs = perturbation_energy(w, g, x, NU, num_perturbations=128, seed=1)
        w0, g0 = random_init_basis(x, h, default, seed=0)
        e_rand = perturbation_energy(w0, g0, x, NU, num_perturbations=128, seed=1)
        rows.append({"num_handles": h, "steps": default.steps, "seconds": seconds, "energy_learned": e_learned,
                     "energy_lbs": e_lbs, "energy_random_init": e_rand, "ratio_learned_over_lbs": e_learned / e_lbs})
        print(f"{h:>3} {default.steps:>6} {seconds:>8.2f} {e_learned:>10.1f} {e_lbs:>9.1f} {e_rand:>9.1f} "
              f"{e_learned / e_lbs:>12.3f}", flush=True)
    step_rows = []
    print(f"\n{'steps':>6} {'s/basis':>8} {'E learned':>10}   (H = 6)")
    for steps in step_counts:
        seconds, e = train_timed(x, 6, dataclasses.replace(default, steps=steps), seed=0)
        step_rows.append({"num_handles": 6, "steps": steps, "seconds": seconds, "energy_learned": e})
        print(f"{steps:>6} {seconds:>8.2f} {e:>10.1f}", flush=True)

    RESULTS.mkdir(parents=True, exist_ok=True)
    out = {
        "bench": "skinning", "quick": args.quick, "shape_m": BEAM_M, "num_points": 2000, "poisson_ratio": NU,
        "settings": dataclasses.asdict(default), "by_handles": rows, "by_steps": step_rows,
        "machine": {"platform": platform.platform(), "cpu_count": os.cpu_count(),
                    "load_avg_1min": os.getloadavg()[0], "torch": torch.__version__},
        "energy_metric": "perturbation_energy: mean stable neo-Hookean energy density (E=1, lengths / longest side) "
                         "of 128 random perturbations T~0.01 N(0,1) of orthonormalised non-constant handles, / 0.01^2",
    }
    (RESULTS / "skinning.json").write_text(json.dumps(out, indent=2))
    _plot(rows, step_rows)
    print(f"\nwrote {RESULTS / 'skinning.json'}")


def _plot(rows: list[dict], step_rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    hs = [r["num_handles"] for r in rows]
    for key, label in (("energy_learned", "learned (Simplicits)"), ("energy_lbs", "LBS (RBF)"),
                       ("energy_random_init", "random-init MLP")):
        a.plot(hs, [r[key] for r in rows], "o-", label=label)
    a.set_xlabel("handles H")
    a.set_ylabel("energy per unit perturbation (E=1)")
    a.set_yscale("log")
    a.legend()
    b.plot([r["steps"] for r in step_rows], [r["seconds"] for r in step_rows], "o-")
    b.set_xlabel("Adam steps (H = 6)")
    b.set_ylabel("seconds per basis")
    fig.tight_layout()
    fig.savefig(RESULTS / "skinning.png", dpi=100)


if __name__ == "__main__":
    main()
