"""Label maps mean what the data contract says (docs/data_contract.md), on simulated scenes chosen to show it.

Every map is checked against a reference computed another way: from the world state (masses, poses,
contacts), the cameras and the scene's geometry, on the two sequences of ``label_sequences``
(tests/data_gen/conftest.py: one scenario with free fall, resting, sliding and object-object contact,
seen by an orbiting and by a shaky handheld camera). A bug can hide behind a scene that does not
exercise it (a static camera hides a map rotated with the wrong frame's camera; yaw about the vertical
hides it for a vertical vector), so ``test_label_scenes_exercise_the_labels`` asserts that the scenes
do exercise what the other tests rely on, and each test states its tolerance against the size of the
error it must see.

The ``check_*`` functions return a list of failure messages (empty = the map passes); the last test
shifts each map by one pixel or one frame and asserts that its checks notice.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from newtphys import geometry, schema
from newtphys.consistency import TOLERANCES, check_sequence
from newtphys.rotations import quat_to_matrix
from newtphys.shards import SequenceArrays

# Tolerances, with what they are measured against (draft quality, 64 x 80 px, tests/data_gen/conftest.py).
GRAVITY_REL_TOL = 1e-5
"""float32 storage; a neighbouring frame's camera is off by 2e-4 .. 1.4e-2 under the handheld camera."""
OUTSIDE_BOX_M = 0.015
"""An object pixel back-projected from its depth may lie this far outside its object's box (splats at the
silhouette reach past the surface: measured <= 21 mm, 0.07 % of pixels past 15 mm)."""
OUTSIDE_BOX_MAX_FRACTION = 0.005
"""Maps shifted by one pixel or one frame put 1.2-12 % of object pixels past OUTSIDE_BOX_M (measured on a
variant of the scene; test_label_checks_notice_a_map_shifted_by_one_pixel_or_frame checks it on this one)."""
FLOOR_OFF_PLANE_M = 0.005
"""Floor pixels back-project onto z = 0 (measured: median 0.3 mm, max 4.2 mm)."""
FLOOR_OFF_PLANE_MAX_FRACTION = 0.001
"""A depth map shifted by one row or one frame puts >= 0.9 % of floor pixels past 5 mm."""
SCENE_FLOW_ABS_TOL_M = 2e-4
SCENE_FLOW_REL_TOL = 0.02
"""Rigid objects that do not spin: the flow of a splat centre and of the back-projected surface point agree
(measured p95 <= 0.065 mm, the small book settling on the block); the wrong frame's camera is off by 6 % of
the sliding book's flow."""
OPTICAL_FLOW_ABS_TOL_PX = 0.05
OPTICAL_FLOW_REL_TOL = 0.02
OPTICAL_FLOW_MAX_BAD_FRACTION = 0.001
"""Same scenes: measured <= 0.01 px off; half a pixel (pixel centres at integers) is 10x the tolerance."""
STRESS_REL_TOL = 0.03
"""A rigid object resting on the floor alone: mean stress theorem, -rho g z_com / 3 (measured 0.03 % off)."""
RESTING_SPEED_M_S = 0.01


def _objects_by_id(seq: SequenceArrays) -> dict:
    return {o.id: o for o in seq.world_state.objects}


def _rigid_ids(seq: SequenceArrays) -> list[int]:
    """Objects with one affine handle: they move rigidly, their stress is one number per frame."""
    return [o.id for o in seq.world_state.objects if o.num_handles == 1]


def _world_points(seq: SequenceArrays, depth: np.ndarray, t: int) -> np.ndarray:
    """(H, W, 3) world points of a depth map seen from frame t's camera, m."""
    cam = geometry.backproject_depth(depth.astype(np.float64), seq.K.astype(np.float64))
    return geometry.transform_points(geometry.rigid_inverse(seq.world_to_camera[t].astype(np.float64)), cam)


def _pose(seq: SequenceArrays, t: int, object_id: int) -> tuple[np.ndarray, np.ndarray]:
    fo = seq.world_state.frames[t].objects[object_id - 1]
    assert fo.id == object_id
    return np.asarray(fo.position, np.float64), quat_to_matrix(fo.orientation)


