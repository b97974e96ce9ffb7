"""Object-object penalty contact and lagged friction between sphere pairs, batched over every pair.

A pair (i on a solved object, j on a solved or a frozen (sleeping) object) penetrates by
``d = r_i + r_j - |x_i - x_j|``; energy ``k/2 d^2`` with ``k`` the pair's stiffness (N/m), gradient
``dE/dx_i = -k d n = -dE/dx_j`` (``n`` from j to i), Gauss-Newton blocks ``H = k n n^T`` with
``d2E/dx_i dx_j = -H``. Friction acts on the relative slip ``(x_i - x_i0) - (x_j - x_j0)`` with the normal
force and normal frozen at the start of the (sub)step.

Reduced blocks are summed per object pair without a Python loop: pairs are grouped by object pair into a
padded (groups, pairs per group) layout (:class:`PairGroups`, built once per solve) and reduced with batched
products.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from data_gen.sim.energy import point_terms
from data_gen.sim.energy.terms import PairTerms, point_hessian

FROZEN = -1  # object slot of a sleeping partner (not solved; its spheres do not move)


@dataclass(frozen=True)
class PairSet:
    """Candidate sphere pairs of one solve (tensors of length P).

    Attributes:
        obj_i, sph_i: solved-object slot and sphere index of side i.
        obj_j, sph_j: slot of side j (``FROZEN`` for a sleeping partner) and its sphere index.
        frozen_x_j: (P, 3) m positions of side j where it is frozen (ignored otherwise).
        stiffness_n_m, radius_sum_m, friction, normal_force_n: (P,) pair constants of the step.
        normal0: (P, 3) unit normal j -> i at the start of the step.
        x0_i, x0_j: (P, 3) m positions at the start of the step.

    ``friction``, ``normal_force_n``, ``normal0``, ``x0_i`` and ``x0_j`` (the start data) are None in a pair set
    for :meth:`data_gen.sim.fused_newton.FusedNewton.solve_substeps`, which computes them at the start of each
    sub-step in its launch; every other user needs them.
    """

    obj_i: torch.Tensor
    sph_i: torch.Tensor
    obj_j: torch.Tensor
    sph_j: torch.Tensor
    frozen_x_j: torch.Tensor
    stiffness_n_m: torch.Tensor
    radius_sum_m: torch.Tensor
    friction: torch.Tensor | None
    normal_force_n: torch.Tensor | None
    normal0: torch.Tensor | None
    x0_i: torch.Tensor | None
    x0_j: torch.Tensor | None

    @property
    def num_pairs(self) -> int:
        return int(self.obj_i.shape[0])

    def positions(self, x_m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Both sides' positions (P, 3) from the solved objects' sphere positions (n, S, 3)."""
        xi = x_m[self.obj_i, self.sph_i]
        xj_solved = x_m[self.obj_j.clamp(min=0), self.sph_j]
        xj = torch.where((self.obj_j >= 0)[:, None], xj_solved, self.frozen_x_j)
        return xi, xj


