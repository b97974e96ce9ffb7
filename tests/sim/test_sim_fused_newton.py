"""The fused Newton kernel (:mod:`data_gen.sim.fused_newton`) against the batched path it replaces: the same
objective, gradient and Newton matrix as :class:`StepObjective` (1e-10), the same minimiser result as
:func:`minimise` to the solver's tolerance, the hand-back to ``minimise`` where it cannot go on, and whole
simulations that agree with the batched path and repeat bit for bit."""

import itertools
from unittest import mock

import numpy as np
import pytest
import torch

from data_gen.sim.contact import pair_depth
from data_gen.sim.fused_newton import FusedNewton
from data_gen.sim.newton import NewtonSettings, minimise
from data_gen.sim.presets import load_preset
from data_gen.sim.static_scene import StaticBox, StaticPoints, StaticScene
from data_gen.sim.step_objective import StepObjective
from tests.sim.test_sim_warp_kernels import _setup, random_rates

D = torch.float64
GRAVITY = torch.tensor([0.0, 0.0, -9.81], dtype=D)
H_S = 0.01
STIFFNESS_FACTOR = load_preset("draft").contact_stiffness_factor

SCENES = [
    StaticScene(),
    StaticScene(boxes=(StaticBox((0.6, 0.0, 0.1), (0.2, 0.3, 0.1), (0.95, 0.05, 0.2, 0.1)),)),
    StaticScene(points=StaticPoints(np.array([[0.0, 0.0, 0.05], [0.05, 0.0, 0.05], [0.6, 0.0, 0.1]]), 0.04, 0.1)),
]
IDS = ["ground", "box", "points"]


def _objective(scene: StaticScene, seed: int = 3, speed: float = 0.3, handles: tuple[int, int, int] = (1, 3, 2)):
    """A step of the three-object set of the kernel tests (by default 1, 3 and 2 handles; two islands, pairs
    within an island and against a frozen partner), moving at ``speed`` (m/s scale) from its start."""
    model, layout, distance, _, _, pairs, tm = _setup(scene, seed, handles)
    tmdot = random_rates(model, tm, seed + 1, speed)
    objective = StepObjective(model, layout, distance, GRAVITY, tm, tmdot, H_S, 20.0, 0.01 * H_S, pairs)
    fused = FusedNewton(model, layout, objective.contact, objective.island_mass_kg, objective.min_median_radius_m)
    return objective, fused, layout.to_islands(tm + H_S * tmdot)


@pytest.mark.parametrize("scene", SCENES, ids=IDS)
@pytest.mark.parametrize("handles", [(1, 3, 2), (1, 1, 1)], ids=["mixed", "one-handle"])
def test_fused_objective_equals_the_step_objective(scene, handles):
    """Mixed handle counts (equal island sizes) and one-handle objects (islands of 24 and 12 unknowns: the
    smaller one's padded rows are identity rows), strained enough that some elastic blocks fail the near-SPD
    test and are projected."""
    objective, fused, q0 = _objective(scene, handles=handles)
    gen = torch.Generator().manual_seed(7)
    layout = objective.layout
    lowered = layout.to_objects(q0).clone()
    lowered[:, 2, 3] -= 0.05  # 5 cm down: spheres clear of the scene at the start now touch it (the kernel skips
    # spheres by their start distance and a bound on their motion: these must not be skipped)
    projected = False
    for q in (q0, q0 + 2e-3 * torch.randn(q0.shape, generator=gen, dtype=D), layout.to_islands(lowered)):
        ref = objective.evaluate(q, True)
        value, grad, hess, flagged = fused.evaluate(objective, q, True)
        projected |= bool(flagged.any())
        torch.testing.assert_close(value, ref.value, rtol=1e-11, atol=0.0)
        scale_g = ref.grad.abs().amax()
        torch.testing.assert_close(grad, ref.grad, rtol=0.0, atol=1e-10 * float(scale_g))
        torch.testing.assert_close(hess, ref.hess, rtol=0.0, atol=1e-10 * float(ref.hess.abs().amax()))
        value_only, no_grad, _, _ = fused.evaluate(objective, q, False)
        assert no_grad is None
        torch.testing.assert_close(value_only, ref.value, rtol=1e-11, atol=0.0)
    assert projected  # the strained states exercise the projection of elastic blocks


