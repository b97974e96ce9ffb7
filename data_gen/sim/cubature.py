"""Cubature points: a weighted subset of an object's particles for integrating energies.

The object's particles are uniform samples of its volume V (each stands for
V / n). Cubature picks m of them; each cubature point stands for a cluster
of particles and carries that cluster's volume, so the volumes sum to V
exactly and a volume-weighted sum approximates an integral over the solid.

How the m points are chosen:

1. Strata: the particles are split into a *contact region* (where contact is
   likely: near a plane, or any region given by a callable) and the rest.
   The region receives ``contact_bias`` times more cubature points per unit
   volume than the rest; each stratum's volumes are scaled to its own
   volume, so the estimator stays unbiased (stratified sampling).
2. Clusters: inside a stratum the particles are ordered along a Morton
   (Z-order) curve and cut into equal-count runs, one per cubature point, so
   the points spread evenly through space. One particle per run is drawn at
   random (seeded) and carries the run's volume.

The contact radius (m) is half the cubature spacing in the densest stratum,
0.5 (V_s / m_s)^(1/3), so neighbouring contact spheres just touch there.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import torch

RegionFn = Callable[[torch.Tensor], torch.Tensor]

_MORTON_BITS = 20  # bits per axis; 3 x 20 = 60 bits fit an int64
_LLOYD_ITERATIONS = 3  # Voronoi relaxation steps after the Morton-run start


@dataclass(frozen=True)
class CubatureSet:
    """Cubature points of one object.

    Attributes:
        indices: (m,) int64 indices into the particle array.
        positions: (m, 3) float64 rest positions, m.
        volumes_m3: (m,) float64 volume each point represents, m^3; sums to the object volume.
        radius_m: contact-sphere radius, m.
        in_contact_region: (m,) bool, True for points of the (denser) contact stratum.
    """

    indices: torch.Tensor
    positions: torch.Tensor
    volumes_m3: torch.Tensor
    radius_m: float
    in_contact_region: torch.Tensor

    @property
    def num_points(self) -> int:
        return int(self.indices.shape[0])


def sample_cubature(
    points_rest: torch.Tensor,
    num_points: int,
    seed: int,
    volume_m3: float,
    contact_region: float | RegionFn | None = None,
    contact_bias: float = 4.0,
    contact_distance_m: float | None = None,
) -> CubatureSet:
    """Choose ``num_points`` cubature points among the particles.

    Args:
        points_rest: (n, 3) particle rest positions, m, uniform in the solid.
        num_points: m, in [1, n].
        seed: seed of the random pick inside each cluster.
        volume_m3: object volume V, m^3 (> 0); the cubature volumes sum to it.
        contact_region: None (no bias), a plane height h in m (the region is
            z - h <= contact_distance_m in the rest frame, e.g. the lowest
            particle's z for "near the bottom"), or a callable taking the (n, 3)
            points and returning a bool mask (n,) or distances (n,) in m
            (the region is distance <= contact_distance_m).
        contact_bias: cubature density in the contact region relative to the
            rest, per unit volume, >= 1.
        contact_distance_m: thickness of the contact region, m (> 0); default
            10 % of the largest bounding-box side.
    """
    x = _check_points(points_rest)
    n = x.shape[0]
    if not isinstance(num_points, int) or not (1 <= num_points <= n):
        raise ValueError(f"num_points={num_points!r} is out of range; allowed: integer in [1, {n}]")
    if not (volume_m3 > 0.0) or math.isinf(volume_m3):
        raise ValueError(f"volume_m3={volume_m3!r} is out of range; allowed: 0 < volume < inf (m^3)")
    if not (contact_bias >= 1.0) or math.isinf(contact_bias):
        raise ValueError(f"contact_bias={contact_bias!r} is out of range; allowed: 1 <= bias < inf")
    lo, hi = x.min(dim=0).values, x.max(dim=0).values
    longest = float((hi - lo).max()) or 1.0  # a single particle has no extent
    distance = 0.1 * longest if contact_distance_m is None else float(contact_distance_m)
    if not (distance > 0.0):
        raise ValueError(f"contact_distance_m={contact_distance_m!r} is out of range; allowed: > 0 (m)")

    region = contact_mask(x, contact_region, distance)
    n_region = int(region.sum())
    m_region = _region_allocation(n_region, n - n_region, num_points, contact_bias)
    gen = torch.Generator().manual_seed(int(seed))
    point_volume = volume_m3 / n

    if 0 < n_region < n and (m_region == 0 or m_region == num_points):  # only for num_points = 1
        strata = [(torch.arange(n), num_points)]  # one point cannot serve two strata: merge them
    else:
        strata = [(torch.nonzero(region == flag).squeeze(1), m_s)
                  for flag, m_s in ((True, m_region), (False, num_points - m_region)) if m_s > 0]

    parts_idx, parts_vol, spacing = [], [], []
    for members, m_s in strata:  # at most two strata
        chosen, counts = _cluster_pick(x[members], m_s, lo, longest, gen)
        parts_idx.append(members[chosen])
        parts_vol.append(counts.to(torch.float64) * point_volume)
        spacing.append((members.shape[0] * point_volume / m_s) ** (1.0 / 3.0))
    indices = torch.cat(parts_idx)
    return CubatureSet(
        indices=indices,
        positions=x[indices].clone(),
        volumes_m3=torch.cat(parts_vol),
        radius_m=0.5 * min(spacing),
        in_contact_region=region[indices],
    )


def contact_mask(points: torch.Tensor, contact_region: float | RegionFn | None, distance_m: float) -> torch.Tensor:
    """Bool mask (n,) of the particles in the contact region (see ``sample_cubature``)."""
    n = points.shape[0]
    if contact_region is None:
        return torch.zeros(n, dtype=torch.bool)
    if callable(contact_region):
        out = torch.as_tensor(contact_region(points))
        if out.shape != (n,):
            raise ValueError(f"contact_region must return shape ({n},); got {tuple(out.shape)}")
        return out if out.dtype == torch.bool else out.to(torch.float64) <= distance_m
    height = float(contact_region)
    if not math.isfinite(height):
        raise ValueError(f"contact_region={contact_region!r} is out of range; allowed: a finite plane height (m)")
    return points[:, 2] - height <= distance_m


def _region_allocation(n_region: int, n_rest: int, num_points: int, bias: float) -> int:
    """Cubature points given to the contact region: proportional to bias x its particle count."""
    if n_region == 0:
        return 0
    if n_rest == 0:
        return num_points
    share = bias * n_region / (bias * n_region + n_rest)
    m_region = int(round(num_points * share))
    lo = max(1 if num_points >= 2 else 0, num_points - n_rest)  # every stratum gets a point when possible
    hi = min(n_region, num_points - (1 if num_points >= 2 else 0))
    return int(min(max(m_region, lo), hi))


def _cluster_pick(
    points: torch.Tensor, m: int, lo: torch.Tensor, longest: float, gen: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """Cluster the points of one stratum into m cells and pick one representative per cell.

    1. Cut the Morton-ordered points into m equal-count runs, the run starts
       shifted by a random (seeded) fraction of a run; each run's
       representative is its member nearest the run's centroid.
    2. ``_LLOYD_ITERATIONS`` times: give every point to its nearest
       representative (Voronoi cells, compact even where a Morton run jumps),
       then move each representative to the member nearest its cell's
       centroid. Cells are disjoint and never empty (a representative owns
       itself), so the representatives stay distinct.

    Returns (indices into ``points`` (m,), cell sizes (m,) int64).
    """
    k = points.shape[0]
    order = torch.argsort(morton_codes(points, lo, longest), stable=True)
    shift = float(torch.rand(1, generator=gen, dtype=torch.float64)) * k / m
    starts = torch.floor(torch.arange(m, dtype=torch.float64) * k / m + shift).to(torch.int64)
    run = torch.bucketize(torch.arange(k), starts, right=True) - 1  # run id per ordered position
    run = torch.where(run < 0, torch.full_like(run, m - 1), run)  # the head wraps into the last run
    cell = torch.empty(k, dtype=torch.int64)
    cell[order] = run
    reps = _member_nearest_centroid(points, cell, m)
    for _ in range(_LLOYD_ITERATIONS):  # loop over iterations, vectorised over points
        cell = _nearest(points, points[reps])
        cell[reps] = torch.arange(m)  # a representative owns itself even if another sits at the same spot
        reps = _member_nearest_centroid(points, cell, m)
    cell = _nearest(points, points[reps])
    cell[reps] = torch.arange(m)
    return reps, torch.bincount(cell, minlength=m)


def _member_nearest_centroid(points: torch.Tensor, cell: torch.Tensor, m: int) -> torch.Tensor:
    """For each of m non-empty cells, the index of its member nearest the cell centroid (ties: lowest index)."""
    k = points.shape[0]
    counts = torch.bincount(cell, minlength=m).to(torch.float64)
    centroids = torch.zeros(m, 3, dtype=torch.float64).index_add_(0, cell, points) / counts[:, None]
    dist = (points - centroids[cell]).norm(dim=1)
    best = torch.full((m,), math.inf, dtype=torch.float64).scatter_reduce(0, cell, dist, reduce="amin")
    index = torch.arange(k, dtype=torch.int64)
    candidate = torch.where(dist == best[cell], index, torch.full_like(index, k))
    return torch.full((m,), k, dtype=torch.int64).scatter_reduce(0, cell, candidate, reduce="amin")


def _nearest(points: torch.Tensor, sites: torch.Tensor, chunk: int = 4096) -> torch.Tensor:
    """Index (n,) of the nearest site for each point, in chunks of ``chunk`` points (memory chunk x m)."""
    return torch.cat([torch.cdist(points[i : i + chunk], sites).argmin(dim=1) for i in range(0, points.shape[0], chunk)])


def morton_codes(points: torch.Tensor, lo: torch.Tensor, longest: float) -> torch.Tensor:
    """Z-order codes (n,) int64 of points quantised to 2^20 cells per axis over a cube of side ``longest``."""
    cells = (1 << _MORTON_BITS) - 1
    q = torch.clamp(((points - lo) / longest * cells).round(), 0, cells).to(torch.int64)
    code = torch.zeros(points.shape[0], dtype=torch.int64)
    for bit in range(_MORTON_BITS):  # loop over bits, vectorised over points
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return code


def _check_points(points: torch.Tensor) -> torch.Tensor:
    if not isinstance(points, torch.Tensor) or points.ndim != 2 or points.shape[1] != 3 or points.shape[0] < 1:
        shape = tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__
        raise ValueError(f"points_rest must be a tensor of shape (n, 3) with n >= 1; got {shape}")
    if not bool(torch.isfinite(points).all()):
        raise ValueError("points_rest contains non-finite values; allowed: finite coordinates in m")
    x = points.detach().to(device="cpu", dtype=torch.float64)
    if not float((x.max(dim=0).values - x.min(dim=0).values).max()) > 0.0 and x.shape[0] > 1:
        raise ValueError("points_rest are all identical; allowed: a point cloud with positive extent")
    return x
