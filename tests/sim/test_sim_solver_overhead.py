"""The solver's vectorised bookkeeping, its cached solve set-up and the grouped broad phase (the pair search
and the object pairs of the solver's :class:`~data_gen.sim.contacts.BroadPhase`) equal their plain
definitions."""

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from data_gen.sim.contact import NonFiniteInput, PairFinder
from data_gen.sim.presets import load_preset
from data_gen.sim.solver import NO_PARTNER, ImplicitEulerSolver, SimBody, SimulationError, StepStats
from data_gen.sim.state import State
from data_gen.sim.static_scene import StaticScene
from tests.sim.test_sim_batched_terms import _object


def brute_force_pairs(points, object_ids, radii, margin, point_margins):
    """All (i < j) on different objects closer than r_i + r_j + margin + m_i + m_j, sorted."""
    extra = np.zeros(len(points)) if point_margins is None else point_margins
    dist = np.linalg.norm(points[:, None] - points[None, :], axis=2)
    limit = radii[:, None] + radii[None, :] + margin + extra[:, None] + extra[None, :]
    i, j = np.nonzero((dist < limit) & (object_ids[:, None] != object_ids[None, :]))
    keep = j > i
    out = np.stack([i[keep], j[keep]], 1).astype(np.int64)
    return out[np.lexsort((out[:, 1], out[:, 0]))]


@pytest.mark.parametrize("parallel_grid", [False, True])
@pytest.mark.parametrize("ids_kind", ["ascending", "shuffled", "sparse"])
def test_grouped_broad_phase_finds_exactly_the_close_pairs(ids_kind, parallel_grid):
    """The pairs equal the brute-force ones, with the grid built by the CPU's single thread or by the parallel
    launches other devices take (run here on the CPU)."""
    rng = np.random.default_rng(3)
    finder = PairFinder(parallel_grid=parallel_grid)
    for trial in range(6):
        sizes = rng.integers(0, 120, rng.integers(2, 8))
        ids = np.concatenate([np.full(s, k) for k, s in enumerate(sizes)])
        if ids_kind == "shuffled":
            ids = rng.permutation(ids)
        elif ids_kind == "sparse":
            ids = 7 * ids + 3
        centres = rng.normal(scale=0.1, size=(len(sizes), 3))
        points = centres[np.searchsorted(np.unique(ids), ids)] + rng.normal(scale=0.04, size=(len(ids), 3))
        radii = rng.uniform(0.002, 0.02, len(ids))
        margins = rng.uniform(0.0, 0.03, len(ids)) if trial % 2 else None
        found = finder.find(points, ids, radii, 0.004, margins)
        expected = brute_force_pairs(points, ids, radii, 0.004, margins)
        assert len(expected) > 0 or trial
        np.testing.assert_array_equal(found, expected)
        # same ids, new radii: the cached upload must follow
        np.testing.assert_array_equal(
            finder.find(points, ids, 1.5 * radii, 0.004, margins),
            brute_force_pairs(points, ids, 1.5 * radii, 0.004, margins),
        )


@pytest.mark.parametrize("parallel_grid", [False, True])
def test_broad_phase_of_objects_apart_skips_the_search_and_finds_exactly_the_close_pairs(parallel_grid):
    """Objects whose bounding boxes are farther apart than their reach find nothing without a hash-grid search;
    moved together step by step (across the reach), the pairs equal the brute-force ones at every distance."""
    rng = np.random.default_rng(5)
    a = rng.normal(scale=0.03, size=(60, 3))
    b = rng.normal(scale=0.03, size=(50, 3))
    ids = np.r_[np.zeros(60, dtype=int), np.ones(50, dtype=int)]
    radii = rng.uniform(0.002, 0.01, 110)
    margins = rng.uniform(0.0, 0.02, 110)
    finder = PairFinder(parallel_grid=parallel_grid)
    builds = finder.builds
    found_any = []
    for offset in np.linspace(0.4, 0.05, 36):
        points = np.r_[a, b + np.array([offset, 0.0, 0.0])]
        before = finder.builds
        found = finder.find(points, ids, radii, 0.003, margins)
        np.testing.assert_array_equal(found, brute_force_pairs(points, ids, radii, 0.003, margins))
        gap = (b[:, 0] + offset).min() - a[:, 0].max()  # the boxes' gap along x (they overlap in y, z)
        if gap >= (radii.max() + margins.max()) * 2 + 0.003 + 1e-6:
            assert finder.builds == before and len(found) == 0  # apart: no search
        found_any.append(len(found) > 0)
    assert found_any[0] is False and found_any[-1] is True  # the sweep crossed from apart to touching
    assert finder.builds > builds


