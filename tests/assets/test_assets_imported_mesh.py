"""Real meshes as objects: get_object("file:...") -> MeshShape SDF, volume, colours, options and errors."""

import numpy as np
import pytest
import trimesh

from data_gen.assets.gaussians_from_geometry import gaussians_from_object
from data_gen.assets.mesh_shape import MeshShape
from data_gen.assets.object_asset import CATEGORIES, semantic_id
from data_gen.assets.registry import get_object
from data_gen.assets.shapes import Scaled


def _coloured_box_obj(tmp_path):
    """A 20 x 10 x 5 cm box (file units: cm) whose +x vertices are blue and -x vertices red, as OBJ."""
    m = trimesh.creation.box(extents=(20.0, 10.0, 5.0))
    colors = np.tile([255, 0, 0, 255], (len(m.vertices), 1)).astype(np.uint8)
    colors[m.vertices[:, 0] > 0] = [0, 0, 255, 255]
    m.visual.vertex_colors = colors
    path = tmp_path / "box.obj"
    m.export(path)
    return path


def test_obj_box_scale_up_axis_volume_and_sdf(tmp_path):
    path = _coloured_box_obj(tmp_path)
    a = get_object(f"file:{path}?scale=0.01&up=y&material=rubber")
    assert isinstance(a.shape, MeshShape)
    # up=y maps file (x, y, z) to (x, -z, y): 20 x 10 x 5 cm -> 0.20 x 0.05 x 0.10 m
    np.testing.assert_allclose(a.size_m, [0.20, 0.05, 0.10], atol=1e-6)
    assert a.volume_m3() == pytest.approx(0.2 * 0.05 * 0.1, rel=1e-6)
    assert a.category == "imported" and a.default_material == "rubber" and a.allowed_materials == ("rubber",)
    pts = np.array([[0.0, 0.0, 0.0], [0.13, 0.0, 0.0], [0.0, 0.0, -0.04], [0.1, 0.025, 0.05 + 0.03]])
    np.testing.assert_allclose(a.shape.sdf(pts), [-0.025, 0.03, -0.01, 0.03], atol=1e-6)


def test_imported_category_appended_last_keeps_existing_ids():
    assert CATEGORIES[-1] == "imported" and semantic_id("imported") == len(CATEGORIES) == 17
    assert semantic_id("ball") == 1 and semantic_id("tool") == 16


def test_vertex_colours_reach_the_gaussians(tmp_path):
    a = get_object(f"file:{_coloured_box_obj(tmp_path)}?scale=0.01")
    assert a.default_material == "plastic" and len(a.allowed_materials) == 12  # no material given: any class
    corners = np.array([[0.1, 0.05, 0.025], [-0.1, -0.05, -0.025]])
    np.testing.assert_allclose(a.colors_at(corners), [[0, 0, 1], [1, 0, 0]], atol=1e-6)
    rng = np.random.default_rng(0)
    same = a.with_material_color("metal", rng)  # the mesh's own colours are kept
    assert same is a
    g = gaussians_from_object(a, np.random.default_rng(1), count=2000)
    # on the +x / -x end faces every vertex has one colour
    plus, minus = g.means_m[:, 0] > 0.0999, g.means_m[:, 0] < -0.0999
    assert plus.sum() > 20 and minus.sum() > 20
    np.testing.assert_allclose(g.colors_rgb[plus], np.tile([0, 0, 1], (plus.sum(), 1)), atol=1e-3)
    np.testing.assert_allclose(g.colors_rgb[minus], np.tile([1, 0, 0], (minus.sum(), 1)), atol=1e-3)
    # colours interpolate linearly along x on the side faces: blue fraction = (x + 0.1) / 0.2
    side = np.abs(g.means_m[:, 1]) > 0.0249
    np.testing.assert_allclose(g.colors_rgb[side, 2], (g.means_m[side, 0] + 0.1) / 0.2, atol=1e-3)


