"""The thread-per-element Newton schedule (:mod:`data_gen.sim.device_newton`) against the fused kernel it mirrors:
the same objective, gradient and matrix from its term launches (round-off), the same iterations, counters and
results on recorded steps and on islands of deformable objects, the same hand-back, and bit-for-bit repeats
on the CPU."""

import itertools

import numpy as np

import pytest
import torch
import warp as wp

from data_gen.sim.device_newton import DeviceNewton
from data_gen.sim.fused_newton import Bodies, FusedNewton, StepData, Work
from data_gen.sim.newton import NewtonSettings
from tests.sim.test_sim_fused_newton import GRAVITY, IDS, SCENES, _captured_solves, _objective

D = torch.float64
_INIT = DeviceNewton.__init__


def _built_as(patch, device, graph: bool | None, tile_factor: bool | None) -> None:
    """The ``DeviceNewton`` the solver builds gets these arguments (``patch``: a monkeypatch or its context)."""
    patch.setattr(DeviceNewton, "__init__", lambda self, fused, timings=None, counters=None, **_:
                  _INIT(self, fused, device, graph, tile_factor, timings, counters))  # fmt: skip


@pytest.fixture(params=["thread", "blocked", "lanes"])
def tile_factor(request, monkeypatch) -> bool:
    """How the islands' matrices are factorised: by a thread each (the CPU's default), by the blocked factorisation
    with one thread per block, or by it with the :data:`~data_gen.sim.tile_cholesky.THREADS` threads of a GPU's
    block as cooperative fibers (``wp.config.enable_cpu_blocks``: lanes that share each tile's work and meet at its
    barriers, as on a GPU; ``tests/sim/test_sim_tile_cholesky.py``). Returns the ``tile_factor`` argument."""
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", request.param == "lanes")
    return request.param != "thread"


@pytest.mark.parametrize("scene", SCENES, ids=IDS)
@pytest.mark.parametrize("handles", [(1, 3, 2), (1, 1, 1)], ids=["mixed", "one-handle"])
def test_term_launches_equal_the_fused_evaluation(scene, handles):
    """Two islands (pairs inside one and against a frozen partner), deformable and one-handle objects, on the
    ground, a box and a point cloud; at the start, a perturbed state and one lowered into the scene (spheres
    the scene test must not skip), where some elastic blocks are projected."""
    objective, fused, q0 = _objective(scene, handles=handles)
    device = DeviceNewton(fused)
    layout = objective.layout
    lowered = layout.to_objects(q0).clone()
    lowered[:, 2, 3] -= 0.05
    gen = torch.Generator().manual_seed(7)
    projected = False
    for q in (q0, q0 + 2e-3 * torch.randn(q0.shape, generator=gen, dtype=D), layout.to_islands(lowered)):
        value, grad, hess, flagged = fused.evaluate(objective, q, True)
        projected |= bool(flagged.any())
        d_value, d_grad, d_hess = device.evaluate(objective, q, True)
        torch.testing.assert_close(d_value, value, rtol=1e-11, atol=0.0)
        torch.testing.assert_close(d_grad, grad, rtol=0.0, atol=1e-10 * float(grad.abs().amax()))
        torch.testing.assert_close(d_hess, hess, rtol=0.0, atol=1e-10 * float(hess.abs().amax()))
        assert float((d_hess - d_hess.mT).abs().amax()) <= 1e-14 * float(hess.abs().amax())  # both triangles
        only, no_grad, _ = device.evaluate(objective, q, False)
        assert no_grad is None
        torch.testing.assert_close(only, value, rtol=1e-11, atol=0.0)
    assert projected  # the strained states exercise the projection of elastic blocks


def _same_solve(objective, fused_result, device_result, settings, scale, same_path: bool = True, gap_tol: float = 1e-6):
    """The same convergence and the same end to within ``gap_tol`` of the tolerance (mass norm); with
    ``same_path`` also the same iterations and every counter."""
    assert device_result is not None, "the schedule handed back a step the fused kernel solved"
    assert torch.equal(device_result.converged, fused_result.converged)
    if same_path:
        assert torch.equal(device_result.iterations, fused_result.iterations)
        assert device_result.counters == fused_result.counters
    gap = objective.mass_norm(device_result.q - fused_result.q)
    assert bool((gap <= gap_tol * settings.tolerance * scale).all()), (gap / (settings.tolerance * scale)).tolist()


def test_schedule_takes_the_fused_kernels_path_on_recorded_steps(tile_factor):
    """Real steps of a thrown stack of one-handle boxes (landing, pairs, friction); every third with a tiny
    trust radius (updates cut by it). Checked against the fused kernel, itself checked against ``minimise``;
    with the islands factorised by a thread each (the CPU's default) and by the blocked factorisation (the GPU's)."""
    solves = _captured_solves(throw=True)
    assert len(solves) >= 20
    trust_limited = line_searched = 0
    for (objective, q0, scale, trust, settings), factor in zip(solves, itertools.cycle([1.0, 1.0, 0.005])):
        trust = factor * trust
        fused = FusedNewton(objective.model, objective.layout, objective.contact, objective.island_mass_kg,
                            objective.min_median_radius_m)  # fmt: skip
        ref = fused.solve(objective, q0, scale, trust, settings)
        ref = type(ref)(ref.q.clone(), ref.iterations, ref.converged, dict(ref.counters))  # (q: the workspace's)
        out = DeviceNewton(fused, tile_factor=tile_factor).solve(objective, q0, scale, trust, settings)
        _same_solve(objective, ref, out, settings, scale)
        trust_limited += out.counters["trust_limited_steps"]
        line_searched += out.counters["evaluations"]
    assert trust_limited > 0 and line_searched > 0  # both the trust limit and halvings were exercised


