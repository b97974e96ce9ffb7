"""Scene and pair contact (penalty + lagged friction) of one evaluation as two fused warp kernels.

The formulas are those of :mod:`data_gen.sim.energy.point_terms` (the batched-torch reference used by
:mod:`.scene_contact` and :mod:`.pair_contact`, which the tests compare these kernels against):

* penalty ``k/2 d^2`` for penetration ``d > 0`` along the normal ``n``, gradient ``-k d n``, Gauss-Newton
  Hessian ``k n n^T``;
* friction ``mu lam f(|u_t|)`` on the tangential slip ``u_t`` with the normal force ``lam`` and normal
  frozen at the start of the (sub)step, ``f(s) = s^2 / (2 eps)`` below ``eps`` and ``s - eps/2`` above,
  gradient ``mu lam / max(s, eps) u_t``, Newton matrix ``mu lam / max(s, eps) (I - n n^T)`` less, when
  sliding (``s >= eps``), ``mu lam / s (1 - eps / s)`` along the slip (the curvature there is
  ``mu lam eps / s^2``: see :func:`data_gen.sim.energy.point_terms.friction`).

One thread per contact sphere (scene) or per candidate sphere pair (pair). A sphere or pair that neither
penetrates nor carries a frozen normal force contributes exactly nothing and returns at once: on a pile
most spheres are far from everything, so the kernels cost little more than the distance query. Active
threads add their energy per object (J) and, when derivatives are asked, ``scale`` times their gradient
and Hessian straight into the flat island vectors (n_isl N) and matrices (n_isl N N) of the minimiser
(:class:`data_gen.sim.model.DofLayout` positions ``flat_index``), including the cross blocks between two
objects of an island: no per-object blocks are formed and nothing is assembled afterwards. Only the
object's own ``4 H`` basis columns are visited, so a one-handle object costs 12 x 12 entries per sphere
whatever the padding.

The sums use atomic adds: on CPU warp runs the threads in order (deterministic); on CUDA the order of the
float64 additions varies between runs (results agree to round-off).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import warp as wp

from data_gen.sim.static_scene import _FAR_M, StaticScene, boxes_distance, points_distance


_ZERO = wp.constant(wp.float64(0.0))


@wp.func
def sphere_position(
    tm: wp.array3d(dtype=wp.float64),
    rest: wp.array2d(dtype=wp.vec3d),
    b: wp.array3d(dtype=wp.float64),
    o: int,
    s: int,
    columns: int,
):
    """``x = x0 + Tm b`` of sphere s of object o (m)."""
    x = rest[o, s]
    for a in range(columns):
        ba = b[o, s, a]
        x = x + wp.vec3d(tm[o, 0, a], tm[o, 1, a], tm[o, 2, a]) * ba
    return x


@wp.func
def _friction(slip: wp.vec3d, normal: wp.vec3d, scale: wp.float64, smoothing_m: wp.float64):
    """Energy (J), gradient (N) and Hessian (N/m) of lagged friction with ``scale = mu lam`` (N)."""
    u = slip - wp.dot(slip, normal) * normal
    s = wp.length(u)
    energy = _ZERO
    if s < smoothing_m:
        energy = scale * s * s / (wp.float64(2.0) * smoothing_m)
    else:
        energy = scale * (s - wp.float64(0.5) * smoothing_m)
    ratio = scale / wp.max(s, smoothing_m)
    hess = ratio * (wp.identity(n=3, dtype=wp.float64) - wp.outer(normal, normal))
    if s >= smoothing_m:  # sliding: along the slip, the curvature mu lam eps / s^2 (point_terms.friction)
        hess = hess - (ratio * (wp.float64(1.0) - smoothing_m / s) / (s * s)) * wp.outer(u, u)
    return energy, ratio * u, hess


@wp.func
def _penalty_and_friction(
    depth: wp.float64,
    normal: wp.vec3d,
    stiffness: wp.float64,
    slip: wp.vec3d,
    frozen_normal: wp.vec3d,
    mu_lam: wp.float64,
    smoothing_m: wp.float64,
):
    """Energy (J), dE/dx (N) and Hessian (N/m) of one sphere or pair: penalty ``k/2 d^2`` where ``d > 0``
    along ``normal`` plus lagged friction of ``slip`` in the frozen tangent plane where ``mu lam > 0``."""
    e = _ZERO
    g = wp.vec3d(_ZERO, _ZERO, _ZERO)
    h = wp.mat33d()
    if depth > _ZERO:
        e = wp.float64(0.5) * stiffness * depth * depth
        g = -(stiffness * depth) * normal
        h = stiffness * wp.outer(normal, normal)
    if mu_lam > _ZERO:
        e_f, g_f, h_f = _friction(slip, frozen_normal, mu_lam, smoothing_m)
        e = e + e_f
        g = g + g_f
        h = h + h_f
    return e, g, h


@wp.func
def add_gradient(
    grad: wp.array(dtype=wp.float64),
    flat_index: wp.array2d(dtype=wp.int32),
    b: wp.array3d(dtype=wp.float64),
    o: int,
    s: int,
    columns: int,
    padded_columns: int,
    g: wp.vec3d,
):
    """grad[(r, a)] += g[r] b[a] over the object's own columns."""
    for a in range(columns):
        ba = b[o, s, a]
        if ba != _ZERO:
            for r in range(3):
                wp.atomic_add(grad, flat_index[o, r * padded_columns + a], g[r] * ba)


