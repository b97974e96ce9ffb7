"""Backbone registry, common interface and the timm ViT family.

Architectures here are the REAL ones (timm ViT-B/16, ViT-B/14, ViT-Ti/16) with
random weights (pretrained=false), run at a reduced input of 64 px (56 px for
the /14 DINOv2) to stay fast on 2 CPU cores.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest
import torch
from omegaconf import OmegaConf

from newtphys.config import CONFIG_DIR
from newtphys.dataset import ClipDataset
from probes.backbones import BACKBONE_NAMES, Backbone, WeightsUnavailableError, build_backbone, get_spec

REPO = Path(__file__).resolve().parents[2]
VIT_B = ("dino", "dinov2", "clip", "siglip", "mae", "deit3")

# Normalisation constants as the model authors document them, typed by hand.
IMAGENET = ((0.485, 0.456, 0.406), (0.229, 0.224, 0.225))
CLIP = ((0.4815, 0.4578, 0.4082), (0.2686, 0.2613, 0.2758))
HALF = ((0.5, 0.5, 0.5), (0.5, 0.5, 0.5))
DOCUMENTED_NORM = {
    "dino": IMAGENET,
    "dinov2": IMAGENET,
    "clip": CLIP,
    "siglip": HALF,
    "mae": IMAGENET,
    "deit3": IMAGENET,
    "sam": IMAGENET,
    "midas": HALF,
    "radio": CLIP,
    "sd": HALF,
    "vit_tiny": HALF,
}


@pytest.fixture(scope="module")
def clip_frames(synthetic_dataset: Path) -> torch.Tensor:
    """(B=2, 3, 32, 32) frames in [0, 1]: the last two frames of the first fixture clip."""
    item = ClipDataset(synthetic_dataset / "train", clip_length=4)[0]
    return item["frames"][-2:].contiguous()


@pytest.fixture(scope="module")
def tiny() -> Backbone:
    return build_backbone("vit_tiny", pretrained=False, image_size=64)


def _backward_into_head(backbone: Backbone, frames: torch.Tensor) -> torch.nn.Module:
    """Train-step of a 1x1 conv head on the concatenated maps; returns the head."""
    maps = backbone.features(frames)
    head = torch.nn.Conv2d(sum(backbone.feat_dims), 3, kernel_size=1)
    out = head(torch.cat(maps, dim=1))
    loss = (out - 1.0).square().mean()
    loss.backward()
    return head


# ---------------------------------------------------------------------------- registry and configs
def test_registry_has_the_eleven_names() -> None:
    assert set(BACKBONE_NAMES) == {
        "dino",
        "dinov2",
        "clip",
        "siglip",
        "mae",
        "deit3",
        "sam",
        "midas",
        "radio",
        "sd",
        "vit_tiny",
    }


def test_unknown_name_lists_valid_ones() -> None:
    with pytest.raises(KeyError) as err:
        build_backbone("dinov3", pretrained=False)
    for name in BACKBONE_NAMES:
        assert name in str(err.value)
    assert "dinov3" in str(err.value)


@pytest.mark.parametrize("name", sorted(DOCUMENTED_NORM))
def test_normalisation_constants_are_the_documented_ones(name: str) -> None:
    spec = get_spec(name)
    mean, std = DOCUMENTED_NORM[name]
    assert spec.mean == pytest.approx(mean, abs=1e-4)
    assert spec.std == pytest.approx(std, abs=1e-4)


@pytest.mark.parametrize("name", [*VIT_B, "vit_tiny", "sam"])
def test_timm_records_agree_with_timm_pretrained_cfg(name: str) -> None:
    """Mean/std and the HF repo in our records equal timm's own pretrained config of the weights id."""
    from timm.models import get_pretrained_cfg

    spec = get_spec(name)
    cfg = get_pretrained_cfg(spec.weights_id)
    assert cfg is not None
    assert spec.mean == pytest.approx(cfg.mean, abs=1e-7)
    assert spec.std == pytest.approx(cfg.std, abs=1e-7)
    assert spec.hf_repo == cfg.hf_hub_id
    assert spec.native_size == tuple(cfg.input_size[1:])


