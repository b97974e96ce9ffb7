"""Scores of a run directory without intervals: the paper's macro accuracy beside the trivial predictors.

The CLI uses :func:`probes.vlm.scoring.score_run` (bootstrap intervals, circular evaluation) when that module
is installed, and this otherwise. Strict = the paper's extraction; lenient = strict, else the option text,
kept apart. In circular mode an item counts as right only when all four rotations are right. Trivial
predictors on the same items and under the same rule: chance (0.25, or 0.25^4 circular), each constant letter
A-D (its macro accuracy on the set; 0 in circular mode) and the text prior (the ``prior`` baseline).
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from newtphys.vqa_scoring import macro_accuracy
from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE, Prompt
from probes.vlm.predictions import read_predictions
from probes.vlm.prompting import ROTATIONS, to_set_letter

SCORER = "probes.vlm.simple_scores (macro accuracy, no intervals)"


def _records(items: dict[str, vs.QuestionItem], idxs: list[str], correct: dict[str, bool]) -> list[dict[str, Any]]:
    return [{"question_id": items[i].question_id, "sub_category": items[i].sub_category,
             "category": items[i].category, "correct": correct[i]} for i in idxs]  # fmt: skip


def trivial_picks(set_dir: Path, idxs: list[str], rotations: list[int]) -> dict[str, dict[tuple[str, int], str]]:
    """What each trivial predictor answers per (item, rotation), as a letter of the set's order: the constant
    letters (a prompt letter, so a different set option per rotation) and the text prior (its choice is the
    same option in every rotation; a seeded guess where it has no evidence)."""
    from probes.vlm.baselines import PriorAnswerer

    prompts = {(i, r): Prompt(i, (), "", ("", "", "", ""), r) for i in idxs for r in rotations}
    picks = {f"constant_{L}": {k: to_set_letter(L, k[1]) for k in prompts} for L in vs.LETTERS}
    prior = PriorAnswerer(set_dir, seed=0)
    keys = list(prompts)
    letters = [g.text for g in prior.answer([prompts[k] for k in keys])]
    picks["prior"] = {k: to_set_letter(letter, k[1]) for k, letter in zip(keys, letters)}
    return picks


def simple_scores(run_dir: Path | str, set_dir: Path | str) -> dict[str, Any]:
    """Strict and lenient macro accuracy of ``run_dir``'s predictions on the set at ``set_dir``, with chance and
    the constant-letter baselines on the same items."""
    run_dir, set_dir = Path(run_dir), Path(set_dir)
    manifest = json.loads((run_dir / MANIFEST_FILE).read_text())
    circular = bool(manifest.get("circular", False))
    items = {it.idx: it for it in vs.read_items(set_dir)}
    answers = {k: a.answer for k, a in vs.read_answers(set_dir).items()}
    preds = read_predictions(run_dir / PREDICTIONS_FILE)
    unknown = sorted({p.idx for p in preds} - set(items))
    if unknown:
        raise KeyError(f"{run_dir / PREDICTIONS_FILE}: items not in the set {set_dir}: {unknown[:5]}")
    by_item: dict[str, dict[int, Any]] = defaultdict(dict)
    for p in preds:
        by_item[p.idx][int(p.rotation)] = p
    need = set(ROTATIONS) if circular else {0}
    idxs = [i for i in items if i in by_item and need <= set(by_item[i])]
    if not idxs:
        raise ValueError(f"{run_dir}: no complete predictions to score")
    strict = {i: all(by_item[i][r].letter == answers[i] for r in need) for i in idxs}
    lenient = {i: all(by_item[i][r].letter_lenient == answers[i] for r in need) for i in idxs}
    extracted = sum(by_item[i][r].letter is not None for i in idxs for r in need) / (len(idxs) * len(need))
    baselines: dict[str, float] = {"chance": (1.0 / len(vs.LETTERS)) ** len(need)}
    for name, picks in trivial_picks(set_dir, idxs, sorted(need)).items():
        right = {i: all(picks[(i, r)] == answers[i] for r in need) for i in idxs}
        baselines[name] = macro_accuracy(_records(items, idxs, right))["overall"]
    best = max(baselines, key=lambda k: (baselines[k], k))
    return {"scorer": SCORER, "answerer": manifest.get("answerer"), "weights": manifest.get("model", {}).get("weights"),
            "circular": circular, "items": len(idxs), "extracted_share": extracted,
            "strict": macro_accuracy(_records(items, idxs, strict)),
            "lenient": macro_accuracy(_records(items, idxs, lenient)),
            "baselines": baselines, "best_trivial": {"name": best, "overall": baselines[best]}}  # fmt: skip
