"""How deep two recorded objects sink into each other: the check that catches a contact the solver missed.

Penalty contact lets touching spheres overlap a little (under a millimetre in the benches' piles at every
preset); a pair the broad phase did not see within a step lets one object sink into another by centimetres
(two boxes released together, the ground stopping the lower one: 6-25 mm before the broad phase's reach moved
to the static scene's frame).  :func:`deepest_overlap` measures, over every recorded frame and every two
objects, the largest overlap of two contact spheres as a fraction of the sum of their radii.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import torch

# A sequence is rejected when two spheres of different objects overlap by more than this fraction of their
# radii's sum (the stability matrix's bound, tests/sim/test_sim_stability.py).
MAX_OVERLAP_FRACTION = 0.5


class Overlap(NamedTuple):
    """The deepest overlap of two objects' contact spheres over a run.

    Attributes:
        fraction: overlap (r_i + r_j - |x_i - x_j|) over r_i + r_j of the deepest sphere pair.
        depth_m: that overlap, m.
        frame: the frame it happens at.
        object_ids: the two objects' ids (smaller first).
    """

    fraction: float
    depth_m: float
    frame: int
    object_ids: tuple[int, int]


def deepest_overlap(
    object_ids: Sequence[int], positions_m: Sequence[np.ndarray], radii_m: Sequence[np.ndarray]
) -> Overlap | None:
    """The deepest overlap between the contact spheres of two different objects over all frames, or None
    when no two objects' spheres overlap at any frame.

    ``positions_m``: per object its sphere centres (T, k, 3), m; ``radii_m``: per object (k,) radii, m.  Only
    frames where two objects' sphere bounding boxes (grown by the largest radii) overlap are compared sphere
    by sphere."""
    best: Overlap | None = None
    boxes = [
        (p.min(axis=1) - r.max(), p.max(axis=1) + r.max()) if len(r) else None for p, r in zip(positions_m, radii_m)
    ]
    for a in range(len(object_ids)):
        for c in range(a + 1, len(object_ids)):
            if boxes[a] is None or boxes[c] is None:
                continue
            (lo_a, hi_a), (lo_c, hi_c) = boxes[a], boxes[c]
            frames = np.flatnonzero(np.all((lo_a <= hi_c) & (lo_c <= hi_a), axis=1))  # (T,) boxes touch
            if not len(frames):
                continue
            xa = torch.from_numpy(np.ascontiguousarray(positions_m[a][frames], dtype=np.float64))
            xc = torch.from_numpy(np.ascontiguousarray(positions_m[c][frames], dtype=np.float64))
            sum_r = torch.from_numpy(radii_m[a][:, None] + radii_m[c][None, :])  # (ka, kc)
            depth = sum_r[None] - torch.cdist(xa, xc)  # (F, ka, kc)
            fraction = depth / sum_r[None]
            k = int(torch.argmax(fraction))
            value = float(fraction.reshape(-1)[k])
            if value > 0.0 and (best is None or value > best.fraction):
                f = k // (fraction.shape[1] * fraction.shape[2])
                ids = sorted((int(object_ids[a]), int(object_ids[c])))
                best = Overlap(value, float(depth.reshape(-1)[k]), int(frames[f]), (ids[0], ids[1]))
    return best
