"""Splat renderer speed on CPU: warp rasterizers vs the dense torch reference, in the same run.

Scene: N random Gaussians filling the view of a 60 degree camera at depths
2-6 m, anisotropic, randomly rotated, projected standard deviations of about
0.5-1.5 px per axis ("a few pixels" wide), opacities 0.3-1, seeded.

Measured per (image size, N): wall time (best of ``reps`` after a warm-up)
of the full call — projection, (sort,) rasterization, copy to numpy — for

* warp labels (``LabelRasterizer.render``: index + depth) with 1 and 2 threads,
* all label maps: the same plus one ``gather_labels`` per contract map
  (instances, semantics, materials, collision, gravity, stress, scene flow),
* warp RGB (``RgbRasterizer.render``) with 1 and 2 threads,
* warp RGB with the tile-binned per-pixel pipeline (the CUDA default), run
  on CPU with one thread at 256^2 only, to compare the two CPU strategies.

The dense torch reference costs O(pixels x visible Gaussians); it is run for
real only at a small size (``REFERENCE_SIZE``), where its throughput in
pixel-Gaussian pairs per second is measured, and the time at the large sizes
is *extrapolated* from that throughput (marked ``extrapolated`` in the table
and JSON). The warp path is measured at the small size too, so one ratio is
measured end to end.

    python bench/bench_render.py [--quick]

Writes bench/results/render.json.

``--lighting`` measures instead what one *frame* of a sequence costs at the paper's
1000 x 562: RGB and every label map (``data_gen.pipeline.render_sequence``, skinning
and gathers included) of a simulated ``drop`` scenario on the ``table`` layout
(5 objects), unlit (``render.lighting=false``, the old behaviour), lit without
shadows, and lit with shadows tested per splat and per pixel (the default), with
the ratio to unlit. Seconds per frame = best of ``reps`` renders of the sequence /
its frames, wall and process CPU time (the light view fit included; modes
interleaved in each rep, after one warm-up render of each).

    python bench/bench_render.py --lighting [--quick] [--device cuda]

Writes bench/results/render_lighting.json (render_lighting_<device>.json off CPU) and a
half-size PNG of the last frame in each mode, top to bottom.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch
import warp as wp

from data_gen.gaussians import Gaussians
from data_gen.render.labels import LabelRasterizer, gather_labels
from data_gen.render.projection import project_gaussians
from data_gen.render.reference_torch import render_label_index_torch, render_rgb_torch
from data_gen.render.rgb import RgbRasterizer
from newtphys.geometry import intrinsics_from_fov, look_at

RESULTS = Path(__file__).resolve().parent / "results" / "render.json"
FOV_DEG = 60.0
REFERENCE_SIZE = (64, 4_000)  # image side (px), Gaussians: where the torch reference really runs


def make_scene(n: int, side: int, seed: int) -> tuple[Gaussians, np.ndarray, np.ndarray]:
    """N splats filling the view of a ``side`` x ``side`` camera at the world origin looking along +y."""
    rng = np.random.default_rng(seed)
    K = intrinsics_from_fov(FOV_DEG, side, side)
    w2c = look_at((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))
    depth = rng.uniform(2.0, 6.0, n)
    half = np.tan(np.deg2rad(FOV_DEG / 2))
    x = rng.uniform(-half, half, n) * depth
    y = rng.uniform(-half, half, n) * depth
    means = np.stack([x, depth, -y], axis=1)  # camera x = world x, camera y = -world z
    sigma_px = rng.uniform(0.5, 1.5, (n, 3))
    g = Gaussians(
        means_m=means,
        scales_m=sigma_px * (depth / K[0, 0])[:, None],
        rotations_wxyz=rng.normal(size=(n, 4)),
        colors_rgb=rng.uniform(0.0, 1.0, (n, 3)),
        opacities=rng.uniform(0.3, 1.0, n),
    )
    return g, K, w2c


def per_gaussian_label_values(n: int, seed: int) -> dict[str, np.ndarray]:
    """Per-Gaussian values of the contract's label maps (random; only their dtypes and shapes matter here)."""
    rng = np.random.default_rng(seed)
    return {
        "instances": rng.integers(1, 10, n).astype(np.uint16),
        "semantic_segmentation": rng.integers(1, 30, n).astype(np.uint16),
        "materials": rng.integers(1, 11, n).astype(np.uint8),
        "collision": rng.uniform(size=n) < 0.1,
        "gravity": rng.normal(size=(n, 3)).astype(np.float32),
        "stress": rng.normal(size=n).astype(np.float32),
        "scene_flow": rng.normal(size=(n, 3)).astype(np.float32),
    }


