"""Task losses (hand values, masking) and decoder heads (shapes, parameter counts, temporal fusion)."""

from __future__ import annotations

import math

import pytest
import torch

from probes.decoders import DPTHead, LinearHead, count_parameters, pyramid_scales
from probes.tasks import TASK_NAMES, CollisionTask, GravityTask, SceneFlowTask, build_task


# --------------------------------------------------------------------------- #
# Tasks
# --------------------------------------------------------------------------- #
def test_build_task_unknown_lists_valid():
    with pytest.raises(ValueError, match="valid tasks: collision, gravity, scene_flow"):
        build_task("stress")
    assert TASK_NAMES == ("collision", "gravity", "scene_flow")


def test_collision_loss_hand_value_and_pos_weight():
    task = CollisionTask()
    target = torch.tensor([[[1.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0]]])
    mask = torch.ones(1, 2, 4, dtype=torch.bool)
    assert task.pos_weight(target, mask).item() == pytest.approx(3.0)  # 6 negatives / 2 positives
    logits = torch.zeros(1, 1, 2, 4)
    # every pixel: BCE(0 logit) = log 2; positives weighted by 3 -> (2*3 + 6) * log2 / 8
    assert task.loss(logits, target, mask).item() == pytest.approx(12 * math.log(2) / 8, rel=1e-6)
    # no positives: weight 1
    assert task.pos_weight(torch.zeros_like(target), mask).item() == 1.0


def test_losses_ignore_pixels_outside_the_object_mask():
    gen = torch.Generator().manual_seed(0)
    mask = torch.rand(2, 5, 5, generator=gen) > 0.5
    for task, ch in ((CollisionTask(), 1), (GravityTask(), 3), (SceneFlowTask(), 3)):
        out = torch.randn(2, ch, 5, 5, generator=gen, requires_grad=True)
        target = (
            torch.randn(2, 3, 5, 5, generator=gen)
            if ch == 3
            else (torch.rand(2, 5, 5, generator=gen) > 0.5).float()
        )
        if ch == 3:  # overwrite every off-object pixel
            changed = torch.where(mask.unsqueeze(1), target, torch.full_like(target, 55.0))
        else:
            changed = torch.where(mask, target, 1.0 - target)
        loss = task.loss(out, target, mask)
        assert task.loss(out, changed, mask).item() == pytest.approx(loss.item(), rel=1e-6)
        loss.backward()
        grad_off = out.grad.abs().sum(1)[~mask]
        assert torch.all(grad_off == 0), task.name
        assert out.grad.abs().sum() > 0


def test_empty_mask_gives_zero_loss_with_graph():
    out = torch.randn(1, 3, 4, 4, requires_grad=True)
    loss = SceneFlowTask().loss(out, torch.zeros(1, 3, 4, 4), torch.zeros(1, 4, 4, dtype=torch.bool))
    assert loss.item() == 0.0
    loss.backward()
    assert out.grad is not None


def test_gravity_loss_hand_values():
    task = GravityTask(target_scale_n=10.0, magnitude_weight=1.0)
    g = torch.tensor([0.0, 0.0, -19.62]).view(1, 3, 1, 1)  # 2 kg x 9.81 m/s^2
    mask = torch.ones(1, 1, 1, dtype=torch.bool)
    perfect = g / 10.0
    assert task.loss(perfect, g, mask).item() == pytest.approx(0.0, abs=1e-5)
    # opposite direction, same magnitude: 1 - cos = 2
    assert task.loss(-perfect, g, mask).item() == pytest.approx(2.0, abs=1e-5)
    # perpendicular, same magnitude: chord between unit vectors sqrt(2) (1 - cos would give 1)
    side = torch.tensor([1.962, 0.0, 0.0]).view(1, 3, 1, 1)
    assert task.loss(side, g, mask).item() == pytest.approx(math.sqrt(2), abs=1e-5)
    # 10 degrees off, same magnitude: chord 2 sin(5 deg) ~ 0.1745, close to the angle in radians
    a = math.radians(10.0)
    tilted = torch.tensor([1.962 * math.sin(a), 0.0, -1.962 * math.cos(a)]).view(1, 3, 1, 1)
    assert task.loss(tilted, g, mask).item() == pytest.approx(2 * math.sin(a / 2), abs=1e-5)
    # right direction, double magnitude: |log 2|
    assert task.loss(2 * perfect, g, mask).item() == pytest.approx(math.log(2), abs=1e-5)
    assert torch.allclose(task.predict(perfect), g)


def test_scene_flow_loss_and_prediction_units():
    task = SceneFlowTask(target_scale_m=0.01)
    g = torch.tensor([0.03, -0.04, 0.0]).view(1, 3, 1, 1)  # m
    out = torch.zeros(1, 3, 1, 1)
    # EPE of a zero prediction = |g| / scale = 0.05 / 0.01 = 5 (loss in units of the scale)
    assert task.loss(out, g, torch.ones(1, 1, 1, dtype=torch.bool)).item() == pytest.approx(5.0, rel=1e-5)
    assert torch.allclose(task.predict(torch.tensor([3.0, -4.0, 0.0]).view(1, 3, 1, 1)), g)


def test_task_parameter_errors_name_parameter():
    with pytest.raises(ValueError, match="target_scale_m must be > 0"):
        SceneFlowTask(target_scale_m=0)
    with pytest.raises(ValueError, match="threshold must be in"):
        CollisionTask(threshold=1.5)


