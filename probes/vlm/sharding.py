"""Split a question set across jobs and merge their run directories.

Sharding semantics (what the evaluate CLI's ``shard_index`` / ``num_shards`` mean)::

    python evaluate_vlm.py -m hydra/launcher=vlm_slurm vlm=qwen2_5_vl_7b vqa_dir=data/vqa/test \
        num_shards=8 'shard_index=range(0,8)'
    python -m probes.vlm.sharding merge --out runs/qwen2_5_vl_7b <the 8 run directories>

* a sequence is the unit: every item of one ``sequence_id`` lands in the same shard (so the sequence
  bootstrap of :mod:`probes.vlm.bootstrap` and the variant/base matching of the reports never straddle two
  shards);
* sequences are dealt to shards by decreasing item count, each to the shard with the fewest items so far
  (ties: the lower shard index; sequences of equal count in ``sequence_id`` order) -- shards are balanced in
  items, and the assignment depends only on the set, not on the order of its lines or on the job;
* the shards of one ``num_shards`` are disjoint and their union is the set; an item keeps its set order
  within its shard;
* a shard's run directory records ``extra["shard_index"]`` and ``extra["num_shards"]`` in its manifest;
  :func:`merge_runs` checks that the manifests agree on everything else, that no (idx, rotation) comes twice,
  that every shard 0..num_shards-1 is there, and that the union answers every item (in the run's
  ``extra["modes"]`` when recorded; rotations 0-3 when circular).

``num_shards=1`` (the default) is the whole set.
"""

from __future__ import annotations

import argparse
import heapq
import json
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE, PredictionRecord
from probes.vlm.scoring import asked_items, manifest_set_dir

SHARD_KEYS: tuple[str, ...] = ("shard_index", "num_shards", "shard")
"""Keys of ``RunManifest.extra`` that differ between the shards of one run (and are dropped by a merge):
``shard_index`` + ``num_shards``, or ``shard`` = [index, count] (the evaluation loop's form)."""
MERGE_VOLATILE_KEYS: tuple[str, ...] = ("started_at", "finished_at", "host", "hostname", "wall_s")
"""Other ``extra`` keys allowed to differ between shards (recorded per shard in ``merged_from``)."""


def check_shard(shard_index: int, num_shards: int) -> None:
    if not isinstance(num_shards, int) or num_shards < 1:
        raise ValueError(f"num_shards={num_shards!r}, must be an integer >= 1")
    if not isinstance(shard_index, int) or not 0 <= shard_index < num_shards:
        raise ValueError(
            f"shard_index={shard_index!r}, must be an integer in [0, {num_shards - 1}] (num_shards={num_shards})"
        )


def shard_of_sequences(items: Sequence[vs.QuestionItem], num_shards: int) -> dict[str, int]:
    """sequence_id -> shard index (module docstring: whole sequences, balanced in items)."""
    check_shard(0, num_shards)
    counts: dict[str, int] = defaultdict(int)
    for it in items:
        counts[it.sequence_id] += 1
    heap = [(0, k) for k in range(num_shards)]  # (items so far, shard index)
    out: dict[str, int] = {}
    for seq in sorted(counts, key=lambda s: (-counts[s], s)):
        load, k = heapq.heappop(heap)
        out[seq] = k
        heapq.heappush(heap, (load + counts[seq], k))
    return out


def shard_items(items: Sequence[vs.QuestionItem], shard_index: int, num_shards: int) -> list[vs.QuestionItem]:
    """The items of shard ``shard_index`` of ``num_shards``, in set order (module docstring)."""
    check_shard(shard_index, num_shards)
    if num_shards == 1:
        return list(items)
    owner = shard_of_sequences(items, num_shards)
    return [it for it in items if owner[it.sequence_id] == shard_index]


# -- merge --------------------------------------------------------------------------------------------------
def _manifest(run_dir: Path) -> dict[str, Any]:
    path = run_dir / MANIFEST_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not a run directory (no {MANIFEST_FILE})")
    return json.loads(path.read_text())


def _identity(manifest: dict[str, Any]) -> dict[str, Any]:
    extra = {
        k: v for k, v in (manifest.get("extra") or {}).items() if k not in SHARD_KEYS + MERGE_VOLATILE_KEYS
    }
    return {**{k: v for k, v in manifest.items() if k != "extra"}, "extra": extra}


def _shard_id(manifest: dict[str, Any]) -> tuple[int | None, int | None]:
    extra = manifest.get("extra") or {}
    if extra.get("shard") is not None:
        index, count = extra["shard"]
        return int(index), int(count)
    return extra.get("shard_index"), extra.get("num_shards")


def _expected_keys(set_dir: Path, manifest: dict[str, Any]) -> list[tuple[str, int]]:
    """(idx, rotation) the answerer was asked, in set order (:func:`probes.vlm.scoring.asked_items`)."""
    rotations = range(4) if manifest.get("circular") else range(1)
    items = vs.read_items(set_dir)
    asked, _ = asked_items(items, manifest)
    return [(it.idx, r) for it in items if it.idx in asked for r in rotations]


