"""User assets through the real pipeline: a captured splat scene with an imported mesh, a splat object and
hollow library objects (slow: it trains skinning weights and simulates; ~20-30 s on 2 CPU cores)."""

import numpy as np
import pytest
import trimesh

from data_gen.assets.materials import get_material
from data_gen.assets.ply_io import export_splats
from data_gen.gaussians import Gaussians


def _splats(means: np.ndarray, scale_m: float, rgb) -> Gaussians:
    n = len(means)
    return Gaussians(
        means_m=means, scales_m=np.full((n, 3), scale_m), colors_rgb=np.tile(rgb, (n, 1)), opacities=np.full(n, 0.95)
    )


@pytest.mark.slow
def test_captured_scene_with_imported_objects_generates_a_sequence(tmp_path):
    from data_gen.configs import render_settings, scenario_config
    from data_gen.pipeline import generate_sequence
    from data_gen.scenario import sample_scenario
    from data_gen.sim.presets import load_preset

    u, v = np.meshgrid(np.linspace(-150, 150, 121), np.linspace(-150, 150, 121), indexing="ij")
    floor = np.stack([u.ravel(), np.full(u.size, 20.0), v.ravel()], 1)  # Y-up capture in cm, floor at y = 20
    export_splats(tmp_path / "room.ply", _splats(floor, 1.5, [0.5, 0.5, 0.5]))
    box = trimesh.creation.box(extents=(20.0, 10.0, 5.0))
    box.visual.vertex_colors = [200, 30, 30, 255]
    box.export(tmp_path / "box.obj")
    k = 4000
    i = np.arange(k) + 0.5
    phi, th = np.arccos(1 - 2 * i / k), np.pi * (1 + 5**0.5) * i
    ball = 0.08 * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)
    export_splats(tmp_path / "ball.ply", _splats(ball, 0.004, [0.2, 0.8, 0.2]))
    cfg = scenario_config(
        "drop",
        scenes=(f"ply:{tmp_path}/room.ply?up=y&scale=0.01",),
        objects=(f"file:{tmp_path}/box.obj?scale=0.01&material=wood", f"ply:{tmp_path}/ball.ply?material=rubber",
                 "cardboard_box", "bottle"),
        num_objects=(4, 4), size_m=(0.12, 0.25), camera_distance_m=(0.9, 1.1),
    )  # fmt: skip
    scenario = sample_scenario(cfg, "imports", 1, "train", "earth", 10, 25.0, (48, 64))
    arrays, _ = generate_sequence(scenario, load_preset("draft"), render_settings(object_gaussians=1500, interior_points=600))
    ws = arrays.world_state
    assert ws.scene.kind == "captured"
    for obj in ws.objects:  # mass = density x material volume, for imported, splat and hollow objects alike
        assert obj.mass == pytest.approx(obj.density * obj.volume, rel=1e-6)
        lo, hi = get_material(obj.material).density_kg_m3
        assert lo <= obj.density <= hi
        if obj.name == "box":  # named by the file's stem; the file itself is provenance
            assert obj.category == "imported" and obj.material == "wood"
            assert obj.extra["source"]["file"] == "box.obj"
        if obj.name in ("cardboard_box", "bottle"):  # shells: a few hundred grams at most at <= 0.25 m
            assert obj.mass < 0.5
    assert int(arrays.maps["instances"][0].max()) >= 1  # objects render over the captured splats
