"""Recording: contact events (one per onset), orientation and angular velocity, presets."""

import numpy as np
import pytest
import torch

from data_gen.sim.material import Material
from data_gen.sim.presets import available_presets, load_preset
from data_gen.sim.recording import ContactEventTracker, angular_velocity
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator
from newtphys.rotations import quat_to_matrix


def entry(force, pos=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0), dt=0.01):
    return {
        "impulse_n_s": force * dt,
        "peak_force_n": force,
        "position_m": np.array(pos),
        "normal": np.array(normal),
    }


def test_event_tracker_merges_steps_and_splits_onsets():
    tracker = ContactEventTracker(dt_s=0.01, substeps_per_frame=4, gap_steps=4)
    forces = {
        2: 5.0,
        3: 20.0,
        4: 10.0,
        6: 1.0,  # one episode (gap of 1 step < 4)
        20: 3.0,
        21: 4.0,
    }  # a second onset after a long gap
    for step in range(30):
        pf = {(1, 0): entry(forces[step], pos=(step, 0, 0))} if step in forces else {}
        if step == 3:
            pf[(1, 2)] = entry(7.0)
        tracker.update(step, pf)
    events = tracker.finish()
    ground = [e for e in events if e.objects == (1, 0)]
    assert len(ground) == 2 and len(events) == 3
    first, second = ground
    assert first.frame == 1  # onset at the end of step 2 = t 0.03 s -> first frame at or after: t = 0.04
    assert abs(first.impulse_n_s - 0.01 * (5 + 20 + 10 + 1)) < 1e-12
    assert first.peak_force_n == 20.0 and first.position_m[0] == 3  # position at the peak
    assert second.frame == 6 and abs(second.impulse_n_s - 0.07) < 1e-12
    assert events[0].to_dict()["objects"] == [1, 0]


def test_angular_velocity_of_a_spinning_point_set():
    quat = np.array([0.7, -0.2, 0.4, 0.1])
    rot = quat_to_matrix(quat)
    gen = torch.Generator().manual_seed(0)
    x0 = torch.rand(50, 3, generator=gen, dtype=torch.float64)
    m = torch.rand(50, generator=gen, dtype=torch.float64) + 0.5
    x = x0 @ torch.from_numpy(rot).T + 3.0
    omega = torch.tensor([0.3, -2.0, 1.0], dtype=torch.float64)
    com = (m[:, None] * x).sum(0) / m.sum()
    v = torch.linalg.cross(omega.expand(50, 3), x - com, dim=1)
    assert torch.allclose(angular_velocity(x - com, v, m), omega, atol=1e-12)


def test_initial_pose_and_spin_are_recorded():
    pts = np.stack(np.meshgrid(*[np.linspace(-0.1, 0.1, 4)] * 3, indexing="ij"), -1).reshape(-1, 3)
    quat = (0.9, 0.3, 0.0, 0.3)
    spec = SimObjectSpec(
        "spinner",
        pts,
        0.008,
        Material(1e9, 0.3, 1000.0),
        position_m=(0.0, 0.0, 2.0),
        orientation_wxyz=quat,
        velocity_m_s=(1.0, 0.0, 0.0),
        angular_velocity_rad_s=(0.0, 0.0, 3.0),
    )
    res = Simulator(StaticScene(), [spec], (0.0, 0.0, 0.0), load_preset("draft"), seed=0).run(6, 25.0)
    tr = res.objects[0]
    np.testing.assert_allclose(tr.orientation_wxyz[0], np.array(quat) / np.linalg.norm(quat), atol=1e-12)
    np.testing.assert_allclose(tr.com_m[0], [0.0, 0.0, 2.0], atol=1e-12)  # the grid is centred
    np.testing.assert_allclose(tr.velocity_m_s[0], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(tr.angular_velocity_rad_s[0], [0.0, 0.0, 3.0], atol=1e-12)
    # free flight: COM moves at constant velocity; the spin (affine body, implicit Euler) decays slowly
    np.testing.assert_allclose(tr.com_m[:, 0], res.times_s * 1.0, atol=1e-9)
    assert np.all(np.abs(tr.angular_velocity_rad_s[1:, 2] - 3.0) < 0.05 * 3.0)
    angle = 2 * np.arccos(np.clip(np.abs(np.sum(tr.orientation_wxyz[5] * tr.orientation_wxyz[0])), 0, 1))
    assert abs(angle - 3.0 * 0.2) < 0.05  # rotated ~ omega t = 0.6 rad in 0.2 s
    # renderer path: deform any rest point with the recorded handle transforms
    x, F = tr.deform(tr.points_rest_m, 3)
    np.testing.assert_allclose(x, tr.cubature_positions_m[3], atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(F), tr.det_f[3], atol=1e-14)
    assert np.abs(tr.det_f - 1.0).max() < 1e-3


def test_presets_load_and_order():
    assert available_presets() == ["draft", "high", "reference", "standard"]
    presets = [load_preset(n) for n in ("draft", "standard", "high", "reference")]
    dts = [p.dt_s(25.0) for p in presets]
    assert dts == sorted(dts, reverse=True) and dts[0] == 0.02
    assert [p.num_cubature_points for p in presets] == sorted(p.num_cubature_points for p in presets)
    with pytest.raises(ValueError, match="valid presets"):
        load_preset("nope")
