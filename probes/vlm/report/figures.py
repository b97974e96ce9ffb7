"""PNG figures of the report tables: :class:`matplotlib.figure.Figure` objects saved directly (no pyplot, no
backend switching -- a report can run inside a notebook or a training process without touching its
plotting state). One function per analysis; each takes a table's ``plot`` data and a path."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.figure import Figure

CHANCE = 0.25
DPI = 120


def _save(fig: Figure, path: Path) -> Path:
    fig.savefig(path, dpi=DPI, bbox_inches="tight")
    return path


def per_category(plot: dict[str, Any], path: Path) -> Path:
    models, cats = plot["models"], plot["categories"]
    fig = Figure(figsize=(max(6.0, 1.4 * len(cats) + 0.3 * len(models) * len(cats) / 2), 4.0))
    ax = fig.add_subplot()
    width = 0.8 / max(1, len(models))
    x = np.arange(len(cats))
    for k, m in enumerate(models):
        acc = [plot["acc"][m].get(c, math.nan) for c in cats]
        ci = [plot["ci"][m].get(c) for c in cats]
        err = np.array([[a - c[0], c[1] - a] if c else [0.0, 0.0] for a, c in zip(acc, ci, strict=True)]).T
        ax.bar(x + (k - (len(models) - 1) / 2) * width, acc, width, yerr=err, capsize=2, label=m)
        best = [plot["baselines"][m].get(c, math.nan) for c in cats]
        ax.scatter(x + (k - (len(models) - 1) / 2) * width, best, marker="_", color="black", s=80, zorder=3)
    ax.axhline(CHANCE, color="grey", linestyle="--", linewidth=1, label="chance")
    ax.set_xticks(x, [c.replace("_", "\n") for c in cats], fontsize=8)
    ax.set_ylim(0, 1)
    ax.set_ylabel("macro accuracy (strict)")
    ax.set_title("Per category (bars: 95 % CI; black ticks: best constant letter)", fontsize=9)
    ax.legend(fontsize=7, ncol=2)
    return _save(fig, path)


def heatmap(plot: dict[str, Any], path: Path) -> Path:
    models, subs, m = plot["models"], plot["subs"], plot["matrix"]
    fig = Figure(figsize=(max(6.0, 0.55 * len(subs) + 3), max(2.5, 0.35 * len(models) + 1.8)))
    ax = fig.add_subplot()
    im = ax.imshow(np.ma.masked_invalid(m), vmin=0, vmax=1, cmap="viridis", aspect="auto")
    ax.set_xticks(range(len(subs)), subs, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(models)), models, fontsize=7)
    for i in range(m.shape[0]):
        for j in range(m.shape[1]):
            if not math.isnan(m[i, j]):
                ax.text(
                    j,
                    i,
                    f"{m[i, j]:.2f}",
                    ha="center",
                    va="center",
                    fontsize=6,
                    color="white" if m[i, j] < 0.5 else "black",
                )
    fig.colorbar(im, ax=ax, label="macro accuracy (strict)")
    return _save(fig, path)


def size_scatter(plot: dict[str, Any], path: Path) -> Path:
    fig = Figure(figsize=(6.0, 4.0))
    ax = fig.add_subplot()
    pts = plot["points"]
    ax.scatter([p[1] for p in pts], [p[2] for p in pts], label="model")
    ax.scatter(
        [p[1] for p in pts],
        [p[3] for p in pts],
        marker="_",
        color="black",
        s=80,
        label="best constant letter",
    )
    for label, size, acc, _ in pts:
        ax.annotate(label, (size, acc), fontsize=6, xytext=(3, 3), textcoords="offset points")
    ax.axhline(CHANCE, color="grey", linestyle="--", linewidth=1, label="chance")
    if all(p[1] > 0 for p in pts):
        ax.set_xscale("log")
    ax.set_xlabel("model size (billions of parameters)")
    ax.set_ylabel("macro accuracy (strict)")
    ax.legend(fontsize=7)
    return _save(fig, path)


def binned_lines(
    plot: dict[str, list[tuple[str, float, float, float]]],
    path: Path,
    xlabel: str,
    ylabel: str = "share right (strict)",
    reference: float = CHANCE,
) -> Path:
    """One line per series (a model, or a category) over the bins (labels in order of first appearance),
    with error bars, and a dashed reference line (chance, or 0 for deltas)."""
    labels: list[str] = []
    for rows in plot.values():
        labels += [r[0] for r in rows if r[0] not in labels]
    fig = Figure(figsize=(max(6.0, 0.9 * len(labels) + 2), 4.0))
    ax = fig.add_subplot()
    offset = 0.25 / max(1, len(plot))
    for k, (model, rows) in enumerate(plot.items()):
        xs = [labels.index(r[0]) + (k - (len(plot) - 1) / 2) * offset for r in rows]
        ys = np.array([r[1] for r in rows])
        err = np.array([[r[1] - r[2], r[3] - r[1]] for r in rows]).T
        ax.errorbar(xs, ys, yerr=err, marker="o", capsize=2, label=model)
    ax.axhline(reference, color="grey", linestyle="--", linewidth=1)
    ax.set_xticks(range(len(labels)), labels, rotation=30, ha="right", fontsize=7)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.legend(fontsize=7)
    return _save(fig, path)


def scatter_grid(plot: dict[str, dict[str, Any]], path: Path, benchmark: str) -> Path:
    """Category accuracy (y) against one benchmark's score (x), one panel per category (title: Pearson r)."""
    cats = list(plot)
    ncol = min(4, len(cats))
    nrow = math.ceil(len(cats) / ncol)
    fig = Figure(figsize=(3.2 * ncol, 2.8 * nrow))
    for k, cat in enumerate(cats):
        ax = fig.add_subplot(nrow, ncol, k + 1)
        pts, r = plot[cat]["points"], plot[cat]["r"]
        ax.scatter([p[1] for p in pts], [p[2] for p in pts], s=14)
        for label, x, y in pts:
            ax.annotate(label, (x, y), fontsize=5, xytext=(2, 2), textcoords="offset points")
        ax.set_title(f"{cat} (n={len(pts)}, r={'–' if r is None else f'{r:.2f}'})", fontsize=8)
        ax.set_xlabel(benchmark, fontsize=7)
        ax.set_ylabel("accuracy", fontsize=7)
        ax.tick_params(labelsize=6)
    fig.tight_layout()
    return _save(fig, path)
