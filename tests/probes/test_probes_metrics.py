"""Metrics: hand-computed values, edge cases, class == functional == NumPy reference, torchmetrics F1."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from torchmetrics.classification import BinaryF1Score

from probes import metrics as M


def _vec_map(
    vectors: dict[tuple[int, int], tuple[float, float, float]], h: int = 2, w: int = 2
) -> torch.Tensor:
    out = torch.zeros(1, 3, h, w, dtype=torch.float64)
    for (i, j), v in vectors.items():
        out[0, :, i, j] = torch.tensor(v, dtype=torch.float64)
    return out


# --------------------------------------------------------------------------- #
# NumPy references (written independently of the torch code)
# --------------------------------------------------------------------------- #
def np_f1(pred: np.ndarray, target: np.ndarray, mask: np.ndarray) -> float:
    p, t = pred[mask].astype(bool), target[mask].astype(bool)
    tp = np.sum(p & t)
    fp = np.sum(p & ~t)
    fn = np.sum(~p & t)
    return 0.0 if 2 * tp + fp + fn == 0 else 2 * tp / (2 * tp + fp + fn)


def np_per_image(err_fn, pred: np.ndarray, target: np.ndarray, mask: np.ndarray, skip_zero_gt: bool = False):
    means = []
    for b in range(pred.shape[0]):
        p = pred[b].reshape(3, -1).T
        g = target[b].reshape(3, -1).T
        m = mask[b].reshape(-1).copy()
        if skip_zero_gt:
            m &= np.linalg.norm(g, axis=1) > M.ZERO_LENGTH_EPS
        if m.sum() == 0:
            continue
        means.append(np.mean(err_fn(p[m], g[m])))
    return float(np.mean(means)) if means else math.nan


def np_angle(p, g):
    cos = np.sum(p * g, 1) / np.maximum(np.linalg.norm(p, axis=1) * np.linalg.norm(g, axis=1), 1e-300)
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def np_mag(p, g):
    return np.abs(np.linalg.norm(p, axis=1) - np.linalg.norm(g, axis=1))


def np_epe(p, g):
    return np.linalg.norm(p - g, axis=1)


# --------------------------------------------------------------------------- #
# Hand-computed values
# --------------------------------------------------------------------------- #
def test_angular_error_hand_values():
    g = _vec_map({(0, 0): (0, 0, -9.81), (0, 1): (0, 0, -9.81), (1, 0): (1, 0, 0), (1, 1): (0, 2, 0)})
    p = _vec_map({(0, 0): (0, 0, -1), (0, 1): (1, 0, 0), (1, 0): (-3, 0, 0), (1, 1): (0, 1, 1)})
    mask = torch.ones(1, 2, 2, dtype=torch.bool)
    # per pixel: 0, 90, 180, 45 degrees -> mean 78.75
    assert M.gravity_angular_error(p, g, mask).item() == pytest.approx(78.75, abs=1e-9)
    # only the first row: (0 + 90) / 2
    mask_row = torch.tensor([[[True, True], [False, False]]])
    assert M.gravity_angular_error(p, g, mask_row).item() == pytest.approx(45.0, abs=1e-9)


def test_angular_error_parallel_vectors_clamped_no_nan():
    # cosine of nearly parallel float32 vectors can exceed 1 by rounding; the clamp keeps acos finite
    g = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float32).view(1, 3, 1, 1).repeat(1, 1, 4, 4)
    p = g * 7.0
    mask = torch.ones(1, 4, 4, dtype=torch.bool)
    val = M.gravity_angular_error(p, g, mask).item()
    assert math.isfinite(val) and val == pytest.approx(0.0, abs=1e-5)


def test_zero_length_ground_truth_excluded_from_angle_but_not_magnitude():
    g = _vec_map({(0, 0): (0, 0, -10), (0, 1): (0, 0, 0)}, h=1, w=2)
    p = _vec_map({(0, 0): (0, 0, -10), (0, 1): (3, 4, 0)}, h=1, w=2)
    mask = torch.ones(1, 1, 2, dtype=torch.bool)
    assert M.gravity_angular_error(p, g, mask).item() == pytest.approx(0.0, abs=1e-9)
    # magnitudes: |10-10| = 0 and |5 - 0| = 5 -> mean 2.5 N
    assert M.gravity_magnitude_error(p, g, mask).item() == pytest.approx(2.5)
    # only zero-length truths: angle undefined -> NaN, magnitude defined
    mask2 = torch.tensor([[[False, True]]])
    assert math.isnan(M.gravity_angular_error(p, g, mask2).item())
    assert M.gravity_magnitude_error(p, g, mask2).item() == pytest.approx(5.0)


def test_zero_length_prediction_counts_90_degrees():
    g = _vec_map({(0, 0): (0, 0, -9.81)}, h=1, w=1)
    p = torch.zeros_like(g)
    assert M.gravity_angular_error(p, g, torch.ones(1, 1, 1, dtype=torch.bool)).item() == pytest.approx(90.0)


def test_small_gravity_forces_are_not_zero_length():
    """A 1 g object weighs 9.81e-3 N: its direction counts (only |g| <= ZERO_LENGTH_EPS = 1e-8 N is
    undefined), so a prediction pointing up is 180 degrees off, not skipped."""
    g = _vec_map({(0, 0): (0, 0, -9.81e-3), (0, 1): (0, 0, -2e-6)}, h=1, w=2)
    p = _vec_map({(0, 0): (0, 0, 1.0), (0, 1): (0, 0, 1.0)}, h=1, w=2)
    assert M.gravity_angular_error(p, g, torch.ones(1, 1, 2, dtype=torch.bool)).item() == pytest.approx(180.0)


def test_per_image_then_over_images_averaging():
    # image 0: 1 object pixel with EPE 4; image 1: 3 pixels with EPE 1 -> per image (4 + 1)/2 = 2.5
    # (per-pixel pooling would give (4 + 3)/4 = 1.75)
    g = torch.zeros(2, 3, 2, 2, dtype=torch.float64)
    p = torch.zeros_like(g)
    p[0, 0, 0, 0] = 4.0
    p[1, 1, :, :] = 1.0
    mask = torch.tensor([[[True, False], [False, False]], [[True, True], [True, False]]])
    assert M.scene_flow_epe(p, g, mask).item() == pytest.approx(2.5)
    metric = M.SceneFlowEPE()
    metric.update(p[:1], g[:1], mask[:1])
    metric.update(p[1:], g[1:], mask[1:])
    assert metric.compute().item() == pytest.approx(2.5)


def test_images_without_object_pixels_are_skipped_and_empty_is_nan():
    g = torch.zeros(2, 3, 2, 2)
    p = torch.ones(2, 3, 2, 2)  # EPE sqrt(3) everywhere
    mask = torch.zeros(2, 2, 2, dtype=torch.bool)
    mask[1, 0, 0] = True
    assert M.scene_flow_epe(p, g, mask).item() == pytest.approx(math.sqrt(3))
    metric = M.SceneFlowEPE()
    metric.update(p, g, torch.zeros_like(mask))
    assert math.isnan(metric.compute().item())
    assert metric.count.item() == 0


def test_collision_f1_hand_values_and_edge_cases():
    target = torch.tensor([[[1, 1, 0, 0], [0, 0, 0, 1]]], dtype=torch.float32)
    pred = torch.tensor([[[1, 0, 1, 0], [0, 0, 0, 1]]], dtype=torch.bool)
    mask = torch.tensor([[[1, 1, 1, 1], [0, 0, 0, 0]]], dtype=torch.bool)
    # on the mask: tp=1, fp=1, fn=1 -> F1 = 2/4 = 0.5 (the masked-out true positive is ignored)
    assert M.collision_f1(pred, target, mask).item() == pytest.approx(0.5)
    # all-negative targets and predictions: tp+fp+fn = 0 -> zero_division (0 by default, like torchmetrics)
    zeros = torch.zeros(1, 2, 4)
    assert M.collision_f1(zeros.bool(), zeros, mask).item() == 0.0
    assert M.collision_f1(zeros.bool(), zeros, mask, zero_division=1.0).item() == 1.0
    # all-negative targets, some positive predictions: F1 = 0
    assert M.collision_f1(pred, zeros, mask).item() == 0.0
    # no object pixels at all
    assert M.CollisionF1()(pred, target, torch.zeros_like(mask)).item() == 0.0


def test_collision_f1_matches_torchmetrics_binary_f1_on_masked_pixels():
    gen = torch.Generator().manual_seed(3)
    metric = M.CollisionF1()
    reference = BinaryF1Score()
    preds_all, target_all, mask_all = [], [], []
    for _ in range(4):
        pred = torch.rand(3, 8, 8, generator=gen) > 0.6
        target = (torch.rand(3, 8, 8, generator=gen) > 0.7).float()
        mask = torch.rand(3, 8, 8, generator=gen) > 0.3
        metric.update(pred, target, mask)
        reference.update(pred[mask].long(), target[mask].long())
        preds_all.append(pred), target_all.append(target), mask_all.append(mask)
    ours = metric.compute().item()
    assert ours == pytest.approx(reference.compute().item(), abs=1e-6)
    p, t, m = (torch.cat(x).numpy() for x in (preds_all, target_all, mask_all))
    assert ours == pytest.approx(np_f1(p, t, m), abs=1e-12)
    assert ours == pytest.approx(
        M.collision_f1(torch.cat(preds_all), torch.cat(target_all), torch.cat(mask_all)).item(), abs=1e-12
    )


@pytest.mark.parametrize(
    "cls, fn, np_err, skip_zero",
    [
        (M.GravityAngularError, M.gravity_angular_error, np_angle, True),
        (M.GravityMagnitudeError, M.gravity_magnitude_error, np_mag, False),
        (M.SceneFlowEPE, M.scene_flow_epe, np_epe, False),
    ],
)
def test_class_equals_functional_equals_numpy(cls, fn, np_err, skip_zero):
    gen = torch.Generator().manual_seed(7)
    p = torch.randn(5, 3, 6, 7, generator=gen)
    g = torch.randn(5, 3, 6, 7, generator=gen)
    g[:, :, 0, 0] = 0.0  # zero-length truths
    mask = torch.rand(5, 6, 7, generator=gen) > 0.5
    mask[2] = False  # an image without object pixels
    metric = cls()
    for b in range(0, 5, 2):  # uneven batches
        metric.update(p[b : b + 2], g[b : b + 2], mask[b : b + 2])
    expected = np_per_image(
        np_err, p.numpy().astype(np.float64), g.numpy().astype(np.float64), mask.numpy(), skip_zero
    )
    assert metric.compute().item() == pytest.approx(expected, rel=1e-9)
    assert fn(p, g, mask).item() == pytest.approx(expected, rel=1e-9)


def test_state_is_sum_and_count_reduced_by_sum():
    metric = M.GravityMagnitudeError()
    assert metric._reductions["total"] is not None and metric._reductions["count"] is not None
    # two halves merged by summing states equal one pass over everything (what DDP reduction does)
    gen = torch.Generator().manual_seed(0)
    p, g = torch.randn(4, 3, 3, 3, generator=gen), torch.randn(4, 3, 3, 3, generator=gen)
    mask = torch.ones(4, 3, 3, dtype=torch.bool)
    a, b = M.GravityMagnitudeError(), M.GravityMagnitudeError()
    a.update(p[:1], g[:1], mask[:1])
    b.update(p[1:], g[1:], mask[1:])
    merged = (a.total + b.total) / (a.count + b.count)
    assert merged.item() == pytest.approx(M.gravity_magnitude_error(p, g, mask).item(), rel=1e-12)


def test_bad_shapes_name_the_shapes():
    with pytest.raises(ValueError, match=r"\(B, 3, H, W\)"):
        M.scene_flow_epe(
            torch.zeros(1, 2, 4, 4), torch.zeros(1, 2, 4, 4), torch.ones(1, 4, 4, dtype=torch.bool)
        )
    with pytest.raises(ValueError, match="mask must be"):
        M.scene_flow_epe(
            torch.zeros(1, 3, 4, 4), torch.zeros(1, 3, 4, 4), torch.ones(1, 4, 5, dtype=torch.bool)
        )
    with pytest.raises(ValueError, match="zero_division"):
        M.CollisionF1(zero_division=0.5)
