"""Canonical skinning domains of library shapes: one trained basis per shape, shared by all its draws.

A scenario draws an object as a library shape scaled to a size (``get_object(name, size_m)``) and samples its
interior points with the draw's own random generator. Training the skinning basis on those points with the
draw's seed made every draw a cache miss (7-11 s per deformable object at ``standard``). The basis is a
function of position, so it is trained once per shape instead, on a fixed point set of the shape at its
library size with a seed fixed by the name (:func:`skinning_domain`), and scaled to each draw
(:class:`~data_gen.sim.skinning.SkinningDomain`).
"""

from __future__ import annotations

import hashlib
from functools import lru_cache

import numpy as np

from data_gen.assets.registry import get_object
from data_gen.sim.skinning import SkinningDomain


def shape_seed(asset_name: str) -> int:
    """Seed (31 bits) of a shape's canonical points and training, fixed by its name."""
    return int.from_bytes(hashlib.sha256(asset_name.encode()).digest()[:4], "little") & 0x7FFFFFFF


@lru_cache(maxsize=512)
def _canonical(asset_name: str, num_points: int) -> tuple[np.ndarray, float]:
    """(n, 3) interior points of the shape at its library size (m, read-only) and that size (largest extent,
    m): a jittered grid of ``num_points`` cells of the volume, as the pipeline samples a draw."""
    asset = get_object(asset_name)
    spacing = (asset.volume_m3() / num_points) ** (1.0 / 3.0)
    points = asset.interior_points(spacing, np.random.default_rng(shape_seed(asset_name)))
    points.setflags(write=False)
    return points, asset.nominal_size_m


def skinning_domain(asset_name: str, size_m: float, num_points: int) -> SkinningDomain | None:
    """The domain of a draw of ``asset_name`` scaled to a largest extent of ``size_m`` (m), from ``num_points``
    canonical interior points; None when the shape holds fewer than 8 of them (the draw trains on its own)."""
    points, nominal_m = _canonical(asset_name, int(num_points))
    if len(points) < 8:
        return None
    return SkinningDomain(points, float(size_m) / nominal_m, shape_seed(asset_name))