@pytest.mark.parametrize("cell_fraction", [0.25, 1.0, 3.0])
def test_broad_phase_with_its_cells_widened_finds_exactly_the_close_pairs(cell_fraction):
    """A row of 40 objects 3 m long, cells a quarter of, as wide as or three times the query radius: with a tenth
    of a cell per sphere allowed, the cells grow wider (the search visits more points, the distance test drops
    them) and the pairs still equal the brute-force ones; with the default cell budget too."""
    rng = np.random.default_rng(11)
    count = 40
    ids = np.repeat(np.arange(count), 30)
    centres = np.stack([np.linspace(0.0, 3.0, count), np.zeros(count), np.zeros(count)], 1)
    points = centres[ids] + rng.normal(scale=0.025, size=(len(ids), 3))
    radii = rng.uniform(0.004, 0.008, len(ids))
    expected = brute_force_pairs(points, ids, radii, 0.004, None)
    assert len(expected) > 50
    for budget in (0.1, 8.0):
        finder = PairFinder(cell_fraction=cell_fraction, max_cells_per_point=budget)
        grid = finder.build_cells(points, ids, radii, 0.004, 0.04)
        width, dims = grid["width"], grid["dims"]
        assert dims.prod(1).sum() <= max(64, budget * len(points))
        assert (width > 0.04) == (budget < 1.0)  # only the small budget widens the 4 cm cells
        found = finder.find(points, ids, radii, 0.004)
        assert np.ptp(points[found[:, 0], 0]) > 2.5  # close pairs all along the row
        np.testing.assert_array_equal(found, expected)


@pytest.mark.parametrize("parallel_grid", [False, True])
def test_broad_phase_grid_built_on_the_device_matches_its_definition(parallel_grid):
    """The grid kernel's boxes are each object's min / max point, its reaches the largest radius plus own margin,
    its cell sort a permutation of the points in which every cell's run holds exactly the points whose
    coordinates fall in that cell (floor of the offset from the box corner over the width, clamped to the grid),
    and its closeness flag the boxes' gap test; three shuffled objects, then the same three moved apart."""
    rng = np.random.default_rng(21)
    ids = rng.permutation(np.repeat([4, 9, 2], [50, 70, 30]))
    dense = np.searchsorted([2, 4, 9], ids)
    centres = np.array([[0.0, 0.0, 0.0], [0.12, 0.0, 0.0], [0.0, 0.1, 0.05]])
    radii = rng.uniform(0.003, 0.01, len(ids))
    margins = rng.uniform(0.0, 0.01, len(ids))
    finder = PairFinder(parallel_grid=parallel_grid)
    for spread, close in ((1.0, True), (20.0, False)):
        points = spread * centres[dense] + rng.normal(scale=0.03, size=(len(ids), 3))
        grid = finder.build_cells(points, ids, radii, 0.002, 0.04, margins)
        lo = np.stack([points[dense == k].min(0) for k in range(3)])
        hi = np.stack([points[dense == k].max(0) for k in range(3)])
        np.testing.assert_array_equal(grid["lo"], lo)
        np.testing.assert_array_equal(grid["hi"], hi)
        np.testing.assert_array_equal(grid["reach"], [(radii + margins)[dense == k].max() for k in range(3)])
        assert grid["close"] is close
        if not close:
            assert brute_force_pairs(points, ids, radii, 0.002, margins).shape == (0, 2)
            continue
        width, dims, first = grid["width"], grid["dims"], grid["first"]
        assert width == 0.04 and np.array_equal(dims, np.floor((hi - lo) / width).astype(int) + 1)
        np.testing.assert_array_equal(first, np.r_[0, np.cumsum(dims.prod(1))[:-1]])
        assert np.array_equal(np.sort(grid["cell_points"]), np.arange(len(ids)))
        cell = np.minimum(np.floor((points - lo[dense]) / width).astype(int), dims[dense] - 1)
        flat = first[dense] + (cell[:, 0] * dims[dense, 1] + cell[:, 1]) * dims[dense, 2] + cell[:, 2]
        start = grid["cell_start"]
        assert start[0] == 0 and start[-1] == len(ids) and np.all(np.diff(start) >= 0)
        for c in range(len(start) - 1):
            run = grid["cell_points"][start[c]:start[c + 1]]
            assert np.array_equal(np.sort(run), np.flatnonzero(flat == c))


