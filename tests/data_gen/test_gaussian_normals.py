"""Surface normals: given and estimated, through rigid moves, deformations (inverse transpose) and skinning."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from data_gen.assets.ply_io import decode_splats, encode_gaussians
from data_gen.gaussians import Gaussians, concatenate, deform_normals, normals_from_covariances
from newtphys.rotations import axis_angle_to_quat, quat_to_matrix


def _flat_splats(n: int, seed: int) -> Gaussians:
    """n flat splats (normal sigma 1/100 of the in-plane ones), random orientations, normals = local z."""
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return Gaussians(
        means_m=rng.uniform(-0.1, 0.1, (n, 3)), scales_m=np.tile([0.01, 0.006, 1e-4], (n, 1)), rotations_wxyz=q,
        colors_rgb=np.full((n, 3), 0.5), opacities=np.full(n, 0.9), normals=quat_to_matrix(q)[:, :, 2],
    )


def test_shortest_axis_is_the_flat_splats_normal_up_to_sign() -> None:
    g = _flat_splats(50, 1)
    est = normals_from_covariances(g.covariances())
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", est, g.normals)), 1.0, atol=1e-6)
    bare = Gaussians(means_m=g.means_m, scales_m=g.scales_m, rotations_wxyz=g.rotations_wxyz,
                     colors_rgb=g.colors_rgb, opacities=g.opacities)
    np.testing.assert_array_equal(bare.surface_normals(), est)  # no normals given: the shortest axis
    with pytest.raises(ValueError, match=r"normals\[0\] = \[0.0, 0.0, 0.0\] has zero length"):
        Gaussians(means_m=[[0, 0, 0]], scales_m=[[1, 1, 1]], colors_rgb=[[0, 0, 0]], opacities=[1.0],
                  normals=[[0.0, 0.0, 0.0]])


def test_shear_maps_normals_by_the_inverse_transpose() -> None:
    """Simple shear F = I + e_x e_z^T (x += z), by hand: the plane z = 0 is spanned by F e_x = e_x and
    F e_y = e_y, so its normal stays e_z; the plane x = 0 is spanned by F e_y = e_y and F e_z = (1, 0, 1),
    so its normal e_x becomes (1, 0, -1) / sqrt 2 (= F^-T e_x normalised)."""
    f = np.eye(3)
    f[0, 2] = 1.0
    out = deform_normals([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], np.stack([f, f]))
    np.testing.assert_allclose(out, [[0.0, 0.0, 1.0], [np.sqrt(0.5), 0.0, -np.sqrt(0.5)]], atol=1e-7)
    # random F with det > 0 and det < 0: the unit inverse transpose, sign kept by sign(det)
    rng = np.random.default_rng(2)
    fs = np.eye(3) + 0.4 * rng.normal(size=(40, 3, 3))
    n = rng.normal(size=(40, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    expected = np.einsum("nij,nj->ni", np.linalg.inv(fs).transpose(0, 2, 1), n)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    assert (np.linalg.det(fs) < 0).any() and (np.linalg.det(fs) > 0).any()
    np.testing.assert_allclose(deform_normals(n, fs), expected, atol=1e-5)


def test_deformed_and_transformed_gaussians_carry_their_normals() -> None:
    g = _flat_splats(30, 3)
    rng = np.random.default_rng(4)
    fs = np.eye(3) + 0.3 * rng.normal(size=(30, 3, 3))
    fs[np.linalg.det(fs) < 0, :, 0] *= -1.0  # proper deformations
    d = g.deformed(fs)
    expected = np.einsum("nij,nj->ni", np.linalg.inv(fs).transpose(0, 2, 1), g.normals.astype(np.float64))
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(d.normals, expected, atol=1e-5)
    # the deformed flat splat's own shortest axis agrees (its plane is spanned by F t1, F t2)
    est = normals_from_covariances(d.covariances())
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", est, d.normals)), 1.0, atol=1e-4)
    # rigid: a quarter turn about x takes e_z to -e_y
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix(axis_angle_to_quat(np.array([1.0, 0.0, 0.0]), np.pi / 2))
    flat = Gaussians(means_m=[[0, 0, 0]], scales_m=[[1, 1, 0.1]], colors_rgb=[[0, 0, 0]], opacities=[1.0],
                     normals=[[0.0, 0.0, 1.0]])
    np.testing.assert_allclose(flat.transformed(m).normals, [[0.0, -1.0, 0.0]], atol=1e-7)
    np.testing.assert_allclose(flat.deformed(m[None, :3, :3]).normals, [[0.0, -1.0, 0.0]], atol=1e-7)
    # concatenating with normal-less Gaussians fills theirs with the shortest axis
    bare = Gaussians(means_m=[[0, 0, 0]], scales_m=[[0.1, 0.001, 0.1]], colors_rgb=[[0, 0, 0]], opacities=[1.0])
    both = concatenate([flat, bare])
    np.testing.assert_allclose(np.abs(both.normals), [[0, 0, 1], [0, 1, 0]], atol=1e-7)
    np.testing.assert_array_equal(g.subset([3, 1]).normals, g.normals[[3, 1]])


def test_skinned_surface_normals_follow_a_bending_deformation() -> None:
    """A fake two-handle track: weights (1, x) with gradients (0, e_x); handle 1 bends (z += a x^2-like):
    T_1 = [[0,0,0,0],[0,0,0,0],[b,0,0,0]] -> x = x0 + w1 T1 [x0; 1] -> z += b x^2. F is checked against a
    finite difference of that position map, the normals against F^-T n0."""
    from data_gen.pipeline import SkinnedSurface

    g = _flat_splats(25, 5)
    b = 3.0

    class Basis:
        def evaluate(self, x: torch.Tensor, num_threads: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
            w = torch.stack([torch.ones_like(x[:, 0]), x[:, 0]], 1)
            grad = torch.zeros(len(x), 2, 3, dtype=x.dtype)
            grad[:, 1, 0] = 1.0
            return w, grad

    t1 = np.zeros((3, 4))
    t1[2, 0] = b
    z = np.concatenate([np.zeros(12), t1.reshape(-1)])  # handle-major, row-major 3x4 per handle
    track = SimpleNamespace(basis=Basis(), handle_transforms=np.stack([np.zeros(24), z]))
    surface = SkinnedSurface(g, track)

    def position(x0: np.ndarray) -> np.ndarray:
        return x0 + np.stack([0 * x0[:, 0], 0 * x0[:, 0], b * x0[:, 0] ** 2], 1)

    x0 = g.means_m.astype(np.float64)
    x, _, _, normals = surface.pose(1)
    np.testing.assert_allclose(x, position(x0), atol=1e-12)
    eps = 1e-6
    f_fd = np.stack([(position(x0 + eps * e) - position(x0 - eps * e)) / (2 * eps) for e in np.eye(3)], 2)
    expected = np.einsum("nij,nj->ni", np.linalg.inv(f_fd).transpose(0, 2, 1), g.normals.astype(np.float64))
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(normals, expected, atol=1e-5)
    np.testing.assert_allclose(surface.pose(0)[3], g.normals, atol=1e-7)  # rest frame: unchanged


def test_splat_files_keep_given_normals_and_leave_missing_ones_unset() -> None:
    g = _flat_splats(6, 6)
    raw = encode_gaussians(g)
    np.testing.assert_allclose(raw.normals, g.normals)
    back = decode_splats(raw)
    np.testing.assert_allclose(back.normals, g.normals, atol=1e-7)
    raw.normals[:] = 0.0  # what most 3DGS trainers write
    bare = decode_splats(raw)
    assert bare.normals is None
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", bare.surface_normals(), g.normals)), 1.0, atol=1e-5)
