"""Probing tasks: which map is predicted, how the head output is scored, which metrics report it.

A task is data (:class:`TaskSpec`: target map, channels, scale, metrics) plus
one loss. Losses and metrics only see object pixels of the last frame
(``object_mask``). Losses average over all object pixels of the batch (pooled
per pixel); a batch without object pixels gives a zero loss that still has a
graph.

* ``collision`` -- 1 logit per pixel. Binary cross-entropy with the positive
  class weighted by ``neg / pos`` counted over the object pixels of the batch
  (clamped to [1/``max_pos_weight``, ``max_pos_weight``]; 1 when the batch has
  no positive or no negative). Prediction: ``sigmoid(logit) > 0.5``.
* ``gravity`` -- 3 channels, the gravity force in N in the camera frame,
  predicted as ``force / target_scale_n``. Loss = direction ``(1 - cos)`` +
  ``magnitude_weight`` x L1 of ``log(|p| + eps)`` vs ``log(|g| + eps)``: the
  log makes the magnitude term relative (a 10 % error costs the same on a
  1 N and on a 100 N object), and the two terms stay on one scale.
* ``scene_flow`` -- 3 channels, displacement in m to the next frame, predicted
  as ``flow / target_scale_m``. Loss = endpoint error (L2 norm of the
  difference, in units of ``target_scale_m``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import Tensor
from torchmetrics import Metric

from newtphys import schema
from probes import metrics as M

LOG_MAGNITUDE_EPS: float = 1e-6
"""Added to magnitudes (in units of the task scale) before the log in the gravity loss."""


@dataclass(frozen=True)
class TaskSpec:
    """What a probing task predicts and how it is reported."""

    name: str
    target: str
    """Map name in :mod:`newtphys.schema` (the dataset key of the target)."""
    out_channels: int
    unit: str
    monitor: str
    """Metric (without split prefix) used for model selection on val."""
    monitor_mode: str
    """"max" or "min"."""
    metric_names: tuple[str, ...] = field(default_factory=tuple)


TASK_SPECS: dict[str, TaskSpec] = {
    s.name: s
    for s in (
        TaskSpec("collision", schema.COLLISION, 1, "bool", "collision_f1", "max", ("collision_f1",)),
        TaskSpec(
            "gravity",
            schema.GRAVITY,
            3,
            "N",
            "gravity_angular_error_deg",
            "min",
            ("gravity_angular_error_deg", "gravity_magnitude_error_n"),
        ),
        TaskSpec("scene_flow", schema.SCENE_FLOW, 3, "m", "scene_flow_epe_m", "min", ("scene_flow_epe_m",)),
    )
}
TASK_NAMES: tuple[str, ...] = tuple(TASK_SPECS)


def _masked_mean(per_pixel: Tensor, mask: Tensor) -> Tensor:
    """Mean of (B, H, W) values over mask pixels; 0 (with a graph) when the mask is empty."""
    m = mask.to(per_pixel.dtype)
    return (per_pixel * m).sum() / m.sum().clamp_min(1.0)


class Task:
    """A probing task: turns head outputs into losses, predictions (physical units) and metric updates."""

    spec: TaskSpec

    def __init__(self, spec: TaskSpec) -> None:
        self.spec = spec

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def target_key(self) -> str:
        return self.spec.target

    @property
    def out_channels(self) -> int:
        return self.spec.out_channels

    @property
    def monitor(self) -> str:
        return self.spec.monitor

    @property
    def monitor_mode(self) -> str:
        return self.spec.monitor_mode

    def loss(self, output: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        """Scalar loss of head ``output`` (B, C, H, W) against ``target`` on ``mask`` (B, H, W) pixels."""
        raise NotImplementedError

    def predict(self, output: Tensor) -> Tensor:
        """Head output -> prediction in the target's unit and layout (what metrics receive)."""
        raise NotImplementedError

    def metrics(self) -> dict[str, Metric]:
        """Fresh metric objects, keyed by the names of ``spec.metric_names``."""
        raise NotImplementedError

    def constant_baseline(self, target: Tensor, mask: Tensor) -> dict[str, Tensor]:
        """Best constant predictors of this task on (target, mask): name -> prediction like ``predict``'s."""
        raise NotImplementedError


