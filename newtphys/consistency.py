"""Cross-map consistency of one sequence: do the maps tell one physical story?

Each check returns a :class:`Residual` (worst and mean error with its unit,
and how many pixels it covered). They need only the shard (maps, camera,
world state), so they run on any dataset: ``python -m newtphys validate
--deep`` reports the ones above tolerance, and the generator's tests assert
on them.

* optical flow = projection of (back-projected depth + scene flow) into the
  next camera, minus the pixel centre;
* gravity at a pixel = mass of the object shown x gravity vector, rotated
  into the camera frame;
* materials / semantic ids at a pixel = the table ids of the object shown;
* collision pixels only on objects that have a contact in that frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from newtphys import geometry, schema
from newtphys.shards import SequenceArrays


@dataclass(frozen=True)
class Residual:
    name: str
    max_error: float
    mean_error: float
    unit: str
    num_pixels: int

    def __str__(self) -> str:
        return f"{self.name}: max {self.max_error:.3g} {self.unit}, mean {self.mean_error:.3g} {self.unit} over {self.num_pixels} px"


def _residual(name: str, err: np.ndarray, unit: str) -> Residual:
    if err.size == 0:
        return Residual(name, 0.0, 0.0, unit, 0)
    return Residual(name, float(err.max()), float(err.mean()), unit, int(err.size))


def optical_flow_from_scene_flow(
    depth: np.ndarray, scene_flow: np.ndarray, K: np.ndarray, w2c_t: np.ndarray, w2c_next: np.ndarray
) -> np.ndarray:
    """(H, W, 2) flow implied by depth + scene flow (camera frame of t) and the two camera poses."""
    pts_cam = geometry.backproject_depth(depth, K)
    c2w = geometry.rigid_inverse(w2c_t)
    pts_world = geometry.transform_points(c2w, pts_cam)
    moved = pts_world + geometry.rotate_vectors(c2w, scene_flow)
    uv_next, _ = geometry.project(geometry.transform_points(w2c_next, moved), K)
    return uv_next - geometry.pixel_centers(*depth.shape)


def check_optical_flow(seq: SequenceArrays) -> Residual:
    m = seq.maps
    errs = []
    for t in range(seq.world_state.num_frames - 1):
        surface = m[schema.DEPTH][t] > 0
        expected = optical_flow_from_scene_flow(
            m[schema.DEPTH][t], m[schema.SCENE_FLOW][t], seq.K, seq.world_to_camera[t], seq.world_to_camera[t + 1]
        )
        errs.append(np.linalg.norm(expected - m[schema.OPTICAL_FLOW][t], axis=-1)[surface])
    return _residual("optical_flow vs projected scene_flow", np.concatenate(errs) if errs else np.zeros(0), "px")


def check_gravity(seq: SequenceArrays) -> Residual:
    ws = seq.world_state
    g = np.asarray(ws.gravity, np.float64)
    mass = np.zeros(max([o.id for o in ws.objects], default=0) + 1)
    for o in ws.objects:
        mass[o.id] = o.mass
    errs = []
    for t in range(ws.num_frames):
        ids = seq.maps[schema.INSTANCES][t].astype(np.int64)
        expected = mass[ids][..., None] * geometry.rotate_vectors(seq.world_to_camera[t], g)
        err = np.linalg.norm(seq.maps[schema.GRAVITY][t] - expected, axis=-1)
        scale = np.maximum(np.linalg.norm(expected, axis=-1), 1e-12)
        errs.append((err / np.where(ids > 0, scale, 1.0)).ravel())
    return _residual("gravity vs mass x g (relative)", np.concatenate(errs), "rel")


def _table_ids(table: dict[str, str]) -> dict[str, int]:
    return {name: int(k) for k, name in table.items()}


def check_labels(seq: SequenceArrays) -> Residual:
    """Fraction of object pixels whose material / semantic id disagrees with the world state."""
    ws = seq.world_state
    mat_ids, sem_ids = _table_ids(ws.materials), _table_ids(ws.semantic_classes)
    size = max([o.id for o in ws.objects], default=0) + 1
    exp_mat = np.zeros(size, np.int64)
    exp_sem = np.zeros(size, np.int64)
    for o in ws.objects:
        exp_mat[o.id] = mat_ids.get(o.material, -1)
        exp_sem[o.id] = sem_ids.get(o.category, -1)
    ids = seq.maps[schema.INSTANCES].astype(np.int64)
    on = ids > 0
    wrong = (seq.maps[schema.MATERIALS] != exp_mat[ids]) | (seq.maps[schema.SEMANTIC_SEGMENTATION] != exp_sem[ids])
    frac = float(wrong[on].mean()) if on.any() else 0.0
    return Residual("material/semantic ids vs world state", frac, frac, "fraction", int(on.sum()))


def check_collision(seq: SequenceArrays) -> Residual:
    """Fraction of collision pixels on objects that have no contact in that frame."""
    ws = seq.world_state
    bad = total = 0
    for t, fr in enumerate(ws.frames):
        in_contact = np.zeros(max([o.id for o in ws.objects], default=0) + 1, bool)
        for o in fr.objects:
            in_contact[o.id] = bool(o.contacts)
        col = seq.maps[schema.COLLISION][t]
        ids = seq.maps[schema.INSTANCES][t].astype(np.int64)
        total += int(col.sum())
        bad += int((col & ~in_contact[ids]).sum())
    frac = bad / total if total else 0.0
    return Residual("collision pixels without a contact", frac, frac, "fraction", total)


CHECKS = (check_optical_flow, check_gravity, check_labels, check_collision)
TOLERANCES = {
    "optical_flow vs projected scene_flow": 0.05,  # px; float32 storage of depth and flow
    "gravity vs mass x g (relative)": 1e-5,
    "material/semantic ids vs world state": 0.0,
    "collision pixels without a contact": 0.0,
}


def check_sequence(seq: SequenceArrays) -> list[Residual]:
    return [check(seq) for check in CHECKS]


def failing(residuals: list[Residual]) -> list[Residual]:
    """Residuals whose worst error exceeds its tolerance."""
    return [r for r in residuals if r.max_error > TOLERANCES[r.name]]
