"""LightningModule: a trainable decoder on top of a frozen backbone, scored by the task's metrics.

* The backbone and the decoder are injected (built from config by
  :func:`probes.run.run`); the optimizer and the scheduler arrive as partials
  (``_partial_: true``) and are bound here.
* One shared step for train / val / test; one metric collection per stage
  and evaluation split, logged as ``<split>/<metric>`` (``train/``, ``val/``,
  ``test/``, ``test_ood_gravity/``).
* The frozen backbone is never trained and never checkpointed: its weights
  are dropped from the state dict on save; the checkpoint holds the decoder
  weights plus the backbone's name / config in ``hyper_parameters``, and the
  task's decision parameters (``task_decision``: the collision threshold, trusts).
* Validation calibrates the task's decision (:meth:`Task.calibrate`: the
  collision threshold with the best val F1, the regression tasks' trust in
  their departure from the train constant) at the end of every epoch, so the
  checkpoint saved for that epoch carries the decision its score was measured
  with.
* Given ``reference`` (the best trivial baseline of val per metric,
  :mod:`probes.baselines`), validation also logs ``val/skill``: the mean over
  the task's metrics of the skill over that baseline, what
  :func:`probes.run.run` selects checkpoints on (for gravity it weighs
  direction and magnitude alike).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import lightning as L
import torch
from torch import Tensor, nn
from torch.optim.lr_scheduler import LambdaLR
from torchmetrics import MetricCollection

from probes.baselines import skill
from probes.datamodule import EVAL_SPLITS
from probes.decoders import count_parameters
from probes.features import clip_features
from probes.tasks import Task

BACKBONE_PREFIX = "backbone."


def warmup_cosine_schedule(
    optimizer: torch.optim.Optimizer,
    total_steps: int,
    warmup_fraction: float = 0.1,
    min_lr_ratio: float = 0.0,
) -> LambdaLR:
    """Warmup from 0 over ``warmup_fraction`` of the steps, then cosine decay to ``min_lr_ratio`` x lr."""
    if total_steps < 1:
        raise ValueError(f"total_steps must be >= 1, got {total_steps}")
    if not 0.0 <= warmup_fraction < 1.0:
        raise ValueError(f"warmup_fraction must be in [0, 1), got {warmup_fraction}")
    if not 0.0 <= min_lr_ratio <= 1.0:
        raise ValueError(f"min_lr_ratio must be in [0, 1], got {min_lr_ratio}")
    warmup = int(round(warmup_fraction * total_steps))

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        progress = min(1.0, (step - warmup) / max(1, total_steps - warmup))
        return min_lr_ratio + (1.0 - min_lr_ratio) * 0.5 * (1.0 + math.cos(math.pi * progress))

    return LambdaLR(optimizer, factor)


def _metrics_key(split: str) -> str:
    """ModuleDict key of a split's metrics ("train" itself would clash with Module.train)."""
    return f"metrics_{split}"


