"""Object-object penalty contact and lagged friction between sphere pairs, batched over every pair.

A pair (i on a solved object, j on a solved or a frozen (sleeping) object) penetrates by
``d = r_i + r_j - |x_i - x_j|``; energy ``k/2 d^2`` with ``k`` the pair's stiffness (N/m), gradient
``dE/dx_i = -k d n = -dE/dx_j`` (``n`` from j to i), Gauss-Newton blocks ``H = k n n^T`` with
``d2E/dx_i dx_j = -H``. Friction acts on the relative slip ``(x_i - x_i0) - (x_j - x_j0)`` with the normal
force and normal frozen at the start of the (sub)step.

Reduced blocks are summed per object pair without a Python loop: pairs are grouped by object pair into a
padded (groups, pairs per group) layout and reduced with batched products.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from data_gen.sim.energy import point_terms
from data_gen.sim.energy.terms import PairTerms, point_gradient, point_hessian

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
    """

    obj_i: torch.Tensor
    sph_i: torch.Tensor
    obj_j: torch.Tensor
    sph_j: torch.Tensor
    frozen_x_j: torch.Tensor
    stiffness_n_m: torch.Tensor
    radius_sum_m: torch.Tensor
    friction: torch.Tensor
    normal_force_n: torch.Tensor
    normal0: torch.Tensor
    x0_i: torch.Tensor
    x0_j: torch.Tensor

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
    pairs: PairSet, x_m: torch.Tensor, b: torch.Tensor, smoothing_m: float, derivatives: bool
) -> PairTerms:
    """Terms of every pair; ``x_m`` (n, S, 3) sphere positions and ``b`` (n, S, K) bases of the solved
    objects."""
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
    active = h.abs().sum(dim=(1, 2)) > 0
    oi, oj = pairs.obj_i[active], pairs.obj_j[active]
    si, sj = pairs.sph_i[active], pairs.sph_j[active]
    ga, ha = g[active], h[active]
    bi = b[oi, si]
    solved_j = oj >= 0
    bj = torch.where(solved_j[:, None], b[oj.clamp(min=0), sj], torch.zeros((), dtype=b.dtype))
    # gradient: +g on side i, -g on a solved side j
    grad_pts = torch.zeros(n, 3, k, dtype=x_m.dtype)
    grad_pts.index_add_(0, oi, ga[:, :, None] * bi[:, None, :])
    grad_pts.index_add_(0, oj[solved_j], -(ga[solved_j][:, :, None] * bj[solved_j][:, None, :]))
    # Hessian, grouped by object pair (slot j = n stands for a frozen partner)
    key = oi * (n + 1) + torch.where(solved_j, oj, torch.full_like(oj, n))
    groups, slot = torch.unique(key, return_inverse=True)
    g_i, g_j = groups // (n + 1), groups % (n + 1)
    hp, bip, bjp = _pad_by_group(slot, len(groups), ha, bi, bj)
    diag_i = point_hessian(bip, hp)
    diag_j = point_hessian(bjp, hp)
    cross = -point_hessian(bip, hp, bjp)
    hess = torch.zeros(n, 3 * k, 3 * k, dtype=x_m.dtype)
    hess.index_add_(0, g_i, diag_i)
    pair_groups = g_j < n
    hess.index_add_(0, g_j[pair_groups], diag_j[pair_groups])
    cross_rows = torch.cat([g_i[pair_groups], g_j[pair_groups]])
    cross_cols = torch.cat([g_j[pair_groups], g_i[pair_groups]])
    cross_blocks = torch.cat([cross[pair_groups], cross[pair_groups].transpose(1, 2)])
    return PairTerms(energy, grad_pts, hess, cross_blocks, cross_rows, cross_cols, -g)


def _pad_by_group(slot: torch.Tensor, num_groups: int, *values: torch.Tensor) -> list[torch.Tensor]:
    """Scatter rows of ``values`` into zero-padded (groups, max rows per group, ...) tensors."""
    order = torch.argsort(slot, stable=True)
    sorted_slot = slot[order]
    counts = torch.bincount(sorted_slot, minlength=num_groups)
    starts = torch.cumsum(counts, 0) - counts
    rank = torch.arange(slot.shape[0]) - starts[sorted_slot]
    width = int(counts.max()) if num_groups else 0
    out = []
    for v in values:
        padded = torch.zeros((num_groups, width, *v.shape[1:]), dtype=v.dtype)
        padded[sorted_slot, rank] = v[order]
        out.append(padded)
    return out