class CollisionTask(Task):
    """Binary contact mask from one logit per pixel (BCE with batch positive weighting)."""

    def __init__(self, max_pos_weight: float = 100.0, threshold: float = 0.5) -> None:
        super().__init__(TASK_SPECS["collision"])
        if max_pos_weight < 1.0:
            raise ValueError(f"max_pos_weight must be >= 1, got {max_pos_weight}")
        if not 0.0 < threshold < 1.0:
            raise ValueError(f"threshold must be in (0, 1), got {threshold}")
        self.max_pos_weight = float(max_pos_weight)
        self.threshold = float(threshold)

    def pos_weight(self, target: Tensor, mask: Tensor) -> Tensor:
        """neg/pos over object pixels, clamped; 1 when either class is absent."""
        m = mask.bool()
        pos = (target.bool() & m).sum().to(torch.float32)
        neg = m.sum().to(torch.float32) - pos
        if pos == 0 or neg == 0:
            return torch.tensor(1.0, device=target.device)
        return (neg / pos).clamp(1.0 / self.max_pos_weight, self.max_pos_weight).to(target.device)

    def loss(self, output: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        logits = output[:, 0]
        t = target.to(logits.dtype)
        per_pixel = F.binary_cross_entropy_with_logits(
            logits, t, pos_weight=self.pos_weight(target, mask), reduction="none"
        )
        return _masked_mean(per_pixel, mask)

    def predict(self, output: Tensor) -> Tensor:
        return torch.sigmoid(output[:, 0]) > self.threshold

    def metrics(self) -> dict[str, Metric]:
        return {"collision_f1": M.CollisionF1()}

    def constant_baseline(self, target: Tensor, mask: Tensor) -> dict[str, Tensor]:
        return {
            "all_negative": torch.zeros_like(target, dtype=torch.bool),
            "all_positive": torch.ones_like(target, dtype=torch.bool),
        }


class GravityTask(Task):
    """Gravity force vector per pixel (N, camera frame): direction + log-magnitude loss."""

    def __init__(self, target_scale_n: float = 10.0, magnitude_weight: float = 1.0) -> None:
        super().__init__(TASK_SPECS["gravity"])
        if target_scale_n <= 0:
            raise ValueError(f"target_scale_n must be > 0 N, got {target_scale_n}")
        if magnitude_weight < 0:
            raise ValueError(f"magnitude_weight must be >= 0, got {magnitude_weight}")
        self.target_scale_n = float(target_scale_n)
        self.magnitude_weight = float(magnitude_weight)

    def loss(self, output: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        g = target / self.target_scale_n
        cos = F.cosine_similarity(output, g, dim=1, eps=1e-8)
        log_p = torch.log(output.norm(dim=1) + LOG_MAGNITUDE_EPS)
        log_g = torch.log(g.norm(dim=1) + LOG_MAGNITUDE_EPS)
        per_pixel = (1.0 - cos) + self.magnitude_weight * (log_p - log_g).abs()
        return _masked_mean(per_pixel, mask)

    def predict(self, output: Tensor) -> Tensor:
        return output * self.target_scale_n

    def metrics(self) -> dict[str, Metric]:
        return {
            "gravity_angular_error_deg": M.GravityAngularError(),
            "gravity_magnitude_error_n": M.GravityMagnitudeError(),
        }

    def constant_baseline(self, target: Tensor, mask: Tensor) -> dict[str, Tensor]:
        m = mask.bool().unsqueeze(1).to(target.dtype)
        mean = (target * m).sum((0, 2, 3)) / m.sum().clamp_min(1.0)
        return {"mean_vector": mean.view(1, 3, 1, 1).expand_as(target).clone()}


class SceneFlowTask(Task):
    """3D scene flow per pixel (m, camera frame): endpoint-error loss."""

    def __init__(self, target_scale_m: float = 0.01) -> None:
        super().__init__(TASK_SPECS["scene_flow"])
        if target_scale_m <= 0:
            raise ValueError(f"target_scale_m must be > 0 m, got {target_scale_m}")
        self.target_scale_m = float(target_scale_m)

    def loss(self, output: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        diff = output - target / self.target_scale_m
        # sqrt with a small floor keeps the gradient finite at a perfect prediction
        epe = torch.sqrt((diff * diff).sum(1) + 1e-12)
        return _masked_mean(epe, mask)

    def predict(self, output: Tensor) -> Tensor:
        return output * self.target_scale_m

    def metrics(self) -> dict[str, Metric]:
        return {"scene_flow_epe_m": M.SceneFlowEPE()}

    def constant_baseline(self, target: Tensor, mask: Tensor) -> dict[str, Tensor]:
        return {"all_zero": torch.zeros_like(target)}


_TASK_CLASSES: dict[str, type[Task]] = {
    "collision": CollisionTask,
    "gravity": GravityTask,
    "scene_flow": SceneFlowTask,
}


def build_task(name: str, **params) -> Task:
    """Build a task by name; unknown names list the valid ones. ``params`` go to the task class."""
    try:
        cls = _TASK_CLASSES[name]
    except KeyError:
        raise ValueError(f"unknown task {name!r}; valid tasks: {', '.join(TASK_NAMES)}") from None
    return cls(**params)
