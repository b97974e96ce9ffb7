"""Macro accuracy (question id -> sub-category -> category -> overall) as matrix algebra over sequences, and
its bootstrap confidence intervals that resample *sequences* (all items of a drawn sequence come along:
items of one sequence share a scene and are not independent).

A :class:`MacroTable` holds, per sequence and question id, the summed score and the item count. A bootstrap
replicate is a vector of sequence multiplicities ``w`` (a multinomial draw); its per-id accuracy is
``w @ sums / w @ counts`` and the macro means follow; ids (and so sub-categories, categories) absent from a
replicate are left out of its means, as they would be from a set without them. With all multiplicities 1
this is exactly :func:`newtphys.vqa_scoring.macro_accuracy` (a test checks it).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

BOOT_CHUNK = 128
"""Replicates computed at once (bounds memory: chunk x sequences floats)."""


@dataclass(frozen=True)
class MacroTable:
    sequences: tuple[str, ...]
    question_ids: tuple[str, ...]
    sub_categories: tuple[str, ...]
    categories: tuple[str, ...]
    sums: np.ndarray
    """(sequences, question ids): summed item scores (0/1, or expected scores such as 0.25)."""
    counts: np.ndarray
    """(sequences, question ids): items."""
    qid_to_sub: np.ndarray
    """(question ids, sub-categories) 0/1 membership."""
    sub_to_cat: np.ndarray
    """(sub-categories, categories) 0/1 membership."""

    @property
    def n_items(self) -> int:
        return int(self.counts.sum())


def build_table(records: Iterable[tuple[str, str, str, str, float]]) -> MacroTable:
    """From (sequence_id, question_id, sub_category, category, score) per item."""
    rows = list(records)
    if not rows:
        raise ValueError("macro accuracy of no items")
    seqs = tuple(sorted({r[0] for r in rows}))
    qids = tuple(sorted({r[1] for r in rows}))
    parent = {r[1]: (r[2], r[3]) for r in rows}
    subs = tuple(sorted({s for s, _ in parent.values()}))
    cats = tuple(sorted({c for _, c in parent.values()}))
    si, qi = {s: k for k, s in enumerate(seqs)}, {q: k for k, q in enumerate(qids)}
    sums, counts = np.zeros((len(seqs), len(qids))), np.zeros((len(seqs), len(qids)))
    for seq, qid, _, _, score in rows:
        sums[si[seq], qi[qid]] += float(score)
        counts[si[seq], qi[qid]] += 1.0
    q2s = np.zeros((len(qids), len(subs)))
    s2c = np.zeros((len(subs), len(cats)))
    for q, (s, c) in parent.items():
        q2s[qi[q], subs.index(s)] = 1.0
        s2c[subs.index(s), cats.index(c)] = 1.0
    return MacroTable(seqs, qids, subs, cats, sums, counts, q2s, s2c)


def _masked_mean(values: np.ndarray, membership: np.ndarray) -> np.ndarray:
    """Mean of the non-NaN ``values`` (B, n) over each group of ``membership`` (n, groups); NaN if none."""
    present = ~np.isnan(values)
    total = np.where(present, values, 0.0) @ membership
    n = present.astype(float) @ membership
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n > 0, total / np.maximum(n, 1e-300), np.nan)


def macro_levels(table: MacroTable, weights: np.ndarray) -> dict[str, np.ndarray]:
    """Per replicate (rows of ``weights``, (B, sequences)): ``question_id`` (B, ids), ``sub_category``,
    ``category`` and ``overall`` (B,) macro accuracies."""
    s, c = weights @ table.sums, weights @ table.counts
    with np.errstate(invalid="ignore", divide="ignore"):
        by_id = np.where(c > 0, s / np.maximum(c, 1e-300), np.nan)
    by_sub = _masked_mean(by_id, table.qid_to_sub)
    by_cat = _masked_mean(by_sub, table.sub_to_cat)
    overall = _masked_mean(by_cat, np.ones((by_cat.shape[1], 1)))[:, 0]
    return {"question_id": by_id, "sub_category": by_sub, "category": by_cat, "overall": overall}


def point_estimate(table: MacroTable) -> dict[str, Any]:
    """The macro accuracies of the table itself (every sequence once), as plain floats."""
    lv = macro_levels(table, np.ones((1, len(table.sequences))))
    return {
        "overall": float(lv["overall"][0]),
        "category": dict(zip(table.categories, map(float, lv["category"][0]), strict=True)),
        "sub_category": dict(zip(table.sub_categories, map(float, lv["sub_category"][0]), strict=True)),
        "question_id": dict(zip(table.question_ids, map(float, lv["question_id"][0]), strict=True)),
    }


def bootstrap_ci(table: MacroTable, n_boot: int = 1000, seed: int = 0, level: float = 0.95) -> dict[str, Any]:
    """Percentile intervals of the overall, per-category and per-sub-category macro accuracy over ``n_boot``
    replicates that draw ``len(sequences)`` sequences with replacement (generator seeded by ``seed``)."""
    if n_boot < 1:
        raise ValueError(f"n_boot={n_boot}, must be >= 1")
    if not 0 < level < 1:
        raise ValueError(f"level={level}, must be in (0, 1)")
    rng = np.random.default_rng(seed)
    n = len(table.sequences)
    chunks: dict[str, list[np.ndarray]] = {"overall": [], "category": [], "sub_category": []}
    for start in range(0, n_boot, BOOT_CHUNK):
        b = min(BOOT_CHUNK, n_boot - start)
        weights = rng.multinomial(n, np.full(n, 1.0 / n), size=b).astype(float)
        lv = macro_levels(table, weights)
        for key, parts in chunks.items():
            parts.append(lv[key])
    q = [100 * (1 - level) / 2, 100 * (1 + level) / 2]

    def interval(samples: np.ndarray) -> list[float] | None:
        return None if np.all(np.isnan(samples)) else [float(v) for v in np.nanpercentile(samples, q)]

    overall = np.concatenate(chunks["overall"])
    cat, sub = np.concatenate(chunks["category"]), np.concatenate(chunks["sub_category"])
    return {
        "level": level,
        "n_boot": n_boot,
        "seed": seed,
        "resampled": "sequence_id",
        "n_sequences": n,
        "overall": interval(overall),
        "overall_se": float(np.nanstd(overall, ddof=1)) if n_boot > 1 else None,
        "category": {c: interval(cat[:, k]) for k, c in enumerate(table.categories)},
        "sub_category": {s: interval(sub[:, k]) for k, s in enumerate(table.sub_categories)},
    }
