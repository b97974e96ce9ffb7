"""Results table of finished probing runs: ``python -m probes.report RUNS_DIR [--out DIR]``.

Gathers every ``metrics.json`` under RUNS_DIR (one per run / multirun job,
written by :func:`probes.run.run`), and writes the table researchers publish:

* rows: one per (backbone, weights, decoder), grouped by supervision type;
  a backbone run with random weights is labelled ``(random)``; when one
  backbone was run with several tapped-layer sets, the layers join the label;
* trivial baselines (``baselines`` of each run's metrics.json,
  :mod:`probes.baselines`) are rows of their own, first, under
  ``trivial baseline``: what a predictor that never looks at the pixels scores
  on the same targets;
* columns: Collision F1, Gravity mAE (deg) / magE (N), Gravity-OOD mAE / magE,
  Scene Flow AEE (m) -- all on the test splits. A probe's cell also shows its
  skill over the best trivial baseline of that split and metric (``skill`` of
  metrics.json: 0 = as good as the best baseline, 1 = perfect) and is marked
  ``✗`` when the skill is not above 0 -- the probe does not beat a constant;
* several runs of one cell (e.g. seeds) are averaged; ``runs`` counts them.

Outputs ``results.md``, ``results.csv`` (values and skills in separate
columns) and a colour-graded ``results.png`` (per column: green = best, red =
worst, direction from the metric).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from probes.baselines import BASELINE_LABELS
from probes.run import METRICS_FILENAME


@dataclass(frozen=True)
class Column:
    title: str
    task: str
    split: str
    metric: str
    higher_is_better: bool
    fmt: str


COLUMNS: tuple[Column, ...] = (
    Column("Collision F1", "collision", "test", "collision_f1", True, "{:.3f}"),
    Column("Gravity mAE (deg)", "gravity", "test", "gravity_angular_error_deg", False, "{:.2f}"),
    Column("Gravity magE (N)", "gravity", "test", "gravity_magnitude_error_n", False, "{:.3f}"),
    Column(
        "Gravity-OOD mAE (deg)", "gravity", "test_ood_gravity", "gravity_angular_error_deg", False, "{:.2f}"
    ),
    Column(
        "Gravity-OOD magE (N)", "gravity", "test_ood_gravity", "gravity_magnitude_error_n", False, "{:.3f}"
    ),
    Column("Scene Flow AEE (m)", "scene_flow", "test", "scene_flow_epe_m", False, "{:.4f}"),
)
BASELINE_GROUP = "trivial baseline"
NOT_BEATEN = "✗"
SUPERVISION_ORDER: tuple[str, ...] = (
    BASELINE_GROUP,
    "self-supervised",
    "language-supervised",
    "supervised",
    "segmentation",
    "depth",
    "distillation",
    "generative",
    "none",
    "unknown",
)


@dataclass
class Row:
    supervision: str
    backbone: str
    decoder: str
    values: dict[str, float | None]
    runs: int
    skills: dict[str, float | None] | None = None
    """Column title -> mean skill over the best trivial baseline (None for baseline rows)."""

    @property
    def is_baseline(self) -> bool:
        return self.supervision == BASELINE_GROUP


def load_runs(runs_dir: str | Path) -> list[dict[str, Any]]:
    """Every finished run's metrics.json under ``runs_dir`` (recursive), sorted by path."""
    runs_dir = Path(runs_dir)
    if not runs_dir.is_dir():
        raise FileNotFoundError(f"runs directory {str(runs_dir)!r} does not exist")
    out = []
    for path in sorted(runs_dir.rglob(METRICS_FILENAME)):
        data = json.loads(path.read_text())
        if data.get("status") == "finished":
            data["_path"] = str(path)
            out.append(data)
    return out


def _label(run: dict[str, Any], show_layers: bool) -> str:
    name = str(run.get("backbone", "?"))
    if show_layers:
        name += " [" + ",".join(str(i) for i in run.get("backbone_layers", [])) + "]"
    return name if run.get("backbone_pretrained", True) else f"{name} (random)"


