"""Surface splats posed by an object's reduced state, one warp thread per splat (CPU or GPU).

A splat i of an object with H handles moves with its precomputed affine basis b_i (4H,) and deformation basis
C_i (4H, 3) (``data_gen.sim.reduced``): for the frame's handle matrix Tm (3, 4H)

    x_i = x0_i + Tm b_i,    F_i = I + Tm C_i,    M_i = F_i R_i S_i,

and its covariance M_i M_i^T is stored back as scales and a rotation through the SVD of M_i (a valid Gaussian by
construction); its normal is F_i^-T n0_i, renormalised (the cofactor form of ``data_gen.gaussians.deform_normals``).

:class:`SplatPoser` does this for all splats in one launch on the render device. It replaces a batched torch SVD
that cost ~0.15 s per 10^5 splats on one CPU thread (about 2 s per frame of a 10-object, 10^6-splat sequence,
the largest per-frame cost of ``render_sequence`` there): warp's ``svd3`` runs ~3x faster on the CPU, and on a GPU
the poses stay on the device until the host reads them. :func:`pose_reference` is the torch formulation it is
tested against (the same covariances, positions and normals to rounding; the SVD's column order and signs may
differ, which leaves the Gaussian unchanged).
"""

from __future__ import annotations

import numpy as np
import torch
import warp as wp

from data_gen.gaussians import deform_normals
from data_gen.sim.reduced import deformation_from_tmat, displacement_from_tmat
from newtphys.rotations import matrix_to_quat

MIN_SCALE_M = 1e-9
"""Scales (singular values) are clamped to at least this, m: a splat flattened to zero thickness stays a
valid (if degenerate) Gaussian."""


