"""Cluster generation: after a multirun of ``generate.py`` (Slurm or submitit-local jobs, each writing its own
shard range of one split, ``num_jobs=N job='range(N)'``), merge the split's ``index.json`` and check that the
jobs' shards form one split (:func:`newtphys.shards.merge_index`).

Hydra calls :class:`MergeIndexCallback` in the launching process once every job of the sweep has returned
(``hydra.callbacks`` in ``newtphys/conf/generate.yaml``); single runs never call it.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from newtphys import schema
from newtphys.shards import MergeReport, merge_index

log = logging.getLogger(__name__)


def merge_generated_splits(out_dir: str | Path, splits: list[str], expected: int | None = None) -> dict[str, MergeReport]:
    """Merge the index of each split directory under ``out_dir`` that holds shards (``expected``: the number of
    sequences each must hold, checked when given)."""
    reports = {}
    for split in splits:
        split_dir = Path(out_dir) / split
        if not split_dir.is_dir() or not any(split_dir.glob(schema.SHARD_GLOB)):
            continue
        reports[split] = merge_index(split_dir, expected)
        r = reports[split]
        log.info("merged %s/index.json: %d shards, %d sequences, %d frames%s", split_dir, r.shards, r.sequences,
                 r.frames, f"; missing shards {r.missing_shards}" if r.missing_shards else "")
    return reports


class MergeIndexCallback(Callback):
    """Merge ``<out_dir>/<split>/index.json`` after a generation multirun (every split the sweep names)."""

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if config.get("dry_run"):
            return
        splits = {str(config.split)}
        for override in config.hydra.overrides.task:  # split=a,b sweeps: merge each
            key, _, value = str(override).partition("=")
            if key.lstrip("+~") == "split":
                splits |= {v.strip() for v in value.split(",") if v.strip() in schema.SPLITS}
        merge_generated_splits(str(config.out_dir), sorted(splits))
