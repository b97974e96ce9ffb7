"""Stable neo-Hookean material: derivatives, invariances and analytic stresses."""

from __future__ import annotations

import pytest
import torch

from data_gen.sim.material import (
    Material,
    cauchy_stress,
    energy_density,
    first_piola,
    hessian,
    hydrostatic_stress,
    lame_parameters,
)

E_PA = 1.0e6


def _random_F(n: int, seed: int, scale: float = 0.3) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    F = torch.eye(3, dtype=torch.float64) + scale * torch.randn(n, 3, 3, generator=g, dtype=torch.float64)
    # keep det > 0 (the physically meaningful branch)
    flip = torch.linalg.det(F) < 0
    F[flip, :, 0] *= -1.0
    return F


def _random_rotations(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q, r = torch.linalg.qr(torch.randn(n, 3, 3, generator=g, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r, dim1=1, dim2=2))[:, None, :]
    q[torch.linalg.det(q) < 0, :, 0] *= -1.0
    return q


def test_lame_parameters_hand_values() -> None:
    mu, lam = lame_parameters(1.0e6, 0.25)
    assert mu == pytest.approx(4.0e5, rel=1e-15)  # 1e6 / 2.5
    assert lam == pytest.approx(4.0e5, rel=1e-15)  # 0.25e6 / (1.25 * 0.5)
    mat = Material(2.0e9, 0.0, 1000.0)
    assert mat.lame_pa == (1.0e9, 0.0)
    assert mat.bulk_modulus_pa == pytest.approx(2.0e9 / 3.0)


@pytest.mark.parametrize(
    "kwargs, name",
    [
        (dict(young_modulus_pa=0.0, poisson_ratio=0.3, density_kg_m3=1000.0), "young_modulus_pa"),
        (dict(young_modulus_pa=-1.0, poisson_ratio=0.3, density_kg_m3=1000.0), "young_modulus_pa"),
        (dict(young_modulus_pa=1e6, poisson_ratio=0.5, density_kg_m3=1000.0), "poisson_ratio"),
        (dict(young_modulus_pa=1e6, poisson_ratio=-0.1, density_kg_m3=1000.0), "poisson_ratio"),
        (dict(young_modulus_pa=1e6, poisson_ratio=0.3, density_kg_m3=0.0), "density_kg_m3"),
        (dict(young_modulus_pa=1e6, poisson_ratio=float("nan"), density_kg_m3=1.0), "poisson_ratio"),
    ],
)
def test_material_validation_names_parameter(kwargs: dict, name: str) -> None:
    with pytest.raises(ValueError, match=name) as info:
        Material(**kwargs)
    assert "allowed" in str(info.value)


def test_bad_shapes_are_rejected() -> None:
    with pytest.raises(ValueError, match=r"shape \(n, 3, 3\)"):
        energy_density(torch.eye(3, dtype=torch.float64), 1.0, 1.0)
    with pytest.raises(ValueError, match="mu"):
        energy_density(_random_F(4, 0), torch.ones(5, dtype=torch.float64), 1.0)


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.45])
def test_first_piola_matches_finite_differences_of_energy(nu: float) -> None:
    mu, lam = lame_parameters(E_PA, nu)
    F = _random_F(16, seed=1)
    P = first_piola(F, mu, lam)
    h = 1e-6
    fd = torch.zeros_like(F)
    for i in range(3):
        for j in range(3):
            d = torch.zeros(3, 3, dtype=torch.float64)
            d[i, j] = h
            fd[:, i, j] = (energy_density(F + d, mu, lam) - energy_density(F - d, mu, lam)) / (2 * h)
    rel = (P - fd).norm() / P.norm()
    assert rel < 1e-6


def test_per_point_lame_parameters_match_scalar_calls() -> None:
    F = _random_F(6, seed=2)
    mu = torch.linspace(1.0e4, 1.0e6, 6, dtype=torch.float64)
    lam = torch.linspace(5.0e3, 2.0e6, 6, dtype=torch.float64)
    psi = energy_density(F, mu, lam)
    for p in range(6):
        ref = energy_density(F[p : p + 1], float(mu[p]), float(lam[p]))
        assert psi[p] == pytest.approx(float(ref[0]), rel=1e-14)


@pytest.mark.parametrize("nu", [0.0, 0.3, 0.45])
def test_hessian_matches_finite_differences_of_piola(nu: float) -> None:
    mu, lam = lame_parameters(E_PA, nu)
    F = _random_F(16, seed=3)
    H = hessian(F, mu, lam, project_spd=False)
    h = 1e-6
    fd = torch.zeros(16, 9, 9, dtype=torch.float64)
    for k in range(9):
        d = torch.zeros(9, dtype=torch.float64)
        d[k] = h
        d = d.reshape(3, 3)  # row-major: index k = 3 * i + j
        fd[:, :, k] = ((first_piola(F + d, mu, lam) - first_piola(F - d, mu, lam)) / (2 * h)).reshape(16, 9)
    rel = (H - fd).norm() / H.norm()
    assert rel < 1e-6
    assert torch.allclose(H, H.transpose(1, 2), rtol=0, atol=1e-9 * float(H.abs().max()))


