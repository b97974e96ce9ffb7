"""Penalty contact of the objects' spheres with the static scene, plus lagged Coulomb friction there.

Per sphere: penetration ``d = r - sdf(x)``, energy ``k/2 d^2`` for ``d > 0`` with ``k = factor m_o / h^2``
(N/m, the object's stiffness), Gauss-Newton Hessian ``k n n^T``; friction (:mod:`.point_terms`) with the
normal force and tangent plane frozen at the start of the (sub)step. One SDF query covers every sphere of
every object.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from data_gen.sim.energy import point_terms
from data_gen.sim.energy.scene_sdf import SceneDistance
from data_gen.sim.energy.terms import ObjectTerms, point_gradient, point_hessian


@dataclass(frozen=True)
class SceneContactStart:
    """What a (sub)step freezes at its start: sphere positions (n, S, 3) m, normal forces (n, S) N (0 where
    not in contact or masked) and scene normals (n, S, 3)."""

    positions_m: torch.Tensor
    normal_force_n: torch.Tensor
    normals: torch.Tensor


@dataclass
class SceneContactResult:
    terms: ObjectTerms
    force_n: torch.Tensor
    """(n, S, 3) contact + friction force on every sphere, N."""
    normals: torch.Tensor
    """(n, S, 3) scene normals at the spheres."""


def query(scene: SceneDistance, x_m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Signed distance (n, S) m and outward normals (n, S, 3) of sphere centres (n, S, 3)."""
    n, s, _ = x_m.shape
    d, normal = scene(x_m.reshape(-1, 3))
    return d.reshape(n, s), normal.reshape(n, s, 3)


def contact_start(
    scene: SceneDistance, x_m: torch.Tensor, radius_m: torch.Tensor, valid: torch.Tensor, stiffness_n_m: torch.Tensor
) -> SceneContactStart:
    """Frozen friction data of spheres (n, S, 3) with radii (n, S), mask (n, S), stiffness (n,) N/m."""
    sdf, normal = query(scene, x_m)
    depth = (radius_m - sdf).clamp(min=0.0) * valid
    return SceneContactStart(x_m, stiffness_n_m[:, None] * depth, normal)


def scene_contact(
    scene: SceneDistance,
    x_m: torch.Tensor,
    b: torch.Tensor,
    radius_m: torch.Tensor,
    valid: torch.Tensor,
    stiffness_n_m: torch.Tensor,
    friction: torch.Tensor,
    start: SceneContactStart,
    smoothing_m: float,
    derivatives: bool,
) -> SceneContactResult:
    """Contact and friction terms of spheres at ``x_m`` (n, S, 3) moved by bases ``b`` (n, S, K).

    ``stiffness_n_m`` is per object (n,) (masked here by ``valid``) or per sphere (n, S) (already masked);
    ``friction`` per object (n,) or per sphere (n, S)."""
    n, s, _ = x_m.shape
    sdf, normal = query(scene, x_m)
    k = (stiffness_n_m[:, None] * valid).reshape(-1) if stiffness_n_m.ndim == 1 else stiffness_n_m.reshape(-1)
    e_c, g_c, h_c = point_terms.penalty((radius_m - sdf).reshape(-1), normal.reshape(-1, 3), k, derivatives)
    e_f, g_f, h_f = point_terms.friction(
        (x_m - start.positions_m).reshape(-1, 3),
        start.normal_force_n.reshape(-1),
        start.normals.reshape(-1, 3),
        friction[:, None].expand(n, s).reshape(-1) if friction.ndim == 1 else friction.reshape(-1),
        smoothing_m,
        derivatives,
    )
    energy = (e_c + e_f).reshape(n, s).sum(1)
    grad_x = (g_c + g_f).reshape(n, s, 3)
    if not derivatives:
        return SceneContactResult(ObjectTerms(energy), -grad_x, normal)
    hess_x = (h_c + h_f).reshape(n, s, 3, 3)
    terms = ObjectTerms(energy, point_gradient(b, grad_x), point_hessian(b, hess_x))
    return SceneContactResult(terms, -grad_x, normal)
