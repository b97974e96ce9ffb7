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


def stats_panel(set_dir: Path | str, out_png: Path | str) -> Path:
    """A question set at a glance: items per category and sub-category, letter shares, objects per question
    and the blind-prior audit (best text-only accuracy per question id against chance)."""
    set_dir, out_png = Path(set_dir), Path(out_png)
    items = vs.read_items(set_dir)
    answers = vs.read_answers(set_dir)
    manifest = vs.read_manifest(set_dir) if (set_dir / vs.MANIFEST_FILE).is_file() else {}
    fig = Figure(figsize=(15, 9))
    axes = fig.subplots(2, 3).ravel()

    def bars(ax, counts: dict[str, float], title: str, horizontal: bool = False, line: float | None = None) -> None:
        names, values = list(counts), list(counts.values())
        if horizontal:
            ax.barh(names, values, color="#4477aa")
            ax.tick_params(axis="y", labelsize=6)
            if line is not None:
                ax.axvline(line, color="red", lw=1)
        else:
            ax.bar(names, values, color="#4477aa")
            ax.tick_params(axis="x", labelrotation=45, labelsize=7)
            if line is not None:
                ax.axhline(line, color="red", lw=1)
        ax.set_title(title, fontsize=10)

    def counts_of(values) -> dict[str, int]:
        out: dict[str, int] = {}
        for v in values:
            out[str(v)] = out.get(str(v), 0) + 1
        return dict(sorted(out.items()))

    bars(axes[0], counts_of(i.category for i in items), "items per category")
    bars(axes[1], counts_of(i.sub_category for i in items), "items per sub-category", horizontal=True)
    letters = counts_of(answers[i.idx].answer for i in items)
    bars(axes[2], {k: v / max(len(items), 1) for k, v in letters.items()}, "share of each answer letter",
         line=1.0 / len(vs.LETTERS))
    by_objects = counts_of(i.meta.get("num_objects") for i in items)
    bars(axes[3], dict(sorted(by_objects.items(), key=lambda kv: int(kv[0]))), "items by objects in the scene")
    bars(axes[4], counts_of(i.mode for i in items), "items per mode")
    blind = manifest.get("blind_prior", {})
    bars(axes[5], {q.removeprefix("F_")[:34]: r["best_accuracy"] for q, r in sorted(blind.items())},
         "blind prior: best text-only accuracy (red: chance)", horizontal=True, line=1.0 / len(vs.LETTERS))
    fig.suptitle(f"{set_dir}: {len(items)} items, {len({i.question_id for i in items})} question ids", fontsize=11)
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=100)
    return out_png