@wp.func
def add_block(
    hess: wp.array(dtype=wp.float64),
    flat_index: wp.array2d(dtype=wp.int32),
    island_size: int,
    b: wp.array3d(dtype=wp.float64),
    o: int,
    s: int,
    columns: int,
    p: int,
    t: int,
    columns_p: int,
    h: wp.mat33d,
):
    """hess[(r, a), (c, e)] += h[r, c] b_os[a] b_pt[e]: the block of object o's rows and object p's columns.

    An object's unknowns are contiguous in its island (:class:`~data_gen.sim.model.DofLayout`: entry (r, a) at
    its first unknown plus ``r columns + a``), so only the first one is looked up."""
    row0 = int(flat_index[o, 0])  # island * N + the object's first local unknown
    col0 = int(flat_index[p, 0])
    # row (island * N + local) -> island * N * N + local * N: row * N - island * N
    shift = (row0 // island_size) * island_size
    for a in range(columns):
        ba = b[o, s, a]
        if ba != _ZERO:
            for e in range(columns_p):
                w = ba * b[p, t, e]
                if w != _ZERO:
                    for r in range(3):
                        base = (row0 + r * columns + a) * island_size - shift + col0 + e
                        for c in range(3):
                            wp.atomic_add(hess, base + c * columns_p, h[r, c] * w)


@wp.func
def scene_sphere_terms(
    tm: wp.array3d(dtype=wp.float64),
    cols: int,
    rest: wp.array2d(dtype=wp.vec3d),
    b: wp.array3d(dtype=wp.float64),
    radius: wp.array2d(dtype=wp.float64),
    stiffness: wp.array2d(dtype=wp.float64),
    friction_scale: wp.array2d(dtype=wp.float64),
    start_x: wp.array2d(dtype=wp.vec3d),
    start_normal: wp.array2d(dtype=wp.vec3d),
    smoothing_m: wp.float64,
    has_ground: int,
    box_centers: wp.array(dtype=wp.vec3d),
    box_rotations: wp.array(dtype=wp.mat33d),
    box_half_extents: wp.array(dtype=wp.vec3d),
    far_m: wp.float64,
    has_points: int,
    grid: wp.uint64,
    static_points: wp.array(dtype=wp.vec3d),
    point_radius_m: wp.float64,
    point_search_m: wp.float64,
    o: int,
    s: int,
):
    """Scene contact + friction of sphere (o, s): (active, energy J, dE/dx N, Hessian N/m, scene normal);
    ``active`` is 0 (and the rest zero) for a padded sphere or one that neither penetrates nor carries a
    frozen normal force."""
    k = stiffness[o, s]
    if k == _ZERO:
        return 0, _ZERO, wp.vec3d(_ZERO, _ZERO, _ZERO), wp.mat33d(), wp.vec3d(_ZERO, _ZERO, _ZERO)
    x = sphere_position(tm, rest, b, o, s, cols)
    return scene_contact_terms(
        x, k, radius, friction_scale, start_x, start_normal, smoothing_m, has_ground, box_centers, box_rotations,
        box_half_extents, far_m, has_points, grid, static_points, point_radius_m, point_search_m, o, s,
    )  # fmt: skip


@wp.func
def scene_contact_terms(
    x: wp.vec3d,
    k: wp.float64,
    radius: wp.array2d(dtype=wp.float64),
    friction_scale: wp.array2d(dtype=wp.float64),
    start_x: wp.array2d(dtype=wp.vec3d),
    start_normal: wp.array2d(dtype=wp.vec3d),
    smoothing_m: wp.float64,
    has_ground: int,
    box_centers: wp.array(dtype=wp.vec3d),
    box_rotations: wp.array(dtype=wp.mat33d),
    box_half_extents: wp.array(dtype=wp.vec3d),
    far_m: wp.float64,
    has_points: int,
    grid: wp.uint64,
    static_points: wp.array(dtype=wp.vec3d),
    point_radius_m: wp.float64,
    point_search_m: wp.float64,
    o: int,
    s: int,
):
    """:func:`scene_sphere_terms` of sphere (o, s) at ``x`` (m) with stiffness ``k`` != 0 (N/m)."""
    e = _ZERO
    g = wp.vec3d(_ZERO, _ZERO, _ZERO)
    h = wp.mat33d()
    sdf, n = boxes_distance(x, has_ground, box_centers, box_rotations, box_half_extents, far_m)
    if has_points != 0:
        sdf, n = points_distance(grid, x, static_points, point_radius_m, point_search_m, sdf, n)
    depth = radius[o, s] - sdf
    mu_lam = friction_scale[o, s]
    if depth <= _ZERO and mu_lam <= _ZERO:
        return 0, e, g, h, n
    e, g, h = _penalty_and_friction(depth, n, k, x - start_x[o, s], start_normal[o, s], mu_lam, smoothing_m)
    return 1, e, g, h, n


@wp.func
def pair_terms(
    tm: wp.array3d(dtype=wp.float64),
    rest: wp.array2d(dtype=wp.vec3d),
    b: wp.array3d(dtype=wp.float64),
    oi: int,
    si: int,
    cols_i: int,
    oj: int,
    sj: int,
    cols_j: int,
    frozen_x_j: wp.vec3d,
    stiffness: wp.float64,
    radius_sum: wp.float64,
    mu_lam: wp.float64,
    normal0: wp.vec3d,
    x0_i: wp.vec3d,
    x0_j: wp.vec3d,
    smoothing_m: wp.float64,
):
    """Pair contact + friction of sphere si of object oi against sphere sj of object oj (or the frozen point
    ``frozen_x_j`` when ``oj < 0``): (active, energy J, dE/dx_i N, Hessian N/m, unit normal j -> i)."""
    xi = sphere_position(tm, rest, b, oi, si, cols_i)
    xj = frozen_x_j
    if oj >= 0:
        xj = sphere_position(tm, rest, b, oj, sj, cols_j)
    return pair_contact_terms(xi, xj, stiffness, radius_sum, mu_lam, normal0, x0_i, x0_j, smoothing_m)


@wp.func
def pair_contact_terms(
    xi: wp.vec3d,
    xj: wp.vec3d,
    stiffness: wp.float64,
    radius_sum: wp.float64,
    mu_lam: wp.float64,
    normal0: wp.vec3d,
    x0_i: wp.vec3d,
    x0_j: wp.vec3d,
    smoothing_m: wp.float64,
):
    """:func:`pair_terms` of two spheres at ``xi`` / ``xj`` (m): (active, energy J, dE/dx_i N, Hessian N/m, unit
    normal j -> i)."""
    delta = xi - xj
    dist = wp.max(wp.length(delta), wp.float64(1.0e-12))
    n = delta / dist
    depth = radius_sum - dist
    if depth <= _ZERO and mu_lam <= _ZERO:
        return 0, _ZERO, wp.vec3d(_ZERO, _ZERO, _ZERO), wp.mat33d(), n
    e, g, h = _penalty_and_friction(depth, n, stiffness, (xi - x0_i) - (xj - x0_j), normal0, mu_lam, smoothing_m)
    return 1, e, g, h, n


@wp.func
def add_pair_derivatives(
    grad: wp.array(dtype=wp.float64),
    hess: wp.array(dtype=wp.float64),
    flat_index: wp.array2d(dtype=wp.int32),
    island_size: int,
    b: wp.array3d(dtype=wp.float64),
    oi: int,
    si: int,
    cols_i: int,
    oj: int,
    sj: int,
    cols_j: int,
    gs: wp.vec3d,
    hs: wp.mat33d,
):
    """A pair's scaled gradient and Hessian into the island system (side j and cross blocks when j is solved)."""
    kp = flat_index.shape[1] // 3
    add_gradient(grad, flat_index, b, oi, si, cols_i, kp, gs)
    add_block(hess, flat_index, island_size, b, oi, si, cols_i, oi, si, cols_i, hs)
    if oj >= 0:
        add_gradient(grad, flat_index, b, oj, sj, cols_j, kp, -gs)
        add_block(hess, flat_index, island_size, b, oj, sj, cols_j, oj, sj, cols_j, hs)
        add_block(hess, flat_index, island_size, b, oi, si, cols_i, oj, sj, cols_j, -hs)
        add_block(hess, flat_index, island_size, b, oj, sj, cols_j, oi, si, cols_i, -hs)


@wp.kernel
def scene_contact_kernel(
    tm: wp.array3d(dtype=wp.float64),
    columns: wp.array(dtype=wp.int32),
    rest: wp.array2d(dtype=wp.vec3d),
    b: wp.array3d(dtype=wp.float64),
    radius: wp.array2d(dtype=wp.float64),
    stiffness: wp.array2d(dtype=wp.float64),
    friction_scale: wp.array2d(dtype=wp.float64),
    start_x: wp.array2d(dtype=wp.vec3d),
    start_normal: wp.array2d(dtype=wp.vec3d),
    smoothing_m: wp.float64,
    has_ground: int,
    box_centers: wp.array(dtype=wp.vec3d),
    box_rotations: wp.array(dtype=wp.mat33d),
    box_half_extents: wp.array(dtype=wp.vec3d),
    far_m: wp.float64,
    has_points: int,
    grid: wp.uint64,
    static_points: wp.array(dtype=wp.vec3d),
    point_radius_m: wp.float64,
    point_search_m: wp.float64,
    flat_index: wp.array2d(dtype=wp.int32),
    island_size: int,
    derivatives: int,
    scale: wp.float64,
    energy: wp.array(dtype=wp.float64),
    grad: wp.array(dtype=wp.float64),
    hess: wp.array(dtype=wp.float64),
    force_out: wp.array2d(dtype=wp.vec3d),
    normal_out: wp.array2d(dtype=wp.vec3d),
):
    """Sphere (o, s): ``stiffness`` (n, S) N/m is 0 on padded spheres, ``friction_scale`` = mu lam (N) of
    the frozen start. ``force_out`` / ``normal_out`` (n, S): contact + friction force on the sphere (N) and
    the scene normal, written for active spheres (left untouched otherwise)."""
    o, s = wp.tid()
    cols = int(columns[o])
    active, e, g, h, n = scene_sphere_terms(
        tm, cols, rest, b, radius, stiffness, friction_scale, start_x, start_normal, smoothing_m, has_ground,
        box_centers, box_rotations, box_half_extents, far_m, has_points, grid, static_points, point_radius_m,
        point_search_m, o, s,
    )  # fmt: skip
    if active == 0:
        return
    wp.atomic_add(energy, o, e)
    force_out[o, s] = -g
    normal_out[o, s] = n
    if derivatives != 0:
        kp = flat_index.shape[1] // 3
        add_gradient(grad, flat_index, b, o, s, cols, kp, scale * g)
        add_block(hess, flat_index, island_size, b, o, s, cols, o, s, cols, scale * h)


@wp.kernel
def pair_contact_kernel(
    tm: wp.array3d(dtype=wp.float64),
    columns: wp.array(dtype=wp.int32),
    rest: wp.array2d(dtype=wp.vec3d),
    b: wp.array3d(dtype=wp.float64),
    obj_i: wp.array(dtype=wp.int32),
    sph_i: wp.array(dtype=wp.int32),
    obj_j: wp.array(dtype=wp.int32),
    sph_j: wp.array(dtype=wp.int32),
    frozen_x_j: wp.array(dtype=wp.vec3d),
    stiffness: wp.array(dtype=wp.float64),
    radius_sum: wp.array(dtype=wp.float64),
    friction_scale: wp.array(dtype=wp.float64),
    normal0: wp.array(dtype=wp.vec3d),
    x0_i: wp.array(dtype=wp.vec3d),
    x0_j: wp.array(dtype=wp.vec3d),
    smoothing_m: wp.float64,
    flat_index: wp.array2d(dtype=wp.int32),
    island_size: int,
    derivatives: int,
    scale: wp.float64,
    energy: wp.array(dtype=wp.float64),
    grad: wp.array(dtype=wp.float64),
    hess: wp.array(dtype=wp.float64),
    force_out: wp.array(dtype=wp.vec3d),
    normal_out: wp.array(dtype=wp.vec3d),
):
    """Pair p: side i on solved object ``obj_i``, side j on solved object ``obj_j`` or frozen (``obj_j < 0``,
    at ``frozen_x_j``). Energy is counted on side i; ``force_out`` is the force on side i (N) and
    ``normal_out`` the unit normal j -> i, written for active pairs."""
    p = wp.tid()
    oi = int(obj_i[p])
    si = int(sph_i[p])
    oj = int(obj_j[p])
    sj = int(sph_j[p])
    cols_i = int(columns[oi])
    cols_j = int(0)
    if oj >= 0:
        cols_j = int(columns[oj])
    active, e, g, h, n = pair_terms(
        tm, rest, b, oi, si, cols_i, oj, sj, cols_j, frozen_x_j[p], stiffness[p], radius_sum[p], friction_scale[p],
        normal0[p], x0_i[p], x0_j[p], smoothing_m,
    )  # fmt: skip
    if active == 0:
        return
    wp.atomic_add(energy, oi, e)
    force_out[p] = -g
    normal_out[p] = n
    if derivatives != 0:
        add_pair_derivatives(grad, hess, flat_index, island_size, b, oi, si, cols_i, oj, sj, cols_j, scale * g,
                             scale * h)  # fmt: skip


def _wp(t: torch.Tensor, dtype=None) -> wp.array:
    """A warp view of a contiguous torch tensor (no copy)."""
    return wp.from_torch(t.contiguous(), dtype=dtype)


@dataclass
class ContactOutputs:
    """What one evaluation of :class:`WarpContact` produced: contact energy per object (n,) J; with
    derivatives the gradient (n_isl, N) and Newton matrix (n_isl, N, N), scaled by the solve's ``scale``;
    the forces of active spheres (n, S, 3) N and pairs (P, 3) N (on side i) with their normals (zeros where
    inactive). The tensors are the contact object's buffers: the next evaluation overwrites them."""

    energy_j: torch.Tensor
    grad: torch.Tensor | None
    hess: torch.Tensor | None
    scene_force_n: torch.Tensor
    scene_normals: torch.Tensor
    pair_force_i_n: torch.Tensor
    pair_normals: torch.Tensor


# the pair buffers' first capacity (about 0.75 MB of buffers; a ten-box pile needs up to ~20k pairs)
_MIN_PAIR_CAPACITY = 4096


class WarpContact:
    """The contact terms of a fixed set of objects and islands on warp, reused by every solve of them.

    Built once per set of objects (their spheres and DOF layout); :meth:`prepare` copies one solve's frozen
    start data and candidate pairs into persistent buffers; :meth:`evaluate` copies the state in, clears the
    outputs and replays the recorded launches (the kernels' arguments are packed once; the pair launch is
    re-recorded only when the pair count outgrows its buffers).

    Args:
        scene: the static scene (its warp box arrays and point grid are cached on it).
        columns: (n,) 4 H per object; rest (n, S, 3) m, b (n, S, K), radius (n, S) m: the spheres.
        flat_index: (n, 3K) island positions (:class:`data_gen.sim.model.DofLayout`); island_size N;
            num_islands.
    """

    def __init__(self, scene: StaticScene, columns: torch.Tensor, rest: torch.Tensor, b: torch.Tensor,
                 radius: torch.Tensor, flat_index: torch.Tensor, island_size: int, num_islands: int) -> None:  # fmt: skip
        wp.init()  # idempotent; not at import, so importing the package prints nothing
        self.scene = scene
        self.torch_device = rest.device
        self.device = "cuda:0" if str(self.torch_device) == "cuda" else str(self.torch_device)
        n, s, k = b.shape
        self.shape = (n, s, k, num_islands, island_size)
        self.num_pairs = 0

        def zeros(*shape: int) -> torch.Tensor:
            return torch.zeros(*shape, dtype=rest.dtype, device=self.torch_device)

        self._zeros = zeros
        self.tm, self.energy = zeros(n, 3, k), zeros(n)
        self.grad = zeros(num_islands * island_size)
        self.hess = zeros(num_islands * island_size * island_size)
        self.scene_force, self.scene_normals = zeros(n, s, 3), zeros(n, s, 3)
        # one solve's scene data: stiffness (0 on padding), mu lam, start positions and normals
        self.stiffness, self.friction_scale = zeros(n, s), zeros(n, s)
        self.start_x, self.start_normals = zeros(n, s, 3), zeros(n, s, 3)
        i32 = torch.int32
        self._constants = [columns.to(i32).contiguous(), flat_index.to(i32).contiguous(), rest.contiguous(),
                           b.contiguous(), radius.contiguous()]  # fmt: skip
        columns_i, flat_i, rest_c, b_c, radius_c = self._constants
        self._common = [_wp(self.tm), _wp(columns_i), _wp(rest_c, wp.vec3d), _wp(b_c)]
        boxes = scene._device_boxes(self.device)
        if scene.points is not None:
            grid, static_points = scene._device_points(self.device)
            points = [1, grid.id, static_points, wp.float64(scene.points.radius_m), wp.float64(scene.points.search_m)]
        else:
            empty = wp.zeros(0, dtype=wp.vec3d, device=self.device)
            points = [0, wp.uint64(0), empty, wp.float64(0.0), wp.float64(1.0)]
        # the last arguments of both kernels: [2] is ``derivatives``, [3] ``scale``
        self._tail = [_wp(flat_i), int(island_size), 1, wp.float64(1.0), _wp(self.energy), _wp(self.grad),
                      _wp(self.hess)]  # fmt: skip
        head = [*self._common, _wp(radius_c), _wp(self.stiffness), _wp(self.friction_scale),
                _wp(self.start_x, wp.vec3d), _wp(self.start_normals, wp.vec3d)]  # fmt: skip
        self._scene_smoothing_index = len(head)
        scene_inputs = [
            *head, wp.float64(0.0), int(scene.ground), *boxes, wp.float64(_FAR_M), *points, *self._tail,
            _wp(self.scene_force, wp.vec3d), _wp(self.scene_normals, wp.vec3d),
        ]  # fmt: skip
        self._scene_inputs = scene_inputs  # the recorded launch holds raw pointers to these
        self._scene = None  # recorded on the first evaluation (a fused solve reads only the buffers)
        self._pair = None
        self._pair_capacity = 0
        self._derivatives, self._smoothing, self._scale = True, 0.0, 1.0

    @property
    def pair_capacity(self) -> int:
        """Size of the pair buffers (they are reallocated, doubling, when a solve has more pairs)."""
        return self._pair_capacity

    @property
    def smoothing_m(self) -> float:
        """Friction smoothing eps (m) of the last :meth:`prepare`."""
        return self._smoothing

    def pair_arrays(self) -> tuple[list[torch.Tensor], list[torch.Tensor], list[torch.Tensor]]:
        """The pair buffers (valid up to ``num_pairs``): ints (obj_i, sph_i, obj_j, sph_j), vectors (frozen
        x_j, normal0, x0_i, x0_j) and scalars (stiffness, radius sum, mu lam); allocated (64 pairs) if no
        solve had pairs yet."""
        if not self._pair_capacity:
            self._grow_pairs(1)
        return self._pair_buffers

    def _tail_index(self, inputs: list, offset: int) -> int:
        """Position of ``tail[offset]`` in a kernel's inputs (every kernel ends with tail, force, normal)."""
        return len(inputs) - 2 - len(self._tail) + offset

    def _grow_pairs(self, count: int) -> None:
        """Pair buffers for at least ``count`` pairs (and at least 4 x the old capacity, and at least
        ``_MIN_PAIR_CAPACITY``: every growth rebinds the buffers wherever they are read, and a pile's first steps would
        otherwise grow them three times over) and a pair launch recorded over them."""
        capacity = max(_MIN_PAIR_CAPACITY, 1 << (count - 1).bit_length(), 4 * self._pair_capacity)
        zeros, i32 = self._zeros, torch.int32
        ints = [torch.zeros(capacity, dtype=i32, device=self.torch_device) for _ in range(4)]
        vec = [zeros(capacity, 3) for _ in range(4)]  # frozen x_j, normal0, x0_i, x0_j
        scal = [zeros(capacity) for _ in range(3)]  # stiffness, radius sum, mu lam
        self.pair_force, self.pair_normals = zeros(capacity, 3), zeros(capacity, 3)
        self._pair_buffers = (ints, vec, scal)
        frozen_x, normal0, x0_i, x0_j = vec
        stiffness, radius_sum, friction_scale = scal
        head = [
            *self._common, *[_wp(t) for t in ints], _wp(frozen_x, wp.vec3d), _wp(stiffness), _wp(radius_sum),
            _wp(friction_scale), _wp(normal0, wp.vec3d), _wp(x0_i, wp.vec3d), _wp(x0_j, wp.vec3d),
        ]  # fmt: skip
        self._pair_smoothing_index = len(head)
        inputs = [*head, wp.float64(self._smoothing), *self._tail, _wp(self.pair_force, wp.vec3d),
                  _wp(self.pair_normals, wp.vec3d)]  # fmt: skip
        self._pair_inputs = inputs
        self._pair = None  # recorded on the first evaluation with pairs
        self._pair_capacity = capacity

    def _record_launches(self) -> None:
        """Record the scene launch, and the pair launch over the current pair buffers, with the current
        parameters (smoothing, scale, derivatives, pair count)."""
        if self._scene is None:
            n, s = self.shape[:2]
            self._scene = wp.launch(scene_contact_kernel, dim=(n, s), inputs=self._scene_inputs, device=self.device,
                                    record_cmd=True)  # fmt: skip
            self._set_parameters(self._scene, self._scene_inputs, self._scene_smoothing_index)
        if self._pair is None and self._pair_capacity:
            inputs = self._pair_inputs
            self._pair = wp.launch(pair_contact_kernel, dim=self._pair_capacity, inputs=inputs, device=self.device,
                                   record_cmd=True)  # fmt: skip
            self._set_parameters(self._pair, inputs, self._pair_smoothing_index)
        if self._pair is not None:
            self._pair.set_dim(max(self.num_pairs, 1))

    def _set_parameters(self, launch: wp.Launch, inputs: list, smoothing_index: int) -> None:
        launch.set_param_at_index(smoothing_index, wp.float64(self._smoothing))
        launch.set_param_at_index(self._tail_index(inputs, 2), int(self._derivatives))
        launch.set_param_at_index(self._tail_index(inputs, 3), wp.float64(self._scale))

    def prepare(self, stiffness_n_m: torch.Tensor, friction_scale_n: torch.Tensor, start_x_m: torch.Tensor,
                start_normals: torch.Tensor, smoothing_m: float, scale: float, pairs) -> None:  # fmt: skip
        """One solve's data: per-sphere stiffness (n, S) N/m (0 on padding), frozen mu lam (n, S) N, start
        positions and scene normals (n, S, 3); friction smoothing eps (m); ``scale`` of the gradient and
        matrix (the solver's h^2; energies are not scaled); the candidate pairs
        (:class:`data_gen.sim.energy.pair_contact.PairSet` in this object set's slots, or None)."""
        self.stiffness.copy_(stiffness_n_m)
        self.friction_scale.copy_(friction_scale_n)
        self.start_x.copy_(start_x_m)
        self.start_normals.copy_(start_normals)
        self.prepare_pairs(smoothing_m, scale, pairs)

    def prepare_pairs(self, smoothing_m: float, scale: float, pairs) -> None:
        """The pair part of :meth:`prepare` (candidate pairs, smoothing, scale), the per-sphere scene data left
        as it is: what a caller that computes the scene data itself (the fused sub-steps) loads."""
        self.num_pairs = 0 if pairs is None else pairs.num_pairs
        if self.num_pairs > self._pair_capacity:
            self._grow_pairs(self.num_pairs)
        if self.num_pairs:
            p = self.num_pairs
            ints, vec, scal = self._pair_buffers
            for buffer, value in zip(ints, (pairs.obj_i, pairs.sph_i, pairs.obj_j, pairs.sph_j)):
                buffer[:p].copy_(value)
            start = pairs.normal0 is not None  # None: the fused sub-steps write them in their launch
            vec_values = (pairs.frozen_x_j, pairs.normal0, pairs.x0_i, pairs.x0_j) if start else (pairs.frozen_x_j,)
            for buffer, value in zip(vec, vec_values):
                buffer[:p].copy_(value)
            scal_values = (pairs.stiffness_n_m, pairs.radius_sum_m)
            if start:
                scal_values += (pairs.friction * pairs.normal_force_n,)
            for buffer, value in zip(scal, scal_values):
                buffer[:p].copy_(value)
            if self._pair is not None:
                self._pair.set_dim(p)
        if smoothing_m != self._smoothing or scale != self._scale:
            self._smoothing, self._scale = float(smoothing_m), float(scale)
            if self._scene is not None:
                self._set_parameters(self._scene, self._scene_inputs, self._scene_smoothing_index)
            if self._pair is not None:
                self._set_parameters(self._pair, self._pair_inputs, self._pair_smoothing_index)

    def evaluate(self, tm: torch.Tensor, derivatives: bool = False) -> ContactOutputs:
        """Contact terms at padded states ``tm`` (n, 3, K) with the data of the last :meth:`prepare`."""
        n, s, k, num_islands, size = self.shape
        p = self.num_pairs
        self.tm.copy_(tm)
        for buffer in (self.energy, self.scene_force, self.scene_normals):
            buffer.zero_()
        if p:
            self.pair_force[:p].zero_()
            self.pair_normals[:p].zero_()
        if derivatives:
            self.grad.zero_()
            self.hess.zero_()
        if derivatives != self._derivatives:
            self._derivatives = derivatives
            for launch, inputs in ((self._scene, self._scene_inputs), (self._pair, getattr(self, "_pair_inputs", None))):
                if launch is not None:
                    launch.set_param_at_index(self._tail_index(inputs, 2), int(derivatives))
        if self._scene is None or (p and self._pair is None):
            self._record_launches()
        self._scene.launch()
        if p:
            self._pair.launch()
        empty = self._zeros(0, 3)
        return ContactOutputs(
            self.energy,
            self.grad.view(num_islands, size) if derivatives else None,
            self.hess.view(num_islands, size, size) if derivatives else None,
            self.scene_force, self.scene_normals,
            self.pair_force[:p] if p else empty, self.pair_normals[:p] if p else empty,
        )  # fmt: skip


__all__ = [
    "ContactOutputs", "WarpContact", "add_block", "add_gradient", "add_pair_derivatives", "pair_contact_kernel",
    "pair_terms", "scene_contact_kernel", "scene_sphere_terms", "sphere_position",
]
