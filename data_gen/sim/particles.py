"""Simulation particles: Monte Carlo interior sampling of a solid and its mass.

An object's interior is given by a membership test: a callable taking rest
points as a NumPy array (k, 3) float64 in m and returning either a boolean
mask (k,) (True = inside) or signed distances (k,) in m (negative = inside).
Uniform points are drawn in an axis-aligned box and rejected outside; the
accepted points are uniform in the solid, and the volume is the box volume
times the accepted fraction, with its binomial standard error.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch

from data_gen.sim.material import Material

InsideFn = Callable[[np.ndarray], np.ndarray]

_DEFAULT_BATCH = 65536


@dataclass(frozen=True)
class InteriorSample:
    """Result of rejection sampling.

    Attributes:
        points: (n, 3) float64 tensor of rest positions, m, uniform in the solid.
        volume_m3: Monte Carlo volume estimate, m^3.
        volume_std_error_m3: its standard error, m^3 (binomial).
        num_drawn: number of box samples drawn (accepted or not).
    """

    points: torch.Tensor
    volume_m3: float
    volume_std_error_m3: float
    num_drawn: int


def sample_interior(
    inside_fn: InsideFn,
    bounds_min: tuple[float, float, float] | np.ndarray,
    bounds_max: tuple[float, float, float] | np.ndarray,
    num_points: int,
    seed: int,
    batch_size: int = _DEFAULT_BATCH,
    max_draws: int | None = None,
) -> InteriorSample:
    """Rejection-sample ``num_points`` uniform interior points and estimate the volume.

    Args:
        inside_fn: membership test (see module docstring).
        bounds_min, bounds_max: corners of a box containing the solid, m.
        num_points: number of interior points to return, >= 1.
        seed: seed of the uniform draws.
        batch_size: box samples per call of ``inside_fn``.
        max_draws: give up after this many box samples (default 1000 x num_points,
            at least 1e6); raises ValueError if fewer than ``num_points`` were accepted.

    The volume uses every drawn sample (accepted / drawn x box volume), so it is
    an unbiased binomial estimate; the returned points are the first
    ``num_points`` accepted ones.
    """
    lo, hi = _check_box(bounds_min, bounds_max)
    if not isinstance(num_points, int) or num_points < 1:
        raise ValueError(f"num_points={num_points!r} is out of range; allowed: integer >= 1")
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"batch_size={batch_size!r} is out of range; allowed: integer >= 1")
    limit = max(1000 * num_points, 1_000_000) if max_draws is None else int(max_draws)
    rng = np.random.default_rng(seed)
    box_volume = float(np.prod(hi - lo))
    accepted: list[np.ndarray] = []
    num_accepted = 0
    drawn = 0
    while num_accepted < num_points and drawn < limit:  # loop over batches, not points
        k = min(batch_size, limit - drawn)
        samples = lo + (hi - lo) * rng.random((k, 3))
        mask = _inside_mask(inside_fn, samples)
        accepted.append(samples[mask])
        num_accepted += int(mask.sum())
        drawn += k
    if num_accepted == 0:
        raise ValueError(
            f"inside_fn accepted 0 of {drawn} samples in the box {lo.tolist()}..{hi.tolist()} m: "
            "the solid has zero volume there; allowed: a solid with positive volume inside the box"
        )
    if num_accepted < num_points:
        raise ValueError(
            f"only {num_accepted} of num_points={num_points} interior points found in max_draws={limit} "
            f"samples (accepted fraction {num_accepted / drawn:.2e}); tighten the box or raise max_draws"
        )
    fraction = num_accepted / drawn
    points = torch.from_numpy(np.concatenate(accepted)[:num_points]).to(torch.float64)
    return InteriorSample(
        points=points,
        volume_m3=box_volume * fraction,
        volume_std_error_m3=box_volume * math.sqrt(fraction * (1.0 - fraction) / drawn),
        num_drawn=drawn,
    )


def sample_interior_points(
    inside_fn: InsideFn,
    bounds_min: tuple[float, float, float] | np.ndarray,
    bounds_max: tuple[float, float, float] | np.ndarray,
    num_points: int,
    seed: int,
) -> tuple[torch.Tensor, float]:
    """Interior points (n, 3) float64 in m and the volume estimate in m^3 (see ``sample_interior``)."""
    sample = sample_interior(inside_fn, bounds_min, bounds_max, num_points, seed)
    return sample.points, sample.volume_m3


@dataclass(frozen=True)
class ObjectParticles:
    """Simulation particles of one object, each representing volume_m3 / n of it.

    Attributes:
        points: (n, 3) float64 rest positions, m.
        volume_m3: object volume, m^3, > 0.
        material: the object's material (density gives the mass).
    """

    points: torch.Tensor
    volume_m3: float
    material: Material

    def __post_init__(self) -> None:
        p = self.points
        if not isinstance(p, torch.Tensor) or p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 1:
            shape = tuple(p.shape) if isinstance(p, torch.Tensor) else type(p).__name__
            raise ValueError(f"points must be a tensor of shape (n, 3) with n >= 1; got {shape}")
        if p.dtype != torch.float64:
            raise ValueError(f"points must be float64; got {p.dtype}")
        if not bool(torch.isfinite(p).all()):
            raise ValueError("points contains non-finite values; allowed: finite coordinates in m")
        if not (self.volume_m3 > 0.0) or math.isinf(self.volume_m3):
            raise ValueError(f"volume_m3={self.volume_m3!r} is out of range; allowed: 0 < volume < inf (m^3)")

    @property
    def num_points(self) -> int:
        return int(self.points.shape[0])

    @property
    def mass_kg(self) -> float:
        """Total mass = density x volume, kg."""
        return self.material.density_kg_m3 * self.volume_m3

    @property
    def point_volume_m3(self) -> float:
        """Volume each particle represents, m^3."""
        return self.volume_m3 / self.num_points

    @property
    def point_mass_kg(self) -> float:
        """Mass each particle represents, kg."""
        return self.mass_kg / self.num_points

    @property
    def center_of_mass_m(self) -> torch.Tensor:
        """(3,) mean of the particles (uniform density), m."""
        return self.points.mean(dim=0)


def _check_box(bounds_min, bounds_max) -> tuple[np.ndarray, np.ndarray]:
    lo = np.asarray(bounds_min, dtype=np.float64)
    hi = np.asarray(bounds_max, dtype=np.float64)
    if lo.shape != (3,) or hi.shape != (3,):
        raise ValueError(f"bounds_min and bounds_max must have 3 entries; got shapes {lo.shape} and {hi.shape}")
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
        raise ValueError(
            f"bounds_min={lo.tolist()} and bounds_max={hi.tolist()} are invalid; allowed: finite, max > min per axis"
        )
    return lo, hi


def _inside_mask(inside_fn: InsideFn, samples: np.ndarray) -> np.ndarray:
    out = inside_fn(samples)
    if isinstance(out, torch.Tensor):
        out = out.detach().cpu().numpy()
    out = np.asarray(out)
    if out.shape != (samples.shape[0],):
        raise ValueError(f"inside_fn must return shape ({samples.shape[0]},); got {out.shape}")
    if out.dtype == np.bool_:
        return out
    if np.issubdtype(out.dtype, np.floating):
        return out < 0.0
    raise ValueError(f"inside_fn must return a bool mask or float signed distances; got dtype {out.dtype}")
