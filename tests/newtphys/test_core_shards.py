"""Shard writer / reader: bit-exact round trip, atomicity, clear errors."""

from __future__ import annotations

import json
import os
import pickle
import shutil
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import h5py
import numpy as np
import pytest

from newtphys import schema
from newtphys.shards import ShardError, ShardReader, ShardWriter, list_shards, read_index
from tests.fixtures.synthetic_scene import render_fixture_sequence


def _write(root: Path, shard_index: int = 0, ids=("s-0", "s-1"), split: str = "train"):
    seqs = {sid: render_fixture_sequence(sid, split, seed=i, num_frames=5, image_size=(16, 24)) for i, sid in enumerate(ids)}
    with ShardWriter(root, split, shard_index, config_yaml="a: 1\n") as w:
        for sid, (maps, K, w2c, ws) in seqs.items():
            w.add_sequence(sid, maps, K, w2c, ws)
    return root / split / schema.shard_filename(shard_index), seqs


def test_round_trip_is_bit_identical(tmp_path: Path) -> None:
    path, seqs = _write(tmp_path)
    with ShardReader(path) as r:
        assert r.sequences() == ["s-0", "s-1"]
        assert r.attrs[schema.FILE_ATTR_SCHEMA_VERSION] == schema.SCHEMA_VERSION
        assert r.attrs[schema.FILE_ATTR_CONFIG] == "a: 1\n"
        for sid, (maps, K, w2c, ws) in seqs.items():
            seq = r.read_sequence(sid)
            for name in schema.MAP_NAMES:
                got = seq.maps[name]
                assert got.dtype == maps[name].dtype and got.shape == maps[name].shape
                assert got.tobytes() == maps[name].tobytes(), name
            assert seq.K.tobytes() == K.tobytes()
            assert seq.world_to_camera.tobytes() == w2c.tobytes()
            assert seq.world_state == ws
            # Every dataset carries its unit; maps are chunked one frame per chunk and compressed.
            for name, spec in schema.MAPS.items():
                ds = r.file[sid][name]
                assert ds.attrs[schema.UNITS_ATTR] == spec.unit
                assert ds.chunks[0] == 1 and ds.chunks[1:] == ds.shape[1:]
                assert ds.compression == "gzip"
            # A frame range reads just those frames.
            np.testing.assert_array_equal(r.read(sid, schema.DEPTH, 2, 4), maps[schema.DEPTH][2:4])


@pytest.mark.parametrize("num_threads", [1, 3])
def test_chunks_deflated_by_the_writer_are_hdf5s_own(tmp_path: Path, num_threads: int) -> None:
    """The writer shuffles and deflates each frame's chunk itself (on num_threads threads) and stores it as is: every
    chunk holds the bytes HDF5's own shuffle + gzip pipeline writes for the same array, and reads back exactly."""
    maps, K, w2c, ws = render_fixture_sequence("s-0", "train", seed=3, num_frames=4, image_size=(16, 24))
    with ShardWriter(tmp_path, "train", 0, num_threads=num_threads) as w:
        w.add_sequence("s-0", maps, K, w2c, ws)
    with h5py.File(tmp_path / "reference.h5", "w") as ref:
        for name, arr in maps.items():
            ref.create_dataset(name, data=arr, chunks=(1,) + arr.shape[1:], compression="gzip", compression_opts=1,
                               shuffle=arr.dtype.itemsize > 1)  # fmt: skip
    with h5py.File(tmp_path / "train" / schema.shard_filename(0)) as f, h5py.File(tmp_path / "reference.h5") as ref:
        widths = set()
        for name, arr in maps.items():
            ours, theirs = f["s-0"][name], ref[name]
            assert ours.shuffle == (arr.dtype.itemsize > 1) and ours.compression_opts == 1
            widths.add(arr.dtype.itemsize)
            for t in range(arr.shape[0]):
                at = (t,) + (0,) * (arr.ndim - 1)
                mask, chunk = ours.id.read_direct_chunk(at)
                assert mask == 0 and chunk == theirs.id.read_direct_chunk(at)[1], (name, t)
            assert ours[()].tobytes() == arr.tobytes()
        assert {1, 2, 4} <= widths  # bytes (bool, uint8), uint16 and float32 maps: with and without the shuffle
    with pytest.raises(ValueError, match="num_threads must be >= 1, got 0"):
        ShardWriter(tmp_path, "train", 1, num_threads=0)


def test_index_lists_shards_and_frames(tmp_path: Path) -> None:
    _write(tmp_path, 0, ids=("a", "b"))
    _write(tmp_path, 1, ids=("c",))
    index = read_index(tmp_path / "train")
    assert [s["file"] for s in index["shards"]] == ["shard-00000.h5", "shard-00001.h5"]
    assert index["shards"][0]["sequences"] == [{"id": "a", "num_frames": 5}, {"id": "b", "num_frames": 5}]
    assert index["shards"][1]["num_frames"] == 5
    assert index["shards"][1]["size_bytes"] == (tmp_path / "train" / "shard-00001.h5").stat().st_size
    # Rewriting a shard replaces its entry instead of duplicating it.
    _write(tmp_path, 1, ids=("c", "d"))
    assert [s["num_sequences"] for s in read_index(tmp_path / "train")["shards"]] == [2, 2]


def test_exception_mid_shard_leaves_no_file(tmp_path: Path) -> None:
    maps, K, w2c, ws = render_fixture_sequence("s", "train", seed=0, num_frames=3, image_size=(8, 8))
    with pytest.raises(RuntimeError, match="boom"):
        with ShardWriter(tmp_path, "train", 0) as w:
            w.add_sequence("s", maps, K, w2c, ws)
            raise RuntimeError("boom")
    assert list((tmp_path / "train").iterdir()) == []


