"""3D Gaussian splats: the one container that assets build, the pipeline skins and the renderer draws.

A Gaussian ``i`` has a centre ``means_m[i]`` (m, in the frame of whoever holds
it: an asset's local frame or the world), a shape given either by per-axis
standard deviations ``scales_m[i]`` (m) and an orientation ``rotations_wxyz[i]``
(quaternion (w, x, y, z) taking the Gaussian's axes to that frame), or directly
by a covariance ``covariances_m2[i]`` (m^2), a colour ``colors_rgb[i]`` in
[0, 1] (the *albedo*: a lit render multiplies it by the light reaching the
splat, ``data_gen.render.shading``), an opacity ``opacities[i]`` in [0, 1], a
part id ``part_ids[i]`` (what the splat belongs to: an object's part, a scene
box + 1 with 0 for the floor, or an object id; 0 when not given) and optionally
a unit surface normal ``normals[i]`` (outward where the source knows it: mesh
and shape normals; a splat file's ``nx ny nz``). Without given normals,
:meth:`Gaussians.surface_normals` takes the shortest axis of each covariance
(the normal of a flat splat, sign arbitrary; the shading flips normals to face
the camera, so the sign does not matter there).

Rotations are kept as given (3DGS files store them unnormalised, and the
encoded bytes must survive a round trip); ``unit_rotations_wxyz`` is their
normalised float32 form, which is what the renderer reads.

Only *surface* Gaussians are rendered. Interior particles that exist only for
the simulation must not be passed to the renderer (they would show up in the
label maps as the nearest covering Gaussian); the caller selects the surface
subset before building a :class:`Gaussians`.

Simulated deformation moves a splat through its centre and deforms its shape
through the local deformation gradient ``F``: Sigma -> F Sigma F^T, and its
normal by the inverse transpose: n -> F^-T n / |F^-T n| (:meth:`Gaussians.deformed`,
:func:`deform_normals`). A rigid transform rotates the normals.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from newtphys.rotations import matrix_to_quat, quat_multiply, quat_to_matrix

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]
I32 = NDArray[np.int32]

#: Relative tolerance for the symmetry / positive semi-definiteness of a given covariance.
COVARIANCE_TOLERANCE = 1e-6


def _as_float_array(name: str, value: ArrayLike, shape_tail: tuple[int, ...], count: int | None) -> F32:
    arr = np.ascontiguousarray(np.asarray(value, dtype=np.float32))
    expected = ("N",) + shape_tail
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise ValueError(f"Gaussians.{name} must have shape {expected}, got {arr.shape}")
    if count is not None and arr.shape[0] != count:
        raise ValueError(f"Gaussians.{name} has {arr.shape[0]} rows but means_m has {count}")
    if not np.isfinite(arr).all():  # (one pass; the offending row is looked up only on failure)
        i = int(np.flatnonzero(_bad_rows(~np.isfinite(arr)))[0])
        raise ValueError(f"Gaussians.{name}[{i}] is not finite: {arr[i].tolist()}")
    return arr


def _bad_rows(flags: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """(N, ...) per-element flags -> (N,) any flag per row (works for N = 0)."""
    return flags.reshape(flags.shape[0], int(np.prod(flags.shape[1:], dtype=np.int64))).any(axis=1)


def _check_range(name: str, arr: F32, low: float, high: float) -> None:
    """(``arr`` is finite: checked first.)"""
    if arr.size == 0 or (arr.min() >= low and arr.max() <= high):
        return
    bad = _bad_rows((arr < low) | (arr > high))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"Gaussians.{name}[{i}] = {arr[i].tolist()} is outside the allowed range [{low}, {high}]"
        )


@dataclass(frozen=True, kw_only=True)
class Gaussians:
    """N Gaussian splats (arrays are converted to contiguous float32, part ids to int32, and validated).

    Give either ``scales_m`` (with optional ``rotations_wxyz``, identity when
    omitted) or ``covariances_m2``, not both.
    """

    means_m: F32
    scales_m: F32 | None = None
    covariances_m2: F32 | None = None
    rotations_wxyz: F32 | None = None
    colors_rgb: F32
    opacities: F32
    part_ids: I32 | None = None
    normals: F32 | None = None
    """(N, 3) unit surface normals (normalised here; a zero row is an error), or None."""

    def __post_init__(self) -> None:
        means = _as_float_array("means_m", self.means_m, (3,), None)
        n = means.shape[0]
        set_ = self._set_field
        set_("means_m", means)
        colors = _as_float_array("colors_rgb", self.colors_rgb, (3,), n)
        _check_range("colors_rgb", colors, 0.0, 1.0)
        set_("colors_rgb", colors)
        opac = _as_float_array("opacities", self.opacities, (), n)
        _check_range("opacities", opac, 0.0, 1.0)
        set_("opacities", opac)
        set_("part_ids", _as_part_ids(self.part_ids, n))
        if self.normals is not None:
            set_("normals", _unit_normals(_as_float_array("normals", self.normals, (3,), n)))

        if (self.scales_m is None) == (self.covariances_m2 is None):
            raise ValueError("Gaussians needs exactly one of scales_m (N,3) or covariances_m2 (N,3,3)")
        if self.covariances_m2 is not None:
            if self.rotations_wxyz is not None:
                raise ValueError("Gaussians.rotations_wxyz must be None when covariances_m2 is given")
            cov = _as_float_array("covariances_m2", self.covariances_m2, (3, 3), n)
            _check_covariances(cov)
            set_("covariances_m2", cov)
            return
        scales = _as_float_array("scales_m", self.scales_m, (3,), n)
        _check_range("scales_m", scales, 0.0, np.inf)  # 0 is a flat splat
        set_("scales_m", scales)
        if self.rotations_wxyz is None:
            rot = np.zeros((n, 4), np.float32)
            rot[:, 0] = 1.0
        else:
            rot = _as_float_array("rotations_wxyz", self.rotations_wxyz, (4,), n)
            norm = np.linalg.norm(rot, axis=1)
            self.__dict__["_rotation_norms"] = norm  # (unit_rotations_wxyz divides by them: computed once)
            bad = norm < 1e-8
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"Gaussians.rotations_wxyz[{i}] = {rot[i].tolist()} has zero norm; "
                    "need a (w, x, y, z) rotation"
                )
        set_("rotations_wxyz", rot)

    def _set_field(self, name: str, value: object) -> None:
        object.__setattr__(self, name, value)  # the dataclass is frozen; only __post_init__ normalises

    def _derived(self, rows: ArrayLike | slice = slice(None), **changes: object) -> Gaussians:
        """These Gaussians' ``rows`` with fields replaced by ``changes``, without validating again: every field
        not in ``changes`` was checked when this set was built, and a subset of checked rows is checked (a
        render derives several sets per frame from 10^6 splats). ``changes`` must be checked by the caller. The
        cached unit rotations are carried over."""
        g = object.__new__(Gaussians)
        for f in dataclasses.fields(Gaussians):
            value = changes[f.name] if f.name in changes else getattr(self, f.name)
            if f.name not in changes and value is not None:
                value = value[rows]
            object.__setattr__(g, f.name, value)
        if "unit_rotations_wxyz" in self.__dict__ and "rotations_wxyz" not in changes:
            g.__dict__["unit_rotations_wxyz"] = self.__dict__["unit_rotations_wxyz"][rows]
        return g

    def __len__(self) -> int:
        return int(self.means_m.shape[0])

    @functools.cached_property
    def unit_rotations_wxyz(self) -> F32:
        """(N, 4) float32 unit quaternions (the rotations normalised); covariance-form Gaussians have none."""
        if self.rotations_wxyz is None:
            raise ValueError("Gaussians given by covariances_m2 have no rotations")
        norm = self.__dict__.pop("_rotation_norms", None)  # __post_init__'s (a derived set has none)
        if norm is None:
            norm = np.linalg.norm(self.rotations_wxyz, axis=1)
        return (self.rotations_wxyz / norm[:, None]).astype(np.float32)

    def covariances(self) -> F64:
        """Covariances (N, 3, 3), m^2, float64: given ones, or R diag(s^2) R^T."""
        if self.covariances_m2 is not None:
            return self.covariances_m2.astype(np.float64)
        assert self.scales_m is not None
        rot = quat_to_matrix(self.unit_rotations_wxyz.astype(np.float64))
        rs = rot * self.scales_m.astype(np.float64)[:, None, :]  # R S (columns scaled)
        return rs @ np.swapaxes(rs, 1, 2)

    def surface_normals(self) -> F32:
        """(N, 3) float32 unit normals: the given ``normals``, else each covariance's shortest axis."""
        if self.normals is not None:
            return self.normals
        return normals_from_covariances(self.covariances())

    def deformed(self, deformation_gradients: ArrayLike, means_m: ArrayLike | None = None) -> Gaussians:
        """Gaussians after a local deformation: Sigma -> F Sigma F^T, centres moved to ``means_m`` if given.

        ``deformation_gradients`` is (N, 3, 3), dimensionless (dx/dX at each
        splat centre). The result stores full covariances; given normals become
        F^-T n, renormalised (:func:`deform_normals`).
        """
        f = np.asarray(deformation_gradients, np.float64)
        if f.shape != (len(self), 3, 3):
            raise ValueError(f"deformation_gradients must have shape ({len(self)}, 3, 3), got {f.shape}")
        bad = _bad_rows(~np.isfinite(f))
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise ValueError(f"deformation_gradients[{i}] is not finite: {f[i].tolist()}")
        cov = f @ self.covariances() @ np.swapaxes(f, 1, 2)
        cov = 0.5 * (cov + np.swapaxes(cov, 1, 2))
        return Gaussians(
            means_m=self.means_m if means_m is None else means_m,
            covariances_m2=cov,
            colors_rgb=self.colors_rgb,
            opacities=self.opacities,
            part_ids=self.part_ids,
            normals=None if self.normals is None else deform_normals(self.normals, f),
        )

    def transformed(self, transform: ArrayLike) -> Gaussians:
        """The Gaussians moved by a rigid 4x4 transform (means, and rotations or covariances; scales unchanged)."""
        m = np.asarray(transform, np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"transform must be a 4x4 rigid matrix, got shape {m.shape}")
        r = m[:3, :3]
        means = self.means_m.astype(np.float64) @ r.T + m[:3, 3]
        normals = None if self.normals is None else self.normals.astype(np.float64) @ r.T
        if self.covariances_m2 is not None:
            return dataclasses.replace(
                self, means_m=means, covariances_m2=r @ self.covariances() @ r.T, normals=normals
            )
        assert self.rotations_wxyz is not None
        q = quat_multiply(matrix_to_quat(r)[None, :], self.rotations_wxyz.astype(np.float64))
        return dataclasses.replace(self, means_m=means, rotations_wxyz=q, normals=normals)

    def scaled(self, factor: float) -> Gaussians:
        """The Gaussians scaled uniformly about the origin by ``factor`` (> 0): centres and sizes."""
        if not (np.isfinite(factor) and factor > 0.0):
            raise ValueError(f"scale factor must be a finite value > 0, got {factor}")
        if self.covariances_m2 is not None:
            return dataclasses.replace(
                self, means_m=self.means_m * factor, covariances_m2=self.covariances_m2 * factor**2
            )
        assert self.scales_m is not None
        return dataclasses.replace(self, means_m=self.means_m * factor, scales_m=self.scales_m * factor)

    def with_part_ids(self, part_ids: ArrayLike) -> Gaussians:
        """The same Gaussians with other part ids (N,)."""
        return dataclasses.replace(self, part_ids=part_ids)

    def subset(self, selection: ArrayLike) -> Gaussians:
        """The Gaussians picked by a boolean mask (N,) or an index array (a mask of one run of rows gives views of
        these arrays, e.g. a render's shadow casters: objects after the scene)."""
        sel = np.asarray(selection)
        if sel.dtype == bool and sel.shape != (len(self),):
            raise ValueError(f"boolean selection must have shape ({len(self)},), got {sel.shape}")
        if sel.dtype != bool and not np.issubdtype(sel.dtype, np.integer) and sel.size:
            raise ValueError(f"selection must be a boolean mask or integer indices, got dtype {sel.dtype}")
        if sel.dtype != bool:
            return self._derived(sel.astype(np.intp))
        picked = np.flatnonzero(sel)
        if len(picked) and picked[-1] - picked[0] + 1 == len(picked):  # one run of rows: views, no copies
            return self._derived(slice(int(picked[0]), int(picked[-1]) + 1))
        return self._derived(picked)

    def with_colors(self, colors_rgb: ArrayLike) -> Gaussians:
        """The same splats with other colours (N, 3) in [0, 1] (checked; nothing else is checked again)."""
        colors = _as_float_array("colors_rgb", colors_rgb, (3,), len(self))
        _check_range("colors_rgb", colors, 0.0, 1.0)
        return self._derived(colors_rgb=colors)


