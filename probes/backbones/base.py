"""The common interface of every frozen backbone.

A backbone takes RGB frames in [0, 1] at any size, resizes them to its
``image_size``, applies its own normalisation, runs the frozen model under
``torch.no_grad`` and returns one ``(B, C_l, h, w)`` map per tapped layer with
``h = image_size[0] // patch_size`` and ``w = image_size[1] // patch_size``.
Subclasses implement only :meth:`Backbone._tapped_maps`.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Sequence
from typing import Any, Protocol

import torch
import torch.nn.functional as F

from probes.backbones.specs import BackboneSpec

logger = logging.getLogger(__name__)

FEATURE_DTYPE = torch.float32


class IntermediatesModel(Protocol):
    """A model with timm's ``forward_intermediates`` (timm ViTs, SAM, AM-RADIO)."""

    def forward_intermediates(self, x: torch.Tensor, **kwargs: Any) -> Sequence[torch.Tensor]: ...


@contextlib.contextmanager
def seeded_init(seed: int) -> Iterator[None]:
    """Run a model construction with torch's global RNG seeded by ``seed``, restoring it afterwards."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        yield


def warn_random_weights(name: str, seed: int) -> None:
    """The loud log line every randomly initialised backbone emits."""
    logger.warning(
        "BACKBONE %r USES RANDOM WEIGHTS (pretrained=false, seed=%d): its features are NOT from the pretrained "
        "model; results only test the pipeline.",
        name,
        seed,
    )


class Backbone(torch.nn.Module):
    """A frozen vision model exposing tapped dense feature maps.

    Attributes:
        name: registry name.
        patch_size: pixels per feature cell (effective stride of every returned map).
        feat_dims: channels of each returned map, in ``layers`` order.
        layers: tapped layers (0-based).
        image_size: (H, W) pixels the frames are resized to.
        mean, std: the model's own normalisation of RGB in [0, 1], applied inside :meth:`features`.
        pretrained: whether the weights are the pretrained ones (False: random, seeded by ``seed``).
        spec: the config record the backbone was built from.
    """

    def __init__(
        self,
        spec: BackboneSpec,
        *,
        pretrained: bool,
        layers: list[int],
        image_size: tuple[int, int],
        feat_dims: list[int],
        seed: int,
        extra_key: dict[str, Any] | None = None,
    ) -> None:
        super().__init__()
        self.spec = spec
        self.name: str = spec.name
        self.patch_size: int = spec.patch_size
        self.layers: list[int] = list(layers)
        self.image_size: tuple[int, int] = (int(image_size[0]), int(image_size[1]))
        self.feat_dims: list[int] = list(feat_dims)
        self.mean: tuple[float, float, float] = (
            float(spec.mean[0]),
            float(spec.mean[1]),
            float(spec.mean[2]),
        )
        self.std: tuple[float, float, float] = (float(spec.std[0]), float(spec.std[1]), float(spec.std[2]))
        self.pretrained: bool = bool(pretrained)
        self.seed: int = int(seed)
        self._extra_key: dict[str, Any] = dict(extra_key or {})
        self.weights_path: str | None = None  # set by the factory when weights come from an explicit path
        self.register_buffer("_mean", torch.tensor(self.mean).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("_std", torch.tensor(self.std).view(1, 3, 1, 1), persistent=False)

    # ------------------------------------------------------------------ frozen state
    def freeze(self) -> Backbone:
        """Set every parameter to ``requires_grad=False`` and the module to eval mode."""
        for param in self.parameters():
            param.requires_grad_(False)
        return self.train(False)

    def train(self, mode: bool = True) -> Backbone:
        """A frozen backbone stays in eval mode whatever ``mode`` a parent module asks for."""
        return super().train(False)

    # ------------------------------------------------------------------ features
    @property
    def grid_size(self) -> tuple[int, int]:
        """(h, w) cells of every returned map."""
        return self.image_size[0] // self.patch_size, self.image_size[1] // self.patch_size

    def resize(self, frames: torch.Tensor) -> torch.Tensor:
        """Frames (B, 3, H, W) in [0, 1] -> float32 (B, 3, *image_size) on the backbone's device."""
        if frames.ndim != 4 or frames.shape[1] != 3:
            raise ValueError(f"frames must have shape (B, 3, H, W); got {tuple(frames.shape)}")
        if not torch.is_floating_point(frames):
            raise TypeError(f"frames must be a float tensor with RGB in [0, 1]; got dtype {frames.dtype}")
        x = frames.to(device=self._mean.device, dtype=FEATURE_DTYPE)
        if tuple(x.shape[-2:]) != self.image_size:
            x = F.interpolate(x, size=self.image_size, mode="bilinear", align_corners=False, antialias=True)
        return x

    def preprocess(self, frames: torch.Tensor) -> torch.Tensor:
        """Frames (B, 3, H, W) in [0, 1] -> resized to ``image_size`` and normalised with mean/std.

        Models whose own code normalises (AM-RADIO's input conditioner) override this to only resize.
        """
        return (self.resize(frames) - self._mean) / self._std

    def features(self, frames: torch.Tensor) -> list[torch.Tensor]:
        """Frames (B, 3, H, W) float RGB in [0, 1] at any size -> one (B, C_l, h, w) map per tapped layer."""
        with torch.no_grad():
            maps = self._tapped_maps(self.preprocess(frames))
        expected = self.grid_size
        for layer, dim, fmap in zip(self.layers, self.feat_dims, maps, strict=True):
            if tuple(fmap.shape[1:]) != (dim, *expected):
                raise RuntimeError(
                    f"backbone {self.name!r} layer {layer} returned shape {tuple(fmap.shape)}; "
                    f"expected (B, {dim}, {expected[0]}, {expected[1]})"
                )
        return [fmap.contiguous() for fmap in maps]

    def forward(self, frames: torch.Tensor) -> list[torch.Tensor]:
        """Same as :meth:`features`."""
        return self.features(frames)

    def _tapped_maps(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Normalised (B, 3, *image_size) input -> tapped maps. Implemented by each family."""
        raise NotImplementedError

    # ------------------------------------------------------------------ cache key
    def cache_key(self) -> dict[str, Any]:
        """Everything that changes the features (JSON-serialisable)."""
        return {
            "backbone": self.name,
            "family": self.spec.family,
            "arch": self.spec.arch,
            "weights": self.spec.weights_id if self.pretrained else f"random(seed={self.seed})",
            "pretrained": self.pretrained,
            "weights_path": self.weights_path,
            "image_size": list(self.image_size),
            "patch_size": self.patch_size,
            "layers": list(self.layers),
            "feat_dims": list(self.feat_dims),
            "mean": list(self.mean),
            "std": list(self.std),
            "resize": "bilinear-antialias",
            "dtype": str(FEATURE_DTYPE).replace("torch.", ""),
            "extra": dict(self._extra_key),
        }