def test_killed_writer_leaves_no_final_file_and_is_cleaned(tmp_path: Path) -> None:
    script = textwrap.dedent(
        f"""
        import os, signal
        from newtphys.shards import ShardWriter
        from tests.fixtures.synthetic_scene import render_fixture_sequence
        maps, K, w2c, ws = render_fixture_sequence("s", "train", seed=0, num_frames=3, image_size=(8, 8))
        w = ShardWriter({str(tmp_path)!r}, "train", 0).open()
        w.add_sequence("s", maps, K, w2c, ws)
        os.kill(os.getpid(), signal.SIGKILL)
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == -signal.SIGKILL
    split = tmp_path / "train"
    assert not (split / "shard-00000.h5").exists()
    assert list_shards(split) == []
    assert len(list(split.glob("shard-00000.h5.tmp-*"))) == 1
    _write(tmp_path, 0, ids=("s",))  # the next writer of that shard removes the stale temp file
    assert sorted(p.name for p in split.iterdir() if not p.name.startswith(".")) == ["index.json", "shard-00000.h5"]


def test_writer_rejects_bad_arrays_before_writing(tmp_path: Path) -> None:
    maps, K, w2c, ws = render_fixture_sequence("s", "train", seed=0, num_frames=3, image_size=(8, 8))
    cases = {
        "dtype": ({**maps, schema.DEPTH: maps[schema.DEPTH].astype(np.float64)}, "map 'depth': dtype float64"),
        "shape": ({**maps, schema.STRESS: maps[schema.STRESS][:2]}, "map 'stress': shape (2, 8, 8), expected (3, 8, 8)"),
        "nan": ({**maps, schema.GRAVITY: np.full_like(maps[schema.GRAVITY], np.nan)}, "map 'gravity': contains NaN"),
        "missing": ({k: v for k, v in maps.items() if k != schema.COLLISION}, "missing maps ['collision']"),
    }
    for bad_maps, phrase in cases.values():
        with ShardWriter(tmp_path, "train", 0) as w, pytest.raises(ShardError) as info:
            w.add_sequence("s", bad_maps, K, w2c, ws)
        assert phrase in str(info.value)
        assert "sequence 's'" in str(info.value)


def _corrupt_copy(src: Path, dst: Path, edit) -> Path:
    dst.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(src, dst)
    with h5py.File(dst, "a") as f:
        edit(f)
    return dst


def test_reader_errors_are_clear(tmp_path: Path) -> None:
    path, _ = _write(tmp_path / "src", ids=("s-0",))
    truncated = tmp_path / "truncated.h5"
    truncated.write_bytes(path.read_bytes()[: path.stat().st_size // 3])
    with pytest.raises(ShardError, match="cannot open as HDF5"):
        ShardReader(truncated).sequences()

    missing = _corrupt_copy(path, tmp_path / "missing.h5", lambda f: f["s-0"].__delitem__(schema.STRESS))
    with pytest.raises(ShardError, match="sequence 's-0': dataset 'stress' missing"):
        ShardReader(missing).read("s-0", schema.STRESS)

    def wrong_dtype(f):
        data = f["s-0"][schema.DEPTH][()]
        del f["s-0"][schema.DEPTH]
        f["s-0"].create_dataset(schema.DEPTH, data=data.astype(np.float16))

    with pytest.raises(ShardError, match="dataset 'depth' has dtype float16, expected float32"):
        ShardReader(_corrupt_copy(path, tmp_path / "dtype.h5", wrong_dtype)).read("s-0", schema.DEPTH)

    def wrong_shape(f):
        data = f["s-0"][schema.INSTANCES][()]
        del f["s-0"][schema.INSTANCES]
        f["s-0"].create_dataset(schema.INSTANCES, data=data[:, :8])

    with pytest.raises(ShardError, match=r"'instances' has shape \(5, 8, 24\), expected \(5, 16, 24\)"):
        ShardReader(_corrupt_copy(path, tmp_path / "shape.h5", wrong_shape)).read("s-0", schema.INSTANCES)

    old = _corrupt_copy(path, tmp_path / "old.h5", lambda f: f.attrs.__setitem__(schema.FILE_ATTR_SCHEMA_VERSION, 0))
    with pytest.raises(ShardError, match="schema_version 0"):
        ShardReader(old).sequences()

    r = ShardReader(path)
    with pytest.raises(ShardError, match=r"frame range \[3, 9\) outside \[0, 5\)"):
        r.read("s-0", schema.RGB, 3, 9)
    with pytest.raises(ShardError, match="no sequence 'nope'"):
        r.read("nope", schema.RGB)
    with pytest.raises(KeyError, match="valid maps"):
        r.read("s-0", "normals")
    with pytest.raises(ShardError, match="no such shard file"):
        ShardReader(tmp_path / "absent.h5")


def test_reader_survives_pickle_and_fork(tmp_path: Path) -> None:
    path, seqs = _write(tmp_path, ids=("s-0",))
    r = ShardReader(path)
    expected = r.read("s-0", schema.RGB)  # opened in the parent
    clone = pickle.loads(pickle.dumps(r))
    assert clone.read("s-0", schema.RGB).tobytes() == expected.tobytes()
    pid = os.fork()
    if pid == 0:  # child: must re-open its own handle
        ok = r.read("s-0", schema.RGB).tobytes() == expected.tobytes()
        os._exit(0 if ok else 3)
    _, status = os.waitpid(pid, 0)
    assert os.WEXITSTATUS(status) == 0
    assert json.loads(r.file["s-0"][schema.WORLD_STATE][()])["sequence_id"] == "s-0"
