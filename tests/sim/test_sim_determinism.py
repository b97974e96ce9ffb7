"""Same inputs and seed give bit-identical trajectories on CPU."""

import numpy as np

from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.skinning import SkinningTrainingSettings
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

TINY_TRAINING = SkinningTrainingSettings(steps=10, points_per_step=64, hidden_layers=1, width=8)


def run(seed, cache_dir):
    rng = np.random.default_rng(7)  # geometry fixed; the simulator seed drives cubature and training
    pts = rng.uniform(-0.1, 0.1, (400, 3))
    objs = [
        SimObjectSpec(
            "a",
            pts,
            0.008,
            Material(1e5, 0.3, 1000.0),
            position_m=(0.0, 0.0, 0.2),
            velocity_m_s=(0.5, 0.0, 0.0),
            num_handles=2,
            skinning_settings=TINY_TRAINING,
        ),
        SimObjectSpec(
            "b",
            pts,
            0.008,
            Material(1e8, 0.3, 1000.0),
            position_m=(0.05, 0.02, 0.6),
            angular_velocity_rad_s=(1.0, 2.0, 0.0),
        ),
    ]
    preset = load_preset("draft").replace(num_cubature_points=40)
    return Simulator(
        StaticScene(), objs, (0.0, 0.0, -9.81), preset, seed=seed, skinning_cache_dir=str(cache_dir)
    ).run(num_frames=11, fps=25.0)


def test_bit_identical_for_the_same_seed(tmp_path):
    first = run(3, tmp_path / "one")
    second = run(3, tmp_path / "two")
    other = run(4, tmp_path / "one")
    for a, b in zip(first.objects, second.objects):
        for key in (
            "handle_transforms",
            "cubature_positions_m",
            "contact_force_n",
            "contact_partner",
            "hydrostatic_stress_pa",
            "orientation_wxyz",
            "angular_velocity_rad_s",
        ):
            assert np.array_equal(getattr(a, key), getattr(b, key)), key
    assert [e.to_dict() for e in first.collisions] == [e.to_dict() for e in second.collisions]
    assert len(first.collisions) >= 2  # both objects reach the ground or each other
    # a different seed samples other cubature points: a different trajectory
    assert not np.array_equal(first.objects[0].cubature_positions_m, other.objects[0].cubature_positions_m)


def _soft_trio(cache_dir, training_threads: int) -> Simulator:
    """Three soft objects (two and three handles) and a stiff one, bases trained in ``training_threads`` threads."""
    rng = np.random.default_rng(3)
    specs = [
        SimObjectSpec(f"soft{k}", rng.uniform(-0.05, 0.05, (300, 3)), 0.001, Material(1e5, 0.3, 1000.0),
                      position_m=(0.3 * k, 0.0, 0.2), num_handles=2 + k % 2, skinning_settings=TINY_TRAINING)
        for k in range(3)
    ] + [SimObjectSpec("stiff", rng.uniform(-0.05, 0.05, (300, 3)), 0.001, Material(1e9, 0.3, 1000.0),
                       position_m=(1.0, 0.0, 0.2))]  # fmt: skip
    preset = load_preset("draft").replace(num_cubature_points=40)
    return Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), preset, seed=5, skinning_cache_dir=str(cache_dir),
                     training_threads=training_threads)  # fmt: skip


def test_bases_trained_side_by_side_are_the_same_bits(tmp_path):
    """Training a draw's bases in several threads (each on one torch thread) gives the bases, the models and the
    trajectory of training them one after another, and leaves torch's thread count as it was."""
    import pytest
    import torch

    threads_before = torch.get_num_threads()
    one = _soft_trio(tmp_path / "one", 1)
    three = _soft_trio(tmp_path / "three", 3)
    assert torch.get_num_threads() == threads_before
    assert len(list((tmp_path / "three").glob("*.pt"))) == 3  # the stiff object trains nothing
    for a, b in zip(one.prepared, three.prepared):
        assert a.basis.num_handles == b.basis.num_handles
        if a.basis.mlp is not None:
            for key, value in a.basis.mlp.state_dict().items():
                assert torch.equal(value, b.basis.mlp.state_dict()[key]), key
    ra, rb = one.run(num_frames=6, fps=25.0), three.run(num_frames=6, fps=25.0)
    for ta, tb in zip(ra.objects, rb.objects):
        np.testing.assert_array_equal(ta.com_m, tb.com_m)
        np.testing.assert_array_equal(ta.contact_positions_m, tb.contact_positions_m)
    with pytest.raises(ValueError, match="training_threads=0 must be an integer >= 1"):
        _soft_trio(tmp_path / "bad", 0)
