"""``run(cfg)``: one probing run from a composed Hydra config (what ``train.py`` calls).

Order: seed -> task -> frozen backbone -> datamodule -> trivial baselines
(fitted on train, scored on every split, :mod:`probes.baselines`) -> decoder
(starting from the train constant) -> module -> callbacks / loggers -> fit
(model selection on ``val/skill``, the skill over the best val baseline) ->
test on ``test`` and ``test_ood_gravity`` with the best checkpoint ->
``metrics.json`` in the run directory (``cfg.paths.output_dir``).

``metrics.json`` holds, besides the run's identity: the probe's metrics per
split (``val``, ``test``, ``test_ood_gravity``); ``baselines`` (split ->
baseline -> metric -> value, for the same splits); ``best_baseline`` (split ->
metric -> name and value); ``skill`` (split -> metric -> skill over the best
baseline, and their ``mean``); ``baseline_fit`` (the fitted constants) and
``decision`` (the calibrated collision threshold or trusts, :mod:`probes.tasks`).
"""

from __future__ import annotations

import json
import logging
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from lightning.pytorch.callbacks import ModelCheckpoint
from omegaconf import DictConfig, OmegaConf

from newtphys import schema
from probes.baselines import BaselineResults, evaluate_baselines
from probes.datamodule import EVAL_SPLITS, ProbeDataModule
from probes.decoders import count_parameters
from probes.module import ProbeModule
from probes.tasks import TASK_NAMES, Task, build_task

log = logging.getLogger(__name__)

METRICS_FILENAME = "metrics.json"


def _container(node: Any) -> Any:
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else node


def build_task_from_config(task_cfg: DictConfig) -> Task:
    """The task named by ``cfg.task.name`` with ``cfg.task.params``; unknown names list the valid ones."""
    name = task_cfg.get("name")
    if name not in TASK_NAMES:
        raise ValueError(f"unknown task {name!r}; valid tasks: {', '.join(TASK_NAMES)}")
    return build_task(name, **(_container(task_cfg.get("params")) or {}))


def _supervision(cfg: DictConfig, backbone_name: str) -> str:
    """Supervision type for the results table: the backbone config's, else the registry's."""
    if cfg.backbone.get("supervision"):
        return str(cfg.backbone.supervision)
    from probes.backbones import get_spec

    try:
        return get_spec(backbone_name).supervision
    except (KeyError, ValueError):
        return "unknown"


MONITOR = "val/skill"
"""Model selection: mean skill over the task's metrics against the best trivial baseline of val."""


def _build_callbacks(cfg: DictConfig) -> list[L.Callback]:
    """Instantiate ``cfg.callbacks``; checkpoint / early stopping monitor ``MONITOR`` (higher is better)."""
    monitor, mode = MONITOR, "max"
    callbacks: list[L.Callback] = []
    for cb_cfg in (cfg.get("callbacks") or {}).values():
        if cb_cfg is None or "_target_" not in cb_cfg:
            continue
        cb_cfg = cb_cfg.copy()
        extra = {}
        if cb_cfg.get("monitor", "unset") is None:
            extra = {"monitor": monitor, "mode": mode}
        callbacks.append(hydra.utils.instantiate(cb_cfg, **extra))
    return callbacks


def _build_loggers(cfg: DictConfig) -> list[Any]:
    loggers = []
    for lg_cfg in (cfg.get("logger") or {}).values():
        if lg_cfg is not None and "_target_" in lg_cfg:
            loggers.append(hydra.utils.instantiate(lg_cfg))
    return loggers


def _split_metrics(results: dict[str, float], split: str) -> dict[str, float]:
    prefix = f"{split}/"
    return {k[len(prefix) :]: float(v) for k, v in results.items() if k.startswith(prefix)}


def _finite_or_none(d: dict[str, float]) -> dict[str, float | None]:
    return {k: (v if math.isfinite(v) else None) for k, v in d.items()}


