"""Rotations: the one implementation every product uses (NumPy, float64, batched).

Conventions (docs/data_contract.md, "Conventions"): quaternions are (w, x, y, z), Hamilton
product, acting on column vectors (``v' = R v``); a quaternion and its
negative are the same rotation, and converters return the one with w >= 0.
Every function takes leading batch dimensions and validates its input,
naming the offending value.

* ``quat_to_matrix`` / ``matrix_to_quat`` — unit quaternion <-> rotation
  matrix (Shepperd's method: the branch with the largest pivot, so no
  cancellation near 180 degrees); ``matrix_to_quat_one`` gives the same result, bit for bit, for one
  matrix at a fraction of the cost (no batching overhead).
* ``quat_multiply`` — Hamilton product (``R(a b) = R(a) R(b)``).
* ``axis_angle_to_quat`` — rotation by an angle (rad) about an axis.
* ``rotation_between`` — the smallest rotation taking one direction to another.
* ``best_fit_rotation`` — the rotation of the weighted least-squares fit of one
  point set to another (Kabsch: the rotation factor of the polar decomposition
  of the cross-covariance); ``rotation_from_cross_covariance`` is its inner step, for a
  cross-covariance formed elsewhere (from precomputed mass moments, say).

Device code keeps its own copy where it must (``@wp.func`` in
``data_gen.render.projection``); tests check it against this module.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

F64 = NDArray[np.float64]

_ZERO_NORM = 1e-12  # a quaternion or direction shorter than this has no orientation


def _as_vectors(name: str, value: ArrayLike, length: int) -> F64:
    """``value`` as float64 (..., length), finite and of non-zero norm; errors quote the value."""
    v = np.asarray(value, np.float64)
    if v.ndim == 0 or v.shape[-1] != length:
        raise ValueError(f"{name} must have shape (..., {length}), got {v.shape}")
    rows = v.reshape(-1, length)
    bad = ~np.all(np.isfinite(rows), axis=1) | (np.linalg.norm(rows, axis=1) < _ZERO_NORM)
    if np.any(bad):
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"{name} must be finite with a non-zero norm, got {rows[i].tolist()} (row {i})")
    return v


def quat_to_matrix(q: ArrayLike) -> F64:
    """(w, x, y, z) quaternions (..., 4) -> rotation matrices (..., 3, 3); the quaternions are normalised."""
    q = _as_vectors("quaternion (w, x, y, z)", q, 4)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
            np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
            np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
        ],
        -2,
    )


def matrix_to_quat(m: ArrayLike) -> F64:
    """Rotation matrices (..., 3, 3) -> unit (w, x, y, z) quaternions (..., 4) with w >= 0.

    Shepperd's method: of the four pivots 1 + trace and 1 + 2 m_ii - trace,
    the largest gives the component computed by a square root, the other three
    follow from sums and differences of off-diagonal entries.
    """
    m = np.asarray(m, np.float64)
    if m.ndim < 2 or m.shape[-2:] != (3, 3):
        raise ValueError(f"rotation matrices must have shape (..., 3, 3), got {m.shape}")
    if not np.all(np.isfinite(m)):
        i = int(np.flatnonzero(~np.all(np.isfinite(m.reshape(-1, 9)), axis=1))[0])
        raise ValueError(f"rotation matrices must be finite, got {m.reshape(-1, 3, 3)[i].tolist()} (matrix {i})")
    batch = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    pick = np.argmax(np.stack([tr, m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]], axis=1), axis=1)
    q = np.empty((m.shape[0], 4))
    for case in range(4):  # the four pivots, each vectorised over the matrices that pick it
        sel = pick == case
        if not np.any(sel):
            continue
        a = m[sel]
        if case == 0:
            s = np.sqrt(1.0 + tr[sel]) * 2
            q[sel] = np.stack(
                [
                    0.25 * s,
                    (a[:, 2, 1] - a[:, 1, 2]) / s,
                    (a[:, 0, 2] - a[:, 2, 0]) / s,
                    (a[:, 1, 0] - a[:, 0, 1]) / s,
                ],
                1,
            )
            continue
        i = case - 1
        j, k = (i + 1) % 3, (i + 2) % 3
        s = np.sqrt(1.0 + a[:, i, i] - a[:, j, j] - a[:, k, k]) * 2
        comp = np.empty((a.shape[0], 4))
        comp[:, 0] = (a[:, k, j] - a[:, j, k]) / s
        comp[:, 1 + i] = 0.25 * s
        comp[:, 1 + j] = (a[:, j, i] + a[:, i, j]) / s
        comp[:, 1 + k] = (a[:, k, i] + a[:, i, k]) / s
        q[sel] = comp
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(batch + (4,))


def matrix_to_quat_one(m: ArrayLike) -> F64:
    """One rotation matrix (3, 3) -> unit (w, x, y, z) quaternion (4,) with w >= 0.

    The same arithmetic, in the same order, as :func:`matrix_to_quat` (Shepperd's method, the first of
    the largest pivots, sums left to right), so the result equals ``matrix_to_quat(m)`` bit for bit;
    written on Python floats for the many single-matrix calls of a per-frame recorder.
    """
    a = np.asarray(m, np.float64)
    if a.shape != (3, 3):
        raise ValueError(f"rotation matrix must have shape (3, 3), got {a.shape}")
    rows = a.tolist()
    if not all(math.isfinite(v) for row in rows for v in row):
        raise ValueError(f"rotation matrices must be finite, got {rows} (matrix 0)")
    tr = rows[0][0] + rows[1][1] + rows[2][2]
    pivots = [tr, rows[0][0], rows[1][1], rows[2][2]]
    case = pivots.index(max(pivots))
    if case == 0:
        s = math.sqrt(1.0 + tr) * 2
        q = [
            0.25 * s,
            (rows[2][1] - rows[1][2]) / s,
            (rows[0][2] - rows[2][0]) / s,
            (rows[1][0] - rows[0][1]) / s,
        ]
    else:
        i = case - 1
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + rows[i][i] - rows[j][j] - rows[k][k]) * 2
        q = [0.0] * 4
        q[0] = (rows[k][j] - rows[j][k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (rows[j][i] + rows[i][j]) / s
        q[1 + k] = (rows[k][i] + rows[i][k]) / s
    sign = -1.0 if q[0] < 0 else 1.0
    q = [v * sign for v in q]
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return np.array([v / norm for v in q])


def quat_multiply(a: ArrayLike, b: ArrayLike) -> F64:
    """Hamilton product a * b of (w, x, y, z) quaternions (broadcast over leading dims): rotate by b, then a."""
    a = np.asarray(a, np.float64)
    b = np.asarray(b, np.float64)
    if a.shape[-1:] != (4,) or b.shape[-1:] != (4,):
        raise ValueError(f"quaternions must have shape (..., 4), got {a.shape} and {b.shape}")
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def axis_angle_to_quat(axis: ArrayLike, angle_rad: ArrayLike) -> F64:
    """Unit (w, x, y, z) quaternions (..., 4) of rotations by ``angle_rad`` (...) about ``axis`` (..., 3).

    The axis need not be unit length; the angle follows the right-hand rule.
    """
    a = _as_vectors("rotation axis", axis, 3)
    half = 0.5 * np.asarray(angle_rad, np.float64)
    if not np.all(np.isfinite(half)):
        raise ValueError(f"angle_rad must be finite, got {np.asarray(angle_rad).tolist()}")
    a = a / np.linalg.norm(a, axis=-1, keepdims=True) * np.sin(half)[..., None]
    w = np.broadcast_to(np.cos(half), a.shape[:-1])
    return np.concatenate([w[..., None], a], axis=-1)


def _skew(v: F64) -> F64:
    """Cross-product matrices (..., 3, 3): ``_skew(v) @ u = v x u``."""
    x, y, z = np.moveaxis(v, -1, 0)
    zero = np.zeros_like(x)
    return np.stack(
        [np.stack([zero, -z, y], -1), np.stack([z, zero, -x], -1), np.stack([-y, x, zero], -1)], -2
    )


def rotation_between(from_dir: ArrayLike, to_dir: ArrayLike) -> F64:
    """The smallest rotation (..., 3, 3) taking direction ``from_dir`` to ``to_dir`` (neither need be unit).

    Rodrigues' formula R = I + [v]x + [v]x^2 / (1 + c) with v = a x b and c = a . b;
    exact (entries 0 and +-1) for coordinate axes.  Opposite directions turn by
    180 degrees about the coordinate axis least aligned with ``from_dir``
    (projected perpendicular to it).
    """
    a = _as_vectors("from_dir", from_dir, 3)
    b = _as_vectors("to_dir", to_dir, 3)
    a = a / np.linalg.norm(a, axis=-1, keepdims=True)
    b = b / np.linalg.norm(b, axis=-1, keepdims=True)
    a, b = np.broadcast_arrays(a, b)
    c = np.einsum("...i,...i->...", a, b)
    k = _skew(np.cross(a, b))
    opposite = c < -1.0 + 1e-12
    safe = np.where(opposite, 1.0, 1.0 + c)
    r = np.eye(3) + k + (k @ k) / safe[..., None, None]
    if np.any(opposite):
        e = np.eye(3)[np.argmin(np.abs(a), axis=-1)]  # the axis least aligned with from_dir
        p = e - np.einsum("...i,...i->...", e, a)[..., None] * a
        p /= np.linalg.norm(p, axis=-1, keepdims=True)
        half_turn = 2.0 * p[..., :, None] * p[..., None, :] - np.eye(3)
        r = np.where(opposite[..., None, None], half_turn, r)
    return r + 0.0  # + 0.0 turns the -0.0 entries of exact results into 0.0


def best_fit_rotation(points_from: ArrayLike, points_to: ArrayLike, weights: ArrayLike | None = None) -> F64:
    """Rotation R (..., 3, 3) of the weighted least-squares fit ``points_to - c_to ~ R (points_from - c_from)``.

    ``points_*`` are (..., n, 3) (metres or any common unit), ``weights`` (..., n) are
    non-negative with a positive sum (masses, say; uniform when omitted) and
    ``c_*`` the weighted centroids.  Kabsch: with the cross-covariance
    H = sum_i w_i (b_i - c_to)(a_i - c_from)^T = U S V^T, R = U diag(1, 1, d) V^T where
    d = sign(det U V^T) keeps R proper (a reflection never fits).  This is the
    rotation factor of the polar decomposition of the best-fit linear map.
    """
    a = np.asarray(points_from, np.float64)
    b = np.asarray(points_to, np.float64)
    if a.ndim < 2 or a.shape[-1] != 3 or a.shape != b.shape:
        raise ValueError(f"point sets must both have shape (..., n, 3), got {a.shape} and {b.shape}")
    w = np.ones(a.shape[:-1]) if weights is None else np.asarray(weights, np.float64)
    if w.shape != a.shape[:-1] or np.any(w < 0) or np.any(w.sum(axis=-1) <= 0):
        raise ValueError(
            f"weights must have shape {a.shape[:-1]}, be >= 0 and have a positive sum; got shape {w.shape}"
        )
    w = w / w.sum(axis=-1, keepdims=True)
    ca = np.einsum("...n,...ni->...i", w, a)
    cb = np.einsum("...n,...ni->...i", w, b)
    h = np.einsum("...n,...ni,...nj->...ij", w, b - cb[..., None, :], a - ca[..., None, :])
    return rotation_from_cross_covariance(h)


def rotation_from_cross_covariance(h: ArrayLike) -> F64:
    """The Kabsch rotation R (..., 3, 3) of a cross-covariance H (..., 3, 3) (the inner step of
    :func:`best_fit_rotation`, for callers that form H from precomputed moments).

    H = sum_i w_i (b_i - c_to)(a_i - c_from)^T (any positive scale of it gives the same R) = U S V^T;
    R = U diag(1, 1, d) V^T with d = sign(det U V^T), so R is proper.  ``best_fit_rotation(a, b, w)``
    equals ``rotation_from_cross_covariance(H)`` exactly for the H it forms from the points.
    """
    h = np.asarray(h, np.float64)
    if h.ndim < 2 or h.shape[-2:] != (3, 3):
        raise ValueError(f"cross-covariances must have shape (..., 3, 3), got {h.shape}")
    u, _, vt = np.linalg.svd(h)
    d = np.where(np.linalg.det(u @ vt) < 0.0, -1.0, 1.0)
    u[..., :, 2] *= d[..., None]
    return u @ vt
