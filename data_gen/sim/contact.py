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
    cell_width: wp.float64,
    grid_dims: wp.array(dtype=wp.vec3i),
    grid_first: wp.array(dtype=wp.int32),
    cell_start: wp.array(dtype=wp.int32),
    cell_points: wp.array(dtype=wp.int32),
    capacity: int,
    count: wp.array(dtype=wp.int32),
    pairs: wp.array(dtype=wp.int32, ndim=2),
):
    i = wp.tid()
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


def _boxes_within_reach(lo: np.ndarray, hi: np.ndarray, reach: np.ndarray, margin_m: float) -> bool:
    """Whether some two objects' bounding boxes (m,) x (3,) of their points, m, are closer on every axis than
    their reaches (m,) m (largest radius + own margin of each) plus ``margin_m``: a pair of points passing the
    search's test needs it (the gap between the boxes bounds their distance from below). A relative 1e-9
    covers round-off."""
    gap = np.maximum(lo[None, :, :] - hi[:, None, :], lo[:, None, :] - hi[None, :, :]).max(2)  # (m, m) m
    limit = (reach[:, None] + reach[None, :] + margin_m) * (1.0 + 1e-9)
    close = gap < limit
    np.fill_diagonal(close, False)
    return bool(close.any())


@dataclass(frozen=True)
class _ObjectTable:
    """What :class:`PairFinder` derives from the object ids and radii (reused while they stay the same).

    Attributes:
        object_ids, radii_m: the arrays as passed (copies).
        dense: (n,) object index 0..m-1 per point on the device (int32); ``dense_np`` the same on the host.
        radii: (n,) radii on the device, m.
        ordered: whether ``dense`` ascends with the point index.
        order: (n,) the points sorted by object (stable); starts: (m,) where each object starts in it.
    """

    object_ids: np.ndarray
    radii_m: np.ndarray
    dense: wp.array
    dense_np: np.ndarray
    radii: wp.array
    ordered: bool
    order: np.ndarray
    starts: np.ndarray

    def matches(self, object_ids: np.ndarray, radii_m: np.ndarray) -> bool:
        return (
            self.object_ids.shape == object_ids.shape
            and np.array_equal(self.object_ids, object_ids)
            and np.array_equal(self.radii_m, radii_m)
        )

    def per_object(self, values: np.ndarray, reduce: np.ufunc) -> np.ndarray:
        """``reduce`` (np.minimum or np.maximum) of per-point ``values`` (n, ...) over each object's points."""
        return reduce.reduceat(values if self.ordered else values[self.order], self.starts, axis=0)


