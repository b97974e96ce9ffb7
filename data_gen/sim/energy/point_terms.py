"""Per-point penalty and friction terms (energy per point, so callers can sum per object or island).

Same formulas as :mod:`data_gen.sim.contact` (which returns totals): penalty ``k/2 d^2`` for penetration
``d > 0`` with Gauss-Newton Hessian ``k n n^T``; lagged smoothed Coulomb friction ``mu lam f(|u_t|)`` with
``f(s) = s^2 / (2 eps)`` below ``eps`` and ``s - eps/2`` above. Its Newton matrix, with ``P = I - n n^T``,
``u`` the tangential slip and ``t = u / |u|``: ``mu lam / eps P`` below ``eps`` (exact) and
``mu lam / s (P - (1 - eps / s) t t^T)`` above. Across the slip direction that is the exact Hessian; along it
the exact curvature is 0, and the matrix's ``mu lam eps / s^2`` goes from the stick value at ``s = eps`` (the
matrix is continuous there) to the exact 0 far into sliding. The old secant ``mu lam / s`` along ``t`` made
Newton's steps on sliding contacts converge only linearly (ratio about 0.8 per iteration on a soft pile);
the exact 0 lets a step overshoot from sliding into sticking (more line-search halvings). See
``README.md``, "The friction matrix".
"""

from __future__ import annotations

import torch

_EYE3 = torch.eye(3, dtype=torch.float64)


def penalty(
    depth_m: torch.Tensor, normal: torch.Tensor, stiffness_n_m: torch.Tensor, derivatives: bool
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Penetration depth (m,) m along ``normal`` (m,3) (the direction that reduces it), stiffness (m,) N/m.
    Returns energy (m,) J, dE/dx (m,3) N and the Hessian (m,3,3) N/m (None unless ``derivatives``)."""
    d = depth_m.clamp(min=0.0)
    k = torch.where(depth_m > 0, stiffness_n_m, torch.zeros((), dtype=depth_m.dtype))
    energy = 0.5 * k * d * d
    grad = -(k * d)[:, None] * normal
    hess = k[:, None, None] * normal[:, :, None] * normal[:, None, :] if derivatives else None
    return energy, grad, hess


def friction(
    slip_m: torch.Tensor,
    normal_force_n: torch.Tensor,
    normal: torch.Tensor,
    coefficient: torch.Tensor,
    smoothing_m: float,
    derivatives: bool,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Lagged friction of slips (m,3) m with frozen normal forces (m,) N and normals (m,3)."""
    u = slip_m - (slip_m * normal).sum(-1, keepdim=True) * normal
    s = u.norm(dim=-1)
    scale = coefficient * normal_force_n
    energy = scale * torch.where(s < smoothing_m, s * s / (2.0 * smoothing_m), s - 0.5 * smoothing_m)
    ratio = scale / s.clamp(min=smoothing_m)
    grad = ratio[:, None] * u
    hess = None
    if derivatives:
        hess = ratio[:, None, None] * (_EYE3 - normal[:, :, None] * normal[:, None, :])
        # sliding: along the slip the curvature falls from the stick value to the exact 0 (see the docstring)
        sliding = s >= smoothing_m
        along = torch.where(sliding, ratio * (1.0 - smoothing_m / s.clamp(min=smoothing_m)), 0.0)
        tangent = u / s.clamp(min=smoothing_m)[:, None]
        hess = hess - along[:, None, None] * tangent[:, :, None] * tangent[:, None, :]
    return energy, grad, hess
