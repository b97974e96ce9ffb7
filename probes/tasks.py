"""Probing tasks: which map is predicted, how the head output is scored, which metrics report it.

A task is data (:class:`TaskSpec`: target map, channels, scale, metrics) plus
one loss. Losses and metrics only see object pixels of the last frame
(``object_mask``). Losses average over all object pixels of the batch (pooled
per pixel); a batch without object pixels gives a zero loss that still has a
graph. Every task also names its trivial baselines (:mod:`probes.baselines`)
and the head output that reproduces their train constant
(:meth:`Task.output_bias`: a decoder starts from it, so a probe begins where a
constant ends).

* ``collision`` -- 1 logit per pixel. Binary cross-entropy with the positive
  class weighted by ``neg / pos`` counted over the object pixels of the batch
  (clamped to [1/``max_pos_weight``, ``max_pos_weight``]; 1 when the batch has
  no positive or no negative). Prediction: ``sigmoid(logit) > threshold``; the
  threshold is calibrated on validation (the one of
  ``CALIBRATION_THRESHOLDS`` with the best F1, :meth:`Task.calibrate`) and
  travels in checkpoints. With rare contacts, F1 rewards recall: an
  uninformed probe at 0.5 scored below predicting contact everywhere.
Calibration on validation (:meth:`Task.calibrate`, after every validation
epoch; the chosen values travel in checkpoints and ``metrics.json``'s
``decision``): a decision threshold for collision, and for the regression
tasks a *trust* per output in ``TRUST_GRID``: the share of the head's
departure from the train constant that is kept (gravity: direction and log
magnitude separately; flow: the vector). Trust 0 is the constant itself, so a
head whose departures are noise (a linear probe on random features fits
them within an epoch) falls back to its bias instead of scoring below it; the
validation metrics and ``val/skill`` are those of the calibrated prediction,
test splits use the values chosen on validation.

* ``gravity`` -- 3 channels, the gravity force in N in the camera frame,
  predicted as ``force / target_scale_n``. Loss = direction term
  ``|p/|p| - g/|g||`` (chord between unit vectors, = 2 sin(angle / 2), about
  the angle in radians) + ``magnitude_weight`` x L1 of ``log(|p| + eps)`` vs
  ``log(|g| + eps)`` (about the relative magnitude error). Both terms are
  linear in their error and their gradients have the same size (``1/|p|``,
  tangential vs radial), so neither drowns the other (``1 - cos``, quadratic
  in the angle, was ~0.03 at 15 degrees next to a log-magnitude term of ~0.4).
  The best constant under this loss is the train median magnitude along the
  spherical median direction.
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
from probes.baselines import BASELINES, TrivialBaselines

LOG_MAGNITUDE_EPS: float = 1e-6
"""Added to magnitudes (in units of the task scale) before the log in the gravity loss."""
UNIT_EPS: float = 1e-8
"""Norms (in units of the task scale) are clamped to at least this before dividing by them."""
CALIBRATION_THRESHOLDS: tuple[float, ...] = tuple(i / 100 for i in range(100))
"""Contact-probability thresholds tried on validation (0 predicts contact on every pixel)."""
TRUST_GRID: tuple[float, ...] = tuple(i / 10 for i in range(11))
"""Shares of the probe's departure from the train constant tried on validation (0: the constant)."""


@dataclass(frozen=True)
class TaskSpec:
    """What a probing task predicts and how it is reported."""

    name: str
    target: str
    """Map name in :mod:`newtphys.schema` (the dataset key of the target)."""
    out_channels: int
    unit: str
    metric_names: tuple[str, ...] = field(default_factory=tuple)
    """Model selection weighs them alike: the mean skill over the best trivial baseline (probes.run)."""


TASK_SPECS: dict[str, TaskSpec] = {
    s.name: s
    for s in (
        TaskSpec("collision", schema.COLLISION, 1, "bool", ("collision_f1",)),
        TaskSpec(
            "gravity", schema.GRAVITY, 3, "N", ("gravity_angular_error_deg", "gravity_magnitude_error_n")
        ),
        TaskSpec("scene_flow", schema.SCENE_FLOW, 3, "m", ("scene_flow_epe_m",)),
    )
}
TASK_NAMES: tuple[str, ...] = tuple(TASK_SPECS)


