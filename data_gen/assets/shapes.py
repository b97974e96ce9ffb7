"""Procedural solid shapes as data, with signed distance functions (numpy, vectorised).

Every shape answers:

* ``sdf(points (n, 3)) -> (n,)`` — signed distance in metres, negative inside;
* ``sdf_and_part(points) -> (distance, part_id)`` — the part (colour id) that owns
  the nearest surface, so composed objects can be multi-coloured;
* ``bounds() -> (2, 3)`` — an axis-aligned box [min, max] (m) that contains the solid;
* ``to_mesh(spacing_m=None)`` — a watertight ``trimesh.Trimesh`` of the zero level set.

Primitives live in their own local frame (centred at the origin; axial shapes
along +z). ``Transformed`` places a child with a rotation (w, x, y, z) and a
translation; ``Scaled`` scales uniformly; ``Union``, ``Intersection``,
``Difference`` and ``Offset`` compose; ``Shell`` hollows a solid into a closed
wall of a given thickness (bottles, cans, boxes, balls).

Exactness: the primitive SDFs are exact Euclidean distances except
``Ellipsoid`` (a first-order approximation, exact sign, exact on the surface).
``Union`` is exact outside the solid and a bound inside; ``Intersection`` and
``Difference`` are bounds (|sdf| <= true distance) with the exact sign.
``Offset`` is exact when its child is.

Meshing uses marching tetrahedra on a regular grid (Freudenthal split of each
cube into six tetrahedra), which is face-conforming and therefore gives a
closed, consistently oriented surface without the ambiguities of marching cubes.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from newtphys.rotations import quat_to_matrix

F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

_EVAL_CHUNK = 1 << 18  # points per SDF evaluation chunk while meshing
MAX_GRID_POINTS = 32_000_000  # meshing grid limit (the SDF values alone take 8 bytes per point)


def _as_points(points: ArrayLike) -> F64:
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {p.shape}")
    return p


def _positive(owner: str, name: str, value: float) -> float:
    v = float(value)
    if not (np.isfinite(v) and v > 0.0):
        raise ValueError(f"{owner}: {name} must be a finite value > 0 m, got {value}")
    return v


class Shape:
    """Base class: subclasses implement ``_sdf_part`` and ``bounds``."""

    def sdf(self, points: ArrayLike) -> F64:
        """Signed distance (n,) in metres at points (n, 3); negative inside."""
        return self._sdf_part(_as_points(points))[0]

    def sdf_and_part(self, points: ArrayLike) -> tuple[F64, I32]:
        """Signed distance (n,) and the part id (n,) of the nearest owning part."""
        return self._sdf_part(_as_points(points))

    def contains(self, points: ArrayLike) -> NDArray[np.bool_]:
        """True where the SDF is negative (strictly inside)."""
        return self.sdf(points) < 0.0

    def bounds(self) -> F64:
        """(2, 3) axis-aligned [min, max] corners, m, containing the solid."""
        raise NotImplementedError

    def extent_m(self) -> F64:
        """(3,) size of ``bounds()`` along x, y, z, m."""
        b = self.bounds()
        return b[1] - b[0]

    def part_ids(self) -> tuple[int, ...]:
        """All part ids used by this shape, sorted."""
        raise NotImplementedError

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        raise NotImplementedError

    def to_mesh(
        self, spacing_m: float | None = None, max_cells: int = 160, min_cells_across: int = 6
    ) -> trimesh.Trimesh:
        """Watertight triangle mesh of the zero level set by marching tetrahedra.

        ``spacing_m`` is the grid spacing; by default it is the largest of
        (longest extent / ``max_cells``) and the smallest of (longest extent / 48,
        shortest extent / ``min_cells_across``), so thin shapes get enough cells.
        """
        return mesh_sdf(self, spacing_m=spacing_m, max_cells=max_cells, min_cells_across=min_cells_across)


# --------------------------------------------------------------------------- #
# Primitives (local frame, centred at the origin, axial shapes along z)
# --------------------------------------------------------------------------- #
class _Primitive(Shape):
    """A primitive: one part id (declared as a dataclass field by each subclass)."""

    part_id: int

    def part_ids(self) -> tuple[int, ...]:
        return (self.part_id,)

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        return self._distance(p), np.full(len(p), self.part_id, np.int32)

    def _distance(self, p: F64) -> F64:
        raise NotImplementedError


@dataclass(frozen=True)
class Sphere(_Primitive):
    radius_m: float
    part_id: int = 0

    def __post_init__(self) -> None:
        _positive("Sphere", "radius_m", self.radius_m)

    def _distance(self, p: F64) -> F64:
        return np.linalg.norm(p, axis=1) - self.radius_m

    def bounds(self) -> F64:
        r = self.radius_m
        return np.array([[-r, -r, -r], [r, r, r]])


def _box_distance(p: F64, half: F64) -> F64:
    q = np.abs(p) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


@dataclass(frozen=True)
class Box(_Primitive):
    half_extents_m: tuple[float, float, float]
    part_id: int = 0

    def __post_init__(self) -> None:
        for i, h in enumerate(self.half_extents_m):
            _positive("Box", f"half_extents_m[{i}]", h)

    def _distance(self, p: F64) -> F64:
        return _box_distance(p, np.asarray(self.half_extents_m, np.float64))

    def bounds(self) -> F64:
        h = np.asarray(self.half_extents_m, np.float64)
        return np.stack([-h, h])


@dataclass(frozen=True)
class RoundedBox(_Primitive):
    """Box of half extents ``half_extents_m`` whose edges are rounded with ``radius_m``."""

    half_extents_m: tuple[float, float, float]
    radius_m: float
    part_id: int = 0

    def __post_init__(self) -> None:
        for i, h in enumerate(self.half_extents_m):
            _positive("RoundedBox", f"half_extents_m[{i}]", h)
        _positive("RoundedBox", "radius_m", self.radius_m)
        if self.radius_m >= min(self.half_extents_m):
            raise ValueError(
                f"RoundedBox: radius_m must be < the smallest half extent {min(self.half_extents_m)} m, got {self.radius_m}"
            )

    def _distance(self, p: F64) -> F64:
        inner = np.asarray(self.half_extents_m, np.float64) - self.radius_m
        return _box_distance(p, inner) - self.radius_m

    def bounds(self) -> F64:
        h = np.asarray(self.half_extents_m, np.float64)
        return np.stack([-h, h])


@dataclass(frozen=True)
class Ellipsoid(_Primitive):
    """Axis-aligned ellipsoid. Approximate SDF k0 (k0 - 1) / k1 (k0 = |p/r|, k1 = |p/r^2|): exact sign and zero set."""

    radii_m: tuple[float, float, float]
    part_id: int = 0

    def __post_init__(self) -> None:
        for i, r in enumerate(self.radii_m):
            _positive("Ellipsoid", f"radii_m[{i}]", r)

    def _distance(self, p: F64) -> F64:
        r = np.asarray(self.radii_m, np.float64)
        k0 = np.linalg.norm(p / r, axis=1)
        k1 = np.linalg.norm(p / (r * r), axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = k0 * (k0 - 1.0) / k1
        return np.where(k1 > 1e-300, d, -r.min())

    def bounds(self) -> F64:
        r = np.asarray(self.radii_m, np.float64)
        return np.stack([-r, r])


@dataclass(frozen=True)
class Capsule(_Primitive):
    """Segment from z = -half_length_m to +half_length_m swept by a ball of ``radius_m``."""

    radius_m: float
    half_length_m: float
    part_id: int = 0

    def __post_init__(self) -> None:
        _positive("Capsule", "radius_m", self.radius_m)
        if not (np.isfinite(self.half_length_m) and self.half_length_m >= 0.0):
            raise ValueError(f"Capsule: half_length_m must be >= 0 m, got {self.half_length_m}")

    def _distance(self, p: F64) -> F64:
        q = p.copy()
        q[:, 2] -= np.clip(p[:, 2], -self.half_length_m, self.half_length_m)
        return np.linalg.norm(q, axis=1) - self.radius_m

    def bounds(self) -> F64:
        r, a = self.radius_m, self.half_length_m
        return np.array([[-r, -r, -a - r], [r, r, a + r]])


@dataclass(frozen=True)
class Cylinder(_Primitive):
    """Solid cylinder along z of ``radius_m`` from z = -half_height_m to +half_height_m."""

    radius_m: float
    half_height_m: float
    part_id: int = 0

    def __post_init__(self) -> None:
        _positive("Cylinder", "radius_m", self.radius_m)
        _positive("Cylinder", "half_height_m", self.half_height_m)

    def _distance(self, p: F64) -> F64:
        d = np.stack(
            [np.hypot(p[:, 0], p[:, 1]) - self.radius_m, np.abs(p[:, 2]) - self.half_height_m], axis=1
        )
        return np.minimum(d.max(axis=1), 0.0) + np.linalg.norm(np.maximum(d, 0.0), axis=1)

    def bounds(self) -> F64:
        r, h = self.radius_m, self.half_height_m
        return np.array([[-r, -r, -h], [r, r, h]])


def _segment_distance_2d(p: F64, a: F64, b: F64) -> F64:
    """Distance from 2D points (n, 2) to the segment a-b."""
    ab = b - a
    t = np.clip(((p - a) @ ab) / float(ab @ ab), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[:, None] * ab), axis=1)


@dataclass(frozen=True)
class Cone(_Primitive):
    """Solid cone along z: base disc of ``radius_m`` at z = -height_m/2, apex at z = +height_m/2. Exact SDF."""

    radius_m: float
    height_m: float
    part_id: int = 0

    def __post_init__(self) -> None:
        _positive("Cone", "radius_m", self.radius_m)
        _positive("Cone", "height_m", self.height_m)

    def _distance(self, p: F64) -> F64:
        r, h = self.radius_m, self.height_m
        q = np.stack([np.hypot(p[:, 0], p[:, 1]), p[:, 2]], axis=1)  # (radial, axial) half-plane
        base = _segment_distance_2d(q, np.array([0.0, -h / 2]), np.array([r, -h / 2]))
        slant = _segment_distance_2d(q, np.array([r, -h / 2]), np.array([0.0, h / 2]))
        dist = np.minimum(base, slant)
        inside = (q[:, 1] > -h / 2) & (q[:, 0] / r + (q[:, 1] + h / 2) / h < 1.0)
        return np.where(inside, -dist, dist)

    def bounds(self) -> F64:
        r, h = self.radius_m, self.height_m
        return np.array([[-r, -r, -h / 2], [r, r, h / 2]])


@dataclass(frozen=True)
class Torus(_Primitive):
    """Torus in the xy plane: tube of ``minor_radius_m`` around a circle of ``major_radius_m``."""

    major_radius_m: float
    minor_radius_m: float
    part_id: int = 0

    def __post_init__(self) -> None:
        _positive("Torus", "major_radius_m", self.major_radius_m)
        _positive("Torus", "minor_radius_m", self.minor_radius_m)
        if self.minor_radius_m >= self.major_radius_m:
            raise ValueError(
                f"Torus: minor_radius_m must be < major_radius_m = {self.major_radius_m} m, got {self.minor_radius_m}"
            )

    def _distance(self, p: F64) -> F64:
        return np.hypot(np.hypot(p[:, 0], p[:, 1]) - self.major_radius_m, p[:, 2]) - self.minor_radius_m

    def bounds(self) -> F64:
        a = self.major_radius_m + self.minor_radius_m
        b = self.minor_radius_m
        return np.array([[-a, -a, -b], [a, a, b]])


# --------------------------------------------------------------------------- #
# Transforms and composition
# --------------------------------------------------------------------------- #
@dataclass(frozen=True)
class Transformed(Shape):
    """``child`` rotated by ``rotation_wxyz`` then translated by ``translation_m`` (rigid)."""

    child: Shape
    translation_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        q = np.asarray(self.rotation_wxyz, np.float64)
        if q.shape != (4,) or not np.all(np.isfinite(q)) or np.linalg.norm(q) < 1e-12:
            raise ValueError(
                f"Transformed: rotation_wxyz must be a non-zero (w, x, y, z) quaternion, got {self.rotation_wxyz}"
            )
        t = np.asarray(self.translation_m, np.float64)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(
                f"Transformed: translation_m must be 3 finite values in m, got {self.translation_m}"
            )

    @property
    def _matrix(self) -> F64:
        """The rotation matrix, computed once per shape (the shape is immutable; read-only array)."""
        m = self.__dict__.get("_matrix_cache")
        if m is None:
            m = quat_to_matrix(self.rotation_wxyz)
            m.flags.writeable = False
            object.__setattr__(self, "_matrix_cache", m)
        return m

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        # R^T (p - t), row-vector form
        local = (p - np.asarray(self.translation_m)) @ self._matrix
        return self.child._sdf_part(local)

    def bounds(self) -> F64:
        def compute() -> F64:
            b = self.child.bounds()
            corners = np.array(list(itertools.product(*zip(b[0], b[1]))))
            world = corners @ self._matrix.T + np.asarray(self.translation_m)
            return np.stack([world.min(axis=0), world.max(axis=0)])

        return _memo(self, "_bounds_cache", compute)

    def part_ids(self) -> tuple[int, ...]:
        return self.child.part_ids()


@dataclass(frozen=True)
class Scaled(Shape):
    """``child`` scaled uniformly by ``scale`` about the origin (exact: sdf = s * child(p / s))."""

    child: Shape
    scale: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.scale) and self.scale > 0.0):
            raise ValueError(f"Scaled: scale must be a finite value > 0, got {self.scale}")

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        d, part = self.child._sdf_part(p / self.scale)
        return d * self.scale, part

    def bounds(self) -> F64:
        return self.child.bounds() * self.scale

    def part_ids(self) -> tuple[int, ...]:
        return self.child.part_ids()


def _memo(shape: Shape, key: str, compute) -> F64:
    """``compute()`` once per (immutable) shape, kept in its ``__dict__``; callers get a copy."""
    value = shape.__dict__.get(key)
    if value is None:
        value = compute()
        object.__setattr__(shape, key, value)
    return value.copy()


def _union_bounds(children: Sequence[Shape]) -> F64:
    b = np.stack([c.bounds() for c in children])
    return np.stack([b[:, 0].min(axis=0), b[:, 1].max(axis=0)])


def _intersection_bounds(children: Sequence[Shape]) -> F64:
    b = np.stack([c.bounds() for c in children])
    lo, hi = b[:, 0].max(axis=0), b[:, 1].min(axis=0)
    return np.stack([lo, np.maximum(hi, lo)])


@dataclass(frozen=True)
class Union(Shape):
    """Union of children: min of their SDFs; the part of the closest child."""

    children: tuple[Shape, ...]

    def __post_init__(self) -> None:
        if len(self.children) == 0:
            raise ValueError("Union: children must hold at least one shape")

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        ds, parts = zip(*(c._sdf_part(p) for c in self.children))
        d = np.stack(ds)
        k = np.argmin(d, axis=0)
        cols = np.arange(len(p))
        return d[k, cols], np.stack(parts)[k, cols]

    def bounds(self) -> F64:
        return _memo(self, "_bounds_cache", lambda: _union_bounds(self.children))

    def part_ids(self) -> tuple[int, ...]:
        return tuple(sorted({i for c in self.children for i in c.part_ids()}))


@dataclass(frozen=True)
class Intersection(Shape):
    """Intersection of children: max of their SDFs (a bound inside and outside)."""

    children: tuple[Shape, ...]

    def __post_init__(self) -> None:
        if len(self.children) == 0:
            raise ValueError("Intersection: children must hold at least one shape")

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        ds, parts = zip(*(c._sdf_part(p) for c in self.children))
        d = np.stack(ds)
        k = np.argmax(d, axis=0)
        cols = np.arange(len(p))
        return d[k, cols], np.stack(parts)[k, cols]

    def bounds(self) -> F64:
        return _memo(self, "_bounds_cache", lambda: _intersection_bounds(self.children))

    def part_ids(self) -> tuple[int, ...]:
        return tuple(sorted({i for c in self.children for i in c.part_ids()}))


@dataclass(frozen=True)
class Difference(Shape):
    """``base`` minus ``cut``: max(base, -cut). The cut surface takes the cut's part id."""

    base: Shape
    cut: Shape

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        da, pa = self.base._sdf_part(p)
        db, pb = self.cut._sdf_part(p)
        use_base = da >= -db
        return np.where(use_base, da, -db), np.where(use_base, pa, pb)

    def bounds(self) -> F64:
        return self.base.bounds()

    def part_ids(self) -> tuple[int, ...]:
        return tuple(sorted(set(self.base.part_ids()) | set(self.cut.part_ids())))