@pytest.mark.parametrize("scene", SCENES, ids=IDS)
def test_schedule_solves_islands_of_deformable_objects_as_the_fused_kernel(scene, tile_factor):
    """Two islands of 1-, 3- and 2-handle objects moving fast into the scene (40-160 trust-limited iterations,
    line searches): each island stops in its own iteration (the schedule runs until the last is done), both
    converge where the fused kernel's do, to 0.05 of the tolerance (the bound the fused kernel meets against
    ``minimise``: over a hundred iterations round-off may move a decision), with the kernel's own limits (no
    scale or trust given) and with given ones."""
    objective, fused, q0 = _objective(scene, speed=1.0)
    settings = NewtonSettings(iterations=300, tolerance=1e-6, line_search_steps=8)
    ref = fused.solve(objective, q0, None, None, settings)
    assert ref is not None and bool(ref.converged.all())
    ref = type(ref)(ref.q.clone(), ref.iterations, ref.converged, dict(ref.counters))
    assert int(ref.iterations.min()) >= 30 and ref.counters["trust_limited_steps"] > 0 and ref.counters["evaluations"] > 0
    scale = fused.threshold.clone() / settings.tolerance
    trust = fused.trust.clone()
    device = DeviceNewton(fused, tile_factor=tile_factor)
    out = device.solve(objective, q0, None, None, settings)
    _same_solve(objective, ref, out, settings, scale, same_path=False, gap_tol=0.05)
    assert bool(((out.iterations - ref.iterations).abs() <= 0.1 * ref.iterations).all())
    given = device.solve(objective, q0, scale, trust, settings)
    _same_solve(objective, ref, given, settings, scale, same_path=False, gap_tol=0.05)
    # the CPU's launches run their threads in order: a repeat is the same bits
    again = device.solve(objective, q0, scale, trust, settings)
    assert torch.equal(again.q, given.q)


def test_iteration_cap_stops_islands_unconverged_as_the_fused_kernel():
    objective, fused, q0 = _objective(SCENES[0], speed=1.0)
    settings = NewtonSettings(iterations=1, tolerance=1e-12, line_search_steps=8)
    ref = fused.solve(objective, q0, None, None, settings)
    ref = type(ref)(ref.q.clone(), ref.iterations, ref.converged, dict(ref.counters))
    assert ref.counters["unconverged_solves"] > 0
    out = DeviceNewton(fused).solve(objective, q0, None, None, settings)
    scale = fused.threshold / settings.tolerance
    _same_solve(objective, ref, out, settings, scale, gap_tol=1.0)  # (tolerance 1e-12: round-off of one update)
    assert bool((out.iterations == 1).all())


def test_schedule_hands_back_a_non_finite_state(tile_factor):
    """The same workspace solves a finite start (converged, as the fused kernel, on the same iterations) and hands a
    non-finite one back (None), as the fused kernel does."""
    objective, q0, scale, trust, settings = _captured_solves(1)[0]
    fused = FusedNewton(objective.model, objective.layout, objective.contact, objective.island_mass_kg,
                        objective.min_median_radius_m)  # fmt: skip
    device = DeviceNewton(fused, tile_factor=tile_factor)
    ref = fused.solve(objective, q0, scale, trust, settings)
    ref_iterations, ref_q = ref.iterations.clone(), ref.q.clone()
    solved = device.solve(objective, q0, scale, trust, settings)
    assert solved is not None and bool(solved.converged.all())
    assert torch.equal(solved.iterations, ref_iterations)
    assert bool((objective.mass_norm(solved.q - ref_q) <= 1e-6 * settings.tolerance * scale).all())
    bad = q0.clone()
    bad[0, 0] = float("nan")
    assert device.solve(objective, bad, scale, trust, settings) is None
    assert fused.solve(objective, bad, scale, trust, settings) is None


def _stack(throw: bool, device_newton: bool, frames: int = 20, handles: int = 1, young_pa: float = 1e9,
           fused_newton: bool = True):  # fmt: skip
    """The fused tests' three stiff boxes dropped into a stack (``throw``: the top one thrown down, spinning),
    draft quality, solved by the fused kernel's sub-step launch or by the device schedule (its own sub-step schedule);
    ``handles`` and ``young_pa`` make them deformable."""
    from data_gen.sim.material import Material
    from data_gen.sim.static_scene import StaticScene
    from data_gen.sim.world import SimObjectSpec, Simulator
    from tests.sim.test_sim_column import grid_box

    half = (0.07, 0.07, 0.05)
    specs = [
        SimObjectSpec(f"box_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(young_pa, 0.3, 1000.0),
                      position_m=(0.01 * k, 0.01 * (k % 2), 0.06 + 0.12 * k), num_handles=handles,
                      velocity_m_s=(0.5, 0.0, -3.0) if throw and k == 2 else (0.0, 0.0, 0.0),
                      angular_velocity_rad_s=(10.0, 3.0, 0.0) if throw and k == 2 else (0.0, 0.0, 0.0))
        for k in range(3)
    ]  # fmt: skip
    sim = Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0, device_newton=device_newton,
                    fused_newton=fused_newton)  # fmt: skip
    return sim.run(frames, fps=25.0)


