"""AM-RADIO (``nvidia/RADIO-B``): real loading only.

RADIO is a timm ViT-B/16 whose patch embedding is replaced by RADIO's own
patch generator (cropped position embeddings from a large grid, one CLS token
per teacher plus registers) and whose input conditioner applies the CLIP
mean/std inside the model. That code is not part of timm, transformers or this
repository: it ships with the checkpoint (``trust_remote_code``). A plain timm
ViT-B/16 with random weights is therefore NOT an architecture-faithful
stand-in, and ``pretrained=false`` is refused with a clear error instead of
returning a different network under RADIO's name.

With ``pretrained=true`` the snapshot (config, remote code, weights) must be
in the local HF cache or at ``weights_path``; the model is loaded with
``transformers.AutoModel.from_pretrained(local_dir, trust_remote_code=True)``
and its ``forward_intermediates(x, indices, output_fmt="NCHW",
intermediates_only=True)`` gives the tapped maps (prefix tokens dropped). The
frames are only resized here: RADIO normalises them itself.
"""

from __future__ import annotations

import logging
import os
from typing import Any, cast

import torch

from probes.backbones.base import Backbone, IntermediatesModel
from probes.backbones.specs import BackboneSpec
from probes.backbones.weights import resolve_hf_snapshot

logger = logging.getLogger(__name__)

RADIO_REQUIRED_FILES: tuple[str, ...] = ("config.json",)


class RadioUnavailableError(NotImplementedError):
    """RADIO cannot be built without its remote code and weights."""


class RadioBackbone(Backbone):
    """A loaded RADIO model; ``model`` exposes ``forward_intermediates`` and normalises internally."""

    def __init__(self, spec: BackboneSpec, model: torch.nn.Module, embed_dim: int, **kwargs: Any) -> None:
        super().__init__(spec, feat_dims=[embed_dim] * len(kwargs["layers"]), **kwargs)
        self.model = model
        self.freeze()

    def preprocess(self, frames: torch.Tensor) -> torch.Tensor:
        """Resize only: RADIO's input conditioner applies the CLIP mean/std inside the model."""
        return self.resize(frames)

    def _tapped_maps(self, x: torch.Tensor) -> list[torch.Tensor]:
        inner = cast(IntermediatesModel, getattr(self.model, "radio_model", self.model))
        return list(
            inner.forward_intermediates(x, indices=self.layers, output_fmt="NCHW", intermediates_only=True)
        )


def _embed_dim(model: torch.nn.Module) -> int:
    inner = getattr(model, "radio_model", model)
    for owner in (inner, getattr(inner, "model", None)):
        dim = getattr(owner, "embed_dim", None)
        if dim is not None:
            return int(dim)
    raise RadioUnavailableError("loaded RADIO model exposes no embed_dim; cannot declare feat_dims")


def build_radio(
    spec: BackboneSpec,
    *,
    pretrained: bool,
    layers: list[int],
    image_size: tuple[int, int],
    seed: int,
    weights_path: str | os.PathLike[str] | None = None,
    allow_download: bool = True,
    arch_overrides: dict[str, Any] | None = None,
) -> RadioBackbone:
    """Load AM-RADIO from the local HF cache / ``weights_path``; ``pretrained=false`` raises."""
    if not pretrained:
        raise RadioUnavailableError(
            "backbone 'radio' has no pretrained=false mode: AM-RADIO's architecture (its CPE patch generator, "
            "per-teacher CLS tokens and registers) lives in the checkpoint's remote code, which is not installed, "
            "and a plain timm ViT-B/16 would not be the same network. Provide the snapshot of "
            f"{spec.hf_repo!r} (HF cache or backbone.weights_path) and use pretrained=true, or probe another backbone."
        )
    if arch_overrides:
        raise ValueError(f"arch_overrides={arch_overrides} is not supported for 'radio'")
    local_dir = resolve_hf_snapshot(
        spec.name, spec.hf_repo, RADIO_REQUIRED_FILES, weights_path, allow_download
    )
    from transformers import AutoModel

    model = AutoModel.from_pretrained(str(local_dir), trust_remote_code=True, local_files_only=True)
    preferred = getattr(getattr(model, "radio_model", model), "preferred_resolution", None)
    logger.info("loaded AM-RADIO from %s (preferred resolution %s)", local_dir, preferred)
    return RadioBackbone(
        spec,
        model,
        _embed_dim(model),
        pretrained=True,
        layers=layers,
        image_size=image_size,
        seed=seed,
        extra_key={"normalisation": "inside model (CLIP mean/std)"},
    )
