"""Lit colours of every splat of one sequence, frame by frame: shadow map + shading.

``SceneLighting`` ties :mod:`data_gen.render.shadow_map` (which splats see the
light) to :mod:`data_gen.render.shading` (how bright they are). The pipeline
builds one per sequence, fits its light view once to the casters' positions over
all frames, and per frame turns the frame's Gaussians (albedo + normals) into the
colours the RGB rasterizer composites. The label maps are rendered from the same
Gaussians and never read colours, so lighting cannot change them.

Who casts and who receives (``casters`` / ``prelit`` masks, chosen by the pipeline):
every splat receives; objects and a procedural layout's boxes cast (the floor
plane z = 0 cannot occlude anything above it); in a captured scene only the
inserted objects cast (its walls and ceiling would block a sun that the capture's
own light never came from) and the captured splats are ``prelit``.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from data_gen.render.shading import shade
from data_gen.render.shadow_map import LightView, ShadowMapper, fit_light_view
from data_gen.scene_light import SceneLight
from newtphys.geometry import camera_pose


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
    ) -> None:
        self.light = light
        self.mapper = ShadowMapper(shadow_map_px, shadow_bias_m, device, num_threads) if shadows else None
        self.view: LightView | None = None

    def fit(self, caster_points_m: ArrayLike, splat_radius_m: float) -> None:
        """Fit the light view to every position (n, 3) a caster centre takes in the sequence, m."""
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
        if self.mapper is not None:
            mask = np.asarray(casters, bool)
            if mask.shape != (len(gaussians),):
                raise ValueError(f"casters must have shape ({len(gaussians)},), got {mask.shape}")
            if self.view is None:
                self.fit(gaussians.means_m[mask], _largest_extent_m(gaussians, mask))
            assert self.view is not None
            self.mapper.render(gaussians.subset(mask), self.view)
            visibility = self.mapper.visibility(gaussians.means_m, normals, self.light.direction)
        centre, _ = camera_pose(np.asarray(world_to_camera, np.float64))
        return shade(gaussians.colors_rgb, normals, gaussians.means_m, centre, self.light, visibility, prelit, two_sided)


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
