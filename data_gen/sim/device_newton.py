"""The fused Newton solve of :mod:`data_gen.sim.fused_newton` as launches with a thread per element: the shape a GPU wants.

:class:`~data_gen.sim.fused_newton.FusedNewton` runs each island's whole solve in one thread: right for a CPU
core, wrong for a GPU, where one thread doing an island's Newton method (its envelope Cholesky included) is far
slower than a core. :class:`DeviceNewton` runs the same algorithm (issue 13, item 4) as a schedule of launches:

* the objective, gradient and Newton matrix are summed by one launch per term with a thread per element:
  per object (inertia, gravity and the motion bound the scene test reads), per cubature point (neo-Hookean),
  per contact sphere (scene contact and friction) and per candidate pair (pair contact and friction), each
  adding its part to its island's value, gradient and dense matrix with atomic adds (:func:`wp.atomic_add`);
* each island's matrix is factorised inside its envelope by a block of threads (:mod:`data_gen.sim.tile_cholesky`,
  the GPU's default) or by one thread (the CPU's), with the fused kernel's ridge and hand-back rules; a thread per
  island takes the trust limit, the converged shortcut and the Armijo decisions, and sets what the next launches
  evaluate;
* the loops (Newton iterations, line-search trials) run under :func:`wp.capture_while` on flags the island
  threads set: directly, the flag is read on the host; captured as a graph (the default on CUDA), each loop is a
  conditional node, so a solve needs no host read at all (not yet run on a GPU: see docs/gpu_checks.md).

:meth:`DeviceNewton.solve` solves what :meth:`FusedNewton.solve` does (any objects the kernels fit: for deformable
ones the full Newton matrix every iteration), :meth:`DeviceNewton.solve_substeps` what
:meth:`FusedNewton.solve_substeps` does (a step's sub-steps of one-handle islands, their start data and forces on
the device). The decisions are the fused kernel's (:func:`data_gen.sim.fused_newton._take_update`, ``_newton``) on
the same values; the values are its terms summed in another order (round-off), so a solve takes the same
iterations and ends at the same state to round-off: ``tests/sim/test_sim_device_newton.py`` checks that on
recorded steps and whole simulations. It uses a :class:`FusedNewton`'s model, scene, step data and buffers, or
copies of them on another device (:class:`StructMirror`).

On the CPU the threads of a launch run one after another, so the sums are deterministic; this path costs 3-5x the
fused kernel there (every term is a launch, every trial another round of them), which stays the CPU's default.
On CUDA the atomic adds make the sums' order, and so the last bits, vary between runs.
"""

from __future__ import annotations

import logging
import sys
import time
from collections import OrderedDict
from collections.abc import Sequence

import numpy as np
import torch
import warp as wp

from data_gen.sim.energy.elastic_kernel import neo_hookean_point, not_positive_definite, projected_neo_hookean_hessian
from data_gen.sim.fused_newton import (
    CONVERGED,
    EVALUATIONS,
    EVALUATIONS_WITH_DERIVATIVES,
    ITERATIONS,
    LINE_SEARCH_EXTENDED,
    LINE_SEARCH_FAILURES,
    NEEDS_FALLBACK,
    NUM_STATS,
    SOLVED,
    STATUS,
    TRUST_LIMITED,
    Bodies,
    FusedNewton,
    SceneArgs,
    StepData,
    Substeps,
    SubstepResult,
    Work,
    add_pair_sums,
    live_pair_force,
    object_scene_sums,
    pair_start_live,
    sphere_force,
    sphere_start,
    _cholesky,
    _deformation_gradient,
    _load_state,
    _motion_bound,
    _newton_direction,
    _pair_at,
    _pair_out_of_reach,
    _scene_sphere,
    sphere_margin,
    _step_limits,
    _update_norms,
    elastic_entry,
    scene_args,
)
from data_gen.sim.newton import ARMIJO_C, EXTRA_HALVINGS, NewtonResult, NewtonSettings
from data_gen.sim.tile_cholesky import THREADS, block_envelope, blocked_cholesky_solve, blocks

wp.set_module_options({"enable_backward": False})
logger = logging.getLogger(__name__)

_ZERO = wp.constant(wp.float64(0.0))
_ONE = wp.constant(wp.float64(1.0))

CUDA_VALIDATED = False
"""Whether this schedule has passed ``tests/sim/test_sim_device_newton_cuda.py`` on a CUDA GPU. Not yet: it is
tested on the CPU only (no GPU was lent since it was written; docs/gpu_checks.md, "The next run"). The session
that sees that file pass on a GPU sets this True; until then a :class:`DeviceNewton` on CUDA logs a warning."""

_UNVALIDATED_WARNED: set[str] = set()  # the devices warned about in this process

GRAPHS_KEPT = 8
"""Captured schedules a :class:`DeviceNewton` keeps for reuse (a few groupings and pair counts of its workspace)."""

# an island's phase between launches
EVALUATE = wp.constant(0)  # its derivatives at q are wanted (an iteration starts with an evaluation)
HAVE = wp.constant(1)  # its derivatives at q are in grad / hess (the accepted first trial left them)
SEARCH = wp.constant(2)  # a line-search trial is being evaluated
DONE = wp.constant(3)  # converged, stopped unconverged, or handed back (stats say which)
# what the term launches evaluate for an island (``Island.mode``)
NOTHING, VALUE, DERIVATIVES = wp.constant(0), wp.constant(1), wp.constant(2)


@wp.struct
class Island:
    """Per-island state of the schedule, and the loop flags (one int32 each) :func:`wp.capture_while` reads."""

    phase: wp.array(dtype=wp.int32)
    mode: wp.array(dtype=wp.int32)
    object_island: wp.array(dtype=wp.int32)  # (n,) each object's island
    value: wp.array(dtype=wp.float64)  # the objective at q, J
    total: wp.array(dtype=wp.float64)  # what the term launches add up: the objective at the evaluated state, J
    alpha: wp.array(dtype=wp.float64)
    slope: wp.array(dtype=wp.float64)  # grad . dq at q
    mass: wp.array(dtype=wp.float64)  # |dq|_M
    trial: wp.array(dtype=wp.int32)  # the line search's trial number
    factor: wp.array(dtype=wp.int32)  # 1: the blocked factorisation takes this island (tile path)
    halted: wp.array(dtype=wp.int32)  # 1: a sub-step of this island needs minimise (its later ones are not run)
    ridge: wp.array(dtype=wp.float64)  # its ridge there
    biggest: wp.array(dtype=wp.float64)  # the largest diagonal entry of its matrix
    iterating: wp.array(dtype=wp.int32)  # [0]: some island is not DONE
    searching: wp.array(dtype=wp.int32)  # [0]: some island is in SEARCH
    live: wp.array(dtype=wp.int32)  # (pair capacity,) 1: the pair in slot k of pair_order is evaluated


@wp.func
def _add_gradient(grad: wp.array(dtype=wp.float64), first: int, b: wp.array3d(dtype=wp.float64), o: int, s: int,
                  cols: int, g: wp.vec3d):  # fmt: skip
    """grad[first + r cols + a] += g[r] b[o, s, a] (atomically; nothing where the basis value is zero)."""
    for a in range(cols):
        ba = b[o, s, a]
        if ba != _ZERO:
            for r in range(3):
                wp.atomic_add(grad, first + r * cols + a, g[r] * ba)


@wp.func
def _add_block(hess: wp.array(dtype=wp.float64), n_size: int, matrix_base: int, b: wp.array3d(dtype=wp.float64),
               o: int, s: int, cols: int, first_o: int, p: int, t: int, cols_p: int, first_p: int, h: wp.mat33d):  # fmt: skip
    """hess[(r, a), (c, e)] += h[r, c] b[o, s, a] b[p, t, e] (atomically) for the rows of sphere (o, s) and the
    columns of sphere (p, t) (island-local first unknowns ``first_o`` / ``first_p``); nothing where the basis
    product is zero, as :func:`data_gen.sim.energy.contact_kernels.add_block`."""
    for a in range(cols):
        ba = b[o, s, a]
        if ba != _ZERO:
            for e in range(cols_p):
                w = ba * b[p, t, e]
                if w != _ZERO:
                    for r in range(3):
                        row = matrix_base + (first_o + r * cols + a) * n_size + first_p + e
                        for c in range(3):
                            wp.atomic_add(hess, row + c * cols_p, h[r, c] * w)


