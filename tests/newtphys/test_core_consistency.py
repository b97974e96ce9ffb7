"""Cross-map checks: exact on the analytic fixture, and they catch planted inconsistencies."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from newtphys import schema
from newtphys.consistency import check_collision, check_gravity, check_labels, check_optical_flow, check_sequence, failing
from newtphys.shards import SequenceArrays
from newtphys.validate import validate_paths
from tests.fixtures.synthetic_scene import render_fixture_sequence, write_fixture_split


@pytest.fixture(scope="module")
def seq() -> SequenceArrays:
    maps, K, w2c, ws = render_fixture_sequence("c-0", "train", seed=5, num_frames=5, image_size=(40, 48))
    return SequenceArrays(maps, K, w2c, ws)


def test_fixture_is_consistent(seq: SequenceArrays) -> None:
    res = {r.name: r for r in check_sequence(seq)}
    assert failing(list(res.values())) == []
    flow = res["optical_flow vs projected scene_flow"]
    assert flow.num_pixels > 0.8 * 4 * 40 * 48  # nearly every pixel of frames 0..3 sees a surface
    assert flow.max_error < 1e-3  # px
    assert res["gravity vs mass x g (relative)"].max_error < 1e-6


def test_planted_errors_are_caught(seq: SequenceArrays) -> None:
    m = {k: v.copy() for k, v in seq.maps.items()}
    on = np.argwhere(m[schema.INSTANCES][1] == 1)[0]
    m[schema.SCENE_FLOW][1][tuple(on)] += np.float32(0.05)  # 5 cm of flow the optical flow does not show
    assert check_optical_flow(dataclasses.replace(seq, maps=m)).max_error > 0.5

    ws = dataclasses.replace(seq.world_state, objects=[dataclasses.replace(o, mass=2 * o.mass) for o in seq.world_state.objects])
    assert check_gravity(dataclasses.replace(seq, world_state=ws)).max_error == pytest.approx(0.5, rel=1e-5)

    m2 = {k: v.copy() for k, v in seq.maps.items()}
    m2[schema.MATERIALS][m2[schema.INSTANCES] == 1] = 2  # object 1 is wood (id 1)
    assert check_labels(dataclasses.replace(seq, maps=m2)).max_error > 0

    frames = [dataclasses.replace(f, objects=[dataclasses.replace(o, contacts=[]) for o in f.objects])
              for f in seq.world_state.frames]
    ws3 = dataclasses.replace(seq.world_state, frames=frames)
    assert check_collision(dataclasses.replace(seq, world_state=ws3)).max_error == 1.0


def test_validate_deep_reports_cross_map_failures(tmp_path) -> None:
    import h5py

    split = write_fixture_split(tmp_path, "train", num_sequences=1, sequences_per_shard=1, num_frames=4, image_size=(16, 16))
    assert validate_paths([split], deep=True) == []
    with h5py.File(split / "shard-00000.h5", "a") as f:
        f["train-000000"][schema.GRAVITY][0] *= 3.0
    msgs = [str(p) for p in validate_paths([split], deep=True)]
    assert len(msgs) == 1 and "cross-map check failed: gravity vs mass x g" in msgs[0]
    assert validate_paths([split], deep=False) == []


def test_failing_flags_errors_just_past_the_shipped_tolerances(seq: SequenceArrays) -> None:
    """``validate --deep`` reports an error a few times its tolerance, in each check (a loosened tolerance
    would let it through): 0.2 px of flow (tolerance 0.05 px), 1e-4 of gravity (1e-5), one pixel of a wrong
    material, one collision pixel on an object that has no contact (both 0)."""
    on = tuple(np.argwhere(seq.maps[schema.INSTANCES][1] == 1)[0])
    planted = {}
    m = {k: v.copy() for k, v in seq.maps.items()}
    m[schema.OPTICAL_FLOW][1][on] += np.float32(0.2)
    planted["optical_flow vs projected scene_flow"] = dataclasses.replace(seq, maps=m)
    m = {k: v.copy() for k, v in seq.maps.items()}
    m[schema.GRAVITY][1][on] *= np.float32(1.0 + 1e-4)
    planted["gravity vs mass x g (relative)"] = dataclasses.replace(seq, maps=m)
    m = {k: v.copy() for k, v in seq.maps.items()}
    m[schema.MATERIALS][1][on] = 2  # object 1 is wood (id 1)
    planted["material/semantic ids vs world state"] = dataclasses.replace(seq, maps=m)
    frame = np.argwhere(seq.maps[schema.COLLISION].reshape(len(seq.world_state.frames), -1).any(axis=1))[0, 0]
    touching = int(seq.maps[schema.INSTANCES][frame][seq.maps[schema.COLLISION][frame]][0])
    frames = list(seq.world_state.frames)
    frames[frame] = dataclasses.replace(frames[frame], objects=[
        dataclasses.replace(o, contacts=[]) if o.id == touching else o for o in frames[frame].objects])
    planted["collision pixels without a contact"] = dataclasses.replace(
        seq, world_state=dataclasses.replace(seq.world_state, frames=frames))
    for name, bad in planted.items():
        assert [r.name for r in failing(check_sequence(bad))] == [name]