def test_broad_phase_refuses_non_finite_points_and_margins_by_name():
    """A NaN centre or an infinite margin is refused with the argument and row named (the device grid would turn it
    into a cell index outside its arrays)."""
    rng = np.random.default_rng(2)
    points = rng.normal(scale=0.05, size=(40, 3))
    ids = np.repeat([0, 1], 20)
    radii = np.full(40, 0.01)
    finder = PairFinder()
    assert len(finder.find(points, ids, radii, 0.01)) > 0
    bad = points.copy()
    bad[7, 1] = np.nan
    with pytest.raises(ValueError, match=r"points_m\[7\] .* not finite"):
        finder.find(bad, ids, radii, 0.01)
    margins = np.zeros(40)
    margins[12] = np.inf
    with pytest.raises(ValueError, match=r"point_margins_m\[12\] = inf is not finite"):
        finder.find(points, ids, radii, 0.01, margins)
    with pytest.raises(NonFiniteInput, match=r"points_m\[7\]"):
        finder.build_cells(bad, ids, radii, 0.01, 0.04)
    assert issubclass(NonFiniteInput, ValueError)


def test_a_non_finite_state_reaching_the_broad_phase_is_a_simulation_error():
    """A NaN in an object's state that reaches the pair search (the solver checks its states after every solve, so
    this is a guard) is a ``SimulationError`` naming the step and the sphere, which a generation run turns into a
    rejected sequence, not a crash."""
    solver = _solver()
    solver.state.q[2] = solver.state.q[2].clone()
    solver.state.q[2][5] = float("nan")
    with pytest.raises(SimulationError, match=r"step 0: broad phase: PairFinder.find: points_m\[\d+\] .* not finite"):
        solver.step()


def test_broad_phase_of_one_object_is_empty():
    points = np.random.default_rng(0).normal(size=(20, 3))
    assert PairFinder().find(points, np.zeros(20, dtype=int), np.full(20, 0.5), 0.1).shape == (0, 2)


# ---------------------------------------------------------------- pair force bookkeeping
def _reference_assign_partner(body, local, magnitude, partner_id):
    """The former per-object-pair update of the dominant partner (strictly stronger contact wins)."""
    best = torch.zeros(body.contact.num_points, dtype=torch.float64)
    best.scatter_reduce_(0, local, magnitude, reduce="amax", include_self=True)
    take = best > body.partner_strength_n
    body.contact_partner = torch.where(take, partner_id, body.contact_partner)
    body.partner_strength_n = torch.maximum(best, body.partner_strength_n)


def _reference_accumulate(solver, obj_i, loc_i, obj_j, loc_j, xi, xj, f_i, normal_ji, h, stats, supported):
    """The former loop over object pairs of ImplicitEulerSolver._accumulate_pair_forces."""
    mag = f_i.norm(dim=1)
    act = mag > 0
    if not bool(act.any()):
        return
    act_np = act.numpy()
    for a, c in np.unique(np.stack([obj_i[act_np], obj_j[act_np]], 1), axis=0):
        sel = torch.from_numpy((obj_i == a) & (obj_j == c)) & act
        li = torch.from_numpy(loc_i)[sel]
        lj = torch.from_numpy(loc_j)[sel]
        fa = f_i[sel]
        m = mag[sel]
        ba, bc = solver.bodies[a], solver.bodies[c]
        c_asleep = solver.state.asleep[c]
        ba.contact_force_n.index_add_(0, li, fa)
        bc.contact_force_n.index_add_(0, lj, -fa * (h / solver.dt if c_asleep else 1.0))
        _reference_assign_partner(ba, li, m, bc.object_id)
        _reference_assign_partner(bc, lj, m, ba.object_id)
        supported[a] = True
        if c_asleep:
            supported[c] = True
        pos = ((m[:, None] * 0.5 * (xi[sel] + xj[sel])).sum(0) / m.sum()).numpy()
        nrm = (m[:, None] * normal_ji[sel]).sum(0).numpy()
        total = fa.sum(0).numpy()
        if ba.object_id > bc.object_id:
            total, nrm = -total, -nrm
        key = (min(ba.object_id, bc.object_id), max(ba.object_id, bc.object_id))
        stats.add_pair_force(key, total, pos, nrm / max(float(np.linalg.norm(nrm)), 1e-300), h)