@dataclass
class ProbeComponents:
    """Everything a probing run is made of, built from one config (shared by run(), tests and bench)."""

    task: Task
    backbone: torch.nn.Module
    datamodule: ProbeDataModule
    model: ProbeModule
    run_info: dict[str, Any]
    baselines: BaselineResults


def fit_baselines(task: Task, datamodule: ProbeDataModule, seed: int) -> BaselineResults:
    """The task's trivial baselines fitted on train, scored on val and the test splits (targets only)."""
    key = task.target_key
    return evaluate_baselines(
        task.name,
        task.metrics,
        datamodule.target_batches(schema.Split.TRAIN.value, key),
        {split: datamodule.target_batches(split, key) for split in ("val", *EVAL_SPLITS)},
        seed=seed,
    )


def build(cfg: DictConfig) -> ProbeComponents:
    """Seed, then build the task, frozen backbone, datamodule (splits checked), decoder and module."""
    L.seed_everything(int(cfg.seed), workers=True)
    task = build_task_from_config(cfg.task)
    backbone = hydra.utils.instantiate(cfg.backbone)
    backbone_name = getattr(backbone, "name", str(cfg.backbone.get("name")))
    pretrained = bool(getattr(backbone, "pretrained", cfg.backbone.get("pretrained")))

    datamodule: ProbeDataModule = hydra.utils.instantiate(
        cfg.data, targets=(task.target_key,), backbone=backbone, seed=int(cfg.seed)
    )
    datamodule.check()  # fail fast on missing / old / too-short data, before any training
    baselines = fit_baselines(task, datamodule, int(cfg.seed))
    log.info("trivial baselines on val: %s", baselines.best.get("val"))
    decoder = hydra.utils.instantiate(
        cfg.decoder,
        feat_dims=list(backbone.feat_dims),
        num_frames=int(cfg.data.clip_length),
        out_channels=task.out_channels,
    )
    if callable(decoder) and not isinstance(decoder, torch.nn.Module):  # a _partial_ config
        decoder = decoder()
    constant = task.output_bias(baselines.fitted)
    decoder.start_from_constant(constant)  # training starts at the train constant ...
    task.set_anchor(constant)  # ... and validation can shrink the probe back toward it (Task.calibrate)
    num_params = count_parameters(decoder)
    log.info("decoder %s: %d trainable parameters", type(decoder).__name__, num_params)

    model = ProbeModule(
        backbone=backbone,
        decoder=decoder,
        task=task,
        optimizer=hydra.utils.instantiate(cfg.optimizer),
        scheduler=hydra.utils.instantiate(cfg.scheduler) if cfg.get("scheduler") is not None else None,
        backbone_config={**_container(cfg.backbone), "name": backbone_name, "pretrained": pretrained},
        decoder_config={**_container(cfg.decoder), "class": type(decoder).__name__},
        task_config=_container(cfg.task),
        reference=baselines.reference(schema.Split.VAL.value),
    )
    run_info = {
        "backbone": backbone_name,
        "backbone_pretrained": pretrained,
        "backbone_layers": [int(i) for i in getattr(backbone, "layers", [])],
        "supervision": _supervision(cfg, backbone_name),
        "task": task.name,
        "decoder": type(decoder).__name__,
        "decoder_parameters": num_params,
        "seed": int(cfg.seed),
    }
    return ProbeComponents(task, backbone, datamodule, model, run_info, baselines)