@pytest.mark.parametrize("throw", [False, True], ids=["dropped", "thrown"])
def test_simulation_with_the_device_schedule_agrees_with_the_fused_kernel_and_repeats(throw, monkeypatch):
    """Whole simulations (landing, stacking, a thrown box hitting the stack, sleep): every island solve went
    through the schedule (none handed back), the trajectories agree with the fused kernel's sub-step launch to
    round-off (1.3e-13 m measured; 1e-9 m asserted), the stack rests one box height per box, and a second run
    repeats bit for bit."""
    fused, device, again = _stack(throw, False), _stack(throw, True), _stack(throw, True)
    com_f, com_d, com_again = (np.stack([t.com_m for t in r.objects]) for r in (fused, device, again))
    assert np.array_equal(com_d, com_again)
    assert np.abs(com_d - com_f).max() < 1e-9, np.abs(com_d - com_f).max()
    # the GPU's factorisation (a block per island) and its captured schedule (warp's CPU graph recording) in the
    # whole simulation too
    _built_as(monkeypatch, None, True, True)
    tiled = _stack(throw, True)
    assert np.abs(np.stack([t.com_m for t in tiled.objects]) - com_f).max() < 1e-9
    # the solves' wall time and their captures' part of it (a GPU run weighs the two: a graph per solve)
    direct_s, tiled_s = device.info.timings_s, tiled.info.timings_s
    assert direct_s["device_capture"] == 0.0 < direct_s["device_solve"] <= direct_s["newton"]
    assert 0.0 < tiled_s["device_capture"] < tiled_s["device_solve"] <= tiled_s["newton"]
    assert "device_solve" not in fused.info.timings_s
    with monkeypatch.context() as m:  # and with a GPU block's lanes sharing each factorisation
        m.setattr(wp.config, "enable_cpu_blocks", True)
        lanes = _stack(throw, True)
    assert np.abs(np.stack([t.com_m for t in lanes.objects]) - com_f).max() < 1e-9
    # on copies of each workspace, as next to a GPU (the model copied again at each regrouping): the same bits
    _built_as(monkeypatch, "cpu", False, False)
    copied = _stack(throw, True)
    assert np.array_equal(np.stack([t.com_m for t in copied.objects]), com_d)
    np.testing.assert_allclose(np.diff(np.sort(com_d[:, -1, 2])), 0.1, atol=0.01)
    counters = device.info.counters
    assert counters["device_island_solves"] == counters["island_solves"] > 0
    assert counters["device_handed_back"] == 0 and counters["unconverged_solves"] == 0
    assert fused.info.counters["device_island_solves"] == 0


def test_the_captured_schedule_gives_the_direct_launches_bits(tile_factor):
    """``graph=True``: the whole solve captured once (its two loops as ``wp.capture_while`` nodes, nested) and
    replayed, as on CUDA; on the CPU warp records the same launches, so the captured solve must give the direct
    one's bits, on the workspace's device and on copies, and the capture must not have fallen back."""
    objective, fused, q0 = _objective(SCENES[1], speed=1.0)
    settings = NewtonSettings(iterations=300, tolerance=1e-6, line_search_steps=8)
    direct = DeviceNewton(fused, graph=False, tile_factor=tile_factor).solve(objective, q0, None, None, settings)
    q, counters = direct.q.clone(), dict(direct.counters)
    for device in (None, "cpu"):
        captured = DeviceNewton(fused, device=device, graph=True, tile_factor=tile_factor)
        captured.clear_entries = tile_factor  # (the GPU's clearing, an entry per thread, with the GPU's factorisation)
        out = captured.solve(objective, q0, None, None, settings)
        assert captured.graph  # (a failed capture logs and turns it off)
        assert torch.equal(out.q, q) and out.counters == counters
    assert counters["evaluations"] > 0 and int(direct.iterations.max()) > 30  # both loops ran many times


@pytest.mark.parametrize("graphs_kept", [8, 1])
def test_captured_schedules_are_launched_again_where_their_launches_would_repeat(graphs_kept, monkeypatch):
    """A graph is launched again by a solve whose launches would be the same bytes (``_schedule_key``): through
    a simulation's steps (new pair counts, sub-step counts, regroupings, pair buffers reallocated) the reused
    graphs give the bits of launching every schedule directly, with most steps reusing one; keeping a single
    graph (evicted at each new key) gives them too."""
    import data_gen.sim.device_newton as device_module

    monkeypatch.setattr(device_module, "GRAPHS_KEPT", graphs_kept)
    runs = {}
    for graph in (False, True):
        with monkeypatch.context() as m:
            _built_as(m, None, graph, True)
            runs[graph] = _stack(True, True, frames=25)
    direct, captured = (np.stack([t.com_m for t in runs[g].objects]) for g in (False, True))
    assert np.array_equal(direct, captured)
    counters = runs[True].info.counters
    assert counters["device_graphs_captured"] > 0 and counters["device_graphs_reused"] > counters["device_graphs_captured"]
    assert runs[False].info.counters["device_graphs_captured"] == runs[False].info.counters["device_graphs_reused"] == 0


