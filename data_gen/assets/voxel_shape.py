"""A voxel occupancy grid as a ``Shape`` (the solid of a captured splat object).

``VoxelShape.from_points`` voxelises point centres (e.g. 3DGS splat means):
voxels holding at least one point are occupied, a morphological closing bridges
gaps of up to ``close_voxels`` voxels, and enclosed holes are filled
(``scipy.ndimage.binary_fill_holes``), so a captured surface becomes a solid.
Points sampled on a surface occupy the voxels the surface passes through, so
the surface is taken through the centres of the outermost occupied voxels (not
their outer faces, which would inflate the solid by half a voxel): the SDF at a
voxel centre is -(distance to the nearest empty voxel centre - h) inside and the
distance to the nearest occupied voxel centre outside (Euclidean distance
transforms), trilinearly interpolated; outside the padded grid it continues as
the distance to the grid box. Volume = (occupied - boundary / 2) voxels x h^3,
the same half-voxel convention (boundary = occupied with an empty face neighbour).
"""

from __future__ import annotations

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray
from scipy import ndimage

from data_gen.assets.shapes import Shape, mesh_sdf

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

PAD_VOXELS = 2  # empty voxels around the occupancy so the zero level set closes inside the grid


class VoxelShape(Shape):
    """Solid made of occupied voxels of edge ``voxel_m`` (m) on a grid whose first voxel centre is ``origin_m``."""

    def __init__(self, occupancy: NDArray[np.bool_], origin_m: ArrayLike, voxel_m: float) -> None:
        occ = np.asarray(occupancy, bool)
        if occ.ndim != 3 or not occ.any():
            raise ValueError(f"VoxelShape: occupancy must be a non-empty 3D bool grid, got shape {occ.shape}")
        if not (np.isfinite(voxel_m) and voxel_m > 0.0):
            raise ValueError(f"VoxelShape: voxel_m must be a finite value > 0 m, got {voxel_m}")
        p = PAD_VOXELS
        self.occupancy = np.pad(occ, p)
        self.voxel_m = float(voxel_m)
        self.origin_m = np.asarray(origin_m, np.float64) - p * self.voxel_m
        h = self.voxel_m
        inside = ndimage.distance_transform_edt(self.occupancy) * h
        outside = ndimage.distance_transform_edt(~self.occupancy) * h
        self._grid_sdf = np.where(self.occupancy, -(inside - h), outside)
        eroded = ndimage.binary_erosion(self.occupancy, structure=ndimage.generate_binary_structure(3, 1))
        self._boundary_count = int((self.occupancy & ~eroded).sum())
        self._box_lo = self.origin_m
        self._box_hi = self.origin_m + (np.asarray(self.occupancy.shape) - 1) * h
        self._mesh: trimesh.Trimesh | None = None
        idx = np.argwhere(occ)
        self._lo = np.asarray(origin_m, np.float64) + idx.min(axis=0) * h
        self._hi = np.asarray(origin_m, np.float64) + idx.max(axis=0) * h

    @staticmethod
    def from_points(points_m: ArrayLike, voxel_m: float, close_voxels: int = 1) -> VoxelShape:
        """Solid voxelisation of points (n, 3), m: occupied cells, closed by ``close_voxels``, holes filled."""
        p = np.asarray(points_m, np.float64).reshape(-1, 3)
        if len(p) == 0:
            raise ValueError("VoxelShape.from_points: no points")
        if not (np.isfinite(voxel_m) and voxel_m > 0.0):
            raise ValueError(f"VoxelShape.from_points: voxel_m must be > 0 m, got {voxel_m}")
        if close_voxels < 0:
            raise ValueError(f"VoxelShape.from_points: close_voxels must be >= 0, got {close_voxels}")
        c = close_voxels
        lo = p.min(axis=0)
        ijk = np.floor((p - lo) / voxel_m).astype(np.int64) + c
        dims = ijk.max(axis=0) + 1 + c
        if np.prod(dims) > 64_000_000:
            raise ValueError(
                f"VoxelShape.from_points: voxel_m={voxel_m} gives {dims.tolist()} voxels (> 6.4e7)"
            )
        occ = np.zeros(tuple(int(d) for d in dims), bool)
        occ[ijk[:, 0], ijk[:, 1], ijk[:, 2]] = True
        if c > 0:
            occ = ndimage.binary_closing(occ, structure=np.ones((3, 3, 3), bool), iterations=c)
        occ = ndimage.binary_fill_holes(occ)
        origin = lo + (0.5 - c) * voxel_m  # centre of voxel (0, 0, 0)
        return VoxelShape(occ, origin, voxel_m)

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        coords = ((p - self.origin_m) / self.voxel_m).T
        d = ndimage.map_coordinates(self._grid_sdf, coords, order=1, mode="nearest")
        q = np.maximum(np.maximum(self._box_lo - p, p - self._box_hi), 0.0)
        d = d + np.linalg.norm(q, axis=1)  # outside the grid: distance to it plus the border value (> 0)
        return d, np.zeros(len(p), np.int32)

    def bounds(self) -> F64:
        return np.stack([self._lo, self._hi])

    def part_ids(self) -> tuple[int, ...]:
        return (0,)

    def own_surface_mesh(self) -> trimesh.Trimesh:
        """The zero level set meshed at half a voxel (computed once; shared: copy to modify)."""
        if self._mesh is None:
            self._mesh = mesh_sdf(self, spacing_m=self.voxel_m / 2.0)
        return self._mesh

    def own_volume_m3(self) -> float:
        return (float(self.occupancy.sum()) - 0.5 * self._boundary_count) * self.voxel_m**3
