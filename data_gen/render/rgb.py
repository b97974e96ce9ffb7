"""RGB splat rasterizer: front-to-back alpha compositing of depth-sorted Gaussians (warp, CPU and CUDA).

Per pixel, Gaussians are composited nearest first (sorted by the camera depth
of their centres, ties by index) with

* alpha_i = min(ALPHA_MAX = 0.99, opacity_i exp(-q_i / 2)), q_i the squared
  Mahalanobis distance of the pixel centre under the projected 2D covariance;
* a Gaussian with alpha_i < ALPHA_MIN = 1/255 is skipped at that pixel (the
  projection's bounding box already drops pixels with q > 2 ln(255 opacity));
* C += T alpha_i c_i, T *= (1 - alpha_i), starting from T = 1;
* early stop (as in the reference 3DGS rasterizer): when compositing the
  next Gaussian would bring T below T_MIN = 1e-4, that Gaussian is not
  composited and the pixel is finished;
* finally rgb = C + T background and alpha = 1 - T.

Execution: one global depth sort (warp radix sort, stable), a gather of the
visible splats into depth order, then *row-band* splatting: a kernel thread
owns a band of image rows and walks the sorted list once, splatting each
Gaussian over the part of its bounding box inside its band (row by row, only
the columns of the ellipse's analytic span) and updating per-pixel colour and
transmittance. Within a band the Gaussians are applied strictly in depth
order and no two threads touch the same pixel, so the image is exact and
independent of scheduling on any device. Per-tile counters of still-open
pixels (OPEN_TILE = 8) let a splat whose box only covers finished tiles be
skipped without visiting its pixels.

On CPU (warp runs one launch on one core) the image is cut into
BANDS_PER_THREAD x ``num_threads`` bands (starting on tile rows), handed out
to ``num_threads`` Python threads (warp launches release the GIL); projection
and gather are split over the threads too.

On CUDA the default is the tile-binned pipeline (``pipeline="tiles"``): every
sorted splat emits one key (tile << 32 | depth rank) per BIN_TILE^2 tile its
box touches, a radix sort groups the keys by tile in depth order, and one
thread per pixel composites its tile's list front to back. It gives the same
image bit for bit (tested on CPU); its GPU speed has not been measured here
(no GPU was available). The band kernel also runs on CUDA (one row per thread).

Why bands on CPU: the per-pixel gather tests every splat of a tile at every
pixel of the tile, while splatting evaluates each splat only over its own
ellipse. bench/bench_render.py measures both on CPU in the same run.
"""

from __future__ import annotations

import numpy as np
import warp as wp
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from data_gen.render.projection import (
    DEFAULT_DILATION_PX2,
    DEFAULT_NEAR_M,
    Camera,
    ProjectedSplats,
    ellipse_row_span,
    row_bands,
    run_in_threads,
    split_range,
    to_warp,
)

#: Alpha of one Gaussian at one pixel is clamped to this.
ALPHA_MAX = 0.99
#: Contributions below this alpha are skipped.
ALPHA_MIN = 1.0 / 255.0
#: A pixel stops compositing before its transmittance would fall below this.
T_MIN = 1e-4
#: CPU row bands per Python thread: more bands than threads balance images whose rows differ in cost.
BANDS_PER_THREAD = 4
#: Side (px) of the tiles whose open-pixel counts let finished regions be skipped; CPU row bands align to it.
OPEN_TILE = wp.constant(8)


@wp.struct
class CompositeParams:
    width: int
    row_lo: int
    row_hi: int
    band_rows: int
    tiles_x: int
    alpha_max: float
    alpha_min: float
    t_min: float
    two_colors: int  # 1: a second colouring is composited with the same weights (RgbRasterizer.render_two)


@wp.kernel
def fill_arange_kernel(values: wp.array(dtype=wp.int32)):
    i = wp.tid()
    values[i] = i


