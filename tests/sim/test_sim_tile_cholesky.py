"""The blocked Cholesky of :mod:`data_gen.sim.tile_cholesky` (a thread block per island; one thread on the CPU)
against numpy: factors and directions of island matrices of every size (whole blocks, partial ones, many), the
symmetric part of an unsymmetric matrix, the ridge, islands left alone, and an indefinite matrix's non-finite
update (what the caller tests)."""

import numpy as np
import pytest
import warp as wp

from data_gen.sim.tile_cholesky import TILE, blocked_cholesky_solve


def _arrays(hess: np.ndarray, grad: np.ndarray, ridge, active):
    n_isl, n, _ = hess.shape
    return (wp.array(hess, dtype=wp.float64), wp.array(grad[..., None], dtype=wp.float64),
            wp.array(np.asarray(ridge, dtype=np.float64), dtype=wp.float64),
            wp.array(np.asarray(active, dtype=np.int32), dtype=wp.int32),
            wp.full((n_isl, n, n), 7.0, dtype=wp.float64), wp.full((n_isl, n, 1), 7.0, dtype=wp.float64))  # fmt: skip


@pytest.mark.parametrize("n", [12, TILE, 36, 2 * TILE, 120, 240])
def test_blocked_factor_and_direction_equal_numpy(n):
    rng = np.random.default_rng(n)
    a = rng.standard_normal((3, n, n))
    hess = a @ a.transpose(0, 2, 1) + n * np.eye(n) + 1e-3 * rng.standard_normal((3, n, n))  # not symmetric
    grad = rng.standard_normal((3, n))
    ridge = [0.0, 0.5, 0.0]
    arrays = _arrays(hess, grad, ridge, [1, 1, 0])
    blocked_cholesky_solve(*arrays)
    sym = 0.5 * (hess + hess.transpose(0, 2, 1)) + np.asarray(ridge)[:, None, None] * np.eye(n)
    factor = np.tril(arrays[4].numpy())
    direction = arrays[5].numpy()[..., 0]
    for isl in (0, 1):
        want = np.linalg.cholesky(sym[isl])
        assert np.abs(factor[isl] - want).max() <= 1e-13 * np.abs(want).max()
        want_dq = -np.linalg.solve(sym[isl], grad[isl])
        assert np.abs(direction[isl] - want_dq).max() <= 1e-13 * np.abs(want_dq).max()
    assert np.all(arrays[5].numpy()[2] == 7.0) and np.all(arrays[4].numpy()[2] == 7.0)  # inactive: untouched


def test_an_indefinite_matrix_leaves_a_non_finite_direction_and_the_ridge_is_added_to_every_row():
    n = 40
    rng = np.random.default_rng(1)
    a = rng.standard_normal((2, n, n))
    hess = a @ a.transpose(0, 2, 1) + n * np.eye(n)
    hess[1, 30, 30] = -1e3  # a negative pivot in the second block
    grad = rng.standard_normal((2, n))
    arrays = _arrays(hess, grad, [0.0, 0.0], [1, 1])
    blocked_cholesky_solve(*arrays)
    direction = arrays[5].numpy()[..., 0]
    assert np.all(np.isfinite(direction[0])) and not np.all(np.isfinite(direction[1]))
    # a singular matrix (zero rows: an unused unknown) becomes solvable with a ridge
    singular = hess[:1].copy()
    singular[0, 5, :] = singular[0, :, 5] = 0.0
    arrays = _arrays(singular, grad[:1], [0.0], [1])
    blocked_cholesky_solve(*arrays)
    assert not np.all(np.isfinite(arrays[5].numpy()))
    arrays = _arrays(singular, grad[:1], [1e-6], [1])
    blocked_cholesky_solve(*arrays)
    want = -np.linalg.solve(singular[0] + 1e-6 * np.eye(n), grad[0])
    np.testing.assert_allclose(arrays[5].numpy()[0, :, 0], want, rtol=1e-9, atol=0.0)
