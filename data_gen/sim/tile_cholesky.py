"""Newton directions of a batch of dense island matrices by a blocked Cholesky, one thread block per island.

:class:`~data_gen.sim.device_newton.DeviceNewton` factorises each island's matrix. One thread doing that (the fused
kernel's envelope Cholesky) suits a CPU core; on a GPU the threads of a block should share the work. This kernel
runs warp's cooperative tile routines over ``TILE`` x ``TILE`` blocks of the matrix (a left-looking blocked
Cholesky: ``tile_matmul`` updates, ``tile_cholesky`` of the diagonal blocks, ``tile_lower_solve`` for the blocks
below them, then the two block triangular solves), reading and writing the matrix and its factor in global memory
so that any island size fits (shared memory holds a few blocks only). Blocks reaching past the matrix read as zero
and get ones on their diagonal, so the size need not be a multiple of ``TILE``.

It solves ``((H + H^T) / 2 + ridge I) dq = -g`` per island, as :func:`data_gen.sim.fused_newton._cholesky` and
``_newton_direction`` do (their sums in another order: round-off apart). A matrix that is not positive definite
leaves non-finite entries in ``dq`` (a pivot's square root of a negative number), which the caller tests.

Barriers: ``tile_store`` issues none (warp 1.19), so a block this kernel stores to global memory and reads back
later must be read after a barrier, or lanes read entries other lanes have not written yet. In the CUDA source
warp generates for this kernel, every tile read from ``chol`` and ``dq`` is a shared tile whose load ends with a
barrier, and each read of a stored block comes after such a load issued after the store: the diagonal block's
load of ``hess`` for the factor's blocks, the preceding load in the same product for the substitutions.

On the CPU warp runs a block in one thread by default; with ``wp.config.enable_cpu_blocks`` it runs its
:data:`THREADS` lanes as cooperative fibers that meet at those barriers. ``tests/sim/test_sim_tile_cholesky.py``
checks the kernel against numpy both ways; a missing barrier shows there as a stale read. What only a GPU runs:
its own factorisation and products (MathDx) and its vectorised copies.
"""

from __future__ import annotations

import warp as wp

wp.set_module_options({"enable_backward": False})

TILE = 32
"""Side of the blocks (float64: 8 KiB each; a factorisation holds a few at a time)."""
THREADS = 64
"""Threads per island on a GPU (``block_dim`` of the launch)."""


@wp.func
def _past_end(k0: int, n: int):
    """1.0 at the rows of the block starting at row ``k0`` that lie past the matrix's end (``n`` rows), else 0.0
    (a tile of ``TILE``). Built from warp's own operators only: a user function passed to ``wp.tile_map`` does not
    enter warp's module hash (warp 1.19), so a change to it would not recompile the kernel."""
    rows = wp.tile_arange(TILE, dtype=wp.int32) - wp.tile_full(shape=TILE, value=n - 1 - k0, dtype=wp.int32)
    clipped = wp.tile_map(wp.min, wp.tile_map(wp.max, rows, wp.tile_zeros(shape=TILE, dtype=wp.int32)),
                          wp.tile_ones(shape=TILE, dtype=wp.int32))  # fmt: skip
    return wp.tile_astype(clipped, wp.float64)


@wp.func
def _symmetric_block(hess: wp.array2d(dtype=wp.float64), i0: int, k0: int):
    """Block (i0, k0) of ``(H + H^T) / 2``."""
    a = wp.tile_load(hess, shape=(TILE, TILE), offset=(i0, k0))
    b = wp.tile_load(hess, shape=(TILE, TILE), offset=(k0, i0))
    return (a + wp.tile_transpose(b)) * wp.float64(0.5)


