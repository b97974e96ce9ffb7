"""3D Gaussian splat .ply files (INRIA layout) and triangle-mesh import.

Splat .ply layout (binary little endian, one ``vertex`` element, float32):
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
``import_mesh`` with the same options and a watertightness check; inside tests
on any mesh use the generalised winding number (``points_inside_mesh``, warp).
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import trimesh
import warp as wp
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from newtphys.rotations import matrix_to_quat, quat_multiply, rotation_between

SH_C0 = 0.28209479177387814
OPACITY_EPS = 1e-6  # opacities are clipped to [eps, 1 - eps] before the logit
UP_AXES = ("z", "y", "-y", "x", "-x", "-z")
FloatArray = NDArray[np.floating[Any]]  # stored as float32 after validation
_PLY_TYPES = {
    "float": "<f4",
    "float32": "<f4",
    "double": "<f8",
    "float64": "<f8",
    "uchar": "u1",
    "uint8": "u1",
    "char": "i1",
    "int8": "i1",
    "ushort": "<u2",
    "uint16": "<u2",
    "short": "<i2",
    "int16": "<i2",
    "uint": "<u4",
    "uint32": "<u4",
    "int": "<i4",
    "int32": "<i4",
}
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


class PlyFormatError(ValueError):
    """A .ply file is malformed or lacks what the INRIA splat layout needs."""


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
    """Gaussians -> raw INRIA fields (f_dc from colour, logit opacity, log scales)."""
    if g.scales_m is None or g.rotations_wxyz is None:
        raise ValueError("encode_gaussians: the INRIA layout needs Gaussians given by scales_m + rotations_wxyz")
    if n_flat := int((g.scales_m <= 0.0).any(axis=1).sum()):
        raise ValueError(
            f"encode_gaussians: scales_m must be > 0 m (the file stores their log); {n_flat} rows are not"
        )
    n = len(g)
    rest = np.zeros((n, 3, 0), np.float32) if f_rest is None else np.asarray(f_rest, np.float32)
    op = np.clip(g.opacities.astype(np.float64), OPACITY_EPS, 1.0 - OPACITY_EPS)
    return SplatPly(
        positions=g.means_m,
        normals=np.zeros((n, 3), np.float32),
        f_dc=(g.colors_rgb.astype(np.float64) - 0.5) / SH_C0,
        f_rest=rest,
        opacity_logit=np.log(op / (1.0 - op)),
        log_scales=np.log(g.scales_m.astype(np.float64)),
        rotations_wxyz=g.rotations_wxyz,
    )


def decode_splats(ply: SplatPly) -> Gaussians:
    """Raw INRIA fields -> Gaussians (colour clipped to [0, 1], rotations normalised); f_rest dropped."""
    q = ply.rotations_wxyz.astype(np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    if len(q) and norm.min() < 1e-12:
        raise ValueError(f"splat rotations contain a zero quaternion (row {int(np.argmin(norm))})")
    colors = np.clip(0.5 + SH_C0 * ply.f_dc.astype(np.float64), 0.0, 1.0)
    opac = 1.0 / (1.0 + np.exp(-ply.opacity_logit.astype(np.float64)))
    opac = np.clip(opac, np.finfo(np.float32).tiny, 1.0)
    return Gaussians(
        means_m=ply.positions,
        scales_m=np.exp(ply.log_scales.astype(np.float64)),
        rotations_wxyz=q / norm,
        colors_rgb=colors,
        opacities=opac,
    )


# --------------------------------------------------------------------------- #
# Binary I/O
# --------------------------------------------------------------------------- #
def _property_names(k_rest: int) -> list[str]:
    return (
        ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        + [f"f_rest_{i}" for i in range(3 * k_rest)]
        + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    )


def write_splat_ply(path: str | os.PathLike[str], ply: SplatPly) -> None:
    """Write raw fields as a binary little-endian INRIA .ply (float32 properties), atomically."""
    k = ply.f_rest.shape[2]
    names = _property_names(k)
    data = np.empty(len(ply), dtype=np.dtype([(name, "<f4") for name in names]))
    for i, axis in enumerate("xyz"):
        data[axis] = ply.positions[:, i]
        data["n" + axis] = ply.normals[:, i]
    for c in range(3):
        data[f"f_dc_{c}"] = ply.f_dc[:, c]
        data[f"scale_{c}"] = ply.log_scales[:, c]
        for j in range(k):  # channel-major: index = c * K + j
            data[f"f_rest_{c * k + j}"] = ply.f_rest[:, c, j]
    data["opacity"] = ply.opacity_logit
    for c in range(4):
        data[f"rot_{c}"] = ply.rotations_wxyz[:, c]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(ply)}"]
    header += [f"property float {name}" for name in names] + ["end_header"]
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())
    os.replace(tmp, path)


def _parse_header(path: Path, raw: bytes) -> tuple[int, int, np.dtype]:
    """Return (data offset in bytes, vertex count, vertex dtype); raise PlyFormatError naming the problem."""
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise PlyFormatError(f"{path}: not a .ply file (missing 'ply' magic or 'end_header')")
    nl = raw.find(b"\n", end)
    if nl < 0:
        raise PlyFormatError(f"{path}: header ends without a newline after 'end_header'")
    lines = raw[:end].decode("ascii", errors="replace").splitlines()[1:]
    fmt, count, props, element = None, None, [], None
    for line in lines:
        tok = line.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format":
            fmt = " ".join(tok[1:])
        elif tok[0] == "element":
            if element == "vertex":
                break  # later elements follow the vertex data; they are not read
            if len(tok) != 3 or not tok[2].isdigit():
                raise PlyFormatError(f"{path}: malformed element line {line!r}")
            element = tok[1]
            if element != "vertex":
                raise PlyFormatError(
                    f"{path}: element {tok[1]!r} precedes 'vertex'; the splat layout has 'vertex' first"
                )
            count = int(tok[2])
        elif tok[0] == "property":
            if element is None:
                raise PlyFormatError(f"{path}: property {line!r} before any element")
            if tok[1] == "list":
                raise PlyFormatError(
                    f"{path}: list property {tok[-1]!r} in 'vertex' is not supported for splats"
                )
            if len(tok) != 3 or tok[1] not in _PLY_TYPES:
                raise PlyFormatError(f"{path}: unsupported property line {line!r}")
            props.append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt != "binary_little_endian 1.0":
        raise PlyFormatError(f"{path}: format {fmt!r} not supported; need 'binary_little_endian 1.0'")
    if count is None:
        raise PlyFormatError(f"{path}: no 'vertex' element")
    names = [p[0] for p in props]
    if len(set(names)) != len(names):
        raise PlyFormatError(f"{path}: duplicate vertex properties in {names}")
    missing = [name for name in _REQUIRED if name not in names]
    if missing:
        raise PlyFormatError(f"{path}: missing required vertex properties {missing}")
    return nl + 1, count, np.dtype(props)


def read_splat_ply(path: str | os.PathLike[str]) -> SplatPly:
    """Read an INRIA splat .ply into raw fields; errors name the file and the offending property."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"splat .ply not found: {path}")
    raw = path.read_bytes()
    offset, count, dtype = _parse_header(path, raw)
    need = count * dtype.itemsize
    if len(raw) - offset < need:
        raise PlyFormatError(
            f"{path}: truncated: header declares {count} vertices ({need} bytes) but "
            f"{len(raw) - offset} bytes follow the header"
        )
    data = np.frombuffer(raw, dtype=dtype, count=count, offset=offset)
    names: tuple[str, ...] = dtype.names or ()
    rest_names = sorted(
        (n for n in names if n.startswith("f_rest_")),
        key=lambda s: int(s[7:]) if s[7:].isdigit() else 1 << 30,
    )
    if len(rest_names) not in _REST_COUNTS or rest_names != [f"f_rest_{i}" for i in range(len(rest_names))]:
        raise PlyFormatError(
            f"{path}: f_rest properties must be f_rest_0..f_rest_(3K-1) with 3K in (0, 9, 24, 45), "
            f"got {len(rest_names)}"
        )
    for name in _REQUIRED + tuple(rest_names):
        col = data[name]
        if col.dtype.kind == "f" and not np.all(np.isfinite(col)):
            bad = int(np.flatnonzero(~np.isfinite(col))[0])
            raise PlyFormatError(f"{path}: property {name!r} holds NaN/inf (first at vertex {bad})")

    def cols(names: list[str]) -> NDArray[np.float32]:
        return (
            np.stack([data[n].astype(np.float32) for n in names], axis=1)
            if names
            else np.zeros((count, 0), np.float32)
        )

    has_normals = all(n in names for n in ("nx", "ny", "nz"))
    k = len(rest_names) // 3
    rest = cols(rest_names).reshape(count, 3, k)
    return SplatPly(
        positions=cols(["x", "y", "z"]),
        normals=cols(["nx", "ny", "nz"]) if has_normals else np.zeros((count, 3), np.float32),
        f_dc=cols(["f_dc_0", "f_dc_1", "f_dc_2"]),
        f_rest=rest,
        opacity_logit=data["opacity"].astype(np.float32),
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
    """Load OBJ/PLY/GLB/STL/OFF via trimesh (scenes are concatenated), scale to m, rotate ``up_axis`` to +z.

    Holes are filled where trimesh can; a mesh that stays open is returned with
    ``watertight=False`` and a warning (inside tests then use the winding number).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"mesh file not found: {path}")
    s = _check_scale(scale, path)
    r = up_axis_rotation(up_axis)
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
