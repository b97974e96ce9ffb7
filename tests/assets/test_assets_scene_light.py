"""Scene light settings: every layout carries one (recorded in its world-state entry); a captured ply: scene
takes its direction from light=x,y,z in the scene's z-up frame; bad values name the option."""

import json

import numpy as np
import pytest

from data_gen.assets.captured import check_scene_reference
from data_gen.assets.ply_io import export_splats
from data_gen.assets.registry import get_scene_layout, list_scene_layouts
from data_gen.gaussians import Gaussians
from data_gen.scene_light import DEFAULT_LIGHT, direction_from_angles


def _room(tmp_path):
    u, v = np.meshgrid(np.linspace(-100, 100, 21), np.linspace(-100, 100, 21), indexing="ij")
    floor = np.stack([u.ravel(), np.zeros(u.size), v.ravel()], 1)  # y-up capture, cm
    n = len(floor)
    g = Gaussians(means_m=floor, scales_m=np.full((n, 3), 2.0), colors_rgb=np.full((n, 3), 0.5),
                  opacities=np.full(n, 0.9))
    path = tmp_path / "room.ply"
    export_splats(path, g)
    return path


def test_default_light_and_world_state_record() -> None:
    # azimuth -35 deg, 55 deg up: (cos 55 cos 35, -cos 55 sin 35, sin 55)
    np.testing.assert_allclose(DEFAULT_LIGHT.direction, [0.46985, -0.32899, 0.81915], atol=1e-5)
    np.testing.assert_allclose(direction_from_angles(90.0, 30.0), [0.0, np.sqrt(0.75), 0.5], atol=1e-12)
    for name in list_scene_layouts():
        state = json.loads(json.dumps(get_scene_layout(name).to_world_state()))
        assert np.linalg.norm(state["light"]["direction"]) == pytest.approx(1.0)
        assert set(state["light"]) == {"direction", "intensity", "ambient", "color"}


def test_captured_scene_light_option(tmp_path) -> None:
    path = _room(tmp_path)
    assert get_scene_layout(f"ply:{path}?up=y&scale=0.01").light == DEFAULT_LIGHT
    scene = get_scene_layout(f"ply:{path}?up=y&scale=0.01&light=0,-2,2")
    np.testing.assert_allclose(scene.light.direction, [0.0, -np.sqrt(0.5), np.sqrt(0.5)], atol=1e-12)
    assert scene.light.intensity == DEFAULT_LIGHT.intensity and scene.light.ambient == DEFAULT_LIGHT.ambient
    assert scene.to_world_state()["light"]["direction"] == pytest.approx([0.0, -np.sqrt(0.5), np.sqrt(0.5)])
    with pytest.raises(ValueError, match=r"light='1,2' must be three numbers x,y,z"):
        check_scene_reference(f"ply:{path}?light=1,2")
    with pytest.raises(ValueError, match=r"option light='1,0,0'.*at least 5.0 deg up"):
        check_scene_reference(f"ply:{path}?light=1,0,0")