@dataclass(frozen=True)
class Offset(Shape):
    """``child`` grown by ``distance_m`` (negative shrinks): sdf - distance_m (rounds convex edges)."""

    child: Shape
    distance_m: float

    def __post_init__(self) -> None:
        if not np.isfinite(self.distance_m):
            raise ValueError(f"Offset: distance_m must be finite, got {self.distance_m}")

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        d, part = self.child._sdf_part(p)
        return d - self.distance_m, part

    def bounds(self) -> F64:
        b = self.child.bounds()
        g = max(self.distance_m, 0.0)
        return np.stack([b[0] - g, b[1] + g])

    def part_ids(self) -> tuple[int, ...]:
        return self.child.part_ids()


@dataclass(frozen=True)
class Shell(Shape):
    """A closed hollow version of ``child``: the material between its surface and the inward offset by
    ``thickness_m``. sdf = max(d, -d - t) = |d + t/2| - t/2 with d = child sdf (exact when d is exact;
    where d is a bound inside, e.g. a Union, the wall is at least ``thickness_m`` thick).

    ``outer`` is the visible surface (``child``); ``cavity()`` is the sealed void ``Offset(child, -t)``.
    """

    child: Shape
    thickness_m: float

    def __post_init__(self) -> None:
        _positive("Shell", "thickness_m", self.thickness_m)
        thinnest = float(self.child.extent_m().min())
        if self.thickness_m >= 0.5 * thinnest:
            raise ValueError(
                f"Shell: thickness_m must be < half the child's thinnest extent ({0.5 * thinnest} m), "
                f"got {self.thickness_m}"
            )

    @property
    def outer(self) -> Shape:
        return self.child

    def cavity(self) -> Shape:
        """The sealed void inside the wall (a solid shape), m."""
        return Offset(self.child, -self.thickness_m)

    def _sdf_part(self, p: F64) -> tuple[F64, I32]:
        d, part = self.child._sdf_part(p)
        return np.maximum(d, -d - self.thickness_m), part

    def bounds(self) -> F64:
        return self.child.bounds()

    def part_ids(self) -> tuple[int, ...]:
        return self.child.part_ids()