class AllLabels:
    """Index + depth render, then one ``gather_labels`` per label map (the pipeline's work per frame)."""

    def __init__(self, rasterizer: LabelRasterizer, values: dict[str, np.ndarray]) -> None:
        self.rasterizer, self.values = rasterizer, values

    def render(self, g: Gaussians, K: np.ndarray, w2c: np.ndarray) -> dict[str, np.ndarray]:
        index, depth = self.rasterizer.render(g, K, w2c)
        return {"depth": depth, **{k: gather_labels(index, v) for k, v in self.values.items()}}


def best_time(fn: Callable[[], object], reps: int) -> tuple[float, float]:
    """(best wall s, best process CPU s summed over threads) of ``reps`` calls after a warm-up call.

    On a shared machine the CPU time is the steadier number: it is about the
    wall time the call would take alone on one core.
    """
    fn()  # warm-up: kernel load, buffer growth
    walls, cpus = [], []
    for _ in range(reps):
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return min(walls), min(cpus)


def visible_count(g: Gaussians, K: np.ndarray, w2c: np.ndarray, side: int, alpha_min: float) -> int:
    return int(project_gaussians(g, K, w2c, side, side, alpha_min=alpha_min)["visible"].sum())


LIGHTING_MODES: dict[str, dict[str, object]] = {
    "unlit": {"lighting": False},
    "lit, no shadows": {"lighting": True, "shadows": False},
    "lit + shadows (splat test)": {"lighting": True, "shadows": True, "shadow_test": "splat"},
    "lit + shadows (pixel test, default)": {"lighting": True, "shadows": True, "shadow_test": "pixel"},
}