@wp.func
def _past_pairs(st: StepData, k: int):
    """Whether slot k of the pairs is past the step's pairs (a graph's pairs launches have a power of two of
    threads: :func:`_pair_threads`)."""
    return k >= st.pair_start[st.pair_start.shape[0] - 1]


@wp.kernel
def start_kernel(bd: Bodies, st: StepData, wk: Work, isl_info: Island,
                 threshold: wp.array(dtype=wp.float64), trust_m: wp.array(dtype=wp.float64), limits_given: int,
                 tolerance: wp.float64, gravity_norm: wp.float64):  # fmt: skip
    """Island ``isl``: unless ``limits_given``, its limits (:func:`data_gen.sim.fused_newton._step_limits`), cleared
    counters and phase EVALUATE. (The scene margins: :func:`margins_kernel`, a thread per sphere; the envelope of
    each factorisation: :func:`row_envelope_kernel`.)"""
    isl = wp.tid()
    if limits_given == 0:
        thr_isl, trust_isl = _step_limits(bd, st, isl, tolerance, gravity_norm)
        threshold[isl] = thr_isl
        trust_m[isl] = trust_isl
    for k in range(NUM_STATS):
        wk.stats[isl, k] = 0
    isl_info.phase[isl] = EVALUATE
    isl_info.mode[isl] = NOTHING
    isl_info.iterating[0] = 1


@wp.kernel
def margins_kernel(bd: Bodies, sc: SceneArgs, st: StepData):
    """Sphere s of object o: its :func:`data_gen.sim.fused_newton.sphere_margin` (what the fused kernel's
    ``_scene_margins`` computes per island): :func:`scene_kernel` skips a sphere whose margin exceeds its motion
    bound."""
    o, s = wp.tid()
    st.margin[o, s] = sphere_margin(bd, sc, st, o, s)


@wp.kernel
def prepare_kernel(bd: Bodies, wk: Work, isl_info: Island, iterations: int):
    """Islands at the iteration cap: DONE; in EVALUATE: their state q loaded for an evaluation with derivatives;
    in HAVE: nothing to evaluate. Clears the outer loop's flag (:func:`iterating_kernel` sets it)."""
    isl = wp.tid()
    if isl == 0:
        isl_info.iterating[0] = 0
    isl_info.mode[isl] = NOTHING
    phase = isl_info.phase[isl]
    if (phase == EVALUATE or phase == HAVE) and wk.stats[isl, ITERATIONS] >= iterations:
        isl_info.phase[isl] = DONE
        return
    if phase == EVALUATE:
        _load_state(bd, wk.q, wk.tm, isl)
        isl_info.mode[isl] = DERIVATIVES
        wk.stats[isl, EVALUATIONS_WITH_DERIVATIVES] += 1


@wp.kernel
def load_kernel(bd: Bodies, wk: Work, isl_info: Island, mode: int):
    """Island ``isl``'s state q loaded for an evaluation of ``mode`` (:meth:`DeviceNewton.evaluate`)."""
    isl = wp.tid()
    _load_state(bd, wk.q, wk.tm, isl)
    isl_info.mode[isl] = mode


@wp.kernel
def clear_kernel(bd: Bodies, wk: Work, isl_info: Island, chunk: int):
    """Entries (isl, i, c chunk .. (c + 1) chunk) of the islands to evaluate: the matrix and gradient cleared for
    derivatives (identity rows on padding), the sum of the objective cleared (a GPU takes an entry per thread, a
    CPU a row). Clears the line search's flag (the launches after the terms set it: :func:`direction_kernel`,
    :func:`decide_kernel`)."""
    isl, i, c = wp.tid()
    if isl == 0 and i == 0 and c == 0:
        isl_info.searching[0] = 0
    mode = isl_info.mode[isl]
    if mode == NOTHING:
        return
    n_size = bd.island_size
    if i == 0 and c == 0:
        isl_info.total[isl] = _ZERO
    if mode == DERIVATIVES:
        if c == 0:
            wk.grad[isl * n_size + i] = _ZERO
        row = (isl * n_size + i) * n_size
        for j in range(c * chunk, wp.min((c + 1) * chunk, n_size)):
            v = _ZERO
            if i == j and i >= bd.island_dofs[isl]:
                v = _ONE
            wk.hess[row + j] = v


@wp.kernel
def inertia_kernel(bd: Bodies, st: StepData, wk: Work, isl_info: Island):
    """Object o: inertia ``1/2 d^T M d`` (d = Tm - Tm_pred) and gravity ``-h^2 g . Tm sum_p m_p b_p``, with their
    derivatives; and its motion bound since the step's start (what the scene test reads)."""
    o = wp.tid()
    isl = isl_info.object_island[o]
    mode = isl_info.mode[isl]
    if mode == NOTHING:
        return
    tm = wk.tm
    cols = bd.columns[o]
    kp = bd.flat_index.shape[1] // 3
    n_size = bd.island_size
    h2 = st.h2[isl]
    value = _ZERO
    for r in range(3):
        for a in range(cols):
            row = r * kp + a
            m_d = _ZERO
            for s in range(3):
                for c in range(cols):
                    m_d = m_d + bd.mass_matrix[o, row, s * kp + c] * (tm[o, s, c] - st.tm_pred[o, s, c])
            value = value + wp.float64(0.5) * (tm[o, r, a] - st.tm_pred[o, r, a]) * m_d
            value = value - h2 * st.gravity[r] * tm[o, r, a] * bd.mass_b_sum[o, a]
            if mode == DERIVATIVES:
                fr = bd.flat_index[o, row]
                wp.atomic_add(wk.grad, fr, m_d - h2 * st.gravity[r] * bd.mass_b_sum[o, a])
                for s in range(3):
                    for c in range(cols):
                        m = bd.mass_matrix[o, row, s * kp + c]
                        if m != _ZERO:
                            fc = bd.flat_index[o, s * kp + c] - isl * n_size
                            wp.atomic_add(wk.hess, fr * n_size + fc, m)
    wp.atomic_add(isl_info.total, isl, value)
    st.moved[o] = _motion_bound(bd, st, tm, o, cols)


@wp.kernel
def elastic_kernel(bd: Bodies, st: StepData, wk: Work, isl_info: Island):
    """Cubature point i of object o: ``h^2 V Psi(F_i)``, its gradient ``h^2 V P C_i^T`` and matrix
    ``h^2 V C_i^T H C_i`` (H projected where it fails the near-SPD test, as the fused kernel does)."""
    o, i = wp.tid()
    isl = isl_info.object_island[o]
    mode = isl_info.mode[isl]
    v = bd.cub_volume[o, i]
    if mode == NOTHING or v == _ZERO:
        return
    cols = bd.columns[o]
    kp = bd.flat_index.shape[1] // 3
    n_size = bd.island_size
    w = st.h2[isl] * v
    f = _deformation_gradient(bd, wk.tm4, o, i, cols)
    psi, piola, h9 = neo_hookean_point(f, bd.mu_pa[o], bd.lam_pa[o], wp.where(mode == DERIVATIVES, 1, 0))
    wp.atomic_add(isl_info.total, isl, w * psi)
    if mode != DERIVATIVES:
        return
    if not_positive_definite(h9, bd.spd_tolerance_pa[o]) != 0:
        h9 = projected_neo_hookean_hessian(f, bd.mu_pa[o], bd.lam_pa[o])
    for r in range(3):
        for a in range(cols):
            fr = bd.flat_index[o, r * kp + a]
            g_ra = _ZERO
            for j in range(3):
                g_ra = g_ra + piola[r, j] * bd.cub_c[o, i, a, j]
            wp.atomic_add(wk.grad, fr, w * g_ra)
            for s in range(3):
                for c in range(cols):
                    k_v = elastic_entry(bd, h9, o, i, r, a, s, c)
                    if k_v != _ZERO:
                        fc = bd.flat_index[o, s * kp + c] - isl * n_size
                        wp.atomic_add(wk.hess, fr * n_size + fc, w * k_v)


