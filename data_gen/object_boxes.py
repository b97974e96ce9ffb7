"""Oriented bounding boxes of deformed objects: what a question's distances and sizes are measured on."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from newtphys.rotations import quat_to_matrix


def oriented_box(points_world_m: ArrayLike, rotation_wxyz: ArrayLike) -> dict[str, list[float]]:
    """The box of ``points`` (n, 3) m whose axes are the object's frame ``rotation_wxyz`` (object -> world).

    Returns the world-state ``box``: ``center`` (world, m), ``extents`` (full side lengths along the object's
    x, y, z axes, m) and ``rotation`` (w, x, y, z), so a deformed object's box is that of what is seen.
    """
    p = np.asarray(points_world_m, np.float64)
    q = np.asarray(rotation_wxyz, np.float64)
    r = quat_to_matrix(q)
    local = p @ r  # rows: R^T p
    lo, hi = local.min(axis=0), local.max(axis=0)
    centre = r @ (0.5 * (lo + hi))
    return {"center": centre.tolist(), "extents": (hi - lo).tolist(), "rotation": q.tolist()}
