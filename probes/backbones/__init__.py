"""Frozen vision backbones behind one interface, built by one factory.

    >>> from probes.backbones import build_backbone
    >>> bb = build_backbone("vit_tiny", pretrained=False, image_size=64)
    >>> maps = bb.features(frames)      # frames (B, 3, H, W) in [0, 1] -> [(B, 192, 4, 4)] * 4

Every model is declared as data in :mod:`probes.backbones.specs`; the factory
validates the arguments, drops ``None`` overrides (``null`` in a Hydra config
means "the model's default") and hands the record to its family's builder.
"""

from __future__ import annotations

import dataclasses
import importlib
import itertools
from collections.abc import Callable, Mapping, Sequence
from typing import Any

from probes.backbones.base import Backbone
from probes.backbones.specs import SPECS, BackboneSpec, get_spec
from probes.backbones.weights import WeightsUnavailableError

__all__ = [
    "BACKBONE_NAMES",
    "Backbone",
    "BackboneSpec",
    "WeightsUnavailableError",
    "build_backbone",
    "get_spec",
    "list_backbones",
]

BACKBONE_NAMES: tuple[str, ...] = tuple(sorted(SPECS))

# family -> "module:function"; imported lazily so `import probes.backbones` stays light.
_BUILDERS: dict[str, str] = {
    "timm_vit": "probes.backbones.vit_timm:build_timm_vit",
    "timm_sam": "probes.backbones.sam:build_sam",
    "dpt": "probes.backbones.midas:build_midas",
    "radio": "probes.backbones.radio:build_radio",
    "stable_diffusion": "probes.backbones.stable_diffusion:build_stable_diffusion",
}
# overrides every family accepts, beyond name/pretrained/layers/image_size
_COMMON_OVERRIDES: tuple[str, ...] = ("seed", "weights_path", "allow_download", "arch_overrides")
# overrides that replace fields of the config record (a config naming other weights of the same arch)
_SPEC_OVERRIDES: tuple[str, ...] = ("weights_id", "hf_repo", "supervision")
# family-specific overrides (they change the features and enter the cache key)
_FAMILY_OVERRIDES: dict[str, tuple[str, ...]] = {"stable_diffusion": ("timestep", "noise_seed", "prompt")}
# name of the depth argument in arch_overrides per family (reduced test configs)
_DEPTH_KEYS: dict[str, str] = {"timm_vit": "depth", "timm_sam": "depth", "dpt": "num_hidden_layers"}


def list_backbones() -> list[str]:
    """Valid registry names."""
    return list(BACKBONE_NAMES)