def run(cfg: DictConfig) -> dict[str, Any]:
    """Train a probe, test it on both test splits, write ``metrics.json``; returns its content."""
    output_dir = Path(cfg.paths.output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    parts = build(cfg)
    model, datamodule = parts.model, parts.datamodule

    callbacks = _build_callbacks(cfg)
    loggers = _build_loggers(cfg)
    for lg in loggers:
        lg.log_hyperparams({**_container(cfg), "run_info": parts.run_info})

    trainer: L.Trainer = hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)
    try:
        trainer.fit(model, datamodule=datamodule)
        ckpt = next((c for c in callbacks if isinstance(c, ModelCheckpoint)), None)
        best = ckpt.best_model_path if ckpt is not None and ckpt.best_model_path else None
        val_results = trainer.validate(model, datamodule=datamodule, ckpt_path=best, verbose=False)
        test_results = trainer.test(model, datamodule=datamodule, ckpt_path=best, verbose=False)
        metrics = _results(parts, [*val_results, *test_results], trainer, best)
        for lg in loggers:  # baselines and skill as their own series next to the probe's metrics
            flat = _flat_baselines_and_skill(parts.baselines, metrics["skill"])
            lg.log_metrics(flat, step=trainer.global_step)
            lg.save()
    finally:
        _finish_wandb(loggers)
    (output_dir / METRICS_FILENAME).write_text(json.dumps(metrics, indent=1))
    log.info("metrics of %s written to %s", parts.run_info["backbone"], output_dir / METRICS_FILENAME)
    return metrics


def monitored_value(metrics: dict[str, Any]) -> float:
    """The monitored validation metric of a ``run`` result (what ``train.py`` returns to Hydra sweepers).

    ``metrics["monitor"]`` is ``"val/skill"`` (the mean skill over the best trivial baseline, in
    ``metrics["skill"]["val"]["mean"]``) or ``"val/<metric>"``; a missing value is NaN, never a silent 0."""
    split, _, name = str(metrics["monitor"]).partition("/")
    value = metrics.get("skill", {}).get(split, {}).get("mean") if name == "skill" else metrics.get(split, {}).get(name)
    return float("nan") if value is None else float(value)


def _results(
    parts: ProbeComponents, results: list[dict[str, float]], trainer: L.Trainer, best: str | None
) -> dict[str, Any]:
    """The content of ``metrics.json`` (module docstring) from Lightning's validate / test results."""
    merged: dict[str, float] = {}
    for res in results:
        merged.update(res)
    names = set(parts.task.metrics())
    probe = {
        split: {k: v for k, v in _split_metrics(merged, split).items() if k in names}
        for split in ("val", *EVAL_SPLITS)
    }
    base = parts.baselines
    return {
        **parts.run_info,
        "status": "finished",
        "best_checkpoint": best,
        "monitor": MONITOR,
        "epochs": int(trainer.current_epoch),
        "global_step": int(trainer.global_step),
        **{split: _finite_or_none(values) for split, values in probe.items()},
        "baselines": {
            split: {n: _finite_or_none(v) for n, v in by.items()} for split, by in base.scores.items()
        },
        "best_baseline": base.best,
        "skill": {split: _finite_or_none(base.skill(split, values)) for split, values in probe.items()},
        "baseline_fit": base.fitted,
        "decision": parts.task.decision(),
    }


def _flat_baselines_and_skill(
    base: BaselineResults, skills: dict[str, dict[str, float | None]]
) -> dict[str, float]:
    """``baseline/<split>/<name>/<metric>`` and ``skill/<split>/<metric>`` -> finite values, for loggers."""
    flat = {
        f"baseline/{split}/{name}/{metric}": value
        for split, by in base.scores.items()
        for name, values in by.items()
        for metric, value in values.items()
    }
    flat.update(
        {f"skill/{split}/{metric}": v for split, values in skills.items() for metric, v in values.items()}
    )
    return {k: float(v) for k, v in flat.items() if v is not None and math.isfinite(v)}


def _finish_wandb(loggers: list[Any]) -> None:
    """Close the W&B run so the next job of a multirun in this process starts its own."""
    if not any(type(lg).__name__ == "WandbLogger" for lg in loggers):
        return
    import wandb

    if wandb.run is not None:
        wandb.finish()
    os.environ.pop("WANDB_RUN_ID", None)