def test_a_graph_is_launched_again_only_for_the_same_launches():
    """Repeating a solve launches its graph again (the same bits as launching directly); another iteration cap
    (a scalar of the schedule) or gravity turned by 30 degrees (a vector inside the step data struct, passed by
    value; its norm, which the key also holds, unchanged) makes another graph, and each solve equals the direct
    launches of its own arguments."""
    objective, fused, q0 = _objective(SCENES[1], speed=1.0)
    solver = DeviceNewton(fused, graph=True, tile_factor=True)
    first = NewtonSettings(iterations=300, tolerance=1e-6, line_search_steps=8)
    capped = NewtonSettings(iterations=3, tolerance=1e-6, line_search_steps=8)
    g = float(GRAVITY.norm())
    turned = torch.tensor([0.0, g * np.sin(np.pi / 6), -g * np.cos(np.pi / 6)], dtype=D)
    results = []
    for settings, gravity, graphs, reused in ((first, GRAVITY, 1, 0), (first, GRAVITY, 1, 1), (capped, GRAVITY, 2, 1),
                                               (first, turned, 3, 1), (first, turned, 3, 2)):  # fmt: skip
        objective.gravity = gravity.clone()
        want = DeviceNewton(fused, graph=False, tile_factor=True).solve(objective, q0, None, None, settings).q.clone()
        got = solver.solve(objective, q0, None, None, settings).q.clone()
        assert torch.equal(got, want)
        assert (solver.counters["device_graphs_captured"], solver.counters["device_graphs_reused"]) == (graphs, reused)
        results.append(got)
    assert not torch.equal(results[0], results[2]) and not torch.equal(results[0], results[3])


def test_the_graph_key_follows_the_pairs_launch():
    """The pair count is left out of the step data's bytes in the key (no kernel reads it) but the pairs launch
    of a graph has a power of two of threads: counts rounding to the same power share a key, others do not.
    Launched directly, the launch has the count's threads."""
    from data_gen.sim.device_newton import _pair_threads

    objective, fused, q0 = _objective(SCENES[1], speed=1.0)
    settings = NewtonSettings(iterations=300, tolerance=1e-6, line_search_steps=8)
    solver = DeviceNewton(fused, graph=True, tile_factor=True)
    solver.solve(objective, q0, None, None, settings)
    st = fused._step
    capacity = st.obj_i.shape[0]
    structs = (fused.bodies, fused.scene, fused.work, solver._island_info(), *fused._limits)
    keys = {}
    for count in (5, 7, 8, 9, capacity - 1):
        st.num_pairs = count
        keys[count] = solver._schedule_key("solve", st, structs, 1)
    assert keys[5] == keys[7] == keys[8] != keys[9] != keys[capacity - 1]
    st.num_pairs = 9
    assert (_pair_threads(st, True), _pair_threads(st, False)) == (16, 9)
    st.num_pairs = capacity - 1
    assert _pair_threads(st, True) == capacity  # (never past the pair buffers)
    st.num_pairs = 0
    assert _pair_threads(st, True) == 0


def test_copy_rows_copies_the_rows_in_use_only():
    """The copies next to a GPU move a pair buffer's rows in use, not its capacity: ``copy_rows`` copies rows
    ``row .. row + rows`` of the first axis (clipped to the array), all of them without ``rows``."""
    from data_gen.sim.device_newton import copy_rows

    src = wp.array(np.arange(24.0).reshape(4, 2, 3), dtype=wp.float64)
    for rows, row, want_rows in ((2, 0, [0, 1]), (2, 1, [1, 2]), (9, 2, [2, 3]), (0, 0, []), (None, 0, [0, 1, 2, 3])):
        dst = wp.full((4, 2, 3), -1.0, dtype=wp.float64)
        copy_rows(dst, src, rows, row)
        want = np.full((4, 2, 3), -1.0)
        want[want_rows] = src.numpy()[want_rows]
        assert np.array_equal(dst.numpy(), want), (rows, row)
    vectors = wp.array(np.arange(12.0).reshape(4, 3), dtype=wp.vec3d)
    dst = wp.zeros(4, dtype=wp.vec3d)
    copy_rows(dst, vectors, 3)
    assert np.array_equal(dst.numpy(), np.concatenate([np.arange(9.0).reshape(3, 3), np.zeros((1, 3))]))


def test_default_graph_applies_where_no_graph_is_given(monkeypatch):
    """``DeviceNewton.default_graph`` (what ``bench_cuda.py --profile-solver`` turns off) decides where the caller
    (the solver) gives no ``graph``; None leaves it to the device (the CPU: no graph); a given one wins."""
    objective, fused, q0 = _objective(SCENES[0], speed=1.0)
    assert not DeviceNewton(fused).graph
    monkeypatch.setattr(DeviceNewton, "default_graph", True)
    assert DeviceNewton(fused).graph and not DeviceNewton(fused, graph=False).graph
    monkeypatch.setattr(DeviceNewton, "default_graph", False)
    assert not DeviceNewton(fused).graph and DeviceNewton(fused, graph=True).graph


