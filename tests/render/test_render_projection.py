"""EWA projection: hand-computed J Sigma J^T, culling, warp vs torch reference, device rotations."""

from __future__ import annotations

import numpy as np
import pytest
import warp as wp

from data_gen.gaussians import Gaussians
from data_gen.render.projection import (
    DEFAULT_DILATION_PX2,
    _rotation_wxyz,
    project_gaussians,
    project_gaussians_torch,
)
from newtphys.geometry import intrinsics_from_fov, look_at, project, transform_points
from newtphys.rotations import quat_to_matrix

H, W = 48, 64


def _camera() -> tuple[np.ndarray, np.ndarray]:
    return intrinsics_from_fov(70.0, H, W), look_at((2.0, -3.0, 1.5), (0.0, 0.0, 0.5))


def _cov2d_from_conic(conic: np.ndarray) -> np.ndarray:
    a, b, c = conic[..., 0], conic[..., 1], conic[..., 2]
    return np.linalg.inv(np.stack([np.stack([a, b], -1), np.stack([b, c], -1)], -2).astype(np.float64))


def test_projected_covariance_equals_hand_computed_jacobian_product() -> None:
    K, w2c = _camera()
    sigma = np.array([[0.04, 0.01, -0.005], [0.01, 0.02, 0.003], [-0.005, 0.003, 0.01]])
    mean = np.array([[0.2, 0.1, 0.6]])
    g = Gaussians(means_m=mean, covariances_m2=sigma[None], colors_rgb=[[1, 1, 1]], opacities=[0.7])
    out = project_gaussians(g, K, w2c, H, W)
    assert out["visible"][0]

    # hand computation: camera point, Jacobian of (fx x/z + cx, fy y/z + cy), J R Sigma R^T J^T + 0.3 I
    p = transform_points(w2c, mean)[0]
    x, y, z = p
    fx, fy = K[0, 0], K[1, 1]
    jac = np.array([[fx / z, 0.0, -fx * x / z**2], [0.0, fy / z, -fy * y / z**2]])
    rot = w2c[:3, :3]
    expected = jac @ rot @ sigma @ rot.T @ jac.T + 0.3 * np.eye(2)
    assert DEFAULT_DILATION_PX2 == 0.3
    np.testing.assert_allclose(_cov2d_from_conic(out["conic"][0]), expected, rtol=2e-5)
    uv, depth = project(p, K)
    np.testing.assert_allclose(out["mean_px"][0], uv, atol=1e-4)
    np.testing.assert_allclose(out["depth_m"][0], depth, rtol=1e-6)
    # radius = sqrt(q_cut * largest eigenvalue), q_cut = 2 ln(255 * 0.7)
    q_cut = 2 * np.log(255 * 0.7)
    np.testing.assert_allclose(out["q_cut"][0], q_cut, rtol=1e-6)
    np.testing.assert_allclose(
        out["radius_px"][0], np.sqrt(q_cut * np.linalg.eigvalsh(expected)[-1]), rtol=1e-5
    )
    # bounding box: pixel centres within the ellipse's axis-aligned extent sqrt(q_cut * Sigma2_ii)
    hx, hy = np.sqrt(q_cut * expected[0, 0]), np.sqrt(q_cut * expected[1, 1])
    box = [
        np.ceil(uv[0] - hx - 0.5),
        np.ceil(uv[1] - hy - 0.5),
        np.floor(uv[0] + hx - 0.5),
        np.floor(uv[1] + hy - 0.5),
    ]
    box = np.clip(box, 0, [W - 1, H - 1, W - 1, H - 1])
    np.testing.assert_array_equal(out["bbox"][0], box)


def test_scale_rotation_input_matches_covariance_input() -> None:
    K, w2c = _camera()
    rng = np.random.default_rng(0)
    n = 50
    g = Gaussians(
        means_m=rng.uniform(-0.5, 0.5, (n, 3)),
        scales_m=rng.uniform(0.01, 0.1, (n, 3)),
        rotations_wxyz=rng.normal(size=(n, 4)),
        colors_rgb=rng.uniform(0, 1, (n, 3)),
        opacities=rng.uniform(0.1, 1, n),
    )
    g_cov = Gaussians(
        means_m=g.means_m, covariances_m2=g.covariances(), colors_rgb=g.colors_rgb, opacities=g.opacities
    )
    a = project_gaussians(g, K, w2c, H, W)
    b = project_gaussians(g_cov, K, w2c, H, W)
    np.testing.assert_array_equal(a["visible"], b["visible"])
    np.testing.assert_allclose(a["conic"], b["conic"], rtol=1e-4, atol=1e-6)


