"""One generated sequence as questions see it: world state, cameras, visibility, boxes, names.

Reads a shard (never re-simulates). Every field a question needs that older shards lack raises
:class:`MissingWorldStateField` naming the shard, the sequence, the field and how to regenerate.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from newtphys import schema
from newtphys.rotations import quat_to_matrix
from newtphys.shards import ShardReader
from newtphys.world_state import WorldState

VISIBLE_FRACTION = 0.31
"""An object is visible in a frame when at least this fraction of its silhouette shows ..."""
VISIBLE_AREA_FRACTION = 0.004
"""... and it covers at least this fraction of the image (the paper's 2248 px at 1000 x 562)."""
NAMED_VISIBLE_FRACTION = 0.9
"""A question names an object only when at least this fraction of it shows in the question's frame."""


class MissingWorldStateField(KeyError):
    """A shard written before the questions' world-state fields existed."""


@dataclass(frozen=True)
class Box:
    center_m: np.ndarray
    extents_m: np.ndarray
    rotation: np.ndarray
    """(3, 3) object -> world."""

    @property
    def volume_m3(self) -> float:
        return float(np.prod(self.extents_m))

    def corners(self) -> np.ndarray:
        signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], np.float64)
        return self.center_m + (0.5 * signs * self.extents_m) @ self.rotation.T

    def distance_to_point(self, p: np.ndarray) -> float:
        """Euclidean distance from world point ``p`` to the box (0 inside), m."""
        local = (np.asarray(p, np.float64) - self.center_m) @ self.rotation
        return float(np.linalg.norm(np.maximum(np.abs(local) - 0.5 * self.extents_m, 0.0)))


def box_distance(a: Box, b: Box, iterations: int = 64) -> float:
    """Minimum distance between two oriented boxes, m (0 when they overlap), by alternating projections
    between the two convex sets (converges for convex sets; exact to well below a millimetre here)."""
    p = a.center_m.copy()
    q = b.center_m.copy()
    for _ in range(iterations):
        q = _project(b, p)
        p = _project(a, q)
    return float(np.linalg.norm(p - q))


def _project(box: Box, p: np.ndarray) -> np.ndarray:
    local = (p - box.center_m) @ box.rotation
    half = 0.5 * box.extents_m
    return box.center_m + box.rotation @ np.clip(local, -half, half)


