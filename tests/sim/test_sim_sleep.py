"""Sleeping: a resting object stops costing Newton work, wakes when a moving object hits it."""

import numpy as np

from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator


def grid_box(half_extents_m, counts):
    axes = [(np.arange(n) + 0.5) / n * 2 * h - h for h, n in zip(half_extents_m, counts, strict=True)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def test_sleep_and_wake_on_impact():
    pts = grid_box((0.1, 0.1, 0.1), (4, 4, 4))
    radius = 0.5 * (0.008 / 64) ** (1 / 3)  # half the grid spacing: the spheres just touch the floor
    base = SimObjectSpec(
        "base", pts, 0.008, Material(1e8, 0.3, 1000.0), position_m=(0.0, 0.0, 0.075 + radius)
    )
    faller = SimObjectSpec("faller", pts, 0.008, Material(1e8, 0.3, 1000.0), position_m=(0.02, 0.0, 1.2))
    preset = load_preset("draft").replace(num_cubature_points=64)
    res = Simulator(StaticScene(), [base, faller], (0.0, 0.0, -9.81), preset, seed=0).run(46, 25.0)
    a, b = res.objects
    hit = next(e.frame for e in res.collisions if e.objects == (1, 2))
    assert 10 <= hit <= 14  # free fall of ~0.9 m takes ~0.43 s = frame 11
    asleep_before = np.nonzero(a.asleep[:hit])[0]
    assert len(asleep_before) > 0 and asleep_before[0] < 6  # the base settles and sleeps within 0.24 s
    assert not a.asleep[hit] or not a.asleep[hit + 1]  # woken by the impact
    assert a.asleep[-1] and b.asleep[-1]  # both resting at the end
    # asleep: the recorded state is frozen, the ground carries both weights, the net force on the base
    # (ground up, faller down) balances its own weight
    f = np.nonzero(a.asleep)[0][-1]
    np.testing.assert_allclose(a.contact_force_n[f].sum(axis=0)[2], a.mass_kg * 9.81, rtol=0.05)
    on_ground = a.contact_partner[f] == 0
    np.testing.assert_allclose(
        a.contact_force_n[f][on_ground, 2].sum(), (a.mass_kg + b.mass_kg) * 9.81, rtol=0.05
    )
    assert np.any(a.contact_partner[f] == 2) and np.any(b.contact_partner[f] == 1)
    assert np.array_equal(a.handle_transforms[f], a.handle_transforms[f - 1])
    # the sleeping base costs no Newton work: well under half of all object-steps were solved
    assert res.info.awake_object_steps < 0.6 * res.info.object_steps
    # the base's contact with the ground is one event for the whole run despite sleeping
    assert len([e for e in res.collisions if e.objects == (1, 0)]) == 1
