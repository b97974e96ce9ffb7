"""One split from many jobs: job -> shard ranges, the index merge, and submitit's local executor running two jobs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from data_gen.configs import generation_config
from data_gen.generator import job_shard_range, slots_of
from newtphys import schema
from newtphys.cli import main
from newtphys.shards import ShardError, ShardReader, ShardWriter, merge_index, read_index
from tests.fixtures.synthetic_scene import render_fixture_sequence

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("num_shards, num_jobs", [(10, 3), (7, 7), (1100, 100), (5, 1), (12, 5)])
def test_jobs_cover_every_shard_once(num_shards: int, num_jobs: int) -> None:
    ranges = [job_shard_range(num_shards, num_jobs, j) for j in range(num_jobs)]
    assert ranges[0][0] == 0 and ranges[-1][1] == num_shards
    assert all(a[1] == b[0] for a, b in zip(ranges, ranges[1:]))  # contiguous and disjoint
    sizes = [b - a for a, b in ranges]
    assert max(sizes) - min(sizes) <= 1 and min(sizes) >= 1


def test_job_config_selects_its_sequences() -> None:
    # 10 sequences, 3 per shard -> 4 shards; 3 jobs take shards [0, 2), [2, 3), [3, 4)
    cfgs = [generation_config("num_sequences=10", "sequences_per_shard=3", "num_jobs=3", f"job={j}") for j in range(3)]
    assert [c.shards for c in cfgs] == [(0, 2), (2, 3), (3, 4)]
    assert [list(slots_of(c)) for c in cfgs] == [[0, 1, 2, 3, 4, 5], [6, 7, 8], [9]]
    with pytest.raises(ValueError, match="num_jobs and job go together"):
        generation_config("num_jobs=3")
    with pytest.raises(ValueError, match="need 1 <= num_jobs <= 4"):
        generation_config("num_sequences=10", "sequences_per_shard=3", "num_jobs=5", "job=0")
    with pytest.raises(ValueError, match="shards or num_jobs/job, not both"):
        generation_config("num_sequences=10", "sequences_per_shard=3", "num_jobs=2", "job=0", "shards=[0,1]")


def _shard(root: Path, index: int, ids: list[str], config: str, split: str = "val") -> None:
    with ShardWriter(root, split, index, config_yaml=config) as w:
        for k, sid in enumerate(ids):
            maps, K, w2c, ws = render_fixture_sequence(sid, split, seed=k, num_frames=3 + k, image_size=(8, 12))
            w.add_sequence(sid, maps, K, w2c, ws)


def test_merge_index_rebuilds_one_split(tmp_path: Path) -> None:
    _shard(tmp_path, 0, ["val-000000", "val-000001"], "seed: 0\njob: 0\nnum_jobs: 2\n")
    _shard(tmp_path, 1, ["val-000002"], "seed: 0\njob: 1\nnum_jobs: 2\n")
    split = tmp_path / "val"
    (split / schema.INDEX_FILENAME).write_text(json.dumps({"shards": []}))  # an index that lost both entries
    report = merge_index(split, expected_sequences=3)
    assert (report.shards, report.sequences, report.frames, report.missing_shards) == (2, 3, 3 + 4 + 3, [])
    index = read_index(split)
    assert index["split"] == "val" and index["schema_version"] == schema.SCHEMA_VERSION
    assert [s["file"] for s in index["shards"]] == ["shard-00000.h5", "shard-00001.h5"]
    assert index["shards"][0]["sequences"] == [{"id": "val-000000", "num_frames": 3}, {"id": "val-000001", "num_frames": 4}]
    assert index["shards"][1]["size_bytes"] == (split / "shard-00001.h5").stat().st_size
    with pytest.raises(ShardError, match="missing \\['val-000003'\\]"):
        merge_index(split, expected_sequences=4)
    assert main(["merge-index", str(split), "--expect", "3"]) == 0


def test_merge_index_refuses_overlapping_or_foreign_jobs(tmp_path: Path) -> None:
    _shard(tmp_path, 0, ["val-000000", "val-000001"], "seed: 0\njob: 0\n")
    _shard(tmp_path, 1, ["val-000001"], "seed: 0\njob: 1\n")
    with pytest.raises(ShardError, match="'val-000001' also in shard-00000.h5 \\(jobs overlapped\\)"):
        merge_index(tmp_path / "val")
    _shard(tmp_path, 1, ["val-000002"], "seed: 7\njob: 1\n")  # another seed: not the same split
    with pytest.raises(ShardError, match="shard-00001.h5.*config other than"):
        merge_index(tmp_path / "val")
    _shard(tmp_path, 1, ["val-000002"], "seed: 0\njob: 1\n")
    _shard(tmp_path, 3, ["val-000006"], "seed: 0\njob: 3\n")  # job 2 not finished yet
    assert merge_index(tmp_path / "val").missing_shards == [2]
    assert main(["merge-index", str(tmp_path / "val")]) == 1  # an unfinished split is an error for scripts


@pytest.mark.slow
def test_submitit_local_runs_two_jobs_into_one_split(tmp_path: Path) -> None:
    """Hydra's submitit launcher with the local executor: two processes, each writing its own shard of one
    split, then the merge callback writes one index.json; every sequence is the one its slot draws alone."""
    out = tmp_path / "data"
    cmd = [sys.executable, "generate.py", "-m", "hydra/launcher=local_generate", "num_jobs=2", "job=0,1",
           "split=val", "num_sequences=2", "sequences_per_shard=1", "seed=5", "num_frames=6", "image_size=[40,48]",
           "progress=false", "render.object_gaussians=1200", "render.interior_points=500",
           "render.scene_spacing_m=0.05", "scenario.num_objects=[1,1]", "scenario.scenes=[empty_floor]",
           "scenario.camera_distance_m=[0.7,0.9]", f"out_dir={out}", f"hydra.sweep.dir={tmp_path / 'sweep'}"]
    env = {**os.environ, "PYTHONPATH": str(REPO), "WANDB_MODE": "offline"}
    run = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    split = out / "val"
    index = read_index(split)
    assert [s["file"] for s in index["shards"]] == ["shard-00000.h5", "shard-00001.h5"]
    assert [q["id"] for s in index["shards"] for q in s["sequences"]] == ["val-000000", "val-000001"]
    assert merge_index(split, expected_sequences=2).missing_shards == []
    from data_gen.generator import slot_seed

    for k in range(2):  # shard k came from job k (its config names it) and holds slot k
        with ShardReader(split / schema.shard_filename(k)) as r:
            assert f"job: {k}" in r.attrs[schema.FILE_ATTR_CONFIG] and "num_jobs: 2" in r.attrs[schema.FILE_ATTR_CONFIG]
            ws = r.world_state(f"val-{k:06d}")
            assert ws.seed in {slot_seed(5, "val", k, a) for a in range(10)}
    jobs = sorted((tmp_path / "sweep" / ".submitit").glob("*/*_result.pkl"))
    assert len(jobs) == 2  # two submitit jobs ran
    assert main(["validate", str(split)]) == 0
