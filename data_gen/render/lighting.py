"""Lit colours of every splat of one sequence, frame by frame: shadow map + shading.

``SceneLighting`` ties :mod:`data_gen.render.shadow_map` (which splats see the
light) to :mod:`data_gen.render.shading` (how bright they are). The pipeline
builds one per sequence, fits its light view once to the casters' positions over
all frames, and per frame turns the frame's Gaussians (albedo + normals) into the
colours the RGB rasterizer composites. The label maps are rendered from the same
Gaussians and never read colours, so lighting cannot change them.

Shadow test (``shadow_test``): ``"pixel"`` (default) looks up every pixel's
surface point (label depth map, with the label winner's normal for the slope
bias) in the shadow map and composites two RGB passes, rgb = ambient image +
visibility x direct image: shadows as sharp as the shadow map, twice the RGB cost.
A pixel no splat covers (an object's soft rim) takes the visibility of its nearest
covered pixel.
``"splat"`` looks up each splat's centre and composites one pass: cheaper, but a
shadow edge is as coarse as the receiving splats (2.5 cm floor grid by default).

Who casts and who receives (``casters`` / ``prelit`` masks, chosen by the pipeline):
every splat receives; objects and a procedural layout's boxes cast (the floor
plane z = 0 cannot occlude anything above it); in a captured scene only the
inserted objects cast (its walls and ceiling would block a sun that the capture's
own light never came from) and the captured splats are ``prelit``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import warp as wp
from scipy import ndimage
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from data_gen.render.rgb import RgbRasterizer
from data_gen.render import shading
from data_gen.render.shading import shade, shade_parts_on
from data_gen.render.shadow_map import LightView, ShadowMapper, fit_light_view
from data_gen.scene_light import SceneLight
from newtphys.geometry import camera_pose


#: Where shadows are tested: every pixel's surface point, or every splat's centre.
SHADOW_TESTS = ("pixel", "splat")


class SceneLighting:
    """Shades one sequence's splats under ``light``, with shadows from a ``shadow_map_px`` map when ``shadows``."""

    def __init__(
        self,
        light: SceneLight,
        shadows: bool,
        shadow_map_px: int,
        shadow_bias_m: float,
        device: str = "cpu",
        num_threads: int = 2,
        shadow_test: str = "pixel",
    ) -> None:
        if shadow_test not in SHADOW_TESTS:
            raise ValueError(f"shadow_test must be one of {SHADOW_TESTS}, got {shadow_test!r}")
        self.light = light
        self.shadow_test = shadow_test
        self.device = device
        self.mapper = ShadowMapper(shadow_map_px, shadow_bias_m, device, num_threads) if shadows else None
        self.view: LightView | None = None
        wp.load_module(shading, device=device)  # here, not first inside a caller's threads

    def fit(self, caster_points_m: ArrayLike | Sequence[ArrayLike], splat_radius_m: float) -> None:
        """Fit the light view to every position (n, 3) a caster centre takes in the sequence, m (one array, or a
        sequence of them: :func:`~data_gen.render.shadow_map.fit_light_view`)."""
        if self.mapper is not None:
            self.view = fit_light_view(self.light.direction, caster_points_m, splat_radius_m, self.mapper.size_px)

    def colors(
        self,
        gaussians: Gaussians,
        world_to_camera: ArrayLike,
        casters: ArrayLike,
        prelit: ArrayLike | None = None,
        two_sided: ArrayLike | None = None,
    ) -> NDArray[np.float32]:
        """Lit colours (N, 3) float32 of ``gaussians`` (albedo in ``colors_rgb``) seen by ``world_to_camera``.

        ``casters`` (N,) bool: the splats drawn into the shadow map; ``prelit`` (N,) bool: captured-scene splats;
        ``two_sided`` (N,) bool: splats whose normal sign is unknown (``shading.shade``). Normals are
        ``gaussians.surface_normals()``.
        """
        normals = gaussians.surface_normals()
        visibility = None
        if self._render_shadow_map(gaussians, casters):
            assert self.mapper is not None
            visibility = self.mapper.visibility(gaussians.means_m, normals, self.light.direction)
        centre, _ = camera_pose(np.asarray(world_to_camera, np.float64))
        return shade(gaussians.colors_rgb, normals, gaussians.means_m, centre, self.light, visibility, prelit, two_sided)

    def render_rgb(
        self,
        rasterizer: RgbRasterizer,
        gaussians: Gaussians,
        K: ArrayLike,
        world_to_camera: ArrayLike,
        label_index: NDArray[np.int32],
        label_depth_m: NDArray[np.float32],
        casters: ArrayLike,
        prelit: ArrayLike | None = None,
        two_sided: ArrayLike | None = None,
        background_rgb: ArrayLike = (0.0, 0.0, 0.0),
    ) -> NDArray[np.float32]:
        """The lit RGB image (H, W, 3) float32 in [0, 1] of ``gaussians`` (albedo + normals).

        ``label_index`` / ``label_depth_m`` are the label rasterizer's maps of the same frame (surface
        depth): the pixel test places each pixel on its nearest covering splat. Masks as in :meth:`colors`.
        """
        if self.mapper is None or self.shadow_test == "splat":
            colors = self.colors(gaussians, world_to_camera, casters, prelit, two_sided)
            lit = gaussians.with_colors(colors)
            return rasterizer.render(lit, K, world_to_camera, background_rgb)[0]
        normals = gaussians.surface_normals()
        centre, _ = camera_pose(np.asarray(world_to_camera, np.float64))
        parts = shade_parts_on(gaussians.colors_rgb, normals, gaussians.means_m, centre, self.light, prelit,
                               two_sided, self.device)  # fmt: skip
        ambient, direct = parts.numpy()
        base, key, _ = rasterizer.render_two(gaussians.with_colors(ambient), direct, K, world_to_camera,
                                             background_rgb)  # fmt: skip
        if self._render_shadow_map(gaussians, casters):
            assert self.mapper is not None
            visibility = self.mapper.pixel_visibility(K, world_to_camera, label_index, label_depth_m, parts.facing,
                                                      self.light.direction)
            visibility = _fill_uncovered(visibility, label_index < 0)
        else:
            visibility = np.ones(label_index.shape, np.float32)
        return np.clip(base + visibility[..., None] * key, 0.0, 1.0)

    def _render_shadow_map(self, gaussians: Gaussians, casters: ArrayLike) -> bool:
        """Draw the casters into the shadow map (fitting the view on first use); False without shadows."""
        if self.mapper is None:
            return False
        mask = np.asarray(casters, bool)
        if mask.shape != (len(gaussians),):
            raise ValueError(f"casters must have shape ({len(gaussians)},), got {mask.shape}")
        if self.view is None:
            self.fit(gaussians.means_m[mask], _largest_extent_m(gaussians, mask))
        assert self.view is not None
        self.mapper.render(gaussians.subset(mask), self.view)
        return True


def _fill_uncovered(visibility: NDArray[np.float32], uncovered: NDArray[np.bool_]) -> NDArray[np.float32]:
    """Visibility (H, W) where pixels no splat covers (label index -1: an object's soft rim, alpha < 0.5)
    take their nearest covered pixel's: the rim's direct light is the splats' next to it (else a shadowed
    object would get a lit fringe)."""
    if not uncovered.any() or uncovered.all():
        return visibility
    iy, ix = ndimage.distance_transform_edt(uncovered, return_distances=False, return_indices=True)
    return visibility[iy, ix]


def _largest_extent_m(gaussians: Gaussians, mask: NDArray[np.bool_]) -> float:
    """3 x the largest standard deviation among the masked splats, m (0 when none)."""
    if not mask.any():
        return 0.0
    g = gaussians.subset(mask)
    if g.scales_m is not None:
        return 3.0 * float(g.scales_m.max())
    return 3.0 * float(np.sqrt(np.linalg.eigvalsh(g.covariances()).max()))


def largest_extent_m(gaussians: Gaussians) -> float:
    """3 x the largest standard deviation of ``gaussians``, m: the margin a light view leaves around casters."""
    return _largest_extent_m(gaussians, np.ones(len(gaussians), bool))
