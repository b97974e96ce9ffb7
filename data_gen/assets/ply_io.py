"""3D Gaussian splat .ply files (INRIA layout) and triangle-mesh import.

Splat .ply layout (one ``vertex`` element, float32; written binary little endian, read in any PLY
encoding and scalar type, ``data_gen.assets.ply_format``):
``x y z``, ``nx ny nz``, ``f_dc_0..2``, ``f_rest_0..(3K-1)`` (channel-major:
all K coefficients of red, then green, then blue; K = (d + 1)^2 - 1 for SH
degree d, so 0, 9, 24 or 45 values), ``opacity`` (logit), ``scale_0..2``
(natural log of the std-dev, m), ``rot_0..3`` (w x y z, not normalised).
Colour = 0.5 + C0 * f_dc with C0 = 0.28209479177387814 (the degree-0 SH constant).

``read_splat_ply`` / ``write_splat_ply`` move the raw encoded fields
(``SplatPly``) bit-exactly. ``import_splats`` decodes to ``Gaussians``
with a metric scale factor and an up-axis conversion to Z-up (positions,
orientations and view-dependent SH rotate together); ``export_splats`` encodes
any ``Gaussians``. Meshes (OBJ/PLY/GLB/STL/OFF) come in through
``import_mesh`` with the same options and a watertightness check (PLY meshes in
any encoding through ``read_ply_mesh``, the rest through trimesh); inside tests
on any mesh use the generalised winding number (``points_inside_mesh``, warp).
"""

from __future__ import annotations

import dataclasses
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from data_gen.assets.ply_format import PlyFormatError, PlyList, read_ply, write_ply
from data_gen.gaussians import Gaussians
from newtphys.rotations import matrix_to_quat, quat_multiply, rotation_between

SH_C0 = 0.28209479177387814
#: A file normal (nx, ny, nz) shorter than this counts as absent (trainers often store zeros).
MIN_FILE_NORMAL = 0.5
OPACITY_EPS = 1e-6  # opacities are clipped to [eps, 1 - eps] before the logit
UP_AXES = ("z", "y", "-y", "x", "-x", "-z")
FloatArray = NDArray[np.floating[Any]]  # stored as float32 after validation
_REQUIRED = (
    "x",
    "y",
    "z",
    "f_dc_0",
    "f_dc_1",
    "f_dc_2",
    "opacity",
    "scale_0",
    "scale_1",
    "scale_2",
    "rot_0",
    "rot_1",
    "rot_2",
    "rot_3",
)
_REST_COUNTS = {0: 0, 9: 1, 24: 2, 45: 3}  # number of f_rest values -> SH degree


@dataclass
class SplatPly:
    """Raw INRIA fields, float32: positions (n, 3) m, normals (n, 3), f_dc (n, 3), f_rest (n, 3, K)
    channel-major, opacity logits (n,), log std-dev scales (n, 3), rotations (n, 4) w x y z unnormalised."""

    positions: FloatArray
    normals: FloatArray
    f_dc: FloatArray
    f_rest: FloatArray
    opacity_logit: FloatArray
    log_scales: FloatArray
    rotations_wxyz: FloatArray

    def __post_init__(self) -> None:
        n = len(self.positions)
        for name, shape in (
            ("positions", (n, 3)),
            ("normals", (n, 3)),
            ("f_dc", (n, 3)),
            ("opacity_logit", (n,)),
            ("log_scales", (n, 3)),
            ("rotations_wxyz", (n, 4)),
        ):
            arr = np.ascontiguousarray(getattr(self, name), np.float32)
            if arr.shape != shape:
                raise ValueError(f"SplatPly.{name} must have shape {shape}, got {arr.shape}")
            setattr(self, name, arr)
        rest = np.ascontiguousarray(self.f_rest, np.float32)
        if rest.ndim != 3 or rest.shape[:2] != (n, 3) or rest.shape[2] * 3 not in _REST_COUNTS:
            raise ValueError(
                f"SplatPly.f_rest must have shape (n, 3, K) with K in (0, 3, 8, 15), got {rest.shape}"
            )
        self.f_rest = rest

    @property
    def sh_degree(self) -> int:
        return _REST_COUNTS[self.f_rest.shape[2] * 3]

    def __len__(self) -> int:
        return len(self.positions)


