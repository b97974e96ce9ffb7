"""timm ViT family: DINO, DINOv2, CLIP, SigLIP, MAE, DeiT III and ViT-Tiny.

The model is created with ``dynamic_img_size=True`` so any ``image_size`` that
is a multiple of the patch size works (position embeddings are interpolated by
timm on the fly, never overwritten). Dense maps come from
``forward_intermediates(..., output_fmt="NCHW", intermediates_only=True)``,
which drops CLS and register tokens (DINOv2 registers, SigLIP has none) and
returns the raw block outputs (no final norm). MAE runs as a plain encoder:
no masking.
"""

from __future__ import annotations

import os
from typing import Any, cast

import torch

from probes.backbones.base import Backbone, IntermediatesModel, seeded_init, warn_random_weights
from probes.backbones.specs import BackboneSpec
from probes.backbones.weights import resolve_hf_file

TIMM_WEIGHT_FILES: tuple[str, ...] = ("model.safetensors", "pytorch_model.bin")


class TimmBackbone(Backbone):
    """A timm model with ``forward_intermediates`` (VisionTransformer or VisionTransformerSAM)."""

    def __init__(self, spec: BackboneSpec, model: torch.nn.Module, **kwargs: Any) -> None:
        embed_dim = int(model.embed_dim)
        super().__init__(spec, feat_dims=[embed_dim] * len(kwargs["layers"]), **kwargs)
        self.model = model
        self.freeze()

    def _tapped_maps(self, x: torch.Tensor) -> list[torch.Tensor]:
        model = cast(IntermediatesModel, self.model)
        return list(
            model.forward_intermediates(
                x, indices=self.layers, output_fmt="NCHW", intermediates_only=True, stop_early=True
            )
        )


def create_timm_model(
    spec: BackboneSpec,
    *,
    pretrained: bool,
    seed: int,
    weights_path: str | os.PathLike[str] | None,
    allow_download: bool,
    model_kwargs: dict[str, Any],
) -> torch.nn.Module:
    """The timm model of ``spec``: pretrained from a local file, or random weights seeded by ``seed``."""
    import timm

    if pretrained:
        path = resolve_hf_file(spec.name, spec.hf_repo, TIMM_WEIGHT_FILES, weights_path, allow_download)
        return timm.create_model(
            spec.weights_id, pretrained=True, pretrained_cfg_overlay={"file": str(path)}, **model_kwargs
        )
    warn_random_weights(spec.name, seed)
    with seeded_init(seed):
        return timm.create_model(spec.arch, pretrained=False, **model_kwargs)


def build_timm_vit(
    spec: BackboneSpec,
    *,
    pretrained: bool,
    layers: list[int],
    image_size: tuple[int, int],
    seed: int,
    weights_path: str | os.PathLike[str] | None = None,
    allow_download: bool = True,
    arch_overrides: dict[str, Any] | None = None,
) -> TimmBackbone:
    """A ViT of the timm family; ``arch_overrides`` (e.g. ``depth``) are for reduced test configs only."""
    model_kwargs = {**spec.arch_kwargs, "dynamic_img_size": True, **(arch_overrides or {})}
    model = create_timm_model(
        spec,
        pretrained=pretrained,
        seed=seed,
        weights_path=weights_path,
        allow_download=allow_download,
        model_kwargs=model_kwargs,
    )
    return TimmBackbone(
        spec,
        model,
        pretrained=pretrained,
        layers=layers,
        image_size=image_size,
        seed=seed,
        extra_key={"arch_overrides": dict(arch_overrides or {})},
    )
