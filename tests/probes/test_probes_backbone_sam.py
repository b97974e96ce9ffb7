"""SAM ViT-B image encoder: the REAL timm ``samvit_base_patch16`` architecture (built at its native
1024 px, random weights) run at a reduced input of 160 px (10 x 10 cells, not a multiple of the
14 x 14 attention window) through position-embedding interpolation."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from newtphys.dataset import ClipDataset
from probes.backbones import Backbone, build_backbone


@pytest.fixture(scope="module")
def clip_frames(synthetic_dataset: Path) -> torch.Tensor:
    return ClipDataset(synthetic_dataset / "train", clip_length=4)[0]["frames"][-2:].contiguous()


@pytest.fixture(scope="module")
def sam() -> Backbone:
    return build_backbone("sam", pretrained=False, image_size=160)


def test_sam_is_the_real_vit_b_encoder(sam: Backbone) -> None:
    model = sam.model
    assert len(model.blocks) == 12 and model.embed_dim == 768
    # the default taps are exactly SAM ViT-B's global-attention blocks; the others use 14 x 14 windows
    assert [i for i, blk in enumerate(model.blocks) if blk.window_size == 0] == sam.layers == [2, 5, 8, 11]
    assert {blk.window_size for i, blk in enumerate(model.blocks) if i not in sam.layers} == {14}
    # absolute position embedding kept at the native 1024 / 16 = 64 grid (weights never resized in place)
    assert tuple(model.pos_embed.shape) == (1, 64, 64, 768)
    assert sam.mean == pytest.approx((0.485, 0.456, 0.406)) and sam.std == pytest.approx(
        (0.229, 0.224, 0.225)
    )


def test_sam_features_at_reduced_size(sam: Backbone, clip_frames: torch.Tensor) -> None:
    pos_before = sam.model.pos_embed.clone()
    maps = sam.features(clip_frames)
    assert [tuple(m.shape) for m in maps] == [(2, 768, 10, 10)] * 4
    assert all(torch.isfinite(m).all() for m in maps)
    torch.testing.assert_close(sam.model.pos_embed, pos_before, atol=0, rtol=0)
    assert not any(p.requires_grad for p in sam.parameters())
    head = torch.nn.Conv2d(768 * 4, 1, 1)
    head(torch.cat(maps, 1)).mean().backward()
    assert head.weight.grad is not None and all(p.grad is None for p in sam.parameters())


def test_sam_deterministic_and_keyed(sam: Backbone, clip_frames: torch.Tensor) -> None:
    again = build_backbone("sam", pretrained=False, image_size=160, layers=[2])
    torch.testing.assert_close(again.features(clip_frames)[0], sam.features(clip_frames)[0], atol=0, rtol=0)
    key = sam.cache_key()
    assert key["extra"]["model_img_size"] == 1024 and key["image_size"] == [160, 160]
    assert again.cache_key() != key  # layers differ
