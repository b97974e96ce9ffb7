"""Frozen-backbone feature extraction throughput (frames/s), every backbone, same run.

Each backbone is built with pretrained=false (random weights: the same
architecture and cost as the pretrained model) at its default resolution and
its default taps, and ``features()`` is timed on random frames of that size
(so no resize is timed) after one warm-up call. The baseline is ``vit_tiny``
(ViT-Ti/16 at 224 px) measured in the same run; the table reports each
backbone's frames/s and its cost relative to the baseline
(``baseline frames/s / frames/s``) and in CPU seconds per frame. The baseline is re-timed right before
each backbone and the ratio uses that adjacent measurement, so a machine
whose load drifts during the run (shared CI boxes) still gives fair ratios.
Also reported: process CPU seconds per frame (robust to other processes
competing for the cores), parameters, build time, the 1-minute load average
and the fp16 size of one frame's features (what the feature cache stores).
AM-RADIO is listed as skipped: it has no random-weight build (see
probes/backbones/radio.py).

    python bench/bench_backbones.py [--quick] [--device cpu|cuda] [--names dino sam ...]

Writes bench/results/backbones.json (backbones_<device>.json for other devices) and a PNG bar plot.
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from probes.backbones import BACKBONE_NAMES, Backbone, build_backbone, get_spec

BASELINE = "vit_tiny"
QUICK = ("vit_tiny", "dino", "dinov2")
# default batch per family on CPU (frames per features() call); GPU uses 4x
BATCH = {"timm_vit": 8, "timm_sam": 1, "dpt": 2, "stable_diffusion": 1}
NO_RANDOM_BUILD = {"radio": "no pretrained=false build (AM-RADIO needs its remote code)"}


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def _time_features(
    bb: Backbone, frames: torch.Tensor, repeats: int, device: torch.device
) -> tuple[float, float]:
    """(wall s, process CPU s) per ``features()`` call, after one warm-up call."""
    bb.features(frames)
    _sync(device)
    wall0, cpu0 = time.perf_counter(), time.process_time()
    for _ in range(repeats):
        bb.features(frames)
    _sync(device)
    return (time.perf_counter() - wall0) / repeats, (time.process_time() - cpu0) / repeats


def measure(name: str, device: torch.device, repeats: int, batch: int | None) -> dict[str, Any]:
    """Build ``name`` (random weights), time ``features()`` at the default size; one result row."""
    spec = get_spec(name)
    t0 = time.perf_counter()
    bb = build_backbone(name, pretrained=False).to(device)
    build_s = time.perf_counter() - t0
    b = batch or BATCH[spec.family] * (4 if device.type == "cuda" else 1)
    frames = torch.rand(b, 3, *bb.image_size, generator=torch.Generator().manual_seed(0)).to(device)
    maps = bb.features(frames)
    seconds, cpu_seconds = _time_features(bb, frames, repeats, device)
    row = {
        "backbone": name,
        "family": spec.family,
        "image_size": list(bb.image_size),
        "batch": b,
        "layers": bb.layers,
        "feat_shapes": [list(m.shape[1:]) for m in maps],
        "params_m": sum(p.numel() for p in bb.parameters()) / 1e6,
        "build_s": build_s,
        "seconds_per_batch": seconds,
        "frames_per_s": b / seconds,
        "cpu_s_per_frame": cpu_seconds / b,
        "load_avg_1min": os.getloadavg()[0],
        "feature_mb_per_frame_fp16": sum(m[0].numel() for m in maps) * 2 / 2**20,
    }
    del bb, maps, frames
    gc.collect()
    if device.type == "cuda":
        torch.cuda.empty_cache()
    return row


def _plot(rows: list[dict[str, Any]], path: Path, device: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    done = [r for r in rows if "frames_per_s" in r]
    fig, ax = plt.subplots(figsize=(7, 0.45 * len(done) + 1.2))
    ax.barh([f"{r['backbone']} ({r['image_size'][0]} px)" for r in done], [r["frames_per_s"] for r in done])
    ax.set_xscale("log")
    ax.set_xlabel(f"frames/s on {device} (log scale), random weights")
    ax.invert_yaxis()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}, 1 timed call each")
    ap.add_argument("--names", nargs="*", default=None, help="backbones to run (baseline always added)")
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--repeats", type=int, default=None, help="timed calls per backbone (default 3, quick 1)")
    ap.add_argument("--batch", type=int, default=None, help="frames per call for every backbone")
    ap.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    args = ap.parse_args()
    logging.basicConfig(level=logging.ERROR)  # the per-build RANDOM WEIGHTS warnings are expected here
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    repeats = args.repeats or (1 if args.quick else 3)
    names = list(args.names) if args.names else list(QUICK if args.quick else BACKBONE_NAMES)
    names = [BASELINE] + [n for n in names if n != BASELINE]
    rows: list[dict[str, Any]] = []
    with torch.inference_mode():
        base_row = measure(BASELINE, device, repeats, args.batch)
        baseline = build_backbone(BASELINE, pretrained=False).to(device)
        base_frames = torch.rand(base_row["batch"], 3, *baseline.image_size).to(device)
        for name in names:
            if name in NO_RANDOM_BUILD:
                rows.append({"backbone": name, "skipped": NO_RANDOM_BUILD[name]})
                continue
            print(f"... {name}", flush=True)
            if name == BASELINE:
                row = base_row
                row["baseline_frames_per_s_adjacent"] = row["frames_per_s"]
            else:
                # re-time the baseline right before each backbone: the ratio uses this adjacent measurement
                base_s, _ = _time_features(baseline, base_frames, repeats, device)
                row = measure(name, device, repeats, args.batch)
                row["baseline_frames_per_s_adjacent"] = base_row["batch"] / base_s
            row["cost_vs_baseline"] = row["baseline_frames_per_s_adjacent"] / row["frames_per_s"]
            row["cpu_cost_vs_baseline"] = row["cpu_s_per_frame"] / base_row["cpu_s_per_frame"]
            rows.append(row)

    header = (
        f"{'backbone':<10} {'size':>9} {'batch':>5} {'params M':>9} {'frames/s':>10} {'CPU s/frame':>11} "
        f"{'x vit_tiny':>10} {'CPU x tiny':>10} {'MB/frame':>9}"
    )
    print(f"\nfeature extraction on {device} (torch threads {torch.get_num_threads()}), random weights")
    print(header)
    print("-" * len(header))
    for r in rows:
        if "skipped" in r:
            print(f"{r['backbone']:<10} skipped: {r['skipped']}")
            continue
        size = "x".join(map(str, r["image_size"]))
        print(
            f"{r['backbone']:<10} {size:>9} {r['batch']:>5} {r['params_m']:>9.1f} {r['frames_per_s']:>10.2f} "
            f"{r['cpu_s_per_frame']:>11.2f} {r['cost_vs_baseline']:>10.1f} {r['cpu_cost_vs_baseline']:>10.1f} "
            f"{r['feature_mb_per_frame_fp16']:>9.2f}"
        )
    print(
        f"(x vit_tiny = {BASELINE} frames/s timed just before / frames/s: how many times slower, same run; "
        f"CPU x tiny = CPU s/frame / {BASELINE}'s CPU s/frame, robust to other load; "
        f"1-min load average at the end {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)"
    )

    out_dir = ROOT / "bench" / "results"
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = "backbones" if device.type == "cpu" else f"backbones_{device.type}"
    result = {
        "benchmark": "backbone feature extraction",
        "baseline": BASELINE,
        "device": str(device),
        "device_name": torch.cuda.get_device_name(device) if device.type == "cuda" else platform.processor(),
        "torch_threads": torch.get_num_threads(),
        "torch": torch.__version__,
        "quick": bool(args.quick),
        "cpu_count": os.cpu_count(),
        "repeats": repeats,
        "weights": "random (pretrained=false): same architecture and cost as pretrained",
        "rows": rows,
    }
    (out_dir / f"{stem}.json").write_text(json.dumps(result, indent=2))
    _plot(rows, out_dir / f"{stem}.png", str(device))
    print(f"wrote {out_dir / (stem + '.json')} and {stem}.png")


if __name__ == "__main__":
    main()
