"""Probe training throughput (clips/s) with and without the feature cache, for two backbones.

For each backbone (random weights: no downloads), in the same run:

* ``frames``: the datamodule serves frames; every training step runs the frozen
  backbone on K frames per clip, then the decoder forward/backward and AdamW.
* ``cache``: the datamodule serves cached fp16 features (filled once; the
  one-off fill time is reported separately); a step is decoder + AdamW only.

The baseline is the ``frames`` row of the same backbone: ratio = cache / frames
clips/s. Also reports the cache's disk size per frame. Data: analytic
test-fixture sequences (tests/fixtures), not simulated data. Prints a table and
writes bench/results/probes.json.

    python bench/bench_probes.py [--quick] [--device cpu|cuda]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the test fixture lives in tests/, not in the package

from newtphys import schema  # noqa: E402
from probes.backbones import build_backbone  # noqa: E402
from probes.datamodule import ProbeDataModule  # noqa: E402
from probes.decoders import LinearHead  # noqa: E402
from probes.features import clip_features  # noqa: E402
from probes.tasks import build_task  # noqa: E402
from tests.fixtures.synthetic_scene import write_fixture_split  # noqa: E402


def _train_steps(dm: ProbeDataModule, backbone, head, task, steps: int, device: str) -> tuple[float, int]:
    """Seconds and clips for ``steps`` training steps (after one warm-up step)."""
    opt = torch.optim.AdamW(head.parameters(), lr=5e-4)
    loader = dm.train_dataloader()

    def batches():
        while True:
            yield from loader

    it = batches()
    clips = 0
    t0 = 0.0
    for step in range(steps + 1):
        if step == 1:
            if device == "cuda":
                torch.cuda.synchronize()
            t0 = time.perf_counter()
        batch = next(it)
        target = batch[task.target_key].to(device)
        mask = batch["object_mask"].to(device)
        if "features" in batch:
            feats = [f.to(device, non_blocking=True) for f in batch["features"]]
        else:
            feats = clip_features(backbone, batch["frames"].to(device))
        loss = task.loss(head(feats, out_size=tuple(target.shape[-2:])), target, mask)
        opt.zero_grad()
        loss.backward()
        opt.step()
        if step >= 1:
            clips += int(mask.shape[0])
    if device == "cuda":
        torch.cuda.synchronize()
    return time.perf_counter() - t0, clips


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true", help="small images and few steps (~1 min on CPU)")
    ap.add_argument("--device", default="cpu", choices=("cpu", "cuda"))
    args = ap.parse_args()
    quick = args.quick
    device = args.device
    steps = {"frames": 10 if quick else 3, "cache": 10 if quick else 40}  # timed steps per mode
    batch = 4 if quick else 8
    data_px = (32, 32) if quick else (64, 64)
    backbones = [
        # (registry name, input size px, layers)
        ("vit_tiny", 64 if quick else 224, [2, 5, 8, 11]),
        ("dino", 64 if quick else 224, [2, 5, 8, 11]),  # ViT-B/16 architecture, random weights
    ]
    task = build_task("collision")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        write_fixture_split(
            tmp / "data",
            schema.Split.TRAIN.value,
            num_sequences=4,
            sequences_per_shard=2,
            num_frames=8,
            image_size=data_px,
            seed=0,
        )
        for name, px, layers in backbones:
            torch.manual_seed(0)
            bb = build_backbone(name, pretrained=False, image_size=px, layers=layers).to(device)
            for mode in ("frames", "cache"):
                dm = ProbeDataModule(
                    tmp / "data",
                    targets=(task.target_key,),
                    clip_length=4,
                    batch_size=batch,
                    num_workers=0,
                    feature_cache=mode == "cache",
                    cache_dir=tmp / "cache",
                    cache_in_memory=False,
                    backbone=bb,
                )
                fill_s, per_frame_bytes = 0.0, None
                if mode == "cache":
                    t0 = time.perf_counter()
                    ds = dm.dataset(schema.Split.TRAIN.value)  # fills the cache
                    fill_s = time.perf_counter() - t0
                    per_frame_bytes = ds.cache.disk_bytes() / max(1, ds.cache.num_entries())
                torch.manual_seed(0)
                head = LinearHead(bb.feat_dims, 4, task.out_channels).to(device)
                secs, clips = _train_steps(dm, bb, head, task, steps[mode], device)
                rows.append(
                    {
                        "backbone": name,
                        "image_size_px": px,
                        "layers": layers,
                        "mode": mode,
                        "clips_per_s": clips / secs,
                        "steps": steps[mode],
                        "batch": batch,
                        "cache_fill_s": fill_s if mode == "cache" else None,
                        "cache_bytes_per_frame": per_frame_bytes,
                    }
                )
            base = next(r for r in rows if r["backbone"] == name and r["mode"] == "frames")["clips_per_s"]
            for r in rows:
                if r["backbone"] == name:
                    r["speedup_vs_frames"] = r["clips_per_s"] / base

    print(
        f"\nprobe training throughput ({device}, {torch.get_num_threads()} threads, batch {batch}, "
        f"K=4, data {data_px[0]}x{data_px[1]} px, timed steps {steps})"
    )
    print(
        f"{'backbone':<10} {'input px':>8} {'mode':<7} {'clips/s':>9} {'x frames':>9} {'fill s':>8} "
        f"{'cache KB/frame':>15}"
    )
    for r in rows:
        fill = f"{r['cache_fill_s']:.2f}" if r["cache_fill_s"] is not None else "-"
        kb = f"{r['cache_bytes_per_frame'] / 1024:.1f}" if r["cache_bytes_per_frame"] else "-"
        print(
            f"{r['backbone']:<10} {r['image_size_px']:>8} {r['mode']:<7} {r['clips_per_s']:>9.2f} "
            f"{r['speedup_vs_frames']:>9.2f} {fill:>8} {kb:>15}"
        )
    out = ROOT / "bench" / "results"
    out.mkdir(parents=True, exist_ok=True)
    result = {
        "benchmark": "probes_training_throughput",
        "quick": quick,
        "device": device,
        "torch_threads": torch.get_num_threads(),
        "machine": platform.platform(),
        "cpu": platform.processor(),
        "gpu": torch.cuda.get_device_name(0) if device == "cuda" else None,
        "data": "analytic test-fixture sequences (tests/fixtures/synthetic_scene.py), not simulated",
        "baseline": "frames (backbone run every step) of the same backbone",
        "rows": rows,
    }
    (out / "probes.json").write_text(json.dumps(result, indent=1))
    print(f"written: {out / 'probes.json'}")


if __name__ == "__main__":
    main()