def test_warp_projection_matches_torch_reference() -> None:
    K, w2c = _camera()
    rng = np.random.default_rng(1)
    n = 400
    g = Gaussians(
        means_m=rng.uniform(-1.5, 1.5, (n, 3)),
        scales_m=rng.uniform(0.005, 0.1, (n, 3)),
        rotations_wxyz=rng.normal(size=(n, 4)),
        colors_rgb=rng.uniform(0, 1, (n, 3)),
        opacities=rng.uniform(0, 1, n),
    )
    a = project_gaussians(g, K, w2c, H, W)
    b = {k: v.numpy() for k, v in project_gaussians_torch(g, K, w2c, H, W).items()}
    np.testing.assert_array_equal(a["visible"], b["visible"])
    v = a["visible"]
    assert 100 < v.sum() < n  # some visible, some culled (off-screen or opacity < 1/255)
    np.testing.assert_array_equal(a["bbox"], b["bbox"])
    np.testing.assert_allclose(a["mean_px"][v], b["mean_px"][v], atol=1e-4)
    np.testing.assert_allclose(a["conic"][v], b["conic"][v], rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(a["depth_m"][v], b["depth_m"][v], rtol=1e-6)
    np.testing.assert_allclose(a["radius_px"][v], b["radius_px"][v], rtol=1e-5)


def test_culling_near_plane_behind_and_off_screen() -> None:
    K = intrinsics_from_fov(60.0, H, W)
    w2c = np.eye(4)  # camera at the origin looking along +z
    means = [
        [0.0, 0.0, 2.0],  # visible
        [0.0, 0.0, -1.0],  # behind the camera
        [0.0, 0.0, 0.005],  # in front but closer than near_m = 0.01
        [50.0, 0.0, 2.0],  # far off-screen to the right
        [0.0, 0.0, 3.0],  # visible but opacity 0.001 < 1/255
    ]
    g = Gaussians(
        means_m=means,
        scales_m=np.full((5, 3), 0.01),
        colors_rgb=np.ones((5, 3)),
        opacities=[1, 1, 1, 1, 0.001],
    )
    out = project_gaussians(g, K, w2c, H, W, near_m=0.01)
    np.testing.assert_array_equal(out["visible"], [True, False, False, False, False])
    np.testing.assert_array_equal(out["radius_px"][1:], 0.0)
    np.testing.assert_array_equal(out["bbox"][1:], [[0, 0, -1, -1]] * 4)
    assert np.all(out["depth_m"][1:] > 1e38)
    # a near plane beyond the Gaussian culls it too
    assert not project_gaussians(g, K, w2c, H, W, near_m=2.5)["visible"][0]


def test_deformation_doubles_projected_variance_along_x() -> None:
    K = intrinsics_from_fov(60.0, H, W)
    g = Gaussians(means_m=[[0.0, 0.0, 2.0]], scales_m=[[0.05] * 3], colors_rgb=[[1, 1, 1]], opacities=[1.0])
    d = g.deformed(np.diag([2.0, 1.0, 1.0])[None])
    c0 = _cov2d_from_conic(project_gaussians(g, K, np.eye(4), H, W, dilation_px2=0.0)["conic"][0])
    c1 = _cov2d_from_conic(project_gaussians(d, K, np.eye(4), H, W, dilation_px2=0.0)["conic"][0])
    np.testing.assert_allclose(c1[0, 0] / c0[0, 0], 4.0, rtol=1e-5)  # std dev x2 along image x
    np.testing.assert_allclose(c1[1, 1] / c0[1, 1], 1.0, rtol=1e-5)
    np.testing.assert_allclose(c0[0, 0], (K[0, 0] * 0.05 / 2.0) ** 2, rtol=1e-5)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        (dict(K=np.diag([0.0, 50.0, 1.0])), r"focal lengths must be > 0 px, got fx=0.0"),
        (dict(K=np.array([[50.0, 1.0, 32], [0, 50, 24], [0, 0, 1]])), r"no skew"),
        (dict(K=np.eye(2)), r"K must be a finite \(3, 3\) matrix"),
        (dict(world_to_camera=np.diag([2.0, 1.0, 1.0, 1.0])), r"must be a rotation"),
        (dict(world_to_camera=np.diag([-1.0, 1.0, 1.0, 1.0])), r"must be a rotation"),
        (dict(near_m=0.0), r"near_m must be a finite distance > 0 m, got 0.0"),
        (dict(dilation_px2=-1.0), r"dilation_px2 must be >= 0 px\^2, got -1.0"),
        (dict(height=0), r"image size must be >= 1 px"),
    ],
)
def test_bad_camera_input(kwargs: dict[str, object], message: str) -> None:
    g = Gaussians(means_m=[[0.0, 0.0, 2.0]], scales_m=[[0.05] * 3], colors_rgb=[[1, 1, 1]], opacities=[1.0])
    args: dict[str, object] = dict(
        K=intrinsics_from_fov(60.0, H, W), world_to_camera=np.eye(4), height=H, width=W
    )
    args.update(kwargs)
    with pytest.raises(ValueError, match=message):
        project_gaussians(g, **args)  # type: ignore[arg-type]


