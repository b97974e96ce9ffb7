"""Contact sheet of sample questions: their images, the question, the options, the correct one marked.
``python -m newtphys view-vqa DIR --out sheet.png``."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from PIL import Image

from newtphys import vqa_schema as vs

MAX_IMAGES = 4
"""Images drawn per item: the question's last images, then the option images."""


def sample_items(items: list[vs.QuestionItem], count: int, seed: int) -> list[vs.QuestionItem]:
    """``count`` items, one question id after another (seeded), so a sheet shows many kinds of question."""
    rng = np.random.default_rng(seed)
    by_qid: dict[str, list[vs.QuestionItem]] = {}
    for item in sorted(items, key=lambda i: i.idx):
        by_qid.setdefault(item.question_id, []).append(item)
    qids = [q for q in sorted(by_qid)]
    order = [qids[int(i)] for i in rng.permutation(len(qids))]
    picked = [by_qid[q][int(rng.integers(len(by_qid[q])))] for q in order]
    return picked[:count]


def contact_sheet(set_dir: Path | str, out_png: Path | str, count: int = 12, seed: int = 0) -> Path:
    set_dir, out_png = Path(set_dir), Path(out_png)
    items = sample_items(vs.read_items(set_dir), count, seed)
    answers = vs.read_answers(set_dir)
    fig = Figure(figsize=(4 * MAX_IMAGES * 0.55 + 6, 2.2 * len(items) + 0.5))
    grid = fig.add_gridspec(max(len(items), 1), MAX_IMAGES + 2)
    for row, item in enumerate(items):
        n_options = sum(o == vs.IMAGE_OPTION for o in item.options)
        question_images = list(item.images[: len(item.images) - n_options])
        shown = (question_images[-(MAX_IMAGES - min(n_options, 2)):] + list(item.images[len(question_images):]))
        for col, path in enumerate(shown[:MAX_IMAGES]):
            ax = fig.add_subplot(grid[row, col])
            ax.imshow(np.asarray(Image.open(set_dir / path)))
            ax.set_xticks([])
            ax.set_yticks([])
            is_option = col >= len(shown) - n_options
            if is_option:
                letter = vs.LETTERS[col - (len(shown) - n_options)]
                correct = letter == answers[item.idx].answer
                ax.set_title(f"option {letter}", fontsize=7, color="green" if correct else "black")
            elif col == len(shown) - n_options - 1:
                ax.set_title(f"frame {item.frames[-1]} (last)", fontsize=7)
        text_ax = fig.add_subplot(grid[row, MAX_IMAGES:])
        text_ax.axis("off")
        answer = answers[item.idx].answer
        lines = [f"{item.question_id} ({item.mode}, {item.sequence_id})", *textwrap.wrap(item.question, 60)]
        text_ax.text(0.0, 1.0, "\n".join(lines), va="top", fontsize=7, transform=text_ax.transAxes)
        for k, (letter, option) in enumerate(zip(vs.LETTERS, item.options)):
            mark = "✔ " if letter == answer else "   "
            text_ax.text(0.0, 0.45 - 0.13 * k, f"{mark}{letter}. {option}", fontsize=7, transform=text_ax.transAxes,
                         color="green" if letter == answer else "black",
                         fontweight="bold" if letter == answer else "normal")  # fmt: skip
    fig.suptitle(f"{set_dir}: {len(items)} sample questions (correct option in green)", fontsize=9)
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    return out_png
