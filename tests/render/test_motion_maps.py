"""The per-pixel motion maps kernel: scene flow and optical flow against the contract's numpy formulas, hand-computed
flows of a moving camera and a moving splat, thread counts, bad input."""

import numpy as np
import pytest

from data_gen.render.labels import gather_labels
from data_gen.render.motion_maps import motion_maps
from newtphys import geometry
from newtphys.consistency import optical_flow_from_scene_flow
from newtphys.rotations import quat_to_matrix


def _pose(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=4)
    m = np.eye(4)
    m[:3, :3] = quat_to_matrix(q / np.linalg.norm(q))
    m[:3, 3] = rng.normal(size=3)
    return m


def _random_frame(h: int = 60, w: int = 80, n: int = 2000, seed: int = 0):
    rng = np.random.default_rng(seed)
    index = rng.integers(0, n, (h, w)).astype(np.int32)
    index[rng.uniform(size=(h, w)) < 0.15] = -1  # pixels no splat covers
    depth = rng.uniform(0.5, 5.0, (h, w)).astype(np.float32)
    depth[rng.uniform(size=(h, w)) < 0.1] = 0.0
    x0 = rng.normal(size=(n, 3))
    x1 = x0 + 0.2 * rng.normal(size=(n, 3))
    K = np.array([[75.0, 0.3, 40.0], [0.0, 70.0, 30.0], [0.0, 0.0, 1.0]])
    return index, depth, x0, x1, K, _pose(1), _pose(2)


def test_motion_maps_are_the_contracts_formulas() -> None:
    """Scene flow = the winner's displacement rotated into frame t's camera (0 where no winner); optical flow =
    newtphys.consistency.optical_flow_from_scene_flow of the stored float32 scene flow (the validator's check),
    0 where the depth is 0 and where the moved point is behind the next camera."""
    index, depth, x0, x1, K, w2c, w2c_next = _random_frame()
    scene_flow, flow = motion_maps(index, depth, x0, x1, K, w2c, w2c_next)
    assert scene_flow.dtype == np.float32 and scene_flow.shape == (60, 80, 3)
    assert flow.dtype == np.float32 and flow.shape == (60, 80, 2)
    want_scene = geometry.rotate_vectors(w2c, gather_labels(index, x1 - x0)).astype(np.float32)
    np.testing.assert_allclose(scene_flow, want_scene, rtol=1e-6, atol=1e-9)
    assert not scene_flow[index < 0].any() and (index < 0).sum() > 10
    implied = optical_flow_from_scene_flow(depth.astype(np.float64), scene_flow.astype(np.float64), K, w2c, w2c_next)
    behind = np.isnan(implied[..., 0]) & (depth > 0)
    assert behind.sum() > 10 and (depth == 0).sum() > 10  # both cases occur in this frame
    implied[depth <= 0] = 0.0
    np.testing.assert_allclose(flow, np.nan_to_num(implied), rtol=1e-6, atol=1e-6)
    assert not flow[behind].any() and not flow[depth == 0].any()


def test_hand_computed_flows_of_a_moving_camera_and_a_moving_splat() -> None:
    """Camera looking down +z from the origin (world = camera frame at t). A static splat at depth 2 m with the
    camera moving 0.1 m along +x: scene flow 0, optical flow -fx x 0.1 / 2 = -20 px in u. A splat moving 0.1 m along
    +y with the camera still: scene flow (0, 0.1, 0) m, optical flow fy x 0.1 / 2 = 20 px in v."""
    K = np.array([[400.0, 0.0, 2.0], [0.0, 400.0, 2.0], [0.0, 0.0, 1.0]])
    index = np.zeros((4, 4), np.int32)
    depth = np.full((4, 4), 2.0, np.float32)
    x0 = np.array([[0.0, 0.0, 2.0]])
    still = np.eye(4)
    moved_camera = np.eye(4)
    moved_camera[0, 3] = -0.1  # world to camera: the camera centre at x = +0.1 m
    scene_flow, flow = motion_maps(index, depth, x0, x0, K, still, moved_camera)
    assert not scene_flow.any()
    np.testing.assert_allclose(flow[..., 0], -20.0, atol=1e-4)
    np.testing.assert_allclose(flow[..., 1], 0.0, atol=1e-4)
    scene_flow, flow = motion_maps(index, depth, x0, x0 + [0.0, 0.1, 0.0], K, still, still)
    np.testing.assert_allclose(scene_flow, np.broadcast_to([0.0, 0.1, 0.0], (4, 4, 3)), atol=1e-7)
    np.testing.assert_allclose(flow[..., 0], 0.0, atol=1e-4)
    np.testing.assert_allclose(flow[..., 1], 20.0, atol=1e-4)


