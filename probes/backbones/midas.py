"""MiDaS v3 DPT-Large encoder (transformers ``DPTModel``, weights ``Intel/dpt-large``).

The maps are the hidden states of the ViT-L/16 encoder after blocks 5, 11,
17, 23 (0-based; the layers DPT's own neck reads), CLS token dropped, tokens
reshaped to (B, 1024, H/16, W/16). DPT interpolates its position embeddings
to the input grid on every forward, so any multiple of 16 works; the native
resolution is 384. Only the encoder is used (no neck, no depth head).
"""

from __future__ import annotations

import os
from typing import Any

import torch

from probes.backbones.base import Backbone, seeded_init, warn_random_weights
from probes.backbones.specs import BackboneSpec
from probes.backbones.weights import resolve_hf_snapshot

DPT_REQUIRED_FILES: tuple[str, ...] = ("config.json",)


class DPTEncoderBackbone(Backbone):
    """Tapped hidden states of a transformers ``DPTModel`` (ViT encoder, one CLS token)."""

    def __init__(self, spec: BackboneSpec, model: torch.nn.Module, **kwargs: Any) -> None:
        hidden = int(model.config.hidden_size)
        super().__init__(spec, feat_dims=[hidden] * len(kwargs["layers"]), **kwargs)
        self.model = model
        self.freeze()

    def _tapped_maps(self, x: torch.Tensor) -> list[torch.Tensor]:
        hidden_states = self.model(pixel_values=x, output_hidden_states=True).hidden_states
        h, w = self.grid_size
        maps = []
        for layer in self.layers:
            tokens = hidden_states[layer + 1][:, 1:]  # index 0 is the embedding output; drop CLS
            maps.append(tokens.transpose(1, 2).reshape(x.shape[0], -1, h, w))
        return maps


def build_midas(
    spec: BackboneSpec,
    *,
    pretrained: bool,
    layers: list[int],
    image_size: tuple[int, int],
    seed: int,
    weights_path: str | os.PathLike[str] | None = None,
    allow_download: bool = True,
    arch_overrides: dict[str, Any] | None = None,
) -> DPTEncoderBackbone:
    """DPT-Large encoder; ``arch_overrides`` (DPTConfig fields) give reduced test configs."""
    from transformers import DPTConfig, DPTModel

    if pretrained:
        local_dir = resolve_hf_snapshot(
            spec.name, spec.hf_repo, DPT_REQUIRED_FILES, weights_path, allow_download
        )
        model = DPTModel.from_pretrained(str(local_dir), add_pooling_layer=False, local_files_only=True)
    else:
        warn_random_weights(spec.name, seed)
        config = DPTConfig(**{**spec.arch_kwargs, **(arch_overrides or {})})
        with seeded_init(seed):
            model = DPTModel(config, add_pooling_layer=False)
    return DPTEncoderBackbone(
        spec,
        model,
        pretrained=pretrained,
        layers=layers,
        image_size=image_size,
        seed=seed,
        extra_key={"arch_overrides": dict(arch_overrides or {})},
    )
