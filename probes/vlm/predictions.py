"""A run directory's predictions that survive ``kill -9``: appended per batch, read back, resumed.

* :meth:`PredictionStore.append` writes a batch's lines with one ``write``, then ``flush`` and ``fsync``: a
  killed process loses at most the batch in flight.
* On open, a torn last line (no newline: the process died inside the write) is cut off the file, and every
  complete line must parse; an ``(idx, rotation)`` present twice is an error (a store never writes one
  twice: :func:`probes.vlm.evaluate.evaluate` skips what is done).
* ``manifest.json`` is written once, atomically, by the first run; a later run whose manifest differs in
  the question set, the prompt template, the circular mode or the model's identity is refused with
  :class:`MixedRunError` naming the differences (volatile settings such as the device or batch size may
  change between runs).
* While a store is open it holds an exclusive ``flock`` on ``<run_dir>/.lock``: a second process writing the
  same directory gets :class:`RunDirectoryBusy` (the kernel releases the lock of a killed process).

The readers every other module uses live here too: :func:`read_manifest`, :func:`manifest_set_dir`,
:func:`read_predictions`.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterable
from dataclasses import asdict
from pathlib import Path
from typing import Any, Self

from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE, PredictionRecord, RunManifest
from probes.vlm.prompting import ROTATIONS, resolve_set_dir

log = logging.getLogger(__name__)

VOLATILE_MODEL_KEYS: frozenset[str] = frozenset(
    {"device", "device_map", "batch_size", "load_seconds", "cache_dir", "path", "attn_implementation"}
)
"""Keys of ``RunManifest.model`` that may differ between the runs of one result (they do not change answers
in principle); every other key is the model's identity."""
IDENTITY_FIELDS: tuple[str, ...] = ("answerer", "question_set_sha256", "prompt_template_sha256", "circular")


LOCK_FILE = ".lock"


class MixedRunError(RuntimeError):
    """A run directory holds predictions of another question set, prompt template or model."""


class RunDirectoryBusy(RuntimeError):
    """Another process is writing the same run directory."""


def _identity(manifest: dict[str, Any]) -> dict[str, Any]:
    model = {k: v for k, v in (manifest.get("model") or {}).items() if k not in VOLATILE_MODEL_KEYS}
    return {**{k: manifest.get(k) for k in IDENTITY_FIELDS}, "model": model}


def manifest_differences(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    """``"key: old -> new"`` for every identity field that differs (empty when the runs may be mixed)."""
    a, b = _identity(old), _identity(new)
    out = [f"{k}: {a[k]!r} -> {b[k]!r}" for k in IDENTITY_FIELDS if a[k] != b[k]]
    for k in sorted(set(a["model"]) | set(b["model"])):
        if a["model"].get(k) != b["model"].get(k):
            out.append(f"model.{k}: {a['model'].get(k)!r} -> {b['model'].get(k)!r}")
    return out


def read_manifest(run_dir: Path | str) -> dict[str, Any]:
    """``<run_dir>/manifest.json`` as a dict; a clear error when ``run_dir`` is not a run directory."""
    path = Path(run_dir) / MANIFEST_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no run manifest (a run directory holds {MANIFEST_FILE})")
    return json.loads(path.read_text())


def manifest_set_dir(manifest: dict[str, Any], run_dir: Path | str | None = None) -> Path:
    """The question-set split directory of a run: ``vqa_dir`` when it holds ``questions.jsonl`` (the evaluation
    loop records the split directory), else ``<vqa_dir>/<split>`` (:func:`probes.vlm.prompting.resolve_set_dir`)."""
    try:
        return resolve_set_dir(manifest["vqa_dir"], manifest.get("split") or None)
    except FileNotFoundError as e:
        where = f"{run_dir}/{MANIFEST_FILE}: " if run_dir is not None else ""
        raise FileNotFoundError(f"{where}{e}; or pass the set directory explicitly") from None


def write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)


def cut_torn_tail(path: Path) -> int:
    """Truncate ``path`` after its last newline; returns the number of bytes dropped (0 when none)."""
    if not path.is_file():
        return 0
    size = path.stat().st_size
    if size == 0:
        return 0
    with open(path, "rb+") as f:
        f.seek(-1, os.SEEK_END)
        if f.read(1) == b"\n":
            return 0
        # scan back for the last newline
        pos, block = size, 1 << 16
        keep = 0
        while pos > 0:
            start = max(0, pos - block)
            f.seek(start)
            chunk = f.read(pos - start)
            nl = chunk.rfind(b"\n")
            if nl >= 0:
                keep = start + nl + 1
                break
            pos = start
        f.truncate(keep)
        f.flush()
        os.fsync(f.fileno())
    return size - keep


