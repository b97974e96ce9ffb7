"""Captured 3DGS scenes as ``SceneLayout``s: the file's splats render; the floor and the captured geometry collide.

Reference syntax (``registry.get_scene_layout`` forwards it)::

    ply:<path>?up=<axis>&scale=<factor>&ground=<auto|keep>&material=<name>&collide=<splats|floor>&thickness=<m>&light=<x>,<y>,<z>

* ``name`` — the scene's name in shards (default: the file's stem; the file name and
  its SHA-256 are recorded as ``source``);
* ``up`` — the file's up axis (z, y, -y, x, -x, -z; default z), rotated to +z;
  ``scale`` — file units to metres (default 1);
* ``ground`` — ``auto`` (default) translates the splats vertically so that the
  ``GROUND_PERCENTILE``-th percentile of the splat centres' z (opacity >= 0.1) lies
  on z = 0, a floor estimate for captures whose origin is not on the floor;
  ``keep`` leaves z as in the file (after up/scale);
* ``material`` — the floor's material class (default ``ceramic``).

* ``collide`` — ``splats`` (default): the captured geometry collides, as the union
  of balls around the splat centres (see below); ``floor``: only the ground plane.
* ``thickness`` — the balls' radius, m (default: 0.75 x the median spacing of the
  collision samples, clipped to [``MIN_THICKNESS_M``, ``MAX_THICKNESS_M``]).
* ``light`` — direction towards the capture's main light, ``x,y,z`` in the scene's
  world frame after ``up`` (z up; normalised; at least 5 deg above the horizon);
  default ``data_gen.scene_light.DEFAULT_LIGHT``'s. Inserted objects are shaded by it
  and cast their shadows along it; the captured splats keep their recorded colours
  (their light is already in them) and only darken where an object shadows them.

Collision: the ground plane z = 0, plus (``collide=splats``) the captured geometry
known by its splat centres (opacity >= ``MIN_OPACITY``) above the floor band
(z > max(2 x thickness, ``FLOOR_BAND_M``): the plane already is the floor, and
capture noise on it would make it bumpy).  The centres are thinned to one per
voxel of edge ``thickness``; neighbours are then at most sqrt(3) thickness apart,
so balls of radius ``thickness`` close the surface.  Objects rest ``thickness``
in front of a captured surface.  The simulator looks the points up in a warp hash
grid (``data_gen.sim.static_scene.StaticPoints``); placement avoids them.  One
placement region ("footprint") is set above the floor, centred on the splats'
footprint (the 2nd-98th percentile box of the centres' x, y), half as wide as that
box but at most ``MAX_REGION_HALF_M`` per side, from 0.1 to 0.9 m above the floor.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from data_gen.assets.asset_uri import file_provenance, parse_asset_uri
from data_gen.assets.materials import ProceduralTexture, get_material
from data_gen.assets.ply_io import UP_AXES, import_splats
from data_gen.assets.scene_layout import PlacementRegion, SceneLayout
from data_gen.scene_light import DEFAULT_LIGHT, SceneLight

SCENE_KEYS = ("name", "up", "scale", "ground", "material", "collide", "thickness", "light")
GROUND_PERCENTILE = 1.0
FOOTPRINT_PERCENTILES = (2.0, 98.0)
MAX_REGION_HALF_M = 0.6
REGION_Z_M = (0.1, 0.9)
MIN_OPACITY = 0.1
MIN_THICKNESS_M, MAX_THICKNESS_M = 0.005, 0.05
FLOOR_BAND_M = 0.02
_FLOOR_TEXTURE = ProceduralTexture("solid", ((0.6, 0.6, 0.6),))


def check_scene_reference(reference: str) -> None:
    """Cheap checks of a ``ply:`` scene reference without loading it: option keys and values, file exists."""
    if reference.partition(":")[0] != "ply":
        raise ValueError(f"scene reference {reference!r}: a captured scene is 'ply:<path>?<options>'")
    uri = parse_asset_uri(reference, SCENE_KEYS)
    uri.display_name()
    _options(uri)
    _light(uri)
    if not uri.path.is_file():
        raise FileNotFoundError(f"ply: scene file not found: {uri.path}")


def _options(uri) -> tuple[str, str, str, float, str, float | None]:
    """(up, ground, material, scale, collide, thickness) of a scene reference, checked."""
    reference = f"{uri.scheme}:{uri.path}"
    up = uri.get("up", "z")
    if up not in UP_AXES:
        raise ValueError(f"{reference}: option up={up!r} must be one of {', '.join(UP_AXES)}")
    ground = uri.get("ground", "auto")
    if ground not in ("auto", "keep"):
        raise ValueError(f"{reference}: option ground={ground!r} must be 'auto' or 'keep'")
    material = uri.get("material", "ceramic")
    get_material(material)
    scale = uri.get_float("scale", 1.0, 1e-9, 1e9)
    collide = uri.get("collide", "splats")
    if collide not in ("splats", "floor"):
        raise ValueError(f"{reference}: option collide={collide!r} must be 'splats' or 'floor'")
    thickness = uri.get_float("thickness", 0.0, MIN_THICKNESS_M, MAX_THICKNESS_M) if "thickness" in dict(uri.options) else None
    return up, ground, material, scale, collide, thickness


def _light(uri) -> SceneLight:
    """The scene's light: the default one, turned towards the ``light`` option's direction when given."""
    text = dict(uri.options).get("light")
    if text is None:
        return DEFAULT_LIGHT
    owner = f"{uri.scheme}:{uri.path}"
    try:
        return DEFAULT_LIGHT.with_direction(SceneLight.parse_direction(text, owner))
    except ValueError as e:
        if str(e).startswith(owner):
            raise
        raise ValueError(f"{owner}: option light={text!r}: {e}") from None


def captured_scene(reference: str) -> SceneLayout:
    """The ``SceneLayout`` of a ``ply:`` scene reference (cached per reference and file version)."""
    uri = parse_asset_uri(reference, SCENE_KEYS)
    if not uri.path.is_file():
        raise FileNotFoundError(f"ply: scene file not found: {uri.path}")
    st = uri.path.stat()
    return _load(reference, st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=8)
def _load(reference: str, _mtime_ns: int, _size: int) -> SceneLayout:
    uri = parse_asset_uri(reference, SCENE_KEYS)
    up, ground, material, scale, collide, thickness = _options(uri)
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
    points, radius = _collision_points(solid, thickness) if collide == "splats" else (None, 0.0)
    splats = dataclasses.replace(g, means_m=means)
    return SceneLayout(
        name=uri.display_name(),
        kind="captured",
        floor_texture=_FLOOR_TEXTURE,
        floor_material=material,
        boxes=(),
        regions=(region,),
        floor_half_extent_m=float(max(0.5, 0.5 * float((hi - lo).max()))),
        splats=splats,
        source=file_provenance(uri.path),
        collision_points_m=points,
        collision_radius_m=radius,
        light=_light(uri),
    )


def _collision_points(solid_m: np.ndarray, thickness_m: float | None) -> tuple[np.ndarray | None, float]:
    """Collision samples (n, 3) m and ball radius (m) of a captured scene's solid splat centres (world, m):
    centres above the floor band, thinned to one per voxel of edge = radius.  (None, 0) if none remain."""
    from scipy.spatial import cKDTree

    above = solid_m[solid_m[:, 2] > FLOOR_BAND_M]
    if len(above) < 2:
        return None, 0.0
    if thickness_m is None:
        spacing = float(np.median(cKDTree(above).query(above, k=2)[0][:, 1]))
        thickness_m = float(np.clip(0.75 * spacing, MIN_THICKNESS_M, MAX_THICKNESS_M))
    above = above[above[:, 2] > max(2.0 * thickness_m, FLOOR_BAND_M)]
    if len(above) == 0:
        return None, 0.0
    voxel = np.floor(above / thickness_m).astype(np.int64)
    _, first = np.unique(voxel, axis=0, return_index=True)
    return above[np.sort(first)], float(thickness_m)