def test_ply_mesh_face_colours_and_glb_sphere(tmp_path):
    m = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    fc = np.tile([128, 128, 128, 255], (len(m.faces), 1)).astype(np.uint8)
    fc[m.face_normals[:, 2] > 0.5] = [0, 255, 0, 255]  # green top
    m.visual.face_colors = fc
    m.export(tmp_path / "cube.ply")
    a = get_object(f"file:{tmp_path / 'cube.ply'}")
    np.testing.assert_allclose(
        a.colors_at([[0.0, 0.0, 0.05], [0.05, 0.0, 0.0]]), [[0, 1, 0], [128 / 255] * 3]
    )
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    sphere.export(tmp_path / "ball.glb")
    b = get_object(f"file:{tmp_path / 'ball.glb'}", size_m=0.2)  # rescaled like a library object
    assert isinstance(b.shape, Scaled) and b.nominal_size_m == pytest.approx(0.2)
    assert b.volume_m3() == pytest.approx(sphere.volume * 0.2**3, rel=1e-6)
    n = 1500
    pts = b.interior_points((b.volume_m3() / n) ** (1 / 3), np.random.default_rng(0))
    assert len(pts) == pytest.approx(n, rel=0.1) and np.all(np.linalg.norm(pts, axis=1) < 0.1)


def test_open_mesh_uses_the_winding_number(tmp_path):
    m = trimesh.creation.box(extents=(0.2, 0.2, 0.2))
    keep = ~(m.face_normals[:, 2] > 0.5)  # remove the top face: a box with a 20 x 20 cm hole
    open_box = trimesh.Trimesh(m.vertices, m.faces[keep], process=False)
    open_box.export(tmp_path / "open.obj")
    shape = MeshShape(open_box)
    assert not open_box.is_watertight
    assert shape.sdf([[0.0, 0.0, 0.0]])[0] == pytest.approx(-0.1, abs=1e-6)  # inside by winding number 0.5+
    assert shape.sdf([[0.0, 0.0, -0.15]])[0] == pytest.approx(0.05, abs=1e-6)
    # the loader's hole filling closes it; the volume is the closed box's
    a = get_object(f"file:{tmp_path / 'open.obj'}")
    assert a.volume_m3() == pytest.approx(0.008, rel=0.03)
    assert shape.own_volume_m3() == pytest.approx(0.008, rel=0.03)  # grid count on the open mesh


def test_bad_inputs_are_clear_errors(tmp_path):
    path = _coloured_box_obj(tmp_path)
    with pytest.raises(FileNotFoundError, match="missing.obj"):
        get_object(f"file:{tmp_path / 'missing.obj'}")
    (tmp_path / "junk.obj").write_text("this is not a mesh\n")
    with pytest.raises(ValueError, match="junk.obj"):
        get_object(f"file:{tmp_path / 'junk.obj'}")
    with pytest.raises(ValueError, match=r"scale=1000 makes the object 2e\+04 m across.*\[0.005, 5.0\]"):
        get_object(f"file:{path}?scale=1000")
    with pytest.raises(ValueError, match=r"scale=1e-05 .*\[0.005, 5.0\]"):
        get_object(f"file:{path}?scale=0.00001")
    with pytest.raises(ValueError, match="unknown option 'colour'; allowed options: name, material, up, scale, resize"):
        get_object(f"file:{path}?colour=red")
    with pytest.raises(ValueError, match="up='w'"):
        get_object(f"file:{path}?up=w")
    with pytest.raises(KeyError, match="unobtainium"):
        get_object(f"file:{path}?material=unobtainium")
    flat = trimesh.Trimesh([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], [[0, 1, 2], [1, 3, 2]])
    flat.export(tmp_path / "flat.obj")
    with pytest.raises(ValueError, match="zero volume"):
        get_object(f"file:{tmp_path / 'flat.obj'}")
