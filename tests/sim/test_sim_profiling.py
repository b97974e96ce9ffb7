"""The speed-work tools: SectionTimer's counts and clean removal, and records_digest's sensitivity."""

from __future__ import annotations

import dataclasses
import time

import numpy as np
import pytest
import warp as wp

import data_gen.sim.newton as newton_module
from data_gen.sim import fused_newton
from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.records_digest import records_digest
from data_gen.sim.section_timer import DEFAULT_SECTIONS, SectionTimer
from data_gen.sim.skinning import SkinningTrainingSettings
from data_gen.sim.solver import ImplicitEulerSolver
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

TINY_TRAINING = SkinningTrainingSettings(steps=10, points_per_step=64, hidden_layers=1, width=8)


class _Toy:
    def outer(self, n: int) -> int:
        return sum(self.inner(k) for k in range(n))

    def inner(self, k: int) -> int:
        time.sleep(0.002)
        return k

    @staticmethod
    def helper(x: int) -> int:
        return 2 * x


class _Child(_Toy):
    """Inherits every method of _Toy (a timed inherited method is wrapped on the subclass only)."""


_SECTIONS = [(__name__, "_Toy", "outer"), (__name__, "_Toy", "inner"), (__name__, "_Toy", "helper")]


def test_counts_inclusive_times_and_shares():
    toy = _Toy()
    with SectionTimer(_SECTIONS, kernels=False) as timer:
        assert toy.outer(5) == 10
        assert _Toy.helper(4) == 8 and toy.helper(1) == 2  # a static method stays static
    rows = {row.name: row for row in timer.results()}
    assert rows["_Toy.outer"].calls == 1 and rows["_Toy.inner"].calls == 5 and rows["_Toy.helper"].calls == 2
    assert rows["_Toy.inner"].seconds >= 5 * 0.002  # five sleeps of 2 ms at least
    assert rows["_Toy.outer"].seconds >= rows["_Toy.inner"].seconds  # inclusive: outer holds the inner calls
    assert rows["_Toy.outer"].share == 1.0  # the first section is the root
    # own time: the outer call's, less its five inner calls (a sum, not a sleep); the inner ones call nothing timed
    assert rows["_Toy.outer"].own_seconds == pytest.approx(rows["_Toy.outer"].seconds - rows["_Toy.inner"].seconds)
    assert rows["_Toy.inner"].own_seconds == rows["_Toy.inner"].seconds
    assert 0.0 <= rows["_Toy.outer"].own_seconds < rows["_Toy.inner"].seconds
    assert rows["_Toy.inner"].share == pytest.approx(rows["_Toy.inner"].seconds / rows["_Toy.outer"].seconds)
    table = timer.table().splitlines()
    assert table[2].startswith("| `_Toy.outer` |") and len(table) == 2 + 3 and table[0].count("|") == 7


def test_wrappers_are_removed_on_exit_and_on_error():
    outer, inner, helper = _Toy.__dict__["outer"], _Toy.__dict__["inner"], _Toy.__dict__["helper"]
    launch, recorded_launch = wp.launch, wp.Launch.__dict__["launch"]
    with pytest.raises(ZeroDivisionError):
        with SectionTimer(_SECTIONS) as timer:
            assert _Toy.__dict__["inner"] is not inner and wp.launch is not launch
            _Toy().inner(1)
            1 / 0
    assert timer.calls["_Toy.inner"] == 1  # counted before the error
    assert _Toy.__dict__["outer"] is outer and _Toy.__dict__["inner"] is inner
    assert _Toy.__dict__["helper"] is helper
    assert wp.launch is launch and wp.Launch.__dict__["launch"] is recorded_launch
    # an inherited method is wrapped on the subclass and deleted there again afterwards
    with SectionTimer([(__name__, "_Child", "inner")], kernels=False) as child_timer:
        _Child().inner(2)
        _Toy().inner(3)  # the base class is not wrapped
    assert child_timer.calls["_Child.inner"] == 1
    assert "inner" not in _Child.__dict__


