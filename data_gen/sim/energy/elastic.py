"""Stable neo-Hookean elastic energy integrated at the cubature points, batched over objects.

``F_i = I + Tm C_i`` (n, P, 3, 3); energy ``sum_i V_i Psi(F_i)``; gradient ``sum_i V_i P_i C_i^T``; Hessian
``K[r a, s b] = sum_i V_i H_i[(r j), (s k)] C_i[a j] C_i[b k]`` with the per-point 9x9 blocks ``H_i`` made
near positive semi-definite as in :meth:`data_gen.sim.reduced.ReducedObject.elastic_hessian` (blocks
failing a Cholesky test at ``-NEAR_SPD_TOLERANCE mu`` are eigen-clamped; ``strict`` objects clamp every
block). Padded points have zero volume and contribute nothing.
"""

from __future__ import annotations

import torch

from data_gen.sim import material as mat
from data_gen.sim.energy.terms import ObjectTerms
from data_gen.sim.reduced import neo_hookean_hessian

_EYE3 = torch.eye(3, dtype=torch.float64)
_EYE9 = torch.eye(9, dtype=torch.float64)


def deformation_gradients(cub_c: torch.Tensor, tm: torch.Tensor) -> torch.Tensor:
    """(n, P, 3, 3) from bases (n, P, K, 3) and states (n, 3, K)."""
    return _EYE3 + tm[:, None] @ cub_c


def elastic(
    cub_c: torch.Tensor,
    volume_m3: torch.Tensor,
    mu_pa: torch.Tensor,
    lam_pa: torch.Tensor,
    spd_tolerance_pa: torch.Tensor,
    tm: torch.Tensor,
    derivatives: bool,
    strict: torch.Tensor | None = None,
) -> ObjectTerms:
    """Elastic terms of n objects: bases (n, P, K, 3), volumes (n, P) m^3, Lamé (n,) Pa, states (n, 3, K);
    ``strict`` (n,) bool projects every block of those objects."""
    n, p, k, _ = cub_c.shape
    F = deformation_gradients(cub_c, tm).reshape(n * p, 3, 3)
    mu = mu_pa[:, None].expand(n, p).reshape(-1)
    lam = lam_pa[:, None].expand(n, p).reshape(-1)
    vol = volume_m3.reshape(-1)
    energy = (vol * mat.energy_density(F, mu, lam)).reshape(n, p).sum(1)
    if not derivatives:
        return ObjectTerms(energy)
    piola = (mat.first_piola(F, mu, lam) * vol[:, None, None]).reshape(n, p, 3, 3)
    h = _project(neo_hookean_hessian_batched(F, mu, lam), spd_tolerance_pa, strict, n, p)
    return ObjectTerms(energy, *_reduce(cub_c, piola, (h * vol[:, None, None]).reshape(n, p, 9, 9)))


def elastic_from_points(
    cub_c: torch.Tensor, energy_j: torch.Tensor, piola: torch.Tensor, hess: torch.Tensor | None
) -> ObjectTerms:
    """Elastic terms from per-point quantities (:class:`data_gen.sim.energy.elastic_kernel.WarpNeoHookean`):
    energies (n, P) J, volume-weighted Piola stresses (n, P, 3, 3) and 9 x 9 Hessians (n, P, 9, 9), the
    blocks failing the near-SPD test (and every block of ``strict`` objects) already projected by the kernel
    as :func:`elastic` eigen-clamps them."""
    energy = energy_j.sum(1)
    if hess is None:
        return ObjectTerms(energy)
    return ObjectTerms(energy, *_reduce(cub_c, piola, hess))


def elastic_gradient(cub_c: torch.Tensor, piola: torch.Tensor) -> torch.Tensor:
    """Gradient (n, 3, K) from volume-weighted Piola stresses (n, P, 3, 3) with bases (n, P, K, 3):
    ``grad[r, a] = sum_i sum_j P_i[r, j] C_i[a, j]``."""
    return torch.einsum("nprj,npaj->nra", piola, cub_c)


def _reduce(cub_c: torch.Tensor, piola: torch.Tensor, h: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Gradient (n, 3, K) and Hessian (n, 3K, 3K) from volume-weighted Piola stresses (n, P, 3, 3) and
    point Hessians (n, P, 9, 9) with bases (n, P, K, 3)."""
    return elastic_gradient(cub_c, piola), elastic_hessian(cub_c, h)


def elastic_hessian(cub_c: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """Hessian (n, 3K, 3K) from volume-weighted point Hessians (n, P, 9, 9) with bases (n, P, K, 3)."""
    n, p, k, _ = cub_c.shape
    # K[r, a, s, b] = sum_i sum_j C_i[a, j] (sum_k H_i[(r, j), (s, k)] C_i[b, k]): the small per-point H is
    # reordered to (j, r, s, k) so that the inner product comes out as [(i j), (r s b)] without a copy
    h_jrs = h.reshape(n, p, 3, 3, 3, 3).transpose(2, 3).reshape(n * p, 27, 3)
    inner = (h_jrs @ cub_c.reshape(n * p, k, 3).transpose(1, 2)).reshape(n, p * 3, 9 * k)
    left = cub_c.permute(0, 2, 1, 3).reshape(n, k, p * 3)  # [a, (i j)]
    return (left @ inner).reshape(n, k, 3, 3, k).transpose(1, 2).reshape(n, 3 * k, 3 * k)


def neo_hookean_hessian_batched(F: torch.Tensor, mu: torch.Tensor, lam: torch.Tensor) -> torch.Tensor:
    """:func:`data_gen.sim.reduced.neo_hookean_hessian` with per-point Lamé parameters (m,) Pa."""
    m = F.shape[0]
    lam_s = lam + mu
    g = mat.cofactor(F).reshape(m, 9)
    coef = lam_s * (torch.linalg.det(F) - 1.0) - mu
    d2j = mat.determinant_hessian(F)
    h = lam_s[:, None, None] * g[:, :, None] * g[:, None, :] + coef[:, None, None] * d2j
    return h + mu[:, None, None] * _EYE9


def _project(h: torch.Tensor, tolerance_pa: torch.Tensor, strict: torch.Tensor | None, n: int, p: int) -> torch.Tensor:
    h = 0.5 * (h + h.transpose(1, 2))
    tol = tolerance_pa[:, None].expand(n, p).reshape(-1)
    bad = torch.linalg.cholesky_ex(h + tol[:, None, None] * _EYE9).info != 0
    if strict is not None:
        bad = bad | strict[:, None].expand(n, p).reshape(-1)
    if bool(bad.any()):
        evals, evecs = torch.linalg.eigh(h[bad])
        h = h.clone()
        h[bad] = (evecs * evals.clamp(min=0.0)[:, None, :]) @ evecs.transpose(1, 2)
    return h


__all__ = ["elastic", "elastic_from_points", "elastic_gradient", "elastic_hessian", "deformation_gradients", "neo_hookean_hessian", "neo_hookean_hessian_batched"]
