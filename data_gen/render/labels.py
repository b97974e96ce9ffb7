"""Label rasterizer: per pixel, the nearest Gaussian that covers it (binarized opacity, no blending).

A Gaussian i *covers* the pixel centre x when

    opacity_i * exp(-q_i(x) / 2) >= LABEL_COVER_ALPHA (= 0.5),

i.e. q_i(x) <= 2 ln(2 opacity_i), with q_i the squared Mahalanobis distance of
x under the projected (dilated) 2D covariance (see ``projection.py``). The
pixel takes the covering Gaussian with the smallest camera depth of its centre
(ties: smallest index).

Algorithm (order independent, deterministic, identical on CPU and CUDA): every
Gaussian scatters the 64-bit key ``(float32 bits of depth) << 32 | index`` over
the pixels it covers with ``wp.atomic_min``; positive float32 bit patterns
sort like the floats, so the integer minimum is the nearest Gaussian. A second
kernel splits the winning key back into index and depth. The depth map holds
the camera z (m) of the winning Gaussian's *centre* (``depth_mode="center"``,
the default; off the true surface by up to the splat's extent along the ray)
or of the winner's density peak along the pixel ray (``depth_mode="surface"``:
t* = d^T P mu / d^T P d with P = Sigma^-1, computed through adj(Sigma) so flat
splats give the exact ray-plane intersection; clamped to the centre depth +-
3 sqrt(trace Sigma) for splats seen edge-on, and to at least ``near_m``). On CPU the image is
split into row bands, one Python thread each (warp launches release the GIL),
and each thread only writes its own rows.

Only surface Gaussians may be passed in: interior (simulation-only) particles
must be dropped by the caller, or they would win pixels where the surface is
thin. For amodal masks pass ``include`` (per-Gaussian bool) to render one
object alone, or use :meth:`LabelRasterizer.render_group_masks`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch
import warp as wp
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from data_gen.render.projection import (
    DEFAULT_DILATION_PX2,
    DEFAULT_NEAR_M,
    Camera,
    ProjectedSplats,
    ellipse_row_span,
    ray_surface_depth,
    row_bands,
    run_in_threads,
)

#: A Gaussian covers a pixel when opacity * exp(-q/2) reaches this value.
LABEL_COVER_ALPHA = 0.5
#: Depth map modes: camera z of the winning splat's centre, or of its density peak along the pixel ray.
DEPTH_MODES = ("center", "surface")
#: Key of a pixel that no Gaussian covers.
EMPTY_KEY = np.uint64(np.iinfo(np.uint64).max)


@wp.kernel
def label_scatter_kernel(
    mean_px: wp.array(dtype=wp.vec2),
    conic: wp.array(dtype=wp.vec3),
    depth_m: wp.array(dtype=float),
    bbox: wp.array(dtype=wp.vec4i),
    q_cut: wp.array(dtype=float),
    use_include: int,
    include: wp.array(dtype=wp.uint8),
    row_lo: int,
    row_hi: int,
    width: int,
    keys: wp.array(dtype=wp.uint64),
):
    """Thread per Gaussian: atomic_min of its key over the covered pixels of rows [row_lo, row_hi)."""
    i = wp.tid()
    b = bbox[i]
    if b[2] < b[0]:
        return
    if use_include != 0:
        if include[i] == wp.uint8(0):
            return
    y0 = wp.max(b[1], row_lo)
    y1 = wp.min(b[3], row_hi - 1)
    if y0 > y1:
        return
    key = (wp.uint64(wp.cast(depth_m[i], wp.uint32)) << wp.uint64(32)) | wp.uint64(i)
    m = mean_px[i]
    co = conic[i]
    qc = q_cut[i]
    for y in range(y0, y1 + 1):
        dy = float(y) + 0.5 - m[1]
        span = ellipse_row_span(co, qc, dy, m[0], b[0], b[2])
        for x in range(span[0], span[1] + 1):
            dx = float(x) + 0.5 - m[0]
            q = co[0] * dx * dx + 2.0 * co[1] * dx * dy + co[2] * dy * dy
            if q <= qc:
                wp.atomic_min(keys, y * width + x, key)


@wp.kernel
def label_resolve_kernel(
    keys: wp.array(dtype=wp.uint64),
    empty_key: wp.uint64,
    index: wp.array(dtype=wp.int32),
    depth_m: wp.array(dtype=float),
):
    """Thread per pixel: key -> (Gaussian index or -1, depth in m or 0)."""
    p = wp.tid()
    key = keys[p]
    if key == empty_key:
        index[p] = -1
        depth_m[p] = 0.0
    else:
        index[p] = wp.int32(key & wp.uint64(0xFFFFFFFF))
        depth_m[p] = wp.cast(wp.uint32(key >> wp.uint64(32)), float)


@wp.struct
class PixelRays:
    """Pinhole intrinsics (px) to turn pixel (x, y) into the camera ray ((u - cx)/fx, (v - cy)/fy, 1)."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    near_m: float  # surface depths are clamped to at least the near plane


