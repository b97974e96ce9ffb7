"""Monte Carlo interior sampling and object particles."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from data_gen.sim.material import Material
from data_gen.sim.particles import ObjectParticles, sample_interior, sample_interior_points


def _unit_sphere_sdf(p: np.ndarray) -> np.ndarray:
    return np.linalg.norm(p, axis=1) - 1.0


def test_unit_sphere_volume_within_three_standard_errors() -> None:
    s = sample_interior(_unit_sphere_sdf, (-1, -1, -1), (1, 1, 1), 20000, seed=0)
    exact = 4.0 / 3.0 * math.pi
    assert abs(s.volume_m3 - exact) < 3.0 * s.volume_std_error_m3
    # binomial error at p = pi/6 with >= 20000 / p draws: ~ 8 * sqrt(p (1-p) / N) ~ 0.02 m^3
    assert 0.005 < s.volume_std_error_m3 < 0.03
    assert s.points.shape == (20000, 3) and s.points.dtype == torch.float64
    assert float(s.points.norm(dim=1).max()) < 1.0
    # uniform in the ball: E|x|^2 = 3/5, std of |x|^2 ~ 0.27 -> 4 sigma ~ 0.008 at n = 20000
    assert float((s.points**2).sum(dim=1).mean()) == pytest.approx(0.6, abs=0.008)


def test_box_filling_its_bounds_is_exact() -> None:
    pts, vol = sample_interior_points(
        lambda p: np.ones(p.shape[0], dtype=bool), (0.0, 0.0, 0.0), (0.2, 0.3, 0.5), 1000, seed=1
    )
    assert vol == pytest.approx(0.03, rel=1e-12)
    assert pts.shape == (1000, 3)


def test_half_box_accepts_torch_mask_and_is_deterministic() -> None:
    def lower_half(p: np.ndarray) -> torch.Tensor:  # a torch-returning membership test is accepted
        return torch.from_numpy(p[:, 2] < 0.5)

    a = sample_interior(lower_half, (0, 0, 0), (1, 1, 1), 5000, seed=2)
    b = sample_interior(lower_half, (0, 0, 0), (1, 1, 1), 5000, seed=2)
    c = sample_interior(lower_half, (0, 0, 0), (1, 1, 1), 5000, seed=3)
    assert torch.equal(a.points, b.points) and a.volume_m3 == b.volume_m3
    assert not torch.equal(a.points, c.points)
    assert abs(a.volume_m3 - 0.5) < 3.0 * a.volume_std_error_m3
    assert float(a.points[:, 2].max()) < 0.5


def test_zero_volume_and_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match="zero volume"):
        sample_interior(lambda p: np.zeros(len(p), dtype=bool), (0, 0, 0), (1, 1, 1), 10, seed=0, max_draws=1000)
    with pytest.raises(ValueError, match="num_points"):
        sample_interior_points(_unit_sphere_sdf, (-1, -1, -1), (1, 1, 1), 0, seed=0)
    with pytest.raises(ValueError, match="bounds_min"):
        sample_interior_points(_unit_sphere_sdf, (1, -1, -1), (1, 1, 1), 10, seed=0)
    with pytest.raises(ValueError, match="inside_fn must return"):
        sample_interior_points(lambda p: np.zeros(3), (-1, -1, -1), (1, 1, 1), 10, seed=0)
    with pytest.raises(ValueError, match="max_draws"):  # tiny solid, too few draws
        sample_interior(lambda p: p[:, 0] < 1e-3, (0, 0, 0), (1, 1, 1), 100, seed=0, max_draws=2000)


def test_object_particles_mass_and_validation() -> None:
    mat = Material(1e6, 0.3, 1200.0)
    pts = torch.zeros(4, 3, dtype=torch.float64)
    pts[:, 0] = torch.arange(4, dtype=torch.float64)
    obj = ObjectParticles(pts, 0.002, mat)
    assert obj.mass_kg == pytest.approx(2.4)
    assert obj.point_mass_kg == pytest.approx(0.6)
    assert obj.point_volume_m3 == pytest.approx(5e-4)
    assert torch.equal(obj.center_of_mass_m, torch.tensor([1.5, 0.0, 0.0], dtype=torch.float64))
    with pytest.raises(ValueError, match="volume_m3=0.0"):
        ObjectParticles(pts, 0.0, mat)
    with pytest.raises(ValueError, match="float64"):
        ObjectParticles(pts.float(), 0.002, mat)
    with pytest.raises(ValueError, match=r"shape \(n, 3\)"):
        ObjectParticles(torch.zeros(0, 3, dtype=torch.float64), 0.002, mat)