def _rigidly_moved(seq: SequenceArrays, t: int, object_id: int, points: np.ndarray) -> np.ndarray:
    """World points of object ``object_id`` at frame t carried to frame t + 1 by its world-state motion."""
    c0, r0 = _pose(seq, t, object_id)
    c1, r1 = _pose(seq, t + 1, object_id)
    return (points - c0) @ (r1 @ r0.T).T + c1


def _first_contact_frame(seq: SequenceArrays, object_id: int) -> int:
    ws = seq.world_state
    return next((t for t, f in enumerate(ws.frames) if f.objects[object_id - 1].contacts), ws.num_frames)


def _resting_frames(seq: SequenceArrays, object_id: int) -> list[int]:
    ws = seq.world_state
    return [
        t for t, f in enumerate(ws.frames)
        if np.linalg.norm(f.objects[object_id - 1].velocity) < RESTING_SPEED_M_S
        and f.objects[object_id - 1].contacts and t >= _first_contact_frame(seq, object_id) + 3
    ]


# --------------------------------------------------------------------------- #
# Checks: each returns failure messages (empty = the map means what the contract says)
# --------------------------------------------------------------------------- #
def check_gravity_in_own_frame(seq: SequenceArrays, maps: dict | None = None) -> list[str]:
    """gravity[t] == mass of the object shown x R_t g (R_t: rotation of world_to_camera[t]); 0 off objects."""
    m = seq.maps if maps is None else maps
    ws = seq.world_state
    mass = np.zeros(max(o.id for o in ws.objects) + 1)
    for o in ws.objects:
        mass[o.id] = o.mass
    g = np.asarray(ws.gravity, np.float64)
    out = []
    for t in range(ws.num_frames):
        ids = m[schema.INSTANCES][t].astype(np.int64)
        rot_g = geometry.rotate_vectors(seq.world_to_camera[t].astype(np.float64), g)
        expected = mass[ids][..., None] * rot_g
        # relative to the force shown; off objects (mass 0) relative to the weight of 1 g
        scale = np.linalg.norm(g) * np.maximum(mass[ids], 1e-3)
        err = np.linalg.norm(m[schema.GRAVITY][t] - expected, axis=-1) / scale
        if err.max() > GRAVITY_REL_TOL:
            out.append(f"frame {t}: gravity off mass x R_t g by {err.max():.3g} (relative) "
                       f"> {GRAVITY_REL_TOL}")
    return out


def check_object_pixels_on_their_object(seq: SequenceArrays, maps: dict | None = None) -> list[str]:
    """Depth + instances: an object pixel back-projects into its object's box (world-state pose and size).

    Every library object of the scene is box-shaped with its centre of mass at the box centre."""
    m = seq.maps if maps is None else maps
    objects = _objects_by_id(seq)
    excess = []
    for t in range(seq.world_state.num_frames):
        pts = _world_points(seq, m[schema.DEPTH][t], t)
        ids = m[schema.INSTANCES][t]
        for oid, o in objects.items():
            on = ids == oid
            centre, rot = _pose(seq, t, oid)
            local = (pts[on] - centre) @ rot  # object frame
            excess.append(np.max(np.abs(local) - 0.5 * np.asarray(o.size), axis=-1))
    e = np.concatenate(excess)
    frac = float(np.mean(e > OUTSIDE_BOX_M))
    if frac > OUTSIDE_BOX_MAX_FRACTION:
        return [f"{frac:.2%} of {e.size} object pixels lie > {OUTSIDE_BOX_M * 1e3:.0f} mm outside their "
                f"object's box (allowed {OUTSIDE_BOX_MAX_FRACTION:.1%}; worst {e.max() * 1e3:.0f} mm)"]
    return []


def check_floor_on_ground_plane(seq: SequenceArrays, maps: dict | None = None) -> list[str]:
    """Depth: pixels of the static scene (only the floor in this scene) back-project onto z = 0."""
    m = seq.maps if maps is None else maps
    off = []
    for t in range(seq.world_state.num_frames):
        floor = (m[schema.INSTANCES][t] == 0) & (m[schema.DEPTH][t] > 0)
        off.append(np.abs(_world_points(seq, m[schema.DEPTH][t], t)[floor][:, 2]))
    z = np.concatenate(off)
    frac = float(np.mean(z > FLOOR_OFF_PLANE_M))
    if z.size == 0 or frac > FLOOR_OFF_PLANE_MAX_FRACTION:
        return [f"{frac:.2%} of {z.size} floor pixels lie > {FLOOR_OFF_PLANE_M * 1e3:.0f} mm off the ground "
                f"plane (allowed {FLOOR_OFF_PLANE_MAX_FRACTION:.1%})"]
    return []


