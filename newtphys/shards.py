"""HDF5 shards: atomic writer, lazy fork-safe reader, and the split index.

Layout and meaning are fixed by docs/data_contract.md and described by
:mod:`newtphys.schema`. Readers need nothing but h5py: maps are compressed
with gzip (+ byte shuffle), which every HDF5 build decodes without plugins,
and chunked one frame per chunk so a frame range reads only those frames.

Atomicity: :class:`ShardWriter` writes ``shard-NNNNN.h5.tmp-<pid>`` and
renames it to ``shard-NNNNN.h5`` only after a successful close, so a shard
that exists under its final name is whole. ``index.json`` is rewritten
atomically under a file lock, so parallel writers (Hydra multirun) never
lose each other's entries.
"""

from __future__ import annotations

import fcntl
import json
import logging
import os
import zlib
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from newtphys import __version__, schema
from newtphys.world_state import WorldState, WorldStateError

log = logging.getLogger(__name__)

COMPRESSION = "gzip"
COMPRESSION_LEVEL = 1
"""gzip level: measured in bench/bench_shards.py, level 1 reads a 4-frame 128^2 clip of all maps ~1.7x faster
than level 4 for ~4% more disk."""
CODECS: tuple[str | None, ...] = ("gzip", "lzf", None)
"""Codecs h5py decodes without plugins (gzip is also read by every other HDF5 build; lzf only by h5py)."""
TMP_MARKER = ".tmp-"


class ShardError(RuntimeError):
    """A shard or index cannot be read or does not follow the data contract."""


# --------------------------------------------------------------------------- #
# Writer
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class SequenceArrays:
    """Everything one sequence group holds, as in-memory arrays."""

    maps: Mapping[str, np.ndarray]
    K: np.ndarray
    world_to_camera: np.ndarray
    world_state: WorldState


def check_sequence_arrays(
    sequence_id: str,
    maps: Mapping[str, np.ndarray],
    K: np.ndarray,
    world_to_camera: np.ndarray,
    world_state: WorldState,
) -> None:
    """Raise ``ShardError`` if the arrays do not follow the contract (before anything is written)."""
    where = f"sequence '{sequence_id}'"
    missing = [n for n in schema.MAP_NAMES if n not in maps]
    if missing:
        raise ShardError(f"{where}: missing maps {missing}")
    unknown = [n for n in maps if n not in schema.MAPS]
    if unknown:
        raise ShardError(f"{where}: unknown maps {unknown}; valid maps: {list(schema.MAP_NAMES)}")
    t = world_state.num_frames
    h, w = world_state.image_size
    n = len(world_state.objects)
    for name, spec in schema.MAPS.items():
        arr = maps[name]
        if arr.dtype != spec.dtype:
            raise ShardError(f"{where}, map '{name}': dtype {arr.dtype}, expected {spec.dtype}")
        expected = spec.expected_shape(t, h, w, n)
        if arr.shape != expected:
            raise ShardError(
                f"{where}, map '{name}': shape {arr.shape}, expected {expected} "
                f"(T={t}, H={h}, W={w}, N={n} from the world state)"
            )
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            raise ShardError(f"{where}, map '{name}': contains NaN or Inf")
    for key, arr in ((schema.CAMERA_K, K), (schema.CAMERA_WORLD_TO_CAMERA, world_to_camera)):
        spec = schema.CAMERA_ARRAYS[key]
        if np.asarray(arr).shape != spec.expected_shape(t):
            raise ShardError(f"{where}, '{key}': shape {np.asarray(arr).shape}, expected {spec.expected_shape(t)}")
        if not np.isfinite(arr).all():
            raise ShardError(f"{where}, '{key}': contains NaN or Inf")
    if world_state.sequence_id != sequence_id:
        raise ShardError(f"{where}: world state names sequence '{world_state.sequence_id}'")


