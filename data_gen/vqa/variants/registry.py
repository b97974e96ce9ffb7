"""The variant registry and what every variant function receives and returns.

A variant function turns the base records of one sequence (before letters are assigned) into its own records
and the images they show. Derived records keep the base record's letter order (``letter_pair``), so that a
variant item differs from its base item only in what the variant changes; counterfactual records are
questions of their own (``CF_<id>``) and get their own balanced letters.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from data_gen.vqa.rules import mention
from data_gen.vqa.view import SequenceView
from newtphys import vqa_schema as vs


@dataclass(frozen=True)
class CounterfactualSettings:
    """``counterfactual:`` of ``conf/generate_vqa.yaml`` (read only when a ``cf_*`` variant is asked for)."""

    gravity_scale: float
    """cf_gravity: gravity times this."""
    shift_m: float
    """cf_shift: one object starts this far to the camera's right (or left when the right is blocked), m."""
    resize_factor: float
    """cf_resize: one object's size times this."""
    device: str
    """Warp device of the twin's simulation and rendering (``cpu`` or ``cuda``)."""

    @staticmethod
    def from_mapping(cfg: dict[str, Any]) -> CounterfactualSettings:
        known = {"gravity_scale", "shift_m", "resize_factor", "device"}
        if set(cfg) != known:
            raise ValueError(f"generate_vqa config: counterfactual keys: unknown {sorted(set(cfg) - known)}, "
                             f"missing {sorted(known - set(cfg))}")  # fmt: skip
        out = CounterfactualSettings(float(cfg["gravity_scale"]), float(cfg["shift_m"]), float(cfg["resize_factor"]),
                                     str(cfg["device"]))  # fmt: skip
        if not (out.gravity_scale > 0 and out.gravity_scale != 1):
            raise ValueError(f"generate_vqa config: counterfactual.gravity_scale must be > 0 and != 1, got {out.gravity_scale}")
        if out.shift_m < 0.1:
            raise ValueError(f"generate_vqa config: counterfactual.shift_m must be >= 0.1 m, got {out.shift_m}")
        if not (out.resize_factor > 0 and out.resize_factor != 1):
            raise ValueError(f"generate_vqa config: counterfactual.resize_factor must be > 0 and != 1, got {out.resize_factor}")
        if out.device not in ("cpu", "cuda") and not out.device.startswith("cuda:"):
            raise ValueError(f"generate_vqa config: counterfactual.device must be 'cpu' or 'cuda[:n]', got {out.device!r}")
        return out


class VariantInputs:
    """One sequence's view, the run's seed and settings, and its frames read once (RGB, instance ids, amodal
    masks) for every variant that draws on them."""

    def __init__(self, view: SequenceView, seed: int, counterfactual: CounterfactualSettings, twin_dir: Path) -> None:
        self.view = view
        self.seed = seed
        self.counterfactual = counterfactual
        self.twin_dir = twin_dir
        """Where counterfactual twins' world states are kept (``<set>/counterfactuals``)."""
        self._rgb: dict[int, np.ndarray] = {}
        self._instances: dict[int, np.ndarray] = {}
        self._amodal: dict[int, np.ndarray] = {}
        self.memo: dict[str, Any] = {}
        """Results shared by several variants of the sequence (the factual scenario of the counterfactuals)."""

    def rgb(self, frame: int) -> np.ndarray:
        if frame not in self._rgb:
            self._rgb[frame] = self.view.read_rgb([frame])[0]
        return self._rgb[frame]

    def instances(self, frame: int) -> np.ndarray:
        if frame not in self._instances:
            self._instances[frame] = self.view.read_instances([frame])[0]
        return self._instances[frame]

    def amodal(self, frame: int, object_id: int) -> np.ndarray:
        """The whole silhouette of ``object_id`` at ``frame`` (H, W) bool, occluded parts included."""
        if frame not in self._amodal:
            self._amodal[frame] = self.view.read_amodal([frame])[0]
        return self._amodal[frame][self.view.object_index(object_id)]


@dataclass
class VariantOutput:
    records: list[dict[str, Any]] = field(default_factory=list)
    images: dict[str, np.ndarray] = field(default_factory=dict)
    """Set-relative path -> RGB (H, W, 3) uint8 to write."""
    skips: Counter = field(default_factory=Counter)
    """Reason -> base records the variant did not apply to although it could have been asked."""


VariantFunction = Callable[[VariantInputs, list[dict[str, Any]]], VariantOutput]
REGISTRY: dict[str, VariantFunction] = {}


def variant(name: str) -> Callable[[VariantFunction], VariantFunction]:
    """Register ``fn`` as the maker of variant ``name`` (a name of ``newtphys.vqa_schema.VARIANTS``)."""
    if name not in vs.VARIANTS or name == vs.BASE_VARIANT:
        raise KeyError(f"{name!r} is not a variant of newtphys.vqa_schema.VARIANTS")

    def register(fn: VariantFunction) -> VariantFunction:
        if name in REGISTRY:
            raise KeyError(f"variant {name} registered twice")
        REGISTRY[name] = fn
        return fn

    return register


def derive(record: dict[str, Any], name: str, **changes: Any) -> dict[str, Any]:
    """A copy of base ``record`` as variant ``name``: its own pair and idx, the base record's letter order."""
    pair = f"{record['pair']}/{name}"
    return {**record, **changes, "variant": name, "pair": pair, "idx": f"{pair}/{record['mode']}",
            "letter_pair": record["pair"]}  # fmt: skip


def variant_image_path(kind: str, sequence_id: str, frame: int, object_id: int | None = None) -> str:
    """``images/<kind>/<sequence_id>/<frame:06d>[-o<object>].png`` (set-relative)."""
    suffix = "" if object_id is None else f"-o{object_id}"
    return f"{vs.IMAGES_DIR}/{kind}/{sequence_id}/{frame:06d}{suffix}.png"


def named_once(record: dict[str, Any]) -> int | None:
    """The one object the question's text names, or None (none or several)."""
    named = record["named"]
    return named[0] if len(named) == 1 else None


def refer(text: str, name: str, phrase: str) -> str:
    """``text`` with every mention "the <name>" replaced by ``phrase`` (whole words only)."""
    pattern = mention(name)
    if not pattern.search(text):
        raise ValueError(f"question text {text!r} does not mention 'the {name}'")
    return pattern.sub(lambda _: phrase, text)
