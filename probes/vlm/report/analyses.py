"""The paper's analyses of scored runs, one function per table (:class:`~probes.vlm.report.tables.Table`).

Every table says how many items (or models) stand behind each number; an analysis whose items are absent
from every run returns a table with no rows and a "not enough items" note instead of a number. Scopes:

* per-category / heatmap / size: the headline scope of :mod:`probes.vlm.scoring` (base items of the
  analysed ids in the run's modes, strict extraction), beside chance, the best constant letter and the text
  prior on the same items;
* Young's modulus / object count bins: base items with that ``meta`` key; accuracy per bin is the share of
  items right (micro) with a sequence-bootstrap interval, beside the bin's best constant-letter share;
* variant deltas (roi_masked, black_image, cues, expertise levels, counterfactuals): each variant item is
  matched to its base item (``pair`` = base pair + ``/<variant>``, same mode; for ``cf_*`` the factual item of
  the id it derives from) and both must be in the run; delta = variant accuracy - base accuracy on the
  matched pairs, with a paired sequence-bootstrap interval;
* correlation: Pearson r over models of a category's accuracy with each benchmark column of a user CSV.
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from itertools import pairwise
from typing import Any

import numpy as np

from newtphys import vqa_schema as vs
from probes.vlm.bootstrap import bootstrap_ci, build_table
from probes.vlm.report.loading import Run
from probes.vlm.report.tables import Table, not_enough
from probes.vlm.scoring import ItemResult

DEFAULT_SIZE_EDGES_B: tuple[float, ...] = (0.0, 1.0, 3.0, 8.0, 16.0, 40.0, math.inf)
"""Model-size bin edges, billions of parameters (the paper's 0.4B-78B range)."""
DEFAULT_YOUNG_LOG10_EDGES: tuple[float, ...] = (4.0, 6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 13.0)
"""log10(Young's modulus / Pa) bin edges: foams and gels ... rubbers (1e6-1e7) ... plastics, wood (1e9-1e10)
... metals and ceramics (1e11-1e12)."""
VARIANT_GROUPS: dict[str, tuple[str, ...]] = {
    "masked": ("roi_masked", "black_image"),
    "counterfactual": ("cf_gravity", "cf_shift", "cf_resize"),
    "cue": (
        "roi_circle",
        "location",
        "roi_circle_location",
        "roi_only",
        "location_only",
        "roi_location_only",
        "cue_duration",
        "cue_mass_exact",
        "cue_mass_approx",
    ),
    "level": ("level_child", "level_teen", "level_undergrad", "level_graduate", "level_expert"),
}
TITLES = {
    "masked": "ROI-masked (and all-black) minus base: answering without looking",
    "counterfactual": "Counterfactual vs factual on overlapping questions",
    "cue": "Spatial and physical cues minus base",
    "level": "Expertise levels of the wording minus base",
}


def scoped(run: Run, variant: str | None = vs.BASE_VARIANT) -> list[ItemResult]:
    """Items of the run's headline scope (its modes, analysed ids), of ``variant`` (None: all variants)."""
    modes = run.scores["protocol"]["modes"]
    return [
        r
        for r in run.results
        if r.item.mode in modes
        and vs.question_spec(r.item.question_id).in_analysis
        and (variant is None or r.item.variant == variant)
    ]


# -- per category, heatmap, size --------------------------------------------------------------------------
def per_category(runs: Sequence[Run]) -> Table:
    cols = [
        "model",
        "category",
        "n_items",
        "strict",
        "ci_lo",
        "ci_hi",
        "lenient",
        "chance",
        "constant_letter",
        "text_prior",
    ]
    t = Table(
        "per_category",
        "Accuracy per category (strict, 95 % CI over sequences) beside trivial baselines",
        cols,
        note="strict = the paper's letter rule; lenient apart; constant_letter = the best single letter of "
        "that category; text_prior = blind leave-one-sequence-out prior (newtphys.vqa_prior).",
    )
    present = sorted({c for run in runs for c in run.scores["strict"]["category"]})
    plot: dict[str, Any] = {"models": [], "categories": present, "acc": {}, "ci": {}, "baselines": {}}
    for run in runs:
        s, b = run.scores["strict"], run.scores["baseline_details"]
        n_cat: dict[str, int] = defaultdict(int)
        for r in scoped(run):
            n_cat[r.item.category] += 1
        ci = (s.get("ci") or {}).get("category", {})
        prior = b["text_prior"].get("category", {})
        for cat in sorted(s["category"]):
            lo, hi = ci.get(cat) or (None, None)
            t.rows.append(
                [
                    run.label,
                    cat,
                    n_cat[cat],
                    s["category"][cat],
                    lo,
                    hi,
                    run.scores["lenient"]["category"][cat],
                    b["chance"],
                    b["constant_letter"]["category_best"][cat],
                    prior.get(cat),
                ]
            )
        lo, hi = (s.get("ci") or {}).get("overall") or (None, None)
        t.rows.append(
            [
                run.label,
                "overall",
                s["n_items"],
                s["overall"],
                lo,
                hi,
                run.scores["lenient"]["overall"],
                b["chance"],
                b["constant_letter"]["overall"],
                b["text_prior"].get("overall"),
            ]
        )
        plot["models"].append(run.label)
        plot["acc"][run.label] = s["category"]
        plot["ci"][run.label] = ci
        plot["baselines"][run.label] = b["constant_letter"]["category_best"]
    t.plot = plot
    return t


def subcategory_heatmap(runs: Sequence[Run]) -> Table:
    subs = sorted({s for run in runs for s in run.scores["strict"]["sub_category"]})
    t = Table(
        "subcategory_heatmap",
        "Models x sub-categories (strict macro accuracy)",
        ["model", *subs, "overall"],
        note="Cells: macro accuracy over the sub-category's question ids; empty: no item of it in the run.",
    )
    matrix = []
    for run in runs:
        acc = run.scores["strict"]["sub_category"]
        row = [acc.get(s) for s in subs]
        matrix.append([math.nan if v is None else v for v in row])
        t.rows.append([run.label, *row, run.scores["strict"]["overall"]])
    t.plot = {"models": [r.label for r in runs], "subs": subs, "matrix": np.array(matrix, dtype=float)}
    return t


def by_model_rank(runs: Sequence[Run], bin_size: int = 10) -> Table:
    """Models ranked by overall strict accuracy (best first), in bins of ``bin_size`` ranks: the mean
    accuracy of each category over the models of a bin (which categories improve as models get better)."""
    cats = sorted({c for run in runs for c in run.scores["strict"]["category"]})
    cols = ["rank_bin", "n_models", "overall", *cats, "models"]
    title = f"Accuracy by model rank (bins of {bin_size}, best first)"
    if len(runs) < 2:
        return not_enough("by_model_rank", title, cols, f"{len(runs)} model(s); ranks need at least 2")
    ranked = sorted(runs, key=lambda r: (-r.scores["strict"]["overall"], r.label))
    t = Table(
        "by_model_rank", title, cols, note="Mean over the models of each bin of their strict macro accuracy."
    )
    series: dict[str, list[tuple[str, float, float, float]]] = {c: [] for c in ["overall", *cats]}
    for start in range(0, len(ranked), bin_size):
        members = ranked[start : start + bin_size]
        label = f"{start + 1}-{start + len(members)}"
        overall = float(np.mean([r.scores["strict"]["overall"] for r in members]))
        per_cat = []
        for c in cats:
            vals = [r.scores["strict"]["category"][c] for r in members if c in r.scores["strict"]["category"]]
            per_cat.append(float(np.mean(vals)) if vals else None)
        t.rows.append([label, len(members), overall, *per_cat, "; ".join(r.label for r in members)])
        for key, v in zip(["overall", *cats], [overall, *per_cat], strict=True):
            if v is not None:
                series[key].append((label, v, v, v))
    t.plot = {k: v for k, v in series.items() if v}
    return t


def by_model_size(runs: Sequence[Run], edges: Sequence[float] = DEFAULT_SIZE_EDGES_B) -> Table:
    cols = ["size_bin_b", "n_models", "mean_strict", "min_strict", "max_strict", "models"]
    sized = [r for r in runs if r.params_b is not None]
    if not sized:
        return not_enough(
            "by_model_size",
            "Accuracy by model size",
            cols,
            "no model size known: add `params_b` "
            "to the model record or pass --sizes CSV (columns model, params_b)",
        )
    t = Table(
        "by_model_size",
        "Accuracy by model size (billions of parameters)",
        cols,
        note=f"Models without a known size: {sorted(r.label for r in runs if r.params_b is None) or 'none'}.",
    )
    points = []
    for lo, hi in pairwise(edges):
        members = [r for r in sized if lo <= r.params_b < hi]  # type: ignore[operator]
        if not members:
            continue
        acc = [r.scores["strict"]["overall"] for r in members]
        t.rows.append(
            [
                f"[{lo:g}, {hi:g})",
                len(members),
                float(np.mean(acc)),
                min(acc),
                max(acc),
                "; ".join(r.label for r in members),
            ]
        )
    for r in sorted(sized, key=lambda r: r.params_b):  # type: ignore[arg-type, return-value]
        points.append(
            (
                r.label,
                r.params_b,
                r.scores["strict"]["overall"],
                r.scores["baseline_details"]["constant_letter"]["overall"],
            )
        )
    t.plot = {"points": points}
    return t


# -- bins over item meta ----------------------------------------------------------------------------------
def _micro_with_ci(rs: Sequence[ItemResult], n_boot: int, seed: int) -> tuple[float, list[float] | None, int]:
    table = build_table((r.item.sequence_id, "all", "all", "all", float(r.right)) for r in rs)
    ci = bootstrap_ci(table, n_boot, seed)["overall"] if n_boot else None
    return sum(r.right for r in rs) / len(rs), ci, len(table.sequences)


def _best_letter_share(rs: Sequence[ItemResult]) -> float:
    return max(sum(r.answer == k for r in rs) for k in vs.LETTERS) / len(rs)


def by_meta_bins(
    runs: Sequence[Run],
    key: str,
    name: str,
    title: str,
    edges: Sequence[float] | None = None,
    log10: bool = False,
    n_boot: int = 1000,
    seed: int = 0,
) -> Table:
    """Micro accuracy per bin of ``meta[key]`` (``edges`` over the value, or its log10; None: one bin per
    distinct value)."""
    cols = ["model", "bin", "n_items", "n_sequences", "strict", "ci_lo", "ci_hi", "constant_letter_share"]
    t = Table(
        name,
        title,
        cols,
        note="Share of base items right (micro) per bin, 95 % CI over sequences; "
        "constant_letter_share = the bin's most frequent answer letter.",
    )
    plot: dict[str, list[tuple[str, float, float, float]]] = {}
    for run in runs:
        bins: dict[tuple[float, str], list[ItemResult]] = defaultdict(list)
        for r in scoped(run):
            v = r.item.meta.get(key)
            if v is None:
                continue
            x = math.log10(v) if log10 and v > 0 else (float("-inf") if log10 else float(v))
            if edges is None:
                bins[(x, f"{v:g}")].append(r)
                continue
            for lo, hi in pairwise(edges):
                if lo <= x < hi:
                    label = f"[1e{lo:g}, 1e{hi:g}) Pa" if log10 else f"[{lo:g}, {hi:g})"
                    bins[(lo, label)].append(r)
                    break
        for (_, label), rs in sorted(bins.items()):
            acc, ci, n_seq = _micro_with_ci(rs, n_boot, seed)
            lo_, hi_ = ci or (None, None)
            t.rows.append([run.label, label, len(rs), n_seq, acc, lo_, hi_, _best_letter_share(rs)])
            plot.setdefault(run.label, []).append(
                (label, acc, lo_ if lo_ is not None else acc, hi_ if hi_ is not None else acc)
            )
    if not t.rows:
        return not_enough(name, title, cols, f"no base item with meta `{key}` in any run")
    t.plot = plot
    return t


# -- variant deltas ---------------------------------------------------------------------------------------
def _base_pair(item: vs.QuestionItem) -> str:
    suffix = "/" + item.variant
    if not item.pair.endswith(suffix):
        raise ValueError(
            f"item {item.idx!r}: variant {item.variant!r} but pair {item.pair!r} does not end in {suffix!r}"
        )
    return item.pair[: -len(suffix)]


def matched_pairs(run: Run, variant: str) -> list[tuple[ItemResult, ItemResult]]:
    """(base item, variant item) of the run, matched by base pair and mode (module docstring)."""
    base = {(r.item.pair, r.item.mode): r for r in scoped(run)}
    out = []
    for r in scoped(run, variant):
        b = base.get((_base_pair(r.item), r.item.mode))
        if b is not None:
            out.append((b, r))
    return out


def paired_delta(
    pairs: Sequence[tuple[ItemResult, ItemResult]], n_boot: int, seed: int, level: float = 0.95
) -> tuple[float, float, float, list[float] | None, int]:
    """(base accuracy, variant accuracy, delta, delta CI over sequences, sequences) of matched pairs."""
    seqs = sorted({b.item.sequence_id for b, _ in pairs})
    k = {s: i for i, s in enumerate(seqs)}
    bs, vs_, c = np.zeros(len(seqs)), np.zeros(len(seqs)), np.zeros(len(seqs))
    for b, v in pairs:
        i = k[b.item.sequence_id]
        bs[i] += b.right
        vs_[i] += v.right
        c[i] += 1
    base_acc, var_acc = bs.sum() / c.sum(), vs_.sum() / c.sum()
    ci = None
    if n_boot:
        rng = np.random.default_rng(seed)
        w = rng.multinomial(len(seqs), np.full(len(seqs), 1 / len(seqs)), size=n_boot).astype(float)
        deltas = (w @ vs_ - w @ bs) / (w @ c)
        ci = [float(v) for v in np.percentile(deltas, [100 * (1 - level) / 2, 100 * (1 + level) / 2])]
    return float(base_acc), float(var_acc), float(var_acc - base_acc), ci, len(seqs)


def variant_deltas(runs: Sequence[Run], group: str, n_boot: int = 1000, seed: int = 0) -> Table:
    variants = VARIANT_GROUPS[group]
    cols = ["model", "variant", "n_matched", "n_sequences", "base", "variant_acc", "delta", "ci_lo", "ci_hi"]
    t = Table(
        f"delta_{group}",
        TITLES[group],
        cols,
        note="Matched pairs only (variant item and its base item both answered in the run); "
        "delta = variant - base, share of items right (strict), paired 95 % CI over sequences.",
    )
    plot: dict[str, list[tuple[str, float, float, float]]] = {}
    absent = []
    for variant in variants:
        found = False
        for run in runs:
            pairs = matched_pairs(run, variant)
            if not pairs:
                continue
            found = True
            b, v, d, ci, n_seq = paired_delta(pairs, n_boot, seed)
            lo, hi = ci or (None, None)
            t.rows.append([run.label, variant, len(pairs), n_seq, b, v, d, lo, hi])
            plot.setdefault(run.label, []).append(
                (variant, d, lo if lo is not None else d, hi if hi is not None else d)
            )
        if not found:
            absent.append(variant)
    if not t.rows:
        return not_enough(t.name, t.title, cols, f"no matched items of {list(variants)} in any run")
    if absent:
        t.note += f" Not in any run (not enough items): {', '.join(absent)}."
    t.plot = plot
    return t


# -- correlation with common-sense benchmarks -------------------------------------------------------------
def correlation(runs: Sequence[Run], benchmarks: dict[str, dict[str, float]]) -> Table:
    """Pearson r over models between each category's strict accuracy (and overall) and each benchmark column."""
    from scipy.stats import pearsonr

    cols = ["benchmark", "category", "n_models", "pearson_r", "p_value", "models"]
    names = sorted({b for row in benchmarks.values() for b in row})
    matched = [(run, run.lookup(benchmarks)) for run in runs]
    matched = [(run, row) for run, row in matched if row]
    if not names or len(matched) < 3:
        return not_enough(
            "correlation",
            "Correlation with common-sense benchmarks",
            cols,
            f"{len(matched)} model(s) of the runs found in the benchmark CSV; Pearson r needs >= 3",
        )
    t = Table(
        "correlation",
        "Pearson correlation of category accuracy with common-sense benchmarks",
        cols,
        note="Over models present in both the runs and the CSV (n_models); r is undefined (–) when either "
        "side is constant.",
    )
    scatter: dict[str, dict[str, list[tuple[str, float, float]]]] = {}
    categories = sorted({c for run, _ in matched for c in run.scores["strict"]["category"]}) + ["overall"]
    for bench in names:
        for cat in categories:
            pts = []
            for run, row in matched:
                acc = (
                    run.scores["strict"]["overall"]
                    if cat == "overall"
                    else run.scores["strict"]["category"].get(cat)
                )
                if acc is not None and bench in row:
                    pts.append((run.label, row[bench], acc))
            scatter.setdefault(bench, {})[cat] = {"points": pts, "r": None}
            if len(pts) < 3:
                t.rows.append([bench, cat, len(pts), None, None, "not enough models"])
                continue
            x, y = np.array([p[1] for p in pts]), np.array([p[2] for p in pts])
            if np.ptp(x) == 0 or np.ptp(y) == 0:
                t.rows.append([bench, cat, len(pts), None, None, "; ".join(p[0] for p in pts)])
                continue
            r, p = pearsonr(x, y)
            scatter[bench][cat]["r"] = float(r)
            t.rows.append([bench, cat, len(pts), float(r), float(p), "; ".join(p_[0] for p_ in pts)])
    t.plot = scatter
    return t
