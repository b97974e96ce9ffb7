"""The pretrained=true loading code paths, exercised with checkpoints written locally.

No real pretrained weights exist on this machine, so these tests save RANDOMLY initialised models
(vit_tiny; a reduced DPT; a reduced SD UNet/VAE with a tiny CLIP text encoder) in the on-disk layouts
the real weights use (an HF hub cache entry, a transformers / diffusers snapshot directory) and check
that pretrained=true loads them and reproduces the features of the saved model exactly. They test the
loaders, not the pretrained features."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from probes.backbones import Backbone, build_backbone, get_spec

FRAMES = torch.rand(2, 3, 32, 32, generator=torch.Generator().manual_seed(0))


def _same_features(a: Backbone, b: Backbone) -> None:
    for x, y in zip(a.features(FRAMES), b.features(FRAMES), strict=True):
        torch.testing.assert_close(x, y, atol=0, rtol=0)


def _fake_hub_entry(cache: Path, repo_id: str, files: dict[str, bytes]) -> Path:
    """Write ``files`` into the huggingface_hub cache layout (models--org--name/snapshots/<rev>/)."""
    revision = "0" * 40
    root = cache / f"models--{repo_id.replace('/', '--')}"
    snapshot = root / "snapshots" / revision
    snapshot.mkdir(parents=True)
    (root / "refs").mkdir()
    (root / "refs" / "main").write_text(revision)
    for name, data in files.items():
        (snapshot / name).parent.mkdir(parents=True, exist_ok=True)
        (snapshot / name).write_bytes(data)
    return snapshot


def test_timm_weights_found_in_hf_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from safetensors.torch import save

    src = build_backbone("vit_tiny", pretrained=False, image_size=32, seed=7)
    cache = tmp_path / "hub"
    state = {k: v.contiguous() for k, v in src.model.state_dict().items()}
    _fake_hub_entry(cache, get_spec("vit_tiny").hf_repo, {"model.safetensors": save(state)})
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HUB_CACHE", str(cache))
    loaded = build_backbone("vit_tiny", pretrained=True, image_size=32)
    assert loaded.pretrained and loaded.cache_key()["weights_path"] is None
    _same_features(src, loaded)


REDUCED_DPT = {
    "hidden_size": 32,
    "intermediate_size": 64,
    "num_hidden_layers": 2,
    "num_attention_heads": 2,
    "backbone_out_indices": [0, 1],
    "neck_hidden_sizes": [8, 8, 8, 8],
}


def test_midas_loads_a_transformers_snapshot(tmp_path: Path) -> None:
    src = build_backbone(
        "midas", pretrained=False, image_size=32, layers=[0, 1], arch_overrides=REDUCED_DPT, seed=3
    )
    src.model.save_pretrained(tmp_path / "dpt")
    loaded = build_backbone(
        "midas", pretrained=True, image_size=32, layers=[0, 1], weights_path=tmp_path / "dpt"
    )
    assert loaded.feat_dims == [32, 32]
    _same_features(src, loaded)


def _tiny_clip_tokenizer_files(folder: Path) -> None:
    """A minimal CLIP BPE vocabulary: enough to tokenise the empty prompt."""
    folder.mkdir(parents=True)
    vocab = {"<|startoftext|>": 0, "<|endoftext|>": 1, "a</w>": 2, "a": 3}
    (folder / "vocab.json").write_text(json.dumps(vocab))
    (folder / "merges.txt").write_text("#version: 0.2\n")
    (folder / "tokenizer_config.json").write_text(json.dumps({"model_max_length": 77}))


def test_sd_loads_a_diffusers_snapshot(tmp_path: Path) -> None:
    from diffusers import AutoencoderKL, DDPMScheduler, UNet2DConditionModel
    from transformers import CLIPTextConfig, CLIPTextModel, CLIPTokenizer

    torch.manual_seed(0)
    snap = tmp_path / "sd"
    unet = UNet2DConditionModel(
        block_out_channels=[16, 16, 32, 32],
        layers_per_block=1,
        cross_attention_dim=16,
        attention_head_dim=4,
        norm_num_groups=8,
        sample_size=8,
        down_block_types=["CrossAttnDownBlock2D"] * 3 + ["DownBlock2D"],
        up_block_types=["UpBlock2D"] + ["CrossAttnUpBlock2D"] * 3,
    )
    vae = AutoencoderKL(
        block_out_channels=[8, 8, 8, 8],
        layers_per_block=1,
        norm_num_groups=8,
        latent_channels=4,
        down_block_types=["DownEncoderBlock2D"] * 4,
        up_block_types=["UpDecoderBlock2D"] * 4,
    )
    unet.save_pretrained(snap / "unet")
    vae.save_pretrained(snap / "vae")
    DDPMScheduler(beta_start=0.00085, beta_end=0.012, beta_schedule="scaled_linear").save_pretrained(
        snap / "scheduler"
    )
    text = CLIPTextModel(
        CLIPTextConfig(
            vocab_size=4,
            hidden_size=16,
            intermediate_size=32,
            num_hidden_layers=1,
            num_attention_heads=2,
            max_position_embeddings=77,
            bos_token_id=0,
            eos_token_id=1,
            pad_token_id=1,
        )
    )
    text.save_pretrained(snap / "text_encoder")
    _tiny_clip_tokenizer_files(snap / "tokenizer")
    tokenizer = CLIPTokenizer.from_pretrained(snap / "tokenizer")

    bb = build_backbone("sd", pretrained=True, image_size=64, weights_path=snap)
    assert bb.feat_dims == [32, 32, 16, 16] and bb.pretrained
    # the conditioning is the text encoder's output for the empty prompt, not zeros
    ids = tokenizer([""], padding="max_length", max_length=77, return_tensors="pt").input_ids
    with torch.no_grad():
        want = text(ids)[0]
    torch.testing.assert_close(bb.text_embedding, want)
    assert bb.text_embedding.abs().max() > 0
    maps = bb.features(FRAMES)
    assert [tuple(m.shape) for m in maps] == [(2, c, 8, 8) for c in bb.feat_dims]
    assert bb.cache_key()["extra"]["text_embedding"] == "clip-text"