@wp.kernel
def blocked_cholesky_solve_kernel(
    hess: wp.array3d(dtype=wp.float64),
    grad: wp.array3d(dtype=wp.float64),
    ridge: wp.array(dtype=wp.float64),
    active: wp.array(dtype=wp.int32),
    first_block: wp.array2d(dtype=wp.int32),
    chol: wp.array3d(dtype=wp.float64),
    dq: wp.array3d(dtype=wp.float64),
):
    """Island ``isl`` (one block of threads) with ``active[isl]``: its factor L of ``(H + H^T) / 2 + ridge I``
    (``hess`` (n_isl, N, N)) in the lower blocks of ``chol`` (n_isl, N, N) and ``dq = -(L L^T)^-1 g`` (``grad`` and
    ``dq`` (n_isl, N, 1)). ``first_block`` (n_isl, blocks): each block row's first block column holding a non-zero
    (:func:`block_envelope_kernel`; zeros: dense). A Cholesky factor's rows keep their matrix's envelope, so block
    (i, k) of L is zero left of ``first_block[i]``: those blocks are neither computed nor read (blocks of ``chol``
    there keep whatever they held)."""
    isl = wp.tid()
    if active[isl] == 0:
        return
    n = hess.shape[1]
    nb = (n + TILE - 1) // TILE
    r = ridge[isl]
    for k in range(nb):
        k0 = k * TILE
        fk = first_block[isl, k]
        past = _past_end(k0, n)
        # the ridge inside the matrix, ones past its end (those rows are then an identity block, never stored)
        a = wp.tile_diag_add(_symmetric_block(hess[isl], k0, k0),
                             (wp.tile_ones(shape=TILE, dtype=wp.float64) - past) * r + past)  # fmt: skip
        for j in range(fk, k):
            lkj = wp.tile_load(chol[isl], shape=(TILE, TILE), offset=(k0, j * TILE))
            wp.tile_matmul(lkj, wp.tile_transpose(lkj), a, alpha=wp.float64(-1.0), beta=wp.float64(1.0))
        lkk = wp.tile_cholesky(a)
        wp.tile_store(chol[isl], lkk, offset=(k0, k0))
        for i in range(k + 1, nb):
            fi = first_block[isl, i]
            if fi <= k:  # (the same for every thread of the block)
                i0 = i * TILE
                b = _symmetric_block(hess[isl], i0, k0)
                for j in range(wp.max(fi, fk), k):
                    lij = wp.tile_load(chol[isl], shape=(TILE, TILE), offset=(i0, j * TILE))
                    lkj = wp.tile_load(chol[isl], shape=(TILE, TILE), offset=(k0, j * TILE))
                    wp.tile_matmul(lij, wp.tile_transpose(lkj), b, alpha=wp.float64(-1.0), beta=wp.float64(1.0))
                # L_ik L_kk^T = B: L_kk L_ik^T = B^T
                wp.tile_store(chol[isl], wp.tile_transpose(wp.tile_lower_solve(lkk, wp.tile_transpose(b))),
                              offset=(i0, k0))  # fmt: skip
    # L y = -g, then L^T x = y (x in dq); the diagonal blocks as stored (zero past the end) plus ones there
    for k in range(nb):
        k0 = k * TILE
        y = -wp.tile_load(grad[isl], shape=(TILE, 1), offset=(k0, 0))
        for j in range(first_block[isl, k], k):
            wp.tile_matmul(wp.tile_load(chol[isl], shape=(TILE, TILE), offset=(k0, j * TILE)),
                           wp.tile_load(dq[isl], shape=(TILE, 1), offset=(j * TILE, 0)), y,
                           alpha=wp.float64(-1.0), beta=wp.float64(1.0))  # fmt: skip
        lkk = wp.tile_diag_add(wp.tile_load(chol[isl], shape=(TILE, TILE), offset=(k0, k0)), _past_end(k0, n))
        wp.tile_store(dq[isl], wp.tile_lower_solve(lkk, y), offset=(k0, 0))
    for kk in range(nb):
        k = nb - 1 - kk
        k0 = k * TILE
        x = wp.tile_load(dq[isl], shape=(TILE, 1), offset=(k0, 0))
        for j in range(k + 1, nb):
            if first_block[isl, j] <= k:
                wp.tile_matmul(wp.tile_transpose(wp.tile_load(chol[isl], shape=(TILE, TILE), offset=(j * TILE, k0))),
                               wp.tile_load(dq[isl], shape=(TILE, 1), offset=(j * TILE, 0)), x,
                               alpha=wp.float64(-1.0), beta=wp.float64(1.0))  # fmt: skip
        lkk = wp.tile_diag_add(wp.tile_load(chol[isl], shape=(TILE, TILE), offset=(k0, k0)), _past_end(k0, n))
        wp.tile_store(dq[isl], wp.tile_upper_solve(wp.tile_transpose(lkk), x), offset=(k0, 0))