@pytest.mark.parametrize("scene", SCENES, ids=IDS)
def test_kernel_evaluation_of_deformable_islands_equals_the_batched_terms(scene):
    """``StepObjective(kernel_evaluation=True)`` on deformable objects (3, 2 and 4 handles, pairs in an island
    and against a frozen partner, lagged elastic matrix): an evaluation without derivatives is one launch
    from the start, one with derivatives once the first has formed the kept elastic blocks (the kernel adds
    only the contact matrix to the kept ``M + h^2 K``; the first forms those blocks from the elastic kernel's
    point Hessians and launches too). Values, gradients and matrices equal the batched terms' at every state
    to round-off, and a projected (strict) evaluation still takes the batched terms."""
    model, layout, distance, _, _, pairs, tm = _setup(scene, 3, (3, 2, 4))
    tmdot = torch.zeros_like(tm)
    gen = torch.Generator().manual_seed(4)
    for o in range(model.num_objects):
        cols = 4 * int(model.num_handles[o])
        tmdot[o, :, :cols] = 0.3 * torch.randn(3, cols, generator=gen, dtype=D) / cols

    def objective(kernel: bool) -> StepObjective:
        return StepObjective(model, layout, distance, GRAVITY, tm, tmdot, H_S, 20.0, 0.01 * H_S, pairs,
                             lagged_elastic_hessian=True, kernel_evaluation=kernel)  # fmt: skip

    kernel, batched = objective(True), objective(False)
    assert kernel.evaluator is not None and batched.evaluator is None
    launches = kernel.evaluator.evaluate_bound = mock.Mock(wraps=kernel.evaluator.evaluate_bound)
    q0 = layout.to_islands(tm + H_S * tmdot)
    states = [q0 + 2e-3 * torch.randn(q0.shape, generator=gen, dtype=D) for _ in range(3)]
    ref_value = batched.evaluate(q0, False).value
    torch.testing.assert_close(kernel.evaluate(q0, False).value, ref_value, rtol=1e-12, atol=0.0)
    assert launches.call_count == 1  # without derivatives: the kernel from the first evaluation on
    for k, q in enumerate([q0, *states]):
        ev, ref = kernel.evaluate(q, True), batched.evaluate(q, True)
        # every evaluation launches, the first with derivatives after forming the kept blocks
        assert launches.call_count == 2 + 2 * k
        torch.testing.assert_close(ev.value, ref.value, rtol=1e-12, atol=0.0)
        torch.testing.assert_close(ev.grad, ref.grad, rtol=0.0, atol=1e-10 * float(ref.grad.abs().amax()))
        torch.testing.assert_close(ev.hess, ref.hess, rtol=0.0, atol=1e-10 * float(ref.hess.abs().amax()))
        only = kernel.evaluate(q, False)
        torch.testing.assert_close(only.value, ref.value, rtol=1e-12, atol=0.0)
    assert not torch.equal(states[0], q0)
    strict = torch.ones(layout.num_islands, dtype=torch.bool)
    before = launches.call_count
    ev, ref = kernel.evaluate(states[-1], True, strict), batched.evaluate(states[-1], True, strict)
    assert launches.call_count == before  # projected: the batched terms
    torch.testing.assert_close(ev.hess, ref.hess, rtol=0.0, atol=1e-10 * float(ref.hess.abs().amax()))
    # the projected blocks are kept from then on: the next kernel evaluation adds its contact matrix to them
    ev, ref = kernel.evaluate(states[0], True), batched.evaluate(states[0], True)
    assert launches.call_count == before + 1
    torch.testing.assert_close(ev.hess, ref.hess, rtol=0.0, atol=1e-10 * float(ref.hess.abs().amax()))


def test_kernel_evaluation_follows_the_next_objective_on_the_same_workspace():
    """The solver builds one objective per (sub)step on a kept workspace: the kernel's launches (packed once per
    bound objective and replayed) must take the new objective's step length, rates and contact data, not the
    previous one's. The second objective has another h and other rates: its kernel evaluations equal its
    batched terms."""
    model, layout, distance, _, _, pairs, tm = _setup(SCENES[0], 3, (3, 2, 4))
    gen = torch.Generator().manual_seed(11)
    rates = []
    for speed in (0.3, 0.8):
        tmdot = torch.zeros_like(tm)
        for o in range(model.num_objects):
            cols = 4 * int(model.num_handles[o])
            tmdot[o, :, :cols] = speed * torch.randn(3, cols, generator=gen, dtype=D) / cols
        rates.append(tmdot)

    def objective(h_s: float, tmdot: torch.Tensor, kernel: bool, workspace=None) -> StepObjective:
        return StepObjective(model, layout, distance, GRAVITY, tm, tmdot, h_s, 20.0, 0.01 * h_s, pairs,
                             workspace=workspace, lagged_elastic_hessian=True, kernel_evaluation=kernel)  # fmt: skip

    first = objective(H_S, rates[0], True)
    q_first = layout.to_islands(tm + H_S * rates[0])
    first.evaluate(q_first, True)  # forms the kept blocks (and launches), as the next two evaluations do
    first.evaluate(q_first, True)
    first.evaluate(q_first, False)
    h2 = 0.5 * H_S
    second = objective(h2, rates[1], True, workspace=first.workspace)
    batched = objective(h2, rates[1], False)
    q = layout.to_islands(tm + h2 * rates[1]) + 1e-3 * torch.randn(q_first.shape, generator=gen, dtype=D)
    launches = second.evaluator.evaluate_bound = mock.Mock(wraps=second.evaluator.evaluate_bound)
    ref = batched.evaluate(q, True)
    torch.testing.assert_close(second.evaluate(q, False).value, ref.value, rtol=1e-12, atol=0.0)
    first_ev = second.evaluate(q, True)  # forms the second objective's own kept blocks
    ev = second.evaluate(q, True)
    assert launches.call_count == 3  # without derivatives, then with them (the first forming the kept blocks)
    torch.testing.assert_close(first_ev.hess, ev.hess, rtol=0.0, atol=0.0)  # the same kept blocks, the same state
    torch.testing.assert_close(ev.value, ref.value, rtol=1e-12, atol=0.0)
    torch.testing.assert_close(ev.grad, ref.grad, rtol=0.0, atol=1e-10 * float(ref.grad.abs().amax()))
    torch.testing.assert_close(ev.hess, ref.hess, rtol=0.0, atol=1e-10 * float(ref.hess.abs().amax()))


def test_step_objective_update_norms_equal_its_two_norms():
    """``minimise`` asks ``update_norms`` once per iteration; ``StepObjective`` computes both norms from one
    conversion to the objects' layout: the same values as ``point_motion`` and ``mass_norm`` bit for bit (two
    islands, mixed handle counts)."""
    objective, _, q0 = _objective(SCENES[0])
    gen = torch.Generator().manual_seed(9)
    for _ in range(3):
        dq = 1e-2 * torch.randn(q0.shape, generator=gen, dtype=D)
        motion, mass = objective.update_norms(dq)
        assert torch.equal(motion, objective.point_motion(dq)) and torch.equal(mass, objective.mass_norm(dq))
        assert bool((motion > 0).all()) and bool((mass > 0).all())


