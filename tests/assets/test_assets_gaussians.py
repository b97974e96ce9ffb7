"""Surface Gaussians from meshes, library objects and static scenes: placement, orientation, coverage."""

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from data_gen.assets.gaussians_from_geometry import (
    box_gaussians,
    floor_gaussians,
    gaussians_from_mesh,
    gaussians_from_object,
    gaussians_from_scene,
    gaussians_from_shape,
)
from data_gen.assets.registry import get_object, get_scene_layout
from data_gen.assets.shapes import Cylinder, Sphere, Union, place
from data_gen.gaussians import Gaussians, concatenate
from newtphys.rotations import quat_to_matrix


def coverage(g: Gaussians, queries: np.ndarray, k: int = 16) -> float:
    """Fraction of query points where some Gaussian passes the binarised test opacity * exp(-q/2) >= 0.5."""
    _, idx = cKDTree(g.means_m).query(queries, k=k)
    rot = quat_to_matrix(g.rotations_wxyz[idx].astype(np.float64))
    local = np.einsum("nkji,nkj->nki", rot, queries[:, None, :] - g.means_m[idx])
    q = ((local / g.scales_m[idx]) ** 2).sum(-1)
    return float((g.opacities[idx] * np.exp(-q / 2) >= 0.5).any(axis=1).mean())


def normals_of(g: Gaussians) -> np.ndarray:
    return quat_to_matrix(g.rotations_wxyz.astype(np.float64))[:, :, 2]


def test_sphere_gaussians_lie_on_surface_and_face_outward():
    mesh = Sphere(0.1).to_mesh()
    g = gaussians_from_mesh(mesh, np.random.default_rng(0), spacing_m=0.005)
    r = np.linalg.norm(g.means_m, axis=1)
    assert np.abs(r - 0.1).max() < 2e-4  # on the (meshed) sphere
    radial = g.means_m / r[:, None]
    assert np.einsum("ij,ij->i", normals_of(g), radial).min() > 0.99
    np.testing.assert_allclose(g.scales_m[:, 2], 0.1 * g.scales_m[:, 0], rtol=1e-6)
    np.testing.assert_allclose(g.scales_m[:, 0], g.scales_m[:, 1])
    np.testing.assert_allclose(g.opacities, 0.95)
    assert len(g) == pytest.approx(mesh.area / 0.005**2, rel=0.05)
    np.testing.assert_allclose(np.linalg.norm(g.rotations_wxyz, axis=1), 1.0, atol=1e-6)


def test_deterministic_from_seed():
    a = get_object("rubber_duck")
    g1 = gaussians_from_object(a, np.random.default_rng(11))
    g2 = gaussians_from_object(a, np.random.default_rng(11))
    g3 = gaussians_from_object(a, np.random.default_rng(12))
    for f in ("means_m", "scales_m", "rotations_wxyz", "colors_rgb", "opacities", "part_ids"):
        np.testing.assert_array_equal(getattr(g1, f), getattr(g2, f))
    assert not np.array_equal(g1.means_m, g3.means_m)


@pytest.mark.parametrize("name, min_cov", [("ball", 0.995), ("mug", 0.98), ("cardboard_box", 0.98)])
def test_object_gaussians_cover_the_surface(name, min_cov):
    a = get_object(name)
    g = gaussians_from_object(a, np.random.default_rng(0))
    queries, _ = trimesh.sample.sample_surface(a.to_mesh(), 5000, seed=np.random.default_rng(1))
    assert coverage(g, queries) >= min_cov


def test_object_colours_and_parts_come_from_the_asset():
    a = get_object("toy_car")
    g = gaussians_from_object(a, np.random.default_rng(0))
    assert set(np.unique(g.part_ids)) == {0, 1, 2}
    np.testing.assert_allclose(g.colors_rgb, a.colors_at(g.means_m, g.part_ids), atol=1e-6)
    np.testing.assert_allclose(g.colors_rgb[g.part_ids == 2][0], (0.08, 0.08, 0.08), atol=1e-6)  # wheels


def test_mesh_face_colours_are_used():
    box = trimesh.creation.box((1.0, 1.0, 1.0))
    colors = np.zeros((len(box.faces), 4), np.uint8)
    colors[:, 3] = 255
    colors[:, 0] = np.where(box.face_normals[:, 2] > 0.5, 255, 0)  # top faces red, others black
    box.visual.face_colors = colors
    g = gaussians_from_mesh(box, np.random.default_rng(0), count=2000)
    top = g.means_m[:, 2] > 0.5 - 1e-6
    np.testing.assert_allclose(g.colors_rgb[top], np.tile([1.0, 0.0, 0.0], (top.sum(), 1)))
    np.testing.assert_allclose(g.colors_rgb[~top], 0.0)


