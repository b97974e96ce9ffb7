"""Kinematic static scene: ground plane z = 0, oriented boxes and a static point cloud, queried as a
signed distance.

The scene costs no degrees of freedom. ``StaticScene.query`` evaluates the signed distance (m,
positive outside) and its outward unit normal at many points with warp kernels (CPU or CUDA);
``StaticScene.query_torch`` is the batched-torch reference used to cross-check the kernels.

Geometry known only as samples (the splat centres of a captured scene) is a :class:`StaticPoints`:
the solid is the union of balls of ``radius_m`` around the points, looked up through a warp hash grid
built once.  Its distance is exact outside the balls up to ``search_m`` from the nearest point;
further away the query reports ``search_m - radius_m``, a lower bound (conservative for the solver's
"is contact near" tests, never a false contact).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
import warp as wp

from newtphys.rotations import quat_to_matrix

_FAR_M = 1.0e30  # distance reported when the scene is empty
DEFAULT_POINT_SEARCH_M = 0.1  # hash-grid search radius of a static point cloud, m


@dataclass(frozen=True)
class StaticBox:
    """An oriented box: centre (m), half extents (m, all > 0), rotation quaternion (w, x, y, z)."""

    center_m: tuple[float, float, float]
    half_extents_m: tuple[float, float, float]
    rotation_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if len(self.center_m) != 3 or not np.all(np.isfinite(self.center_m)):
            raise ValueError(f"StaticBox center_m={self.center_m!r} must be 3 finite numbers")
        he = np.asarray(self.half_extents_m, dtype=np.float64)
        if he.shape != (3,) or not np.all(he > 0) or not np.all(np.isfinite(he)):
            raise ValueError(f"StaticBox half_extents_m={self.half_extents_m!r} must be 3 finite numbers > 0")
        q = np.asarray(self.rotation_wxyz, dtype=np.float64)
        if q.shape != (4,):
            raise ValueError(f"StaticBox rotation_wxyz={self.rotation_wxyz!r} must be 4 numbers (w, x, y, z)")
        try:
            quat_to_matrix(q)
        except ValueError as exc:
            raise ValueError(f"StaticBox rotation_wxyz={self.rotation_wxyz!r}: {exc}") from None

    @property
    def rotation(self) -> np.ndarray:
        """World-from-box rotation matrix (3, 3)."""
        return quat_to_matrix(self.rotation_wxyz)


@wp.func
def _box_sdf(p_world: wp.vec3d, center: wp.vec3d, rot: wp.mat33d, half: wp.vec3d):
    """Signed distance (m) and outward normal of one oriented box."""
    p = wp.transpose(rot) * (p_world - center)
    q = wp.vec3d(wp.abs(p[0]) - half[0], wp.abs(p[1]) - half[1], wp.abs(p[2]) - half[2])
    zero = wp.float64(0.0)
    qo = wp.vec3d(wp.max(q[0], zero), wp.max(q[1], zero), wp.max(q[2], zero))
    outside = wp.length(qo)
    inside = wp.min(wp.max(q[0], wp.max(q[1], q[2])), zero)
    n_local = wp.vec3d(zero, zero, zero)
    if outside > zero:
        n_local = wp.vec3d(qo[0] * wp.sign(p[0]), qo[1] * wp.sign(p[1]), qo[2] * wp.sign(p[2])) / outside
    else:
        axis = int(0)
        if q[1] > q[axis]:
            axis = 1
        if q[2] > q[axis]:
            axis = 2
        s = wp.float64(1.0)
        if p[axis] < zero:
            s = wp.float64(-1.0)
        n_local[axis] = s
    return outside + inside, rot * n_local


@wp.func
def boxes_distance(
    p: wp.vec3d,
    has_ground: int,
    box_centers: wp.array(dtype=wp.vec3d),
    box_rotations: wp.array(dtype=wp.mat33d),
    box_half_extents: wp.array(dtype=wp.vec3d),
    far_m: wp.float64,
):
    """Signed distance (m) and outward normal of point ``p`` to the ground (if any) and the boxes; the
    ground wins ties. Shared by the query kernel and the solver's contact kernels."""
    best = far_m
    best_n = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(1.0))
    if has_ground != 0:
        best = p[2]
    for b in range(box_centers.shape[0]):
        d, n = _box_sdf(p, box_centers[b], box_rotations[b], box_half_extents[b])
        if d < best:
            best = d
            best_n = n
    return best, best_n