def lighting_main(quick: bool, device: str) -> None:
    """Seconds per frame of RGB + every map at 1000 x 562 before / after lighting (see the module docstring)."""
    import dataclasses

    from data_gen.assets.registry import get_scene_layout
    from data_gen.configs import render_settings, scenario_config
    from data_gen.pipeline import build_objects, render_sequence, simulate
    from data_gen.scenario import sample_scenario
    from data_gen.sim.presets import load_preset

    wp.config.quiet = True
    wp.init()
    load_start = os.getloadavg()
    frames, reps, (h, w) = (2, 1, (281, 500)) if quick else (3, 8, (562, 1000))
    cfg = scenario_config("drop", scenes=("table",), num_objects=(5, 5))
    settings = dataclasses.replace(render_settings(), device=device)
    scenario = sample_scenario(cfg, "bench-light", 7, "train", "earth", frames, 25.0, (h, w))
    layout = get_scene_layout(scenario.scene)
    objects = build_objects(scenario, settings)
    result = simulate(scenario, objects, layout, load_preset("draft"))
    n_gauss = int(sum(len(o.surface) for o in objects))
    runs = {name: dataclasses.replace(settings, **changes) for name, changes in LIGHTING_MODES.items()}
    for run in runs.values():  # warm-up (module loads)
        render_sequence(scenario, objects, layout, result, run)
    wall: dict[str, list[float]] = {name: [] for name in runs}
    cpu: dict[str, list[float]] = {name: [] for name in runs}
    n_maps = 0
    last_rgb: dict[str, np.ndarray] = {}
    for _ in range(reps):  # modes interleaved, so that load changes on the shared machine hit all of them
        for name, run in runs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            maps, _, _ = render_sequence(scenario, objects, layout, result, run)
            wall[name].append((time.perf_counter() - t0) / frames)
            cpu[name].append((time.process_time() - c0) / frames)
            n_maps = len(maps)
            last_rgb[name] = maps["rgb"][-1]
    rows = [{"mode": name, "settings": LIGHTING_MODES[name], "seconds_per_frame": min(wall[name]),
             "cpu_seconds_per_frame": min(cpu[name]), "median_seconds_per_frame": float(np.median(wall[name])),
             "samples_seconds_per_frame": wall[name], "samples_cpu_seconds_per_frame": cpu[name], "maps": n_maps}
            for name in runs]
    base, base_cpu = rows[0]["seconds_per_frame"], rows[0]["cpu_seconds_per_frame"]
    for r in rows:
        r["ratio_to_unlit"] = r["seconds_per_frame"] / base
        r["cpu_ratio_to_unlit"] = r["cpu_seconds_per_frame"] / base_cpu
    print(f"RGB + {rows[0]['maps'] - 1} label maps per frame, {w}x{h}, {device}, table layout + 5 objects "
          f"({n_gauss} object Gaussians, scene spacing {settings.scene_spacing_m} m), shadow map "
          f"{settings.shadow_map_px} px; best of {reps} x {frames} frames")
    print(f"{'mode':<38}{'s / frame':>12}{'x unlit':>10}{'CPU s / frame':>16}{'x unlit':>10}")
    for r in rows:
        print(f"{r['mode']:<38}{r['seconds_per_frame']:>12.3f}{r['ratio_to_unlit']:>10.2f}"
              f"{r['cpu_seconds_per_frame']:>16.3f}{r['cpu_ratio_to_unlit']:>10.2f}")
    out = RESULTS.with_name("render_lighting.json" if device == "cpu" else f"render_lighting_{device}.json")
    meta = {"quick": quick, "device": device, "image_size": [h, w], "frames": frames, "reps": reps,
            "scene": scenario.scene, "objects": len(objects), "object_gaussians": n_gauss,
            "shadow_map_px": settings.shadow_map_px, "cpu_count": os.cpu_count(), "render_threads": settings.num_threads,
            "load_average_at_start": load_start, "load_average_at_end": os.getloadavg(),
            "platform": platform.platform(), "warp": wp.__version__, "torch": torch.__version__,
            "note": "seconds_per_frame: best-of-reps wall time of render_sequence (RGB + every map, skinning and "
                    "label gathers included) / frames; cpu_seconds_per_frame: the same with process CPU time (all "
                    "threads); samples_*: every rep; modes interleaved per rep; the machine is shared, see "
                    "load_average_*."}
    out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    from PIL import Image

    strip = Image.fromarray(np.concatenate([last_rgb[name] for name in runs], axis=0))
    strip.resize((strip.width // 2, strip.height // 2), Image.LANCZOS).save(out.with_suffix(".png"), optimize=True)
    print(f"wrote {out} and {out.with_suffix('.png').name} (last frame of each mode, top to bottom)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="small sizes, fewer repetitions")
    ap.add_argument("--lighting", action="store_true", help="per-frame cost at 1000x562 before/after lighting")
    ap.add_argument("--device", default="cpu", help="warp device of --lighting (cpu | cuda)")
    args = ap.parse_args()
    if args.lighting:
        lighting_main(args.quick, args.device)
        return
    wp.config.quiet = True
    wp.init()
    load_start = os.getloadavg()
    if args.quick:
        configs, reps, ref_side, ref_n = [(128, 10_000), (128, 100_000)], 2, 32, 1_000
    else:
        configs = [(256, 100_000), (256, 1_000_000), (512, 100_000), (512, 1_000_000)]
        reps, (ref_side, ref_n) = 5, REFERENCE_SIZE

    # ---- torch reference at the small size: measured, and its pair throughput ----
    g, K, w2c = make_scene(ref_n, ref_side, seed=0)
    ref = {}
    for task, fn, alpha_min in (
        ("labels", lambda: render_label_index_torch(g, K, w2c, ref_side, ref_side), 0.5),
        ("rgb", lambda: render_rgb_torch(g, K, w2c, ref_side, ref_side), 1 / 255),
    ):
        t, _ = best_time(fn, 1)
        pairs = ref_side * ref_side * visible_count(g, K, w2c, ref_side, alpha_min)
        ref[task] = {"time_s": t, "pairs_per_s": pairs / t}
    small = {
        "labels": best_time(lambda: LabelRasterizer(ref_side, ref_side).render(g, K, w2c), reps),
        "rgb": best_time(lambda: RgbRasterizer(ref_side, ref_side).render(g, K, w2c), reps),
    }

    rows = [
        {"task": task, "side": ref_side, "gaussians": ref_n, "threads": 2, "warp_s": small[task][0],
         "warp_cpu_s": small[task][1], "torch_s": ref[task]["time_s"], "torch_kind": "measured"}
        for task in ("labels", "rgb")
    ]  # fmt: skip
    for side, n in configs:
        g, K, w2c = make_scene(n, side, seed=1)
        renderers = {
            ("labels", 1): LabelRasterizer(side, side, num_threads=1),
            ("labels", 2): LabelRasterizer(side, side, num_threads=2),
            ("rgb", 1): RgbRasterizer(side, side, num_threads=1),
            ("rgb", 2): RgbRasterizer(side, side, num_threads=2),
        }
        values = per_gaussian_label_values(n, seed=2)
        all_labels = AllLabels(LabelRasterizer(side, side, num_threads=2), values)
        renderers[("all-labels", 2)] = all_labels
        if side <= 256 or args.quick:  # the CUDA-default tile pipeline, run on CPU for comparison
            renderers[("rgb-tiles", 1)] = RgbRasterizer(side, side, num_threads=1, pipeline="tiles")
        vis = {"labels": visible_count(g, K, w2c, side, 0.5), "rgb": visible_count(g, K, w2c, side, 1 / 255)}
        for (task, threads), r in renderers.items():
            t, cpu = best_time(lambda r=r, g=g, K=K, w2c=w2c: r.render(g, K, w2c), reps)
            base = "labels" if "labels" in task else task.split("-")[0]
            torch_s = side * side * vis[base] / ref[base]["pairs_per_s"]
            rows.append({"task": task, "side": side, "gaussians": n, "threads": threads, "warp_s": t,
                         "warp_cpu_s": cpu, "torch_s": torch_s, "torch_kind": "extrapolated"})  # fmt: skip

    print(f"load average at start: {load_start[0]:.1f} on {os.cpu_count()} cores")
    print(f"{'task':10s} {'size':>8s} {'N':>9s} {'thr':>3s} {'warp s':>8s} {'warp FPS':>9s} {'cpu s':>7s} "
          f"{'torch s':>11s} {'torch':>12s} {'speedup':>9s}")  # fmt: skip
    for r in rows:
        r["warp_fps"] = 1.0 / r["warp_s"]
        r["speedup_vs_torch"] = r["torch_s"] / r["warp_s"]
        print(
            f"{r['task']:10s} {r['side']:>4d}^2   {r['gaussians']:>9d} {r['threads']:>3d} {r['warp_s']:8.3f} "
            f"{r['warp_fps']:9.2f} {r['warp_cpu_s']:7.3f} {r['torch_s']:11.3f} {r['torch_kind']:>12s} "
            f"{r['speedup_vs_torch']:9.1f}x"
        )
    bands = {
        (r["side"], r["gaussians"]): r["warp_s"] for r in rows if r["task"] == "rgb" and r["threads"] == 1
    }
    for r in rows:
        if r["task"] == "rgb-tiles":
            print(f"rgb {r['side']}^2 N={r['gaussians']}, 1 thread: tile pipeline / band pipeline = "
                  f"{r['warp_s'] / bands[(r['side'], r['gaussians'])]:.1f}x the time")  # fmt: skip
    for task in ("labels", "rgb"):
        one = {
            (r["side"], r["gaussians"]): r["warp_s"] for r in rows if r["task"] == task and r["threads"] == 1
        }
        two = [
            r for r in rows if r["task"] == task and r["threads"] == 2 and (r["side"], r["gaussians"]) in one
        ]
        for r in two:
            print(f"{task} {r['side']}^2 N={r['gaussians']}: 2 threads vs 1: "
                  f"{one[(r['side'], r['gaussians'])] / r['warp_s']:.2f}x")  # fmt: skip

    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    meta = {
        "quick": args.quick,
        "cpu_count": os.cpu_count(),
        "load_average_at_start": load_start,
        "load_average_at_end": os.getloadavg(),
        "platform": platform.platform(),
        "warp": wp.__version__,
        "torch": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "reference": {"side": ref_side, "gaussians": ref_n, **{k: v for k, v in ref.items()}},
        "sched_autogroup_enabled": _read_text("/proc/sys/kernel/sched_autogroup_enabled"),
        "note": "warp_s: best-of-reps wall time; warp_cpu_s: best-of-reps process CPU time (all threads); "
        "torch_s 'extrapolated' = pixels x visible Gaussians / reference pair throughput measured at the "
        "reference size; the machine is shared, see load_average_*. With Linux sched autogroups on, a "
        "busy machine gives each session a fixed CPU share, so extra threads cannot show a speed-up then.",
    }
    RESULTS.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"wrote {RESULTS}")
    plot(rows, RESULTS.with_suffix(".png"))


def _read_text(path: str) -> str | None:
    try:
        return Path(path).read_text().strip()
    except OSError:
        return None


def plot(rows: list[dict], path: Path) -> None:
    """Bar chart of warp frames per second per configuration (log scale)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    big = [r for r in rows if r["torch_kind"] == "extrapolated"]
    labels = [f"{r['task']}\n{r['side']}^2 N={r['gaussians']:.0e}\n{r['threads']} thr" for r in big]
    fig, ax = plt.subplots(figsize=(max(6, 0.9 * len(big)), 4))
    colors = ["C0" if "labels" in r["task"] else "C1" for r in big]
    ax.bar(range(len(big)), [r["warp_fps"] for r in big], color=colors)
    ax.set_xticks(range(len(big)), labels, fontsize=6)
    ax.set_yscale("log")
    ax.set_ylabel("frames per second (CPU, warp)")
    ax.set_title("Gaussian splat renderer on CPU (shared machine; see render.json for load)")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