def _bookkeeping_solver(rng, num_points, asleep, dt_s):
    """A solver holding only what the force bookkeeping reads: bodies with per-sphere records, sleep flags."""
    solver = object.__new__(ImplicitEulerSolver)
    solver.bodies = []
    for k, (n, sleeping) in enumerate(zip(num_points, asleep, strict=True)):
        force = torch.from_numpy(rng.normal(size=(n, 3)) * (rng.random((n, 1)) < 0.3))
        strength = force.norm(dim=1)
        solver.bodies.append(
            SimpleNamespace(
                object_id=k + 1,
                contact=SimpleNamespace(num_points=n),
                contact_force_n=force,
                partner_strength_n=strength,
                contact_partner=torch.where(strength > 0, 0, NO_PARTNER),
            )
        )
    empty = [torch.zeros(0, dtype=torch.float64) for _ in num_points]
    solver.state = State(empty, list(empty), np.array(asleep), np.zeros(len(num_points), dtype=np.int64))
    solver.dt = dt_s
    solver._object_id = np.array([b.object_id for b in solver.bodies])
    solver._record_spheres = True
    return solver


def test_vectorised_pair_bookkeeping_equals_the_loop_over_object_pairs():
    num_points, asleep = [7, 5, 9, 4, 6], [False, False, True, False, True]
    for seed in range(8):
        rng = np.random.default_rng(seed)
        p = 60
        obj_i = rng.choice([0, 1, 3], size=p)  # awake side i (solved objects)
        obj_j = (obj_i + rng.integers(1, 5, size=p)) % 5
        loc_i = np.array([rng.integers(num_points[o]) for o in obj_i])
        loc_j = np.array([rng.integers(num_points[o]) for o in obj_j])
        f_i = torch.from_numpy(rng.normal(size=(p, 3)))
        f_i[torch.from_numpy(rng.random(p) < 0.3)] = 0.0  # inactive pairs
        # one sphere pushed equally hard by two objects: the first object pair in order is its partner
        obj_i[4:6], loc_i[4:6], obj_j[4:6] = 0, 0, [2, 1]
        f_i[4] = 100.0 * f_i[4]
        f_i[5] = -f_i[4]
        xi, xj = torch.from_numpy(rng.normal(size=(p, 3))), torch.from_numpy(rng.normal(size=(p, 3)))
        normal = torch.nn.functional.normalize(xi - xj, dim=1)
        args = (obj_i, loc_i, obj_j, loc_j, xi, xj, f_i, normal, 0.0025)  # a quarter sub-step
        ref, new = (_bookkeeping_solver(np.random.default_rng(seed), num_points, asleep, 0.01) for _ in "ab")
        stats_ref, stats_new = StepStats(), StepStats()
        sup_ref, sup_new = np.zeros(5, dtype=bool), np.zeros(5, dtype=bool)
        _reference_accumulate(ref, *args, stats_ref, sup_ref)
        ImplicitEulerSolver._accumulate_pair_forces(new, *args, stats_new, sup_new)
        np.testing.assert_array_equal(sup_new, sup_ref)
        for b_ref, b_new in zip(ref.bodies, new.bodies, strict=True):
            assert torch.equal(b_new.contact_force_n, b_ref.contact_force_n)  # same additions in the same order
            assert torch.equal(b_new.partner_strength_n, b_ref.partner_strength_n)
            assert torch.equal(b_new.contact_partner, b_ref.contact_partner)
        assert list(stats_new.pair_forces) == list(stats_ref.pair_forces)
        for key, entry in stats_ref.pair_forces.items():
            for name, value in entry.items():
                np.testing.assert_allclose(stats_new.pair_forces[key][name], value, rtol=1e-12, atol=1e-14)


def test_pair_bookkeeping_without_active_pairs_changes_nothing():
    solver = _bookkeeping_solver(np.random.default_rng(0), [3, 3], [False, False], 0.01)
    before = [b.contact_force_n.clone() for b in solver.bodies]
    stats, supported = StepStats(), np.zeros(2, dtype=bool)
    zeros = torch.zeros(2, 3, dtype=torch.float64)
    ImplicitEulerSolver._accumulate_pair_forces(
        solver, np.array([0, 0]), np.array([0, 1]), np.array([1, 1]), np.array([2, 0]), zeros, zeros, zeros, zeros,
        0.01, stats, supported,
    )  # fmt: skip
    assert not stats.pair_forces and not supported.any()
    for b, f in zip(solver.bodies, before, strict=True):
        assert torch.equal(b.contact_force_n, f)


