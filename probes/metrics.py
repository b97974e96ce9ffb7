"""Per-pixel physics metrics on object pixels of the last frame.

One formula, two doors: every metric has a functional core (``*_update``
returns running sums and counts for one batch, ``*_compute`` turns the summed
state into the value) and a torchmetrics :class:`~torchmetrics.Metric` class
that stores the same sums and counts with ``dist_reduce_fx="sum"`` and calls
the same helpers, so distributed reduction is exact.

Averaging
---------
* ``CollisionF1`` pools true/false positives and false negatives over **all
  object pixels of all images** (per-pixel F1, what ``BinaryF1Score`` gives on
  the masked pixels). When there is no positive in the targets and none in the
  predictions (``tp + fp + fn == 0``) the F1 is ``zero_division`` (0.0 by
  default, as torchmetrics). Given ``thresholds`` it takes contact scores and
  keeps the sums per threshold (a precision-recall curve in sums and counts);
  its value is then the F1 of the best threshold.
* The vector errors (``GravityAngularError`` in degrees, ``GravityMagnitudeError``
  in N, ``SceneFlowEPE`` in m) are averaged **per image first** (mean over that
  image's valid pixels), **then over images**. An image with no valid pixel
  contributes nothing (it is not counted); when no image of the whole epoch has
  a valid pixel the value is NaN.
* Every metric class names the value of a perfect prediction (``optimum``:
  1 for F1, 0 for errors); skill scores (:mod:`probes.baselines`) measure the
  way from a trivial baseline to it.
* Valid pixels: object pixels (``mask`` True). For the angular error, pixels
  whose ground-truth vector has zero length (``|g| <= ZERO_LENGTH_EPS``) are
  excluded too: their direction is undefined. A zero-length *prediction* has
  cosine 0 with any direction, i.e. an error of 90 degrees. The cosine is
  clamped to [-1, 1] before ``acos``.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import torch
from torch import Tensor, nn
from torchmetrics import Metric

ZERO_LENGTH_EPS: float = 1e-8
"""Vectors with a norm at or below this (in their own unit) count as zero-length."""


# --------------------------------------------------------------------------- #
# Input checks
# --------------------------------------------------------------------------- #
def _check_vector_inputs(preds: Tensor, target: Tensor, mask: Tensor) -> None:
    if preds.shape != target.shape:
        raise ValueError(f"preds shape {tuple(preds.shape)} must equal target shape {tuple(target.shape)}")
    if preds.ndim != 4 or preds.shape[1] != 3:
        raise ValueError(f"preds must be (B, 3, H, W), got shape {tuple(preds.shape)}")
    expected = (preds.shape[0], *preds.shape[2:])
    if tuple(mask.shape) != expected:
        raise ValueError(f"mask must be (B, H, W) = {expected}, got shape {tuple(mask.shape)}")


def _check_scalar_inputs(preds: Tensor, target: Tensor, mask: Tensor) -> None:
    if preds.shape != target.shape or preds.shape != mask.shape:
        raise ValueError(
            f"preds, target and mask must share one (B, H, W) shape, got "
            f"{tuple(preds.shape)}, {tuple(target.shape)}, {tuple(mask.shape)}"
        )
    if preds.ndim != 3:
        raise ValueError(f"preds must be (B, H, W), got shape {tuple(preds.shape)}")


def _gather(preds: Tensor, target: Tensor, mask: Tensor) -> tuple[Tensor, Tensor, Tensor]:
    """Object-pixel vectors (N, 3) of preds and target in float64, and the image index (N,) of each.

    Errors are computed on these pixels only (objects cover a fraction of the image)."""
    m = mask.bool()
    image = m.nonzero()[:, 0]
    p = preds.movedim(1, -1)[m].to(torch.float64)
    g = target.movedim(1, -1)[m].to(torch.float64)
    return p, g, image


def _per_image_mean(err: Tensor, image: Tensor, num_images: int) -> tuple[Tensor, Tensor]:
    """Sum over images of the per-image mean error, and the number of images with a pixel.

    err: (N,) errors of valid pixels; image: (N,) their image index in [0, num_images).
    Returns (sum of per-image means, count of images) as float64 scalars.
    """
    n = torch.bincount(image, minlength=num_images).to(torch.float64)
    s = torch.zeros(num_images, dtype=torch.float64, device=err.device)
    s.index_add_(0, image, err.to(torch.float64))
    has = n > 0
    means = s[has] / n[has]
    return means.sum(), has.sum().to(torch.float64)


def _mean_from_state(total: Tensor, count: Tensor) -> Tensor:
    if count <= 0:
        return torch.tensor(math.nan, dtype=torch.float64)
    return total / count


# --------------------------------------------------------------------------- #
# Functional cores
# --------------------------------------------------------------------------- #
def collision_f1_update(
    preds: Tensor, target: Tensor, mask: Tensor, thresholds: Tensor | None = None
) -> tuple[Tensor, Tensor, Tensor]:
    """True positives, false positives, false negatives over object pixels.

    preds: (B, H, W) bool (or {0,1}) predicted contact -- or, with ``thresholds`` (T,) increasing,
    contact scores (probabilities) that count as positive where ``score > threshold``: the sums
    are then (T,), one per threshold. target: (B, H, W) {0,1}; mask: (B, H, W) bool.
    """
    _check_scalar_inputs(preds, target, mask)
    m = mask.bool()
    t = target.bool() & m
    if thresholds is None:
        p = preds.bool() & m
        tp = (p & t).sum().to(torch.float64)
        fp = (p & ~t).sum().to(torch.float64)
        fn = (~p & t & m).sum().to(torch.float64)
        return tp, fp, fn
    thr = _check_thresholds(thresholds).to(preds.device)
    scores = preds[m].to(torch.float64)
    positive = t[m]
    # bin k holds scores above exactly k thresholds; a pixel is predicted positive at threshold j iff k > j
    bins = torch.searchsorted(thr, scores, right=False)
    hist_pos = torch.bincount(bins[positive], minlength=len(thr) + 1).to(torch.float64)
    hist_neg = torch.bincount(bins[~positive], minlength=len(thr) + 1).to(torch.float64)
    tp = hist_pos.flip(0).cumsum(0).flip(0)[1:]  # positives in bins j+1 .. T
    fp = hist_neg.flip(0).cumsum(0).flip(0)[1:]
    fn = hist_pos.sum() - tp
    return tp.cpu(), fp.cpu(), fn.cpu()


def _check_thresholds(thresholds: Tensor) -> Tensor:
    thr = torch.as_tensor(thresholds, dtype=torch.float64).reshape(-1)
    if thr.numel() == 0 or not bool(torch.all(thr[1:] > thr[:-1])):
        raise ValueError(f"thresholds must be a non-empty, strictly increasing sequence, got {thr.tolist()}")
    return thr


def collision_f1_compute(tp: Tensor, fp: Tensor, fn: Tensor, zero_division: float = 0.0) -> Tensor:
    """F1 = 2 tp / (2 tp + fp + fn) (elementwise for per-threshold sums); ``zero_division`` where the
    denominator is 0."""
    denom = 2 * tp + fp + fn
    return torch.where(
        denom > 0, 2 * tp / denom.clamp_min(1.0), torch.full_like(denom, float(zero_division))
    ).to(torch.float64)


def collision_f1(
    preds: Tensor, target: Tensor, mask: Tensor, zero_division: float = 0.0, thresholds: Tensor | None = None
) -> Tensor:
    """Per-pixel F1 of predicted contact over object pixels (see module docstring); (T,) per threshold
    when ``thresholds`` are given (``preds`` are then scores)."""
    return collision_f1_compute(
        *collision_f1_update(preds, target, mask, thresholds), zero_division=zero_division
    )


def _angle_deg(p: Tensor, g: Tensor, dim: int) -> Tensor:
    """Angle between vectors along ``dim`` in degrees (float64); cosine clamped to [-1, 1]; 90 degrees
    for a zero vector."""
    p = p.to(torch.float64)
    g = g.to(torch.float64)
    dot = (p * g).sum(dim)
    norms = p.norm(dim=dim) * g.norm(dim=dim)
    cos = torch.where(
        norms > 0, dot / norms.clamp_min(torch.finfo(torch.float64).tiny), torch.zeros_like(dot)
    )
    return torch.rad2deg(torch.acos(cos.clamp(-1.0, 1.0)))


def angular_error_deg(preds: Tensor, target: Tensor) -> Tensor:
    """Angle between (B, 3, H, W) vectors in degrees, (B, H, W); cosine clamped to [-1, 1]."""
    return _angle_deg(preds, target, dim=1)


def gravity_angular_error_update(preds: Tensor, target: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """(sum of per-image mean angular errors in degrees, number of images with a valid pixel)."""
    _check_vector_inputs(preds, target, mask)
    p, g, image = _gather(preds, target, mask)
    keep = g.norm(dim=1) > ZERO_LENGTH_EPS
    return _per_image_mean(_angle_deg(p[keep], g[keep], dim=1), image[keep], preds.shape[0])


def gravity_magnitude_error_update(preds: Tensor, target: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """(sum of per-image mean | |p| - |g| | in N, number of images with an object pixel)."""
    _check_vector_inputs(preds, target, mask)
    p, g, image = _gather(preds, target, mask)
    return _per_image_mean((p.norm(dim=1) - g.norm(dim=1)).abs(), image, preds.shape[0])


def scene_flow_epe_update(preds: Tensor, target: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """(sum of per-image mean endpoint error |p - g| in m, number of images with an object pixel)."""
    _check_vector_inputs(preds, target, mask)
    p, g, image = _gather(preds, target, mask)
    return _per_image_mean((p - g).norm(dim=1), image, preds.shape[0])


def gravity_angular_error(preds: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    """Mean angular error in degrees, per image then over images (NaN when no valid pixel)."""
    return _mean_from_state(*gravity_angular_error_update(preds, target, mask))


def gravity_magnitude_error(preds: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    """Mean magnitude error in N, per image then over images (NaN when no object pixel)."""
    return _mean_from_state(*gravity_magnitude_error_update(preds, target, mask))


def scene_flow_epe(preds: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    """Average endpoint error in m, per image then over images (NaN when no object pixel)."""
    return _mean_from_state(*scene_flow_epe_update(preds, target, mask))


# --------------------------------------------------------------------------- #
# Metric classes
# --------------------------------------------------------------------------- #
class CollisionF1(Metric):
    """Per-pixel F1 of contact on object pixels, pooled over all images (see module docstring).

    Without ``thresholds`` it scores bool decisions. With ``thresholds`` (increasing scores in
    [0, 1)) it takes contact scores, keeps tp / fp / fn per threshold, and ``compute`` gives the F1
    of the best threshold (:meth:`best_threshold`): how a decision threshold is calibrated on
    validation.
    """

    is_differentiable = False
    higher_is_better = True
    full_state_update = False
    optimum = 1.0

    def __init__(
        self, zero_division: float = 0.0, thresholds: Sequence[float] | Tensor | None = None, **kwargs
    ) -> None:
        super().__init__(**kwargs)
        if zero_division not in (0.0, 1.0):
            raise ValueError(f"zero_division must be 0.0 or 1.0, got {zero_division!r}")
        self.zero_division = float(zero_division)
        self.thresholds = None
        if thresholds is not None:
            self.thresholds = _check_thresholds(torch.as_tensor(thresholds, dtype=torch.float64))
        shape = () if self.thresholds is None else (len(self.thresholds),)
        for name in ("tp", "fp", "fn"):
            self.add_state(name, default=torch.zeros(shape, dtype=torch.float64), dist_reduce_fx="sum")

    def update(self, preds: Tensor, target: Tensor, mask: Tensor) -> None:
        tp, fp, fn = collision_f1_update(preds, target, mask, self.thresholds)
        self.tp += tp.to(self.tp.device)
        self.fp += fp.to(self.fp.device)
        self.fn += fn.to(self.fn.device)

    def f1_per_threshold(self) -> Tensor:
        """F1 of every threshold (a 0-d tensor without thresholds)."""
        return collision_f1_compute(self.tp, self.fp, self.fn, self.zero_division)

    def best_threshold(self) -> float:
        """The (lowest) threshold with the highest F1 on the data seen so far."""
        if self.thresholds is None:
            raise ValueError("best_threshold needs a CollisionF1 built with thresholds=...")
        return float(self.thresholds[int(torch.argmax(self.f1_per_threshold()))])

    def compute(self) -> Tensor:
        f1 = self.f1_per_threshold()
        return f1 if self.thresholds is None else f1.max()


class _PerImageMeanMetric(Metric):
    """Shared state of the per-image-then-over-images vector errors."""

    is_differentiable = False
    higher_is_better = False
    full_state_update = False
    optimum = 0.0

    def __init__(self, **kwargs) -> None:
        super().__init__(**kwargs)
        self.add_state("total", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("count", default=torch.tensor(0.0, dtype=torch.float64), dist_reduce_fx="sum")

    @staticmethod
    def _update_fn(preds: Tensor, target: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
        raise NotImplementedError

    def update(self, preds: Tensor, target: Tensor, mask: Tensor) -> None:
        total, count = self._update_fn(preds, target, mask)
        self.total += total
        self.count += count

    def compute(self) -> Tensor:
        return _mean_from_state(self.total, self.count)


class GravityAngularError(_PerImageMeanMetric):
    """Mean angle between predicted and true gravity force, degrees (zero-length truths excluded)."""

    _update_fn = staticmethod(gravity_angular_error_update)


class GravityMagnitudeError(_PerImageMeanMetric):
    """Mean absolute difference of gravity force magnitudes, N."""

    _update_fn = staticmethod(gravity_magnitude_error_update)


class SceneFlowEPE(_PerImageMeanMetric):
    """Average endpoint error of scene flow, m."""

    _update_fn = staticmethod(scene_flow_epe_update)


class ParameterSweep(Metric):
    """One metric evaluated at every value of a decision parameter: how a task calibrates on validation.

    ``predict_at(scores, value)`` turns what the task hands over (its raw head output, say) into the
    metric's predictions for one parameter value; each value keeps its own metric (sums and counts).
    ``compute`` gives the best value over the grid (direction from the metric), :meth:`best_parameter`
    the parameter that reaches it (the lowest one of ties).
    """

    is_differentiable = False
    full_state_update = False

    def __init__(
        self,
        metric_factory: Callable[[], Metric],
        predict_at: Callable[[Tensor, float], Tensor],
        grid: Sequence[float],
        **kwargs,
    ) -> None:
        super().__init__(**kwargs)
        if len(grid) == 0:
            raise ValueError("grid must hold at least one parameter value")
        self.grid = tuple(float(v) for v in grid)
        self.predict_at = predict_at
        self.sweep = nn.ModuleList(metric_factory() for _ in self.grid)
        self.maximize = bool(self.sweep[0].higher_is_better)

    def update(self, scores: Tensor, target: Tensor, mask: Tensor) -> None:
        for value, metric in zip(self.grid, self.sweep):
            metric.update(self.predict_at(scores, value), target, mask)

    def values(self) -> Tensor:
        """The metric at every grid value (float64)."""
        return torch.stack([m.compute().to(torch.float64).reshape(()) for m in self.sweep])

    def best_parameter(self) -> float:
        v = self.values()
        v = torch.where(torch.isnan(v), torch.tensor(-math.inf if self.maximize else math.inf), v)
        return self.grid[int(torch.argmax(v) if self.maximize else torch.argmin(v))]

    def compute(self) -> Tensor:
        return self.values()[self.grid.index(self.best_parameter())]

    def reset(self) -> None:
        super().reset()
        for metric in self.sweep:
            metric.reset()
