"""The lagged elastic Newton matrix (``QualityPreset.lagged_elastic_hessian``, :class:`StepObjective`): a soft
object's elastic matrix is formed at the first evaluation of a (sub)step and kept for its later iterations,
while values and gradients stay exact and one-handle objects keep getting theirs formed; Newton's method
with it reaches the same step as with the exact matrix."""

import torch

from data_gen.sim.newton import NewtonSettings, minimise
from data_gen.sim.presets import available_presets, load_preset
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.step_objective import StepObjective
from tests.sim.test_sim_warp_kernels import _setup, random_rates

D = torch.float64
GRAVITY = torch.tensor([0.0, 0.0, -9.81], dtype=D)
H_S = 0.01


def _objectives(seed: int = 3):
    """The same step (objects of 1, 3 and 2 handles; two islands; scene and pair contact) with the exact and
    the lagged elastic matrix, and its predicted state (island vectors)."""
    model, layout, distance, _, _, pairs, tm = _setup(StaticScene(), seed, (1, 3, 2))
    tmdot = random_rates(model, tm, seed + 1)
    args = (model, layout, distance, GRAVITY, tm, tmdot, H_S, 20.0, 0.01 * H_S, pairs)
    return StepObjective(*args), StepObjective(*args, lagged_elastic_hessian=True), layout.to_islands(tm + H_S * tmdot)


def _object_block(layout, matrix: torch.Tensor, o: int) -> torch.Tensor:
    """Object o's diagonal block of island matrices (n_isl, N, N)."""
    rows = layout.flat_index[o]
    rows = rows[rows >= 0]
    island, local = rows // layout.island_size, rows % layout.island_size
    return matrix[island[0]][local[:, None], local[None, :]]


def test_lagged_objective_keeps_the_first_elastic_matrix_of_soft_objects_only():
    exact, lagged, q0 = _objectives()
    layout, model = exact.layout, exact.model
    gen = torch.Generator().manual_seed(11)
    q1 = q0 + 0.02 * torch.randn(q0.shape, generator=gen, dtype=D) * (q0 != 0)  # deform every object
    first_exact, first_lagged = exact.evaluate(q0, True), lagged.evaluate(q0, True)
    assert torch.equal(first_lagged.hess, first_exact.hess) and torch.equal(first_lagged.grad, first_exact.grad)

    later_exact, later_lagged = exact.evaluate(q1, True), lagged.evaluate(q1, True)
    # values and gradients at the new state: exact
    torch.testing.assert_close(later_lagged.value, later_exact.value, rtol=1e-14, atol=0.0)
    torch.testing.assert_close(later_lagged.grad, later_exact.grad, rtol=0.0, atol=1e-12 * float(later_exact.grad.abs().max()))
    # the matrix: the exact one with each soft object's elastic block at q0 instead of q1
    el0 = exact._elastic(layout.to_objects(q0), True, None).hess
    el1 = exact._elastic(layout.to_objects(q1), True, None).hess
    soft = (model.num_handles > 1)[:, None, None].to(D)
    expected = later_exact.hess + layout.assemble(exact.h2 * soft * (el0 - el1))
    scale = float(later_exact.hess.abs().max())
    torch.testing.assert_close(later_lagged.hess, expected, rtol=0.0, atol=1e-12 * scale)
    difference = later_lagged.hess - later_exact.hess
    for o in range(model.num_objects):
        block = _object_block(layout, difference, o)
        if int(model.num_handles[o]) == 1:
            assert torch.equal(block, torch.zeros_like(block))  # formed anew
        else:  # kept: differs from the exact block by what the deformation changed (not a vacuous check)
            assert float(block.abs().max()) > 1e-6 * scale
    # a projected re-evaluation (minimise's answer to an indefinite matrix) forms its matrix, as the exact one does
    every = torch.ones(layout.num_islands, dtype=torch.bool)
    strict_exact, strict_lagged = exact.evaluate(q1, True, every), lagged.evaluate(q1, True, every)
    assert torch.equal(strict_lagged.hess, strict_exact.hess)


def test_lagged_newton_reaches_the_step_of_exact_newton():
    """Island 1 holds the 3-handle object alone (scene contact and friction). Island 0's artificial pile of 228
    penetrating pairs is left out: it does not converge in 200 iterations with the exact matrix either."""
    exact, lagged, q0 = _objectives()
    settings = NewtonSettings(iterations=60, tolerance=1e-8, line_search_steps=12)
    results = {
        name: minimise(objective, q0, objective.motion_scale(), objective.trust_radius(), settings)
        for name, objective in (("exact", exact), ("lagged", lagged))
    }
    assert bool(results["exact"].converged[1]) and bool(results["lagged"].converged[1])
    q_exact, q_lagged = results["exact"].q[1:], results["lagged"].q[1:]
    motion = float(exact.mass_norm(results["exact"].q - q0)[1])  # how far the step moved the island (|dq|_M)
    assert float(exact.mass_norm(torch.cat([results["exact"].q[:1], q_lagged]) - results["exact"].q)[1]) <= 1e-9 * motion
    assert not torch.equal(q_lagged, q_exact)  # two different iterations, one step
    # the kept matrix slows convergence a little (measured 15 -> 18 iterations), it does not stall it
    exact_its, lagged_its = int(results["exact"].iterations[1]), int(results["lagged"].iterations[1])
    assert exact_its <= lagged_its <= 2 * exact_its


def test_every_preset_but_the_reference_lags_the_elastic_matrix():
    """What the shipped presets choose (README, "Lagged elastic matrix"): draft, standard and high keep a soft
    object's elastic matrix through a step (measured: the same errors against the reference); the reference,
    the yardstick of those measurements, forms it at every iteration."""
    assert {name: load_preset(name).lagged_elastic_hessian for name in available_presets()} == {
        "draft": True, "high": True, "reference": False, "standard": True,
    }
