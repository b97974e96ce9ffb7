"""EWA projection of 3D Gaussians to image-space ellipses (warp kernel + torch reference).

For a Gaussian with world centre mu and covariance Sigma (m^2), camera
rotation R and translation t (``world_to_camera``), and pinhole intrinsics
fx, fy, cx, cy (px):

* camera point p = R mu + t, depth z = p_z (m, camera frame);
* 2D mean (u, v) = (fx p_x / z + cx, fy p_y / z + cy) (px, centres at +0.5);
* J = [[fx/z, 0, -fx p_x/z^2], [0, fy/z, -fy p_y/z^2]] (Jacobian of the
  perspective map at p; like the reference 3DGS rasterizer, p_x/z and p_y/z
  are clamped to the view frustum enlarged by ``FRUSTUM_CLAMP_MARGIN`` of the
  image on each side, so splats far off-screen do not get huge footprints);
* 2D covariance Sigma2 = J R Sigma R^T J^T + d I with the low-pass dilation
  d = ``DEFAULT_DILATION_PX2`` = 0.3 px^2 (the usual anti-aliasing filter:
  every splat is at least about half a pixel wide, so sub-pixel splats do not
  fall between pixel centres);
* conic = Sigma2^-1 stored as (A, B, C): q(d) = A dx^2 + 2 B dx dy + C dy^2 is
  the squared Mahalanobis distance of the pixel offset d = (dx, dy);
* q_cut = 2 ln(opacity / alpha_min): the pixels a splat can reach with
  opacity exp(-q/2) >= alpha_min are exactly those with q <= q_cut;
* bbox = the pixels whose centres lie in the axis-aligned box of that ellipse,
  half-widths sqrt(q_cut Sigma2_xx), sqrt(q_cut Sigma2_yy), clipped to the image;
* radius_px = sqrt(q_cut lambda_max(Sigma2)), a circular bound of the same ellipse.

Culled (radius 0, empty bbox (0, 0, -1, -1), depth ``CULLED_DEPTH`` = float32
max): centre closer than ``near_m`` in front of the camera (or behind it),
opacity below ``alpha_min``, a singular 2D covariance (only possible with
``dilation_px2 = 0`` and a flat splat seen edge-on), or a bbox that misses the
image. The centre decides: a large splat whose centre is behind the near
plane is dropped whole, as in the reference 3DGS rasterizer.

Host side, ``ProjectedSplats`` keeps the outputs in warp arrays reused across
frames and, on CPU, splits the Gaussians over Python threads.
"""

from __future__ import annotations

import itertools
import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch
import warp as wp
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians

#: Low-pass dilation added to the diagonal of every projected 2D covariance, px^2.
DEFAULT_DILATION_PX2 = 0.3
#: Default near plane, m: Gaussians whose centre has camera z below it are culled.
DEFAULT_NEAR_M = 0.01
#: Fraction of the image size by which the Jacobian's frustum clamp exceeds the image on each side.
FRUSTUM_CLAMP_MARGIN = 0.15
#: Slack (px) added on both sides of an ellipse's analytic row span before the exact per-pixel test.
SPAN_SLACK_PX = wp.constant(1e-3)
#: Surface depth is clamped to the centre depth +- this many sqrt(trace(Sigma)) (edge-on splats).
SURFACE_DEPTH_SIGMAS = wp.constant(3.0)
#: Depth written for culled Gaussians (sorts after every visible one).
CULLED_DEPTH = float(np.finfo(np.float32).max)
_CULLED_DEPTH_WP = wp.constant(CULLED_DEPTH)


