"""A triangle mesh as a ``Shape``: signed distance by warp's closest-point query with a winding-number sign.

``MeshShape`` answers ``sdf`` for any triangle soup: the distance is the exact
Euclidean distance to the closest triangle; the sign comes from the generalised
winding number (``wp.mesh_query_point_sign_winding_number``), which stays
meaningful on meshes with holes or flipped patches. One warp launch per query
batch (no Python loop over points). ``MeshColors`` reads colours from the mesh's
visuals (vertex or face colours; textures converted by trimesh ``to_color``) at
the closest surface point.

Identity semantics: two ``MeshShape`` objects are equal only if they are the same
object (meshes are large; the asset loader caches one per file and options).
"""

from __future__ import annotations

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray
from trimesh.visual import ColorVisuals, TextureVisuals

from data_gen.assets.shapes import Shape

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

WINDING_ACCURACY = 2.0  # warp's beta: >= 2 gives an accurate winding number far from the surface
WINDING_THRESHOLD = 0.5  # inside where the winding number exceeds this
_DEVICE = "cpu"


@wp.kernel
def _closest_signed_kernel(
    mesh_id: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    max_dist: float,
    accuracy: float,
    threshold: float,
    distance: wp.array(dtype=float),
    closest: wp.array(dtype=wp.vec3),
    face: wp.array(dtype=wp.int32),
):
    tid = wp.tid()
    p = points[tid]
    q = wp.mesh_query_point_sign_winding_number(mesh_id, p, max_dist, accuracy, threshold)
    if q.result:
        c = wp.mesh_eval_position(mesh_id, q.face, q.u, q.v)
        closest[tid] = c
        face[tid] = q.face
        distance[tid] = wp.length(p - c) * q.sign
    else:
        closest[tid] = p
        face[tid] = -1
        distance[tid] = max_dist


class MeshShape(Shape):
    """A triangle mesh (m, local frame) as a solid: exact unsigned distance, winding-number sign, part 0."""

    def __init__(self, mesh: trimesh.Trimesh) -> None:
        if len(mesh.faces) == 0:
            raise ValueError("MeshShape: mesh has no faces")
        self.mesh = mesh
        self._vertices = np.asarray(mesh.vertices, np.float64)
        self._lo = self._vertices.min(axis=0)
        self._hi = self._vertices.max(axis=0)
        self._diag = float(np.linalg.norm(self._hi - self._lo))
        if not self._diag > 0.0:
            raise ValueError("MeshShape: mesh has zero extent")
        wp.init()
        self._points = wp.array(self._vertices.astype(np.float32), dtype=wp.vec3, device=_DEVICE)
        self._indices = wp.array(np.asarray(mesh.faces, np.int32).ravel(), dtype=wp.int32, device=_DEVICE)
        self._wmesh = wp.Mesh(points=self._points, indices=self._indices, support_winding_number=True)
        self._volume: float | None = None

    def __repr__(self) -> str:
        return f"MeshShape(vertices={len(self._vertices)}, faces={len(self.mesh.faces)})"

    def closest(self, points: ArrayLike) -> tuple[F64, F64, NDArray[np.int64]]:
        """(signed distance (n,) m, closest surface point (n, 3) m, closest face (n,)) for points (n, 3)."""
        p = np.asarray(points, np.float64).reshape(-1, 3)
        n = len(p)
        if n == 0:
            return np.zeros(0), np.zeros((0, 3)), np.zeros(0, np.int64)
        # float32 inside warp: query relative to the mesh centre to keep precision
        max_dist = float(np.linalg.norm(p - 0.5 * (self._lo + self._hi), axis=1).max()) + 2.0 * self._diag
        pts = wp.array(p.astype(np.float32), dtype=wp.vec3, device=_DEVICE)
        dist = wp.zeros(n, dtype=float, device=_DEVICE)
        close = wp.zeros(n, dtype=wp.vec3, device=_DEVICE)
        face = wp.zeros(n, dtype=wp.int32, device=_DEVICE)
        wp.launch(
            _closest_signed_kernel,
            dim=n,
            inputs=[self._wmesh.id, pts, max_dist, WINDING_ACCURACY, WINDING_THRESHOLD],
            outputs=[dist, close, face],
            device=_DEVICE,
        )
        c = close.numpy().astype(np.float64)
        sign = np.sign(dist.numpy().astype(np.float64))
        d = np.linalg.norm(p - c, axis=1) * np.where(sign == 0.0, 1.0, sign)  # distance in float64
        return d, c, face.numpy().astype(np.int64)

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        return self.closest(p)[0], np.zeros(len(p), np.int32)

    def bounds(self) -> F64:
        return np.stack([self._lo, self._hi])

    def part_ids(self) -> tuple[int, ...]:
        return (0,)

    def own_surface_mesh(self) -> trimesh.Trimesh:
        return self.mesh

    def own_volume_m3(self, cells_across: int = 96) -> float:
        """Enclosed volume, m^3: the mesh volume when watertight, else a winding-number count on a grid."""
        if self._volume is None:
            if self.mesh.is_watertight and self.mesh.is_winding_consistent:
                self._volume = abs(float(self.mesh.volume))
            else:
                h = float((self._hi - self._lo).max()) / cells_across
                dims = np.maximum(np.ceil((self._hi - self._lo) / h).astype(np.int64), 1)
                axes = [self._lo[i] + h * (np.arange(dims[i]) + 0.5) for i in range(3)]
                grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
                self._volume = float((self.closest(grid)[0] < 0.0).sum()) * h**3
        return self._volume


