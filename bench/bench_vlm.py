"""VLM evaluation throughput: items per second of the harness with the baselines and the tiny random-weight
VLM fixtures (measured, CPU here; GPU when one is visible), and the hours the 15K subset would take per
model size (PROJECTED from a stated cost model, not measured).

Measured: each answerer answers the same question set through :func:`probes.vlm.evaluate.evaluate` into a
fresh run directory (prompt building, image loading, processor, generation, extraction, fsynced appends all
included); items/s = items / wall seconds, after a warm-up batch. The tiny models (probes/vlm/tiny.py) are
random-weight fixtures of the real Qwen2-VL and Idefics3 classes at 32-dim width: their speed is the
harness's overhead, not a real model's.

Projected (per model size P, billions of parameters), on one GPU, for N items, batched:
    t_item = 2 * P * T_in / (F * u)  +  T_out * 2 bytes * P / (BW * B)
prefill compute-bound (2 FLOPs per parameter per prompt token at F peak bf16 FLOP/s and utilisation u) plus
greedy decode memory-bound (each of T_out steps reads the bf16 weights once per batch of B prompts).
T_in = the set's mean prompt characters / 4 (characters per text token) + mean images per item x visual
tokens per image (V). Single-image models get only the single items (the set's share). Defaults: H200 SXM
(F = 989e12 dense bf16, BW = 4.8e12 B/s), u = 0.4, B = 8, T_out = 16 (the records' max_new_tokens, an upper
bound), V = 256 (a 448 px image in Qwen2-VL's merged 28 px patches: (448 / 28)^2). Every assumption is an
argument and is printed with the table; multi-GPU models (device_map) are projected as one GPU of the summed
speed. It is an optimistic bound: transformers' generate() with padding, image preprocessing on the CPU and
Python overhead are slower; measure one model on the GPU and set --utilisation from it.

    python bench/bench_vlm.py [--vqa-dir DIR] [--quick]   (writes bench/results/vlm[_quick].json)
"""

from __future__ import annotations

import argparse
import json
import platform
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import torch

from newtphys import vqa_schema as vs
from probes.vlm.baselines import build_baseline
from probes.vlm.evaluate import evaluate
from probes.vlm.interface import PREDICTIONS_FILE
from probes.vlm.predictions import read_predictions
from probes.vlm.prompting import build_prompt
from probes.vlm.specs import SPECS
from probes.vlm.tiny import TINY_ARCHS, build_tiny_answerer

ROOT = Path(__file__).resolve().parents[1]
SUBSET_ITEMS = 15_000


def generated_set(tmp: Path) -> Path:
    """One simulated push sequence -> a question set (the slow end-to-end test's settings)."""
    from generate import run as generate
    from generate_vqa import run as generate_vqa
    from newtphys.config import compose_config

    generate(compose_config("generate", [f"out_dir={tmp / 'data'}", "split=test", "scenario=push", "quality=draft",
                                         "num_sequences=1", "sequences_per_shard=1", "num_frames=24",
                                         "image_size=[128,128]", "scenario.num_objects=[2,3]", "progress=false",
                                         "seed=1"]))  # fmt: skip
    generate_vqa(compose_config("generate_vqa", [f"data_dir={tmp / 'data'}", "split=test", f"out_dir={tmp / 'vqa'}",
                                                 "progress=false", "workers=1"]))  # fmt: skip
    return tmp / "vqa" / "test"


def measure(answerer, set_dir: Path, tmp: Path, batch_size: int) -> dict:
    """Items per second of ``answerer`` on the set (a warm-up batch first, in its own run directory)."""
    evaluate(answerer, set_dir, tmp / f"warm-{answerer.name}", batch_size=batch_size, limit=batch_size, progress=False)
    run_dir = tmp / f"run-{answerer.name}"
    start = time.perf_counter()
    result = evaluate(answerer, set_dir, run_dir, batch_size=batch_size, progress=False)
    seconds = time.perf_counter() - start
    preds = read_predictions(run_dir / PREDICTIONS_FILE)
    tin = [p.tokens_in for p in preds if p.tokens_in is not None]
    tout = [p.tokens_out for p in preds if p.tokens_out is not None]
    return {"answerer": answerer.name, "weights": answerer.describe().get("weights"), "items": result.items,
            "seconds": seconds, "items_per_s": result.items / seconds,
            "mean_tokens_in": statistics.mean(tin) if tin else None,
            "mean_tokens_out": statistics.mean(tout) if tout else None}  # fmt: skip


def set_shape(set_dir: Path) -> dict:
    items = vs.read_items(set_dir)
    prompts = [build_prompt(i, set_dir) for i in items]
    single = [i for i in items if i.mode == "single"]
    return {"items": len(items), "single_share": len(single) / len(items),
            "mean_images": statistics.mean(len(i.images) for i in items),
            "mean_images_single": statistics.mean(len(i.images) for i in single) if single else 0.0,
            "mean_prompt_chars": statistics.mean(len(p.text) for p in prompts)}  # fmt: skip