def merge_runs(
    run_dirs: Sequence[Path | str],
    out_dir: Path | str,
    set_dir: Path | str | None = None,
    allow_incomplete: bool = False,
) -> dict[str, Any]:
    """Merge the run directories of the shards of one run into ``out_dir`` (``manifest.json`` without the
    shard keys, plus ``extra["merged_from"]``; ``predictions.jsonl`` in set order). Returns a summary
    (``shards``, ``predictions``, ``missing``). Raises on disagreeing manifests, duplicate predictions, a
    missing shard or -- unless ``allow_incomplete`` -- items without a prediction."""
    dirs = [Path(d) for d in run_dirs]
    if not dirs:
        raise ValueError("merge_runs: no run directories given")
    manifests = [_manifest(d) for d in dirs]
    ref = _identity(manifests[0])
    for d, m in zip(dirs[1:], manifests[1:], strict=True):
        ident = _identity(m)
        diff = sorted(k for k in set(ref) | set(ident) if ref.get(k) != ident.get(k))
        if diff:
            k = diff[0]
            raise ValueError(
                f"merge_runs: {d}/{MANIFEST_FILE} disagrees with {dirs[0]}/{MANIFEST_FILE} on {diff}: "
                f"{k}={ident.get(k)!r} vs {ref.get(k)!r}"
            )
    shard_ids = [_shard_id(m) for m in manifests]
    if any(n is not None for _, n in shard_ids):
        nums = {n for _, n in shard_ids}
        if len(nums) != 1 or None in nums:
            raise ValueError(
                f"merge_runs: shards disagree on num_shards: {[n for _, n in shard_ids]} ({[str(d) for d in dirs]})"
            )
        n = nums.pop()
        got = sorted(k for k, _ in shard_ids)
        if got != list(range(n)):
            missing = sorted(set(range(n)) - set(got))
            dup = sorted({k for k in got if got.count(k) > 1})
            raise ValueError(
                f"merge_runs: num_shards={n} but shard_index {got}: missing {missing}, repeated {dup}"
            )
    seen: dict[tuple[str, int], Path] = {}
    records: dict[tuple[str, int], PredictionRecord] = {}
    for d in dirs:
        path = d / PREDICTIONS_FILE
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no predictions in shard run directory")
        for line, obj in vs.iter_jsonl(path):
            rec = PredictionRecord.from_dict(obj)
            key = (rec.idx, int(rec.rotation))
            if key in seen:
                raise ValueError(
                    f"merge_runs: idx={rec.idx!r} rotation={rec.rotation} in both {seen[key]} and "
                    f"{path}:{line}"
                )
            seen[key], records[key] = path, rec
    m0 = manifests[0]
    set_dir = Path(set_dir) if set_dir is not None else manifest_set_dir(m0, dirs[0])
    expected = _expected_keys(set_dir, m0)
    order = {key: k for k, key in enumerate(expected)}
    extra_keys = sorted(set(records) - set(order))
    if extra_keys:
        raise ValueError(
            f"merge_runs: {len(extra_keys)} predictions not in {set_dir}/{vs.QUESTIONS_FILE} "
            f"(modes {(m0.get('extra') or {}).get('modes')}), e.g. {extra_keys[:3]}"
        )
    missing = [key for key in expected if key not in records]
    if missing and not allow_incomplete:
        raise ValueError(
            f"merge_runs: the union of {len(dirs)} shard(s) misses {len(missing)} of {len(expected)} "
            f"(idx, rotation), e.g. {missing[:3]}; rerun those shards or pass allow_incomplete"
        )
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    if (out / PREDICTIONS_FILE).exists():
        raise FileExistsError(f"merge_runs: {out / PREDICTIONS_FILE} exists; merge into a new directory")
    merged = {
        **m0,
        "extra": {
            **ref["extra"],
            "merged_from": [
                {
                    "run_dir": str(d),
                    **{
                        k: (m.get("extra") or {}).get(k)
                        for k in SHARD_KEYS + MERGE_VOLATILE_KEYS
                        if k in (m.get("extra") or {})
                    },
                }
                for d, m in zip(dirs, manifests, strict=True)
            ],
        },
    }
    vs.write_jsonl(
        out / PREDICTIONS_FILE, (records[key].to_json() for key in sorted(records, key=order.__getitem__))
    )
    (out / MANIFEST_FILE).write_text(json.dumps(merged, indent=2, sort_keys=True))
    return {
        "shards": len(dirs),
        "predictions": len(records),
        "expected": len(expected),
        "missing": len(missing),
        "out_dir": str(out),
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m probes.vlm.sharding", description="Merge shard run directories."
    )
    sub = p.add_subparsers(dest="command", required=True)
    m = sub.add_parser("merge", help="merge the run directories of the shards of one run")
    m.add_argument("run_dirs", nargs="+", type=Path)
    m.add_argument("--out", required=True, type=Path)
    m.add_argument(
        "--set-dir", type=Path, default=None, help="the question set split (default: from the manifest)"
    )
    m.add_argument("--allow-incomplete", action="store_true")
    args = p.parse_args(argv)
    print(json.dumps(merge_runs(args.run_dirs, args.out, args.set_dir, args.allow_incomplete), indent=2))


if __name__ == "__main__":
    main()