@wp.kernel
def gather_sorted_kernel(
    order: wp.array(dtype=wp.int32),
    mean_px: wp.array(dtype=wp.vec2),
    conic: wp.array(dtype=wp.vec3),
    bbox: wp.array(dtype=wp.vec4i),
    q_cut: wp.array(dtype=float),
    opacities: wp.array(dtype=float),
    colors: wp.array(dtype=wp.vec3),
    colors2: wp.array(dtype=wp.vec3),
    two_colors: int,
    out_mean_px: wp.array(dtype=wp.vec2),
    out_conic: wp.array(dtype=wp.vec3),
    out_bbox: wp.array(dtype=wp.vec4i),
    out_q_cut: wp.array(dtype=float),
    out_opacity: wp.array(dtype=float),
    out_color: wp.array(dtype=wp.vec3),
    out_color2: wp.array(dtype=wp.vec3),
):
    """Thread per sorted slot: copy the splat data into depth order (contiguous reads later)."""
    k = wp.tid()
    i = order[k]
    out_mean_px[k] = mean_px[i]
    out_conic[k] = conic[i]
    out_bbox[k] = bbox[i]
    out_q_cut[k] = q_cut[i]
    out_opacity[k] = opacities[i]
    out_color[k] = colors[i]
    if two_colors != 0:
        out_color2[k] = colors2[i]


