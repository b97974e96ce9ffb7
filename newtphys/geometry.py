"""Camera conventions, projection and frame transforms (NumPy, float64 inside).

Conventions (docs/data_contract.md, "Conventions"):

* World frame: right-handed, Z up, ground plane Z = 0; metres.
* Camera frame: OpenCV — x right, y down, z forward (depth = camera z).
* ``world_to_camera`` is a 4x4 rigid transform; ``K`` is 3x3 intrinsics in
  pixels with the pixel (u, v) = (column, row) and pixel centres at integer
  coordinates + 0.5 (the centre of the top-left pixel is (0.5, 0.5)).
* Quaternions are (w, x, y, z), unit norm; rotation maths lives in ``newtphys.rotations``.

Every function accepts arrays with leading batch dimensions.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from newtphys.rotations import matrix_to_quat as matrix_to_quat  # re-exported: one implementation
from newtphys.rotations import quat_to_matrix as quat_to_matrix  # re-exported: one implementation

F64 = NDArray[np.float64]


def intrinsics_from_fov(fov_x_deg: float, height_px: int, width_px: int) -> F64:
    """Pinhole K with square pixels, horizontal field of view ``fov_x_deg``, centred principal point."""
    if not 0.0 < fov_x_deg < 180.0:
        raise ValueError(f"fov_x_deg must be in (0, 180) degrees, got {fov_x_deg}")
    if height_px < 1 or width_px < 1:
        raise ValueError(f"image size must be positive, got H={height_px}, W={width_px}")
    f = 0.5 * width_px / np.tan(np.deg2rad(fov_x_deg) / 2.0)
    return np.array([[f, 0.0, width_px / 2.0], [0.0, f, height_px / 2.0], [0.0, 0.0, 1.0]])


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> F64:
    """World-to-camera 4x4 of an OpenCV camera at ``eye`` looking at ``target``.

    ``up`` is the world direction that appears upward in the image (image y
    points down, so camera -y aligns with ``up`` projected on the image plane).
    """
    eye = np.asarray(eye, np.float64)
    target = np.asarray(target, np.float64)
    up = np.asarray(up, np.float64)
    z = target - eye
    n = np.linalg.norm(z)
    if n < 1e-12:
        raise ValueError(f"look_at: eye {eye.tolist()} and target {target.tolist()} coincide")
    z = z / n
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError(f"look_at: viewing direction {z.tolist()} is parallel to up {up.tolist()}")
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot_c2w = np.stack([x, y, z], axis=1)  # columns: camera axes in world
    return rigid_inverse(compose_rigid(rot_c2w, eye))


def compose_rigid(rotation: ArrayLike, translation: ArrayLike) -> F64:
    """4x4 from a 3x3 rotation and a translation (batched)."""
    r = np.asarray(rotation, np.float64)
    t = np.asarray(translation, np.float64)
    out = np.zeros(r.shape[:-2] + (4, 4))
    out[..., :3, :3] = r
    out[..., :3, 3] = t
    out[..., 3, 3] = 1.0
    return out


def rigid_inverse(transform: ArrayLike) -> F64:
    """Inverse of a 4x4 rigid transform (batched)."""
    m = np.asarray(transform, np.float64)
    r = m[..., :3, :3]
    t = m[..., :3, 3]
    rt = np.swapaxes(r, -1, -2)
    return compose_rigid(rt, -np.einsum("...ij,...j->...i", rt, t))


def transform_points(transform: ArrayLike, points: ArrayLike) -> F64:
    """Apply a 4x4 transform to (..., 3) points."""
    m = np.asarray(transform, np.float64)
    p = np.asarray(points, np.float64)
    return p @ m[:3, :3].T + m[:3, 3]


def rotate_vectors(transform: ArrayLike, vectors: ArrayLike) -> F64:
    """Apply only the rotation of a 4x4 transform to (..., 3) vectors (forces, velocities)."""
    m = np.asarray(transform, np.float64)
    return np.asarray(vectors, np.float64) @ m[:3, :3].T


def project(points_cam: ArrayLike, K: ArrayLike) -> tuple[F64, F64]:
    """Camera-frame points (..., 3) -> pixel coordinates (..., 2) and depth z (...).

    Points with z <= 0 get NaN pixel coordinates.
    """
    p = np.asarray(points_cam, np.float64)
    k = np.asarray(K, np.float64)
    z = p[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = k[0, 0] * p[..., 0] / z + k[0, 1] * p[..., 1] / z + k[0, 2]
        v = k[1, 1] * p[..., 1] / z + k[1, 2]
    uv = np.stack([u, v], axis=-1)
    uv[z <= 0] = np.nan
    return uv, z


def pixel_centers(height_px: int, width_px: int) -> F64:
    """(H, W, 2) array of pixel-centre coordinates (u, v) = (col + 0.5, row + 0.5)."""
    v, u = np.meshgrid(np.arange(height_px) + 0.5, np.arange(width_px) + 0.5, indexing="ij")
    return np.stack([u, v], axis=-1)


def camera_rays(K: ArrayLike, height_px: int, width_px: int) -> F64:
    """(H, W, 3) camera-frame ray directions with z = 1 through each pixel centre."""
    kinv = np.linalg.inv(np.asarray(K, np.float64))
    uv = pixel_centers(height_px, width_px)
    homog = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], axis=-1)
    return homog @ kinv.T


def backproject_depth(depth_m: ArrayLike, K: ArrayLike) -> F64:
    """Depth map (H, W) of camera z -> camera-frame points (H, W, 3); depth 0 gives (0, 0, 0)."""
    d = np.asarray(depth_m, np.float64)
    rays = camera_rays(K, d.shape[-2], d.shape[-1])
    return rays * d[..., None]


def camera_pose(world_to_camera: ArrayLike) -> tuple[F64, F64]:
    """World-to-camera 4x4 -> (camera centre in world, m; camera-to-world rotation as (w, x, y, z))."""
    c2w = rigid_inverse(world_to_camera)
    return c2w[..., :3, 3], matrix_to_quat(c2w[..., :3, :3])
