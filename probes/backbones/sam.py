"""SAM ViT-B image encoder (timm ``samvit_base_patch16``).

The model is always created at its native 1024 px so the pretrained absolute
position embeddings and relative-position tables load unchanged. A smaller
``image_size`` (any multiple of 16) is allowed: timm resamples the absolute
position embedding to the input grid on every forward
(``resample_abs_pos_embed_nhwc``) and SAM's attention interpolates its
relative-position tables, so weights are never overwritten. Windowed blocks
pad to the 14 x 14 window. Features are the 768-d outputs of the tapped
blocks (default 2, 5, 8, 11: the global-attention blocks), before the neck.
The original SAM takes pixels in [0, 255] with mean/std x 255; that equals
ImageNet mean/std on [0, 1] input.
"""

from __future__ import annotations

import os
from typing import Any

from probes.backbones.specs import BackboneSpec
from probes.backbones.vit_timm import TimmBackbone, create_timm_model


def build_sam(
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
    """The SAM image encoder; ``image_size`` below 1024 uses interpolated position embeddings."""
    model_kwargs = {**spec.arch_kwargs, **(arch_overrides or {})}
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
        extra_key={
            "arch_overrides": dict(arch_overrides or {}),
            "model_img_size": model_kwargs.get("img_size"),
        },
    )