def _mean(values: list[float] | None) -> float | None:
    return sum(values) / len(values) if values else None


def _finite(value: Any) -> bool:
    return value is not None and math.isfinite(value)


def build_rows(runs: list[dict[str, Any]]) -> list[Row]:
    """Aggregate runs into table rows (mean over runs of the same backbone, weights and decoder), plus one
    row per trivial baseline (mean over the runs that scored it)."""
    cells: dict[tuple[str, str, str], dict[str, list[float]]] = {}
    skills: dict[tuple[str, str, str], dict[str, list[float]]] = {}
    counts: dict[tuple[str, str, str], set[str]] = {}
    layer_sets: dict[str, set[tuple[int, ...]]] = {}
    for run in runs:
        layer_sets.setdefault(str(run.get("backbone")), set()).add(tuple(run.get("backbone_layers", [])))
    for run in runs:
        show_layers = len(layer_sets[str(run.get("backbone"))]) > 1  # tapped layers differ between runs
        key = (str(run.get("supervision", "unknown")), _label(run, show_layers), str(run.get("decoder", "?")))
        cells.setdefault(key, {})
        skills.setdefault(key, {})
        counts.setdefault(key, set()).add(run["_path"])
        for col in COLUMNS:
            if run.get("task") != col.task:
                continue
            value = (run.get(col.split) or {}).get(col.metric)
            if _finite(value):
                cells[key].setdefault(col.title, []).append(float(value))
            sk = ((run.get("skill") or {}).get(col.split) or {}).get(col.metric)
            if _finite(sk):
                skills[key].setdefault(col.title, []).append(float(sk))
            for name, by_metric in ((run.get("baselines") or {}).get(col.split) or {}).items():
                bkey = (BASELINE_GROUP, BASELINE_LABELS.get(name, name), "-")
                b = (by_metric or {}).get(col.metric)
                if _finite(b):
                    cells.setdefault(bkey, {}).setdefault(col.title, []).append(float(b))
                    counts.setdefault(bkey, set()).add(run["_path"])

    def order(key: tuple[str, str, str]) -> tuple[int, str, str]:
        sup = key[0]
        rank = SUPERVISION_ORDER.index(sup) if sup in SUPERVISION_ORDER else len(SUPERVISION_ORDER)
        return (rank, key[1], key[2])

    rows = []
    for key in sorted(cells, key=order):
        values = {c.title: _mean(cells[key].get(c.title)) for c in COLUMNS}
        row_skills = (
            None if key[0] == BASELINE_GROUP else {c.title: _mean(skills[key].get(c.title)) for c in COLUMNS}
        )
        rows.append(Row(key[0], key[1], key[2], values, len(counts[key]), row_skills))
    return rows


def _fmt(col: Column, value: float | None) -> str:
    return "-" if value is None else col.fmt.format(value)


def _cell(row: Row, col: Column) -> str:
    """The value; for a probe also its skill over the best trivial baseline, marked when not above 0."""
    text = _fmt(col, row.values[col.title])
    sk = None if row.skills is None else row.skills.get(col.title)
    if row.values[col.title] is None or sk is None:
        return text
    return f"{text} ({sk:+.2f})" + (f" {NOT_BEATEN}" if sk <= 0 else "")


