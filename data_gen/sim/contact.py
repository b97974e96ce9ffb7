"""Contact between cubature spheres and the static scene, and between objects.

* Static scene: sphere i (centre x_i, radius r_i) penetrates by ``d_i = r_i - sdf(x_i)``; the penalty
  energy is ``k/2 d_i^2`` for ``d_i > 0`` (C1, Gauss-Newton Hessian ``k n n^T``).
* Object-object: candidate pairs come from a grid over each object's bounding box (:class:`PairFinder`),
  rebuilt every step (a sphere visits only other objects' spheres); pair (i, j) penetrates by
  ``d = r_i + r_j - |x_i - x_j|`` with energy ``k/2 d^2`` (Hessian ``k n n^T``, the negative curvature
  term dropped so it stays PSD).
* Friction: lagged, smoothed Coulomb.  The normal force ``lam`` and the tangent plane are frozen at the
  start of the step; with tangential slip ``u`` (m) over the step the energy is ``mu lam f(|u|)``,
  ``f(s) = s^2 / (2 eps)`` for ``s < eps`` and ``s - eps/2`` beyond, ``eps = v_eps dt`` (m).

The stiffness ``k`` (N/m) is chosen by the caller as ``factor * mass / dt^2`` so that the penetration
under load does not depend on the material stiffness (a stiff object cannot push through the floor).
All functions are batched over points/pairs (torch float64); energies in J, forces in N. The per-point
formulas live in :mod:`data_gen.sim.energy.point_terms` (shared with the solver's energy terms); these
wrappers return totals.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
import warp as wp

from data_gen.sim.energy import point_terms
from data_gen.sim.static_scene import StaticScene


@dataclass
class PointContact:
    """Per-point penalty terms: energy (J), dE/dx (n,3) N, Gauss-Newton d2E/dx2 (n,3,3) N/m."""

    energy: float
    grad_x: torch.Tensor
    hess_x: torch.Tensor


def static_contact(
    x_m: torch.Tensor, radius_m: torch.Tensor, stiffness_n_m: torch.Tensor, scene: StaticScene
) -> tuple[PointContact, torch.Tensor, torch.Tensor]:
    """Penalty contact of spheres with the static scene.

    Returns the per-point terms, the penetration depth (n,) m (``> 0`` in contact) and the outward
    scene normals (n,3).
    """
    sdf, normal = scene.query(x_m)
    return penalty_from_sdf(torch.from_numpy(sdf), torch.from_numpy(normal), radius_m, stiffness_n_m)


def penalty_from_sdf(
    sdf_m: torch.Tensor, n_t: torch.Tensor, radius_m: torch.Tensor, stiffness_n_m: torch.Tensor
) -> tuple[PointContact, torch.Tensor, torch.Tensor]:
    """:func:`static_contact` from already queried signed distances (n,) and normals (n,3)."""
    depth = radius_m - sdf_m
    energy, grad, hess = point_terms.penalty(depth, n_t, stiffness_n_m, True)
    return PointContact(float(energy.sum()), grad, hess), depth, n_t


def friction_terms(
    slip_m: torch.Tensor,
    normal_force_n: torch.Tensor,
    tangent_normals: torch.Tensor,
    friction_coefficient: torch.Tensor,
    smoothing_m: float,
) -> PointContact:
    """Lagged smoothed Coulomb friction on a slip (n,3) with frozen normal forces (n,) and normals (n,3)."""
    energy, grad, hess = point_terms.friction(
        slip_m, normal_force_n, tangent_normals, friction_coefficient, smoothing_m, True
    )
    return PointContact(float(energy.sum()), grad, hess)


@wp.func
def _cell_of(v: wp.float64, width: wp.float64, count: int):
    """Cell index along one axis of a coordinate ``v`` (m) from the grid's corner, cells ``width`` wide, clamped to
    the grid's ``count`` cells (clamping keeps the order of coordinates, so a range of them maps onto a range of
    cells holding every point between them)."""
    t = wp.floor(v / width)
    t = wp.min(wp.max(t, wp.float64(0.0)), wp.float64(count - 1))
    return int(t)


@wp.kernel
def _candidate_pairs_kernel(
    points: wp.array(dtype=wp.vec3d),
    object_ids: wp.array(dtype=wp.int32),
    radii: wp.array(dtype=wp.float64),
    point_margins: wp.array(dtype=wp.float64),
    box_lo: wp.array(dtype=wp.vec3d),
    box_hi: wp.array(dtype=wp.vec3d),
    object_reach: wp.array(dtype=wp.float64),
    ordered: int,
    margin: wp.float64,
    grid_width: wp.array(dtype=wp.float64),
    close: wp.array(dtype=wp.int32),
    grid_dims: wp.array(dtype=wp.vec3i),
    grid_first: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    cell_points: wp.array(dtype=wp.int32),
    capacity: int,
    count: wp.array(dtype=wp.int32),
    pairs: wp.array(dtype=wp.int32, ndim=2),
):
    if close[0] == 0:  # every two objects apart (_grid_kernel): no pair
        return
    i = wp.tid()
    cell_width = grid_width[0]
    p = points[i]
    a = object_ids[i]
    own = radii[i] + margin + point_margins[i]
    first = int(0)
    if ordered != 0:  # object ids ascend with the point index: every j > i on another object has a larger id
        first = a + 1
    for c in range(first, box_lo.shape[0]):
        if c == a:
            continue
        # a partner j on object c is closer than own + radii[j] + point_margins[j] <= own + object_reach[c]
        # (grown by a relative 1e-9 against round-off)
        r = (own + object_reach[c]) * wp.float64(1.000000001)
        lo = box_lo[c]
        hi = box_hi[c]
        if p[0] < lo[0] - r or p[0] > hi[0] + r or p[1] < lo[1] - r or p[1] > hi[1] + r:
            continue
        if p[2] < lo[2] - r or p[2] > hi[2] + r:
            continue
        # object c's cells within r of p on every axis (its grid starts at its box's corner; the range is grown by a
        # further relative 1e-6 so that no rounding of the cell arithmetic can leave a partner's cell out)
        rc = r * wp.float64(1.000001)
        dims = grid_dims[c]
        nx, ny, nz = dims[0], dims[1], dims[2]
        x0, x1 = _cell_of(p[0] - rc - lo[0], cell_width, nx), _cell_of(p[0] + rc - lo[0], cell_width, nx)
        y0, y1 = _cell_of(p[1] - rc - lo[1], cell_width, ny), _cell_of(p[1] + rc - lo[1], cell_width, ny)
        z0, z1 = _cell_of(p[2] - rc - lo[2], cell_width, nz), _cell_of(p[2] + rc - lo[2], cell_width, nz)
        r2 = r * r
        for ix in range(x0, x1 + 1):
            for iy in range(y0, y1 + 1):
                row = grid_first[c] + (ix * ny + iy) * nz  # cells along z are contiguous: one run of points
                for k in range(cell_start[row + z0], cell_start[row + z1 + 1]):
                    j = cell_points[k]
                    if j > i:
                        d = points[j] - p
                        dd = wp.dot(d, d)
                        # most points of the visited cells lie beyond r, which bounds every partner's distance (the
                        # exact test below, grown by the relative 1e-9 of r): one read and a squared distance drop them
                        if dd < r2 and wp.sqrt(dd) < radii[i] + radii[j] + margin + point_margins[i] + point_margins[j]:
                            slot = wp.atomic_add(count, 0, 1)
                            if slot < capacity:
                                pairs[slot, 0] = i
                                pairs[slot, 1] = j


@wp.func
def _empty_box(c: int, box_lo: wp.array(dtype=wp.vec3d), box_hi: wp.array(dtype=wp.vec3d),
               object_reach: wp.array(dtype=wp.float64)):  # fmt: skip
    """Object ``c``'s box and reach before any of its points is added (every min / max then takes the point's)."""
    huge = wp.float64(1.0e300)
    box_lo[c] = wp.vec3d(huge, huge, huge)
    box_hi[c] = wp.vec3d(-huge, -huge, -huge)
    object_reach[c] = -huge


@wp.func
def _grid_layout(margin: wp.float64, width0: wp.float64, limit: int, box_lo: wp.array(dtype=wp.vec3d),
                 box_hi: wp.array(dtype=wp.vec3d), object_reach: wp.array(dtype=wp.float64),
                 close: wp.array(dtype=wp.int32), grid_width: wp.array(dtype=wp.float64),
                 grid_dims: wp.array(dtype=wp.vec3i), grid_first: wp.array(dtype=wp.int32)):  # fmt: skip
    """From the objects' boxes and reaches: ``close[0]`` = whether some two objects' boxes are closer on every axis
    than their reaches plus ``margin`` (a pair of points passing the search's test needs it; a relative 1e-9 covers
    round-off); if so, each object's grid over its box, cells ``width0`` wide, widened (by at least 5 % a time)
    until all grids hold at most ``limit`` cells (``grid_width[0]``), numbered object by object. Returns the cell
    count (0 when apart)."""
    m = box_lo.shape[0]
    near = int(0)
    for a in range(m):
        for c in range(a + 1, m):
            gap = wp.max(box_lo[c] - box_hi[a], box_lo[a] - box_hi[c])  # per axis, m
            limit_ac = (object_reach[a] + object_reach[c] + margin) * wp.float64(1.000000001)
            if wp.max(wp.max(gap[0], gap[1]), gap[2]) < limit_ac:
                near = 1
    close[0] = near
    if near == 0:
        return int(0)
    width = width0
    cells = wp.float64(0.0)
    while True:  # the cell counts in float64 (a tiny width cannot overflow them)
        cells = wp.float64(0.0)
        for c in range(m):
            e = box_hi[c] - box_lo[c]
            cells += (wp.floor(e[0] / width) + wp.float64(1.0)) * (wp.floor(e[1] / width) + wp.float64(1.0)) * (
                wp.floor(e[2] / width) + wp.float64(1.0))  # fmt: skip
        if cells <= wp.float64(limit):
            break
        width = width * wp.max(wp.float64(1.05), wp.pow(cells / wp.float64(limit), wp.float64(1.0) / wp.float64(3.0)))
    grid_width[0] = width
    total = int(0)
    for c in range(m):
        e = box_hi[c] - box_lo[c]
        dims = wp.vec3i(int(wp.floor(e[0] / width)) + 1, int(wp.floor(e[1] / width)) + 1, int(wp.floor(e[2] / width)) + 1)
        grid_dims[c] = dims
        grid_first[c] = total
        total += dims[0] * dims[1] * dims[2]
    return total


@wp.func
def _point_cell(p: wp.vec3d, c: int, width: wp.float64, box_lo: wp.array(dtype=wp.vec3d),
                grid_dims: wp.array(dtype=wp.vec3i), grid_first: wp.array(dtype=wp.int32)):  # fmt: skip
    """The cell of a point ``p`` (m) of object ``c`` in the grids of :func:`_grid_layout` (z varying fastest)."""
    dims = grid_dims[c]
    lo = box_lo[c]
    x = _cell_of(p[0] - lo[0], width, dims[0])
    y = _cell_of(p[1] - lo[1], width, dims[1])
    z = _cell_of(p[2] - lo[2], width, dims[2])
    return grid_first[c] + (x * dims[1] + y) * dims[2] + z


@wp.kernel
def _grid_kernel(
    points: wp.array(dtype=wp.vec3d),
    object_ids: wp.array(dtype=wp.int32),
    radii: wp.array(dtype=wp.float64),
    point_margins: wp.array(dtype=wp.float64),
    margin: wp.float64,
    width0: wp.array(dtype=wp.float64),
    limit: int,
    pair_count: wp.array(dtype=wp.int32),
    box_lo: wp.array(dtype=wp.vec3d),
    box_hi: wp.array(dtype=wp.vec3d),
    object_reach: wp.array(dtype=wp.float64),
    close: wp.array(dtype=wp.int32),
    grid_width: wp.array(dtype=wp.float64),
    grid_dims: wp.array(dtype=wp.vec3i),
    grid_first: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    cursor: wp.array(dtype=wp.int32),
    point_cell: wp.array(dtype=wp.int32),
    cell_points: wp.array(dtype=wp.int32),
):
    """One thread (the CPU's path): what :func:`_candidate_pairs_kernel` searches, from the points (m objects,
    ``object_ids`` 0..m-1). Each object's bounding box of its points and its reach (largest radius plus own
    margin), then :func:`_grid_layout` (nothing more when every two objects are apart), then ``cell_start[c]``, the
    first of cell c's points in ``cell_points``: a counting sort of the points by cell (``cursor``, ``point_cell``
    scratch). A serial loop over the points: the host's array calls it replaces cost more than the arithmetic.
    ``width0[0]`` is read from the device (the launch is packed once and replayed); ``pair_count[0]`` is cleared for
    the search that follows. :class:`PairFinder` runs the same steps as parallel launches on other devices."""
    pair_count[0] = 0
    n = points.shape[0]
    for c in range(box_lo.shape[0]):
        _empty_box(c, box_lo, box_hi, object_reach)
    for i in range(n):
        c = object_ids[i]
        box_lo[c] = wp.min(box_lo[c], points[i])
        box_hi[c] = wp.max(box_hi[c], points[i])
        object_reach[c] = wp.max(object_reach[c], radii[i] + point_margins[i])
    total = _grid_layout(margin, width0[0], limit, box_lo, box_hi, object_reach, close, grid_width, grid_dims,
                         grid_first)  # fmt: skip
    if close[0] == 0:
        return
    width = grid_width[0]
    for k in range(total + 1):
        cell_start[k] = 0
    for i in range(n):
        cell = _point_cell(points[i], object_ids[i], width, box_lo, grid_dims, grid_first)
        point_cell[i] = cell
        cell_start[cell + 1] += 1
    for k in range(total):
        cell_start[k + 1] += cell_start[k]
        cursor[k] = cell_start[k]
    for i in range(n):
        cell = point_cell[i]
        cell_points[cursor[cell]] = i
        cursor[cell] += 1


# the same grid as parallel launches (devices other than the CPU, where one thread's loops would be slow): boxes by
# atomic min / max, the layout in one thread, a count per cell by atomic adds, a scan, a scatter by atomic adds (the
# order within a cell is free: the search's pairs come out sorted)
@wp.kernel
def _grid_reset_kernel(pair_count: wp.array(dtype=wp.int32), box_lo: wp.array(dtype=wp.vec3d),
                       box_hi: wp.array(dtype=wp.vec3d), object_reach: wp.array(dtype=wp.float64)):  # fmt: skip
    c = wp.tid()
    if c == 0:
        pair_count[0] = 0
    _empty_box(c, box_lo, box_hi, object_reach)


@wp.kernel
def _grid_boxes_kernel(points: wp.array(dtype=wp.vec3d), object_ids: wp.array(dtype=wp.int32),
                       radii: wp.array(dtype=wp.float64), point_margins: wp.array(dtype=wp.float64),
                       box_lo: wp.array(dtype=wp.vec3d), box_hi: wp.array(dtype=wp.vec3d),
                       object_reach: wp.array(dtype=wp.float64)):  # fmt: skip
    i = wp.tid()
    c = object_ids[i]
    wp.atomic_min(box_lo, c, points[i])
    wp.atomic_max(box_hi, c, points[i])
    wp.atomic_max(object_reach, c, radii[i] + point_margins[i])


@wp.kernel
def _grid_layout_kernel(margin: wp.float64, width0: wp.array(dtype=wp.float64), limit: int,
                        box_lo: wp.array(dtype=wp.vec3d), box_hi: wp.array(dtype=wp.vec3d),
                        object_reach: wp.array(dtype=wp.float64), close: wp.array(dtype=wp.int32),
                        grid_width: wp.array(dtype=wp.float64), grid_dims: wp.array(dtype=wp.vec3i),
                        grid_first: wp.array(dtype=wp.int32)):  # fmt: skip
    _grid_layout(margin, width0[0], limit, box_lo, box_hi, object_reach, close, grid_width, grid_dims, grid_first)


@wp.kernel
def _grid_count_kernel(points: wp.array(dtype=wp.vec3d), object_ids: wp.array(dtype=wp.int32),
                       close: wp.array(dtype=wp.int32), grid_width: wp.array(dtype=wp.float64),
                       box_lo: wp.array(dtype=wp.vec3d), grid_dims: wp.array(dtype=wp.vec3i),
                       grid_first: wp.array(dtype=wp.int32), counts: wp.array(dtype=wp.int32),
                       point_cell: wp.array(dtype=wp.int32)):  # fmt: skip
    if close[0] == 0:
        return
    i = wp.tid()
    cell = _point_cell(points[i], object_ids[i], grid_width[0], box_lo, grid_dims, grid_first)
    point_cell[i] = cell
    wp.atomic_add(counts, cell, 1)


@wp.kernel
def _grid_scatter_kernel(close: wp.array(dtype=wp.int32), point_cell: wp.array(dtype=wp.int32),
                         cursor: wp.array(dtype=wp.int32), cell_points: wp.array(dtype=wp.int32)):  # fmt: skip
    if close[0] == 0:
        return
    i = wp.tid()
    cell_points[wp.atomic_add(cursor, point_cell[i], 1)] = i


class NonFiniteInput(ValueError):
    """:meth:`PairFinder.find` was given a non-finite sphere centre or margin (the message names which)."""


def _check_finite(points_m: np.ndarray, margins_m: np.ndarray) -> None:
    """Refuse non-finite sphere centres or margins (:class:`NonFiniteInput`): the device grid turns coordinates
    into cell indices, where a NaN would index outside its arrays."""
    for name, values in (("points_m", points_m), ("point_margins_m", margins_m)):
        finite = np.isfinite(values)
        if not finite.all():
            row = int(np.argwhere(~finite)[0][0])
            raise NonFiniteInput(f"PairFinder.find: {name}[{row}] = {np.asarray(values)[row].tolist()} is not finite")


@dataclass(frozen=True)
class _ObjectTable:
    """What :class:`PairFinder` derives from the object ids and radii (reused while they stay the same).

    Attributes:
        object_ids, radii_m: the arrays as passed (copies).
        dense: (n,) object index 0..m-1 per point on the device (int32).
        radii: (n,) radii on the device, m.
        ordered: whether ``dense`` ascends with the point index.
        num_objects: m.  max_radius_m: the largest radius, m.
    """

    object_ids: np.ndarray
    radii_m: np.ndarray
    dense: wp.array
    radii: wp.array
    ordered: bool
    num_objects: int
    max_radius_m: float

    def matches(self, object_ids: np.ndarray, radii_m: np.ndarray) -> bool:
        return (
            self.object_ids.shape == object_ids.shape
            and np.array_equal(self.object_ids, object_ids)
            and np.array_equal(self.radii_m, radii_m)
        )


@dataclass(frozen=True)
class _Grid:
    """The device arrays :func:`_grid_kernel` fills and :func:`_candidate_pairs_kernel` reads (see there), for n
    points of m objects (a finder keeps one per (n, m) and reuses it every call)."""

    box_lo: wp.array
    box_hi: wp.array
    reach: wp.array
    close: wp.array
    width: wp.array
    dims: wp.array
    first: wp.array
    cell_start: wp.array
    cursor: wp.array
    point_cell: wp.array
    cell_points: wp.array

    @classmethod
    def allocate(cls, num_points: int, num_objects: int, limit: int, device: str) -> _Grid:
        def zeros(length: int, dtype) -> wp.array:
            return wp.zeros(length, dtype=dtype, device=device)

        return cls(
            zeros(num_objects, wp.vec3d), zeros(num_objects, wp.vec3d), zeros(num_objects, wp.float64),
            zeros(1, wp.int32), zeros(1, wp.float64), zeros(num_objects, wp.vec3i), zeros(num_objects, wp.int32),
            zeros(limit + 1, wp.int32), zeros(limit + 1, wp.int32), zeros(num_points, wp.int32),
            zeros(num_points, wp.int32),
        )  # fmt: skip


class PairFinder:
    """Broad phase over all cubature spheres, with a grid of cells over each object's bounding box (rebuilt on every
    call).

    A sphere queries only the objects whose bounding box, grown by its reach, it lies in, and visits only the
    cells of that object's grid within its query radius, never its own object's; the radius is its own radius and
    margins plus the largest radius and margin of that object (not of all spheres). Cells are ``cell_fraction``
    of the largest query radius wide (wider where the grids would otherwise hold more than
    ``max_cells_per_point`` cells per sphere). Each object's grid holds only its own points, so no two places
    share a cell. The boxes, the test whether any two objects are close enough to search at all, and the grids
    (a counting sort of the points by cell) are built on the device, on the CPU in one single-thread launch
    (:func:`_grid_kernel`), elsewhere (``parallel_grid``, the default off the CPU) in parallel launches with atomics
    and a scan; the search is one more launch: the host only uploads the points and margins and reads the pairs
    back. The object ids and radii are uploaded again only when they change (a solver passes the same arrays every
    step)."""

    def __init__(self, device: str = "cpu", cell_fraction: float = 0.25, max_cells_per_point: float = 8.0,
                 parallel_grid: bool | None = None) -> None:  # fmt: skip
        self.device = device
        self.cell_fraction = float(cell_fraction)
        self.max_cells_per_point = float(max_cells_per_point)
        self.parallel_grid = (str(device) != "cpu") if parallel_grid is None else bool(parallel_grid)
        wp.init()
        self.capacity = 1024
        self._count = wp.zeros(1, dtype=wp.int32, device=device)
        self._pairs = wp.zeros((self.capacity, 2), dtype=wp.int32, device=device)
        self._objects: _ObjectTable | None = None
        self._grid: tuple[tuple[int, int, int], _Grid] | None = None
        # the launches packed once and replayed while their arrays and scalars stay the same (packing a dozen arrays
        # costs more than the grid kernel's work): (key, the grid's build, the search launch)
        self._launches: tuple[tuple, Callable[[], None], wp.Launch] | None = None
        # per input name: a device array kept between calls and, on CPU, the numpy view it is written through
        self._staged: dict[str, tuple[wp.array, np.ndarray | None]] = {}
        self.builds = 0  # grids built (calls whose objects were apart build none)

    def _object_table(self, object_ids: np.ndarray, radii_m: np.ndarray) -> _ObjectTable:
        if self._objects is not None and self._objects.matches(object_ids, radii_m):
            return self._objects
        _, dense = np.unique(object_ids, return_inverse=True)
        dense = dense.reshape(-1).astype(np.int32)
        radii = np.asarray(radii_m, dtype=np.float64)
        self._objects = _ObjectTable(
            np.array(object_ids, copy=True),
            radii.copy(),
            wp.array(dense, dtype=wp.int32, device=self.device),
            wp.array(radii, dtype=wp.float64, device=self.device),
            bool(np.all(dense[1:] >= dense[:-1])),
            int(dense.max()) + 1 if len(dense) else 0,
            float(radii.max()) if len(radii) else 0.0,
        )
        return self._objects

    def _grid_of(self, num_points: int, objects: _ObjectTable) -> _Grid:
        """The grid arrays for ``num_points`` points of ``objects`` (kept while n and m stay the same)."""
        limit = int(max(64.0, self.max_cells_per_point * num_points))
        key = (num_points, objects.num_objects, limit)
        if self._grid is None or self._grid[0] != key:
            self._grid = (key, _Grid.allocate(num_points, objects.num_objects, limit, self.device))
        return self._grid[1]

    def _bound_launches(self, points: wp.array, objects: _ObjectTable, margins: wp.array, width0: wp.array,
                        margin_m: float) -> tuple[_Grid, Callable[[], None], wp.Launch]:  # fmt: skip
        """The grid's build (a call that also clears the pair count) and the search launch over these staged arrays
        (``width0``: the initial cell width, m, on the device), packed at first use and replayed while every array and
        scalar they were packed with is the same."""
        n = points.shape[0]
        g = self._grid_of(n, objects)
        limit = g.cell_start.shape[0] - 1
        key = (points, objects, margins, width0, g, self._pairs, self.capacity, float(margin_m))
        if self._launches is None or len(self._launches[0]) != len(key) or any(
            a is not b if isinstance(a, (wp.array, _ObjectTable, _Grid)) else a != b
            for a, b in zip(self._launches[0], key)
        ):
            if self.parallel_grid:
                build = self._parallel_build(points, objects, margins, width0, margin_m, g, limit)
            else:
                build = wp.launch(
                    _grid_kernel, dim=1, device=self.device, record_cmd=True,
                    inputs=[points, objects.dense, objects.radii, margins, wp.float64(margin_m), width0, limit,
                            self._count],
                    outputs=[g.box_lo, g.box_hi, g.reach, g.close, g.width, g.dims, g.first, g.cell_start, g.cursor,
                             g.point_cell, g.cell_points],
                ).launch  # fmt: skip
            search = wp.launch(
                _candidate_pairs_kernel, dim=n, device=self.device, record_cmd=True,
                inputs=[points, objects.dense, objects.radii, margins, g.box_lo, g.box_hi, g.reach, int(objects.ordered),
                        wp.float64(margin_m), g.width, g.close, g.dims, g.first, g.cell_start, g.cell_points,
                        self.capacity],
                outputs=[self._count, self._pairs],
            )  # fmt: skip
            self._launches = (key, build, search)
        return g, self._launches[1], self._launches[2]

    def _parallel_build(self, points: wp.array, objects: _ObjectTable, margins: wp.array, width0: wp.array,
                        margin_m: float, g: _Grid, limit: int) -> Callable[[], None]:  # fmt: skip
        """:func:`_grid_kernel`'s work as parallel launches (packed once): reset, boxes by atomic min / max, the
        layout in one thread, cell counts by atomic adds, an exclusive scan into ``cell_start``, a scatter."""
        n, m, device = points.shape[0], objects.num_objects, self.device
        reset = wp.launch(_grid_reset_kernel, dim=m, device=device, record_cmd=True,
                          inputs=[self._count, g.box_lo, g.box_hi, g.reach])  # fmt: skip
        boxes = wp.launch(_grid_boxes_kernel, dim=n, device=device, record_cmd=True,
                          inputs=[points, objects.dense, objects.radii, margins, g.box_lo, g.box_hi, g.reach])  # fmt: skip
        layout = wp.launch(_grid_layout_kernel, dim=1, device=device, record_cmd=True,
                           inputs=[wp.float64(margin_m), width0, limit, g.box_lo, g.box_hi, g.reach, g.close, g.width,
                                   g.dims, g.first])  # fmt: skip
        count = wp.launch(_grid_count_kernel, dim=n, device=device, record_cmd=True,
                          inputs=[points, objects.dense, g.close, g.width, g.box_lo, g.dims, g.first, g.cursor,
                                  g.point_cell])  # fmt: skip
        scatter = wp.launch(_grid_scatter_kernel, dim=n, device=device, record_cmd=True,
                            inputs=[g.close, g.point_cell, g.cursor, g.cell_points])  # fmt: skip

        def build() -> None:
            reset.launch()
            boxes.launch()
            layout.launch()
            g.cursor.zero_()  # the counts per cell
            count.launch()
            wp.utils.array_scan(g.cursor, g.cell_start, inclusive=False)
            wp.copy(g.cursor, g.cell_start)  # each cell's next free slot
            scatter.launch()

        return build

    def build_cells(self, points_m: np.ndarray, object_ids: np.ndarray, radii_m: np.ndarray, margin_m: float,
                    width_m: float, point_margins_m: np.ndarray | None = None) -> dict[str, np.ndarray | float | bool]:  # fmt: skip
        """What :meth:`find` builds before its search, read back (for tests and inspection): ``close`` (whether any
        two objects are close enough to search), the cell ``width`` (m, at least ``width_m``), each object's box
        ``lo`` / ``hi`` (m, 3) and ``reach`` (m,), its grid's cell counts ``dims`` (m, 3) and first cell ``first``
        (m,), each cell's first point ``cell_start`` and the points sorted by cell ``cell_points``."""
        objects = self._object_table(object_ids, radii_m)
        n = len(points_m)
        extra = np.zeros(n) if point_margins_m is None else np.asarray(point_margins_m, dtype=np.float64)
        _check_finite(points_m, extra)
        g, grid, _ = self._bound_launches(self._stage("points", points_m, wp.vec3d), objects,
                                          self._stage("margins", extra, wp.float64),
                                          self._stage("width0", np.array([width_m]), wp.float64), margin_m)  # fmt: skip
        grid()
        dims = g.dims.numpy()
        cells = int(dims.prod(1).sum())
        return {
            "close": bool(g.close.numpy()[0]), "width": float(g.width.numpy()[0]), "lo": g.box_lo.numpy(),
            "hi": g.box_hi.numpy(), "reach": g.reach.numpy(), "dims": dims, "first": g.first.numpy(),
            "cell_start": g.cell_start.numpy()[: cells + 1], "cell_points": g.cell_points.numpy(),
        }  # fmt: skip

    def find(
        self,
        points_m: np.ndarray,
        object_ids: np.ndarray,
        radii_m: np.ndarray,
        margin_m: float,
        point_margins_m: np.ndarray | None = None,
    ) -> np.ndarray:
        """Pairs (P,2) of global point indices i < j on different objects with gap < margin_m (+ the two
        points' own ``point_margins_m`` (n,) m, e.g. how far each can move in a step).

        The result is sorted lexicographically, so it is deterministic on every device.
        """
        n = points_m.shape[0]
        if n == 0:
            return np.zeros((0, 2), dtype=np.int64)
        objects = self._object_table(object_ids, radii_m)
        if objects.num_objects < 2:
            return np.zeros((0, 2), dtype=np.int64)
        extra = np.zeros(n) if point_margins_m is None else np.asarray(point_margins_m, dtype=np.float64)
        _check_finite(points_m, extra)
        query_radius = 2.0 * objects.max_radius_m + margin_m + 2.0 * float(extra.max())
        pts = self._stage("points", points_m, wp.vec3d)
        extra_wp = self._stage("margins", extra, wp.float64)
        width0 = self._stage("width0", np.array([self.cell_fraction * query_radius]), wp.float64)
        g, grid, search = self._bound_launches(pts, objects, extra_wp, width0, margin_m)
        grid()  # (clears the pair count)
        search.launch()
        found = int(self._count.numpy()[0])
        while found > self.capacity:  # more pairs than the buffer holds: a larger one, the search again
            self.capacity = int(2 ** np.ceil(np.log2(found)))
            self._pairs = wp.zeros((self.capacity, 2), dtype=wp.int32, device=self.device)
            g, grid, search = self._bound_launches(pts, objects, extra_wp, width0, margin_m)
            self._count.zero_()
            search.launch()
            found = int(self._count.numpy()[0])
        self.builds += int(g.close.numpy()[0])
        if not found:
            return np.zeros((0, 2), dtype=np.int64)
        out = self._pairs.numpy()[:found].astype(np.int64)
        # lexicographic (i, j) order: i < j < n. The launch finds them in runs (on CPU the points' order: i ascending),
        # which the stable sort (a merge sort over runs) orders in half the time of the default one
        key = np.sort(out[:, 0] * n + out[:, 1], kind="stable")
        return np.stack(np.divmod(key, n), axis=1)

    def _stage(self, name: str, values: np.ndarray, dtype) -> wp.array:
        """``values`` (n,) or (n, 3) in the finder's device array ``name`` of warp ``dtype`` (float64 scalars or
        3-vectors), kept between calls and reallocated only when the length changes: a new warp array per call
        costs more than the copy."""
        values = np.asarray(values)
        length = values.shape[0]
        kept = self._staged.get(name)
        if kept is None or kept[0].shape[0] != length:
            array = wp.zeros(length, dtype=dtype, device=self.device)
            kept = self._staged[name] = (array, array.numpy() if self.device == "cpu" else None)  # CPU: a view
        array, host = kept
        if host is not None:
            np.copyto(host, values)
        else:
            array.assign(np.ascontiguousarray(values, dtype=np.float64))
        return array


