"""Free fall under implicit Euler: v_n = -g t_n exactly, y_n = y0 - g t^2/2 - g h t/2, no strain."""

import numpy as np
import pytest

from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.skinning import SkinningTrainingSettings
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

TINY_TRAINING = SkinningTrainingSettings(steps=20, points_per_step=128, hidden_layers=1, width=16)


def grid_box(half_extents_m, counts):
    """Cell-centred grid of rest points filling a box centred at the origin."""
    axes = [(np.arange(n) + 0.5) / n * 2 * h - h for h, n in zip(half_extents_m, counts)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


@pytest.mark.parametrize("g", [0.98, 9.81, 20.0])
def test_free_fall_matches_implicit_euler_closed_form(g, tmp_path):
    pts = grid_box((0.1, 0.1, 0.1), (4, 4, 4))
    spec = SimObjectSpec(
        "soft",
        pts,
        0.2**3,
        Material(2e4, 0.3, 500.0),
        position_m=(0.0, 0.0, 20.0),
        velocity_m_s=(0.3, 0.0, 0.0),
        friction_coefficient=0.0,
        num_handles=3,
        skinning_settings=TINY_TRAINING,
    )
    preset = load_preset("draft").replace(num_cubature_points=64)
    sim = Simulator(StaticScene(), [spec], (0.0, 0.0, -g), preset, seed=1, skinning_cache_dir=str(tmp_path))
    res = sim.run(num_frames=11, fps=25.0)
    tr = res.objects[0]
    assert tr.num_handles == 3
    t = res.times_s
    h = res.info.dt_s
    # velocity exact to solver round-off
    np.testing.assert_allclose(tr.velocity_m_s[:, 2], -g * t, rtol=0, atol=1e-9 * g)
    np.testing.assert_allclose(tr.velocity_m_s[:, 0], 0.3, rtol=0, atol=1e-12)
    z0 = tr.com_m[0, 2]
    np.testing.assert_allclose(tr.com_m[:, 2], z0 - 0.5 * g * t**2 - 0.5 * g * h * t, rtol=0, atol=1e-9)
    # no strain: det F = 1 and zero stress everywhere
    assert np.abs(tr.det_f - 1.0).max() < 1e-10
    assert np.abs(tr.hydrostatic_stress_pa).max() < 1e-6
    assert np.abs(tr.angular_velocity_rad_s).max() < 1e-9
    assert res.collisions == []
    assert np.all(tr.contact_partner == -1)
    np.testing.assert_allclose(tr.gravity_force_n.sum(axis=1)[:, 2], -tr.mass_kg * g, rtol=1e-12)
