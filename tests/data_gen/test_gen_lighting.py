"""Lighting through the pipeline: every label map byte-identical with lighting on and off, the RGB lit and
shadowed, deterministic; captured scenes take their light direction from the reference."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from newtphys import schema


@pytest.fixture(scope="module")
def simulated():
    """A 16 cm wooden block dropped 2 cm onto the empty floor, seen by a static camera: 3 frames, 48 x 64."""
    from data_gen.assets.registry import get_scene_layout
    from data_gen.cameras import CameraPathSpec
    from data_gen.configs import render_settings
    from data_gen.pipeline import build_objects, simulate
    from data_gen.scenario import ObjectPlacement, Scenario
    from data_gen.sim.presets import load_preset

    block = ObjectPlacement(
        object_id=1, asset="wooden_block", size_m=0.16, material="wood", young_modulus_pa=1.0e10,
        poisson_ratio=0.35, density_kg_m3=600.0, position_m=(0.0, 0.0, 0.024 + 0.02),
        orientation_wxyz=(1.0, 0.0, 0.0, 0.0), velocity_m_s=(0.0, 0.0, 0.0), angular_velocity_rad_s=(0.0, 0.0, 0.0),
        motion="drop", color_seed=101,
    )  # fmt: skip
    camera = CameraPathSpec(kind="static", look_target_m=(0.0, 0.0, 0.03), radius_m=0.5, height_m=0.35,
                            azimuth_rad=-2.0, fov_x_deg=55.0)
    scenario = Scenario(sequence_id="light", seed=2, split="train", scene="empty_floor", objects=(block,),
                        gravity_m_s2=(0.0, 0.0, -9.81), camera=camera, num_frames=3, fps=25.0, image_size=(48, 64))
    settings = render_settings(object_gaussians=1500, interior_points=400, scene_spacing_m=0.04)
    layout = get_scene_layout(scenario.scene)
    objects = build_objects(scenario, settings)
    result = simulate(scenario, objects, layout, load_preset("draft"))
    return scenario, objects, layout, result, settings


def _render(simulated, **changes):
    from data_gen.pipeline import render_sequence

    scenario, objects, layout, result, settings = simulated
    return render_sequence(scenario, objects, layout, result, dataclasses.replace(settings, **changes))[0]


def test_labels_are_byte_identical_with_lighting_on_and_off(simulated) -> None:
    lit = _render(simulated, lighting=True, shadows=True)
    unlit = _render(simulated, lighting=False)
    assert set(lit) == set(schema.MAPS)
    compared = [name for name in schema.MAPS if name != schema.RGB]
    for name in compared:
        assert lit[name].tobytes() == unlit[name].tobytes(), name
    assert len(compared) == len(schema.MAPS) - 1 >= 11  # every map of the contract but RGB
    # the RGB did change: the floor is shaded (0.96 of its albedo lit, 0.35 in shadow), the block too
    diff = np.abs(lit[schema.RGB].astype(int) - unlit[schema.RGB].astype(int))
    assert diff.max() > 40
    # deterministic: a second lit render is the same bytes
    assert _render(simulated, lighting=True, shadows=True)[schema.RGB].tobytes() == lit[schema.RGB].tobytes()


def _in_sweep(xy: np.ndarray, half_xy: tuple[float, float], horiz: np.ndarray, length_m: float,
              grow_m: float) -> np.ndarray:
    """Whether floor points (n, 2) reach the block's footprint (|x| <= hx, |y| <= hy, grown by ``grow_m``)
    when moved towards the light by some s in [0, length_m]: the shadow of a box standing on the floor."""
    s = np.linspace(0.0, length_m, 41)
    p = xy[:, None, :] + s[None, :, None] * horiz
    return ((np.abs(p[..., 0]) <= half_xy[0] + grow_m) & (np.abs(p[..., 1]) <= half_xy[1] + grow_m)).any(1)


def test_the_block_shadows_the_floor_where_geometry_puts_it(simulated) -> None:
    """The block (0.16 x 0.08 x 0.048 m, axis-aligned at the origin, dropped without spin) under the default
    light (azimuth -35 deg, 55 deg up) shadows the floor points that reach its footprint when moved towards
    the light by up to 0.048 / tan 55 deg = 3.4 cm. Floor pixels (instance 0) are placed on the floor by
    their depth; lit-with-shadows is compared with lit-without-shadows of the same frame."""
    from data_gen.pipeline import camera_matrices
    from data_gen.scene_light import DEFAULT_LIGHT

    scenario = simulated[0]
    shadowed = _render(simulated, lighting=True, shadows=True)
    plain = _render(simulated, lighting=True, shadows=False)
    K, w2c = camera_matrices(scenario)
    t = 2
    depth = shadowed[schema.DEPTH][t].astype(np.float64)
    floor = (shadowed[schema.INSTANCES][t] == 0) & (depth > 0)
    v, u = np.nonzero(floor)
    rays = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0], (v + 0.5 - K[1, 2]) / K[1, 1], np.ones_like(u, float)], 1)
    world = (rays * depth[v, u][:, None] - w2c[t][:3, 3]) @ w2c[t][:3, :3]  # R^T (p - t)
    assert np.abs(world[:, 2]).max() < 0.01  # floor pixels lie on the floor
    d = np.asarray(DEFAULT_LIGHT.direction)
    horiz = d[:2] / np.linalg.norm(d[:2])
    length = 0.048 * np.linalg.norm(d[:2]) / d[2]
    xy = world[:, :2]
    inside = _in_sweep(xy, (0.07, 0.03), horiz, length - 0.01, 0.0)  # 1 cm inside the shadow's edges
    outside = ~_in_sweep(xy, (0.08, 0.04), horiz, length + 0.02, 0.02)  # 2 cm outside them
    darker = shadowed[schema.RGB][t][v, u].astype(float).mean(1) < plain[schema.RGB][t][v, u].astype(float).mean(1) - 20
    assert inside.sum() >= 5 and outside.sum() >= 100
    assert darker[inside].mean() > 0.9
    assert not darker[outside].any()


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"shadow_test": "ray"}, r"render.shadow_test must be one of \('pixel', 'splat'\), got 'ray'"),
        ({"shadow_map_px": 4}, r"render.shadow_map_px must be >= 8 px, got 4"),
        ({"shadow_bias_m": -0.01}, r"render.shadow_bias_m must be a finite distance >= 0 m, got -0.01"),
    ],
)
def test_render_settings_reject_bad_lighting_values(changes, match) -> None:
    from data_gen.configs import render_settings

    with pytest.raises(ValueError, match=match):
        render_settings(**changes)


def test_lighting_keys_are_in_the_shipped_config() -> None:
    from data_gen.configs import generation_config

    cfg = generation_config("render.lighting=false")
    assert cfg.render.lighting is False and cfg.render.shadows is True
    assert "lighting: false" in cfg.config_yaml and "shadow_test: pixel" in cfg.config_yaml  # recorded in shards
