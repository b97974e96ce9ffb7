"""The main job on the embedded default (``make demo``): simulate a small dataset, look at it, probe it.

Every step is a command you can run yourself; the demo prints each one before
running it. Re-running resumes (finished shards are skipped).

    python demo.py [--out demo_out] [--sequences 8] [--task gravity]

Steps: generate train / val / test (Earth gravity) and test_ood_gravity
(g ~ U[0.98, 20] m/s^2) splits with the simulator and splat renderer ->
validate them (contract + cross-map physics) -> summary table and dataset
statistics -> contact sheet and video of one sequence -> train a probe
(the tiny ViT with RANDOM weights: no pretrained weights can be downloaded
here) on the train split and print its metrics on both test splits -> generate
physics questions on the test split, validate them and print their counts.
"""

from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent


def step(title: str, args: list[str]) -> None:
    print(f"\n== {title}\n$ {shlex.join(args)}", flush=True)
    t0 = time.perf_counter()
    subprocess.run(args, cwd=ROOT, check=True)
    print(f"   ({time.perf_counter() - t0:.1f} s)", flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default="demo_out", help="output directory (data, pictures, statistics, logs)")
    ap.add_argument("--sequences", type=int, default=8, help="training sequences (val/test splits get a quarter)")
    ap.add_argument("--frames", type=int, default=16)
    ap.add_argument("--size", type=int, default=64, help="image height and width, px")
    ap.add_argument("--task", default="gravity", choices=["gravity", "collision", "scene_flow"])
    ap.add_argument("--quality", default="draft")
    args = ap.parse_args()
    out = Path(args.out).resolve()
    data = out / "data"
    py = sys.executable
    common = [f"out_dir={data}", f"num_frames={args.frames}", f"image_size=[{args.size},{args.size}]",
              f"quality={args.quality}", "scenario=drop", "render.object_gaussians=2000",
              "render.interior_points=800", "render.scene_spacing_m=0.03", "scenario.camera_distance_m=[0.7,1.0]",
              f"paths.log_dir={out / 'logs'}"]
    small = max(2, args.sequences // 4)
    splits = [("train", args.sequences, "earth", 0), ("val", small, "earth", 1), ("test", small, "earth", 2),
              ("test_ood_gravity", small, "ood", 3)]
    t0 = time.perf_counter()
    for split, n, gravity, seed in splits:
        step(f"simulate and render the {split} split ({n} sequences, gravity={gravity})",
             [py, "generate.py", f"split={split}", f"num_sequences={n}", "sequences_per_shard=4",
              f"gravity={gravity}", f"seed={seed}"] + common)
    step("validate every shard against the data contract and the cross-map physics checks",
         [py, "-m", "newtphys", "validate", "--deep", str(data)])
    step("summary table", [py, "-m", "newtphys", "info", str(data)])
    step("dataset statistics", [py, "-m", "newtphys", "stats", str(data), "--out", str(out / "stats")])
    step("contact sheet and video of one sequence",
         [py, "-m", "newtphys", "view", str(data / "train"), "--sequence", "train-000000",
          "--out", str(out / "pictures" / "train-000000")])
    run_dir = out / "probe"
    step(f"train a {args.task} probe (tiny ViT, RANDOM weights) and test it on test and test_ood_gravity",
         [py, "train.py", "experiment=demo", f"task={args.task}", f"data.data_root={data}",
          f"paths.log_dir={out / 'logs'}", f"paths.cache_dir={out / 'cache'}", f"hydra.run.dir={run_dir}"])
    metrics_path = run_dir / "metrics.json"
    if metrics_path.is_file():
        metrics = json.loads(metrics_path.read_text())
        print(f"\n== {metrics.get('task')} probe on {metrics.get('backbone')} "
              f"(pretrained={bool(metrics.get('backbone_pretrained'))}; random weights make this a pipeline check, "
              "not a result about any model)")
        for split in ("val", "test", "test_ood_gravity"):
            for name, value in sorted((metrics.get(split) or {}).items()):
                print(f"   {split + '/' + name:<48} {value:.4g}")
    vqa = out / "vqa"
    step("generate physics questions from the test split's world states and frames (short clips: the last 4 "
         "frames are excluded instead of 10)",
         [py, "generate_vqa.py", f"data_dir={data}", "split=test", f"out_dir={vqa}", "exclude_last_frames=4",
          f"paths.log_dir={out / 'logs'}"])
    step("validate the question set against the VQA contract", [py, "-m", "newtphys", "validate-vqa", str(vqa)])
    step("contact sheet of sample questions", [py, "-m", "newtphys", "view-vqa", str(vqa), "--out",
                                               str(out / "pictures" / "questions.png")])
    manifest = json.loads((vqa / "test" / "manifest.json").read_text())
    print(f"\n== {manifest['num_items']} questions, {len(manifest['counts']['question_id'])} question ids")
    for category, n in manifest["counts"]["category"].items():
        print(f"   {category:<28} {n}")
    print(f"   letters {manifest['counts']['letter']}")
    print(f"   answered by the text alone above chance (blind-prior audit): {manifest['blind_solvable_question_ids']}")
    print(f"\ndone in {time.perf_counter() - t0:.0f} s; outputs under {out}:")
    print("   pictures/train-000000.png, .mp4   stats/stats.png   probe/metrics.json   vqa/test/questions.jsonl")
    print(f"   question contact sheet: {out / 'pictures' / 'questions.png'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
