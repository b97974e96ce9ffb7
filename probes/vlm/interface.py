"""The contract between the question set, the answerers and the results on disk.

An *answerer* (a Hugging Face VLM, a model behind an OpenAI-compatible server, a baseline) turns a batch of
:class:`Prompt` into one :class:`Generation` each. The evaluation loop writes one
:class:`PredictionRecord` per (item, rotation) to ``predictions.jsonl`` of a run directory and a
``manifest.json`` beside it; scoring and reports read only those files and the set's ``answers.jsonl``.

Run directory layout (one model on one question set)::

    <run_dir>/manifest.json       RunManifest (model id and revision, dtype, weights, prompt and set hashes)
    <run_dir>/predictions.jsonl   one PredictionRecord per line, appended and flushed per batch
    <run_dir>/scores.json         strict and lenient macro accuracy with bootstrap CIs, beside the baselines
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol, runtime_checkable

MANIFEST_FILE = "manifest.json"
PREDICTIONS_FILE = "predictions.jsonl"
SCORES_FILE = "scores.json"


@dataclass(frozen=True)
class Prompt:
    """What one item shows a model: images first (absolute paths, in order), then the text."""

    idx: str
    """The item's ``idx`` in the question set."""
    images: tuple[Path, ...]
    text: str
    """The full text after the images: question, options "A. ...", answer instruction."""
    options: tuple[str, str, str, str]
    """Option texts in the letter order of this prompt (for lenient extraction and baselines)."""
    rotation: int = 0
    """0 for the set's letter order; 1-3 when options are rotated (circular evaluation)."""


@dataclass(frozen=True)
class Generation:
    """One answerer reply."""

    text: str
    latency_s: float
    """Wall time of the batch that produced it divided by the batch size, s."""
    tokens_in: int | None = None
    tokens_out: int | None = None


@runtime_checkable
class Answerer(Protocol):
    """Anything that answers prompts. ``name`` names it in results; ``describe`` goes into the manifest
    (model id, revision, dtype, weights ``pretrained`` / ``random`` / ``none`` ...)."""

    name: str

    def describe(self) -> dict[str, Any]: ...

    def answer(self, prompts: list[Prompt]) -> list[Generation]: ...


@dataclass(frozen=True)
class PredictionRecord:
    """One line of ``predictions.jsonl``."""

    idx: str
    rotation: int
    raw: str
    letter: str | None
    """Strict extraction (the paper's rule), in the set's letter order; None when nothing is extracted."""
    letter_lenient: str | None
    """Lenient extraction (strict, else the option text matched), in the set's letter order."""
    latency_s: float
    tokens_in: int | None = None
    tokens_out: int | None = None

    def to_json(self) -> str:
        return json.dumps(asdict(self), sort_keys=False)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> PredictionRecord:
        return PredictionRecord(**{k: d.get(k) for k in PredictionRecord.__dataclass_fields__})


@dataclass(frozen=True)
class RunManifest:
    """``manifest.json`` of a run directory; a run refuses to append to predictions of a different set,
    prompt template or model."""

    answerer: str
    model: dict[str, Any]
    """``Answerer.describe()``: id, revision, dtype, weights, ..."""
    vqa_dir: str
    split: str
    question_set_sha256: str
    """SHA-256 of the set's ``questions.jsonl`` bytes."""
    prompt_template_sha256: str
    circular: bool = False
    extra: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        return json.dumps(asdict(self), indent=2, sort_keys=True)