@dataclass(frozen=True)
class Camera:
    """Validated pinhole camera: intrinsics (px) and world-to-camera rotation/translation (m)."""

    fx: float
    fy: float
    cx: float
    cy: float
    rotation: NDArray[np.float64]  # (3, 3) world -> camera
    translation_m: NDArray[np.float64]  # (3,)
    height: int
    width: int

    @staticmethod
    def from_matrices(K: ArrayLike, world_to_camera: ArrayLike, height: int, width: int) -> Camera:
        k = np.asarray(K, np.float64)
        m = np.asarray(world_to_camera, np.float64)
        if k.shape != (3, 3) or not np.isfinite(k).all():
            raise ValueError(f"K must be a finite (3, 3) matrix, got shape {k.shape}: {k.tolist()}")
        if k[0, 0] <= 0 or k[1, 1] <= 0:
            raise ValueError(f"K focal lengths must be > 0 px, got fx={k[0, 0]}, fy={k[1, 1]}")
        if abs(k[0, 1]) > 0 or abs(k[1, 0]) > 0 or not np.allclose(k[2], (0.0, 0.0, 1.0)):
            raise ValueError(f"K must be [[fx,0,cx],[0,fy,cy],[0,0,1]] (no skew), got {k.tolist()}")
        if m.shape != (4, 4) or not np.isfinite(m).all():
            raise ValueError(f"world_to_camera must be a finite (4, 4) matrix, got shape {m.shape}")
        r = m[:3, :3]
        err = np.abs(r @ r.T - np.eye(3)).max()
        if err > 1e-4 or np.linalg.det(r) < 0:
            raise ValueError(
                f"world_to_camera[:3,:3] must be a rotation (orthonormal, det +1); |R R^T - I|max = {err:.3g}"
            )
        if not np.allclose(m[3], (0.0, 0.0, 0.0, 1.0)):
            raise ValueError(f"world_to_camera last row must be (0, 0, 0, 1), got {m[3].tolist()}")
        if int(height) < 1 or int(width) < 1:
            raise ValueError(f"image size must be >= 1 px, got height={height}, width={width}")
        return Camera(k[0, 0], k[1, 1], k[0, 2], k[1, 2], r.copy(), m[:3, 3].copy(), int(height), int(width))


def check_projection_options(near_m: float, dilation_px2: float, alpha_min: float) -> None:
    if not (np.isfinite(near_m) and near_m > 0):
        raise ValueError(f"near_m must be a finite distance > 0 m, got {near_m}")
    if not (np.isfinite(dilation_px2) and dilation_px2 >= 0):
        raise ValueError(f"dilation_px2 must be >= 0 px^2, got {dilation_px2}")
    if not 0.0 < alpha_min <= 1.0:
        raise ValueError(f"alpha_min must be in (0, 1], got {alpha_min}")


# --------------------------------------------------------------------------- #
# warp
# --------------------------------------------------------------------------- #
@wp.struct
class ProjectionParams:
    rotation: wp.mat33  # world -> camera
    translation: wp.vec3  # m
    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    near_m: float
    dilation_px2: float
    alpha_min: float
    clamp_margin: float
    surface_depth: int  # 1: also output the ray-depth data (labels' surface depth)


@wp.func
def _rotation_wxyz(q: wp.vec4) -> wp.mat33:
    """Unit quaternion stored (w, x, y, z) -> rotation matrix."""
    w = q[0]
    x = q[1]
    y = q[2]
    z = q[3]
    return wp.mat33(
        1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - w * z), 2.0 * (x * z + w * y),
        2.0 * (x * y + w * z), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - w * x),
        2.0 * (x * z - w * y), 2.0 * (y * z + w * x), 1.0 - 2.0 * (x * x + y * y),
    )  # fmt: skip


@wp.func
def _world_covariance(
    i: int,
    use_covariances: int,
    covariances: wp.array(dtype=wp.mat33),
    scales: wp.array(dtype=wp.vec3),
    rotations: wp.array(dtype=wp.vec4),
) -> wp.mat33:
    if use_covariances != 0:
        return covariances[i]
    r = _rotation_wxyz(rotations[i])
    s = scales[i]
    rs = r * wp.diag(s)
    return rs * wp.transpose(rs)


