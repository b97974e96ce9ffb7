"""Contact between cubature spheres and the static scene, and between objects.

* Static scene: sphere i (centre x_i, radius r_i) penetrates by ``d_i = r_i - sdf(x_i)``; the penalty
  energy is ``k/2 d_i^2`` for ``d_i > 0`` (C1, Gauss-Newton Hessian ``k n n^T``).
* Object-object: candidate pairs come from a ``wp.HashGrid`` over all cubature points, rebuilt every
  step; same-object pairs are skipped; pair (i, j) penetrates by ``d = r_i + r_j - |x_i - x_j|`` with
  energy ``k/2 d^2`` (Hessian ``k n n^T``, the negative curvature term dropped so it stays PSD).
* Friction: lagged, smoothed Coulomb.  The normal force ``lam`` and the tangent plane are frozen at the
  start of the step; with tangential slip ``u`` (m) over the step the energy is ``mu lam f(|u|)``,
  ``f(s) = s^2 / (2 eps)`` for ``s < eps`` and ``s - eps/2`` beyond, ``eps = v_eps dt`` (m).

The stiffness ``k`` (N/m) is chosen by the caller as ``factor * mass / dt^2`` so that the penetration
under load does not depend on the material stiffness (a stiff object cannot push through the floor).
All functions are batched over points/pairs (torch float64); energies in J, forces in N. The per-point
formulas live in :mod:`data_gen.sim.energy.point_terms` (shared with the solver's energy terms); these
wrappers return totals.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import warp as wp

from data_gen.sim.energy import point_terms
from data_gen.sim.static_scene import StaticScene


@dataclass
class PointContact:
    """Per-point penalty terms: energy (J), dE/dx (n,3) N, Gauss-Newton d2E/dx2 (n,3,3) N/m."""

    energy: float
    grad_x: torch.Tensor
    hess_x: torch.Tensor


def static_contact(
    x_m: torch.Tensor, radius_m: torch.Tensor, stiffness_n_m: torch.Tensor, scene: StaticScene
) -> tuple[PointContact, torch.Tensor, torch.Tensor]:
    """Penalty contact of spheres with the static scene.

    Returns the per-point terms, the penetration depth (n,) m (``> 0`` in contact) and the outward
    scene normals (n,3).
    """
    sdf, normal = scene.query(x_m)
    return penalty_from_sdf(torch.from_numpy(sdf), torch.from_numpy(normal), radius_m, stiffness_n_m)


def penalty_from_sdf(
    sdf_m: torch.Tensor, n_t: torch.Tensor, radius_m: torch.Tensor, stiffness_n_m: torch.Tensor
) -> tuple[PointContact, torch.Tensor, torch.Tensor]:
    """:func:`static_contact` from already queried signed distances (n,) and normals (n,3)."""
    depth = radius_m - sdf_m
    energy, grad, hess = point_terms.penalty(depth, n_t, stiffness_n_m, True)
    return PointContact(float(energy.sum()), grad, hess), depth, n_t


def friction_terms(
    slip_m: torch.Tensor,
    normal_force_n: torch.Tensor,
    tangent_normals: torch.Tensor,
    friction_coefficient: torch.Tensor,
    smoothing_m: float,
) -> PointContact:
    """Lagged smoothed Coulomb friction on a slip (n,3) with frozen normal forces (n,) and normals (n,3)."""
    energy, grad, hess = point_terms.friction(
        slip_m, normal_force_n, tangent_normals, friction_coefficient, smoothing_m, True
    )
    return PointContact(float(energy.sum()), grad, hess)


@wp.kernel
def _candidate_pairs_kernel(
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3d),
    object_ids: wp.array(dtype=wp.int32),
    radii: wp.array(dtype=wp.float64),
    point_margins: wp.array(dtype=wp.float64),
    query_radius: wp.float64,
    margin: wp.float64,
    capacity: int,
    count: wp.array(dtype=wp.int32),
    pairs: wp.array(dtype=wp.int32, ndim=2),
):
    i = wp.tid()
    p = points[i]
    query = wp.hash_grid_query(grid, p, query_radius)
    j = int(0)
    while wp.hash_grid_query_next(query, j):
        if j > i and object_ids[j] != object_ids[i]:
            if wp.length(points[j] - p) < radii[i] + radii[j] + margin + point_margins[i] + point_margins[j]:
                slot = wp.atomic_add(count, 0, 1)
                if slot < capacity:
                    pairs[slot, 0] = i
                    pairs[slot, 1] = j


class PairFinder:
    """Broad phase over all cubature spheres with a warp hash grid (rebuilt on every call)."""

    def __init__(self, device: str = "cpu", grid_dim: int = 64) -> None:
        self.device = device
        wp.init()
        self.grid = wp.HashGrid(grid_dim, grid_dim, grid_dim, device=device, dtype=wp.float64)
        self.capacity = 1024

    def find(
        self,
        points_m: np.ndarray,
        object_ids: np.ndarray,
        radii_m: np.ndarray,
        margin_m: float,
        point_margins_m: np.ndarray | None = None,
    ) -> np.ndarray:
        """Pairs (P,2) of global point indices i < j on different objects with gap < margin_m (+ the two
        points' own ``point_margins_m`` (n,) m, e.g. how far each can move in a step).

        The result is sorted lexicographically, so it is deterministic on every device.
        """
        n = points_m.shape[0]
        if n == 0 or len(np.unique(object_ids)) < 2:
            return np.zeros((0, 2), dtype=np.int64)
        extra = np.zeros(n) if point_margins_m is None else np.asarray(point_margins_m, dtype=np.float64)
        query_radius = 2.0 * float(radii_m.max()) + margin_m + 2.0 * float(extra.max())
        pts = wp.array(np.ascontiguousarray(points_m, dtype=np.float64), dtype=wp.vec3d, device=self.device)
        self.grid.build(pts, query_radius)
        ids = wp.array(object_ids.astype(np.int32), dtype=wp.int32, device=self.device)
        rad = wp.array(radii_m.astype(np.float64), dtype=wp.float64, device=self.device)
        pm = wp.array(extra, dtype=wp.float64, device=self.device)
        while True:
            count = wp.zeros(1, dtype=wp.int32, device=self.device)
            pairs = wp.zeros((self.capacity, 2), dtype=wp.int32, device=self.device)
            wp.launch(
                _candidate_pairs_kernel,
                dim=n,
                inputs=[
                    self.grid.id,
                    pts,
                    ids,
                    rad,
                    pm,
                    wp.float64(query_radius),
                    wp.float64(margin_m),
                    self.capacity,
                ],
                outputs=[count, pairs],
                device=self.device,
            )
            found = int(count.numpy()[0])
            if found <= self.capacity:
                break
            self.capacity = int(2 ** np.ceil(np.log2(found)))
        out = pairs.numpy()[:found].astype(np.int64)
        order = np.lexsort((out[:, 1], out[:, 0]))
        return out[order]


@dataclass
class PairContact:
    """Pair penalty terms: energy (J), dE/dx_i (P,3) (dE/dx_j = -grad), Hessian block (P,3,3) N/m."""

    energy: float
    grad_i: torch.Tensor
    hess: torch.Tensor
    depth_m: torch.Tensor
    normal_ji: torch.Tensor  # unit vector from j to i


def pair_contact(
    x_i: torch.Tensor, x_j: torch.Tensor, radius_sum_m: torch.Tensor, stiffness_n_m: torch.Tensor
) -> PairContact:
    """Penalty between sphere pairs; ``d2E/dx_i dx_i = hess``, ``d2E/dx_i dx_j = -hess``."""
    delta = x_i - x_j
    dist = delta.norm(dim=1).clamp(min=1e-12)
    n = delta / dist[:, None]
    depth = radius_sum_m - dist
    energy, grad_i, hess = point_terms.penalty(depth, n, stiffness_n_m, True)
    return PairContact(float(energy.sum()), grad_i, hess, depth, n)
