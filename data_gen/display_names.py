"""Human-readable object names, unique within a scene (what questions call objects).

A name is the asset's name in words (``tennis_ball`` -> "tennis ball"). When several objects of a scene
would share it, a distinguishing word goes in front: their colour ("red ball", "blue ball") when the
colours differ, else their size ("small ball", "large ball") for two objects whose sizes differ by at
least ``SIZE_RATIO``. When neither tells them apart the name is None: questions then skip naming them.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

SIZE_RATIO = 1.25
"""Largest extents must differ by this factor for "small"/"large" to tell two objects apart."""
_HUES: tuple[tuple[float, str], ...] = (
    (15.0, "red"), (40.0, "orange"), (70.0, "yellow"), (160.0, "green"), (250.0, "blue"), (290.0, "purple"),
    (335.0, "pink"), (360.0, "red"),
)  # fmt: skip


def color_name(rgb: ArrayLike) -> str:
    """A basic colour word for a linear-ish RGB colour in [0, 1] (black, white, grey, brown or a hue)."""
    r, g, b = (float(v) for v in np.clip(np.asarray(rgb, np.float64), 0.0, 1.0))
    hi, lo = max(r, g, b), min(r, g, b)
    sat = 0.0 if hi <= 0 else (hi - lo) / hi
    if hi < 0.18:
        return "black"
    if sat < 0.18:
        return "white" if hi > 0.8 else "grey"
    if hi == r:
        hue = (60.0 * (g - b) / (hi - lo)) % 360.0
    elif hi == g:
        hue = 60.0 * (b - r) / (hi - lo) + 120.0
    else:
        hue = 60.0 * (r - g) / (hi - lo) + 240.0
    name = next(n for limit, n in _HUES if hue < limit)
    if name in ("orange", "red") and hi < 0.6 and sat > 0.3:
        return "brown"
    return name


def words(asset_name: str) -> str:
    """``tennis_ball`` -> ``tennis ball``."""
    return asset_name.replace("_", " ").strip()


def display_names(asset_names: Sequence[str], colors_rgb: Sequence[ArrayLike], sizes_m: Sequence[float]) -> list[str | None]:
    """One name per object, unique within the scene, or None where no distinguishing word works."""
    base = [words(n) for n in asset_names]
    groups: dict[str, list[int]] = defaultdict(list)
    for i, b in enumerate(base):
        groups[b].append(i)
    out: list[str | None] = list(base)
    for name, members in groups.items():
        if len(members) == 1:
            continue
        colours = [color_name(colors_rgb[i]) for i in members]
        if len(set(colours)) == len(members):
            for i, c in zip(members, colours):
                out[i] = f"{c} {name}"
            continue
        sizes = sorted((float(sizes_m[i]), i) for i in members)
        if len(members) == 2 and sizes[1][0] >= SIZE_RATIO * sizes[0][0]:
            out[sizes[0][1]], out[sizes[1][1]] = f"small {name}", f"large {name}"
            continue
        for i in members:
            out[i] = None
    taken = [n for n in out if n is not None]
    if len(taken) != len(set(taken)):  # a qualified name equal to another object's plain name
        counts = {n: taken.count(n) for n in taken}
        out = [None if n is not None and counts[n] > 1 else n for n in out]
    return out