class ShardWriter:
    """Write sequences into one shard; the file appears under its final name only when complete.

    Use as a context manager::

        with ShardWriter(out_dir, split="train", shard_index=0, config_yaml=cfg) as w:
            w.add_sequence("seq-000000", maps, K, world_to_camera, world_state)

    An exception inside the block (or a kill) leaves no file under the final
    name; the temporary file is removed on exception, and a stale one from a
    killed writer is removed the next time that shard is written.
    """

    def __init__(
        self,
        out_dir: str | os.PathLike,
        split: str,
        shard_index: int,
        config_yaml: str = "",
        generator: str = f"newtphys {__version__}",
        compression: str | None = COMPRESSION,
        compression_level: int = COMPRESSION_LEVEL,
        num_threads: int = 1,
    ) -> None:
        """``num_threads``: threads compressing a map's frames (gzip: each frame is one chunk, deflated here by
        zlib, which releases the GIL, and stored as is; the same chunk bytes as HDF5's own filter pipeline)."""
        if compression not in CODECS:
            raise ValueError(f"compression must be one of {CODECS}, got {compression!r}")
        if int(num_threads) < 1:
            raise ValueError(f"num_threads must be >= 1, got {num_threads}")
        self.split_dir = Path(out_dir) / split
        self.split = split
        self.final_path = self.split_dir / schema.shard_filename(shard_index)
        self.tmp_path = self.final_path.with_name(f"{self.final_path.name}{TMP_MARKER}{os.getpid()}")
        self.config_yaml = config_yaml
        self.generator = generator
        self.compression = compression
        self.compression_level = compression_level if compression == "gzip" else None
        self.num_threads = int(num_threads)
        self._file: h5py.File | None = None
        self._sequences: list[tuple[str, int]] = []

    # -- lifecycle --------------------------------------------------------
    def open(self) -> ShardWriter:
        self.split_dir.mkdir(parents=True, exist_ok=True)
        for stale in self.split_dir.glob(f"{self.final_path.name}{TMP_MARKER}*"):
            log.warning("removing stale temporary shard %s (an earlier writer was interrupted)", stale)
            stale.unlink(missing_ok=True)
        f = h5py.File(self.tmp_path, "w")
        f.attrs[schema.FILE_ATTR_SCHEMA_VERSION] = schema.SCHEMA_VERSION
        f.attrs[schema.FILE_ATTR_SPLIT] = self.split
        f.attrs[schema.FILE_ATTR_GENERATOR] = self.generator
        f.attrs[schema.FILE_ATTR_CONFIG] = self.config_yaml
        self._file = f
        return self

    def __enter__(self) -> ShardWriter:
        return self.open()

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def abort(self) -> None:
        """Drop the temporary file; nothing appears under the final name."""
        if self._file is not None:
            try:
                self._file.close()
            finally:
                self._file = None
        self.tmp_path.unlink(missing_ok=True)

    def close(self) -> Path:
        """Flush, rename to the final name, and record the shard in ``index.json``."""
        if self._file is None:
            raise ShardError(f"{self.final_path}: writer is not open")
        self._file.flush()
        self._file.close()
        self._file = None
        os.replace(self.tmp_path, self.final_path)
        update_index(self.split_dir, self.final_path.name, self._sequences, self.final_path.stat().st_size)
        return self.final_path

    # -- content ----------------------------------------------------------
    def add_sequence(
        self,
        sequence_id: str,
        maps: Mapping[str, np.ndarray],
        K: np.ndarray,
        world_to_camera: np.ndarray,
        world_state: WorldState,
    ) -> None:
        """Validate and write one sequence group (all maps of docs/data_contract.md)."""
        if self._file is None:
            raise ShardError(f"{self.final_path}: writer is not open (use it as a context manager)")
        if sequence_id in self._file:
            raise ShardError(f"{self.final_path}: sequence '{sequence_id}' written twice")
        if world_state.split != self.split:
            raise ShardError(
                f"sequence '{sequence_id}': world state split '{world_state.split}' != shard split '{self.split}'"
            )
        check_sequence_arrays(sequence_id, maps, K, world_to_camera, world_state)
        g = self._file.create_group(sequence_id)
        for name, spec in schema.MAPS.items():
            arr = np.ascontiguousarray(maps[name])
            compress = self.compression is not None and arr.size > 0
            direct = compress and self.compression == "gzip"  # chunks deflated here, stored as they are
            ds = g.create_dataset(
                name,
                data=None if direct else arr,
                shape=arr.shape,
                dtype=arr.dtype,
                chunks=(1,) + arr.shape[1:] if arr.size else None,
                compression=self.compression if compress else None,
                compression_opts=self.compression_level if compress else None,
                shuffle=compress and arr.dtype.itemsize > 1,
            )
            if direct:
                self._write_gzip_chunks(ds, arr)
            ds.attrs[schema.UNITS_ATTR] = spec.unit
        for key, arr in ((schema.CAMERA_K, K), (schema.CAMERA_WORLD_TO_CAMERA, world_to_camera)):
            spec = schema.CAMERA_ARRAYS[key]
            ds = g.create_dataset(key, data=np.asarray(arr, dtype=spec.dtype))
            ds.attrs[schema.UNITS_ATTR] = spec.unit
        ds = g.create_dataset(schema.WORLD_STATE, data=world_state.to_json(), dtype=h5py.string_dtype("utf-8"))
        ds.attrs[schema.UNITS_ATTR] = schema.WORLD_STATE_UNIT
        self._sequences.append((sequence_id, world_state.num_frames))

    def _write_gzip_chunks(self, ds: h5py.Dataset, arr: np.ndarray) -> None:
        """Every frame of ``arr`` as one chunk of ``ds``, through the dataset's own filters done here: HDF5's
        byte shuffle (elements wider than a byte), then zlib's deflate at the writer's level (HDF5's gzip filter
        is zlib's ``compress2``: the same bytes). Frames are compressed ``num_threads`` at a time."""
        level = int(self.compression_level)  # (gzip: always set)
        tail = (0,) * (arr.ndim - 1)

        def deflate(t: int) -> bytes:
            frame = arr[t].reshape(-1).view(np.uint8)
            size = arr.dtype.itemsize
            if size > 1:  # HDF5's shuffle: every element's first byte, then every second byte, ...
                frame = np.ascontiguousarray(frame.reshape(-1, size).T)
            return zlib.compress(frame.tobytes(), level)

        frames = range(arr.shape[0])
        if self.num_threads == 1:
            for t in frames:
                ds.id.write_direct_chunk((t,) + tail, deflate(t), filter_mask=0)
            return
        with ThreadPoolExecutor(min(self.num_threads, arr.shape[0])) as pool:
            for t, chunk in enumerate(pool.map(deflate, frames)):  # (in frame order; the chunks are written here)
                ds.id.write_direct_chunk((t,) + tail, chunk, filter_mask=0)

    @property
    def num_sequences(self) -> int:
        return len(self._sequences)