@wp.func
def points_distance(
    grid: wp.uint64,
    p: wp.vec3d,
    static_points: wp.array(dtype=wp.vec3d),
    radius_m: wp.float64,
    search_m: wp.float64,
    best_in: wp.float64,
    best_n_in: wp.vec3d,
):
    """Lower a distance ``best_in`` (m) and normal to that of the union of balls around the static points
    (hash-grid search within ``search_m``)."""
    best = search_m - radius_m
    best_n = wp.vec3d(wp.float64(0.0), wp.float64(0.0), wp.float64(1.0))
    found = int(0)
    pf = wp.vec3(wp.float32(p[0]), wp.float32(p[1]), wp.float32(p[2]))
    query = wp.hash_grid_query(grid, pf, wp.float32(search_m))
    index = int(0)
    while wp.hash_grid_query_next(query, index):
        delta = p - static_points[index]
        dist = wp.length(delta)
        d = dist - radius_m
        if d < best and dist > wp.float64(0.0):
            best = d
            best_n = delta / dist
            found = 1
    out = best_in
    out_n = best_n_in
    if best < best_in:
        out = best
        if found != 0:
            out_n = best_n
    return out, out_n


@wp.kernel
def _scene_sdf_kernel(
    points: wp.array(dtype=wp.vec3d),
    has_ground: int,
    box_centers: wp.array(dtype=wp.vec3d),
    box_rotations: wp.array(dtype=wp.mat33d),
    box_half_extents: wp.array(dtype=wp.vec3d),
    far_m: wp.float64,
    sdf_out: wp.array(dtype=wp.float64),
    normal_out: wp.array(dtype=wp.vec3d),
):
    tid = wp.tid()
    d, n = boxes_distance(points[tid], has_ground, box_centers, box_rotations, box_half_extents, far_m)
    sdf_out[tid] = d
    normal_out[tid] = n


@wp.kernel
def _points_sdf_kernel(
    grid: wp.uint64,
    points: wp.array(dtype=wp.vec3d),
    static_points: wp.array(dtype=wp.vec3d),
    radius_m: wp.float64,
    search_m: wp.float64,
    sdf_out: wp.array(dtype=wp.float64),
    normal_out: wp.array(dtype=wp.vec3d),
):
    """Lower sdf_out/normal_out to the distance of the union of balls around the static points."""
    tid = wp.tid()
    d, n = points_distance(grid, points[tid], static_points, radius_m, search_m, sdf_out[tid], normal_out[tid])
    sdf_out[tid] = d
    normal_out[tid] = n