# --------------------------------------------------------------------------- #
# Encoding
# --------------------------------------------------------------------------- #
def encode_gaussians(g: Gaussians, f_rest: ArrayLike | None = None) -> SplatPly:
    """Gaussians -> raw INRIA fields (f_dc from colour, logit opacity, log scales; normals or zeros)."""
    if g.scales_m is None or g.rotations_wxyz is None:
        raise ValueError(
            "encode_gaussians: the INRIA layout needs Gaussians given by scales_m + rotations_wxyz"
        )
    if n_flat := int((g.scales_m <= 0.0).any(axis=1).sum()):
        raise ValueError(
            f"encode_gaussians: scales_m must be > 0 m (the file stores their log); {n_flat} rows are not"
        )
    n = len(g)
    rest = np.zeros((n, 3, 0), np.float32) if f_rest is None else np.asarray(f_rest, np.float32)
    op = np.clip(g.opacities.astype(np.float64), OPACITY_EPS, 1.0 - OPACITY_EPS)
    return SplatPly(
        positions=g.means_m,
        normals=np.zeros((n, 3), np.float32) if g.normals is None else g.normals.copy(),
        f_dc=(g.colors_rgb.astype(np.float64) - 0.5) / SH_C0,
        f_rest=rest,
        opacity_logit=np.log(op / (1.0 - op)),
        log_scales=np.log(g.scales_m.astype(np.float64)),
        rotations_wxyz=g.rotations_wxyz,
    )


def decode_splats(ply: SplatPly) -> Gaussians:
    """Raw INRIA fields -> Gaussians (colour clipped to [0, 1], rotations normalised); f_rest dropped.

    Normals: the file's ``nx ny nz`` when every row has length >= ``MIN_FILE_NORMAL`` (oriented);
    otherwise none are set (most 3DGS trainers write zeros) and ``Gaussians.surface_normals`` gives
    each splat's shortest axis, of unknown sign (lit two-sided, ``data_gen.render.shading``). The
    colour (degree-0 SH) becomes the albedo; the light baked into a capture stays in it.
    """
    q = ply.rotations_wxyz.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    if len(q) and norm.min() < 1e-12:
        raise ValueError(f"splat rotations contain a zero quaternion (row {int(np.argmin(norm))})")
    colors = np.clip(0.5 + SH_C0 * ply.f_dc.astype(np.float64), 0.0, 1.0)
    opac = 1.0 / (1.0 + np.exp(-ply.opacity_logit.astype(np.float64)))
    opac = np.clip(opac, np.finfo(np.float32).tiny, 1.0)
    g = Gaussians(
        means_m=ply.positions,
        scales_m=np.exp(ply.log_scales.astype(np.float64)),
        rotations_wxyz=q / norm,
        colors_rgb=colors,
        opacities=opac,
    )
    given = ply.normals.astype(np.float64)
    if len(given) and bool((np.linalg.norm(given, axis=1) >= MIN_FILE_NORMAL).all()):
        return dataclasses.replace(g, normals=given)
    return g