# ---------------------------------------------------------------- solve set-up
def _solver(handles=(1, 3, 2, 1)):
    """A solver over small random objects (1..3 handles) at random states."""
    gen = torch.Generator().manual_seed(11)
    bodies, qs, qdots = [], [], []
    for k, h in enumerate(handles):
        model, contact = _object(h, seed=k)
        qs.append(0.05 * torch.randn(model.num_dofs, generator=gen, dtype=torch.float64))
        qdots.append(torch.randn(model.num_dofs, generator=gen, dtype=torch.float64))
        bodies.append(SimBody(k + 1, f"o{k}", model, contact, 0.5))
    return ImplicitEulerSolver(
        bodies, State.awake(qs, qdots), StaticScene(), np.array([0.0, 0.0, -9.81]), load_preset("draft"), 0.01
    )


def test_contact_stiffness_follows_the_substep_length_passed_in():
    """The scene and pair stiffness (factor * mass / h^2, the pair's reduced mass) of a (sub)step of the length
    passed in; the kept pair tables follow a change of it and back. The solver keeps no current step length."""
    solver = _solver()
    factor = solver.preset.contact_stiffness_factor
    mass = np.array([b.model.mass_kg for b in solver.bodies])
    reduced = mass[0] * mass[1] / (mass[0] + mass[1])
    for h in (0.01, 0.0025, 0.01):
        stiffness, friction = solver._pair_tables(h)
        assert stiffness[0, 1] == pytest.approx(factor * reduced / h**2, rel=1e-12)
        assert friction[0, 1] == pytest.approx(0.5, rel=1e-12)  # sqrt(0.5 * 0.5)
        assert solver.stiffness(2, h) == pytest.approx(factor * mass[2] / h**2, rel=1e-12)
    solver.step()
    assert not hasattr(solver, "h")


def test_solve_setup_gathers_the_states_of_each_object_and_is_reused():
    solver = _solver()
    islands = [[0, 2], [1], [3]]
    setup = solver._group_setup(islands)
    assert solver._group_setup([list(i) for i in islands]) is setup  # the same islands: the same set-up
    tm, tmdot = solver._padded_states(setup)
    k = solver.model.columns
    for slot, o in enumerate(setup.objects):  # the per-object reference: each q at its padded positions
        ref, ref_dot = torch.zeros(3 * k, dtype=torch.float64), torch.zeros(3 * k, dtype=torch.float64)
        ref[solver._padded_index[o]] = solver.state.q[o]
        ref_dot[solver._padded_index[o]] = solver.state.qdot[o]
        assert torch.equal(tm[slot].reshape(-1), ref) and torch.equal(tmdot[slot].reshape(-1), ref_dot)
    assert setup.objects == [0, 2, 1, 3] and list(setup.slot_of) == [0, 2, 1, 3]
    assert torch.equal(setup.layout.island, torch.tensor([0, 0, 1, 2]))
    assert torch.equal(setup.model.num_handles, solver.model.num_handles[[0, 2, 1, 3]])
    # least recently used set-ups are dropped beyond the memory bound
    solver._groups_max_bytes = 2 * setup.nbytes
    for groups in ([[0]], [[1]], [[2]], [[3]], [[0, 1]]):
        solver._group_setup(groups)
        assert len(solver._groups) >= 1 and solver._groups_bytes <= max(solver._groups_max_bytes, setup.nbytes)
    assert tuple(map(tuple, islands)) not in solver._groups


def test_object_pairs_are_the_sorted_distinct_pairs_of_candidates():
    broad_phase = _solver().broad_phase  # the solver's broad phase, built from its bodies
    point_object = broad_phase.point_object
    rng = np.random.default_rng(2)
    n = len(point_object)
    i = rng.integers(0, n, 200)
    j = rng.integers(0, n, 200)
    keep = point_object[i] < point_object[j]
    pairs = np.stack([i[keep], j[keep]], 1)
    np.testing.assert_array_equal(broad_phase.object_pairs(pairs), np.unique(point_object[pairs], axis=0))
    assert broad_phase.object_pairs(np.zeros((0, 2), dtype=np.int64)).shape == (0, 2)


