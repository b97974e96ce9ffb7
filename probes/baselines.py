"""Trivial baselines: what predictors that never look at the pixels score on the probes' own targets.

A probe's number means something only next to these. Every task has a few,
fitted on the train split and scored on every split with the task's own
metric objects (same targets, same object masks, same per-image averaging):

============  ==============  ==================================================================
task          baseline        prediction on every object pixel
============  ==============  ==================================================================
collision     all_negative    no contact
collision     all_positive    contact
collision     train_rate      contact with the train positive rate (a Bernoulli draw per pixel
                              from a seeded generator: sklearn's "stratified" dummy)
gravity       constant        train mean direction x train median magnitude (N)
scene_flow    zero            no motion
scene_flow    mean            train mean flow vector (m)
scene_flow    median          train geometric median flow (m): the constant of least endpoint error
============  ==============  ==================================================================

Fitting pools the object pixels of the last frame of every train clip, as sums
and counts: the mean direction is the normalised sum of unit gravity vectors,
the median magnitude the (lower) weighted median of a table of distinct
magnitudes and their pixel counts (one object has one gravity magnitude), the
positive rate and the mean flow are sums over counts; the geometric median
of the flow (Weiszfeld) runs on up to ``FLOW_SAMPLES_PER_IMAGE`` object pixels
per train image.

Skill of a probe over the best baseline of the same split, per metric::

    skill = (probe - best) / (optimum - best)

0 = as good as the best trivial predictor, 1 = perfect, < 0 = worse than a
predictor that never looks at the pixels. For errors (optimum 0) that is
``1 - probe / best``; for F1 (optimum 1) the share of the gap to a perfect
score that the probe closes. The best baseline is chosen per metric and split
(the strictest reference); NaN where the best baseline is already perfect.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

import torch
from torch import Tensor
from torchmetrics import Metric

from probes.metrics import ZERO_LENGTH_EPS

Batches = Iterable[tuple[Tensor, Tensor]]
"""(target, mask) pairs: target in the task's layout, mask (B, H, W) object pixels of the last frame."""


class TrivialBaselines(ABC):
    """Predictors of one task that ignore the image: ``update`` fits them on train targets."""

    names: tuple[str, ...] = ()

    @abstractmethod
    def update(self, target: Tensor, mask: Tensor) -> None:
        """Accumulate one batch of train targets (object pixels of ``mask``)."""

    @abstractmethod
    def fitted(self) -> dict[str, Any]:
        """The fitted constants, JSON-ready."""

    @abstractmethod
    def predictions(self, target: Tensor, mask: Tensor, generator: torch.Generator) -> dict[str, Tensor]:
        """Baseline name -> prediction shaped like ``target`` (what the task's metrics receive)."""

    def _need_pixels(self, count: Tensor) -> None:
        if count <= 0:
            raise ValueError(
                f"{type(self).__name__}: the train split has no object pixel to fit the trivial baselines on"
            )


class CollisionBaselines(TrivialBaselines):
    names = ("all_negative", "all_positive", "train_rate")

    def __init__(self) -> None:
        self.positive = torch.zeros((), dtype=torch.float64)
        self.total = torch.zeros((), dtype=torch.float64)

    def update(self, target: Tensor, mask: Tensor) -> None:
        m = mask.bool()
        self.positive += (target.bool() & m).sum().to(torch.float64).cpu()
        self.total += m.sum().to(torch.float64).cpu()

    @property
    def positive_rate(self) -> float:
        self._need_pixels(self.total)
        return float(self.positive / self.total)

    def fitted(self) -> dict[str, Any]:
        return {"positive_rate": self.positive_rate}

    def predictions(self, target: Tensor, mask: Tensor, generator: torch.Generator) -> dict[str, Tensor]:
        draw = torch.rand(target.shape, generator=generator, dtype=torch.float64) < self.positive_rate
        return {
            "all_negative": torch.zeros(target.shape, dtype=torch.bool, device=target.device),
            "all_positive": torch.ones(target.shape, dtype=torch.bool, device=target.device),
            "train_rate": draw.to(target.device),
        }


def weighted_lower_median(values: Tensor, counts: Tensor) -> float:
    """Lower median of ``values`` repeated ``counts`` times (what ``torch.median`` gives on the expansion)."""
    order = torch.argsort(values)
    v, c = values[order], counts[order].to(torch.float64)
    cum = torch.cumsum(c, 0)
    rank = math.ceil(float(cum[-1]) / 2.0)  # the lower middle element, 1-based
    return float(v[int(torch.searchsorted(cum, torch.tensor(rank, dtype=cum.dtype)))])