# --------------------------------------------------------------------------- #
# Index
# --------------------------------------------------------------------------- #
@contextmanager
def _locked(split_dir: Path) -> Iterator[None]:
    lock_path = split_dir / f".{schema.INDEX_FILENAME}.lock"
    with open(lock_path, "a+") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _write_json_atomic(path: Path, data: Any) -> None:
    tmp = path.with_name(f"{path.name}{TMP_MARKER}{os.getpid()}")
    tmp.write_text(json.dumps(data, indent=1, sort_keys=False))
    os.replace(tmp, path)


def read_index(split_dir: str | os.PathLike) -> dict[str, Any]:
    """Read ``<split_dir>/index.json``; raises ShardError naming the file when missing or malformed."""
    path = Path(split_dir) / schema.INDEX_FILENAME
    if not path.is_file():
        raise ShardError(f"{path}: index file missing (is {split_dir} a NewtPhys split directory?)")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ShardError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(data, dict) or not isinstance(data.get("shards"), list):
        raise ShardError(f"{path}: expected an object with a 'shards' list")
    return data


def update_index(split_dir: Path, shard_name: str, sequences: list[tuple[str, int]], size_bytes: int) -> None:
    """Add or replace one shard's entry in ``index.json`` (atomic, locked)."""
    split_dir = Path(split_dir)
    with _locked(split_dir):
        path = split_dir / schema.INDEX_FILENAME
        if path.exists():
            data = read_index(split_dir)
        else:
            data = {"schema_version": schema.SCHEMA_VERSION, "split": split_dir.name, "shards": []}
        entry = {
            "file": shard_name,
            "size_bytes": int(size_bytes),
            "num_sequences": len(sequences),
            "num_frames": int(sum(n for _, n in sequences)),
            "sequences": [{"id": sid, "num_frames": int(n)} for sid, n in sequences],
        }
        shards = [s for s in data["shards"] if s.get("file") != shard_name] + [entry]
        data["shards"] = sorted(shards, key=lambda s: s["file"])
        _write_json_atomic(path, data)


