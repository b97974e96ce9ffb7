"""Split a question set across jobs by whole sequences, and merge the shards' run directories into one run.

    python evaluate_vlm.py -m hydra/launcher=vlm_slurm vlm=qwen2_5_vl_7b vqa_dir=data/vqa/test \
        num_shards=8 'shard_index=range(0,8)'
    python -m probes.vlm.sharding merge results/vlm/vqa-test/qwen2_5_vl_7b      # join the shards, score

* the config keys are ``shard_index`` and ``num_shards`` (``newtphys/conf/evaluate_vlm.yaml``); shard k of N
  writes the run directory ``<run_dir>/shards/<k>-of-<N>/`` (:func:`shard_dir`), resumable on its own, and
  records ``extra["shard_index"]`` and ``extra["num_shards"]`` in its manifest;
* a sequence is the unit: every item of one ``sequence_id`` lands in the same shard (so the sequence
  bootstrap of :mod:`probes.vlm.bootstrap` and the variant/base matching of the reports never straddle two
  shards);
* sequences are dealt to shards by decreasing item count, each to the shard with the fewest items so far
  (ties: the lower shard index; sequences of equal count in ``sequence_id`` order) -- shards are balanced in
  items, and the assignment depends only on the items, not on the order of their lines or on the job;
* the shards of one ``num_shards`` are disjoint and their union is the asked items
  (:func:`probes.vlm.selection.asked_items`); an item keeps its set order within its shard;
* :func:`merge_runs` checks that the manifests agree on everything but the shard keys, that no
  (idx, rotation) comes twice, that every shard 0..num_shards-1 is there, and that the union answers every
  asked item (rotations 0-3 when circular); it writes one run directory in set order, which scores like an
  unsharded run of the same answerer.

``num_shards=1`` (the default) is the whole set in ``<run_dir>`` itself.
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
from probes.vlm.predictions import manifest_set_dir, read_manifest, read_predictions, write_atomic
from probes.vlm.selection import asked_items

SHARDS_DIR = "shards"
SHARD_KEYS: tuple[str, ...] = ("shard_index", "num_shards")
"""Keys of ``RunManifest.extra`` that differ between the shards of one run (and are dropped by a merge)."""
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


def shard_dir(run_dir: Path | str, shard_index: int, num_shards: int) -> Path:
    """The run directory of shard ``shard_index`` of ``num_shards`` of the run ``run_dir``."""
    check_shard(shard_index, num_shards)
    return Path(run_dir) / SHARDS_DIR / f"{shard_index}-of-{num_shards}"


def shard_run_dirs(run_dir: Path | str) -> list[Path]:
    """The shard run directories under ``<run_dir>/shards/`` (those with a manifest), sorted."""
    dirs = sorted(d for d in (Path(run_dir) / SHARDS_DIR).glob("*-of-*") if (d / MANIFEST_FILE).is_file())
    if not dirs:
        raise FileNotFoundError(
            f"{Path(run_dir) / SHARDS_DIR}: no shard run directories (<k>-of-<N>/{MANIFEST_FILE})"
        )
    return dirs


# -- merge --------------------------------------------------------------------------------------------------


def _identity(manifest: dict[str, Any]) -> dict[str, Any]:
    extra = {
        k: v for k, v in (manifest.get("extra") or {}).items() if k not in SHARD_KEYS + MERGE_VOLATILE_KEYS
    }
    return {**{k: v for k, v in manifest.items() if k != "extra"}, "extra": extra}


def _shard_id(manifest: dict[str, Any]) -> tuple[int | None, int | None]:
    extra = manifest.get("extra") or {}
    return extra.get("shard_index"), extra.get("num_shards")


def _expected_keys(set_dir: Path, manifest: dict[str, Any]) -> list[tuple[str, int]]:
    """(idx, rotation) the answerer was asked, in set order (:func:`probes.vlm.selection.asked_items`)."""
    rotations = range(4) if manifest.get("circular") else range(1)
    asked, _ = asked_items(vs.read_items(set_dir), manifest)
    return [(it.idx, r) for it in asked for r in rotations]


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
    manifests = [read_manifest(d) for d in dirs]
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
        for rec in read_predictions(path):
            key = (rec.idx, int(rec.rotation))
            if key in seen:
                raise ValueError(
                    f"merge_runs: idx={rec.idx!r} rotation={rec.rotation} in both {seen[key]} and {path}"
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
        raise FileExistsError(
            f"merge_runs: {out / PREDICTIONS_FILE} exists; merge into a new directory (or delete it to merge again)"
        )
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
    lines = [records[key].to_json() + "\n" for key in sorted(records, key=order.__getitem__)]
    write_atomic(out / PREDICTIONS_FILE, "".join(lines))
    write_atomic(out / MANIFEST_FILE, json.dumps(merged, indent=2, sort_keys=True) + "\n")
    return {
        "shards": len(dirs),
        "predictions": len(records),
        "expected": len(expected),
        "missing": len(missing),
        "out_dir": str(out),
    }


def main(argv: list[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m probes.vlm.sharding",
        description="Merge the shard run directories of one run, then score it.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    m = sub.add_parser(
        "merge",
        help="RUN_DIR: merge RUN_DIR/shards/* into RUN_DIR; or --out OUT SHARD_DIR...: merge those into OUT",
    )
    m.add_argument("run_dirs", nargs="+", type=Path)
    m.add_argument("--out", type=Path, default=None, help="merged run directory (default: the one RUN_DIR)")
    m.add_argument(
        "--set-dir", type=Path, default=None, help="the question set split (default: from the manifest)"
    )
    m.add_argument(
        "--allow-incomplete", action="store_true", help="merge what the shards have so far (unscored)"
    )
    m.add_argument("--no-score", action="store_true", help="do not write scores.json")
    args = p.parse_args(argv)
    if args.out is None:
        if len(args.run_dirs) != 1:
            p.error("merge: several shard directories need --out")
        out, dirs = args.run_dirs[0], shard_run_dirs(args.run_dirs[0])
    else:
        out, dirs = args.out, args.run_dirs
    summary = merge_runs(dirs, out, args.set_dir, args.allow_incomplete)
    if not args.no_score and not summary["missing"]:
        from probes.vlm.scoring import score_run

        score_run(out, args.set_dir)
        summary["scores"] = str(Path(out) / "scores.json")
    print(json.dumps(summary, indent=2))


if __name__ == "__main__":
    main()
