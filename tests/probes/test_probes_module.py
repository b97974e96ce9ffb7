"""ProbeModule: warmup + cosine schedule values, frozen backbone, checkpoint without backbone weights."""

from __future__ import annotations

import functools
import math

import pytest
import torch

from probes.backbones import build_backbone
from probes.decoders import LinearHead
from probes.module import ProbeModule, warmup_cosine_schedule
from probes.tasks import build_task


def test_warmup_cosine_schedule_hand_values():
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)
    sched = warmup_cosine_schedule(opt, total_steps=10, warmup_fraction=0.2)
    lrs = []
    for _ in range(11):
        lrs.append(opt.param_groups[0]["lr"])
        opt.step()
        sched.step()
    # warmup over 2 steps: 1/2, 2/2; then 0.5 (1 + cos(pi (s - 2) / 8))
    expected = [0.5, 1.0] + [0.5 * (1 + math.cos(math.pi * (s - 2) / 8)) for s in range(2, 11)]
    assert lrs == pytest.approx(expected, abs=1e-12)
    assert lrs[6] == pytest.approx(0.5) and lrs[10] == pytest.approx(0.0, abs=1e-12)
    with pytest.raises(ValueError, match="warmup_fraction must be in"):
        warmup_cosine_schedule(opt, total_steps=10, warmup_fraction=1.0)


def _module() -> ProbeModule:
    bb = build_backbone(
        "vit_tiny", pretrained=False, image_size=32, layers=[0, 1], arch_overrides={"depth": 2}
    )
    task = build_task("scene_flow")
    head = LinearHead(bb.feat_dims, num_frames=2, out_channels=3)
    return ProbeModule(
        bb,
        head,
        task,
        optimizer=functools.partial(torch.optim.AdamW, lr=1e-2),
        backbone_config={"name": "vit_tiny", "pretrained": False},
    )


def test_backbone_frozen_gets_no_gradient_and_stays_in_eval():
    model = _module()
    model.train()
    assert not model.backbone.training and model.decoder.training
    before = [p.detach().clone() for p in model.backbone.parameters()]
    gen = torch.Generator().manual_seed(0)
    batch = {
        "frames": torch.rand(2, 2, 3, 32, 32, generator=gen),
        "scene_flow": torch.randn(2, 3, 32, 32, generator=gen) * 0.01,
        "object_mask": torch.ones(2, 32, 32, dtype=torch.bool),
    }
    opt = model.optimizer_factory(params=model.decoder.parameters())
    loss = model.task.loss(model(batch), batch["scene_flow"], batch["object_mask"])
    loss.backward()
    opt.step()
    assert all(p.grad is None and not p.requires_grad for p in model.backbone.parameters())
    assert all(torch.equal(a, b) for a, b in zip(before, model.backbone.parameters(), strict=True))
    assert model.decoder.proj.weight.grad is not None and model.decoder.proj.weight.grad.abs().sum() > 0


def test_checkpoint_drops_backbone_weights_keeps_config():
    model = _module()
    ckpt = {"state_dict": model.state_dict()}
    assert any(k.startswith("backbone.") for k in ckpt["state_dict"])
    model.on_save_checkpoint(ckpt)
    assert sorted(ckpt["state_dict"]) == ["decoder.proj.bias", "decoder.proj.weight"]
    assert model.hparams["backbone_config"] == {"name": "vit_tiny", "pretrained": False}