def _captured_solves(max_solves: int = 40, throw: bool = False):
    """Real (sub)step solves of the stack below (one-handle boxes falling, landing on the ground and on each
    other, with pairs and friction): the arguments the solver passed to ``minimise`` (batched path)."""
    import data_gen.sim.solver as solver_module

    captured = []
    original = solver_module.minimise

    def capture(objective, q0, scale, trust, settings, **kwargs):
        if len(captured) < max_solves:
            # the solver's objective shares its contact buffers with later solves of the same islands: rebuild
            # it with a workspace of its own
            o = objective
            own = StepObjective(o.model, o.layout, o.scene, o.gravity, o.tm_n, (o.tm_pred - o.tm_n) / o.h, o.h,
                                STIFFNESS_FACTOR, o.smoothing_m, o.pairs)  # fmt: skip
            captured.append((own, q0.clone(), scale.clone(), trust.clone(), settings))
        return original(objective, q0, scale, trust, settings, **kwargs)

    solver_module.minimise = capture
    try:
        _stack(fused=False, frames=10, throw=throw)
    finally:
        solver_module.minimise = original
    return captured


@pytest.mark.parametrize("throw", [False, True], ids=["dropped", "thrown"])
def test_fused_solve_matches_minimise_on_real_steps(throw):
    solves = _captured_solves(throw=throw)
    assert len(solves) >= 5
    trust_limited = 0
    for (objective, q0, scale, trust, settings), trust_factor in zip(solves, itertools.cycle([1.0, 1.0, 0.005])):
        # every third solve with a tiny trust radius: updates cut by it (the search starts below alpha = 1)
        trust = trust_factor * trust
        fused = FusedNewton(objective.model, objective.layout, objective.contact, objective.island_mass_kg,
                            objective.min_median_radius_m)
        ref = minimise(objective, q0, scale, trust, settings)
        out = fused.solve(objective, q0, scale, trust, settings)
        assert out is not None, "the kernel handed a recorded step back"
        trust_limited += out.counters["trust_limited_steps"]
        assert out.counters["trust_limited_steps"] == ref.counters["trust_limited_steps"]
        assert torch.equal(out.converged, ref.converged)
        # the same algorithm on the same objective takes the same path: the results differ by round-off, far
        # below the stopping tolerance (mass norm), and so do the iteration counts
        gap = objective.mass_norm(out.q - ref.q)
        assert bool((gap <= 0.05 * settings.tolerance * scale).all()), (gap / (settings.tolerance * scale)).tolist()
        assert torch.equal(out.iterations, ref.iterations)
        v_ref, v_out = objective.evaluate(ref.q, False).value, objective.evaluate(out.q, False).value
        assert bool(((v_out - v_ref).abs() <= 1e-9 * v_ref.abs()).all())
        assert out.counters["evaluations_with_derivatives"] >= int(out.iterations.sum())
        assert (out.iterations >= 1).all() and (out.iterations <= settings.iterations).all()
        if trust_factor == 1.0:  # the kernel's own threshold and trust radius: StepObjective's, to round-off
            own = fused.solve(objective, q0, None, None, settings)
            torch.testing.assert_close(fused.threshold, settings.tolerance * scale, rtol=1e-12, atol=0.0)
            torch.testing.assert_close(fused.trust, trust, rtol=1e-12, atol=0.0)
            assert torch.equal(own.iterations, out.iterations) and torch.equal(own.converged, out.converged)
            assert bool((objective.mass_norm(own.q - out.q) <= 1e-3 * settings.tolerance * scale).all())
    assert trust_limited > 0


def test_fused_solve_does_not_depend_on_the_previous_solve():
    """The envelope Cholesky reads only inside the current matrix's profile: a solve whose islands have no
    pairs (block-diagonal matrix) after one with pairs on the same buffers equals the same solve on fresh
    buffers, bit for bit."""
    from dataclasses import fields

    objective, q0, scale, trust, settings = next(c for c in _captured_solves() if c[0].pairs.num_pairs)
    first = objective.workspace.fused.solve(objective, q0, scale, trust, settings)
    assert bool(first.converged.all()) and int(first.iterations.sum()) >= 1
    o = objective
    no_pairs = type(o.pairs)(**{f.name: getattr(o.pairs, f.name)[:0] for f in fields(o.pairs)})
    args = (o.model, o.layout, o.scene, o.gravity, o.tm_n, (o.tm_pred - o.tm_n) / o.h, o.h, STIFFNESS_FACTOR,
            o.smoothing_m, no_pairs)  # fmt: skip
    reused = StepObjective(*args, workspace=objective.workspace)
    fresh = StepObjective(*args)
    a = reused.workspace.fused.solve(reused, q0, scale, trust, settings)
    b = fresh.workspace.fused.solve(fresh, q0, scale, trust, settings)
    assert torch.equal(a.q, b.q) and torch.equal(a.iterations, b.iterations)


def test_fused_solve_projects_an_inverted_block_and_hands_back_a_non_finite_state():
    """A one-handle object turned inside out: its elastic block fails the near-SPD test and is projected,
    as the batched path does (equal matrices); a non-finite start makes the kernel hand the solve back (None)
    to ``minimise``, which names the object."""
    objective, q0, scale, trust, settings = _captured_solves(1)[0]
    fused = FusedNewton(objective.model, objective.layout, objective.contact, objective.island_mass_kg,
                            objective.min_median_radius_m)
    solved = fused.solve(objective, q0, scale, trust, settings)
    assert bool(solved.converged.all()) and solved.counters["unconverged_solves"] == 0
    layout = objective.layout
    tm = layout.to_objects(q0).clone()
    tm[0, 2, 2] = -2.5  # F_zz = 1 - 2.5: inverted
    inverted = layout.to_islands(tm)
    _, _, hess, flagged = fused.evaluate(objective, inverted, True)
    assert bool(flagged[layout.island[0]])
    ref = objective.evaluate(inverted, True)
    torch.testing.assert_close(hess, ref.hess, rtol=0.0, atol=1e-10 * float(ref.hess.abs().amax()))
    assert float(torch.linalg.eigvalsh(0.5 * (hess + hess.transpose(1, 2))).min()) > 0.0
    bad = q0.clone()
    bad[0, 0] = float("nan")
    assert fused.solve(objective, bad, scale, trust, settings) is None


