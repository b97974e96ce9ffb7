"""Per-splat shading: the colours a lit RGB render composites (labels never read them).

Every splat gets one colour per frame, computed from its albedo (the colour the
asset baked into the Gaussian), its unit normal at that frame (rotated and
deformed with the object, ``data_gen.gaussians.deform_normals``), the scene's
light (``data_gen.scene_light.SceneLight``) and its shadow visibility ``v`` in
[0, 1] (``data_gen.render.shadow_map``):

    rgb = albedo * (ambient + intensity * color * max(0, n . l) * v)        (clipped to [0, 1])

* **Two-sided** splats (``two_sided``: those whose normal is a splat's shortest
  axis, of arbitrary sign, e.g. a 3DGS file without ``nx ny nz``) have their
  normal flipped to face the camera (n . (camera - centre) >= 0) first: a thin
  disc seen from either side is lit on the side the camera sees. Oriented
  normals (meshes, shapes, grids, files with normals) are used as they are, so a
  face turned away from the light is dark whichever way the camera looks.
* **Baked shading**: procedural assets (library objects, layouts) bake no light
  into their colours, so those are pure albedo. Imported splat *objects* keep
  what their capture baked in as part of the albedo (they are lit like any
  object). Captured *scenes* (``prelit``) already hold their real light, so
  they are not relit: their colour is only multiplied by the ratio of shadowed to
  unshadowed light, (ambient + intensity color (n . l) v) / (ambient + intensity
  color (n . l)), which is exactly 1 where no inserted object shadows them.

Shading (n . l) is per splat, at its centre: exact for flat splats. Shadow
visibility is applied per splat (``shade``) or, through ``shade_parts``, per
pixel (``data_gen.render.lighting``: rgb = ambient image + visibility x direct image).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data_gen.scene_light import SceneLight

F32 = NDArray[np.float32]


def camera_facing(normals: ArrayLike, centres_m: ArrayLike, camera_centre_m: ArrayLike) -> NDArray[np.float64]:
    """Unit normals (n, 3) flipped where they point away from the camera at ``camera_centre_m`` (world, m)."""
    n = np.asarray(normals, np.float64)
    to_cam = np.asarray(camera_centre_m, np.float64)[None, :] - np.asarray(centres_m, np.float64)
    flip = np.einsum("ij,ij->i", n, to_cam) < 0.0
    return np.where(flip[:, None], -n, n)


def facing_normals(
    normals: ArrayLike, centres_m: ArrayLike, camera_centre_m: ArrayLike, two_sided: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Unit normals (n, 3) as shading uses them: two-sided ones turned to the camera, the others as given."""
    facing = np.asarray(normals, np.float64)
    if two_sided is None:
        return facing
    flip = np.asarray(two_sided, bool)
    if flip.shape != (len(facing),):
        raise ValueError(f"two_sided must have shape ({len(facing)},), got {flip.shape}")
    if not flip.any():
        return facing
    facing = facing.copy()
    facing[flip] = camera_facing(facing[flip], np.asarray(centres_m)[flip], camera_centre_m)
    return facing


def shade_parts(
    albedo_rgb: ArrayLike,
    normals: ArrayLike,
    centres_m: ArrayLike,
    camera_centre_m: ArrayLike,
    light: SceneLight,
    prelit: ArrayLike | None = None,
    two_sided: ArrayLike | None = None,
) -> tuple[F32, F32]:
    """(ambient part, direct part), each (n, 3) float32 clipped to [0, 1]: the lit colour is
    ambient + visibility x direct, so shadows can be applied per splat or per pixel.

    Plain splats: ambient = albedo x ambient, direct = albedo x intensity x color x max(0, n . l).
    Prelit splats: both divided by (ambient + intensity x color x max(0, n . l)) (1 where that is 0: all
    ambient), so an unshadowed prelit splat keeps its colour. ``prelit`` / ``two_sided`` as in :func:`shade`.
    """
    albedo = np.asarray(albedo_rgb, np.float64)
    n = len(albedo)
    facing = facing_normals(normals, centres_m, camera_centre_m, two_sided)
    cos = np.maximum(facing @ np.asarray(light.direction, np.float64), 0.0)  # (n,)
    key = light.intensity * cos[:, None] * np.asarray(light.color_rgb, np.float64)[None, :]  # (n, 3)
    ambient = np.full((n, 3), light.ambient)
    if prelit is not None:
        mask = np.asarray(prelit, bool)
        if mask.shape != (n,):
            raise ValueError(f"prelit must have shape ({n},), got {mask.shape}")
        total = light.ambient + key[mask]
        ok = total > 0.0
        safe = np.where(ok, total, 1.0)
        ambient[mask] = np.where(ok, light.ambient / safe, 1.0)
        key[mask] = np.where(ok, key[mask] / safe, 0.0)
    parts = (np.clip(albedo * ambient, 0.0, 1.0), np.clip(albedo * key, 0.0, 1.0))
    return parts[0].astype(np.float32), parts[1].astype(np.float32)


def shade(
    albedo_rgb: ArrayLike,
    normals: ArrayLike,
    centres_m: ArrayLike,
    camera_centre_m: ArrayLike,
    light: SceneLight,
    visibility: ArrayLike | None = None,
    prelit: ArrayLike | None = None,
    two_sided: ArrayLike | None = None,
) -> F32:
    """Lit colours (n, 3) float32 in [0, 1] of n splats (see the module docstring).

    ``visibility`` (n,) in [0, 1] (None: no shadows, all 1); ``prelit`` (n,) bool marks captured-scene
    splats whose colours already hold their light (None: none); ``two_sided`` (n,) bool marks splats
    whose normal sign is unknown and is turned to the camera (None: none).
    """
    ambient, direct = shade_parts(albedo_rgb, normals, centres_m, camera_centre_m, light, prelit, two_sided)
    n = len(ambient)
    vis = np.ones(n) if visibility is None else np.asarray(visibility, np.float64)
    if vis.shape != (n,):
        raise ValueError(f"visibility must have shape ({n},), got {vis.shape}")
    return np.clip(ambient + vis[:, None] * direct, 0.0, 1.0).astype(np.float32)
