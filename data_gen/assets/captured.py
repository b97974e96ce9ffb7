"""Captured 3DGS scenes as ``StaticScene``s: the file's splats render, the ground plane z = 0 collides.

Reference syntax (``scenes.get_scene`` forwards it)::

    ply:<path>?up=<axis>&scale=<factor>&ground=<auto|keep>&material=<name>

* ``up`` — the file's up axis (z, y, -y, x, -x, -z; default z), rotated to +z;
  ``scale`` — file units to metres (default 1);
* ``ground`` — ``auto`` (default) translates the splats vertically so that the
  ``GROUND_PERCENTILE``-th percentile of the splat centres' z (opacity >= 0.1) lies
  on z = 0, a floor estimate for captures whose origin is not on the floor;
  ``keep`` leaves z as in the file (after up/scale);
* ``material`` — the floor's material class (default ``ceramic``).

Collision: only the ground plane z = 0 is collidable. The captured geometry
itself (furniture, walls in the capture) is NOT collidable yet: the scene has no
boxes, so objects pass through captured furniture. One placement region
("footprint") is set above the floor, centred on the splats' footprint (the
2nd-98th percentile box of the centres' x, y), half as wide as that box but at
most ``MAX_REGION_HALF_M`` per side, from 0.1 to 0.9 m above the floor.
"""

from __future__ import annotations

import functools

import numpy as np

from data_gen.assets.asset_uri import parse_asset_uri
from data_gen.assets.gaussians_from_geometry import SurfaceGaussians
from data_gen.assets.materials import ProceduralTexture, get_material
from data_gen.assets.ply_io import UP_AXES, import_splats
from data_gen.assets.scenes import PlacementRegion, StaticScene

SCENE_KEYS = ("up", "scale", "ground", "material")
GROUND_PERCENTILE = 1.0
FOOTPRINT_PERCENTILES = (2.0, 98.0)
MAX_REGION_HALF_M = 0.6
REGION_Z_M = (0.1, 0.9)
MIN_OPACITY = 0.1
_FLOOR_TEXTURE = ProceduralTexture("solid", ((0.6, 0.6, 0.6),))


def captured_scene(reference: str) -> StaticScene:
    """The ``StaticScene`` of a ``ply:`` scene reference (cached per reference and file version)."""
    uri = parse_asset_uri(reference, SCENE_KEYS)
    if not uri.path.is_file():
        raise FileNotFoundError(f"ply: scene file not found: {uri.path}")
    st = uri.path.stat()
    return _load(reference, st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=8)
def _load(reference: str, _mtime_ns: int, _size: int) -> StaticScene:
    uri = parse_asset_uri(reference, SCENE_KEYS)
    up = uri.get("up", "z")
    if up not in UP_AXES:
        raise ValueError(f"{reference}: option up={up!r} must be one of {', '.join(UP_AXES)}")
    ground = uri.get("ground", "auto")
    if ground not in ("auto", "keep"):
        raise ValueError(f"{reference}: option ground={ground!r} must be 'auto' or 'keep'")
    material = uri.get("material", "ceramic")
    get_material(material)
    scale = uri.get_float("scale", 1.0, 1e-9, 1e9)
    g, _ = import_splats(uri.path, scale=scale, up_axis=up)
    solid = g.means_m[g.opacities >= MIN_OPACITY].astype(np.float64)
    if len(solid) == 0:
        raise ValueError(f"{reference}: no splat has opacity >= {MIN_OPACITY}; nothing to place objects on")
    means = g.means_m.astype(np.float64)
    if ground == "auto":
        dz = -float(np.percentile(solid[:, 2], GROUND_PERCENTILE))
        means = means + np.array([0.0, 0.0, dz])
        solid = solid + np.array([0.0, 0.0, dz])
    lo = np.percentile(solid[:, :2], FOOTPRINT_PERCENTILES[0], axis=0)
    hi = np.percentile(solid[:, :2], FOOTPRINT_PERCENTILES[1], axis=0)
    centre = 0.5 * (lo + hi)
    half = np.clip(0.25 * (hi - lo), 0.05, MAX_REGION_HALF_M)
    region = PlacementRegion(
        "footprint",
        (float(centre[0] - half[0]), float(centre[1] - half[1]), REGION_Z_M[0]),
        (float(centre[0] + half[0]), float(centre[1] + half[1]), REGION_Z_M[1]),
    )
    splats = SurfaceGaussians(
        means, g.scales_m, g.rotations_wxyz, g.colors_rgb, g.opacities, np.zeros(len(means), np.int32)
    )
    return StaticScene(
        name=reference,
        kind="captured",
        floor_texture=_FLOOR_TEXTURE,
        floor_material=material,
        boxes=(),
        regions=(region,),
        floor_half_extent_m=float(max(0.5, 0.5 * float((hi - lo).max()))),
        splats=splats,
        source=reference,
    )