def test_a_cuda_device_is_warned_about_once_until_the_gpu_test_has_passed(monkeypatch, caplog):
    """Until ``tests/sim/test_sim_device_newton_cuda.py`` has passed on a GPU (``CUDA_VALIDATED``), a schedule on a
    CUDA device logs once per device that it is untested there, naming the test to run; a CPU one never does, and
    neither does any device once it is validated."""
    from data_gen.sim import device_newton as dn

    monkeypatch.setattr(dn, "_UNVALIDATED_WARNED", set())
    with caplog.at_level("WARNING", logger=dn.__name__):
        assert not dn.warn_if_unvalidated(wp.get_device("cpu"))
        assert [dn.warn_if_unvalidated(d) for d in (_Named("cuda:0"), _Named("cuda:0"), _Named("cuda:1"))] == [
            True, False, True]
        objective, fused, q0 = _objective(SCENES[0], speed=1.0)
        DeviceNewton(fused)  # the CPU: no warning from the constructor either
    warned = [r.getMessage() for r in caplog.records if r.name == dn.__name__]
    assert len(warned) == 2 and "cuda:0" in warned[0] and "cuda:1" in warned[1]
    assert all("tests/sim/test_sim_device_newton_cuda.py" in m and "never on a CUDA GPU" in m for m in warned)
    monkeypatch.setattr(dn, "CUDA_VALIDATED", True)
    assert not dn.warn_if_unvalidated(_Named("cuda:2"))


class _Named:
    """A stand-in for a warp CUDA device where the test has none: its name and ``is_cuda``."""

    is_cuda = True

    def __init__(self, name: str) -> None:
        self.name = name

    def __str__(self) -> str:
        return self.name


def test_the_gpus_configuration_emulated_on_the_cpu_runs_a_simulation_as_the_fused_kernel(monkeypatch):
    """Everything a GPU run sets at once, emulated on the CPU: copies of the workspace on another device, the
    schedule captured as graphs (and launched again), the matrices cleared an entry per thread, the blocked
    factorisation with 64 lanes per block (warp's CPU fibers). A thrown stack's trajectory stays within 1e-9 m of
    the fused kernel's, every island solve goes through the schedule, no capture falls back, graphs are reused."""
    run = DeviceNewton._run
    fallbacks = []

    def gpu_like(self, schedule, *args):
        self.clear_entries = True
        out = run(self, schedule, *args)
        if not self.graph:
            fallbacks.append(args[0])
        return out

    monkeypatch.setattr(DeviceNewton, "_run", gpu_like)
    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    _built_as(monkeypatch, "cpu", True, True)
    emulated = _stack(True, True)
    fused = _stack(True, False)
    gap = np.abs(np.stack([t.com_m for t in emulated.objects]) - np.stack([t.com_m for t in fused.objects])).max()
    assert gap < 1e-9, gap
    counters = emulated.info.counters
    assert counters["device_island_solves"] == counters["island_solves"] > 0 and counters["device_handed_back"] == 0
    assert not fallbacks and counters["device_graphs_reused"] > 0
    # deformable boxes: their solves (not sub-steps) in the same configuration, against the split solve
    kwargs = dict(frames=20, handles=2, young_pa=1e5)
    soft, split = _stack(False, True, **kwargs), _stack(False, False, **kwargs)
    gap = np.abs(np.stack([t.com_m for t in soft.objects]) - np.stack([t.com_m for t in split.objects])).max()
    assert gap < 2e-5, gap  # (the in-place schedule's bound: test_deformable_islands_on_the_device_schedule_...)
    counters = soft.info.counters
    assert counters["device_island_solves"] == counters["island_solves"] > 0 and counters["device_handed_back"] == 0
    assert not fallbacks and counters["device_graphs_captured"] > 0


def test_every_module_variant_the_capture_launches_is_loaded_before_it(monkeypatch):
    """A CUDA graph capture cannot load a module (compiling and loading it synchronises the device), and warp
    compiles a module once per block size: the factorisation's blocks of THREADS are a variant of their module
    apart from its default one. So ``DeviceNewton(graph=True)`` loads every variant its launches use before any
    capture; here the modules start unloaded, with a GPU's blocks (lanes), and no launch inside the capture may
    find its variant missing."""
    from warp._src.context import Module

    import data_gen.sim.device_newton as device_module
    import data_gen.sim.tile_cholesky as tile_module

    monkeypatch.setattr(wp.config, "enable_cpu_blocks", True)
    objective, fused, q0 = _objective(SCENES[0], speed=1.0)
    settings = NewtonSettings(iterations=300, tolerance=1e-6, line_search_steps=8)
    for module in (device_module, tile_module):
        wp.get_module(module.__name__).unload()
    load = Module.load
    missing, loads_in_capture = [], []

    def checked(self, device, block_dim=None, *args, **kwargs):
        device = wp.get_device(device)
        if device.is_capturing:
            key = (device.context, block_dim if block_dim is not None else self.options["block_dim"])
            loads_in_capture.append((self.name, key[1]))
            if self.execs.get(key) is None:
                missing.append((self.name, key[1]))
        return load(self, device, block_dim, *args, **kwargs)

    monkeypatch.setattr(Module, "load", checked)
    solver = DeviceNewton(fused, graph=True, tile_factor=True)
    out = solver.solve(objective, q0, None, None, settings)
    assert solver.graph and out is not None and bool(out.converged.all())
    assert (tile_module.__name__, tile_module.THREADS) in loads_in_capture  # the check saw the tiled launch
    assert not missing, missing


