"""Label rasterizer: exact coverage rule, nearest wins, order independence, warp == torch reference."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from data_gen.gaussians import Gaussians
from data_gen.render.labels import LabelRasterizer, gather_labels, render_label_index, render_mask_of_subset
from data_gen.render.reference_torch import render_label_index_torch
from newtphys.geometry import intrinsics_from_fov, look_at

N_SIDE = 33  # odd: the principal point (16.5, 16.5) is the centre of pixel (16, 16)


def _straight_ahead(scale_m: float, opacity: float, depth_m: float = 2.0, **kw: object) -> Gaussians:
    return Gaussians(
        means_m=[[0.0, 0.0, depth_m]],
        scales_m=[[scale_m] * 3],
        colors_rgb=[[1.0, 0.0, 0.0]],
        opacities=[opacity],
        **kw,
    )  # type: ignore[arg-type]


def _random_scene(n: int, seed: int) -> tuple[Gaussians, np.ndarray, np.ndarray, int, int]:
    rng = np.random.default_rng(seed)
    h, w = 40, 56
    g = Gaussians(
        means_m=rng.uniform(-1.0, 1.0, (n, 3)),
        scales_m=rng.uniform(0.01, 0.12, (n, 3)),
        rotations_wxyz=rng.normal(size=(n, 4)),
        colors_rgb=rng.uniform(0, 1, (n, 3)),
        opacities=rng.uniform(0.2, 1.0, n),
    )
    return g, intrinsics_from_fov(65.0, h, w), look_at((2.5, -2.0, 1.5), (0.0, 0.0, 0.0)), h, w


def test_single_gaussian_covers_exactly_the_hand_computed_disc() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    f, z, opacity = K[0, 0], 2.0, 0.9
    # choose the 3D scale so the covered disc has squared radius 10.5 px^2:
    # q <= 2 ln(2 o)  <=>  r^2 <= 2 ln(2 o) * ((f s / z)^2 + 0.3)
    radius2 = 10.5
    sigma2_px2 = radius2 / (2.0 * np.log(2.0 * opacity))
    scale = np.sqrt(sigma2_px2 - 0.3) * z / f
    index, depth = render_label_index(_straight_ahead(scale, opacity), K, np.eye(4), N_SIDE, N_SIDE)
    r, c = np.mgrid[0:N_SIDE, 0:N_SIDE]
    expected = (r - 16) ** 2 + (c - 16) ** 2 <= 10  # integer offsets with dx^2 + dy^2 <= 10.5
    assert expected.sum() == 37  # 1 + 4 (r^2=1) + 4 (2) + 4 (4) + 8 (5) + 4 (8) + 4 (9) + 8 (10)
    np.testing.assert_array_equal(index >= 0, expected)
    np.testing.assert_array_equal(index[expected], 0)
    np.testing.assert_array_equal(depth[expected], np.float32(2.0))
    np.testing.assert_array_equal(depth[~expected], 0.0)
    np.testing.assert_array_equal(index[~expected], -1)


def test_low_opacity_gaussian_never_covers() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    index, _ = render_label_index(_straight_ahead(0.2, 0.49), K, np.eye(4), N_SIDE, N_SIDE)
    assert (index == -1).all()  # 0.49 * exp(-q/2) < 0.5 everywhere


def test_nearest_covering_gaussian_wins() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    # far (index 0) is larger on screen than near (index 1); both centred on the image centre
    g = Gaussians(
        means_m=[[0.0, 0.0, 4.0], [0.0, 0.0, 2.0]],
        scales_m=[[0.4] * 3, [0.05] * 3],
        colors_rgb=[[0, 0, 1], [1, 0, 0]],
        opacities=[1.0, 1.0],
    )
    index, depth = render_label_index(g, K, np.eye(4), N_SIDE, N_SIDE)
    near_only, _ = render_label_index(g, K, np.eye(4), N_SIDE, N_SIDE, include=[False, True])
    near_mask = near_only >= 0
    assert 0 < near_mask.sum() < (index >= 0).sum()
    np.testing.assert_array_equal(index[near_mask], 1)
    np.testing.assert_array_equal(depth[near_mask], np.float32(2.0))
    ring = (index >= 0) & ~near_mask
    np.testing.assert_array_equal(index[ring], 0)
    np.testing.assert_array_equal(depth[ring], np.float32(4.0))


def test_label_maps_do_not_depend_on_gaussian_order() -> None:
    g, K, w2c, h, w = _random_scene(2000, seed=5)
    index, depth = render_label_index(g, K, w2c, h, w)
    perm = np.random.default_rng(11).permutation(len(g))
    index_p, depth_p = render_label_index(g.subset(perm), K, w2c, h, w)
    hit = index_p >= 0
    assert 0.4 < hit.mean() < 1.0
    np.testing.assert_array_equal(hit, index >= 0)
    np.testing.assert_array_equal(perm[index_p[hit]], index[hit])
    np.testing.assert_array_equal(depth_p, depth)


def test_warp_labels_equal_torch_reference() -> None:
    g, K, w2c, h, w = _random_scene(800, seed=2)
    index, depth = render_label_index(g, K, w2c, h, w)
    index_t, depth_t = render_label_index_torch(g, K, w2c, h, w)
    np.testing.assert_array_equal(index, index_t)
    # depth: warp computes z in float32, the reference in float64 then rounds: <= 1 ulp apart
    np.testing.assert_allclose(depth, depth_t, rtol=3e-7, atol=0)
    include = np.random.default_rng(0).uniform(size=len(g)) < 0.3
    np.testing.assert_array_equal(
        render_label_index(g, K, w2c, h, w, include=include)[0],
        render_label_index_torch(g, K, w2c, h, w, include=include)[0],
    )


def test_deterministic_and_thread_count_independent() -> None:
    g, K, w2c, h, w = _random_scene(500, seed=8)
    a = render_label_index(g, K, w2c, h, w, num_threads=2)
    b = render_label_index(g, K, w2c, h, w, num_threads=2)
    c = render_label_index(g, K, w2c, h, w, num_threads=3)
    for x, y in ((a, b), (a, c)):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1].tobytes() == y[1].tobytes()


def test_deformation_doubles_footprint_along_x() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    f, z = K[0, 0], 2.0
    # no dilation, opacity 1: covered where r^2 <= 2 ln 2 * sigma^2; pick the covered half-width 3.3 px
    scale = 3.3 / np.sqrt(2 * np.log(2.0)) * z / f
    g = _straight_ahead(scale, 1.0)
    d = g.deformed(np.diag([2.0, 1.0, 1.0])[None])
    idx0, _ = render_label_index(g, K, np.eye(4), N_SIDE, N_SIDE, dilation_px2=0.0)
    idx1, _ = render_label_index(d, K, np.eye(4), N_SIDE, N_SIDE, dilation_px2=0.0)
    assert (idx0[16] >= 0).sum() == 7 and (idx0[:, 16] >= 0).sum() == 7  # |dx| <= 3.3
    assert (idx1[16] >= 0).sum() == 13 and (idx1[:, 16] >= 0).sum() == 7  # |dx| <= 6.6 along x only


def test_group_masks_are_per_object_silhouettes() -> None:
    g, K, w2c, h, w = _random_scene(400, seed=4)
    groups = np.arange(len(g)) % 3 + 1  # object ids 1..3
    masks = LabelRasterizer(h, w).render_group_masks(g, K, w2c, groups, [1, 2, 3])
    index, _ = render_label_index(g, K, w2c, h, w)
    for k, obj in enumerate((1, 2, 3)):
        alone = render_mask_of_subset(g, K, w2c, h, w, include=groups == obj)
        np.testing.assert_array_equal(masks[k], alone)
        np.testing.assert_array_equal(
            masks[k], render_label_index_torch(g, K, w2c, h, w, groups == obj)[0] >= 0
        )
        modal = (index >= 0) & (groups[np.maximum(index, 0)] == obj)
        assert not (modal & ~masks[k]).any()  # the amodal silhouette contains the visible part
    np.testing.assert_array_equal(masks.any(0), index >= 0)
    # reusing the projection of a render just made (surface depth, as the pipeline renders): the same masks
    r = LabelRasterizer(h, w, depth_mode="surface")
    r.render(g, K, w2c)
    np.testing.assert_array_equal(r.render_group_masks(g, K, w2c, groups, [1, 2, 3], projected=True), masks)
    with pytest.raises(ValueError, match=r"projected=True but the last projection holds 400 splats, not 200"):
        r.render_group_masks(g.subset(np.arange(200)), K, w2c, groups[:200], [1], projected=True)


def test_gather_labels_any_dtype_and_shape() -> None:
    index = np.array([[0, -1], [2, 1]], np.int32)
    ids = np.array([7, 8, 9], np.uint16)
    np.testing.assert_array_equal(gather_labels(index, ids), [[7, 0], [9, 8]])
    vec = np.arange(9, dtype=np.float32).reshape(3, 3)
    out = gather_labels(index, vec, background=-1.0)
    assert out.shape == (2, 2, 3) and out.dtype == np.float32
    np.testing.assert_array_equal(out[0, 1], [-1, -1, -1])
    np.testing.assert_array_equal(out[1, 0], [6, 7, 8])
    flags = gather_labels(index, np.array([True, False, True]))
    np.testing.assert_array_equal(flags, [[True, False], [True, False]])
    t = gather_labels(torch.as_tensor(index), torch.arange(6.0).reshape(3, 2))
    assert isinstance(t, torch.Tensor)
    np.testing.assert_array_equal(t.numpy(), [[[0, 1], [0, 0]], [[4, 5], [2, 3]]])


@pytest.mark.parametrize(
    ("index", "values", "message"),
    [
        (np.array([[3]]), np.zeros(3), r"index holds Gaussian 3 but per_gaussian_values has only 3 rows"),
        (np.array([[-2]]), np.zeros(3), r"index holds -2"),
        (np.zeros(4, np.int32), np.zeros(3), r"integer \(H, W\) map, got shape \(4,\)"),
        (np.zeros((2, 2)), np.zeros(3), r"integer \(H, W\) map"),
    ],
)
def test_gather_labels_bad_input(index: np.ndarray, values: np.ndarray, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        gather_labels(index, values)


def test_bad_include_and_size() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    g = _straight_ahead(0.1, 1.0)
    with pytest.raises(ValueError, match=r"include must be a bool array of shape \(1,\), got \(2,\)"):
        render_label_index(g, K, np.eye(4), N_SIDE, N_SIDE, include=[True, False])
    with pytest.raises(ValueError, match=r"num_threads must be >= 1, got 0"):
        render_label_index(g, K, np.eye(4), N_SIDE, N_SIDE, num_threads=0)


def test_no_gaussians_gives_empty_maps() -> None:
    g = Gaussians(
        means_m=np.zeros((0, 3)), scales_m=np.zeros((0, 3)), colors_rgb=np.zeros((0, 3)), opacities=[]
    )
    K = intrinsics_from_fov(60.0, 8, 10)
    index, depth = render_label_index(g, K, np.eye(4), 8, 10)
    np.testing.assert_array_equal(index, np.full((8, 10), -1))
    np.testing.assert_array_equal(depth, 0.0)
    np.testing.assert_array_equal(
        gather_labels(index, np.zeros((0, 2), np.float32), 7.0), np.full((8, 10, 2), 7.0)
    )


def test_surface_depth_of_a_tilted_flat_splat_is_the_ray_plane_intersection() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    # a disc (flat Gaussian, zero thickness) at 2 m, tilted 40 degrees about the camera x axis
    angle = np.deg2rad(40.0)
    half = angle / 2
    rotation = [[np.cos(half), np.sin(half), 0.0, 0.0]]
    centre = np.array([0.0, 0.0, 2.0])
    g = Gaussians(
        means_m=[centre],
        scales_m=[[0.3, 0.3, 0.0]],
        rotations_wxyz=rotation,
        colors_rgb=[[1, 1, 1]],
        opacities=[1.0],
    )
    index, depth = render_label_index(g, K, np.eye(4), N_SIDE, N_SIDE, depth_mode="surface")
    _, centre_depth = render_label_index(g, K, np.eye(4), N_SIDE, N_SIDE)
    hit = index == 0
    assert hit.sum() > 50
    np.testing.assert_array_equal(centre_depth[hit], np.float32(2.0))
    # plane through the centre with normal R e_z: depth of pixel ray d (d_z = 1) is (n . c) / (n . d)
    normal = np.array([0.0, -np.sin(angle), np.cos(angle)])
    r, c = np.mgrid[0:N_SIDE, 0:N_SIDE]
    rays = np.stack([(c + 0.5 - K[0, 2]) / K[0, 0], (r + 0.5 - K[1, 2]) / K[1, 1], np.ones(r.shape)], -1)
    expected = (normal @ centre) / (rays @ normal)
    np.testing.assert_allclose(depth[hit], expected[hit], rtol=2e-5)
    assert np.ptp(depth[hit]) > 0.2  # the tilt is visible in the depth map
    index_t, depth_t = render_label_index_torch(g, K, np.eye(4), N_SIDE, N_SIDE, depth_mode="surface")
    np.testing.assert_array_equal(index, index_t)
    np.testing.assert_allclose(depth, depth_t, rtol=2e-5)


def test_surface_depth_matches_torch_reference_on_random_splats() -> None:
    g, K, w2c, h, w = _random_scene(800, seed=2)
    index, depth = render_label_index(g, K, w2c, h, w, depth_mode="surface")
    index_t, depth_t = render_label_index_torch(g, K, w2c, h, w, depth_mode="surface")
    np.testing.assert_array_equal(index, index_t)
    np.testing.assert_allclose(depth, depth_t, rtol=1e-5, atol=1e-6)
    _, centre = render_label_index(g, K, w2c, h, w)
    hit = index >= 0
    assert np.abs(depth[hit] - centre[hit]).max() > 1e-3  # the modes differ
    with pytest.raises(ValueError, match=r"depth_mode must be one of \('center', 'surface'\), got 'mid'"):
        render_label_index(g, K, w2c, h, w, depth_mode="mid")
