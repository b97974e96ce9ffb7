"""Generated data: contract, cross-map consistency, world-state physics, OOD gravity."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from newtphys import geometry, schema
from newtphys.consistency import TOLERANCES, check_sequence
from newtphys.rotations import quat_to_matrix
from newtphys.shards import ShardReader, list_shards, read_index
from newtphys.validate import validate_paths


def _sequences(root: Path, split: str):
    for shard in list_shards(root / split):
        with ShardReader(shard) as r:
            for sid in r.sequences():
                yield r.read_sequence(sid)


def test_generated_data_validates(generated_root: Path) -> None:
    problems = validate_paths([generated_root], deep=True)
    assert [str(p) for p in problems if p.severity == "error"] == []
    index = read_index(generated_root / "train")
    assert [s["num_frames"] for s in index["shards"]] == [12, 12]
    assert [s["sequences"][0]["id"] for s in index["shards"]] == ["train-000000", "train-000001"]


def test_cross_map_consistency(generated_root: Path) -> None:
    for seq in _sequences(generated_root, "train"):
        for r in check_sequence(seq):
            assert r.max_error <= TOLERANCES[r.name], str(r)
        m = seq.maps
        # Label maps only where something is visible; objects have positive depth and a gravity force.
        ids = m[schema.INSTANCES]
        assert (ids > 0).any()
        assert np.all(m[schema.DEPTH][ids > 0] > 0)
        g = np.linalg.norm(m[schema.GRAVITY], axis=-1)
        assert np.all(g[ids > 0] > 0) and np.all(g[ids == 0] == 0)
        assert np.all(m[schema.STRESS][ids == 0] == 0)
        assert not m[schema.COLLISION][ids == 0].any()
        # Amodal silhouettes contain the modal ones.
        for k in range(m[schema.AMODAL_INSTANCES].shape[1]):
            assert not np.any((ids == k + 1) & ~m[schema.AMODAL_INSTANCES][:, k])
        assert not m[schema.SCENE_FLOW][-1].any() and not m[schema.OPTICAL_FLOW][-1].any()


def test_depth_lands_on_the_simulated_surface(generated_root: Path) -> None:
    """Back-projected object pixels lie on the object where the world state says it is."""
    seq = next(_sequences(generated_root, "train"))
    ws = seq.world_state
    for t in (0, ws.num_frames - 1):
        pts_cam = geometry.backproject_depth(seq.maps[schema.DEPTH][t], seq.K)
        pts = geometry.transform_points(geometry.rigid_inverse(seq.world_to_camera[t]), pts_cam)
        for o, fo in zip(ws.objects, ws.frames[t].objects):
            on = seq.maps[schema.INSTANCES][t] == o.id
            if not on.any():
                continue
            dist = np.linalg.norm(pts[on] - np.asarray(fo.position), axis=-1)
            # The COM lies inside the bounding box, so every surface point is within one box diagonal of it
            # (+ 1 cm for the splat footprint); the median within half of it.
            diag = float(np.linalg.norm(o.size))
            assert dist.max() <= diag + 0.01, (o.name, dist.max())
            assert np.median(dist) <= 0.5 * diag + 0.01, (o.name, float(np.median(dist)))


def test_scene_flow_matches_rigid_motion(generated_root: Path) -> None:
    """For near-rigid objects, scene flow = displacement of the rigid motion (COM + orientation) of the world state."""
    checked = 0
    for seq in _sequences(generated_root, "train"):
        ws = seq.world_state
        for t in range(ws.num_frames - 1):
            pts_cam = geometry.backproject_depth(seq.maps[schema.DEPTH][t], seq.K)
            c2w = geometry.rigid_inverse(seq.world_to_camera[t])
            pts = geometry.transform_points(c2w, pts_cam)
            for o, a, b in zip(ws.objects, ws.frames[t].objects, ws.frames[t + 1].objects):
                on = seq.maps[schema.INSTANCES][t] == o.id
                if o.num_handles != 1 or on.sum() < 5:
                    continue
                rel = quat_to_matrix(b.orientation) @ quat_to_matrix(a.orientation).T
                moved = (pts[on] - np.asarray(a.position)) @ rel.T + np.asarray(b.position)
                expected = geometry.rotate_vectors(seq.world_to_camera[t], moved - pts[on])
                err = np.linalg.norm(seq.maps[schema.SCENE_FLOW][t][on] - expected, axis=-1)
                scale = max(np.linalg.norm(seq.maps[schema.SCENE_FLOW][t][on], axis=-1).max(), 1e-3)
                # The depth of a pixel is its splat centre's, so the back-projected point is off the splat
                # centre by < one splat; rotation makes that a small flow error. 2 mm + 10% of the motion.
                assert np.percentile(err, 95) <= 2e-3 + 0.1 * scale, (o.name, t, float(np.percentile(err, 95)))
                checked += 1
    assert checked > 5


def test_free_fall_acceleration_equals_gravity(generated_root: Path) -> None:
    """Before its first contact, every object's COM accelerates at the split's gravity.

    Uses the recorded COM velocities: implicit Euler gives v(t) = v0 + g t exactly for any step size
    (positions carry an O(g h t) term that changes when the solver adapts its substeps near contact).
    """
    checked = 0
    for split in ("train", "test_ood_gravity"):
        for seq in _sequences(generated_root, split):
            ws = seq.world_state
            g = np.asarray(ws.gravity)
            for o in ws.objects:
                first = min([ev.frame for ev in ws.collisions if o.id in ev.objects] + [ws.num_frames])
                vel = np.array([f.objects[o.id - 1].velocity for f in ws.frames[:first]])  # frames before onset
                if len(vel) < 2:
                    continue
                acc = np.diff(vel, axis=0) * ws.fps
                np.testing.assert_allclose(acc, np.broadcast_to(g, acc.shape), atol=1e-6 * np.linalg.norm(g))
                checked += 1
    assert checked >= 1


def test_ood_split_carries_its_own_gravity(generated_root: Path) -> None:
    seq = next(_sequences(generated_root, "test_ood_gravity"))
    g = seq.world_state.gravity_magnitude
    assert schema.OOD_GRAVITY_RANGE_M_S2[0] <= g <= schema.OOD_GRAVITY_RANGE_M_S2[1]
    assert g != pytest.approx(schema.EARTH_GRAVITY_M_S2)
    ids = seq.maps[schema.INSTANCES][0]
    o = seq.world_state.objects[0]
    on = ids == o.id
    if on.any():
        mag = np.linalg.norm(seq.maps[schema.GRAVITY][0][on], axis=-1)
        np.testing.assert_allclose(mag, o.mass * g, rtol=1e-5)