def test_floor_grid_is_flat_textured_and_hole_free():
    scene = get_scene_layout("empty_floor")
    g = floor_gaussians(scene, 0.05)
    cells = int(np.ceil(2 * scene.floor_half_extent_m / 0.05))
    assert len(g) == cells**2
    np.testing.assert_array_equal(g.means_m[:, 2], 0.0)
    np.testing.assert_allclose(normals_of(g), np.tile([0.0, 0.0, 1.0], (len(g), 1)), atol=1e-7)
    np.testing.assert_allclose(g.colors_rgb, scene.floor_texture.colors_at(g.means_m), atol=1e-6)
    q = np.random.default_rng(0).uniform(-2.9, 2.9, (5000, 3))
    q[:, 2] = 0.0
    assert coverage(g, q) == 1.0


def test_box_gaussians_on_faces_with_outward_normals():
    scene = get_scene_layout("ramp")
    box = scene.boxes[0]  # tilted plank
    g = box_gaussians(box, 0.02, part_id=1)
    shape = box.shape()
    np.testing.assert_allclose(shape.sdf(g.means_m), 0.0, atol=1e-6)
    eps = 1e-4
    grad = np.stack(
        [(shape.sdf(g.means_m + e) - shape.sdf(g.means_m - e)) / (2 * eps) for e in np.eye(3) * eps], 1
    )
    faces = (
        np.abs(shape.sdf(g.means_m + grad * 1e-3) - 1e-3) < 1e-7
    )  # away from edges the gradient is the normal
    assert np.einsum("ij,ij->i", normals_of(g)[faces], grad[faces]).min() > 0.999
    assert np.all(g.part_ids == 1)
    full = gaussians_from_scene(scene, 0.05)
    assert set(np.unique(full.part_ids)) == {0, 1, 2}


def test_transformed_moves_means_and_rotations():
    g = gaussians_from_mesh(Sphere(0.1).to_mesh(), np.random.default_rng(0), count=200)
    rot = quat_to_matrix(np.array([0.9, 0.1, -0.3, 0.2]))
    m = np.eye(4)
    m[:3, :3] = rot
    m[:3, 3] = [1.0, 2.0, 3.0]
    h = g.transformed(m)
    np.testing.assert_allclose(h.means_m, g.means_m @ rot.T + [1, 2, 3], atol=1e-6)
    np.testing.assert_allclose(
        quat_to_matrix(h.rotations_wxyz), rot @ quat_to_matrix(g.rotations_wxyz), atol=1e-6
    )
    both = concatenate([g, h])
    assert len(both) == 400


def test_surface_gaussians_validation():
    ok = {
        "means_m": np.zeros((2, 3)),
        "scales_m": np.ones((2, 3)),
        "rotations_wxyz": np.tile([1.0, 0, 0, 0], (2, 1)),
        "colors_rgb": np.zeros((2, 3)),
        "opacities": np.ones(2),
        "part_ids": np.zeros(2),
    }
    Gaussians(**ok)
    with pytest.raises(ValueError, match="scales_m"):
        Gaussians(**{**ok, "scales_m": -np.ones((2, 3))})
    with pytest.raises(ValueError, match="opacities"):
        Gaussians(**{**ok, "opacities": np.full(2, 1.5)})
    with pytest.raises(ValueError, match="means_m"):
        Gaussians(**{**ok, "means_m": np.full((2, 3), np.nan)})
    with pytest.raises(ValueError, match="rotations_wxyz"):
        Gaussians(**{**ok, "rotations_wxyz": np.zeros((2, 3))})
    with pytest.raises(ValueError, match="spacing_m or count"):
        gaussians_from_mesh(Sphere(0.1).to_mesh(), np.random.default_rng(0))


def test_primitive_shape_gaussians_take_part_colours():
    shape = Union((Sphere(0.05), place(Cylinder(0.02, 0.05, part_id=1), (0.0, 0.0, 0.08))))
    g = gaussians_from_shape(shape, np.random.default_rng(0), {0: (1.0, 0.0, 0.0), 1: (0.0, 0.0, 1.0)})
    on_cyl = g.means_m[:, 2] > 0.06  # well above the sphere: cylinder surface only
    np.testing.assert_array_equal(g.part_ids[on_cyl], 1)
    np.testing.assert_allclose(g.colors_rgb[on_cyl], np.tile([0.0, 0.0, 1.0], (on_cyl.sum(), 1)))
    low = g.means_m[:, 2] < 0.0
    np.testing.assert_allclose(g.colors_rgb[low], np.tile([1.0, 0.0, 0.0], (low.sum(), 1)))
    d = np.abs(shape.sdf(g.means_m))
    assert np.mean(d < 2e-4) > 0.98 and d.max() < 2e-3  # off only at edges chamfered by the 3.75 mm grid
    with pytest.raises(ValueError, match="part ids"):
        gaussians_from_shape(shape, np.random.default_rng(0), {0: (1.0, 0.0, 0.0)})
