"""User objects from files: triangle meshes and captured 3DGS splat objects, as ``ObjectAsset``s.

Reference syntax (``registry.get_object`` forwards these)::

    file:<path>?material=<name>&up=<axis>&scale=<factor>
    ply:<path>?material=<name>&up=<axis>&scale=<factor>&voxel=<m>

* ``file:`` — a triangle mesh (OBJ, PLY, GLB/GLTF, STL, OFF; read by trimesh,
  scenes concatenated). The solid is a ``MeshShape`` (exact distance, sign by
  winding number, so meshes with small holes still work); colours come from the
  mesh's vertex/face colours or its texture (trimesh ``to_color``), else from the
  material palette. Rendering samples the mesh as loaded.
* ``ply:`` — an INRIA 3DGS splat ``.ply``. Rendering uses the file's splats. The
  solid for simulation is a voxel fill of the splat centres (splats with opacity
  >= ``SOLID_MIN_OPACITY``): occupied voxels of edge ``voxel`` m (default: the
  largest extent / ``DEFAULT_VOXELS_ACROSS``, at least twice the centres' median
  nearest-neighbour spacing), closed by one voxel, enclosed
  holes filled; the surface runs through the centres of the outermost voxels and
  the volume follows the same convention (``voxel_shape.VoxelShape``).

Options: ``name`` — the object's name in shards and questions (default: the file's
stem; the file name and its SHA-256 are kept apart as ``source``); ``resize`` —
``false`` (default): the object keeps the size ``scale`` gives it; ``true``: scenario
sampling rescales it to a drawn ``size_m`` like a library object; ``material`` — the object's material class: when given it is the only
allowed material (scenario sampling then always uses it); when omitted the
default is ``plastic`` and every class is allowed; ``up`` — the file's up axis, one of z, y, -y, x, -x, -z
(default z), rotated to +z; ``scale`` — file units to metres (default 1; e.g.
0.01 for centimetres); ``voxel`` — splat objects only, m. The asset is centred on
its bounding box, category ``imported``. The scaled object's largest extent must
lie in [``MIN_SIZE_M``, ``MAX_SIZE_M``] m; ``get_object(..., size_m=...)`` can still
rescale it (counterfactuals do).
"""

from __future__ import annotations

import dataclasses
import functools
import warnings
from typing import Any

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from data_gen.assets.asset_uri import AssetUri, file_provenance, parse_asset_uri
from data_gen.assets.materials import ProceduralTexture, get_material, list_materials
from data_gen.assets.mesh_shape import MeshColors, MeshShape
from data_gen.assets.object_asset import MAX_SIZE_M, MIN_SIZE_M, ObjectAsset
from data_gen.assets.ply_io import UP_AXES, import_mesh, import_splats
from data_gen.assets.shapes import Shape
from data_gen.assets.voxel_shape import VoxelShape

MESH_KEYS = ("name", "material", "up", "scale", "resize")
SPLAT_KEYS = ("name", "material", "up", "scale", "resize", "voxel")
DEFAULT_MATERIAL = "plastic"
DEFAULT_VOXELS_ACROSS = 32
SOLID_MIN_OPACITY = 0.1
MIN_VOLUME_FRACTION = 1e-4  # enclosed volume / bounding-box volume below this is "zero volume"
_GREY = ProceduralTexture("solid", ((0.7, 0.7, 0.7),))


def _common_options(uri: AssetUri) -> tuple[str, str, float]:
    material = uri.get("material", DEFAULT_MATERIAL)
    get_material(material)  # unknown names list the valid ones
    up = uri.get("up", "z")
    if up not in UP_AXES:
        raise ValueError(f"{uri.scheme}:{uri.path}: option up={up!r} must be one of {', '.join(UP_AXES)}")
    scale = uri.get_float("scale", 1.0, 1e-9, 1e9)
    return material, up, scale


def _check_size(uri: AssetUri, extent_m: np.ndarray, scale: float) -> None:
    size = float(np.max(extent_m))
    if not MIN_SIZE_M <= size <= MAX_SIZE_M:
        raise ValueError(
            f"{uri.scheme}:{uri.path}: scale={scale:g} makes the object {size:.4g} m across; its largest "
            f"extent must be in [{MIN_SIZE_M}, {MAX_SIZE_M}] m (scale converts file units to metres)"
        )


def _file_key(uri: AssetUri) -> tuple[int, int]:
    if not uri.path.is_file():
        raise FileNotFoundError(f"{uri.scheme}: asset file not found: {uri.path}")
    st = uri.path.stat()
    return st.st_mtime_ns, st.st_size


def _uri(reference: str) -> AssetUri:
    scheme = reference.partition(":")[0]
    if scheme not in ("file", "ply"):
        raise ValueError(f"asset reference {reference!r}: scheme must be 'file' (mesh) or 'ply' (splats)")
    return parse_asset_uri(reference, MESH_KEYS if scheme == "file" else SPLAT_KEYS)