@wp.kernel
def scene_kernel(bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, isl_info: Island):
    """Contact sphere s of object o against the static scene (with its frozen friction), skipped where its start
    margin exceeds its motion bound (the scene distance is 1-Lipschitz: it cannot touch)."""
    o, s = wp.tid()
    isl = isl_info.object_island[o]
    mode = isl_info.mode[isl]
    if mode == NOTHING:
        return
    if st.margin[o, s] > st.moved[o] * bd.b_norm[o, s]:
        return
    cols = bd.columns[o]
    active, e, g, h, normal = _scene_sphere(bd, sc, st, wk.tm, o, s, cols)
    if active == 0:
        return
    h2 = st.h2[isl]
    wp.atomic_add(isl_info.total, isl, h2 * e)
    if mode == DERIVATIVES:
        n_size = bd.island_size
        first = bd.flat_index[o, 0]
        local = first - isl * n_size
        _add_gradient(wk.grad, first, bd.b, o, s, cols, h2 * g)
        _add_block(wk.hess, n_size, isl * n_size * n_size, bd.b, o, s, cols, local, o, s, cols, local, h2 * h)


@wp.kernel
def pairs_kernel(bd: Bodies, st: StepData, wk: Work, isl_info: Island):
    """A candidate pair p the island evaluates (its side i on an object of the island; side j another object of
    it, or frozen; in sub-steps those that can touch within the sub-step, ``isl_info.live``): pair contact with its
    frozen friction, the four blocks of the matrix where j moves."""
    k = wp.tid()  # slot k of the pairs ordered by island
    if _past_pairs(st, k) or isl_info.live[k] == 0:
        return
    p = st.pair_order[k]
    isl = isl_info.object_island[st.obj_i[p]]
    mode = isl_info.mode[isl]
    if mode == NOTHING:
        return
    if _pair_out_of_reach(bd, st, p):
        return
    active, e, g, h, normal, oi, si, cols_i, oj, sj, cols_j = _pair_at(bd, st, wk.tm, p)
    if active == 0:
        return
    h2 = st.h2[isl]
    wp.atomic_add(isl_info.total, isl, h2 * e)
    if mode != DERIVATIVES:
        return
    n_size = bd.island_size
    start = isl * n_size
    base = start * n_size
    gs = h2 * g
    hs = h2 * h
    fi = bd.flat_index[oi, 0]
    li = fi - start
    _add_gradient(wk.grad, fi, bd.b, oi, si, cols_i, gs)
    _add_block(wk.hess, n_size, base, bd.b, oi, si, cols_i, li, oi, si, cols_i, li, hs)
    if oj >= 0:
        fj = bd.flat_index[oj, 0]
        lj = fj - start
        _add_gradient(wk.grad, fj, bd.b, oj, sj, cols_j, -gs)
        _add_block(wk.hess, n_size, base, bd.b, oj, sj, cols_j, lj, oj, sj, cols_j, lj, hs)
        _add_block(wk.hess, n_size, base, bd.b, oi, si, cols_i, li, oj, sj, cols_j, lj, -hs)
        _add_block(wk.hess, n_size, base, bd.b, oj, sj, cols_j, lj, oi, si, cols_i, li, -hs)


@wp.func
def _set_trial(bd: Bodies, wk: Work, isl_info: Island, isl: int, mode: int):
    """The trial point ``q + alpha dq`` of island ``isl`` loaded for an evaluation of ``mode``."""
    n_size = bd.island_size
    start = isl * n_size
    alpha = isl_info.alpha[isl]
    for r in range(n_size):
        wk.trial_q[start + r] = wk.q[start + r] + alpha * wk.dq[start + r]
    _load_state(bd, wk.trial_q, wk.tm, isl)
    isl_info.mode[isl] = mode
    isl_info.phase[isl] = SEARCH
    isl_info.searching[0] = 1


@wp.func
def _checked_start(bd: Bodies, wk: Work, isl_info: Island, isl: int, phase: int):
    """An iteration's start for island ``isl`` in EVALUATE or HAVE: its value at q taken from the sum just made
    (EVALUATE), then 1 when that value and the gradient are finite, else the island is handed back (DONE with
    NEEDS_FALLBACK) and 0. Also returns the largest diagonal entry of its matrix (the ridge's scale)."""
    n_size = bd.island_size
    start = isl * n_size
    if phase == EVALUATE:
        isl_info.value[isl] = isl_info.total[isl]
    finite = int(1)
    biggest = _ZERO
    for r in range(n_size):
        if not wp.isfinite(wk.grad[start + r]):
            finite = int(0)
        biggest = wp.max(biggest, wp.abs(wk.hess[start * n_size + r * n_size + r]))
    if finite == 0 or not wp.isfinite(isl_info.value[isl]):
        wk.stats[isl, STATUS] = NEEDS_FALLBACK
        isl_info.phase[isl] = DONE
        return 0, biggest
    return 1, biggest


@wp.kernel
def row_envelope_kernel(bd: Bodies, wk: Work, isl_info: Island):
    """Row r of island ``isl`` (in EVALUATE or HAVE): the first column of the envelope the one-thread Cholesky
    (:func:`data_gen.sim.fused_newton._cholesky`) works in: that of the first non-zero of ``H + H^T`` left of the
    diagonal, rounded down to a multiple of 4 (that factorisation reads four entries at a time), or r itself (and
    on padding rows). A factor keeps its matrix's envelope, so the entries left of it are zero and skipped, as
    the fused kernel's band does; a pile's objects touch their neighbours only."""
    isl, r = wp.tid()
    phase = isl_info.phase[isl]
    if phase != EVALUATE and phase != HAVE:
        return
    n_size = bd.island_size
    base = isl * n_size * n_size
    first = r
    if r < bd.island_dofs[isl]:
        for c in range(r):
            if wk.hess[base + r * n_size + c] != _ZERO or wk.hess[base + c * n_size + r] != _ZERO:
                first = c - c % 4
                break
    wk.first[isl * n_size + r] = first


@wp.kernel
def factor_start_kernel(bd: Bodies, wk: Work, isl_info: Island):
    """Before the blocked factorisation (:mod:`data_gen.sim.tile_cholesky`): islands in EVALUATE or HAVE that pass
    :func:`_checked_start` are marked for it, without a ridge."""
    isl = wp.tid()
    isl_info.factor[isl] = 0
    phase = isl_info.phase[isl]
    if phase != EVALUATE and phase != HAVE:
        return
    ok, biggest = _checked_start(bd, wk, isl_info, isl, phase)
    isl_info.biggest[isl] = biggest
    isl_info.ridge[isl] = _ZERO
    isl_info.factor[isl] = ok


@wp.func
def _direction_finite(bd: Bodies, wk: Work, isl: int):
    n_size = bd.island_size
    start = isl * n_size
    for r in range(n_size):
        if not wp.isfinite(wk.dq[start + r]):
            return 0
    return 1


@wp.kernel
def ridge_kernel(bd: Bodies, wk: Work, isl_info: Island):
    """After the first blocked factorisation: an island whose update is not finite (a pivot was not positive) is
    factorised again with the 1e-10 relative ridge; the others are done with it."""
    isl = wp.tid()
    if isl_info.factor[isl] != 0 and _direction_finite(bd, wk, isl) == 0:
        isl_info.ridge[isl] = wp.float64(1e-10) * isl_info.biggest[isl]
    else:
        isl_info.factor[isl] = 0


