"""Optional W&B logging of a report, like the probing runs (``newtphys/conf/logger/wandb.yaml``): one W&B run
of ``job_type="vlm_report"``, the headline numbers as summary values, every table as a ``wandb.Table`` and
every PNG as an image. ``mode="offline"`` (or ``WANDB_MODE=offline``) writes the run files locally."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from probes.vlm.report.tables import Table


def log_report(
    tables: Sequence[Table],
    summary: dict[str, Any],
    out: Path,
    project: str = "newtphys-vlm",
    mode: str | None = None,
    name: str | None = None,
) -> str:
    """Log to W&B; returns the run's local directory."""
    import wandb

    run = wandb.init(
        project=project,
        job_type="vlm_report",
        name=name,
        dir=str(out),
        mode=mode or os.environ.get("WANDB_MODE", "online"),
        config={"models": sorted(summary)},
    )
    try:
        for label, s in summary.items():
            for key in ("strict", "lenient", "rotation0"):
                if s.get(key) is not None:
                    run.summary[f"{label}/{key}"] = s[key]
            run.summary[f"{label}/constant_letter"] = s["baselines"]["constant_letter"]
        for t in tables:
            if t.rows:
                run.log(
                    {
                        f"table/{t.name}": wandb.Table(
                            columns=t.columns, data=[[_cell(v) for v in r] for r in t.rows]
                        )
                    }
                )
        for png in sorted(out.glob("*.png")):
            run.log({f"figure/{png.stem}": wandb.Image(str(png))})
        return str(run.dir)
    finally:
        run.finish()


def _cell(v: Any) -> Any:
    return "" if v is None else v