class ProbeModule(L.LightningModule):
    """Frozen backbone -> decoder -> task loss and metrics."""

    def __init__(
        self,
        backbone: nn.Module,
        decoder: nn.Module,
        task: Task,
        optimizer: Callable[..., torch.optim.Optimizer],
        scheduler: Callable[..., Any] | None = None,
        backbone_config: dict | None = None,
        decoder_config: dict | None = None,
        task_config: dict | None = None,
        eval_splits: Sequence[str] = EVAL_SPLITS,
        reference: dict[str, float] | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(
            ignore=["backbone", "decoder", "task", "optimizer", "scheduler", "reference"]
        )
        self.backbone = backbone
        for p in self.backbone.parameters():
            p.requires_grad_(False)
        self.backbone.eval()
        self.decoder = decoder
        self.task = task
        self.optimizer_factory = optimizer
        self.scheduler_factory = scheduler
        self.eval_splits = tuple(eval_splits)
        calibration = task.calibration_metrics()
        self.metrics = nn.ModuleDict(
            {
                _metrics_key(split): MetricCollection(
                    {k: m for k, m in task.metrics().items() if split != "val" or k not in calibration},
                    prefix=f"{split}/",
                )
                for split in ("train", "val", *self.eval_splits)
            }
        )
        self.calibration = MetricCollection(calibration, prefix="val/") if calibration else None
        self.reference = dict(reference) if reference else None
        self._optimum = {k: float(m.optimum) for k, m in task.metrics().items()}
        self.strict_loading = False  # checkpoints hold no backbone weights

    # ------------------------------------------------------------------ #
    def num_decoder_parameters(self) -> int:
        return count_parameters(self.decoder)

    def train(self, mode: bool = True) -> ProbeModule:
        super().train(mode)
        self.backbone.eval()  # frozen: dropout / norm statistics never switch to training
        return self

    def features(self, batch: dict[str, Any]) -> list[Tensor]:
        """Per-layer (B, K, C, h, w) features: cached ones from the batch or the backbone's on the frames."""
        if "features" in batch:
            return batch["features"]
        return clip_features(self.backbone, batch["frames"])

    def forward(self, batch: dict[str, Any]) -> Tensor:
        """Head output (B, C_out, H, W) at the target resolution."""
        target = batch[self.task.target_key]
        return self.decoder(self.features(batch), out_size=tuple(target.shape[-2:]))

    # ------------------------------------------------------------------ #
    def _shared_step(self, batch: dict[str, Any], split: str) -> Tensor:
        output = self(batch)
        target = batch[self.task.target_key]
        mask = batch["object_mask"]
        loss = self.task.loss(output, target, mask)
        bs = int(mask.shape[0])
        self.log(
            f"{split}/loss",
            loss,
            on_step=split == "train",
            on_epoch=True,
            batch_size=bs,
            prog_bar=split == "train",
            add_dataloader_idx=False,
        )
        collections = [self.metrics[_metrics_key(split)]]
        with torch.no_grad():
            if len(collections[0]):
                collections[0].update(self.task.predict(output.detach()), target, mask)
            if split == "val" and self.calibration is not None:
                self.calibration.update(self.task.scores(output.detach()), target, mask)
                collections.append(self.calibration)
        for collection in collections:
            if len(collection):
                self.log_dict(
                    collection, on_step=False, on_epoch=True, batch_size=bs, add_dataloader_idx=False
                )
        return loss

    def training_step(self, batch: dict[str, Any], batch_idx: int) -> Tensor:
        return self._shared_step(batch, "train")

    def validation_step(self, batch: dict[str, Any], batch_idx: int) -> None:
        self._shared_step(batch, "val")

    def test_step(self, batch: dict[str, Any], batch_idx: int, dataloader_idx: int = 0) -> None:
        self._shared_step(batch, self.eval_splits[dataloader_idx])

    def on_validation_epoch_end(self) -> None:
        # runs before Lightning computes and resets the logged metrics: their sums are the whole epoch's
        if self.calibration is not None:
            self.task.calibrate({k.removeprefix("val/"): m for k, m in self.calibration.items()})
        if self.reference is not None:
            values = {}
            for collection in (self.metrics[_metrics_key("val")], self.calibration):
                for name, metric in (collection or {}).items():
                    values[name.removeprefix("val/")] = float(metric.compute())
            skills = [skill(values.get(k), self.reference.get(k), opt) for k, opt in self._optimum.items()]
            self.log("val/skill", sum(skills) / len(skills), prog_bar=True)

    # ------------------------------------------------------------------ #
    def configure_optimizers(self) -> Any:
        params = [p for p in self.decoder.parameters() if p.requires_grad]
        optimizer = self.optimizer_factory(params=params)
        if self.scheduler_factory is None:
            return optimizer
        total = int(self.trainer.estimated_stepping_batches) if self.trainer is not None else 1
        scheduler = self.scheduler_factory(optimizer=optimizer, total_steps=max(1, total))
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        checkpoint["state_dict"] = {
            k: v for k, v in checkpoint["state_dict"].items() if not k.startswith(BACKBONE_PREFIX)
        }
        checkpoint["task_decision"] = self.task.decision()

    def on_load_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        self.task.load_decision(checkpoint.get("task_decision", {}))
