"""Trivial baselines: hand-computed metric values on hand-made targets and masks, skill, threshold calibration."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from probes import metrics as M
from probes.baselines import (
    CollisionBaselines,
    GravityBaselines,
    SceneFlowBaselines,
    evaluate_baselines,
    geometric_median,
    skill,
    weighted_lower_median,
)
from probes.tasks import build_task


def _evaluate(task_name: str, train, splits, seed: int = 0):
    return evaluate_baselines(task_name, build_task(task_name).metrics, train, splits, seed=seed)


# --------------------------------------------------------------------------- #
def test_collision_baselines_hand_values():
    # one 2x4 image: 2 contacts among 6 object pixels; the last column is background (a contact there is ignored)
    target = torch.tensor([[[1, 1, 0, 1], [0, 0, 0, 1]]], dtype=torch.float32)
    mask = torch.tensor([[[1, 1, 1, 0], [1, 1, 1, 0]]], dtype=torch.bool)
    res = _evaluate("collision", [(target, mask)], {"val": [(target, mask)]})
    assert res.fitted == {"positive_rate": pytest.approx(2 / 6)}
    scores = res.scores["val"]
    # all positive: tp 2, fp 4, fn 0 -> F1 = 4 / (4 + 4) = 0.5 (= 2 p / (1 + p) with p = 1/3)
    assert scores["all_positive"]["collision_f1"] == pytest.approx(0.5)
    assert scores["all_negative"]["collision_f1"] == 0.0
    assert res.best["val"]["collision_f1"] == {"baseline": "all_positive", "value": pytest.approx(0.5)}


def test_collision_train_rate_is_the_expected_random_f1_and_seeded():
    gen = torch.Generator().manual_seed(1)
    train = (torch.rand(1, 200, 200, generator=gen) < 0.1).float()  # rate q ~ 0.1
    val = (torch.rand(1, 200, 200, generator=gen) < 0.3).float()  # rate p ~ 0.3
    mask = torch.ones(1, 200, 200, dtype=torch.bool)
    a = _evaluate("collision", [(train, mask)], {"val": [(val, mask)]}, seed=4)
    b = _evaluate("collision", [(train, mask)], {"val": [(val, mask)]}, seed=4)
    q, p = a.fitted["positive_rate"], val.mean().item()
    f1 = a.scores["val"]["train_rate"]["collision_f1"]
    # random decisions at rate q on data at rate p: E[F1] ~ 2 q p / (q + p) (40k pixels: within 3 %)
    assert f1 == pytest.approx(2 * q * p / (q + p), rel=0.03)
    assert b.scores["val"]["train_rate"]["collision_f1"] == f1


def test_gravity_constant_is_train_mean_direction_and_median_magnitude():
    # train: image 0 has three pixels of a 10 N object pulled along -z, image 1 one pixel of 30 N along -y
    g = torch.zeros(2, 3, 1, 3)
    g[0, 2] = -10.0
    g[1, 1, 0, 0] = -30.0
    mask = torch.zeros(2, 1, 3, dtype=torch.bool)
    mask[0] = True
    mask[1, 0, 0] = True
    fit = GravityBaselines()
    fit.update(g, mask)
    # unit vectors: 3 x (0, 0, -1) + 1 x (0, -1, 0) -> (0, -1, -3) / sqrt(10); magnitudes [10, 10, 10, 30] -> 10
    np.testing.assert_allclose(fit.fitted()["direction"], np.array([0, -1, -3]) / math.sqrt(10), atol=1e-12)
    assert fit.fitted()["median_magnitude_n"] == 10.0
    res = _evaluate("gravity", [(g, mask)], {"test": [(g, mask)]})
    s = res.scores["test"]["constant"]
    # per image then over images: image 0 atan(1/3) = 18.43 deg, 0 N; image 1 acos(1/sqrt(10)) = 71.57 deg, 20 N
    ang = (math.degrees(math.atan(1 / 3)) + math.degrees(math.acos(1 / math.sqrt(10)))) / 2
    assert s["gravity_angular_error_deg"] == pytest.approx(ang, rel=1e-6)  # float32 predictions
    assert s["gravity_magnitude_error_n"] == pytest.approx(10.0, rel=1e-6)


def test_weighted_lower_median_matches_torch_median_of_the_expansion():
    gen = torch.Generator().manual_seed(0)
    for n in (1, 2, 5, 8):
        values = torch.rand(n, generator=gen, dtype=torch.float64) * 50
        counts = torch.randint(1, 6, (n,), generator=gen)
        expanded = values.repeat_interleave(counts)
        assert weighted_lower_median(values, counts) == torch.median(expanded).item()


def test_gravity_magnitude_table_merges_batches():
    a, b = GravityBaselines(), GravityBaselines()
    g = torch.zeros(4, 3, 2, 2)
    g[:, 2] = torch.tensor([-5.0, -7.0, -5.0, -40.0]).view(4, 1, 1)
    mask = torch.ones(4, 2, 2, dtype=torch.bool)
    a.update(g, mask)
    for i in range(4):
        b.update(g[i : i + 1], mask[i : i + 1])
    assert a.median_magnitude_n == b.median_magnitude_n == 5.0  # [5 x 8, 7 x 4, 40 x 4]: lower median 5
    assert b.counts.tolist() == [8.0, 4.0, 4.0]


def test_scene_flow_zero_and_mean_hand_values():
    f = torch.zeros(2, 3, 1, 2)
    f[0, 0] = 0.03  # image 0: both pixels move 3 cm along x
    f[1, 1, 0, 0] = -0.04  # image 1: one object pixel 4 cm along -y, the other pixel is background
    mask = torch.tensor([[[True, True]], [[True, False]]])
    res = _evaluate("scene_flow", [(f, mask)], {"val": [(f, mask)]})
    mean = np.array([0.06, -0.04, 0.0]) / 3
    np.testing.assert_allclose(res.fitted["mean_flow_m"], mean, atol=1e-12)
    # geometric median of three points: the pixel at (0.03, 0, 0) twice and (0, -0.04, 0) once -> the repeated point
    np.testing.assert_allclose(res.fitted["median_flow_m"], [0.03, 0.0, 0.0], atol=1e-7)
    s = res.scores["val"]
    assert s["zero"]["scene_flow_epe_m"] == pytest.approx((0.03 + 0.04) / 2)
    assert s["median"]["scene_flow_epe_m"] == pytest.approx((0.0 + 0.05) / 2, rel=1e-5)  # |(-0.03, -0.04, 0)|
    e0 = np.linalg.norm(np.array([0.03, 0, 0]) - mean)
    e1 = np.linalg.norm(np.array([0, -0.04, 0]) - mean)
    assert s["mean"]["scene_flow_epe_m"] == pytest.approx((e0 + e1) / 2)
    assert res.best["val"]["scene_flow_epe_m"]["baseline"] == "mean"


def test_geometric_median_hand_values():
    collinear = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [5.0, 0, 0]], dtype=torch.float64)
    np.testing.assert_allclose(geometric_median(collinear).numpy(), [1.0, 0, 0], atol=1e-7)
    # a majority at rest pulls the median onto 0 exactly, whatever the movers do
    resting = torch.tensor([[0.0, 0, 0]] * 3 + [[0.05, 0, 0], [0, 0.08, 0]], dtype=torch.float64)
    np.testing.assert_allclose(geometric_median(resting).numpy(), [0.0, 0, 0], atol=1e-7)
    # a square's corners: the centre
    square = torch.tensor([[0.0, 0], [2.0, 0], [0.0, 2], [2.0, 2]], dtype=torch.float64)
    np.testing.assert_allclose(geometric_median(square).numpy(), [1.0, 1.0], atol=1e-7)


def test_skill_hand_values_and_missing_inputs():
    assert skill(0.7, 0.4, 1.0) == pytest.approx(0.5)  # F1: half of the gap to 1 closed
    assert skill(5.0, 10.0, 0.0) == pytest.approx(0.5)  # error: half of the baseline error removed
    assert skill(16.3, 7.5, 0.0) == pytest.approx(1 - 16.3 / 7.5)  # worse than a constant: negative
    assert math.isnan(skill(None, 1.0, 0.0)) and math.isnan(skill(0.1, 0.0, 0.0))
    res = _evaluate(
        "gravity",
        [(torch.full((1, 3, 1, 1), -10.0), torch.ones(1, 1, 1, dtype=torch.bool))],
        {"val": [(torch.full((1, 3, 1, 1), -10.0), torch.ones(1, 1, 1, dtype=torch.bool))]},
    )
    out = res.skill("val", {"gravity_angular_error_deg": 1.0, "gravity_magnitude_error_n": 0.0})
    # the constant's magnitude is exact here (0 N): that skill is undefined, and so is the mean
    assert math.isnan(out["gravity_magnitude_error_n"]) and math.isnan(out["mean"])
    assert out["gravity_angular_error_deg"] < 0


def test_no_train_pixels_is_a_clear_error():
    empty = torch.zeros(1, 4, 4, dtype=torch.bool)
    for cls, target in (
        (CollisionBaselines, torch.zeros(1, 4, 4)),
        (GravityBaselines, torch.zeros(1, 3, 4, 4)),
        (SceneFlowBaselines, torch.zeros(1, 3, 4, 4)),
    ):
        fit = cls()
        fit.update(target, empty)
        with pytest.raises(ValueError, match="no object pixel"):
            fit.fitted()


# --------------------------------------------------------------------------- #
def _f1_reference(scores, target, mask, thresholds):
    s, t = scores[mask].numpy(), target[mask].numpy().astype(bool)
    out = []
    for thr in thresholds:
        p = s > thr
        tp, fp, fn = (p & t).sum(), (p & ~t).sum(), (~p & t).sum()
        out.append(2 * tp / (2 * tp + fp + fn) if 2 * tp + fp + fn else 0.0)
    return np.array(out)


def test_collision_f1_per_threshold_class_equals_function_equals_numpy():
    gen = torch.Generator().manual_seed(3)
    thresholds = (0.0, 0.25, 0.5, 0.75)
    batches = []
    for _ in range(3):
        scores = torch.rand(2, 5, 6, generator=gen)
        target = ((scores + 0.3 * torch.rand(2, 5, 6, generator=gen)) > 0.8).float()
        batches.append((scores, target, torch.rand(2, 5, 6, generator=gen) > 0.3))
    metric = M.CollisionF1(thresholds=thresholds)
    for b in batches:
        metric.update(*b)
    scores, target, mask = (torch.cat(x) for x in zip(*batches))
    ref = _f1_reference(scores, target, mask, thresholds)
    fn = M.collision_f1(scores, target, mask, thresholds=torch.tensor(thresholds))
    np.testing.assert_allclose(metric.f1_per_threshold().numpy(), ref, atol=1e-12)
    np.testing.assert_allclose(fn.numpy(), ref, atol=1e-12)
    assert metric.compute().item() == pytest.approx(ref.max())
    assert metric.best_threshold() == thresholds[int(np.argmax(ref))]
    # threshold 0 predicts contact on every object pixel: the all-positive F1
    p = target[mask].mean().item()
    assert ref[0] == pytest.approx(2 * p / (1 + p))
    with pytest.raises(ValueError, match="strictly increasing"):
        M.CollisionF1(thresholds=(0.5, 0.2))


def test_collision_task_calibrates_its_threshold_on_scores():
    task = build_task("collision")
    # contacts have logits around +1, non-contacts around -0.5: 0.5 misses nothing, 0.3 < sigmoid(-0.5) = 0.38
    logits = torch.tensor([[[[1.0, 1.2, -0.5, -0.4, -3.0, -2.5]]]])
    target = torch.tensor([[[1.0, 1.0, 0.0, 0.0, 0.0, 0.0]]])
    mask = torch.ones(1, 1, 6, dtype=torch.bool)
    metrics = task.calibration_metrics()
    metrics["collision_f1"].update(task.scores(logits), target, mask)
    task.calibrate(metrics)
    assert 0.38 <= task.threshold < 0.73  # separates sigmoid(-0.4) = 0.40 from sigmoid(1.0) = 0.73
    assert task.threshold == pytest.approx(0.41)  # the lowest threshold of the grid with F1 = 1
    assert task.decision() == {"threshold": pytest.approx(0.41)}
    other = build_task("collision")
    other.load_decision(task.decision())
    assert torch.equal(other.predict(logits), target.bool())


# --------------------------------------------------------------------------- #
def test_gravity_trust_moves_direction_and_log_magnitude_from_the_anchor():
    task = build_task("gravity", target_scale_n=10.0)
    task.set_anchor(torch.tensor([0.0, 0.0, -0.2]))  # the train constant: 2 N straight down (-z)
    out = torch.tensor([0.8, 0.0, 0.0]).view(1, 3, 1, 1)  # the head: 8 N along +x
    np.testing.assert_allclose(task.predict_with_trust(out, 1.0, 1.0).flatten(), [8.0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(task.predict_with_trust(out, 0.0, 0.0).flatten(), [0, 0, -2.0], atol=1e-6)
    # half trust: the unit vectors' normalised mean (45 deg) and the geometric mean of 2 N and 8 N (4 N)
    half = task.predict_with_trust(out, 0.5, 0.5).flatten()
    np.testing.assert_allclose(half, 4.0 * np.array([1.0, 0.0, -1.0]) / np.sqrt(2), atol=1e-5)
    # direction and magnitude are trusted separately
    np.testing.assert_allclose(task.predict_with_trust(out, 1.0, 0.0).flatten(), [2.0, 0, 0], atol=1e-6)
    task.load_decision({"trust_direction": 0.0, "trust_magnitude": 1.0})
    np.testing.assert_allclose(task.predict(out).flatten(), [0, 0, -8.0], atol=1e-5)


def test_calibration_trusts_a_head_that_helps_and_not_one_that_is_noise():
    gen = torch.Generator().manual_seed(0)
    target = torch.zeros(4, 3, 5, 5)
    target[:, 2] = -torch.tensor([2.0, 4.0, 6.0, 8.0]).view(4, 1, 1)  # four objects, 2-8 N, all along -z
    mask = torch.ones(4, 5, 5, dtype=torch.bool)
    task = build_task("gravity", target_scale_n=10.0)
    task.set_anchor(torch.tensor([0.0, 0.0, -0.5]))  # the median, 5 N down
    # the head: exact magnitudes, but a direction tilted at random by up to ~40 deg
    out = target / 10.0 + torch.cat([torch.rand(4, 2, 5, 5, generator=gen) - 0.5, torch.zeros(4, 1, 5, 5)], 1)
    out = out * (target.norm(dim=1, keepdim=True) / 10.0) / out.norm(dim=1, keepdim=True)
    metrics = task.calibration_metrics()
    for m in metrics.values():
        m.update(task.scores(out), target, mask)
    task.calibrate(metrics)
    assert task.decision() == {"trust_direction": 0.0, "trust_magnitude": 1.0}
    assert metrics["gravity_angular_error_deg"].compute().item() == pytest.approx(0.0, abs=1e-3)
    assert metrics["gravity_magnitude_error_n"].compute().item() == pytest.approx(0.0, abs=1e-4)
    # every grid value is scored like the plain metric on that prediction
    sweep = metrics["gravity_magnitude_error_n"]
    for t, value in zip(sweep.grid, sweep.values()):
        expected = M.gravity_magnitude_error(task.predict_with_trust(out, 1.0, t), target, mask)
        assert value.item() == pytest.approx(expected.item(), rel=1e-12)


def test_scene_flow_trust_shrinks_toward_the_anchor():
    task = build_task("scene_flow", target_scale_m=0.01)
    task.set_anchor(torch.tensor([0.0, 0.0, 0.0]))
    out = torch.tensor([2.0, 0.0, 0.0]).view(1, 3, 1, 1)  # 2 cm along x
    np.testing.assert_allclose(task.predict_with_trust(out, 0.3).flatten(), [0.006, 0, 0], atol=1e-9)
    target = torch.tensor([0.005, 0.0, 0.0]).view(1, 3, 1, 1)  # the truth: 5 mm
    sweep = task.calibration_metrics()["scene_flow_epe_m"]
    sweep.update(task.scores(out), target, torch.ones(1, 1, 1, dtype=torch.bool))
    task.calibrate({"scene_flow_epe_m": sweep})
    assert task.decision() == {"trust": pytest.approx(0.2)} and sweep.compute().item() == pytest.approx(0.001)
    with pytest.raises(ValueError, match="at least one"):
        M.ParameterSweep(M.SceneFlowEPE, task.predict_with_trust, ())
