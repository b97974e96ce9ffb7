"""Rules every question shares: what a question is, distractors, letters, frame windows, wording.

* Numeric distractors: a slope ``s`` drawn deterministically from the answer's text in [1, 4] (0.4 when
  |x| < 1); candidates ``x (j + s) / s`` for j in -3..3, j != 0, kept when inside the question's range and
  above 0.04; three kept; fixed values when |x| < 0.04. Young's modulus: ``x 10^k``, k = +-1..+-5, above 1e4 Pa.
* Name distractors: other visible objects of the scene first, then names from the object library.
* Letters: the correct option's position is assigned over the whole set (balanced per question id and over
  the set, each id's pairs in the order of a SHA-256 of seed, sequence, question key and frame), identical for
  the single and multi versions of a question; the distractors keep a seeded order.
"""

from __future__ import annotations

import hashlib
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

MULTI_FRAMES = 8
"""Frames a multi-frame item shows, ending at the question's frame."""
STRIDES = (4, 3, 2, 1)
"""Multi-frame stride: the largest that fits before the question's frame."""
MIN_DISTRACTOR = 0.04
MULTI_PREFIX = "Consider all the frames shown, in order; answer for the last one. "
"""Lead-in of the multi-frame version of a question asked in both modes."""


class NotAnswerable(Exception):
    """The rules are not met for this question here (the reason is counted in the manifest)."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class Question:
    """A generated question before letters are assigned: the correct option and three distractors."""

    text: str
    correct: str
    distractors: tuple[str, str, str]
    value: Any
    unit: str
    objects: tuple[int, ...]
    key: str
    """Identifies the question within (sequence, frame), e.g. the object ids it is about."""
    option_frames: tuple[int, ...] | None = None
    """Image options: the frame of the correct option, then of each distractor."""
    shown_frames: tuple[int, ...] | None = None
    """Frames the question shows when they are not the standard window (temporal questions)."""
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        texts = [self.correct, *self.distractors]
        if len(self.distractors) != 3:
            raise ValueError(f"{self.key}: a question needs 3 distractors, got {self.distractors}")
        if self.option_frames is None and len({t.strip().lower() for t in texts}) != 4:
            raise NotAnswerable("options_not_distinct")


def seed_of(*parts: Any) -> int:
    """A 64-bit seed from the SHA-256 of the parts' text (stable across processes and platforms)."""
    text = "\x1f".join(str(p) for p in parts)
    return int.from_bytes(hashlib.sha256(text.encode()).digest()[:8], "little")


def multi_window(frame: int, count: int = MULTI_FRAMES) -> list[int]:
    """``count`` frames ending at ``frame`` with the largest stride in STRIDES that fits (>= 0)."""
    for k in STRIDES:
        if frame - (count - 1) * k >= 0:
            return [frame - (count - 1 - i) * k for i in range(count)]
    raise NotAnswerable("window_too_short")


# -- numbers -------------------------------------------------------------------------------------------
def fmt(value: float, decimals: int, unit: str = "") -> str:
    text = f"{value:.{decimals}f}"
    return f"{text} {unit}".strip()


def numeric_distractors(
    value: float, decimals: int, unit: str, rng: np.random.Generator,
    valid: Callable[[float], bool] = lambda v: True,
) -> tuple[str, str, str]:  # fmt: skip
    """Three distinct formatted distractors by the slope rule (see the module docstring)."""
    answer = fmt(value, decimals, unit)
    x = float(value)
    if abs(x) < MIN_DISTRACTOR:
        pool = [0.05, 0.1, 0.2, 0.5, 1.0, 2.0]
    else:
        s = 0.4 if abs(x) < 1 else 1.0 + 3.0 * (seed_of(answer) % 10_000) / 9_999.0
        pool = [x * (j + s) / s for j in (-3, -2, -1, 1, 2, 3)]
    texts: list[str] = []
    for v in rng.permutation(np.array(pool, np.float64)):
        t = fmt(float(v), decimals, unit)
        if v > MIN_DISTRACTOR and valid(float(v)) and t != answer and t not in texts:
            texts.append(t)
    if len(texts) < 3:
        raise NotAnswerable("too_few_numeric_distractors")
    return tuple(texts[:3])  # type: ignore[return-value]


def modulus_text(pa: float) -> str:
    """Young's modulus in MPa, three significant digits, plain notation (``0.0123 MPa``, ``2170 MPa``)."""
    mpa = float(f"{pa / 1e6:.3g}")
    return f"{np.format_float_positional(mpa, trim='-')} MPa"


def modulus_distractors(pa: float, rng: np.random.Generator) -> tuple[str, str, str]:
    """``E 10^k`` for k = +-1..+-5 above 1e4 Pa, three drawn."""
    ks = [k for k in rng.permutation([-5, -4, -3, -2, -1, 1, 2, 3, 4, 5]) if pa * 10.0**k > 1e4]
    texts = []
    for k in ks:
        t = modulus_text(pa * 10.0 ** int(k))
        if t != modulus_text(pa) and t not in texts:
            texts.append(t)
    if len(texts) < 3:
        raise NotAnswerable("too_few_numeric_distractors")
    return tuple(texts[:3])  # type: ignore[return-value]


def integer_window(answer: int, position: int) -> list[int]:
    """Four consecutive integers >= 0 holding ``answer`` at ``position`` (0-3) when possible."""
    start = max(answer - position, 0)
    return list(range(start, start + 4))


def integer_question(text: str, answer: int, objects: tuple[int, ...], key: str, **meta: Any) -> Question:
    """A count question: options are four consecutive integers in ascending order; the generator places the
    window so that the answer lands on its assigned letter (balanced like every other question)."""
    window = integer_window(answer, 0)
    return Question(text, str(answer), tuple(str(v) for v in window[1:]), answer, "", objects, key,  # type: ignore[arg-type]
                    meta={"ordered_integer_options": True, **meta})


# -- names ---------------------------------------------------------------------------------------------
def mention(name: str) -> re.Pattern[str]:
    """Matches "the <name>" as whole words (not "the red ball" inside "the red ball-point")."""
    return re.compile(rf"\bthe {re.escape(name)}(?![\w-])")


def pick(pool: Sequence[str], exclude: Sequence[str], rng: np.random.Generator, count: int = 3) -> tuple[str, ...]:
    """``count`` distinct entries of ``pool`` (in a seeded order) not in ``exclude``."""
    seen = {e.strip().lower() for e in exclude}
    out: list[str] = []
    for i in rng.permutation(len(pool)):
        t = pool[int(i)]
        if t.strip().lower() not in seen:
            seen.add(t.strip().lower())
            out.append(t)
        if len(out) == count:
            return tuple(out)
    raise NotAnswerable("too_few_distractors")


def label_options(correct: str, labels: Sequence[str], rng: np.random.Generator) -> tuple[str, str, str]:
    """Three of the other labels of a fixed label set (bins, directions, lens classes)."""
    return pick([lab for lab in labels if lab != correct], [correct], rng)  # type: ignore[return-value]
