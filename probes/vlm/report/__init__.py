"""The report of scored VLM runs (``python -m probes.vlm_report RESULTS... --out DIR``): ``report.md``, one CSV
per analysis and PNG figures (:mod:`.analyses`, :mod:`.figures`, :mod:`.tables`, :mod:`.loading`)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from probes.vlm.report import analyses, figures
from probes.vlm.report.loading import Run
from probes.vlm.report.tables import Table

REPORT_FILE = "report.md"


def build_tables(
    runs: Sequence[Run],
    benchmarks: dict[str, dict[str, float]] | None = None,
    n_boot: int = 1000,
    seed: int = 0,
    size_edges: Sequence[float] = analyses.DEFAULT_SIZE_EDGES_B,
    young_log10_edges: Sequence[float] = analyses.DEFAULT_YOUNG_LOG10_EDGES,
    rank_bin: int = 10,
) -> list[Table]:
    tables = [
        analyses.per_category(runs),
        analyses.subcategory_heatmap(runs),
        analyses.by_model_rank(runs, rank_bin),
        analyses.by_model_size(runs, size_edges),
        analyses.by_meta_bins(
            runs,
            "young_modulus_pa",
            "by_young_modulus",
            "Accuracy by Young's modulus of the asked object",
            young_log10_edges,
            log10=True,
            n_boot=n_boot,
            seed=seed,
        ),
        analyses.by_meta_bins(
            runs,
            "num_objects",
            "by_num_objects",
            "Accuracy by number of objects in the scene",
            None,
            n_boot=n_boot,
            seed=seed,
        ),
    ]
    tables += [analyses.variant_deltas(runs, g, n_boot, seed) for g in analyses.VARIANT_GROUPS]
    if benchmarks is not None:
        tables.append(analyses.correlation(runs, benchmarks))
    else:
        tables.append(
            analyses.not_enough(
                "correlation",
                "Correlation with common-sense benchmarks",
                ["benchmark", "category", "n_models", "pearson_r", "p_value", "models"],
                "no benchmark CSV given (--benchmarks, columns model, <benchmark>...)",
            )
        )
    return tables


def _figure(t: Table, out: Path) -> list[Path]:
    if t.plot is None:
        return []
    if t.name == "per_category":
        return [figures.per_category(t.plot, out / "per_category.png")]
    if t.name == "subcategory_heatmap":
        return [figures.heatmap(t.plot, out / "subcategory_heatmap.png")]
    if t.name == "by_model_rank":
        return [
            figures.binned_lines(t.plot, out / f"{t.name}.png", "model rank bin", "macro accuracy (strict)")
        ]
    if t.name == "by_model_size":
        return [figures.size_scatter(t.plot, out / "by_model_size.png")]
    if t.name == "by_young_modulus":
        return [figures.binned_lines(t.plot, out / f"{t.name}.png", "Young's modulus of the asked object")]
    if t.name == "by_num_objects":
        return [figures.binned_lines(t.plot, out / f"{t.name}.png", "objects in the scene")]
    if t.name.startswith("delta_"):
        return [
            figures.binned_lines(t.plot, out / f"{t.name}.png", "variant", "delta vs base (share right)", 0.0)
        ]
    if t.name == "correlation":
        return [
            figures.scatter_grid(pts, out / f"correlation_{_safe(b)}.png", b) for b, pts in t.plot.items()
        ]
    return []


MIN_SEQUENCES_FOR_CI = 10
"""Below this many sequences the report warns that its bootstrap intervals are not to be relied on."""


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_" else "_" for c in name)


def write_report(runs: Sequence[Run], out: Path, tables: Sequence[Table]) -> dict[str, Any]:
    """``report.md``, ``<table>.csv`` per table, the PNGs and ``summary.json`` (per model headline numbers)."""
    out.mkdir(parents=True, exist_ok=True)
    intro = (
        "Strict extraction (a letter A-D alone or at the end of the reply) is the paper's number; lenient "
        "(option text matched) is reported apart. Missing predictions count as wrong. Intervals: 95 % "
        "bootstrap over sequences. Rule `circular`: the run asked every item four times with its options rotated "
        "and an item is right only if all four are (the rotation-0 number, the paper's, is `rotation0` in "
        "summary.json)."
    )
    header = (
        "| model | items | coverage | strict | 95 % CI | lenient | best constant letter | text prior | weights "
        "| rule |"
    )
    parts = ["# VLM evaluation report", "", intro, "", header, "|---|---|---|---|---|---|---|---|---|---|"]
    few = sorted({int(r.scores["strict"].get("n_sequences") or 0) for r in runs
                  if int(r.scores["strict"].get("n_sequences") or 0) < MIN_SEQUENCES_FOR_CI})  # fmt: skip
    if few:
        parts[4:4] = [
            f"**Warning:** some runs cover only {', '.join(map(str, few))} sequence(s); a bootstrap over fewer than "
            f"{MIN_SEQUENCES_FOR_CI} sequences is not a confidence interval to rely on (a macro mean over few "
            "sequences can even sit at the edge of its own interval).",
            "",
        ]
    summary: dict[str, Any] = {}
    for run in runs:
        s = run.scores
        ci = (s["strict"].get("ci") or {}).get("overall")
        cov = s["coverage"]
        weights = (run.manifest.get("model") or {}).get("weights", "?")
        details = s["baseline_details"]
        prior = details["text_prior"].get("overall")
        parts.append(
            f"| {run.label} | {cov['items']} | {cov['predicted']}/{cov['items']} | {s['strict']['overall']:.3f} | "
            + (f"[{ci[0]:.3f}, {ci[1]:.3f}]" if ci else "–")
            + f" | {s['lenient']['overall']:.3f} | {details['constant_letter']['overall']:.3f} "
            f"({details['constant_letter']['letter'] or '–'}) | "
            + ("–" if prior is None else f"{prior:.3f}")
            + f" | {weights} | {'circular' if s['circular'] else 'rotation 0'} |"
        )
        summary[run.label] = {
            "run_dir": str(run.run_dir),
            "strict": s["strict"]["overall"],
            "ci": ci,
            "lenient": s["lenient"]["overall"],
            "coverage": cov,
            "params_b": run.params_b,
            "baselines": {
                "chance": details["chance"],
                "constant_letter": details["constant_letter"]["overall"],
                "text_prior": prior,
            },
            "best_trivial": s["best_trivial"],
            "circular": s["circular"],
            "rotation0": None if s["rotation0"] is None else s["rotation0"]["strict"]["overall"],
        }
    parts.append("")
    files: list[str] = []
    for t in tables:
        csv_path = t.write_csv(out)
        pngs = _figure(t, out)
        files += [csv_path.name, *(p.name for p in pngs)]
        parts.append(t.markdown(pngs[0].name if pngs else None))
        parts += [f"![{p.stem}]({p.name})\n" for p in pngs[1:]]
    (out / REPORT_FILE).write_text("\n".join(parts))
    (out / "summary.json").write_text(json.dumps(summary, indent=2, sort_keys=True))
    return {
        "report": str(out / REPORT_FILE),
        "files": [REPORT_FILE, "summary.json", *files],
        "summary": summary,
    }
