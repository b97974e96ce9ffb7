"""Shadows of a directional light: a depth map rendered from the light, looked up per splat.

Method (one map per frame):

1. **Light view** (:func:`fit_light_view`): the sun is approximated by a pinhole
   camera far away along the light direction, ``DISTANCE_RADII`` (= 50) radii of
   the casters' bounding sphere from its centre, looking back along the light;
   its rays then deviate at most atan(1/50) = 1.1 deg from parallel. The image
   (``size_px`` square) is fitted to the casters' projected extent (plus their
   largest splat's 3 sigma), so every shadow falls inside the map and a receiver
   that projects outside it is lit. Fit once per sequence (the casters' union over
   all frames) and the texels stay put: shadows do not shimmer as objects move.
2. **Depth map** (:meth:`ShadowMapper.render`): the label rasterizer
   (``data_gen.render.labels``, binarised coverage at alpha 0.5, nearest splat wins)
   draws the *casters* from the light; the depth is where each texel's ray meets
   the winning splat (``depth_mode="surface"``: the ray-plane hit of a flat splat).
3. **Lookup** (warp kernels): a receiver point — each pixel's surface point (its
   camera depth along the pixel ray, :meth:`ShadowMapper.pixel_visibility`) or each
   splat's centre (:meth:`ShadowMapper.visibility`) — is projected into the map; it
   is lit by a texel when its light-space depth is at most the texel's depth + bias
   (or the texel is empty). Percentage-closer filtering over the 3 x 3 texels
   around it gives the visibility in [0, 1] (0, 1/9, ..., 1), which softens the
   edge over about one texel.

Bias: the receiver point is first moved ``bias_m`` along its normal (turned to the
light's side: a *normal offset*, which lifts it out from under the few millimetres
a neighbouring face's splats reach past a shared edge), then compared with a depth
bias of ``bias_m`` + ``SLOPE_TEXELS`` x texel size at the receiver x tan(angle between
its normal and the light), the tangent capped at ``MAX_SLOPE``: a tilted lit surface
changes depth across the filter's reach by that much, so it does not shadow itself;
surfaces nearly edge-on to the light get no key light anyway (n . l ~ 0). In the
pixel test, a pixel whose nearest splat faces away from the light counts as lit
(its own direct light is 0; what direct light the pixel has comes from overlapping
neighbours).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass

import numpy as np
import warp as wp
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from data_gen.render.labels import LabelRasterizer
from data_gen.render.projection import to_warp
from newtphys.geometry import look_at

#: Distance of the light's camera from the casters' centre, in radii of their bounding sphere.
DISTANCE_RADII = 50.0
#: Slope-scaled bias: texels of depth change per unit tan(angle) allowed before a splat shadows itself.
SLOPE_TEXELS = 2.0
#: Largest tan(angle between normal and light) used by the slope bias (about 79 deg).
MAX_SLOPE = 5.0
#: Extra fraction of the fitted extent left on each side of the map.
FIT_MARGIN = 0.02


@dataclass(frozen=True)
class LightView:
    """The light's pinhole camera: intrinsics ``K`` (px), ``world_to_light`` (4x4, m) and map side (px)."""

    K: NDArray[np.float64]
    world_to_light: NDArray[np.float64]
    size_px: int


