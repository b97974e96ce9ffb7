"""Newton directions by LAPACK's Cholesky routines of torch's own CPU library, called in place.

``torch.linalg.cholesky_ex`` copies its input into a new column-major matrix, calls LAPACK's ``dpotrf``, then
clears the other triangle; two ``torch.linalg.solve_triangular`` calls follow, and the solver symmetrised the
matrix before all that. For a soft island's 240-unknown matrix, factorised once per Newton iteration, those
passes and new tensors cost a third of the work. :class:`CholeskyDirections` calls the same library's
``dpotrf`` and ``dpotrs`` on the matrix in place (or on one copy of it) instead. A matrix stored row by row is
read by ``dpotrf`` as its transpose, and ``dpotrf`` reads one triangle only: the factor is that of the
symmetric matrix whose entries are the row-major upper triangle of the given one. The solver's matrices are
symmetric but for round-off (``|H - H^T| <= 7e-17 max |H|`` over the matrices of a ``soft_5`` run), so that
is their symmetric part to round-off, and for an exactly symmetric matrix it is :func:`data_gen.sim.newton.cholesky_direction`'s
result bit for bit (the routines are the ones torch calls). :func:`lapack_routines` checks that once per
process on a test matrix: where torch's library lacks the routines or differs, they are not used and the
caller keeps ``torch.linalg``.
"""

from __future__ import annotations

import ctypes
import functools
import os
from collections.abc import Sequence

import torch

from data_gen.sim.newton import cholesky_direction

_DTYPE = torch.float64


@functools.lru_cache(maxsize=1)
def lapack_routines() -> tuple[ctypes._CFuncPtr, ctypes._CFuncPtr] | None:
    """``(dpotrf_, dpotrs_)`` of the LAPACK linked into torch's CPU library, or None where that library does not
    export them or their direction for an exactly symmetric test matrix differs from :func:`data_gen.sim.newton.cholesky_direction`'s
    in any bit."""
    path = os.path.join(os.path.dirname(torch.__file__), "lib", "libtorch_cpu.so")
    try:
        library = ctypes.CDLL(path)
        routines = (library.dpotrf_, library.dpotrs_)
    except (OSError, AttributeError):
        return None
    for routine in routines:
        routine.restype = None
    generator = torch.Generator().manual_seed(0)
    a = torch.randn(1, 13, 13, dtype=_DTYPE, generator=generator)
    hess = a @ a.mT + 0.1 * torch.eye(13, dtype=_DTYPE)
    hess = torch.add(hess, hess.mT).mul_(0.5)  # exactly symmetric
    grad = torch.randn(1, 13, dtype=_DTYPE, generator=generator)
    out = torch.empty(1, 13, dtype=_DTYPE)
    if not _factor_and_solve(routines, hess.clone(), grad, out, [True]):
        return None
    return routines if torch.equal(out, cholesky_direction(hess, grad)[0]) else None


def upper_symmetric(hess: torch.Tensor) -> torch.Tensor:
    """The symmetric matrices (n, N, N) whose entries are ``hess``'s row-major upper triangles: what
    :class:`CholeskyDirections` factorises."""
    upper = torch.triu(hess)
    return upper + torch.triu(hess, diagonal=1).mT


