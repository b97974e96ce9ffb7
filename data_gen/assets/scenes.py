"""Procedural static scene layouts as data: the ground plane z = 0 plus oriented boxes.

A ``StaticScene`` is kinematic geometry (no DOFs): a textured floor (the
half-space z < 0 is solid) and furniture-like oriented boxes, each with a
material class and a procedural texture, plus named placement regions — free
axis-aligned boxes above supporting surfaces where objects may be dropped.

The simulator reads ``sdf`` (contact); the renderer reads the boxes and the
floor texture (via ``gaussians_from_geometry.gaussians_from_scene``); the shard
writer reads ``to_world_state``. Nobody changes a scene after it is built.

``get_scene("ply:<path>?up=y&scale=1.0")`` loads a captured 3DGS scene
(``data_gen.assets.captured``): its splats render, and only the ground plane
z = 0 collides (captured furniture is not collidable yet).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from data_gen.assets.materials import ProceduralTexture, get_material
from data_gen.assets.shapes import Box, Transformed
from newtphys.rotations import axis_angle_to_quat

if TYPE_CHECKING:  # a runtime import would be circular (gaussians_from_geometry imports this module)
    from data_gen.assets.gaussians_from_geometry import SurfaceGaussians

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
        """The box as a placed ``shapes.Box`` (world frame)."""
        return Transformed(Box(self.half_extents_m), self.center_m, self.rotation_wxyz)


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
class StaticScene:
    """Ground plane z = 0 (textured square of ``floor_half_extent_m`` for rendering) plus static boxes."""

    name: str
    kind: str
    floor_texture: ProceduralTexture
    floor_material: str
    boxes: tuple[SceneBox, ...]
    regions: tuple[PlacementRegion, ...]
    floor_half_extent_m: float = 3.0
    splats: SurfaceGaussians | None = field(default=None, compare=False)
    """Captured scenes: the file's splats (world frame, Z-up, m), rendered instead of floor and boxes."""
    source: str = ""
    """Captured scenes: the reference the scene was loaded from."""
    collision_points_m: NDArray[np.float64] | None = field(default=None, compare=False, repr=False)
    """Captured scenes: (n, 3) samples of the collidable captured geometry (world, m); the solid is the
    union of balls of ``collision_radius_m`` around them (the simulator looks them up in a hash grid)."""
    collision_radius_m: float = 0.0

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
        }


# --------------------------------------------------------------------------- #
# Layouts
# --------------------------------------------------------------------------- #
WOOD = ((0.72, 0.52, 0.30), (0.62, 0.42, 0.24), (0.80, 0.62, 0.40))
DARK_WOOD = ((0.45, 0.30, 0.18), (0.38, 0.25, 0.15), (0.52, 0.36, 0.22))


def _planks(colors: tuple = WOOD, period_m: float = 0.12, axis: int = 0, seed: int = 0) -> ProceduralTexture:
    return ProceduralTexture("planks", colors, period_m, axis, 0.3, seed)


def _region_above(
    name: str, box: SceneBox, margin_m: float, z_min_m: float, z_max_m: float
) -> PlacementRegion:
    """Region over an axis-aligned box's top face, shrunk by ``margin_m``, from top + z_min to top + z_max."""
    c, h = np.asarray(box.center_m), np.asarray(box.half_extents_m)
    top = c[2] + h[2]
    return PlacementRegion(
        name,
        (c[0] - h[0] + margin_m, c[1] - h[1] + margin_m, top + z_min_m),
        (c[0] + h[0] - margin_m, c[1] + h[1] - margin_m, top + z_max_m),
    )


def _empty_floor() -> StaticScene:
    floor = ProceduralTexture("checker", ((0.80, 0.80, 0.78), (0.35, 0.35, 0.38)), 0.25)
    return StaticScene(
        "empty_floor",
        "floor",
        floor,
        "ceramic",
        (),
        (PlacementRegion("floor", (-0.6, -0.6, 0.1), (0.6, 0.6, 0.9)),),
    )


def _table() -> StaticScene:
    top = SceneBox("table_top", (0.0, 0.0, 0.735), (0.6, 0.4, 0.015), "wood", _planks(DARK_WOOD, 0.1))
    legs = tuple(
        SceneBox(
            f"table_leg_{i}",
            (0.55 * sx, 0.35 * sy, 0.36),
            (0.025, 0.025, 0.36),
            "wood",
            _planks(DARK_WOOD, 0.05, 2),
        )
        for i, (sx, sy) in enumerate(((-1, -1), (-1, 1), (1, -1), (1, 1)))
    )
    floor = _planks(WOOD, 0.15, 0, seed=3)
    regions = (
        _region_above("table_top", top, 0.12, 0.08, 0.6),
        PlacementRegion("floor_front", (0.8, -0.5, 0.1), (1.3, 0.5, 0.6)),
    )
    return StaticScene("table", "table", floor, "wood", (top,) + legs, regions)


def _bench_steps() -> StaticScene:
    grey = ProceduralTexture("noise", ((0.60, 0.60, 0.62),), 0.05, contrast=0.15, seed=5)
    bench = SceneBox("bench", (0.0, 0.6, 0.225), (0.6, 0.18, 0.225), "wood", _planks(WOOD, 0.06, 0, seed=1))
    steps = tuple(
        SceneBox(
            f"step_{i}", (0.0, -0.3 - 0.3 * i, 0.075 * (i + 1)), (0.5, 0.15, 0.075 * (i + 1)), "ceramic", grey
        )
        for i in range(3)
    )
    floor = ProceduralTexture("tiles", ((0.75, 0.72, 0.68), (0.30, 0.30, 0.30)), 0.3, seed=2)
    regions = (
        (_region_above("bench", bench, 0.08, 0.08, 0.6),)
        + tuple(_region_above(f"step_{i}", s, 0.05, 0.08, 0.5) for i, s in enumerate(steps))
        + (PlacementRegion("floor", (0.8, -0.6, 0.1), (1.3, 0.6, 0.6)),)
    )
    return StaticScene("bench_steps", "bench_steps", floor, "ceramic", (bench,) + steps, regions)


