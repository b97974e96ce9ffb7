"""VLM scoring and serving-client benchmark (CPU).

* scoring: ``item_results`` + ``score_results`` (macro accuracy strict / lenient, 1000 sequence-bootstrap
  replicates, constant-letter and text-prior baselines, variants) on synthetic sets the size of the paper's
  15K subset and of its released 158K answer file (items spread over every question id, 12 items per
  sequence, random predictions); the same with ``n_boot=0`` as the baseline cost of the join and the point
  estimates;
* client: items per second of :class:`~probes.vlm.openai_client.OpenAIServerAnswerer` against the stub
  server (tests/fixtures/openai_stub_server.py) answering after a fixed delay (a stand-in for model latency)
  at several concurrencies, against the ideal ``concurrency / delay``; with no delay, the client + HTTP
  overhead per request.

Usage: python bench/bench_vlm_scoring.py [--sizes 15000 158593]   (writes bench/results/vlm_scoring.json)
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root: tests.fixtures is not installed
from newtphys import vqa_schema as vs  # noqa: E402
from probes.vlm.interface import Prompt  # noqa: E402
from probes.vlm.openai_client import OpenAIServerAnswerer, ServerConfig  # noqa: E402
from probes.vlm.scoring import item_results, score_results  # noqa: E402
from tests.fixtures.vlm_runs import item, write_run, write_set  # noqa: E402

RESULTS = Path(__file__).parent / "results" / "vlm_scoring.json"
SERVER = Path(__file__).resolve().parents[1] / "tests" / "fixtures" / "openai_stub_server.py"
ITEMS_PER_SEQUENCE = 12


def synthetic_run(root: Path, n_items: int, seed: int = 0) -> tuple[Path, Path]:
    rng = np.random.default_rng(seed)
    qids = sorted(vs.QUESTION_SPECS)
    items, answers, preds = [], {}, {}
    for k in range(n_items):
        qid = qids[k % len(qids)]
        mode = "multi" if vs.QUESTION_SPECS[qid].modes == ("multi",) else "single"
        it = item(
            f"p{k}/{mode}", f"s{k // ITEMS_PER_SEQUENCE}", qid, mode=mode, question=f"What about {qid} {k}?"
        )
        items.append(it)
        answers[it.idx] = vs.LETTERS[rng.integers(4)]
        preds[(it.idx, 0)] = vs.LETTERS[rng.integers(4)] if rng.random() > 0.05 else None
    set_dir = write_set(root / "vqa" / "test", items, answers)
    return set_dir, write_run(root / "run", set_dir, preds)


def bench_scoring(n_items: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        set_dir, run = synthetic_run(Path(tmp), n_items)
        out = {"items": n_items, "sequences": -(-n_items // ITEMS_PER_SEQUENCE)}
        t = time.perf_counter()
        results = item_results(run, set_dir)
        out["join_s"] = time.perf_counter() - t
        t = time.perf_counter()
        s0 = score_results(results, n_boot=0)
        out["score_no_bootstrap_s"] = time.perf_counter() - t
        t = time.perf_counter()
        s = score_results(results, n_boot=1000)
        out["score_1000_bootstrap_s"] = time.perf_counter() - t
        out["strict"] = s["strict"]["overall"]
        out["ci"] = s["strict"]["ci"]["overall"]
        out["text_prior"] = s["baselines"].get("prior")  # absent when the prior could not be fitted
        out["same_point_estimate"] = s0["strict"]["overall"] == s["strict"]["overall"]
    return out


def bench_client(tmp: Path, delay_s: float, concurrency: int, n: int = 64) -> dict:
    img = tmp / "img.png"
    Image.new("RGB", (256, 256), (85, 10, 10)).save(img)
    prompts = [
        Prompt(f"i{k}", (img,), "Question?\nA. a\nB. b\nC. c\nD. d", ("a", "b", "c", "d")) for k in range(n)
    ]
    proc = subprocess.Popen(
        [sys.executable, str(SERVER), "--port", "0", "--delay-s", str(delay_s)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline().split()[1])
        cfg = ServerConfig(base_url=f"http://127.0.0.1:{port}/v1", model="stub", concurrency=concurrency)
        answerer = OpenAIServerAnswerer(cfg)
        answerer.answer(prompts[:2])  # warm up
        t = time.perf_counter()
        gens = answerer.answer(prompts)
        wall = time.perf_counter() - t
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert all(g.text == "The answer is B." for g in gens)
    ideal = concurrency / delay_s if delay_s else None
    return {
        "delay_s": delay_s,
        "concurrency": concurrency,
        "requests": n,
        "items_per_s": n / wall,
        "ideal_items_per_s": ideal,
        "overhead_ms_per_request": 1000 * (wall / n - (delay_s / concurrency)),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[15000, 158593])
    p.add_argument("--quick", action="store_true", help="only the smallest size (what `make bench` runs)")
    args = p.parse_args()
    if args.quick:
        args.sizes = [min(args.sizes)]
    report = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "scoring": [],
        "client": [],
    }
    for n in args.sizes:
        row = bench_scoring(n)
        report["scoring"].append(row)
        print(json.dumps(row))
    with tempfile.TemporaryDirectory() as tmp:
        for delay, conc in ((0.0, 1), (0.0, 8), (0.1, 1), (0.1, 8), (0.1, 32)):
            row = bench_client(Path(tmp), delay, conc, n=64 if delay else 200)
            report["client"].append(row)
            print(json.dumps(row))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    out = RESULTS.with_name(RESULTS.stem + "_quick.json") if args.quick else RESULTS
    out.write_text(json.dumps(report, indent=2))
    print(f"written {out}")


if __name__ == "__main__":
    main()