def test_nothing_is_allocated_while_the_schedule_is_captured(monkeypatch):
    """A capture must not allocate (a CUDA device without graph memory pools refuses, and memory allocated
    into a graph lives as long as it): every buffer of a solve, of a step's sub-steps and of their copies on
    another device is allocated before ``DeviceNewton`` starts capturing. Recorded on the CPU's capture, with the
    GPU's factorisation and clearing, through a simulation's steps (sub-step schedules, regroupings) and a solve
    of deformable islands."""
    from warp._src.context import CpuDefaultAllocator

    allocate = CpuDefaultAllocator.allocate
    during_capture: list[int] = []
    captures = 0

    def recorded(self, size_in_bytes):
        if wp.get_device("cpu").is_capturing:
            during_capture.append(size_in_bytes)
        return allocate(self, size_in_bytes)

    run = DeviceNewton._run

    def counted(self, schedule, *args):
        nonlocal captures
        captures += int(self.graph)
        self.clear_entries = True
        return run(self, schedule, *args)

    monkeypatch.setattr(CpuDefaultAllocator, "allocate", recorded)
    monkeypatch.setattr(DeviceNewton, "_run", counted)
    for device in (None, "cpu"):
        with monkeypatch.context() as m:
            _built_as(m, device, True, True)
            result = _stack(True, True, frames=8)
        assert result.info.counters["device_island_solves"] > 0
        objective, fused, q0 = _objective(SCENES[1], speed=1.0)
        settings = NewtonSettings(iterations=300, tolerance=1e-6, line_search_steps=8)
        direct = DeviceNewton(fused, graph=False, tile_factor=True).solve(objective, q0, None, None, settings)
        want_q, want_counters = direct.q.clone(), dict(direct.counters)
        out = DeviceNewton(fused, device=device, graph=True, tile_factor=True).solve(objective, q0, None, None, settings)
        assert bool(out.converged.all()) and torch.equal(out.q, want_q) and out.counters == want_counters
    assert captures >= 10 and not during_capture, (captures, during_capture)


def _arrays(struct, struct_type) -> list:
    return [getattr(struct, name) for name in struct_type.vars if isinstance(getattr(struct, name), wp.array)]


@pytest.mark.parametrize("scene", SCENES, ids=IDS)
def test_a_solve_on_copies_of_the_workspace_equals_the_solve_in_place(scene):
    """``DeviceNewton(fused, device=...)`` (what a GPU next to a CPU workspace runs) copies the model, the step and
    the buffers, solves there and brings the state, counters and limits back. On the CPU the copies must give the
    in-place solve's bits exactly, hold no array of the workspace (a field left pointing at the source would
    still work here and fail on a GPU), and keep the four-at-a-time views on their copy's memory."""
    objective, fused, q0 = _objective(scene, speed=1.0)
    settings = NewtonSettings(iterations=300, tolerance=1e-6, line_search_steps=8)
    in_place = DeviceNewton(fused).solve(objective, q0, None, None, settings)
    ref_q, ref_counters, ref_limits = in_place.q.clone(), dict(in_place.counters), fused.threshold.clone()
    fused.threshold.zero_()  # (the copies' start launch computes the limits again: they must come back)
    copies = DeviceNewton(fused, device="cpu")
    out = copies.solve(objective, q0, None, None, settings)
    assert torch.equal(out.q, ref_q) and out.counters == ref_counters
    assert torch.equal(out.iterations, in_place.iterations) and torch.equal(fused.threshold, ref_limits)
    value, grad, hess, _ = fused.evaluate(objective, q0, True)
    d_value, d_grad, d_hess = copies.evaluate(objective, q0, True)
    e_value, e_grad, e_hess = DeviceNewton(fused).evaluate(objective, q0, True)
    assert torch.equal(d_value, e_value) and torch.equal(d_grad, e_grad) and torch.equal(d_hess, e_hess)
    torch.testing.assert_close(d_value, value, rtol=1e-11, atol=0.0)
    bd, sc, st, wk, threshold, trust = copies._structs(fused._step_data(objective))
    types = (Bodies, StepData, Work)
    own = {a.ptr for s, t in zip((fused.bodies, fused._step, fused.work), types) for a in _arrays(s, t) if a.ptr}
    own |= {fused._limits[0].ptr, fused._limits[1].ptr}
    copied = {a.ptr for s, t in zip((bd, st, wk), types) for a in _arrays(s, t) if a.ptr} | {threshold.ptr, trust.ptr}
    assert not own & copied
    assert wk.hess4.ptr == wk.hess.ptr and wk.chol4.ptr == wk.chol.ptr and wk.tm4.ptr == wk.tm.ptr
    assert st.tm_pred4.ptr == st.tm_pred.ptr and bd.b4.ptr == bd.b.ptr


