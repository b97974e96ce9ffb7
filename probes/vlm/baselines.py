"""Trivial answerers every VLM score is reported beside, and the harness's own check.

* ``random`` — a letter drawn per (seed, idx, rotation) from a hash: the same item gets the same letter in
  every run, batch or order; chance is 0.25.
* ``oracle`` — reads the set's ``answers.jsonl`` and replies with the correct letter of the prompt's letter
  order: it must score exactly 1.0, else the harness (prompting, rotation, extraction, scoring) is wrong.
* ``constant_letter`` — always the same letter: its accuracy is the set's share of that letter.
* ``prior`` — :class:`newtphys.vqa_prior.TextPrior` (text only, leave-one-sequence-out answer priors);
  where it has no evidence it must still reply a letter and guesses like ``random``. The trivial-baseline
  number reported beside every score (``baselines.prior`` of :mod:`probes.vlm.scoring`) counts those items
  at their expected 0.25 instead, so this answerer's own run differs from it by the luck of its guesses.
* ``blind`` — :class:`Blind` wraps any answerer and removes the images from its prompts.
"""

from __future__ import annotations

import hashlib
from dataclasses import replace
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from newtphys.vqa_prior import TextPrior
from probes.vlm.interface import Answerer, Generation, Prompt
from probes.vlm.prompting import to_prompt_letter

BASELINE_NAMES: tuple[str, ...] = ("random", "oracle", "constant_letter", "prior")


def hashed_index(seed: int, idx: str, rotation: int, n: int = len(vs.LETTERS)) -> int:
    """A uniform draw in [0, n) from (seed, idx, rotation): deterministic per item, independent of order."""
    digest = hashlib.sha256(f"{int(seed)}\x00{idx}\x00{int(rotation)}".encode()).digest()
    return int.from_bytes(digest[:8], "big") % n


def _reply(prompts: list[Prompt], letters: list[str]) -> list[Generation]:
    return [Generation(text=letter, latency_s=0.0, tokens_in=None, tokens_out=None) for letter in letters]


class RandomAnswerer:
    """A seeded uniform letter per (idx, rotation)."""

    def __init__(self, seed: int = 0) -> None:
        self.seed = int(seed)
        self.name = "random"

    def describe(self) -> dict[str, Any]:
        return {"id": "baseline/random", "kind": "baseline", "weights": "none", "seed": self.seed}

    def answer(self, prompts: list[Prompt]) -> list[Generation]:
        return _reply(prompts, [vs.LETTERS[hashed_index(self.seed, p.idx, p.rotation)] for p in prompts])


class ConstantLetterAnswerer:
    """Always ``letter``."""

    def __init__(self, letter: str = "A") -> None:
        letter = str(letter).strip().upper()
        if letter not in vs.LETTERS:
            raise ValueError(f"constant_letter: letter must be one of {list(vs.LETTERS)}, got {letter!r}")
        self.letter = letter
        self.name = f"constant_{letter}"

    def describe(self) -> dict[str, Any]:
        return {"id": f"baseline/constant_{self.letter}", "kind": "baseline", "weights": "none",
                "letter": self.letter}  # fmt: skip

    def answer(self, prompts: list[Prompt]) -> list[Generation]:
        return _reply(prompts, [self.letter] * len(prompts))


class OracleAnswerer:
    """The correct letter, read from ``<set_dir>/answers.jsonl`` (the harness's self-check)."""

    def __init__(self, set_dir: Path | str) -> None:
        self.set_dir = Path(set_dir)
        self.answers = {idx: a.answer for idx, a in vs.read_answers(self.set_dir).items()}
        self.name = "oracle"

    def describe(self) -> dict[str, Any]:
        return {"id": "baseline/oracle", "kind": "baseline", "weights": "none", "reads_answers": True}

    def answer(self, prompts: list[Prompt]) -> list[Generation]:
        missing = [p.idx for p in prompts if p.idx not in self.answers]
        if missing:
            raise KeyError(f"{self.set_dir / vs.ANSWERS_FILE}: no answer for items {missing[:5]}")
        return _reply(prompts, [to_prompt_letter(self.answers[p.idx], p.rotation) for p in prompts])


class PriorAnswerer:
    """The text-only prior of the VQA set (:class:`newtphys.vqa_prior.TextPrior`); a seeded guess where the
    prior has no evidence."""

    def __init__(self, set_dir: Path | str, seed: int = 0) -> None:
        self.set_dir = Path(set_dir)
        self.seed = int(seed)
        items = vs.read_items(self.set_dir)
        self.items = {item.idx: item for item in items}
        self.prior = TextPrior(items, vs.read_answers(self.set_dir))
        self.name = "prior"

    def describe(self) -> dict[str, Any]:
        return {"id": "baseline/text_prior", "kind": "baseline", "weights": "none", "seed": self.seed,
                "reads_answers": "of the other sequences (leave-one-sequence-out)"}  # fmt: skip

    def answer(self, prompts: list[Prompt]) -> list[Generation]:
        letters = []
        for p in prompts:
            choice = self.prior.choose(self.items[p.idx])
            if choice is None:
                letters.append(vs.LETTERS[hashed_index(self.seed, p.idx, p.rotation)])
            else:
                letters.append(to_prompt_letter(vs.LETTERS[choice], p.rotation))
        return _reply(prompts, letters)


class Blind:
    """``inner`` answering the same prompts with every image removed (text only)."""

    def __init__(self, inner: Answerer) -> None:
        self.inner = inner
        self.name = f"{inner.name}-blind"

    def __getattr__(self, key: str) -> Any:  # spec, single_image_only, ... of the wrapped answerer
        if key == "inner":
            raise AttributeError(key)
        return getattr(self.inner, key)

    def describe(self) -> dict[str, Any]:
        return {**self.inner.describe(), "blind": True}

    def answer(self, prompts: list[Prompt]) -> list[Generation]:
        return self.inner.answer([replace(p, images=()) for p in prompts])


def build_baseline(name: str, set_dir: Path | str | None = None, seed: int = 0, letter: str = "A") -> Answerer:
    """The baseline ``name`` (one of :data:`BASELINE_NAMES`); ``oracle`` and ``prior`` read ``set_dir``."""
    if name == "random":
        return RandomAnswerer(seed)
    if name == "constant_letter":
        return ConstantLetterAnswerer(letter)
    if name in ("oracle", "prior"):
        if set_dir is None:
            raise ValueError(f"baseline {name!r} reads the question set: pass set_dir")
        return OracleAnswerer(set_dir) if name == "oracle" else PriorAnswerer(set_dir, seed)
    raise KeyError(f"unknown baseline {name!r}; valid baselines: {', '.join(BASELINE_NAMES)}")