@wp.func
def _store_ray_depth_data(
    i: int,
    s: wp.mat33,
    p: wp.vec3,
    adj_diag: wp.array(dtype=wp.vec3),
    adj_off: wp.array(dtype=wp.vec3),
    adj_mean: wp.array(dtype=wp.vec3),
    depth_halfwidth_m: wp.array(dtype=float),
):
    """Adjugate of the camera covariance (scaled by 1/trace^2), times the centre, and a depth bound.

    The density along a ray x = t d peaks at t* = d^T P p / d^T P d (P = Sigma^-1);
    adj(Sigma) = det(Sigma) P gives the same ratio and stays finite for flat splats
    (where t* becomes the ray-plane intersection).
    """
    tr = s[0, 0] + s[1, 1] + s[2, 2]
    k = 1.0 / (tr * tr)
    a00 = (s[1, 1] * s[2, 2] - s[1, 2] * s[1, 2]) * k
    a11 = (s[0, 0] * s[2, 2] - s[0, 2] * s[0, 2]) * k
    a22 = (s[0, 0] * s[1, 1] - s[0, 1] * s[0, 1]) * k
    a01 = (s[0, 2] * s[1, 2] - s[0, 1] * s[2, 2]) * k
    a02 = (s[0, 1] * s[1, 2] - s[0, 2] * s[1, 1]) * k
    a12 = (s[0, 1] * s[0, 2] - s[0, 0] * s[1, 2]) * k
    adj_diag[i] = wp.vec3(a00, a11, a22)
    adj_off[i] = wp.vec3(a01, a02, a12)
    adj_mean[i] = wp.vec3(
        a00 * p[0] + a01 * p[1] + a02 * p[2],
        a01 * p[0] + a11 * p[1] + a12 * p[2],
        a02 * p[0] + a12 * p[1] + a22 * p[2],
    )
    depth_halfwidth_m[i] = SURFACE_DEPTH_SIGMAS * wp.sqrt(tr)


@wp.func
def ray_surface_depth(
    d: wp.vec3, adj_diag: wp.vec3, adj_off: wp.vec3, adj_mean: wp.vec3, centre_depth: float, halfwidth: float
) -> float:
    """Camera z of the density peak of a splat along the ray t d (d_z = 1), clamped to centre +- halfwidth."""
    den = (
        d[0] * (adj_diag[0] * d[0] + adj_off[0] * d[1] + adj_off[1] * d[2])
        + d[1] * (adj_off[0] * d[0] + adj_diag[1] * d[1] + adj_off[2] * d[2])
        + d[2] * (adj_off[1] * d[0] + adj_off[2] * d[1] + adj_diag[2] * d[2])
    )
    num = d[0] * adj_mean[0] + d[1] * adj_mean[1] + d[2] * adj_mean[2]
    if not (den > 0.0):
        return centre_depth
    return wp.clamp(num / den, centre_depth - halfwidth, centre_depth + halfwidth)