@wp.kernel
def direction_kernel(bd: Bodies, wk: Work, isl_info: Island, threshold: wp.array(dtype=wp.float64),
                     trust_m: wp.array(dtype=wp.float64), factored: int):  # fmt: skip
    """Islands in EVALUATE (just evaluated) or HAVE: the Newton update (Cholesky, with the 1e-10 relative ridge
    where needed; hand-back where the matrix stays indefinite or a value is not finite), then the start of
    :func:`data_gen.sim.fused_newton._take_update`: trust limit, converged shortcut, slope, first trial (with
    derivatives). With ``factored`` the update is already in ``dq`` (the blocked factorisation, after
    :func:`factor_start_kernel`): only its finiteness is tested here."""
    isl = wp.tid()
    phase = isl_info.phase[isl]
    if phase != EVALUATE and phase != HAVE:
        return
    n_size = bd.island_size
    start = isl * n_size
    if factored != 0:
        if _direction_finite(bd, wk, isl) == 0:  # indefinite even with the ridge
            wk.stats[isl, STATUS] = NEEDS_FALLBACK
            isl_info.phase[isl] = DONE
            return
    else:
        ok, biggest = _checked_start(bd, wk, isl_info, isl, phase)
        if ok == 0:
            return
        if _cholesky(wk.hess, wk.chol, wk.chol4, wk.first, isl, n_size, _ZERO) == 0:
            if _cholesky(wk.hess, wk.chol, wk.chol4, wk.first, isl, n_size, wp.float64(1e-10) * biggest) == 0:
                wk.stats[isl, STATUS] = NEEDS_FALLBACK
                isl_info.phase[isl] = DONE
                return
        _newton_direction(wk.chol, wk.chol4, wk.first, wk.grad, wk.dq, wk.dq4, isl, n_size)
    wk.stats[isl, ITERATIONS] += 1
    mass, motion = _update_norms(bd, wk.dq, isl)
    alpha = wp.min(trust_m[isl] / wp.max(motion, wp.float64(1e-300)), _ONE)
    if alpha < _ONE:
        wk.stats[isl, TRUST_LIMITED] += 1
    if alpha >= _ONE and mass <= threshold[isl]:  # already below the tolerance: taken whole, converged
        for r in range(n_size):
            wk.q[start + r] = wk.q[start + r] + wk.dq[start + r]
        wk.stats[isl, CONVERGED] = 1
        isl_info.phase[isl] = DONE
        return
    slope = _ZERO
    for r in range(n_size):
        slope = slope + wk.grad[start + r] * wk.dq[start + r]
    isl_info.slope[isl] = slope
    isl_info.mass[isl] = mass
    isl_info.alpha[isl] = alpha
    isl_info.trial[isl] = 0
    wk.stats[isl, EVALUATIONS_WITH_DERIVATIVES] += 1
    _set_trial(bd, wk, isl_info, isl, DERIVATIVES)


@wp.kernel
def decide_kernel(bd: Bodies, wk: Work, isl_info: Island, threshold: wp.array(dtype=wp.float64),
                  line_search_steps: int):  # fmt: skip
    """Islands in SEARCH: the Armijo test of the trial just evaluated (plain decrease for the extra halvings),
    then the accepted point's convergence test, or the next halving."""
    isl = wp.tid()
    if isl_info.phase[isl] != SEARCH:
        return
    t = isl_info.trial[isl]
    trial = isl_info.total[isl]
    value = isl_info.value[isl]
    alpha = isl_info.alpha[isl]
    ok = int(0)
    if t < line_search_steps:
        if trial <= value + wp.float64(ARMIJO_C) * alpha * isl_info.slope[isl] + wp.float64(1e-14) * wp.abs(value):
            ok = int(1)
    elif trial < value:
        ok = int(1)
        wk.stats[isl, LINE_SEARCH_EXTENDED] += 1
    isl_info.mode[isl] = NOTHING
    if ok != 0:
        n_size = bd.island_size
        start = isl * n_size
        for r in range(n_size):
            wk.q[start + r] = wk.trial_q[start + r]
        if alpha * isl_info.mass[isl] <= threshold[isl]:
            wk.stats[isl, CONVERGED] = 1
            isl_info.phase[isl] = DONE
        elif t == 0:  # the first trial was evaluated with derivatives: the next iteration starts from them
            isl_info.value[isl] = trial
            isl_info.phase[isl] = HAVE
        else:
            isl_info.phase[isl] = EVALUATE
        return
    if t + 1 >= line_search_steps + EXTRA_HALVINGS:  # no decrease along dq: stopped where it is, unconverged
        wk.stats[isl, LINE_SEARCH_FAILURES] += 1
        isl_info.phase[isl] = DONE
        return
    isl_info.alpha[isl] = wp.float64(0.5) * alpha
    isl_info.trial[isl] = t + 1
    wk.stats[isl, EVALUATIONS] += 1
    _set_trial(bd, wk, isl_info, isl, VALUE)


@wp.kernel
def iterating_kernel(isl_info: Island):
    """Sets ``iterating[0]`` when island ``isl`` is not DONE (the outer loop's condition)."""
    isl = wp.tid()
    if isl_info.phase[isl] != DONE:
        isl_info.iterating[0] = 1


@wp.kernel
def clear_iterating_kernel(isl_info: Island):
    isl_info.iterating[0] = 0


@wp.kernel
def all_live_kernel(isl_info: Island):
    """Slot k of the pairs: evaluated (outside sub-steps every candidate pair is)."""
    isl_info.live[wp.tid()] = 1


# A step's sub-steps on the device: the fused kernel's per-island sub-step (data_gen.sim.fused_newton.substeps_kernel)
# cut into launches with a thread per object, sphere and pair (through the same functions, on the same values), so
# that no thread walks an island's spheres or pairs: on a GPU one thread doing that costs more than the solve.


@wp.kernel
def substep_begin_kernel(ss: Substeps, isl_info: Island, j: int):
    """Island ``isl``: EVALUATE if it has a sub-step ``j`` and none of its earlier ones was handed back, else
    DONE; nothing to evaluate yet (the start data follow)."""
    isl = wp.tid()
    isl_info.mode[isl] = NOTHING
    if j >= ss.num_sub[isl] or isl_info.halted[isl] != 0:
        isl_info.phase[isl] = DONE
    else:
        isl_info.phase[isl] = EVALUATE


@wp.kernel
def substep_objects_kernel(bd: Bodies, st: StepData, ss: Substeps, isl_info: Island):
    """Object o of an island starting a sub-step: its start states (the current ones) and predicted states."""
    o = wp.tid()
    isl = isl_info.object_island[o]
    if isl_info.phase[isl] != EVALUATE:
        return
    h = ss.h[isl]
    for r in range(3):
        for a in range(bd.columns[o]):
            st.tm_start[o, r, a] = ss.tm_now[o, r, a]
            st.tm_pred[o, r, a] = ss.tm_now[o, r, a] + h * ss.tmdot[o, r, a]


@wp.kernel
def substep_spheres_kernel(bd: Bodies, sc: SceneArgs, st: StepData, ss: Substeps, isl_info: Island):
    """Sphere s of object o of an island starting a sub-step: its start data
    (:func:`data_gen.sim.fused_newton.sphere_start`)."""
    o, s = wp.tid()
    if isl_info.phase[isl_info.object_island[o]] != EVALUATE:
        return
    sphere_start(bd, sc, st, ss, o, s, bd.columns[o])


@wp.kernel
def substep_pairs_kernel(st: StepData, ss: Substeps, isl_info: Island):
    """Slot k of the pairs, of an island starting a sub-step: whether its pair can touch within the sub-step
    (``isl_info.live``) and then its start data (:func:`data_gen.sim.fused_newton.pair_start_live`)."""
    k = wp.tid()
    if _past_pairs(st, k):
        return
    p = st.pair_order[k]
    isl = isl_info.object_island[st.obj_i[p]]
    if isl_info.phase[isl] != EVALUATE:
        return
    isl_info.live[k] = pair_start_live(st, ss, p, ss.h[isl])


@wp.kernel
def substep_ready_kernel(bd: Bodies, st: StepData, wk: Work, ss: Substeps, isl_info: Island,
                         threshold: wp.array(dtype=wp.float64), trust_m: wp.array(dtype=wp.float64)):  # fmt: skip
    """Island ``isl`` starting a sub-step: its limits, q at the predicted states, cleared counters."""
    isl = wp.tid()
    if isl_info.phase[isl] != EVALUATE:
        return
    thr, trust = _step_limits(bd, st, isl, ss.tolerance, ss.gravity_norm)
    threshold[isl] = thr
    trust_m[isl] = trust
    kp = bd.flat_index.shape[1] // 3
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):  # q0 = the predicted states
        o = bd.island_objects[slot]
        for r in range(3):
            for a in range(bd.columns[o]):
                wk.q[bd.flat_index[o, r * kp + a]] = st.tm_pred[o, r, a]
    for k in range(NUM_STATS):
        wk.stats[isl, k] = 0


