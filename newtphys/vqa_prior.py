"""Blind baselines of a question set: how far the text alone goes, without a single pixel.

Every strategy sees an item's question text and options, never its images, and never the answer of any
item of the same sequence: priors are learned leave-one-sequence-out from the answers of the *other*
sequences of the set (as a model that memorised the world's regularities would).

* ``text_prior`` — for the same question text (object names included, numbers removed) or, failing
  that, the same question id: the option text that was most often correct elsewhere (categorical
  questions), or the option nearest (in log scale) to the median correct value elsewhere (numeric ones);
* ``middle_value`` — numeric questions only: the option of median value among the four (catches
  distractor rules that leave the answer in the middle).

``audit`` scores each strategy per question id and flags the ids where the best blind strategy beats chance
(0.25) with a 95 % Wilson interval entirely above it: questions a model may answer without looking.
"""

from __future__ import annotations

import math
import re
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from newtphys import vqa_schema as vs

CHANCE = 1.0 / len(vs.LETTERS)
_NUMBER = re.compile(r"^\s*(-?\d+(?:\.\d+)?)")


def _number(text: str) -> float | None:
    m = _NUMBER.match(text)
    return float(m.group(1)) if m else None


def _is_numeric(item: vs.QuestionItem) -> bool:
    return all(o != vs.IMAGE_OPTION and _number(o) is not None for o in item.options)


def _text_key(item: vs.QuestionItem) -> str:
    return re.sub(r"\d+(\.\d+)?", "#", item.question)


def wilson_interval(successes: int, n: int, z: float = 1.96) -> tuple[float, float]:
    """95 % Wilson score interval of a proportion."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


class TextPrior:
    """Leave-one-sequence-out answer priors from the correct option texts of the other sequences."""

    def __init__(self, items: Sequence[vs.QuestionItem], answers: dict[str, vs.AnswerRecord]) -> None:
        self.by_text: dict[str, list[tuple[str, str]]] = defaultdict(list)  # key -> [(sequence, correct text)]
        self.by_qid: dict[str, list[tuple[str, str]]] = defaultdict(list)
        for item in items:
            correct = item.options[vs.LETTERS.index(answers[item.idx].answer)]
            if correct == vs.IMAGE_OPTION:
                continue
            self.by_text[_text_key(item)].append((item.sequence_id, correct))
            self.by_qid[item.question_id].append((item.sequence_id, correct))

    def _evidence(self, item: vs.QuestionItem) -> list[str]:
        for table, key in ((self.by_text, _text_key(item)), (self.by_qid, item.question_id)):
            seen = [c for seq, c in table.get(key, []) if seq != item.sequence_id]
            if seen:
                return seen
        return []

    def choose(self, item: vs.QuestionItem) -> int | None:
        """Index of the chosen option, or None when there is no evidence (then the item is guessed)."""
        seen = self._evidence(item)
        if not seen or all(o == vs.IMAGE_OPTION for o in item.options):
            return None
        if _is_numeric(item):
            values = [v for v in (_number(c) for c in seen) if v is not None]
            if not values:
                return None
            target = float(np.median(values))
            scale = lambda v: math.log(max(abs(v), 1e-6))  # noqa: E731
            return int(np.argmin([abs(scale(_number(o)) - scale(target)) for o in item.options]))
        counts = Counter(seen)
        scores = [counts.get(o, 0) for o in item.options]
        return int(np.argmax(scores)) if max(scores) > 0 else None


def middle_value(item: vs.QuestionItem) -> int | None:
    if not _is_numeric(item):
        return None
    values = [_number(o) for o in item.options]
    order = np.argsort(values, kind="stable")
    return int(order[1])  # the lower median of four


def audit(items: Sequence[vs.QuestionItem], answers: dict[str, vs.AnswerRecord]) -> dict[str, Any]:
    """Per question id: items, accuracy of each blind strategy (a guess counts 1/4 where a strategy abstains),
    the best one, its 95 % interval and whether it beats chance."""
    prior = TextPrior(items, answers)
    strategies: dict[str, Callable[[vs.QuestionItem], int | None]] = {"text_prior": prior.choose,
                                                                      "middle_value": middle_value}
    scores: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for item in items:
        truth = vs.LETTERS.index(answers[item.idx].answer)
        for name, strategy in strategies.items():
            choice = strategy(item)
            scores[item.question_id][name].append(CHANCE if choice is None else float(choice == truth))
    report: dict[str, Any] = {}
    for qid in sorted(scores):
        acc = {name: float(np.mean(v)) for name, v in scores[qid].items()}
        best = max(acc, key=lambda k: (acc[k], k))
        n = len(scores[qid][best])
        lo, hi = wilson_interval(round(acc[best] * n), n)
        report[qid] = {"n": n, "accuracy": acc, "best": best, "best_accuracy": acc[best],
                       "interval_95": [lo, hi], "beats_chance": lo > CHANCE}  # fmt: skip
    return report
