"""Score one run directory against its question set: ``score_run(run_dir, set_dir) -> dict`` (and
``scores.json``).

Scope of the headline number (the paper's protocol): ``base`` items of the question ids in the analysis
(``QuestionSpec.in_analysis``), in the modes the run was asked (``manifest.extra["modes"]`` when the
evaluation loop recorded it, else every mode of the set). Within the scope:

* an item is right (``strict``, the paper's number) when the letter extracted by the paper's rule
  (``PredictionRecord.letter``, in the set's letter order) is the answer; ``lenient`` uses
  ``letter_lenient`` (option text matched too) and is reported apart, never mixed in;
* an item without a prediction counts as wrong, and ``coverage`` says how many there were;
* macro accuracy question id -> sub-category -> category -> overall
  (:func:`newtphys.vqa_scoring.macro_accuracy`), with bootstrap 95 % intervals that resample sequences
  (:mod:`probes.vlm.bootstrap`);
* circular evaluation, when the run has rotations 1-3: the headline ``strict`` / ``lenient`` count an item
  right only if rotations 0-3 all are; ``rotation0`` keeps the paper's number (rotation 0 alone) apart;
* beside every score, the trivial predictors on the same items under the same rule (``baselines``, flat:
  ``chance``, ``constant_A`` ... ``constant_D``, ``prior``; ``best_trivial``; ``baseline_details``): chance
  (0.25, circular 0.25^4), each constant letter (macro accuracy of answering it everywhere; 0 circular),
  the text prior of :mod:`newtphys.vqa_prior` (leave-one-sequence-out; an abstention scores its *expected*
  0.25 -- the ``prior`` answerer of :mod:`probes.vlm.baselines` must reply a letter and guesses there, so its
  own run scores that expectation plus the luck of its guesses); details: the best letter per category, the
  letter shares, the prior per category.

The ``scores.json`` keys are documented in one place: docs/vlm_evaluation.md ("scores.json").

The variants (roi_masked, cue_*, level_*, cf_* ...) are scored too, by variant, and the ids left out of the
analysis apart; :mod:`probes.vlm.report` builds the paper's analyses from :func:`item_results`.
"""

from __future__ import annotations

import json
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from newtphys.vqa_prior import CHANCE, TextPrior
from newtphys.vqa_scoring import macro_accuracy
from probes.vlm.bootstrap import bootstrap_ci, build_table, point_estimate
from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE, SCORES_FILE, PredictionRecord
from probes.vlm.predictions import manifest_set_dir, read_manifest, write_atomic
from probes.vlm.predictions import read_predictions as read_prediction_list
from probes.vlm.prompting import ROTATIONS, question_set_sha256
from probes.vlm.selection import asked_items

SCORER = "probes.vlm.scoring (macro accuracy, sequence-bootstrap CIs)"
PRIOR_MAX_ITEMS = 20_000
"""The text prior is quadratic in items per question id: skipped (and said so) above this many items."""


@dataclass(frozen=True)
class ItemResult:
    """One item of the set joined with the run's predictions."""

    item: vs.QuestionItem
    answer: str
    predicted: bool
    """A rotation-0 prediction exists."""
    strict: bool
    lenient: bool
    circular_strict: bool | None = None
    """All four rotations right (None when the run has no rotations)."""
    circular_lenient: bool | None = None
    letter: str | None = None
    """The strict letter of rotation 0 (None: missing or not extracted)."""

    @property
    def right(self) -> bool:
        """The headline correctness: circular strict in a circular run, else strict."""
        return self.strict if self.circular_strict is None else self.circular_strict


def read_predictions(run_dir: Path) -> dict[tuple[str, int], PredictionRecord]:
    """(idx, rotation) -> prediction of ``<run_dir>/predictions.jsonl``
    (:func:`probes.vlm.predictions.read_predictions`: duplicates and bad rotations are errors)."""
    path = Path(run_dir) / PREDICTIONS_FILE
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no predictions")
    return {(r.idx, int(r.rotation)): r for r in read_prediction_list(path)}


def check_set(manifest: dict[str, Any], set_dir: Path, run_dir: Path) -> None:
    """The run was made on this set: ``question_set_sha256`` matches ``questions.jsonl``."""
    want = manifest.get("question_set_sha256")
    got = question_set_sha256(set_dir)
    if want and want != got:
        raise ValueError(
            f"{run_dir}/{MANIFEST_FILE}: question_set_sha256={want[:12]}... but "
            f"{set_dir}/{vs.QUESTIONS_FILE} has {got[:12]}...: predictions of another set"
        )


