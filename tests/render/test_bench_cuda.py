"""``bench/bench_cuda.py``, the script a GPU session runs (once per lent GPU, so it must work the first time): its
dry run on the CPU compares the CPU with itself, where every comparison must come out exact (the serial and the
parallel broad-phase grid, the two rasterizer instances, two renders of one sequence, two posers), and its grid
comparison tells a last-bit cell width (reported) from a different grid (failed)."""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[2] / "bench" / "bench_cuda.py"


@pytest.fixture(scope="module")
def bench_cuda():
    sys.path.insert(0, str(BENCH.parent))
    spec = importlib.util.spec_from_file_location("bench_cuda", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules["bench_cuda"] = module  # (its dataclasses look their module up there)
    spec.loader.exec_module(module)
    return module


def _grid(width: float = 0.01) -> dict:
    return {"close": True, "width": width, "lo": np.zeros((2, 3)), "hi": np.ones((2, 3)), "reach": np.ones(2),
            "dims": np.array([[2, 1, 1], [1, 1, 1]]), "first": np.array([0, 2]), "cell_start": np.array([0, 2, 3, 4]),
            "cell_points": np.array([0, 1, 2, 3])}  # fmt: skip


def test_grid_comparison_reports_a_last_bit_width_and_fails_a_different_grid(bench_cuda) -> None:
    a = _grid()
    assert bench_cuda._grid_differences(a, _grid()) == ({}, {})
    shuffled = _grid()
    shuffled["cell_points"] = np.array([1, 0, 2, 3])  # the same cell, another order: the same grid
    assert bench_cuda._grid_differences(a, shuffled) == ({}, {})
    diffs, notes = bench_cuda._grid_differences(a, _grid(0.01 * (1 + 1e-15)))
    assert diffs == {} and set(notes) == {"width"}
    diffs, _ = bench_cuda._grid_differences(a, _grid(0.011))
    assert set(diffs) == {"width"}
    moved = _grid()
    moved["cell_points"] = np.array([0, 2, 1, 3])  # point 2 in the first cell, point 1 in the second
    diffs, _ = bench_cuda._grid_differences(a, moved)
    assert diffs == {"cell_points": "cell 0: [0, 1] vs [0, 2]"}


def test_dry_run_on_the_cpu_is_exact(bench_cuda, tmp_path, monkeypatch) -> None:
    out = tmp_path / "cuda.json"
    monkeypatch.setattr(sys, "argv", ["bench_cuda.py", "--device", "cpu", "--quick", "--profile-solver", "--out", str(out)])
    with pytest.raises(SystemExit) as stop:
        bench_cuda.main()
    assert stop.value.code == 0
    report = json.loads(out.read_text())
    assert report["failures"] == []
    pairs = report["pairs"]
    assert pairs["pairs_compared"] > 1000 and pairs["pair_sets_different"] == 0 and pairs["grids_different"] == 0
    assert pairs["grid_differences"] == []  # the serial and the parallel build: not even a width note
    for row in report["rasterizers"]:
        assert row["index_equal_fraction"] == 1.0 and row["rgb_max_abs_diff"] == 0.0
        assert row["rgb_cpu_pipeline"] == row["rgb_device_pipeline"] == "bands"
    assert set(report["sequences"]) == {"issue", "dataset"}
    for name, seq in report["sequences"].items():
        assert seq["frames"] == 6 and seq["objects"] == 3
        assert set(seq["fps"]) == {"simulate", "simulate_device", "render_device", "simulate_and_render_device",
                                   "render_cpu", "simulate_and_render_cpu"}  # fmt: skip
        # the simulation again with every Newton solve on the device schedule (here the CPU: round-off apart)
        counters = seq["device_solver_counters"]
        assert counters["device_island_solves"] == counters["island_solves"] > 0
        assert counters["device_handed_back"] == 0 and seq["device_solver_com_max_abs_diff_m"] < 1e-9
        timed = seq["device_solver_timings_s"]  # (no graph on the CPU: no capture)
        assert timed["device_capture"] == 0.0 < timed["device_solve"] <= timed["newton"]
        assert all(v > 0 for v in seq["fps"].values())
        assert all(v == 0 for k, v in seq["pose_device_vs_cpu"].items() if k.endswith("diff") or "_diff_" in k)
        assert len(seq["maps_device_vs_cpu"]) == 13
        assert all(row["equal_fraction"] == 1.0 for row in seq["maps_device_vs_cpu"].values()), name
        assert (tmp_path / f"cuda_{name}_frame.png").is_file()
    issue, dataset = report["sequences"]["issue"], report["sequences"]["dataset"]
    assert issue["cubature_points"] == 3 * 64 and issue["image_hw_px"] == [128, 128] and issue["preset"] == "standard"
    assert dataset["image_hw_px"] == [72, 128] and dataset["preset"] == "draft"
    solver = report["solver"]
    assert solver["boxes"] == 3 and set(solver["runs"]) == {"cpu_fused", "device"}
    fused, device = solver["runs"]["cpu_fused"], solver["runs"]["device"]
    # the same physics by both paths (here both on the CPU: round-off apart), every device-path solve its own
    assert device["counters"]["device_island_solves"] == device["counters"]["island_solves"] > 0
    assert fused["counters"]["device_island_solves"] == 0 and device["counters"]["device_handed_back"] == 0
    assert device["newton_iterations"] == fused["newton_iterations"]
    assert solver["final_com_max_abs_diff_m"] < 1e-9
    assert 0.0 < device["timings_s"]["device_solve"] <= device["timings_s"]["newton"]
    # every kernel of the schedule timed, launched directly: the Newton loop's and the sub-steps'
    profile = {row["kernel"]: row for row in solver["kernel_profile"]}
    for kernel in ("pairs_kernel", "scene_kernel", "direction_kernel", "decide_kernel", "substep_spheres_kernel",
                   "substep_pair_forces_kernel", "substep_ready_kernel"):  # fmt: skip
        assert profile[kernel]["launches"] > 0 and profile[kernel]["total_ms"] > 0.0, kernel
    totals = [row["total_ms"] for row in solver["kernel_profile"]]
    assert totals == sorted(totals, reverse=True)
    assert "device_solve" not in fused["timings_s"]
    assert not device["checks"]["tunnelled"] and not fused["checks"]["tunnelled"]


def test_solver_check_fails_a_hand_back_a_tunnelled_box_and_an_error(bench_cuda) -> None:
    ok = {"counters": {"device_handed_back": 0, "device_island_solves": 5}, "checks": {"tunnelled": False},
          "final_com_m": [[0.0, 0.0, 0.05]]}  # fmt: skip
    assert bench_cuda.solver_failures({"runs": {"cpu_fused": ok, "device": ok}}) == []
    handed = {**ok, "counters": {"device_handed_back": 2, "device_island_solves": 3}}
    tunnelled = {**ok, "checks": {"tunnelled": True}}
    nan = {**ok, "final_com_m": [[0.0, float("nan"), 0.05]]}
    assert len(bench_cuda.solver_failures({"runs": {"cpu_fused": ok, "device": handed}})) == 1
    assert len(bench_cuda.solver_failures({"runs": {"cpu_fused": tunnelled, "device": nan}})) == 2
    assert bench_cuda.solver_failures({"runs": {"device": {"error": "step 3: boom"}}}) == ["solver device: step 3: boom"]