@wp.kernel
def substep_finish_kernel(bd: Bodies, wk: Work, ss: Substeps, isl_info: Island, j: int):
    """After island ``isl``'s sub-step ``j``: its counters into row j; a hand-back halts the island; else its
    result loaded as the states its forces are recorded at (mode VALUE)."""
    isl = wp.tid()
    isl_info.mode[isl] = NOTHING
    if j >= ss.num_sub[isl] or isl_info.halted[isl] != 0:
        return
    for k in range(NUM_STATS):
        ss.stats[j, isl, k] = wk.stats[isl, k]
    if wk.stats[isl, STATUS] != SOLVED:
        isl_info.halted[isl] = 1
        return
    _load_state(bd, wk.q, wk.tm, isl)
    isl_info.mode[isl] = VALUE


@wp.kernel
def substep_object_end_kernel(bd: Bodies, st: StepData, wk: Work, ss: Substeps, isl_info: Island):
    """Object o of an island whose sub-step was solved: its motion bound at the result, and its states and rates
    advanced to the result."""
    o = wp.tid()
    isl = isl_info.object_island[o]
    if isl_info.mode[isl] == NOTHING:
        return
    cols = bd.columns[o]
    st.moved[o] = _motion_bound(bd, st, wk.tm, o, cols)
    h = ss.h[isl]
    for r in range(3):
        for a in range(cols):
            ss.tmdot[o, r, a] = (wk.tm[o, r, a] - st.tm_start[o, r, a]) / h
            ss.tm_now[o, r, a] = wk.tm[o, r, a]


@wp.kernel
def substep_sphere_forces_kernel(bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, ss: Substeps,
                                 isl_info: Island, j: int):  # fmt: skip
    """Sphere s of object o of an island whose sub-step was solved: its position, scene force and normal into
    row j (:func:`data_gen.sim.fused_newton.sphere_force`)."""
    o, s = wp.tid()
    if isl_info.mode[isl_info.object_island[o]] == NOTHING:
        return
    out = ss.forces
    sphere_force(bd, sc, st, wk.tm, o, s, bd.columns[o], st.moved[o], out.sphere_x[j], out.scene_force[j],
                 out.scene_normal[j])  # fmt: skip


@wp.kernel
def substep_pair_forces_kernel(bd: Bodies, st: StepData, wk: Work, ss: Substeps, isl_info: Island, j: int):
    """Slot k of the pairs, of an island whose sub-step was solved: its pair's force and normal into row j, zero
    unless it is live and touches (:func:`data_gen.sim.fused_newton.live_pair_force`)."""
    k = wp.tid()
    if _past_pairs(st, k):
        return
    p = st.pair_order[k]
    if isl_info.mode[isl_info.object_island[st.obj_i[p]]] == NOTHING:
        return
    out = ss.forces
    out.pair_force[j, p] = wp.vec3d(_ZERO, _ZERO, _ZERO)
    out.pair_normal[j, p] = wp.vec3d(_ZERO, _ZERO, _ZERO)
    if isl_info.live[k] != 0:
        live_pair_force(bd, st, wk.tm, p, out.pair_force[j], out.pair_normal[j])


@wp.kernel
def substep_object_sums_kernel(ss: Substeps, isl_info: Island, j: int):
    """Object o of an island whose sub-step was solved: row j of its scene force sums."""
    o = wp.tid()
    if isl_info.mode[isl_info.object_island[o]] == NOTHING:
        return
    object_scene_sums(ss, o, j)


@wp.kernel
def substep_pair_sums_kernel(st: StepData, ss: Substeps, isl_info: Island, j: int):
    """Slot k of the pairs, of an island whose sub-step was solved: its live pair's force added to row j of its
    group's sums (atomically: a group's pairs are slots of one island, added in slot order on the CPU)."""
    k = wp.tid()
    if _past_pairs(st, k) or isl_info.live[k] == 0:
        return
    p = st.pair_order[k]
    if isl_info.mode[isl_info.object_island[st.obj_i[p]]] == NOTHING:
        return
    add_pair_sums(st, ss, p, j)


_WORK_INPUTS = frozenset({"q"})
"""What a solve reads of :class:`Work` before writing it: the start state (the matrices, factors, updates, envelope
and counters are written first)."""

PAIR_FIELDS = ("pair_gap", "pair_order", "live_order", "obj_i", "sph_i", "obj_j", "sph_j", "frozen_x_j",
               "pair_stiffness", "radius_sum", "pair_friction_scale", "normal0", "x0_i", "x0_j")  # fmt: skip
""":class:`StepData`'s arrays over the pair buffers' capacity: only their first ``num_pairs`` rows are in use."""

_SUBSTEP_STEP_INPUTS = frozenset(StepData.vars) - {
    "tm_pred", "tm_pred4", "tm_start", "margin", "pair_gap", "moved", "stiffness", "friction_scale", "start_x",
    "start_speed", "start_normal", "live_order", "live_count", "pair_friction_scale", "normal0", "x0_i", "x0_j",
}  # fmt: skip
"""What the sub-step schedule reads of :class:`StepData` from the host: the rest is the start data its launches
compute at each sub-step before reading it (states, sphere and pair start data, margins, motion bounds)."""

_SUBSTEP_INPUTS = frozenset(Substeps.vars) - {"forces", "scene_sums"}
"""What the sub-step schedule reads of :class:`Substeps` from the host: not its outputs (the forces and the scene
sums are written for every entry a caller reads; the counters and the pair sums start at the host's zeros)."""


class StructMirror:
    """Copies, on another warp device, of the arrays a warp struct instance holds: allocated at first use (again
    when a source array changes shape or type) and refreshed by copy. Fields that share memory in the source
    (an array and its four-at-a-time view: ``hess`` / ``hess4``) share it in the copy."""

    def __init__(self, device) -> None:
        self.device = wp.get_device(device)
        self._buffers: dict[str, wp.array] = {}

    def copy(self, tag: str, source, struct_type, refresh: bool | frozenset[str] = True,
             leading: dict[str, int] | None = None):  # fmt: skip
        """A ``struct_type`` instance whose arrays are this device's copies of ``source``'s (filled from them with
        ``refresh``, or only those named in it; the others only allocated: scratch the launches write first) and
        whose other fields are ``source``'s. ``tag`` names the source. ``leading`` names arrays of which only
        their first rows are filled (the rows in use: a pair buffer's first ``num_pairs`` of its capacity)."""
        out = struct_type()
        by_address: dict[int, wp.array] = {}
        for name in struct_type.vars:
            value = getattr(source, name)
            var_type = struct_type.vars[name].type
            if isinstance(var_type, type(struct_type)):  # a struct inside: copied the same way
                setattr(out, name, self.copy(f"{tag}.{name}", value, var_type, refresh, leading))
                continue
            if not isinstance(value, wp.array):
                setattr(out, name, value)
                continue
            shared = by_address.get(value.ptr) if value.ptr else None
            if shared is not None:  # a view of a field already copied: the same view of its copy
                setattr(out, name, wp.array(ptr=shared.ptr, dtype=value.dtype, shape=value.shape,
                                            strides=value.strides, device=self.device))  # fmt: skip
                continue
            buffer = self.array(f"{tag}.{name}", value, refresh if isinstance(refresh, bool) else name in refresh,
                                (leading or {}).get(name))  # fmt: skip
            if value.ptr:
                by_address[value.ptr] = buffer
            setattr(out, name, buffer)
        return out

    def array(self, tag: str, value: wp.array, refresh: bool = True, rows: int | None = None) -> wp.array:
        """This device's copy of the array ``value`` (named ``tag``), allocated at first use or when its shape or
        type changes, filled from it with ``refresh`` (its first ``rows`` rows only, if given)."""
        buffer = self._buffers.get(tag)
        if buffer is None or buffer.shape != value.shape or buffer.dtype != value.dtype:
            buffer = self._buffers[tag] = wp.empty(value.shape, dtype=value.dtype, device=self.device)
        if refresh and value.size:
            copy_rows(buffer, value, rows)
        return buffer