def check_amodal_masks(seq: SequenceArrays, maps: dict | None = None) -> list[str]:
    """Amodal silhouettes contain the visible pixels of their object and carry its material and class ids."""
    m = seq.maps if maps is None else maps
    ws = seq.world_state
    mat_ids = {name: int(k) for k, name in ws.materials.items()}
    sem_ids = {name: int(k) for k, name in ws.semantic_classes.items()}
    out = []
    for k, o in enumerate(ws.objects):
        amodal = m[schema.AMODAL_INSTANCES][:, k]
        missing = int(((m[schema.INSTANCES] == o.id) & ~amodal).sum())
        if missing:
            out.append(f"object {o.id}: {missing} visible pixels outside its amodal silhouette")
        if not amodal.reshape(ws.num_frames, -1).any(axis=1).all():
            out.append(f"object {o.id}: empty amodal silhouette in a frame where it is in view")
        for name, want in ((schema.AMODAL_MATERIALS, mat_ids[o.material]),
                           (schema.AMODAL_SEMANTIC_SEGMENTATION, sem_ids[o.category])):
            ok = np.where(amodal, m[name][:, k] == want, m[name][:, k] == 0)
            if not ok.all():
                out.append(f"object {o.id}: {name} is not id {want} on its silhouette and 0 off it "
                           f"at {int((~ok).sum())} px")
    return out


def check_scene_flow_rigid_motion(seq: SequenceArrays, maps: dict | None = None) -> list[str]:
    """Scene flow of rigid objects == R_t (x_{t+1} - x_t) of the back-projected point moved by the world-state
    poses (R_t: world_to_camera[t]); exactly 0 on the static scene."""
    m = seq.maps if maps is None else maps
    out = []
    for t in range(seq.world_state.num_frames - 1):
        pts = _world_points(seq, m[schema.DEPTH][t], t)
        ids = m[schema.INSTANCES][t]
        flow = m[schema.SCENE_FLOW][t]
        floor = (ids == 0) & (m[schema.DEPTH][t] > 0)
        if np.abs(flow[floor]).max(initial=0.0) > 1e-6:
            out.append(f"frame {t}: the static floor has scene flow up to {np.abs(flow[floor]).max():.3g} m")
        for oid in _rigid_ids(seq):
            on = ids == oid
            if on.sum() < 10:
                continue
            ref = geometry.rotate_vectors(seq.world_to_camera[t].astype(np.float64),
                                          _rigidly_moved(seq, t, oid, pts[on]) - pts[on])
            err = np.percentile(np.linalg.norm(flow[on] - ref, axis=-1), 95)
            tol = SCENE_FLOW_ABS_TOL_M + SCENE_FLOW_REL_TOL * float(np.median(np.linalg.norm(ref, axis=-1)))
            if err > tol:
                out.append(f"frame {t}, object {oid}: scene flow off the rigid motion by {err * 1e3:.2f} mm "
                           f"(p95) > {tol * 1e3:.2f} mm")
    if m[schema.SCENE_FLOW][-1].any():
        out.append("the last frame has non-zero scene flow")
    return out


