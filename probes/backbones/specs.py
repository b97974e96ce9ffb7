"""Backbone config records: every probed model declared as data.

One :class:`BackboneSpec` per registry name. The factory in
``probes/backbones/__init__.py`` reads a record and hands it to its family's
builder; adding a checkpoint of a known family is adding one entry here.

Ids, taps and normalisation constants are those the model authors publish
(timm, transformers and diffusers model cards). Layer indices are 0-based
block indices: tap ``2`` is the output of the third
transformer block (the Probe3D off-by-one for MAE is avoided by using the
same convention for every ViT).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

IMAGENET_MEAN: tuple[float, float, float] = (0.485, 0.456, 0.406)
IMAGENET_STD: tuple[float, float, float] = (0.229, 0.224, 0.225)
CLIP_MEAN: tuple[float, float, float] = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD: tuple[float, float, float] = (0.26862954, 0.26130258, 0.27577711)
HALF: tuple[float, float, float] = (0.5, 0.5, 0.5)

SUPERVISION_TYPES: tuple[str, ...] = (
    "self-supervised",
    "language-supervised",
    "supervised",
    "segmentation",
    "depth",
    "distillation",
    "generative",
    "none",
)


@dataclass(frozen=True)
class BackboneSpec:
    """Everything that declares one backbone.

    Attributes:
        name: registry name (``build_backbone(name)``).
        family: builder family: ``timm_vit``, ``timm_sam``, ``dpt``, ``radio``, ``stable_diffusion``.
        arch: architecture id inside the family (timm model name, or a label for HF models).
        weights_id: pretrained weights id (timm ``arch.tag``, HF repo id or diffusers repo id).
        hf_repo: Hugging Face repo the weights live in (what must be in the HF cache).
        patch_size: pixels per returned feature cell (effective stride of every returned map).
        depth: number of tappable layers (blocks, or up blocks for the SD UNet).
        default_layers: default taps (0-based).
        mean, std: the model's own input normalisation of RGB in [0, 1].
        native_size: (H, W) the weights were trained at, pixels.
        default_image_size: (H, W) frames are resized to when ``image_size`` is None, pixels.
        size_multiple: ``image_size`` must be a multiple of this, pixels.
        supervision: supervision type for the results table (one of SUPERVISION_TYPES).
        arch_kwargs: architecture arguments of the family builder (model configs).
        extra: family-specific settings that change the features (e.g. SD timestep).
        description: one line for reports.
    """

    name: str
    family: str
    arch: str
    weights_id: str
    hf_repo: str
    patch_size: int
    depth: int
    default_layers: tuple[int, ...]
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    native_size: tuple[int, int]
    default_image_size: tuple[int, int]
    size_multiple: int
    supervision: str
    arch_kwargs: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    description: str = ""


def _vit_b(
    name: str,
    arch: str,
    tag: str,
    hf_repo: str,
    mean: tuple[float, float, float],
    std: tuple[float, float, float],
    supervision: str,
    description: str,
    patch_size: int = 16,
    native: int = 224,
) -> BackboneSpec:
    """A timm ViT-B record (12 blocks, taps 2,5,8,11; 224 px default input = 14 x 16 = 16 x 14)."""
    default = 224
    return BackboneSpec(
        name=name,
        family="timm_vit",
        arch=arch,
        weights_id=f"{arch}.{tag}",
        hf_repo=hf_repo,
        patch_size=patch_size,
        depth=12,
        default_layers=(2, 5, 8, 11),
        mean=mean,
        std=std,
        native_size=(native, native),
        default_image_size=(default, default),
        size_multiple=patch_size,
        supervision=supervision,
        description=description,
    )


# Stable Diffusion 1.5 architecture (diffusers configs of the public checkpoint), used for
# pretrained=false. Only the VAE encoder is used.
SD15_UNET_CONFIG: dict[str, Any] = {
    "sample_size": 64,
    "in_channels": 4,
    "out_channels": 4,
    "down_block_types": [
        "CrossAttnDownBlock2D",
        "CrossAttnDownBlock2D",
        "CrossAttnDownBlock2D",
        "DownBlock2D",
    ],
    "up_block_types": ["UpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D", "CrossAttnUpBlock2D"],
    "block_out_channels": [320, 640, 1280, 1280],
    "layers_per_block": 2,
    "cross_attention_dim": 768,
    "attention_head_dim": 8,
    "norm_num_groups": 32,
}
SD15_VAE_CONFIG: dict[str, Any] = {
    "in_channels": 3,
    "out_channels": 3,
    "down_block_types": ["DownEncoderBlock2D"] * 4,
    "up_block_types": ["UpDecoderBlock2D"] * 4,
    "block_out_channels": [128, 256, 512, 512],
    "layers_per_block": 2,
    "latent_channels": 4,
    "norm_num_groups": 32,
    "sample_size": 512,
    "scaling_factor": 0.18215,
}
# DDPM noise schedule of SD 1.x / 2.x (scaled-linear betas).
SD_SCHEDULER_CONFIG: dict[str, Any] = {
    "num_train_timesteps": 1000,
    "beta_start": 0.00085,
    "beta_end": 0.012,
    "beta_schedule": "scaled_linear",
}

# Intel/dpt-large: ViT-L/16 encoder at 384 px (config of the public checkpoint).
DPT_LARGE_CONFIG: dict[str, Any] = {
    "hidden_size": 1024,
    "num_hidden_layers": 24,
    "num_attention_heads": 16,
    "intermediate_size": 4096,
    "image_size": 384,
    "patch_size": 16,
    "qkv_bias": True,
    "is_hybrid": False,
    "backbone_out_indices": [5, 11, 17, 23],
    "readout_type": "project",
    "neck_hidden_sizes": [256, 512, 1024, 1024],
    "fusion_hidden_size": 256,
    "layer_norm_eps": 1e-12,
}


SPECS: dict[str, BackboneSpec] = {
    spec.name: spec
    for spec in (
        _vit_b(
            "dino",
            "vit_base_patch16_224",
            "dino",
            "timm/vit_base_patch16_224.dino",
            IMAGENET_MEAN,
            IMAGENET_STD,
            "self-supervised",
            "DINO ViT-B/16 (self-distillation, ImageNet)",
        ),
        _vit_b(
            "dinov2",
            "vit_base_patch14_dinov2",
            "lvd142m",
            "timm/vit_base_patch14_dinov2.lvd142m",
            IMAGENET_MEAN,
            IMAGENET_STD,
            "self-supervised",
            "DINOv2 ViT-B/14 (LVD-142M), no registers",
            patch_size=14,
            native=518,
        ),
        _vit_b(
            "clip",
            "vit_base_patch16_clip_quickgelu_224",
            "openai",
            "timm/vit_base_patch16_clip_224.openai",
            CLIP_MEAN,
            CLIP_STD,
            "language-supervised",
            "OpenAI CLIP ViT-B/16 image tower (QuickGELU)",
        ),
        _vit_b(
            "siglip",
            "vit_base_patch16_siglip_224",
            "webli",
            "timm/vit_base_patch16_siglip_224.webli",
            HALF,
            HALF,
            "language-supervised",
            "SigLIP ViT-B/16 image tower (WebLI), no CLS token",
        ),
        _vit_b(
            "mae",
            "vit_base_patch16_224",
            "mae",
            "timm/vit_base_patch16_224.mae",
            IMAGENET_MEAN,
            IMAGENET_STD,
            "self-supervised",
            "MAE ViT-B/16 encoder, run without masking",
        ),
        _vit_b(
            "deit3",
            "deit3_base_patch16_224",
            "fb_in22k_ft_in1k",
            "timm/deit3_base_patch16_224.fb_in22k_ft_in1k",
            IMAGENET_MEAN,
            IMAGENET_STD,
            "supervised",
            "DeiT III ViT-B/16 (IN-22k -> IN-1k classification)",
        ),
        BackboneSpec(
            name="vit_tiny",
            family="timm_vit",
            arch="vit_tiny_patch16_224",
            weights_id="vit_tiny_patch16_224.augreg_in21k_ft_in1k",
            hf_repo="timm/vit_tiny_patch16_224.augreg_in21k_ft_in1k",
            patch_size=16,
            depth=12,
            default_layers=(2, 5, 8, 11),
            mean=HALF,
            std=HALF,
            native_size=(224, 224),
            default_image_size=(224, 224),
            size_multiple=16,
            supervision="supervised",
            description="ViT-Ti/16 (AugReg IN-21k -> IN-1k); small model for CPU tests and the demo",
        ),
        BackboneSpec(
            name="sam",
            family="timm_sam",
            arch="samvit_base_patch16",
            weights_id="samvit_base_patch16.sa1b",
            hf_repo="timm/samvit_base_patch16.sa1b",
            patch_size=16,
            depth=12,
            default_layers=(2, 5, 8, 11),
            mean=IMAGENET_MEAN,
            std=IMAGENET_STD,
            native_size=(1024, 1024),
            default_image_size=(1024, 1024),
            size_multiple=16,
            supervision="segmentation",
            arch_kwargs={"img_size": 1024},
            description="SAM ViT-B image encoder (SA-1B); blocks 2,5,8,11 are its global-attention blocks",
        ),
        BackboneSpec(
            name="midas",
            family="dpt",
            arch="dpt-large",
            weights_id="Intel/dpt-large",
            hf_repo="Intel/dpt-large",
            patch_size=16,
            depth=24,
            default_layers=(5, 11, 17, 23),
            mean=HALF,
            std=HALF,
            native_size=(384, 384),
            default_image_size=(384, 384),
            size_multiple=16,
            supervision="depth",
            arch_kwargs=DPT_LARGE_CONFIG,
            description="MiDaS v3 DPT-Large: ViT-L/16 encoder hidden states",
        ),
        BackboneSpec(
            name="radio",
            family="radio",
            arch="RADIO-B",
            weights_id="nvidia/RADIO-B",
            hf_repo="nvidia/RADIO-B",
            patch_size=16,
            depth=12,
            default_layers=(2, 5, 8, 11),
            mean=CLIP_MEAN,
            std=CLIP_STD,
            # 512 px: the input of the RADIO authors' own ADE20k linear probe of nvidia/RADIO-B; RADIO accepts
            # any multiple of 16 (its preferred resolution is logged when the model loads)
            native_size=(512, 512),
            default_image_size=(512, 512),
            size_multiple=16,
            supervision="distillation",
            description="AM-RADIO ViT-B/16 (multi-teacher distillation); needs its remote code",
        ),
        BackboneSpec(
            name="sd",
            family="stable_diffusion",
            arch="sd-1.5",
            weights_id="stable-diffusion-v1-5/stable-diffusion-v1-5",
            hf_repo="stable-diffusion-v1-5/stable-diffusion-v1-5",
            patch_size=8,
            depth=4,
            default_layers=(0, 1, 2, 3),
            mean=HALF,
            std=HALF,
            native_size=(512, 512),
            default_image_size=(512, 512),
            size_multiple=64,
            supervision="generative",
            arch_kwargs={"unet": SD15_UNET_CONFIG, "vae": SD15_VAE_CONFIG, "scheduler": SD_SCHEDULER_CONFIG},
            extra={"timestep": 261, "noise_seed": 0, "prompt": ""},
            description="Stable Diffusion 1.5 UNet up-block features of the noised VAE latent (DIFT-style)",
        ),
    )
}


def get_spec(name: str) -> BackboneSpec:
    """The record of backbone ``name``; an unknown name raises ``KeyError`` listing the valid ones."""
    if name not in SPECS:
        raise KeyError(f"unknown backbone name {name!r}; valid names: {', '.join(sorted(SPECS))}")
    return SPECS[name]
