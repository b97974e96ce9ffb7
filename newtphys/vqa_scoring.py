"""How a NewtPhys item is prompted and scored (the evaluation protocol, docs/vqa_contract.md): the prompt
(question, options "A. ...", an instruction to answer with the letter only), the answer extraction (a letter
A-D alone or at the end of the reply, case-insensitive; anything else is wrong; a lenient variant, reported
apart, also accepts the one option whose text the reply contains) and the macro accuracy
(mean per question id, then per sub-category, then per category, then overall).

Standalone on purpose (standard library; Pillow only to open images): ``python -m newtphys export-vqa
--format lmms-eval`` copies this file verbatim as the task's ``utils.py``, so that lmms-eval scores with the
same functions as our own tools. The ``doc_*`` / ``process_results`` / ``aggregate_*`` functions are the
lmms-eval hooks; a doc is one line of the exported JSONL (``question``, ``options``, ``images`` (absolute
paths), ``answer``, ``question_id``, ``sub_category``, ``category``, ...).
"""

from __future__ import annotations

import re
from collections import defaultdict
from collections.abc import Iterable, Sequence
from typing import Any

LETTERS = ("A", "B", "C", "D")
ANSWER_INSTRUCTION = "Reply with the letter of the correct option (A, B, C or D) and nothing else."
_TRAILING = " \t\r\n.,;:!?)]}*\"'`"
_LAST_LETTER = re.compile(r"(?:^|[^A-Za-z])([A-Da-d])$")


def format_prompt(question: str, options: Sequence[str]) -> str:
    """The text that follows the images: the question, one line per option, the answer instruction."""
    if len(options) != len(LETTERS):
        raise ValueError(f"an item has {len(LETTERS)} options, got {len(options)}: {list(options)!r}")
    return "\n".join([question, *(f"{k}. {o}" for k, o in zip(LETTERS, options)), ANSWER_INSTRUCTION])


def extract_letter(reply: str) -> str | None:
    """The option letter of a reply: a letter A-D alone or at its end ("B", "b.", "The answer is (C)"), in
    upper case; None otherwise ("I cannot tell")."""
    text = str(reply).strip().rstrip(_TRAILING)
    m = _LAST_LETTER.search(text)
    return m.group(1).upper() if m else None


def _normalise(text: str) -> str:
    """Lower case, punctuation other than ``.`` ``%`` ``-`` ``/`` inside words dropped, spaces collapsed."""
    text = re.sub(r"[^0-9a-z.%/\- ]+", " ", str(text).lower())
    text = re.sub(r"(?<![0-9])\.|\.(?![0-9])", " ", text)  # a full stop, not a decimal point
    return " ".join(text.split())


def extract_letter_lenient(reply: str, options: Sequence[str]) -> str | None:
    """The strict letter (:func:`extract_letter`) when there is one; else the letter of the one option whose
    text the reply contains as whole words ("It weighs 0.50 kg" -> the option "0.50 kg"), case and
    punctuation ignored. An option contained in another matched option ("1 kg" in "1 kg or more") yields to
    it; several unrelated matches, or none, give None. Reported apart from the strict (paper's) number."""
    strict = extract_letter(reply)
    if strict is not None:
        return strict
    if len(options) != len(LETTERS):
        raise ValueError(f"an item has {len(LETTERS)} options, got {len(options)}: {list(options)!r}")
    text = f" {_normalise(reply)} "
    matched = [k for k, o in enumerate(options) if _normalise(o) and f" {_normalise(o)} " in text]
    keep = [k for k in matched
            if not any(j != k and f" {_normalise(options[k])} " in f" {_normalise(options[j])} " for j in matched)]
    return LETTERS[keep[0]] if len(keep) == 1 else None


def macro_accuracy(records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Accuracy of ``records`` (each ``question_id``, ``sub_category``, ``category``, ``correct``): the mean
    per question id, the mean of those per sub-category, of those per category, and of those overall."""
    per_id: dict[str, list[float]] = defaultdict(list)
    parent: dict[str, tuple[str, str]] = {}
    for r in records:
        per_id[r["question_id"]].append(1.0 if r["correct"] else 0.0)
        parent[r["question_id"]] = (r["sub_category"], r["category"])
    if not per_id:
        raise ValueError("macro accuracy of no records")
    by_id = {q: sum(v) / len(v) for q, v in sorted(per_id.items())}
    subs: dict[str, list[float]] = defaultdict(list)
    for q, acc in by_id.items():
        subs[parent[q][0]].append(acc)
    by_sub = {s: sum(v) / len(v) for s, v in sorted(subs.items())}
    cats: dict[str, list[float]] = defaultdict(list)
    sub_parent = {sub: cat for sub, cat in parent.values()}
    for s, acc in by_sub.items():
        cats[sub_parent[s]].append(acc)
    by_cat = {c: sum(v) / len(v) for c, v in sorted(cats.items())}
    return {"overall": sum(by_cat.values()) / len(by_cat), "category": by_cat, "sub_category": by_sub,
            "question_id": by_id}  # fmt: skip


# -- lmms-eval hooks ------------------------------------------------------------------------------------
def doc_to_visual(doc: dict[str, Any]) -> list[Any]:
    from PIL import Image

    return [Image.open(p).convert("RGB") for p in doc["images"]]


def doc_to_text(doc: dict[str, Any], lmms_eval_specific_kwargs: dict[str, Any] | None = None) -> str:
    return format_prompt(doc["question"], doc["options"])


def doc_to_target(doc: dict[str, Any]) -> str:
    return doc["answer"]


def process_results(doc: dict[str, Any], results: Sequence[str]) -> dict[str, dict[str, Any]]:
    record = {"idx": doc["idx"], "question_id": doc["question_id"], "sub_category": doc["sub_category"],
              "category": doc["category"], "prediction": extract_letter(results[0]) if results else None,
              "answer": doc["answer"]}  # fmt: skip
    record["correct"] = record["prediction"] == doc["answer"]
    return {"accuracy": record, "macro_accuracy": record}


def aggregate_accuracy(records: list[dict[str, Any]]) -> float:
    """Share of items answered correctly (micro)."""
    return sum(bool(r["correct"]) for r in records) / len(records)


def aggregate_macro_accuracy(records: list[dict[str, Any]]) -> float:
    """Mean per question id, then sub-category, then category, then overall (the paper's number)."""
    return macro_accuracy(records)["overall"]