def _stack(fused: bool, frames: int = 20, throw: bool = False):
    """Three one-handle boxes (14 x 14 x 10 cm) dropped in a staggered column, draft quality; with ``throw``
    the top one is thrown down at 3 m/s, spinning at 10 rad/s."""
    from data_gen.sim.material import Material
    from data_gen.sim.world import SimObjectSpec, Simulator
    from tests.sim.test_sim_column import grid_box

    half = (0.07, 0.07, 0.05)
    specs = [
        SimObjectSpec(f"box_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(1e9, 0.3, 1000.0),
                      position_m=(0.01 * k, 0.01 * (k % 2), 0.06 + 0.12 * k), num_handles=1,
                      velocity_m_s=(0.5, 0.0, -3.0) if throw and k == 2 else (0.0, 0.0, 0.0),
                      angular_velocity_rad_s=(10.0, 3.0, 0.0) if throw and k == 2 else (0.0, 0.0, 0.0))
        for k in range(3)
    ]  # fmt: skip
    sim = Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0, fused_newton=fused)
    return sim.run(frames, fps=25.0)


def test_fused_simulation_agrees_with_the_batched_path_and_repeats():
    """Three stiff boxes dropped into a stack (islands of one and several objects, pairs, friction): the
    fused path (default) and the batched path give the same trajectories to well under a millimetre, the
    fused path actually ran (fewer Python-side evaluations are not observable, its counters are per island),
    and a second fused run is bit-identical."""
    a, b, c = _stack(True), _stack(False), _stack(True)
    com_a = np.stack([t.com_m for t in a.objects])
    com_b = np.stack([t.com_m for t in b.objects])
    com_c = np.stack([t.com_m for t in c.objects])
    assert np.array_equal(com_a, com_c)
    assert np.abs(com_a - com_b).max() < 2e-4, np.abs(com_a - com_b).max()
    # the boxes came to rest on each other: each centre about one box height (0.1 m) above the one below
    z = np.sort(com_a[:, -1, 2])
    np.testing.assert_allclose(np.diff(z), 0.1, atol=0.01)
    assert a.info.counters["unconverged_solves"] == 0
    # every island solve of the fused run went through the kernel (nothing handed back); none in the other
    assert a.info.counters["fused_island_solves"] == a.info.counters["island_solves"] > 0
    assert a.info.counters["fused_handed_back"] == 0
    assert b.info.counters["fused_island_solves"] == 0


def test_fused_step_statistics_equal_the_batched_paths(monkeypatch):
    """Every step's contact statistics (per object pair and with the scene: impulse, peak force, its position
    and normal), which the fused path sums inside its launch (:func:`~data_gen.sim.fused_newton._force_sums`)
    and the batched path sums on the host sub-step by
    sub-step, agree to 1e-6 in every step of a thrown box hitting a stack that then falls asleep (pairs between
    awake objects and with sleeping partners); so do the contact events made from them."""
    import data_gen.sim.solver as solver_module

    step = solver_module.ImplicitEulerSolver.step
    runs: dict[bool, list] = {True: [], False: []}

    def recording_step(self, *args, **kwargs):
        stats = step(self, *args, **kwargs)
        runs[self.fused_newton].append((stats.pair_forces, self.state.asleep.copy()))
        return stats

    monkeypatch.setattr(solver_module.ImplicitEulerSolver, "step", recording_step)
    fused, batched = _stack(True, frames=45, throw=True), _stack(False, frames=45, throw=True)
    assert len(runs[True]) == len(runs[False]) == 88
    pair_steps = sleeping_partner_steps = 0
    for (stats_f, asleep_f), (stats_b, asleep_b) in zip(runs[True], runs[False]):
        assert np.array_equal(asleep_f, asleep_b)
        assert stats_f.keys() == stats_b.keys()
        for key, entry in stats_f.items():
            ref = stats_b[key]
            for name in ("impulse_n_s", "peak_force_n"):
                np.testing.assert_allclose(entry[name], ref[name], rtol=1e-6, err_msg=f"{key} {name}")
            np.testing.assert_allclose(entry["position_m"], ref["position_m"], atol=1e-6, err_msg=str(key))
            np.testing.assert_allclose(entry["normal"], ref["normal"], atol=1e-6, err_msg=str(key))
            if key[1] > 0:
                pair_steps += 1
                sleeping_partner_steps += bool(asleep_f[key[0] - 1] or asleep_f[key[1] - 1])
    assert pair_steps > 20 and sleeping_partner_steps > 0  # object pairs, some with a sleeping side
    assert [(e.objects, e.frame) for e in fused.collisions] == [(e.objects, e.frame) for e in batched.collisions]
    for e_f, e_b in zip(fused.collisions, batched.collisions):
        np.testing.assert_allclose([e_f.impulse_n_s, e_f.peak_force_n], [e_b.impulse_n_s, e_b.peak_force_n], rtol=1e-6)


def test_fused_launch_leaves_the_sphere_caches_the_per_object_methods_compute(monkeypatch):
    """After each fused launch the solver keeps every object's contact-sphere centres and velocities and its
    fastest sphere's speed, computed for all objects at once; at the end of every step of a thrown box hitting a
    stack they equal, bit for bit, what ``ContactPoints.positions`` / ``velocities`` give object by object (the
    broad phase, sub-steps, sleep checks and recorder read the kept values)."""
    import data_gen.sim.solver as solver_module

    step = solver_module.ImplicitEulerSolver.step
    checked = {"objects": 0}

    def checking_step(self, *args, **kwargs):
        stats = step(self, *args, **kwargs)
        for k, body in enumerate(self.bodies):
            q, qdot = self.state.q[k], self.state.qdot[k]
            kept = self._velocity_cache[k]
            if self.state.asleep[k] or kept is None or kept[0] is not qdot:
                continue  # not moved by this step's launch
            velocity = body.contact.velocities(qdot)
            assert torch.equal(kept[2], velocity)
            assert kept[3] == float(velocity.norm(dim=1).max())
            assert torch.equal(body.contact_positions(q), body.contact.positions(q))
            checked["objects"] += 1
        return stats

    monkeypatch.setattr(solver_module.ImplicitEulerSolver, "step", checking_step)
    result = _stack(True, frames=30, throw=True)
    assert result.info.counters["fused_island_solves"] > 0
    assert checked["objects"] > 100


