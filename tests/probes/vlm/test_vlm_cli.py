"""The command line: the composed ``evaluate_vlm`` config answers, scores (``probes.vlm.scoring.score_run``)
and logs (W&B offline) a set; blind and circular runs get their own directories; a Hydra multirun sweeps
answerers."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from newtphys.config import compose_config
from probes.vlm.cli import run

REPO = Path(__file__).resolve().parents[3]


def _cfg(vlm: str, set_dir: Path, results: Path, *extra: str):
    return compose_config("evaluate_vlm", [f"vlm={vlm}", f"vqa_dir={set_dir}", f"results_dir={results}",
                                           "progress=false", "wandb.offline=true", *extra])  # fmt: skip


def test_cli_answers_scores_and_logs_offline(vlm_set: Path, tmp_path: Path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    out = run(_cfg("oracle", vlm_set, tmp_path))
    run_dir = tmp_path / "vqa-test" / "oracle"
    assert out["run_dir"] == run_dir and out["scores"]["strict"]["overall"] == 1.0
    scores = json.loads((run_dir / "scores.json").read_text())
    assert scores["scorer"].startswith("probes.vlm.scoring") and scores["protocol"]["n_boot"] == 1000
    assert scores["strict"]["overall"] == 1.0 and scores["strict"]["ci"]["overall"] == [1.0, 1.0]
    assert scores["baselines"]["constant_A"] == pytest.approx(5 / 18)
    assert scores["best_trivial"]["overall"] == max(scores["baselines"].values())
    assert list((run_dir / "wandb").glob("offline-run-*")), "no offline W&B run written"
    # vqa_dir may be the set root with split=...
    again = run(_cfg("oracle", vlm_set.parent, tmp_path, "split=test", "wandb.enabled=false"))
    assert again["result"].answered == 0 and again["result"].already_done == 18
    # blind and circular: own run directories, own manifests
    blind = run(_cfg("constant_letter", vlm_set, tmp_path, "blind=true", "circular=true", "vlm.letter=C",
                     "wandb.enabled=false"))  # fmt: skip
    assert blind["run_dir"] == tmp_path / "vqa-test" / "constant_C-blind-circular"
    manifest = json.loads((blind["run_dir"] / "manifest.json").read_text())
    assert manifest["circular"] is True and manifest["model"]["blind"] is True
    # constant C in circular mode: the rotated prompts show the correct option under C only at one rotation
    assert blind["scores"]["strict"]["overall"] == 0.0
    with pytest.raises(FileNotFoundError, match="no question set found"):
        run(_cfg("random", tmp_path / "nowhere", tmp_path))


def test_multirun_sweeps_answerers(vlm_set: Path, tmp_path: Path):
    env = {**os.environ, "PYTHONPATH": str(REPO), "WANDB_MODE": "offline", "HF_HUB_OFFLINE": "1"}
    proc = subprocess.run(
        [sys.executable, "evaluate_vlm.py", "-m", "vlm=random,oracle,prior", f"vqa_dir={vlm_set}",
         f"results_dir={tmp_path / 'res'}", f"hydra.sweep.dir={tmp_path / 'sweep'}", "wandb.enabled=false",
         "progress=false"],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=300, check=False,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    scores = {p.name: json.loads((p / "scores.json").read_text()) for p in (tmp_path / "res" / "vqa-test").iterdir()}
    assert set(scores) == {"random", "oracle", "prior"} and scores["oracle"]["strict"]["overall"] == 1.0
    # The text prior on the 18 items, by hand (leave-one-sequence-out; conftest.ANSWERS): mass single picks
    # the option nearest the others' median -> right for seq-b only (1/3), mass multi 2/3, size 6/6, material
    # 2/3 (wood, wood, wood vs A A B); the temporal items have image options: the prior abstains on all 3.
    # Macro: material_understanding = (mass 3/6 + material 2/3) / 2 = 7/12, spatial_reasoning = 1.
    # The reported baseline counts an abstention at its expected 0.25: (7/12 + 1 + 1/4) / 3 = 11/18.
    oracle = scores["oracle"]
    assert oracle["baselines"]["prior"] == pytest.approx(11 / 18)
    assert oracle["baseline_details"]["text_prior"]["abstained"] == 3
    # The prior *answerer* must reply a letter: it guesses by hashed_index(seed 0) where the prior abstains:
    # A, D, C for seq-a, -b, -c against answers A, B, D -> 1/3 on temporal: (7/12 + 1 + 1/3) / 3 = 23/36.
    prior = scores["prior"]["strict"]
    assert prior["category"] == pytest.approx({"material_understanding": 7 / 12, "spatial_reasoning": 1.0,
                                               "temporal": 1 / 3})  # fmt: skip
    assert prior["overall"] == pytest.approx(23 / 36)
    # where the prior has evidence, the answerer and the baseline agree category by category
    assert oracle["baseline_details"]["text_prior"]["category"] == pytest.approx(
        {**prior["category"], "temporal": 0.25})


def test_the_logged_config_says_the_weights_are_random(vlm_set: Path, tiny_cache: Path, tmp_path: Path, monkeypatch,
                                                       one_thread):  # fmt: skip
    monkeypatch.setenv("WANDB_MODE", "offline")
    out = run(_cfg("tiny_idefics3", vlm_set, tmp_path, f"vlm.cache_dir={tiny_cache}", "limit=4", "batch_size=4"))
    assert out["result"].answered == 4 and out["scores"]["weights"] == "random"
    (log_file,) = (out["run_dir"] / "wandb").glob("offline-run-*/run-*.wandb")
    # the offline run's records (the config is stored as JSON text); wandb-core may still be writing them
    # after run.finish() returns on a loaded machine, so wait for the config record (at most 30 s)
    deadline = time.monotonic() + 30.0
    while b'"weights":"random"' not in (logged := log_file.read_bytes()) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert b'"weights":"random"' in logged and b'"fixture":"TEST FIXTURE' in logged
    assert b'"id":"newtphys/tiny-random-idefics3"' in logged