def check_optical_flow_projection(seq: SequenceArrays, maps: dict | None = None) -> list[str]:
    """Optical flow == projection into camera t+1 of the surface point seen at t, moved by its world-state
    motion (rigid objects; the static floor stays), minus the pixel centre."""
    m = seq.maps if maps is None else maps
    K = seq.K.astype(np.float64)
    h, w = m[schema.DEPTH].shape[1:]
    centres = geometry.pixel_centers(h, w)
    out = []
    for t in range(seq.world_state.num_frames - 1):
        pts = _world_points(seq, m[schema.DEPTH][t], t)
        ids = m[schema.INSTANCES][t]
        moved = np.full_like(pts, np.nan)
        floor = (ids == 0) & (m[schema.DEPTH][t] > 0)
        moved[floor] = pts[floor]
        for oid in _rigid_ids(seq):
            on = ids == oid
            moved[on] = _rigidly_moved(seq, t, oid, pts[on])
        known = ~np.isnan(moved[..., 0])
        next_cam = geometry.transform_points(seq.world_to_camera[t + 1].astype(np.float64), moved[known])
        uv, _ = geometry.project(next_cam, K)
        ref = uv - centres[known]
        err = np.linalg.norm(m[schema.OPTICAL_FLOW][t][known] - ref, axis=-1)
        tol = OPTICAL_FLOW_ABS_TOL_PX + OPTICAL_FLOW_REL_TOL * np.linalg.norm(ref, axis=-1)
        bad = float(np.mean(err > tol))
        if bad > OPTICAL_FLOW_MAX_BAD_FRACTION:
            out.append(f"frame {t}: optical flow off the projected motion on {bad:.2%} of {known.sum()} px "
                       f"(worst {err.max():.2f} px)")
    if m[schema.OPTICAL_FLOW][-1].any():
        out.append("the last frame has non-zero optical flow")
    return out


# --------------------------------------------------------------------------- #
# Tests
# --------------------------------------------------------------------------- #
def test_label_scenes_exercise_the_labels(label_sequences: dict) -> None:
    """What the other tests rely on actually happens in the label scenes (a restructured simulator or camera
    could silently stop exercising a label)."""
    orbit, handheld = label_sequences["orbit"], label_sequences["handheld"]
    for seq in (orbit, handheld):
        ws = seq.world_state
        eyes = geometry.camera_pose(seq.world_to_camera.astype(np.float64))[0]
        assert np.linalg.norm(np.diff(eyes, axis=0), axis=1).min() > 0.004  # the camera moves every frame (m)
        for o in ws.objects:
            first = _first_contact_frame(seq, o.id)
            assert first >= 1, (o.name, first)  # free fall (or a push) before the first contact
            assert min(f.objects[o.id - 1].visible_pixels for f in ws.frames) >= 30, o.name  # always in view
            assert len(_resting_frames(seq, o.id)) >= 5, o.name  # comes to rest
        assert _first_contact_frame(seq, 1) >= 3  # 3 frames of free fall for the wooden block
        assert any(set(ev.objects) == {1, 2} for ev in ws.collisions)  # the small book lands on the block
        assert [o.num_handles > 1 for o in ws.objects] == [False, False, False, True]  # rigid x 3, soft x 1
        book = np.array([f.objects[2].position for f in ws.frames])
        slide = np.linalg.norm(np.diff(book[:, :2], axis=0), axis=1)
        assert (slide > 0.01).sum() >= 3  # the big book slides >= 1 cm per frame for 3 frames
    rot = orbit.world_to_camera[:, :3, :3].astype(np.float64)
    yaw = np.degrees(np.arccos(np.clip((np.einsum("tij,tij->t", rot[1:], rot[:-1]) - 1) / 2, -1, 1)))
    assert yaw.min() > 2.0  # orbit: degrees per frame
    down = handheld.world_to_camera[:, :3, :3].astype(np.float64) @ np.array([0.0, 0.0, -1.0])
    assert np.linalg.norm(np.diff(down, axis=0), axis=1).max() > 100 * GRAVITY_REL_TOL  # handheld tilts


def test_gravity_map_uses_its_own_frames_camera(label_sequences: dict) -> None:
    """gravity[t] = mass x g rotated by world_to_camera[t], not by a neighbouring frame's camera."""
    for seq in label_sequences.values():
        assert check_gravity_in_own_frame(seq) == []
    # The handheld camera tilts: a neighbouring frame's rotation is off by far more than the tolerance.
    seq = label_sequences["handheld"]
    w2c = seq.world_to_camera.astype(np.float64)
    g = np.asarray(seq.world_state.gravity)
    down = np.einsum("tij,j->ti", w2c[:, :3, :3], g) / np.linalg.norm(g)  # (T, 3): g in each frame's camera
    assert np.linalg.norm(np.diff(down, axis=0), axis=1).max() > 100 * GRAVITY_REL_TOL