def test_one_handle_islands_take_the_fused_path_next_to_a_soft_object(tmp_path, monkeypatch):
    """A two-handle soft box falling beside the three-box stack: the stack's islands are solved by the
    fused kernel, the soft box's by ``solve_split`` (the solver splits a sub-step's islands by kind; draft keeps
    the elastic matrix), and the trajectories equal those of the batched path (``minimise``) for every object."""
    from data_gen.sim.material import Material
    from data_gen.sim.world import SimObjectSpec, Simulator
    from tests.sim.test_sim_collision import TINY_TRAINING
    from tests.sim.test_sim_column import grid_box

    import data_gen.sim.fused_newton as fused_module
    import data_gen.sim.solver as solver_module

    calls = {"fused": 0, "split": 0, "minimise": 0}
    fused_solve, batched = fused_module.FusedNewton.solve, solver_module.minimise
    fused_substeps, split = fused_module.FusedNewton.solve_substeps, fused_module.FusedNewton.solve_split

    def count_split(self, objective, *args, **kwargs):
        calls["split"] += 1
        assert bool((objective.model.num_handles > 1).all())
        return split(self, objective, *args, **kwargs)

    def count_fused(self, *args, **kwargs):
        calls["fused"] += 1
        return fused_solve(self, *args, **kwargs)

    def count_fused_substeps(self, *args, **kwargs):
        calls["fused"] += 1
        return fused_substeps(self, *args, **kwargs)

    def count_minimise(objective, *args, **kwargs):
        calls["minimise"] += 1
        assert not bool((objective.model.num_handles == 1).all())  # one-handle islands went to the kernel
        return batched(objective, *args, **kwargs)

    monkeypatch.setattr(fused_module.FusedNewton, "solve", count_fused)
    monkeypatch.setattr(fused_module.FusedNewton, "solve_substeps", count_fused_substeps)
    monkeypatch.setattr(fused_module.FusedNewton, "solve_split", count_split)
    monkeypatch.setattr(solver_module, "minimise", count_minimise)
    half = (0.07, 0.07, 0.05)

    def run(fused: bool):
        specs = [
            SimObjectSpec(f"box_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(1e9, 0.3, 1000.0),
                          position_m=(0.01 * k, 0.01 * (k % 2), 0.06 + 0.12 * k), num_handles=1)
            for k in range(3)
        ] + [SimObjectSpec("soft", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(1e5, 0.3, 1000.0),
                           position_m=(0.6, 0.0, 0.2), num_handles=2, skinning_settings=TINY_TRAINING)]  # fmt: skip
        sim = Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0, fused_newton=fused,
                        skinning_cache_dir=str(tmp_path))  # fmt: skip
        return np.stack([t.com_m for t in sim.run(12, fps=25.0).objects])

    with_kernel = run(True)
    assert calls["fused"] > 0 and calls["split"] > 0 and calls["minimise"] == 0
    monkeypatch.setattr(fused_module.FusedNewton, "solve", fused_solve)
    monkeypatch.setattr(fused_module.FusedNewton, "solve_substeps", fused_substeps)
    monkeypatch.setattr(solver_module, "minimise", batched)
    without = run(False)
    assert np.abs(with_kernel - without).max() < 2e-4


def test_fused_forces_equal_the_step_objective_forces():
    """The recorder's forces of a fused solve (one kernel launch) equal StepObjective.forces at its result:
    per-sphere scene forces, normals and positions, per-pair forces and normals."""
    checked = 0
    for objective, q0, scale, trust, settings in _captured_solves(12):
        fused = objective.workspace.fused
        out = fused.solve(objective, q0, scale, trust, settings)
        got = fused.forces()
        ref = objective.forces(objective.layout.to_objects(out.q))
        for name in ("scene_force_n", "scene_normals", "sphere_positions_m", "pair_force_i_n", "pair_normals"):
            a, b = getattr(got, name), getattr(ref, name)
            assert a.shape == b.shape, name
            torch.testing.assert_close(a, b, rtol=0.0, atol=1e-12 * max(1.0, float(b.abs().max())))
        checked += int(ref.pair_force_i_n.abs().sum() > 0) + int(ref.scene_force_n.abs().sum() > 0)
    assert checked >= 10  # forces were active, not only zeros compared


@pytest.mark.parametrize("throw", [False, True], ids=["dropped", "thrown"])
def test_one_fused_substep_computes_the_start_data_of_the_step_objective(throw):
    """``solve_substeps`` computes each sub-step's start data in the kernel (scene stiffness, frozen scene and
    pair friction, start positions and normals, predicted states, threshold and trust radius); one sub-step
    from a recorded start lands where ``solve`` lands on the ``StepObjective`` built for it (same iterations,
    states equal far below the tolerance) with the same contact forces, every pair evaluated."""
    for objective, q0, scale, trust, settings in _captured_solves(throw=throw):
        o = objective
        if not bool((o.model.num_handles == 1).all()):
            continue
        fused = FusedNewton(o.model, o.layout, o.contact, o.island_mass_kg, o.min_median_radius_m)
        ref = fused.solve(o, q0, scale, trust, settings)
        ref_tm = o.layout.to_objects(ref.q)
        ref_forces = fused.forces()
        ref_forces = [t.clone() for t in (ref_forces.scene_force_n, ref_forces.scene_normals,
                                          ref_forces.pair_force_i_n)]  # fmt: skip
        out = fused.solve_substeps(
            o.tm_n, (o.tm_pred - o.tm_n) / o.h, o.h, 1, o.gravity, settings, o.scene_stiffness_n_m, o.smoothing_m,
            o.pairs, o.pairs.friction, 1e9,  # a huge margin: every pair is live, as in the objective
        )  # fmt: skip
        assert out is not None
        assert torch.equal(out.iterations[0], ref.iterations)
        gap = o.mass_norm(o.layout.to_islands(out.tm) - ref.q)
        assert bool((gap <= 1e-3 * settings.tolerance * scale).all()), (gap / (settings.tolerance * scale)).tolist()
        torch.testing.assert_close(out.tmdot, (out.tm - o.tm_n) / o.h, rtol=0.0, atol=1e-12)
        got = out.forces[0]
        for a, b in zip((got.scene_force_n, got.scene_normals, got.pair_force_i_n), ref_forces):
            torch.testing.assert_close(a, b, rtol=1e-6, atol=1e-6 * float(b.abs().max()) + 1e-12)
        torch.testing.assert_close(ref_tm, out.tm, rtol=0.0, atol=1e-9)