def _norm(v: Tensor) -> Tensor:
    """L2 norm over channels of (B, 3, H, W); the floor under the sqrt keeps the gradient finite at 0."""
    return torch.sqrt((v * v).sum(1) + 1e-12)


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

    def loss(self, output: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        """Scalar loss of head ``output`` (B, C, H, W) against ``target`` on ``mask`` (B, H, W) pixels."""
        raise NotImplementedError

    def predict(self, output: Tensor) -> Tensor:
        """Head output -> prediction in the target's unit and layout (what metrics receive)."""
        raise NotImplementedError

    def metrics(self) -> dict[str, Metric]:
        """Fresh metric objects, keyed by the names of ``spec.metric_names``."""
        raise NotImplementedError

    def baselines(self) -> TrivialBaselines:
        """This task's trivial baselines, unfitted (:mod:`probes.baselines`)."""
        return BASELINES[self.name]()

    def output_bias(self, fitted: dict) -> Tensor:
        """Head output (``out_channels``,) predicting the train constant of ``TrivialBaselines.fitted()``."""
        raise NotImplementedError

    anchor: Tensor | None = None
    """The head output of the train constant (``output_bias``), once set: what trust shrinks toward."""

    def set_anchor(self, bias: Tensor) -> None:
        self.anchor = torch.as_tensor(bias, dtype=torch.float32).detach().clone().reshape(-1)

    # Decision parameters beyond the head (threshold, trusts): chosen on validation, kept in checkpoints.
    def calibration_metrics(self) -> dict[str, Metric]:
        """Validation metrics that replace ``metrics()`` entries of the same name and pick the decision;
        they are fed :meth:`scores`. None for tasks without a decision parameter."""
        return {}

    def scores(self, output: Tensor) -> Tensor:
        """What calibration metrics receive (for collision the contact probability)."""
        return self.predict(output)

    def calibrate(self, metrics: dict[str, Metric]) -> None:
        """Set the decision parameters from the filled ``calibration_metrics()``."""

    def decision(self) -> dict[str, float]:
        """The decision parameters (JSON-ready)."""
        return {}

    def load_decision(self, decision: dict[str, float]) -> None:
        """Restore :meth:`decision` (from a checkpoint)."""


class CollisionTask(Task):
    """Binary contact mask from one logit per pixel (BCE with batch positive weighting)."""

    def __init__(self, max_pos_weight: float = 100.0, threshold: float = 0.5) -> None:
        super().__init__(TASK_SPECS["collision"])
        if max_pos_weight < 1.0:
            raise ValueError(f"max_pos_weight must be >= 1, got {max_pos_weight}")
        if not 0.0 <= threshold < 1.0:
            raise ValueError(f"threshold must be in [0, 1), got {threshold}")
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

    def output_bias(self, fitted: dict) -> Tensor:
        # the balanced loss is minimised by a constant logit of 0 whatever the positive rate
        return torch.zeros(1)

    def calibration_metrics(self) -> dict[str, Metric]:
        return {"collision_f1": M.CollisionF1(thresholds=CALIBRATION_THRESHOLDS)}

    def scores(self, output: Tensor) -> Tensor:
        return torch.sigmoid(output[:, 0])

    def calibrate(self, metrics: dict[str, Metric]) -> None:
        metric = metrics["collision_f1"]
        if not isinstance(metric, M.CollisionF1):
            raise TypeError(f"collision calibration needs a CollisionF1, got {type(metric).__name__}")
        self.threshold = metric.best_threshold()

    def decision(self) -> dict[str, float]:
        return {"threshold": self.threshold}

    def load_decision(self, decision: dict[str, float]) -> None:
        if "threshold" in decision:
            self.threshold = float(decision["threshold"])


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
        self.trust_direction = 1.0
        self.trust_magnitude = 1.0

    def loss(self, output: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        g = target / self.target_scale_n
        norm_p, norm_g = _norm(output), _norm(g)
        # chord between unit vectors: 2 sin(angle / 2)
        unit_p = output / norm_p.clamp_min(UNIT_EPS).unsqueeze(1)
        unit_g = g / norm_g.clamp_min(UNIT_EPS).unsqueeze(1)
        chord = _norm(unit_p - unit_g)
        log_ratio = torch.log(norm_p + LOG_MAGNITUDE_EPS) - torch.log(norm_g + LOG_MAGNITUDE_EPS)
        per_pixel = chord + self.magnitude_weight * log_ratio.abs()
        return _masked_mean(per_pixel, mask)

    def predict(self, output: Tensor) -> Tensor:
        return self.predict_with_trust(output, self.trust_direction, self.trust_magnitude)

    def predict_with_trust(self, output: Tensor, trust_direction: float, trust_magnitude: float) -> Tensor:
        """Force in N: the head's direction and log magnitude, each moved from the anchor's (the train
        constant) by the given share (1: the head as it is, 0: the constant)."""
        if self.anchor is None or (trust_direction == 1.0 and trust_magnitude == 1.0):
            return output * self.target_scale_n
        anchor = self.anchor.to(output).view(1, 3, 1, 1)
        norm_o, norm_a = _norm(output).clamp_min(UNIT_EPS), _norm(anchor).clamp_min(UNIT_EPS)
        unit_a, unit_o = anchor / norm_a.unsqueeze(1), output / norm_o.unsqueeze(1)
        mixed = (1.0 - trust_direction) * unit_a + trust_direction * unit_o
        unit = mixed / _norm(mixed).clamp_min(UNIT_EPS).unsqueeze(1)
        log_m = (1.0 - trust_magnitude) * torch.log(norm_a) + trust_magnitude * torch.log(norm_o)
        return unit * torch.exp(log_m).unsqueeze(1) * self.target_scale_n

    def metrics(self) -> dict[str, Metric]:
        return {
            "gravity_angular_error_deg": M.GravityAngularError(),
            "gravity_magnitude_error_n": M.GravityMagnitudeError(),
        }

    def output_bias(self, fitted: dict) -> Tensor:
        direction = torch.tensor(fitted["direction"], dtype=torch.float32)
        return direction * float(fitted["median_magnitude_n"]) / self.target_scale_n

    def calibration_metrics(self) -> dict[str, Metric]:
        return {
            "gravity_angular_error_deg": M.ParameterSweep(
                M.GravityAngularError, lambda out, t: self.predict_with_trust(out, t, 1.0), TRUST_GRID
            ),
            "gravity_magnitude_error_n": M.ParameterSweep(
                M.GravityMagnitudeError, lambda out, t: self.predict_with_trust(out, 1.0, t), TRUST_GRID
            ),
        }

    def scores(self, output: Tensor) -> Tensor:
        return output

    def calibrate(self, metrics: dict[str, Metric]) -> None:
        self.trust_direction = _best_parameter(metrics["gravity_angular_error_deg"])
        self.trust_magnitude = _best_parameter(metrics["gravity_magnitude_error_n"])

    def decision(self) -> dict[str, float]:
        return {"trust_direction": self.trust_direction, "trust_magnitude": self.trust_magnitude}

    def load_decision(self, decision: dict[str, float]) -> None:
        self.trust_direction = float(decision.get("trust_direction", self.trust_direction))
        self.trust_magnitude = float(decision.get("trust_magnitude", self.trust_magnitude))


class SceneFlowTask(Task):
    """3D scene flow per pixel (m, camera frame): endpoint-error loss."""

    def __init__(self, target_scale_m: float = 0.01) -> None:
        super().__init__(TASK_SPECS["scene_flow"])
        if target_scale_m <= 0:
            raise ValueError(f"target_scale_m must be > 0 m, got {target_scale_m}")
        self.target_scale_m = float(target_scale_m)
        self.trust = 1.0

    def loss(self, output: Tensor, target: Tensor, mask: Tensor) -> Tensor:
        return _masked_mean(_norm(output - target / self.target_scale_m), mask)

    def predict(self, output: Tensor) -> Tensor:
        return self.predict_with_trust(output, self.trust)

    def predict_with_trust(self, output: Tensor, trust: float) -> Tensor:
        """Flow in m: the anchor (train constant) plus ``trust`` x the head's departure from it."""
        if self.anchor is None or trust == 1.0:
            return output * self.target_scale_m
        anchor = self.anchor.to(output).view(1, 3, 1, 1)
        return (anchor + trust * (output - anchor)) * self.target_scale_m

    def metrics(self) -> dict[str, Metric]:
        return {"scene_flow_epe_m": M.SceneFlowEPE()}

    def output_bias(self, fitted: dict) -> Tensor:
        # the constant of least endpoint error (on generated data half the object pixels rest: it is 0)
        return torch.tensor(fitted["median_flow_m"], dtype=torch.float32) / self.target_scale_m

    def calibration_metrics(self) -> dict[str, Metric]:
        return {"scene_flow_epe_m": M.ParameterSweep(M.SceneFlowEPE, self.predict_with_trust, TRUST_GRID)}

    def scores(self, output: Tensor) -> Tensor:
        return output

    def calibrate(self, metrics: dict[str, Metric]) -> None:
        self.trust = _best_parameter(metrics["scene_flow_epe_m"])

    def decision(self) -> dict[str, float]:
        return {"trust": self.trust}

    def load_decision(self, decision: dict[str, float]) -> None:
        self.trust = float(decision.get("trust", self.trust))


def _best_parameter(metric: Metric) -> float:
    if not isinstance(metric, M.ParameterSweep):
        raise TypeError(f"calibration needs a ParameterSweep, got {type(metric).__name__}")
    return metric.best_parameter()


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
