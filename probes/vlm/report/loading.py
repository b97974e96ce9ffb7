"""Find run directories, join them with their question sets and score them; model sizes and benchmark scores
from the run manifests or user CSVs."""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE
from probes.vlm.predictions import manifest_set_dir, read_manifest
from probes.vlm.scoring import ItemResult, asked_results, item_results, score_results

SIZE_KEYS_B: tuple[str, ...] = ("params_b", "size_b", "num_params_b", "parameters_b")
"""Keys of a manifest's ``model`` record read as the model size in billions of parameters."""
SIZE_KEYS_COUNT: tuple[str, ...] = ("num_params", "num_parameters", "parameters")
"""Keys read as a parameter count (divided by 1e9)."""


@dataclass
class Run:
    """One scored run: a model on a question set."""

    label: str
    run_dir: Path
    set_dir: Path
    manifest: dict[str, Any]
    results: list[ItemResult]
    scores: dict[str, Any]
    params_b: float | None = None
    """Model size, billions of parameters (manifest or --sizes CSV); None when unknown."""
    aliases: tuple[str, ...] = ()
    """Names a user CSV may use for this model: the label, the answerer name, the model id / name."""

    def lookup(self, table: dict[str, dict[str, float]]) -> dict[str, float] | None:
        """This model's row of a ``model``-keyed CSV table, by the first alias found."""
        for name in (self.label, *self.aliases):
            if name in table:
                return table[name]
        return None


def find_run_dirs(paths: list[Path]) -> list[Path]:
    """Each path is a run directory (``manifest.json`` + ``predictions.jsonl``) or a folder searched for them."""
    found: list[Path] = []
    for p in paths:
        p = Path(p)
        if (p / MANIFEST_FILE).is_file() and (p / PREDICTIONS_FILE).is_file():
            found.append(p)
        elif p.is_dir():
            found += sorted(
                m.parent for m in p.rglob(MANIFEST_FILE) if (m.parent / PREDICTIONS_FILE).is_file()
            )
        else:
            raise FileNotFoundError(
                f"{p}: neither a run directory ({MANIFEST_FILE} + {PREDICTIONS_FILE}) nor a folder"
            )
    if not found:
        raise FileNotFoundError(f"no run directories under {[str(p) for p in paths]}")
    return list(dict.fromkeys(found))


def _size_from_record(model: dict[str, Any]) -> float | None:
    for k in SIZE_KEYS_B:
        if model.get(k) is not None:
            return float(model[k])
    for k in SIZE_KEYS_COUNT:
        if model.get(k) is not None:
            return float(model[k]) / 1e9
    return None


def read_model_csv(path: Path, value_columns: list[str] | None = None) -> dict[str, dict[str, float]]:
    """``model`` column -> {column: float} of a CSV (empty cells skipped); a non-number names file, row, column."""
    out: dict[str, dict[str, float]] = {}
    with open(path, newline="") as f:
        reader = csv.DictReader(f)
        if reader.fieldnames is None or "model" not in reader.fieldnames:
            raise ValueError(f"{path}: needs a 'model' column, has {reader.fieldnames}")
        cols = value_columns or [c for c in reader.fieldnames if c != "model"]
        for n, row in enumerate(reader, 2):
            values = {}
            for c in cols:
                cell = (row.get(c) or "").strip()
                if not cell:
                    continue
                try:
                    values[c] = float(cell)
                except ValueError:
                    raise ValueError(f"{path}:{n}: column {c!r} = {cell!r} is not a number") from None
                if not math.isfinite(values[c]):
                    raise ValueError(f"{path}:{n}: column {c!r} = {cell!r} is not finite")
            out[row["model"].strip()] = values
    return out


def _label(manifest: dict[str, Any], run_dir: Path) -> str:
    model = manifest.get("model") or {}
    label = str(model.get("name") or manifest.get("answerer") or model.get("id") or run_dir.name)
    if model.get("weights") == "random":
        label += " (random)"
    return label


def load_runs(
    paths: list[Path],
    set_dir: Path | None = None,
    n_boot: int = 1000,
    seed: int = 0,
    sizes_csv: Path | None = None,
) -> list[Run]:
    """Every run under ``paths``, joined with its set (``set_dir`` or the manifest's) and scored."""
    sizes = read_model_csv(sizes_csv, ["params_b"]) if sizes_csv else {}
    runs: list[Run] = []
    for d in find_run_dirs(paths):
        manifest = read_manifest(d)
        sd = Path(set_dir) if set_dir else manifest_set_dir(manifest, d)
        results, not_asked = asked_results(item_results(d, sd), manifest)
        scores = score_results(results, not_asked, n_boot=n_boot, seed=seed)
        model = manifest.get("model") or {}
        aliases = tuple(
            dict.fromkeys(str(a) for a in (manifest.get("answerer"), model.get("id"), model.get("name")) if a)
        )
        run = Run(_label(manifest, d), d, sd, manifest, results, scores, _size_from_record(model), aliases)
        if run.params_b is None:
            run.params_b = (run.lookup(sizes) or {}).get("params_b")
        runs.append(run)
    seen: dict[str, int] = {}
    for r in runs:
        seen[r.label] = seen.get(r.label, 0) + 1
    for r in runs:  # two runs of one model (e.g. two sets): tell them apart by directory
        if seen[r.label] > 1:
            r.label = f"{r.label} [{r.run_dir.name}]"
    return runs
