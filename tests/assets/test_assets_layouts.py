"""Scene layouts: free placement regions above supports, floor and box SDF, world-state export."""

import json

import numpy as np
import pytest

from data_gen.assets.layouts import RAMP_ANGLE_DEG
from data_gen.assets.registry import (
    get_object,
    get_scene_layout,
    is_object_name,
    is_scene_layout_name,
    list_scene_layouts,
)
from data_gen.assets.scene_layout import PlacementRegion
from data_gen.configs import scenario_config
from data_gen.scenario import ScenarioError


def test_at_least_five_layouts():
    names = list_scene_layouts()
    assert len(names) >= 5 and len(set(names)) == len(names)
    assert {"empty_floor", "table", "bench_steps", "shelf_wall", "ramp", "room_corner"} <= set(names)


@pytest.mark.parametrize("name", list_scene_layouts())
def test_regions_are_free_space(name):
    scene = get_scene_layout(name)
    rng = np.random.default_rng(0)
    for region in scene.regions:
        p = region.sample(2000, rng)
        assert np.all(p >= region.min_m) and np.all(p <= region.max_m)
        assert scene.sdf(p).min() > 0.03, f"{name}/{region.name} overlaps static geometry"


@pytest.mark.parametrize("name", list_scene_layouts())
def test_floor_sdf_and_world_state(name):
    scene = get_scene_layout(name)
    far = np.array([[50.0, 50.0, 0.3], [50.0, -50.0, -0.2]])
    np.testing.assert_allclose(scene.sdf(far), [0.3, -0.2])
    _d, part = scene.sdf_and_part(far)
    assert list(part) == [0, 0]
    state = json.loads(json.dumps(scene.to_world_state()))
    assert state["name"] == name and len(state["boxes"]) == len(scene.boxes)


def test_table_region_is_above_the_table_top():
    scene = get_scene_layout("table")
    region = scene.region("table_top")
    top = scene.boxes[0]
    top_z = top.center_m[2] + top.half_extents_m[2]
    assert region.min_m[2] > top_z
    xy = region.sample(500, np.random.default_rng(1))[:, :2]
    below = np.concatenate([xy, np.full((len(xy), 1), top_z - 0.005)], axis=1)
    np.testing.assert_allclose(scene.sdf(below), -0.005, atol=1e-9)  # inside the top, 5 mm under its face


def test_ramp_surface_has_the_stated_slope():
    scene = get_scene_layout("ramp")
    ramp = scene.boxes[0]
    angle = np.deg2rad(RAMP_ANGLE_DEG)
    xs = np.linspace(-0.5, 0.5, 11)
    # top face of a plank of half thickness t centred at height c, tilted by angle: z = c + t / cos - x tan
    z_top = ramp.center_m[2] + ramp.half_extents_m[2] / np.cos(angle) - xs * np.tan(angle)
    on = np.stack([xs, np.zeros_like(xs), z_top], axis=1)
    np.testing.assert_allclose(ramp.shape().sdf(on), 0.0, atol=1e-12)
    np.testing.assert_allclose(scene.sdf(on + [0.0, 0.0, 0.01]), 0.01 * np.cos(angle), rtol=1e-9)
    lowest = ramp.shape().sdf([[0.6 * np.cos(angle) - 0.02 * np.sin(angle), 0.0, 0.0]])
    np.testing.assert_allclose(lowest, 0.0, atol=1e-12)  # the low corner rests on the floor


def test_bad_region_and_unknown_scene():
    with pytest.raises(ValueError, match="max_m"):
        PlacementRegion("r", (0, 0, 1), (1, 1, 0.5))
    with pytest.raises(ValueError, match="above the floor"):
        PlacementRegion("r", (0, 0, -1), (1, 1, 0.5))
    with pytest.raises(KeyError, match="empty_floor"):
        get_scene_layout("moon_base")


def test_registry_resolves_names_and_references_and_scenario_configs_accept_them(tmp_path):
    assert is_scene_layout_name("ramp") and is_scene_layout_name("ply:/data/room.ply?up=y")
    assert not is_scene_layout_name("moon_base") and not is_scene_layout_name("file:/data/room.obj")
    assert is_object_name("mug") and is_object_name("file:/m.obj") and is_object_name("ply:/t.ply")
    assert not is_object_name("unicorn") and not is_object_name("obj:/m.obj")
    with pytest.raises(KeyError, match=r"scheme in \['file', 'ply'\]"):
        get_object("obj:/m.obj")
    # references to existing files pass the config check (they are opened when a scenario is drawn), unknown
    # names do not
    (tmp_path / "room.ply").touch()
    (tmp_path / "m.obj").touch()
    scene, mesh = f"ply:{tmp_path / 'room.ply'}", f"file:{tmp_path / 'm.obj'}"
    cfg = scenario_config("drop", scenes=["table", scene], objects=["mug", mesh])
    assert cfg.scenes == ("table", scene) and cfg.objects == ("mug", mesh)
    with pytest.raises(ScenarioError, match="unknown scene 'moon_base'"):
        scenario_config("drop", scenes=["moon_base"])