@wp.kernel
def label_surface_depth_kernel(
    index: wp.array(dtype=wp.int32),
    rays: PixelRays,
    centre_depth_m: wp.array(dtype=float),
    adj_diag: wp.array(dtype=wp.vec3),
    adj_off: wp.array(dtype=wp.vec3),
    adj_mean: wp.array(dtype=wp.vec3),
    depth_halfwidth_m: wp.array(dtype=float),
    depth_m: wp.array(dtype=float),
):
    """Thread per pixel: replace the winner's centre depth by its density peak along the pixel ray."""
    p = wp.tid()
    i = index[p]
    if i < 0:
        return
    x = p % rays.width
    y = p / rays.width
    d = wp.vec3((float(x) + 0.5 - rays.cx) / rays.fx, (float(y) + 0.5 - rays.cy) / rays.fy, 1.0)
    z = ray_surface_depth(d, adj_diag[i], adj_off[i], adj_mean[i], centre_depth_m[i], depth_halfwidth_m[i])
    depth_m[p] = wp.max(z, rays.near_m)


class LabelRasterizer:
    """Owns the per-pixel buffers of one image size on one warp device.

    ``num_threads`` row bands are scattered by that many Python threads on
    CPU (1 launch on CUDA, where the kernel is already parallel).
    """

    def __init__(
        self,
        height: int,
        width: int,
        device: str = "cpu",
        num_threads: int = 2,
        near_m: float = DEFAULT_NEAR_M,
        dilation_px2: float = DEFAULT_DILATION_PX2,
        depth_mode: str = "center",
    ) -> None:
        """``depth_mode``: "center" (camera z of the winning splat's centre) or "surface" (camera z
        of the winner's density peak along the pixel ray: the ray-plane hit for flat splats)."""
        if int(height) < 1 or int(width) < 1:
            raise ValueError(f"image size must be >= 1 px, got height={height}, width={width}")
        if int(num_threads) < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        if depth_mode not in DEPTH_MODES:
            raise ValueError(f"depth_mode must be one of {DEPTH_MODES}, got {depth_mode!r}")
        self.height, self.width, self.device = int(height), int(width), device
        self.near_m, self.dilation_px2, self.depth_mode = near_m, dilation_px2, depth_mode
        self._rays = PixelRays()
        cpu = wp.get_device(device).is_cpu
        self.bands = row_bands(self.height, int(num_threads) if cpu else 1)
        n_pix = self.height * self.width
        self.keys = wp.empty(n_pix, dtype=wp.uint64, device=device)
        self.index = wp.empty(n_pix, dtype=wp.int32, device=device)
        self.depth_m = wp.empty(n_pix, dtype=float, device=device)
        self.splats = ProjectedSplats(device, int(num_threads))
        self._no_include = wp.zeros(1, dtype=wp.uint8, device=device)
        # Compile/load once here: concurrent first launches from the band threads would each compile it.
        wp.load_module(__name__, device=device)
        wp.load_module("data_gen.render.projection", device=device)

    def project(self, gaussians: Gaussians, K: ArrayLike, world_to_camera: ArrayLike) -> int:
        """Project for label coverage (alpha_min = 0.5); returns the number of visible Gaussians."""
        camera = Camera.from_matrices(K, world_to_camera, self.height, self.width)
        r = self._rays
        r.fx, r.fy, r.cx, r.cy, r.width = camera.fx, camera.fy, camera.cx, camera.cy, self.width
        r.near_m = self.near_m
        surface = self.depth_mode == "surface"
        return self.splats.project(
            gaussians, camera, LABEL_COVER_ALPHA, self.near_m, self.dilation_px2, surface
        )

    def rasterize(self, include: ArrayLike | None = None) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
        """Index (H, W) int32 (-1 = none) and depth (H, W) float32 m (0 = none) of the last projection."""
        self._resolve_index(include)
        n, s = self.splats.count, self.splats
        if self.depth_mode == "surface" and n > 0:
            wp.launch(
                label_surface_depth_kernel,
                dim=self.height * self.width,
                inputs=[
                    self.index,
                    self._rays,
                    s.depth_m,
                    s.adj_diag,
                    s.adj_off,
                    s.adj_mean,
                    s.depth_halfwidth_m,
                ],
                outputs=[self.depth_m],
                device=self.device,
            )
        shape = (self.height, self.width)
        return self.index.numpy().reshape(shape).copy(), self.depth_m.numpy().reshape(shape).copy()

    def _resolve_index(self, include: ArrayLike | None) -> None:
        """The nearest covering splat of every pixel (``self.index``; centre depth in ``self.depth_m``) among the
        last projection's splats (those ``include`` (n,) bool flags when given)."""
        n = self.splats.count
        use_include = include is not None
        inc = self._no_include
        if use_include:
            mask = np.asarray(include)
            if mask.shape != (n,):
                raise ValueError(f"include must be a bool array of shape ({n},), got {mask.shape}")
            inc = wp.array(mask.astype(np.uint8), dtype=wp.uint8, device=self.device)
        self.keys.fill_(EMPTY_KEY)
        s = self.splats

        def scatter(part: int) -> None:
            band = self.bands[part]
            if n == 0:
                return
            wp.launch(
                label_scatter_kernel,
                dim=n,
                inputs=[s.mean_px, s.conic, s.depth_m, s.bbox, s.q_cut, int(use_include), inc,
                        band[0], band[1], self.width],
                outputs=[self.keys],
                device=self.device,
            )  # fmt: skip

        run_in_threads(scatter, len(self.bands))
        wp.launch(
            label_resolve_kernel,
            dim=self.height * self.width,
            inputs=[self.keys, wp.uint64(EMPTY_KEY)],
            outputs=[self.index, self.depth_m],
            device=self.device,
        )

    def render(
        self, gaussians: Gaussians, K: ArrayLike, world_to_camera: ArrayLike, include: ArrayLike | None = None
    ) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
        """Project and rasterize: (index (H, W) int32, -1 = none; depth (H, W) float32 m, 0 = none)."""
        self.project(gaussians, K, world_to_camera)
        return self.rasterize(include)

    def render_group_masks(
        self,
        gaussians: Gaussians,
        K: ArrayLike,
        world_to_camera: ArrayLike,
        group_of_gaussian: ArrayLike,
        groups: Sequence[int],
        projected: bool = False,
    ) -> NDArray[np.bool_]:
        """Silhouette (G, H, W) of each group rendered alone (amodal masks); projects once (not at all with
        ``projected``: the last :meth:`render` of this rasterizer projected these ``gaussians`` with this camera).

        ``group_of_gaussian`` (N,) holds a group id (e.g. object id) per Gaussian.
        """
        gid = np.asarray(group_of_gaussian)
        if gid.shape != (len(gaussians),):
            raise ValueError(f"group_of_gaussian must have shape ({len(gaussians)},), got {gid.shape}")
        if not projected:
            self.project(gaussians, K, world_to_camera)
        elif self.splats.count != len(gaussians):
            raise ValueError(f"projected=True but the last projection holds {self.splats.count} splats, not "
                             f"{len(gaussians)}: render these gaussians first")  # fmt: skip
        out = np.zeros((len(groups), self.height, self.width), bool)
        shape = (self.height, self.width)
        for k, group in enumerate(groups):  # loop over objects
            self._resolve_index(gid == group)  # (a silhouette needs no surface depth)
            out[k] = self.index.numpy().reshape(shape) >= 0
        return out