def test_collision_pixels_appear_on_visible_objects_in_contact(label_sequences: dict) -> None:
    """Contacts show up in the collision map: from the onset frame on, on every visible rigid object in
    contact, with the floor (block, big book) or only with another object (the small book on the block);
    never on an object before its first contact."""
    for seq in label_sequences.values():
        ws = seq.world_state
        col, ids = seq.maps[schema.COLLISION], seq.maps[schema.INSTANCES]
        onsets = {ev.objects[0]: ev.frame for ev in ws.collisions if ev.objects[1] == 0}
        kinds = set()
        for oid in _rigid_ids(seq):
            on = ids == oid
            hits = (col & on).reshape(ws.num_frames, -1).sum(axis=1)
            visible = on.reshape(ws.num_frames, -1).sum(axis=1)
            first = _first_contact_frame(seq, oid)
            assert first >= 1 and hits[:first].sum() == 0, (ws.sequence_id, oid, hits[:first])
            contacts = [ws.frames[t].objects[oid - 1].contacts for t in range(ws.num_frames)]
            frames = [t for t in range(ws.num_frames) if contacts[t] and visible[t] >= 50]
            if oid in onsets:
                assert onsets[oid] in frames and hits[onsets[oid]] > 0, (oid, onsets[oid], hits)
            for t in frames:  # every frame of contact shows some of it
                assert hits[t] >= 1, (ws.sequence_id, oid, t, contacts[t], visible[t])
            # and a fair share: measured 6-10 % (block; small book on it), 55-60 % (big book on the floor)
            assert hits[frames].sum() >= 0.03 * visible[frames].sum(), (oid, hits, visible)
            kinds |= {"floor" if 0 in contacts[t] else "object only" for t in frames}
        assert kinds == {"floor", "object only"}, kinds


def test_resting_object_stress_is_compressive_in_the_map(label_sequences: dict) -> None:
    """A resting object is in compression in the stress map: rigid and alone on the floor exactly
    -rho g z_com / 3 (mean stress theorem); rigid under a load or on another object below -rho g h / 12
    (h its smallest extent; a body on a support at height z_s has -rho g (z_com - z_s) / 3 = -rho g h / 6).

    Soft objects are not checked here: the reduced field of the 3-handle foam block, resting alone on the
    floor, averages -0.1 .. -0.7 Pa over its visible pixels (volume mean -5 Pa, theory -8.5 Pa), and
    +5 .. +8 Pa in a variant of this scene where it rests on the wooden block; the map's sign there
    follows the simulator's coarse field, not the label path (tests/sim/test_sim_soft_stress.py checks the
    recorded field's volume mean)."""
    checked = {"alone": 0, "loaded": 0}
    for seq in label_sequences.values():
        ws = seq.world_state
        g = float(np.linalg.norm(ws.gravity))
        for oid in _rigid_ids(seq):
            o = _objects_by_id(seq)[oid]
            rho = o.mass / o.volume
            frames = _resting_frames(seq, oid)
            values = [seq.maps[schema.STRESS][t][seq.maps[schema.INSTANCES][t] == oid] for t in frames]
            assert all(np.ptp(v) <= 1e-3 * abs(v.mean()) for v in values), o.name  # one number per rigid body
            means = np.array([v.mean() for v in values])
            alone = all(ws.frames[t].objects[oid - 1].contacts == [0] for t in frames) and not any(
                oid in f.contacts for t in frames for f in ws.frames[t].objects)
            if alone:
                z = np.array([ws.frames[t].objects[oid - 1].position[2] for t in frames])
                np.testing.assert_allclose(means, -rho * g * z / 3.0, rtol=STRESS_REL_TOL, err_msg=o.name)
                checked["alone"] += 1
            else:
                assert means.max() <= -0.5 * rho * g * min(o.size) / 6.0, (o.name, means)
                checked["loaded"] += 1
    assert checked["alone"] >= 2 and checked["loaded"] >= 2, checked


def test_stress_is_zero_in_free_fall(label_sequences: dict) -> None:
    """Before its first contact a non-spinning object carries no stress (contacts are what load it)."""
    checked = 0
    for seq in label_sequences.values():
        for o in seq.world_state.objects:
            for t in range(_first_contact_frame(seq, o.id)):
                on = seq.maps[schema.INSTANCES][t] == o.id
                assert np.abs(seq.maps[schema.STRESS][t][on]).max() <= 0.1, (o.name, t)  # Pa
                checked += 1
    assert checked >= 10


