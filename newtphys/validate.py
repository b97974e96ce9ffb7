"""Check shards and split indices against the data contract.

``validate_paths`` walks files and directories and returns one
:class:`Problem` per violation: file, sequence, dataset and what is wrong.
It never raises on bad data; it reports it.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

from newtphys import schema
from newtphys.shards import TMP_MARKER, ShardReader, list_shards
from newtphys.world_state import WorldState, WorldStateError


@dataclass(frozen=True)
class Problem:
    file: str
    message: str
    sequence: str = ""
    dataset: str = ""
    severity: str = "error"  # "error" fails validation, "warning" does not

    def __str__(self) -> str:
        where = "/".join(p for p in (self.sequence, self.dataset) if p)
        return f"{self.severity}: {self.file}: {where + ': ' if where else ''}{self.message}"


def _frames(ds: h5py.Dataset) -> Iterable[np.ndarray]:
    """Iterate a per-frame-chunked dataset frame by frame (bounded memory)."""
    for t in range(ds.shape[0]):
        yield ds[t]


class _ShardChecker:
    def __init__(self, path: Path, deep: bool = False) -> None:
        self.path = path
        self.deep = deep
        self.problems: list[Problem] = []

    def add(self, message: str, sequence: str = "", dataset: str = "", severity: str = "error") -> None:
        self.problems.append(Problem(str(self.path), message, sequence, dataset, severity))

    def run(self) -> list[Problem]:
        try:
            f = h5py.File(self.path, "r")
        except OSError as e:
            self.add(f"cannot open as HDF5 (truncated or corrupted?): {e}")
            return self.problems
        with f:
            self._check_file_attrs(f)
            if not len(f.keys()):
                self.add("shard holds no sequence")
            for sid in sorted(f.keys()):
                item = f[sid]
                if not isinstance(item, h5py.Group):
                    self.add("top-level item is not a sequence group", sid)
                    continue
                before = len(self.problems)
                try:
                    self._check_sequence(sid, item)
                except (OSError, RuntimeError) as e:  # HDF5 read errors inside a corrupted file
                    self.add(f"read error (corrupted data?): {e}", sid)
                if self.deep and len(self.problems) == before:
                    self._check_physics(sid)
        return self.problems

    def _check_physics(self, sid: str) -> None:
        from newtphys.consistency import TOLERANCES, check_sequence, failing

        with ShardReader(self.path) as reader:
            residuals = check_sequence(reader.read_sequence(sid))
        for r in failing(residuals):
            self.add(f"cross-map check failed: {r} (tolerance {TOLERANCES[r.name]:g} {r.unit})", sid)

    def _check_file_attrs(self, f: h5py.File) -> None:
        for attr in schema.FILE_ATTRS:
            if attr not in f.attrs:
                self.add(f"missing file attribute '{attr}'")
        version = f.attrs.get(schema.FILE_ATTR_SCHEMA_VERSION)
        if version is not None and int(version) != schema.SCHEMA_VERSION:
            self.add(f"schema_version {int(version)}, expected {schema.SCHEMA_VERSION}")

    def _check_sequence(self, sid: str, g: h5py.Group) -> None:
        if schema.WORLD_STATE not in g:
            self.add("dataset missing", sid, schema.WORLD_STATE)
            return
        raw = g[schema.WORLD_STATE][()]
        try:
            ws = WorldState.from_json(raw.decode() if isinstance(raw, bytes) else str(raw), sid)
        except WorldStateError as e:
            self.add(str(e), sid, schema.WORLD_STATE)
            return
        if ws.sequence_id != sid:
            self.add(f"names sequence '{ws.sequence_id}', group is '{sid}'", sid, schema.WORLD_STATE)
        t, (h, w), n = ws.num_frames, ws.image_size, len(ws.objects)
        object_ids = {o.id for o in ws.objects}
        known = {
            schema.INSTANCES: object_ids | {schema.BACKGROUND_ID},
            schema.MATERIALS: {int(k) for k in ws.materials} | {schema.BACKGROUND_ID},
            schema.AMODAL_MATERIALS: {int(k) for k in ws.materials} | {schema.BACKGROUND_ID},
            schema.SEMANTIC_SEGMENTATION: {int(k) for k in ws.semantic_classes} | {schema.BACKGROUND_ID},
            schema.AMODAL_SEMANTIC_SEGMENTATION: {int(k) for k in ws.semantic_classes} | {schema.BACKGROUND_ID},
        }
        table = {
            schema.INSTANCES: "world-state objects",
            schema.MATERIALS: "world-state materials table",
            schema.AMODAL_MATERIALS: "world-state materials table",
            schema.SEMANTIC_SEGMENTATION: "world-state semantic_classes table",
            schema.AMODAL_SEMANTIC_SEGMENTATION: "world-state semantic_classes table",
        }
        extra = set(g.keys()) - set(schema.MAP_NAMES) - {schema.CAMERA_GROUP, schema.WORLD_STATE}
        for name in sorted(extra):
            self.add("unknown dataset (not in the schema)", sid, name, severity="warning")
        for name, spec in schema.MAPS.items():
            if name not in g:
                self.add("dataset missing", sid, name)
                continue
            ds = g[name]
            expected = spec.expected_shape(t, h, w, n)
            ok = True
            if ds.dtype != spec.dtype:
                self.add(f"dtype {ds.dtype}, expected {spec.dtype}", sid, name)
                ok = False
            if ds.shape != expected:
                self.add(
                    f"shape {ds.shape}, expected {expected} (T={t} frames, H={h}, W={w}, N={n} objects "
                    "from the world state)",
                    sid,
                    name,
                )
                ok = False
            unit = ds.attrs.get(schema.UNITS_ATTR)
            if unit is None:
                self.add(f"missing '{schema.UNITS_ATTR}' attribute (expected '{spec.unit}')", sid, name)
            elif (unit.decode() if isinstance(unit, bytes) else str(unit)) != spec.unit:
                self.add(f"units '{unit}', expected '{spec.unit}'", sid, name)
            if not ok:
                continue
            if spec.dtype.kind == "f":
                bad = [i for i, fr in enumerate(_frames(ds)) if not np.isfinite(fr).all()]
                if bad:
                    self.add(f"non-finite values (NaN/Inf) in frames {bad[:10]}", sid, name)
            if name in known:
                seen: set[int] = set()
                for fr in _frames(ds):
                    seen.update(np.unique(fr).tolist())
                unknown = sorted(seen - known[name])
                if unknown:
                    self.add(f"ids {unknown[:10]} not in the {table[name]}", sid, name)
        for key, spec in schema.CAMERA_ARRAYS.items():
            if key not in g:
                self.add("dataset missing", sid, key)
                continue
            ds = g[key]
            if ds.dtype != spec.dtype or ds.shape != spec.expected_shape(t):
                self.add(
                    f"dtype {ds.dtype} shape {ds.shape}, expected {spec.dtype} {spec.expected_shape(t)}", sid, key
                )
            elif not np.isfinite(ds[()]).all():
                self.add("non-finite values (NaN/Inf)", sid, key)
        self._check_cross_map(sid, g, ws)

    def _check_cross_map(self, sid: str, g: h5py.Group, ws: WorldState) -> None:
        """Cheap consistency: labels only where there is a surface; amodal contains modal."""
        needed = (schema.DEPTH, schema.INSTANCES, schema.AMODAL_INSTANCES)
        if not all(n in g and g[n].dtype == schema.MAPS[n].dtype for n in needed):
            return
        depth, inst, amodal = (g[n] for n in needed)
        if depth.shape[:3] != inst.shape or amodal.shape[0] != inst.shape[0]:
            return
        for t in range(inst.shape[0]):
            ids = inst[t]
            if np.any((ids > 0) & (depth[t] <= 0)):
                self.add(f"frame {t}: object pixels without positive depth", sid, schema.DEPTH)
                return
            a = amodal[t]
            for k in range(a.shape[0]):
                if np.any((ids == k + 1) & ~a[k]):
                    self.add(
                        f"frame {t}: visible pixels of object {k + 1} outside its amodal silhouette",
                        sid,
                        schema.AMODAL_INSTANCES,
                    )
                    return


def validate_shard(path: str | os.PathLike, deep: bool = False) -> list[Problem]:
    """Contract checks of one shard; ``deep`` adds the cross-map physics checks of newtphys.consistency."""
    return _ShardChecker(Path(path), deep).run()


def validate_split_dir(split_dir: str | os.PathLike, deep: bool = False) -> list[Problem]:
    """Every shard of a split directory plus its ``index.json``."""
    split_dir = Path(split_dir)
    problems: list[Problem] = []
    shards = list_shards(split_dir)
    for path in shards:
        problems += validate_shard(path, deep)
    for stale in sorted(split_dir.glob(f"*{TMP_MARKER}*")):
        problems.append(
            Problem(str(stale), "temporary file of an interrupted writer (safe to delete)", severity="warning")
        )
    index_path = split_dir / schema.INDEX_FILENAME
    if not index_path.exists():
        problems.append(Problem(str(index_path), "index file missing"))
        return problems
    try:
        index = json.loads(index_path.read_text())
        entries = {e["file"]: e for e in index["shards"]}
    except (json.JSONDecodeError, KeyError, TypeError) as e:
        problems.append(Problem(str(index_path), f"malformed index ({e!r})"))
        return problems
    on_disk = {p.name for p in shards}
    for name in sorted(set(entries) - on_disk):
        problems.append(Problem(str(index_path), f"lists shard '{name}' that does not exist"))
    for name in sorted(on_disk - set(entries)):
        problems.append(Problem(str(index_path), f"does not list shard '{name}'"))
    for name in sorted(set(entries) & on_disk):
        try:
            with h5py.File(split_dir / name, "r") as f:
                actual = {}
                for sid in f.keys():
                    raw = f[sid][schema.WORLD_STATE][()] if schema.WORLD_STATE in f[sid] else None
                    actual[sid] = json.loads(raw)["num_frames"] if raw is not None else None
        except (OSError, KeyError, json.JSONDecodeError, TypeError):
            continue  # already reported by the shard check
        listed = {s["id"]: s["num_frames"] for s in entries[name].get("sequences", [])}
        if listed != actual:
            problems.append(
                Problem(str(index_path), f"entry for '{name}' lists {listed}, the shard holds {actual}")
            )
    return problems


def validate_paths(paths: Iterable[str | os.PathLike], deep: bool = False) -> list[Problem]:
    """Validate shard files, split directories, or dataset roots holding split directories."""
    problems: list[Problem] = []
    for raw in paths:
        p = Path(raw)
        if p.is_file():
            problems += validate_shard(p, deep)
        elif p.is_dir():
            split_dirs = [p] if (list_shards(p) or (p / schema.INDEX_FILENAME).exists()) else []
            split_dirs += [d for d in sorted(p.iterdir()) if d.is_dir() and (list_shards(d) or (d / schema.INDEX_FILENAME).exists())]
            if not split_dirs:
                problems.append(Problem(str(p), "no shards and no index.json found"))
            for d in split_dirs:
                problems += validate_split_dir(d, deep)
        else:
            problems.append(Problem(str(p), "no such file or directory"))
    return problems
