"""Object library: >= 30 unique objects, watertight meshes whose inside agrees with the SDF, scaling."""

import numpy as np
import pytest
import trimesh

from data_gen.assets.object_asset import CATEGORIES, semantic_class_table, semantic_id
from data_gen.assets.registry import get_object, list_objects, object_pool
from data_gen.assets.materials import list_materials
from data_gen.assets.ply_io import points_inside_mesh

NAMES = list_objects()
CORE = object_pool("core")
MESHED = [n if n in CORE else pytest.param(n, marks=pytest.mark.slow) for n in NAMES]
"""The core objects in the default run; the ~85 family objects (same check, ~0.5 s each) in the slow run
(tests/assets/test_assets_families.py builds a sample of them by default)."""


def test_library_size_and_metadata():
    assert len(NAMES) >= 30 and len(set(NAMES)) == len(NAMES)
    assert semantic_class_table()["1"] == CATEGORIES[0]
    for name in NAMES:
        a = get_object(name)
        assert a.name == name
        assert 1 <= a.semantic_id <= len(CATEGORIES) and CATEGORIES[a.semantic_id - 1] == a.category
        assert a.default_material in a.allowed_materials
        assert set(a.allowed_materials) <= set(list_materials())
        assert 0.01 <= a.nominal_size_m <= 1.0
        lo, hi = a.shape.bounds()
        np.testing.assert_allclose(0.5 * (lo + hi), 0.0, atol=1e-9)  # local frame centred on the bounds
    assert len({get_object(n).category for n in NAMES}) >= 12


@pytest.mark.parametrize("name", MESHED)
def test_mesh_watertight_and_sdf_sign_agrees(name):
    a = get_object(name)
    mesh = a.to_mesh()  # the visible surface: for hollow objects the outer wall only
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    solid = a.shape.outer if a.is_hollow else a.shape
    rng = np.random.default_rng(0)
    lo, hi = a.shape.bounds()
    pad = 0.1 * (hi - lo)  # 10% margin so box-like objects get outside points too
    pts = rng.uniform(lo - pad, hi + pad, size=(3000, 3))
    inside_sdf = solid.sdf(pts) < 0
    assert 0.02 < inside_sdf.mean() < 1.0  # the test points straddle the surface
    agree = np.mean(points_inside_mesh(mesh, pts) == inside_sdf)
    assert agree > 0.99, f"{name}: SDF sign and mesh winding number agree on {agree:.4f} of points"
    # no internal sheets: parts that merely touch leave a zero-thickness sheet inside the union where the
    # SDF is 0 with zero gradient; on a clean surface the gradient has unit length (creases excepted)
    p, _ = trimesh.sample.sample_surface(mesh, 4000, seed=np.random.default_rng(0))
    eps = 1e-3 * a.nominal_size_m
    grad = np.stack([(solid.sdf(p + e) - solid.sdf(p - e)) / (2 * eps) for e in np.eye(3) * eps], 1)
    assert np.mean(np.linalg.norm(grad, axis=1) < 0.5) < 0.001


def test_sdf_sign_agrees_with_trimesh_contains():
    pytest.importorskip("rtree")  # trimesh's ray-based contains needs rtree
    for name in ("ball", "rubber_duck"):
        a = get_object(name)
        mesh = a.to_mesh(spacing_m=a.nominal_size_m / 30)  # coarser mesh keeps the ray test fast
        pts = np.random.default_rng(1).uniform(*a.shape.bounds(), size=(200, 3))
        solid = a.shape.outer if a.is_hollow else a.shape  # the mesh is the visible (outer) surface
        agree = np.mean(mesh.contains(pts) == (solid.sdf(pts) < 0))
        assert agree > 0.98, f"{name}: {agree}"


def test_scaling_to_requested_size():
    a = get_object("mug")
    b = get_object("mug", size_m=0.3)
    assert b.nominal_size_m == pytest.approx(0.3, rel=1e-12)
    s = 0.3 / a.nominal_size_m
    np.testing.assert_allclose(b.size_m, a.size_m * s, rtol=1e-12)
    assert b.volume_m3() == pytest.approx(a.volume_m3() * s**3, rel=1e-6)  # the grid scales with the shape
    p = np.random.default_rng(2).uniform(-0.05, 0.05, (100, 3))
    np.testing.assert_allclose(b.shape.sdf(p * s), a.shape.sdf(p) * s, atol=1e-12)
    with pytest.raises(ValueError, match="size_m"):
        a.scaled_to(0.0)


def test_volume_of_simple_objects_vs_analytic():
    ball = get_object("ball")  # hollow sphere, r = 0.11 m, wall 3 mm: the material only
    assert ball.is_hollow
    assert ball.volume_m3() == pytest.approx(4 / 3 * np.pi * (0.11**3 - 0.107**3), rel=0.005)
    ring = get_object("ring_toy")  # torus R = 0.08, r = 0.012
    assert ring.volume_m3() == pytest.approx(2 * np.pi**2 * 0.08 * 0.012**2, rel=0.01)


def test_interior_points_inside_and_dense():
    a = get_object("teddy_bear")
    spacing = 0.006
    p1 = a.interior_points(spacing, np.random.default_rng(3))
    p2 = a.interior_points(spacing, np.random.default_rng(3))
    np.testing.assert_array_equal(p1, p2)
    assert np.all(a.shape.sdf(p1) < 0)
    assert len(p1) == pytest.approx(a.volume_m3() / spacing**3, rel=0.1)


def test_part_colours_follow_textures():
    mug = get_object("mug")  # part 0 outside glaze (0.2, 0.4, 0.7), part 1 cavity (0.93, 0.93, 0.90)
    # a line along x through the mug at mid-height crosses the wall (part 0) and the cavity surface (part 1)
    xs = np.linspace(-0.06, 0.06, 2001)
    line = np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], 1)
    d, part = mug.shape.sdf_and_part(line)
    inside = np.flatnonzero(d < 0)
    assert set(np.unique(part[inside])) == {0, 1}
    col = mug.colors_at(line[inside], part[inside])
    np.testing.assert_allclose(col[part[inside] == 0][0], (0.20, 0.40, 0.70))
    np.testing.assert_allclose(col[part[inside] == 1][0], (0.93, 0.93, 0.90))
    rec = mug.with_material_color("metal", np.random.default_rng(0))
    assert rec.textures[1] == mug.textures[1] and rec.textures[0] != mug.textures[0]


def test_unknown_object_lists_valid_names():
    with pytest.raises(KeyError, match="teddy_bear"):
        get_object("unicorn")
    with pytest.raises(KeyError, match="ball"):
        semantic_id("spaceship")
