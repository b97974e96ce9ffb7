"""`python -m newtphys validate`: one precise line per problem, non-zero exit on errors."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest

from newtphys import schema
from newtphys.cli import main
from newtphys.validate import validate_paths
from tests.fixtures.synthetic_scene import write_fixture_split

SEQ = "train-000000"


@pytest.fixture()
def split_dir(tmp_path: Path) -> Path:
    return write_fixture_split(tmp_path, "train", num_sequences=2, sequences_per_shard=2, num_frames=4, image_size=(12, 16))


def _edit(split_dir: Path, edit) -> Path:
    path = split_dir / "shard-00000.h5"
    with h5py.File(path, "a") as f:
        edit(f[SEQ])
    return path


def _replace(g: h5py.Group, name: str, data: np.ndarray) -> None:
    units = g[name].attrs.get(schema.UNITS_ATTR)
    del g[name]
    g.create_dataset(name, data=data).attrs[schema.UNITS_ATTR] = units


def _messages(paths) -> list[str]:
    return [str(p) for p in validate_paths(paths) if p.severity == "error"]


def test_clean_data_passes(split_dir: Path, capsys) -> None:
    assert _messages([split_dir]) == []
    assert main(["validate", str(split_dir)]) == 0
    assert "0 error(s)" in capsys.readouterr().out


@pytest.mark.parametrize(
    "edit, expected",
    [
        (lambda g: g.__delitem__(schema.OPTICAL_FLOW), f"{SEQ}/optical_flow: dataset missing"),
        (lambda g: _replace(g, schema.DEPTH, g[schema.DEPTH][()].astype(np.float64)),
         f"{SEQ}/depth: dtype float64, expected float32"),
        (lambda g: _replace(g, schema.SCENE_FLOW, g[schema.SCENE_FLOW][()][:3]),
         f"{SEQ}/scene_flow: shape (3, 12, 16, 3), expected (4, 12, 16, 3) (T=4 frames"),
        (lambda g: _replace(g, schema.AMODAL_INSTANCES, g[schema.AMODAL_INSTANCES][()][:, :1]),
         f"{SEQ}/amodal_instances: shape (4, 1, 12, 16), expected (4, 2, 12, 16)"),
        (lambda g: g[schema.INSTANCES].__setitem__((1, 0, 0), 7),
         f"{SEQ}/instances: ids [7] not in the world-state objects"),
        (lambda g: g[schema.MATERIALS].__setitem__((0, 0, 0), 9),
         f"{SEQ}/materials: ids [9] not in the world-state materials table"),
        (lambda g: g[schema.STRESS].__setitem__((2, 3, 3), np.nan),
         f"{SEQ}/stress: non-finite values (NaN/Inf) in frames [2]"),
        (lambda g: g[schema.CAMERA_WORLD_TO_CAMERA].__setitem__((0, 0, 0), np.inf),
         f"{SEQ}/camera/world_to_camera: non-finite values"),
        (lambda g: g[schema.DEPTH].attrs.__setitem__(schema.UNITS_ATTR, "mm"),
         f"{SEQ}/depth: units 'mm', expected 'm'"),
        (lambda g: _replace(g, schema.WORLD_STATE, np.array(
            json.dumps({**json.loads(g[schema.WORLD_STATE][()]), "num_frames": 5}), dtype=h5py.string_dtype())),
         "key 'frames': has 4 entries but num_frames is 5"),
        (lambda g: g[schema.AMODAL_INSTANCES].__setitem__(slice(None), False),
         "visible pixels of object 1 outside its amodal silhouette"),
    ],
    ids=["missing", "dtype", "frames", "objects", "unknown-id", "unknown-material", "nan", "camera-inf",
         "units", "num-frames", "amodal"],
)
def test_each_problem_is_reported_precisely(split_dir: Path, edit, expected: str) -> None:
    path = _edit(split_dir, edit)
    msgs = _messages([split_dir])
    assert any(expected in m and str(path) in m for m in msgs), msgs


def test_truncated_and_garbage_files(split_dir: Path) -> None:
    path = split_dir / "shard-00000.h5"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    assert any("cannot open as HDF5 (truncated or corrupted?)" in m for m in _messages([path]))
    path.write_bytes(b"\x00" * 1000)
    assert any("cannot open as HDF5" in m for m in _messages([path]))


def test_index_mismatches(split_dir: Path) -> None:
    shutil.copy(split_dir / "shard-00000.h5", split_dir / "shard-00007.h5")
    (split_dir / "shard-00000.h5").rename(split_dir / "shard-00003.h5")
    msgs = _messages([split_dir])
    assert any("lists shard 'shard-00000.h5' that does not exist" in m for m in msgs)
    assert any("does not list shard 'shard-00007.h5'" in m for m in msgs)


def test_cli_exit_code_and_one_line_per_problem(split_dir: Path) -> None:
    _edit(split_dir, lambda g: g[schema.STRESS].__setitem__((0, 0, 0), np.nan))
    proc = subprocess.run([sys.executable, "-m", "newtphys", "validate", str(split_dir)],
                          capture_output=True, text=True, cwd=Path(__file__).resolve().parents[2])
    assert proc.returncode == 1
    lines = proc.stdout.strip().splitlines()
    assert lines[0].startswith("error: ") and "stress: non-finite" in lines[0]
    assert lines[-1].endswith("1 error(s), 0 warning(s)")
    missing = subprocess.run([sys.executable, "-m", "newtphys", "validate", "/nonexistent/x"],
                             capture_output=True, text=True)
    assert missing.returncode == 1 and "no such file or directory" in missing.stdout