def concatenate(items: Sequence[Gaussians]) -> Gaussians:
    """One Gaussians holding all of ``items`` in order (all given by scales + rotations, or all by covariances).

    If some items have normals and others not, the others get their shortest covariance axes."""
    if not items:
        raise ValueError("concatenate: items must hold at least one Gaussians")
    forms = {g.covariances_m2 is None for g in items}
    if len(forms) != 1:
        raise ValueError("concatenate: items mix scales + rotations with covariances; deform them all first")
    if any(g.normals is not None for g in items):
        items = [g if g.normals is not None else dataclasses.replace(g, normals=g.surface_normals()) for g in items]
    fields = [f.name for f in dataclasses.fields(Gaussians)]
    joined = {
        k: None if getattr(items[0], k) is None else np.concatenate([getattr(g, k) for g in items]) for k in fields
    }
    return Gaussians(**joined)


def normals_from_covariances(covariances_m2: ArrayLike) -> F32:
    """(N, 3) float32 unit eigenvectors of the smallest eigenvalue of each (N, 3, 3) covariance.

    The normal of a flat splat; its sign is whatever ``numpy.linalg.eigh`` returns (deterministic, arbitrary).
    """
    c = np.asarray(covariances_m2, np.float64)
    if c.ndim != 3 or c.shape[1:] != (3, 3):
        raise ValueError(f"covariances_m2 must have shape (N, 3, 3), got {c.shape}")
    if len(c) == 0:
        return np.zeros((0, 3), np.float32)
    _, vecs = np.linalg.eigh(c)
    return np.ascontiguousarray(vecs[:, :, 0], np.float32)