def test_scene_flow_is_rigid_motion_in_its_own_frames_camera(label_sequences: dict) -> None:
    """Scene flow at t = displacement t -> t+1 (world-state poses) rotated by world_to_camera[t]."""
    for seq in label_sequences.values():
        assert check_scene_flow_rigid_motion(seq) == []
    # Under the orbit, the sliding book's flow rotated by the next frame's camera would be off by far more.
    seq = label_sequences["orbit"]
    w2c = seq.world_to_camera.astype(np.float64)
    worst = 0.0
    for t in range(seq.world_state.num_frames - 1):
        on = seq.maps[schema.INSTANCES][t] == 3
        pts = _world_points(seq, seq.maps[schema.DEPTH][t], t)[on]
        d = _rigidly_moved(seq, t, 3, pts) - pts
        worst = max(worst, float(np.median(np.linalg.norm(geometry.rotate_vectors(w2c[t + 1], d)
                                                           - geometry.rotate_vectors(w2c[t], d), axis=-1))))
    assert worst > 4 * SCENE_FLOW_ABS_TOL_M, worst


def test_optical_flow_is_the_projection_of_the_motion_into_the_next_camera(label_sequences: dict) -> None:
    for seq in label_sequences.values():
        assert check_optical_flow_projection(seq) == []


def test_depth_and_instances_put_object_pixels_on_their_object(label_sequences: dict) -> None:
    for seq in label_sequences.values():
        assert check_object_pixels_on_their_object(seq) == []


def test_floor_depth_lies_on_the_ground_plane(label_sequences: dict) -> None:
    for seq in label_sequences.values():
        assert check_floor_on_ground_plane(seq) == []


def test_amodal_masks_contain_the_visible_pixels_and_carry_their_objects_ids(label_sequences: dict) -> None:
    for seq in label_sequences.values():
        assert check_amodal_masks(seq) == []


@pytest.mark.parametrize("camera", ["orbit", "handheld"])
def test_label_sequences_pass_the_cross_map_checks(label_sequences: dict, camera: str) -> None:
    """newtphys.consistency (what ``validate --deep`` runs) accepts the label scenes under moving cameras."""
    for r in check_sequence(label_sequences[camera]):
        assert r.max_error <= TOLERANCES[r.name], str(r)
        assert r.num_pixels > 0, r.name


# --------------------------------------------------------------------------- #
# The checks above notice a map shifted by one pixel or one frame
# --------------------------------------------------------------------------- #
def _roll(axis_from_end: int, step: int) -> Callable[[np.ndarray, str], np.ndarray]:
    def shift(a: np.ndarray, name: str) -> np.ndarray:
        spatial = schema.MAPS[name].shape.index("H")  # (T, H, W, ...) or (T, N, H, W)
        return np.roll(a, step, axis=spatial + axis_from_end)
    return shift


SHIFTS: dict[str, Callable[[np.ndarray, str], np.ndarray]] = {
    "one pixel right": _roll(1, 1),
    "one pixel left": _roll(1, -1),
    "one pixel down": _roll(0, 1),
    "one pixel up": _roll(0, -1),
    "previous frame": lambda a, name: np.concatenate([a[:1], a[:-1]]),
    "next frame": lambda a, name: np.concatenate([a[1:], a[-1:]]),
}
CHECKS_OF_MAP = {
    schema.DEPTH: (
        check_object_pixels_on_their_object, check_floor_on_ground_plane, check_optical_flow_projection),
    schema.INSTANCES: (check_object_pixels_on_their_object, check_amodal_masks, check_gravity_in_own_frame),
    schema.AMODAL_INSTANCES: (check_amodal_masks,),
    schema.OPTICAL_FLOW: (check_optical_flow_projection,),
    schema.SCENE_FLOW: (check_scene_flow_rigid_motion,),
}


@pytest.mark.parametrize("name", list(CHECKS_OF_MAP))
def test_label_checks_notice_a_map_shifted_by_one_pixel_or_frame(label_sequences: dict, name: str) -> None:
    for shift_name, shift in SHIFTS.items():
        failures = []
        for seq in label_sequences.values():
            maps = dict(seq.maps)
            maps[name] = shift(seq.maps[name], name)
            failures += [msg for check in CHECKS_OF_MAP[name] for msg in check(seq, maps)]
        assert failures, f"{name} shifted {shift_name} passes every check of {name}"