def fit_light_view(direction: ArrayLike, caster_points_m: ArrayLike | Sequence[ArrayLike], splat_radius_m: float,
                   size_px: int) -> LightView:  # fmt: skip
    """A ``size_px`` square light view seeing all ``caster_points_m`` from ``direction`` (towards the light).

    ``caster_points_m``: one (n, 3) array, or a sequence of them (e.g. one per object and frame: read in blocks,
    never joined, so a sequence's 10^7 positions cost no copy; the view is the same as for their concatenation).
    ``splat_radius_m`` (>= 0) widens the fit by the casters' largest splat extent.
    """
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    if int(size_px) < 8:
        raise ValueError(f"shadow map size_px must be >= 8, got {size_px}")
    blocks = list(_point_blocks(caster_points_m))
    if not blocks:
        blocks = [np.zeros((1, 3))]
    lo = np.min([b.min(axis=0) for b in blocks], axis=0)
    hi = np.max([b.max(axis=0) for b in blocks], axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(float(np.linalg.norm(hi - lo)) * 0.5 + float(splat_radius_m), 1e-3)
    distance = DISTANCE_RADII * radius
    up = (1.0, 0.0, 0.0) if abs(d[2]) > 0.99 else (0.0, 0.0, 1.0)
    w2l = look_at(centre + distance * d, centre, up)
    half_x = half_y = -np.inf
    for b in blocks:  # loop over blocks of points: the largest tangent each way, in the light's frame
        p = b @ w2l[:3, :3].T + w2l[:3, 3]
        z = p[:, 2] - splat_radius_m
        half_x = max(half_x, float(np.max((np.abs(p[:, 0]) + splat_radius_m) / z)))
        half_y = max(half_y, float(np.max((np.abs(p[:, 1]) + splat_radius_m) / z)))
    half = (1.0 + FIT_MARGIN) * max(half_x, half_y, 1e-6)
    f = 0.5 * size_px / half
    K = np.array([[f, 0.0, 0.5 * size_px], [0.0, f, 0.5 * size_px], [0.0, 0.0, 1.0]])
    return LightView(K, w2l, int(size_px))


FIT_BLOCK_ROWS = 1 << 18
"""Rows :func:`fit_light_view` transforms at a time (per-row arithmetic: the view does not depend on it)."""


def _point_blocks(points: ArrayLike | Sequence[ArrayLike]) -> Iterator[NDArray[np.float64]]:
    """Non-empty float64 (m, 3) blocks of at most ``FIT_BLOCK_ROWS`` rows of one array or a sequence of arrays."""
    is_one_array = isinstance(points, np.ndarray) or (len(points) > 0 and np.ndim(points[0]) <= 1)
    for part in [points] if is_one_array else points:
        rows = np.asarray(part, np.float64).reshape(-1, 3)
        for start in range(0, len(rows), FIT_BLOCK_ROWS):
            yield rows[start:start + FIT_BLOCK_ROWS]


@wp.struct
class ShadowParams:
    """A light view and the shadow test's constants, for the lookup kernels."""

    rotation: wp.mat33  # world -> light
    translation: wp.vec3  # m
    f: float  # px (square pixels)
    c: float  # principal point, px (x and y: square map)
    size: int
    bias_m: float
    slope_texels: float
    max_slope: float
    direction: wp.vec3  # unit, towards the light


@wp.func
def light_visibility(x: wp.vec3, n: wp.vec3, p: ShadowParams, shadow_depth: wp.array(dtype=float)) -> float:
    """Share of the 3 x 3 texels around world point x whose caster depth does not hide it (1 outside the map)."""
    side = wp.where(wp.dot(n, p.direction) < 0.0, -1.0, 1.0)
    q = p.rotation * (x + (side * p.bias_m) * n) + p.translation  # normal offset, towards the light's side
    z = q[2]
    if z <= 1e-9:
        return 1.0
    ix = int(wp.floor(p.f * q[0] / z + p.c))
    iy = int(wp.floor(p.f * q[1] / z + p.c))
    cos = wp.clamp(wp.abs(wp.dot(n, p.direction)), 1e-6, 1.0)
    slope = wp.min(wp.sqrt(wp.max(1.0 - cos * cos, 0.0)) / cos, p.max_slope)
    bias = p.bias_m + p.slope_texels * (z / p.f) * slope
    lit = float(0.0)
    for dy in range(-1, 2):
        for dx in range(-1, 2):
            tx = ix + dx
            ty = iy + dy
            if tx < 0 or tx >= p.size or ty < 0 or ty >= p.size:
                lit += 1.0
            else:
                d = shadow_depth[ty * p.size + tx]
                if d <= 0.0 or z <= d + bias:
                    lit += 1.0
    return lit / 9.0


@wp.kernel
def point_visibility_kernel(
    points: wp.array(dtype=wp.vec3),
    normals: wp.array(dtype=wp.vec3),
    params: ShadowParams,
    shadow_depth: wp.array(dtype=float),
    visibility: wp.array(dtype=float),
):
    """Thread per receiver point (a splat centre)."""
    i = wp.tid()
    visibility[i] = light_visibility(points[i], normals[i], params, shadow_depth)


@wp.struct
class PixelFrame:
    """A camera's intrinsics (px) and camera-to-world rotation / centre (m), to place pixels in the world."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    camera_to_world: wp.mat33
    centre: wp.vec3


@wp.kernel
def pixel_visibility_kernel(
    index: wp.array(dtype=wp.int32),
    depth_m: wp.array(dtype=float),
    normals: wp.array(dtype=wp.vec3),
    frame: PixelFrame,
    params: ShadowParams,
    shadow_depth: wp.array(dtype=float),
    visibility: wp.array(dtype=float),
):
    """Thread per pixel: its surface point (camera depth along the pixel ray, the label winner's normal).

    A winner turned away from the light (n . l <= 0) adds no direct light of its own: the pixel's direct
    light comes from neighbours it overlaps (e.g. a face's splats reaching past an edge over the next
    face), whose shadow it cannot tell, so it counts as lit (its own direct term is 0 anyway)."""
    k = wp.tid()
    i = index[k]
    if i < 0:
        visibility[k] = 1.0
        return
    if wp.dot(normals[i], params.direction) <= 0.0:
        visibility[k] = 1.0
        return
    x = k % frame.width
    y = k / frame.width
    z = depth_m[k]
    cam = wp.vec3((float(x) + 0.5 - frame.cx) / frame.fx * z, (float(y) + 0.5 - frame.cy) / frame.fy * z, z)
    world = frame.camera_to_world * cam + frame.centre
    visibility[k] = light_visibility(world, normals[i], params, shadow_depth)


class ShadowMapper:
    """Renders casters' depth from a light view and looks receivers up in it (buffers reused across frames)."""

    def __init__(self, size_px: int, bias_m: float, device: str = "cpu", num_threads: int = 2) -> None:
        if not (np.isfinite(bias_m) and bias_m >= 0.0):
            raise ValueError(f"shadow bias_m must be a finite distance >= 0 m, got {bias_m}")
        self.size_px, self.bias_m, self.device = int(size_px), float(bias_m), device
        self.rasterizer = LabelRasterizer(self.size_px, self.size_px, device, num_threads, depth_mode="surface")
        self._empty = wp.zeros(self.size_px * self.size_px, dtype=float, device=device)
        self._depth = self._empty
        self.view: LightView | None = None
        wp.load_module(__name__, device=device)

    @property
    def depth_m(self) -> NDArray[np.float32]:
        """The last light-space depth map (size, size) float32, m (0 = no caster)."""
        return self._depth.numpy().reshape(self.size_px, self.size_px).copy()

    def render(self, casters: Gaussians, view: LightView) -> None:
        """Draw ``casters``' depth seen from ``view`` into the map (kept on the device for the lookups)."""
        if view.size_px != self.size_px:
            raise ValueError(f"light view is {view.size_px} px but this shadow map is {self.size_px} px")
        self.view = view
        if len(casters) == 0:
            self._depth = self._empty
            return
        self.rasterizer.render(casters, view.K, view.world_to_light)
        self._depth = self.rasterizer.depth_m

    def _params(self, direction: ArrayLike) -> ShadowParams:
        if self.view is None:
            raise RuntimeError("ShadowMapper: render() a shadow map before looking it up")
        v = self.view
        d = np.asarray(direction, np.float64)
        p = ShadowParams()
        p.rotation = wp.mat33(v.world_to_light[:3, :3].astype(np.float32))
        p.translation = wp.vec3(*v.world_to_light[:3, 3].astype(np.float32).tolist())
        p.f, p.c, p.size = float(v.K[0, 0]), float(v.K[0, 2]), self.size_px
        p.bias_m, p.slope_texels, p.max_slope = self.bias_m, SLOPE_TEXELS, MAX_SLOPE
        p.direction = wp.vec3(*(d / np.linalg.norm(d)).astype(np.float32).tolist())
        return p

    def visibility(self, points_m: ArrayLike, normals: ArrayLike, direction: ArrayLike) -> NDArray[np.float32]:
        """Share (n,) float32 in [0, 1] of the 3 x 3 texels around each world point (n, 3) that see the light.

        ``normals`` (n, 3) unit (sign ignored; for the slope bias), ``direction`` towards the light.
        """
        params = self._params(direction)
        pts = np.ascontiguousarray(np.asarray(points_m, np.float32).reshape(-1, 3))
        out = wp.empty(len(pts), dtype=float, device=self.device)
        if len(pts):
            nrm = np.ascontiguousarray(np.asarray(normals, np.float32).reshape(-1, 3))
            wp.launch(point_visibility_kernel, dim=len(pts),
                      inputs=[to_warp(pts, wp.vec3, self.device), to_warp(nrm, wp.vec3, self.device), params,
                              self._depth], outputs=[out], device=self.device)  # fmt: skip
        return out.numpy().copy()

    def pixel_visibility(
        self,
        K: ArrayLike,
        world_to_camera: ArrayLike,
        label_index: NDArray[np.int32],
        label_depth_m: NDArray[np.float32],
        normals: ArrayLike | wp.array,
        direction: ArrayLike,
    ) -> NDArray[np.float32]:
        """Visibility (H, W) float32 of every pixel's surface point: camera depth ``label_depth_m`` along its
        ray, slope bias from the label winner's normal (``normals`` (N, 3) per Gaussian, or a (N,) vec3 warp array on
        this mapper's device); 1 where no splat."""
        params = self._params(direction)
        k = np.asarray(K, np.float64)
        m = np.asarray(world_to_camera, np.float64)
        frame = PixelFrame()
        frame.fx, frame.fy, frame.cx, frame.cy = float(k[0, 0]), float(k[1, 1]), float(k[0, 2]), float(k[1, 2])
        h, w = label_index.shape
        frame.width = w
        frame.camera_to_world = wp.mat33(m[:3, :3].T.astype(np.float32))
        frame.centre = wp.vec3(*(-m[:3, :3].T @ m[:3, 3]).astype(np.float32).tolist())
        d = self.device
        out = wp.empty(h * w, dtype=float, device=d)
        index = wp.array(np.ascontiguousarray(label_index, np.int32).reshape(-1), dtype=wp.int32, device=d)
        depth = to_warp(np.ascontiguousarray(label_depth_m, np.float32).reshape(-1), float, d)
        if isinstance(normals, wp.array):  # (e.g. shading's facing normals, already on the device)
            if normals.dtype != wp.vec3 or normals.device != wp.get_device(d):
                raise ValueError(f"normals: a vec3 array on {d} expected, got {normals.dtype} on {normals.device}")
            nrm = normals
        else:
            nrm = to_warp(np.ascontiguousarray(np.asarray(normals, np.float32).reshape(-1, 3)), wp.vec3, d)
        wp.launch(pixel_visibility_kernel, dim=h * w, inputs=[index, depth, nrm, frame, params, self._depth],
                  outputs=[out], device=d)  # fmt: skip
        return out.numpy().reshape(h, w).copy()
