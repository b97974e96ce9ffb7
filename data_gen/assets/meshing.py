"""Cached surface meshes and solid volumes of shapes, reusing canonical meshes under scaling.

Two questions are asked of every object per sequence: "what surface is visible"
(``surface_mesh``, sampled for rendering Gaussians) and "how much material is
there" (``solid_volume_m3``, mass = density x volume). Both are answered by
decomposing the shape tree before meshing anything:

* ``Scaled(child, s)``: the child's mesh at spacing / s, vertices scaled by s
  (volume x s^3) — one canonical mesh serves every random size of an object;
* ``Transformed(child, t, q)``: the child's mesh moved rigidly;
* ``Shell(child, t)``: the visible surface is the child's outer surface only (the
  inner wall of a closed shell is never seen); the volume is
  V(child) - V(cavity), each a smooth solid meshed on its own grid, so a wall far
  thinner than the grid spacing still gets the right material volume;
* shapes that carry their own geometry (``MeshShape``, ``VoxelShape``: anything
  with ``own_surface_mesh()`` and ``own_volume_m3()``) answer directly;
* anything else: marching tetrahedra (``shapes.mesh_sdf``), cached in memory by
  (shape, spacing rounded to 6 significant digits) and, after
  ``enable_disk_cache(dir)``, on disk: one ``.npz`` per mesh named by the SHA-256
  of (the shape's repr, the spacing, the source of ``shapes.py``), so editing
  the SDF code invalidates every entry; written atomically (tmp + rename), so
  parallel workers can share one directory.

Meshes returned here are shared cache entries: callers that modify them must copy.
"""

from __future__ import annotations

import functools
import hashlib
import os
from pathlib import Path

import numpy as np
import trimesh

from data_gen.assets import shapes as _shapes_module
from data_gen.assets.shapes import Scaled, Shape, Shell, Transformed, mesh_sdf
from newtphys.rotations import quat_to_matrix

MESH_CACHE_SIZE = 256  # canonical meshes kept in memory (34 library objects x a few spacings)


def _key(spacing_m: float) -> float:
    """Spacing rounded to 6 significant digits, so s * h / s hits the cache entry of h."""
    h = float(spacing_m)
    if not (np.isfinite(h) and h > 0.0):
        raise ValueError(f"spacing_m must be a finite value > 0 m, got {spacing_m}")
    return float(f"{h:.6g}")


_disk_cache_dir: Path | None = None


def enable_disk_cache(directory: str | os.PathLike[str] | None) -> None:
    """Also keep marching-tetrahedra meshes in ``directory`` (created if needed); None turns it off."""
    global _disk_cache_dir
    _disk_cache_dir = None if directory is None else Path(directory)
    if _disk_cache_dir is not None:
        _disk_cache_dir.mkdir(parents=True, exist_ok=True)


@functools.cache
def _code_digest() -> str:
    return hashlib.sha256(Path(_shapes_module.__file__).read_bytes()).hexdigest()


def disk_cache_key(shape: Shape, spacing_m: float) -> str:
    """SHA-256 hex of (shape description, spacing, meshing/SDF source code)."""
    text = f"{shape!r}|{_key(spacing_m)!r}|{_code_digest()}"
    return hashlib.sha256(text.encode()).hexdigest()


@functools.lru_cache(maxsize=MESH_CACHE_SIZE)
def _marched(shape: Shape, spacing_m: float) -> trimesh.Trimesh:
    if _disk_cache_dir is None:
        return mesh_sdf(shape, spacing_m=spacing_m)
    path = _disk_cache_dir / f"mesh-{disk_cache_key(shape, spacing_m)}.npz"
    if path.is_file():
        with np.load(path) as data:
            return trimesh.Trimesh(data["vertices"], data["faces"], process=False)
    mesh = mesh_sdf(shape, spacing_m=spacing_m)
    tmp = path.with_name(f"{path.stem}.{os.getpid()}.tmp.npz")
    np.savez(tmp, vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces))
    os.replace(tmp, path)
    return mesh


def _has_own_geometry(shape: Shape) -> bool:
    return hasattr(shape, "own_surface_mesh") and hasattr(shape, "own_volume_m3")


def _scaled_copy(mesh: trimesh.Trimesh, scale: float) -> trimesh.Trimesh:
    return trimesh.Trimesh(np.asarray(mesh.vertices) * scale, mesh.faces, visual=mesh.visual, process=False)


def surface_mesh(shape: Shape, spacing_m: float) -> trimesh.Trimesh:
    """The visible (outer) surface of ``shape`` as a watertight mesh, m (shared cache entry: copy to modify).

    Imported meshes (``MeshShape``) are returned as loaded, which may be open.
    """
    h = _key(spacing_m)
    if isinstance(shape, Scaled):
        return _scaled_copy(surface_mesh(shape.child, h / shape.scale), shape.scale)
    if isinstance(shape, Transformed):
        m = surface_mesh(shape.child, h)
        rot = quat_to_matrix(np.asarray(shape.rotation_wxyz, np.float64))
        v = np.asarray(m.vertices) @ rot.T + np.asarray(shape.translation_m)
        return trimesh.Trimesh(v, m.faces, visual=m.visual, process=False)
    if isinstance(shape, Shell):
        return surface_mesh(shape.outer, h)
    if _has_own_geometry(shape):
        return shape.own_surface_mesh()  # type: ignore[attr-defined]
    return _marched(shape, h)


def solid_volume_m3(shape: Shape, spacing_m: float) -> float:
    """Volume of the material of ``shape``, m^3 (a shell counts its wall only)."""
    h = _key(spacing_m)
    if isinstance(shape, Scaled):
        return solid_volume_m3(shape.child, h / shape.scale) * shape.scale**3
    if isinstance(shape, Transformed):
        return solid_volume_m3(shape.child, h)
    if isinstance(shape, Shell):
        outer = solid_volume_m3(shape.outer, h)
        cavity = float(_marched(shape.cavity(), h).volume)
        return outer - cavity
    if _has_own_geometry(shape):
        return float(shape.own_volume_m3())  # type: ignore[attr-defined]
    return float(_marched(shape, h).volume)


def clear_mesh_cache() -> None:
    """Drop every cached marching-tetrahedra mesh (benchmarks use it to time cold meshing)."""
    _marched.cache_clear()
