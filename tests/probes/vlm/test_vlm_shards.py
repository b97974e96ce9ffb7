"""Sharded runs through the evaluation loop and the command line: N jobs answer whole sequences into shard
directories; the merge gives the predictions of one unsharded run line for line, and the merge CLI scores the
merged run. (Shard assignment and merge checks on hand-made runs: tests/probes/test_vlm_sharding.py.)"""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from newtphys.config import compose_config
from probes.vlm.cli import run
from probes.vlm.evaluate import evaluate
from probes.vlm.interface import PREDICTIONS_FILE
from probes.vlm.predictions import read_predictions
from probes.vlm.sharding import main as sharding_main
from probes.vlm.sharding import merge_runs, shard_dir, shard_run_dirs
from tests.probes.vlm.conftest import SEQUENCES


def _keys(path: Path) -> list[tuple]:
    return [(r.idx, r.rotation, r.raw, r.letter, r.letter_lenient, r.tokens_in) for r in read_predictions(path)]


def test_three_shards_merge_into_the_unsharded_run(vlm_set: Path, tiny_cache: Path, tmp_path: Path, one_thread):
    from probes.vlm.tiny import build_tiny_answerer

    answerer = build_tiny_answerer("qwen2_vl", cache_dir=str(tiny_cache))
    evaluate(answerer, vlm_set, tmp_path / "whole", batch_size=2, progress=False)
    run_dir = tmp_path / "sharded"
    for k in range(3):
        result = evaluate(answerer, vlm_set, shard_dir(run_dir, k, 3), batch_size=2, shard_index=k, num_shards=3,
                          progress=False)  # fmt: skip
        preds = read_predictions(shard_dir(run_dir, k, 3) / PREDICTIONS_FILE)
        # 3 sequences of 6 items, dealt one per shard in sequence_id order (equal counts): shard k = sequence k
        assert result.items == 6 and {p.idx.split("/")[0] for p in preds} == {SEQUENCES[k]}
        manifest = json.loads((shard_dir(run_dir, k, 3) / "manifest.json").read_text())
        assert (manifest["extra"]["shard_index"], manifest["extra"]["num_shards"]) == (k, 3)
    dirs = shard_run_dirs(run_dir)
    assert [d.name for d in dirs] == ["0-of-3", "1-of-3", "2-of-3"]
    out = merge_runs(dirs, run_dir)
    assert (out["shards"], out["predictions"], out["missing"]) == (3, 18, 0)
    # a sequence holds 6 items = 3 whole batches of 2, so every batch (padding included) is the unsharded one's
    assert _keys(run_dir / PREDICTIONS_FILE) == _keys(tmp_path / "whole" / PREDICTIONS_FILE)
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert "shard_index" not in manifest["extra"] and manifest["model"]["weights"] == "random"
    assert [m["shard_index"] for m in manifest["extra"]["merged_from"]] == [0, 1, 2]


def test_bad_shard_is_refused_before_answering(vlm_set: Path, tmp_path: Path):
    from probes.vlm.baselines import ConstantLetterAnswerer

    with pytest.raises(ValueError, match=r"shard_index=2, must be an integer in \[0, 1\] \(num_shards=2\)"):
        evaluate(ConstantLetterAnswerer("A"), vlm_set, tmp_path / "x", shard_index=2, num_shards=2, progress=False)
    assert not (tmp_path / "x").exists()


def test_cli_shards_then_merge_cli_scores(vlm_set: Path, tmp_path: Path, capsys, monkeypatch):
    monkeypatch.setenv("CUDA_VISIBLE_DEVICES", "")  # restored after the test (the run sets it)
    base = tmp_path / "vqa-test" / "oracle"
    for k in range(2):
        out = run(compose_config("evaluate_vlm", ["vlm=oracle", f"vqa_dir={vlm_set}", f"results_dir={tmp_path}",
                                                  "progress=false", "wandb.enabled=false", "batch_size=4",
                                                  "num_shards=2", f"shard_index={k}", "shard_gpus=[3,5]"]))  # fmt: skip
        assert out["run_dir"] == shard_dir(base, k, 2) and out["scores"] == {}
        assert os.environ["CUDA_VISIBLE_DEVICES"] == "35"[k]  # job k pinned to shard_gpus[k]
    # 3 sequences of 6 items into 2 shards: seq-a -> 0, seq-b -> 1, seq-c -> 0 (lighter, lower index): 12 + 6
    assert [len(read_predictions(d / PREDICTIONS_FILE)) for d in shard_run_dirs(base)] == [12, 6]
    with pytest.raises(ValueError, match=r"num_shards=2 but shard_index \[0\]: missing \[1\]"):
        merge_runs(shard_run_dirs(base)[:1], tmp_path / "half")
    sharding_main(["merge", str(base)])
    assert '"predictions": 18' in capsys.readouterr().out
    scores = json.loads((base / "scores.json").read_text())
    assert scores["strict"]["overall"] == 1.0 and scores["items"] == 18
    assert scores["strict"]["ci"]["overall"] == [1.0, 1.0]  # every bootstrap replicate of an oracle is 1