@pytest.mark.parametrize("name", sorted(BACKBONE_NAMES))
def test_hydra_config_restates_nothing_of_the_record(name: str) -> None:
    """The record in specs.py is the one source: the YAML names the model and leaves every field null."""
    cfg = OmegaConf.load(CONFIG_DIR / "backbone" / f"{name}.yaml")
    assert cfg._target_ == "probes.backbones.build_backbone"
    assert cfg.name == name and cfg.pretrained is True
    overrides = {k: v for k, v in cfg.items() if k not in ("_target_", "name", "pretrained")}
    assert overrides and all(v is None for v in overrides.values()), overrides


def test_hydra_config_nulls_take_the_records_values() -> None:
    from hydra.utils import instantiate

    spec = get_spec("vit_tiny")
    bb = instantiate(OmegaConf.load(CONFIG_DIR / "backbone" / "vit_tiny.yaml"), pretrained=False)
    assert list(bb.layers) == list(spec.default_layers)
    assert tuple(bb.cache_key()["image_size"]) == spec.default_image_size


def test_hydra_instantiate_builds_vit_tiny(clip_frames: torch.Tensor) -> None:
    from hydra.utils import instantiate

    cfg = OmegaConf.load(CONFIG_DIR / "backbone" / "vit_tiny.yaml")
    cfg.pretrained = False
    cfg.image_size = 32
    cfg.layers = [0, 11]
    bb = instantiate(cfg)
    maps = bb.features(clip_frames)
    assert [tuple(m.shape) for m in maps] == [(2, 192, 2, 2)] * 2
    assert bb.cache_key()["layers"] == [0, 11]


# ---------------------------------------------------------------------------- common interface (ViT-Ti)
def test_vit_tiny_shapes_and_frozen(tiny: Backbone, clip_frames: torch.Tensor) -> None:
    maps = tiny.features(clip_frames)
    assert tiny.patch_size == 16 and tiny.image_size == (64, 64) and tiny.layers == [2, 5, 8, 11]
    assert tiny.feat_dims == [192] * 4
    assert [tuple(m.shape) for m in maps] == [(2, 192, 4, 4)] * 4
    assert all(m.dtype == torch.float32 and torch.isfinite(m).all() for m in maps)
    assert not any(p.requires_grad for p in tiny.parameters())
    tiny.train()
    assert tiny.training is False and not any(m.training for m in tiny.modules())


def test_vit_tiny_no_gradient_reaches_backbone(tiny: Backbone, clip_frames: torch.Tensor) -> None:
    head = _backward_into_head(tiny, clip_frames)
    assert head.weight.grad is not None and head.weight.grad.abs().sum() > 0
    assert all(p.grad is None for p in tiny.parameters())


def test_taps_are_zero_based_block_outputs_without_prefix_tokens(
    tiny: Backbone, clip_frames: torch.Tensor
) -> None:
    """Map l equals the patch tokens after block layers[l] of a manual forward (CLS dropped)."""
    m = tiny.model
    with torch.no_grad():
        x = tiny.preprocess(clip_frames)
        tokens = m.norm_pre(m.patch_drop(m._pos_embed(m.patch_embed(x))))
        manual = []
        for i, block in enumerate(m.blocks):
            tokens = block(tokens)
            if i in tiny.layers:
                patches = tokens[:, m.num_prefix_tokens :]
                manual.append(patches.transpose(1, 2).reshape(2, 192, 4, 4))
    assert m.num_prefix_tokens == 1
    for got, want in zip(tiny.features(clip_frames), manual, strict=True):
        torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)


def test_preprocess_resizes_and_normalises(tiny: Backbone) -> None:
    frames = torch.full((1, 3, 32, 48), 0.75)
    x = tiny.preprocess(frames)
    assert tuple(x.shape) == (1, 3, 64, 64)
    torch.testing.assert_close(x, torch.full_like(x, (0.75 - 0.5) / 0.5))  # constant stays constant
    exact = tiny.preprocess(torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(0)))
    ref = (torch.rand(1, 3, 64, 64, generator=torch.Generator().manual_seed(0)) - 0.5) / 0.5
    torch.testing.assert_close(exact, ref)  # no resampling at the native size


SMALL = {"arch_overrides": {"depth": 2}, "layers": [0, 1]}  # ViT-Ti with 2 blocks: same code path, cheaper


def test_features_are_deterministic_per_seed(clip_frames: torch.Tensor) -> None:
    a, b, c = (
        build_backbone("vit_tiny", pretrained=False, image_size=64, seed=s, **SMALL).features(clip_frames)
        for s in (0, 0, 1)
    )
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert all((x - z).abs().max() > 1e-2 for x, z in zip(a, c))