def test_blocked_factorisation_takes_the_ridge_where_a_matrix_is_singular():
    """An island whose matrix has a zero row and column (an unknown nothing acts on) fails the first blocked
    factorisation; the second adds the fused kernel's ridge (1e-10 of the largest diagonal entry) and its update
    is numpy's solve of that matrix; the other island's update has no ridge."""
    from data_gen.sim.device_newton import EVALUATE

    objective, fused, q0 = _objective(SCENES[0])
    device = DeviceNewton(fused, tile_factor=True)
    _, grad, hess = device.evaluate(objective, q0, True)
    n_isl, size = fused.shape
    singular = hess.clone()
    singular[0, 5, :] = 0.0
    singular[0, :, 5] = 0.0
    fused.hess.view(n_isl, size, size).copy_(singular)
    info = device._island_info()
    info.phase.assign(np.full(n_isl, EVALUATE, dtype=np.int32))
    device._factor_blocked(fused.bodies, fused.work, info)
    assert info.factor.numpy().tolist() == [1, 0]  # (after the second pass: the island that needed the ridge)
    dq = fused.dq.view(n_isl, size)
    sym = 0.5 * (singular + singular.mT)
    ridge = 1e-10 * float(singular[0].diagonal().abs().max())
    want0 = -torch.linalg.solve(sym[0] + ridge * torch.eye(size, dtype=D), grad[0])
    want1 = -torch.linalg.solve(sym[1], grad[1])
    torch.testing.assert_close(dq[0], want0, rtol=1e-6, atol=0.0)
    torch.testing.assert_close(dq[1], want1, rtol=1e-9, atol=1e-12 * float(want1.abs().max()))
    assert float(info.ridge.numpy()[0]) == ridge


def test_deformable_islands_on_the_device_schedule_agree_with_the_split_and_batched_paths():
    """Three soft boxes (2 handles, E = 1e5 Pa) dropped into a stack, 20 frames: every island solve through the
    schedule on the deformable workspace (the full Newton matrix each iteration, no kept elastic blocks). The
    split solve (kept blocks) and the batched ``minimise`` differ from each other by 1.2e-5 m; the schedule
    differs from each by 7e-6 m (asserted: 2e-5 m)."""
    kwargs = dict(frames=20, handles=2, young_pa=1e5)
    device, split, batched = (_stack(False, d, fused_newton=f, **kwargs) for d, f in ((True, True), (False, True),
                                                                                   (False, False)))  # fmt: skip
    com_d, com_s, com_b = (np.stack([t.com_m for t in r.objects]) for r in (device, split, batched))
    assert np.abs(com_d - com_s).max() < 2e-5 and np.abs(com_d - com_b).max() < 2e-5
    counters = device.info.counters
    assert counters["device_island_solves"] == counters["island_solves"] > 0
    assert counters["device_handed_back"] == counters["split_island_solves"] == 0
    assert split.info.counters["split_island_solves"] > 0  # (the reference took its own path)
    np.testing.assert_allclose(np.diff(np.sort(com_d[:, -1, 2])), 0.1, atol=0.01)


def test_islands_mixing_one_handle_and_deformable_objects_take_the_device_schedule():
    """A stiff one-handle box dropped on a soft two-handle one, sliding on it: their island has no fused or split
    solver (it takes ``minimise``); with ``device_newton`` a workspace of its own solves it. The two solve each step
    to the preset's tolerance and drift apart by 2.7e-5 m in 20 frames (measured; 1e-4 m asserted: the soft
    stack's split and batched paths drift by 1.2e-5 m)."""
    from data_gen.sim.material import Material
    from data_gen.sim.static_scene import StaticScene
    from data_gen.sim.world import SimObjectSpec, Simulator
    from tests.sim.test_sim_column import grid_box

    half = (0.07, 0.07, 0.05)

    def run(device_newton: bool):
        specs = [
            SimObjectSpec(f"box_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(young, 0.3, 1000.0),
                          position_m=(0.01 * k, 0.0, 0.06 + 0.12 * k), num_handles=handles)
            for k, (young, handles) in enumerate(((1e5, 2), (1e9, 1)))
        ]  # fmt: skip
        sim = Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0, device_newton=device_newton)
        return sim.run(20, fps=25.0)

    device, default = run(True), run(False)
    com_d, com_m = (np.stack([t.com_m for t in r.objects]) for r in (device, default))
    assert np.abs(com_d - com_m).max() < 1e-4, np.abs(com_d - com_m).max()
    counters = device.info.counters
    assert counters["device_island_solves"] == counters["island_solves"] > 0 and counters["device_handed_back"] == 0
    assert default.info.counters["fused_island_solves"] + default.info.counters["split_island_solves"] < (
        default.info.counters["island_solves"]
    )  # (the mixed island took minimise there)
    assert 0.09 < com_d[1, -1, 2] - com_d[0, -1, 2] < 0.11  # the stiff box rests on the soft one


TOLERANCE = dict(tm=1e-10, tmdot=1e-7, scene_force_n=1e-8, scene_normals=1e-10, sphere_positions_m=1e-10,
                 pair_force_i_n=1e-8, pair_normals=1e-10, scene_sums=1e-8, pair_sums=1e-8)
"""Largest differences of the device sub-steps from the fused launch's, relative to each field's largest value.
Measured: states 6e-12, rates 1.2e-9 (a state's round-off divided by the sub-step), forces and their sums
8e-11, positions 6e-13, normals 1.4e-12."""


