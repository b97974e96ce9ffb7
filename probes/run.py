"""``run(cfg)``: one probing run from a composed Hydra config (what ``train.py`` calls).

Order: seed -> task -> frozen backbone -> datamodule -> decoder -> module ->
callbacks / loggers -> fit (model selection on val) -> test on ``test`` and
``test_ood_gravity`` with the best checkpoint -> ``metrics.json`` in the run
directory (``cfg.paths.output_dir``).
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


def _build_callbacks(cfg: DictConfig, task: Task) -> list[L.Callback]:
    """Instantiate ``cfg.callbacks``; checkpoint / early stopping monitor the task's val metric."""
    monitor, mode = f"val/{task.monitor}", task.monitor_mode
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
    decoder = hydra.utils.instantiate(
        cfg.decoder,
        feat_dims=list(backbone.feat_dims),
        num_frames=int(cfg.data.clip_length),
        out_channels=task.out_channels,
    )
    if callable(decoder) and not isinstance(decoder, torch.nn.Module):  # a _partial_ config
        decoder = decoder()
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
    return ProbeComponents(task, backbone, datamodule, model, run_info)


def run(cfg: DictConfig) -> dict[str, Any]:
    """Train a probe, test it on both test splits, write ``metrics.json``; returns its content."""
    output_dir = Path(cfg.paths.output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    parts = build(cfg)
    task, model, datamodule = parts.task, parts.model, parts.datamodule

    callbacks = _build_callbacks(cfg, task)
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
    finally:
        _finish_wandb(loggers)

    merged: dict[str, float] = {}
    for res in [*val_results, *test_results]:
        merged.update(res)
    metrics = {
        **parts.run_info,
        "status": "finished",
        "best_checkpoint": best,
        "monitor": f"val/{task.monitor}",
        "epochs": int(trainer.current_epoch),
        "global_step": int(trainer.global_step),
        "val": _finite_or_none(_split_metrics(merged, "val")),
        **{s: _finite_or_none(_split_metrics(merged, s)) for s in EVAL_SPLITS},
    }
    (output_dir / METRICS_FILENAME).write_text(json.dumps(metrics, indent=1))
    log.info("metrics of %s written to %s", parts.run_info["backbone"], output_dir / METRICS_FILENAME)
    return metrics


def monitored_value(metrics: dict[str, Any]) -> float:
    """The monitored validation metric of a ``run`` result (what ``train.py`` returns to Hydra sweepers).

    ``metrics["monitor"]`` is ``"val/<name>"``; a missing or non-finite value is NaN, never a silent 0."""
    split, _, name = str(metrics["monitor"]).partition("/")
    value = metrics.get(split, {}).get(name)
    return float("nan") if value is None else float(value)


def _finish_wandb(loggers: list[Any]) -> None:
    """Close the W&B run so the next job of a multirun in this process starts its own."""
    if not any(type(lg).__name__ == "WandbLogger" for lg in loggers):
        return
    import wandb

    if wandb.run is not None:
        wandb.finish()
    os.environ.pop("WANDB_RUN_ID", None)