@wp.func
def _quat_wxyz(m: wp.mat33d) -> wp.vec4d:
    """Unit (w, x, y, z) of a rotation matrix with w >= 0 (Shepperd's method, as ``rotations.matrix_to_quat``)."""
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    q = wp.vec4d()
    if tr >= m[0, 0] and tr >= m[1, 1] and tr >= m[2, 2]:
        s = wp.sqrt(wp.float64(1.0) + tr) * wp.float64(2.0)
        q = wp.vec4d(wp.float64(0.25) * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] >= m[1, 1] and m[0, 0] >= m[2, 2]:
        s = wp.sqrt(wp.float64(1.0) + m[0, 0] - m[1, 1] - m[2, 2]) * wp.float64(2.0)
        q = wp.vec4d((m[2, 1] - m[1, 2]) / s, wp.float64(0.25) * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] >= m[2, 2]:
        s = wp.sqrt(wp.float64(1.0) + m[1, 1] - m[0, 0] - m[2, 2]) * wp.float64(2.0)
        q = wp.vec4d((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, wp.float64(0.25) * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = wp.sqrt(wp.float64(1.0) + m[2, 2] - m[0, 0] - m[1, 1]) * wp.float64(2.0)
        q = wp.vec4d((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, wp.float64(0.25) * s)
    q = q / wp.length(q)
    if q[0] < wp.float64(0.0):
        q = -q
    return q


@wp.kernel
def _pose_kernel(
    x0: wp.array(dtype=wp.vec3d),
    b: wp.array2d(dtype=wp.float64),  # (n, 4H)
    c: wp.array3d(dtype=wp.float64),  # (n, 4H, 3)
    rs: wp.array(dtype=wp.mat33d),  # R_i S_i at rest
    n0: wp.array(dtype=wp.vec3d),
    tm: wp.array2d(dtype=wp.float64),  # (3, 4H)
    x_out: wp.array(dtype=wp.vec3d),
    scales_out: wp.array(dtype=wp.vec3d),
    quat_out: wp.array(dtype=wp.vec4d),
    normal_out: wp.array(dtype=wp.vec3f),
):
    i = wp.tid()
    u = wp.vec3d()
    f = wp.identity(n=3, dtype=wp.float64)
    for j in range(b.shape[1]):
        t = wp.vec3d(tm[0, j], tm[1, j], tm[2, j])
        u += t * b[i, j]
        f += wp.outer(t, wp.vec3d(c[i, j, 0], c[i, j, 1], c[i, j, 2]))
    x_out[i] = x0[i] + u
    # covariance (F R S)(F R S)^T = U diag(s)^2 U^T, |s| its scales: warp's svd3 returns U and V as proper
    # rotations, the sign of det(F R S) in s[2] (checked on 2e5 random and degenerate matrices), so U is a quaternion
    uu = wp.mat33d()
    s = wp.vec3d()
    v = wp.mat33d()
    wp.svd3(f * rs[i], uu, s, v)
    lo = wp.float64(MIN_SCALE_M)
    scales_out[i] = wp.vec3d(wp.max(wp.abs(s[0]), lo), wp.max(wp.abs(s[1]), lo), wp.max(wp.abs(s[2]), lo))
    quat_out[i] = _quat_wxyz(uu)
    # normal: cof(F) n0 * sign(det F), renormalised; a vanished image keeps the old direction
    f0 = wp.vec3d(f[0, 0], f[1, 0], f[2, 0])
    f1 = wp.vec3d(f[0, 1], f[1, 1], f[2, 1])
    f2 = wp.vec3d(f[0, 2], f[1, 2], f[2, 2])
    n = n0[i]
    m = n[0] * wp.cross(f1, f2) + n[1] * wp.cross(f2, f0) + n[2] * wp.cross(f0, f1)
    if wp.determinant(f) < wp.float64(0.0):
        m = -m
    length = wp.length(m)
    if length > wp.float64(1e-20):
        m = m / length
    else:
        m = n
    normal_out[i] = wp.vec3f(wp.float32(m[0]), wp.float32(m[1]), wp.float32(m[2]))


class SplatPoser:
    """Poses one object's surface splats for any handle matrix Tm, on ``device`` (warp: ``cpu``, ``cuda``).

    Args:
        x0: (n, 3) rest centres, m; b: (n, 4H) affine basis; c: (n, 4H, 3) deformation basis;
        rs: (n, 3, 3) rest rotation times scales (columns scaled), m; n0: (n, 3) rest unit normals.
    """

    def __init__(self, x0: torch.Tensor, b: torch.Tensor, c: torch.Tensor, rs: torch.Tensor, n0: np.ndarray,
                 device: str = "cpu") -> None:  # fmt: skip
        n = x0.shape[0]
        if b.shape[0] != n or c.shape[:2] != b.shape or c.shape[2] != 3 or rs.shape != (n, 3, 3) or n0.shape != (n, 3):
            shapes = ", ".join(str(tuple(a.shape)) for a in (x0, b, c, rs, n0))
            raise ValueError(f"SplatPoser: need x0 (n, 3), b (n, 4H), c (n, 4H, 3), rs (n, 3, 3), n0 (n, 3); got {shapes}")
        wp.init()
        self.device = device
        self.num_splats, self.width = n, int(b.shape[1])
        target = wp.get_device(device)

        def up(values, dtype) -> wp.array:
            if isinstance(values, torch.Tensor) and values.dtype == torch.float64 and values.is_contiguous() and (
                    wp.device_from_torch(values.device) == target):  # fmt: skip
                return wp.from_torch(values, dtype=dtype)  # shared: the caller keeps the tensor alive
            host = values.cpu().numpy() if isinstance(values, torch.Tensor) else values
            return wp.array(np.ascontiguousarray(np.asarray(host, dtype=np.float64)), dtype=dtype, device=device)

        self._tensors = (x0, b, c, rs)  # what the shared inputs view
        self._inputs = [up(x0, wp.vec3d), up(b, wp.float64), up(c, wp.float64), up(rs, wp.mat33d), up(n0, wp.vec3d)]
        self._tm = wp.zeros((3, self.width), dtype=wp.float64, device=device)
        self._out = [wp.empty(n, dtype=t, device=device) for t in (wp.vec3d, wp.vec3d, wp.vec4d, wp.vec3f)]
        self._launch = wp.launch(_pose_kernel, dim=n, inputs=[*self._inputs, self._tm, *self._out], device=device,
                                 record_cmd=True)  # fmt: skip

    def pose(self, tm: torch.Tensor | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(centres (n, 3) m float64, scales (n, 3) m float64, rotations (n, 4) wxyz float64, normals (n, 3)
        float32) for the handle matrix ``tm`` (3, 4H)."""
        t = np.asarray(tm, dtype=np.float64)
        if t.shape != (3, self.width):
            raise ValueError(f"SplatPoser.pose: tm must have shape (3, {self.width}), got {t.shape}")
        if self.num_splats == 0:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 3), np.float32)
        self._tm.assign(t)
        self._launch.launch()
        return tuple(a.numpy() for a in self._out)  # type: ignore[return-value]


def pose_reference(x0: torch.Tensor, b: torch.Tensor, c: torch.Tensor, rs: torch.Tensor, n0: np.ndarray,
                   tm: torch.Tensor) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:meth:`SplatPoser.pose` through torch's batched SVD (the formulation it replaced; tests compare the two)."""
    x = x0 + displacement_from_tmat(b, tm)
    f = deformation_from_tmat(c, tm)
    u, sv, _ = torch.linalg.svd(f @ rs)
    u[:, :, 2] *= torch.sign(torch.linalg.det(u))[:, None]  # proper rotation; cov = U S^2 U^T unchanged
    return x.numpy(), sv.clamp_min(MIN_SCALE_M).numpy(), matrix_to_quat(u.numpy()), deform_normals(n0, f.numpy())
