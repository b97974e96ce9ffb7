"""The blocked Cholesky of :mod:`data_gen.sim.tile_cholesky` (a thread block per island) against numpy: factors and
directions of island matrices of every size (whole blocks, partial ones, many), the symmetric part of an
unsymmetric matrix, the ridge, islands left alone, and an indefinite matrix's non-finite update (what the caller
tests).

Every test runs twice: with one thread per block (the CPU's default) and with the :data:`THREADS` threads of a
GPU's block, which warp runs on the CPU as cooperative fibers (``wp.config.enable_cpu_blocks``): the lanes split
each tile's loads, stores and products between them as on a GPU, and a lane runs on until the next barrier, so a
block stored to global memory by some lanes and read back by others without a barrier between is read stale
(:func:`test_lanes_read_what_others_stored_only_after_a_barrier`). What the CPU cannot show: the GPU's own
(MathDx) factorisation and products, and its vectorised copies."""

import numpy as np
import pytest
import warp as wp

from data_gen.sim.tile_cholesky import THREADS, TILE, block_envelope, blocked_cholesky_solve, blocks


@pytest.fixture(autouse=True, params=[1, THREADS], ids=["one-lane", "lanes"])
def lanes(request, monkeypatch) -> int:
    """Threads per block the launches get on the CPU: 1, or :data:`THREADS` cooperative fibers."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", request.param > 1)
    return request.param


@wp.kernel
def _neighbour_kernel(stored: wp.array(dtype=wp.float64), seen: wp.array2d(dtype=wp.float64), barrier: int):
    """Lane l stores l + 1, then reads lane l + 1's value, without a barrier between or with one (a tile sum)."""
    i, lane = wp.tid()
    stored[lane] = wp.float64(lane + 1)
    if barrier != 0:
        wp.tile_sum(wp.tile_ones(shape=THREADS, dtype=wp.float64))
    seen[i, lane] = stored[(lane + 1) % THREADS]


def test_lanes_read_what_others_stored_only_after_a_barrier(lanes):
    """The lanes mode has teeth: without a barrier, lane l reads lane l + 1's slot before that lane ran (0); after
    one, every lane reads it. With one lane per block the loop over lanes hides the difference."""
    for barrier in (0, 1):
        stored = wp.zeros(THREADS, dtype=wp.float64)
        seen = wp.zeros((1, THREADS), dtype=wp.float64)
        wp.launch_tiled(_neighbour_kernel, dim=[1], inputs=[stored, seen, barrier], block_dim=THREADS)
        want = (np.arange(THREADS) + 1) % THREADS + 1.0
        if lanes == 1:  # one thread: lane 0 only, reading slot 1 it never stored
            assert seen.numpy()[0, 0] == 0.0
        elif barrier:
            assert np.array_equal(seen.numpy()[0], want)
        else:
            assert seen.numpy()[0, 0] == 0.0 and seen.numpy()[0, -1] == 1.0  # lane 63 ran after lane 0 stored


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


def _envelope_numpy(hess: np.ndarray) -> np.ndarray:
    """Per block row: the first block column holding a non-zero of H + H^T (at most the row's own block)."""
    n_isl, n, _ = hess.shape
    nb = blocks(n)
    out = np.zeros((n_isl, nb), dtype=np.int32)
    nonzero = (hess != 0) | (hess.transpose(0, 2, 1) != 0)
    for isl in range(n_isl):
        for i in range(nb):
            rows = nonzero[isl, i * TILE:(i + 1) * TILE, : i * TILE]
            cols = np.nonzero(rows.any(0))[0]
            out[isl, i] = cols[0] // TILE if len(cols) else i
    return out


@pytest.mark.parametrize("n", [96, 204, 600])
def test_block_envelope_skips_zero_blocks_and_gives_the_dense_result(n):
    """Pile-like matrices: a chain of 12-unknown objects coupled to their neighbours, plus one long-range coupling
    (a box touching one far down the column). The envelope kernel finds numpy's first non-zero blocks; the factor
    and direction computed inside it equal numpy's, though every block of ``chol`` outside starts as garbage."""
    rng = np.random.default_rng(n)
    n_isl = 2
    hess = np.zeros((n_isl, n, n))
    for isl in range(n_isl):
        for o in range(n // 12):
            a = rng.standard_normal((12, 12))
            hess[isl, 12 * o:12 * o + 12, 12 * o:12 * o + 12] = a @ a.T + 40 * np.eye(12)
            if o:
                c = 0.3 * rng.standard_normal((12, 12))
                hess[isl, 12 * o:12 * o + 12, 12 * o - 12:12 * o] = c
                hess[isl, 12 * o - 12:12 * o, 12 * o:12 * o + 12] = c.T
    far = 0.3 * rng.standard_normal((12, 12))  # island 1: its last object touches its fourth
    hess[1, n - 12:, 36:48] = far
    hess[1, 36:48, n - 12:] = far.T
    grad = rng.standard_normal((n_isl, n))
    arrays = _arrays(hess, grad, [0.0, 0.0], [1, 1])
    first = wp.zeros((n_isl, blocks(n)), dtype=wp.int32)
    block_envelope(arrays[0], arrays[3], first)
    want_first = _envelope_numpy(hess)
    assert np.array_equal(first.numpy(), want_first)
    assert want_first[0, -1] >= blocks(n) - 2 and want_first[1, -1] == 1  # banded; the far coupling widens it
    blocked_cholesky_solve(*arrays, first_block=first)
    factor = arrays[4].numpy()
    for isl in range(n_isl):
        want = np.linalg.cholesky(hess[isl])
        inside = np.zeros((n, n), dtype=bool)  # the envelope's blocks, where the factor was computed
        for i, f in enumerate(want_first[isl]):
            inside[i * TILE:(i + 1) * TILE, f * TILE:(i + 1) * TILE] = True
        got = np.where(inside, np.tril(factor[isl]), 0.0)
        assert np.abs(got - want).max() <= 1e-13 * np.abs(want).max()
        want_dq = -np.linalg.solve(hess[isl], grad[isl])
        assert np.abs(arrays[5].numpy()[isl, :, 0] - want_dq).max() <= 1e-12 * np.abs(want_dq).max()
