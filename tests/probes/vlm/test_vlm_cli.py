"""The command line: the composed ``evaluate_vlm`` config answers, scores and logs (W&B offline) a set; blind
and circular runs get their own directories; ``scores.json`` comes from ``probes.vlm.scoring.score_run``
when that module exists; a Hydra multirun sweeps answerers."""

from __future__ import annotations

import importlib.machinery
import json
import os
import subprocess
import sys
import types
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
    assert scores["strict"]["overall"] == 1.0 and scores["baselines"]["constant_A"] == pytest.approx(5 / 18)
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


def test_scores_come_from_scoring_score_run_when_it_exists(vlm_set: Path, tmp_path: Path, monkeypatch):
    calls = []
    fake = types.ModuleType("probes.vlm.scoring")
    fake.__spec__ = importlib.machinery.ModuleSpec("probes.vlm.scoring", loader=None)

    def score_run(run_dir, set_dir):
        calls.append((Path(run_dir), Path(set_dir)))
        return {"scorer": "fake", "strict": {"overall": {"value": 1.0, "ci95": [1.0, 1.0]}}}

    fake.score_run = score_run
    monkeypatch.setitem(sys.modules, "probes.vlm.scoring", fake)
    out = run(_cfg("oracle", vlm_set, tmp_path, "wandb.enabled=false"))
    assert calls == [(out["run_dir"], vlm_set)]
    assert json.loads((out["run_dir"] / "scores.json").read_text())["scorer"] == "fake"


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
    # the prior answering through the loop scores what the scorer's prior baseline computes from the set
    assert scores["prior"]["strict"]["overall"] == scores["oracle"]["baselines"]["prior"]


def test_the_logged_config_says_the_weights_are_random(vlm_set: Path, tiny_cache: Path, tmp_path: Path, monkeypatch,
                                                       one_thread):  # fmt: skip
    monkeypatch.setenv("WANDB_MODE", "offline")
    out = run(_cfg("tiny_idefics3", vlm_set, tmp_path, f"vlm.cache_dir={tiny_cache}", "limit=4", "batch_size=4"))
    assert out["result"].answered == 4 and out["scores"]["weights"] == "random"
    (log_file,) = (out["run_dir"] / "wandb").glob("offline-run-*/run-*.wandb")
    logged = log_file.read_bytes()  # the offline run's records: the config is stored as JSON text
    assert b'"weights":"random"' in logged and b'"fixture":"TEST FIXTURE' in logged
    assert b'"id":"newtphys/tiny-random-idefics3"' in logged
