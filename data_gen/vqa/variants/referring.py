"""How a question refers to its object: the seven combinations of name, red circle (ROI) and image location.

Name only is the base question; the six others are variants. They apply to questions whose text names exactly
one object (a question about two named objects would read "the object circled in red" twice). The circle is
drawn on every question image where the object is in view (options that are images stay as they are); the
location is the 3 x 3 grid cell of the object's visible pixels in the question's last frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from data_gen.vqa.variants.registry import (
    VariantInputs,
    VariantOutput,
    derive,
    named_once,
    refer,
    variant,
    variant_image_path,
)  # fmt: skip
from data_gen.vqa.variants.roi import draw_ring, grid_location

CIRCLE_IMAGES = "roi_circle"
"""Image directory shared by every variant that draws the circle (the same pixels)."""


@dataclass(frozen=True)
class Reference:
    name: bool
    circle: bool
    location: bool

    def phrase(self, name: str, location: str, multi: bool) -> str:
        where = f"located at the {location} of the {'last frame' if multi else 'image'}"
        if self.name:
            return " ".join(filter(None, (f"the {name}", "(circled in red)" if self.circle else "",
                                          where if self.location else "")))  # fmt: skip
        if self.circle and self.location:
            return f"the object circled in red and {where}"
        return "the object circled in red" if self.circle else f"the object {where}"


REFERENCES: dict[str, Reference] = {
    "roi_circle": Reference(name=True, circle=True, location=False),
    "location": Reference(name=True, circle=False, location=True),
    "roi_circle_location": Reference(name=True, circle=True, location=True),
    "roi_only": Reference(name=False, circle=True, location=False),
    "location_only": Reference(name=False, circle=False, location=True),
    "roi_location_only": Reference(name=False, circle=True, location=True),
}


def circled_images(inputs: VariantInputs, record: dict[str, Any], object_id: int, out: VariantOutput) -> list[str]:
    """The record's question images with a red ring around ``object_id`` where it is in view."""
    paths = list(record["question_images"])
    for k, t in enumerate(record["frames"]):
        mask = inputs.amodal(t, object_id)
        if mask.any():
            paths[k] = variant_image_path(CIRCLE_IMAGES, inputs.view.sequence_id, t, object_id)
            if paths[k] not in out.images:
                out.images[paths[k]] = draw_ring(inputs.rgb(t), mask)
    return paths


def location_of(inputs: VariantInputs, record: dict[str, Any], object_id: int) -> str | None:
    t = record["frames"][-1]
    visible = inputs.instances(t) == object_id
    return grid_location(visible if visible.any() else inputs.amodal(t, object_id))


def _make(name: str, ref: Reference):
    @variant(name)
    def make(inputs: VariantInputs, records: list[dict[str, Any]]) -> VariantOutput:
        out = VariantOutput()
        for r in records:
            target = named_once(r)
            if target is None:
                continue
            location = location_of(inputs, r, target) if ref.location else ""
            if location is None:
                out.skips["object_not_in_view"] += 1
                continue
            text = refer(r["question"], inputs.view.name(target) or "", ref.phrase(inputs.view.name(target) or "",
                                                                                  location, r["mode"] == "multi"))
            images = circled_images(inputs, r, target, out) if ref.circle else r["question_images"]
            meta = {**r["meta"], **({"location": location} if ref.location else {})}
            out.records.append(derive(r, name, question=text, question_images=images, meta=meta))
        return out

    return make


for _name, _ref in REFERENCES.items():
    _make(_name, _ref)