def copy_rows(dst: wp.array, src: wp.array, rows: int | None = None, row: int = 0) -> None:
    """``src``'s rows ``row .. row + rows`` (its first axis; all of them without ``rows``) into the same rows of
    ``dst`` (contiguous arrays of one shape): one copy, of what is in use only."""
    if rows is None:
        wp.copy(dst, src)
        return
    per_row = src.size // src.shape[0] if src.shape[0] else 0
    count = max(0, min(rows, src.shape[0] - row)) * per_row
    if count:
        wp.copy(dst, src, dest_offset=row * per_row, src_offset=row * per_row, count=count)


def warn_if_unvalidated(device) -> bool:
    """Log, once per device and process, that the schedule has not been validated on CUDA (while
    :data:`CUDA_VALIDATED` is False) when ``device`` (a warp device) is a CUDA one; True if it logged now."""
    name = str(device)
    if CUDA_VALIDATED or not device.is_cuda or name in _UNVALIDATED_WARNED:
        return False
    _UNVALIDATED_WARNED.add(name)
    logger.warning(
        "DeviceNewton on %s: this schedule has been tested on the CPU only, never on a CUDA GPU; before relying on "
        "its results there, run `pytest -s tests/sim/test_sim_device_newton_cuda.py` on this machine (it compares "
        "them with the fused CPU solver; docs/gpu_checks.md)", name)
    return True