def _assert_same_results(a, b) -> None:
    """Every recorded array, contact event (there are some) and energy of two simulation results equal, bit for
    bit."""
    from dataclasses import fields

    for track_a, track_b in zip(a.objects, b.objects, strict=True):
        for f in fields(track_a):
            if isinstance(getattr(track_a, f.name), np.ndarray):
                assert np.array_equal(getattr(track_a, f.name), getattr(track_b, f.name)), f.name
    assert len(a.collisions) == len(b.collisions) > 0
    for event_a, event_b in zip(a.collisions, b.collisions):
        assert vars(event_a).keys() == vars(event_b).keys()
        for key, value in vars(event_b).items():
            assert np.array_equal(vars(event_a)[key], value), key
    for key in b.energies_j:
        assert np.array_equal(a.energies_j[key], b.energies_j[key]), key


def test_steps_without_sphere_records_change_no_recorded_value(monkeypatch):
    """The simulator skips the per-sphere force records of steps between frames (nobody reads them): every
    recorded array (per-point contact forces and partners included), every contact event and the energies
    equal those of a run that keeps the records of every step, bit for bit. A thrown box hits a stack
    (pairs between awake objects), and the stack falls asleep (frozen scene forces, sleeping partners)."""

    from tests.sim.test_sim_fused_newton import _stack

    lean = _stack(True, frames=45, throw=True)
    step = ImplicitEulerSolver.step
    monkeypatch.setattr(ImplicitEulerSolver, "step", lambda self, record_sphere_forces=True: step(self, True))
    full = _stack(True, frames=45, throw=True)
    assert any(tr.asleep.any() for tr in full.objects)  # the records of sleepers were exercised
    assert any((tr.contact_partner > 0).any() for tr in full.objects)  # and object-object partners
    _assert_same_results(lean, full)


def test_islands_of_different_substeps_in_one_launch_record_what_one_launch_per_substep_count_records(monkeypatch):
    """The solver puts every one-handle island of a step into one fused launch, each island with its own
    sub-step. A thrown box next to a settling stack gives steps with islands of different sub-step counts
    in one launch; every state, recorded array, contact event and energy equals, bit for bit, a run that
    launches each sub-step count's islands on their own (as the solver did before), and so do the counters."""

    from data_gen.sim.material import Material
    from data_gen.sim.world import SimObjectSpec, Simulator
    from tests.sim.test_sim_column import grid_box

    def scene():
        """A box resting on the ground, one dropped next to it, one thrown at the first, one far off falling
        fast: islands of one to three objects that need different sub-steps in the same step."""
        half = (0.07, 0.07, 0.05)
        starts = [((0.0, 0.0, 0.05), (0.0, 0.0, 0.0)), ((0.3, 0.0, 0.25), (0.0, 0.0, 0.0)),
                  ((-0.45, 0.02, 0.12), (3.0, 0.0, 0.5)), ((1.0, 0.0, 0.6), (0.0, 0.0, -4.0))]  # fmt: skip
        specs = [
            SimObjectSpec(f"box_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(1e9, 0.3, 1000.0),
                          position_m=x, num_handles=1, velocity_m_s=v, angular_velocity_rad_s=(0.0, 4.0 * k, 0.0))
            for k, (x, v) in enumerate(starts)
        ]  # fmt: skip
        return Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0).run(20, fps=25.0)

    launches = []
    launch = ImplicitEulerSolver._launch_rigid_parts

    def counted(self, parts, *args):
        launches.append(sorted(num_sub for num_sub, _ in parts))
        return launch(self, parts, *args)

    monkeypatch.setattr(ImplicitEulerSolver, "_launch_rigid_parts", counted)
    merged = scene()
    mixed = [counts for counts in launches if len(counts) > 1]
    assert len(mixed) >= 3, launches  # steps whose islands took different sub-steps, in one launch
    assert all(len(set(counts)) == len(counts) for counts in launches)

    def one_launch_per_count(self, parts, pairs_all, positions, stats, supported):
        records = {}
        for part in parts:
            records.update(launch(self, [part], pairs_all, positions, stats, supported) or {})
        return records

    monkeypatch.setattr(ImplicitEulerSolver, "_solve_rigid_substeps", one_launch_per_count)
    separate = scene()
    _assert_same_results(merged, separate)
    assert merged.info.counters == separate.info.counters
    assert merged.info.newton_iterations == separate.info.newton_iterations