def test_device_substeps_equal_the_fused_substep_launch_on_a_simulations_steps(tile_factor, monkeypatch):
    """Every step of the thrown stack that the fused sub-step launch solves is solved again, right there on the
    same bindings, by ``DeviceNewton.solve_substeps``: the same counters and iterations, and states, rates,
    contact forces, normals and force sums within :data:`TOLERANCE`; and on copies of the workspace (what a GPU
    gets) the in-place schedule's bits; a non-finite state handed back by both (the simulation goes on with the
    fused result)."""
    original = FusedNewton.solve_substeps
    compared = []
    worst: dict[str, float] = {}

    def poisoned(self):  # every force buffer NaN: what a launch leaves unwritten stays NaN
        original(self, *args_of[0], **args_of[1])  # (allocates them for this step's sub-steps)
        for name in ("sub_sphere_x", "sub_scene_force", "sub_scene_normal", "sub_pair_force", "sub_pair_normal"):
            getattr(self, name).fill_(float("nan"))

    args_of: list = []

    def both(self, *args, **kwargs):
        args_of[:] = [args, kwargs]
        poisoned(self)
        ref = original(self, *args, **kwargs)
        fields = ("tm", "tmdot", "iterations", "scene_force_n", "scene_normals", "sphere_positions_m", "pair_force_i_n",
                  "pair_normals", "scene_sums", "pair_sums")  # fmt: skip
        kept = {name: getattr(ref, name).clone() for name in fields if getattr(ref, name) is not None}
        counters = dict(ref.counters)
        poisoned(self)  # (so that the entries compared below are the device schedule's own writes)
        out = DeviceNewton(self, tile_factor=tile_factor).solve_substeps(*args, **kwargs)
        assert out is not None and out.counters == counters
        for name, want in kept.items():
            got = getattr(out, name)
            if want.is_floating_point():  # (rows of an island past its sub-steps: the same untouched memory)
                scale = float(want.nan_to_num(0.0).abs().max()) or 1.0
                worst[name] = max(worst.get(name, 0.0), float((got - want).nan_to_num(0.0).abs().max()) / scale)
                torch.testing.assert_close(got, want, rtol=0.0, atol=TOLERANCE[name] * scale, equal_nan=True, msg=name)
            else:
                assert torch.equal(got, want), name
        in_place = {name: getattr(out, name).clone() for name in kept}
        poisoned(self)
        copies = DeviceNewton(self, device="cpu", tile_factor=tile_factor).solve_substeps(*args, **kwargs)
        assert copies.counters == counters  # on copies of the workspace (what a GPU gets): the same bits
        for name, want in in_place.items():
            assert torch.equal(getattr(copies, name).nan_to_num(7.0), want.nan_to_num(7.0)), name
        compared.append(int(ref.iterations.shape[0]))
        if len(compared) == 3:  # a non-finite state: the step is handed back (None), as the fused launch does
            bad = args[0].clone()
            bad[0, 0, 0] = float("nan")
            assert DeviceNewton(self, tile_factor=tile_factor).solve_substeps(bad, *args[1:], **kwargs) is None
            assert original(self, bad, *args[1:], **kwargs) is None
        return original(self, *args, **kwargs)  # (the device runs overwrote the workspace's buffers)

    monkeypatch.setattr(FusedNewton, "solve_substeps", both)
    _stack(True, False, frames=10)
    assert len(compared) >= 10 and max(compared) >= 2  # steps of several sub-steps among them


def test_copies_follow_the_workspace_through_its_regroupings(monkeypatch):
    """Three stiff boxes apart (three islands), one dropped onto another (two islands): the kept workspace is
    regrouped as they meet, and the copies of its grouping's arrays (the islands' objects, their unknowns) must
    be made again each time, or the copied solve would run on the old islands. The same bits as the in-place
    schedule, and the islands did change."""
    from data_gen.sim.material import Material
    from data_gen.sim.static_scene import StaticScene
    from data_gen.sim.world import SimObjectSpec, Simulator
    from tests.sim.test_sim_column import grid_box

    half = (0.07, 0.07, 0.05)
    regroupings = []
    relayout = FusedNewton.relayout

    def counted(self, layout, *args):
        regroupings.append(layout.num_islands)
        return relayout(self, layout, *args)

    def run(copies: bool):
        with monkeypatch.context() as m:
            m.setattr(FusedNewton, "relayout", counted)
            if copies:
                _built_as(m, "cpu", None, None)
            specs = [
                SimObjectSpec(f"box_{k}", grid_box(half, (5, 5, 4)), 0.14 * 0.14 * 0.1, Material(1e9, 0.3, 1000.0),
                              position_m=pos, num_handles=1, velocity_m_s=vel)
                for k, (pos, vel) in enumerate((((0.0, 0.0, 0.05), (0.0, 0.0, 0.0)), ((0.6, 0.0, 0.05), (0.0, 0.0, 0.0)),
                                                ((0.01, 0.0, 0.25), (0.0, 0.0, -1.0))))
            ]  # fmt: skip
            sim = Simulator(StaticScene(), specs, (0.0, 0.0, -9.81), "draft", seed=0, device_newton=True)
            return np.stack([t.com_m for t in sim.run(12, fps=25.0).objects])

    in_place, copied = run(False), run(True)
    assert np.array_equal(copied, in_place)
    assert len(set(regroupings)) >= 2  # the workspace was regrouped into other island counts
    assert 0.09 < in_place[2, -1, 2] - in_place[0, -1, 2] < 0.11  # the dropped box rests on the first