class DeviceNewton:
    """:meth:`FusedNewton.solve` as a schedule of launches with a thread per element (see the module docstring),
    on ``fused``'s model, step data and buffers.

    With ``device`` (a warp device other than ``fused``'s, e.g. "cuda" next to a CPU workspace) the solve runs
    there: the model is copied once, each solve's step data and start state are copied over, and the state and
    counters come back when it ends; nothing crosses between its Newton iterations. With ``graph`` (CUDA) the
    schedule is captured as one CUDA graph per solve, its loops as conditional nodes (CUDA 12.4+), and launched
    once: no host read inside the solve at all (``graph`` True on the CPU captures it too, with warp's CPU graph
    recording: the same schedule replayed, how the tests check the captured structure without a GPU). With
    ``tile_factor`` (the default on CUDA) the islands' matrices
    are factorised by :mod:`data_gen.sim.tile_cholesky`, a block of threads per island, instead of one thread
    each (the CPU's default: there a block is one thread, and the envelope factorisation costs less).

    A captured schedule is kept (the last :data:`GRAPHS_KEPT`) and launched again by a later solve whose launches
    would be the same: the same kernels with the same argument bytes (the structs' array pointers, shapes and
    scalars, :func:`_launch_bytes`) over the same dimensions. Those are all a graph holds, and the schedule's
    launches are a function of them, so the replay is the capture that solve would have made; the arrays'
    contents are read when it runs. A workspace's buffers keep their addresses between steps, so a step with
    the same islands and pair count as an earlier one reuses its graph.

    ``timings`` (a dict, e.g. the solver's) gets the wall seconds of the solves added to ``device_solve`` (from
    the first launch to the results back on the host, the capture included) and of their captures to
    ``device_capture``; ``counters`` (a dict, e.g. the solver's) counts ``device_graphs_captured`` and
    ``device_graphs_reused``."""

    default_graph: bool | None = None
    """``graph`` where a caller gives none (None: capture on CUDA). ``bench_cuda.py --profile-solver`` sets it
    False for a run whose kernels are timed one by one (a graph's launches cannot be)."""

    def __init__(self, fused: FusedNewton, device=None, graph: bool | None = None, tile_factor: bool | None = None,
                 timings: dict[str, float] | None = None, counters: dict[str, int] | None = None) -> None:  # fmt: skip
        self.fused = fused
        self.timings = timings if timings is not None else {}
        for key in ("device_solve", "device_capture"):
            self.timings.setdefault(key, 0.0)
        self.counters = counters if counters is not None else {}
        for key in ("device_graphs_captured", "device_graphs_reused"):
            self.counters.setdefault(key, 0)
        self._graphs: OrderedDict[tuple, wp.Graph] = OrderedDict()
        self.mirror = StructMirror(device) if device is not None else None
        self.device = self.mirror.device if self.mirror is not None else wp.get_device(fused.device)
        if graph is None:
            graph = self.device.is_cuda if DeviceNewton.default_graph is None else DeviceNewton.default_graph
        self.graph = bool(graph)
        warn_if_unvalidated(self.device)
        self.tile_factor = self.device.is_cuda if tile_factor is None else bool(tile_factor)
        self.clear_entries = self.device.is_cuda  # the matrices cleared an entry per thread (GPU), else a row
        if self.graph:  # a module cannot be loaded while a graph is captured: every variant launched, here
            tiles = sys.modules[blocked_cholesky_solve.__module__]
            wp.load_module(sys.modules[__name__], device=self.device)
            wp.load_module(tiles, device=self.device)  # (block_envelope_kernel: the default block)
            # the factorisation's blocks of THREADS: warp compiles and loads a module once per block size
            wp.load_module(tiles, device=self.device, block_dim=THREADS)
        self._info: Island | None = None
        self._info_key: tuple | None = None
        self._bodies_key: tuple | None = None
        self._scene: SceneArgs | None = None
        self._first_block: wp.array | None = None  # (n_isl, blocks) the blocked factorisation's envelope

    def _island_info(self) -> Island:
        """The per-island arrays for the fused workspace's grouping and pair capacity now (remade when either
        changed), on this solver's device."""
        f = self.fused
        n_isl = f.shape[0]
        capacity = len(f.pair_order)
        key = (f.layout_version, capacity)
        if self._info is not None and self._info_key == key:
            return self._info
        info = Island()
        for name in Island.vars:
            dtype = wp.float64 if name in ("value", "total", "alpha", "slope", "mass", "ridge", "biggest") else wp.int32
            count = 1 if name in ("iterating", "searching") else capacity if name == "live" else n_isl
            if name != "object_island":
                setattr(info, name, wp.zeros(count, dtype=dtype, device=self.device))
        info.object_island = wp.array(f.island_of.to(torch.int32).cpu().numpy(), dtype=wp.int32, device=self.device)
        self._info, self._info_key = info, key
        return info

    def _structs(self, st: StepData, step_inputs: bool | frozenset[str] = True
                 ) -> tuple[Bodies, SceneArgs, StepData, Work, wp.array, wp.array]:  # fmt: skip
        """(bodies, scene, step data, work, threshold, trust) on this solver's device: the fused workspace's own,
        or copies of them (the model's once per grouping, the step's and the work's at every solve: of the step
        data ``step_inputs`` and of its pair arrays their rows in use)."""
        f = self.fused
        threshold, trust = f._limits
        if self.mirror is None:
            return f.bodies, f.scene, st, f.work, threshold, trust
        m = self.mirror
        key = f.layout_version  # (the grouping's arrays in Bodies change with it)
        if self._bodies_key != key:
            self._bodies = m.copy("bodies", f.bodies, Bodies)
            self._bodies_key = key
        if self._scene is None:
            self._scene = scene_args(f.contact.scene, self.device.alias)
        step = m.copy("step", st, StepData, refresh=step_inputs, leading=dict.fromkeys(PAIR_FIELDS, int(st.num_pairs)))
        work = m.copy("work", f.work, Work, refresh=_WORK_INPUTS)
        return self._bodies, self._scene, step, work, m.array("threshold", threshold), m.array("trust", trust)

    def _bring_back(self, step: StepData, work: Work, threshold: wp.array, trust: wp.array) -> None:
        """What the solve wrote that the workspace's callers read, copied back to it: the state, the counters,
        the limits, and the scratch its force evaluation reads (scene margins, motion bounds)."""
        if self.mirror is None:
            return
        f = self.fused
        st = f._step
        for dst, src in ((f.work.q, work.q), (f.work.stats, work.stats), (f._limits[0], threshold),
                         (f._limits[1], trust), (st.margin, step.margin), (st.moved, step.moved)):  # fmt: skip
            wp.copy(dst, src)
        wp.synchronize_device(self.device)  # (the host reads them next)

    def _launch_terms(self, bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, info: Island) -> None:
        """The term launches at the state each island has loaded (those whose mode is not NOTHING)."""
        f = self.fused
        n_isl, size = f.shape
        n, num_points = f._keep["cub_volume"].shape
        num_spheres = f._keep["radius"].shape[1]
        device = self.device
        chunk = 1 if self.clear_entries else size
        wp.launch(clear_kernel, dim=(n_isl, size, size // chunk), device=device, inputs=[bd, wk, info, chunk])
        wp.launch(inertia_kernel, dim=n, device=device, inputs=[bd, st, wk, info])
        wp.launch(elastic_kernel, dim=(n, num_points), device=device, inputs=[bd, st, wk, info])
        wp.launch(scene_kernel, dim=(n, num_spheres), device=device, inputs=[bd, sc, st, wk, info])
        if st.num_pairs:
            wp.launch(pairs_kernel, dim=_pair_threads(st, self.graph), device=device, inputs=[bd, st, wk, info])

    def _start(self, bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, info: Island, threshold: wp.array,
               trust: wp.array, limits_given: bool, tolerance: float) -> None:  # fmt: skip
        """A solve's start: the islands' limits (unless given), counters and phases; every sphere's scene margin."""
        f = self.fused
        n, num_spheres = f._keep["radius"].shape
        wp.launch(start_kernel, dim=f.shape[0], device=self.device, inputs=[
            bd, st, wk, info, threshold, trust, int(limits_given), wp.float64(tolerance),
            wp.float64(f._gravity_norm),
        ])  # fmt: skip
        wp.launch(margins_kernel, dim=(n, num_spheres), device=self.device, inputs=[bd, sc, st])
        if st.num_pairs:
            wp.launch(all_live_kernel, dim=_pair_threads(st, self.graph), device=self.device, inputs=[info])

    def _factor_blocked(self, bd: Bodies, wk: Work, info: Island) -> None:
        """The update ``dq`` of every island in EVALUATE or HAVE by the blocked factorisation inside its matrix's
        block envelope (a pile's matrix is nearly block-banded), again with the ridge where the first left it
        non-finite (:func:`factor_start_kernel`, :func:`ridge_kernel`)."""
        n_isl, size = self.fused.shape
        matrices = (_view(wk.hess, (n_isl, size, size)), _view(wk.grad, (n_isl, size, 1)))
        outputs = (_view(wk.chol, (n_isl, size, size)), _view(wk.dq, (n_isl, size, 1)))
        first_block = self._first_blocks()  # (allocated before a capture by _run)
        wp.launch(factor_start_kernel, dim=n_isl, device=self.device, inputs=[bd, wk, info])
        block_envelope(matrices[0], info.factor, first_block)
        blocked_cholesky_solve(*matrices, info.ridge, info.factor, *outputs, first_block=first_block)
        wp.launch(ridge_kernel, dim=n_isl, device=self.device, inputs=[bd, wk, info])
        blocked_cholesky_solve(*matrices, info.ridge, info.factor, *outputs, first_block=first_block)

    def evaluate(self, objective, q: torch.Tensor,
                 derivatives: bool) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:  # fmt: skip
        """``objective`` per island (n_isl,) at ``q`` (n_isl, N) summed by the term launches; with ``derivatives``
        the gradient (n_isl, N) and Newton matrix (n_isl, N, N) (copies, on the CPU): what
        :meth:`FusedNewton.evaluate` returns, to round-off."""
        f = self.fused
        n_isl, size = f.shape
        f.q.copy_(q.reshape(-1))
        bd, sc, st, wk, threshold, trust = self._structs(f._step_data(objective))
        info = self._island_info()
        self._start(bd, sc, st, wk, info, threshold, trust, False, 1.0)
        mode = DERIVATIVES if derivatives else VALUE
        wp.launch(load_kernel, dim=n_isl, device=self.device, inputs=[bd, wk, info, int(mode)])
        self._launch_terms(bd, sc, st, wk, info)
        value = torch.as_tensor(info.total.numpy()).clone()
        if not derivatives:
            return value, None, None
        grad = torch.as_tensor(wk.grad.numpy()).view(n_isl, size).clone()
        return value, grad, torch.as_tensor(wk.hess.numpy()).view(n_isl, size, size).clone()

    def _iteration(self, bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, info: Island, threshold: wp.array,
                   trust: wp.array, settings: NewtonSettings):  # fmt: skip
        """The body of the Newton loop: one iteration of every island not DONE, its line search a nested loop."""
        n_isl = self.fused.shape[0]
        device = self.device

        def search() -> None:  # one line-search trial of every searching island
            self._launch_terms(bd, sc, st, wk, info)
            wp.launch(decide_kernel, dim=n_isl, device=device,
                      inputs=[bd, wk, info, threshold, int(settings.line_search_steps)])  # fmt: skip

        def iteration() -> None:
            wp.launch(prepare_kernel, dim=n_isl, device=device, inputs=[bd, wk, info, int(settings.iterations)])
            self._launch_terms(bd, sc, st, wk, info)
            if self.tile_factor:
                self._factor_blocked(bd, wk, info)
            else:
                wp.launch(row_envelope_kernel, dim=(n_isl, self.fused.shape[1]), device=device, inputs=[bd, wk, info])
            wp.launch(direction_kernel, dim=n_isl, device=device,
                      inputs=[bd, wk, info, threshold, trust, int(self.tile_factor)])  # fmt: skip
            wp.capture_while(info.searching, search)
            wp.launch(iterating_kernel, dim=n_isl, device=device, inputs=[info])

        return iteration

    def _first_blocks(self) -> wp.array:
        """The blocked factorisation's envelope (n_isl, blocks), allocated for the workspace's shape now."""
        n_isl, size = self.fused.shape
        key = (n_isl, blocks(size))
        if self._first_block is None or self._first_block.shape != key:
            self._first_block = wp.zeros(key, dtype=wp.int32, device=self.device)
        return self._first_block

    def _run(self, schedule, kind: str, st: StepData, structs: tuple, *scalars) -> None:
        """``schedule()``'s launches, captured as one graph and launched (``graph``), else launched directly; a
        graph captured for the same launches (``kind``, ``st``, ``structs`` and ``scalars``:
        :meth:`_schedule_key`) is launched again instead of capturing. (What the launches need is allocated
        first: nothing is allocated during a capture.)"""
        self._first_blocks()
        if not self.graph:
            schedule()
            return
        key = self._schedule_key(kind, st, structs, *scalars)
        graph = self._graphs.get(key)
        if graph is not None:
            self._graphs.move_to_end(key)
            self.counters["device_graphs_reused"] += 1
            wp.capture_launch(graph)
            return
        try:
            t0 = time.perf_counter()
            with wp.ScopedCapture(device=self.device) as capture:
                schedule()
            self.timings["device_capture"] += time.perf_counter() - t0
        except Exception as err:  # (e.g. a driver without conditional graph nodes) launched directly instead
            logger.warning("DeviceNewton: the solve's graph could not be captured on %s (%s): launching "
                           "directly from now on (the loops' conditions are then read on the host)",
                           self.device, err)  # fmt: skip
            self.graph = False
            self._graphs.clear()
            schedule()
            return
        self.counters["device_graphs_captured"] += 1
        self._graphs[key] = capture.graph
        while len(self._graphs) > GRAPHS_KEPT:
            self._graphs.popitem(last=False)
        wp.capture_launch(capture.graph)

    def _schedule_key(self, kind: str, st: StepData, structs: tuple, *scalars) -> tuple:
        """What the launches of a ``kind`` schedule over the step data ``st`` and its other struct and array
        arguments ``structs`` depend on: their bytes, the workspace's dimensions (the pairs launch's threads among
        them), this solver's choices and the schedule's ``scalars``."""
        f = self.fused
        dims = (f.shape, tuple(f._keep["cub_volume"].shape), tuple(f._keep["radius"].shape),
                _pair_threads(st, self.graph))  # fmt: skip
        return (kind, _launch_bytes(st, *structs, self._first_block), dims, self.tile_factor, self.clear_entries,
                float(f._gravity_norm), scalars)  # fmt: skip

    def solve(self, objective, q0: torch.Tensor, scale: torch.Tensor | None, trust_m: torch.Tensor | None,
              settings: NewtonSettings) -> NewtonResult | None:  # fmt: skip
        """What :meth:`FusedNewton.solve` returns for the same arguments (to round-off), or None where an island
        needs ``minimise``."""
        f = self.fused
        f.q.copy_(q0.reshape(-1))
        given = f._given_limits(scale, trust_m, settings)
        bd, sc, st, wk, threshold, trust = self._structs(f._step_data(objective))
        info = self._island_info()
        iteration = self._iteration(bd, sc, st, wk, info, threshold, trust, settings)

        def schedule() -> None:
            self._start(bd, sc, st, wk, info, threshold, trust, given, settings.tolerance)
            wp.capture_while(info.iterating, iteration)

        t0 = time.perf_counter()
        self._run(schedule, "solve", st, (bd, sc, wk, info, threshold, trust), bool(given), float(settings.tolerance),
                  int(settings.iterations), int(settings.line_search_steps))  # fmt: skip
        self._bring_back(st, wk, threshold, trust)
        self.timings["device_solve"] += time.perf_counter() - t0
        if bool((f.stats[:, STATUS] != SOLVED).any()):
            return None
        return f._result()

    def solve_substeps(self, tm: torch.Tensor, tmdot: torch.Tensor, h_s: float | Sequence[float],
                       num_sub: int | Sequence[int], gravity_m_s2: torch.Tensor, settings: NewtonSettings,
                       scene_stiffness_n_m: torch.Tensor, smoothing_m: float | Sequence[float], pairs,
                       pair_mu: torch.Tensor, pair_margin_m: float,
                       pair_group: np.ndarray | None = None) -> SubstepResult | None:  # fmt: skip
        """What :meth:`FusedNewton.solve_substeps` returns for the same arguments (to round-off): every island's
        sub-steps, each one's start data computed on the device from the previous one's result
        (:func:`substep_begin_kernel` to :func:`substep_ready_kernel`), solved by the schedule, its forces and sums
        recorded (:func:`substep_finish_kernel` to :func:`substep_pair_sums_kernel`): a step of one-handle islands
        without the host between its sub-steps, and no thread walking an island's spheres or pairs."""
        f = self.fused
        n_isl = f.shape[0]
        n, num_spheres = f._keep["radius"].shape
        st_host, ss_host, count_max, count, num_pairs, groups = f.prepare_substeps(
            tm, tmdot, h_s, num_sub, gravity_m_s2, settings, scene_stiffness_n_m, smoothing_m, pairs, pair_mu,
            pair_margin_m, pair_group,
        )  # fmt: skip
        bd, sc, st, wk, threshold, trust = self._structs(st_host, _SUBSTEP_STEP_INPUTS)
        ss = ss_host
        if self.mirror is not None:  # (of the counters and pair sums, the rows of this step's sub-steps)
            ss = self.mirror.copy("substeps", ss_host, Substeps, refresh=_SUBSTEP_INPUTS,
                                  leading={"stats": count_max, "pair_sums": count_max, "pair_mu": num_pairs,
                                           "pair_group": num_pairs})  # fmt: skip
        info = self._island_info()
        info.halted.zero_()
        iteration = self._iteration(bd, sc, st, wk, info, threshold, trust, settings)
        device = self.device

        pair_threads = _pair_threads(st, self.graph)
        sums = ss_host.with_sums != 0

        def schedule() -> None:
            for j in range(count_max):
                wp.launch(clear_iterating_kernel, dim=1, device=device, inputs=[info])
                wp.launch(substep_begin_kernel, dim=n_isl, device=device, inputs=[ss, info, j])
                wp.launch(substep_objects_kernel, dim=n, device=device, inputs=[bd, st, ss, info])
                wp.launch(substep_spheres_kernel, dim=(n, num_spheres), device=device, inputs=[bd, sc, st, ss, info])
                if pair_threads:
                    wp.launch(substep_pairs_kernel, dim=pair_threads, device=device, inputs=[st, ss, info])
                wp.launch(substep_ready_kernel, dim=n_isl, device=device, inputs=[bd, st, wk, ss, info, threshold, trust])
                wp.launch(iterating_kernel, dim=n_isl, device=device, inputs=[info])
                wp.capture_while(info.iterating, iteration)
                wp.launch(substep_finish_kernel, dim=n_isl, device=device, inputs=[bd, wk, ss, info, j])
                wp.launch(substep_object_end_kernel, dim=n, device=device, inputs=[bd, st, wk, ss, info])
                wp.launch(substep_sphere_forces_kernel, dim=(n, num_spheres), device=device,
                          inputs=[bd, sc, st, wk, ss, info, j])  # fmt: skip
                if pair_threads:
                    wp.launch(substep_pair_forces_kernel, dim=pair_threads, device=device,
                              inputs=[bd, st, wk, ss, info, j])  # fmt: skip
                if sums:
                    wp.launch(substep_object_sums_kernel, dim=n, device=device, inputs=[ss, info, j])
                    if pair_threads:
                        wp.launch(substep_pair_sums_kernel, dim=pair_threads, device=device, inputs=[st, ss, info, j])

        t0 = time.perf_counter()
        self._run(schedule, "substeps", st, (bd, sc, wk, ss, info, threshold, trust), count_max,
                  int(settings.iterations), int(settings.line_search_steps))  # fmt: skip
        if self.mirror is not None:  # what substep_result reads: this step's sub-steps' rows, its pairs' entries
            for name in ("tm_now", "tmdot"):
                wp.copy(getattr(ss_host, name), getattr(ss, name))
            for name in ("stats", "scene_sums", "pair_sums"):
                copy_rows(getattr(ss_host, name), getattr(ss, name), count_max)
            for name in ("sphere_x", "scene_force", "scene_normal"):
                copy_rows(getattr(ss_host.forces, name), getattr(ss.forces, name), count_max)
            for name in ("pair_force", "pair_normal"):
                for j in range(count_max):
                    copy_rows(getattr(ss_host.forces, name)[j], getattr(ss.forces, name)[j], num_pairs)
        wp.synchronize_device(device)
        self.timings["device_solve"] += time.perf_counter() - t0
        return f.substep_result(count_max, count, num_pairs, groups, pair_group is not None)


def _pair_threads(st: StepData, graph: bool) -> int:
    """Threads of the pairs launch for the step's ``num_pairs`` (0 without pairs): that count launched directly;
    for a graph the next power of two (at most the pair buffers' capacity), those past the pairs stopping at
    ``pair_start[-1]``, so that a graph fits every step whose pair count rounds to the same power (at most twice
    the threads a launch needs; a GPU's idle threads cost little, a CPU's loop over them does)."""
    p = int(st.num_pairs)
    if p == 0 or not graph:
        return p
    return min(1 << (p - 1).bit_length(), st.obj_i.shape[0])


def _launch_bytes(*values) -> tuple:
    """What launches pass to the device for each of ``values``: a warp struct's packed bytes (its arrays'
    pointers, shapes and strides, its scalars, its structs), an array's pointer, shape and strides.

    ``StepData.num_pairs`` is left out: no kernel of the schedule reads it; its pairs launch has
    :func:`_pair_threads` threads (part of the key)."""
    out = []
    for value in values:
        if isinstance(value, wp.array):
            out.append((value.ptr, value.shape, value.strides, value.dtype))
        elif isinstance(value, StepData.cls):  # its bytes with those of num_pairs zeroed
            packed = value.__ctype__()
            field = type(packed).num_pairs
            raw = bytearray(bytes(packed))
            raw[field.offset:field.offset + field.size] = bytes(field.size)
            out.append(bytes(raw))
        else:
            out.append(bytes(value.__ctype__()))
    return tuple(out)


def _view(array: wp.array, shape: tuple[int, ...]) -> wp.array:
    """A contiguous float64 array's memory seen with another shape (no copy)."""
    return wp.array(ptr=array.ptr, dtype=wp.float64, shape=shape, device=array.device)


__all__ = ["DeviceNewton", "StructMirror"]