class PairFinder:
    """Broad phase over all cubature spheres, with a grid of cells over each object's bounding box (rebuilt on every
    call).

    A sphere queries only the objects whose bounding box, grown by its reach, it lies in, and visits only the
    cells of that object's grid within its query radius, never its own object's; the radius is its own radius and
    margins plus the largest radius and margin of that object (not of all spheres). Cells are ``cell_fraction``
    of the largest query radius wide (wider where the grids would otherwise hold more than
    ``max_cells_per_point`` cells per sphere). Each object's grid holds only its own points, so no two places
    share a cell; building it is a sort of the points by cell on the host. The object ids and radii are uploaded
    again only when they change (a solver passes the same arrays every step)."""

    def __init__(self, device: str = "cpu", cell_fraction: float = 0.25, max_cells_per_point: float = 8.0) -> None:
        self.device = device
        self.cell_fraction = float(cell_fraction)
        self.max_cells_per_point = float(max_cells_per_point)
        wp.init()
        self.capacity = 1024
        self._count = wp.zeros(1, dtype=wp.int32, device=device)
        self._pairs = wp.zeros((self.capacity, 2), dtype=wp.int32, device=device)
        self._objects: _ObjectTable | None = None
        # per input name: a device array kept between calls and, on CPU, the numpy view it is written through
        self._staged: dict[str, tuple[wp.array, np.ndarray | None]] = {}
        self.builds = 0  # grids built (calls whose objects were apart build none)

    def build_cells(self, x: np.ndarray, objects: _ObjectTable, lo: np.ndarray, hi: np.ndarray,
                    width_m: float) -> tuple[float, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
        """Each object's grid over its box ``lo``..``hi`` (m, 3) (m): cells ``width_m`` wide or wider (see the
        class), numbered object by object, z varying fastest (a row of z cells is contiguous). Returns the cell
        width (m), the grids' cell counts per axis (m, 3), each object's first cell (m,), each cell's first point in
        the sorted order (``limit + 1``, the cells beyond the grids' own starting at n: one length for every call
        with n points), and the points sorted by cell (n,)."""
        self.builds += 1
        obj = objects.dense_np
        extent = hi - lo  # (m, 3) m
        limit = int(max(64.0, self.max_cells_per_point * len(x)))
        while True:
            dims = np.floor(extent / width_m).astype(np.int64) + 1
            cells = int(dims.prod(1).sum())
            if cells <= limit:
                break
            width_m *= max(1.05, (cells / limit) ** (1.0 / 3.0))
        first = np.zeros(len(dims) + 1, dtype=np.int64)
        np.cumsum(dims.prod(1), out=first[1:])
        d = dims[obj]  # (n, 3)
        cell = np.minimum(np.floor((x - lo[obj]) / width_m).astype(np.int64), d - 1)
        flat = first[obj] + (cell[:, 0] * d[:, 1] + cell[:, 1]) * d[:, 2] + cell[:, 2]
        # (the order within a cell is free: the pairs come out sorted. 16-bit keys take numpy's radix sort)
        order = np.argsort(flat.astype(np.uint16) if cells <= 65536 else flat, kind="stable")
        start = np.zeros(limit + 1, dtype=np.int64)
        np.cumsum(np.bincount(flat, minlength=limit), out=start[1:])
        return width_m, dims, first[:-1], start, order

    def _object_table(self, object_ids: np.ndarray, radii_m: np.ndarray) -> _ObjectTable:
        if self._objects is not None and self._objects.matches(object_ids, radii_m):
            return self._objects
        _, dense = np.unique(object_ids, return_inverse=True)
        dense = dense.reshape(-1).astype(np.int32)
        ordered = bool(np.all(dense[1:] >= dense[:-1]))
        order = np.arange(len(dense)) if ordered else np.argsort(dense, kind="stable")
        radii = np.asarray(radii_m, dtype=np.float64)
        self._objects = _ObjectTable(
            np.array(object_ids, copy=True),
            radii.copy(),
            wp.array(dense, dtype=wp.int32, device=self.device),
            dense.astype(np.int64),
            wp.array(radii, dtype=wp.float64, device=self.device),
            ordered,
            order,
            np.flatnonzero(np.r_[True, np.diff(dense[order]) != 0]),
        )
        return self._objects

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
        if n == 0 or np.min(object_ids) == np.max(object_ids):  # fewer than two objects
            return np.zeros((0, 2), dtype=np.int64)
        extra = np.zeros(n) if point_margins_m is None else np.asarray(point_margins_m, dtype=np.float64)
        query_radius = 2.0 * float(radii_m.max()) + margin_m + 2.0 * float(extra.max())
        objects = self._object_table(object_ids, radii_m)
        x = np.ascontiguousarray(points_m, dtype=np.float64)
        lo_np, hi_np = objects.per_object(x, np.minimum), objects.per_object(x, np.maximum)  # bounding boxes
        reach = objects.per_object(objects.radii_m + extra, np.maximum)  # (m,) largest radius + margin, m
        if not _boxes_within_reach(lo_np, hi_np, reach, margin_m):  # objects apart (in flight): no search
            return np.zeros((0, 2), dtype=np.int64)
        pts = self._stage("points", x, wp.vec3d)
        width_m, dims, first, start, order = self.build_cells(x, objects, lo_np, hi_np, self.cell_fraction * query_radius)
        grid = [self._stage("grid_dims", dims, wp.vec3i), self._stage("grid_first", first, wp.int32),
                self._stage("cell_start", start, wp.int32), self._stage("cell_points", order, wp.int32)]  # fmt: skip
        lo, hi = self._stage("box_lo", lo_np, wp.vec3d), self._stage("box_hi", hi_np, wp.vec3d)
        extra_wp, reach_wp = self._stage("margins", extra, wp.float64), self._stage("reach", reach, wp.float64)
        while True:
            self._count.zero_()
            wp.launch(
                _candidate_pairs_kernel,
                dim=n,
                inputs=[
                    pts,
                    objects.dense,
                    objects.radii,
                    extra_wp,
                    lo,
                    hi,
                    reach_wp,
                    int(objects.ordered),
                    wp.float64(margin_m),
                    wp.float64(width_m),
                    *grid,
                    self.capacity,
                ],
                outputs=[self._count, self._pairs],
                device=self.device,
            )
            found = int(self._count.numpy()[0])
            if found <= self.capacity:
                break
            self.capacity = int(2 ** np.ceil(np.log2(found)))
            self._pairs = wp.zeros((self.capacity, 2), dtype=wp.int32, device=self.device)
        out = self._pairs.numpy()[:found].astype(np.int64)
        # lexicographic (i, j) order: i < j < n. The launch finds them in runs (on CPU the points' order: i ascending),
        # which the stable sort (a merge sort over runs) orders in half the time of the default one
        key = np.sort(out[:, 0] * n + out[:, 1], kind="stable")
        return np.stack(np.divmod(key, n), axis=1)

    def _stage(self, name: str, values: np.ndarray, dtype) -> wp.array:
        """``values`` (n,) or (n, 3) in the finder's device array ``name`` of warp ``dtype`` (float64 or int32
        scalars or 3-vectors), kept between calls and reallocated only when the length changes: a new warp array per
        call costs more than the copy."""
        np_dtype = np.int32 if dtype in (wp.int32, wp.vec3i) else np.float64
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
            array.assign(np.ascontiguousarray(values, dtype=np_dtype))
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