@wp.kernel
def block_envelope_start_kernel(active: wp.array(dtype=wp.int32), first_block: wp.array2d(dtype=wp.int32)):
    """Block row i of island ``isl`` (``active``): its own block, until its rows find a coupling further left."""
    isl, i = wp.tid()
    if active[isl] != 0:
        first_block[isl, i] = i


@wp.kernel
def block_envelope_kernel(hess: wp.array3d(dtype=wp.float64), active: wp.array(dtype=wp.int32),
                          first_block: wp.array2d(dtype=wp.int32)):  # fmt: skip
    """Row r of island ``isl``'s matrix (``active``): its block row's first block column lowered (atomic min) to
    that of the row's first column left of its own block where ``H + H^T`` is non-zero. A thread per row, each
    stopping at its first coupling: no thread walks a block row."""
    isl, r = wp.tid()
    if active[isl] == 0:
        return
    i = r // TILE
    for c in range(i * TILE):  # (columns inside its own block cannot lower it)
        if hess[isl, r, c] != wp.float64(0.0) or hess[isl, c, r] != wp.float64(0.0):
            wp.atomic_min(first_block, isl, i, c // TILE)
            return


def blocks(size: int) -> int:
    """Blocks of :data:`TILE` per side of a ``size`` x ``size`` matrix."""
    return (size + TILE - 1) // TILE


def blocked_cholesky_solve(hess: wp.array, grad: wp.array, ridge: wp.array, active: wp.array, chol: wp.array,
                           dq: wp.array, first_block: wp.array | None = None) -> None:  # fmt: skip
    """Launch :func:`blocked_cholesky_solve_kernel` over the islands (``hess``'s first axis), a block of
    :data:`THREADS` threads each; with ``first_block`` (n_isl, :func:`blocks`) from :func:`block_envelope_kernel`
    the blocks outside the matrices' envelopes are skipped, without it the matrices are taken as dense."""
    if first_block is None:
        first_block = wp.zeros((hess.shape[0], blocks(hess.shape[1])), dtype=wp.int32, device=hess.device)
    wp.launch_tiled(blocked_cholesky_solve_kernel, dim=[hess.shape[0]],
                    inputs=[hess, grad, ridge, active, first_block, chol, dq], block_dim=THREADS,
                    device=hess.device)  # fmt: skip


def block_envelope(hess: wp.array, active: wp.array, first_block: wp.array) -> None:
    """``first_block`` (n_isl, :func:`blocks`) of the active islands: per block row the first block column holding
    a non-zero of ``H + H^T`` in its rows (its own block when none); :func:`block_envelope_start_kernel`, then
    :func:`block_envelope_kernel` with a thread per row."""
    wp.launch(block_envelope_start_kernel, dim=first_block.shape, inputs=[active, first_block], device=hess.device)
    wp.launch(block_envelope_kernel, dim=hess.shape[:2], inputs=[hess, active, first_block], device=hess.device)


__all__ = ["TILE", "THREADS", "block_envelope", "blocked_cholesky_solve", "blocked_cholesky_solve_kernel", "blocks"]