def test_seeded_build_leaves_global_rng_alone() -> None:
    torch.manual_seed(123)
    before = torch.rand(3)
    torch.manual_seed(123)
    build_backbone("vit_tiny", pretrained=False, image_size=32, **SMALL)
    assert torch.equal(torch.rand(3), before)


def test_random_weights_are_logged_loudly(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level("WARNING"):
        build_backbone("vit_tiny", pretrained=False, image_size=32, **SMALL)
    assert any("RANDOM WEIGHTS" in r.getMessage() and "vit_tiny" in r.getMessage() for r in caplog.records)


def test_weights_path_round_trip(tiny: Backbone, clip_frames: torch.Tensor, tmp_path: Path) -> None:
    """pretrained=true from a local weights file reproduces the features of the model it was saved from."""
    path = tmp_path / "vit_tiny.pth"
    torch.save(tiny.model.state_dict(), path)
    loaded = build_backbone("vit_tiny", pretrained=True, image_size=64, weights_path=str(path))
    for x, y in zip(tiny.features(clip_frames), loaded.features(clip_frames)):
        torch.testing.assert_close(x, y, atol=0, rtol=0)
    assert tiny.cache_key()["pretrained"] is False and tiny.cache_key()["weights"] == "random(seed=0)"
    assert loaded.cache_key()["pretrained"] is True
    assert loaded.cache_key()["weights"] == "vit_tiny_patch16_224.augreg_in21k_ft_in1k"
    assert loaded.cache_key()["weights_path"] == str(path) and tiny.cache_key()["weights_path"] is None
    differ = {k for k in tiny.cache_key() if tiny.cache_key()[k] != loaded.cache_key()[k]}
    assert differ == {"pretrained", "weights", "weights_path"}


def test_cache_key_changes_with_what_changes_features() -> None:
    def key(**kwargs: Any) -> dict[str, Any]:
        args = {"pretrained": False, "image_size": 32, **SMALL, **kwargs}
        return build_backbone("vit_tiny", **args).cache_key()

    ref = key()
    assert key() == ref  # rebuilding the same thing gives the same key
    assert ref["layers"] == [0, 1] and ref["image_size"] == [32, 32] and ref["mean"] == [0.5] * 3
    changed = {
        "layers": key(layers=[1]),
        "image_size": key(image_size=[32, 64]),
        "seed": key(seed=3),
        "arch": key(arch_overrides={"depth": 3}, layers=[0, 1]),
    }
    for what, other in changed.items():
        assert other != ref, what


# ---------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"image_size": 30}, ValueError, r"image_size=\[30, 30\].*multiples of 16"),
        ({"image_size": [64, 0]}, ValueError, "multiples of 16"),
        ({"layers": [12]}, ValueError, r"\[0, 11\]"),
        ({"layers": [2], "arch_overrides": {"depth": 2}}, ValueError, r"\[0, 1\]"),
        ({"arch_overrides": {"depth": 2}}, ValueError, "default layers .* reduced depth of 2"),
        ({"layers": [5, 2]}, ValueError, "strictly increasing"),
        ({"layers": []}, ValueError, "non-empty"),
        ({"seed": -1}, ValueError, "seed must be >= 0"),
        ({"timestep": 10}, TypeError, r"unknown option\(s\) \['timestep'\].*allowed"),
        ({"arch_overrides": {"depth": 2}, "pretrained": True}, ValueError, "arch_overrides"),
    ],
)
def test_bad_arguments_are_named(kwargs: dict, error: type, match: str) -> None:
    kwargs = {"pretrained": False, **kwargs}
    with pytest.raises(error, match=match):
        build_backbone("vit_tiny", **kwargs)


def test_dinov2_needs_multiples_of_14() -> None:
    with pytest.raises(ValueError, match="multiples of 14"):
        build_backbone("dinov2", pretrained=False, image_size=112 + 16)


def test_bad_frames_are_named(tiny: Backbone) -> None:
    with pytest.raises(ValueError, match=r"\(B, 3, H, W\).*\(3, 32, 32\)"):
        tiny.features(torch.rand(3, 32, 32))
    with pytest.raises(TypeError, match="uint8"):
        tiny.features(torch.zeros(1, 3, 32, 32, dtype=torch.uint8))


