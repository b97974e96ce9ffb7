"""The in-place LAPACK Newton directions (:mod:`data_gen.sim.lapack`): torch.linalg's bits on symmetric
matrices, the upper triangle of nearly symmetric ones, analytic values, and the cases they hand back."""

import platform
import sys

import pytest
import torch

from data_gen.sim.lapack import CholeskyDirections, lapack_routines, upper_symmetric
from data_gen.sim.newton import cholesky_direction

# torch's x86_64 Linux builds (the project's machines) link MKL into libtorch_cpu: there the in-place path must be
# taken, so these tests run and fail if the routines went missing or failed their check against torch.linalg (a
# silent fall back to the slower path); other builds may not export them
ON_MKL_BUILD = sys.platform == "linux" and platform.machine() == "x86_64"
needs_lapack = pytest.mark.skipif(not ON_MKL_BUILD and lapack_routines() is None,
                                  reason="torch's CPU library exports no dpotrf/dpotrs")  # fmt: skip


def torch_direction(hess: torch.Tensor, grad: torch.Tensor) -> torch.Tensor:
    """The solver's torch.linalg direction of positive definite matrices (the reference)."""
    dq, ok = cholesky_direction(hess, grad)
    assert ok is None  # every matrix positive definite
    return dq


def _spd(n_isl: int, size: int, seed: int, asymmetry: float = 0.0) -> tuple[torch.Tensor, torch.Tensor]:
    generator = torch.Generator().manual_seed(seed)
    a = torch.randn(n_isl, size, size, dtype=torch.float64, generator=generator)
    hess = a @ a.mT + 1e-3 * torch.eye(size, dtype=torch.float64)
    hess = torch.add(hess, hess.mT).mul_(0.5)  # exactly symmetric
    hess = hess + asymmetry * torch.randn(hess.shape, dtype=torch.float64, generator=generator)
    return hess, torch.randn(n_isl, size, dtype=torch.float64, generator=generator)


@needs_lapack
@pytest.mark.parametrize("n_isl,size", [(1, 240), (3, 48), (2, 96)])
def test_directions_of_symmetric_matrices_are_torch_linalg_bit_for_bit(n_isl, size):
    hess, grad = _spd(n_isl, size, seed=size)
    out = torch.full((n_isl, size), float("nan"), dtype=torch.float64)
    before = hess.clone()
    assert CholeskyDirections().solve(hess, grad, out, [True] * n_isl)
    assert torch.equal(hess, before)  # factorised on a copy
    assert torch.equal(out, torch_direction(hess, grad))
    assert torch.allclose(hess @ out[:, :, None], -grad[:, :, None], rtol=0, atol=1e-6)  # it solves the system


@needs_lapack
def test_a_nearly_symmetric_matrix_is_read_by_its_upper_triangle():
    """The solver's matrices are symmetric to round-off: the factor is the upper triangle's (exactly), within
    round-off of the symmetric part's; in place, the matrix is consumed."""
    hess, grad = _spd(2, 60, seed=5, asymmetry=1e-13)
    assert not torch.equal(hess, hess.mT)
    out = torch.empty(2, 60, dtype=torch.float64)
    directions = CholeskyDirections()
    matrix = hess.clone()
    assert directions.solve(matrix, grad, out, [True, True], overwrite=True)
    assert not torch.equal(matrix, hess)  # overwritten by its factor
    assert torch.equal(out, torch_direction(upper_symmetric(hess), grad))
    reference = torch_direction(hess, grad)
    torch.testing.assert_close(out, reference, rtol=0.0, atol=1e-9 * float(reference.abs().amax()))


@needs_lapack
def test_direction_of_a_diagonal_system_is_exact():
    # square diagonal entries: the factor and both triangular solves are exact
    hess = torch.diag(torch.tensor([4.0, 16.0, 0.25], dtype=torch.float64))[None]
    out = torch.empty(1, 3, dtype=torch.float64)
    assert CholeskyDirections().solve(hess, torch.tensor([[4.0, 32.0, -0.25]], dtype=torch.float64), out, [True])
    assert out.tolist() == [[-1.0, -2.0, 1.0]]


@needs_lapack
def test_only_wanted_islands_are_solved_and_buffers_are_reused():
    hess, grad = _spd(3, 12, seed=1)
    hess[1] = -torch.eye(12, dtype=torch.float64)  # indefinite, but not wanted: never factorised
    out = torch.full((3, 12), 7.0, dtype=torch.float64)
    directions = CholeskyDirections()
    assert directions.solve(hess, grad, out, [True, False, True])
    assert torch.equal(out[[0, 2]], torch_direction(hess[[0, 2]], grad[[0, 2]]))
    assert directions.sum_buffer(3, 12) is directions.sum_buffer(3, 12)  # kept per shape
    assert directions.sum_buffer(3, 12).shape == (3, 12, 12)


@needs_lapack
def test_an_indefinite_wanted_matrix_is_handed_back_and_the_copy_path_keeps_it():
    hess, grad = _spd(2, 6, seed=2)
    hess[1, 3, 3] = -50.0
    before = hess.clone()
    out = torch.empty(2, 6, dtype=torch.float64)
    assert not CholeskyDirections().solve(hess, grad, out, [True, True])
    assert torch.equal(hess, before)  # the caller's matrix is untouched: its torch.linalg fallback reads it


def test_tensors_the_routines_cannot_take_are_handed_back():
    hess, grad = _spd(1, 8, seed=3)
    directions = CholeskyDirections()
    out = torch.empty(1, 8, dtype=torch.float64)
    assert not directions.solve(hess.float(), grad.float(), out.float(), [True])  # float32
    assert not directions.solve(hess.mT, grad, out, [True])  # not contiguous
    assert not directions.suits(hess.mT, grad, out) and not directions.suits(hess, grad.float(), out)


@needs_lapack
def test_a_solve_checked_once_equals_the_checked_solve():
    hess, grad = _spd(2, 24, seed=4)
    directions = CholeskyDirections()
    checked, unchecked = torch.empty(2, 24, dtype=torch.float64), torch.empty(2, 24, dtype=torch.float64)
    assert directions.suits(hess, grad, unchecked)
    assert directions.solve(hess, grad, checked, [True, True])
    assert directions.solve_suited(hess, grad, unchecked, [True, True])
    assert torch.equal(checked, unchecked)


def test_upper_symmetric_mirrors_the_upper_triangle():
    hess = torch.arange(9, dtype=torch.float64).reshape(1, 3, 3)
    assert upper_symmetric(hess).tolist() == [[[0.0, 1.0, 2.0], [1.0, 4.0, 5.0], [2.0, 5.0, 8.0]]]
