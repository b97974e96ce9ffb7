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
3. **Per-splat lookup** (:meth:`ShadowMapper.visibility`): each receiver's centre
   is projected into the map; it is lit by a texel when its light-space depth is at
   most the texel's depth + bias (or the texel is empty). Percentage-closer
   filtering over the 3 x 3 texels around it gives the visibility in [0, 1]
   (0, 1/9, ..., 1), which softens the edge over about one texel.

Bias: ``bias_m`` + ``SLOPE_TEXELS`` x texel size at the receiver x tan(angle between
its normal and the light), the tangent capped at ``MAX_SLOPE``: a tilted lit surface
changes depth across the filter's reach by that much, so it does not shadow itself;
surfaces nearly edge-on to the light get no key light anyway (n . l ~ 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from data_gen.render.labels import LabelRasterizer
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


def fit_light_view(direction: ArrayLike, caster_points_m: ArrayLike, splat_radius_m: float, size_px: int) -> LightView:
    """A ``size_px`` square light view seeing all ``caster_points_m`` (n, 3) from ``direction`` (towards the light).

    ``splat_radius_m`` (>= 0) widens the fit by the casters' largest splat extent.
    """
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    pts = np.asarray(caster_points_m, np.float64).reshape(-1, 3)
    if int(size_px) < 8:
        raise ValueError(f"shadow map size_px must be >= 8, got {size_px}")
    if len(pts) == 0:
        pts = np.zeros((1, 3))
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = 0.5 * (lo + hi)
    radius = max(float(np.linalg.norm(hi - lo)) * 0.5 + float(splat_radius_m), 1e-3)
    distance = DISTANCE_RADII * radius
    up = (1.0, 0.0, 0.0) if abs(d[2]) > 0.99 else (0.0, 0.0, 1.0)
    w2l = look_at(centre + distance * d, centre, up)
    p = pts @ w2l[:3, :3].T + w2l[:3, 3]
    z = p[:, 2]
    half_x = float(np.max((np.abs(p[:, 0]) + splat_radius_m) / (z - splat_radius_m)))
    half_y = float(np.max((np.abs(p[:, 1]) + splat_radius_m) / (z - splat_radius_m)))
    half = (1.0 + FIT_MARGIN) * max(half_x, half_y, 1e-6)
    f = 0.5 * size_px / half
    K = np.array([[f, 0.0, 0.5 * size_px], [0.0, f, 0.5 * size_px], [0.0, 0.0, 1.0]])
    return LightView(K, w2l, int(size_px))


class ShadowMapper:
    """Renders casters' depth from a light view and looks receivers up in it (buffers reused across frames)."""

    def __init__(self, size_px: int, bias_m: float, device: str = "cpu", num_threads: int = 2) -> None:
        if not (np.isfinite(bias_m) and bias_m >= 0.0):
            raise ValueError(f"shadow bias_m must be a finite distance >= 0 m, got {bias_m}")
        self.size_px, self.bias_m = int(size_px), float(bias_m)
        self.rasterizer = LabelRasterizer(self.size_px, self.size_px, device, num_threads, depth_mode="surface")
        self.depth_m: NDArray[np.float32] = np.zeros((self.size_px, self.size_px), np.float32)
        self.view: LightView | None = None

    def render(self, casters: Gaussians, view: LightView) -> NDArray[np.float32]:
        """The light-space depth map (size, size) float32, m (0 = no caster) of ``casters`` seen from ``view``."""
        if view.size_px != self.size_px:
            raise ValueError(f"light view is {view.size_px} px but this shadow map is {self.size_px} px")
        self.view = view
        if len(casters) == 0:
            self.depth_m = np.zeros((self.size_px, self.size_px), np.float32)
        else:
            self.depth_m = self.rasterizer.render(casters, view.K, view.world_to_light)[1]
        return self.depth_m

    def visibility(self, centres_m: ArrayLike, normals: ArrayLike, direction: ArrayLike) -> NDArray[np.float32]:
        """Share (n,) float32 in [0, 1] of the 3 x 3 texels around each receiver that see the light.

        ``centres_m`` (n, 3) world, ``normals`` (n, 3) unit (sign ignored), ``direction`` towards the light;
        uses the map of the last :meth:`render`.
        """
        if self.view is None:
            raise RuntimeError("ShadowMapper.visibility needs a render() first")
        v = self.view
        x = np.asarray(centres_m, np.float64).reshape(-1, 3)
        p = x @ v.world_to_light[:3, :3].T + v.world_to_light[:3, 3]
        z = p[:, 2]
        safe_z = np.where(z > 1e-9, z, 1.0)
        u = v.K[0, 0] * p[:, 0] / safe_z + v.K[0, 2]
        w = v.K[1, 1] * p[:, 1] / safe_z + v.K[1, 2]
        texel_m = z / v.K[0, 0]
        d = np.asarray(direction, np.float64)
        cos = np.clip(np.abs(np.asarray(normals, np.float64) @ (d / np.linalg.norm(d))), 1e-6, 1.0)
        slope = np.minimum(np.sqrt(np.maximum(1.0 - cos * cos, 0.0)) / cos, MAX_SLOPE)
        bias = self.bias_m + SLOPE_TEXELS * texel_m * slope
        ix, iy = np.floor(u).astype(np.int64), np.floor(w).astype(np.int64)
        lit = np.zeros(len(x), np.float64)
        size = self.size_px
        for dy in (-1, 0, 1):  # 9 filter taps, vectorised over receivers
            for dx in (-1, 0, 1):
                tx, ty = ix + dx, iy + dy
                inside = (tx >= 0) & (tx < size) & (ty >= 0) & (ty < size) & (z > 1e-9)
                depth = np.zeros(len(x), np.float64)
                depth[inside] = self.depth_m[ty[inside], tx[inside]]
                lit += (~inside) | (depth <= 0.0) | (z <= depth + bias)
        return (lit / 9.0).astype(np.float32)
