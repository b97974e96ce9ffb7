"""The CUDA paths on a GPU: are they right (against the CPU, same inputs), and how many frames per second do they give
(issue 13, item 4).

Run on a machine with a CUDA GPU (the `device` tool's machine); on this 2-core CPU machine ``--device cpu`` runs the
same code against itself (a dry run of the script: every comparison must then be exact).

1. **Broad phase** (``PairFinder``): on the GPU the cell grid is built by parallel launches (atomics and a scan).
   Random clouds of 2-60 objects: the pairs must equal the CPU's, and the grids (boxes, reaches, cell layout, each
   cell's run of points as a set: the scatter's order within a cell is the atomics') must be the same.  Also the time
   of one ``find`` over 50 objects x 256 spheres, CPU single thread against the GPU.
2. **Rasterizers** on random splats (``bench_render.make_scene``): the label index, depth and RGB of the GPU (the
   tile-binned RGB pipeline, its default there) against the CPU's (row bands), and their times per frame.
3. **A whole sequence** at the size the issue names: ``--objects`` 10 objects with ``--cubature`` 1,000 cubature
   points each (10^4), ``--gaussians`` 10^5 surface splats each (10^6 with the floor's), ``--size`` 512^2, a ``pile``
   of the shipped scenario, ``standard`` preset. Simulated once (the solver runs on the CPU: its island kernels run
   one island per thread, the wrong shape for a GPU, and its torch model lives on the CPU), then rendered (RGB lit
   with shadows and all 11 label maps, ``data_gen.pipeline.render_sequence``) with ``render.device`` the GPU and
   again the CPU (``num_threads`` = the machine's cores): every contract map compared, and frames per second of
   simulation, of rendering on each device and of the two together.

4. **The solver's one-handle islands on the device** (``DeviceNewton``, ``Simulator(device_newton=True)``): the
   ``bench_peers`` pile of ``--solver-boxes`` stiff boxes (10; 3 with ``--quick``), 1 s at 25 FPS, ``standard``,
   simulated by the fused kernel on the CPU and by the thread-per-element schedule on the device (the model and
   each step's data copied there, one CUDA graph per solve, the state back once per solve). Times, frames per
   second, counters, the piles' checks (no tunnelling, resting heights), and how far the final centres differ (a
   toppling pile amplifies round-off: the CPU's own paths differ by centimetres after 1 s, see
   ``docs/sim_speed_history.md``). Fails where the device hands a solve back, a box tunnels, or a value is
   not finite.

5. **A dataset sequence** (``--sequences dataset``): what a generation run renders by default at the paper's 1000 x 562
   (5 objects dropped on the ``table`` layout, ``draft``, ``generate.yaml``'s 3,000 splats per object), the same
   comparisons and times: whether a GPU pays for the data researchers generate.

Prints a table and writes ``cuda.json`` (``--out``, default ``bench/results/cuda.json``) and per sequence
``cuda_<name>_frame.png`` (the last frame's RGB, GPU above CPU); ``--profile-render`` adds
``cuda_<name>_render_profile.txt`` (one more GPU render under cProfile: the host work around the kernels, which
bounded the GPU render in the first run).

    python bench/bench_cuda.py                         # on a GPU machine: everything, full size
    python bench/bench_cuda.py --device cpu --quick    # here: a dry run at small sizes
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import platform
import sys
import time
from pathlib import Path

import numpy as np
import torch
import warp as wp

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_render import make_scene  # noqa: E402

from data_gen.configs import render_settings, scenario_config  # noqa: E402
from data_gen.pipeline import (  # noqa: E402
    SequenceRejected,
    build_objects,
    get_scene_layout,
    render_sequence,
    simulate,
    skinned_surfaces,
)
from data_gen.render.labels import LabelRasterizer  # noqa: E402
from data_gen.render.rgb import RgbRasterizer  # noqa: E402
from data_gen.scenario import sample_scenario  # noqa: E402
from data_gen.sim import KERNEL_MODULES  # noqa: E402
from data_gen.sim.contact import PairFinder  # noqa: E402
from data_gen.sim.presets import load_preset  # noqa: E402
from data_gen.sim.threads import torch_threads  # noqa: E402
from data_gen.sim.tile_cholesky import THREADS  # noqa: E402
from data_gen.sim.world import SimulationError  # noqa: E402
from newtphys import schema  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
WIDTH_RTOL = 1e-12
"""Relative difference of the GPU's broad-phase cell width from the CPU's that is reported, not failed (see
:func:`_grid_differences`)."""

POSE_TOLERANCE = {"centre_max_abs_diff_m": 1e-9, "covariance_max_rel_diff": 1e-9, "normal_max_abs_diff": 1e-5}
"""Largest differences of the device's splat poses from the CPU's that pass (float64 rounding gives ~1e-15; the
normals are float32): a sequence whose poses differ more is a failure (:func:`_compare_poses`)."""


def _sync(device: str) -> None:
    wp.synchronize_device(device)


def _timed(fn, device: str, reps: int) -> tuple[float, object]:
    """(median wall s of ``reps`` calls after one untimed call, the last result); the device is synchronised
    around each call (the results are read back to numpy by the calls themselves)."""
    out = fn()
    times = []
    for _ in range(reps):
        _sync(device)
        t0 = time.perf_counter()
        out = fn()
        _sync(device)
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


# --------------------------------------------------------------------------------------------- the solver
def check_solver(device: str, boxes: int) -> dict:
    """The ``bench_peers`` pile of ``boxes`` stiff boxes, 1 s: the fused kernel on the CPU against
    :class:`~data_gen.sim.device_newton.DeviceNewton` on ``device`` (each run once untimed first: kernel loading
    and compilation)."""
    import bench_peers

    scene = bench_peers.PeerScene(f"stiff_{boxes}", boxes, 1e9, "standard")
    runs = {}
    for name, kwargs in (("cpu_fused", {}), ("device", {"device": device, "device_newton": True})):
        try:
            bench_peers.run_newtphys(scene, **kwargs)
            row = bench_peers.run_newtphys(scene, **kwargs)
        except SimulationError as err:  # (a non-finite value names its object)
            runs[name] = {"error": str(err)}
            continue
        com = np.asarray(row["final_com_m"])
        frames = int(round(bench_peers.DURATION_S * bench_peers.FPS)) + 1
        runs[name] = {"wall_s": row["wall_s"], "cpu_s": row["cpu_s"], "fps": frames / row["wall_s"],
                      "newton_iterations": row["newton_iterations"], "counters": row["counters"],
                      "timings_s": {k: float(v) for k, v in row["timings_s"].items()},
                      "checks": bench_peers.pile_checks(com), "final_com_m": com.tolist()}  # fmt: skip
    out = {"boxes": boxes, "runs": runs}
    if all("error" not in r for r in runs.values()):
        a, b = (np.asarray(runs[k]["final_com_m"]) for k in ("cpu_fused", "device"))
        out["final_com_max_abs_diff_m"] = float(np.abs(a - b).max())
    return out


def profile_device_solver(device: str, boxes: int) -> list[dict]:
    """The ``bench_peers`` pile of ``boxes`` stiff boxes, 1 s, with its Newton solves on ``device``'s schedule
    launched directly (no graph: a graph's kernels cannot be timed one by one), every kernel timed: on CUDA its
    device time (warp's CUDA activity timing), on the CPU the launch's wall time. Rows by total time: kernel,
    launches, total ms, µs per launch. What dominates a GPU's Newton iteration, measured rather than guessed."""
    import bench_peers
    from data_gen.sim.device_newton import DeviceNewton

    scene = bench_peers.PeerScene(f"stiff_{boxes}", boxes, 1e9, "standard")
    bench_peers.run_newtphys(scene, device=device, device_newton=True)  # (kernels loaded)
    totals: dict[str, list[float]] = {}
    previous, DeviceNewton.default_graph = DeviceNewton.default_graph, False
    launch = wp.launch
    try:
        if wp.get_device(device).is_cuda:
            wp.timing_begin(cuda_filter=wp.TIMING_KERNEL)
            bench_peers.run_newtphys(scene, device=device, device_newton=True)
            for r in wp.timing_end():
                row = totals.setdefault(r.name, [0, 0.0])
                row[0] += 1
                row[1] += r.elapsed * 1e-3
        else:
            def timed(kernel, *args, **kwargs):
                t0 = time.perf_counter()
                out = launch(kernel, *args, **kwargs)
                row = totals.setdefault(kernel.key, [0, 0.0])
                row[0] += 1
                row[1] += time.perf_counter() - t0
                return out

            wp.launch = timed
            bench_peers.run_newtphys(scene, device=device, device_newton=True)
    finally:
        wp.launch = launch
        DeviceNewton.default_graph = previous
    rows = [{"kernel": k, "launches": n, "total_ms": 1e3 * t, "us_per_launch": 1e6 * t / n}
            for k, (n, t) in totals.items()]  # fmt: skip
    return sorted(rows, key=lambda r: -r["total_ms"])


def _solve_seconds(timings_s: dict) -> str:
    """The Newton solves' seconds, and where a device schedule ran, its part and its captures' part of that."""
    out = f"; Newton {timings_s.get('newton', 0.0):.2f} s"
    if timings_s.get("device_solve"):
        out += (f" (device schedule {timings_s['device_solve']:.2f} s, of which graph captures "
                f"{timings_s.get('device_capture', 0.0):.2f} s)")
    return out


def solver_failures(solver: dict) -> list[str]:
    """What fails the solver check: an error, a hand-back to ``minimise``, a tunnelled box, a non-finite centre."""
    out = []
    for name, run in solver["runs"].items():
        if "error" in run:
            out.append(f"solver {name}: {run['error']}")
            continue
        if run["checks"]["tunnelled"] or not np.all(np.isfinite(run["final_com_m"])):
            out.append(f"solver {name}: tunnelled or not finite")
        if name == "device" and (run["counters"]["device_handed_back"] or not run["counters"]["device_island_solves"]):
            out.append(f"solver {name}: solves handed back or none on the device")
    return out


# --------------------------------------------------------------------------------------------- 1. broad phase
def _cloud(rng: np.random.Generator, num_objects: int, spheres: int) -> tuple[np.ndarray, ...]:
    """Objects of ``spheres`` contact spheres (radius 4-12 mm) in 10 cm blobs packed so that neighbours touch."""
    side = int(np.ceil(num_objects ** (1 / 3)))
    centres = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:num_objects] * 0.17
    points = np.concatenate([c + rng.normal(0.0, 0.05, (spheres, 3)) for c in centres])
    ids = np.repeat(np.arange(num_objects) * 3 + 1, spheres)  # sparse ids, as a scene's object ids may be
    radii = rng.uniform(0.004, 0.012, len(points))
    margins = rng.uniform(0.0, 0.004, len(points))
    return points, ids, radii, margins


def _grid_differences(a: dict, b: dict) -> tuple[dict[str, str], dict[str, str]]:
    """(differences, notes) between two grids. Differences: a box, reach, layout or cell that is not the same (each
    cell's points compared as a set: the GPU's scatter orders a cell by its atomics). Notes: a cell width that
    differs by at most ``WIDTH_RTOL`` (the widening takes a cube root, ``wp.pow``, whose last bit differs between
    the CPU's libm and CUDA's; the search's test is exact, so the pairs stay the same)."""
    out, notes = {}, {}
    for key in ("close", "width", "lo", "hi", "reach", "dims", "first", "cell_start"):
        x, y = np.asarray(a[key]), np.asarray(b[key])
        if x.shape != y.shape:
            out[key] = f"shapes {x.shape} vs {y.shape}"
        elif not np.array_equal(x, y):
            diff = np.abs(x.astype(np.float64) - y.astype(np.float64)).max()
            text = f"max |diff| {diff:.3g} at {np.argwhere(x != y)[0].tolist()}"
            if key == "width" and diff <= WIDTH_RTOL * abs(float(x)):
                notes[key] = text
            else:
                out[key] = text
    if not out:
        starts, pa, pb = a["cell_start"], a["cell_points"], b["cell_points"]
        for cell, (s, e) in enumerate(zip(starts[:-1], starts[1:])):
            if not np.array_equal(np.sort(pa[s:e]), np.sort(pb[s:e])):
                out["cell_points"] = f"cell {cell}: {np.sort(pa[s:e]).tolist()} vs {np.sort(pb[s:e]).tolist()}"
                break
    return out, notes


def check_pairs(device: str, quick: bool) -> dict:
    rng = np.random.default_rng(0)
    cpu, other = PairFinder("cpu"), PairFinder(device, parallel_grid=True)  # (the default off the CPU)
    trials, mismatched_pairs, mismatched_grids, total_pairs, grid_notes = 0, 0, 0, 0, []
    for num_objects in (2, 5, 10, 27, 60):
        for spheres in (16, 128) if quick else (16, 128, 512):
            points, ids, radii, margins = _cloud(rng, num_objects, spheres)
            margin = float(rng.uniform(0.0, 0.01))
            want = cpu.find(points, ids, radii, margin, margins)
            got = other.find(points, ids, radii, margin, margins)
            trials += 1
            total_pairs += len(want)
            mismatched_pairs += int(not np.array_equal(want, got))
            width = 0.25 * (2 * radii.max() + margin + 2 * margins.max())
            grid_a = cpu.build_cells(points, ids, radii, margin, width, margins)
            grid_b = other.build_cells(points, ids, radii, margin, width, margins)
            diffs, notes = _grid_differences(grid_a, grid_b)
            mismatched_grids += int(bool(diffs))
            if diffs or notes:
                grid_notes.append({"objects": num_objects, "spheres": spheres, "width0_m": width, "differences": diffs,
                                   "notes": notes})  # fmt: skip
    # time: a 50-box pile's spheres (256 each), the solver's call every step
    points, ids, radii, margins = _cloud(rng, 50, 256)
    t_cpu, _ = _timed(lambda: cpu.find(points, ids, radii, 0.005, margins), "cpu", 5 if quick else 20)
    t_dev, _ = _timed(lambda: other.find(points, ids, radii, 0.005, margins), device, 5 if quick else 20)
    return {"trials": trials, "pairs_compared": total_pairs, "pair_sets_different": mismatched_pairs,
            "grids_different": mismatched_grids, "grid_differences": grid_notes, "find_50x256_cpu_ms": 1e3 * t_cpu,
            "find_50x256_device_ms": 1e3 * t_dev}  # fmt: skip


# --------------------------------------------------------------------------------------------- 2. rasterizers
def check_rasterizers(device: str, quick: bool) -> list[dict]:
    rows = []
    threads = os.cpu_count() or 1
    for side, n in ((128, 20_000),) if quick else ((256, 100_000), (512, 1_000_000)):
        g, K, w2c = make_scene(n, side, seed=side)
        out = {"side_px": side, "gaussians": n}
        results = {}
        for key, dev in (("cpu", "cpu"), ("device", device)):
            lab = LabelRasterizer(side, side, dev, threads)
            rgb = RgbRasterizer(side, side, dev, threads)
            t_lab, (index, depth) = _timed(lambda lab=lab: lab.render(g, K, w2c), dev, 3 if quick else 10)
            t_rgb, (colour, alpha) = _timed(lambda rgb=rgb: rgb.render(g, K, w2c), dev, 3 if quick else 10)
            results[key] = (index, depth, colour, alpha)
            out[f"labels_{key}_ms"], out[f"rgb_{key}_ms"] = 1e3 * t_lab, 1e3 * t_rgb
            out[f"rgb_{key}_pipeline"] = rgb.pipeline
        (i0, d0, c0, a0), (i1, d1, c1, a1) = results["cpu"], results["device"]
        same = i0 == i1
        out["index_equal_fraction"] = float(same.mean())
        out["depth_max_abs_diff_m_where_index_equal"] = float(np.abs(d0 - d1)[same].max(initial=0.0))
        out["rgb_max_abs_diff"] = float(np.abs(c0 - c1).max())
        out["rgb_mean_abs_diff"] = float(np.abs(c0 - c1).mean())
        out["alpha_max_abs_diff"] = float(np.abs(a0 - a1).max())
        rows.append(out)
    return rows


# --------------------------------------------------------------------------------------------- 3. a sequence
def _compare_maps(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> dict[str, dict]:
    """Per contract map: the fraction of equal entries, and for float maps the largest absolute difference."""
    out = {}
    for name in schema.MAPS:
        x, y = a[name], b[name]
        row = {"equal_fraction": float((x == y).mean())}
        if x.dtype.kind == "f":
            diff = np.abs(x.astype(np.float64) - y.astype(np.float64))
            row["max_abs_diff"] = float(diff.max(initial=0.0))
            row["p99_abs_diff"] = float(np.quantile(diff, 0.99)) if diff.size else 0.0
        elif name == schema.RGB:
            diff = np.abs(x.astype(np.int16) - y.astype(np.int16))
            row["max_abs_diff"] = int(diff.max(initial=0))
            row["mean_abs_diff"] = float(diff.mean())
        out[name] = row
    return out


@dataclasses.dataclass(frozen=True)
class SequenceSpec:
    """One timed sequence: the scenario drawn, its size and the simulation preset."""

    name: str
    scenario: str
    scene: str
    objects: int
    image_hw: tuple[int, int]
    frames: int
    preset: str
    cubature: int | None = None
    """Cubature points per object (None: the preset's)."""
    gaussians: int | None = None
    """Surface splats per object (None: ``generate.yaml``'s)."""


def sequence_specs(args: argparse.Namespace) -> list[SequenceSpec]:
    """``issue``: the issue's size (``--objects``, ``--cubature``, ``--gaussians``, ``--size``); ``dataset``: what a
    generation run renders by default at the paper's resolution (5 objects dropped on the table, ``draft``,
    ``generate.yaml``'s splats; 1000 x 562, 128 x 72 with ``--quick``)."""
    specs = {
        "issue": SequenceSpec("issue", "pile", "empty_floor", args.objects, (args.size, args.size), args.frames,
                              "standard", args.cubature, args.gaussians),  # fmt: skip
        "dataset": SequenceSpec("dataset", "drop", "table", 3 if args.quick else 5,
                                (72, 128) if args.quick else (562, 1000), args.frames, "draft"),  # fmt: skip
    }
    return [specs[name] for name in args.sequences]


def run_sequence(device: str, spec: SequenceSpec, args: argparse.Namespace) -> tuple[dict, dict[str, np.ndarray]]:
    threads = os.cpu_count() or 1
    cfg = scenario_config(spec.scenario, scenes=(spec.scene,), num_objects=(spec.objects, spec.objects))
    preset = load_preset(spec.preset)
    if spec.cubature is not None:
        preset = dataclasses.replace(preset, num_cubature_points=spec.cubature)
    base: dict = dict(num_threads=threads)
    if spec.gaussians is not None:
        base["object_gaussians"] = spec.gaussians
    if spec.cubature is not None:
        base["interior_points"] = 2 * spec.cubature
    settings = {"cpu": render_settings(device="cpu", **base), "device": render_settings(device=device, **base)}
    scenario = sample_scenario(cfg, f"cuda-bench-{spec.name}", 1000, "train", "earth", spec.frames, 25.0,
                               spec.image_hw)  # fmt: skip
    layout = get_scene_layout(scenario.scene)
    objects = build_objects(scenario, settings["cpu"])
    t0 = time.perf_counter()
    for name in KERNEL_MODULES:  # the solver's kernels run on the CPU
        wp.load_module(importlib.import_module(name), device="cpu")
    kernel_load_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    result = simulate(scenario, objects, layout, preset, training_threads=threads)
    sim_s = time.perf_counter() - t0
    setup_s = float(result.info.timings_s["setup"])
    out = {"scenario": f"{spec.scenario} on {spec.scene}", "preset": spec.preset, "objects": len(objects),
           "frames": spec.frames, "image_hw_px": list(spec.image_hw),
           "cubature_points": int(sum(len(t.points_rest_m) for t in result.objects)),
           "splats": int(sum(len(o.surface) for o in objects)),  # objects' surface splats (+ the floor's, below)
           "handles": [int(t.num_handles) for t in result.objects],
           "newton_iterations": int(result.info.newton_iterations),
           "kernel_load_s": kernel_load_s, "simulate_s": sim_s, "simulate_setup_s": setup_s}  # fmt: skip
    if not args.no_device_solver:  # the same simulation with its Newton solves on the device (DeviceNewton)
        t0 = time.perf_counter()
        for name in ("data_gen.sim.device_newton", "data_gen.sim.tile_cholesky"):
            wp.load_module(importlib.import_module(name), device=device)
        # and the factorisation's variant (blocks of THREADS threads: warp compiles a module once per block size)
        wp.load_module(importlib.import_module("data_gen.sim.tile_cholesky"), device=device, block_dim=THREADS)
        out["device_kernel_load_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        try:
            on_device = simulate(scenario, objects, layout, preset, training_threads=threads, device=device,
                                 device_newton=True)  # fmt: skip
        except SequenceRejected as err:  # (the checks of generate's own rejection: reported, a failure)
            on_device = None
            out["device_solver_error"] = f"{err.reason}: {err}"
    if not args.no_device_solver and on_device is not None:
        out["simulate_device_s"] = time.perf_counter() - t0
        out["simulate_device_setup_s"] = float(on_device.info.timings_s["setup"])
        out["device_solver_counters"] = {k: int(on_device.info.counters[k]) for k in
                                         ("island_solves", "device_island_solves", "device_handed_back",
                                          "unconverged_solves")}  # fmt: skip
        # the Newton solves' wall time, the device schedule's part of it and its graphs' captures
        out["device_solver_timings_s"] = {k: float(on_device.info.timings_s.get(k, 0.0)) for k in
                                          ("newton", "device_solve", "device_capture", "broad_phase")}  # fmt: skip
        com = [np.abs(a.com_m - b.com_m).max() for a, b in zip(result.objects, on_device.objects)]
        out["device_solver_com_max_abs_diff_m"] = float(max(com))
    out["pose_device_vs_cpu"] = _compare_poses(objects, result, device)
    maps = {}
    for key, dev in (("device", device), ("cpu", "cpu"))[: 1 if args.no_cpu_render else 2]:
        times = []
        for rep in range(2 if key == "device" else 1):  # the first GPU render loads its kernels: the second is timed
            _sync(dev)
            t1 = time.perf_counter()
            with torch_threads(1):  # as generate_sequence renders
                skinned = skinned_surfaces(objects, result, dev, settings[key].num_threads)
                maps[key], _, _ = render_sequence(scenario, objects, layout, result, settings[key], skinned)
            _sync(dev)
            times.append(time.perf_counter() - t1)
        out[f"render_{key}_s"] = times[-1]
        if len(times) > 1:
            out[f"render_{key}_first_s"] = times[0]
    if args.profile_render:  # one more device render under cProfile: where the host time around the kernels goes
        import cProfile
        import io
        import pstats

        profile = cProfile.Profile()
        with torch_threads(1):
            profile.enable()
            render_sequence(scenario, objects, layout, result, settings["device"],
                            skinned_surfaces(objects, result, device, settings["device"].num_threads))  # fmt: skip
            profile.disable()
        text = io.StringIO()
        pstats.Stats(profile, stream=text).sort_stats("tottime").print_stats(30)
        pstats.Stats(profile, stream=text).sort_stats("cumulative").print_stats(30)
        args.out.with_name(f"{args.out.stem}_{spec.name}_render_profile.txt").write_text(text.getvalue())
    frames = spec.frames
    sim_run = sim_s - setup_s
    out["fps"] = {"simulate": frames / sim_run}
    if "simulate_device_s" in out:
        out["fps"]["simulate_device"] = frames / (out["simulate_device_s"] - out["simulate_device_setup_s"])
    for key in maps:
        out["fps"][f"render_{key}"] = frames / out[f"render_{key}_s"]
        out["fps"][f"simulate_and_render_{key}"] = frames / (sim_run + out[f"render_{key}_s"])
    if "cpu" in maps:
        out["maps_device_vs_cpu"] = _compare_maps(maps["device"], maps["cpu"])
    return out, maps


def _compare_poses(objects: list, result, device: str) -> dict:
    """The splat poser on ``device`` against the CPU's, for the most deformable object at the last frame: largest
    differences of centres (m), covariances (relative to the largest entry) and normals."""
    from data_gen.pipeline import SkinnedSurface
    from newtphys.rotations import quat_to_matrix

    tracks = {t.object_id: t for t in result.objects}
    o = max(objects, key=lambda o: tracks[o.object_id].num_handles)
    frame = len(tracks[o.object_id].handle_transforms) - 1
    poses = [SkinnedSurface(o.surface, tracks[o.object_id], dev).pose(frame) for dev in ("cpu", device)]

    def cov(scales, quats):
        r = quat_to_matrix(quats)
        return np.einsum("nij,nj,nkj->nik", r, scales**2, r)

    (x0, s0, q0, n0), (x1, s1, q1, n1) = poses
    c0, c1 = cov(s0, q0), cov(s1, q1)
    return {"object_handles": int(tracks[o.object_id].num_handles), "splats": len(x0),
            "centre_max_abs_diff_m": float(np.abs(x0 - x1).max()),
            "covariance_max_rel_diff": float(np.abs(c0 - c1).max() / np.abs(c0).max()),
            "normal_max_abs_diff": float(np.abs(n0 - n1).max())}  # fmt: skip


def _save_frame(maps: dict, path: Path) -> None:
    import imageio.v3 as iio

    top, bottom = maps["device"][schema.RGB][-1], maps["cpu"][schema.RGB][-1]
    iio.imwrite(path, np.concatenate([top, bottom], axis=0))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", default="cuda", help="the device checked against the CPU (cuda, cuda:0, cpu)")
    ap.add_argument("--quick", action="store_true", help="small sizes (a dry run)")
    ap.add_argument("--objects", type=int, default=None)
    ap.add_argument("--cubature", type=int, default=None, help="cubature points per object")
    ap.add_argument("--gaussians", type=int, default=None, help="surface splats per object")
    ap.add_argument("--size", type=int, default=None, help="image side, px")
    ap.add_argument("--frames", type=int, default=None)
    ap.add_argument("--skip", nargs="*", default=[], choices=["pairs", "raster", "solver", "sequence"])
    ap.add_argument("--solver-boxes", type=int, default=None, help="stiff boxes of the solver check's pile")
    ap.add_argument("--sequences", nargs="+", default=["issue", "dataset"], choices=["issue", "dataset"],
                    help="issue: the issue's 10-object / 10^6-splat / 512^2 sequence; dataset: a generation run's "
                    "default sequence at 1000 x 562")  # fmt: skip
    ap.add_argument("--profile-solver", action="store_true", help="the solver check's pile once more with the "
                    "device schedule launched directly, every kernel timed (printed and in the JSON)")
    ap.add_argument("--profile-render", action="store_true", help="one more device render under cProfile, written "
                    "to <out>_render_profile.txt")  # fmt: skip
    ap.add_argument("--no-device-solver", action="store_true", help="do not simulate the sequences again with the "
                    "Newton solves on the device (Simulator(device_newton=True))")
    ap.add_argument("--no-cpu-render", action="store_true", help="render the sequence on the device only (no maps "
                    "compared; the poses still are)")  # fmt: skip
    ap.add_argument("--out", type=Path, default=ROOT / "bench" / "results" / "cuda.json")
    args = ap.parse_args()
    quick = dict(objects=3, cubature=64, gaussians=5_000, size=128, frames=6, solver_boxes=3)
    full = dict(objects=10, cubature=1000, gaussians=100_000, size=512, frames=25, solver_boxes=10)
    for k, v in (quick if args.quick else full).items():
        if getattr(args, k) is None:
            setattr(args, k, v)
    wp.init()
    device = args.device
    dev = wp.get_device(device)
    report = {"device": device, "device_name": dev.name if dev.is_cpu else f"{dev.name} (sm_{dev.arch})",
              "cpu": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
              "warp": wp.config.version, "torch": torch.__version__, "numpy": np.__version__,
              "args": {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}}  # fmt: skip
    print(f"device {report['device_name']}, {report['cpu_count']} CPU cores ({report['cpu']}), warp "
          f"{report['warp']}, torch {report['torch']}", flush=True)  # fmt: skip
    args.out.parent.mkdir(parents=True, exist_ok=True)

    def save() -> None:
        args.out.write_text(json.dumps(report, indent=1))

    failures = []
    if "pairs" not in args.skip:
        t = time.perf_counter()
        report["pairs"] = p = check_pairs(device, args.quick)
        save()
        print(f"[pairs] {p['trials']} clouds, {p['pairs_compared']} pairs: pair sets different "
              f"{p['pair_sets_different']}, grids different {p['grids_different']}; find 50x256: CPU "
              f"{p['find_50x256_cpu_ms']:.2f} ms, {device} {p['find_50x256_device_ms']:.2f} ms "
              f"({time.perf_counter() - t:.0f} s)", flush=True)  # fmt: skip
        if p["pair_sets_different"] or p["grids_different"]:
            failures.append("pairs")
    if "raster" not in args.skip:
        t = time.perf_counter()
        report["rasterizers"] = rows = check_rasterizers(device, args.quick)
        save()
        for r in rows:
            print(f"[raster] {r['side_px']}^2, {r['gaussians']} splats: labels CPU {r['labels_cpu_ms']:.1f} ms, "
                  f"{device} {r['labels_device_ms']:.1f} ms; RGB CPU ({r['rgb_cpu_pipeline']}) {r['rgb_cpu_ms']:.1f} "
                  f"ms, {device} ({r['rgb_device_pipeline']}) {r['rgb_device_ms']:.1f} ms; index equal "
                  f"{r['index_equal_fraction']:.6f}, depth diff {r['depth_max_abs_diff_m_where_index_equal']:.2e} m, "
                  f"RGB max diff {r['rgb_max_abs_diff']:.2e} (mean {r['rgb_mean_abs_diff']:.2e})",
                  flush=True)  # fmt: skip
        print(f"[raster] ({time.perf_counter() - t:.0f} s)", flush=True)
    if "solver" not in args.skip:
        t = time.perf_counter()
        report["solver"] = sol = check_solver(device, args.solver_boxes)
        save()
        for name, run in sol["runs"].items():
            if "error" in run:
                print(f"[solver] {name}: {run['error']}", flush=True)
                continue
            c = run["counters"]
            print(f"[solver] {name}: {sol['boxes']} stiff boxes, 1 s: {run['wall_s']:.2f} s wall ({run['fps']:.1f} FPS), "
                  f"{run['newton_iterations']} Newton iterations, island solves {c['island_solves']} (device "
                  f"{c['device_island_solves']}, handed back {c['device_handed_back']}), tunnelled "
                  f"{run['checks']['tunnelled']}" + _solve_seconds(run["timings_s"]), flush=True)  # fmt: skip
        if "final_com_max_abs_diff_m" in sol:
            print(f"[solver] final centres differ by at most {sol['final_com_max_abs_diff_m']:.3g} m "
                  f"({time.perf_counter() - t:.0f} s)", flush=True)  # fmt: skip
        failures += solver_failures(sol)
        if args.profile_solver:
            sol["kernel_profile"] = profile = profile_device_solver(device, args.solver_boxes)
            save()
            total = sum(r["total_ms"] for r in profile) or 1.0
            print(f"[solver] the device schedule's kernels, launched directly ({'device' if 'cuda' in device else 'wall'}"
                  " time):", flush=True)  # fmt: skip
            for r in profile[:16]:
                print(f"[solver]   {r['kernel'][:60]:60s} {r['total_ms']:9.1f} ms {100 * r['total_ms'] / total:5.1f} % "
                      f"{r['launches']:7d} launches {r['us_per_launch']:9.1f} us each", flush=True)  # fmt: skip
    if "sequence" not in args.skip:
        report["sequences"] = {}
        for spec in sequence_specs(args):
            seq, maps = run_sequence(device, spec, args)
            report["sequences"][spec.name] = seq
            save()
            if "cpu" in maps:
                _save_frame(maps, args.out.with_name(f"{args.out.stem}_{spec.name}_frame.png"))
            h, w = spec.image_hw
            print(f"[{spec.name}] {seq['scenario']}, {seq['objects']} objects, {seq['cubature_points']} cubature "
                  f"points, {seq['splats']} object splats, {w}x{h}, {seq['frames']} frames, {spec.preset}: solver "
                  f"kernels loaded in {seq['kernel_load_s']:.1f} s, simulate {seq['simulate_s']:.1f} s (set-up "
                  f"{seq['simulate_setup_s']:.1f} s), render {device} {seq['render_device_s']:.2f} s (first "
                  f"{seq.get('render_device_first_s', float('nan')):.2f} s), render CPU "
                  f"{seq.get('render_cpu_s', float('nan')):.2f} s", flush=True)  # fmt: skip
            print(f"[{spec.name}] FPS: " + ", ".join(f"{k} {v:.2f}" for k, v in seq["fps"].items()), flush=True)
            if "device_solver_error" in seq:
                print(f"[{spec.name}] device solver: {seq['device_solver_error']}", flush=True)
                failures.append(f"{spec.name} device solver")
            elif "device_solver_counters" in seq:
                print(f"[{spec.name}] device solver: kernels loaded in {seq['device_kernel_load_s']:.1f} s, simulate "
                      f"{seq['simulate_device_s']:.1f} s, " + ", ".join(f"{k} {v}" for k, v in
                      seq["device_solver_counters"].items()) + f", centres differ from the CPU's by at most "
                      f"{seq['device_solver_com_max_abs_diff_m']:.3g} m" + _solve_seconds(seq["device_solver_timings_s"]),
                      flush=True)  # fmt: skip
                if seq["device_solver_counters"]["device_handed_back"]:
                    failures.append(f"{spec.name} device solver handed back")
            print(f"[{spec.name}] pose: " + ", ".join(f"{k} {v:.3g}" for k, v in seq["pose_device_vs_cpu"].items()),
                  flush=True)  # fmt: skip
            if any(seq["pose_device_vs_cpu"][k] > tol for k, tol in POSE_TOLERANCE.items()):
                failures.append(f"{spec.name} poses")
            for name, row in seq.get("maps_device_vs_cpu", {}).items():
                print(f"[{spec.name}] {name:<30}" + ", ".join(f"{k} {v:.3g}" for k, v in row.items()), flush=True)
    report["failures"] = failures
    save()
    print(f"wrote {args.out}; failures: {failures or 'none'}")
    sys.exit(1 if failures else 0)


if __name__ == "__main__":
    main()