def test_still_points_under_a_still_camera_have_exactly_zero_flow() -> None:
    """A pixel whose splat did not move, seen by a camera that did not move, has optical flow exactly 0 (not the
    ~1e-13 px round-off of projecting its ray back to the pixel centre, which no compressor can shrink); the
    splats that moved keep their flow."""
    index, depth, x0, _, K, w2c, _ = _random_frame(seed=5)
    x1 = x0.copy()
    moving = np.arange(len(x0)) % 10 == 0
    x1[moving] += [0.05, -0.02, 0.01]
    scene_flow, flow = motion_maps(index, depth, x0, x1, K, w2c, w2c)
    still = (index >= 0) & ~moving[np.maximum(index, 0)]
    assert still.sum() > 1000 and not flow[still].any() and not scene_flow[still].any()
    moved = (index >= 0) & moving[np.maximum(index, 0)] & (depth > 0)
    assert moved.sum() > 100 and (np.abs(flow[moved]).max(axis=-1) > 1e-3).all()
    implied = optical_flow_from_scene_flow(depth.astype(np.float64), scene_flow.astype(np.float64), K, w2c, w2c)
    assert np.abs(implied[still & (depth > 0)]).max() > 0.0  # the formula's round-off, which the kernel avoids
    np.testing.assert_allclose(flow[moved], implied[moved], rtol=1e-6, atol=1e-6)


def test_motion_maps_are_the_same_bytes_on_any_thread_count() -> None:
    frame = _random_frame(seed=3)
    first = motion_maps(*frame, num_threads=1)
    for threads in (2, 3, 7):
        for a, b in zip(first, motion_maps(*frame, num_threads=threads)):
            assert a.tobytes() == b.tobytes()


def test_motion_maps_fill_given_arrays_in_place() -> None:
    """``out``: the caller's arrays (e.g. a sequence's map slices) hold the same bytes the returned ones would."""
    frame = _random_frame(seed=4)
    want = motion_maps(*frame, num_threads=2)
    maps3, maps2 = np.full((2, 60, 80, 3), np.nan, np.float32), np.full((2, 60, 80, 2), np.nan, np.float32)
    got = motion_maps(*frame, num_threads=2, out=(maps3[1], maps2[1]))
    assert got[0] is maps3[1] or np.shares_memory(got[0], maps3)
    assert maps3[1].tobytes() == want[0].tobytes() and maps2[1].tobytes() == want[1].tobytes()
    assert np.isnan(maps3[0]).all() and np.isnan(maps2[0]).all()  # nothing written past the slices
    with pytest.raises(ValueError, match=r"out arrays must be C-contiguous float32 \(60, 80, 2\)"):
        motion_maps(*frame, out=(maps3[1], maps2[1].astype(np.float64)))


def test_motion_maps_refuse_mismatched_input() -> None:
    index, depth, x0, x1, K, w2c, w2c_next = _random_frame()
    with pytest.raises(ValueError, match=r"depth_m must have the label index's shape \(60, 80\)"):
        motion_maps(index, depth[:10], x0, x1, K, w2c, w2c_next)
    with pytest.raises(ValueError, match=r"centres \(N, 3\) at both frames"):
        motion_maps(index, depth, x0, x1[:5], K, w2c, w2c_next)
    with pytest.raises(ValueError, match=r"label index 19\d\d out of range for 100 splats"):
        motion_maps(index, depth, x0[:100], x1[:100], K, w2c, w2c_next)