def list_shards(split_dir: str | os.PathLike) -> list[Path]:
    """Complete shards of a split directory, sorted (temporary files are ignored)."""
    return sorted(p for p in Path(split_dir).glob(schema.SHARD_GLOB) if p.is_file())


# --------------------------------------------------------------------------- #
# Reader
# --------------------------------------------------------------------------- #
class ShardReader:
    """Lazy reader of one shard.

    The HDF5 file is opened on first access and re-opened after a fork, so
    one reader may be created in the main process and used from DataLoader
    worker processes. Every read checks the dataset against the schema and
    raises :class:`ShardError` naming the file, sequence and dataset instead
    of returning garbage.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._file: h5py.File | None = None
        self._pid: int | None = None
        self._world_states: dict[str, WorldState] = {}
        if not self.path.is_file():
            raise ShardError(f"{self.path}: no such shard file")

    # -- file handling ----------------------------------------------------
    @property
    def file(self) -> h5py.File:
        if self._file is None or self._pid != os.getpid():
            try:
                f = h5py.File(self.path, "r")
            except OSError as e:
                raise ShardError(f"{self.path}: cannot open as HDF5 (truncated or corrupted?): {e}") from None
            version = f.attrs.get(schema.FILE_ATTR_SCHEMA_VERSION)
            if version is None:
                f.close()
                raise ShardError(f"{self.path}: missing file attribute '{schema.FILE_ATTR_SCHEMA_VERSION}'")
            if int(version) != schema.SCHEMA_VERSION:
                f.close()
                raise ShardError(
                    f"{self.path}: schema_version {int(version)}, this reader reads version "
                    f"{schema.SCHEMA_VERSION}; regenerate the data or install a matching newtphys"
                )
            self._file, self._pid = f, os.getpid()
        return self._file

    def close(self) -> None:
        if self._file is not None and self._pid == os.getpid():
            self._file.close()
        self._file = None

    def __enter__(self) -> ShardReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __getstate__(self) -> dict[str, Any]:  # picklable for DataLoader workers
        state = self.__dict__.copy()
        state["_file"] = None
        state["_pid"] = None
        return state

    # -- metadata ---------------------------------------------------------
    @property
    def attrs(self) -> dict[str, Any]:
        return {k: (v.decode() if isinstance(v, bytes) else v) for k, v in self.file.attrs.items()}

    @property
    def split(self) -> str:
        return str(self.attrs.get(schema.FILE_ATTR_SPLIT, ""))

    def sequences(self) -> list[str]:
        return sorted(self.file.keys())

    def _group(self, sequence_id: str) -> h5py.Group:
        try:
            return self.file[sequence_id]
        except KeyError:
            raise ShardError(
                f"{self.path}: no sequence '{sequence_id}' (has {', '.join(self.sequences()) or 'none'})"
            ) from None

    def _dataset(self, sequence_id: str, name: str) -> h5py.Dataset:
        g = self._group(sequence_id)
        if name not in g:
            raise ShardError(f"{self.path}: sequence '{sequence_id}': dataset '{name}' missing")
        return g[name]

    def world_state(self, sequence_id: str) -> WorldState:
        if sequence_id not in self._world_states:
            raw = self._dataset(sequence_id, schema.WORLD_STATE)[()]
            text = raw.decode("utf-8") if isinstance(raw, bytes) else str(raw)
            try:
                self._world_states[sequence_id] = WorldState.from_json(text, sequence_id)
            except WorldStateError as e:
                raise ShardError(f"{self.path}: {e}") from None
        return self._world_states[sequence_id]

    def num_frames(self, sequence_id: str) -> int:
        return self.world_state(sequence_id).num_frames

    def intrinsics(self, sequence_id: str) -> np.ndarray:
        return self._read_array(sequence_id, schema.CAMERA_K)

    def world_to_camera(self, sequence_id: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        return self._read_array(sequence_id, schema.CAMERA_WORLD_TO_CAMERA, start, stop)

    def _read_array(self, sequence_id: str, key: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        spec = schema.CAMERA_ARRAYS[key]
        ds = self._dataset(sequence_id, key)
        ws = self.world_state(sequence_id)
        if ds.dtype != spec.dtype or ds.shape != spec.expected_shape(ws.num_frames):
            raise ShardError(
                f"{self.path}: sequence '{sequence_id}': dataset '{key}' has dtype {ds.dtype} shape {ds.shape}, "
                f"expected {spec.dtype} {spec.expected_shape(ws.num_frames)}"
            )
        return ds[()] if "T" not in spec.shape else ds[start:stop]

    # -- maps ---------------------------------------------------------------
    def read(self, sequence_id: str, name: str, start: int = 0, stop: int | None = None) -> np.ndarray:
        """Frames [start, stop) of one map, without touching other maps or frames."""
        spec = schema.get_map(name)
        ds = self._dataset(sequence_id, name)
        ws = self.world_state(sequence_id)
        h, w = ws.image_size
        expected = spec.expected_shape(ws.num_frames, h, w, len(ws.objects))
        if ds.dtype != spec.dtype:
            raise ShardError(
                f"{self.path}: sequence '{sequence_id}': dataset '{name}' has dtype {ds.dtype}, expected {spec.dtype}"
            )
        if ds.shape != expected:
            raise ShardError(
                f"{self.path}: sequence '{sequence_id}': dataset '{name}' has shape {ds.shape}, expected {expected}"
            )
        t = ws.num_frames
        stop = t if stop is None else stop
        if not 0 <= start < stop <= t:
            raise ShardError(
                f"{self.path}: sequence '{sequence_id}': frame range [{start}, {stop}) outside [0, {t})"
            )
        try:
            return ds[start:stop]
        except OSError as e:
            raise ShardError(
                f"{self.path}: sequence '{sequence_id}': dataset '{name}' frames [{start}, {stop}) "
                f"cannot be read (corrupted?): {e}"
            ) from None

    def read_frames(self, sequence_id: str, names: list[str], start: int, stop: int) -> dict[str, np.ndarray]:
        return {n: self.read(sequence_id, n, start, stop) for n in names}

    def read_sequence(self, sequence_id: str) -> SequenceArrays:
        """Everything of one sequence (for tools and tests; training reads frame ranges)."""
        return SequenceArrays(
            maps={n: self.read(sequence_id, n) for n in schema.MAP_NAMES},
            K=self.intrinsics(sequence_id),
            world_to_camera=self.world_to_camera(sequence_id),
            world_state=self.world_state(sequence_id),
        )



# --------------------------------------------------------------------------- #
# Merging the work of many jobs
# --------------------------------------------------------------------------- #
CONFIG_KEYS_PER_JOB = ("job", "num_jobs", "shards", "progress")
"""Top-level config keys that differ between the jobs of one split and are ignored by :func:`merge_index`."""


def _job_independent_config(config_yaml: str) -> str:
    """A shard's resolved config without the keys that name its job (comparable across jobs)."""
    import yaml

    try:
        data = yaml.safe_load(config_yaml) if config_yaml else None
    except yaml.YAMLError:
        return config_yaml
    if not isinstance(data, dict):
        return config_yaml
    return yaml.safe_dump({k: v for k, v in data.items() if k not in CONFIG_KEYS_PER_JOB}, sort_keys=True)