@dataclass(frozen=True, eq=False)
class StaticPoints:
    """Static geometry known by surface samples: solid within ``radius_m`` of any of ``points_m``.

    Attributes:
        points_m: (n, 3) world positions, m (n >= 1, finite).
        radius_m: ball radius around each point, m (> 0); at least the point spacing, so the balls close
            the surface between samples.
        search_m: hash-grid search radius, m (> radius_m); distances beyond it are reported as
            ``search_m - radius_m`` (a lower bound).
    """

    points_m: np.ndarray
    radius_m: float
    search_m: float = DEFAULT_POINT_SEARCH_M

    def __post_init__(self) -> None:
        pts = np.ascontiguousarray(self.points_m, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0 or not np.all(np.isfinite(pts)):
            raise ValueError(f"StaticPoints points_m must be finite with shape (n >= 1, 3); got {pts.shape}")
        if not (self.radius_m > 0 and np.isfinite(self.radius_m)):
            raise ValueError(f"StaticPoints radius_m={self.radius_m!r} must be > 0 (m)")
        if not self.search_m > self.radius_m:
            raise ValueError(
                f"StaticPoints search_m={self.search_m!r} must exceed radius_m={self.radius_m!r} (m)"
            )
        object.__setattr__(self, "points_m", pts)


@dataclass(frozen=True)
class StaticScene:
    """Ground plane z = 0 (optional), oriented boxes and an optional static point cloud; the union is
    the solid static geometry."""

    ground: bool = True
    boxes: tuple[StaticBox, ...] = field(default_factory=tuple)
    points: StaticPoints | None = None
    _cache: dict = field(default_factory=dict, init=False, repr=False, compare=False, hash=False)

    def _box_arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        if not self.boxes:
            return np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3))
        centers = np.array([b.center_m for b in self.boxes], dtype=np.float64)
        rots = np.stack([b.rotation for b in self.boxes])
        halves = np.array([b.half_extents_m for b in self.boxes], dtype=np.float64)
        return centers, rots, halves

    def query(
        self, points_m: np.ndarray | torch.Tensor, device: str = "cpu"
    ) -> tuple[np.ndarray, np.ndarray]:
        """Signed distance (n,) m and outward unit normal (n,3) at ``points_m`` (n,3), via a warp kernel.

        The box arrays are uploaded once per device and cached on the scene (the scene is immutable).
        """
        pts = _as_points(points_m)
        n = pts.shape[0]
        if n == 0:
            return np.zeros(0), np.zeros((0, 3))
        if not self.boxes and self.points is None:  # the ground alone (or nothing): the kernel's values, directly
            sdf = pts[:, 2].copy() if self.ground else np.full(n, _FAR_M)
            normals = np.zeros((n, 3))
            normals[:, 2] = 1.0
            return sdf, normals
        boxes = self._device_boxes(device)
        sdf = wp.empty(n, dtype=wp.float64, device=device)
        normals = wp.empty(n, dtype=wp.vec3d, device=device)
        wp.launch(
            _scene_sdf_kernel,
            dim=n,
            inputs=[
                wp.array(pts, dtype=wp.vec3d, device=device, copy=False),
                int(self.ground),
                *boxes,
                wp.float64(_FAR_M),
            ],
            outputs=[sdf, normals],
            device=device,
        )
        if self.points is not None:
            grid, static_points = self._device_points(device)
            wp.launch(
                _points_sdf_kernel,
                dim=n,
                inputs=[
                    grid.id,
                    wp.array(pts, dtype=wp.vec3d, device=device, copy=False),
                    static_points,
                    wp.float64(self.points.radius_m),
                    wp.float64(self.points.search_m),
                ],
                outputs=[sdf, normals],
                device=device,
            )
        return sdf.numpy(), normals.numpy()

    def _device_points(self, device: str) -> tuple[wp.HashGrid, wp.array]:
        """The static points' hash grid (cell = search radius) and float64 positions, built once per device."""
        key = ("points", device)
        cached = self._cache.get(key)
        if cached is None:
            pts = self.points.points_m
            extent = np.ptp(pts, axis=0) / self.points.search_m
            dims = [int(np.clip(np.ceil(e) + 1, 1, 128)) for e in extent]
            grid = wp.HashGrid(*dims, device=device)
            grid.build(wp.array(pts.astype(np.float32), dtype=wp.vec3, device=device), float(self.points.search_m))
            cached = (grid, wp.array(pts, dtype=wp.vec3d, device=device))
            self._cache[key] = cached
        return cached

    def _device_boxes(self, device: str) -> tuple[wp.array, wp.array, wp.array]:
        cached = self._cache.get(device)
        if cached is None:
            centers, rots, halves = self._box_arrays()
            cached = (
                wp.array(centers, dtype=wp.vec3d, device=device),
                wp.array(rots, dtype=wp.mat33d, device=device),
                wp.array(halves, dtype=wp.vec3d, device=device),
            )
            self._cache[device] = cached
        return cached

    def query_torch(self, points_m: np.ndarray | torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Batched-torch reference of :meth:`query` (float64)."""
        p = torch.as_tensor(_as_points(points_m))
        n = p.shape[0]
        best = torch.full((n,), _FAR_M, dtype=torch.float64)
        best_n = torch.zeros((n, 3), dtype=torch.float64)
        best_n[:, 2] = 1.0
        if self.ground:
            best = p[:, 2].clone()
        for box in self.boxes:  # loop over boxes, batched over points
            rot = torch.as_tensor(box.rotation)
            half = torch.as_tensor(np.asarray(box.half_extents_m, dtype=np.float64))
            local = (p - torch.as_tensor(np.asarray(box.center_m, dtype=np.float64))) @ rot
            q = local.abs() - half
            qo = q.clamp(min=0.0)
            outside = qo.norm(dim=1)
            inside = q.max(dim=1).values.clamp(max=0.0)
            n_out = qo * torch.sign(local) / outside.clamp(min=1e-300)[:, None]
            axis = q.argmax(dim=1)
            n_in = torch.zeros_like(local)
            n_in[torch.arange(n), axis] = torch.where(local[torch.arange(n), axis] < 0, -1.0, 1.0).double()
            n_local = torch.where((outside > 0)[:, None], n_out, n_in)
            d = outside + inside
            closer = d < best
            best = torch.where(closer, d, best)
            best_n = torch.where(closer[:, None], n_local @ rot.T, best_n)
        if self.points is not None:
            cloud = torch.as_tensor(self.points.points_m)
            for start in range(0, n, 4096):  # chunks of query points, brute force over the cloud
                chunk = slice(start, start + 4096)
                dist = torch.cdist(p[chunk], cloud)
                nearest, index = dist.min(dim=1)
                d = torch.where(
                    nearest < self.points.search_m,
                    nearest - self.points.radius_m,
                    torch.full_like(nearest, self.points.search_m - self.points.radius_m),
                )
                normal = (p[chunk] - cloud[index]) / nearest.clamp(min=1e-300)[:, None]
                closer = d < best[chunk]
                in_reach = closer & (nearest < self.points.search_m)
                best_n[chunk] = torch.where(in_reach[:, None], normal, best_n[chunk])
                best[chunk] = torch.where(closer, d, best[chunk])
        return best, best_n


def _as_points(points_m: np.ndarray | torch.Tensor) -> np.ndarray:
    if isinstance(points_m, torch.Tensor):
        points_m = points_m.detach().cpu().numpy()
    pts = np.ascontiguousarray(points_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points_m must have shape (n, 3), got {pts.shape}")
    return pts
