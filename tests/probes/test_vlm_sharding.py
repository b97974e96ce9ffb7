"""Sharding a set by sequence (disjoint, complete, balanced, independent of line order) and merging shard run
directories (manifests agree, no duplicates, every shard and every item there; the merge scores like the
unsharded run); the launcher configs compose with the submitit plugin."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest

from newtphys import vqa_schema as vs
from probes.vlm.scoring import score_run
from probes.vlm.sharding import main, merge_runs, shard_items, shard_of_sequences
from tests.fixtures.vlm_runs import item, write_run, write_set

SIZES = {"s_a": 5, "s_b": 4, "s_c": 3, "s_d": 3, "s_e": 2, "s_f": 1}


def _items() -> list[vs.QuestionItem]:
    return [item(f"{seq}-{k}/single", seq, "F_MASS_OBJECT") for seq, n in SIZES.items() for k in range(n)]


def test_whole_sequences_dealt_largest_first_to_the_lightest_shard() -> None:
    items = _items()
    # s_a(5)->0, s_b(4)->1, s_c(3)->1 (4<5), s_d(3)->0 (5<7), s_e(2)->1 (7<8), s_f(1)->0 (8<9): 9 and 9 items
    assert shard_of_sequences(items, 2) == {"s_a": 0, "s_b": 1, "s_c": 1, "s_d": 0, "s_e": 1, "s_f": 0}
    shards = [shard_items(items, k, 2) for k in range(2)]
    assert [len(s) for s in shards] == [9, 9]
    assert {it.sequence_id for it in shards[0]} == {"s_a", "s_d", "s_f"}
    assert shards[0] == [it for it in items if it.sequence_id in ("s_a", "s_d", "s_f")]  # set order kept
    shuffled = items[:]
    random.Random(0).shuffle(shuffled)
    assert shard_of_sequences(shuffled, 2) == shard_of_sequences(items, 2)  # the set decides, not its order
    for n in (1, 3, 4, 7):
        parts = [shard_items(items, k, n) for k in range(n)]
        assert sorted(it.idx for p in parts for it in p) == sorted(
            it.idx for it in items
        )  # disjoint and complete
        owners = {(it.sequence_id, k) for k, p in enumerate(parts) for it in p}
        assert len(owners) == len(SIZES)  # every sequence in exactly one shard
    assert shard_items(items, 0, 1) == items


def test_bad_shard_arguments_name_the_allowed_range() -> None:
    with pytest.raises(ValueError, match=r"shard_index=2, must be an integer in \[0, 1\] \(num_shards=2\)"):
        shard_items(_items(), 2, 2)
    with pytest.raises(ValueError, match=r"num_shards=0, must be an integer >= 1"):
        shard_items(_items(), 0, 0)


def _sharded_runs(tmp_path: Path, n: int = 3) -> tuple[Path, list[Path], dict]:
    items = _items()
    letters = {it.idx: "ABCD"[k % 4] for k, it in enumerate(items)}
    set_dir = write_set(tmp_path / "vqa" / "test", items, letters)
    preds = {(it.idx, 0): ("ABCD"[k % 3]) for k, it in enumerate(items)}
    runs = []
    for k in range(n):
        mine = {(it.idx, 0): preds[(it.idx, 0)] for it in shard_items(items, k, n)}
        extra = {"shard_index": k, "num_shards": n, "batch_size": 8}
        runs.append(write_run(tmp_path / f"shard{k}", set_dir, mine, extra=extra))
    return set_dir, runs, preds


def test_merged_shards_equal_the_unsharded_run(tmp_path: Path) -> None:
    set_dir, runs, preds = _sharded_runs(tmp_path)
    summary = merge_runs(runs[::-1], tmp_path / "merged")  # any order
    assert summary == {
        "shards": 3,
        "predictions": 18,
        "expected": 18,
        "missing": 0,
        "out_dir": str(tmp_path / "merged"),
    }
    whole = write_run(tmp_path / "whole", set_dir, preds)
    lines = (tmp_path / "merged" / "predictions.jsonl").read_text()
    assert lines == (whole / "predictions.jsonl").read_text()  # same records, in set order
    manifest = json.loads((tmp_path / "merged" / "manifest.json").read_text())
    extra = manifest["extra"]
    assert "shard_index" not in extra and "num_shards" not in extra and extra["batch_size"] == 8
    assert [(m["shard_index"], m["num_shards"]) for m in extra["merged_from"]] == [(2, 3), (1, 3), (0, 3)]
    a, b = score_run(tmp_path / "merged", n_boot=50), score_run(whole, n_boot=50)
    assert a["strict"] == b["strict"] and a["coverage"] == b["coverage"]
    with pytest.raises(FileExistsError, match="merge into a new directory"):
        merge_runs(runs, tmp_path / "merged")


def test_merge_refuses_disagreeing_duplicate_missing_and_incomplete(tmp_path: Path) -> None:
    set_dir, runs, _ = _sharded_runs(tmp_path)
    with pytest.raises(ValueError, match=r"num_shards=3 but shard_index \[0, 1\]: missing \[2\]"):
        merge_runs(runs[:2], tmp_path / "m1")
    extra = {"shard_index": 2, "num_shards": 3, "batch_size": 8}
    other = write_run(tmp_path / "other", set_dir, {}, answerer="another-model", extra=extra)
    with pytest.raises(
        ValueError, match=r"disagrees with .* on \['answerer', 'model'\]: answerer='another-model'"
    ):
        merge_runs([*runs[:2], other], tmp_path / "m2")
    first_idx = next(
        iter(json.loads(line)["idx"] for line in (runs[0] / "predictions.jsonl").read_text().splitlines())
    )
    with open(runs[1] / "predictions.jsonl", "a") as f:
        f.write((runs[0] / "predictions.jsonl").read_text().splitlines()[0] + "\n")
    with pytest.raises(ValueError, match=rf"idx='{first_idx}' rotation=0 in both .*shard0.* and .*shard1"):
        merge_runs(runs, tmp_path / "m3")
    _, runs, _ = _sharded_runs(tmp_path / "b")
    lines = (runs[2] / "predictions.jsonl").read_text().splitlines()
    (runs[2] / "predictions.jsonl").write_text("\n".join(lines[1:]) + "\n")  # one item lost
    with pytest.raises(ValueError, match=r"misses 1 of 18 \(idx, rotation\)"):
        merge_runs(runs, tmp_path / "b" / "m4")
    main(["merge", *map(str, runs), "--out", str(tmp_path / "b" / "m5"), "--allow-incomplete"])
    assert len((tmp_path / "b" / "m5" / "predictions.jsonl").read_text().splitlines()) == 17
    assert not (tmp_path / "b" / "m5" / "scores.json").exists()  # an incomplete merge is not scored


@pytest.mark.parametrize("launcher", ["vlm_slurm", "vlm_local_gpus"])
def test_shard_launchers_compose_with_the_submitit_plugin(launcher: str) -> None:
    from hydra import compose, initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra

    GlobalHydra.instance().clear()
    conf = Path(__file__).resolve().parents[2] / "newtphys" / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        cfg = compose(config_name="train", overrides=[f"hydra/launcher={launcher}"], return_hydra_config=True)
    GlobalHydra.instance().clear()
    assert cfg.hydra.launcher.gpus_per_node == 1 and cfg.hydra.launcher.tasks_per_node == 1
    assert cfg.hydra.launcher._target_.endswith(
        "SlurmLauncher" if launcher == "vlm_slurm" else "LocalLauncher"
    )
