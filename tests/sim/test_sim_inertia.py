"""Inertia from all particles: the reduced mass matrix does not depend on the cubature count."""

import numpy as np
import pytest
import torch

from data_gen.sim.cubature import sample_cubature
from data_gen.sim.material import Material
from data_gen.sim.reduced import ReducedObject
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

HALF = np.array([0.1, 0.06, 0.03])  # m
RHO = 800.0


def grid_box(counts=(40, 24, 12)):
    axes = [(np.arange(n) + 0.5) / n * 2 * h - h for h, n in zip(HALF, counts)]
    return torch.from_numpy(np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3))


def rigid_model(pts, num_cubature, with_particles):
    cub = sample_cubature(pts, num_cubature, seed=0, volume_m3=float(np.prod(2 * HALF)))
    ones = torch.ones(num_cubature, 1, dtype=torch.float64)
    kw = dict(mass_points_rest=pts, mass_weights=torch.ones(len(pts), 1, dtype=torch.float64)) if with_particles else {}
    return ReducedObject(cub.positions, cub.volumes_m3, RHO, ones, torch.zeros(num_cubature, 1, 3, dtype=torch.float64),
                         1e6, 1e6, **kw)


def spin_energy(model, omega_z):
    """Kinetic energy (J) of a rigid spin omega_z (rad/s) about the z axis through the origin."""
    skew = np.array([[0.0, -omega_z, 0.0], [omega_z, 0.0, 0.0], [0.0, 0.0, 0.0]])
    qdot = torch.from_numpy(np.concatenate([skew, np.zeros((3, 1))], 1).reshape(-1))  # 1 handle: q = z
    return model.kinetic_energy(qdot)


def test_spin_energy_matches_the_box_and_ignores_the_cubature_count():
    pts = grid_box()
    mass = RHO * float(np.prod(2 * HALF))
    analytic = 0.5 * 3.0**2 * mass * ((2 * HALF[0]) ** 2 + (2 * HALF[1]) ** 2) / 12.0
    exact = [spin_energy(rigid_model(pts, m, True), 3.0) for m in (16, 64, 256)]
    # cell-centred grid: the second moment is h^2 (1 - 1/n^2) / 3 per axis, here within 0.07 % of the box
    assert exact[0] == pytest.approx(analytic, rel=1e-3)
    assert np.ptp(exact) < 1e-12 * analytic  # identical whatever the cubature count
    coarse = [spin_energy(rigid_model(pts, m, False), 3.0) for m in (16, 64)]
    assert max(abs(e / analytic - 1.0) for e in coarse) > 0.01  # cubature-only inertia was off by > 1 %


def test_recorded_com_is_the_particle_centroid():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-1, 1, (1500, 3)) * HALF
    spec = SimObjectSpec("box", pts, float(np.prod(2 * HALF)), Material(1e9, 0.3, RHO), position_m=(0.0, 0.0, 0.5))
    res = Simulator(StaticScene(ground=False), [spec], (0.0, 0.0, 0.0), "draft", seed=0).run(3, 25.0)
    np.testing.assert_allclose(res.objects[0].com_m[0], pts.mean(0) + (0.0, 0.0, 0.5), atol=1e-12)