def test_weights_path_that_does_not_exist(tmp_path: Path) -> None:
    with pytest.raises(WeightsUnavailableError, match="weights_path="):
        build_backbone("vit_tiny", pretrained=True, weights_path=str(tmp_path / "missing.pth"))


# ---------------------------------------------------------------------------- pretrained=true fails fast
@pytest.fixture()
def empty_hf_cache(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf_home"))
    monkeypatch.delenv("HF_HUB_CACHE", raising=False)
    return tmp_path / "hf_home" / "hub"


@pytest.mark.parametrize("name", sorted(BACKBONE_NAMES))
@pytest.mark.parametrize("allow_download", [False, True])
def test_pretrained_without_weights_fails_fast(name: str, allow_download: bool, empty_hf_cache: Path) -> None:
    """With HF_HUB_OFFLINE=1 and an empty cache every backbone raises the documented message, no network."""
    spec = get_spec(name)
    with pytest.raises(WeightsUnavailableError) as err:
        build_backbone(name, pretrained=True, allow_download=allow_download)
    msg = str(err.value)
    for needle in (
        spec.hf_repo,
        str(empty_hf_cache),
        "HF_HUB_OFFLINE=1",
        "weights_path",
        "huggingface-cli download",
    ):
        assert needle in msg


# ---------------------------------------------------------------------------- the ViT-B family
@pytest.fixture(scope="module", params=VIT_B)
def vit_b(request: pytest.FixtureRequest) -> Backbone:
    """Real ViT-B architectures, random weights, 4 x 4 cells (64 px; 56 px for patch 14)."""
    return build_backbone(request.param, pretrained=False, image_size=4 * get_spec(request.param).patch_size)


def test_vit_b_features(vit_b: Backbone, clip_frames: torch.Tensor) -> None:
    spec = get_spec(vit_b.name)
    maps = vit_b.features(clip_frames)
    grid = 4
    assert vit_b.layers == [2, 5, 8, 11] and vit_b.feat_dims == [768] * 4
    assert [tuple(m.shape) for m in maps] == [(2, 768, grid, grid)] * 4
    assert len(vit_b.model.blocks) == 12 and vit_b.model.embed_dim == 768
    assert vit_b.model.patch_embed.patch_size == (spec.patch_size,) * 2
    assert not any(p.requires_grad for p in vit_b.parameters())
    head = _backward_into_head(vit_b, clip_frames)
    assert head.weight.grad is not None
    assert all(p.grad is None for p in vit_b.parameters())
    # prefix tokens: CLS for all but SigLIP; DINOv2 (no-register checkpoint) also exactly one
    assert vit_b.model.num_prefix_tokens == (0 if vit_b.name == "siglip" else 1)
    # different layers are different maps, except that DINOv2 and DeiT III initialise LayerScale to
    # 1e-5 / 1e-6: with random weights their blocks are near-identity maps (a property of the real arch)
    gap = (maps[0] - maps[3]).abs().max().item()
    layer_scale = {"dinov2": 1e-5, "deit3": 1e-6}.get(vit_b.name)
    if layer_scale is None:
        assert gap > 1e-3
    else:
        torch.testing.assert_close(vit_b.model.blocks[0].ls1.gamma, torch.full((768,), layer_scale))
        assert gap < 1e-3


@pytest.mark.parametrize("name", VIT_B)
def test_vit_b_deterministic(name: str, clip_frames: torch.Tensor) -> None:
    """Same seed -> identical features; another seed -> other features. Checked on the family's
    architecture cut to 2 blocks (same patch embedding, position embedding and block type; the full
    12-block build is covered by test_vit_b_features) to keep the default run fast."""
    size = 4 * get_spec(name).patch_size

    def feats(seed: int) -> torch.Tensor:
        bb = build_backbone(
            name, pretrained=False, image_size=size, layers=[1], seed=seed, arch_overrides={"depth": 2}
        )
        return bb.features(clip_frames)[0]

    a, b, c = feats(0), feats(0), feats(1)
    torch.testing.assert_close(a, b, atol=0, rtol=0)
    assert (a - c).abs().max() > 1e-3


def test_clip_uses_quick_gelu() -> None:
    spec = get_spec("clip")
    assert "quickgelu" in spec.arch
    assert math.isclose(spec.mean[0], 0.48145466)
