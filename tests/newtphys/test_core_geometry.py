"""Camera conventions: OpenCV frame, projection round trips, camera poses."""

from __future__ import annotations

import numpy as np
import pytest

from newtphys import geometry
from newtphys.rotations import quat_to_matrix


def test_look_at_is_opencv_and_rigid() -> None:
    w2c = geometry.look_at(eye=(0.0, -2.0, 1.0), target=(0.0, 0.0, 1.0))
    # Target straight ahead on +z at distance 2.
    np.testing.assert_allclose(geometry.transform_points(w2c, [0.0, 0.0, 1.0]), [0.0, 0.0, 2.0], atol=1e-12)
    # World up (+Z) is image up, i.e. camera -y; world +X is image right (+x).
    np.testing.assert_allclose(geometry.rotate_vectors(w2c, [0, 0, 1]), [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(geometry.rotate_vectors(w2c, [1, 0, 0]), [1, 0, 0], atol=1e-12)
    r = w2c[:3, :3]
    np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(r) == pytest.approx(1.0)
    np.testing.assert_allclose(geometry.rigid_inverse(w2c) @ w2c, np.eye(4), atol=1e-12)


def test_intrinsics_and_projection_round_trip() -> None:
    K = geometry.intrinsics_from_fov(90.0, 40, 60)
    assert K[0, 0] == pytest.approx(30.0)  # f = (W/2) / tan(45 deg)
    assert (K[0, 2], K[1, 2]) == (30.0, 20.0)
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 3.0, (40, 60))
    pts = geometry.backproject_depth(depth, K)
    uv, z = geometry.project(pts, K)
    np.testing.assert_allclose(uv, geometry.pixel_centers(40, 60), atol=1e-9)
    np.testing.assert_allclose(z, depth)
    uv_behind, _ = geometry.project(np.array([0.0, 0.0, -1.0]), K)
    assert np.isnan(uv_behind).all()


def test_camera_pose() -> None:
    w2c = geometry.look_at((1.0, 2.0, 3.0), (0.0, 0.0, 0.0))
    pos, rot = geometry.camera_pose(w2c)
    np.testing.assert_allclose(pos, [1, 2, 3], atol=1e-12)
    assert rot[0] >= 0.0
    np.testing.assert_allclose(quat_to_matrix(rot), geometry.rigid_inverse(w2c)[:3, :3], atol=1e-12)


def test_bad_camera_input() -> None:
    with pytest.raises(ValueError, match="fov_x_deg"):
        geometry.intrinsics_from_fov(0.0, 10, 10)
    with pytest.raises(ValueError, match="parallel to up"):
        geometry.look_at((0, 0, 2), (0, 0, 0))
