"""The solver's vectorised bookkeeping and the grouped broad phase equal their plain definitions."""

import numpy as np
import pytest

from data_gen.sim.contact import PairFinder


def brute_force_pairs(points, object_ids, radii, margin, point_margins):
    """All (i < j) on different objects closer than r_i + r_j + margin + m_i + m_j, sorted."""
    extra = np.zeros(len(points)) if point_margins is None else point_margins
    dist = np.linalg.norm(points[:, None] - points[None, :], axis=2)
    limit = radii[:, None] + radii[None, :] + margin + extra[:, None] + extra[None, :]
    i, j = np.nonzero((dist < limit) & (object_ids[:, None] != object_ids[None, :]))
    keep = j > i
    out = np.stack([i[keep], j[keep]], 1).astype(np.int64)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


@pytest.mark.parametrize("ids_kind", ["ascending", "shuffled", "sparse"])
def test_grouped_broad_phase_finds_exactly_the_close_pairs(ids_kind):
    rng = np.random.default_rng(3)
    finder = PairFinder()
    for trial in range(6):
        sizes = rng.integers(0, 120, rng.integers(2, 8))
        ids = np.concatenate([np.full(s, k) for k, s in enumerate(sizes)])
        if ids_kind == "shuffled":
            ids = rng.permutation(ids)
        elif ids_kind == "sparse":
            ids = 7 * ids + 3
        centres = rng.normal(scale=0.1, size=(len(sizes), 3))
        points = centres[np.searchsorted(np.unique(ids), ids)] + rng.normal(scale=0.04, size=(len(ids), 3))
        radii = rng.uniform(0.002, 0.02, len(ids))
        margins = rng.uniform(0.0, 0.03, len(ids)) if trial % 2 else None
        found = finder.find(points, ids, radii, 0.004, margins)
        expected = brute_force_pairs(points, ids, radii, 0.004, margins)
        assert len(expected) > 0 or trial
        np.testing.assert_array_equal(found, expected)
        # same ids, new radii: the cached upload must follow
        np.testing.assert_array_equal(
            finder.find(points, ids, 1.5 * radii, 0.004, margins),
            brute_force_pairs(points, ids, 1.5 * radii, 0.004, margins),
        )


def test_broad_phase_of_one_object_is_empty():
    points = np.random.default_rng(0).normal(size=(20, 3))
    assert PairFinder().find(points, np.zeros(20, dtype=int), np.full(20, 0.5), 0.1).shape == (0, 2)