@wp.kernel
def project_kernel(
    means: wp.array(dtype=wp.vec3),
    use_covariances: int,
    covariances: wp.array(dtype=wp.mat33),
    scales: wp.array(dtype=wp.vec3),
    rotations: wp.array(dtype=wp.vec4),
    opacities: wp.array(dtype=float),
    params: ProjectionParams,
    mean_px: wp.array(dtype=wp.vec2),
    conic: wp.array(dtype=wp.vec3),
    depth_m: wp.array(dtype=float),
    bbox: wp.array(dtype=wp.vec4i),
    q_cut: wp.array(dtype=float),
    radius_px: wp.array(dtype=float),
    visible_count: wp.array(dtype=int),
    adj_diag: wp.array(dtype=wp.vec3),
    adj_off: wp.array(dtype=wp.vec3),
    adj_mean: wp.array(dtype=wp.vec3),
    depth_halfwidth_m: wp.array(dtype=float),
):
    i = wp.tid()
    mean_px[i] = wp.vec2(0.0, 0.0)
    conic[i] = wp.vec3(0.0, 0.0, 0.0)
    depth_m[i] = _CULLED_DEPTH_WP
    bbox[i] = wp.vec4i(0, 0, -1, -1)
    q_cut[i] = 0.0
    radius_px[i] = 0.0

    p = params.rotation * means[i] + params.translation
    z = p[2]
    opacity = opacities[i]
    if z < params.near_m or opacity < params.alpha_min:
        return
    qc = 2.0 * wp.log(opacity / params.alpha_min)

    w = float(params.width)
    h = float(params.height)
    lim_x0 = (-params.clamp_margin * w - params.cx) / params.fx
    lim_x1 = ((1.0 + params.clamp_margin) * w - params.cx) / params.fx
    lim_y0 = (-params.clamp_margin * h - params.cy) / params.fy
    lim_y1 = ((1.0 + params.clamp_margin) * h - params.cy) / params.fy
    tx = wp.clamp(p[0] / z, lim_x0, lim_x1)
    ty = wp.clamp(p[1] / z, lim_y0, lim_y1)
    j00 = params.fx / z
    j02 = -params.fx * tx / z
    j11 = params.fy / z
    j12 = -params.fy * ty / z

    s = params.rotation * _world_covariance(i, use_covariances, covariances, scales, rotations)
    s = s * wp.transpose(params.rotation)
    a = j00 * j00 * s[0, 0] + 2.0 * j00 * j02 * s[0, 2] + j02 * j02 * s[2, 2] + params.dilation_px2
    b = j00 * j11 * s[0, 1] + j00 * j12 * s[0, 2] + j02 * j11 * s[1, 2] + j02 * j12 * s[2, 2]
    c = j11 * j11 * s[1, 1] + 2.0 * j11 * j12 * s[1, 2] + j12 * j12 * s[2, 2] + params.dilation_px2
    det = a * c - b * b
    if not (det > 0.0):
        return

    u = params.fx * p[0] / z + params.cx
    v = params.fy * p[1] / z + params.cy
    hx = wp.sqrt(qc * a)
    hy = wp.sqrt(qc * c)
    x0 = wp.max(wp.ceil(u - hx - 0.5), 0.0)
    x1 = wp.min(wp.floor(u + hx - 0.5), w - 1.0)
    y0 = wp.max(wp.ceil(v - hy - 0.5), 0.0)
    y1 = wp.min(wp.floor(v + hy - 0.5), h - 1.0)
    if x0 > x1 or y0 > y1:
        return

    mean_px[i] = wp.vec2(u, v)
    conic[i] = wp.vec3(c / det, -b / det, a / det)
    depth_m[i] = z
    bbox[i] = wp.vec4i(int(x0), int(y0), int(x1), int(y1))
    q_cut[i] = qc
    lam_max = 0.5 * (a + c) + wp.sqrt(0.25 * (a - c) * (a - c) + b * b)
    radius_px[i] = wp.sqrt(qc * lam_max)
    wp.atomic_add(visible_count, 0, 1)
    if params.surface_depth != 0:
        _store_ray_depth_data(i, s, p, adj_diag, adj_off, adj_mean, depth_halfwidth_m)


@wp.func
def ellipse_row_span(conic: wp.vec3, q_cut: float, dy: float, mean_x: float, x0: int, x1: int) -> wp.vec2i:
    """Pixel columns [first, last] of one row whose centres can satisfy q <= q_cut (empty: first > last).

    ``dy`` is the row's pixel-centre offset from the mean (px). Solves
    A dx^2 + 2 B dy dx + C dy^2 <= q_cut for dx and widens the interval by
    ``SPAN_SLACK_PX`` so that rounding never drops a pixel; callers still
    test q <= q_cut per pixel, so the result equals a full bounding-box scan.
    """
    a = conic[0]
    bdy = conic[1] * dy
    disc = bdy * bdy - a * (conic[2] * dy * dy - q_cut)
    if disc < 0.0:
        return wp.vec2i(1, 0)
    r = wp.sqrt(disc)
    lo = wp.max(wp.ceil(mean_x + (-bdy - r) / a - 0.5 - SPAN_SLACK_PX), float(x0))
    hi = wp.min(wp.floor(mean_x + (-bdy + r) / a - 0.5 + SPAN_SLACK_PX), float(x1))
    if lo > hi:
        return wp.vec2i(1, 0)
    return wp.vec2i(int(lo), int(hi))


