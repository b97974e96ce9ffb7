"""Balanced subsets of a question set (like the paper's NewtPhys-15K): equal per sub-category, about equal
per number of objects, seeded. ``python -m newtphys subset-vqa DIR --size 15000 --seed 42 --out OUT``."""

from __future__ import annotations

import json
import shutil
from collections import defaultdict
from pathlib import Path

import numpy as np

from newtphys import vqa_schema as vs


def balanced_subset(items: list[vs.QuestionItem], size: int, seed: int) -> list[vs.QuestionItem]:
    """``size`` items (or all of them when fewer): the same quota for every sub-category present (a small
    sub-category gives what it has and its unused quota goes to the others), and inside a sub-category the
    items are drawn in turn from each number-of-objects bucket, each bucket in a seeded order."""
    if size < 1:
        raise ValueError(f"subset size must be >= 1, got {size}")
    rng = np.random.default_rng(seed)
    by_sub: dict[str, dict[int, list[vs.QuestionItem]]] = defaultdict(lambda: defaultdict(list))
    for item in sorted(items, key=lambda i: i.idx):
        by_sub[item.sub_category][int(item.meta.get("num_objects", 0))].append(item)
    queues: dict[str, list[vs.QuestionItem]] = {}
    for sub in sorted(by_sub):
        buckets = [list(np.array(b, dtype=object)[rng.permutation(len(b))]) for _, b in sorted(by_sub[sub].items())]
        order: list[vs.QuestionItem] = []
        while any(buckets):
            for b in buckets:
                if b:
                    order.append(b.pop(0))
        queues[sub] = order
    chosen: list[vs.QuestionItem] = []
    remaining = min(size, len(items))
    open_subs = sorted(queues)
    while remaining > 0 and open_subs:
        quota = max(1, remaining // len(open_subs))
        for sub in list(open_subs):
            take = queues[sub][:min(quota, remaining)]
            queues[sub] = queues[sub][len(take):]
            chosen += take
            remaining -= len(take)
            if not queues[sub]:
                open_subs.remove(sub)
            if remaining == 0:
                break
    return sorted(chosen, key=lambda i: i.idx)


def write_subset(set_dir: Path | str, out_dir: Path | str, size: int, seed: int) -> dict:
    """Write the subset as a question set of its own (items, answers, the images they show, a manifest)."""
    set_dir, out_dir = Path(set_dir), Path(out_dir)
    items = balanced_subset(vs.read_items(set_dir), size, seed)
    answers = vs.read_answers(set_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    for image in sorted({p for i in items for p in i.images}):
        (out_dir / image).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(set_dir / image, out_dir / image)
    vs.write_jsonl(out_dir / vs.QUESTIONS_FILE, (i.to_json() for i in items))
    vs.write_jsonl(out_dir / vs.ANSWERS_FILE, (answers[i.idx].to_json() for i in items))

    def count(values) -> dict[str, int]:
        out: dict[str, int] = defaultdict(int)
        for v in values:
            out[str(v)] += 1
        return dict(sorted(out.items()))

    manifest = {
        "subset_of": str(set_dir), "size": len(items), "seed": seed,
        "source_manifest": vs.read_manifest(set_dir) if (set_dir / vs.MANIFEST_FILE).is_file() else None,
        "counts": {"sub_category": count(i.sub_category for i in items), "category": count(i.category for i in items),
                   "num_objects": count(i.meta.get("num_objects") for i in items),
                   "letter": count(answers[i.idx].answer for i in items)},
    }  # fmt: skip
    (out_dir / vs.MANIFEST_FILE).write_text(json.dumps(manifest, indent=1, sort_keys=True))
    return manifest
