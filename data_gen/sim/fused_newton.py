"""A whole implicit Euler (sub)step solve in one warp launch: Newton's method, one thread per island.

:func:`data_gen.sim.newton.minimise` drives a batched torch/warp evaluation from Python; every Newton
iteration costs a dozen tensor operations and several host reads however small the islands are. On a pile of
near-rigid objects (one affine handle each, 12 unknowns) that per-iteration overhead, not arithmetic,
dominated. This module runs the same algorithm compiled: each island's thread evaluates its objective,
gradient and Newton matrix (the terms of :mod:`data_gen.sim.step_objective`: inertia, gravity, the
neo-Hookean cubature sum, scene and pair contact with lagged friction, through the same ``wp.func``\\ s as
the contact and elastic kernels), factorises the matrix (envelope Cholesky, the 1e-10 relative ridge where
needed), limits the update by the trust radius on contact-sphere motion, runs the Armijo backtracking search
(then plain decrease for ``EXTRA_HALVINGS`` more halvings) and tests convergence
(``alpha |dq|_M <= tol scale``; an update already that small is taken whole) exactly as ``minimise`` does:
on recorded steps it takes the same iterations and ends at the same state up to round-off (the sums run
in another order), which ``tests/sim/test_sim_fused_newton.py`` checks.

What it does not do, it hands back: an island whose Newton matrix stays indefinite after the ridge
(``minimise`` then projects every elastic block of the island) or whose objective or gradient is not finite
is marked ``NEEDS_FALLBACK``; :meth:`FusedNewton.solve` then returns None and the caller runs ``minimise``
(which projects, or raises the error that names the object). Elastic blocks that fail the near-SPD test are
projected here as in the batched path (the analytic eigensystem of
:func:`data_gen.sim.energy.elastic_kernel.projected_neo_hookean_hessian`).

On CPU warp runs the island threads one after another (deterministic); on CUDA each island is one thread,
so this path suits many small islands; large islands want the batched path.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import torch
import warp as wp

from data_gen.sim.energy.contact_kernels import (
    WarpContact,
    pair_contact_terms,
    scene_contact_terms,
    sphere_position,
)
from data_gen.sim.energy.elastic_kernel import (
    mat99d,
    neo_hookean_point,
    not_positive_definite,
    projected_neo_hookean_hessian,
)
from data_gen.sim.lapack import CholeskyDirections
from data_gen.sim.model import DofLayout, Model
from data_gen.sim.newton import ARMIJO_C, EXTRA_HALVINGS, NewtonResult, NewtonSettings, cholesky_direction
from data_gen.sim.static_scene import _FAR_M, boxes_distance, points_distance

if TYPE_CHECKING:
    from data_gen.sim.energy.pair_contact import PairSet
    from data_gen.sim.step_objective import ContactForces, StepObjective

wp.set_module_options({"enable_backward": False})  # forward only: no adjoint code to compile

_ZERO = wp.constant(wp.float64(0.0))
_ONE = wp.constant(wp.float64(1.0))

# columns of the per-island ``stats`` output
STATUS, ITERATIONS, CONVERGED, EVALUATIONS, EVALUATIONS_WITH_DERIVATIVES = 0, 1, 2, 3, 4
LINE_SEARCH_FAILURES, LINE_SEARCH_EXTENDED, TRUST_LIMITED = 5, 6, 7
NUM_STATS = 8
# island-sized work buffers are kept for this many (islands, unknowns) shapes (FusedNewton.relayout)
_SCRATCH_SHAPES = 8
# a split solve that started from soft objects' elastic matrices kept from earlier (sub)steps
# (``QualityPreset.elastic_hessian_reuse``) and still runs after this many iterations forms them anew where it is
REUSED_MATRIX_REFRESH = 6
# ``derivatives`` of _evaluate: the gradient and only the contact part of the Newton matrix
CONTACT_MATRIX_ONLY = wp.constant(2)
# STATUS values
SOLVED, NEEDS_FALLBACK = 0, 1
# STATUS of an island still iterating in FusedNewton.solve_split
RUNNING = 2


@wp.struct
class SceneArgs:
    """The static scene as the contact ``wp.func``\\ s read it."""

    has_ground: int
    box_centers: wp.array(dtype=wp.vec3d)
    box_rotations: wp.array(dtype=wp.mat33d)
    box_half_extents: wp.array(dtype=wp.vec3d)
    far_m: wp.float64
    has_points: int
    grid: wp.uint64
    static_points: wp.array(dtype=wp.vec3d)
    point_radius_m: wp.float64
    point_search_m: wp.float64


@wp.struct
class Bodies:
    """The fixed model of a set of objects (padded layout of :class:`data_gen.sim.model.Model`) and its
    island layout (:class:`data_gen.sim.model.DofLayout`)."""

    columns: wp.array(dtype=wp.int32)  # (n,) 4 H
    object_start: wp.array(dtype=wp.int32)  # (n_isl + 1,) island i's objects: island_objects[start[i]:start[i+1]]
    island_objects: wp.array(dtype=wp.int32)  # (n,) the objects sorted by island
    island_dofs: wp.array(dtype=wp.int32)  # (n_isl,) unpadded DOF count; entries beyond are padding
    flat_index: wp.array2d(dtype=wp.int32)  # (n, 3K) position in the flat island vectors
    island_size: int
    mass_matrix: wp.array3d(dtype=wp.float64)  # (n, 3K, 3K)
    mass_matrix4: wp.array3d(dtype=wp.vec4d)  # (n, 3K, 3K / 4) the same, four columns at a time
    mass_separable: int  # 1: every mass matrix is kron(I3, M_b) (its blocks coupling rows r != s are zero)
    identity_c: wp.array(dtype=wp.int32)  # (n,) 1: one cubature point with C = [I; 0] (a one-handle object)
    mass_b_sum: wp.array2d(dtype=wp.float64)  # (n, K) kg
    cub_c: wp.array4d(dtype=wp.float64)  # (n, P, K, 3)
    cub_c3: wp.array3d(dtype=wp.vec3d)  # (n, P, K) the same, one row C[a, :] at a time
    cub_volume: wp.array2d(dtype=wp.float64)  # (n, P) m^3
    mu_pa: wp.array(dtype=wp.float64)
    lam_pa: wp.array(dtype=wp.float64)
    spd_tolerance_pa: wp.array(dtype=wp.float64)
    rest: wp.array2d(dtype=wp.vec3d)  # (n, S) sphere centres at rest, m
    b: wp.array3d(dtype=wp.float64)  # (n, S, K)
    b4: wp.array3d(dtype=wp.vec4d)  # (n, S, K / 4) ``b`` four columns at a time (a one-handle object's row: b4[o, s, 0])
    radius: wp.array2d(dtype=wp.float64)  # (n, S) m
    b_norm: wp.array2d(dtype=wp.float64)  # (n, S) |b|: a sphere moves at most |Tm - Tm_n|_F |b| from its start
    extreme_count: wp.array(dtype=wp.int32)  # (n,) spheres on the hull of the object's basis rows
    extreme_index: wp.array2d(dtype=wp.int32)  # (n, S) those spheres first (Model.sphere_extreme)
    island_mass: wp.array(dtype=wp.float64)  # (n_isl,) kg
    island_radius: wp.array(dtype=wp.float64)  # (n_isl,) smallest median contact radius of the island, m


@wp.struct
class StepData:
    """One (sub)step's data: the predicted state, gravity, h^2 and the frozen contact start (the buffers of
    :class:`data_gen.sim.energy.contact_kernels.WarpContact` after ``prepare``)."""

    tm_pred: wp.array3d(dtype=wp.float64)  # (n, 3, K)
    tm_pred4: wp.array3d(dtype=wp.vec4d)  # (n, 3, K / 4) the same, four columns at a time
    tm_start: wp.array3d(dtype=wp.float64)  # (n, 3, K) the states at the start of the step
    margin: wp.array2d(dtype=wp.float64)  # (n, S) scratch: start distance to the scene minus radius, m
    pair_gap: wp.array(dtype=wp.float64)  # (pairs,) sub-step start gap (centre distance - radius sum), m; -1 outside
    moved: wp.array(dtype=wp.float64)  # (n,) scratch: |Tm - Tm_n|_F of the state being evaluated
    gravity: wp.vec3d  # m/s^2
    h2: wp.array(dtype=wp.float64)  # (n_isl,) each island's (sub)step squared, s^2
    smoothing_m: wp.array(dtype=wp.float64)  # (n,) friction smoothing of each object's (sub)step, m
    stiffness: wp.array2d(dtype=wp.float64)  # (n, S) N/m, 0 on padding
    friction_scale: wp.array2d(dtype=wp.float64)  # (n, S) mu lam, N
    start_x: wp.array2d(dtype=wp.vec3d)
    start_speed: wp.array2d(dtype=wp.float64)  # (n, S) scratch of sub-steps: sphere speeds at their start, m/s
    start_normal: wp.array2d(dtype=wp.vec3d)
    num_pairs: int
    pair_start: wp.array(dtype=wp.int32)  # (n_isl + 1,) island i's pairs: pair_order[start[i]:start[i+1]]
    pair_order: wp.array(dtype=wp.int32)  # the pairs sorted by the island of side i
    live_order: wp.array(dtype=wp.int32)  # island i's evaluated pairs: live_order[start[i]:start[i] + live[i]]
    live_count: wp.array(dtype=wp.int32)  # (n_isl,) (all of them, except in sub-steps: see _substep_start)
    obj_i: wp.array(dtype=wp.int32)
    sph_i: wp.array(dtype=wp.int32)
    obj_j: wp.array(dtype=wp.int32)
    sph_j: wp.array(dtype=wp.int32)
    frozen_x_j: wp.array(dtype=wp.vec3d)
    pair_stiffness: wp.array(dtype=wp.float64)
    radius_sum: wp.array(dtype=wp.float64)
    pair_friction_scale: wp.array(dtype=wp.float64)
    normal0: wp.array(dtype=wp.vec3d)
    x0_i: wp.array(dtype=wp.vec3d)
    x0_j: wp.array(dtype=wp.vec3d)


@wp.struct
class Work:
    """A solve's scratch and results, flat per island (n_isl N vectors, n_isl N N matrices)."""

    q: wp.array(dtype=wp.float64)  # the island states: start, then result
    trial_q: wp.array(dtype=wp.float64)  # the line search's trial point
    tm: wp.array3d(dtype=wp.float64)  # (n, 3, K) padded states of the point being evaluated
    tm4: wp.array3d(dtype=wp.vec4d)  # (n, 3, K / 4) the same, four columns at a time
    grad: wp.array(dtype=wp.float64)
    hess: wp.array(dtype=wp.float64)
    hess4: wp.array(dtype=wp.vec4d)  # ``hess`` four entries at a time (an island's rows and objects' columns are aligned)
    grad4: wp.array(dtype=wp.vec4d)  # ``grad`` likewise (every object's unknowns start at a multiple of 4)
    chol: wp.array(dtype=wp.float64)  # the envelope Cholesky factor
    dq: wp.array(dtype=wp.float64)  # the Newton update
    chol4: wp.array(dtype=wp.vec4d)  # ``chol`` read four entries at a time (see _subtract_products)
    dq4: wp.array(dtype=wp.vec4d)  # ``dq`` likewise
    first: wp.array(dtype=wp.int32)  # per row: the first column inside the envelope
    band: wp.array2d(dtype=wp.int32)  # (n, 2): the columns each object's rows hold in hess
    stats: wp.array2d(dtype=wp.int32)  # (n_isl, NUM_STATS)


@wp.func
def _load_state(bd: Bodies, q: wp.array(dtype=wp.float64), tm: wp.array3d(dtype=wp.float64), isl: int):
    """Island vector ``q`` -> padded states ``tm`` of the island's objects."""
    kp = bd.flat_index.shape[1] // 3
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        for r in range(3):
            for a in range(bd.columns[o]):
                tm[o, r, a] = q[bd.flat_index[o, r * kp + a]]


@wp.func
def _scene_distance(sc: SceneArgs, x: wp.vec3d):
    """Signed distance (m) from ``x`` to the static scene (ground, boxes, point cloud) and the scene normal."""
    sdf, n = boxes_distance(x, sc.has_ground, sc.box_centers, sc.box_rotations, sc.box_half_extents, sc.far_m)
    if sc.has_points != 0:
        sdf, n = points_distance(sc.grid, x, sc.static_points, sc.point_radius_m, sc.point_search_m, sdf, n)
    return sdf, n


@wp.func
def elastic_entry(bd: Bodies, h9: mat99d, o: int, i: int, r: int, a: int, s: int, c: int):
    """Entry ((r, a), (s, c)) of cubature point i's elastic block ``C_i^T H C_i`` (before the weight ``h^2 V``):
    ``sum_jl H[3r + j, 3s + l] C[a, j] C[c, l]``, summed in that order."""
    k_v = _ZERO
    for j in range(3):
        caj = bd.cub_c[o, i, a, j]
        for l in range(3):
            k_v = k_v + h9[r * 3 + j, s * 3 + l] * caj * bd.cub_c[o, i, c, l]
    return k_v


@wp.func
def sphere_margin(bd: Bodies, sc: SceneArgs, st: StepData, o: int, s: int):
    """How far sphere (o, s)'s start position is from touching the scene (m), or -1 when it carries a frozen
    friction force (always evaluated). The scene distance is 1-Lipschitz, so a sphere whose margin exceeds its
    largest possible motion cannot touch the scene: it contributes nothing and :func:`_evaluate` skips it."""
    m = wp.float64(-1.0)
    if st.stiffness[o, s] != _ZERO and st.friction_scale[o, s] <= _ZERO:
        sdf, n = _scene_distance(sc, st.start_x[o, s])
        m = sdf - bd.radius[o, s]
    return m


@wp.func
def _scene_margins(bd: Bodies, sc: SceneArgs, st: StepData, isl: int):
    """:func:`sphere_margin` of every sphere of the island's objects, into ``st.margin``."""
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        for s in range(bd.radius.shape[1]):
            st.margin[o, s] = sphere_margin(bd, sc, st, o, s)


@wp.func
def _step_limits(bd: Bodies, st: StepData, isl: int, tolerance: wp.float64, gravity_norm: wp.float64):
    """(convergence threshold |dq|_M, trust radius m) of island ``isl``'s step, as ``StepObjective``'s
    ``tolerance * motion_scale()`` and ``trust_radius()``: the predicted motion ``Tm_pred - Tm_n`` in the
    mass norm and as the largest sphere displacement, plus what gravity adds in the step."""
    kp = bd.flat_index.shape[1] // 3
    mass2 = _ZERO
    moved = _ZERO
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        cols = bd.columns[o]
        for r in range(3):
            c_lo, c_hi = _coupled_rows(bd, r)
            for a in range(cols):
                m_d = _ZERO
                for c_r in range(c_lo, c_hi):
                    for c in range(cols):
                        m_d = m_d + bd.mass_matrix[o, r * kp + a, c_r * kp + c] * (st.tm_pred[o, c_r, c] - st.tm_start[o, c_r, c])
                mass2 = mass2 + (st.tm_pred[o, r, a] - st.tm_start[o, r, a]) * m_d
        for e in range(bd.extreme_count[o]):  # the largest displacement is at a vertex of the rows' hull
            s = bd.extreme_index[o, e]
            u = wp.vec3d(_ZERO, _ZERO, _ZERO)
            for a in range(cols):
                u = u + bd.b[o, s, a] * wp.vec3d(st.tm_pred[o, 0, a] - st.tm_start[o, 0, a],
                                                 st.tm_pred[o, 1, a] - st.tm_start[o, 1, a],
                                                 st.tm_pred[o, 2, a] - st.tm_start[o, 2, a])  # fmt: skip
            moved = wp.max(moved, wp.length(u))
    root_mass = wp.sqrt(bd.island_mass[isl])
    h2 = st.h2[isl]
    scale = wp.sqrt(wp.max(mass2, _ZERO)) + h2 * gravity_norm * root_mass + wp.float64(1e-9) * root_mass
    trust = wp.float64(2.0) * moved + h2 * gravity_norm + bd.island_radius[isl]
    return tolerance * scale, trust