def _shelf_wall() -> StaticScene:
    wall = SceneBox(
        "wall",
        (-0.5, 0.0, 1.0),
        (0.05, 1.5, 1.0),
        "ceramic",
        ProceduralTexture("noise", ((0.85, 0.83, 0.78),), 0.1, contrast=0.06, seed=7),
    )
    boards = tuple(
        SceneBox(
            f"shelf_{i}",
            (-0.3, 0.0, 0.35 + 0.45 * i),
            (0.15, 0.6, 0.012),
            "wood",
            _planks(WOOD, 0.08, 1, seed=10 + i),
        )
        for i in range(3)
    )
    floor = ProceduralTexture("tiles", ((0.55, 0.45, 0.35), (0.2, 0.18, 0.15)), 0.4, seed=4)
    regions = tuple(_region_above(f"shelf_{i}", b, 0.04, 0.06, 0.3) for i, b in enumerate(boards)) + (
        PlacementRegion("floor", (0.1, -0.8, 0.1), (0.9, 0.8, 0.7)),
    )
    return StaticScene("shelf_wall", "shelf", floor, "ceramic", (wall,) + boards, regions)


RAMP_ANGLE_DEG = 20.0


def _ramp() -> StaticScene:
    angle = np.deg2rad(RAMP_ANGLE_DEG)
    half_len, half_thick = 0.6, 0.02
    # the plank rises toward -x: rotate about +y by +angle (x axis tilts down at +x)
    rot = tuple(axis_angle_to_quat((0.0, 1.0, 0.0), angle).tolist())
    cz = half_len * np.sin(angle) + half_thick * np.cos(angle)  # lowest corner touches z = 0
    ramp = SceneBox(
        "ramp", (0.0, 0.0, float(cz)), (half_len, 0.3, half_thick), "wood", _planks(WOOD, 0.1, 0, seed=8), rot
    )
    # a block under the high end whose top meets the plank's underside z = cz - t / cos - x tan at its inner edge
    x_inner = -half_len * np.cos(angle) + 0.1
    support_top = float(cz - half_thick / np.cos(angle) - x_inner * np.tan(angle))
    support = SceneBox(
        "ramp_support",
        (x_inner - 0.05, 0.0, 0.5 * support_top),
        (0.05, 0.3, 0.5 * support_top),
        "wood",
        _planks(DARK_WOOD, 0.1, 2, seed=9),
    )
    floor = ProceduralTexture("noise", ((0.45, 0.55, 0.40),), 0.2, contrast=0.25, seed=6)
    # top surface height along x: z_top(x) = cz + t/cos - x tan(angle); region over the upper third
    x0, x1 = -0.45, -0.2
    z_top = float(cz + half_thick / np.cos(angle) - x0 * np.tan(angle))
    regions = (
        PlacementRegion("ramp_top", (x0, -0.2, z_top + 0.08), (x1, 0.2, z_top + 0.5)),
        PlacementRegion("floor", (0.8, -0.6, 0.1), (1.3, 0.6, 0.6)),
    )
    return StaticScene("ramp", "ramp", floor, "wood", (ramp, support), regions)


def _room_corner() -> StaticScene:
    paint = ProceduralTexture("noise", ((0.90, 0.88, 0.82),), 0.15, contrast=0.05, seed=11)
    paint2 = ProceduralTexture("noise", ((0.70, 0.80, 0.88),), 0.15, contrast=0.05, seed=12)
    wall_x = SceneBox("wall_x", (-1.05, 0.0, 1.2), (0.05, 1.5, 1.2), "ceramic", paint)
    wall_y = SceneBox("wall_y", (0.4, -1.05, 1.2), (1.5, 0.05, 1.2), "ceramic", paint2)
    skirting = SceneBox("skirting", (-0.99, 0.0, 0.04), (0.01, 1.5, 0.04), "wood", _planks(DARK_WOOD, 0.1, 1))
    floor = _planks(WOOD, 0.14, 0, seed=13)
    regions = (
        PlacementRegion("corner", (-0.85, -0.85, 0.1), (-0.2, -0.2, 0.9)),
        PlacementRegion("floor", (-0.2, -0.2, 0.1), (0.6, 0.6, 0.7)),
    )
    return StaticScene("room_corner", "room", floor, "wood", (wall_x, wall_y, skirting), regions)


_LAYOUTS: dict[str, Callable[[], StaticScene]] = {
    "empty_floor": _empty_floor,
    "table": _table,
    "bench_steps": _bench_steps,
    "shelf_wall": _shelf_wall,
    "ramp": _ramp,
    "room_corner": _room_corner,
}


def list_scenes() -> list[str]:
    """Names of all scene layouts."""
    return list(_LAYOUTS)


def get_scene(name: str) -> StaticScene:
    """The scene layout ``name``; an unknown name lists the valid ones.

    ``"ply:<path>?up=<axis>&scale=<factor>&..."`` loads a captured 3DGS scene
    (see ``data_gen.assets.captured``).
    """
    if name.startswith("ply:"):
        from data_gen.assets.captured import captured_scene  # lazy: captured.py builds on this module

        return captured_scene(name)
    if name not in _LAYOUTS:
        raise KeyError(f"unknown scene {name!r}; valid scenes: {', '.join(list_scenes())}")
    return _LAYOUTS[name]()