class GravityBaselines(TrivialBaselines):
    names = ("constant",)

    def __init__(self) -> None:
        self.direction_sum = torch.zeros(3, dtype=torch.float64)
        self.magnitudes = torch.zeros(0, dtype=torch.float64)  # distinct magnitudes, N
        self.counts = torch.zeros(0, dtype=torch.float64)  # pixels of each

    def update(self, target: Tensor, mask: Tensor) -> None:
        g = target.movedim(1, -1)[mask.bool()].to(torch.float64).cpu()  # object pixels (N, 3)
        norm = g.norm(dim=1)
        keep = norm > ZERO_LENGTH_EPS
        self.direction_sum += (g[keep] / norm[keep].unsqueeze(1)).sum(0)
        values, counts = torch.unique(norm[keep], return_counts=True)
        merged, inverse = torch.unique(torch.cat([self.magnitudes, values]), return_inverse=True)
        self.counts = torch.zeros(len(merged), dtype=torch.float64).index_add_(
            0, inverse, torch.cat([self.counts, counts.to(torch.float64)])
        )
        self.magnitudes = merged

    @property
    def direction(self) -> Tensor:
        """Unit mean direction (3,) of gravity over the train object pixels, camera frame."""
        self._need_pixels(self.counts.sum())
        return self.direction_sum / self.direction_sum.norm().clamp_min(ZERO_LENGTH_EPS)

    @property
    def median_magnitude_n(self) -> float:
        self._need_pixels(self.counts.sum())
        return weighted_lower_median(self.magnitudes, self.counts)

    def fitted(self) -> dict[str, Any]:
        return {"direction": self.direction.tolist(), "median_magnitude_n": self.median_magnitude_n}

    def predictions(self, target: Tensor, mask: Tensor, generator: torch.Generator) -> dict[str, Tensor]:
        vector = (self.direction * self.median_magnitude_n).to(target.device, target.dtype)
        return {"constant": vector.view(1, 3, 1, 1).expand_as(target).clone()}


def geometric_median(points: Tensor, iterations: int = 200, eps: float = 1e-9) -> Tensor:
    """Point minimising the summed Euclidean distance to ``points`` (N, D) (Weiszfeld's iteration; distances
    are floored at ``eps`` so a median on a data point -- e.g. at rest, 0 -- is reached, not divided by)."""
    x = points.mean(0)
    for _ in range(iterations):
        w = 1.0 / (points - x).norm(dim=1).clamp_min(eps)
        x_new = (points * w[:, None]).sum(0) / w.sum()
        if float((x_new - x).norm()) <= eps:
            return x_new
        x = x_new
    return x


FLOW_SAMPLES_PER_IMAGE = 256
"""Object pixels per train image (evenly spaced in raster order) kept for the geometric median."""


class SceneFlowBaselines(TrivialBaselines):
    names = ("zero", "mean", "median")

    def __init__(self) -> None:
        self.total = torch.zeros(3, dtype=torch.float64)
        self.count = torch.zeros((), dtype=torch.float64)
        self.samples: list[Tensor] = []

    def update(self, target: Tensor, mask: Tensor) -> None:
        m = mask.bool()
        self.total += target.movedim(1, -1)[m].to(torch.float64).sum(0).cpu()
        self.count += m.sum().to(torch.float64).cpu()
        for flow, mi in zip(target, m):  # loop over images
            v = flow.movedim(0, -1)[mi].to(torch.float64).cpu()
            if len(v) > FLOW_SAMPLES_PER_IMAGE:
                v = v[torch.linspace(0, len(v) - 1, FLOW_SAMPLES_PER_IMAGE).round().long()]
            self.samples.append(v)

    @property
    def mean_m(self) -> Tensor:
        self._need_pixels(self.count)
        return self.total / self.count

    @property
    def median_m(self) -> Tensor:
        """Geometric median of the sampled train flow: the constant with the smallest endpoint error."""
        self._need_pixels(self.count)
        return geometric_median(torch.cat(self.samples))

    def fitted(self) -> dict[str, Any]:
        return {"mean_flow_m": self.mean_m.tolist(), "median_flow_m": self.median_m.tolist()}

    def predictions(self, target: Tensor, mask: Tensor, generator: torch.Generator) -> dict[str, Tensor]:
        mean = self.mean_m.to(target.device, target.dtype).view(1, 3, 1, 1)
        median = self.median_m.to(target.device, target.dtype).view(1, 3, 1, 1)
        return {
            "zero": torch.zeros_like(target),
            "mean": mean.expand_as(target).clone(),
            "median": median.expand_as(target).clone(),
        }


