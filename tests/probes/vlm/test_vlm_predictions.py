"""Results that survive: a torn last line is cut, a re-run resumes without duplicates, a run directory of
another set / prompt / model is refused, and SIGKILL mid-run then a re-run gives the predictions of an
uninterrupted run."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest

from probes.vlm.baselines import ConstantLetterAnswerer, RandomAnswerer, build_baseline
from probes.vlm.evaluate import evaluate
from probes.vlm.interface import MANIFEST_FILE, PREDICTIONS_FILE, PredictionRecord
from probes.vlm.predictions import (
    MixedRunError,
    PredictionStore,
    RunDirectoryBusy,
    cut_torn_tail,
    read_predictions,
)
from tests.probes.vlm.conftest import write_question_set

REPO = Path(__file__).resolve().parents[3]


def _keys(records: list[PredictionRecord]) -> list[tuple]:
    """Everything but the timing."""
    return [(r.idx, r.rotation, r.raw, r.letter, r.letter_lenient, r.tokens_in, r.tokens_out) for r in records]


def test_torn_last_line_is_cut_and_the_run_resumes_without_duplicates(vlm_set: Path, tmp_path: Path):
    run = tmp_path / "run"
    full = evaluate(RandomAnswerer(0), vlm_set, tmp_path / "full", batch_size=4, progress=False)
    assert full.answered == 18
    evaluate(RandomAnswerer(0), vlm_set, run, batch_size=4, limit=9, progress=False)  # 9 items written
    path = run / PREDICTIONS_FILE
    whole = path.read_bytes()
    path.write_bytes(whole + b'{"idx": "seq-b/F_SIZE_OBJ')  # killed inside a write
    assert len(read_predictions(path)) == 9  # readers ignore the torn piece
    again = evaluate(RandomAnswerer(0), vlm_set, run, batch_size=4, progress=False)
    assert (again.already_done, again.answered) == (9, 9)
    recs = read_predictions(path)
    assert _keys(recs) == _keys(read_predictions(tmp_path / "full" / PREDICTIONS_FILE))
    assert len({(r.idx, r.rotation) for r in recs}) == 18
    # nothing left: a third run answers nothing
    assert evaluate(RandomAnswerer(0), vlm_set, run, batch_size=4, progress=False).answered == 0
    assert cut_torn_tail(path) == 0


def test_mixing_another_set_prompt_or_model_is_refused(vlm_set: Path, tmp_path: Path):
    run = tmp_path / "run"
    evaluate(ConstantLetterAnswerer("A"), vlm_set, run, batch_size=8, limit=4, progress=False)
    with pytest.raises(MixedRunError, match=r"model\.letter: 'A' -> 'B'"):
        evaluate(ConstantLetterAnswerer("B"), vlm_set, run, batch_size=8, progress=False)
    other = write_question_set(tmp_path / "other")
    lines = (other / "questions.jsonl").read_text().splitlines()
    (other / "questions.jsonl").write_text("\n".join(lines[:-1]) + "\n")  # one item fewer: another set
    with pytest.raises(MixedRunError, match="question_set_sha256"):
        evaluate(ConstantLetterAnswerer("A"), other, run, batch_size=8, progress=False)
    with pytest.raises(MixedRunError, match="circular: False -> True"):
        evaluate(ConstantLetterAnswerer("A"), vlm_set, run, batch_size=8, circular=True, progress=False)
    manifest = json.loads((run / MANIFEST_FILE).read_text())
    manifest["prompt_template_sha256"] = "0" * 64  # predictions made with another prompt template
    (run / MANIFEST_FILE).write_text(json.dumps(manifest))
    with pytest.raises(MixedRunError, match="prompt_template_sha256"):
        evaluate(ConstantLetterAnswerer("A"), vlm_set, run, batch_size=8, progress=False)
    # predictions without a manifest: unknown provenance
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / PREDICTIONS_FILE).write_text((run / PREDICTIONS_FILE).read_text())
    with pytest.raises(MixedRunError, match="without a manifest.json"):
        evaluate(ConstantLetterAnswerer("A"), vlm_set, bare, batch_size=8, progress=False)
    # volatile settings (batch size) may change between runs of one result
    assert evaluate(ConstantLetterAnswerer("A"), vlm_set, run / ".." / "run2", batch_size=3, progress=False).answered == 18


def test_store_refuses_to_write_twice_and_reads_duplicates_as_an_error(vlm_set: Path, tmp_path: Path):
    evaluate(build_baseline("oracle", vlm_set), vlm_set, tmp_path / "r", batch_size=18, limit=2, progress=False)
    store = PredictionStore(tmp_path / "r")
    store.done = {(r.idx, r.rotation) for r in read_predictions(store.path)}
    rec = read_predictions(store.path)[0]
    with pytest.raises(ValueError, match="refusing to write predictions twice"):
        store.append([rec])
    with pytest.raises(ValueError, match="repeated in the batch"):
        store.append([replace(rec, idx="new"), replace(rec, idx="new")])
    store.path.write_text(store.path.read_text() + rec.to_json() + "\n")
    with pytest.raises(ValueError, match=r"predictions\.jsonl:3: .* duplicates line 1"):
        read_predictions(store.path)


def test_a_second_writer_of_the_same_run_directory_is_refused(vlm_set: Path, tmp_path: Path):
    from probes.vlm.evaluate import make_manifest

    manifest = make_manifest(RandomAnswerer(0), vlm_set, circular=False)
    with PredictionStore(tmp_path / "r") as first:
        first.open(manifest)
        with pytest.raises(RunDirectoryBusy, match="another process is writing this run directory"):
            evaluate(RandomAnswerer(0), vlm_set, tmp_path / "r", progress=False)
    assert evaluate(RandomAnswerer(0), vlm_set, tmp_path / "r", progress=False).answered == 18  # released


KILL_SCRIPT = """
import sys, time
from probes.vlm.evaluate import evaluate
from probes.vlm.tiny import build_tiny_answerer