def test_projected_hessian_is_psd_and_unchanged_when_already_psd() -> None:
    mu, lam = lame_parameters(E_PA, 0.4)
    F = _random_F(64, seed=4, scale=0.6)  # large deformations: raw Hessian indefinite somewhere
    raw = hessian(F, mu, lam, project_spd=False)
    assert float(torch.linalg.eigvalsh(raw).min()) < 0.0  # the test really exercises the projection
    proj = hessian(F, mu, lam, project_spd=True)
    evals = torch.linalg.eigvalsh(proj)
    assert float(evals.min()) >= -1e-9 * mu
    # at rest the exact Hessian is PSD (mu I9 + ... is the linear-elastic tensor) -> projection is identity
    rest = torch.eye(3, dtype=torch.float64).expand(3, 3, 3).contiguous()
    assert torch.allclose(hessian(rest, mu, lam), hessian(rest, mu, lam, project_spd=False), atol=1e-6, rtol=0)
    floor = hessian(F, mu, lam, project_spd=True, min_eigenvalue=0.01)
    assert float(torch.linalg.eigvalsh(floor).min()) >= 0.01 * mu * (1 - 1e-9)


def test_rotations_have_zero_energy_and_stress() -> None:
    mu, lam = lame_parameters(E_PA, 0.3)
    R = _random_rotations(32, seed=5)
    assert float(energy_density(R, mu, lam).abs().max()) < 1e-9 * E_PA
    assert float(first_piola(R, mu, lam).abs().max()) < 1e-9 * E_PA
    assert float(cauchy_stress(R, mu, lam).abs().max()) < 1e-9 * E_PA
    assert float(hydrostatic_stress(R, mu, lam).abs().max()) < 1e-9 * E_PA


def test_energy_is_rotation_invariant() -> None:
    mu, lam = lame_parameters(E_PA, 0.3)
    F = _random_F(32, seed=6)
    R = _random_rotations(32, seed=7)
    assert torch.allclose(energy_density(R @ F, mu, lam), energy_density(F, mu, lam), rtol=1e-12, atol=1e-6)


@pytest.mark.parametrize("eps", [1e-3, 1e-4, -1e-3])
def test_uniaxial_stretch_nu0_gives_hooke(eps: float) -> None:
    """nu = 0, F = diag(1 + eps, 1, 1): sigma_xx = E eps + O(eps^2), lateral stresses O(eps^2).

    Tolerance: |sigma_xx - E eps| <= E eps^2 and |sigma_yy|, |sigma_zz| <= E eps^2.
    (For this energy sigma_xx = E eps exactly; lateral = mu eps^2 / (1 + eps).)
    """
    mu, lam = lame_parameters(E_PA, 0.0)
    F = torch.diag(torch.tensor([1.0 + eps, 1.0, 1.0], dtype=torch.float64))[None]
    s = cauchy_stress(F, mu, lam)[0]
    assert abs(float(s[0, 0]) - E_PA * eps) <= E_PA * eps**2
    assert abs(float(s[1, 1])) <= E_PA * eps**2
    assert abs(float(s[2, 2])) <= E_PA * eps**2
    assert float(s[0, 1].abs() + s[0, 2].abs() + s[1, 2].abs()) == 0.0


@pytest.mark.parametrize("nu", [0.0, 0.25, 0.45])
@pytest.mark.parametrize("s", [0.99, 0.9])
def test_uniform_compression_hydrostatic_stress(nu: float, s: float) -> None:
    """F = s I: sigma = (mu (1/s - 1) + lam' (s^3 - 1)) I (hand-derived), < 0 for s < 1."""
    mu, lam = lame_parameters(E_PA, nu)
    F = (s * torch.eye(3, dtype=torch.float64))[None]
    p = float(hydrostatic_stress(F, mu, lam)[0])
    analytic = mu * (1.0 / s - 1.0) + (lam + mu) * (s**3 - 1.0)
    assert p < 0.0
    assert p == pytest.approx(analytic, rel=1e-12)
    # small-strain check: p ~ 3 K (s - 1), K the bulk modulus; relative error O(|s - 1|)
    K = Material(E_PA, nu, 1000.0).bulk_modulus_pa
    assert p == pytest.approx(3.0 * K * (s - 1.0), rel=3.0 * abs(s - 1.0) * (1 + lam / K))


def test_linearised_piola_is_hooke() -> None:
    """dP at F = I in direction H equals 2 mu sym(H) + lam tr(H) I (central difference)."""
    mu, lam = lame_parameters(E_PA, 0.35)
    g = torch.Generator().manual_seed(8)
    Hd = torch.randn(3, 3, generator=g, dtype=torch.float64)
    t = 1e-6
    I = torch.eye(3, dtype=torch.float64)
    dP = (first_piola((I + t * Hd)[None], mu, lam) - first_piola((I - t * Hd)[None], mu, lam))[0] / (2 * t)
    ref = mu * (Hd + Hd.T) + lam * torch.trace(Hd) * I
    assert torch.allclose(dP, ref, rtol=1e-7, atol=1e-7 * E_PA * 1e-3)
