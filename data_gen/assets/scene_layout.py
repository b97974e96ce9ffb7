"""The scene layout type: the static stage a scenario plays on (kinematic, no DOFs), as data.

A ``SceneLayout`` is the ground plane z = 0 (a textured floor; the half-space
z < 0 is solid) plus furniture-like oriented ``SceneBox``es, each with a material
class and a procedural texture, plus named ``PlacementRegion``s — free
axis-aligned boxes above supporting surfaces where objects may be dropped.  A
captured layout (``data_gen.assets.captured``) renders its own splats instead
and may collide through sample points of its geometry.  Each layout carries its
light (``light``: a directional key light plus ambient, ``data_gen.scene_light``).

The simulator's collision geometry is built from it
(``data_gen.pipeline.sim_static_scene`` -> ``data_gen.sim.static_scene.StaticScene``);
the renderer reads the boxes and the floor texture (via
``gaussians_from_geometry.gaussians_from_scene``); the shard writer reads
``to_world_state``.  Nobody changes a layout after it is built.  The catalogue
is ``data_gen.assets.layouts``; look layouts up by name through
``data_gen.assets.registry.get_scene_layout``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data_gen.assets.materials import ProceduralTexture, get_material
from data_gen.assets.shapes import Box, Transformed
from data_gen.gaussians import Gaussians
from data_gen.scene_light import DEFAULT_LIGHT, SceneLight

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]
IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)


def _vec3(owner: str, name: str, v: ArrayLike) -> Vec3:
    a = np.asarray(v, np.float64)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        raise ValueError(f"{owner}: {name} must be 3 finite numbers (m), got {v}")
    return (float(a[0]), float(a[1]), float(a[2]))


@dataclass(frozen=True)
class SceneBox:
    """An oriented static box: centre (m), half extents (m), rotation (w, x, y, z), material and texture."""

    name: str
    center_m: Vec3
    half_extents_m: Vec3
    material: str
    texture: ProceduralTexture
    rotation_wxyz: Quat = IDENTITY

    def __post_init__(self) -> None:
        _vec3(self.name, "center_m", self.center_m)
        h = _vec3(self.name, "half_extents_m", self.half_extents_m)
        if min(h) <= 0.0:
            raise ValueError(
                f"scene box {self.name!r}: half_extents_m must be > 0 m, got {self.half_extents_m}"
            )
        get_material(self.material)

    def shape(self) -> Transformed:
        """The box as a placed ``shapes.Box`` (world frame), built once (the box is immutable)."""
        shape = self.__dict__.get("_shape_cache")
        if shape is None:
            shape = Transformed(Box(self.half_extents_m), self.center_m, self.rotation_wxyz)
            object.__setattr__(self, "_shape_cache", shape)
        return shape


@dataclass(frozen=True)
class PlacementRegion:
    """Free axis-aligned box [min_m, max_m] (m) above a supporting surface; object centres go inside."""

    name: str
    min_m: Vec3
    max_m: Vec3

    def __post_init__(self) -> None:
        lo = np.asarray(_vec3(self.name, "min_m", self.min_m))
        hi = np.asarray(_vec3(self.name, "max_m", self.max_m))
        if np.any(hi <= lo):
            raise ValueError(
                f"placement region {self.name!r}: max_m {self.max_m} must exceed min_m {self.min_m}"
            )
        if lo[2] <= 0.0:
            raise ValueError(
                f"placement region {self.name!r}: min_m z must be above the floor (> 0 m), got {lo[2]}"
            )

    def sample(self, count: int, rng: np.random.Generator) -> NDArray[np.float64]:
        """``count`` uniform points (count, 3) inside the region, m."""
        if count < 0:
            raise ValueError(f"count must be >= 0, got {count}")
        return rng.uniform(self.min_m, self.max_m, size=(count, 3))


@dataclass(frozen=True)
class SceneLayout:
    """Ground plane z = 0 (textured square of ``floor_half_extent_m`` for rendering) plus static boxes."""

    name: str
    kind: str
    floor_texture: ProceduralTexture
    floor_material: str
    boxes: tuple[SceneBox, ...]
    regions: tuple[PlacementRegion, ...]
    floor_half_extent_m: float = 3.0
    splats: Gaussians | None = field(default=None, compare=False)
    """Captured scenes: the file's splats (world frame, Z-up, m), rendered instead of floor and boxes."""
    source: dict[str, str] | None = field(default=None, compare=False)
    """Captured scenes: provenance of the file (``{"file": file name, "sha256": digest}``), never its path."""
    collision_points_m: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    """Captured scenes: (n, 3) samples of the collidable captured geometry (world, m); the solid is the
    union of balls of ``collision_radius_m`` around them (the simulator looks them up in a hash grid)."""
    collision_radius_m: float = 0.0
    light: SceneLight = DEFAULT_LIGHT
    """The scene's key and ambient light (``data_gen.scene_light``), read by lit renders."""

    def __post_init__(self) -> None:
        get_material(self.floor_material)
        if not self.floor_half_extent_m > 0.0:
            raise ValueError(
                f"scene {self.name!r}: floor_half_extent_m must be > 0 m, got {self.floor_half_extent_m}"
            )
        if not self.regions:
            raise ValueError(f"scene {self.name!r}: needs at least one placement region")
        if self.collision_points_m is not None and not self.collision_radius_m > 0.0:
            raise ValueError(
                f"scene {self.name!r}: collision_radius_m must be > 0 m with collision points, "
                f"got {self.collision_radius_m}"
            )

    def region(self, name: str) -> PlacementRegion:
        for r in self.regions:
            if r.name == name:
                return r
        raise KeyError(
            f"scene {self.name!r} has no region {name!r}; regions: {[r.name for r in self.regions]}"
        )

    def sdf_and_part(self, points_m: ArrayLike) -> tuple[NDArray[np.float64], NDArray[np.int32]]:
        """Signed distance (n,) to the static geometry, m (floor half-space z < 0 is solid), and the part:
        0 = floor, k + 1 = ``boxes[k]``, ``len(boxes) + 1`` = the captured collision points."""
        p = np.asarray(points_m, np.float64).reshape(-1, 3)
        d = [p[:, 2]] + [b.shape().sdf(p) for b in self.boxes]  # loop over boxes, vectorised over points
        if self.collision_points_m is not None:
            nearest, _ = self._collision_tree.query(p)
            d.append(nearest - self.collision_radius_m)
        stack = np.stack(d)
        k = np.argmin(stack, axis=0).astype(np.int32)
        return stack[k, np.arange(len(p))], k

    @functools.cached_property
    def _collision_tree(self):
        """k-d tree over the collision points (built on first use; the scene is immutable)."""
        from scipy.spatial import cKDTree

        return cKDTree(self.collision_points_m)

    def support_height(self, xy_m: ArrayLike, reach_m: float) -> float:
        """Top (m) of the collidable captured geometry within ``reach_m`` horizontally of ``xy_m``: the
        highest collision ball there; 0.0 (the floor) where there is none or the scene has no points."""
        if self.collision_points_m is None:
            return 0.0
        pts = self.collision_points_m
        near = np.linalg.norm(pts[:, :2] - np.asarray(xy_m, np.float64)[:2], axis=1) <= reach_m + self.collision_radius_m
        return float(pts[near, 2].max() + self.collision_radius_m) if near.any() else 0.0

    def sdf(self, points_m: ArrayLike) -> NDArray[np.float64]:
        """Signed distance (n,) to the static geometry, m; negative inside a box or below the floor."""
        return self.sdf_and_part(points_m)[0]

    def to_world_state(self) -> dict[str, Any]:
        """The world-state ``scene`` entry (JSON-ready)."""
        extra: dict[str, Any] = {}
        if self.splats is not None:
            extra = {"source": self.source, "num_splats": len(self.splats)}
        if self.collision_points_m is not None:
            extra["collision"] = {
                "num_points": len(self.collision_points_m),
                "radius_m": self.collision_radius_m,
            }
        return extra | {
            "name": self.name,
            "kind": self.kind,
            "floor": {
                "z": 0.0,
                "material": self.floor_material,
                "texture": self.floor_texture.kind,
                "half_extent": self.floor_half_extent_m,
            },
            "boxes": [
                {
                    "name": b.name,
                    "center": list(b.center_m),
                    "half_extents": list(b.half_extents_m),
                    "rotation": list(b.rotation_wxyz),
                    "material": b.material,
                    "texture": b.texture.kind,
                }
                for b in self.boxes
            ],
            "regions": [{"name": r.name, "min": list(r.min_m), "max": list(r.max_m)} for r in self.regions],
            "light": self.light.to_dict(),
        }
