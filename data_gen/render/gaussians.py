"""A set of 3D Gaussian splats: the only scene description the renderer knows.

A Gaussian ``i`` has a centre ``means_m[i]`` (world frame, m), a shape given
either by per-axis standard deviations ``scales_m[i]`` (m) and a rotation
``rotations_wxyz[i]`` (unit quaternion, (w, x, y, z)), or directly by a world
covariance ``covariances_m2[i]`` (m^2), a colour ``colors_rgb[i]`` in [0, 1]
and an opacity ``opacities[i]`` in [0, 1].

Only *surface* Gaussians are rendered. Interior particles that exist only for
the simulation must not be passed to the renderer (they would show up in the
label maps as the nearest covering Gaussian); the caller selects the surface
subset before building a :class:`Gaussians`.

Simulated deformation moves a splat through its centre and deforms its shape
through the local deformation gradient ``F``: Sigma -> F Sigma F^T
(:meth:`Gaussians.deformed`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from newtphys.rotations import quat_to_matrix

F32 = NDArray[np.float32]
F64 = NDArray[np.float64]

#: Relative tolerance for the symmetry / positive semi-definiteness of a given covariance.
COVARIANCE_TOLERANCE = 1e-6


def _as_float_array(name: str, value: ArrayLike, shape_tail: tuple[int, ...], count: int | None) -> F32:
    arr = np.ascontiguousarray(np.asarray(value, dtype=np.float32))
    expected = ("N",) + shape_tail
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        raise ValueError(f"Gaussians.{name} must have shape {expected}, got {arr.shape}")
    if count is not None and arr.shape[0] != count:
        raise ValueError(f"Gaussians.{name} has {arr.shape[0]} rows but means_m has {count}")
    bad = _bad_rows(~np.isfinite(arr))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"Gaussians.{name}[{i}] is not finite: {arr[i].tolist()}")
    return arr


def _bad_rows(flags: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """(N, ...) per-element flags -> (N,) any flag per row (works for N = 0)."""
    return flags.reshape(flags.shape[0], int(np.prod(flags.shape[1:], dtype=np.int64))).any(axis=1)


def _check_range(name: str, arr: F32, low: float, high: float) -> None:
    bad = _bad_rows((arr < low) | (arr > high))
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"Gaussians.{name}[{i}] = {arr[i].tolist()} is outside the allowed range [{low}, {high}]"
        )


@dataclass(frozen=True, kw_only=True)
class Gaussians:
    """N Gaussian splats (arrays are converted to contiguous float32 and validated).

    Give either ``scales_m`` (with optional ``rotations_wxyz``, identity when
    omitted) or ``covariances_m2``, not both.
    """

    means_m: F32
    scales_m: F32 | None = None
    covariances_m2: F32 | None = None
    rotations_wxyz: F32 | None = None
    colors_rgb: F32
    opacities: F32

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
        _check_range("scales_m", scales, 0.0, np.inf)
        set_("scales_m", scales)
        if self.rotations_wxyz is None:
            rot = np.zeros((n, 4), np.float32)
            rot[:, 0] = 1.0
        else:
            rot = _as_float_array("rotations_wxyz", self.rotations_wxyz, (4,), n)
            norm = np.linalg.norm(rot, axis=1)
            bad = norm < 1e-8
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"Gaussians.rotations_wxyz[{i}] = {rot[i].tolist()} has zero norm; need a unit quaternion"
                )
            rot = (rot / norm[:, None]).astype(np.float32)
        set_("rotations_wxyz", rot)

    def _set_field(self, name: str, value: object) -> None:
        object.__setattr__(self, name, value)  # the dataclass is frozen; only __post_init__ normalises

    def __len__(self) -> int:
        return int(self.means_m.shape[0])

    def covariances(self) -> F64:
        """World covariances (N, 3, 3), m^2, float64: given ones, or R diag(s^2) R^T."""
        if self.covariances_m2 is not None:
            return self.covariances_m2.astype(np.float64)
        assert self.scales_m is not None and self.rotations_wxyz is not None
        rot = quat_to_matrix(self.rotations_wxyz.astype(np.float64))
        rs = rot * self.scales_m.astype(np.float64)[:, None, :]  # R S (columns scaled)
        return rs @ np.swapaxes(rs, 1, 2)

    def deformed(self, deformation_gradients: ArrayLike, means_m: ArrayLike | None = None) -> Gaussians:
        """Gaussians after a local deformation: Sigma -> F Sigma F^T, centres moved to ``means_m`` if given.

        ``deformation_gradients`` is (N, 3, 3), dimensionless (dx/dX at each
        splat centre). The result stores full covariances.
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
        )

    def subset(self, selection: ArrayLike) -> Gaussians:
        """The Gaussians picked by a boolean mask (N,) or an index array."""
        sel = np.asarray(selection)
        if sel.dtype == bool and sel.shape != (len(self),):
            raise ValueError(f"boolean selection must have shape ({len(self)},), got {sel.shape}")
        fields = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return Gaussians(**{k: (None if v is None else v[sel]) for k, v in fields.items()})


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