def place(
    child: Shape,
    translation_m: Sequence[float] = (0.0, 0.0, 0.0),
    rotation_wxyz: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
) -> Transformed:
    """Shorthand for ``Transformed(child, translation_m, rotation_wxyz)``."""
    t = [float(v) for v in translation_m]
    q = [float(v) for v in rotation_wxyz]
    if len(t) != 3 or len(q) != 4:
        raise ValueError(
            f"place: translation_m needs 3 values and rotation_wxyz 4, got {len(t)} and {len(q)}"
        )
    return Transformed(child, (t[0], t[1], t[2]), (q[0], q[1], q[2], q[3]))


# --------------------------------------------------------------------------- #
# Meshing: marching tetrahedra over a regular grid
# --------------------------------------------------------------------------- #
_CUBE_CORNERS = np.array([[(c >> 0) & 1, (c >> 1) & 1, (c >> 2) & 1] for c in range(8)], np.int64)


def _freudenthal_tets() -> NDArray[np.int64]:
    """Six tetrahedra (corner indices 0..7, bit i = axis i) sharing the diagonal 0 -> 7."""
    tets = []
    for perm in itertools.permutations(range(3)):
        c0 = 0
        c1 = c0 | (1 << perm[0])
        c2 = c1 | (1 << perm[1])
        tets.append([c0, c1, c2, 7])
    return np.array(tets, np.int64)


