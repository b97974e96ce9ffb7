"""Stable Diffusion UNet features.

Default run: a REDUCED diffusers config with the SD 1.5 block types (CrossAttnDownBlock2D x3 +
DownBlock2D; UpBlock2D + CrossAttnUpBlock2D x3) at small widths, and a small VAE. The REAL SD 1.5
UNet (859.5M parameters) is built in a test marked slow."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch

from newtphys.dataset import ClipDataset
from probes.backbones import Backbone, build_backbone, get_spec

REDUCED = {
    "unet": {
        "block_out_channels": [32, 48, 64, 64],
        "layers_per_block": 1,
        "cross_attention_dim": 32,
        "attention_head_dim": 4,
        "norm_num_groups": 8,
        "sample_size": 8,
    },
    "vae": {
        "block_out_channels": [8, 16, 16, 16],
        "layers_per_block": 1,
        "norm_num_groups": 8,
        "sample_size": 64,
    },
}


@pytest.fixture(scope="module")
def clip_frames(synthetic_dataset: Path) -> torch.Tensor:
    return ClipDataset(synthetic_dataset / "train", clip_length=4)[0]["frames"][-2:].contiguous()


@pytest.fixture(scope="module")
def sd() -> Backbone:
    return build_backbone("sd", pretrained=False, image_size=64, arch_overrides=REDUCED)


def _build(**kwargs: Any) -> Backbone:
    return build_backbone("sd", pretrained=False, image_size=64, arch_overrides=REDUCED, **kwargs)


def test_sd_reduced_config_keeps_the_sd_block_types(sd: Backbone) -> None:
    real = get_spec("sd").arch_kwargs["unet"]
    assert [type(b).__name__ for b in sd.unet.down_blocks] == real["down_block_types"]
    assert [type(b).__name__ for b in sd.unet.up_blocks] == real["up_block_types"]


def test_sd_features_shapes_and_stride(sd: Backbone, clip_frames: torch.Tensor) -> None:
    maps = sd.features(clip_frames)
    assert sd.patch_size == 8 and sd.layers == [0, 1, 2, 3]
    assert sd.feat_dims == [64, 64, 48, 32]  # reversed block_out_channels, as SD 1.5's 1280, 1280, 640, 320
    assert [tuple(m.shape) for m in maps] == [(2, c, 8, 8) for c in sd.feat_dims]
    assert tuple(sd.latents(sd.preprocess(clip_frames)).shape) == (2, 4, 8, 8)
    assert all(torch.isfinite(m).all() for m in maps)
    assert not any(p.requires_grad for p in sd.parameters())
    head = torch.nn.Conv2d(sum(sd.feat_dims), 3, 1)
    head(torch.cat(maps, 1)).square().mean().backward()
    assert head.weight.grad is not None and all(p.grad is None for p in sd.parameters())


def test_sd_noise_schedule_matches_hand_computed_ddpm() -> None:
    """sqrt(abar_t) and sqrt(1 - abar_t) at t = 261 of the scaled-linear schedule (0.00085 -> 0.012)."""
    bb = _build(layers=[0])
    betas = np.linspace(0.00085**0.5, 0.012**0.5, 1000, dtype=np.float64) ** 2
    abar = np.prod(1.0 - betas[:262])
    assert bb.timestep == 261
    assert bb.signal_scale == pytest.approx(abar**0.5, rel=1e-5)
    assert bb.noise_scale == pytest.approx((1 - abar) ** 0.5, rel=1e-5)
    assert bb.scaling_factor == pytest.approx(0.18215)


def test_sd_features_are_deterministic_and_batch_independent(sd: Backbone, clip_frames: torch.Tensor) -> None:
    a = sd.features(clip_frames)
    b = _build().features(clip_frames)
    single = sd.features(clip_frames[1:])
    for x, y, s in zip(a, b, single):
        torch.testing.assert_close(x, y, atol=0, rtol=0)
        torch.testing.assert_close(x[1:], s, atol=1e-5, rtol=1e-4)  # same frame, other batch: same features


def test_sd_noise_seed_and_timestep_change_features_and_key(sd: Backbone, clip_frames: torch.Tensor) -> None:
    ref = sd.features(clip_frames)[1]
    for kwargs in ({"noise_seed": 1}, {"timestep": 50}):
        other = _build(**kwargs)
        assert (other.features(clip_frames)[1] - ref).abs().max() > 1e-4
        assert other.cache_key() != sd.cache_key()
        assert other.cache_key()["extra"][next(iter(kwargs))] == next(iter(kwargs.values()))


def test_sd_stops_after_last_tapped_block(sd: Backbone, clip_frames: torch.Tensor) -> None:
    only_first = _build(layers=[0, 1])
    calls: list[int] = []
    handles = [
        blk.register_forward_hook(lambda *_a, i=i: calls.append(i))
        for i, blk in enumerate(only_first.unet.up_blocks)
    ]
    maps = only_first.features(clip_frames)
    for h in handles:
        h.remove()
    assert calls == [0, 1]  # up blocks 2 and 3 never ran
    full = sd.features(clip_frames)
    torch.testing.assert_close(maps[1], full[1], atol=1e-5, rtol=1e-5)  # stopping early changes nothing


def test_sd_bad_timestep_and_size() -> None:
    with pytest.raises(ValueError, match=r"timestep=1000.*\[0, 999\]"):
        _build(timestep=1000)
    with pytest.raises(ValueError, match="multiples of 64"):
        build_backbone("sd", pretrained=False, image_size=72, arch_overrides=REDUCED)


@pytest.mark.slow
def test_sd15_real_architecture(clip_frames: torch.Tensor) -> None:
    bb = build_backbone("sd", pretrained=False, image_size=64)
    assert sum(p.numel() for p in bb.unet.parameters()) == 859_520_964  # SD 1.5 UNet
    assert bb.feat_dims == [1280, 1280, 640, 320]
    assert [tuple(m.shape) for m in bb.features(clip_frames)] == [(2, c, 8, 8) for c in bb.feat_dims]
