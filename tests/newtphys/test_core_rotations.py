"""Rotations: hand-computed rotations, batched round trips, the w >= 0 convention, products, best fits."""

from __future__ import annotations

import numpy as np
import pytest

from newtphys.rotations import (
    axis_angle_to_quat,
    best_fit_rotation,
    matrix_to_quat,
    quat_multiply,
    quat_to_matrix,
    rotation_between,
)

S = np.sqrt(0.5)
# 90 degrees about x, y and z: quaternion by hand (cos 45, sin 45 * axis) and the matrix whose columns are
# the images of the basis vectors (about x: y -> z, z -> -y; about y: z -> x, x -> -z; about z: x -> y, y -> -x).
QUARTER_TURNS = {
    "x": ((S, S, 0.0, 0.0), [[1, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "y": ((S, 0.0, S, 0.0), [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
    "z": ((S, 0.0, 0.0, S), [[0, -1, 0], [1, 0, 0], [0, 0, 1]]),
}


def random_unit_quats(n: int, seed: int) -> np.ndarray:
    q = np.random.default_rng(seed).normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


@pytest.mark.parametrize("axis", ["x", "y", "z"])
def test_quarter_turns_by_hand(axis: str) -> None:
    quat, matrix = QUARTER_TURNS[axis]
    e = np.eye(3)["xyz".index(axis)]
    np.testing.assert_allclose(quat_to_matrix(quat), matrix, atol=1e-15)
    np.testing.assert_allclose(matrix_to_quat(matrix), quat, atol=1e-15)
    np.testing.assert_allclose(axis_angle_to_quat(e, np.pi / 2), quat, atol=1e-15)
    np.testing.assert_allclose(axis_angle_to_quat(3.0 * e, np.pi / 2), quat, atol=1e-15)  # axis length is free
    # the smallest rotation taking the next axis to the one after it is this quarter turn, exactly
    i = "xyz".index(axis)
    r = rotation_between(np.eye(3)[(i + 1) % 3], np.eye(3)[(i + 2) % 3])
    assert r.tobytes() == np.asarray(matrix, np.float64).tobytes()


def test_half_turns_and_identity_by_hand() -> None:
    np.testing.assert_array_equal(quat_to_matrix([1.0, 0.0, 0.0, 0.0]), np.eye(3))
    np.testing.assert_array_equal(matrix_to_quat(np.eye(3)), [1.0, 0.0, 0.0, 0.0])
    for i in range(3):  # 180 degrees about axis i: diag with +1 on i, -1 elsewhere; w = 0
        m = -np.eye(3)
        m[i, i] = 1.0
        q = np.zeros(4)
        q[1 + i] = 1.0
        np.testing.assert_array_equal(matrix_to_quat(m), q)
        np.testing.assert_allclose(quat_to_matrix(q), m, atol=1e-15)
    # opposite directions: 180 degrees about the axis least aligned with the start
    np.testing.assert_array_equal(rotation_between((0, 0, -1), (0, 0, 1)), np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_array_equal(rotation_between((0, 0, 1), (0, 0, 2)), np.eye(3))


def test_batched_round_trips_on_random_rotations() -> None:
    q = random_unit_quats(2000, seed=1).reshape(40, 50, 4)
    m = quat_to_matrix(q)
    assert m.shape == (40, 50, 3, 3)
    np.testing.assert_allclose(m @ np.swapaxes(m, -1, -2), np.broadcast_to(np.eye(3), m.shape), atol=1e-14)
    np.testing.assert_allclose(np.linalg.det(m), 1.0, atol=1e-14)
    np.testing.assert_allclose(matrix_to_quat(m), q, atol=1e-14)
    # non-unit input is normalised first
    np.testing.assert_allclose(quat_to_matrix(7.5 * q), m, atol=1e-14)
    # near 180 degrees (w ~ 0) Shepperd's pivot keeps full precision
    near_half = np.concatenate([np.full((200, 1), 1e-9), random_unit_quats(200, seed=2)[:, 1:]], axis=1)
    near_half /= np.linalg.norm(near_half, axis=1, keepdims=True)
    np.testing.assert_allclose(matrix_to_quat(quat_to_matrix(near_half)), near_half, atol=1e-14)


def test_w_is_never_negative() -> None:
    q = random_unit_quats(1000, seed=3)
    flipped = -q  # every w < 0: the same rotations
    back = matrix_to_quat(quat_to_matrix(flipped))
    assert np.all(back[:, 0] >= 0.0)
    np.testing.assert_allclose(back, q, atol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(back, axis=1), 1.0, atol=1e-15)


def test_axis_angle_matches_rodrigues_and_batches() -> None:
    rng = np.random.default_rng(4)
    axes = rng.normal(size=(300, 3))
    angles = rng.uniform(-np.pi, np.pi, 300)
    m = quat_to_matrix(axis_angle_to_quat(axes, angles))
    u = axes / np.linalg.norm(axes, axis=1, keepdims=True)
    k = np.zeros((300, 3, 3))
    k[:, 0, 1], k[:, 0, 2], k[:, 1, 2] = -u[:, 2], u[:, 1], -u[:, 0]
    k -= np.swapaxes(k, 1, 2)
    rodrigues = np.eye(3) + np.sin(angles)[:, None, None] * k + (1 - np.cos(angles))[:, None, None] * (k @ k)
    np.testing.assert_allclose(m, rodrigues, atol=1e-14)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", m, u), u, atol=1e-14)  # the axis is fixed


def test_quat_multiply_composes_rotations() -> None:
    a, b = random_unit_quats(500, seed=5), random_unit_quats(500, seed=6)
    product = quat_to_matrix(quat_multiply(a, b))
    np.testing.assert_allclose(product, quat_to_matrix(a) @ quat_to_matrix(b), atol=1e-14)
    # by hand: a quarter turn about z twice is a half turn about z
    qz = QUARTER_TURNS["z"][0]
    np.testing.assert_allclose(quat_multiply(qz, qz), [0.0, 0.0, 0.0, 1.0], atol=1e-15)
    # broadcast: one quaternion times a batch
    np.testing.assert_allclose(quat_multiply(qz, b), quat_multiply(np.broadcast_to(qz, b.shape), b), atol=0)


def test_rotation_between_takes_one_direction_to_the_other() -> None:
    rng = np.random.default_rng(7)
    a, b = rng.normal(size=(500, 3)), rng.normal(size=(500, 3))
    b[:3] = -a[:3] * 2.0  # opposite directions
    b[3:6] = a[3:6] * 0.5  # equal directions
    r = rotation_between(a, b)
    ua = a / np.linalg.norm(a, axis=1, keepdims=True)
    ub = b / np.linalg.norm(b, axis=1, keepdims=True)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", r, ua), ub, atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(r), 1.0, atol=1e-13)
    np.testing.assert_allclose(r[3:6], np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-15)
    # smallest: the rotation axis is perpendicular to both directions (angle = the angle between them)
    angle = np.arccos(np.clip((np.trace(r, axis1=1, axis2=2) - 1) / 2, -1, 1))
    np.testing.assert_allclose(angle, np.arccos(np.clip(np.einsum("ni,ni->n", ua, ub), -1, 1)), atol=1e-7)


def test_best_fit_rotation_recovers_a_known_rotation_from_noisy_points() -> None:
    rng = np.random.default_rng(8)
    q = np.array([0.7, -0.2, 0.4, 0.1])
    rot = quat_to_matrix(q)
    rest = rng.uniform(-0.5, 0.5, (400, 3))  # m
    masses = rng.uniform(0.5, 1.5, 400)
    moved = rest @ rot.T + [3.0, -1.0, 2.0]
    np.testing.assert_allclose(best_fit_rotation(rest, moved, masses), rot, atol=1e-13)  # exact points
    noisy = moved + rng.normal(scale=1e-3, size=moved.shape)  # 1 mm noise on a 1 m cloud
    fit = best_fit_rotation(rest, noisy, masses)
    np.testing.assert_allclose(fit @ fit.T, np.eye(3), atol=1e-13)
    assert np.linalg.det(fit) == pytest.approx(1.0, abs=1e-13)
    angle_err = np.arccos(np.clip((np.trace(fit.T @ rot) - 1) / 2, -1, 1))
    assert angle_err < 5e-4  # rad; ~ noise / (extent sqrt(n)) = 1e-3 / (0.3 x 20)
    np.testing.assert_allclose(matrix_to_quat(fit), q / np.linalg.norm(q), atol=5e-4)
    # batched, uniform weights; a mirrored cloud still gives a proper rotation
    batch = best_fit_rotation(np.stack([rest, rest]), np.stack([moved, rest * [-1, 1, 1]]))
    np.testing.assert_allclose(batch[0], rot, atol=1e-13)
    np.testing.assert_allclose(np.linalg.det(batch[1]), 1.0, atol=1e-13)


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: quat_to_matrix([0.0, 0.0, 0.0, 0.0]), r"non-zero norm, got \[0.0, 0.0, 0.0, 0.0\] \(row 0\)"),
        (lambda: quat_to_matrix([[1.0, 0, 0, 0], [np.nan, 0, 0, 1]]), r"got \[nan, 0.0, 0.0, 1.0\] \(row 1\)"),
        (lambda: quat_to_matrix([1.0, 0.0, 0.0]), r"shape \(\.\.\., 4\), got \(3,\)"),
        (lambda: matrix_to_quat(np.eye(4)), r"shape \(\.\.\., 3, 3\), got \(4, 4\)"),
        (lambda: axis_angle_to_quat((0.0, 0.0, 0.0), 1.0), r"rotation axis must be finite with a non-zero norm"),
        (lambda: rotation_between((1.0, 0.0, 0.0), (0.0, 0.0, 0.0)), r"to_dir must be finite"),
        (lambda: best_fit_rotation(np.zeros((4, 3)), np.zeros((5, 3))), r"got \(4, 3\) and \(5, 3\)"),
        (lambda: best_fit_rotation(np.zeros((4, 3)), np.zeros((4, 3)), -np.ones(4)), r"weights must"),
    ],
)
def test_bad_input_is_named(call, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        call()