answerer = build_tiny_answerer("qwen2_vl", cache_dir=sys.argv[3])
slow = float(sys.argv[4])
inner = answerer.answer
def answer(prompts):
    out = inner(prompts)
    time.sleep(slow)  # slow batches: the parent kills this process between or inside them
    return out
answerer.answer = answer
evaluate(answerer, sys.argv[1], sys.argv[2], batch_size=2, progress=False)
"""


def test_sigkill_mid_run_then_rerun_equals_an_uninterrupted_run(vlm_set: Path, tiny_cache: Path, tmp_path: Path,
                                                                one_thread):
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "HF_HUB_OFFLINE": "1"}
    cmd = [sys.executable, "-c", KILL_SCRIPT, str(vlm_set)]
    killed = tmp_path / "killed"
    proc = subprocess.Popen([*cmd, str(killed), str(tiny_cache), "0.4"], env=env, cwd=REPO,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)  # fmt: skip
    path = killed / PREDICTIONS_FILE
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if path.is_file() and path.read_bytes().count(b"\n") >= 6:  # three batches of two written
            break
        time.sleep(0.05)
    assert proc.poll() is None, f"the run ended before it could be killed: {proc.stderr.read().decode()[-2000:]}"
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    partial = read_predictions(path)
    assert 6 <= len(partial) < 18
    # the re-run and the uninterrupted reference run here (the model is the same file: same weights)
    from probes.vlm.tiny import build_tiny_answerer

    answerer = build_tiny_answerer("qwen2_vl", cache_dir=str(tiny_cache))
    rerun = evaluate(answerer, vlm_set, killed, batch_size=2, progress=False)
    assert (rerun.already_done, rerun.answered) == (len(partial), 18 - len(partial))
    evaluate(answerer, vlm_set, tmp_path / "whole", batch_size=2, progress=False)
    resumed, whole = read_predictions(path), read_predictions(tmp_path / "whole" / PREDICTIONS_FILE)
    assert len(resumed) == 18 and len({(r.idx, r.rotation) for r in resumed}) == 18
    assert _keys(resumed) == _keys(whole)
    assert _keys(resumed[: len(partial)]) == _keys(partial)  # what survived the kill was kept as written