@wp.func
def _any_tile_open(tile_open: wp.array(dtype=int), tiles_x: int, x0: int, y0: int, x1: int, y1: int) -> bool:
    """Whether any OPEN_TILE x OPEN_TILE tile touching pixels [x0, x1] x [y0, y1] still has an open pixel."""
    for ty in range(y0 // OPEN_TILE, y1 // OPEN_TILE + 1):
        for tx in range(x0 // OPEN_TILE, x1 // OPEN_TILE + 1):
            if tile_open[ty * tiles_x + tx] > 0:
                return True
    return False


@wp.kernel
def composite_bands_kernel(
    count: int,
    mean_px: wp.array(dtype=wp.vec2),
    conic: wp.array(dtype=wp.vec3),
    bbox: wp.array(dtype=wp.vec4i),
    q_cut: wp.array(dtype=float),
    opacity: wp.array(dtype=float),
    color: wp.array(dtype=wp.vec3),
    color2: wp.array(dtype=wp.vec3),
    params: CompositeParams,
    accum_rgb: wp.array(dtype=wp.vec3),
    accum_rgb2: wp.array(dtype=wp.vec3),
    transmittance: wp.array(dtype=float),
    tile_open: wp.array(dtype=int),
):
    """Thread per row band: composite the depth-sorted splats front to back over the band's pixels.

    ``transmittance`` holds T > 0 while a pixel is open and -T once it has
    stopped. ``tile_open`` counts the open pixels of each OPEN_TILE^2 tile
    (atomically decremented, since on CUDA row bands share tiles); a splat
    whose box only touches finished tiles is skipped without visiting pixels.
    Skipping only ever happens for finished pixels, so it does not change the image.
    """
    band = wp.tid()
    r0 = params.row_lo + band * params.band_rows
    r1 = wp.min(r0 + params.band_rows, params.row_hi) - 1
    for k in range(count):
        b = bbox[k]
        if b[3] < r0 or b[1] > r1:
            continue
        y0 = wp.max(b[1], r0)
        y1 = wp.min(b[3], r1)
        if not _any_tile_open(tile_open, params.tiles_x, b[0], y0, b[2], y1):
            continue
        m = mean_px[k]
        co = conic[k]
        qc = q_cut[k]
        o = opacity[k]
        c = color[k]
        c2 = wp.vec3(0.0, 0.0, 0.0)
        if params.two_colors != 0:
            c2 = color2[k]
        for y in range(y0, y1 + 1):
            dy = float(y) + 0.5 - m[1]
            row = y * params.width
            span = ellipse_row_span(co, qc, dy, m[0], b[0], b[2])
            for x in range(span[0], span[1] + 1):
                p = row + x
                t = transmittance[p]
                if t <= 0.0:
                    continue
                dx = float(x) + 0.5 - m[0]
                q = co[0] * dx * dx + 2.0 * co[1] * dx * dy + co[2] * dy * dy
                alpha = wp.min(params.alpha_max, o * wp.exp(-0.5 * q))
                if alpha < params.alpha_min:
                    continue
                t_next = t * (1.0 - alpha)
                if t_next < params.t_min:
                    transmittance[p] = -t
                    wp.atomic_sub(tile_open, (y // OPEN_TILE) * params.tiles_x + x // OPEN_TILE, 1)
                    continue
                accum_rgb[p] = accum_rgb[p] + (t * alpha) * c
                if params.two_colors != 0:
                    accum_rgb2[p] = accum_rgb2[p] + (t * alpha) * c2
                transmittance[p] = t_next


@wp.kernel
def init_tile_open_kernel(width: int, height: int, tiles_x: int, tile_open: wp.array(dtype=int)):
    """Thread per tile: number of image pixels in the tile."""
    t = wp.tid()
    tx = t % tiles_x
    ty = t / tiles_x
    w = wp.min(OPEN_TILE, width - tx * OPEN_TILE)
    h = wp.min(OPEN_TILE, height - ty * OPEN_TILE)
    tile_open[t] = w * h


#: Side (px) of the screen tiles of the tile-binned pipeline (the CUDA default).
BIN_TILE = wp.constant(16)
#: Rasterization pipelines: "bands" (row-band splatting), "tiles" (per-pixel gather over per-tile lists).
PIPELINES = ("auto", "bands", "tiles")


@wp.kernel
def count_tiles_kernel(bbox: wp.array(dtype=wp.vec4i), counts: wp.array(dtype=wp.int32)):
    """Thread per sorted splat: number of BIN_TILE^2 tiles its bounding box touches."""
    k = wp.tid()
    b = bbox[k]
    counts[k] = (b[2] / BIN_TILE - b[0] / BIN_TILE + 1) * (b[3] / BIN_TILE - b[1] / BIN_TILE + 1)


@wp.kernel
def emit_tile_keys_kernel(
    bbox: wp.array(dtype=wp.vec4i),
    counts: wp.array(dtype=wp.int32),
    inclusive_offsets: wp.array(dtype=wp.int32),
    tiles_x: int,
    keys: wp.array(dtype=wp.int64),
    values: wp.array(dtype=wp.int32),
):
    """Thread per sorted splat k: one (tile << 32 | k) key per touched tile; sorting the keys groups
    splats by tile, and k (the depth rank) keeps them in depth order inside a tile."""
    k = wp.tid()
    b = bbox[k]
    o = inclusive_offsets[k] - counts[k]
    for ty in range(b[1] / BIN_TILE, b[3] / BIN_TILE + 1):
        for tx in range(b[0] / BIN_TILE, b[2] / BIN_TILE + 1):
            keys[o] = (wp.int64(ty * tiles_x + tx) << wp.int64(32)) | wp.int64(k)
            values[o] = k
            o += 1


@wp.kernel
def tile_ranges_kernel(
    keys: wp.array(dtype=wp.int64),
    total: int,
    tile_start: wp.array(dtype=wp.int32),
    tile_end: wp.array(dtype=wp.int32),
):
    """Thread per sorted key: mark where each tile's run of keys starts and ends."""
    i = wp.tid()
    tile = int(keys[i] >> wp.int64(32))
    if i == 0:
        tile_start[tile] = i
    elif int(keys[i - 1] >> wp.int64(32)) != tile:
        tile_start[tile] = i
    if i == total - 1:
        tile_end[tile] = i + 1
    elif int(keys[i + 1] >> wp.int64(32)) != tile:
        tile_end[tile] = i + 1


@wp.kernel
def composite_tiles_kernel(
    values: wp.array(dtype=wp.int32),
    tile_start: wp.array(dtype=wp.int32),
    tile_end: wp.array(dtype=wp.int32),
    mean_px: wp.array(dtype=wp.vec2),
    conic: wp.array(dtype=wp.vec3),
    opacity: wp.array(dtype=float),
    color: wp.array(dtype=wp.vec3),
    color2: wp.array(dtype=wp.vec3),
    params: CompositeParams,
    accum_rgb: wp.array(dtype=wp.vec3),
    accum_rgb2: wp.array(dtype=wp.vec3),
    transmittance: wp.array(dtype=float),
):
    """Thread per pixel: composite its tile's splats front to back (same rules as the band kernel)."""
    p = wp.tid()
    x = p % params.width
    y = p / params.width
    tile = (y / BIN_TILE) * params.tiles_x + x / BIN_TILE
    t = float(1.0)  # warp: float() makes t a mutable loop-carried value
    acc = wp.vec3(0.0, 0.0, 0.0)
    acc2 = wp.vec3(0.0, 0.0, 0.0)
    for i in range(tile_start[tile], tile_end[tile]):
        k = values[i]
        m = mean_px[k]
        co = conic[k]
        dx = float(x) + 0.5 - m[0]
        dy = float(y) + 0.5 - m[1]
        q = co[0] * dx * dx + 2.0 * co[1] * dx * dy + co[2] * dy * dy
        alpha = wp.min(params.alpha_max, opacity[k] * wp.exp(-0.5 * q))
        if alpha < params.alpha_min:
            continue
        t_next = t * (1.0 - alpha)
        if t_next < params.t_min:
            break
        acc = acc + (t * alpha) * color[k]
        if params.two_colors != 0:
            acc2 = acc2 + (t * alpha) * color2[k]
        t = t_next
    accum_rgb[p] = acc
    if params.two_colors != 0:
        accum_rgb2[p] = acc2
    transmittance[p] = t


@wp.kernel
def finish_rgb_kernel(
    accum_rgb: wp.array(dtype=wp.vec3),
    transmittance: wp.array(dtype=float),
    background: wp.vec3,
    rgb: wp.array(dtype=wp.vec3),
    alpha: wp.array(dtype=float),
):
    """Thread per pixel: add the background behind the remaining transmittance."""
    p = wp.tid()
    t = wp.abs(transmittance[p])
    rgb[p] = accum_rgb[p] + t * background
    alpha[p] = 1.0 - t


def _check_background(background_rgb: ArrayLike) -> NDArray[np.float32]:
    bg = np.asarray(background_rgb, np.float32)
    if bg.shape != (3,) or not np.isfinite(bg).all() or (bg < 0).any() or (bg > 1).any():
        raise ValueError(
            f"background_rgb must be 3 values in [0, 1], got {np.asarray(background_rgb).tolist()}"
        )
    return bg


class RgbRasterizer:
    """Owns the per-pixel and per-Gaussian buffers of one image size on one warp device."""

    def __init__(
        self,
        height: int,
        width: int,
        device: str = "cpu",
        num_threads: int = 2,
        near_m: float = DEFAULT_NEAR_M,
        dilation_px2: float = DEFAULT_DILATION_PX2,
        rows_per_band: int | None = None,
        pipeline: str = "auto",
    ) -> None:
        """``pipeline``: "bands" (row-band splatting, the CPU default), "tiles" (per-pixel gather over
        per-tile depth-sorted lists, the CUDA default) or "auto". ``rows_per_band``: rows owned by one
        band-kernel thread; None = a whole band on CPU, 1 on CUDA (any value gives the same image)."""
        if pipeline not in PIPELINES:
            raise ValueError(f"pipeline must be one of {PIPELINES}, got {pipeline!r}")
        if int(height) < 1 or int(width) < 1:
            raise ValueError(f"image size must be >= 1 px, got height={height}, width={width}")
        if int(num_threads) < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        if rows_per_band is not None and int(rows_per_band) < 1:
            raise ValueError(f"rows_per_band must be >= 1 or None, got {rows_per_band}")
        self.height, self.width, self.device = int(height), int(width), device
        self.near_m, self.dilation_px2 = near_m, dilation_px2
        is_cpu = wp.get_device(device).is_cpu
        # CPU bands start on tile rows so that no two Python threads share a tile counter
        self.bands = (
            row_bands(self.height, int(num_threads) * BANDS_PER_THREAD, OPEN_TILE)
            if is_cpu
            else [(0, self.height)]
        )
        self.rows_per_band = rows_per_band if rows_per_band is not None else (self.height if is_cpu else 1)
        self.pipeline = ("bands" if is_cpu else "tiles") if pipeline == "auto" else pipeline
        self.bin_tiles_x = -(-self.width // BIN_TILE)
        num_bins = self.bin_tiles_x * -(-self.height // BIN_TILE)
        self.tile_start = wp.empty(num_bins, dtype=wp.int32, device=device)
        self.tile_end = wp.empty(num_bins, dtype=wp.int32, device=device)
        self.key_capacity = -1
        self._reserve_keys(0)
        n_pix = self.height * self.width
        self.accum_rgb = wp.empty(n_pix, dtype=wp.vec3, device=device)
        self.accum_rgb2 = wp.empty(n_pix, dtype=wp.vec3, device=device)  # a second colouring's (render_two)
        self.transmittance = wp.empty(n_pix, dtype=float, device=device)
        self.tiles_x = -(-self.width // OPEN_TILE)
        self.num_tiles = self.tiles_x * -(-self.height // OPEN_TILE)
        self.tile_open = wp.empty(self.num_tiles, dtype=int, device=device)
        self.rgb = wp.empty(n_pix, dtype=wp.vec3, device=device)
        self.rgb2 = wp.empty(n_pix, dtype=wp.vec3, device=device)
        self.alpha = wp.empty(n_pix, dtype=float, device=device)
        self._two_colors = 0
        self.splats = ProjectedSplats(device, int(num_threads))
        self.num_threads = self.splats.num_threads
        self.capacity = -1
        self._reserve(0)
        wp.load_module(__name__, device=device)
        wp.load_module("data_gen.render.projection", device=device)

    def _reserve(self, n: int) -> None:
        if n <= self.capacity:
            return
        cap, d = max(n, 16), self.device
        self.sort_keys = wp.empty(2 * cap, dtype=float, device=d)
        self.sort_values = wp.empty(2 * cap, dtype=wp.int32, device=d)
        self.s_mean_px = wp.empty(cap, dtype=wp.vec2, device=d)
        self.s_conic = wp.empty(cap, dtype=wp.vec3, device=d)
        self.s_bbox = wp.empty(cap, dtype=wp.vec4i, device=d)
        self.s_q_cut = wp.empty(cap, dtype=float, device=d)
        self.s_opacity = wp.empty(cap, dtype=float, device=d)
        self.s_color = wp.empty(cap, dtype=wp.vec3, device=d)
        self.s_color2 = wp.empty(cap, dtype=wp.vec3, device=d)
        self.tile_counts = wp.empty(cap, dtype=wp.int32, device=d)
        self.tile_offsets = wp.empty(cap, dtype=wp.int32, device=d)
        self.capacity = cap

    def _reserve_keys(self, total: int) -> None:
        if total <= self.key_capacity:
            return
        cap = max(total, 16)
        self.tile_keys = wp.empty(2 * cap, dtype=wp.int64, device=self.device)
        self.tile_values = wp.empty(2 * cap, dtype=wp.int32, device=self.device)
        self.key_capacity = cap

    def render(
        self,
        gaussians: Gaussians,
        K: ArrayLike,
        world_to_camera: ArrayLike,
        background_rgb: ArrayLike = (0.0, 0.0, 0.0),
    ) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """(rgb (H, W, 3) float32 in [0, 1], alpha (H, W) float32 = 1 - final transmittance)."""
        bg = _check_background(background_rgb)
        self._composite(gaussians, K, world_to_camera, None)
        return self._finish(self.accum_rgb, bg, self.rgb), self._alpha()

    def render_two(
        self,
        gaussians: Gaussians,
        second_colors_rgb: ArrayLike,
        K: ArrayLike,
        world_to_camera: ArrayLike,
        background_rgb: ArrayLike = (0.0, 0.0, 0.0),
        second_background_rgb: ArrayLike = (0.0, 0.0, 0.0),
    ) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
        """Two colourings of the same splats in one pass: (rgb of ``gaussians.colors_rgb``, rgb of
        ``second_colors_rgb`` (N, 3) in [0, 1], alpha), each as :meth:`render` gives it (the same bits: the
        weights are computed once and applied to both). Lighting's ambient and direct parts are two colourings."""
        bg, bg2 = _check_background(background_rgb), _check_background(second_background_rgb)
        second = gaussians.with_colors(second_colors_rgb).colors_rgb  # checked: (N, 3) in [0, 1]
        self._composite(gaussians, K, world_to_camera, second)
        first = self._finish(self.accum_rgb, bg, self.rgb)
        return first, self._finish(self.accum_rgb2, bg2, self.rgb2), self._alpha()

    def _composite(self, gaussians: Gaussians, K: ArrayLike, world_to_camera: ArrayLike,
                   second_colors: NDArray[np.float32] | None) -> None:  # fmt: skip
        """Project, sort and composite ``gaussians`` (and a second colouring when given) into the accumulators."""
        camera = Camera.from_matrices(K, world_to_camera, self.height, self.width)
        n = len(gaussians)
        d = self.device
        self._reserve(n)
        self._two_colors = int(second_colors is not None)
        n_visible = self.splats.project(gaussians, camera, ALPHA_MIN, self.near_m, self.dilation_px2)
        self.accum_rgb.zero_()
        if self._two_colors:
            self.accum_rgb2.zero_()
        self.transmittance.fill_(1.0)
        wp.launch(
            init_tile_open_kernel,
            dim=self.num_tiles,
            inputs=[self.width, self.height, self.tiles_x],
            outputs=[self.tile_open],
            device=d,
        )
        if n_visible > 0:
            s = self.splats
            wp.copy(self.sort_keys, s.depth_m, count=n)
            wp.launch(fill_arange_kernel, dim=n, inputs=[self.sort_values], device=d)
            wp.utils.radix_sort_pairs(self.sort_keys, self.sort_values, n)  # stable: ties keep index order
            opacities = to_warp(gaussians.opacities, float, d)
            colors = to_warp(gaussians.colors_rgb, wp.vec3, d)
            colors2 = colors if second_colors is None else to_warp(second_colors, wp.vec3, d)
            parts = split_range(n_visible, self.num_threads)

            def gather(part: int) -> None:  # sorted slots [lo, hi)
                lo, hi = parts[part]
                wp.launch(
                    gather_sorted_kernel,
                    dim=hi - lo,
                    inputs=[self.sort_values[lo:hi], s.mean_px, s.conic, s.bbox, s.q_cut, opacities, colors, colors2,
                            self._two_colors],
                    outputs=[self.s_mean_px[lo:hi], self.s_conic[lo:hi], self.s_bbox[lo:hi],
                             self.s_q_cut[lo:hi],
                             self.s_opacity[lo:hi], self.s_color[lo:hi], self.s_color2[lo:hi]],
                    device=d,
                )  # fmt: skip

            run_in_threads(gather, len(parts))
            if self.pipeline == "bands":
                self._composite_bands(n_visible)
            else:
                self._composite_tiles(n_visible)

    def _finish(self, accum: wp.array, bg: NDArray[np.float32], out: wp.array) -> NDArray[np.float32]:
        """The image (H, W, 3) of an accumulator with ``bg`` behind the remaining transmittance."""
        wp.launch(finish_rgb_kernel, dim=self.height * self.width,
                  inputs=[accum, self.transmittance, wp.vec3(*bg.tolist())], outputs=[out, self.alpha],
                  device=self.device)  # fmt: skip
        return out.numpy().reshape(self.height, self.width, 3).copy()

    def _alpha(self) -> NDArray[np.float32]:
        return self.alpha.numpy().reshape(self.height, self.width).copy()

    def _params(self, row_lo: int, row_hi: int, band_rows: int, tiles_x: int) -> CompositeParams:
        params = CompositeParams()
        params.width, params.row_lo, params.row_hi, params.band_rows = self.width, row_lo, row_hi, band_rows
        params.tiles_x = tiles_x
        params.alpha_max, params.alpha_min, params.t_min = ALPHA_MAX, ALPHA_MIN, T_MIN
        params.two_colors = self._two_colors
        return params

    def _composite_tiles(self, count: int) -> None:
        """Bin the ``count`` depth-sorted splats into BIN_TILE^2 tiles, then one thread per pixel."""
        d = self.device
        wp.launch(count_tiles_kernel, dim=count, inputs=[self.s_bbox], outputs=[self.tile_counts], device=d)
        wp.utils.array_scan(self.tile_counts[:count], self.tile_offsets[:count], inclusive=True)
        total = int(self.tile_offsets[count - 1 : count].numpy()[0])
        self._reserve_keys(total)
        wp.launch(
            emit_tile_keys_kernel,
            dim=count,
            inputs=[self.s_bbox, self.tile_counts, self.tile_offsets, self.bin_tiles_x],
            outputs=[self.tile_keys, self.tile_values],
            device=d,
        )
        num_bins = self.tile_start.shape[0]
        wp.utils.radix_sort_pairs(
            self.tile_keys, self.tile_values, total, 0, 32 + max(1, num_bins - 1).bit_length()
        )
        self.tile_start.zero_()
        self.tile_end.zero_()
        wp.launch(
            tile_ranges_kernel, dim=total, inputs=[self.tile_keys, total],
            outputs=[self.tile_start, self.tile_end], device=d,
        )  # fmt: skip
        wp.launch(
            composite_tiles_kernel,
            dim=self.height * self.width,
            inputs=[self.tile_values, self.tile_start, self.tile_end, self.s_mean_px, self.s_conic,
                    self.s_opacity,
                    self.s_color, self.s_color2, self._params(0, self.height, self.height, self.bin_tiles_x)],
            outputs=[self.accum_rgb, self.accum_rgb2, self.transmittance],
            device=d,
        )  # fmt: skip

    def _composite_bands(self, count: int) -> None:
        def run(part: int) -> None:
            band = self.bands[part]
            params = self._params(
                band[0], band[1], min(int(self.rows_per_band), band[1] - band[0]), self.tiles_x
            )
            wp.launch(
                composite_bands_kernel,
                dim=-(-(band[1] - band[0]) // params.band_rows),
                inputs=[
                    count,
                    self.s_mean_px,
                    self.s_conic,
                    self.s_bbox,
                    self.s_q_cut,
                    self.s_opacity,
                    self.s_color,
                    self.s_color2,
                    params,
                ],
                outputs=[self.accum_rgb, self.accum_rgb2, self.transmittance, self.tile_open],
                device=self.device,
            )

        run_in_threads(run, len(self.bands), self.num_threads)


def render_rgb(
    gaussians: Gaussians,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    height: int,
    width: int,
    background_rgb: ArrayLike = (0.0, 0.0, 0.0),
    device: str = "cpu",
    num_threads: int = 2,
    near_m: float = DEFAULT_NEAR_M,
    dilation_px2: float = DEFAULT_DILATION_PX2,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Alpha-composited colour (H, W, 3) float32 and alpha (H, W) float32 of ``gaussians``."""
    rasterizer = RgbRasterizer(height, width, device, num_threads, near_m, dilation_px2)
    return rasterizer.render(gaussians, K, world_to_camera, background_rgb)