@wp.func
def _motion_bound(bd: Bodies, st: StepData, tm: wp.array3d(dtype=wp.float64), o: int, cols: int):
    """``|Tm - Tm_n|_F`` of object o: a sphere with basis row b has moved at most this times ``|b|`` (m)."""
    moved2 = _ZERO
    for r in range(3):
        for a in range(cols):
            dm = tm[o, r, a] - st.tm_start[o, r, a]
            moved2 = moved2 + dm * dm
    return wp.sqrt(moved2)


@wp.func
def _sphere_x(bd: Bodies, tm: wp.array3d(dtype=wp.float64), o: int, s: int, cols: int):
    """:func:`sphere_position` of sphere (o, s) at the states ``tm`` (m): the same sums in the same order, a
    one-handle object's with its four columns unrolled and its basis row read at once (warp's indexing, not the
    arithmetic, is what a position costs)."""
    if cols != 4:  # sphere_position's sums, the basis row read four entries at a time
        x = bd.rest[o, s]
        for a4 in range(cols // 4):
            b4 = bd.b4[o, s, a4]
            for k in range(4):
                a = 4 * a4 + k
                x = x + wp.vec3d(tm[o, 0, a], tm[o, 1, a], tm[o, 2, a]) * b4[k]
        return x
    bo = bd.b4[o, s, 0]
    x = bd.rest[o, s]
    x = x + wp.vec3d(tm[o, 0, 0], tm[o, 1, 0], tm[o, 2, 0]) * bo[0]
    x = x + wp.vec3d(tm[o, 0, 1], tm[o, 1, 1], tm[o, 2, 1]) * bo[1]
    x = x + wp.vec3d(tm[o, 0, 2], tm[o, 1, 2], tm[o, 2, 2]) * bo[2]
    x = x + wp.vec3d(tm[o, 0, 3], tm[o, 1, 3], tm[o, 2, 3]) * bo[3]
    return x


@wp.func
def _scene_sphere(bd: Bodies, sc: SceneArgs, st: StepData, tm: wp.array3d(dtype=wp.float64), o: int, s: int,
                  cols: int):  # fmt: skip
    """:func:`data_gen.sim.energy.contact_kernels.scene_sphere_terms` of sphere (o, s) with the step's and
    scene's data."""
    k = st.stiffness[o, s]
    if k == _ZERO:
        zero3 = wp.vec3d(_ZERO, _ZERO, _ZERO)
        return 0, _ZERO, zero3, wp.mat33d(), zero3
    return scene_contact_terms(
        _sphere_x(bd, tm, o, s, cols), k, bd.radius, st.friction_scale, st.start_x, st.start_normal,
        st.smoothing_m[o], sc.has_ground, sc.box_centers, sc.box_rotations, sc.box_half_extents, sc.far_m,
        sc.has_points, sc.grid, sc.static_points, sc.point_radius_m, sc.point_search_m, o, s,
    )  # fmt: skip


@wp.func
def _pair_at(bd: Bodies, st: StepData, tm: wp.array3d(dtype=wp.float64), p: int):
    """:func:`pair_terms` of candidate pair p: (active, energy, dE/dx_i, Hessian, normal j -> i, its object i,
    sphere i, columns i, object j (< 0: frozen), sphere j, columns j). The normal is zero for an inactive pair
    (no caller reads it). Most evaluated pairs do not touch: the pair's other data is read only when they may
    (a squared-distance test first, grown by a relative 1e-9: the square root and the exact test follow in
    :func:`pair_contact_terms`, so the result is the same)."""
    oi = st.obj_i[p]
    si = st.sph_i[p]
    oj = st.obj_j[p]
    sj = st.sph_j[p]
    cols_i = bd.columns[oi]
    cols_j = int(0)
    xi = _sphere_x(bd, tm, oi, si, cols_i)
    xj = wp.vec3d(_ZERO, _ZERO, _ZERO)
    if oj >= 0:
        cols_j = bd.columns[oj]
        xj = _sphere_x(bd, tm, oj, sj, cols_j)
    else:
        xj = st.frozen_x_j[p]
    radius_sum = st.radius_sum[p]
    mu_lam = st.pair_friction_scale[p]
    delta = xi - xj
    zero3 = wp.vec3d(_ZERO, _ZERO, _ZERO)
    if mu_lam <= _ZERO and wp.dot(delta, delta) > radius_sum * radius_sum * wp.float64(1.000000001):
        return 0, _ZERO, zero3, wp.mat33d(), zero3, oi, si, cols_i, oj, sj, cols_j
    active, e, g, h, normal = pair_contact_terms(
        xi, xj, st.pair_stiffness[p], radius_sum, mu_lam, st.normal0[p], st.x0_i[p], st.x0_j[p], st.smoothing_m[oi]
    )  # fmt: skip
    return active, e, g, h, normal, oi, si, cols_i, oj, sj, cols_j


@wp.func
def _pair_out_of_reach(bd: Bodies, st: StepData, p: int):
    """Whether candidate pair p cannot touch at the state being evaluated (``st.moved`` of its objects set):
    its start gap exceeds how far its spheres can have closed in since the start, ``|Tm - Tm_n|_F |b|`` each
    (a frozen side j does not move), so :func:`pair_terms` would return nothing. A pair with a frozen friction
    force touched at the start (gap < 0) and is always evaluated, as is every pair outside sub-steps (gap -1).
    A relative 1e-9 of the radius sum covers round-off."""
    gap = st.pair_gap[p]
    if gap <= _ZERO:
        return False
    oi = st.obj_i[p]
    reach = st.moved[oi] * bd.b_norm[oi, st.sph_i[p]]
    oj = st.obj_j[p]
    if oj >= 0:
        reach = reach + st.moved[oj] * bd.b_norm[oj, st.sph_j[p]]
    return gap > reach + wp.float64(1e-9) * st.radius_sum[p]


@wp.func
def _coupled_rows(bd: Bodies, r: int):
    """The rows s in [lo, hi) of Tm whose mass-matrix block couples to row r: r alone when the mass matrices
    are ``kron(I3, M_b)`` (the other blocks hold exact zeros: skipping them changes no sum), else all three."""
    if bd.mass_separable != 0:
        return r, r + 1
    return 0, 3


@wp.func
def _add_affine_elastic(grad: wp.array(dtype=wp.float64), hess: wp.array(dtype=wp.float64), n_size: int, isl: int,
                        first: int, w: wp.float64, piola: wp.mat33d, h9: mat99d):  # fmt: skip
    """The elastic gradient ``w P C^T`` and Hessian ``w C^T H C`` of a one-handle object whose single cubature
    point has ``C = [I; 0]`` (unknowns contiguous from ``first``): entry (r, a) of the gradient is ``w P[r, a]``
    and entry ((r, a), (s, c)) of the Hessian ``w H[3 r + a, 3 s + c]`` for a, c < 3, the fourth column's
    entries are zero. The general loops' sums hold one non-zero term each (the others are exact zeros), so
    this adds the same values."""
    for r in range(3):
        for a in range(3):
            fr = first + 4 * r + a
            grad[fr] = grad[fr] + w * piola[r, a]
            row = fr * n_size - isl * n_size  # as in _evaluate: unknowns are numbered across islands
            for s in range(3):
                for c in range(3):
                    fc = first + 4 * s + c
                    hess[row + fc] = hess[row + fc] + w * h9[r * 3 + a, s * 3 + c]


@wp.func
def _deformation_gradient(bd: Bodies, tm4: wp.array3d(dtype=wp.vec4d), o: int, i: int, cols: int):
    """:func:`data_gen.sim.energy.elastic_kernel.deformation_gradient` of cubature point i of object o at the
    states ``tm4`` (``Work.tm`` four columns at a time): the same sums in the same order, with a quarter of the
    array reads (warp's indexing, not the arithmetic, is what it costs)."""
    f = wp.identity(n=3, dtype=wp.float64)
    for a4 in range(cols // 4):
        t0 = tm4[o, 0, a4]
        t1 = tm4[o, 1, a4]
        t2 = tm4[o, 2, a4]
        for k in range(4):
            c = bd.cub_c3[o, i, 4 * a4 + k]
            t = t0[k]
            f[0, 0] = f[0, 0] + t * c[0]
            f[0, 1] = f[0, 1] + t * c[1]
            f[0, 2] = f[0, 2] + t * c[2]
            t = t1[k]
            f[1, 0] = f[1, 0] + t * c[0]
            f[1, 1] = f[1, 1] + t * c[1]
            f[1, 2] = f[1, 2] + t * c[2]
            t = t2[k]
            f[2, 0] = f[2, 0] + t * c[0]
            f[2, 1] = f[2, 1] + t * c[1]
            f[2, 2] = f[2, 2] + t * c[2]
    return f


@wp.func
def _point_gradient_entry(piola: wp.mat33d, r: int, c: wp.vec3d):
    """``sum_j P[r, j] C[a, j]`` for the row ``c`` = C[a, :], summed in order."""
    g_ra = _ZERO
    g_ra = g_ra + piola[r, 0] * c[0]
    g_ra = g_ra + piola[r, 1] * c[1]
    g_ra = g_ra + piola[r, 2] * c[2]
    return g_ra


@wp.func
def _add_point_gradient(grad4: wp.array(dtype=wp.vec4d), first: int, cub_c3: wp.array3d(dtype=wp.vec3d), o: int,
                        i: int, cols: int, w: wp.float64, piola: wp.mat33d):  # fmt: skip
    """Cubature point i of object o: its elastic gradient ``w P C_i^T`` (entry (r, a): ``w sum_j P[r, j] C[a, j]``)
    added to the object's unknowns, contiguous from ``first`` (entry (r, a) at ``first + r cols + a``; ``first``
    and ``cols`` multiples of 4), four entries of a row per read and write of ``grad4`` (the gradient's memory),
    each row C[a, :] read once: every entry gets the same one addition as one at a time."""
    for a4 in range(cols // 4):
        c0 = cub_c3[o, i, 4 * a4]
        c1 = cub_c3[o, i, 4 * a4 + 1]
        c2 = cub_c3[o, i, 4 * a4 + 2]
        c3 = cub_c3[o, i, 4 * a4 + 3]
        for r in range(3):
            q = (first + r * cols) // 4 + a4
            v = grad4[q]
            grad4[q] = wp.vec4d(
                v[0] + w * _point_gradient_entry(piola, r, c0), v[1] + w * _point_gradient_entry(piola, r, c1),
                v[2] + w * _point_gradient_entry(piola, r, c2), v[3] + w * _point_gradient_entry(piola, r, c3),
            )  # fmt: skip


@wp.func
def _affine_row(b: wp.array3d(dtype=wp.vec4d), o: int, s: int):
    """The four basis values of sphere (o, s) of a one-handle object (its ``[x0; 1]`` weights)."""
    return b[o, s, 0]


@wp.func
def _add_affine_gradient(grad: wp.array(dtype=wp.float64), first: int, bo: wp.vec4d, g: wp.vec3d):
    """grad[first + 4 r + a] += g[r] b[a]: a one-handle object's 12 entries (contiguous from ``first``)."""
    for r in range(3):
        for a in range(4):
            grad[first + 4 * r + a] = grad[first + 4 * r + a] + g[r] * bo[a]


@wp.func
def _add_affine_block(hess4: wp.array(dtype=wp.vec4d), n_size: int, base: int, first_o: int, bo: wp.vec4d,
                      first_p: int, bp: wp.vec4d, h: wp.mat33d):  # fmt: skip
    """hess[(r, a), (c, e)] += h[r, c] bo[a] bp[e] for the rows of one one-handle object and the columns of
    another (island-local offsets ``first_o`` / ``first_p`` of the matrix at ``base``): direct addressing, no
    index tables; each (r, a, c) adds its four entries e through ``hess4`` (the same matrix: every index here is
    a multiple of 4), the same operations as one entry at a time."""
    for r in range(3):
        for a in range(4):
            row4 = (base + (first_o + 4 * r + a) * n_size + first_p) // 4
            for c in range(3):
                w = h[r, c] * bo[a]
                v = hess4[row4 + c]
                hess4[row4 + c] = wp.vec4d(v[0] + w * bp[0], v[1] + w * bp[1], v[2] + w * bp[2], v[3] + w * bp[3])


@wp.func
def _add_gradient_direct(grad: wp.array(dtype=wp.float64), first: int, b: wp.array3d(dtype=wp.float64), o: int,
                         s: int, cols: int, g: wp.vec3d):  # fmt: skip
    """:func:`data_gen.sim.energy.contact_kernels.add_gradient` of sphere (o, s), the object's unknowns contiguous
    from ``first`` (entry (r, a) at ``first + r cols + a``): no index table."""
    for a in range(cols):
        ba = b[o, s, a]
        if ba != _ZERO:
            for r in range(3):
                fr = first + r * cols + a
                grad[fr] = grad[fr] + g[r] * ba


@wp.func
def _plus_nonzero(v: wp.float64, h: wp.float64, w: wp.float64):
    """``v + h w``, or ``v`` untouched where ``w`` is zero (as ``contact_kernels.add_block`` skips those entries)."""
    return wp.where(w != _ZERO, v + h * w, v)


@wp.func
def _add_block4(hess4: wp.array(dtype=wp.vec4d), n_size: int, matrix_base: int, b: wp.array3d(dtype=wp.float64),
                b4: wp.array3d(dtype=wp.vec4d), o: int, s: int, cols: int, first_o: int, p: int, t: int, cols_p: int,
                first_p: int, h: wp.mat33d):  # fmt: skip
    """:func:`data_gen.sim.energy.contact_kernels.add_block` (rows of sphere (o, s), columns of sphere (p, t); the
    objects' island-local first unknowns ``first_o`` / ``first_p``) through ``hess4``: each (a, r, c) adds its
    ``cols_p`` entries four at a time (every index here is a multiple of 4), each entry the same ``h[r, c] w`` and
    none where ``w`` is zero."""
    quads = cols_p // 4
    for a in range(cols):
        ba = b[o, s, a]
        if ba != _ZERO:
            for e4 in range(quads):
                bp = b4[p, t, e4]
                w = wp.vec4d(ba * bp[0], ba * bp[1], ba * bp[2], ba * bp[3])
                if w[0] != _ZERO or w[1] != _ZERO or w[2] != _ZERO or w[3] != _ZERO:
                    for r in range(3):
                        row4 = (matrix_base + (first_o + r * cols + a) * n_size + first_p) // 4 + e4
                        for c in range(3):
                            hrc = h[r, c]
                            q = row4 + c * quads
                            v = hess4[q]
                            hess4[q] = wp.vec4d(_plus_nonzero(v[0], hrc, w[0]), _plus_nonzero(v[1], hrc, w[1]),
                                                _plus_nonzero(v[2], hrc, w[2]), _plus_nonzero(v[3], hrc, w[3]))  # fmt: skip


@wp.func
def _evaluate(
    bd: Bodies,
    sc: SceneArgs,
    st: StepData,
    tm: wp.array3d(dtype=wp.float64),
    isl: int,
    derivatives: int,
    grad: wp.array(dtype=wp.float64),
    hess: wp.array(dtype=wp.float64),
    band: wp.array2d(dtype=wp.int32),
    hess4: wp.array(dtype=wp.vec4d),
    tm4: wp.array3d(dtype=wp.vec4d),
    grad4: wp.array(dtype=wp.vec4d),
):
    """Objective of island ``isl`` at the states ``tm`` (J); with ``derivatives`` its gradient and Newton
    matrix are written into the island's part of ``grad`` / ``hess`` (elastic blocks failing the near-SPD
    test projected, as :class:`StepObjective` does). Returns (value, 1 if such a block was met else 0).

    ``derivatives``: 0 the value only; 1 the gradient and the whole matrix; :data:`CONTACT_MATRIX_ONLY` the
    gradient and the contact part of the matrix only (no inertia, elastic or padding entries: the caller adds
    its kept ``M + h^2 K``, :meth:`FusedNewton.evaluate_bound`).

    ``band`` (n, 2): the island-local columns [lo, hi) that object o's rows hold, its own and those of the
    objects an active pair couples it to. The matrix is cleared only there (what the previous evaluation
    wrote: everything else is still zero) and the band is rebuilt here for the factorisation's envelope."""
    n_size = bd.island_size
    kp = bd.flat_index.shape[1] // 3
    start = isl * n_size
    base = start * n_size
    matrix_base = start * n_size  # the island's matrix in hess (``base`` is reused below)
    if derivatives != 0:
        for r in range(n_size):
            grad[start + r] = _ZERO
        for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
            o = bd.island_objects[slot]
            first_dof = bd.flat_index[o, 0] - start
            end_dof = first_dof + 3 * bd.columns[o]
            quads = (band[o, 1] - band[o, 0]) // 4  # object bands start and end at multiples of 4
            for r in range(first_dof, end_dof):
                row4 = (base + r * n_size + band[o, 0]) // 4
                for t in range(quads):
                    hess4[row4 + t] = wp.vec4d(_ZERO, _ZERO, _ZERO, _ZERO)
            band[o, 0] = first_dof
            band[o, 1] = end_dof
        if derivatives == 1:
            for r in range(bd.island_dofs[isl], n_size):  # padding: identity rows (nothing else is written there)
                hess[base + r * n_size + r] = _ONE
    h2 = st.h2[isl]
    value = _ZERO
    flagged = int(0)
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        cols = bd.columns[o]
        # inertia 1/2 d^T M d with d = tm - tm_pred, gravity -g . Tm sum_p m_p b_p (times h^2)
        for r in range(3):
            s_lo, s_hi = _coupled_rows(bd, r)
            for a in range(cols):
                row = r * kp + a
                m_d = _ZERO
                for s in range(s_lo, s_hi):  # four columns at a time (cols and kp are multiples of 4), in order
                    col4 = (s * kp) // 4
                    for c4 in range(cols // 4):
                        mm = bd.mass_matrix4[o, row, col4 + c4]
                        t4 = tm4[o, s, c4]
                        p4 = st.tm_pred4[o, s, c4]
                        m_d = m_d + mm[0] * (t4[0] - p4[0])
                        m_d = m_d + mm[1] * (t4[1] - p4[1])
                        m_d = m_d + mm[2] * (t4[2] - p4[2])
                        m_d = m_d + mm[3] * (t4[3] - p4[3])
                value = value + wp.float64(0.5) * (tm[o, r, a] - st.tm_pred[o, r, a]) * m_d
                value = value - h2 * st.gravity[r] * tm[o, r, a] * bd.mass_b_sum[o, a]
                if derivatives != 0:
                    fr = bd.flat_index[o, row]
                    grad[fr] = grad[fr] + m_d - h2 * st.gravity[r] * bd.mass_b_sum[o, a]
                    if derivatives == 1:  # (CONTACT_MATRIX_ONLY: the mass matrix is in the caller's kept base)
                        base = fr * n_size - isl * n_size
                        for s in range(s_lo, s_hi):
                            for c in range(cols):
                                fc = bd.flat_index[o, s * kp + c]
                                hess[base + fc] = hess[base + fc] + bd.mass_matrix[o, row, s * kp + c]
        # neo-Hookean cubature sum (h^2 V Psi(F_i))
        for i in range(bd.cub_volume.shape[1]):
            v = bd.cub_volume[o, i]
            if v != _ZERO:
                f = _deformation_gradient(bd, tm4, o, i, cols)
                psi, piola, h9 = neo_hookean_point(f, bd.mu_pa[o], bd.lam_pa[o], wp.where(derivatives == 1, 1, 0))
                value = value + h2 * v * psi
                if derivatives == CONTACT_MATRIX_ONLY:  # the elastic gradient only
                    _add_point_gradient(grad4, bd.flat_index[o, 0], bd.cub_c3, o, i, cols, h2 * v, piola)
                if derivatives == 1:
                    if not_positive_definite(h9, bd.spd_tolerance_pa[o]) != 0:  # as StepObjective: projected
                        flagged = int(1)
                        h9 = projected_neo_hookean_hessian(f, bd.mu_pa[o], bd.lam_pa[o])
                    w = h2 * v
                    if bd.identity_c[o] != 0:  # C = [I; 0]: the sums below reduce to P and H themselves
                        _add_affine_elastic(grad, hess, n_size, isl, bd.flat_index[o, 0], w, piola, h9)
                        continue
                    _add_point_gradient(grad4, bd.flat_index[o, 0], bd.cub_c3, o, i, cols, w, piola)
                    for r in range(3):
                        for a in range(cols):
                            fr = bd.flat_index[o, r * kp + a]
                            base = fr * n_size - isl * n_size
                            for s in range(3):
                                for c in range(cols):
                                    k_v = elastic_entry(bd, h9, o, i, r, a, s, c)
                                    fc = bd.flat_index[o, s * kp + c]
                                    hess[base + fc] = hess[base + fc] + w * k_v
        # scene contact + friction of every sphere that may touch the scene
        moved = _motion_bound(bd, st, tm, o, cols)
        st.moved[o] = moved
        for s in range(bd.radius.shape[1]):
            if st.margin[o, s] > moved * bd.b_norm[o, s]:
                continue
            active, e, g, h, normal = _scene_sphere(bd, sc, st, tm, o, s, cols)
            if active != 0:
                value = value + h2 * e
                if derivatives != 0:
                    if cols == 4:  # one handle: its 12 unknowns are contiguous
                        first_o = bd.flat_index[o, 0]
                        bo = _affine_row(bd.b4, o, s)
                        _add_affine_gradient(grad, first_o, bo, h2 * g)
                        local = first_o - start
                        _add_affine_block(hess4, n_size, matrix_base, local, bo, local, bo, h2 * h)
                    else:
                        first_o = bd.flat_index[o, 0]
                        _add_gradient_direct(grad, first_o, bd.b, o, s, cols, h2 * g)
                        local = first_o - start
                        _add_block4(hess4, n_size, matrix_base, bd.b, bd.b4, o, s, cols, local, o, s, cols, local, h2 * h)
    # pair contact + friction of the island's candidate pairs (side i on one of its objects) that may touch
    for k in range(st.pair_start[isl], st.pair_start[isl] + st.live_count[isl]):
        p = st.live_order[k]
        if _pair_out_of_reach(bd, st, p):
            continue
        active, e, g, h, normal, oi, si, cols_i, oj, sj, cols_j = _pair_at(bd, st, tm, p)
        if active != 0:
            value = value + h2 * e
            if derivatives != 0:
                if cols_i == 4 and (oj < 0 or cols_j == 4):  # one-handle objects: direct addressing
                    gs = h2 * g
                    hs = h2 * h
                    fi = bd.flat_index[oi, 0]
                    bi = _affine_row(bd.b4, oi, si)
                    _add_affine_gradient(grad, fi, bi, gs)
                    _add_affine_block(hess4, n_size, matrix_base, fi - start, bi, fi - start, bi, hs)
                    if oj >= 0:
                        fj = bd.flat_index[oj, 0]
                        bj = _affine_row(bd.b4, oj, sj)
                        _add_affine_gradient(grad, fj, bj, -gs)
                        _add_affine_block(hess4, n_size, matrix_base, fj - start, bj, fj - start, bj, hs)
                        _add_affine_block(hess4, n_size, matrix_base, fi - start, bi, fj - start, bj, -hs)
                        _add_affine_block(hess4, n_size, matrix_base, fj - start, bj, fi - start, bi, -hs)
                else:  # as add_pair_derivatives
                    gs = h2 * g
                    hs = h2 * h
                    fi = bd.flat_index[oi, 0]
                    _add_gradient_direct(grad, fi, bd.b, oi, si, cols_i, gs)
                    li = fi - start
                    _add_block4(hess4, n_size, matrix_base, bd.b, bd.b4, oi, si, cols_i, li, oi, si, cols_i, li, hs)
                    if oj >= 0:
                        fj = bd.flat_index[oj, 0]
                        _add_gradient_direct(grad, fj, bd.b, oj, sj, cols_j, -gs)
                        lj = fj - start
                        _add_block4(hess4, n_size, matrix_base, bd.b, bd.b4, oj, sj, cols_j, lj, oj, sj, cols_j, lj, hs)
                        _add_block4(hess4, n_size, matrix_base, bd.b, bd.b4, oi, si, cols_i, li, oj, sj, cols_j, lj, -hs)
                        _add_block4(hess4, n_size, matrix_base, bd.b, bd.b4, oj, sj, cols_j, lj, oi, si, cols_i, li, -hs)
                if oj >= 0:  # the cross blocks widen both objects' bands
                    first_i = bd.flat_index[oi, 0] - start
                    first_j = bd.flat_index[oj, 0] - start
                    band[oi, 0] = wp.min(band[oi, 0], first_j)
                    band[oi, 1] = wp.max(band[oi, 1], first_j + 3 * cols_j)
                    band[oj, 0] = wp.min(band[oj, 0], first_i)
                    band[oj, 1] = wp.max(band[oj, 1], first_i + 3 * cols_i)
    return value, flagged


@wp.func
def _envelope(bd: Bodies, band: wp.array2d(dtype=wp.int32), first: wp.array(dtype=wp.int32), isl: int):
    """``first[i]``: the first column of row i inside the matrix's envelope (its object's band; padded rows
    hold their diagonal only)."""
    n_size = bd.island_size
    start = isl * n_size
    for r in range(bd.island_dofs[isl], n_size):
        first[start + r] = r
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        first_dof = bd.flat_index[o, 0] - start
        for r in range(first_dof, first_dof + 3 * bd.columns[o]):
            first[start + r] = band[o, 0]


@wp.func
def _subtract_products(chol: wp.array(dtype=wp.float64), chol4: wp.array(dtype=wp.vec4d), row_a: int, row_b: int,
                       k0: int, k1: int, v0: wp.float64, v1: wp.float64):  # fmt: skip
    """``v0`` minus the products ``chol[row_a + k] chol[row_b + k]`` of the even ``k - k0``, ``v1`` minus those of
    the odd, for k in [k0, k1), each chain in increasing k: two interleaved sums, so the additions are not one
    dependent chain. Four entries are read at a time through ``chol4`` (an index costs more than a product
    here: warp's array access wraps negative indices and multiplies by the stride), so ``row_a + k0`` and
    ``row_b + k0`` must be multiples of 4: an island's rows are (its size is a multiple of 12) and so are the
    envelope's first columns (object starts). The same products in the same order as one entry at a time."""
    a0 = v0
    a1 = v1
    quads = (k1 - k0) // 4
    qa = (row_a + k0) // 4
    qb = (row_b + k0) // 4
    for t in range(quads):
        x = chol4[qa + t]
        y = chol4[qb + t]
        a0 = a0 - x[0] * y[0]
        a1 = a1 - x[1] * y[1]
        a0 = a0 - x[2] * y[2]
        a1 = a1 - x[3] * y[3]
    k = k0 + 4 * quads
    if k + 1 < k1:
        a0 = a0 - chol[row_a + k] * chol[row_b + k]
        a1 = a1 - chol[row_a + k + 1] * chol[row_b + k + 1]
        k = k + 2
    if k < k1:
        a0 = a0 - chol[row_a + k] * chol[row_b + k]
    return a0, a1


@wp.func
def _cholesky(hess: wp.array(dtype=wp.float64), chol: wp.array(dtype=wp.float64), chol4: wp.array(dtype=wp.vec4d),
              first: wp.array(dtype=wp.int32), isl: int, n_size: int, ridge: wp.float64):  # fmt: skip
    """Lower Cholesky factor of ``(H + H^T) / 2 + ridge I`` of island ``isl`` into ``chol`` (``chol4``: the same
    memory, see :func:`_subtract_products`); 1 on success.

    Envelope (profile) factorisation by rows: row i of the factor is zero left of ``first[i]`` (the
    envelope of the matrix bounds the factor's), and only entries inside the envelope are computed, read
    or stored. A pile's objects touch their neighbours only: the cost is about sum_i (i - first[i])^2 / 2
    instead of N^3 / 6. Each dot product runs as two interleaved partial sums (even and odd k), so its additions
    do not form one dependent chain (about 7 % off the whole solve on a pile)."""
    base = isl * n_size * n_size
    start = isl * n_size
    for i in range(n_size):
        fi = first[start + i]
        row_i = base + i * n_size
        for j in range(fi, i):
            row_j = base + j * n_size
            v0, v1 = _subtract_products(chol, chol4, row_i, row_j, wp.max(fi, first[start + j]), j,
                                        wp.float64(0.5) * (hess[row_i + j] + hess[row_j + i]), _ZERO)  # fmt: skip
            chol[row_i + j] = (v0 + v1) / chol[row_j + j]
        d0, d1 = _subtract_products(chol, chol4, row_i, row_i, fi, i, hess[row_i + i] + ridge, _ZERO)
        d = d0 + d1
        if not (d > _ZERO):
            return 0
        chol[base + i * n_size + i] = wp.sqrt(d)
    return 1


@wp.func
def _newton_direction(chol: wp.array(dtype=wp.float64), chol4: wp.array(dtype=wp.vec4d),
                      first: wp.array(dtype=wp.int32), grad: wp.array(dtype=wp.float64), dq: wp.array(dtype=wp.float64),
                      dq4: wp.array(dtype=wp.vec4d), isl: int, n_size: int):  # fmt: skip
    """``dq = -(L L^T)^-1 grad`` of island ``isl`` (``L`` from :func:`_cholesky`, inside the envelope; ``chol4`` and
    ``dq4`` the same memory read four entries at a time, as in :func:`_subtract_products`: the same operations in
    the same order)."""
    base = isl * n_size * n_size
    start = isl * n_size
    for i in range(n_size):
        v = -grad[start + i]
        row = base + i * n_size
        fi = first[start + i]
        quads = (i - fi) // 4
        ql = (row + fi) // 4
        qd = (start + fi) // 4
        for t in range(quads):
            lq = chol4[ql + t]
            y = dq4[qd + t]
            v = v - lq[0] * y[0]
            v = v - lq[1] * y[1]
            v = v - lq[2] * y[2]
            v = v - lq[3] * y[3]
        for k in range(fi + 4 * quads, i):
            v = v - chol[row + k] * dq[start + k]
        dq[start + i] = v / chol[row + i]
    for ii in range(n_size):  # L^T dq = y by columns of L: row i of L touches only its envelope
        i = n_size - 1 - ii
        row = base + i * n_size
        x = dq[start + i] / chol[row + i]
        dq[start + i] = x
        fi = first[start + i]
        quads = (i - fi) // 4
        ql = (row + fi) // 4
        qd = (start + fi) // 4
        for t in range(quads):
            c = chol4[ql + t]
            z = dq4[qd + t]
            dq4[qd + t] = wp.vec4d(z[0] - c[0] * x, z[1] - c[1] * x, z[2] - c[2] * x, z[3] - c[3] * x)
        for k in range(fi + 4 * quads, i):
            dq[start + k] = dq[start + k] - chol[row + k] * x


@wp.func
def _update_norms(bd: Bodies, dq: wp.array(dtype=wp.float64), isl: int):
    """(|dq|_M, largest contact-sphere displacement in m) of island ``isl``'s update ``dq``. For one-handle
    objects the unknowns are addressed directly and only the spheres on the hull of their basis rows are
    visited (:attr:`Model.sphere_extreme`): the same sums as the general loops, in the same order."""
    kp = bd.flat_index.shape[1] // 3
    mass2 = _ZERO
    motion = _ZERO
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        cols = bd.columns[o]
        f = bd.flat_index[o, 0]
        for r in range(3):
            s_lo, s_hi = _coupled_rows(bd, r)
            for a in range(cols):
                row = r * kp + a
                m_d = _ZERO
                for s in range(s_lo, s_hi):
                    for c in range(cols):  # (an object's unknowns are contiguous: (s, c) at f + s cols + c)
                        m_d = m_d + bd.mass_matrix[o, row, s * kp + c] * dq[f + s * cols + c]
                mass2 = mass2 + dq[f + r * cols + a] * m_d
        if cols == 4:  # the update's columns loaded once
            d0 = wp.vec3d(dq[f], dq[f + 4], dq[f + 8])
            d1 = wp.vec3d(dq[f + 1], dq[f + 5], dq[f + 9])
            d2 = wp.vec3d(dq[f + 2], dq[f + 6], dq[f + 10])
            d3 = wp.vec3d(dq[f + 3], dq[f + 7], dq[f + 11])
            for e in range(bd.extreme_count[o]):  # the largest |dTm b| is at a vertex of the rows' hull
                s = bd.extreme_index[o, e]
                u = wp.vec3d(_ZERO, _ZERO, _ZERO)  # the same sums, in the same order, as below
                u = u + bd.b[o, s, 0] * d0
                u = u + bd.b[o, s, 1] * d1
                u = u + bd.b[o, s, 2] * d2
                u = u + bd.b[o, s, 3] * d3
                motion = wp.max(motion, wp.length(u))
        else:
            for s in range(bd.radius.shape[1]):
                u = wp.vec3d(_ZERO, _ZERO, _ZERO)
                for a4 in range(cols // 4):  # (four basis entries per read, summed in order)
                    b4 = bd.b4[o, s, a4]
                    for k in range(4):
                        a = 4 * a4 + k
                        u = u + b4[k] * wp.vec3d(dq[f + a], dq[f + cols + a], dq[f + 2 * cols + a])
                motion = wp.max(motion, wp.length(u))
    return wp.sqrt(wp.max(mass2, _ZERO)), motion


# outcomes of :func:`_take_update`
STOPPED, HAVE_DERIVATIVES, NEED_DERIVATIVES = 0, 1, 2


@wp.func
def _take_update(bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, isl: int, thr: wp.float64, trust: wp.float64,
                 line_search_steps: int, derivatives: int, value: wp.float64):  # fmt: skip
    """The rest of one Newton iteration of island ``isl`` once its update ``wk.dq`` is known (``wk.grad`` the
    gradient and ``value`` the objective at ``wk.q``): the trust limit on sphere motion, the converged shortcut,
    the Armijo search (trials evaluated with ``derivatives``, the first one with them) and the convergence test.
    ``wk.q`` ends at the accepted point. Returns (outcome, value): :data:`STOPPED` (converged or the search
    failed: ``wk.stats`` says which), :data:`HAVE_DERIVATIVES` (the accepted first trial left its gradient and
    matrix in ``wk.grad`` / ``wk.hess``, ``value`` its objective) or :data:`NEED_DERIVATIVES`."""
    q, trial_q, tm, grad, hess, dq = wk.q, wk.trial_q, wk.tm, wk.grad, wk.hess, wk.dq
    band, stats = wk.band, wk.stats
    n_size = bd.island_size
    start = isl * n_size
    mass, motion = _update_norms(bd, dq, isl)
    alpha = wp.min(trust / wp.max(motion, wp.float64(1e-300)), _ONE)
    if alpha < _ONE:
        stats[isl, TRUST_LIMITED] += 1
    if alpha >= _ONE and mass <= thr:  # already below the tolerance: taken whole, converged
        for r in range(n_size):
            q[start + r] = q[start + r] + dq[start + r]
        stats[isl, CONVERGED] = 1
        return STOPPED, value
    slope = _ZERO
    for r in range(n_size):
        slope = slope + grad[start + r] * dq[start + r]
    accepted = int(0)
    have = int(0)
    for t in range(line_search_steps + EXTRA_HALVINGS):
        for r in range(n_size):
            trial_q[start + r] = q[start + r] + alpha * dq[start + r]
        _load_state(bd, trial_q, tm, isl)
        with_derivatives = int(0)
        if t == 0:
            with_derivatives = derivatives  # with derivatives: when taken, the next iteration starts from them
            stats[isl, EVALUATIONS_WITH_DERIVATIVES] += 1
        else:
            stats[isl, EVALUATIONS] += 1
        trial, flagged = _evaluate(bd, sc, st, tm, isl, with_derivatives, grad, hess, band, wk.hess4, wk.tm4,
                                   wk.grad4)  # fmt: skip
        ok = int(0)
        if t < line_search_steps:
            if trial <= value + wp.float64(ARMIJO_C) * alpha * slope + wp.float64(1e-14) * wp.abs(value):
                ok = int(1)
        elif trial < value:
            ok = int(1)
            stats[isl, LINE_SEARCH_EXTENDED] += 1
        if ok != 0:
            accepted = int(1)
            if with_derivatives != 0:
                have = int(1)
                value = trial
            break
        alpha = wp.float64(0.5) * alpha
    if accepted == 0:  # no decrease along dq: the island stops where it is, unconverged
        stats[isl, LINE_SEARCH_FAILURES] += 1
        return STOPPED, value
    for r in range(n_size):
        q[start + r] = trial_q[start + r]
    if alpha * mass <= thr:
        stats[isl, CONVERGED] = 1
        return STOPPED, value
    if have != 0:
        return HAVE_DERIVATIVES, value
    return NEED_DERIVATIVES, value


@wp.func
def _newton(bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, isl: int, thr: wp.float64, trust: wp.float64,
            iterations: int, line_search_steps: int):  # fmt: skip
    """Newton's method on island ``isl`` from ``wk.q`` (its part of the flat island vectors, overwritten with the
    result), convergence threshold ``thr`` (|dq|_M) and trust radius ``trust`` (m); ``wk.stats[isl]`` receives
    the status and counters. The step's start data (``st``) must be set and the scene margins computed."""
    q, tm, grad, hess, chol, dq = wk.q, wk.tm, wk.grad, wk.hess, wk.chol, wk.dq
    first, band, stats = wk.first, wk.band, wk.stats
    n_size = bd.island_size
    start = isl * n_size
    have = int(0)  # derivatives at q already in grad / hess (from an accepted first trial)
    value = _ZERO
    for k in range(NUM_STATS):
        stats[isl, k] = 0
    for it in range(iterations):
        if have == 0:
            _load_state(bd, q, tm, isl)
            value, flagged = _evaluate(bd, sc, st, tm, isl, 1, grad, hess, band, wk.hess4, wk.tm4, wk.grad4)
            stats[isl, EVALUATIONS_WITH_DERIVATIVES] += 1
        finite = int(1)
        biggest = _ZERO
        for r in range(n_size):
            if not wp.isfinite(grad[start + r]):
                finite = int(0)
            biggest = wp.max(biggest, wp.abs(hess[start * n_size + r * n_size + r]))
        if finite == 0 or not wp.isfinite(value):
            stats[isl, STATUS] = NEEDS_FALLBACK
            return
        _envelope(bd, band, first, isl)
        if _cholesky(hess, chol, wk.chol4, first, isl, n_size, _ZERO) == 0:
            if _cholesky(hess, chol, wk.chol4, first, isl, n_size, wp.float64(1e-10) * biggest) == 0:
                stats[isl, STATUS] = NEEDS_FALLBACK  # minimise projects every elastic block of the island
                return
        _newton_direction(chol, wk.chol4, first, grad, dq, wk.dq4, isl, n_size)
        stats[isl, ITERATIONS] += 1
        outcome, value = _take_update(bd, sc, st, wk, isl, thr, trust, line_search_steps, 1, value)
        if outcome == STOPPED:
            return
        have = int(0)
        if outcome == HAVE_DERIVATIVES:
            have = int(1)


@wp.func
def _solve_start(bd: Bodies, sc: SceneArgs, st: StepData, threshold: wp.array(dtype=wp.float64),
                 trust_m: wp.array(dtype=wp.float64), isl: int, limits_given: int, tolerance: wp.float64,
                 gravity_norm: wp.float64):  # fmt: skip
    """What a solve of island ``isl`` needs before its first evaluation: unless ``limits_given``, its convergence
    threshold and trust radius (:func:`_step_limits`) written to ``threshold`` / ``trust_m``; its scene margins
    (:func:`_scene_margins`)."""
    if limits_given == 0:
        thr_isl, trust_isl = _step_limits(bd, st, isl, tolerance, gravity_norm)
        threshold[isl] = thr_isl
        trust_m[isl] = trust_isl
    _scene_margins(bd, sc, st, isl)


@wp.kernel
def newton_islands_kernel(
    bd: Bodies,
    sc: SceneArgs,
    st: StepData,
    threshold: wp.array(dtype=wp.float64),
    trust_m: wp.array(dtype=wp.float64),
    iterations: int,
    line_search_steps: int,
    wk: Work,
    limits_given: int,
    tolerance: wp.float64,
    gravity_norm: wp.float64,
):
    """Island ``isl``: :func:`_newton` from ``wk.q``, after :func:`_solve_start`."""
    isl = wp.tid()
    _solve_start(bd, sc, st, threshold, trust_m, isl, limits_given, tolerance, gravity_norm)
    _newton(bd, sc, st, wk, isl, threshold[isl], trust_m[isl], iterations, line_search_steps)


@wp.kernel
def evaluate_islands_kernel(
    bd: Bodies,
    sc: SceneArgs,
    st: StepData,
    wk: Work,
    derivatives: int,
    value: wp.array(dtype=wp.float64),
    flagged: wp.array(dtype=wp.int32),
):
    """Island ``isl``'s objective at ``wk.q`` (and its gradient and Newton matrix): what the Newton kernel
    minimises, exposed for tests against :class:`data_gen.sim.step_objective.StepObjective`."""
    isl = wp.tid()
    _scene_margins(bd, sc, st, isl)
    _load_state(bd, wk.q, wk.tm, isl)
    v, f = _evaluate(bd, sc, st, wk.tm, isl, derivatives, wk.grad, wk.hess, wk.band, wk.hess4, wk.tm4, wk.grad4)
    value[isl] = v
    flagged[isl] = f


@wp.kernel
def split_start_kernel(
    bd: Bodies,
    sc: SceneArgs,
    st: StepData,
    threshold: wp.array(dtype=wp.float64),
    trust_m: wp.array(dtype=wp.float64),
    limits_given: int,
    tolerance: wp.float64,
    gravity_norm: wp.float64,
):
    """:func:`_solve_start` of island ``isl`` (:meth:`FusedNewton.solve_split`, whose first evaluation is the
    objective's)."""
    _solve_start(bd, sc, st, threshold, trust_m, wp.tid(), limits_given, tolerance, gravity_norm)


@wp.kernel
def update_islands_kernel(
    bd: Bodies,
    sc: SceneArgs,
    st: StepData,
    wk: Work,
    threshold: wp.array(dtype=wp.float64),
    trust_m: wp.array(dtype=wp.float64),
    line_search_steps: int,
    value: wp.array(dtype=wp.float64),
):
    """One Newton iteration of every :data:`RUNNING` island whose update ``wk.dq`` the host has solved for
    (:meth:`FusedNewton.solve_split`): :func:`_take_update` with trials evaluated with the contact part of the
    matrix (:data:`CONTACT_MATRIX_ONLY`), then, where the accepted point's derivatives are missing, an evaluation
    there; ``value[isl]`` becomes the objective at the new ``wk.q``. An island that stops is marked
    :data:`SOLVED`; a non-finite objective or gradient marks it :data:`NEEDS_FALLBACK`. The scene margins must
    be computed (:func:`split_start_kernel`)."""
    isl = wp.tid()
    if wk.stats[isl, STATUS] != RUNNING:
        return
    wk.stats[isl, ITERATIONS] += 1
    outcome, v = _take_update(bd, sc, st, wk, isl, threshold[isl], trust_m[isl], line_search_steps,
                              CONTACT_MATRIX_ONLY, value[isl])  # fmt: skip
    if outcome == STOPPED:
        wk.stats[isl, STATUS] = SOLVED
        return
    if outcome == NEED_DERIVATIVES:
        _load_state(bd, wk.q, wk.tm, isl)
        v, flagged = _evaluate(bd, sc, st, wk.tm, isl, CONTACT_MATRIX_ONLY, wk.grad, wk.hess, wk.band, wk.hess4,
                               wk.tm4, wk.grad4)  # fmt: skip
        wk.stats[isl, EVALUATIONS_WITH_DERIVATIVES] += 1
    value[isl] = v
    finite = int(1)
    if not wp.isfinite(v):
        finite = int(0)
    start = isl * bd.island_size
    for r in range(bd.island_size):
        if not wp.isfinite(wk.grad[start + r]):
            finite = int(0)
    if finite == 0:
        wk.stats[isl, STATUS] = NEEDS_FALLBACK


@wp.struct
class ForceOutputs:
    """The contact forces of solve results, one row per (sub)step: sphere positions (m), scene contact +
    friction forces (N) and scene normals (step, n, S); pair forces on side i (N) and normals j -> i
    (step, pairs)."""

    sphere_x: wp.array3d(dtype=wp.vec3d)
    scene_force: wp.array3d(dtype=wp.vec3d)
    scene_normal: wp.array3d(dtype=wp.vec3d)
    pair_force: wp.array2d(dtype=wp.vec3d)
    pair_normal: wp.array2d(dtype=wp.vec3d)


@wp.func
def _final_forces(bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, isl: int, out: ForceOutputs, j: int):
    """Island ``isl`` at ``wk.q`` (a solve's result; its margins still hold) into row ``j`` of ``out``: every
    sphere's position, scene force and normal, and every pair's force and normal, zero where inactive: what
    :meth:`StepObjective.forces` returns, for the recorder."""
    sphere_x, scene_force, scene_normal = out.sphere_x[j], out.scene_force[j], out.scene_normal[j]
    pair_force, pair_normal = out.pair_force[j], out.pair_normal[j]
    tm = wk.tm
    _load_state(bd, wk.q, tm, isl)
    zero = wp.vec3d(_ZERO, _ZERO, _ZERO)
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        cols = bd.columns[o]
        moved = _motion_bound(bd, st, tm, o, cols)
        st.moved[o] = moved
        for s in range(bd.radius.shape[1]):
            sphere_force(bd, sc, st, tm, o, s, cols, moved, sphere_x, scene_force, scene_normal)
    for k in range(st.pair_start[isl], st.pair_start[isl + 1]):
        pair_force[st.pair_order[k]] = zero
        pair_normal[st.pair_order[k]] = zero
    for k in range(st.pair_start[isl], st.pair_start[isl] + st.live_count[isl]):
        live_pair_force(bd, st, tm, st.live_order[k], pair_force, pair_normal)


@wp.func
def sphere_force(bd: Bodies, sc: SceneArgs, st: StepData, tm: wp.array3d(dtype=wp.float64), o: int, s: int,
                 cols: int, moved: wp.float64, sphere_x: wp.array2d(dtype=wp.vec3d),
                 scene_force: wp.array2d(dtype=wp.vec3d), scene_normal: wp.array2d(dtype=wp.vec3d)):  # fmt: skip
    """Sphere (o, s) at the states ``tm`` (its object's motion bound ``moved`` since the start): its position,
    scene force and normal (zero where it cannot touch or does not), for :func:`_final_forces`."""
    zero = wp.vec3d(_ZERO, _ZERO, _ZERO)
    sphere_x[o, s] = _sphere_x(bd, tm, o, s, cols)
    scene_force[o, s] = zero
    scene_normal[o, s] = zero
    if st.margin[o, s] <= moved * bd.b_norm[o, s]:
        active, e, g, h, normal = _scene_sphere(bd, sc, st, tm, o, s, cols)
        if active != 0:
            scene_force[o, s] = -g
            scene_normal[o, s] = normal


@wp.func
def live_pair_force(bd: Bodies, st: StepData, tm: wp.array3d(dtype=wp.float64), p: int,
                    pair_force: wp.array(dtype=wp.vec3d), pair_normal: wp.array(dtype=wp.vec3d)):  # fmt: skip
    """Live pair p at the states ``tm``: its force on side i and normal where it touches (left as they are
    where it does not: :func:`_final_forces` zeroes them first)."""
    if _pair_out_of_reach(bd, st, p):
        return
    active, e, g, h, normal, oi, si, cols_i, oj, sj, cols_j = _pair_at(bd, st, tm, p)
    if active != 0:
        pair_force[p] = -g
        pair_normal[p] = normal


@wp.kernel
def final_forces_kernel(bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, out: ForceOutputs):
    """:func:`_final_forces` of every island (one thread each) into row 0 of ``out``."""
    _final_forces(bd, sc, st, wk, wp.tid(), out, 0)


@wp.struct
class Substeps:
    """What :func:`substeps_kernel` needs beyond one solve's data: the states it advances, the per-object and
    per-pair constants from which each sub-step's start data is computed, and its outputs per sub-step."""

    tm_now: wp.array3d(dtype=wp.float64)  # (n, 3, K) padded states: the start, then after each sub-step
    tmdot: wp.array3d(dtype=wp.float64)  # (n, 3, K) their rates, 1/s
    h: wp.array(dtype=wp.float64)  # (n_isl,) each island's sub-step, s
    num_sub: wp.array(dtype=wp.int32)  # (n_isl,) each island's number of sub-steps
    scene_stiffness: wp.array(dtype=wp.float64)  # (n,) N/m per contact sphere
    friction: wp.array(dtype=wp.float64)  # (n,) Coulomb coefficients
    valid: wp.array2d(dtype=wp.int32)  # (n, S) 1 for real spheres
    pair_mu: wp.array(dtype=wp.float64)  # (pairs,) friction coefficient of each candidate pair
    tolerance: wp.float64
    gravity_norm: wp.float64
    pair_margin_m: wp.float64  # the broad phase's margin (gap below which spheres are candidates)
    iterations: int
    line_search_steps: int
    forces: ForceOutputs  # one row per sub-step, see _final_forces
    stats: wp.array3d(dtype=wp.int32)  # (sub, n_isl, NUM_STATS)
    with_sums: int  # 1: each sub-step's force sums (_force_sums) into the three arrays below
    scene_sums: wp.array3d(dtype=wp.float64)  # (sub, n, SUMS) per object
    pair_sums: wp.array3d(dtype=wp.float64)  # (sub, groups, SUMS) per group of pairs
    pair_group: wp.array(dtype=wp.int32)  # (pairs,) each pair's group, -1 for none


@wp.func
def sphere_velocity(tmdot: wp.array3d(dtype=wp.float64), b: wp.array3d(dtype=wp.float64), o: int, s: int, cols: int):
    """Velocity (m/s) of sphere (o, s) at the rates ``tmdot``: ``Tmdot b``."""
    v = wp.vec3d(_ZERO, _ZERO, _ZERO)
    for a in range(cols):
        v = v + b[o, s, a] * wp.vec3d(tmdot[o, 0, a], tmdot[o, 1, a], tmdot[o, 2, a])
    return v


@wp.func
def _sphere_v(bd: Bodies, tmdot: wp.array3d(dtype=wp.float64), o: int, s: int, cols: int):
    """:func:`sphere_velocity` of sphere (o, s) (m/s), a one-handle object's four columns unrolled as in
    :func:`_sphere_x` (the same products and sums in the same order)."""
    if cols != 4:
        return sphere_velocity(tmdot, bd.b, o, s, cols)
    bo = bd.b4[o, s, 0]
    v = wp.vec3d(_ZERO, _ZERO, _ZERO)
    v = v + bo[0] * wp.vec3d(tmdot[o, 0, 0], tmdot[o, 1, 0], tmdot[o, 2, 0])
    v = v + bo[1] * wp.vec3d(tmdot[o, 0, 1], tmdot[o, 1, 1], tmdot[o, 2, 1])
    v = v + bo[2] * wp.vec3d(tmdot[o, 0, 2], tmdot[o, 1, 2], tmdot[o, 2, 2])
    v = v + bo[3] * wp.vec3d(tmdot[o, 0, 3], tmdot[o, 1, 3], tmdot[o, 2, 3])
    return v


@wp.func
def _substep_start(bd: Bodies, sc: SceneArgs, st: StepData, ss: Substeps, isl: int):
    """The start data of island ``isl``'s next sub-step from the current states ``ss.tm_now``, as
    ``StepObjective`` (``contact_start``) and the solver (the pairs' frozen normal forces) compute it: start
    and predicted states; per sphere its start position, scene normal, stiffness and frozen ``mu k depth``;
    per pair its start positions, normal j -> i and frozen ``mu lam``. The pairs that can touch within the
    sub-step are the island's live ones (``st.live_order``): as the solver's sub-step filter
    (:meth:`data_gen.sim.contacts.BroadPhase.within_reach`), start gap below the margin plus 1.5 h times
    the sum of the two spheres' speeds (in the static scene's frame) plus what gravity adds to both."""
    h = ss.h[isl]
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        o = bd.island_objects[slot]
        cols = bd.columns[o]
        for r in range(3):
            for a in range(cols):
                st.tm_start[o, r, a] = ss.tm_now[o, r, a]
                st.tm_pred[o, r, a] = ss.tm_now[o, r, a] + h * ss.tmdot[o, r, a]
        for s in range(bd.radius.shape[1]):
            sphere_start(bd, sc, st, ss, o, s, cols)
    live = int(0)
    for m in range(st.pair_start[isl], st.pair_start[isl + 1]):  # each sphere's start position and speed
        p = st.pair_order[m]  # computed once above, read here
        if pair_start_live(st, ss, p, h) != 0:
            st.live_order[st.pair_start[isl] + live] = p
            live = live + 1
    st.live_count[isl] = live


@wp.func
def sphere_start(bd: Bodies, sc: SceneArgs, st: StepData, ss: Substeps, o: int, s: int, cols: int):
    """Sphere (o, s)'s start data for a sub-step from the current states (:func:`_substep_start`): position,
    speed, scene normal, stiffness, frozen ``mu k depth`` and scene margin."""
    k = ss.scene_stiffness[o]
    x = _sphere_x(bd, ss.tm_now, o, s, cols)
    sdf, n = _scene_distance(sc, x)
    valid = wp.float64(ss.valid[o, s])
    depth = wp.max(bd.radius[o, s] - sdf, _ZERO) * valid
    stiffness = k * valid
    friction_scale = ss.friction[o] * (k * depth)
    st.start_x[o, s] = x
    st.start_speed[o, s] = wp.length(_sphere_v(bd, ss.tmdot, o, s, cols))
    st.start_normal[o, s] = n
    st.stiffness[o, s] = stiffness
    st.friction_scale[o, s] = friction_scale
    margin = wp.float64(-1.0)  # as _scene_margins, from the same distance
    if stiffness != _ZERO and friction_scale <= _ZERO:
        margin = sdf - bd.radius[o, s]
    st.margin[o, s] = margin


@wp.func
def pair_start_live(st: StepData, ss: Substeps, p: int, h: wp.float64):
    """Pair p's start data for a sub-step of ``h`` s (:func:`_substep_start`), from its spheres' start
    positions and speeds: 1 where it can touch within the sub-step (and then its start positions, normal
    j -> i, frozen ``mu lam`` and start gap), else 0 (nothing written)."""
    reach_g = wp.float64(2.0) * ss.gravity_norm * h * h + ss.pair_margin_m
    oi = st.obj_i[p]
    xi = st.start_x[oi, st.sph_i[p]]
    speeds = st.start_speed[oi, st.sph_i[p]]
    oj = st.obj_j[p]
    xj = wp.vec3d(_ZERO, _ZERO, _ZERO)
    if oj >= 0:
        xj = st.start_x[oj, st.sph_j[p]]
        speeds = speeds + st.start_speed[oj, st.sph_j[p]]
    else:
        xj = st.frozen_x_j[p]
    delta = xi - xj
    reach = wp.float64(1.5) * h * speeds + reach_g
    far = (st.radius_sum[p] + reach) * wp.float64(1.000000001)
    if wp.dot(delta, delta) >= far * far:
        return 0  # beyond the test below with room for round-off: the same decision without a square root
    dist = wp.max(wp.length(delta), wp.float64(1.0e-12))
    if dist - st.radius_sum[p] >= reach:
        return 0  # cannot touch within the sub-step
    lam = st.pair_stiffness[p] * wp.max(st.radius_sum[p] - dist, _ZERO)
    st.x0_i[p] = xi
    st.x0_j[p] = xj
    st.normal0[p] = delta / dist
    mu_lam = _ZERO
    if lam > _ZERO:
        mu_lam = ss.pair_mu[p] * lam
    st.pair_friction_scale[p] = mu_lam
    st.pair_gap[p] = dist - st.radius_sum[p]  # < 0 for a pair with a frozen friction force (lam > 0)
    return 1


# per-object and per-object-pair sums of a sub-step's contact forces (what a step's statistics are made of)
SUMS = 10  # force (3, N), force-weighted position (3, N m), force-weighted normal (3, N), force magnitude (1, N)


@wp.func
def _force_sums(bd: Bodies, st: StepData, ss: Substeps, isl: int, j: int):
    """Row ``j`` of island ``isl``'s force sums, from the forces :func:`_final_forces` just wrote: per object,
    over its real spheres in order, the scene force f (N), |f| x (N m), |f| n (N, n the scene normal) and |f|
    (N); per group of pairs (``ss.pair_group``: one object pair's candidates, all on this island's side i), over
    its pairs with a force in row order, the force on side i, |f| (x_i + x_j) / 2, |f| n (n from j to i) and
    |f|."""
    for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):
        object_scene_sums(ss, bd.island_objects[slot], j)
    # the island's pairs with a force, in row order: live ones only (_final_forces leaves the others at zero);
    # the group sums start at zero (FusedNewton.solve_substeps clears them before the launch)
    for k in range(st.pair_start[isl], st.pair_start[isl] + st.live_count[isl]):
        add_pair_sums(st, ss, st.live_order[k], j)


@wp.func
def object_scene_sums(ss: Substeps, o: int, j: int):
    """Row ``j`` of object o's scene force sums (:func:`_force_sums`), over its real spheres in order."""
    forces = ss.forces
    total = wp.vec3d(_ZERO, _ZERO, _ZERO)
    moment = wp.vec3d(_ZERO, _ZERO, _ZERO)
    normal = wp.vec3d(_ZERO, _ZERO, _ZERO)
    weight = _ZERO
    for s in range(ss.valid.shape[1]):
        f = forces.scene_force[j, o, s]
        # most spheres carry no force: adding their zeros would leave every sum as it is (each starts at +0,
        # and a sum of nonzero terms is never -0), so they are skipped before the square root and the reads
        if ss.valid[o, s] != 0 and (f[0] != _ZERO or f[1] != _ZERO or f[2] != _ZERO):
            m = wp.length(f)
            total = total + f
            moment = moment + m * forces.sphere_x[j, o, s]
            normal = normal + m * forces.scene_normal[j, o, s]
            weight = weight + m
    for r in range(3):
        ss.scene_sums[j, o, r] = total[r]
        ss.scene_sums[j, o, 3 + r] = moment[r]
        ss.scene_sums[j, o, 6 + r] = normal[r]
    ss.scene_sums[j, o, 9] = weight


@wp.func
def add_pair_sums(st: StepData, ss: Substeps, p: int, j: int):
    """Live pair p's force, if any, added to row ``j`` of its group's sums (:func:`_force_sums`), atomically
    (one thread adding: the plain sums; several: their order is the adds')."""
    forces = ss.forces
    f = forces.pair_force[j, p]
    m = wp.length(f)
    g = ss.pair_group[p]
    if m > _ZERO and g >= 0:
        x_i = forces.sphere_x[j, st.obj_i[p], st.sph_i[p]]
        x_j = st.frozen_x_j[p]
        if st.obj_j[p] >= 0:
            x_j = forces.sphere_x[j, st.obj_j[p], st.sph_j[p]]
        middle = (m * wp.float64(0.5)) * (x_i + x_j)
        n_m = m * forces.pair_normal[j, p]
        for r in range(3):
            wp.atomic_add(ss.pair_sums, j, g, r, f[r])
            wp.atomic_add(ss.pair_sums, j, g, 3 + r, middle[r])
            wp.atomic_add(ss.pair_sums, j, g, 6 + r, n_m[r])
        wp.atomic_add(ss.pair_sums, j, g, 9, m)


@wp.kernel
def substeps_kernel(bd: Bodies, sc: SceneArgs, st: StepData, wk: Work, ss: Substeps):
    """Island ``isl`` through its ``ss.num_sub[isl]`` implicit Euler sub-steps of ``ss.h[isl]`` (islands may
    differ: rows beyond an island's count are left alone): each starts from the previous
    one's result (:func:`_substep_start`), is solved by :func:`_newton` (its own threshold and trust radius)
    and leaves its contact forces in the outputs (:func:`_final_forces`), their sums (:func:`_force_sums`, with
    ``ss.with_sums``) and its counters in ``ss.stats``;
    ``ss.tm_now`` / ``ss.tmdot`` end at the last one's state and rate. A sub-step that needs ``minimise``
    stops the island there (its status in ``ss.stats``)."""
    isl = wp.tid()
    kp = bd.flat_index.shape[1] // 3
    h = ss.h[isl]
    for j in range(ss.num_sub[isl]):
        _substep_start(bd, sc, st, ss, isl)
        thr, trust = _step_limits(bd, st, isl, ss.tolerance, ss.gravity_norm)
        for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):  # q0 = the predicted states
            o = bd.island_objects[slot]
            for r in range(3):
                for a in range(bd.columns[o]):
                    wk.q[bd.flat_index[o, r * kp + a]] = st.tm_pred[o, r, a]
        _newton(bd, sc, st, wk, isl, thr, trust, ss.iterations, ss.line_search_steps)  # (margins: _substep_start)
        for k in range(NUM_STATS):
            ss.stats[j, isl, k] = wk.stats[isl, k]
        if wk.stats[isl, STATUS] != SOLVED:
            return
        _final_forces(bd, sc, st, wk, isl, ss.forces, j)
        if ss.with_sums != 0:
            _force_sums(bd, st, ss, isl, j)
        for slot in range(bd.object_start[isl], bd.object_start[isl + 1]):  # wk.tm holds the result
            o = bd.island_objects[slot]
            for r in range(3):
                for a in range(bd.columns[o]):
                    ss.tmdot[o, r, a] = (wk.tm[o, r, a] - st.tm_start[o, r, a]) / h
                    ss.tm_now[o, r, a] = wk.tm[o, r, a]


class SubstepResult:
    """What :meth:`FusedNewton.solve_substeps` returns: the padded states and rates (n, 3, K) after the last
    sub-step, the Newton iterations (sub, n_isl), the counters summed over sub-steps and islands, and per
    sub-step the contact forces at its result (views of buffers the next call overwrites).

    The forces stacked over the sub-steps: ``scene_force_n``, ``scene_normals``, ``sphere_positions_m``
    (J, n, S, 3) and ``pair_force_i_n``, ``pair_normals`` (J, P, 3); with pair groups, per sub-step the sums of
    :data:`SUMS` per object slot ``scene_sums`` (J, n, 10) and per group ``pair_sums`` (J, G, 10), else None.
    ``forces``: the same per sub-step, as :class:`ContactForces`. A :meth:`part` gathers each of these only when
    it is read (a step's statistics read three of them, its per-sphere records two more, every few steps)."""

    _STACKED = ("scene_force_n", "scene_normals", "sphere_positions_m", "pair_force_i_n", "pair_normals",
                "scene_sums", "pair_sums")  # fmt: skip

    def __init__(self, tm: torch.Tensor, tmdot: torch.Tensor, iterations: torch.Tensor, counters: dict[str, int],
                 scene_force_n: torch.Tensor, scene_normals: torch.Tensor, sphere_positions_m: torch.Tensor,
                 pair_force_i_n: torch.Tensor, pair_normals: torch.Tensor, scene_sums: torch.Tensor | None = None,
                 pair_sums: torch.Tensor | None = None) -> None:  # fmt: skip
        self.tm, self.tmdot, self.iterations, self.counters = tm, tmdot, iterations, counters
        self._whole = dict(zip(self._STACKED, (scene_force_n, scene_normals, sphere_positions_m, pair_force_i_n,
                                               pair_normals, scene_sums, pair_sums)))  # fmt: skip
        self._select: tuple[torch.Tensor, int, int, int, tuple[int, int] | None] | None = None  # a part's rows
        self._gathered: dict[str, torch.Tensor | None] = {}

    def _field(self, name: str) -> torch.Tensor | None:
        whole = self._whole[name]
        if self._select is None or whole is None:
            return whole
        if name not in self._gathered:
            slots, p0, p1, num_sub, groups = self._select
            if name in ("pair_force_i_n", "pair_normals"):
                value = whole[:num_sub, p0:p1]
            elif name == "pair_sums":
                value = None if groups is None else whole[:num_sub, groups[0]:groups[1]]
            else:  # per object slot
                value = whole[:num_sub, slots]
            self._gathered[name] = value
        return self._gathered[name]

    scene_force_n = property(lambda self: self._field("scene_force_n"))
    scene_normals = property(lambda self: self._field("scene_normals"))
    sphere_positions_m = property(lambda self: self._field("sphere_positions_m"))
    pair_force_i_n = property(lambda self: self._field("pair_force_i_n"))
    pair_normals = property(lambda self: self._field("pair_normals"))
    scene_sums = property(lambda self: self._field("scene_sums"))
    pair_sums = property(lambda self: self._field("pair_sums"))

    def scene_force_at(self, j: int) -> torch.Tensor:
        """Sub-step ``j``'s scene forces (n, S, 3) N of this result's object slots (one row gathered, not all)."""
        if self._select is None or "scene_force_n" in self._gathered:
            return self.scene_force_n[j]
        return self._whole["scene_force_n"][j, self._select[0]]

    @property
    def num_substeps(self) -> int:
        return self.iterations.shape[0]

    @property
    def forces(self) -> list[ContactForces]:
        """Per sub-step its :class:`ContactForces` (views of the stacked rows)."""
        from data_gen.sim.step_objective import ContactForces  # step_objective imports this module

        stacked = (self.scene_force_n, self.scene_normals, self.sphere_positions_m, self.pair_force_i_n,
                   self.pair_normals)  # fmt: skip
        return [ContactForces(*(t[j] for t in stacked)) for j in range(self.num_substeps)]

    def part(self, slots: torch.Tensor, rows: tuple[int, int], num_sub: int,
             groups: tuple[int, int] | None = None) -> SubstepResult:  # fmt: skip
        """The result of the objects in solve slots ``slots`` (in that order), the pairs in rows ``rows`` and the
        pair groups ``groups`` (first, end) over their first ``num_sub`` sub-steps (the whole result when that is
        all of it, in order). ``iterations`` and ``counters`` stay those of the whole launch."""
        p0, p1 = rows
        n = self.tm.shape[0]
        pair_sums = self._whole["pair_sums"]
        whole_groups = groups is None or pair_sums is None or groups == (0, pair_sums.shape[1])
        if (self._select is None and whole_groups
                and (p0, p1, num_sub) == (0, self._whole["pair_force_i_n"].shape[1], self.num_substeps)
                and torch.equal(slots, torch.arange(n, dtype=slots.dtype))):  # fmt: skip
            return self
        if self._select is not None:
            raise ValueError("SubstepResult.part: a part cannot be split again")
        out = SubstepResult(self.tm[slots], self.tmdot[slots], self.iterations[:num_sub], self.counters,
                            *(self._whole[name] for name in self._STACKED))  # fmt: skip
        out._select = (slots, p0, p1, num_sub, groups)
        return out


def scene_args(scene, device) -> SceneArgs:
    """:class:`SceneArgs` of a :class:`~data_gen.sim.static_scene.SceneDistance`'s static scene on a warp
    ``device`` (its boxes and its points' hash grid built there once)."""
    sc = SceneArgs()
    sc.has_ground = int(scene.ground)
    sc.box_centers, sc.box_rotations, sc.box_half_extents = scene._device_boxes(device)
    sc.far_m = wp.float64(_FAR_M)
    if scene.points is not None:
        grid, static_points = scene._device_points(device)
        sc.has_points, sc.grid, sc.static_points = 1, grid.id, static_points
        sc.point_radius_m, sc.point_search_m = wp.float64(scene.points.radius_m), wp.float64(scene.points.search_m)
    else:
        sc.has_points, sc.grid = 0, wp.uint64(0)
        sc.static_points = wp.zeros(0, dtype=wp.vec3d, device=device)
        sc.point_radius_m, sc.point_search_m = wp.float64(0.0), wp.float64(1.0)
    return sc


def _identity_c(model: Model) -> torch.Tensor:
    """(n,) bool: objects whose elastic energy is one cubature point with ``C = [I; 0]`` exactly (one handle:
    ``F = I + Tm[:, :3]``), assembled by :func:`_add_affine_elastic`."""
    n, p, k, _ = model.cub_c.shape
    device = model.cub_c.device
    if k < 4:
        return torch.zeros(n, dtype=torch.bool, device=device)
    c = torch.zeros(k, 3, dtype=model.cub_c.dtype, device=device)
    c[:3] = torch.eye(3, dtype=c.dtype, device=device)
    one_point = (model.cub_volume_m3[:, 1:] == 0).all(1) if p > 1 else torch.ones(n, dtype=torch.bool, device=device)
    handles = model.num_handles.to(device)
    return (handles == 1) & one_point & (model.cub_c[:, 0] == c).all(2).all(1)


def _mass_separable(model: Model) -> bool:
    """Whether every mass matrix (n, 3K, 3K) is ``kron(I3, M_b)``: its blocks coupling rows r != s of Tm are
    exact zeros (what :func:`_coupled_rows` skips)."""
    n, size, _ = model.mass_matrix.shape
    k = size // 3
    blocks = model.mass_matrix.reshape(n, 3, k, 3, k)
    off = ~torch.eye(3, dtype=torch.bool, device=blocks.device)[None, :, None, :, None].expand_as(blocks)
    return bool((blocks[off] == 0).all())


def _quads(t: torch.Tensor) -> torch.Tensor:
    """A contiguous tensor whose last dimension is a multiple of 4, viewed as (..., last / 4, 4): the memory the
    kernels read four entries at a time (``wp.vec4d``)."""
    if t.shape[-1] % 4:
        raise ValueError(f"last dimension {t.shape[-1]} is not a multiple of 4 (4 columns per handle)")
    return t.view(*t.shape[:-1], t.shape[-1] // 4, 4)


def _wp(t: torch.Tensor, dtype=None) -> wp.array:
    return wp.from_torch(t.contiguous(), dtype=dtype)


class FusedNewton:
    """:func:`data_gen.sim.newton.minimise` for a fixed set of objects and islands in one warp launch per
    solve (see the module docstring). Built once per group of islands next to its
    :class:`data_gen.sim.step_objective.SolveWorkspace`, whose contact buffers it reads."""

    def __init__(self, model: Model, layout: DofLayout, contact: WarpContact, island_mass_kg: torch.Tensor,
                 min_median_radius_m: torch.Tensor) -> None:  # fmt: skip
        wp.init()
        self.contact = contact
        self.device = contact.device
        self._island_scratch: OrderedDict[tuple[int, int], tuple[dict, dict]] = OrderedDict()
        n = model.num_objects
        i32 = torch.int32
        self._model = model
        self._keep = {
            "columns": (4 * model.num_handles).to(i32),
            "mass_matrix": model.mass_matrix, "mass_b_sum": model.mass_b_sum, "cub_c": model.cub_c,
            "cub_volume": model.cub_volume_m3, "mu_pa": model.mu_pa, "lam_pa": model.lam_pa,
            "spd_tolerance_pa": model.spd_tolerance_pa, "rest": model.sphere_rest_m, "b": model.sphere_b,
            "radius": model.sphere_radius_m, "b_norm": model.sphere_b.norm(dim=2),
            "extreme_count": model.sphere_extreme.sum(1).to(i32),
            # stable sort: each object's hull spheres first, in index order
            "extreme_index": torch.sort((~model.sphere_extreme).to(i32), dim=1, stable=True).indices.to(i32),
        }  # fmt: skip
        self._keep["identity_c"] = _identity_c(model).to(i32)
        substep_constants = {"friction": model.friction, "valid": model.sphere_valid.to(i32)}
        self._keep = {key: value.contiguous() for key, value in self._keep.items()}
        bd = Bodies()
        for key, value in self._keep.items():
            setattr(bd, key, _wp(value, wp.vec3d if key == "rest" else None))
        bd.b4 = _wp(_quads(self._keep["b"]), wp.vec4d)
        bd.mass_matrix4 = _wp(_quads(self._keep["mass_matrix"]), wp.vec4d)
        bd.cub_c3 = _wp(self._keep["cub_c"], wp.vec3d)
        self._keep.update({key: value.contiguous() for key, value in substep_constants.items()})
        bd.mass_separable = int(_mass_separable(model))
        self.bodies = bd
        self.scene = scene_args(contact.scene, self.device)
        like = dict(dtype=model.mass_kg.dtype, device=model.mass_kg.device)
        self.tm = torch.zeros(n, 3, model.columns, **like)
        self.tm_pred = torch.zeros_like(self.tm)
        self.tm_start = torch.zeros_like(self.tm)
        self.margin = torch.zeros_like(model.sphere_radius_m)
        self.moved = torch.zeros(n, **like)  # the kernels' per-object motion bound (scratch)
        self.start_speed = torch.zeros_like(model.sphere_radius_m)  # sub-step sphere speeds (scratch), m/s
        # (n, 2) columns each object's rows hold in hess (the kernels keep it: hess is cleared only there)
        self.band = torch.zeros(n, 2, dtype=i32, device=model.mass_kg.device)
        # forces() output: one row of ForceOutputs (the pair rows are bound with the pair buffers)
        self._sphere_rows = [torch.zeros(1, n, model.sphere_radius_m.shape[1], 3, **like) for _ in range(3)]
        self.sphere_x, self.scene_force, self.scene_normals = (t[0] for t in self._sphere_rows)
        self._forces = ForceOutputs()
        self._forces.sphere_x, self._forces.scene_force, self._forces.scene_normal = (
            _wp(t, wp.vec3d) for t in self._sphere_rows
        )
        self.work = Work()
        self.work.tm, self.work.band = _wp(self.tm), _wp(self.band)
        self.work.tm4 = _wp(_quads(self.tm), wp.vec4d)
        self._step = StepData()
        self.smoothing = torch.zeros(n, **like)  # friction smoothing (m) per object
        self._step.smoothing_m = _wp(self.smoothing)
        self._step.moved = _wp(self.moved)
        self._step.start_speed = _wp(self.start_speed)
        self._pair_capacity = -1
        self._gravity_key: tuple[torch.Tensor, int] | None = None  # the gravity tensor (and version) bound last
        self._substeps: Substeps | None = None
        self._bound_objective: StepObjective | None = None  # evaluate_bound: the objective whose step is bound
        self._bound_step: StepData | None = None
        # evaluate_bound's launches, packed once per mode (0 / CONTACT_MATRIX_ONLY), and solve_split's, once per
        # line search length, and replayed: warp packs a struct argument by reference (a new objective's step data,
        # written into the same StepData, is what the replay reads), an array by value; re-packed after a
        # regrouping (relayout: other island-sized arrays, and the launch size and outputs where the count changes)
        self._bound_launches: dict[int | tuple, wp.Launch] = {}
        self._value = torch.zeros(layout.num_islands, dtype=model.mass_kg.dtype, device=model.mass_kg.device)
        self._flagged = torch.zeros(layout.num_islands, dtype=torch.int32, device=model.mass_kg.device)
        self._value_wp, self._flagged_wp = _wp(self._value), _wp(self._flagged)
        self._directions = CholeskyDirections()  # solve_split's host factorisations (LAPACK in place)
        self.device_newton = None  # the solver's DeviceNewton on this workspace, kept with it (device_newton=True)
        self.relayout(layout, island_mass_kg, min_median_radius_m)
        # solve_substeps: the states it advances and the per-object scene stiffness, N/m
        self.tm_now, self.tmdot = torch.zeros_like(self.tm), torch.zeros_like(self.tm)
        self.scene_k = torch.zeros(n, **like)

    def relayout(self, layout: DofLayout, island_mass_kg: torch.Tensor, min_median_radius_m: torch.Tensor) -> None:
        """The same objects (in the same order) grouped into other islands: ``layout`` with its islands' masses
        (kg) and smallest median contact radii (m). The per-object buffers and the contact object's pair buffers
        are kept; the island-sized ones are rebuilt, or taken cleared from an earlier grouping of the same shape (a
        grouping costs a fraction of a new workspace)."""
        n_isl, size = layout.num_islands, layout.island_size
        self.shape = (n_isl, size)
        self.layout_version = getattr(self, "layout_version", -1) + 1  # (what copies of the layout are keyed by)
        i32 = torch.int32
        counts = torch.bincount(layout.island, minlength=n_isl)
        object_start = torch.zeros(n_isl + 1, dtype=torch.int64)
        object_start[1:] = torch.cumsum(counts, 0)
        dofs = torch.zeros(n_isl, dtype=torch.int64).index_add_(0, layout.island, 12 * self._model.num_handles)
        islands = {
            "object_start": object_start.to(i32), "island_objects": torch.sort(layout.island, stable=True).indices.to(i32),
            "island_dofs": dofs.to(i32), "flat_index": layout.flat_index.to(i32), "island_mass": island_mass_kg,
            "island_radius": min_median_radius_m,
        }  # fmt: skip
        bd = self.bodies
        for key, value in islands.items():
            self._keep[key] = value.contiguous()
            setattr(bd, key, _wp(self._keep[key]))
        bd.island_size = int(size)
        scratch, arrays = self._island_scratch_of(n_isl, size)
        for name, tensor in scratch.items():
            setattr(self, name, tensor)
        self.band.zero_()  # the new matrix is zero everywhere
        self.island_of = layout.island
        wk = self.work
        wk.q, wk.trial_q, wk.grad, wk.hess, wk.chol, wk.dq = (
            arrays[name] for name in ("q", "trial_q", "grad", "hess", "chol", "dq")
        )
        wk.first, wk.stats = arrays["first"], arrays["stats"]
        wk.chol4, wk.dq4, wk.hess4, wk.grad4 = arrays["chol4"], arrays["dq4"], arrays["hess4"], arrays["grad4"]
        self._limits = [arrays["threshold"], arrays["trust"]]
        self._bound_launches.clear()  # solve_split's launch holds the limits' arrays (packed by value)
        st = self._step
        st.live_count, st.h2 = arrays["live_count"], arrays["h2"]
        if self._pair_capacity >= 0:  # pair buffers already bound: their island order and starts anew
            st.pair_start = arrays["pair_start"]
        self._identity_pairs = 0
        if self._substeps is not None:  # the sub-step buffers stay; their per-island ones are rebound
            self._bind_island_substeps(self._substeps, self.sub_stats.shape[0])

    def _island_scratch_of(self, n_isl: int, size: int) -> tuple[dict[str, torch.Tensor], dict[str, wp.array]]:
        """The island-sized work buffers of ``n_isl`` islands of ``size`` unknowns, all zero as if new, and their
        warp views: kept per shape for the ``_SCRATCH_SHAPES`` shapes used last (a pile's regroupings repeat
        a few shapes; a new warp view costs more than clearing a buffer)."""
        key = (n_isl, size)
        entry = self._island_scratch.get(key)
        if entry is not None:
            self._island_scratch.move_to_end(key)
            for tensor in entry[0].values():
                tensor.zero_()
            return entry
        like = dict(dtype=self.tm.dtype, device=self.tm.device)
        ints = dict(dtype=torch.int32, device=self.tm.device)
        scratch = {
            "q": torch.zeros(n_isl * size, **like), "trial_q": torch.zeros(n_isl * size, **like),
            "dq": torch.zeros(n_isl * size, **like), "grad": torch.zeros(n_isl * size, **like),
            "hess": torch.zeros(n_isl * size * size, **like), "chol": torch.zeros(n_isl * size * size, **like),
            "pair_start": torch.zeros(n_isl + 1, **ints), "live_count": torch.zeros(n_isl, **ints),
            "first": torch.zeros(n_isl * size, **ints), "stats": torch.zeros(n_isl, NUM_STATS, **ints),
            "threshold": torch.zeros(n_isl, **like), "trust": torch.zeros(n_isl, **like),
            "h2": torch.zeros(n_isl, **like),  # s^2 per island
            "sub_h": torch.zeros(n_isl, **like), "sub_count": torch.zeros(n_isl, **ints),  # sub-steps (s), count
        }  # fmt: skip
        if size % 4:
            raise ValueError(f"island size {size}: the kernels read the factor four entries at a time and need a multiple "
                             "of 4 (every object has 12 unknowns per handle)")
        views = {name: _wp(tensor) for name, tensor in scratch.items()}
        views["chol4"], views["dq4"], views["hess4"], views["grad4"] = (
            _wp(scratch[name].view(-1, 4), wp.vec4d) for name in ("chol", "dq", "hess", "grad")
        )
        entry = (scratch, views)
        self._island_scratch[key] = entry
        while len(self._island_scratch) > _SCRATCH_SHAPES:
            self._island_scratch.popitem(last=False)
        return entry

    def _step_data(self, objective: StepObjective) -> StepData:
        """The step's data for the kernels: ``objective``'s states, gravity and h^2, and the contact data of
        its last ``prepare`` (pairs ordered by island)."""
        if objective.contact is not self.contact:
            raise ValueError("the objective's contact buffers are not this FusedNewton's (another workspace)")
        self.tm_pred.copy_(objective.tm_pred)
        self.tm_start.copy_(objective.tm_n)
        st = self._bind_step(objective.gravity, objective.h2)
        self.pair_gap.fill_(-1.0)  # every pair evaluated (no start gaps: only sub-steps compute them)
        return st

    def _bind_step(self, gravity_m_s2: torch.Tensor, h2: float) -> StepData:
        """:class:`StepData` over this workspace's buffers, with gravity, h^2 and the contact data of the last
        ``prepare`` (pairs ordered by island); the states ``tm_pred`` / ``tm_start`` are the caller's."""
        c = self.contact
        st = self._step
        if self._pair_capacity != c.pair_capacity:  # the contact object's pair buffers were (re)allocated
            c_ints, c_vec, c_scal = c.pair_arrays()
            self._pair_capacity = c.pair_capacity
            st.stiffness, st.friction_scale = _wp(c.stiffness), _wp(c.friction_scale)
            st.start_x, st.start_normal = _wp(c.start_x, wp.vec3d), _wp(c.start_normals, wp.vec3d)
            st.tm_pred, st.tm_start, st.margin = _wp(self.tm_pred), _wp(self.tm_start), _wp(self.margin)
            st.tm_pred4 = _wp(_quads(self.tm_pred), wp.vec4d)
            st.obj_i, st.sph_i, st.obj_j, st.sph_j = (_wp(t) for t in c_ints)
            st.frozen_x_j, st.normal0, st.x0_i, st.x0_j = (_wp(t, wp.vec3d) for t in c_vec)
            st.pair_stiffness, st.radius_sum, st.pair_friction_scale = (_wp(t) for t in c_scal)
            self._obj_i = c_ints[0]
            self.pair_order = torch.zeros_like(c_ints[0])
            pair_rows = [torch.zeros(1, len(c_ints[0]), 3, dtype=self.q.dtype, device=self.q.device) for _ in "fn"]
            self.pair_force, self.pair_normals = pair_rows[0][0], pair_rows[1][0]
            self._forces.pair_force, self._forces.pair_normal = (_wp(t, wp.vec3d) for t in pair_rows)
            self._pair_rows = pair_rows
            self._identity_pairs = 0  # pair_order[:k] = 0..k-1 for this k (one-island solves)
            st.pair_start, st.pair_order = _wp(self.pair_start), _wp(self.pair_order)
            self.live_order = torch.zeros_like(c_ints[0])
            self._pair_order_wp, self._live_order_wp = st.pair_order, _wp(self.live_order)
            self.pair_mu = torch.zeros(len(c_ints[0]), dtype=self.q.dtype, device=self.q.device)
            self.pair_gap = torch.full_like(self.pair_mu, -1.0)  # -1: always evaluated
            st.pair_gap = _wp(self.pair_gap)
            self._substeps = None  # (re)bound to the new pair buffers on next use
        key = (gravity_m_s2, gravity_m_s2._version)  # the solver passes the same tensor every step
        if self._gravity_key is None or self._gravity_key[0] is not key[0] or self._gravity_key[1] != key[1]:
            g = gravity_m_s2.tolist()
            st.gravity = wp.vec3d(g[0], g[1], g[2])
            self._gravity_norm = float(gravity_m_s2.norm())
            self._gravity_key = key
        self.h2.fill_(h2)
        self.smoothing.fill_(c.smoothing_m)
        p = int(c.num_pairs)
        st.num_pairs = p
        if self.shape[0] == 1:  # one island: every pair, in order
            if p > self._identity_pairs:
                self.pair_order[:p] = torch.arange(p, dtype=torch.int32)
                self._identity_pairs = p
            self.pair_start[1] = p
            self.live_count[0] = p
        else:
            island = self.island_of[self._obj_i[:p].long()]
            self.pair_order[:p] = torch.sort(island, stable=True).indices.to(torch.int32)
            self.pair_start[1:] = torch.cumsum(torch.bincount(island, minlength=self.shape[0]), 0)
            self.live_count.copy_(self.pair_start[1:] - self.pair_start[:-1])
            self._identity_pairs = 0
        st.live_order = self._pair_order_wp  # every pair is evaluated (sub-steps choose: solve_substeps)
        return st

    def evaluate(self, objective: StepObjective, q: torch.Tensor,
                 derivatives: bool) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None, torch.Tensor]:  # fmt: skip
        """``objective`` per island (n_isl,) at ``q`` (n_isl, N) as the kernel computes it, with derivatives
        the gradient (n_isl, N) and matrix (n_isl, N, N) (copies), and per island whether an elastic block
        failed the near-SPD test (projected, as ``StepObjective`` does)."""
        n_isl, size = self.shape
        st = self._step_data(objective)
        self.q.copy_(q.reshape(-1))
        value = torch.zeros(n_isl, dtype=self.q.dtype, device=self.q.device)
        flagged = torch.zeros(n_isl, dtype=torch.int32, device=self.q.device)
        wp.launch(evaluate_islands_kernel, dim=n_isl, device=self.device, inputs=[
            self.bodies, self.scene, st, self.work, int(derivatives), _wp(value), _wp(flagged),
        ])  # fmt: skip
        if not derivatives:
            return value, None, None, flagged.bool()
        return value, self.grad.view(n_isl, size).clone(), self.hess.view(n_isl, size, size).clone(), flagged.bool()

    def _recorded(self, key: int | tuple, kernel: wp.Kernel, inputs: list) -> wp.Launch:
        """The launch of ``kernel`` over the islands with ``inputs``, packed at its first use under ``key`` and
        kept (packing the structs' arrays costs more than these kernels' work; the structs are read by
        reference, so a replay sees the step data bound since; ``key`` holds every scalar input)."""
        launch = self._bound_launches.get(key)
        if launch is None:
            launch = self._bound_launches[key] = wp.launch(
                kernel, dim=self.shape[0], device=self.device, record_cmd=True, inputs=inputs
            )
        return launch

    def _bound_step_of(self, objective: StepObjective) -> StepData:
        """The step data of ``objective``, bound at its first use (evaluate_bound and solve_split read the same)."""
        if self._bound_objective is not objective:
            self._bound_step = self._step_data(objective)
            self._bound_objective = objective
        return self._bound_step

    def _island_outputs(self) -> None:
        """Per-island value and flag outputs of the island count now (remade after a regrouping changed it,
        and with them the launches packed on the old ones)."""
        n_isl = self.shape[0]
        if self._value.shape[0] != n_isl:
            self._value, self._flagged = self._value.new_zeros(n_isl), self._flagged.new_zeros(n_isl)
            self._value_wp, self._flagged_wp = _wp(self._value), _wp(self._flagged)
            self._bound_launches.clear()

    def evaluate_bound(self, objective: StepObjective, q: torch.Tensor,
                       derivatives: bool) -> tuple[torch.Tensor, torch.Tensor | None, torch.Tensor | None]:  # fmt: skip
        """``objective`` per island (n_isl,) at ``q`` (n_isl, N) in one launch; with ``derivatives`` the gradient
        (n_isl, N) (a copy) and the contact part of the matrix (n_isl, N, N) (a view of this workspace's buffer,
        overwritten by the next evaluation; :data:`CONTACT_MATRIX_ONLY`): what :meth:`StepObjective.evaluate`
        adds to its kept ``M + h^2 K``. The step's data are bound once per objective (its contact buffers are
        this workspace's, prepared by its constructor)."""
        n_isl, size = self.shape
        self._island_outputs()
        st = self._bound_step_of(objective)
        self.q.copy_(q.reshape(-1))
        mode = int(CONTACT_MATRIX_ONLY if derivatives else 0)
        self._recorded(mode, evaluate_islands_kernel, [
            self.bodies, self.scene, st, self.work, mode, self._value_wp, self._flagged_wp,
        ]).launch()  # fmt: skip
        value = self._value.clone()
        if not derivatives:
            return value, None, None
        return value, self.grad.view(n_isl, size).clone(), self.hess.view(n_isl, size, size)

    def _given_limits(self, scale: torch.Tensor | None, trust_m: torch.Tensor | None, settings: NewtonSettings) -> bool:
        """Whether a solve was given its limits (then ``tolerance * scale`` and ``trust_m`` are copied to
        ``self.threshold`` and ``self.trust``) or leaves them to the kernel (both None)."""
        given = scale is not None
        if given != (trust_m is not None):
            raise ValueError("FusedNewton: give a solve both scale and trust_m, or neither")
        if given:
            self.threshold.copy_(settings.tolerance * scale)
            self.trust.copy_(trust_m)
        return given

    def solve(self, objective: StepObjective, q0: torch.Tensor, scale: torch.Tensor | None,
              trust_m: torch.Tensor | None, settings: NewtonSettings) -> NewtonResult | None:  # fmt: skip
        """Minimise ``objective`` (a :class:`StepObjective` on this workspace's contact buffers, as just
        built: its ``prepare`` is the last) on every island from ``q0`` (n_isl, N); ``scale`` and ``trust_m``
        (n_isl,) as in ``minimise``, or both None: the kernel computes them as ``objective.motion_scale()``
        and ``objective.trust_radius()`` do (then in ``self.threshold``, ``tolerance * scale``, and
        ``self.trust``). None when an island needs ``minimise``."""
        n_isl = self.shape[0]
        st = self._step_data(objective)
        self.q.copy_(q0.reshape(-1))
        given = self._given_limits(scale, trust_m, settings)
        wp.launch(newton_islands_kernel, dim=n_isl, device=self.device, inputs=[
            self.bodies, self.scene, st, *self._limits, int(settings.iterations), int(settings.line_search_steps),
            self.work, int(given), wp.float64(settings.tolerance), wp.float64(self._gravity_norm),
        ])  # fmt: skip
        if bool((self.stats[:, STATUS] != SOLVED).any()):
            return None
        return self._result()

    def _result(self, host_evaluations: int = 0) -> NewtonResult:
        """The solve's result from ``self.q`` and the per-island ``self.stats`` (``host_evaluations``: evaluations
        with derivatives the host made besides the kernel's)."""
        n_isl, size = self.shape
        out = self.stats.to(torch.int64)
        totals = out.sum(0).tolist()
        counters = {
            "evaluations": totals[EVALUATIONS],
            "evaluations_with_derivatives": host_evaluations + totals[EVALUATIONS_WITH_DERIVATIVES],
            "strict_projections": 0,
            "line_search_failures": totals[LINE_SEARCH_FAILURES],
            "line_search_extended": totals[LINE_SEARCH_EXTENDED],
            "trust_limited_steps": totals[TRUST_LIMITED],
            "unconverged_solves": n_isl - totals[CONVERGED],
        }
        return NewtonResult(self.q.view(n_isl, size).clone(), out[:, ITERATIONS], out[:, CONVERGED].bool(), counters)

    def solve_split(self, objective: StepObjective, q0: torch.Tensor, scale: torch.Tensor | None,
                    trust_m: torch.Tensor | None, settings: NewtonSettings) -> NewtonResult | None:  # fmt: skip
        """``minimise(objective, q0, ...)`` for islands of deformable objects with a kept elastic matrix
        (``lagged_elastic_hessian``), the work split at the factorisation: the first evaluation is
        ``objective``'s own (it forms and keeps ``M + h^2 K``); per iteration the host factorises the kept matrix
        plus the kernel's contact part (LAPACK in place, :class:`data_gen.sim.lapack.CholeskyDirections`, with
        :func:`cholesky_direction`'s ridge as ``minimise``'s where a matrix is not positive definite) and one launch
        (:func:`update_islands_kernel`) does the rest: update norms, trust limit, Armijo search, convergence and
        the next point's derivatives. One thread's factorisation of a 240-unknown island costs 25x LAPACK's,
        so the fused :meth:`solve` does not suit these islands; ``minimise``'s per-iteration tensor operations
        are what this saves. The same decisions as ``minimise`` on the same values (its norms and slope summed
        in another order). ``scale`` and ``trust_m`` (n_isl,) as in ``minimise``, or both None: the kernel
        computes them as ``objective.motion_scale()`` and ``objective.trust_radius()`` do (:func:`_step_limits`;
        then in ``self.threshold``, ``tolerance * scale``, and ``self.trust``). None when ``objective`` keeps no
        matrix or an island needs what only ``minimise`` does (a matrix indefinite after the ridge, a non-finite
        value): the caller runs ``minimise`` (whose first evaluation is then the kernel's, the matrix being
        kept)."""
        n_isl, size = self.shape
        ev = objective.evaluate(q0, True)
        base = objective.kept_matrix
        if base is None or not bool(torch.isfinite(ev.grad).all() & torch.isfinite(ev.value).all()):
            return None
        st = self._bound_step_of(objective)  # (bound by the first evaluation when it was the kernel's)
        self.q.copy_(q0.reshape(-1))
        self.grad.copy_(ev.grad.reshape(-1))
        self._island_outputs()
        self._value.copy_(ev.value)
        given = self._given_limits(scale, trust_m, settings)
        self.stats.zero_()
        self.stats[:, STATUS] = RUNNING
        self._recorded(("start", int(given), float(settings.tolerance), self._gravity_norm), split_start_kernel, [
            self.bodies, self.scene, st, *self._limits, int(given), wp.float64(settings.tolerance),
            wp.float64(self._gravity_norm),
        ]).launch()  # fmt: skip
        launch = self._recorded(("update", int(settings.line_search_steps)), update_islands_kernel, [
            self.bodies, self.scene, st, self.work, *self._limits, int(settings.line_search_steps), self._value_wp,
        ])  # fmt: skip
        grad = self.grad.view(n_isl, size)
        status = self.stats[:, STATUS]  # (a view: what the last launch left)
        hess = ev.hess
        dq_out = self.dq.view(n_isl, size)
        directions = self._directions if self._directions.suits(hess, grad, dq_out) else None
        summed = directions.sum_buffer(n_isl, size) if directions is not None else None

        def kept_plus_contact() -> torch.Tensor:  # the matrix at the kernel's last point, into the kept buffer
            return torch.add(base, self.hess.view(n_isl, size, size), out=summed)

        running = [True] * n_isl
        for iteration in range(settings.iterations):
            # an island that has stopped keeps its last matrix: only the running ones need a direction; the
            # matrices summed here are factorised in place (the first, the evaluation's, on a copy)
            in_place = hess is summed
            if directions is None or not directions.solve_suited(hess, grad, dq_out, running, overwrite=in_place):
                if in_place:  # the failed factorisation consumed the sum: formed again for the ridge path
                    hess = kept_plus_contact()
                dq, ok = cholesky_direction(hess, grad)  # (with its ridge where a matrix is not positive definite)
                if ok is not None and not bool((ok | (status != RUNNING)).all()):
                    return None  # minimise projects every elastic block of such an island
                self.dq.copy_(dq.reshape(-1))
            launch.launch()
            codes = status.tolist()  # one host read per iteration
            if NEEDS_FALLBACK in codes:
                return None
            if RUNNING not in codes:
                break
            running = [code == RUNNING for code in codes]
            if iteration + 1 == REUSED_MATRIX_REFRESH and objective.reuses_elastic_hessian:
                # started from elastic matrices of earlier (sub)steps and still running: formed anew here
                base = objective.refresh_kept_matrix(self.q.view(n_isl, size))
            hess = kept_plus_contact()
        return self._result(host_evaluations=1)  # (the objective's first evaluation)

    def solve_substeps(self, tm: torch.Tensor, tmdot: torch.Tensor, h_s: float | Sequence[float],
                       num_sub: int | Sequence[int], gravity_m_s2: torch.Tensor, settings: NewtonSettings,
                       scene_stiffness_n_m: torch.Tensor, smoothing_m: float | Sequence[float], pairs: PairSet | None,
                       pair_mu: torch.Tensor, pair_margin_m: float,
                       pair_group: np.ndarray | None = None) -> SubstepResult | None:  # fmt: skip
        """``num_sub`` implicit Euler sub-steps of ``h_s`` seconds of every island in one launch
        (:func:`substeps_kernel`), from padded states ``tm`` and rates ``tmdot`` (n, 3, K). ``h_s``, ``num_sub``
        and ``smoothing_m`` are one value for every island or one per island (islands of one launch may take
        different sub-steps; result rows beyond an island's count hold nothing of it). Each sub-step's
        start data is computed as :class:`StepObjective` computes it (scene stiffness ``scene_stiffness_n_m``
        (n,) N/m per sphere, the objects' friction, friction smoothing ``smoothing_m`` m), the candidate
        ``pairs`` (their frozen normal forces from each sub-step's start, friction coefficients ``pair_mu``
        (P,)) serve every sub-step (each evaluates those that can touch within it, ``pair_margin_m`` m being the
        broad phase's margin), and each is solved as :meth:`solve` solves one. None when a sub-step of
        some island needs ``minimise`` (nothing is kept: the caller solves the sub-steps one by one).

        With ``pair_group`` ((P,) int, each pair's group 0..G-1, or -1 for none) the result also holds each
        sub-step's sums of the scene forces per object slot and of the pair forces per group, summed in the
        launch (:func:`_force_sums`): a step's statistics without a pass over the per-sphere forces on the
        host."""
        st, ss, num_sub, count, p, groups = self.prepare_substeps(
            tm, tmdot, h_s, num_sub, gravity_m_s2, settings, scene_stiffness_n_m, smoothing_m, pairs, pair_mu,
            pair_margin_m, pair_group,
        )  # fmt: skip
        self._recorded(("substeps",), substeps_kernel, [self.bodies, self.scene, st, self.work, ss]).launch()
        return self.substep_result(num_sub, count, p, groups, pair_group is not None)

    def prepare_substeps(self, tm: torch.Tensor, tmdot: torch.Tensor, h_s: float | Sequence[float],
                         num_sub: int | Sequence[int], gravity_m_s2: torch.Tensor, settings: NewtonSettings,
                         scene_stiffness_n_m: torch.Tensor, smoothing_m: float | Sequence[float],
                         pairs: PairSet | None, pair_mu: torch.Tensor, pair_margin_m: float,
                         pair_group: np.ndarray | None = None) -> tuple[StepData, Substeps, int, list[int], int, int]:  # fmt: skip
        """What :meth:`solve_substeps` binds before its launch (the same arguments): (step data, sub-step
        arguments, the largest count, each island's count, the number of pairs, the number of pair groups);
        :class:`~data_gen.sim.device_newton.DeviceNewton` runs its own schedule on them."""
        n_isl, _ = self.shape
        h_isl = [float(h_s)] * n_isl if isinstance(h_s, (int, float)) else [float(h) for h in h_s]
        count = [int(num_sub)] * n_isl if isinstance(num_sub, int) else [int(k) for k in num_sub]
        eps = [float(smoothing_m)] * n_isl if isinstance(smoothing_m, (int, float)) else [float(e) for e in smoothing_m]
        if not (len(h_isl) == len(count) == len(eps) == n_isl):
            raise ValueError(f"solve_substeps: h_s, num_sub and smoothing_m need one value or {n_isl} (one per island)")
        num_sub = max(count)
        c = self.contact
        c.prepare_pairs(eps[0], h_isl[0] * h_isl[0], pairs if pairs is not None and pairs.num_pairs else None)
        st = self._bind_step(gravity_m_s2, h_isl[0] * h_isl[0])
        if n_isl > 1 and (min(h_isl) != max(h_isl) or min(eps) != max(eps)):  # per island (each h * h)
            self.h2.copy_(torch.tensor([h * h for h in h_isl], dtype=self.h2.dtype))
            self.smoothing.copy_(torch.tensor(eps, dtype=self.smoothing.dtype)[self.island_of])
        st.live_order = self._live_order_wp
        ss = self._substep_buffers(num_sub)
        self.sub_h.copy_(torch.tensor(h_isl, dtype=self.sub_h.dtype))
        self.sub_count.copy_(torch.tensor(count, dtype=self.sub_count.dtype))
        ss.pair_margin_m = wp.float64(pair_margin_m)
        p = int(st.num_pairs)
        self.pair_mu[:p].copy_(pair_mu[:p])
        self.tm_now.copy_(tm)
        self.tmdot.copy_(tmdot)
        self.scene_k.copy_(scene_stiffness_n_m)
        self.sub_stats.zero_()
        ss.tolerance = wp.float64(settings.tolerance)
        ss.gravity_norm = wp.float64(self._gravity_norm)
        ss.iterations, ss.line_search_steps = int(settings.iterations), int(settings.line_search_steps)
        groups = self._bind_sums(ss, num_sub, p, pair_group)
        return st, ss, num_sub, count, p, groups

    def substep_result(self, num_sub: int, count: list[int], num_pairs: int, groups: int,
                       with_sums: bool) -> SubstepResult | None:  # fmt: skip
        """:meth:`solve_substeps`'s result from its buffers after the sub-steps ran (None: some island's sub-step
        needs ``minimise``)."""
        p = num_pairs
        out = self.sub_stats[:num_sub].to(torch.int64)  # (sub, n_isl, NUM_STATS)
        if bool((out[:, :, STATUS] != SOLVED).any()):
            return None
        scene_sums = pair_sums = None
        if with_sums:
            scene_sums, pair_sums = self.sub_scene_sums[:num_sub], self.sub_pair_sums[:num_sub, :groups]
        totals = out.sum((0, 1)).tolist()
        counters = {
            "evaluations": totals[EVALUATIONS],
            "evaluations_with_derivatives": totals[EVALUATIONS_WITH_DERIVATIVES],
            "strict_projections": 0,
            "line_search_failures": totals[LINE_SEARCH_FAILURES],
            "line_search_extended": totals[LINE_SEARCH_EXTENDED],
            "trust_limited_steps": totals[TRUST_LIMITED],
            "unconverged_solves": sum(count) - totals[CONVERGED],
        }
        return SubstepResult(
            self.tm_now.clone(), self.tmdot.clone(), out[:, :, ITERATIONS], counters,
            self.sub_scene_force[:num_sub], self.sub_scene_normal[:num_sub], self.sub_sphere_x[:num_sub],
            self.sub_pair_force[:num_sub, :p], self.sub_pair_normal[:num_sub, :p], scene_sums, pair_sums,
        )  # fmt: skip

    def _bind_sums(self, ss: Substeps, num_sub: int, num_pairs: int, pair_group: np.ndarray | None) -> int:
        """Set ``ss`` up for :func:`_force_sums` with each pair's group ``pair_group`` (P,) (none: no sums);
        the pair-sum buffer grows to the number of groups, which is returned."""
        if pair_group is None:
            ss.with_sums = 0
            return 0
        groups = int(pair_group.max()) + 1 if len(pair_group) else 0
        if self.sub_pair_sums.shape[1] < groups:
            old = self.sub_pair_sums
            self.sub_pair_sums = old.new_zeros(old.shape[0], 2 * groups, SUMS)
            ss.pair_sums = _wp(self.sub_pair_sums)
        self.sub_pair_sums[:num_sub, :groups].zero_()  # _force_sums adds each group's forces to zero
        self.pair_group[:num_pairs].copy_(torch.from_numpy(np.asarray(pair_group, dtype=np.int32)))
        ss.with_sums = 1
        return groups

    def _substep_buffers(self, num_sub: int) -> Substeps:
        """The :class:`Substeps` arguments over buffers for at least ``num_sub`` sub-steps (kept; reallocated for
        more sub-steps or after the pair buffers grew)."""
        have = 0 if self._substeps is None else self.sub_stats.shape[0]
        if num_sub <= have:
            return self._substeps
        like = dict(dtype=self.q.dtype, device=self.q.device)
        n, s = self.sphere_x.shape[:2]
        capacity = len(self.pair_mu)
        # at least twice the rows held so far (a pile's sub-steps climb 1, 2, 3, ... as it falls: one
        # reallocation, and its dozen warp views, per doubling rather than per new count)
        count = max(num_sub, 2 * have, 4)
        ss = Substeps()
        # the per-sub-step outputs are left uninitialised: _final_forces writes every entry a caller reads (each
        # sphere of an island's objects, each pair of its range, in each of its sub-steps) before it is read, and
        # pages never written are never touched (these buffers hold capacity rows: tens of MB in a large pile)
        self.sub_sphere_x = torch.empty(count, n, s, 3, **like)
        self.sub_scene_force = torch.empty_like(self.sub_sphere_x)
        self.sub_scene_normal = torch.empty_like(self.sub_sphere_x)
        self.sub_pair_force = torch.empty(count, capacity, 3, **like)
        self.sub_pair_normal = torch.empty_like(self.sub_pair_force)
        self.sub_scene_sums = torch.zeros(count, n, SUMS, **like)
        self.sub_pair_sums = torch.zeros(count, 8, SUMS, **like)  # (grows with the groups, see _bind_sums)
        self.pair_group = torch.full((capacity,), -1, dtype=torch.int32, device=self.q.device)
        ss.scene_sums, ss.pair_sums, ss.pair_group = _wp(self.sub_scene_sums), _wp(self.sub_pair_sums), _wp(self.pair_group)
        ss.with_sums = 0
        ss.tm_now, ss.tmdot = _wp(self.tm_now), _wp(self.tmdot)
        ss.scene_stiffness, ss.friction = _wp(self.scene_k), _wp(self._keep["friction"])
        ss.valid, ss.pair_mu = _wp(self._keep["valid"]), _wp(self.pair_mu)
        forces = ForceOutputs()
        forces.sphere_x, forces.scene_force, forces.scene_normal = (
            _wp(t, wp.vec3d) for t in (self.sub_sphere_x, self.sub_scene_force, self.sub_scene_normal)
        )
        forces.pair_force, forces.pair_normal = _wp(self.sub_pair_force, wp.vec3d), _wp(self.sub_pair_normal, wp.vec3d)
        ss.forces = forces
        self._bind_island_substeps(ss, count)
        self._substeps = ss
        self._bound_launches.pop(("substeps",), None)  # packed with the previous Substeps
        return ss

    def _bind_island_substeps(self, ss: Substeps, count: int) -> None:
        """The per-island parts of ``ss``: counters for ``count`` sub-steps, each island's sub-step and count."""
        self.sub_stats = torch.zeros(count, self.shape[0], NUM_STATS, dtype=torch.int32, device=self.q.device)
        ss.stats = _wp(self.sub_stats)
        arrays = self._island_scratch[self.shape][1]
        ss.h, ss.num_sub = arrays["sub_h"], arrays["sub_count"]

    def forces(self) -> ContactForces:
        """The contact forces of the last :meth:`solve`'s or :meth:`solve_split`'s result (it must have returned
        a result): what :meth:`StepObjective.forces` computes at that state, from one launch over the islands."""
        from data_gen.sim.step_objective import ContactForces  # step_objective imports this module

        inputs = [self.bodies, self.scene, self._step, self.work, self._forces]
        self._recorded(("forces",), final_forces_kernel, inputs).launch()
        p = int(self._step.num_pairs)
        return ContactForces(self.scene_force.clone(), self.scene_normals.clone(), self.sphere_x.clone(),
                             self.pair_force[:p].clone(), self.pair_normals[:p].clone())  # fmt: skip


__all__ = ["FusedNewton", "evaluate_islands_kernel", "final_forces_kernel", "newton_islands_kernel", "substeps_kernel"]
