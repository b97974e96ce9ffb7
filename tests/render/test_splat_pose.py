"""The splat poser (one warp thread per splat) against the torch formulation it replaced, and against analytic poses:
the same centres, covariances and normals (the SVD's column order and signs may differ, which leaves a Gaussian
unchanged)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from data_gen.render.splat_pose import MIN_SCALE_M, SplatPoser, pose_reference
from data_gen.sim.reduced import affine_basis, deformation_basis
from newtphys.rotations import quat_to_matrix


def _covariance(scales: np.ndarray, quats: np.ndarray) -> np.ndarray:
    r = quat_to_matrix(quats)
    return np.einsum("nij,nj,nkj->nik", r, scales**2, r)


def _random_object(n: int, handles: int, seed: int) -> tuple[torch.Tensor, ...]:
    """Splats of an object with ``handles`` handles: smooth random weights (handle 0 constant), rest rotations and
    scales of a few mm, unit normals; and a handle matrix near the identity motion with a rotation, a translation
    and a random deformation (det F > 0 everywhere)."""
    rng = np.random.default_rng(seed)
    x0 = torch.as_tensor(rng.uniform(-0.1, 0.1, (n, 3)))
    centres = rng.uniform(-0.1, 0.1, (handles, 3))
    w = np.exp(-((x0.numpy()[:, None] - centres[None]) ** 2).sum(-1) / 0.01)
    grad = -2.0 * (x0.numpy()[:, None] - centres[None]) / 0.01 * w[..., None]
    w[:, 0], grad[:, 0] = 1.0, 0.0
    w, grad = torch.as_tensor(w), torch.as_tensor(grad)
    b, c = affine_basis(x0, w), deformation_basis(x0, w, grad)
    quats = rng.normal(size=(n, 4))
    rs = torch.as_tensor(quat_to_matrix(quats / np.linalg.norm(quats, axis=1, keepdims=True))
                         * rng.uniform(1e-3, 5e-3, (n, 1, 3)))  # fmt: skip
    n0 = rng.normal(size=(n, 3))
    n0 /= np.linalg.norm(n0, axis=1, keepdims=True)
    angle = rng.uniform(0.2, 2.5)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    rotation = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    tm = 0.05 * rng.normal(size=(3, 4 * handles))
    tm[:, :3] += rotation - np.eye(3)  # handle 0: x -> R x + t (the Tm of x = x0 + Tm b holds R - I)
    tm[:, 3] += rng.uniform(-1.0, 1.0, 3)
    return x0, b, c, rs, n0, torch.as_tensor(tm)


@pytest.mark.parametrize("handles", [1, 2, 6])
def test_poser_matches_the_torch_svd_formulation(handles: int) -> None:
    x0, b, c, rs, n0, tm = _random_object(2_000, handles, seed=handles)
    poser = SplatPoser(x0, b, c, rs, n0)
    x, scales, quats, normals = poser.pose(tm)
    x_ref, s_ref, q_ref, n_ref = pose_reference(x0, b, c, rs, n0, tm.clone())
    np.testing.assert_allclose(x, x_ref, rtol=0, atol=1e-15)
    cov, cov_ref = _covariance(scales, quats), _covariance(s_ref, q_ref)
    np.testing.assert_allclose(cov, cov_ref, rtol=0, atol=1e-12 * np.abs(cov_ref).max())
    np.testing.assert_allclose(np.sort(scales, 1), np.sort(s_ref, 1), rtol=1e-10)
    np.testing.assert_allclose(np.linalg.norm(quats, axis=1), 1.0, atol=1e-12)
    assert (quats[:, 0] >= 0).all()
    np.testing.assert_allclose(normals, n_ref, atol=2e-7)
    assert normals.dtype == np.float32 and x.dtype == np.float64
    # the launch is replayed: a second frame's Tm gives that frame's pose, not the first one's
    x2 = poser.pose(2.0 * tm)[0]
    np.testing.assert_allclose(x2, pose_reference(x0, b, c, rs, n0, 2.0 * tm)[0], atol=1e-15)


def test_rigid_motion_rotates_each_splat_and_keeps_its_scales() -> None:
    """One handle moving rigidly (F = R): each centre is R x0 + t, each covariance R (R_i S_i^2 R_i^T) R^T, each
    normal R n0, and the scales are the rest scales (in some order)."""
    x0, b, c, rs, n0, tm = _random_object(500, 1, seed=7)
    rotation = np.linalg.qr(np.random.default_rng(1).normal(size=(3, 3)))[0]
    if np.linalg.det(rotation) < 0:
        rotation = -rotation
    tm[:, :3] = torch.as_tensor(rotation - np.eye(3))
    x, scales, quats, normals = SplatPoser(x0, b, c, rs, n0).pose(tm)
    np.testing.assert_allclose(x, x0.numpy() @ rotation.T + tm[:, 3].numpy(), atol=1e-14)
    rest = rs.numpy()
    want = np.einsum("ij,njk,nlk,ml->nim", rotation, rest, rest, rotation)
    np.testing.assert_allclose(_covariance(scales, quats), want, atol=1e-15)
    np.testing.assert_allclose(np.sort(scales, 1), np.sort(np.linalg.norm(rest, axis=1), 1), rtol=1e-12)
    np.testing.assert_allclose(normals, n0 @ rotation.T, atol=1e-7)


def _two_axis_aligned_splats() -> tuple[torch.Tensor, ...]:
    """Two splats at the origin of a one-handle object, scales 1, 2, 3 mm along x, y, z: (x0, b, c, rs)."""
    x0 = torch.zeros(2, 3, dtype=torch.float64)
    w, grad = torch.ones(2, 1, dtype=torch.float64), torch.zeros(2, 1, 3, dtype=torch.float64)
    rs = torch.as_tensor(np.stack([np.diag([1e-3, 2e-3, 3e-3])] * 2))
    return x0, affine_basis(x0, w), deformation_basis(x0, w, grad), rs


def test_flattened_splat_keeps_a_minimum_scale_and_a_collapsed_normal_keeps_its_direction() -> None:
    """F projecting onto the x-y plane: the z scale is clamped to MIN_SCALE_M; a normal in the plane (whose image
    under cof(F) vanishes) keeps its rest direction."""
    x0, b, c, rs = _two_axis_aligned_splats()
    n0 = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    tm = torch.zeros(3, 4, dtype=torch.float64)
    tm[2, 2] = -1.0  # F = diag(1, 1, 0)
    _, scales, _, normals = SplatPoser(x0, b, c, rs, n0).pose(tm)
    np.testing.assert_allclose(np.sort(scales, 1), [[MIN_SCALE_M, 1e-3, 2e-3]] * 2, rtol=1e-12)
    np.testing.assert_allclose(normals, [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]], atol=1e-7)


def test_normals_follow_an_inverting_deformation() -> None:
    """F = diag(1, 1, -1) (a mirror, det F < 0, as a crushed soft object can briefly reach): F^-T n0 flips the z
    normal and keeps the in-plane one; the scales are the rest scales."""
    x0, b, c, rs = _two_axis_aligned_splats()
    n0 = np.array([[0.0, 0.0, 1.0], [0.6, 0.8, 0.0]])
    tm = torch.zeros(3, 4, dtype=torch.float64)
    tm[2, 2] = -2.0  # F = diag(1, 1, -1)
    _, scales, quats, normals = SplatPoser(x0, b, c, rs, n0).pose(tm)
    np.testing.assert_allclose(normals, [[0.0, 0.0, -1.0], [0.6, 0.8, 0.0]], atol=1e-7)
    np.testing.assert_allclose(normals, pose_reference(x0, b, c, rs, n0, tm)[3], atol=1e-7)
    np.testing.assert_allclose(_covariance(scales, quats), np.stack([np.diag([1e-6, 4e-6, 9e-6])] * 2), atol=1e-18)


def test_poser_refuses_mismatched_shapes_by_name() -> None:
    x0, b, c, rs, n0, tm = _random_object(10, 2, seed=3)
    with pytest.raises(ValueError, match=r"need x0 \(n, 3\), b \(n, 4H\)"):
        SplatPoser(x0, b[:5], c, rs, n0)
    with pytest.raises(ValueError, match=r"tm must have shape \(3, 8\), got \(3, 4\)"):
        SplatPoser(x0, b, c, rs, n0).pose(tm[:, :4])


def test_an_object_without_splats_poses_to_empty_arrays() -> None:
    z = torch.zeros
    poser = SplatPoser(z(0, 3, dtype=torch.float64), z(0, 8, dtype=torch.float64), z(0, 8, 3, dtype=torch.float64),
                       z(0, 3, 3, dtype=torch.float64), np.zeros((0, 3)))  # fmt: skip
    x, scales, quats, normals = poser.pose(np.zeros((3, 8)))
    assert x.shape == scales.shape == normals.shape == (0, 3) and quats.shape == (0, 4)
    assert normals.dtype == np.float32


def test_inputs_shared_from_torch_pose_the_same_as_copied_ones_and_are_not_written() -> None:
    """Float64 contiguous tensors on the poser's device are viewed, not copied (on a GPU the skinned bases stay
    there); any other input is copied up. Both give the same bytes, and posing leaves the shared inputs as they
    were."""
    x0, b, c, rs, n0, tm = _random_object(500, 3, seed=11)
    kept = [t.clone() for t in (x0, b, c, rs)]
    shared = SplatPoser(x0, b, c, rs, n0).pose(tm)
    copied = SplatPoser(x0.numpy().copy(), b.numpy().copy(), c.numpy().copy(), rs.numpy().copy(),
                        n0).pose(tm)  # fmt: skip
    as_float32 = SplatPoser(x0.float(), b, c, rs, n0).pose(tm)  # a float32 tensor is converted, not viewed
    for a, e in zip(shared, copied):
        np.testing.assert_array_equal(a, e)
    np.testing.assert_allclose(as_float32[0], shared[0], rtol=0, atol=1e-8)
    for t, k in zip((x0, b, c, rs), kept):
        assert torch.equal(t, k)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA (checked on a lent GPU: docs/gpu_checks.md)")
def test_bases_evaluated_on_the_gpu_pose_as_on_the_cpu() -> None:
    from data_gen.sim.skinning import BlendWeights, SkinningBasis, SkinningMLP

    gen = torch.Generator().manual_seed(0)
    mlp = SkinningMLP(outputs=3, hidden_layers=2, width=16)
    mlp.reset_parameters(gen)
    learned = SkinningBasis(4, mlp, torch.zeros(3, dtype=torch.float64), torch.full((3,), 0.1, dtype=torch.float64))
    blend = SkinningBasis(3, blend=BlendWeights(torch.rand(3, 3, generator=gen, dtype=torch.float64) * 0.1, 0.05,
                                                torch.eye(3, dtype=torch.float64)))  # fmt: skip
    x = torch.rand(1_000, 3, generator=gen, dtype=torch.float64) * 0.2 - 0.1
    for basis in (learned, blend):
        w_cpu, g_cpu = basis.evaluate(x)
        w_gpu, g_gpu = basis.evaluate(x.cuda())
        assert w_gpu.is_cuda and g_gpu.is_cuda
        torch.testing.assert_close(w_gpu.cpu(), w_cpu, rtol=1e-12, atol=1e-14)
        torch.testing.assert_close(g_gpu.cpu(), g_cpu, rtol=1e-12, atol=1e-12)