@dataclass
class PairContact:
    """Pair penalty terms: energy (J), dE/dx_i (P,3) (dE/dx_j = -grad), Hessian block (P,3,3) N/m."""

    energy: float
    grad_i: torch.Tensor
    hess: torch.Tensor
    depth_m: torch.Tensor
    normal_ji: torch.Tensor  # unit vector from j to i


def pair_depth(x_i: torch.Tensor, x_j: torch.Tensor, radius_sum_m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Penetration depth (P,) m (radius sum minus centre distance) and unit normal j -> i (P, 3) of sphere
    pairs (what :func:`pair_contact` computes its terms from)."""
    delta = x_i - x_j
    dist = delta.norm(dim=1).clamp(min=1e-12)
    return radius_sum_m - dist, delta / dist[:, None]


def pair_contact(
    x_i: torch.Tensor, x_j: torch.Tensor, radius_sum_m: torch.Tensor, stiffness_n_m: torch.Tensor
) -> PairContact:
    """Penalty between sphere pairs; ``d2E/dx_i dx_i = hess``, ``d2E/dx_i dx_j = -hess``."""
    depth, n = pair_depth(x_i, x_j, radius_sum_m)
    energy, grad_i, hess = point_terms.penalty(depth, n, stiffness_n_m, True)
    return PairContact(float(energy.sum()), grad_i, hess, depth, n)