def render_label_index(
    gaussians: Gaussians,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    height: int,
    width: int,
    include: ArrayLike | None = None,
    near_m: float = DEFAULT_NEAR_M,
    dilation_px2: float = DEFAULT_DILATION_PX2,
    device: str = "cpu",
    num_threads: int = 2,
    depth_mode: str = "center",
) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
    """Nearest covering Gaussian per pixel: (index (H, W) int32, -1 = none; depth (H, W) float32 m, 0 = none).

    ``include`` (N,) bool restricts the render to a subset (indices stay those of ``gaussians``);
    ``depth_mode`` as in :class:`LabelRasterizer`.
    """
    rasterizer = LabelRasterizer(height, width, device, num_threads, near_m, dilation_px2, depth_mode)
    return rasterizer.render(gaussians, K, world_to_camera, include)


def render_mask_of_subset(
    gaussians: Gaussians,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    height: int,
    width: int,
    include: ArrayLike,
    near_m: float = DEFAULT_NEAR_M,
    dilation_px2: float = DEFAULT_DILATION_PX2,
    device: str = "cpu",
    num_threads: int = 2,
) -> NDArray[np.bool_]:
    """(H, W) bool silhouette of the included Gaussians rendered alone (ignores all others)."""
    index, _ = render_label_index(
        gaussians, K, world_to_camera, height, width, include, near_m, dilation_px2, device, num_threads
    )
    return index >= 0


