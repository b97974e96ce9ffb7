"""World-state dataclasses and their JSON form (docs/data_contract.md).

``WorldState.to_json`` / ``WorldState.from_json`` round-trip exactly. Parsing
validates every key and type and the physical ranges (positive masses, unit
quaternions, Poisson ratio in [0, 0.5), ...); an error names the sequence and
the full key path (``objects[2].mass``) and quotes the offending value.

Units: SI everywhere (m, kg, s, N, Pa); quaternions are (w, x, y, z); vectors
are in the world frame (Z up).
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from dataclasses import dataclass, field
from typing import Any

from newtphys.schema import SCHEMA_VERSION

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]


class WorldStateError(ValueError):
    """A world-state JSON document is malformed or physically invalid."""


@dataclass
class _Record:
    """Base of every world-state record: keys a newer writer added are kept in ``extra``.

    The contract lets writers add fields (never rename them); readers keep
    what they do not know so that a document round-trips unchanged.
    """

    extra: dict[str, Any] = field(default_factory=dict, kw_only=True)


@dataclass
class CameraPose(_Record):
    position: Vec3
    """Camera centre, world frame, m."""
    rotation: Quat
    """Camera-to-world rotation (w, x, y, z) of the OpenCV camera frame."""


@dataclass
class ObjectFrameState(_Record):
    id: int
    position: Vec3
    """Centre of mass, world frame, m."""
    orientation: Quat
    """Rotation (w, x, y, z) of the best-fit rigid motion from rest."""
    velocity: Vec3
    """Centre-of-mass velocity, m/s."""
    angular_velocity: Vec3
    """rad/s, world frame."""
    visible_pixels: int
    visible_fraction: float
    """visible pixels / pixels of the full (amodal) silhouette; 0 when out of view."""
    in_view: bool
    contacts: list[int]
    """Ids of what the object touches at this frame (0 = the static scene)."""


@dataclass
class FrameState(_Record):
    index: int
    time: float
    """s since the start of the sequence."""
    camera: CameraPose
    objects: list[ObjectFrameState]


@dataclass
class ObjectInfo(_Record):
    id: int
    name: str
    category: str
    material: str
    young_modulus: float
    """Pa."""
    poisson_ratio: float
    density: float
    """kg/m^3."""
    mass: float
    """kg."""
    volume: float
    """m^3."""
    size: Vec3
    """Axis-aligned extent at rest, m."""
    num_handles: int
    num_cubature_points: int


@dataclass
class CollisionEvent(_Record):
    """One contact onset between a pair (b = 0: the static scene)."""

    frame: int
    objects: tuple[int, int]
    position: Vec3
    """m, world frame."""
    normal: Vec3
    """Unit normal, world frame, pointing from b to a."""
    impulse: float
    """N s, integrated over the contact episode."""
    peak_force: float
    """N."""


@dataclass
class SceneInfo(_Record):
    """Scene fields beyond name and kind (layout, ...) live in ``extra``."""

    name: str
    kind: str


@dataclass
class SimulationInfo(_Record):
    """Solver fields beyond the required ones live in ``extra``."""

    quality: str
    dt: float
    """s."""
    substeps: int
    newton_iterations: int
    wall_time_s: float


@dataclass
class WorldState(_Record):
    schema_version: int
    sequence_id: str
    seed: int
    split: str
    fps: float
    num_frames: int
    image_size: tuple[int, int]
    """(H, W), pixels."""
    gravity: Vec3
    """m/s^2, world frame."""
    scene: SceneInfo
    materials: dict[str, str]
    """Material id (as a string key) -> name."""
    semantic_classes: dict[str, str]
    """Semantic id (as a string key) -> name."""
    objects: list[ObjectInfo]
    frames: list[FrameState]
    collisions: list[CollisionEvent]
    simulation: SimulationInfo

    # ------------------------------------------------------------------ #
    def to_dict(self) -> dict[str, Any]:
        return _encode(self)

    def to_json(self, indent: int | None = None) -> str:
        return json.dumps(self.to_dict(), indent=indent, allow_nan=False)

    @classmethod
    def from_dict(cls, data: Any, sequence_id: str | None = None) -> WorldState:
        sid = sequence_id
        if sid is None and isinstance(data, dict) and isinstance(data.get("sequence_id"), str):
            sid = data["sequence_id"]
        ctx = _Context(sid or "<unknown>")
        state = _decode(cls, data, "", ctx)
        _check_physics(state, ctx)
        return state

    @classmethod
    def from_json(cls, text: str | bytes, sequence_id: str | None = None) -> WorldState:
        try:
            data = json.loads(text)
        except json.JSONDecodeError as e:
            raise WorldStateError(
                f"world state of sequence '{sequence_id or '<unknown>'}': not valid JSON ({e})"
            ) from None
        return cls.from_dict(data, sequence_id)

    # convenience --------------------------------------------------------
    def object_by_id(self, object_id: int) -> ObjectInfo:
        for obj in self.objects:
            if obj.id == object_id:
                return obj
        raise KeyError(f"sequence {self.sequence_id!r} has no object id {object_id}")

    @property
    def gravity_magnitude(self) -> float:
        return math.sqrt(sum(g * g for g in self.gravity))


# --------------------------------------------------------------------------- #
# Generic encode / decode with type checking
# --------------------------------------------------------------------------- #
_FLATTENED_EXTRA = "extra"


def _encode(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        out: dict[str, Any] = {}
        for f in dataclasses.fields(obj):
            value = getattr(obj, f.name)
            if f.name == _FLATTENED_EXTRA:
                for k, v in value.items():
                    out[k] = _encode(v)
            else:
                out[f.name] = _encode(value)
        return out
    if isinstance(obj, (list, tuple)):
        return [_encode(v) for v in obj]
    if isinstance(obj, dict):
        return {str(k): _encode(v) for k, v in obj.items()}
    if hasattr(obj, "item") and callable(obj.item):  # numpy / torch scalars
        return obj.item()
    return obj


@dataclass
class _Context:
    sequence_id: str

    def error(self, path: str, message: str) -> WorldStateError:
        where = path or "<root>"
        return WorldStateError(
            f"world state of sequence '{self.sequence_id}': key '{where}': {message}"
        )


def _join(path: str, key: str | int) -> str:
    if isinstance(key, int):
        return f"{path}[{key}]"
    return f"{path}.{key}" if path else key


def _short(value: Any) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


_HINTS: dict[type, dict[str, Any]] = {}


def _hints(cls: type) -> dict[str, Any]:
    if cls not in _HINTS:
        _HINTS[cls] = typing.get_type_hints(cls)
    return _HINTS[cls]


def _decode(tp: Any, value: Any, path: str, ctx: _Context) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if dataclasses.is_dataclass(tp):
        return _decode_dataclass(tp, value, path, ctx)
    if tp is Any:
        return value
    if tp is bool:
        if not isinstance(value, bool):
            raise ctx.error(path, f"expected a boolean, got {_short(value)}")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ctx.error(path, f"expected an integer, got {_short(value)}")
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ctx.error(path, f"expected a number, got {_short(value)}")
        if not math.isfinite(value):
            raise ctx.error(path, f"expected a finite number, got {_short(value)}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ctx.error(path, f"expected a string, got {_short(value)}")
        return value
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ctx.error(path, f"expected a list of {len(args)} items, got {_short(value)}")
        if len(value) != len(args):
            raise ctx.error(path, f"expected {len(args)} items, got {len(value)}")
        return tuple(_decode(a, v, _join(path, i), ctx) for i, (a, v) in enumerate(zip(args, value)))
    if origin is list:
        if not isinstance(value, list):
            raise ctx.error(path, f"expected a list, got {_short(value)}")
        return [_decode(args[0], v, _join(path, i), ctx) for i, v in enumerate(value)]
    if origin is dict:
        if not isinstance(value, dict):
            raise ctx.error(path, f"expected an object, got {_short(value)}")
        return {
            _decode(args[0], k, _join(path, str(k)), ctx): _decode(args[1], v, _join(path, str(k)), ctx)
            for k, v in value.items()
        }
    if origin in (typing.Union, types.UnionType):
        raise TypeError(f"unsupported union type at {path}")  # not used by the schema
    raise TypeError(f"unsupported type {tp!r} at {path}")


def _decode_dataclass(cls: type, value: Any, path: str, ctx: _Context) -> Any:
    if not isinstance(value, dict):
        raise ctx.error(path, f"expected an object, got {_short(value)}")
    hints = _hints(cls)
    kwargs: dict[str, Any] = {}
    names = [f.name for f in dataclasses.fields(cls)]
    for name in names:
        if name == _FLATTENED_EXTRA:
            continue
        if name not in value:
            raise ctx.error(_join(path, name), "missing")
        kwargs[name] = _decode(hints[name], value[name], _join(path, name), ctx)
    if _FLATTENED_EXTRA in value:
        raise ctx.error(_join(path, _FLATTENED_EXTRA), "reserved key name")
    kwargs[_FLATTENED_EXTRA] = {k: v for k, v in value.items() if k not in names}
    return cls(**kwargs)


# --------------------------------------------------------------------------- #
# Physical checks
# --------------------------------------------------------------------------- #
def _check_quat(q: Quat, path: str, ctx: _Context) -> None:
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > 1e-3:
        raise ctx.error(path, f"quaternion (w, x, y, z) must have unit norm, got norm {norm:.6g}")


def _check_physics(ws: WorldState, ctx: _Context) -> None:
    if ws.schema_version != SCHEMA_VERSION:
        raise ctx.error(
            "schema_version",
            f"unsupported version {ws.schema_version}; this reader reads version {SCHEMA_VERSION}",
        )
    if ws.fps <= 0:
        raise ctx.error("fps", f"must be > 0 frames/s, got {ws.fps}")
    if ws.num_frames < 1:
        raise ctx.error("num_frames", f"must be >= 1, got {ws.num_frames}")
    if len(ws.frames) != ws.num_frames:
        raise ctx.error("frames", f"has {len(ws.frames)} entries but num_frames is {ws.num_frames}")
    if min(ws.image_size) < 1:
        raise ctx.error("image_size", f"must be positive (H, W) pixels, got {list(ws.image_size)}")
    ids = [o.id for o in ws.objects]
    if len(set(ids)) != len(ids):
        raise ctx.error("objects", f"duplicate object ids {ids}")
    for i, o in enumerate(ws.objects):
        p = _join("objects", i)
        if o.id < 1:
            raise ctx.error(_join(p, "id"), f"object ids are 1-based, got {o.id}")
        for key, low in (("young_modulus", 0.0), ("density", 0.0), ("mass", 0.0), ("volume", 0.0)):
            v = getattr(o, key)
            if not v > low:
                raise ctx.error(_join(p, key), f"must be > 0, got {v}")
        if not 0.0 <= o.poisson_ratio < 0.5:
            raise ctx.error(_join(p, "poisson_ratio"), f"must be in [0, 0.5), got {o.poisson_ratio}")
        if min(o.size) < 0:
            raise ctx.error(_join(p, "size"), f"extents must be >= 0 m, got {list(o.size)}")
    known = set(ids) | {0}
    for fi, fr in enumerate(ws.frames):
        p = _join("frames", fi)
        if fr.index != fi:
            raise ctx.error(_join(p, "index"), f"expected {fi}, got {fr.index}")
        _check_quat(fr.camera.rotation, _join(_join(p, "camera"), "rotation"), ctx)
        for oi, ofs in enumerate(fr.objects):
            q = _join(_join(p, "objects"), oi)
            if ofs.id not in known:
                raise ctx.error(_join(q, "id"), f"object id {ofs.id} is not in 'objects'")
            _check_quat(ofs.orientation, _join(q, "orientation"), ctx)
            if not 0.0 <= ofs.visible_fraction <= 1.0 + 1e-6:
                raise ctx.error(_join(q, "visible_fraction"), f"must be in [0, 1], got {ofs.visible_fraction}")
            if ofs.visible_pixels < 0:
                raise ctx.error(_join(q, "visible_pixels"), f"must be >= 0, got {ofs.visible_pixels}")
            bad = [c for c in ofs.contacts if c not in known]
            if bad:
                raise ctx.error(_join(q, "contacts"), f"unknown object ids {bad}")
    for ci, ev in enumerate(ws.collisions):
        p = _join("collisions", ci)
        if not 0 <= ev.frame < ws.num_frames:
            raise ctx.error(_join(p, "frame"), f"must be in [0, {ws.num_frames}), got {ev.frame}")
        bad = [c for c in ev.objects if c not in known]
        if bad:
            raise ctx.error(_join(p, "objects"), f"unknown object ids {bad}")
        if ev.impulse < 0 or ev.peak_force < 0:
            raise ctx.error(p, f"impulse and peak_force must be >= 0, got {ev.impulse}, {ev.peak_force}")
    if ws.simulation.dt <= 0:
        raise ctx.error("simulation.dt", f"must be > 0 s, got {ws.simulation.dt}")
