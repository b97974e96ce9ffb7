"""Elastic material: parameters and the stable neo-Hookean constitutive model.

Energy density (Smith et al. 2018, "Stable Neo-Hookean Flesh Simulation", in
the Lamé-reparameterised form used by Simplicits):

    Psi(F) = mu/2 (I1 - 3) + lam'/2 (J - 1)^2 - mu (J - 1),   lam' = lam + mu,

with I1 = tr(F^T F) and J = det F. Psi is in J/m^3, PK1 stress in Pa. The
extra ``- mu (J - 1)`` makes the rest state stress free and ``lam' = lam + mu``
makes the small-strain limit exactly Hooke's law with Lamé parameters
(mu, lam):  P ~ 2 mu eps + lam tr(eps) I.

All functions are batched over points: ``F`` has shape (n, 3, 3); ``mu`` and
``lam`` are Python floats, 0-dim tensors or per-point tensors of shape (n,).
Use float64 (the reduced solver does); the functions compute in ``F.dtype``.

Flattening convention for the Hessian: vec(F) is **row-major**,
``vec(F)[3 * i + j] = F[i, j]`` (the same order as ``F.reshape(n, 9)``), so
``hessian(F)[p, 3*i + j, 3*k + l] = d^2 Psi / dF_ij dF_kl`` at point p.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

# Levi-Civita symbol eps_{abc}; float64, cast to the input dtype when used.
_LEVI_CIVITA = torch.zeros(3, 3, 3, dtype=torch.float64)
for _a, _b, _c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI_CIVITA[_a, _b, _c] = 1.0
    _LEVI_CIVITA[_a, _c, _b] = -1.0

# d^2 J / dF^2 is linear in F: vec81(d2J) = _DET_HESSIAN_MAP @ vec9(F), both row-major.
_DET_HESSIAN_MAP = torch.einsum("ikm,jln->ijklmn", _LEVI_CIVITA, _LEVI_CIVITA).reshape(81, 9)


@dataclass(frozen=True)
class Material:
    """A homogeneous isotropic elastic material.

    Attributes:
        young_modulus_pa: Young's modulus E in Pa, must be > 0.
        poisson_ratio: Poisson's ratio nu, dimensionless, in [0, 0.5).
        density_kg_m3: mass density rho in kg/m^3, must be > 0.
    """

    young_modulus_pa: float
    poisson_ratio: float
    density_kg_m3: float

    def __post_init__(self) -> None:
        _check_young_modulus(self.young_modulus_pa)
        _check_poisson_ratio(self.poisson_ratio)
        if not (self.density_kg_m3 > 0.0) or self.density_kg_m3 == float("inf"):
            raise ValueError(f"density_kg_m3={self.density_kg_m3!r} is out of range; allowed: 0 < rho < inf (kg/m^3)")

    @property
    def lame_pa(self) -> tuple[float, float]:
        """Lamé parameters (mu, lam) in Pa."""
        return lame_parameters(self.young_modulus_pa, self.poisson_ratio)

    @property
    def shear_modulus_pa(self) -> float:
        """Shear modulus mu = E / (2 (1 + nu)) in Pa."""
        return self.lame_pa[0]

    @property
    def bulk_modulus_pa(self) -> float:
        """Bulk modulus K = E / (3 (1 - 2 nu)) in Pa."""
        return self.young_modulus_pa / (3.0 * (1.0 - 2.0 * self.poisson_ratio))


def _check_young_modulus(young_modulus_pa: float) -> None:
    if not (young_modulus_pa > 0.0) or young_modulus_pa == float("inf"):
        raise ValueError(f"young_modulus_pa={young_modulus_pa!r} is out of range; allowed: 0 < E < inf (Pa)")


def _check_poisson_ratio(poisson_ratio: float) -> None:
    if not (0.0 <= poisson_ratio < 0.5):
        raise ValueError(f"poisson_ratio={poisson_ratio!r} is out of range; allowed: 0 <= nu < 0.5")


def lame_parameters(young_modulus_pa: float, poisson_ratio: float) -> tuple[float, float]:
    """Lamé parameters from Young's modulus (Pa) and Poisson's ratio.

    Returns:
        (mu, lam) in Pa: mu = E / (2 (1 + nu)), lam = E nu / ((1 + nu)(1 - 2 nu)).
    """
    _check_young_modulus(young_modulus_pa)
    _check_poisson_ratio(poisson_ratio)
    e, nu = float(young_modulus_pa), float(poisson_ratio)
    return e / (2.0 * (1.0 + nu)), e * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))


# --------------------------------------------------------------------------- helpers


def _check_deformation_gradient(F: torch.Tensor) -> int:
    if F.ndim != 3 or F.shape[1:] != (3, 3):
        raise ValueError(f"F must have shape (n, 3, 3); got {tuple(F.shape)}")
    if not F.is_floating_point():
        raise ValueError(f"F must be a floating-point tensor (float64 recommended); got dtype {F.dtype}")
    return F.shape[0]


def _per_point(value: float | torch.Tensor, n: int, like: torch.Tensor, name: str) -> torch.Tensor:
    """Broadcast a scalar or (n,) Lamé parameter to a (n,) tensor in F's dtype/device."""
    t = torch.as_tensor(value, dtype=like.dtype, device=like.device)
    if t.ndim == 0:
        return t.expand(n)
    if t.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},); got shape {tuple(t.shape)}")
    return t