def row_bands(height: int, parts: int, align: int = 1) -> list[tuple[int, int]]:
    """Rows [0, height) cut into up to ``parts`` bands whose starts are multiples of ``align``."""
    blocks = -(-height // align)
    edges = np.linspace(0, blocks, max(1, min(parts, blocks)) + 1).round().astype(int) * align
    edges[-1] = height
    return [(int(a), int(min(b, height))) for a, b in itertools.pairwise(edges) if min(b, height) > a]


def split_range(n: int, parts: int) -> list[tuple[int, int]]:
    """[0, n) cut into up to ``parts`` contiguous non-empty ranges (one range when n == 0)."""
    edges = np.linspace(0, n, max(1, min(parts, n)) + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in itertools.pairwise(edges)]


_POOLS: dict[int, ThreadPoolExecutor] = {}
"""The render's thread pools by worker count, kept for the process (a 256² frame runs ~17 parallel sections: a new
pool per section started ~1,700 threads per 50-frame sequence, a fifth of its render time)."""
_POOLS_LOCK = threading.Lock()
_IN_POOL = threading.local()


def _mark_pool_thread() -> None:
    _IN_POOL.active = True


def _pool(workers: int) -> ThreadPoolExecutor:
    with _POOLS_LOCK:
        pool = _POOLS.get(workers)
        if pool is None:
            pool = _POOLS[workers] = ThreadPoolExecutor(workers, thread_name_prefix=f"render{workers}",
                                                        initializer=_mark_pool_thread)  # fmt: skip
        return pool


os.register_at_fork(after_in_child=_POOLS.clear)  # a forked child has none of the parent's threads


def run_in_threads(fn: Callable[[int], None], count: int, workers: int | None = None) -> None:
    """Call fn(0..count-1) on ``workers`` threads (default: one per call), in order when single-threaded.

    warp launches release the GIL, so CPU kernels writing disjoint outputs run
    on separate cores; more calls than workers balance uneven work. The threads are kept for the process, one pool
    per worker count; a call from one of them runs in order on that thread (no pool waits on itself).
    """
    workers = count if workers is None else max(1, min(workers, count))
    if workers == 1 or getattr(_IN_POOL, "active", False):
        for i in range(count):
            fn(i)
        return
    list(_pool(workers).map(fn, range(count)))


def to_warp(array: np.ndarray, dtype: object, device: str) -> wp.array:
    """Warp view of a contiguous float32 numpy array (no copy on CPU; uploaded on CUDA)."""
    host = np.ascontiguousarray(array, np.float32)
    return wp.array(host, dtype=dtype, device=device, copy=not wp.get_device(device).is_cpu)


class ProjectedSplats:
    """Per-Gaussian screen-space data on a warp device, reusable across frames (grows on demand)."""

    def __init__(self, device: str, num_threads: int = 1) -> None:
        """``num_threads`` Python threads split the Gaussians on CPU (1 launch on CUDA)."""
        self.device = device
        self.num_threads = max(1, int(num_threads)) if wp.get_device(device).is_cpu else 1
        self.capacity = -1
        self.count = 0
        self.visible_count = wp.zeros(self.num_threads, dtype=int, device=device)
        self._empty_cov = wp.zeros(0, dtype=wp.mat33, device=device)
        self._empty_vec3 = wp.zeros(0, dtype=wp.vec3, device=device)
        self._empty_vec4 = wp.zeros(0, dtype=wp.vec4, device=device)
        self._reserve(0)

    def _reserve(self, n: int) -> None:
        if n <= self.capacity:
            return
        cap = max(n, 16)
        d = self.device
        self.mean_px = wp.zeros(cap, dtype=wp.vec2, device=d)
        self.conic = wp.zeros(cap, dtype=wp.vec3, device=d)
        self.depth_m = wp.zeros(cap, dtype=float, device=d)
        self.bbox = wp.zeros(cap, dtype=wp.vec4i, device=d)
        self.q_cut = wp.zeros(cap, dtype=float, device=d)
        self.radius_px = wp.zeros(cap, dtype=float, device=d)
        self.adj_diag = wp.zeros(cap, dtype=wp.vec3, device=d)
        self.adj_off = wp.zeros(cap, dtype=wp.vec3, device=d)
        self.adj_mean = wp.zeros(cap, dtype=wp.vec3, device=d)
        self.depth_halfwidth_m = wp.zeros(cap, dtype=float, device=d)
        self.capacity = cap

    def project(
        self,
        gaussians: Gaussians,
        camera: Camera,
        alpha_min: float,
        near_m: float = DEFAULT_NEAR_M,
        dilation_px2: float = DEFAULT_DILATION_PX2,
        surface_depth: bool = False,
    ) -> int:
        """Project ``gaussians``; returns the number of visible (not culled) Gaussians.

        ``surface_depth`` also fills ``adj_diag``, ``adj_off``, ``adj_mean`` and
        ``depth_halfwidth_m`` for :func:`ray_surface_depth`.
        """
        check_projection_options(near_m, dilation_px2, alpha_min)
        n = len(gaussians)
        self._reserve(n)
        self.count = n
        self.visible_count.zero_()
        if n == 0:
            return 0
        d = self.device
        params = ProjectionParams()
        params.rotation = wp.mat33(camera.rotation.astype(np.float32))
        params.translation = wp.vec3(*camera.translation_m.astype(np.float32))
        params.fx, params.fy, params.cx, params.cy = camera.fx, camera.fy, camera.cx, camera.cy
        params.width, params.height = camera.width, camera.height
        params.near_m, params.dilation_px2, params.alpha_min = near_m, dilation_px2, alpha_min
        params.clamp_margin = FRUSTUM_CLAMP_MARGIN
        params.surface_depth = int(surface_depth)
        use_cov = gaussians.covariances_m2 is not None
        cov = to_warp(gaussians.covariances_m2, wp.mat33, d) if use_cov else None
        scales = None if use_cov else to_warp(gaussians.scales_m, wp.vec3, d)
        rots = None if use_cov else to_warp(gaussians.unit_rotations_wxyz, wp.vec4, d)
        means = to_warp(gaussians.means_m, wp.vec3, d)
        opacities = to_warp(gaussians.opacities, float, d)
        parts = split_range(n, self.num_threads)

        def launch(part: int) -> None:  # Gaussians [lo, hi) into their own output slots and counter
            lo, hi = parts[part]
            wp.launch(
                project_kernel,
                dim=hi - lo,
                inputs=[
                    means[lo:hi], int(use_cov),
                    cov[lo:hi] if cov is not None else self._empty_cov,
                    scales[lo:hi] if scales is not None else self._empty_vec3,
                    rots[lo:hi] if rots is not None else self._empty_vec4,
                    opacities[lo:hi], params,
                ],
                outputs=[self.mean_px[lo:hi], self.conic[lo:hi], self.depth_m[lo:hi], self.bbox[lo:hi],
                         self.q_cut[lo:hi], self.radius_px[lo:hi], self.visible_count[part : part + 1],
                         self.adj_diag[lo:hi], self.adj_off[lo:hi], self.adj_mean[lo:hi],
                         self.depth_halfwidth_m[lo:hi]],
                device=d,
            )  # fmt: skip

        run_in_threads(launch, len(parts))
        return int(self.visible_count.numpy().sum())

    def to_numpy(self) -> dict[str, np.ndarray]:
        """Host copies of the first ``count`` entries (for tests and debugging)."""
        n = self.count
        return {
            "mean_px": self.mean_px.numpy()[:n].copy(),
            "conic": self.conic.numpy()[:n].copy(),
            "depth_m": self.depth_m.numpy()[:n].copy(),
            "bbox": self.bbox.numpy()[:n].copy(),
            "q_cut": self.q_cut.numpy()[:n].copy(),
            "radius_px": self.radius_px.numpy()[:n].copy(),
        }


def project_gaussians(
    gaussians: Gaussians,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    height: int,
    width: int,
    alpha_min: float = 1.0 / 255.0,
    near_m: float = DEFAULT_NEAR_M,
    dilation_px2: float = DEFAULT_DILATION_PX2,
    device: str = "cpu",
) -> dict[str, np.ndarray]:
    """One-shot warp projection returning numpy arrays (see :meth:`ProjectedSplats.to_numpy`).

    ``visible`` (N,) bool is added: True where the Gaussian was not culled.
    """
    camera = Camera.from_matrices(K, world_to_camera, height, width)
    splats = ProjectedSplats(device)
    splats.project(gaussians, camera, alpha_min, near_m, dilation_px2)
    out = splats.to_numpy()
    out["visible"] = out["radius_px"] > 0
    return out


# --------------------------------------------------------------------------- #
# torch reference (float64, batched; same formulas)
# --------------------------------------------------------------------------- #
def project_gaussians_torch(
    gaussians: Gaussians,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    height: int,
    width: int,
    alpha_min: float = 1.0 / 255.0,
    near_m: float = DEFAULT_NEAR_M,
    dilation_px2: float = DEFAULT_DILATION_PX2,
) -> dict[str, torch.Tensor]:
    """Reference projection in float64 torch; returns the fields of the warp path plus ``visible``.

    Also returns ``cov2d`` (N, 2, 2), the dilated 2D covariance in px^2, and the
    camera-frame covariance ``cov_cam`` (N, 3, 3), m^2, and centre ``mean_cam`` (N, 3), m.
    """
    check_projection_options(near_m, dilation_px2, alpha_min)
    cam = Camera.from_matrices(K, world_to_camera, height, width)
    dt = torch.float64
    rot = torch.as_tensor(cam.rotation, dtype=dt)
    p = torch.as_tensor(gaussians.means_m, dtype=dt) @ rot.T + torch.as_tensor(cam.translation_m, dtype=dt)
    sigma = torch.as_tensor(gaussians.covariances(), dtype=dt)
    sigma_cam = rot @ sigma @ rot.T
    opacity = torch.as_tensor(gaussians.opacities, dtype=dt)
    z = p[:, 2]
    safe_z = torch.where(z > 0, z, torch.ones_like(z))
    m = FRUSTUM_CLAMP_MARGIN
    tx = (p[:, 0] / safe_z).clamp((-m * width - cam.cx) / cam.fx, ((1 + m) * width - cam.cx) / cam.fx)
    ty = (p[:, 1] / safe_z).clamp((-m * height - cam.cy) / cam.fy, ((1 + m) * height - cam.cy) / cam.fy)
    jac = torch.zeros(len(gaussians), 2, 3, dtype=dt)
    jac[:, 0, 0] = cam.fx / safe_z
    jac[:, 0, 2] = -cam.fx * tx / safe_z
    jac[:, 1, 1] = cam.fy / safe_z
    jac[:, 1, 2] = -cam.fy * ty / safe_z
    cov2d = jac @ sigma_cam @ jac.transpose(1, 2) + dilation_px2 * torch.eye(2, dtype=dt)
    a, b, c = cov2d[:, 0, 0], cov2d[:, 0, 1], cov2d[:, 1, 1]
    det = a * c - b * b
    mean_px = torch.stack([cam.fx * p[:, 0] / safe_z + cam.cx, cam.fy * p[:, 1] / safe_z + cam.cy], 1)
    qc = 2.0 * torch.log(opacity.clamp_min(1e-30) / alpha_min)
    hx = torch.sqrt((qc * a).clamp_min(0))
    hy = torch.sqrt((qc * c).clamp_min(0))
    x0 = torch.ceil(mean_px[:, 0] - hx - 0.5).clamp_min(0)
    x1 = torch.floor(mean_px[:, 0] + hx - 0.5).clamp_max(width - 1)
    y0 = torch.ceil(mean_px[:, 1] - hy - 0.5).clamp_min(0)
    y1 = torch.floor(mean_px[:, 1] + hy - 0.5).clamp_max(height - 1)
    visible = (z >= near_m) & (opacity >= alpha_min) & (det > 0) & (x0 <= x1) & (y0 <= y1)
    lam_max = 0.5 * (a + c) + torch.sqrt(0.25 * (a - c) ** 2 + b * b)
    conic = torch.stack([c / det, -b / det, a / det], 1)
    zero = torch.zeros_like(z)
    return {
        "mean_px": torch.where(visible[:, None], mean_px, 0.0),
        "conic": torch.where(visible[:, None], conic, 0.0),
        "depth_m": torch.where(visible, z, torch.full_like(z, CULLED_DEPTH)),
        "bbox": torch.where(
            visible[:, None],
            torch.stack([x0, y0, x1, y1], 1),
            torch.tensor([0.0, 0.0, -1.0, -1.0], dtype=dt),
        ).to(torch.int64),
        "q_cut": torch.where(visible, qc, zero),
        "radius_px": torch.where(visible, torch.sqrt((qc * lam_max).clamp_min(0)), zero),
        "cov2d": cov2d,
        "cov_cam": sigma_cam,
        "mean_cam": p,
        "visible": visible,
    }
