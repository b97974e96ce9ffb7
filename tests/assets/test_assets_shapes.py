"""Primitive SDFs against hand-computed values; meshes against analytic volumes; composition."""

import numpy as np
import pytest

from data_gen.assets.shapes import (
    Box,
    Capsule,
    Cone,
    Cylinder,
    Difference,
    Ellipsoid,
    Intersection,
    Offset,
    RoundedBox,
    Scaled,
    Sphere,
    Torus,
    Union,
    place,
)
from newtphys.rotations import axis_angle_to_quat


def test_sphere_sdf():
    s = Sphere(0.5)
    np.testing.assert_allclose(
        s.sdf([[0, 0, 0], [1, 0, 0], [0.3, 0.4, 0], [0, 0, -2]]), [-0.5, 0.5, 0.0, 1.5]
    )


def test_box_sdf_inside_face_edge_corner():
    b = Box((1.0, 2.0, 3.0))
    pts = [[0, 0, 0], [0.5, 0, 0], [2, 0, 0], [2, 3, 0], [2, 3, 4], [0, 2.5, 0]]
    np.testing.assert_allclose(b.sdf(pts), [-1.0, -0.5, 1.0, np.sqrt(2), np.sqrt(3), 0.5])


def test_rounded_box_sdf():
    b = RoundedBox((1.0, 1.0, 1.0), 0.25)
    # the corner is a ball of radius 0.25 around (0.75, 0.75, 0.75)
    np.testing.assert_allclose(
        b.sdf([[2, 2, 2], [1, 0, 0], [0, 0, 0]]), [np.sqrt(3) * 1.25 - 0.25, 0.0, -1.0]
    )


def test_torus_sdf():
    t = Torus(1.0, 0.25)
    pts = [[1, 0, 0], [0, 0, 0], [2, 0, 0], [0, 0, 1], [0, 1.25, 0]]
    np.testing.assert_allclose(t.sdf(pts), [-0.25, 0.75, 0.75, np.sqrt(2) - 0.25, 0.0])


def test_capsule_sdf():
    c = Capsule(0.2, 0.5)
    pts = [[0, 0, 1], [0.5, 0, 0], [0, 0, 0], [0.3, 0, 0.9], [0, 0, -0.7]]
    np.testing.assert_allclose(c.sdf(pts), [0.3, 0.3, -0.2, 0.3, 0.0], atol=1e-12)


def test_cylinder_sdf():
    c = Cylinder(1.0, 0.5)
    np.testing.assert_allclose(
        c.sdf([[2, 0, 0], [0, 0, 1], [2, 0, 1], [0, 0, 0], [0.9, 0, 0]]),
        [1.0, 0.5, np.sqrt(1.25), -0.5, -0.1],
    )


def test_cone_sdf():
    c = Cone(1.0, 2.0)  # base z = -1 radius 1, apex z = +1; slant line 2 rho + z = 1
    pts = [[0, 0, 2], [0, 0, -2], [0, 0, -0.9], [1, 0, 1], [2, 0, -1]]
    np.testing.assert_allclose(c.sdf(pts), [1.0, 1.0, -0.1, 2 / np.sqrt(5), 1.0], atol=1e-12)


def test_ellipsoid_sign_and_sphere_limit():
    e = Ellipsoid((0.3, 0.2, 0.1))
    np.testing.assert_allclose(e.sdf([[0.3, 0, 0], [0, 0.2, 0], [0, 0, 0.1]]), 0.0, atol=1e-12)
    assert e.sdf([[0, 0, 0]])[0] < 0 and e.sdf([[0.31, 0, 0]])[0] > 0 and e.sdf([[0.29, 0, 0]])[0] < 0
    np.testing.assert_allclose(Ellipsoid((1.0, 1.0, 1.0)).sdf([[2, 0, 0], [0, 0.5, 0]]), [1.0, -0.5])


