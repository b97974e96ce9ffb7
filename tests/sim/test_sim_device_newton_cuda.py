"""The device schedule (:mod:`data_gen.sim.device_newton`) on a CUDA GPU against the fused kernel on the CPU: what
only a GPU runs (atomic adds in any order, MathDx's blocked factorisation with 64 threads a block, CUDA graphs with
nested conditional loops, the copies to and from the device). Skipped without a GPU (CI has none); the first lent
GPU runs it (``docs/gpu_checks.md``).

The bounds are looser than the CPU tests' bits: on a GPU the atomic adds sum in any order, so values differ from
the fused kernel's by round-off and a decision at the edge (an Armijo test, a convergence test) may go the other
way; a wrong kernel differs by orders of magnitude more. Each test prints what it measured."""

import itertools

import numpy as np
import pytest
import torch
import warp as wp

from data_gen.sim.device_newton import DeviceNewton
from data_gen.sim.fused_newton import FusedNewton
from tests.sim.test_sim_device_newton import _built_as, _stack
from tests.sim.test_sim_fused_newton import _captured_solves

wp.init()
pytestmark = pytest.mark.skipif(not wp.is_cuda_available(), reason="no CUDA device")


def test_recorded_steps_on_the_gpu_end_where_the_fused_kernel_ends():
    """The thrown stack's recorded steps (every third trust-limited), each solved by the fused kernel on the CPU
    and by the schedule on the GPU (copies, the captured graph, the blocked factorisation): the same convergence,
    iterations within 10 % (+1), the states within 0.05 of the tolerance (mass norm), the graph not fallen back."""
    worst = 0.0
    for (objective, q0, scale, trust, settings), factor in zip(_captured_solves(throw=True),
                                                               itertools.cycle([1.0, 1.0, 0.005])):  # fmt: skip
        trust = factor * trust
        fused = FusedNewton(objective.model, objective.layout, objective.contact, objective.island_mass_kg,
                            objective.min_median_radius_m)  # fmt: skip
        ref = fused.solve(objective, q0, scale, trust, settings)
        ref_q, ref_iterations, ref_converged = ref.q.clone(), ref.iterations.clone(), ref.converged.clone()
        gpu = DeviceNewton(fused, device="cuda")
        out = gpu.solve(objective, q0, scale, trust, settings)
        assert gpu.graph and gpu.tile_factor  # (a failed capture logs and turns the graph off)
        assert out is not None and torch.equal(out.converged, ref_converged)
        assert bool(((out.iterations - ref_iterations).abs() <= 0.1 * ref_iterations + 1).all())
        gap = objective.mass_norm(out.q - ref_q) / (settings.tolerance * scale)
        worst = max(worst, float(gap.max()))
        assert bool((gap <= 0.05).all()), gap.tolist()
    print(f"recorded steps on the GPU: largest state gap {worst:.3g} of the tolerance")


def test_a_simulation_on_the_gpu_follows_the_fused_kernel(monkeypatch):
    """The thrown stack (sub-step schedules on the GPU, graphs reused) and the soft stack (deformable solves):
    every island solve through the schedule, none handed back, trajectories within 1e-6 m and 1e-4 m of the
    fused and split paths on the CPU, resting one box height per box."""
    _built_as(monkeypatch, "cuda", None, None)
    gpu, cpu = _stack(True, True), _stack(True, False)
    com_g, com_c = (np.stack([t.com_m for t in r.objects]) for r in (gpu, cpu))
    counters = gpu.info.counters
    print(f"thrown stack on the GPU: largest centre gap {np.abs(com_g - com_c).max():.3g} m; graphs captured "
          f"{counters['device_graphs_captured']}, reused {counters['device_graphs_reused']}")  # fmt: skip
    assert counters["device_island_solves"] == counters["island_solves"] > 0 and counters["device_handed_back"] == 0
    assert counters["device_graphs_captured"] > 0
    assert np.abs(com_g - com_c).max() < 1e-6
    np.testing.assert_allclose(np.diff(np.sort(com_g[:, -1, 2])), 0.1, atol=0.01)
    kwargs = dict(frames=20, handles=2, young_pa=1e5)
    soft, split = _stack(False, True, **kwargs), _stack(False, False, **kwargs)
    gap = np.abs(np.stack([t.com_m for t in soft.objects]) - np.stack([t.com_m for t in split.objects])).max()
    print(f"soft stack on the GPU: largest centre gap from the split solve {gap:.3g} m")
    assert soft.info.counters["device_handed_back"] == 0 and soft.info.counters["device_island_solves"] > 0
    assert gap < 1e-4