BASELINES: dict[str, type[TrivialBaselines]] = {
    "collision": CollisionBaselines,
    "gravity": GravityBaselines,
    "scene_flow": SceneFlowBaselines,
}


BASELINE_LABELS: dict[str, str] = {
    "all_negative": "collision: none",
    "all_positive": "collision: everywhere",
    "train_rate": "collision: random at train rate",
    "constant": "gravity: mean direction, median magnitude",
    "zero": "flow: zero",
    "mean": "flow: train mean",
    "median": "flow: train geometric median",
}
"""How tables name each baseline."""


def skill(value: float | None, reference: float | None, optimum: float) -> float:
    """(value - reference) / (optimum - reference); NaN when either is missing or the reference is perfect."""
    if value is None or reference is None or not (math.isfinite(value) and math.isfinite(reference)):
        return math.nan
    gap = optimum - reference
    return math.nan if gap == 0 else (value - reference) / gap


@dataclass
class BaselineResults:
    """Fitted constants, every baseline's metrics per split, and the best baseline per split and metric."""

    fitted: dict[str, Any]
    scores: dict[str, dict[str, dict[str, float]]]
    """split -> baseline -> metric -> value."""
    best: dict[str, dict[str, dict[str, Any]]] = field(default_factory=dict)
    """split -> metric -> {"baseline": name, "value": value}."""
    optimum: dict[str, float] = field(default_factory=dict)
    """metric -> value of a perfect prediction."""

    def reference(self, split: str) -> dict[str, float]:
        """metric -> best baseline value on ``split``."""
        return {k: v["value"] for k, v in self.best.get(split, {}).items()}

    def skill(self, split: str, values: Mapping[str, float | None]) -> dict[str, float]:
        """metric -> skill of ``values`` over the best baseline of ``split``, plus "mean" over the metrics."""
        ref = self.reference(split)
        out = {k: skill(values.get(k), ref.get(k), opt) for k, opt in self.optimum.items()}
        finite = [v for v in out.values() if math.isfinite(v)]
        out["mean"] = sum(finite) / len(finite) if len(finite) == len(out) else math.nan
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"fitted": self.fitted, "scores": self.scores, "best": self.best}


def _best(scores: dict[str, dict[str, float]], metrics: Mapping[str, Metric]) -> dict[str, dict[str, Any]]:
    out: dict[str, dict[str, Any]] = {}
    for metric, obj in metrics.items():
        candidates = [(name, v[metric]) for name, v in scores.items() if math.isfinite(v[metric])]
        if not candidates:
            continue
        pick = max if obj.higher_is_better else min
        name, value = pick(candidates, key=lambda c: c[1])
        out[metric] = {"baseline": name, "value": value}
    return out


def evaluate_baselines(
    task_name: str,
    metrics_factory: Callable[[], dict[str, Metric]],
    train: Batches,
    splits: Mapping[str, Batches],
    seed: int = 0,
) -> BaselineResults:
    """Fit the task's trivial baselines on ``train`` and score them on every split of ``splits``.

    Random baselines draw from a generator seeded with ``seed`` per split (reproducible for a fixed
    batch order).
    """
    try:
        baselines = BASELINES[task_name]()
    except KeyError:
        known = ", ".join(BASELINES)
        raise ValueError(f"no trivial baselines for task {task_name!r}; known: {known}") from None
    for target, mask in train:
        baselines.update(target, mask)
    prototype = metrics_factory()
    results = BaselineResults(
        fitted=baselines.fitted(),
        scores={},
        optimum={k: float(getattr(m, "optimum", math.nan)) for k, m in prototype.items()},
    )
    for split, batches in splits.items():
        generator = torch.Generator().manual_seed(int(seed))
        per_baseline = {name: metrics_factory() for name in baselines.names}
        for target, mask in batches:
            for name, pred in baselines.predictions(target, mask, generator).items():
                for metric in per_baseline[name].values():
                    metric.update(pred, target, mask)
        results.scores[split] = {
            name: {k: float(m.compute()) for k, m in metrics.items()}
            for name, metrics in per_baseline.items()
        }
        results.best[split] = _best(results.scores[split], prototype)
    return results