def test_transformed_and_scaled():
    # a 2 x 1 x 1 (half extents) box rotated 90 deg about z becomes 1 x 2 x 1, then moved by (5, 0, 0)
    b = place(Box((2.0, 1.0, 1.0)), (5.0, 0.0, 0.0), axis_angle_to_quat((0, 0, 1), np.pi / 2))
    np.testing.assert_allclose(b.sdf([[5, 0, 0], [7, 0, 0], [5, 3, 0]]), [-1.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(b.bounds(), [[4, -2, -1], [6, 2, 1]], atol=1e-12)
    s = Scaled(Sphere(1.0), 0.25)
    np.testing.assert_allclose(s.sdf([[1, 0, 0]]), [0.75])


def test_composition_sdf_and_parts():
    u = Union((Sphere(1.0, part_id=0), place(Sphere(1.0, part_id=1), (3.0, 0.0, 0.0))))
    d, part = u.sdf_and_part([[-1.5, 0, 0], [4.5, 0, 0], [1.5, 0, 0]])
    np.testing.assert_allclose(d, [0.5, 0.5, 0.5])
    assert part[0] == 0 and part[1] == 1
    cup = Difference(Cylinder(1.0, 1.0), place(Cylinder(0.8, 1.0, part_id=1), (0.0, 0.0, 0.2)))
    d, part = cup.sdf_and_part([[0, 0, 0.0], [0.9, 0, 0], [0, 0, -0.9]])
    np.testing.assert_allclose(d, [0.8, -0.1, -0.1], atol=1e-12)  # cavity is outside; wall and floor inside
    assert part[0] == 1  # nearest surface is the cavity's
    i = Intersection((Box((1.0, 1.0, 1.0)), Sphere(1.2)))
    assert i.sdf([[0.95, 0.95, 0.0]])[0] > 0 and i.sdf([[0.9, 0, 0]])[0] < 0
    np.testing.assert_allclose(Offset(Box((1.0, 1.0, 1.0)), 0.1).sdf([[1.1, 0, 0]]), [0.0], atol=1e-12)


@pytest.mark.parametrize(
    "shape, volume_m3, tol",
    [
        (Sphere(0.1), 4 / 3 * np.pi * 0.1**3, 0.005),
        (Box((0.1, 0.05, 0.02)), 8 * 0.1 * 0.05 * 0.02, 0.012),  # MT chamfers edges by ~1 cell
        (Cylinder(0.05, 0.1), np.pi * 0.05**2 * 0.2, 0.006),
        (Torus(0.1, 0.03), 2 * np.pi**2 * 0.1 * 0.03**2, 0.006),
        (Cone(0.05, 0.1), np.pi * 0.05**2 * 0.1 / 3, 0.006),
        (Capsule(0.03, 0.05), np.pi * 0.03**2 * 0.1 + 4 / 3 * np.pi * 0.03**3, 0.005),
    ],
)
def test_mesh_volume_matches_analytic(shape, volume_m3, tol):
    mesh = shape.to_mesh()
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert abs(mesh.volume / volume_m3 - 1.0) < tol
    # vertices lie on the zero level set up to a small fraction of the grid spacing
    spacing = float(np.ptp(mesh.vertices, axis=0).max()) / 48.0
    assert np.abs(shape.sdf(mesh.vertices)).max() < 0.25 * spacing


def test_mesh_volume_converges_with_resolution():
    s = Sphere(0.1)
    exact = 4 / 3 * np.pi * 0.1**3
    coarse = abs(s.to_mesh(spacing_m=0.02).volume / exact - 1)
    fine = abs(s.to_mesh(spacing_m=0.005).volume / exact - 1)
    assert fine < coarse and fine < 0.002


def test_bad_parameters_name_the_field():
    with pytest.raises(ValueError, match="radius_m"):
        Sphere(-1.0)
    with pytest.raises(ValueError, match="minor_radius_m"):
        Torus(0.1, 0.2)
    with pytest.raises(ValueError, match="radius_m"):
        RoundedBox((0.1, 0.1, 0.1), 0.2)
    with pytest.raises(ValueError, match="points"):
        Sphere(1.0).sdf(np.zeros((3, 2)))
    with pytest.raises(ValueError, match="spacing_m"):
        Sphere(1.0).to_mesh(spacing_m=-0.1)
