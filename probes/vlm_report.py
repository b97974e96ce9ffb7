"""Report of VLM runs: ``python -m probes.vlm_report RESULTS... --out DIR``.

RESULTS are run directories (``manifest.json`` + ``predictions.jsonl``, :mod:`probes.vlm.interface`) or folders
searched for them. Each run is scored against its question set (the manifest's ``<vqa_dir>/<split>``, or
``--set-dir``) and the paper's analyses are written to DIR: ``report.md``, one CSV per analysis, PNG figures
and ``summary.json`` (:mod:`probes.vlm.report`). Model sizes come from the model record (``params_b``) or
``--sizes CSV`` (columns ``model, params_b``); common-sense benchmark scores from ``--benchmarks CSV``
(columns ``model, <benchmark>, ...``; ``model`` matches a run's label, answerer name or model id).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from probes.vlm.report import build_tables, write_report
from probes.vlm.report.analyses import DEFAULT_SIZE_EDGES_B, DEFAULT_YOUNG_LOG10_EDGES
from probes.vlm.report.loading import load_runs, read_model_csv


def _edges(text: str, name: str) -> list[float]:
    try:
        edges = [float(v) for v in text.split(",")]
    except ValueError:
        raise SystemExit(f"error: {name}={text!r}: a comma-separated list of numbers") from None
    if len(edges) < 2 or sorted(edges) != edges:
        raise SystemExit(f"error: {name}={text!r}: at least two increasing edges")
    return edges


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m probes.vlm_report", description=__doc__.splitlines()[0])
    p.add_argument("results", nargs="+", type=Path, help="run directories or folders holding them")
    p.add_argument("--out", required=True, type=Path)
    p.add_argument("--set-dir", type=Path, default=None, help="question set split (default: each manifest's)")
    p.add_argument("--sizes", type=Path, default=None, help="CSV: model, params_b (billions of parameters)")
    p.add_argument("--benchmarks", type=Path, default=None, help="CSV: model, <benchmark>...")
    p.add_argument("--n-boot", type=int, default=1000, help="bootstrap replicates (0: no intervals)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument(
        "--size-bins",
        default=",".join(f"{e:g}" for e in DEFAULT_SIZE_EDGES_B),
        help="model-size bin edges, billions of parameters",
    )
    p.add_argument(
        "--young-bins",
        default=",".join(f"{e:g}" for e in DEFAULT_YOUNG_LOG10_EDGES),
        help="log10(Young's modulus / Pa) bin edges",
    )
    p.add_argument(
        "--rank-bin", type=int, default=10, help="models per rank bin (ranked by overall accuracy)"
    )
    p.add_argument("--wandb-project", default=None, help="also log to this W&B project")
    p.add_argument("--wandb-mode", default=None, choices=["online", "offline", "disabled"])
    args = p.parse_args(argv)
    if args.rank_bin < 1:
        p.error(f"--rank-bin={args.rank_bin}, must be >= 1")
    try:
        runs = load_runs(args.results, args.set_dir, args.n_boot, args.seed, args.sizes)
        benchmarks = read_model_csv(args.benchmarks) if args.benchmarks else None
    except (FileNotFoundError, ValueError, KeyError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    tables = build_tables(
        runs,
        benchmarks,
        args.n_boot,
        args.seed,
        _edges(args.size_bins, "--size-bins"),
        _edges(args.young_bins, "--young-bins"),
        args.rank_bin,
    )
    written = write_report(runs, args.out, tables)
    if args.wandb_project:
        from probes.vlm.report.wandb_log import log_report

        print(
            f"W&B run files: {log_report(tables, written['summary'], args.out, args.wandb_project, args.wandb_mode)}"
        )
    print(f"{len(runs)} run(s); written to {args.out}: {', '.join(written['files'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