@dataclass(frozen=True)
class MergeReport:
    shards: int
    sequences: int
    frames: int
    missing_shards: list[int]
    """Shard indices below the highest present one with no final file (a job still running or failed)."""


def merge_index(split_dir: str | os.PathLike, expected_sequences: int | None = None) -> MergeReport:
    """Rebuild ``<split_dir>/index.json`` from the complete shards there (what many jobs wrote, each under
    its own shard names), atomically and under the index lock, after checking that they form one split:

    * every shard's ``split`` attribute is the directory's split and its schema version this one;
    * no sequence id appears in two shards (jobs wrote disjoint shards);
    * every shard was generated from the same config apart from the job keys (``CONFIG_KEYS_PER_JOB``);
    * with ``expected_sequences``: exactly that many sequences, ids ``<split>-000000`` onwards, none missing.

    Raises :class:`ShardError` naming the shard and the problem; returns counts and missing shard indices."""
    split_dir = Path(split_dir)
    shards = list_shards(split_dir)
    if not shards:
        raise ShardError(f"{split_dir}: no complete shards ({schema.SHARD_GLOB}) to merge")
    entries, seen, configs = [], {}, {}
    for path in shards:
        with ShardReader(path) as r:
            if r.split != split_dir.name:
                raise ShardError(f"{path}: split attribute {r.split!r}, but the directory is split {split_dir.name!r}")
            configs[path.name] = _job_independent_config(str(r.attrs.get(schema.FILE_ATTR_CONFIG, "")))
            seqs = [(sid, r.num_frames(sid)) for sid in r.sequences()]
        for sid, _ in seqs:
            if sid in seen:
                raise ShardError(f"{path}: sequence {sid!r} also in {seen[sid]} (jobs overlapped)")
            seen[sid] = path.name
        entries.append({"file": path.name, "size_bytes": int(path.stat().st_size), "num_sequences": len(seqs),
                        "num_frames": int(sum(n for _, n in seqs)),
                        "sequences": [{"id": sid, "num_frames": int(n)} for sid, n in seqs]})
    reference = configs[shards[0].name]
    differing = [name for name, c in configs.items() if c != reference]
    if differing:
        raise ShardError(f"{split_dir}: shards {differing} were generated with a config other than {shards[0].name}'s "
                         f"(apart from {list(CONFIG_KEYS_PER_JOB)}): not one split")
    if expected_sequences is not None:
        want = {f"{split_dir.name}-{i:06d}" for i in range(expected_sequences)}
        missing, extra = sorted(want - set(seen)), sorted(set(seen) - want)
        if missing or extra:
            raise ShardError(f"{split_dir}: expected sequences {split_dir.name}-000000..{expected_sequences - 1:06d}; "
                             f"missing {missing[:5]}{'...' if len(missing) > 5 else ''} ({len(missing)}), "
                             f"unexpected {extra[:5]} ({len(extra)})")
    present = sorted(int(p.name[len("shard-"):-len(".h5")]) for p in shards)
    missing_shards = sorted(set(range(present[-1] + 1)) - set(present))
    with _locked(split_dir):
        _write_json_atomic(split_dir / schema.INDEX_FILENAME,
                           {"schema_version": schema.SCHEMA_VERSION, "split": split_dir.name, "shards": entries})
    return MergeReport(shards=len(entries), sequences=len(seen), frames=int(sum(e["num_frames"] for e in entries)),
                       missing_shards=missing_shards)