def read_predictions(path: Path | str) -> list[PredictionRecord]:
    """Every complete record of a ``predictions.jsonl`` in file order (a torn last line is ignored, not cut;
    no file: none); a malformed complete line, a rotation outside 0-3 or a duplicated ``(idx, rotation)``
    raises ValueError naming file and line."""
    path = Path(path)
    if not path.is_file():
        return []
    data = path.read_bytes()
    lines = data.split(b"\n")
    complete = lines[:-1]  # the piece after the last newline is empty or torn
    out: list[PredictionRecord] = []
    seen: dict[tuple[str, int], int] = {}
    for n, raw in enumerate(complete, 1):
        if not raw.strip():
            continue
        try:
            rec = PredictionRecord.from_dict(json.loads(raw))
        except (json.JSONDecodeError, TypeError, UnicodeDecodeError) as e:
            raise ValueError(f"{path}:{n}: not a prediction record ({e})") from None
        if rec.rotation not in ROTATIONS:
            raise ValueError(f"{path}:{n}: rotation={rec.rotation!r}, allowed {list(ROTATIONS)}")
        key = (rec.idx, int(rec.rotation))
        if key in seen:
            raise ValueError(f"{path}:{n}: prediction for idx={rec.idx!r} rotation={rec.rotation} duplicates "
                             f"line {seen[key]}")  # fmt: skip
        seen[key] = n
        out.append(rec)
    return out


class PredictionStore:
    """The predictions of one run directory; :meth:`open` checks (or writes) its manifest."""

    def __init__(self, run_dir: Path | str) -> None:
        self.run_dir = Path(run_dir)
        self.path = self.run_dir / PREDICTIONS_FILE
        self.manifest_path = self.run_dir / MANIFEST_FILE
        self.done: set[tuple[str, int]] = set()
        self._lock: Any = None

    def _acquire(self) -> None:
        """An exclusive ``flock`` on ``<run_dir>/.lock`` for the store's life (the kernel drops it when the
        process dies, ``kill -9`` included); a second writer is refused instead of duplicating items."""
        import fcntl

        f = open(self.run_dir / LOCK_FILE, "a")  # noqa: SIM115 (held open until close())
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            f.close()
            raise RunDirectoryBusy(f"{self.run_dir}: another process is writing this run directory (its lock "
                                   f"{self.run_dir / LOCK_FILE} is held); wait for it or use another run_dir") from None
        self._lock = f

    def close(self) -> None:
        """Release the run directory."""
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def open(self, manifest: RunManifest) -> list[PredictionRecord]:
        """Lock the run directory; write ``manifest`` (first run) or refuse a different one; cut a torn tail;
        return the records already done."""
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self._acquire()
        try:
            return self._open(manifest)
        except BaseException:
            self.close()
            raise

    def _open(self, manifest: RunManifest) -> list[PredictionRecord]:
        new = json.loads(manifest.to_json())
        if self.manifest_path.is_file():
            old = json.loads(self.manifest_path.read_text())
            diff = manifest_differences(old, new)
            if diff:
                raise MixedRunError(
                    f"{self.manifest_path}: this run directory holds predictions of a different run; refusing to "
                    f"mix them. Differences (recorded -> this run): {'; '.join(diff)}. Use another run_dir, or "
                    "delete the directory to start over."
                )
        elif self.path.is_file() and self.path.stat().st_size > 0:
            raise MixedRunError(f"{self.path}: predictions without a {MANIFEST_FILE}: cannot tell which model, set "
                                "and prompt made them; move them away or delete them")  # fmt: skip
        else:
            write_atomic(self.manifest_path, manifest.to_json() + "\n")
        dropped = cut_torn_tail(self.path)
        if dropped:
            log.warning("%s: cut a torn last line of %d bytes (a run was killed while writing)", self.path, dropped)
        records = read_predictions(self.path)
        self.done = {(r.idx, int(r.rotation)) for r in records}
        return records

    def append(self, records: Iterable[PredictionRecord]) -> int:
        """Append ``records`` (none already done) in one write, flushed and fsynced; returns how many."""
        records = list(records)
        dup = [(r.idx, r.rotation) for r in records if (r.idx, int(r.rotation)) in self.done]
        if dup or len({(r.idx, int(r.rotation)) for r in records}) != len(records):
            raise ValueError(f"{self.path}: refusing to write predictions twice: {dup or 'repeated in the batch'}")
        if not records:
            return 0
        payload = "".join(json.dumps(asdict(r)) + "\n" for r in records)
        with open(self.path, "a", encoding="utf-8") as f:
            f.write(payload)
            f.flush()
            os.fsync(f.fileno())
        self.done.update((r.idx, int(r.rotation)) for r in records)
        return len(records)
