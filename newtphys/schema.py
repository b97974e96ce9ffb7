"""The data contract: every map's name, dtype, shape pattern, unit and meaning.

This module is the single source of truth for what a NewtPhys shard holds
(docs/data_contract.md). Writers, readers, the validator, the dataset, the
visualiser and the probes all look names, dtypes and units up here; no other
module spells a map name as a string literal.

Shape patterns use the symbols ``T`` (frames), ``H`` and ``W`` (image rows and
columns, pixels) and ``N`` (number of objects); integers are fixed sizes.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

SCHEMA_VERSION: int = 1
"""Version of the shard layout and world-state JSON; raised on any breaking change."""

# --------------------------------------------------------------------------- #
# Physical and sampling conventions
# --------------------------------------------------------------------------- #
DEFAULT_FPS: float = 25.0
MAX_SEQUENCE_SECONDS: float = 10.0
EARTH_GRAVITY_M_S2: float = 9.81
OOD_GRAVITY_RANGE_M_S2: tuple[float, float] = (0.98, 20.0)
"""Closed interval of gravity magnitudes sampled uniformly on the OOD split."""

BACKGROUND_ID: int = 0
"""Object, material and semantic id of 'nothing' (static scene or background)."""


class Split(str, Enum):
    """Dataset splits. ``test_ood_gravity`` draws g uniformly from OOD_GRAVITY_RANGE_M_S2."""

    TRAIN = "train"
    VAL = "val"
    TEST = "test"
    TEST_OOD_GRAVITY = "test_ood_gravity"


SPLITS: tuple[str, ...] = tuple(s.value for s in Split)


class MapKind(str, Enum):
    """How a map is drawn and how its values are interpreted."""

    COLOR = "color"  # uint8 RGB
    SCALAR = "scalar"  # continuous, one channel
    SIGNED_SCALAR = "signed_scalar"  # continuous, sign matters (diverging colour map)
    LABEL = "label"  # integer ids
    MASK = "mask"  # boolean
    VECTOR3 = "vector3"  # 3-vector per pixel, camera frame
    FLOW2 = "flow2"  # 2-vector per pixel, image plane


@dataclass(frozen=True)
class MapSpec:
    """One per-frame dataset of a sequence group."""

    name: str
    dtype: np.dtype
    shape: tuple[str | int, ...]
    unit: str
    kind: MapKind
    description: str
    background: float | int | bool = 0
    """Value off objects / with no surface."""

    @property
    def per_object(self) -> bool:
        """True for amodal maps, which hold one slice per object (axis 1)."""
        return "N" in self.shape

    @property
    def channels(self) -> int:
        """Trailing channel count (1 for maps without a channel axis)."""
        last = self.shape[-1]
        return last if isinstance(last, int) else 1

    def expected_shape(self, t: int, h: int, w: int, n: int) -> tuple[int, ...]:
        sizes = {"T": t, "H": h, "W": w, "N": n}
        return tuple(sizes[s] if isinstance(s, str) else s for s in self.shape)


def _spec(name, dtype, shape, unit, kind, description, background=0) -> MapSpec:
    return MapSpec(name, np.dtype(dtype), tuple(shape), unit, kind, description, background)


# Map names (import these instead of spelling strings).
RGB = "rgb"
DEPTH = "depth"
INSTANCES = "instances"
SEMANTIC_SEGMENTATION = "semantic_segmentation"
MATERIALS = "materials"
COLLISION = "collision"
GRAVITY = "gravity"
STRESS = "stress"
SCENE_FLOW = "scene_flow"
OPTICAL_FLOW = "optical_flow"
AMODAL_INSTANCES = "amodal_instances"
AMODAL_MATERIALS = "amodal_materials"
AMODAL_SEMANTIC_SEGMENTATION = "amodal_semantic_segmentation"

MAPS: dict[str, MapSpec] = {
    s.name: s
    for s in (
        _spec(RGB, np.uint8, ("T", "H", "W", 3), "srgb_uint8", MapKind.COLOR, "rendered colour"),
        _spec(
            DEPTH,
            np.float32,
            ("T", "H", "W"),
            "m",
            MapKind.SCALAR,
            "camera-frame z of the visible surface; 0 = no surface",
        ),
        _spec(
            INSTANCES,
            np.uint16,
            ("T", "H", "W"),
            "id",
            MapKind.LABEL,
            "object id of the visible surface (1-based); 0 = scene/background",
        ),
        _spec(
            SEMANTIC_SEGMENTATION,
            np.uint16,
            ("T", "H", "W"),
            "id",
            MapKind.LABEL,
            "semantic class id (table in world state); 0 = background",
        ),
        _spec(
            MATERIALS,
            np.uint8,
            ("T", "H", "W"),
            "id",
            MapKind.LABEL,
            "material id (table in world state); 0 = none",
        ),
        _spec(
            COLLISION,
            np.bool_,
            ("T", "H", "W"),
            "bool",
            MapKind.MASK,
            "the visible surface point is in contact at frame t",
            False,
        ),
        _spec(
            GRAVITY,
            np.float32,
            ("T", "H", "W", 3),
            "N",
            MapKind.VECTOR3,
            "gravity force on the object the pixel shows (mass x gravity vector), "
            "camera frame of frame t; 0 off objects",
        ),
        _spec(
            STRESS,
            np.float32,
            ("T", "H", "W"),
            "Pa",
            MapKind.SIGNED_SCALAR,
            "signed hydrostatic Cauchy stress at the nearest cubature point; "
            "negative = compression; 0 off objects",
        ),
        _spec(
            SCENE_FLOW,
            np.float32,
            ("T", "H", "W", 3),
            "m",
            MapKind.VECTOR3,
            "3D displacement from frame t to t+1 of the surface point seen at the pixel, "
            "camera frame of frame t; last frame 0",
        ),
        _spec(
            OPTICAL_FLOW,
            np.float32,
            ("T", "H", "W", 2),
            "px",
            MapKind.FLOW2,
            "forward optical flow (dx, dy) from frame t to t+1; last frame 0",
        ),
        _spec(
            AMODAL_INSTANCES,
            np.bool_,
            ("T", "N", "H", "W"),
            "bool",
            MapKind.MASK,
            "full silhouette of object n+1, ignoring occlusion",
            False,
        ),
        _spec(
            AMODAL_MATERIALS,
            np.uint8,
            ("T", "N", "H", "W"),
            "id",
            MapKind.LABEL,
            "material ids over each full silhouette",
        ),
        _spec(
            AMODAL_SEMANTIC_SEGMENTATION,
            np.uint16,
            ("T", "N", "H", "W"),
            "id",
            MapKind.LABEL,
            "semantic ids over each full silhouette",
        ),
    )
}
"""Every per-frame map of the contract, by name, in canonical order."""

MAP_NAMES: tuple[str, ...] = tuple(MAPS)
GROUND_TRUTH_MAP_NAMES: tuple[str, ...] = tuple(n for n in MAPS if n != RGB)

# --------------------------------------------------------------------------- #
# Non-map datasets of a sequence group
# --------------------------------------------------------------------------- #
CAMERA_GROUP = "camera"
CAMERA_K = "camera/K"
CAMERA_WORLD_TO_CAMERA = "camera/world_to_camera"
WORLD_STATE = "world_state"


@dataclass(frozen=True)
class ArraySpec:
    """A non-map array dataset of a sequence group."""

    name: str
    dtype: np.dtype
    shape: tuple[str | int, ...]
    unit: str
    description: str

    def expected_shape(self, t: int) -> tuple[int, ...]:
        return tuple(t if s == "T" else s for s in self.shape)  # type: ignore[misc]


CAMERA_ARRAYS: dict[str, ArraySpec] = {
    CAMERA_K: ArraySpec(CAMERA_K, np.dtype(np.float32), (3, 3), "px", "pinhole intrinsics"),
    CAMERA_WORLD_TO_CAMERA: ArraySpec(
        CAMERA_WORLD_TO_CAMERA,
        np.dtype(np.float32),
        ("T", 4, 4),
        "m",
        "world-to-camera rigid transform per frame (OpenCV camera: x right, y down, z forward); "
        "translation in m",
    ),
}
WORLD_STATE_UNIT = "json"

# --------------------------------------------------------------------------- #
# File-level layout
# --------------------------------------------------------------------------- #
FILE_ATTR_SCHEMA_VERSION = "schema_version"
FILE_ATTR_SPLIT = "split"
FILE_ATTR_GENERATOR = "generator"
FILE_ATTR_CONFIG = "config"
FILE_ATTRS: tuple[str, ...] = (
    FILE_ATTR_SCHEMA_VERSION,
    FILE_ATTR_SPLIT,
    FILE_ATTR_GENERATOR,
    FILE_ATTR_CONFIG,
)
UNITS_ATTR = "units"
INDEX_FILENAME = "index.json"
SHARD_PATTERN = "shard-{index:05d}.h5"
SHARD_GLOB = "shard-*.h5"


def shard_filename(index: int) -> str:
    """File name of shard number ``index`` (``shard-00042.h5``)."""
    if index < 0:
        raise ValueError(f"shard index must be >= 0, got {index}")
    return SHARD_PATTERN.format(index=index)


def get_map(name: str) -> MapSpec:
    """Look a map up by name; unknown names list the valid ones."""
    try:
        return MAPS[name]
    except KeyError:
        raise KeyError(f"unknown map {name!r}; valid maps: {', '.join(MAP_NAMES)}") from None