def deform_normals(normals: ArrayLike, deformation_gradients: ArrayLike) -> F32:
    """Unit normals (N, 3) after local deformations F (N, 3, 3): F^-T n, renormalised (float32).

    Computed with the cofactor matrix cof(F) = det(F) F^-T (columns f1 x f2, f2 x f0, f0 x f1 of
    F = [f0 f1 f2]) times sign(det F): finite for singular F, and the tangent plane's normal
    (F t1) x (F t2) = cof(F) (t1 x t2) for any tangents t1 x t2 = n. A normal whose image vanishes
    (F collapses the tangent plane) keeps its old direction.
    """
    n = np.asarray(normals, np.float64)
    f = np.asarray(deformation_gradients, np.float64)
    if n.ndim != 2 or n.shape[1] != 3 or f.shape != (len(n), 3, 3):
        raise ValueError(f"deform_normals: need normals (N, 3) and F (N, 3, 3), got {n.shape} and {f.shape}")
    f0, f1, f2 = f[:, :, 0], f[:, :, 1], f[:, :, 2]
    out = (
        n[:, 0:1] * np.cross(f1, f2) + n[:, 1:2] * np.cross(f2, f0) + n[:, 2:3] * np.cross(f0, f1)
    ) * np.where(np.linalg.det(f) < 0.0, -1.0, 1.0)[:, None]
    norm = np.linalg.norm(out, axis=1, keepdims=True)
    ok = norm[:, 0] > 1e-20
    out[ok] /= norm[ok]
    out[~ok] = n[~ok]
    return np.ascontiguousarray(out, np.float32)