class SequenceView:
    """Read-only access to one sequence of a shard for question generation."""

    def __init__(self, shard: Path, sequence_id: str, shard_relative: str) -> None:
        self.shard = Path(shard)
        self.shard_relative = shard_relative
        self.sequence_id = sequence_id
        with ShardReader(self.shard) as r:
            self.world_state: WorldState = r.world_state(sequence_id)
            self.K = r.intrinsics(sequence_id).astype(np.float64)
            self.world_to_camera = r.world_to_camera(sequence_id).astype(np.float64)
        self._require_fields()

    @classmethod
    def from_arrays(cls, world_state: WorldState, K: np.ndarray, world_to_camera: np.ndarray, shard: Path,
                    shard_relative: str) -> SequenceView:
        """A view of a sequence held in memory (a simulated counterfactual twin); its maps are not readable."""
        view = cls.__new__(cls)
        view.shard, view.shard_relative, view.sequence_id = Path(shard), shard_relative, world_state.sequence_id
        view.world_state = world_state
        view.K = np.asarray(K, np.float64)
        view.world_to_camera = np.asarray(world_to_camera, np.float64)
        view._require_fields()
        return view

    # -- checks ---------------------------------------------------------------
    def _missing(self, field: str) -> MissingWorldStateField:
        return MissingWorldStateField(
            f"{self.shard}: sequence '{self.sequence_id}': world state lacks '{field}', which questions read "
            "(shards written before the VQA fields were added); regenerate the split with generate.py"
        )

    def _require_fields(self) -> None:
        ws = self.world_state
        for key in ("display_name", "material_taxonomy", "color"):
            if any(key not in o.extra for o in ws.objects):
                raise self._missing(f"objects[].{key}")
        if any("box" not in ofs.extra for fr in ws.frames for ofs in fr.objects):
            raise self._missing("frames[].objects[].box")
        if any("fov_x_deg" not in fr.camera.extra for fr in ws.frames):
            raise self._missing("frames[].camera.fov_x_deg")

    # -- sequence facts -----------------------------------------------------------
    @property
    def num_frames(self) -> int:
        return self.world_state.num_frames

    @property
    def image_size(self) -> tuple[int, int]:
        return self.world_state.image_size

    @cached_property
    def object_ids(self) -> list[int]:
        return [o.id for o in self.world_state.objects]

    def name(self, object_id: int) -> str | None:
        """Display name, unique in the scene (None when ambiguous)."""
        return self.world_state.object_by_id(object_id).extra["display_name"]

    def info(self, object_id: int):
        return self.world_state.object_by_id(object_id)

    def state(self, frame: int, object_id: int):
        for ofs in self.world_state.frames[frame].objects:
            if ofs.id == object_id:
                return ofs
        raise KeyError(f"{self.sequence_id}: frame {frame} has no object {object_id}")

    def box(self, frame: int, object_id: int) -> Box:
        b = self.state(frame, object_id).extra["box"]
        return Box(np.asarray(b["center"], np.float64), np.asarray(b["extents"], np.float64),
                   quat_to_matrix(np.asarray(b["rotation"], np.float64)))  # fmt: skip

    def visible(self, frame: int, object_id: int) -> bool:
        """The paper's visibility rule: enough of the silhouette and enough of the image."""
        s = self.state(frame, object_id)
        h, w = self.image_size
        return s.visible_fraction >= VISIBLE_FRACTION and s.visible_pixels >= VISIBLE_AREA_FRACTION * h * w

    def visible_ids(self, frame: int) -> list[int]:
        return [i for i in self.object_ids if self.visible(frame, i)]

    def nameable(self, frame: int, object_id: int) -> bool:
        """A question may name this object at ``frame``: a unique name and >= 90 % of it visible."""
        s = self.state(frame, object_id)
        return self.name(object_id) is not None and self.visible(frame, object_id) and (
            s.visible_fraction >= NAMED_VISIBLE_FRACTION
        )

    def nameable_ids(self, frame: int) -> list[int]:
        return [i for i in self.object_ids if self.nameable(frame, i)]

    def camera_center(self, frame: int) -> np.ndarray:
        w2c = self.world_to_camera[frame]
        return -w2c[:3, :3].T @ w2c[:3, 3]

    def camera_axes(self, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World directions of the camera's forward, right and up axes (OpenCV z, x and -y)."""
        r = self.world_to_camera[frame, :3, :3]
        return r[2], r[0], -r[1]

    def camera_pitch_deg(self, frame: int) -> float:
        """Elevation of the viewing direction above the horizon, degrees (negative: looking down)."""
        forward = self.camera_axes(frame)[0]
        return float(np.degrees(np.arcsin(np.clip(forward[2], -1.0, 1.0))))

    def fov_x_deg(self, frame: int) -> float:
        return float(self.world_state.frames[frame].camera.extra["fov_x_deg"])

    def project(self, frame: int, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (n, 2) (x right, y down) and camera depth (n,) of world points at ``frame``."""
        p = np.asarray(points_world, np.float64) @ self.world_to_camera[frame, :3, :3].T + self.world_to_camera[frame, :3, 3]
        uv = p @ self.K.T
        return uv[:, :2] / uv[:, 2:3], p[:, 2]

    def velocity(self, frame: int, object_id: int) -> np.ndarray:
        return np.asarray(self.state(frame, object_id).velocity, np.float64)

    def position(self, frame: int, object_id: int) -> np.ndarray:
        return np.asarray(self.state(frame, object_id).position, np.float64)

    def acceleration(self, frame: int, object_id: int) -> np.ndarray:
        """Central difference of the recorded velocity (one-sided at the ends), m/s^2."""
        lo, hi = max(frame - 1, 0), min(frame + 1, self.num_frames - 1)
        dt = (hi - lo) / self.world_state.fps
        return (self.velocity(hi, object_id) - self.velocity(lo, object_id)) / dt

    def read_rgb(self, frames: list[int]) -> np.ndarray:
        """RGB frames (len(frames), H, W, 3) uint8 from the shard."""
        with ShardReader(self.shard) as r:
            return np.stack([r.read(self.sequence_id, schema.RGB, t, t + 1)[0] for t in frames])

    def read_instances(self, frames: list[int]) -> np.ndarray:
        """Visible-object id per pixel (len(frames), H, W)."""
        with ShardReader(self.shard) as r:
            return np.stack([r.read(self.sequence_id, schema.INSTANCES, t, t + 1)[0] for t in frames])

    def read_amodal(self, frames: list[int]) -> np.ndarray:
        """Whole-silhouette masks (len(frames), num_objects, H, W) bool, objects in world-state order."""
        with ShardReader(self.shard) as r:
            return np.stack([r.read(self.sequence_id, schema.AMODAL_INSTANCES, t, t + 1)[0] for t in frames])

    def object_index(self, object_id: int) -> int:
        """Position of ``object_id`` in the world state's object list (the amodal maps' object axis)."""
        return self.object_ids.index(object_id)