def to_markdown(rows: list[Row]) -> str:
    header = ["Supervision", "Backbone", "Decoder", *[c.title for c in COLUMNS], "runs"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    last_sup = None
    for r in rows:
        sup = r.supervision if r.supervision != last_sup else ""
        last_sup = r.supervision
        cells = [sup, r.backbone, r.decoder, *[_cell(r, c) for c in COLUMNS], str(r.runs)]
        lines.append("| " + " | ".join(cells) + " |")
    arrows = ", ".join(f"{c.title} {'higher' if c.higher_is_better else 'lower'} is better" for c in COLUMNS)
    return (
        "\n".join(lines)
        + f"\n\nTest splits; {arrows}. In brackets: skill over the best trivial baseline of the split and "
        + f"metric, (probe - best) / (perfect - best); {NOT_BEATEN} = no better than a predictor that never "
        + "looks at the pixels.\n"
    )


def write_csv(rows: list[Row], path: Path) -> None:
    def num(v: float | None) -> str:
        return "" if v is None else repr(v)

    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(
            ["supervision", "backbone", "decoder", *[c.title for c in COLUMNS],
             *[f"{c.title} skill" for c in COLUMNS], "runs"]
        )
        for r in rows:
            w.writerow(
                [
                    r.supervision,
                    r.backbone,
                    r.decoder,
                    *[num(r.values[c.title]) for c in COLUMNS],
                    *[num(None if r.skills is None else r.skills.get(c.title)) for c in COLUMNS],
                    r.runs,
                ]
            )


def column_grades(rows: list[Row]) -> dict[str, list[float | None]]:
    """Per column, each row's grade in [0, 1] (1 = best of the column, 0 = worst; None = missing)."""
    grades: dict[str, list[float | None]] = {}
    for c in COLUMNS:
        vals = [r.values[c.title] for r in rows]
        present = [v for v in vals if v is not None]
        if not present:
            grades[c.title] = [None] * len(rows)
            continue
        lo, hi = min(present), max(present)
        span = hi - lo
        g = []
        for v in vals:
            if v is None:
                g.append(None)
            elif span == 0:
                g.append(1.0)
            else:
                t = (v - lo) / span
                g.append(t if c.higher_is_better else 1.0 - t)
        grades[c.title] = g
    return grades


def write_png(rows: list[Row], path: Path) -> None:
    import matplotlib
    from matplotlib.figure import Figure  # no pyplot: writing a table switches no backend

    cmap = matplotlib.colormaps["RdYlGn"]
    grades = column_grades(rows)
    header = ["Supervision", "Backbone", "Decoder", *[c.title for c in COLUMNS]]
    text = [[r.supervision, r.backbone, r.decoder, *[_cell(r, c) for c in COLUMNS]] for r in rows]
    colours = [
        ["white"] * 3
        + [
            "#eeeeee" if grades[c.title][i] is None else cmap(0.15 + 0.7 * grades[c.title][i])
            for c in COLUMNS
        ]
        for i in range(len(rows))
    ]
    fig = Figure(figsize=(2 + 1.6 * len(header), 0.8 + 0.4 * max(1, len(rows))))
    ax = fig.subplots()
    ax.axis("off")
    if rows:
        table = ax.table(cellText=text, cellColours=colours, colLabels=header, loc="center", cellLoc="center")
        table.auto_set_font_size(False)
        table.set_fontsize(8)
        table.scale(1.0, 1.4)
    ax.set_title(
        f"NewtPhys probes (test splits; green = best per column; (skill over best trivial baseline), "
        f"{NOT_BEATEN} = not above it)",
        fontsize=10,
    )
    fig.savefig(path, dpi=150, bbox_inches="tight")


def make_report(runs_dir: str | Path, out_dir: str | Path | None = None) -> dict[str, Path]:
    """Write results.md / .csv / .png for the runs under ``runs_dir``; returns the paths."""
    runs = load_runs(runs_dir)
    if not runs:
        raise FileNotFoundError(
            f"no finished runs ({METRICS_FILENAME} with status 'finished') under {runs_dir}"
        )
    rows = build_rows(runs)
    out = Path(out_dir) if out_dir is not None else Path(runs_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"md": out / "results.md", "csv": out / "results.csv", "png": out / "results.png"}
    paths["md"].write_text(to_markdown(rows))
    write_csv(rows, paths["csv"])
    write_png(rows, paths["png"])
    return paths


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "runs_dir", help="directory holding run folders with metrics.json (searched recursively)"
    )
    parser.add_argument("--out", default=None, help="output directory (default: RUNS_DIR)")
    args = parser.parse_args(argv)
    try:
        paths = make_report(args.runs_dir, args.out)
    except FileNotFoundError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(paths["md"].read_text())
    print(f"written: {', '.join(str(p) for p in paths.values())}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
