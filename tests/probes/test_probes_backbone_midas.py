"""MiDaS DPT-Large encoder.

Default run: a REDUCED DPTConfig (hidden 64, 4 layers, 4 heads; same DPTModel code path, same token
layout). The REAL architecture (ViT-L/16, 24 layers, 1024-d, ~304M parameters) is built once and run
at 32 px."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from newtphys.dataset import ClipDataset
from probes.backbones import Backbone, build_backbone, get_spec

REDUCED = {
    "hidden_size": 64,
    "intermediate_size": 128,
    "num_hidden_layers": 4,
    "num_attention_heads": 4,
    "backbone_out_indices": [0, 1, 2, 3],
    "neck_hidden_sizes": [16, 16, 16, 16],
}


@pytest.fixture(scope="module")
def clip_frames(synthetic_dataset: Path) -> torch.Tensor:
    return ClipDataset(synthetic_dataset / "train", clip_length=4)[0]["frames"][-2:].contiguous()


@pytest.fixture(scope="module")
def midas() -> Backbone:
    # 64 x 96 px: a non-square grid (4 x 6) catches any h/w swap in the token reshape
    return build_backbone(
        "midas", pretrained=False, image_size=[64, 96], layers=[1, 3], arch_overrides=REDUCED
    )


def test_midas_record() -> None:
    spec = get_spec("midas")
    assert spec.default_layers == (5, 11, 17, 23) and spec.patch_size == 16 and spec.native_size == (384, 384)
    assert spec.arch_kwargs["hidden_size"] == 1024 and spec.arch_kwargs["num_hidden_layers"] == 24
    assert spec.mean == (0.5, 0.5, 0.5) and spec.std == (0.5, 0.5, 0.5)


def test_midas_maps_are_the_hidden_states(midas: Backbone, clip_frames: torch.Tensor) -> None:
    maps = midas.features(clip_frames)
    assert midas.feat_dims == [64, 64]
    assert [tuple(m.shape) for m in maps] == [(2, 64, 4, 6)] * 2
    with torch.no_grad():
        hidden = midas.model(
            pixel_values=midas.preprocess(clip_frames), output_hidden_states=True
        ).hidden_states
    assert len(hidden) == 5  # embeddings + 4 layers
    for layer, fmap in zip(midas.layers, maps):
        tokens = hidden[layer + 1]
        assert tokens.shape[1] == 1 + 4 * 6  # one CLS token, dropped
        want = tokens[:, 1:].reshape(2, 4, 6, 64).permute(0, 3, 1, 2)
        torch.testing.assert_close(fmap, want, atol=0, rtol=0)


def test_midas_frozen_and_deterministic(midas: Backbone, clip_frames: torch.Tensor) -> None:
    maps = midas.features(clip_frames)
    assert not any(p.requires_grad for p in midas.parameters())
    head = torch.nn.Conv2d(128, 1, 1)
    head(torch.cat(maps, 1)).square().mean().backward()
    assert head.weight.grad is not None and all(p.grad is None for p in midas.parameters())
    again = build_backbone(
        "midas", pretrained=False, image_size=[64, 96], layers=[1, 3], arch_overrides=REDUCED
    )
    for x, y in zip(maps, again.features(clip_frames)):
        torch.testing.assert_close(x, y, atol=0, rtol=0)
    other = build_backbone(
        "midas", pretrained=False, image_size=[64, 96], layers=[1, 3], arch_overrides=REDUCED, seed=5
    )
    assert (other.features(clip_frames)[0] - maps[0]).abs().max() > 1e-3
    assert other.cache_key() != midas.cache_key()


def test_midas_reduced_layers_are_range_checked() -> None:
    with pytest.raises(ValueError, match=r"\[0, 3\]"):
        build_backbone("midas", pretrained=False, layers=[5], arch_overrides=REDUCED)


def test_midas_real_architecture(clip_frames: torch.Tensor) -> None:
    bb = build_backbone("midas", pretrained=False, image_size=32)
    n_params = sum(p.numel() for p in bb.parameters())
    assert len(bb.model.encoder.layer) == 24 and bb.feat_dims == [1024] * 4
    assert 300e6 < n_params < 310e6  # ViT-L/16 encoder with 384 px position embeddings: 303.7M
    assert [tuple(m.shape) for m in bb.features(clip_frames)] == [(2, 1024, 2, 2)] * 4