def _tet_case_table() -> list[list[tuple[tuple[int, int], ...]]]:
    """Per inside-mask case (16), the triangles as triples of tet edges (inside vertex, outside vertex)."""
    table: list[list[tuple[tuple[int, int], ...]]] = []
    for case in range(16):
        ins = [v for v in range(4) if (case >> v) & 1]
        out = [v for v in range(4) if not (case >> v) & 1]
        if len(ins) in (0, 4):
            table.append([])
        elif len(ins) == 1:
            table.append([tuple((ins[0], o) for o in out)])
        elif len(ins) == 3:
            table.append([tuple((i, out[0]) for i in ins)])
        else:
            a, b = ins
            c, d = out
            table.append([((a, c), (a, d), (b, d)), ((a, c), (b, d), (b, c))])
    return table


_TETS = _freudenthal_tets()
_CASES = _tet_case_table()


def _default_spacing(extent: F64, max_cells: int, min_cells_across: int) -> float:
    longest, shortest = float(extent.max()), float(extent.min())
    if longest <= 0.0:
        raise ValueError(f"shape has empty bounds (extent {extent.tolist()} m)")
    return max(longest / max_cells, min(longest / 48.0, shortest / min_cells_across))


def mesh_sdf(
    shape: Shape,
    spacing_m: float | None = None,
    max_cells: int = 160,
    min_cells_across: int = 6,
    projection_steps: int = 1,
) -> trimesh.Trimesh:
    """Watertight mesh (outward normals) of ``shape``'s zero level set on a grid of ``spacing_m``.

    After marching tetrahedra, each vertex takes ``projection_steps`` Newton
    steps onto the zero set along the SDF gradient (moves clipped to a quarter
    of the spacing), which removes most of the linear-interpolation error on
    smooth parts (sharp edges stay chamfered by about one cell).
    """
    lo, hi = shape.bounds()
    if spacing_m is None:
        spacing_m = _default_spacing(hi - lo, max_cells, min_cells_across)
    h = _positive("mesh_sdf", "spacing_m", spacing_m)
    lo = lo - 2.0 * h
    hi = hi + 2.0 * h
    dims = np.ceil((hi - lo) / h).astype(np.int64) + 1
    if np.prod(dims) > MAX_GRID_POINTS:
        raise ValueError(
            f"mesh_sdf: spacing_m={h} gives a grid of {dims.tolist()} points (> {MAX_GRID_POINTS:.0e}); "
            "use a larger spacing"
        )
    values = _grid_values(shape, lo, h, dims)
    mesh = _marching_tetrahedra(values, lo, h)
    if projection_steps > 0:
        mesh = trimesh.Trimesh(
            _project_to_surface(shape, mesh.vertices, h, projection_steps), mesh.faces, process=False
        )
    return mesh