def test_threaded_projection_is_identical() -> None:
    from data_gen.render.projection import Camera, ProjectedSplats

    K, w2c = _camera()
    rng = np.random.default_rng(9)
    n = 1001
    g = Gaussians(
        means_m=rng.uniform(-1.5, 1.5, (n, 3)),
        scales_m=rng.uniform(0.005, 0.1, (n, 3)),
        rotations_wxyz=rng.normal(size=(n, 4)),
        colors_rgb=rng.uniform(0, 1, (n, 3)),
        opacities=rng.uniform(0, 1, n),
    )
    cam = Camera.from_matrices(K, w2c, H, W)
    one, three = ProjectedSplats("cpu", 1), ProjectedSplats("cpu", 3)
    assert one.project(g, cam, 0.5) == three.project(g, cam, 0.5) > 0
    for key, value in one.to_numpy().items():
        assert value.tobytes() == three.to_numpy()[key].tobytes(), key


@wp.kernel
def _rotations_kernel(quats: wp.array(dtype=wp.vec4), out: wp.array(dtype=wp.mat33)):
    i = wp.tid()
    out[i] = _rotation_wxyz(quats[i])


def test_device_quaternion_rotation_agrees_with_the_rotations_module() -> None:
    q = np.random.default_rng(3).normal(size=(300, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q[:3] = [[np.sqrt(0.5), np.sqrt(0.5), 0, 0], [np.sqrt(0.5), 0, np.sqrt(0.5), 0], [np.sqrt(0.5), 0, 0, np.sqrt(0.5)]]
    wp.init()
    out = wp.zeros(len(q), dtype=wp.mat33, device="cpu")
    wp.launch(_rotations_kernel, dim=len(q), inputs=[wp.array(q.astype(np.float32), dtype=wp.vec4, device="cpu"), out])
    np.testing.assert_allclose(out.numpy(), quat_to_matrix(q), atol=1e-6)  # float32 on the device
    np.testing.assert_allclose(out.numpy()[2], [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-6)  # 90 deg about z


def test_run_in_threads_keeps_its_threads_calls_each_index_once_and_runs_nested_calls_inline() -> None:
    """The render's parallel sections share kept pools (no thread started per section): two calls with the same
    worker count run on the same threads; every index is called exactly once; a call made from a pool thread runs
    in order on that thread (a pool never waits on itself); one worker runs in order on the caller's thread."""
    import threading

    from data_gen.render.projection import run_in_threads

    barrier = threading.Barrier(3, timeout=10)  # three calls at once: three distinct pool threads

    def collect(into: list):
        def fn(i: int) -> None:
            barrier.wait()
            into.append((i, threading.get_ident()))
        return fn

    first: list = []
    second: list = []
    run_in_threads(collect(first), 3)
    run_in_threads(collect(second), 3)
    assert sorted(i for i, _ in first) == [0, 1, 2] and sorted(i for i, _ in second) == [0, 1, 2]
    assert len({t for _, t in first}) == 3 and {t for _, t in first} == {t for _, t in second}
    assert threading.get_ident() not in {t for _, t in first}

    nested: list = []

    def outer(i: int) -> None:
        run_in_threads(lambda j: nested.append((i, j, threading.get_ident())), 2)

    run_in_threads(outer, 2)
    assert sorted((i, j) for i, j, _ in nested) == [(0, 0), (0, 1), (1, 0), (1, 1)]
    for i in (0, 1):  # each outer call's inner calls ran in order on its own thread
        inner = [(j, t) for k, j, t in nested if k == i]
        assert [j for j, _ in inner] == [0, 1] and len({t for _, t in inner}) == 1
    order: list = []
    run_in_threads(lambda i: order.append((i, threading.get_ident())), 4, workers=1)
    assert order == [(i, threading.get_ident()) for i in range(4)]
