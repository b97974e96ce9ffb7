"""Sharded runs: N jobs answer disjoint batches into shard directories; the merge gives the predictions of one
unsharded run line for line (same batches: same padding, same replies), refuses disagreeing or missing
shards, and the CLI scores the merged run."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from newtphys.config import compose_config
from probes.vlm.baselines import ConstantLetterAnswerer
from probes.vlm.cli import run
from probes.vlm.evaluate import evaluate
from probes.vlm.interface import PREDICTIONS_FILE
from probes.vlm.merge import main as merge_main
from probes.vlm.merge import merge_shards, shard_dir
from probes.vlm.predictions import MixedRunError, read_predictions


def _keys(path: Path) -> list[tuple]:
    return [(r.idx, r.rotation, r.raw, r.letter, r.letter_lenient, r.tokens_in) for r in read_predictions(path)]


def test_three_shards_merge_into_the_unsharded_run(vlm_set: Path, tiny_cache: Path, tmp_path: Path, one_thread):
    from probes.vlm.tiny import build_tiny_answerer

    answerer = build_tiny_answerer("qwen2_vl", cache_dir=str(tiny_cache))
    evaluate(answerer, vlm_set, tmp_path / "whole", batch_size=2, progress=False)
    run_dir = tmp_path / "sharded"
    sizes = []
    for k in range(3):
        evaluate(answerer, vlm_set, shard_dir(run_dir, k, 3), batch_size=2, shard=(k, 3), progress=False)
        sizes.append(len(read_predictions(shard_dir(run_dir, k, 3) / PREDICTIONS_FILE)))
    assert sizes == [6, 6, 6]  # 9 batches of 2 -> batches 0,3,6 / 1,4,7 / 2,5,8
    out = merge_shards(run_dir)
    assert out == {"shards": 3, "predictions": 18, "missing": 0, "set_dir": str(vlm_set.resolve())}
    assert _keys(run_dir / PREDICTIONS_FILE) == _keys(tmp_path / "whole" / PREDICTIONS_FILE)
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["extra"]["merged_shards"] == 3 and manifest["model"]["weights"] == "random"


def test_merge_refuses_missing_disagreeing_or_incomplete_shards(vlm_set: Path, tmp_path: Path):
    run_dir = tmp_path / "r"
    evaluate(ConstantLetterAnswerer("A"), vlm_set, shard_dir(run_dir, 0, 2), batch_size=4, shard=(0, 2), progress=False)
    with pytest.raises(FileNotFoundError, match=r"shards \[1\] of 2 have not started"):
        merge_shards(run_dir)
    evaluate(ConstantLetterAnswerer("B"), vlm_set, shard_dir(run_dir, 1, 2), batch_size=4, shard=(1, 2), progress=False)
    with pytest.raises(MixedRunError, match=r"shard 1 .* differs from shard 0: answerer: 'constant_A' -> 'constant_B'"):
        merge_shards(run_dir)
    other = tmp_path / "o"
    evaluate(ConstantLetterAnswerer("A"), vlm_set, shard_dir(other, 0, 2), batch_size=4, shard=(0, 2), progress=False)
    evaluate(ConstantLetterAnswerer("A"), vlm_set, shard_dir(other, 1, 2), batch_size=4, shard=(1, 2), limit=4,
             progress=False)  # fmt: skip  (a shard that has not finished: items 8-17 of its batches missing)
    with pytest.raises(RuntimeError, match="have no prediction yet"):
        merge_shards(other)
    assert merge_shards(other, allow_incomplete=True)["missing"] > 0
    with pytest.raises(ValueError, match="0 <= index < count"):
        evaluate(ConstantLetterAnswerer("A"), vlm_set, tmp_path / "x", shard=(2, 2), progress=False)


def test_cli_shards_then_merge_module_scores(vlm_set: Path, tmp_path: Path, capsys):
    for k in range(2):
        out = run(compose_config("evaluate_vlm", ["vlm=oracle", f"vqa_dir={vlm_set}", f"results_dir={tmp_path}",
                                                  "progress=false", "wandb.enabled=false", "batch_size=4",
                                                  "shard.count=2", f"shard.index={k}"]))  # fmt: skip
        assert out["run_dir"] == tmp_path / "vqa-test" / "oracle" / "shards" / f"{k}-of-2" and out["scores"] == {}
    merge_main([str(tmp_path / "vqa-test" / "oracle")])
    assert "merged 2 shards: 18 predictions (0 missing)" in capsys.readouterr().out
    scores = json.loads((tmp_path / "vqa-test" / "oracle" / "scores.json").read_text())
    assert scores["strict"]["overall"] == 1.0