def project(shape: dict, args: argparse.Namespace) -> list[dict]:
    """Projected hours for SUBSET_ITEMS items per model record size (see the module docstring)."""
    rows = []
    text_tokens = shape["mean_prompt_chars"] / args.chars_per_token
    for spec in sorted((s for s in SPECS.values() if not s.needs_remote_code), key=lambda s: (s.params_b, s.name)):
        images = shape["mean_images_single"] if spec.single_image_only else shape["mean_images"]
        n_items = SUBSET_ITEMS * (shape["single_share"] if spec.single_image_only else 1.0)
        t_in = text_tokens + images * args.visual_tokens
        p = spec.params_b * 1e9
        prefill = 2 * p * t_in / (args.peak_flops * args.utilisation)
        decode = args.tokens_out * 2 * p / (args.bandwidth * args.batch)
        rows.append({"model": spec.name, "params_b": spec.params_b, "items": round(n_items), "tokens_in": t_in,
                     "s_per_item": prefill + decode, "hours": n_items * (prefill + decode) / 3600,
                     "gpu_memory_gb_bf16_weights": 2 * p / 1e9})  # fmt: skip
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--vqa-dir", type=Path, default=None, help="a question set (split dir); default: generate one")
    ap.add_argument("--quick", action="store_true", help="first 24 items only")
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--peak-flops", type=float, default=989e12, help="GPU dense bf16 FLOP/s (H200 SXM)")
    ap.add_argument("--utilisation", type=float, default=0.4, help="share of peak reached in prefill")
    ap.add_argument("--bandwidth", type=float, default=4.8e12, help="GPU memory bandwidth, B/s (H200)")
    ap.add_argument("--batch", type=int, default=8, help="prompts per generate() call in the projection")
    ap.add_argument("--tokens-out", type=int, default=16, help="generated tokens per item (max_new_tokens)")
    ap.add_argument("--visual-tokens", type=int, default=256, help="visual tokens per image")
    ap.add_argument("--chars-per-token", type=float, default=4.0)
    args = ap.parse_args()
    torch.set_num_threads(max(1, min(2, torch.get_num_threads())))
    tmp = Path(tempfile.mkdtemp(prefix="bench_vlm-"))
    try:
        set_dir = args.vqa_dir if args.vqa_dir is not None else generated_set(tmp)
        if args.quick:
            quick = tmp / "quick"
            quick.mkdir(exist_ok=True)
            lines = (set_dir / vs.QUESTIONS_FILE).read_text().splitlines()[:24]
            (quick / vs.QUESTIONS_FILE).write_text("\n".join(lines) + "\n")
            shutil.copy(set_dir / vs.ANSWERS_FILE, quick / vs.ANSWERS_FILE)
            (quick / "images").symlink_to((set_dir / "images").resolve())
            set_dir = quick
        shape = set_shape(set_dir)
        device = "cuda" if torch.cuda.is_available() else "cpu"
        answerers = [build_baseline("random"), build_baseline("oracle", set_dir), build_baseline("prior", set_dir)]
        answerers += [build_tiny_answerer(a, cache_dir=str(tmp / "tiny"), device=device) for a in TINY_ARCHS]
        measured = [{**measure(a, set_dir, tmp, args.batch_size), "device": device} for a in answerers]
        projected = project(shape, args)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    print(f"MEASURED on {device} ({platform.processor() or platform.machine()}, {torch.get_num_threads()} threads), "
          f"{shape['items']} items, mean {shape['mean_images']:.2f} images / item, batch {args.batch_size}")
    print(f"{'answerer':<16} {'weights':<8} {'items':>6} {'seconds':>8} {'items/s':>9} {'tok in':>7} {'tok out':>7}")
    for r in measured:
        tin = f"{r['mean_tokens_in']:.0f}" if r["mean_tokens_in"] is not None else "-"
        tout = f"{r['mean_tokens_out']:.1f}" if r["mean_tokens_out"] is not None else "-"
        print(f"{r['answerer']:<16} {r['weights']:<8} {r['items']:>6} {r['seconds']:>8.2f} {r['items_per_s']:>9.1f} "
              f"{tin:>7} {tout:>7}")
    print(f"\nPROJECTED (cost model, not measured) for the {SUBSET_ITEMS}-item subset on one GPU: "
          f"F={args.peak_flops:.3g} FLOP/s x u={args.utilisation}, BW={args.bandwidth:.3g} B/s, batch {args.batch}, "
          f"T_out={args.tokens_out}, {args.visual_tokens} visual tokens / image, {args.chars_per_token} chars / token")
    print(f"{'model':<22} {'params B':>8} {'items':>6} {'T_in':>6} {'s/item':>8} {'hours':>7} {'bf16 GB':>8}")
    for r in projected:
        print(f"{r['model']:<22} {r['params_b']:>8.2f} {r['items']:>6} {r['tokens_in']:>6.0f} {r['s_per_item']:>8.4f} "
              f"{r['hours']:>7.2f} {r['gpu_memory_gb_bf16_weights']:>8.1f}")
    out = ROOT / "bench" / "results" / ("vlm_quick.json" if args.quick else "vlm.json")
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"measured": measured, "set": shape, "projection_assumptions": vars(args) | {
        "vqa_dir": str(args.vqa_dir) if args.vqa_dir else "generated"}, "projected": projected}, indent=2) + "\n")
    print(f"\nwrote {out}")


if __name__ == "__main__":
    main()
