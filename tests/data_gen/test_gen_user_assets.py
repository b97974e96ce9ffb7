"""User assets through the documented route: ``generate.py`` with file:/ply: references, as a user types it.

The README's import command must work end to end; imported objects are named by their file's stem (or a
``name=`` option) with provenance apart, never by a path; a given ``scale`` is kept.
"""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import trimesh

from data_gen.gaussians import Gaussians
from data_gen.assets.ply_io import export_splats
from data_gen.configs import scenario_config
from data_gen.scenario import ScenarioError, sample_scenario
from newtphys.shards import ShardReader, list_shards
from newtphys.validate import validate_shard

REPO = Path(__file__).resolve().parents[2]
BOX_EXTENT_CM = (20.0, 10.0, 6.0)


def _splats(means: np.ndarray, scale: float, rgb) -> Gaussians:
    n = len(means)
    return Gaussians(means_m=means, scales_m=np.full((n, 3), scale), colors_rgb=np.tile(rgb, (n, 1)),
                     opacities=np.full(n, 0.95))  # fmt: skip


def _fibonacci_sphere(n: int, radius: float) -> np.ndarray:
    i = np.arange(n) + 0.5
    phi, th = np.arccos(1 - 2 * i / n), np.pi * (1 + 5**0.5) * i
    return radius * np.stack([np.cos(th) * np.sin(phi), np.sin(th) * np.sin(phi), np.cos(phi)], 1)


@pytest.fixture(scope="module")
def user_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """A textured-colour mesh in centimetres, a 3DGS splat object in millimetres and a Y-up captured floor."""
    root = tmp_path_factory.mktemp("user files")  # a space in the path, as users have
    box = trimesh.creation.box(extents=BOX_EXTENT_CM)
    box.visual.vertex_colors = [200, 40, 30, 255]
    box.export(root / "crate.obj")
    export_splats(root / "orb.ply", _splats(_fibonacci_sphere(3000, 60.0), 4.0, [0.2, 0.7, 0.3]))
    u, v = np.meshgrid(np.linspace(-1.5, 1.5, 61), np.linspace(-1.5, 1.5, 61), indexing="ij")
    floor = np.stack([u.ravel(), np.zeros(u.size), v.ravel()], 1)
    export_splats(root / "studio.ply", _splats(floor, 0.03, [0.5, 0.5, 0.55]))
    return {"crate": root / "crate.obj", "orb": root / "orb.ply", "studio": root / "studio.ply"}


def test_generate_py_imports_a_mesh_a_splat_object_and_a_captured_scene(user_files, tmp_path: Path) -> None:
    out = tmp_path / "data"
    objects = [f"file:{user_files['crate']}?scale=0.01&material=wood",
               f"ply:{user_files['orb']}?scale=0.001&material=plastic&name=green_orb"]  # fmt: skip
    scene = f"ply:{user_files['studio']}?up=y"
    cmd = [
        sys.executable, "generate.py", f"out_dir={out}", "num_sequences=1", "num_frames=6", "image_size=[32,48]",
        "progress=false", "render.object_gaussians=800", "render.interior_points=300",
        "render.contact_surface_samples=1000", "scenario.num_objects=[2,2]", "scenario.camera_distance_m=[0.9,1.0]",
        "scenario.objects=[" + ",".join(f'"{o}"' for o in objects) + "]", f'scenario.scenes=["{scene}"]',
    ]  # fmt: skip
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    shards = list_shards(out / "train")
    assert len(shards) == 1
    assert [p for p in validate_shard(shards[0]) if p.severity == "error"] == []
    with ShardReader(shards[0]) as r:
        sid = r.sequences()[0]
        ws = r.world_state(sid)
        ws_json = json.dumps(ws.to_dict())
    assert str(user_files["crate"].parent) not in ws_json  # no user path anywhere in the world state
    assert ws.scene.name == "studio" and ws.scene.kind == "captured"
    assert ws.scene.extra["source"] == {"file": "studio.ply",
                                        "sha256": hashlib.sha256(user_files["studio"].read_bytes()).hexdigest()}
    names = {o.name for o in ws.objects}
    assert names <= {"crate", "green_orb"} and names, names
    for obj in ws.objects:
        source = obj.extra["source"]
        if obj.name == "crate":  # scale=0.01 kept: 20 x 10 x 6 cm, not a drawn size
            assert source["file"] == "crate.obj"
            assert sorted(obj.size) == pytest.approx(sorted(np.array(BOX_EXTENT_CM) * 0.01), abs=1e-6)
        else:  # splat centres on a 60 mm sphere at scale=0.001: a 0.12 m ball
            assert source["file"] == "orb.ply"
            assert source["sha256"] == hashlib.sha256(user_files["orb"].read_bytes()).hexdigest()
            assert max(obj.size) == pytest.approx(0.12, abs=0.01)


def test_imported_objects_keep_their_scale_unless_asked_to_resize(user_files) -> None:
    crate = f"file:{user_files['crate']}?scale=0.01&material=wood"
    kept = scenario_config("drop", scenes=("empty_floor",), objects=(crate,), num_objects=(2, 2))
    for seed in range(3):
        for obj in sample_scenario(kept, "s", seed, "train", "earth", 4, 25.0, (16, 16)).objects:
            assert obj.size_m == pytest.approx(0.2, abs=1e-6)  # the box's 20 cm, whatever size_m draws
    resized = kept.replace(objects=(crate + "&resize=true",), size_m=(0.3, 0.4))
    sizes = [o.size_m for o in sample_scenario(resized, "s", 0, "train", "earth", 4, 25.0, (16, 16)).objects]
    assert all(0.3 <= s <= 0.4 for s in sizes), sizes


@pytest.mark.parametrize(
    ("key", "reference", "message"),
    [
        ("objects", "file:{crate}?material=wood&colour=red", "unknown option 'colour'"),
        ("objects", "file:{crate}?scale=abc", "option scale='abc' is not a number"),
        ("objects", "file:{crate}?resize=maybe", "option resize='maybe' must be true or false"),
        ("objects", "file:{crate}?material=unobtainium", "unobtainium"),
        ("objects", "file:/nowhere/duck.obj?scale=0.1", "asset file not found: /nowhere/duck.obj"),
        ("objects", "spaceship", "unknown object 'spaceship'"),
        ("scenes", "ply:{studio}?up=w", "option up='w' must be one of"),
        ("scenes", "ply:/nowhere/room.ply", "scene file not found: /nowhere/room.ply"),
        ("scenes", "file:{crate}", "a captured scene is 'ply:<path>"),
    ],
)
def test_bad_references_fail_when_the_config_is_read(user_files, key: str, reference: str, message: str) -> None:
    ref = reference.format(crate=user_files["crate"], studio=user_files["studio"])
    with pytest.raises(ScenarioError, match=message.replace("(", r"\(").replace("?", r"\?")) as info:
        scenario_config("drop", **{key: (ref,)})
    assert "scenario 'drop'" in str(info.value)
