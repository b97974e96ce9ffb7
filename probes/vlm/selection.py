"""Which items of a question set a run asks -- one rule for the evaluation loop, the shard merge and scoring.

The rule reads only a run manifest (:class:`~probes.vlm.interface.RunManifest` as a dict), so a run directory
says by itself which items it should hold:

* a model with ``model.single_image_only`` gets ``single`` items only (reason ``multi``);
* a model with ``model.max_images`` gets no item with more images (reason ``too_many_images``);
* ``extra.modes``, when recorded, restricts the modes (reason ``mode``);
* ``extra.limit``, when recorded, keeps the first N of the rest in set order (reason ``limit``).

Sharding (:func:`probes.vlm.sharding.shard_items`) splits the asked items after this selection.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from newtphys import vqa_schema as vs

NOT_ASKED_REASONS: tuple[str, ...] = ("multi", "too_many_images", "mode", "limit")


def asked_items(
    items: Sequence[vs.QuestionItem], manifest: dict[str, Any]
) -> tuple[list[vs.QuestionItem], dict[str, int]]:
    """The items the run's answerer is asked, in set order, and the counts left out by reason
    (module docstring)."""
    model, extra = manifest.get("model") or {}, manifest.get("extra") or {}
    modes = extra.get("modes")
    max_images = model.get("max_images")
    keep: list[vs.QuestionItem] = []
    left = dict.fromkeys(NOT_ASKED_REASONS, 0)
    for it in items:
        if model.get("single_image_only") and it.mode != "single":
            left["multi"] += 1
        elif max_images is not None and len(it.images) > int(max_images):
            left["too_many_images"] += 1
        elif modes is not None and it.mode not in modes:
            left["mode"] += 1
        else:
            keep.append(it)
    limit = extra.get("limit")
    if limit is not None:
        if int(limit) < 1:
            raise ValueError(f"manifest extra.limit={limit!r}: must be >= 1 or absent")
        left["limit"] = max(0, len(keep) - int(limit))
        keep = keep[: int(limit)]
    return keep, left