@pytest.mark.parametrize("decoder", ["linear", "dpt"])
@pytest.mark.parametrize("task_name", TASK_NAMES)
def test_heads_start_from_the_train_constant(decoder, task_name):
    task = build_task(task_name)
    fitted = {
        "positive_rate": 0.2,
        "direction": [0.0, 0.6, 0.8],
        "median_magnitude_n": 4.0,
        "mean_flow_m": [0.5, 0.5, 0.5],
        "median_flow_m": [0.001, 0.0, -0.002],  # the head starts from the median (least endpoint error)
    }
    bias = task.output_bias(fitted)
    assert bias.shape == (task.out_channels,)
    dims = (8, 8)
    head = (
        LinearHead(list(dims), num_frames=2, out_channels=task.out_channels)
        if decoder == "linear"
        else DPTHead(list(dims), num_frames=2, out_channels=task.out_channels, width=8)
    )
    head.start_from_constant(bias)
    out = head(_feats(k=2, dims=dims, sizes=((3, 4), (3, 4))), out_size=(6, 8))
    pred = task.predict(out)
    expected = {
        "collision": torch.zeros(2, 6, 8, dtype=torch.bool),  # logit 0 at the default threshold 0.5
        "gravity": torch.tensor([0.0, 2.4, 3.2]).view(1, 3, 1, 1).expand(2, 3, 6, 8),  # 4 N along (0, .6, .8)
        "scene_flow": torch.tensor([0.001, 0.0, -0.002]).view(1, 3, 1, 1).expand(2, 3, 6, 8),
    }[task_name]
    assert torch.allclose(pred, expected, atol=1e-6)
    with pytest.raises(ValueError, match="one per output channel"):
        head.start_from_constant(torch.zeros(task.out_channels + 1))


# --------------------------------------------------------------------------- #
# Decoders
# --------------------------------------------------------------------------- #
def _feats(b=2, k=4, dims=(8, 8, 8, 8), sizes=((3, 4),) * 4, seed=0):
    gen = torch.Generator().manual_seed(seed)
    return [torch.randn(b, k, c, *s, generator=gen) for c, s in zip(dims, sizes)]


def test_linear_head_shapes_and_parameter_count():
    head = LinearHead([8, 8, 8, 16], num_frames=4, out_channels=3)
    assert count_parameters(head) == 4 * 16 * 3 + 3
    out = head(_feats(dims=(8, 8, 8, 16)), out_size=(24, 32))
    assert out.shape == (2, 3, 24, 32)
    head_all = LinearHead([8, 8, 8, 16], num_frames=4, out_channels=1, layers="all")
    assert count_parameters(head_all) == 4 * 40 * 1 + 1
    sizes = ((6, 8), (3, 4), (3, 4), (2, 2))
    assert head_all(_feats(dims=(8, 8, 8, 16), sizes=sizes), out_size=(12, 16)).shape == (2, 1, 12, 16)


def test_linear_head_is_exactly_a_1x1_conv_at_feature_resolution():
    head = LinearHead([4], num_frames=2, out_channels=1)
    feats = _feats(b=1, k=2, dims=(4,), sizes=((3, 3),))
    out = head(feats, out_size=(3, 3))  # same size: interpolation is the identity
    x = feats[0].reshape(1, 8, 3, 3)
    expected = torch.einsum("oc,bchw->bohw", head.proj.weight[:, :, 0, 0], x) + head.proj.bias.view(
        1, -1, 1, 1
    )
    assert torch.allclose(out, expected, atol=1e-6)


@pytest.mark.parametrize("num_layers", [1, 2, 4])
def test_dpt_head_shapes_and_every_frame_matters(num_layers):
    dims = tuple([6] * num_layers)
    sizes = tuple([(4, 5)] * num_layers)
    head = DPTHead(list(dims), num_frames=3, out_channels=3, width=16)
    feats = _feats(b=2, k=3, dims=dims, sizes=sizes)
    out = head(feats, out_size=(20, 25))
    assert out.shape == (2, 3, 20, 25)
    # temporal fusion: changing only the first (oldest) frame changes the prediction
    feats2 = [f.clone() for f in feats]
    feats2[-1][:, 0] += 1.0
    assert not torch.allclose(head(feats2, out_size=(20, 25)), out)
    assert len(pyramid_scales(num_layers)) == num_layers
    assert pyramid_scales(4) == [4.0, 2.0, 1.0, 0.5]


def test_dpt_head_width_sets_parameter_count_and_gradients_flow():
    small = DPTHead([8, 8], num_frames=2, out_channels=1, width=8)
    large = DPTHead([8, 8], num_frames=2, out_channels=1, width=32)
    assert count_parameters(large) > 8 * count_parameters(small) / 2
    feats = [f.requires_grad_(True) for f in _feats(k=2, dims=(8, 8), sizes=((4, 4), (4, 4)))]
    small(feats, out_size=(8, 8)).sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in small.parameters())


def test_decoder_input_errors_name_the_shape():
    head = LinearHead([8], num_frames=4, out_channels=1)
    with pytest.raises(ValueError, match=r"\(B, K=4, C=8, h, w\)"):
        head([torch.zeros(2, 3, 8, 4, 4)], out_size=(8, 8))
    with pytest.raises(ValueError, match="layers must be one of"):
        LinearHead([8], num_frames=4, out_channels=1, layers="first")
    with pytest.raises(ValueError, match="num_frames must be >= 1"):
        DPTHead([8], num_frames=0, out_channels=1)