def test_fused_substeps_hand_back_a_non_finite_state_and_keep_nothing():
    objective, q0, scale, trust, settings = _captured_solves(max_solves=1)[0]
    o = objective
    fused = FusedNewton(o.model, o.layout, o.contact, o.island_mass_kg, o.min_median_radius_m)
    rates = (o.tm_pred - o.tm_n) / o.h
    bad = o.tm_n.clone()
    bad[0, 0, 0] = float("nan")
    args = (o.h, 3, o.gravity, settings, o.scene_stiffness_n_m, o.smoothing_m, o.pairs, o.pairs.friction, 0.01)
    assert fused.solve_substeps(bad, rates, *args) is None
    good = fused.solve_substeps(o.tm_n, rates, *args)
    assert good is not None and good.iterations.shape == (3, o.layout.num_islands)
    assert bool(torch.isfinite(good.tm).all())


@pytest.mark.parametrize("scene", SCENES, ids=IDS)
def test_fused_substep_start_data_equals_the_step_objectives_on_every_scene(scene):
    """The start data ``solve_substeps`` computes in the kernel for a sub-step (per sphere: stiffness, frozen
    ``mu k depth``, start position and scene normal; per pair: start positions, normal and frozen ``mu lam``)
    equal what ``StepObjective`` and the solver compute, on the ground, a static box and a point cloud, with
    spheres pressed 2 cm into the scene (friction frozen at the start)."""
    model, layout, distance, _, _, pairs, tm = _setup(scene, 3, (1, 1, 1))
    tm = tm.clone()
    tm[:, 2, 3] -= 0.02
    gen = torch.Generator().manual_seed(4)
    tmdot = 0.05 * torch.randn(tm.shape, generator=gen, dtype=D)
    objective = StepObjective(model, layout, distance, GRAVITY, tm, tmdot, H_S, 20.0, 0.01 * H_S, pairs)
    c = objective.contact
    assert float(c.friction_scale.max()) > 0.0  # spheres in the scene carry a frozen friction force
    expected = [t.clone() for t in (c.stiffness, c.friction_scale, c.start_x, c.start_normals)]
    # the pairs as the solver starts a (sub)step: positions at its start, frozen normal force k max(depth, 0)
    p = pairs.num_pairs
    x = model.sphere_positions(tm)
    xi = x[pairs.obj_i, pairs.sph_i]
    xj = torch.where((pairs.obj_j >= 0)[:, None], x[pairs.obj_j.clamp(min=0), pairs.sph_j], pairs.frozen_x_j)
    depth, normal = pair_depth(xi, xj, pairs.radius_sum_m)
    lam = pairs.stiffness_n_m * depth.clamp(min=0.0)
    mu = torch.linspace(0.3, 0.7, p, dtype=D)
    assert bool((lam > 0).any()) and bool((lam == 0).any())
    expected_pairs = [normal, xi, xj, mu * lam]
    fused = FusedNewton(model, layout, c, objective.island_mass_kg, objective.min_median_radius_m)
    settings = NewtonSettings(40, 3e-4, 10)
    out = fused.solve_substeps(tm, tmdot, H_S, 1, GRAVITY, settings, objective.scene_stiffness_n_m, 0.01 * H_S,
                               pairs, mu, 1e9)  # fmt: skip
    ints, vec, scal = c.pair_arrays()
    assert out is not None
    valid = model.sphere_valid
    for got, want in zip((c.stiffness, c.friction_scale), expected[:2]):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-9 * float(want.abs().max()))
    torch.testing.assert_close(c.start_x[valid], expected[2][valid], rtol=0.0, atol=1e-15)
    touching = valid & (expected[0] > 0)
    torch.testing.assert_close(c.start_normals[touching], expected[3][touching], rtol=0.0, atol=1e-12)
    for got, want in zip((vec[1][:p], vec[2][:p], vec[3][:p], scal[2][:p]), expected_pairs):
        torch.testing.assert_close(got, want, rtol=1e-12, atol=1e-12 * (1.0 + float(want.abs().max())))


def test_steps_beyond_the_fused_substep_cap_are_solved_one_sub_step_at_a_time(monkeypatch):
    """With the cap on sub-steps per fused launch at 1, every sub-stepped group goes through the per-sub-step
    path (still fused, one launch per sub-step) and the thrown stack ends where the batched path ends."""
    import data_gen.sim.fused_newton as fused_module
    import data_gen.sim.solver as solver_module

    calls = {"substeps": 0}
    original = fused_module.FusedNewton.solve_substeps

    def counted(self, tm, tmdot, h_s, num_sub, *args, **kwargs):
        calls["substeps"] += 1
        assert max(np.atleast_1d(num_sub)) <= 1  # one count, or one per island
        return original(self, tm, tmdot, h_s, num_sub, *args, **kwargs)

    per_substep = solver_module.ImplicitEulerSolver._solve_group

    def counted_per_substep(self, *args, **kwargs):
        calls["per_substep"] = calls.get("per_substep", 0) + 1
        return per_substep(self, *args, **kwargs)

    monkeypatch.setattr(fused_module.FusedNewton, "solve_substeps", counted)
    monkeypatch.setattr(solver_module.ImplicitEulerSolver, "_solve_group", counted_per_substep)
    monkeypatch.setattr(solver_module, "FUSED_MAX_SUBSTEPS", 1)
    capped = _stack(True, throw=True)
    assert calls["substeps"] > 0  # single sub-step groups still take it
    assert calls.get("per_substep", 0) > 0  # the sub-stepped ones went one sub-step at a time
    assert capped.info.counters["fused_island_solves"] == capped.info.counters["island_solves"]
    monkeypatch.setattr(fused_module.FusedNewton, "solve_substeps", original)
    batched = _stack(False, throw=True)
    com_capped = np.stack([t.com_m for t in capped.objects])
    com_batched = np.stack([t.com_m for t in batched.objects])
    assert np.abs(com_capped - com_batched).max() < 2e-4