def _unit_normals(arr: F32) -> F32:
    norm = np.linalg.norm(arr.astype(np.float64), axis=1)
    bad = norm < 1e-6
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"Gaussians.normals[{i}] = {arr[i].tolist()} has zero length; need a direction")
    return np.ascontiguousarray(arr / norm[:, None], np.float32)


def _as_part_ids(value: ArrayLike | None, count: int) -> I32:
    if value is None:
        return np.zeros(count, np.int32)
    ids = np.ascontiguousarray(np.asarray(value), np.int32)
    if ids.shape != (count,):
        raise ValueError(f"Gaussians.part_ids must have shape ({count},), got {ids.shape}")
    return ids


def _check_covariances(cov: F32) -> None:
    c = cov.astype(np.float64)
    if len(c) == 0:
        return
    scale = np.maximum(np.abs(c).reshape(len(c), 9).max(axis=1), 1e-30)
    asym = np.abs(c - np.swapaxes(c, 1, 2)).reshape(len(c), 9).max(axis=1) / scale
    bad = asym > COVARIANCE_TOLERANCE
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"Gaussians.covariances_m2[{i}] is not symmetric: {cov[i].tolist()}")
    lam_min = np.linalg.eigvalsh(c)[:, 0] / scale
    bad = lam_min < -COVARIANCE_TOLERANCE
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"Gaussians.covariances_m2[{i}] is not positive semi-definite "
            f"(smallest eigenvalue {lam_min[i] * scale[i]:.3g} m^2 < 0)"
        )