def _grid_values(shape: Shape, origin: F64, h: float, dims: NDArray[np.int64]) -> F64:
    """SDF on the grid origin + h * (i, j, k), evaluated in x-slabs of about _EVAL_CHUNK points."""
    ys = origin[1] + h * np.arange(dims[1])
    zs = origin[2] + h * np.arange(dims[2])
    yy, zz = np.meshgrid(ys, zs, indexing="ij")
    plane = np.stack([np.zeros(yy.size), yy.ravel(), zz.ravel()], axis=1)  # one x = const slab
    per_chunk = max(1, _EVAL_CHUNK // len(plane))
    values = np.empty(tuple(int(d) for d in dims))
    for i0 in range(0, int(dims[0]), per_chunk):  # loop over slabs of x, vectorised inside
        xs = origin[0] + h * np.arange(i0, min(i0 + per_chunk, int(dims[0])))
        pts = np.repeat(plane[None], len(xs), axis=0)
        pts[:, :, 0] = xs[:, None]
        values[i0 : i0 + len(xs)] = shape.sdf(pts.reshape(-1, 3)).reshape(len(xs), int(dims[1]), int(dims[2]))
    return values


def _project_to_surface(shape: Shape, vertices: F64, h: float, steps: int) -> F64:
    """Newton steps v <- v - sdf(v) grad / |grad|^2 (forward differences), each move clipped to h / 4."""
    v = np.array(vertices, np.float64)
    eps = 1e-3 * h
    for _ in range(steps):  # a few iterations, vectorised over vertices
        d = shape.sdf(v)
        grad = np.stack([(shape.sdf(v + e) - d) / eps for e in np.eye(3) * eps], axis=1)
        g2 = np.maximum((grad * grad).sum(axis=1), 1e-12)
        move = -(d / g2)[:, None] * grad
        norm = np.linalg.norm(move, axis=1, keepdims=True)
        v += move * np.minimum(1.0, 0.25 * h / np.maximum(norm, 1e-300))
    return v


def _marching_tetrahedra(values: F64, origin: F64, h: float) -> trimesh.Trimesh:
    nx, ny, nz = values.shape
    inside = values < 0.0
    # cubes whose eight corners do not all agree
    any_in = np.zeros((nx - 1, ny - 1, nz - 1), bool)
    all_in = np.ones((nx - 1, ny - 1, nz - 1), bool)
    for c in _CUBE_CORNERS:
        sl = inside[c[0] : nx - 1 + c[0], c[1] : ny - 1 + c[1], c[2] : nz - 1 + c[2]]
        any_in |= sl
        all_in &= sl
    cubes = np.argwhere(any_in & ~all_in)  # (m, 3)
    if len(cubes) == 0:
        raise ValueError("mesh_sdf: the shape has no surface inside its bounds (empty or grid too coarse)")
    strides = np.array([ny * nz, nz, 1], np.int64)
    corner_index = (cubes[:, None, :] + _CUBE_CORNERS[None]) @ strides  # (m, 8) flat grid indices
    tet_vertices = corner_index[:, _TETS].reshape(-1, 4)  # (6m, 4)
    flat_values = values.reshape(-1)
    flat_inside = inside.reshape(-1)
    case = (flat_inside[tet_vertices] * (1 << np.arange(4))).sum(axis=1)

    edge_a: list[NDArray[np.int64]] = []
    edge_b: list[NDArray[np.int64]] = []
    for c in range(1, 15):  # loop over the 14 mixed cases, vectorised over tetrahedra
        sel = tet_vertices[case == c]
        if len(sel) == 0:
            continue
        for tri in _CASES[c]:
            edge_a.append(np.stack([sel[:, e[0]] for e in tri], axis=1))
            edge_b.append(np.stack([sel[:, e[1]] for e in tri], axis=1))
    ea = np.concatenate(edge_a)  # (f, 3) inside grid index per triangle corner
    eb = np.concatenate(edge_b)  # (f, 3) outside grid index
    n_grid = flat_values.size
    keys = (ea * n_grid + eb).reshape(-1)
    unique_keys, faces = np.unique(keys, return_inverse=True)
    ia, ib = unique_keys // n_grid, unique_keys % n_grid
    va, vb = flat_values[ia], flat_values[ib]
    t = np.clip(va / (va - vb), 1e-3, 1.0 - 1e-3)  # keep vertices on distinct edges distinct
    pa = _grid_points(ia, values.shape, origin, h)
    pb = _grid_points(ib, values.shape, origin, h)
    vertices = pa + t[:, None] * (pb - pa)
    faces = faces.reshape(-1, 3)
    # orient every triangle outward: its normal must point from the inside corner to the outside corner
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    outward = (_grid_points(eb, values.shape, origin, h) - _grid_points(ea, values.shape, origin, h)).sum(
        axis=1
    )
    flip = np.einsum("ij,ij->i", normal, outward) < 0.0
    faces[flip] = faces[flip][:, ::-1]
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)


def _grid_points(flat: NDArray[np.int64], shape: tuple[int, ...], origin: F64, h: float) -> F64:
    ijk = np.stack(np.unravel_index(flat, shape), axis=-1).astype(np.float64)
    return origin + h * ijk
