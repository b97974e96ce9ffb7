"""Join the shards of a sharded run into one run directory, then score it.

A sharded run (``shard.count=N shard.index=0,...,N-1``, e.g. Slurm jobs through ``hydra/launcher=slurm``)
writes ``<run_dir>/shards/<k>-of-<N>/``; each shard answers the batches whose position modulo N is k.
:func:`merge_shards` checks that the N shard manifests agree (same set, prompt, circular mode, model
identity: :func:`probes.vlm.predictions.manifest_differences`) and that every shard is there, then writes
``<run_dir>/manifest.json`` and ``<run_dir>/predictions.jsonl`` in the set's order (the lines an unsharded
run writes), atomically. Shards still running, or missing items, are reported, not merged.

    python -m probes.vlm.merge RUN_DIR [--allow-incomplete]
"""

from __future__ import annotations

import argparse
import json
import re
from dataclasses import asdict
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE, PredictionRecord
from probes.vlm.predictions import MixedRunError, manifest_differences, read_predictions, write_atomic

SHARDS_DIR = "shards"
_SHARD_NAME = re.compile(r"^(\d+)-of-(\d+)$")


def shard_dir(run_dir: Path | str, index: int, count: int) -> Path:
    return Path(run_dir) / SHARDS_DIR / f"{index}-of-{count}"


def merge_shards(run_dir: Path | str, allow_incomplete: bool = False) -> dict[str, Any]:
    """Merge ``run_dir/shards/*`` into ``run_dir``; returns counts. Raises when shards disagree, one is missing,
    or (unless ``allow_incomplete``) an item the shards should hold has no prediction."""
    run_dir = Path(run_dir)
    found = {}
    for d in sorted((run_dir / SHARDS_DIR).glob("*-of-*")):
        m = _SHARD_NAME.match(d.name)
        if m and (d / MANIFEST_FILE).is_file():
            found[(int(m.group(1)), int(m.group(2)))] = d
    if not found:
        raise FileNotFoundError(f"{run_dir / SHARDS_DIR}: no shard directories (<k>-of-<N>/manifest.json)")
    counts = {n for _, n in found}
    if len(counts) != 1:
        raise MixedRunError(f"{run_dir / SHARDS_DIR}: shards of different counts {sorted(counts)}; keep one layout")
    count = counts.pop()
    missing = sorted(set(range(count)) - {k for k, _ in found})
    if missing:
        raise FileNotFoundError(f"{run_dir / SHARDS_DIR}: shards {missing} of {count} have not started (no manifest)")
    manifests = {k: json.loads((d / MANIFEST_FILE).read_text()) for (k, _), d in found.items()}
    for k, m in manifests.items():
        diff = manifest_differences(manifests[0], m)
        if diff:
            raise MixedRunError(f"shard {k} of {run_dir} differs from shard 0: {'; '.join(diff)}")
    records: dict[tuple[str, int], PredictionRecord] = {}
    for d in found.values():
        for r in read_predictions(d / PREDICTIONS_FILE):
            key = (r.idx, int(r.rotation))
            if key in records:
                raise MixedRunError(f"{d}: prediction for {key} is also in another shard")
            records[key] = r
    merged = dict(manifests[0])
    extra = {k: v for k, v in (merged.get("extra") or {}).items() if k != "shard"}
    merged["extra"] = {**extra, "merged_shards": count}
    if (run_dir / MANIFEST_FILE).is_file():
        diff = manifest_differences(json.loads((run_dir / MANIFEST_FILE).read_text()), merged)
        if diff:
            raise MixedRunError(f"{run_dir / MANIFEST_FILE} belongs to another run: {'; '.join(diff)}")
    set_dir = Path(merged["vqa_dir"])
    order = {item.idx: n for n, item in enumerate(vs.read_items(set_dir))}
    unknown = sorted({idx for idx, _ in records} - set(order))
    if unknown:
        raise KeyError(f"{run_dir}: predictions for items not in {set_dir}: {unknown[:5]}")
    rotations = (0, 1, 2, 3) if merged.get("circular") else (0,)
    expected = _expected_items(set_dir, manifests[0])
    absent = [(idx, r) for idx in expected for r in rotations if (idx, r) not in records]
    if absent and not allow_incomplete:
        raise RuntimeError(f"{run_dir}: {len(absent)} (item, rotation) pairs have no prediction yet, e.g. "
                           f"{absent[:3]}; wait for the shards (or re-run them), or pass --allow-incomplete")  # fmt: skip
    lines = [json.dumps(asdict(records[k])) for k in sorted(records, key=lambda k: (order[k[0]], k[1]))]
    write_atomic(run_dir / MANIFEST_FILE, json.dumps(merged, indent=2, sort_keys=True) + "\n")
    write_atomic(run_dir / PREDICTIONS_FILE, "".join(line + "\n" for line in lines))
    return {"shards": count, "predictions": len(lines), "missing": len(absent), "set_dir": str(set_dir)}


def _expected_items(set_dir: Path, manifest: dict[str, Any]) -> list[str]:
    """Items the shards should cover: the set minus the ones the manifest says were skipped (by mode or image
    count: recomputed from the model's record), within ``limit``."""
    model = manifest.get("model") or {}
    items = vs.read_items(set_dir)
    if model.get("single_image_only"):
        items = [i for i in items if i.mode == "single"]
    if model.get("max_images") is not None:
        items = [i for i in items if len(i.images) <= int(model["max_images"])]
    limit = (manifest.get("extra") or {}).get("limit")
    return [i.idx for i in (items[: int(limit)] if limit else items)]


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--allow-incomplete", action="store_true", help="merge what the shards have so far")
    ap.add_argument("--no-score", action="store_true", help="do not write scores.json")
    args = ap.parse_args(argv)
    out = merge_shards(args.run_dir, args.allow_incomplete)
    print(f"merged {out['shards']} shards: {out['predictions']} predictions ({out['missing']} missing) "
          f"-> {args.run_dir}")
    if not args.no_score and not out["missing"]:
        from probes.vlm.cli import score

        score(args.run_dir, Path(out["set_dir"]))
        print(f"wrote {args.run_dir / 'scores.json'}")


if __name__ == "__main__":
    main()