def gather_labels(
    index: ArrayLike | torch.Tensor,
    per_gaussian_values: ArrayLike | torch.Tensor,
    background: float | int | bool | ArrayLike = 0,
) -> np.ndarray | torch.Tensor:
    """Per-pixel values ``per_gaussian_values[index]`` with ``background`` where index == -1.

    ``index`` is (H, W) integer, ``per_gaussian_values`` (N, ...) of any dtype;
    the result is (H, W, ...) of that dtype. Torch tensors in give a tensor out.
    """
    if isinstance(index, torch.Tensor) or isinstance(per_gaussian_values, torch.Tensor):
        idx = torch.as_tensor(index)
        vals = torch.as_tensor(per_gaussian_values)
        lo, hi = (int(idx.min()), int(idx.max())) if idx.numel() else (-1, -1)
        _check_gather(tuple(idx.shape), idx.dtype.is_floating_point, int(vals.shape[0]), hi, lo)
        hit = idx >= 0
        out = vals[idx.clamp_min(0).long()] if vals.shape[0] else vals.new_zeros(idx.shape + vals.shape[1:])
        bg = torch.as_tensor(background, dtype=vals.dtype, device=out.device)
        return torch.where(hit.reshape(hit.shape + (1,) * (out.dim() - hit.dim())), out, bg)
    idx_np = np.asarray(index)
    vals_np = np.asarray(per_gaussian_values)
    if vals_np.ndim == 0:
        raise ValueError("per_gaussian_values must have a leading Gaussian axis (N, ...), got a scalar")
    lo, hi = (int(idx_np.min()), int(idx_np.max())) if idx_np.size else (-1, -1)
    _check_gather(idx_np.shape, not np.issubdtype(idx_np.dtype, np.integer), vals_np.shape[0], hi, lo)
    hit = idx_np >= 0
    if vals_np.shape[0]:
        out = vals_np[np.where(hit, idx_np, 0)]
    else:
        out = np.zeros(idx_np.shape + vals_np.shape[1:], vals_np.dtype)
    out[~hit] = np.asarray(background, dtype=vals_np.dtype)
    return out


def _check_gather(shape: tuple[int, ...], is_float: bool, n: int, max_index: int, min_index: int) -> None:
    if len(shape) != 2 or is_float:
        raise ValueError(f"index must be an integer (H, W) map, got shape {shape}")
    if max_index >= n:
        raise ValueError(f"index holds Gaussian {max_index} but per_gaussian_values has only {n} rows")
    if min_index < -1:
        raise ValueError(f"index holds {min_index}; only -1 (no Gaussian) or valid indices are allowed")