def test_recorded_energies_and_the_next_step_share_one_broad_phase_search(monkeypatch):
    """The energies of a recorded frame take their contact pairs from the next step's broad-phase candidates
    (a superset, filtered to the pairs in contact) and that step reuses them: one pair search per step (and one
    for the initial frame's forces), and every recorded array, event and energy equals a run that searches
    again each time (to round-off in the contact energy, whose sum now skips the zero terms)."""
    from dataclasses import fields

    import data_gen.sim.solver as solver_module
    from data_gen.sim.contacts import BroadPhase
    from tests.sim.test_sim_fused_newton import _stack

    calls = {"n": 0}
    search = BroadPhase.candidates

    def counted(self, *args, **kwargs):
        calls["n"] += 1
        return search(self, *args, **kwargs)

    monkeypatch.setattr(BroadPhase, "candidates", counted)
    shared = _stack(True, frames=12, throw=True)
    shared_calls = calls["n"]
    calls["n"] = 0
    monkeypatch.setattr(solver_module, "_same_state_key", lambda a, b: False)
    again = _stack(True, frames=12, throw=True)
    # the initial frame's forces, 11 frames of 2 steps (draft) after the first, and the last frame's energies
    # (for a step never taken); searching again each time adds one search per recorded frame
    assert shared_calls == 1 + 22 + 1 and calls["n"] == 1 + 22 + 12, (shared_calls, calls["n"])
    for a, b in zip(shared.objects, again.objects, strict=True):
        for f in fields(a):
            if isinstance(getattr(a, f.name), np.ndarray):
                assert np.array_equal(getattr(a, f.name), getattr(b, f.name)), f.name
    assert len(shared.collisions) == len(again.collisions) > 0
    for key in ("kinetic", "elastic", "gravity"):
        assert np.array_equal(shared.energies_j[key], again.energies_j[key]), key
    contact = again.energies_j["contact"]
    assert contact.max() > 0
    np.testing.assert_allclose(shared.energies_j["contact"], contact, rtol=1e-12, atol=1e-15 * contact.max())


def _stack_then_drop():
    """Two one-handle boxes resting on each other fall asleep, then a third dropped from 1.6 m lands on them
    (draft, 30 frames): the step of the impact wakes the upper box only (a box woken in a step wakes nobody),
    so the lower one is a sleeping partner of a fast island that takes several sub-steps."""
    from data_gen.sim.material import Material
    from data_gen.sim.world import SimObjectSpec, Simulator
    from tests.sim.test_sim_column import grid_box

    half = (0.07, 0.07, 0.05)
    starts = [(0.0, 0.0, 0.05), (0.01, 0.0, 0.151), (0.03, 0.01, 1.6)]
    specs = [
        SimObjectSpec(f"box_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(1e9, 0.3, 1000.0),
                      position_m=x, num_handles=1)
        for k, x in enumerate(starts)
    ]  # fmt: skip
    return Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0).run(30, fps=25.0)


def test_a_recorded_fused_step_keeps_the_sphere_records_of_one_record_per_substep(monkeypatch):
    """A recorded step of a fused launch takes its statistics for all sub-steps at once and its per-sphere
    records (contact force, partner, partner strength) from the last sub-step, plus every sub-step's forces on a
    sleeping partner. Every recorded array, event and energy equals, bit for bit, a run that records each
    sub-step in turn (each record starting the island's objects anew, the sleeping partner collecting)."""

    seen = {"calls": 0, "sleeping_partner_forces": 0}
    batched = ImplicitEulerSolver._record_substep_sphere_forces

    def counted(self, objects, result, ps, sphere_valid, h_s):
        seen["calls"] += 1
        if len(ps.obj_i) and len(result.forces) > 1:
            asleep = torch.from_numpy(self.state.asleep[ps.obj_j])
            for forces in result.forces[:-1]:
                seen["sleeping_partner_forces"] += int(((forces.pair_force_i_n != 0).any(1) & asleep).sum())
        return batched(self, objects, result, ps, sphere_valid, h_s)

    monkeypatch.setattr(ImplicitEulerSolver, "_record_substep_sphere_forces", counted)
    lean = _stack_then_drop()
    # sleeping partners pushed in sub-steps before a recorded step's last: their records sum sub-steps
    assert seen["calls"] > 0 and seen["sleeping_partner_forces"] > 0, seen

    def every_substep(self, objects, result, ps, sphere_valid, h_s):  # the records as before, sub-step by sub-step
        slot_of = np.full(len(self.bodies), -1, dtype=np.int64)
        slot_of[objects] = np.arange(len(objects))
        pairs = self._group_pairs(objects, slot_of, ps)  # the part's pairs in its own slots
        for forces in result.forces:
            self._record_group_forces(objects, forces, ps, pairs, sphere_valid, h_s, StepStats(),
                                      np.zeros(len(self.bodies), dtype=bool))  # fmt: skip

    monkeypatch.setattr(ImplicitEulerSolver, "_record_substep_sphere_forces", every_substep)
    full = _stack_then_drop()
    assert any((tr.contact_partner > 0).any() for tr in full.objects)
    _assert_same_results(lean, full)


