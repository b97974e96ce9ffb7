"""Camera trajectories: target stays in view every frame, static is constant, kinematics of each kind."""

import numpy as np
import pytest

from data_gen.cameras import (
    CAMERA_KINDS,
    PAN_FOV_FRACTION,
    CameraPathSpec,
    camera_path,
    path_from_spec,
    sample_camera_spec,
)
from newtphys.geometry import camera_pose, intrinsics_from_fov, project, transform_points

H, W, FOV = 240, 320, 60.0
TARGET = np.array([0.2, -0.1, 0.3])


def target_pixels(w2c: np.ndarray, target=TARGET) -> tuple[np.ndarray, np.ndarray]:
    k = intrinsics_from_fov(FOV, H, W)
    cam = np.stack([transform_points(m, target) for m in w2c])
    uv, z = project(cam, k)
    return uv, z


@pytest.mark.parametrize("kind", CAMERA_KINDS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_target_projected_inside_image_every_frame(kind, seed):
    w2c = camera_path(kind, 250, 25.0, TARGET, 2.0, 1.2, np.random.default_rng(seed), fov_x_deg=FOV)
    assert w2c.shape == (250, 4, 4)
    uv, z = target_pixels(w2c)
    assert np.all(z > 0)
    assert np.all((uv[:, 0] >= 0) & (uv[:, 0] < W) & (uv[:, 1] >= 0) & (uv[:, 1] < H))
    rot = w2c[:, :3, :3]
    np.testing.assert_allclose(
        rot @ np.swapaxes(rot, 1, 2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-12)


def test_static_is_constant_and_centred():
    w2c = camera_path("static", 50, 25.0, TARGET, 2.0, 1.0, np.random.default_rng(0))
    np.testing.assert_array_equal(w2c, np.broadcast_to(w2c[0], w2c.shape))
    uv, _ = target_pixels(w2c)
    np.testing.assert_allclose(uv, np.tile([W / 2, H / 2], (50, 1)), atol=1e-9)
    centre, _ = camera_pose(w2c[0])
    assert np.hypot(*(centre - TARGET)[:2]) == pytest.approx(2.0) and centre[2] - TARGET[2] == pytest.approx(
        1.0
    )


def test_orbit_keeps_radius_height_and_rate():
    spec = sample_camera_spec("orbit", TARGET, 2.0, 1.0, np.random.default_rng(3), orbit_speed_rad_s=0.5)
    w2c = path_from_spec(spec, 100, 25.0)
    centre, _ = camera_pose(w2c)
    rel = centre - TARGET
    np.testing.assert_allclose(np.hypot(rel[:, 0], rel[:, 1]), 2.0, atol=1e-9)
    np.testing.assert_allclose(rel[:, 2], 1.0, atol=1e-9)
    step = np.diff(np.unwrap(np.arctan2(rel[:, 1], rel[:, 0])))
    np.testing.assert_allclose(step, spec.orbit_rate_rad_s / 25.0, atol=1e-9)
    assert abs(spec.orbit_rate_rad_s) == 0.5


def test_dolly_is_linear_along_a_ray():
    w2c = camera_path("dolly", 51, 25.0, TARGET, 2.0, 1.0, np.random.default_rng(4), dolly_end_ratio=0.5)
    centre, _ = camera_pose(w2c)
    rel = centre - TARGET
    dist = np.linalg.norm(rel, axis=1)
    np.testing.assert_allclose(dist, np.linspace(np.hypot(2.0, 1.0), 0.5 * np.hypot(2.0, 1.0), 51), atol=1e-9)
    direction = rel / dist[:, None]
    np.testing.assert_allclose(direction, np.broadcast_to(direction[0], direction.shape), atol=1e-9)


def test_handheld_is_small_and_smooth():
    spec = sample_camera_spec("handheld", TARGET, 2.0, 1.0, np.random.default_rng(5), jitter_m=0.02)
    w2c = path_from_spec(spec, 250, 25.0)
    centre, _ = camera_pose(w2c)
    base = TARGET + [2.0 * np.cos(spec.azimuth_rad), 2.0 * np.sin(spec.azimuth_rad), 1.0]
    offset = np.linalg.norm(centre - base, axis=1)
    assert offset.max() <= 0.02 * np.sqrt(3) + 1e-12 and offset.max() > 0.002
    # sinusoids of at most 1.5 Hz and amplitude <= 2 cm: per-frame motion <= 2 pi 1.5 x 0.02 / 25 per axis
    per_frame = np.abs(np.diff(centre, axis=0)).max()
    assert per_frame <= 2 * np.pi * 1.5 * 0.02 / 25.0 + 1e-12


def test_pan_yaws_within_the_allowed_angle():
    spec = sample_camera_spec(
        "pan", TARGET, 2.0, 0.0, np.random.default_rng(6), fov_x_deg=FOV, pan_period_s=4.0
    )
    assert spec.pan_half_angle_rad == pytest.approx(PAN_FOV_FRACTION * np.deg2rad(FOV) / 2)
    w2c = path_from_spec(spec, 101, 25.0)  # one full 4 s period
    centre, _ = camera_pose(w2c)
    np.testing.assert_allclose(centre, np.broadcast_to(centre[0], centre.shape), atol=1e-12)
    uv, _ = target_pixels(w2c)
    f = intrinsics_from_fov(FOV, H, W)[0, 0]
    # camera level with the target: horizontal angle to the target equals the yaw
    yaw = np.arctan((uv[:, 0] - W / 2) / f)
    assert np.abs(yaw).max() == pytest.approx(spec.pan_half_angle_rad, rel=1e-3)


def test_determinism_and_bad_input():
    a = camera_path("handheld", 30, 25.0, TARGET, 2.0, 1.0, np.random.default_rng(9))
    b = camera_path("handheld", 30, 25.0, TARGET, 2.0, 1.0, np.random.default_rng(9))
    np.testing.assert_array_equal(a, b)
    with pytest.raises(ValueError, match="orbit"):
        camera_path("crane", 10, 25.0, TARGET, 2.0, 1.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="num_frames"):
        camera_path("static", 0, 25.0, TARGET, 2.0, 1.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="radius_m"):
        camera_path("static", 5, 25.0, TARGET, 0.0, 1.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match="pan_half_angle_rad"):
        CameraPathSpec("pan", tuple(TARGET), 2.0, 1.0, pan_half_angle_rad=1.0, fov_x_deg=60.0)
    with pytest.raises(ValueError, match="jitter_m"):
        sample_camera_spec("handheld", TARGET, 2.0, 1.0, np.random.default_rng(0), jitter_m=1.0)
    spec = sample_camera_spec("orbit", TARGET, 2.0, 1.0, np.random.default_rng(0))
    assert spec.to_dict()["kind"] == "orbit"
