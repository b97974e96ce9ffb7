"""Question items -> :class:`~probes.vlm.interface.Prompt` (the evaluation protocol, docs/vqa_contract.md).

The text is :func:`newtphys.vqa_scoring.format_prompt` of the question and the option texts (an image
option is "image N", the N-th image shown, as in the exports); the images are the item's images, question
images first, then option images, as absolute paths.

Circular evaluation asks each item four times with its options rotated: rotation ``r`` shows the set's
option ``(k + r) % 4`` at letter ``k``; :func:`to_set_letter` maps a letter of the rotated prompt back to the
set's letter order.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

from newtphys import vqa_schema as vs
from newtphys import vqa_scoring
from newtphys.vqa_export import option_texts
from probes.vlm.interface import Prompt

ROTATIONS: tuple[int, ...] = (0, 1, 2, 3)
PROMPT_TEMPLATE_VERSION = "newtphys-vqa-prompt-v1"
"""Bump when the way a prompt is built changes without the template text changing (image order ...)."""


def rotate(options: tuple[str, ...] | list[str], rotation: int) -> tuple[str, str, str, str]:
    """The options in the letter order of ``rotation``: letter ``k`` shows the set's option ``(k + r) % 4``."""
    if rotation not in ROTATIONS:
        raise ValueError(f"rotation must be one of {list(ROTATIONS)}, got {rotation!r}")
    n = len(vs.LETTERS)
    return tuple(options[(k + rotation) % n] for k in range(n))  # type: ignore[return-value]


def to_set_letter(letter: str | None, rotation: int) -> str | None:
    """A letter of the prompt of ``rotation`` -> the letter of the same option in the set's order."""
    if letter is None:
        return None
    return vs.LETTERS[(vs.LETTERS.index(letter) + rotation) % len(vs.LETTERS)]


def to_prompt_letter(set_letter: str, rotation: int) -> str:
    """The set's letter -> the letter that option has in the prompt of ``rotation`` (inverse of the above)."""
    return vs.LETTERS[(vs.LETTERS.index(set_letter) - rotation) % len(vs.LETTERS)]


def build_prompt(item: vs.QuestionItem, set_dir: Path | str, rotation: int = 0) -> Prompt:
    """The prompt of ``item`` (images resolved against ``set_dir``) with its options rotated ``rotation``."""
    set_dir = Path(set_dir).resolve()
    options = rotate(option_texts(item), rotation)
    return Prompt(idx=item.idx, images=tuple(set_dir / p for p in item.images),
                  text=vqa_scoring.format_prompt(item.question, options), options=options,
                  rotation=rotation)  # fmt: skip


def prompt_template_sha256() -> str:
    """SHA-256 of the protocol's prompt with placeholders (question, four options, instruction) and its
    version: two runs with the same hash prompted every item with the same text."""
    template = vqa_scoring.format_prompt("{question}", ["{A}", "{B}", "{C}", "{D}"])
    return hashlib.sha256(f"{PROMPT_TEMPLATE_VERSION}\n{template}".encode()).hexdigest()


def file_sha256(path: Path | str, chunk_bytes: int = 1 << 20) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_bytes):
            h.update(chunk)
    return h.hexdigest()


def question_set_sha256(set_dir: Path | str) -> str:
    """SHA-256 of the set's ``questions.jsonl`` bytes (RunManifest.question_set_sha256)."""
    return file_sha256(Path(set_dir) / vs.QUESTIONS_FILE)


def resolve_set_dir(vqa_dir: Path | str, split: str | None = None) -> Path:
    """The directory holding ``questions.jsonl``: ``vqa_dir`` itself, else ``vqa_dir/<split>``; a clear error
    naming both when neither holds one."""
    vqa_dir = Path(vqa_dir)
    candidates: Iterable[Path] = [vqa_dir] + ([vqa_dir / split] if split else [])
    for c in candidates:
        if (c / vs.QUESTIONS_FILE).is_file():
            return c
    tried = ", ".join(str(c / vs.QUESTIONS_FILE) for c in candidates)
    raise FileNotFoundError(f"vqa_dir={str(vqa_dir)!r}: no question set found (tried {tried}); point vqa_dir at "
                            "a split directory written by generate_vqa.py, e.g. vqa_dir=data/vqa/test")  # fmt: skip
