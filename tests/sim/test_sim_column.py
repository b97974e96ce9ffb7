"""Soft column (nu = 0) resting on a frictionless floor under its own weight."""

import numpy as np

from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator


def grid_box(half_extents_m, counts):
    axes = [(np.arange(n) + 0.5) / n * 2 * h - h for h, n in zip(half_extents_m, counts)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def staggered_soft_column(count: int = 3) -> list[SimObjectSpec]:
    """``count`` soft two-handle boxes (14 x 14 x 10 cm, E = 1e5 Pa) stacked 12 cm apart, each shifted by a
    centimetre: they fall, land on the ground and on each other (pairs, friction, one island or several)."""
    from tests.sim.test_sim_collision import TINY_TRAINING  # (test_sim_collision imports grid_box from here)

    half = (0.07, 0.07, 0.05)
    return [
        SimObjectSpec(f"soft_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(1e5, 0.3, 1000.0),
                      position_m=(0.01 * k, 0.01 * (k % 2), 0.06 + 0.12 * k), num_handles=2,
                      skinning_settings=TINY_TRAINING)
        for k in range(count)
    ]  # fmt: skip


def test_column_top_displacement_and_reaction():
    length, young, rho, g = 1.0, 1e6, 1000.0, 9.81
    layers = 20
    spacing = length / layers
    pts = grid_box((0.1, 0.1, length / 2), (3, 3, layers))
    spec = SimObjectSpec(
        "column",
        pts,
        0.2 * 0.2 * length,
        Material(young, 0.0, rho),
        position_m=(0.0, 0.0, length / 2),
        friction_coefficient=0.0,
        num_handles=1,
    )
    preset = load_preset("draft").replace(num_cubature_points=pts.shape[0])
    res = Simulator(StaticScene(), [spec], (0.0, 0.0, -g), preset, seed=0).run(num_frames=26, fps=25.0)
    tr = res.objects[0]
    x_top, _ = tr.deform(np.array([[0.0, 0.0, length / 2]]), 25)
    x_bot, _ = tr.deform(np.array([[0.0, 0.0, -length / 2]]), 25)
    shortening = length - (x_top - x_bot)[0, 2]
    analytic = rho * g * length**2 / (2 * young)  # 4.905e-3 m, strain <= 1 %
    # One affine handle gives uniform strain; with the load carried by the lowest cubature layer at
    # height spacing/2 (not 0) the discrete optimum is analytic * (1 - spacing / length) = 0.95 analytic.
    assert abs(shortening / analytic - (1.0 - spacing / length)) < 0.005
    assert abs(shortening / analytic - 1.0) < 0.06
    # total reaction = m g (static equilibrium), to 0.5 %
    reaction = tr.contact_force_n[25].sum(axis=0)
    np.testing.assert_allclose(reaction[2], tr.mass_kg * g, rtol=5e-3)
    assert abs(reaction[0]) + abs(reaction[1]) < 1e-6 * tr.mass_kg * g
    # resting contact: penetration below the contact radius; contacts are with the scene (partner 0)
    depth = tr.contact_radius_m - tr.cubature_positions_m[25, :, 2]
    assert depth.max() < 0.1 * tr.contact_radius_m.min()
    assert set(np.unique(tr.contact_partner[25])) == {-1, 0}
    # the column settles and sleeps: no Newton work for most of the run
    assert tr.asleep[-1]
    assert res.info.awake_object_steps < 0.5 * res.info.object_steps
    # hydrostatic stress is compressive, bounded by the base stress rho g L / 3 (uniaxial, mean of 3 axes)
    assert tr.hydrostatic_stress_pa[25].max() < 0
    np.testing.assert_allclose(tr.hydrostatic_stress_pa[25].mean(), -rho * g * length / 2 / 3, rtol=0.1)
    # one contact event with the scene, impulse ~ m g t while in contact
    events = [e for e in res.collisions if e.objects == (1, 0)]
    assert len(events) == 1