def check_object_reference(reference: str) -> None:
    """Cheap checks of an object reference without loading it: scheme, option keys and values, file exists."""
    uri = _uri(reference)
    _common_options(uri)
    uri.display_name()
    uri.get_bool("resize", False)
    if uri.scheme == "ply":
        uri.get_float("voxel", 0.0, 1e-5, 1.0)
    _file_key(uri)


def imported_object(reference: str) -> ObjectAsset:
    """The ``ObjectAsset`` of a ``file:`` or ``ply:`` reference (cached per reference and file version)."""
    return _load(reference, *_file_key(_uri(reference)))


@functools.lru_cache(maxsize=32)
def _load(reference: str, _mtime_ns: int, _size: int) -> ObjectAsset:
    scheme = reference.partition(":")[0]
    if scheme == "file":
        return mesh_object(reference)
    return splat_object(reference)


def default_voxel_m(points_m: np.ndarray) -> float:
    """Voxel edge, m: the largest extent / DEFAULT_VOXELS_ACROSS, but at least twice the median spacing of
    the points (nearest-neighbour distance), so a sampled surface leaves no holes between voxels."""
    p = np.asarray(points_m, np.float64)
    extent = float((p.max(axis=0) - p.min(axis=0)).max())
    sample = p[np.linspace(0, len(p) - 1, min(len(p), 20000)).astype(np.int64)]
    spacing = float(np.median(cKDTree(sample).query(sample, k=2)[0][:, 1])) if len(sample) > 1 else 0.0
    return max(extent / DEFAULT_VOXELS_ACROSS, 2.0 * spacing)


def _asset(reference: str, material: str, shape: Shape, min_feature_m: float, **extra: Any) -> ObjectAsset:
    uri = _uri(reference)
    allowed = (material,) if "material" in dict(uri.options) else tuple(list_materials())
    return ObjectAsset(
        name=uri.display_name(),
        category="imported",
        shape=shape,
        default_material=material,
        allowed_materials=allowed,
        textures=(_GREY,),
        min_feature_m=min_feature_m,
        source=file_provenance(uri.path),
        keep_scale=not uri.get_bool("resize", False),
        **extra,
    )


def mesh_object(reference: str) -> ObjectAsset:
    """A ``file:`` mesh reference as an asset (MeshShape solid, mesh colours when the file has them)."""
    uri = parse_asset_uri(reference, MESH_KEYS)
    material, up, scale = _common_options(uri)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # open meshes are fine: the winding number decides inside
        imported = import_mesh(uri.path, scale=scale, up_axis=up)
    mesh = imported.mesh
    extent = np.asarray(mesh.bounds[1] - mesh.bounds[0], np.float64)
    _check_size(uri, extent, scale)
    mesh = mesh.copy()
    mesh.apply_translation(-0.5 * (mesh.bounds[0] + mesh.bounds[1]))
    shape = MeshShape(mesh)
    volume = shape.own_volume_m3()
    if not volume > MIN_VOLUME_FRACTION * float(np.prod(np.maximum(extent, 1e-12))):
        raise ValueError(
            f"{reference}: the mesh encloses zero volume ({volume:.3g} m^3 inside a "
            f"{extent.round(4).tolist()} m box); a solid object needs a closed (or nearly closed) surface"
        )
    return _asset(
        reference,
        material,
        shape,
        float(extent.max()) / 50.0,
        mesh_colors=MeshColors.from_mesh(shape),
        normals_from_mesh=True,
    )


def splat_object(reference: str) -> ObjectAsset:
    """A ``ply:`` splat reference as an asset (file splats render; voxel-filled centres simulate)."""
    uri = parse_asset_uri(reference, SPLAT_KEYS)
    material, up, scale = _common_options(uri)
    gaussians, _ = import_splats(uri.path, scale=scale, up_axis=up)
    if len(gaussians) == 0:
        raise ValueError(f"{reference}: the file holds no splats")
    solid_pts = gaussians.means_m[gaussians.opacities >= SOLID_MIN_OPACITY].astype(np.float64)
    if len(solid_pts) == 0:
        raise ValueError(f"{reference}: no splat has opacity >= {SOLID_MIN_OPACITY} to build a solid from")
    lo, hi = solid_pts.min(axis=0), solid_pts.max(axis=0)
    extent = hi - lo
    _check_size(uri, extent, scale)
    voxel = uri.get_float("voxel", default_voxel_m(solid_pts), 1e-5, 1.0)
    centre = 0.5 * (lo + hi)
    shape = VoxelShape.from_points(solid_pts - centre, voxel)
    interior = shape.occupancy & ndimage.binary_erosion(shape.occupancy)
    if not interior.any():
        raise ValueError(
            f"{reference}: the splat centres enclose no volume at voxel={voxel:g} m (the voxelised surface has "
            "holes or is one voxel thick); pass a larger voxel=<m>"
        )
    splats = dataclasses.replace(gaussians, means_m=gaussians.means_m.astype(np.float64) - centre)
    return _asset(reference, material, shape, voxel, splats=splats)