# --------------------------------------------------------------------------- #
# File I/O (any PLY encoding)
# --------------------------------------------------------------------------- #
def _property_names(k_rest: int) -> list[str]:
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(3 * k_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def write_splat_ply(
    path: str | os.PathLike[str], ply: SplatPly, encoding: str = "binary_little_endian"
) -> None:
    """Write raw fields as an INRIA .ply (float32 properties, one ``vertex`` element), atomically.

    ``encoding`` is any PLY encoding (``ply_format.ENCODINGS``); 3DGS tools expect the default.
    """
    k = ply.f_rest.shape[2]
    columns: dict[str, NDArray[np.float32]] = {}
    for i, axis in enumerate("xyz"):
        columns[axis] = ply.positions[:, i]
    for i, axis in enumerate("xyz"):
        columns["n" + axis] = ply.normals[:, i]
    for c in range(3):
        columns[f"f_dc_{c}"] = ply.f_dc[:, c]
    for c in range(3):
        for j in range(k):  # channel-major: index = c * K + j
            columns[f"f_rest_{c * k + j}"] = ply.f_rest[:, c, j]
    columns["opacity"] = ply.opacity_logit
    for c in range(3):
        columns[f"scale_{c}"] = ply.log_scales[:, c]
    for c in range(4):
        columns[f"rot_{c}"] = ply.rotations_wxyz[:, c]
    assert list(columns) == _property_names(k)
    write_ply(path, {"vertex": columns}, encoding)


def read_splat_ply(path: str | os.PathLike[str]) -> SplatPly:
    """Read an INRIA splat .ply (any encoding, any scalar property types) into raw float32 fields; errors
    name the file and the offending property."""
    data = read_ply(path)
    path = data.path
    vertex = data.element("vertex")
    lists = [name for name, col in vertex.items() if isinstance(col, PlyList)]
    if lists:
        raise PlyFormatError(f"{path}: list property {lists[0]!r} in 'vertex' is not supported for splats")
    missing = [name for name in _REQUIRED if name not in vertex]
    if missing:
        raise PlyFormatError(f"{path}: missing required vertex properties {missing}")
    names = tuple(vertex)
    count = len(vertex["x"])
    rest_names = sorted(
        (n for n in names if n.startswith("f_rest_")),
        key=lambda s: int(s[7:]) if s[7:].isdigit() else 1 << 30,
    )
    if len(rest_names) not in _REST_COUNTS or rest_names != [f"f_rest_{i}" for i in range(len(rest_names))]:
        raise PlyFormatError(
            f"{path}: f_rest properties must be f_rest_0..f_rest_(3K-1) with 3K in (0, 9, 24, 45), "
            f"got {len(rest_names)}"
        )

    def cols(names: list[str]) -> NDArray[np.float32]:
        if not names:
            return np.zeros((count, 0), np.float32)
        for name in names:
            col = vertex[name]
            assert not isinstance(col, PlyList)
            if col.dtype.kind == "f" and not np.all(np.isfinite(col)):
                bad = int(np.flatnonzero(~np.isfinite(col))[0])
                raise PlyFormatError(f"{path}: property {name!r} holds NaN/inf (first at vertex {bad})")
        return np.stack([np.asarray(vertex[n]).astype(np.float32) for n in names], axis=1)

    has_normals = all(n in names for n in ("nx", "ny", "nz"))
    k = len(rest_names) // 3
    return SplatPly(
        positions=cols(["x", "y", "z"]),
        normals=cols(["nx", "ny", "nz"]) if has_normals else np.zeros((count, 3), np.float32),
        f_dc=cols(["f_dc_0", "f_dc_1", "f_dc_2"]),
        f_rest=cols(rest_names).reshape(count, 3, k),
        opacity_logit=cols(["opacity"])[:, 0],
        log_scales=cols(["scale_0", "scale_1", "scale_2"]),
        rotations_wxyz=cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
    )


# --------------------------------------------------------------------------- #
# Frame conversion: metric scale + up axis -> Z-up
# --------------------------------------------------------------------------- #
def up_axis_rotation(up_axis: str) -> NDArray[np.float64]:
    """Proper rotation (3, 3) taking the file's ``up_axis`` to +z: the smallest such rotation, 180 deg about x
    for "-z" (e.g. "y" is +90 deg about x: (x, y, z) -> (x, -z, y)); entries are exactly 0 and +-1."""
    if up_axis not in UP_AXES:
        raise ValueError(f"up_axis must be one of {UP_AXES}, got {up_axis!r}")
    sign = -1.0 if up_axis.startswith("-") else 1.0
    return rotation_between(sign * np.eye(3)["xyz".index(up_axis[-1])], (0.0, 0.0, 1.0))


def _check_scale(scale: float, path: object) -> float:
    if not (np.isfinite(scale) and scale > 0.0):
        raise ValueError(f"{path}: scale must be a finite factor > 0 (file units -> m), got {scale}")
    return float(scale)


def _sh_basis(dirs: NDArray[np.float64], degree: int) -> NDArray[np.float64]:
    """Real SH basis without the DC term, bands 1..degree, in the 3DGS coefficient order: (m, K)."""
    x, y, z = dirs[:, 0], dirs[:, 1], dirs[:, 2]
    cols = []
    if degree >= 1:
        c1 = 0.4886025119029199
        cols += [-c1 * y, c1 * z, -c1 * x]
    if degree >= 2:
        xx, yy, zz = x * x, y * y, z * z
        cols += [
            1.0925484305920792 * x * y,
            -1.0925484305920792 * y * z,
            0.31539156525252005 * (2 * zz - xx - yy),
            -1.0925484305920792 * x * z,
            0.5462742152960396 * (xx - yy),
        ]
    if degree >= 3:
        cols += [
            -0.5900435899266435 * y * (3 * xx - yy),
            2.890611442640554 * x * y * z,
            -0.4570457994644658 * y * (4 * zz - xx - yy),
            0.3731763325901154 * z * (2 * zz - 3 * xx - 3 * yy),
            -0.4570457994644658 * x * (4 * zz - xx - yy),
            1.445305721320277 * z * (xx - yy),
            -0.5900435899266435 * x * (xx - 3 * yy),
        ]
    return np.stack(cols, axis=1).astype(np.float64) if cols else np.zeros((len(dirs), 0))


def sh_rotation_matrix(rotation: ArrayLike, degree: int) -> NDArray[np.float64]:
    """(K, K) matrix M with f' = M f (rows: f_rest' = f_rest @ M.T) for a world rotation R; bands stay separate.

    Found by least squares on fixed directions: the rotated colour at R d must
    equal the original colour at d, exactly representable band by band.
    """
    r = np.asarray(rotation, np.float64)
    if degree == 0:
        return np.zeros((0, 0))
    dirs = np.random.default_rng(12345).normal(size=(256, 3))  # fixed probe directions, not a data draw
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    b_orig = _sh_basis(dirs, degree)
    b_rot = _sh_basis(dirs @ r.T, degree)
    m, *_ = np.linalg.lstsq(b_rot, b_orig, rcond=None)  # B(R d) m = B(d)  =>  f' = m f
    return m


def transform_splats(
    ply: SplatPly, scale: float = 1.0, up_axis: str = "z", translation_m: ArrayLike = (0.0, 0.0, 0.0)
) -> SplatPly:
    """Scale (file units -> m), rotate ``up_axis`` to +z, then translate; SH bands rotate with the splats."""
    s = _check_scale(scale, "transform_splats")
    r = up_axis_rotation(up_axis)
    t = np.asarray(translation_m, np.float64)
    q_r = matrix_to_quat(r)
    rest = ply.f_rest.astype(np.float64)
    if ply.sh_degree > 0 and up_axis != "z":
        rest = rest @ sh_rotation_matrix(r, ply.sh_degree).T
    return SplatPly(
        positions=(ply.positions.astype(np.float64) * s) @ r.T + t,
        normals=ply.normals.astype(np.float64) @ r.T,
        f_dc=ply.f_dc,
        f_rest=rest,
        opacity_logit=ply.opacity_logit,
        log_scales=ply.log_scales.astype(np.float64) + np.log(s),
        rotations_wxyz=quat_multiply(q_r[None, :], ply.rotations_wxyz.astype(np.float64)),
    )


def import_splats(
    path: str | os.PathLike[str],
    scale: float = 1.0,
    up_axis: str = "z",
    translation_m: ArrayLike = (0.0, 0.0, 0.0),
) -> tuple[Gaussians, SplatPly]:
    """Read a splat .ply into world Gaussians (Z-up, metres) and the transformed raw fields (with SH)."""
    _check_scale(scale, path)
    raw = transform_splats(read_splat_ply(path), scale, up_axis, translation_m)
    return decode_splats(raw), raw


def export_splats(path: str | os.PathLike[str], gaussians: Gaussians) -> None:
    """Write any Gaussians as an INRIA splat .ply (SH degree 0)."""
    write_splat_ply(path, encode_gaussians(gaussians))


# --------------------------------------------------------------------------- #
# Meshes
# --------------------------------------------------------------------------- #
FACE_INDEX_NAMES = ("vertex_indices", "vertex_index")  # what exporters call a face's vertex list
VERTEX_UV_NAMES = (("texture_u", "texture_v"), ("u", "v"), ("s", "t"))
COLOR_NAMES = ("red", "green", "blue", "alpha")


def triangulate_polygons(polygons: PlyList) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Triangles (m, 3) of polygons given as vertex-index lists, and the polygon each comes from (m,).

    Order (trimesh's, so a PLY mesh reads the same either way): the triangles as they are, then every
    quad's (0, 1, 2) halves followed by every quad's (2, 3, 0) halves, then larger polygons as fans
    (0, j, j + 1) polygon by polygon.  Vectorised over polygons.
    """
    counts, starts = polygons.counts, polygons.offsets[:-1]
    values = np.asarray(polygons.values, np.int64)
    tri = np.flatnonzero(counts == 3)
    quad = np.flatnonzero(counts == 4)
    fan = np.flatnonzero(counts > 4)
    fans_per = counts[fan] - 2
    fan_poly = np.repeat(fan, fans_per)
    j = np.arange(len(fan_poly)) - np.repeat(np.cumsum(fans_per) - fans_per, fans_per) + 1
    corners = [
        starts[tri, None] + np.arange(3),
        starts[quad, None] + np.array([0, 1, 2]),
        starts[quad, None] + np.array([2, 3, 0]),
        np.stack([starts[fan_poly], starts[fan_poly] + j, starts[fan_poly] + j + 1], axis=1),
    ]
    faces = values[np.concatenate([c.reshape(-1, 3) for c in corners])]
    return faces, np.concatenate([tri, quad, quad, fan_poly])


def _columns(
    element: dict[str, NDArray[np.generic] | PlyList], names: tuple[str, ...]
) -> NDArray[np.generic] | None:
    """The scalar columns ``names`` side by side (n, len(names)), or None unless all are there."""
    cols = [element[n] for n in names if n in element and not isinstance(element[n], PlyList)]
    return np.column_stack(cols) if len(cols) == len(names) else None


def _texture_image(path: Path, comments: tuple[str, ...]):
    """The image named by a ``comment TextureFile <name>`` line (relative to the file), or None."""
    names = [c.split(maxsplit=1)[1] for c in comments if c.startswith("TextureFile") and len(c.split()) > 1]
    if not names:
        return None
    import PIL.Image  # soft dependency, as for trimesh's textures

    image_path = path.parent / names[0]
    if not image_path.is_file():
        warnings.warn(
            f"{path}: texture image {names[0]!r} not found next to the file; ignoring it", stacklevel=3
        )
        return None
    return PIL.Image.open(image_path)


def read_ply_mesh(path: str | os.PathLike[str]) -> trimesh.Trimesh:
    """A triangle mesh from a .ply file in any encoding (``process=True``, as ``trimesh.load`` builds it).

    Reads vertex ``x y z`` (and ``nx ny nz``), the ``face`` element's vertex-index list (``vertex_indices``
    or ``vertex_index``; polygons triangulated by :func:`triangulate_polygons`), vertex and face colours
    (``red green blue [alpha]``) and texture coordinates (per vertex ``texture_u/v``, ``u/v`` or ``s/t``,
    or a face ``texcoord`` list) with the image of a ``comment TextureFile <name>`` line.
    """
    data = read_ply(path)
    path = data.path
    vertex = data.element("vertex")
    xyz = _columns(vertex, ("x", "y", "z"))
    if xyz is None:
        raise PlyFormatError(f"{path}: the 'vertex' element needs scalar properties x, y and z")
    vertices = xyz.astype(np.float64)
    face = data.elements.get("face", {})
    lists = [n for n, col in face.items() if isinstance(col, PlyList) and n != "texcoord"]
    name = next((n for n in FACE_INDEX_NAMES if n in lists), lists[0] if len(lists) == 1 else None)
    if name is None or len(face[name]) == 0:
        raise ValueError(
            f"{path}: no triangles found (no 'face' element with a {' or '.join(FACE_INDEX_NAMES)} list)"
        )
    polygons = face[name]
    assert isinstance(polygons, PlyList)
    if np.any(polygons.counts < 3):
        i = int(np.flatnonzero(polygons.counts < 3)[0])
        raise PlyFormatError(f"{path}: face {i} has {polygons.counts[i]} vertices; a face needs at least 3")
    bad = (polygons.values < 0) | (polygons.values >= len(vertices))
    if np.any(bad):
        row = int(np.searchsorted(polygons.offsets, np.flatnonzero(bad)[0], side="right") - 1)
        raise PlyFormatError(
            f"{path}: face {row} refers to vertex {int(polygons.values[np.flatnonzero(bad)[0]])}; "
            f"the file has vertices 0..{len(vertices) - 1}"
        )
    faces, source = triangulate_polygons(polygons)
    kwargs: dict[str, object] = {}
    normals = _columns(vertex, ("nx", "ny", "nz"))
    if normals is not None:
        kwargs["vertex_normals"] = normals
    vertex_colors = _columns(vertex, COLOR_NAMES) if "alpha" in vertex else _columns(vertex, COLOR_NAMES[:3])
    face_colors = _columns(face, COLOR_NAMES) if "alpha" in face else _columns(face, COLOR_NAMES[:3])
    if vertex_colors is not None:
        kwargs["vertex_colors"] = vertex_colors
    if face_colors is not None:
        kwargs["face_colors"] = face_colors[source]
    texcoord = face.get("texcoord")
    if isinstance(texcoord, PlyList) and np.all(texcoord.counts == 2 * polygons.counts):
        corner_uv = np.asarray(texcoord.values, np.float64).reshape(-1, 2)  # one (u, v) per polygon corner
        uv_of_corner, _ = triangulate_polygons(PlyList(polygons.counts, np.arange(len(corner_uv))))
        uv_faces = corner_uv[uv_of_corner]
    else:
        uv_names = next((n for n in VERTEX_UV_NAMES if _columns(vertex, n) is not None), None)
        uv_faces = None if uv_names is None else _columns(vertex, uv_names).astype(np.float64)[faces]
    if uv_faces is not None:  # vertices with one position but several uv are split (what trimesh does)
        unique, inverse = trimesh.grouping.unique_rows(uv_faces.reshape(-1, 2))
        faces, mask_v, mask_vt = trimesh.visual.texture.unmerge_faces(faces, inverse.reshape(faces.shape))
        vertices = vertices[mask_v]
        kwargs = {k: (v[mask_v] if k in ("vertex_normals", "vertex_colors") else v) for k, v in kwargs.items()}
        uv = uv_faces.reshape(-1, 2)[unique][mask_vt]
        kwargs["visual"] = trimesh.visual.texture.TextureVisuals(
            uv=uv, image=_texture_image(path, data.header.comments)
        )
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=True, **kwargs)


@dataclass
class ImportedMesh:
    """A mesh in world units (m, Z-up) and whether it is watertight (else use the winding number)."""

    mesh: trimesh.Trimesh
    watertight: bool
    source: str

    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """Inside test by the generalised winding number (robust on open meshes)."""
        return points_inside_mesh(self.mesh, points)


def import_mesh(
    path: str | os.PathLike[str],
    scale: float = 1.0,
    up_axis: str = "z",
    translation_m: ArrayLike = (0.0, 0.0, 0.0),
) -> ImportedMesh:
    """Load PLY (``read_ply_mesh``, any encoding) or OBJ/GLB/STL/OFF (trimesh; scenes are concatenated),
    scale to m, rotate ``up_axis`` to +z.

    Holes are filled where trimesh can; a mesh that stays open is returned with
    ``watertight=False`` and a warning (inside tests then use the winding number).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    s = _check_scale(scale, path)
    r = up_axis_rotation(up_axis)
    if path.suffix.lower() == ".ply":
        mesh = read_ply_mesh(path)
    else:
        try:
            mesh = trimesh.load(path, force="mesh")
        except Exception as exc:  # trimesh raises many types for unreadable files
            raise ValueError(f"{path}: could not read mesh: {exc}") from exc
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        raise ValueError(f"{path}: no triangles found")
    if not np.all(np.isfinite(mesh.vertices)):
        raise ValueError(f"{path}: vertices hold NaN/inf values")
    transform = np.eye(4)
    transform[:3, :3] = r * s
    transform[:3, 3] = np.asarray(translation_m, np.float64)
    mesh.apply_transform(transform)
    mesh.merge_vertices()
    watertight = bool(mesh.is_watertight)
    if not watertight:
        mesh.fill_holes()
        watertight = bool(mesh.is_watertight)
    if not watertight:
        warnings.warn(
            f"{path}: mesh is not watertight after hole filling; inside tests use the winding number",
            stacklevel=2,
        )
    elif mesh.volume < 0:
        mesh.invert()
    return ImportedMesh(mesh, watertight, str(path))


@wp.kernel
def _winding_inside_kernel(
    mesh_id: wp.uint64,
    points: wp.array(dtype=wp.vec3),
    max_dist: float,
    accuracy: float,
    threshold: float,
    inside: wp.array(dtype=wp.int32),
):
    tid = wp.tid()
    q = wp.mesh_query_point_sign_winding_number(mesh_id, points[tid], max_dist, accuracy, threshold)
    inside[tid] = 0
    if q.result and q.sign < 0.0:
        inside[tid] = 1


def points_inside_mesh(mesh: trimesh.Trimesh, points: ArrayLike, threshold: float = 0.5) -> NDArray[np.bool_]:
    """True where the generalised winding number of ``mesh`` at a point exceeds ``threshold`` (warp, CPU)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    if len(p) == 0:
        return np.zeros(0, bool)
    wp.init()
    device = "cpu"
    wmesh = wp.Mesh(
        points=wp.array(np.asarray(mesh.vertices, np.float32), dtype=wp.vec3, device=device),
        indices=wp.array(np.asarray(mesh.faces, np.int32).ravel(), dtype=wp.int32, device=device),
        support_winding_number=True,
    )
    pts = wp.array(p.astype(np.float32), dtype=wp.vec3, device=device)
    out = wp.zeros(len(p), dtype=wp.int32, device=device)
    wp.launch(
        _winding_inside_kernel, dim=len(p), inputs=[wmesh.id, pts, 1.0e6, 2.0, threshold, out], device=device
    )
    return out.numpy().astype(bool)
