"""Stability matrix: E x nu x g x preset -- finite, no tunnelling, bounded penetration, or a clear error."""

import itertools

import numpy as np
import pytest

from data_gen.sim.contact_points import box_surface
from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.skinning import SkinningTrainingSettings
from data_gen.sim.static_scene import StaticBox, StaticScene
from data_gen.sim.world import MAX_SELF_WEIGHT_STRAIN, SimObjectSpec, Simulator

TINY_TRAINING = SkinningTrainingSettings(steps=20, points_per_step=128, hidden_layers=1, width=16)
YOUNG = [1e3, 1e5, 1e7, 1e10]
POISSON = [0.0, 0.3, 0.49]
GRAVITY = [0.98, 9.81, 20.0]
PRESETS = ["draft", "standard", "high", "reference"]
DEFAULT_SUBSET = [
    (1e3, 0.49, 0.98, "draft"),
    (1e10, 0.49, 20.0, "draft"),
    (1e5, 0.3, 9.81, "draft"),
    (1e7, 0.0, 20.0, "standard"),
]
RHO, SIZE = 1000.0, 0.2


def grid_box(half_extents_m, counts):
    axes = [(np.arange(n) + 0.5) / n * 2 * h - h for h, n in zip(half_extents_m, counts)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)


def run_pile(young, nu, g, preset_name, cache_dir, seconds=0.6):
    pts = grid_box((0.1, 0.1, 0.1), (4, 4, 4))
    surface = box_surface((0.1, 0.1, 0.1), 2000, seed=0)  # contact spheres on the true surface, as in the pipeline
    objs = [
        SimObjectSpec(
            "bottom",
            pts,
            SIZE**3,
            Material(young, nu, RHO),
            position_m=(0.0, 0.0, 0.15),
            skinning_settings=TINY_TRAINING,
            surface=surface,
        ),
        SimObjectSpec(
            "top",
            pts,
            SIZE**3,
            Material(young, nu, RHO),
            position_m=(0.03, 0.0, 0.45),
            velocity_m_s=(0.0, 0.0, -2.0),
            skinning_settings=TINY_TRAINING,
            surface=surface,
        ),
    ]
    preset = load_preset(preset_name).replace(num_cubature_points=64, num_contact_points=128, max_handles=3)
    scene = StaticScene(boxes=(StaticBox((0.6, 0.0, 0.1), (0.2, 0.2, 0.1)),))
    sim = Simulator(scene, objs, (0.0, 0.0, -g), preset, seed=0, skinning_cache_dir=str(cache_dir))
    return sim.run(num_frames=int(round(seconds * 25)) + 1, fps=25.0)


def check_or_refused(young, nu, g, preset_name, cache_dir):
    if RHO * g * SIZE / young > MAX_SELF_WEIGHT_STRAIN:
        with pytest.raises(ValueError, match="young_modulus_pa"):
            run_pile(young, nu, g, preset_name, cache_dir)
        return
    res = run_pile(young, nu, g, preset_name, cache_dir)
    bottom, top = res.objects
    for tr in res.objects:
        for key in (
            "cubature_positions_m",
            "contact_positions_m",
            "contact_force_n",
            "hydrostatic_stress_pa",
            "det_f",
            "com_m",
            "velocity_m_s",
            "angular_velocity_rad_s",
            "handle_transforms",
        ):
            assert np.all(np.isfinite(getattr(tr, key))), (tr.name, key)
        radius = tr.contact_radius_m.min()
        # no tunnelling through the floor: every sphere centre stays above z = 0 (penetration < r)
        assert tr.contact_positions_m[:, :, 2].min() > 0.0
        if young >= 1e5:
            assert tr.det_f.min() > 0.2
        # E = 1e3 Pa: a 1 kPa jelly hit by an 8 kg block at 2 m/s is crushed flat (measured det F down to
        # -0.02 at nu = 0 in `high`); the run stays finite and nothing tunnels, which is what is asserted.
        assert (tr.contact_radius_m[None] - tr.contact_positions_m[:, :, 2]).max() < radius
    # the top object never passes through the bottom one: while it is over the bottom's footprint it
    # stays above it (it may slide off a soft base: where it ends up is not a stability property) ...
    over = np.all(np.abs(top.com_m[:, :2] - bottom.com_m[:, :2]) < 0.1, axis=1)
    assert np.all(top.com_m[over, 2] > bottom.com_m[over, 2])
    # ... and no pair of their contact spheres overlaps by half the sum of their radii
    gaps = np.linalg.norm(top.contact_positions_m[:, :, None] - bottom.contact_positions_m[:, None], axis=-1)
    sum_r = top.contact_radius_m[:, None] + bottom.contact_radius_m[None, :]
    assert (sum_r[None] - gaps).max() < 0.5 * sum_r.max()
    assert any(e.objects == (1, 2) for e in res.collisions)


@pytest.mark.parametrize("young,nu,g,preset_name", DEFAULT_SUBSET)
def test_stability_subset(young, nu, g, preset_name, tmp_path):
    check_or_refused(young, nu, g, preset_name, tmp_path)


def test_too_soft_is_refused_with_named_parameter(tmp_path):
    with pytest.raises(ValueError, match=r"young_modulus_pa=1000\.0.*too soft"):
        run_pile(1e3, 0.3, 20.0, "draft", tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("young,nu,g,preset_name", list(itertools.product(YOUNG, POISSON, GRAVITY, PRESETS)))
def test_stability_full_matrix(young, nu, g, preset_name, tmp_path_factory):
    check_or_refused(young, nu, g, preset_name, tmp_path_factory.getbasetemp() / "skinning")