def test_pair_force_series_equals_one_call_per_entry_in_order():
    """StepStats.add_pair_force_series leaves the same entries, bit for bit and in the same key order, as one
    add_pair_force per present entry, sub-step by sub-step and key by key: impulses summed in that order, the
    first of equal strongest forces kept (ties made on purpose), keys met earlier in the step added to."""
    rng = np.random.default_rng(4)
    for trial in range(20):
        num_sub, count = int(rng.integers(1, 9)), int(rng.integers(1, 12))
        keys = [(int(a), int(b)) for a, b in rng.integers(0, 6, (count, 2))]
        keys = list(dict.fromkeys(keys))  # distinct keys, as a part's objects and object pairs are
        count = len(keys)
        force = rng.normal(size=(num_sub, count, 3)) * rng.uniform(0.0, 50.0, (num_sub, count, 1))
        tie = rng.random((num_sub, count)) < 0.2
        force[tie] = np.broadcast_to(force[0], force.shape)[tie]  # equal magnitudes in several sub-steps
        position = rng.normal(size=(num_sub, count, 3))
        normal = rng.normal(size=(num_sub, count, 3))
        present = rng.random((num_sub, count)) < 0.6
        h = float(rng.uniform(1e-3, 1e-2))
        expected, series = StepStats(), StepStats()
        for stats in (expected, series):  # a key met earlier in the step (e.g. a sleeping contact)
            if trial % 3 == 0:
                stats.add_pair_force(keys[0], np.array([1.0, 2.0, 2.0]), np.zeros(3), np.ones(3), h)
        for j in range(num_sub):
            for k in np.flatnonzero(present[j]):
                expected.add_pair_force(keys[k], force[j, k], position[j, k], normal[j, k], h)
        series.add_pair_force_series(keys, force, position, normal, present, h)
        assert list(series.pair_forces) == list(expected.pair_forces)
        for key, entry in expected.pair_forces.items():
            got = series.pair_forces[key]
            assert got["impulse_n_s"] == entry["impulse_n_s"] and got["peak_force_n"] == entry["peak_force_n"]
            np.testing.assert_array_equal(got["position_m"], entry["position_m"])
            np.testing.assert_array_equal(got["normal"], entry["normal"])


def test_distinct_codes_equal_numpy_unique():
    from data_gen.sim.solver import _distinct_codes

    rng = np.random.default_rng(2)
    for size in (1, 4, 100, 2500):
        for n in (0, 1, 50, 3000):
            codes = rng.integers(0, size, n)
            keys, index = _distinct_codes(codes, size)
            expected_keys, expected_index = np.unique(codes, return_inverse=True)
            np.testing.assert_array_equal(keys, expected_keys)
            np.testing.assert_array_equal(index, expected_index.reshape(-1))


def test_pair_set_without_start_data_keeps_what_the_fused_launch_reads():
    """The fused path's pair set (no start data) has the same objects, spheres, stiffness, friction and radius
    sums as the full one, and side j's start positions wherever side j is off the island's members (a sleeping
    partner, frozen in the solve: the only rows the launch reads)."""
    solver = _solver()
    solver.state.asleep[3] = True
    positions = solver._contact_positions()
    offsets = solver.broad_phase.offsets
    rng = np.random.default_rng(6)
    members = [0, 1, 2]
    gi = np.concatenate([rng.integers(offsets[o], offsets[o + 1], 15) for o in members])
    partner = rng.choice([0, 1, 2, 3], size=len(gi))
    gj = np.array([rng.integers(offsets[o], offsets[o + 1]) for o in partner])
    full = solver._island_pairs(gi, gj, positions, 0.0025, within_substep=False)
    lean = solver._pair_set_without_start(gi, gj, positions, 0.0025, members)
    for name in ("obj_i", "loc_i", "obj_j", "loc_j"):
        np.testing.assert_array_equal(getattr(lean, name), getattr(full, name))
    for name in ("stiffness_n_m", "radius_sum_m", "mu", "global_i", "global_j"):
        assert torch.equal(getattr(lean, name), getattr(full, name)), name
    frozen = torch.from_numpy(partner == 3)
    assert frozen.any() and torch.equal(lean.x0_j[frozen], full.x0_j[frozen])
    assert lean.lam_n is None and lean.x0_i is None