def item_results(run_dir: Path | str, set_dir: Path | str, check: bool = True) -> list[ItemResult]:
    """Every item of the set with the run's correctness (missing predictions are wrong). The run is circular
    when its manifest says so or it holds rotations 1-3."""
    run_dir, set_dir = Path(run_dir), Path(set_dir)
    manifest = read_manifest(run_dir) if (run_dir / MANIFEST_FILE).is_file() else {}
    if check:
        check_set(read_manifest(run_dir), set_dir, run_dir)
    items, answers = vs.read_items(set_dir), vs.read_answers(set_dir)
    preds = read_predictions(run_dir)
    known = {it.idx for it in items}
    unknown = sorted({idx for idx, _ in preds if idx not in known})
    if unknown:
        raise ValueError(
            f"{run_dir}/{PREDICTIONS_FILE}: {len(unknown)} idx not in {set_dir}/{vs.QUESTIONS_FILE}, "
            f"e.g. {unknown[:3]}"
        )
    circular = bool(manifest.get("circular")) or any(rot != 0 for _, rot in preds)
    out = []
    for it in items:
        if it.idx not in answers:
            raise KeyError(f"{set_dir}/{vs.ANSWERS_FILE}: no answer for idx {it.idx!r}")
        truth = answers[it.idx].answer
        p0 = preds.get((it.idx, 0))
        cs = cl = None
        if circular:
            rots = [preds.get((it.idx, r)) for r in ROTATIONS]
            cs = all(p is not None and p.letter == truth for p in rots)
            cl = all(p is not None and p.letter_lenient == truth for p in rots)
        out.append(
            ItemResult(
                item=it,
                answer=truth,
                predicted=p0 is not None,
                strict=p0 is not None and p0.letter == truth,
                lenient=p0 is not None and p0.letter_lenient == truth,
                circular_strict=cs,
                circular_lenient=cl,
                letter=None if p0 is None else p0.letter,
            )
        )
    return out


def _records(results: Iterable[ItemResult], key: str) -> list[dict[str, Any]]:
    return [
        {
            "question_id": r.item.question_id,
            "sub_category": r.item.sub_category,
            "category": r.item.category,
            "correct": bool(getattr(r, key)),
        }
        for r in results
    ]


def macro_score(
    results: Sequence[ItemResult], key: str = "strict", n_boot: int = 1000, seed: int = 0, level: float = 0.95
) -> dict[str, Any]:
    """Macro accuracy of ``key`` (``strict``, ``lenient``, ``circular_strict``, ``circular_lenient``) with
    its sequence-bootstrap interval (``ci``) and the item-level (micro) accuracy; n items / sequences."""
    m = macro_accuracy(_records(results, key))
    table = build_table(
        (
            r.item.sequence_id,
            r.item.question_id,
            r.item.sub_category,
            r.item.category,
            float(bool(getattr(r, key))),
        )
        for r in results
    )
    m["micro"] = sum(bool(getattr(r, key)) for r in results) / len(results)
    m["n_items"], m["n_sequences"] = len(results), len(table.sequences)
    m["ci"] = bootstrap_ci(table, n_boot=n_boot, seed=seed, level=level) if n_boot else None
    return m


def constant_letter_baseline(results: Sequence[ItemResult]) -> dict[str, Any]:
    """Answering one letter everywhere: the macro accuracy per letter, the best one (overall, and per
    category the best letter of that category), the letter shares."""
    shares = Counter(r.answer for r in results)
    n = len(results)
    per_letter, per_category = {}, {}
    for letter in vs.LETTERS:
        t = build_table(
            (
                r.item.sequence_id,
                r.item.question_id,
                r.item.sub_category,
                r.item.category,
                float(r.answer == letter),
            )
            for r in results
        )
        pe = point_estimate(t)
        per_letter[letter], per_category[letter] = pe["overall"], pe["category"]
    best = max(vs.LETTERS, key=lambda k: (per_letter[k], -vs.LETTERS.index(k)))
    category_best = {c: max(per_category[k][c] for k in vs.LETTERS) for c in per_category[best]}
    return {
        "letter": best,
        "overall": per_letter[best],
        "macro_per_letter": per_letter,
        "category_best": category_best,
        "letter_share": {k: shares.get(k, 0) / n for k in vs.LETTERS},
        "best_share": max(shares.get(k, 0) for k in vs.LETTERS) / n,
    }


