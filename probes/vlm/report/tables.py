"""A result table of the report (one analysis): columns, rows, and a note when there is nothing to show;
written as CSV and Markdown."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

NOT_ENOUGH = "not enough items"


@dataclass
class Table:
    name: str
    """File stem: ``<name>.csv`` (and ``<name>.png`` when plotted)."""
    title: str
    columns: list[str]
    rows: list[list[Any]] = field(default_factory=list)
    note: str = ""
    """Shown under the title: how the numbers were made, or why there are none ("not enough items: ...")."""
    plot: Any = None
    """Data for the figure (analysis-specific), None: no figure."""

    @property
    def empty(self) -> bool:
        return not self.rows

    def write_csv(self, out_dir: Path) -> Path:
        path = out_dir / f"{self.name}.csv"
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(self.columns)
            for row in self.rows:
                w.writerow(["" if v is None else (f"{v:.6g}" if isinstance(v, float) else v) for v in row])
        return path

    def markdown(self, figure: str | None = None) -> str:
        lines = [f"## {self.title}", ""]
        if self.note:
            lines += [self.note, ""]
        if self.rows:
            lines.append("| " + " | ".join(self.columns) + " |")
            lines.append("|" + "|".join("---" for _ in self.columns) + "|")
            lines += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in self.rows]
            lines.append("")
        if figure:
            lines += [f"![{self.title}]({figure})", ""]
        return "\n".join(lines)


def fmt(v: Any) -> str:
    if v is None:
        return "–"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.3f}"
    return str(v)


def not_enough(name: str, title: str, columns: list[str], why: str) -> Table:
    return Table(name, title, columns, [], f"**{NOT_ENOUGH}**: {why}")