def _plain(value: Any) -> Any:
    """OmegaConf containers -> plain Python (Hydra passes ListConfig/DictConfig)."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf
    except ImportError:  # pragma: no cover - hydra is a dependency
        return value
    if isinstance(value, (DictConfig, ListConfig)):
        return OmegaConf.to_container(value, resolve=True)
    return value


def _depth(spec: BackboneSpec, arch_overrides: Mapping[str, Any]) -> int:
    """Number of tappable layers, honouring a reduced-depth test config."""
    if spec.family == "stable_diffusion" and "unet" in arch_overrides:
        return len(arch_overrides["unet"].get("up_block_types", spec.arch_kwargs["unet"]["up_block_types"]))
    key = _DEPTH_KEYS.get(spec.family)
    return int(arch_overrides[key]) if key and key in arch_overrides else spec.depth


def _check_layers(spec: BackboneSpec, layers: Any, depth: int) -> list[int]:
    if layers is None:
        if max(spec.default_layers) >= depth:
            raise ValueError(
                f"the default layers {list(spec.default_layers)} of {spec.name!r} do not fit a reduced depth of "
                f"{depth}: pass layers explicitly (each in [0, {depth - 1}])"
            )
        return list(spec.default_layers)
    if isinstance(layers, int) or not isinstance(layers, Sequence) or len(layers) == 0:
        raise ValueError(f"layers must be a non-empty list of ints in [0, {depth - 1}]; got {layers!r}")
    out = [int(v) for v in layers]
    if any(v < 0 or v >= depth for v in out):
        raise ValueError(f"layers={out} for backbone {spec.name!r}: each tap must be in [0, {depth - 1}]")
    if any(b <= a for a, b in itertools.pairwise(out)):
        raise ValueError(f"layers={out} for backbone {spec.name!r} must be strictly increasing (no repeats)")
    return out


def _check_image_size(spec: BackboneSpec, image_size: Any) -> tuple[int, int]:
    if image_size is None:
        return spec.default_image_size
    if isinstance(image_size, int):
        size = (image_size, image_size)
    elif isinstance(image_size, Sequence) and len(image_size) == 2:
        size = (int(image_size[0]), int(image_size[1]))
    else:
        raise ValueError(f"image_size must be an int or [H, W]; got {image_size!r}")
    m = spec.size_multiple
    if any(s <= 0 or s % m for s in size):
        raise ValueError(
            f"image_size={list(size)} for backbone {spec.name!r}: H and W must be positive multiples of {m} px "
            f"(e.g. {[max(m, round(s / m) * m) for s in size]})"
        )
    return size


def _builder(family: str) -> Callable[..., Backbone]:
    module_name, func = _BUILDERS[family].split(":")
    return getattr(importlib.import_module(module_name), func)


def build_backbone(
    name: str,
    pretrained: bool = True,
    layers: list[int] | None = None,
    image_size: int | list[int] | None = None,
    **overrides: Any,
) -> Backbone:
    """Build the frozen backbone ``name``.

    Args:
        name: registry name, one of :data:`BACKBONE_NAMES`.
        pretrained: load the real pretrained weights (from the HF cache or ``weights_path``; missing weights
            are downloaded into the HF cache, like timm / transformers; with ``HF_HUB_OFFLINE=1`` or
            ``allow_download=False`` they raise :class:`WeightsUnavailableError` at once). False: same architecture, random weights seeded
            by ``seed`` (logged loudly).
        layers: tapped layers (0-based); None: the model's default taps.
        image_size: int or [H, W] pixels frames are resized to; None: the model's default.
        **overrides: ``seed`` (int, default 0), ``weights_path``, ``allow_download`` (bool, default True: fetch missing
            weights into the HF cache as timm and transformers do, unless ``HF_HUB_OFFLINE=1``),
            ``arch_overrides`` (dict: reduced architecture for tests; only with pretrained=False),
            ``weights_id`` / ``hf_repo`` / ``supervision`` (replace the record's), and for ``sd``:
            ``timestep`` (int), ``noise_seed`` (int), ``prompt`` (str). ``None`` values mean "default".
    """
    name = str(name)
    spec = get_spec(name)
    overrides = {k: _plain(v) for k, v in overrides.items() if v is not None}
    allowed = set(_COMMON_OVERRIDES) | set(_SPEC_OVERRIDES) | set(_FAMILY_OVERRIDES.get(spec.family, ()))
    unknown = sorted(set(overrides) - allowed)
    if unknown:
        raise TypeError(f"unknown option(s) {unknown} for backbone {name!r}; allowed: {sorted(allowed)}")
    spec_fields = {k: overrides.pop(k) for k in _SPEC_OVERRIDES if k in overrides}
    if spec_fields:
        spec = dataclasses.replace(spec, **spec_fields)
    arch_overrides = dict(overrides.pop("arch_overrides", {}) or {})
    if pretrained and arch_overrides:
        raise ValueError(
            f"arch_overrides={arch_overrides} changes the architecture of {name!r}; pretrained weights would not "
            "fit: use pretrained=false with reduced configs"
        )
    seed = int(overrides.pop("seed", 0))
    if seed < 0:
        raise ValueError(f"seed must be >= 0; got {seed}")
    weights_path = overrides.pop("weights_path", None)
    backbone = _builder(spec.family)(
        spec,
        pretrained=bool(pretrained),
        layers=_check_layers(spec, _plain(layers), _depth(spec, arch_overrides)),
        image_size=_check_image_size(spec, _plain(image_size)),
        seed=seed,
        weights_path=weights_path,
        allow_download=bool(overrides.pop("allow_download", True)),
        arch_overrides=arch_overrides,
        **overrides,
    )
    if pretrained and weights_path is not None:
        backbone.weights_path = str(weights_path)  # an explicit file may differ from the named weights id
    return backbone