def text_prior_baseline(results: Sequence[ItemResult], max_items: int = PRIOR_MAX_ITEMS) -> dict[str, Any]:
    """The leave-one-sequence-out text prior of :mod:`newtphys.vqa_prior`, learned and scored on these items;
    an abstention scores its expected 0.25."""
    if len(results) > max_items:
        return {"skipped": f"{len(results)} items > {max_items} (the prior is quadratic); not computed"}
    items = [r.item for r in results]
    prior = TextPrior(items, {r.item.idx: vs.AnswerRecord(r.item.idx, r.answer, None, "") for r in results})
    choices = [prior.choose(r.item) for r in results]
    t = build_table(
        (
            r.item.sequence_id,
            r.item.question_id,
            r.item.sub_category,
            r.item.category,
            CHANCE if c is None else float(vs.LETTERS[c] == r.answer),
        )
        for r, c in zip(results, choices)
    )
    pe = point_estimate(t)
    return {
        "overall": pe["overall"],
        "category": pe["category"],
        "abstained": sum(c is None for c in choices),
    }


def trivial_baselines(
    results: Sequence[ItemResult], circular: bool = False, max_prior_items: int = PRIOR_MAX_ITEMS
) -> tuple[dict[str, float], dict[str, Any]]:
    """Trivial predictors on the same items, under the headline rule: ``chance`` (0.25; 0.25^4 circular),
    ``constant_A`` ... ``constant_D`` (macro accuracy of answering that letter everywhere; 0 circular: one prompt
    letter names a different option in each rotation) and ``prior`` (the text prior; it picks the same option
    in every rotation, so circular changes nothing). Returns (name -> overall, details)."""
    constant = constant_letter_baseline(results)
    prior = text_prior_baseline(results, max_prior_items)
    flat: dict[str, float] = {"chance": CHANCE ** (len(ROTATIONS) if circular else 1)}
    for letter in vs.LETTERS:
        flat[f"constant_{letter}"] = 0.0 if circular else constant["macro_per_letter"][letter]
    if circular:
        constant = {**constant, "overall": 0.0, "category_best": dict.fromkeys(constant["category_best"], 0.0),
                    "letter": None, "note": "circular: a constant prompt letter is never right in all four rotations",
                    "rotation0_overall": constant["overall"]}  # fmt: skip
    if "overall" in prior:
        flat["prior"] = prior["overall"]
    return flat, {"chance": flat["chance"], "constant_letter": constant, "text_prior": prior}


def _scope(results: Sequence[ItemResult], modes: Sequence[str], variant: str | None) -> list[ItemResult]:
    return [r for r in results if r.item.mode in modes and (variant is None or r.item.variant == variant)]


def asked_results(
    results: Sequence[ItemResult], manifest: dict[str, Any]
) -> tuple[list[ItemResult], dict[str, int]]:
    """The results of the items the run's answerer was asked, and the counts left out
    (:func:`probes.vlm.selection.asked_items`)."""
    asked, left = asked_items([r.item for r in results], manifest)
    idx = {it.idx for it in asked}
    return [r for r in results if r.item.idx in idx], left


