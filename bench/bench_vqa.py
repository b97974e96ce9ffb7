"""Question-generation speed: questions per second per core, seconds per sequence, and the share spent reading
shards, against a baseline measured in the same run (reading every map of the same sequences).

Generates a small dataset of multi-object scenarios (push, pile, throw) with ``generate.py``'s code, then, for
every sequence, times the three stages of ``data_gen.vqa`` in one process (one core): loading the sequence
(world state, cameras), asking every question id, reading the shown RGB frames and writing them as PNGs.
Also reports how many question ids the scenarios cover. Prints a table, writes bench/results/vqa.json.

    python bench/bench_vqa.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import platform
import tempfile
import time
from pathlib import Path

from PIL import Image

from data_gen.configs import generation_config
from data_gen.generator import run_generation
from data_gen.vqa.cli import vqa_config
from data_gen.vqa.generator import list_jobs, question_frames, sequence_questions
from data_gen.vqa.view import SequenceView
from newtphys import schema
from newtphys.shards import ShardReader
from newtphys.vqa_schema import QUESTION_SPECS

ROOT = Path(__file__).resolve().parents[1]


def _generate(root: Path, scenario: str, n: int, frames: int, size: int) -> None:
    cfg = generation_config(f"out_dir={root}", "split=test", f"scenario={scenario}", f"num_sequences={n}",
                            f"sequences_per_shard={n}", f"num_frames={frames}", f"image_size=[{size},{size}]",
                            "progress=false", f"seed={len(scenario)}")  # fmt: skip
    run_generation(cfg)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    per_scenario, frames, size = (1, 25, 64) if args.quick else (3, 50, 128)
    rows, produced = [], set()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        data = tmp / "data"
        t0 = time.perf_counter()
        for name, split_root in (("push", data / "push"), ("pile", data / "pile"), ("throw", data / "throw")):
            _generate(split_root, name, per_scenario, frames, size)
        gen_s = time.perf_counter() - t0
        for scenario in ("push", "pile", "throw"):
            cfg = vqa_config(f"data_dir={data / scenario}", "split=test", f"out_dir={tmp / 'vqa' / scenario}",
                             "workers=1", "progress=false")  # the shipped settings (base questions)
            for job in list_jobs(cfg):
                t_read = time.perf_counter()
                view = SequenceView(Path(job.shard), job.sequence_id, job.shard_relative)
                t_ask = time.perf_counter()
                records, _, shown = sequence_questions(view, cfg)
                t_img = time.perf_counter()
                out = tmp / "img"
                out.mkdir(exist_ok=True)
                for t, rgb in zip(sorted(shown), view.read_rgb(sorted(shown))):
                    Image.fromarray(rgb).save(out / f"{job.sequence_id}-{t}.png")
                t_end = time.perf_counter()
                with ShardReader(Path(job.shard)) as r:  # baseline: every map of the sequence, read once
                    t_base = time.perf_counter()
                    for name in schema.MAP_NAMES:
                        r.read(job.sequence_id, name)
                    base_s = time.perf_counter() - t_base
                produced |= {rec["question_id"] for rec in records}
                rows.append({"scenario": scenario, "sequence": job.sequence_id, "items": len(records),
                             "frames_asked": len(question_frames(view, cfg)), "load_s": t_ask - t_read,
                             "ask_s": t_img - t_ask, "images_s": t_end - t_img, "total_s": t_end - t_read,
                             "read_all_maps_s": base_s})  # fmt: skip
    total = sum(r["total_s"] for r in rows)
    items = sum(r["items"] for r in rows)
    reading = sum(r["load_s"] + r["images_s"] for r in rows)
    print(f"{'scenario':<8} {'sequence':<14} {'items':>5} {'load s':>7} {'ask s':>7} {'images s':>8} {'total s':>8} "
          f"{'all maps s':>10}")  # fmt: skip
    for r in rows:
        print(f"{r['scenario']:<8} {r['sequence']:<14} {r['items']:>5} {r['load_s']:>7.3f} {r['ask_s']:>7.3f} "
              f"{r['images_s']:>8.3f} {r['total_s']:>8.3f} {r['read_all_maps_s']:>10.3f}")  # fmt: skip
    base = sum(r["read_all_maps_s"] for r in rows)
    summary = {
        "items": items, "sequences": len(rows), "items_per_s_per_core": items / total,
        "s_per_sequence": total / len(rows), "share_reading_shards": reading / total,
        "ratio_to_reading_every_map": total / base, "question_ids_covered": len(produced),
        "question_ids_in_catalogue": len(QUESTION_SPECS), "missing_ids": sorted(set(QUESTION_SPECS) - produced),
        "generation_s": gen_s, "frames": frames, "image_size": size, "per_scenario": per_scenario,
        "machine": platform.platform(),
    }  # fmt: skip
    print(f"\n{items} items from {len(rows)} sequences: {summary['items_per_s_per_core']:.0f} items/s on one core, "
          f"{summary['s_per_sequence']:.2f} s per sequence, {100 * summary['share_reading_shards']:.0f} % of it "
          f"reading shards and writing PNGs; {summary['ratio_to_reading_every_map']:.2f}x the time to read every "
          f"map of the same sequences once; {len(produced)} of {len(QUESTION_SPECS)} question ids covered "
          f"(missing: {summary['missing_ids']})")  # fmt: skip
    out = ROOT / "bench" / "results" / ("vqa_quick.json" if args.quick else "vqa.json")
    out.write_text(json.dumps({"summary": summary, "rows": rows}, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
