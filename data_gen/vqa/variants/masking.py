"""Answering without looking: the asked object hidden under a black disc (``roi_masked``), or every image
black (``black_image``). The texts stay as they are."""

from __future__ import annotations

from typing import Any

import numpy as np

from data_gen.vqa.variants.registry import (
    VariantInputs,
    VariantOutput,
    derive,
    named_once,
    variant,
    variant_image_path,
)
from data_gen.vqa.variants.roi import draw_disc


@variant("roi_masked")
def roi_masked(inputs: VariantInputs, records: list[dict[str, Any]]) -> VariantOutput:
    """Questions naming one object: a filled black disc over its whole silhouette on every question image."""
    out = VariantOutput()
    for r in records:
        target = named_once(r)
        if target is None:
            continue
        paths = list(r["question_images"])
        for k, t in enumerate(r["frames"]):
            mask = inputs.amodal(t, target)
            if mask.any():
                paths[k] = variant_image_path("roi_masked", inputs.view.sequence_id, t, target)
                if paths[k] not in out.images:
                    out.images[paths[k]] = draw_disc(inputs.rgb(t), mask)
        out.records.append(derive(r, "roi_masked", question_images=paths))
    return out


@variant("black_image")
def black_image(inputs: VariantInputs, records: list[dict[str, Any]]) -> VariantOutput:
    """Every item, every image (question and option images) replaced by an all-black one of the same size."""
    out = VariantOutput()
    h, w = inputs.view.image_size
    black = np.zeros((h, w, 3), np.uint8)
    sid = inputs.view.sequence_id

    def paths(frames: list[int]) -> list[str]:
        chosen = [variant_image_path("black_image", sid, t) for t in frames]
        out.images.update({p: black for p in chosen})
        return chosen

    for r in records:
        out.records.append(derive(r, "black_image", question_images=paths(r["frames"]),
                                  option_images=paths(r["option_frames"])))  # fmt: skip
    return out