def pair_contact(
    pairs: PairSet, x_m: torch.Tensor, b: torch.Tensor, smoothing_m: float, derivatives: bool,
    pairs_groups: PairGroups | None = None,
) -> PairTerms:
    """Terms of every pair; ``x_m`` (n, S, 3) sphere positions and ``b`` (n, S, K) bases of the solved
    objects; ``pairs_groups`` is :meth:`PairGroups.build` of the same pairs (built here when omitted)."""
    n, _, k = b.shape
    xi, xj = pairs.positions(x_m)
    delta = xi - xj
    dist = delta.norm(dim=1).clamp(min=1e-12)
    normal = delta / dist[:, None]
    e_c, g_c, h_c = point_terms.penalty(pairs.radius_sum_m - dist, normal, pairs.stiffness_n_m, derivatives)
    slip = (xi - pairs.x0_i) - (xj - pairs.x0_j)
    e_f, g_f, h_f = point_terms.friction(
        slip, pairs.normal_force_n, pairs.normal0, pairs.friction, smoothing_m, derivatives
    )
    energy = torch.zeros(n, dtype=x_m.dtype).index_add_(0, pairs.obj_i, e_c + e_f)
    g = g_c + g_f
    if not derivatives:
        return PairTerms(energy, None, None, None, None, None, -g)
    h = h_c + h_f
    groups = pairs_groups if pairs_groups is not None else PairGroups.build(pairs, b)
    solved_j = pairs.obj_j >= 0
    # gradient: +g on side i, -g on a solved side j
    grad_pts = torch.zeros(n, 3, k, dtype=x_m.dtype)
    grad_pts.index_add_(0, pairs.obj_i, g[:, :, None] * groups.b_i[:, None, :])
    grad_pts.index_add_(0, pairs.obj_j[solved_j], -(g[solved_j][:, :, None] * groups.b_j[solved_j][:, None, :]))
    # Hessian blocks summed per object pair (inactive pairs have h = 0)
    hp = torch.zeros(groups.num_groups, groups.width, 3, 3, dtype=x_m.dtype)
    hp[groups.slot, groups.rank] = h
    diag_i = point_hessian(groups.b_i_padded, hp)
    hess = torch.zeros(n, 3 * k, 3 * k, dtype=x_m.dtype)
    hess.index_add_(0, groups.g_i, diag_i)
    pg = groups.pair_groups
    if not bool(pg.any()):
        empty = torch.zeros(0, 3 * k, 3 * k, dtype=x_m.dtype)
        none = torch.zeros(0, dtype=torch.int64)
        return PairTerms(energy, grad_pts, hess, empty, none, none, -g)
    hp_pairs, bi_pairs, bj_pairs = hp[pg], groups.b_i_padded[pg], groups.b_j_padded[pg]
    hess.index_add_(0, groups.g_j[pg], point_hessian(bj_pairs, hp_pairs))
    cross = -point_hessian(bi_pairs, hp_pairs, bj_pairs)
    cross_rows = torch.cat([groups.g_i[pg], groups.g_j[pg]])
    cross_cols = torch.cat([groups.g_j[pg], groups.g_i[pg]])
    return PairTerms(energy, grad_pts, hess, torch.cat([cross, cross.transpose(1, 2)]), cross_rows, cross_cols, -g)


@dataclass(frozen=True)
class PairGroups:
    """The pairs of a :class:`PairSet` grouped by object pair (fixed for a solve): per pair its group
    ``slot`` and ``rank`` in the group, the groups' objects ``g_i`` / ``g_j`` (``g_j = n`` for a frozen
    partner), and the sphere bases of both sides, per pair (P, K) and padded per group (G, W, K)."""

    slot: torch.Tensor
    rank: torch.Tensor
    g_i: torch.Tensor
    g_j: torch.Tensor
    pair_groups: torch.Tensor
    b_i: torch.Tensor
    b_j: torch.Tensor
    b_i_padded: torch.Tensor
    b_j_padded: torch.Tensor

    @property
    def num_groups(self) -> int:
        return int(self.g_i.shape[0])

    @property
    def width(self) -> int:
        return int(self.b_i_padded.shape[1])

    @staticmethod
    def build(pairs: PairSet, b: torch.Tensor) -> PairGroups:
        n = b.shape[0]
        solved_j = pairs.obj_j >= 0
        b_i = b[pairs.obj_i, pairs.sph_i]
        b_j = torch.where(solved_j[:, None], b[pairs.obj_j.clamp(min=0), pairs.sph_j], torch.zeros((), dtype=b.dtype))
        key = pairs.obj_i * (n + 1) + torch.where(solved_j, pairs.obj_j, torch.full_like(pairs.obj_j, n))
        groups, slot = torch.unique(key, return_inverse=True)
        counts = torch.bincount(slot, minlength=len(groups))
        order = torch.argsort(slot, stable=True)
        starts = torch.cumsum(counts, 0) - counts
        rank = torch.empty_like(slot)
        rank[order] = torch.arange(slot.shape[0]) - starts[slot[order]]
        width = int(counts.max()) if len(groups) else 0
        b_i_padded = torch.zeros(len(groups), width, b.shape[2], dtype=b.dtype)
        b_j_padded = torch.zeros_like(b_i_padded)
        b_i_padded[slot, rank] = b_i
        b_j_padded[slot, rank] = b_j
        g_j = groups % (n + 1)
        return PairGroups(slot, rank, groups // (n + 1), g_j, g_j < n, b_i, b_j, b_i_padded, b_j_padded)