def score_results(
    results: Sequence[ItemResult],
    not_asked: dict[str, int] | None = None,
    modes: Sequence[str] | None = None,
    n_boot: int = 1000,
    seed: int = 0,
    level: float = 0.95,
    max_prior_items: int = PRIOR_MAX_ITEMS,
) -> dict[str, Any]:
    """The scores dictionary of :func:`score_run` from joined results (module docstring)."""
    modes = tuple(modes) if modes else tuple(sorted({r.item.mode for r in results}))
    in_scope = _scope(results, modes, None)
    analysed = [r for r in in_scope if vs.question_spec(r.item.question_id).in_analysis]
    head = [r for r in analysed if r.item.variant == vs.BASE_VARIANT]
    if not head:
        raise ValueError(
            f"no base items of the analysed question ids in modes {list(modes)}: nothing to score"
        )
    circular = any(r.circular_strict is not None for r in results)
    key_strict, key_lenient = ("circular_strict", "circular_lenient") if circular else ("strict", "lenient")
    flat, details = trivial_baselines(head, circular, max_prior_items)
    best = max(flat, key=lambda k: (flat[k], k))
    predicted = sum(r.predicted for r in head)
    out: dict[str, Any] = {
        "scorer": SCORER,
        "circular": circular,
        "items": len(head),
        "extracted_share": (predicted - sum(r.predicted and r.letter is None for r in head)) / predicted
        if predicted
        else 0.0,
        "protocol": {
            "variant": vs.BASE_VARIANT,
            "modes": list(modes),
            "extraction": "strict = the paper's letter rule; lenient = strict, else the option text matched",
            "missing_prediction": "wrong",
            "ci_level": level,
            "n_boot": n_boot,
            "seed": seed,
            "resampled": "sequence_id",
            "circular": circular,
            "headline": "all four rotations right" if circular else "rotation 0 (the paper's protocol)",
        },
        "coverage": {
            "items": len(head),
            "predicted": sum(r.predicted for r in head),
            "missing": sum(not r.predicted for r in head),
            "unextracted_strict": sum(r.predicted and r.letter is None for r in head),
            "not_asked": dict(not_asked or {}),
        },
        "strict": macro_score(head, key_strict, n_boot, seed, level),
        "lenient": macro_score(head, key_lenient, n_boot, seed, level),
        "rotation0": None,
        "baselines": flat,
        "best_trivial": {"name": best, "overall": flat[best]},
        "baseline_details": details,
    }
    if circular:  # the paper's number (no circular evaluation) from the same run, apart
        out["rotation0"] = {
            "strict": macro_score(head, "strict", n_boot, seed, level),
            "lenient": macro_score(head, "lenient", n_boot, seed, level),
        }
    out["by_mode"] = {}
    for mode in modes:
        sub = [r for r in head if r.item.mode == mode]
        if sub:
            out["by_mode"][mode] = {
                "n_items": len(sub),
                "strict": macro_accuracy(_records(sub, key_strict))["overall"],
                "lenient": macro_accuracy(_records(sub, key_lenient))["overall"],
            }
    out["variants"] = {}
    by_variant: dict[str, list[ItemResult]] = defaultdict(list)
    for r in analysed:
        if r.item.variant != vs.BASE_VARIANT:
            by_variant[r.item.variant].append(r)
    for variant, rs in sorted(by_variant.items()):
        out["variants"][variant] = {
            "n_items": len(rs),
            "predicted": sum(r.predicted for r in rs),
            "strict": macro_score(rs, key_strict, n_boot, seed, level),
            "lenient": macro_accuracy(_records(rs, key_lenient))["overall"],
            "constant_letter": 0.0 if circular else constant_letter_baseline(rs)["overall"],
        }
    apart = [
        r
        for r in in_scope
        if not vs.question_spec(r.item.question_id).in_analysis and r.item.variant == "base"
    ]
    out["excluded_from_analysis"] = (
        {"n_items": len(apart), "question_id": macro_accuracy(_records(apart, key_strict))["question_id"]}
        if apart
        else {"n_items": 0, "question_id": {}}
    )
    return out


def score_run(
    run_dir: Path | str,
    set_dir: Path | str | None = None,
    n_boot: int = 1000,
    seed: int = 0,
    level: float = 0.95,
    modes: Sequence[str] | None = None,
    write: bool = True,
) -> dict[str, Any]:
    """Scores of one run directory (module docstring); written to ``<run_dir>/scores.json`` when ``write``.
    ``set_dir`` defaults to the manifest's (:func:`manifest_set_dir`); the items scored are those the answerer
    was asked (:func:`asked_items`), further restricted to ``modes`` when given."""
    run_dir = Path(run_dir)
    manifest = read_manifest(run_dir)
    set_dir = Path(set_dir) if set_dir is not None else manifest_set_dir(manifest, run_dir)
    results = item_results(run_dir, set_dir)
    scores = score_results(
        *asked_results(results, manifest), modes=modes, n_boot=n_boot, seed=seed, level=level
    )
    scores = {
        "run_dir": str(run_dir),
        "set_dir": str(set_dir),
        "answerer": manifest.get("answerer"),
        "model": manifest.get("model"),
        "weights": (manifest.get("model") or {}).get("weights"),
        "question_set_sha256": manifest.get("question_set_sha256"),
        **scores,
    }
    if write:
        write_atomic(run_dir / SCORES_FILE, json.dumps(scores, indent=2, sort_keys=True) + "\n")
    return scores