class MeshColors:
    """RGB of a mesh's visuals at the closest surface point; ``scale`` maps asset points back to the mesh frame."""

    def __init__(self, shape: MeshShape, vertex_rgb: F64 | None, face_rgb: F64 | None, scale: float = 1.0):
        if (vertex_rgb is None) == (face_rgb is None):
            raise ValueError("MeshColors: give exactly one of vertex_rgb or face_rgb")
        self.shape = shape
        self.vertex_rgb = vertex_rgb
        self.face_rgb = face_rgb
        self.scale = float(scale)

    @staticmethod
    def from_mesh(shape: MeshShape) -> MeshColors | None:
        """Colours of ``shape.mesh``'s visuals, or None when the mesh has none (or only a flat default)."""
        visual = shape.mesh.visual
        if isinstance(visual, TextureVisuals):
            if visual.uv is None or visual.material is None:
                return None
            visual = visual.to_color()
        if not isinstance(visual, ColorVisuals) or visual.kind is None:
            return None
        if visual.kind == "face":
            return MeshColors(shape, None, np.asarray(visual.face_colors, np.float64)[:, :3] / 255.0)
        return MeshColors(shape, np.asarray(visual.vertex_colors, np.float64)[:, :3] / 255.0, None)

    def scaled(self, factor: float) -> MeshColors:
        return MeshColors(self.shape, self.vertex_rgb, self.face_rgb, self.scale * factor)

    def colors_at(self, points_m: ArrayLike) -> F64:
        """RGB (n, 3) in [0, 1] at points (n, 3) in the asset frame, m."""
        p = np.asarray(points_m, np.float64).reshape(-1, 3) / self.scale
        _, c, face = self.shape.closest(p)
        face = np.clip(face, 0, len(self.shape.mesh.faces) - 1)
        if self.face_rgb is not None:
            return self.face_rgb[face]
        tri = self.shape.mesh.triangles[face]
        bary = np.clip(trimesh.triangles.points_to_barycentric(tri, c), 0.0, 1.0)
        bary /= np.maximum(bary.sum(axis=1, keepdims=True), 1e-12)
        assert self.vertex_rgb is not None
        return np.clip(np.einsum("nk,nkc->nc", bary, self.vertex_rgb[self.shape.mesh.faces[face]]), 0.0, 1.0)