def test_regrouped_workspace_solves_as_a_new_one():
    """``relayout`` to another grouping and back (the island buffers of the first shape taken again, cleared,
    after solves left them dirty) solves the sub-steps exactly as a workspace built for that grouping: the same
    states, rates, iterations and forces, bit for bit. Without pairs (a grouping must keep paired objects in one
    island), so that every object may be an island of its own."""
    from data_gen.sim.model import DofLayout
    from data_gen.sim.step_objective import island_constants

    checked = 0
    for objective, _, _, _, settings in _captured_solves(max_solves=12):
        o = objective
        if not bool((o.model.num_handles == 1).all()) or o.model.num_objects < 2:
            continue
        n = o.model.num_objects
        apart = DofLayout.build(o.model.num_handles, torch.arange(n), o.model.columns)  # one island per object
        together = DofLayout.build(o.model.num_handles, torch.zeros(n, dtype=torch.int64), o.model.columns)
        args = ((o.tm_pred - o.tm_n) / o.h, o.h, 2, o.gravity, settings, o.scene_stiffness_n_m, o.smoothing_m,
                None, o.pairs.friction[:0], 0.01)  # fmt: skip
        fresh = FusedNewton(o.model, apart, o.contact, *island_constants(o.model, apart))
        expected = fresh.solve_substeps(o.tm_n, *args)
        regrouped = FusedNewton(o.model, apart, o.contact, *island_constants(o.model, apart))
        regrouped.solve_substeps(o.tm_n, *args)  # leaves the buffers of this shape dirty
        regrouped.relayout(together, *island_constants(o.model, together))
        regrouped.solve_substeps(o.tm_n, *args)
        regrouped.relayout(apart, *island_constants(o.model, apart))
        got = regrouped.solve_substeps(o.tm_n, *args)
        assert got.counters == expected.counters  # the same evaluations, searches and convergence
        for name in ("tm", "tmdot", "iterations", "scene_force_n"):
            assert torch.equal(getattr(got, name), getattr(expected, name)), name
        assert float(expected.scene_force_n.abs().max()) > 0.0  # the boxes touch the ground
        checked += 1
    assert checked >= 3


def _captured_soft_solves(tmp_path, max_solves: int = 30):
    """Real (sub)step solves of three soft two-handle boxes (E = 1e5 Pa, draft: the kept elastic matrix) dropped
    into a staggered column, batched path: per solve an objective of its own with the kernel evaluation and
    the kept matrix (what ``solve_split`` serves), and the start, scale, trust radius and settings the solver
    passed to ``minimise``."""
    from data_gen.sim.world import Simulator
    from tests.sim.test_sim_column import staggered_soft_column

    import data_gen.sim.solver as solver_module

    captured = []
    original = solver_module.minimise

    def capture(objective, q0, scale, trust, settings, **kwargs):
        if len(captured) < max_solves:
            o = objective
            captured.append((
                lambda o=o: StepObjective(o.model, o.layout, o.scene, o.gravity, o.tm_n, (o.tm_pred - o.tm_n) / o.h,
                                          o.h, STIFFNESS_FACTOR, o.smoothing_m, o.pairs, lagged_elastic_hessian=True,
                                          kernel_evaluation=True),
                q0.clone(), scale.clone(), trust.clone(), settings,
            ))  # fmt: skip
        return original(objective, q0, scale, trust, settings, **kwargs)

    specs = staggered_soft_column()
    solver_module.minimise = capture
    try:
        sim = Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0, fused_newton=False,
                        skinning_cache_dir=str(tmp_path))  # fmt: skip
        sim.run(10, fps=25.0)
    finally:
        solver_module.minimise = original
    return captured


def test_split_solve_matches_minimise_on_real_soft_steps(tmp_path):
    """``FusedNewton.solve_split`` (the host factorises, one launch per iteration does the rest) against
    ``minimise`` on the same real soft solves (falling, landing on the ground and on each other: pairs, friction,
    one island or several), every third with a tiny trust radius so that updates are cut by it: the same
    iterations, convergence and trust-limited updates, the same state to round-off (only the update norms and
    the slope are summed in another order), and nothing handed back; with the limits left to the kernel, its
    threshold and trust radius are ``StepObjective``'s to round-off and the solve takes the same path. (Several
    islands in one solve: the test below.)"""
    solves = _captured_soft_solves(tmp_path)
    assert len(solves) >= 10
    trust_limited = with_pairs = 0
    for (make, q0, scale, trust, settings), trust_factor in zip(solves, itertools.cycle([1.0, 1.0, 0.005])):
        trust = trust_factor * trust
        reference, split = make(), make()
        ref = minimise(reference, q0, scale, trust, settings)
        out = split.evaluator.solve_split(split, q0, scale, trust, settings)
        assert out is not None, "the split solve handed a recorded step back"
        assert torch.equal(out.iterations, ref.iterations) and torch.equal(out.converged, ref.converged)
        assert out.counters["trust_limited_steps"] == ref.counters["trust_limited_steps"]
        gap = reference.mass_norm(out.q - ref.q)
        assert bool((gap <= 1e-6 * settings.tolerance * scale).all()), (gap / (settings.tolerance * scale)).tolist()
        trust_limited += out.counters["trust_limited_steps"]
        with_pairs += int(split.pairs.num_pairs > 0)
        if trust_factor == 1.0:  # the kernel's own threshold and trust radius: StepObjective's, to round-off
            own_objective = make()
            own = own_objective.evaluator.solve_split(own_objective, q0, None, None, settings)
            torch.testing.assert_close(own_objective.evaluator.threshold, settings.tolerance * scale, rtol=1e-12, atol=0.0)
            torch.testing.assert_close(own_objective.evaluator.trust, trust, rtol=1e-12, atol=0.0)
            assert torch.equal(own.iterations, out.iterations) and torch.equal(own.converged, out.converged)
            assert bool((reference.mass_norm(own.q - out.q) <= 1e-6 * settings.tolerance * scale).all())
    assert trust_limited > 0 and with_pairs > 0, (trust_limited, with_pairs)