def test_module_functions_are_wrapped_wherever_imported():
    """``fused_newton`` imports ``cholesky_direction`` by name: both references are timed, both restored."""
    original = newton_module.cholesky_direction
    assert fused_newton.cholesky_direction is original
    with SectionTimer([("data_gen.sim.newton", None, "cholesky_direction")], kernels=False) as timer:
        assert fused_newton.cholesky_direction is newton_module.cholesky_direction is not original
        import torch

        hess = torch.eye(3, dtype=torch.float64)[None] * 4.0  # L = 2 I: exact
        dq, ok = fused_newton.cholesky_direction(hess, torch.ones(1, 3, dtype=torch.float64))
        assert ok is None and torch.equal(dq, torch.full((1, 3), -0.25, dtype=torch.float64))
    assert timer.calls["cholesky_direction"] == 1
    assert fused_newton.cholesky_direction is original and newton_module.cholesky_direction is original


def test_unknown_section_is_named():
    with pytest.raises(ValueError, match="ImplicitEulerSolver has no callable 'no_such_method'"):
        SectionTimer([("data_gen.sim.solver", "ImplicitEulerSolver", "no_such_method")])
    SectionTimer()  # every default section exists (a renamed method breaks this line, not a profiling session)
    assert DEFAULT_SECTIONS[0] == ("data_gen.sim.world", "Simulator", "run")


def _two_boxes(gravity=(0.0, 0.0, -9.81)) -> Simulator:
    rng = np.random.default_rng(7)
    pts = rng.uniform(-0.05, 0.05, (300, 3))
    specs = [
        SimObjectSpec("soft", pts, 0.001, Material(1e5, 0.3, 1000.0), position_m=(0.0, 0.0, 0.08), num_handles=2,
                      skinning_settings=TINY_TRAINING),
        SimObjectSpec("stiff", pts, 0.001, Material(1e9, 0.3, 1000.0), position_m=(0.02, 0.0, 0.25)),
    ]  # fmt: skip
    preset = load_preset("draft").replace(num_cubature_points=32)
    return Simulator(StaticScene(), specs, gravity, preset, seed=1, num_threads=1)


def test_a_timed_simulation_counts_its_steps_and_records_the_same_bits(tmp_path):
    sim = _two_boxes()
    plain = sim.run(num_frames=6, fps=25.0)
    with SectionTimer() as timer:
        timed = sim.run(num_frames=6, fps=25.0)
    rows = {row.name: row for row in timer.results()}
    steps = 5 * sim.preset.substeps_per_frame  # frames after the first
    assert rows["Simulator.run"].calls == 1 and rows["ImplicitEulerSolver.step"].calls == steps
    assert rows["ImplicitEulerSolver.energies"].calls == 6  # one per recorded frame
    assert rows["ImplicitEulerSolver.step"].seconds <= rows["Simulator.run"].seconds
    assert any(name.startswith("launch:") for name in rows)  # the warp kernels are timed too
    assert ImplicitEulerSolver.__dict__["step"].__name__ == "step" and "__wrapped__" not in vars(
        ImplicitEulerSolver.__dict__["step"]
    )
    assert records_digest(timed) == records_digest(plain)  # the timers change nothing


def test_digest_sees_one_ulp_anywhere():
    result = _two_boxes().run(num_frames=4, fps=25.0)
    reference = records_digest(result)
    assert len(reference) == 64 and records_digest(result) == reference
    track = result.objects[1]
    moved = track.com_m.copy()
    moved[2, 0] = np.nextafter(moved[2, 0], np.inf)  # one unit in the last place of one coordinate
    nudged = dataclasses.replace(result, objects=[result.objects[0], dataclasses.replace(track, com_m=moved)])
    assert records_digest(nudged) != reference
    energies = dict(result.energies_j)
    energies["kinetic"] = energies["kinetic"].copy()
    energies["kinetic"][-1] = np.nextafter(energies["kinetic"][-1], -np.inf)
    assert records_digest(dataclasses.replace(result, energies_j=energies)) != reference
    info = dataclasses.replace(result.info, newton_iterations=result.info.newton_iterations + 1)
    assert records_digest(dataclasses.replace(result, info=info)) != reference
    assert result.collisions  # the soft box lands within the four frames
    assert records_digest(dataclasses.replace(result, collisions=result.collisions[1:])) != reference
    # another run of another scene (gravity halved) records other values
    assert records_digest(_two_boxes((0.0, 0.0, -4.9)).run(num_frames=4, fps=25.0)) != reference