def _factor_and_solve(routines, matrices: torch.Tensor, grad: torch.Tensor, out: torch.Tensor,
                      wanted: Sequence[bool]) -> bool:  # fmt: skip
    """``out[i] = -H_i^-1 g_i`` for the islands ``i`` with ``wanted[i]``, ``H_i`` factorised in place in
    ``matrices[i]`` (overwritten). False as soon as one of those matrices is not positive definite."""
    dpotrf, dpotrs = routines
    torch.neg(grad, out=out)
    n = ctypes.c_int(matrices.shape[1])
    one, info = ctypes.c_int(1), ctypes.c_int(0)
    lower = ctypes.c_char(b"L")  # of the column-major matrix LAPACK sees: the row-major upper triangle
    for i, want in enumerate(wanted):
        if not want:
            continue
        matrix = ctypes.c_void_p(matrices[i].data_ptr())
        dpotrf(ctypes.byref(lower), ctypes.byref(n), matrix, ctypes.byref(n), ctypes.byref(info))
        if info.value != 0:
            return False
        rhs = ctypes.c_void_p(out[i].data_ptr())
        dpotrs(ctypes.byref(lower), ctypes.byref(n), ctypes.byref(one), matrix, ctypes.byref(n), rhs, ctypes.byref(n),
               ctypes.byref(info))  # fmt: skip
        if info.value != 0:
            return False
    return True


class CholeskyDirections:
    """Newton directions ``-H^-1 g`` of a batch of island matrices, written into a caller's buffer, by
    :func:`lapack_routines` (see the module docstring), with scratch buffers kept per shape."""

    def __init__(self) -> None:
        self._routines = lapack_routines()
        self._scratch: dict[tuple[int, int], tuple[torch.Tensor, torch.Tensor]] = {}

    def sum_buffer(self, n_isl: int, size: int) -> torch.Tensor:
        """A kept (n_isl, size, size) buffer for the caller's matrix (``torch.add(..., out=)``), which
        :meth:`solve` may then factorise in place (``overwrite``)."""
        return self._buffers(n_isl, size)[0]

    def _buffers(self, n_isl: int, size: int) -> tuple[torch.Tensor, torch.Tensor]:
        key = (n_isl, size)
        buffers = self._scratch.get(key)
        if buffers is None:
            buffers = self._scratch[key] = tuple(torch.empty(n_isl, size, size, dtype=_DTYPE) for _ in range(2))
        return buffers

    def solve(self, hess: torch.Tensor, grad: torch.Tensor, out: torch.Tensor, wanted: Sequence[bool],
              overwrite: bool = False) -> bool:  # fmt: skip
        """``out[i] = -H_i^-1 g_i`` (``hess`` (n, N, N), ``grad`` and ``out`` (n, N), float64, contiguous, on the
        CPU; ``H_i`` :func:`upper_symmetric` of ``hess[i]``) for the islands with ``wanted[i]``; the others' rows
        of ``out`` are left undefined. ``hess`` is factorised in place with ``overwrite``, else a copy of it.
        False, with ``out`` (and with ``overwrite`` ``hess``) undefined, when the routines are unavailable, the
        tensors do not suit them, or a wanted matrix is not positive definite: the caller then takes the
        ``torch.linalg`` path (with its ridge)."""
        if not self.suits(hess, grad, out):
            return False
        return self.solve_suited(hess, grad, out, wanted, overwrite)

    def suits(self, hess: torch.Tensor, grad: torch.Tensor, out: torch.Tensor) -> bool:
        """Whether :meth:`solve` can take these tensors (the routines are available; float64, contiguous, on the
        CPU)."""
        return self._routines is not None and _suits(hess, grad, out)

    def solve_suited(self, hess: torch.Tensor, grad: torch.Tensor, out: torch.Tensor, wanted: Sequence[bool],
                     overwrite: bool = False) -> bool:  # fmt: skip
        """:meth:`solve` of tensors :meth:`suits` has accepted (or others like them: the same dtype, device and
        layout), without checking them again (a solve's loop over its Newton iterations checks once)."""
        matrices = hess
        if not overwrite:
            matrices = self._buffers(*grad.shape)[1]
            matrices.copy_(hess)
        return _factor_and_solve(self._routines, matrices, grad, out, wanted)


def _suits(*tensors: torch.Tensor) -> bool:
    return all(t.dtype == _DTYPE and t.device.type == "cpu" and t.is_contiguous() for t in tensors)


__all__ = ["CholeskyDirections", "lapack_routines", "upper_symmetric"]
