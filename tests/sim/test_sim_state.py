"""The solver's State: stepping replaces its entries instead of writing into them; a copy is independent."""

import numpy as np
import pytest
import torch

from data_gen.sim.presets import load_preset
from data_gen.sim.reduced import z_to_q
from data_gen.sim.solver import ImplicitEulerSolver, SimBody
from data_gen.sim.state import State
from data_gen.sim.static_scene import StaticScene
from tests.sim.test_sim_batched_terms import _object


def _falling(state: State, handles=(1, 3)) -> ImplicitEulerSolver:
    """A solver of small objects above the ground, at ``state``."""
    bodies = [SimBody(k + 1, f"o{k}", *_object(h, seed=k), 0.5) for k, h in enumerate(handles)]
    gravity = np.array([0.0, 0.0, -9.81])
    return ImplicitEulerSolver(bodies, state, StaticScene(), gravity, load_preset("draft"), 0.01)


def _initial_state(handles=(1, 3)) -> State:
    gen = torch.Generator().manual_seed(4)
    qs, qdots = [], []
    for k, h in enumerate(handles):
        z = torch.zeros(12 * h, dtype=torch.float64)
        z[3], z[11] = 2.0 * k - 1.0, 2.0  # handle 0 translated to (+-1, 0, 2) m, well apart, above the ground
        qs.append(z_to_q(z))
        qdots.append(0.1 * torch.randn(12 * h, generator=gen, dtype=torch.float64))
    return State.awake(qs, qdots)


def test_stepping_replaces_state_entries_and_copies_step_alike():
    state = _initial_state()
    given = state.copy()
    q_before, qdot_before = list(state.q), list(state.qdot)
    solver = _falling(state)
    assert solver.state is state
    twin = _falling(given.copy())
    for _ in range(3):
        solver.step()
        twin.step()
    for k in range(state.num_objects):
        assert not torch.equal(state.q[k], given.q[k])  # the objects moved, by new tensors:
        assert torch.equal(q_before[k], given.q[k]) and torch.equal(qdot_before[k], given.qdot[k])
        assert torch.equal(twin.state.q[k], state.q[k]) and torch.equal(twin.state.qdot[k], state.qdot[k])
    # a copy shares nothing with its original
    snapshot = state.copy()
    snapshot.q[0] += 1.0
    snapshot.qdot[1][0] = 5.0
    snapshot.asleep[:] = True
    snapshot.slow_steps += 3
    assert torch.equal(state.q[0], twin.state.q[0]) and torch.equal(state.qdot[1], twin.state.qdot[1])
    assert not state.asleep.any() and not state.slow_steps.any()


def test_state_and_bodies_must_agree_in_number():
    state = _initial_state()
    with pytest.raises(ValueError, match="2 rates"):
        State(state.q + state.q[:1], state.qdot, state.asleep, state.slow_steps)
    with pytest.raises(ValueError, match="2 objects for 1 bodies"):
        _falling(state, handles=(1,))