def test_split_solve_of_deformable_islands_hands_back_what_only_minimise_does():
    """Two islands of deformable objects (3, 2 and 4 handles; pairs in an island and against a frozen partner),
    one of them still above the tolerance at the iteration cap: ``solve_split`` ends where ``minimise`` does (the
    same iterations and convergence, the state to round-off); without the kept
    matrix (no lagged elastic Hessian) or from a non-finite start it hands the solve back (None)."""
    model, layout, distance, _, _, pairs, tm = _setup(SCENES[0], 3, (3, 2, 4))
    gen = torch.Generator().manual_seed(5)
    tmdot = torch.zeros_like(tm)
    for o in range(model.num_objects):
        cols = 4 * int(model.num_handles[o])
        tmdot[o, :, :cols] = 0.3 * torch.randn(3, cols, generator=gen, dtype=D) / cols

    def objective(lagged: bool = True) -> StepObjective:
        return StepObjective(model, layout, distance, GRAVITY, tm, tmdot, H_S, 20.0, 0.01 * H_S, pairs,
                             lagged_elastic_hessian=lagged, kernel_evaluation=True)  # fmt: skip

    settings = NewtonSettings(30, 1e-3, 8)
    q0 = layout.to_islands(tm + H_S * tmdot)
    reference, split = objective(), objective()
    assert layout.num_islands == 2
    ref = minimise(reference, q0, reference.motion_scale(), reference.trust_radius(), settings)
    out = split.evaluator.solve_split(split, q0, None, None, settings)
    assert int(ref.iterations.min()) >= 2 and not bool(ref.converged.all())  # one island stops at the cap
    assert torch.equal(out.iterations, ref.iterations) and torch.equal(out.converged, ref.converged)
    torch.testing.assert_close(split.evaluator.threshold, settings.tolerance * reference.motion_scale(), rtol=1e-12,
                               atol=0.0)  # fmt: skip
    torch.testing.assert_close(split.evaluator.trust, reference.trust_radius(), rtol=1e-12, atol=0.0)
    gap = reference.mass_norm(out.q - ref.q)  # (30 trust-limited updates: alpha's round-off adds up)
    assert bool((gap <= 1e-4 * settings.tolerance * reference.motion_scale()).all())
    unlagged = objective(lagged=False)
    assert unlagged.evaluator.solve_split(unlagged, q0, None, None, settings) is None
    bad = q0.clone()
    bad[0, 0] = float("nan")
    again = objective()
    assert again.evaluator.solve_split(again, bad, None, None, settings) is None


def test_fused_substep_filter_keeps_the_pairs_whose_gap_is_within_both_speeds_in_the_scene_frame():
    """The pairs a fused sub-step evaluates: start gap below the margin plus 1.5 h (|v_i| + |v_j|) plus what
    gravity adds to both (:meth:`BroadPhase.within_reach`'s bound), with the speeds in the static scene's frame.
    The objects fall together at 3 m/s: a bound on the relative speed (zero) would drop the pairs the ground can
    bring together within the sub-step by stopping one object (see ``test_boxes_released_together_...``)."""
    model, layout, distance, _, _, pairs, tm = _setup(StaticScene(), 3, (1, 1, 1))
    gen = torch.Generator().manual_seed(8)
    tmdot = 0.2 * torch.randn(tm.shape, generator=gen, dtype=D)
    tmdot[:, 2, 3] = -3.0  # the translation column: every object falls at 3 m/s (plus a little spin and strain)
    margin = 0.004
    objective = StepObjective(model, layout, distance, GRAVITY, tm, tmdot, H_S, 20.0, 0.01 * H_S, pairs)
    fused = FusedNewton(model, layout, objective.contact, objective.island_mass_kg, objective.min_median_radius_m)
    mu = torch.full((pairs.num_pairs,), 0.5, dtype=D)
    fused.solve_substeps(tm, tmdot, H_S, 1, GRAVITY, NewtonSettings(40, 3e-4, 10),
                         objective.scene_stiffness_n_m, 0.01 * H_S, pairs, mu, margin)  # fmt: skip
    start, count = fused.pair_start.tolist(), fused.live_count.tolist()
    live = sorted(int(p) for i in range(len(count)) for p in fused.live_order[start[i] : start[i] + count[i]])
    # the bound from the start state, in float64 on the host
    x, v = model.sphere_positions(tm), model.sphere_b @ tmdot.transpose(1, 2)  # x = x0 + Tm b, v = Tmdot b
    xi, vi = x[pairs.obj_i, pairs.sph_i], v[pairs.obj_i, pairs.sph_i]
    partner = pairs.obj_j >= 0
    xj = torch.where(partner[:, None], x[pairs.obj_j.clamp(min=0), pairs.sph_j], pairs.frozen_x_j)
    vj = torch.where(partner[:, None], v[pairs.obj_j.clamp(min=0), pairs.sph_j], torch.zeros(3, dtype=D))
    gap = (xi - xj).norm(dim=1) - pairs.radius_sum_m
    reach = 1.5 * H_S * (vi.norm(dim=1) + vj.norm(dim=1)) + 2.0 * 9.81 * H_S**2 + margin
    expected = torch.nonzero(gap < reach).flatten().tolist()
    relative = torch.nonzero(gap < 1.5 * H_S * (vi - vj).norm(dim=1) + 2.0 * 9.81 * H_S**2 + margin).flatten()
    assert live == expected
    assert 0 < len(relative) < len(expected) < pairs.num_pairs  # the frame matters here, and the filter filters
