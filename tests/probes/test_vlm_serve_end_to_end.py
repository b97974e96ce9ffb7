"""Server to report in one go: a question set whose images encode their answers is answered through the
stub OpenAI-compatible server (a real process, with an injected 500 and a timeout), the replies are
extracted with the paper's rule into a run directory, scored and reported: every item right, exactly."""

from __future__ import annotations

import hashlib
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

from PIL import Image

from newtphys import vqa_schema as vs
from newtphys.vqa_scoring import extract_letter, format_prompt
from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE, PredictionRecord, Prompt, RunManifest
from probes.vlm.openai_client import OpenAIServerAnswerer, ServerConfig
from probes.vlm.scoring import score_run
from probes.vlm_report import main as report_main
from tests.fixtures.vlm_runs import item, write_set

SERVER = Path(__file__).resolve().parents[1] / "fixtures" / "openai_stub_server.py"


def test_served_answers_are_scored_and_reported(tmp_path: Path) -> None:
    set_dir = tmp_path / "vqa" / "test"
    items, answers = [], {}
    for k in range(8):
        it = item(f"q{k}/single", f"s{k // 2}", "F_MASS_OBJECT" if k % 2 else "F_SIZE_OBJECT")
        it = replace(it, frames=(k,), images=(f"images/{it.sequence_id}/{k:06d}.png",))
        answers[it.idx] = vs.LETTERS[(3 * k) % 4]
        (set_dir / it.images[0]).parent.mkdir(parents=True, exist_ok=True)
        # the stub server answers "ABCD"[round(mean red / 85)]: this image says the right letter
        Image.new("RGB", (16, 12), (85 * vs.LETTERS.index(answers[it.idx]), 40, 40)).save(
            set_dir / it.images[0]
        )
        items.append(it)
    write_set(set_dir, items, answers)
    proc = subprocess.Popen(
        [
            sys.executable,
            str(SERVER),
            "--port",
            "0",
            "--fail-first",
            "1",
            "--hang-first",
            "1",
            "--hang-s",
            "2",
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline().split()[1])
        answerer = OpenAIServerAnswerer(
            ServerConfig(
                base_url=f"http://127.0.0.1:{port}/v1",
                model="stub",
                concurrency=1,
                timeout_s=0.5,
                max_retries=3,
                backoff_s=0.01,
            )
        )
        prompts = [
            Prompt(
                it.idx,
                tuple(set_dir / p for p in it.images),
                format_prompt(it.question, it.options),
                it.options,
            )
            for it in items
        ]
        gens = answerer.answer(prompts)
    finally:
        proc.terminate()
        proc.wait(timeout=10)
    assert answerer.stats.retries == 2  # the 500, then the timed-out request
    run = tmp_path / "run"
    run.mkdir()
    sha = hashlib.sha256((set_dir / vs.QUESTIONS_FILE).read_bytes()).hexdigest()
    manifest = RunManifest(answerer.name, answerer.describe(), str(set_dir), "test", sha, "0" * 64)
    (run / MANIFEST_FILE).write_text(manifest.to_json())
    records = [
        PredictionRecord(
            p.idx,
            0,
            g.text,
            extract_letter(g.text),
            extract_letter(g.text),
            g.latency_s,
            g.tokens_in,
            g.tokens_out,
        )
        for p, g in zip(prompts, gens, strict=True)
    ]
    (run / PREDICTIONS_FILE).write_text("".join(r.to_json() + "\n" for r in records))
    scores = score_run(run, n_boot=100)
    assert scores["strict"]["overall"] == 1.0 and scores["strict"]["ci"]["overall"] == [1.0, 1.0]
    assert scores["coverage"]["items"] == 8 and scores["coverage"]["missing"] == 0
    assert (
        scores["baseline_details"]["constant_letter"]["best_share"] == 0.25
    )  # letters 0, 3, 2, 1, ... balanced
    assert report_main([str(run), "--out", str(tmp_path / "report"), "--n-boot", "50"]) == 0
    assert "| openai-stub | 8 | 8/8 | 1.000 |" in (tmp_path / "report" / "report.md").read_text()