def cofactor(F: torch.Tensor) -> torch.Tensor:
    """dJ/dF = cof(F) = J F^{-T}, computed without inversion, shape (n, 3, 3).

    Column j of cof(F) is the cross product of the other two columns of F.
    """
    c0, c1, c2 = F[:, :, 0], F[:, :, 1], F[:, :, 2]
    return torch.stack(
        (torch.linalg.cross(c1, c2, dim=-1), torch.linalg.cross(c2, c0, dim=-1), torch.linalg.cross(c0, c1, dim=-1)),
        dim=-1,
    )


def _lame_tensors(F: torch.Tensor, mu: float | torch.Tensor, lam: float | torch.Tensor):
    n = _check_deformation_gradient(F)
    mu_t = _per_point(mu, n, F, "mu")
    lam_t = _per_point(lam, n, F, "lam")
    return mu_t, lam_t + mu_t


# --------------------------------------------------------------------------- model


def energy_density(F: torch.Tensor, mu: float | torch.Tensor, lam: float | torch.Tensor) -> torch.Tensor:
    """Stable neo-Hookean energy density Psi(F), J/m^3, shape (n,)."""
    mu_t, lam_s = _lame_tensors(F, mu, lam)
    i1 = (F * F).sum(dim=(1, 2))
    jm1 = torch.linalg.det(F) - 1.0
    return 0.5 * mu_t * (i1 - 3.0) + 0.5 * lam_s * jm1 * jm1 - mu_t * jm1


def first_piola(F: torch.Tensor, mu: float | torch.Tensor, lam: float | torch.Tensor) -> torch.Tensor:
    """First Piola-Kirchhoff stress P = dPsi/dF, Pa, shape (n, 3, 3).

    P = mu F + (lam' (J - 1) - mu) cof(F).
    """
    mu_t, lam_s = _lame_tensors(F, mu, lam)
    jm1 = torch.linalg.det(F) - 1.0
    coef = lam_s * jm1 - mu_t
    return mu_t[:, None, None] * F + coef[:, None, None] * cofactor(F)


def determinant_hessian(F: torch.Tensor) -> torch.Tensor:
    """d^2 J / dF^2 in row-major vec(F) ordering, shape (n, 9, 9).

    d^2 J / dF_ij dF_kl = eps_ikm eps_jln F_mn.
    """
    linear_map = _DET_HESSIAN_MAP.to(dtype=F.dtype, device=F.device)
    return (F.reshape(F.shape[0], 9) @ linear_map.T).reshape(F.shape[0], 9, 9)


def hessian(
    F: torch.Tensor,
    mu: float | torch.Tensor,
    lam: float | torch.Tensor,
    project_spd: bool = True,
    min_eigenvalue: float = 0.0,
) -> torch.Tensor:
    """Analytic Hessian d^2 Psi / dF^2, Pa, shape (n, 9, 9), row-major vec(F).

    H = mu I9 + lam' g g^T + (lam' (J - 1) - mu) d^2J/dF^2,  g = vec(cof F).

    Args:
        F: deformation gradients (n, 3, 3).
        mu, lam: Lamé parameters in Pa, scalars or (n,).
        project_spd: if True, clamp the eigenvalues of each 9x9 block at
            ``min_eigenvalue * mu`` (a symmetric eigendecomposition per point), so
            the result is positive semidefinite and Newton descends.
        min_eigenvalue: floor of the projected eigenvalues, as a fraction of
            mu (dimensionless, >= 0).
    """
    if min_eigenvalue < 0.0:
        raise ValueError(f"min_eigenvalue={min_eigenvalue!r} is out of range; allowed: >= 0")
    mu_t, lam_s = _lame_tensors(F, mu, lam)
    n = F.shape[0]
    g = cofactor(F).reshape(n, 9)
    jm1 = torch.linalg.det(F) - 1.0
    coef = lam_s * jm1 - mu_t
    eye = torch.eye(9, dtype=F.dtype, device=F.device)
    h = (
        mu_t[:, None, None] * eye
        + lam_s[:, None, None] * g[:, :, None] * g[:, None, :]
        + coef[:, None, None] * determinant_hessian(F)
    )
    if not project_spd:
        return h
    h = 0.5 * (h + h.transpose(1, 2))
    evals, evecs = torch.linalg.eigh(h)
    floor = (min_eigenvalue * mu_t)[:, None]
    evals = torch.maximum(evals, floor)
    return (evecs * evals[:, None, :]) @ evecs.transpose(1, 2)


def cauchy_stress(F: torch.Tensor, mu: float | torch.Tensor, lam: float | torch.Tensor) -> torch.Tensor:
    """Cauchy (true) stress sigma = P F^T / J, Pa, shape (n, 3, 3)."""
    P = first_piola(F, mu, lam)
    det = torch.linalg.det(F)
    return (P @ F.transpose(1, 2)) / det[:, None, None]


def hydrostatic_stress(F: torch.Tensor, mu: float | torch.Tensor, lam: float | torch.Tensor) -> torch.Tensor:
    """Signed hydrostatic Cauchy stress tr(sigma) / 3, Pa, shape (n,); negative = compression.

    In closed form (one determinant, no 3 x 3 products): with ``sigma = P F^T / J`` and ``cof(F) F^T = J I``,
    ``tr(sigma) / 3 = mu |F|^2 / (3 J) + lam' (J - 1) - mu``, ``|F|`` the Frobenius norm."""
    mu_t, lam_s = _lame_tensors(F, mu, lam)
    det = torch.linalg.det(F)
    return mu_t * (F * F).sum(dim=(1, 2)) / (3.0 * det) + lam_s * (det - 1.0) - mu_t
