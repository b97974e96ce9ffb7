"""Scoring of a run directory on hand-computed examples: macro aggregation (strict and lenient apart),
coverage, constant-letter and chance baselines, circular evaluation, and the sequence bootstrap's interval
width on known cases (identical sequences: zero; Bernoulli p: the analytic +-1.96 sqrt(p(1-p)/n))."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from newtphys import vqa_schema as vs
from newtphys.vqa_scoring import macro_accuracy
from probes.vlm.bootstrap import bootstrap_ci, build_table, point_estimate
from probes.vlm.predictions import manifest_set_dir
from probes.vlm.scoring import item_results, score_run
from tests.fixtures.vlm_runs import item, write_run, write_set

MASS, HEAVIEST = "F_MASS_OBJECT", "F_MASS_HEAVIEST_OBJECT"
DENSITY, DISTANCE = "F_PHYSICS_PROPERTY_DENSITY_OBJECT", "F_DISTANCE_OBJECT_OBJECT"
OCCLUSION = "F_OCCLUSION_PERCENTAGE_OBJECT"  # generated, reported apart from the analysis


def _hand_set(tmp_path: Path) -> Path:
    items = [
        item("a1/single", "s1", MASS),
        item("a2/single", "s1", MASS),
        item("b1/single", "s2", HEAVIEST),
        item("c1/single", "s2", DENSITY),
        item("d1/single", "s3", DISTANCE),
        item("d2/single", "s3", DISTANCE),
        item("e1/single", "s3", OCCLUSION),
        item("a1/roi_masked/single", "s1", MASS, variant="roi_masked", pair="a1/roi_masked"),
    ]
    answers = {
        "a1/single": "A",
        "a2/single": "B",
        "b1/single": "C",
        "c1/single": "D",
        "d1/single": "A",
        "d2/single": "A",
        "e1/single": "B",
        "a1/roi_masked/single": "A",
    }
    return write_set(tmp_path / "vqa" / "test", items, answers)


def test_macro_aggregation_coverage_and_baselines_by_hand(tmp_path: Path) -> None:
    set_dir = _hand_set(tmp_path)
    preds = {
        ("a1/single", 0): "A",
        ("a2/single", 0): "C",
        ("b1/single", 0): "C",
        ("c1/single", 0): (None, "D"),
        ("d2/single", 0): "A",
        ("e1/single", 0): "B",
        ("a1/roi_masked/single", 0): "B",
    }  # d1 missing
    run = write_run(tmp_path / "run", set_dir, preds)
    s = score_run(run, n_boot=200)  # set from the manifest
    # ids: mass 1/2, heaviest 1, density 0 (nothing extracted), distance 1/2 (d1 missing = wrong)
    assert s["strict"]["question_id"] == {DISTANCE: 0.5, MASS: 0.5, HEAVIEST: 1.0, DENSITY: 0.0}
    assert s["strict"]["sub_category"] == {"mass": 0.75, "density": 0.0, "distance": 0.5}
    assert s["strict"]["category"] == {"material_understanding": 0.375, "spatial_reasoning": 0.5}
    assert s["strict"]["overall"] == 0.4375 and s["strict"]["micro"] == 0.5
    assert s["lenient"]["overall"] == (0.875 + 0.5) / 2  # density right when the option text counts
    assert s["coverage"] == {
        "items": 6,
        "predicted": 5,
        "missing": 1,
        "unextracted_strict": 1,
        "not_asked": {"multi": 0, "too_many_images": 0, "mode": 0, "limit": 0},
    }
    assert s["strict"]["n_sequences"] == 3
    # constant letter: answers A B C D A A; "A everywhere" -> mass .25, density 0, distance 1 -> .5625
    cl = s["baseline_details"]["constant_letter"]
    assert cl["letter"] == "A" and cl["overall"] == 0.5625 and cl["best_share"] == 0.5
    assert cl["macro_per_letter"] == {"A": 0.5625, "B": 0.0625, "C": 0.125, "D": 0.25}
    assert cl["category_best"] == {"material_understanding": 0.5, "spatial_reasoning": 1.0}  # D there, A here
    assert s["baseline_details"]["text_prior"]["abstained"] == 6  # no question text repeats across sequences
    assert s["baselines"] == {"chance": 0.25, "constant_A": 0.5625, "constant_B": 0.0625, "constant_C": 0.125,
                              "constant_D": 0.25, "prior": 0.25}  # fmt: skip
    assert s["best_trivial"] == {"name": "constant_A", "overall": 0.5625}  # beats this model's 0.4375
    assert s["items"] == 6 and s["extracted_share"] == 0.8 and s["circular"] is False
    # the variant and the excluded id are reported apart, never in the headline
    assert (
        s["variants"]["roi_masked"]["strict"]["overall"] == 0.0
        and s["variants"]["roi_masked"]["n_items"] == 1
    )
    assert s["excluded_from_analysis"] == {"n_items": 1, "question_id": {OCCLUSION: 1.0}}
    assert s["rotation0"] is None and s["by_mode"]["single"]["strict"] == 0.4375
    assert json.loads((run / "scores.json").read_text())["strict"]["overall"] == 0.4375


def test_modes_from_the_manifest_restrict_the_scope(tmp_path: Path) -> None:
    items = [item("p/single", "s1", MASS), item("p/multi", "s1", MASS, mode="multi")]
    set_dir = write_set(tmp_path / "vqa" / "test", items, {"p/single": "A", "p/multi": "B"})
    run = write_run(tmp_path / "run", set_dir, {("p/single", 0): "A"}, extra={"modes": ["single"]})
    s = score_run(run, n_boot=0)
    assert (
        s["coverage"]["items"] == 1 and s["strict"]["overall"] == 1.0 and s["protocol"]["modes"] == ["single"]
    )
    assert s["coverage"]["not_asked"]["mode"] == 1
    both = write_run(
        tmp_path / "both", set_dir, {("p/single", 0): "A"}
    )  # asked everything: multi missing = wrong
    s_all = score_run(both, n_boot=0)
    assert s_all["strict"]["overall"] == 0.5 and s_all["coverage"]["missing"] == 1
    assert (
        score_run(both, n_boot=0, modes=["single"], write=False)["strict"]["overall"] == 1.0
    )  # restrict further


def test_only_the_items_the_model_was_asked_are_scored(tmp_path: Path) -> None:
    items = [
        item("p/single", "s1", MASS),
        item("p/multi", "s1", MASS, mode="multi"),
        item("q/single", "s2", MASS),
        item("r/single", "s3", MASS),
    ]
    many = vs.QuestionItem(**{**item("r/single", "s3", MASS).__dict__, "images": ("a.png", "b.png", "c.png")})
    items[3] = many
    set_dir = write_set(tmp_path / "vqa" / "test", items, {it.idx: "A" for it in items})
    preds = {("p/single", 0): "A", ("q/single", 0): "B"}
    run = write_run(
        tmp_path / "run", set_dir, preds, model={"id": "m", "single_image_only": True, "max_images": 2}
    )
    s = score_run(run, n_boot=0)  # asked: p/single, q/single (multi and 3-image items never were)
    assert s["coverage"]["items"] == 2 and s["coverage"]["missing"] == 0 and s["strict"]["overall"] == 0.5
    assert s["coverage"]["not_asked"] == {"multi": 1, "too_many_images": 1, "mode": 0, "limit": 0}
    run2 = write_run(tmp_path / "run2", set_dir, preds, extra={"limit": 1})  # smoke run: the first item only
    s2 = score_run(run2, n_boot=0)
    assert (
        s2["coverage"]["items"] == 1
        and s2["strict"]["overall"] == 1.0
        and s2["coverage"]["not_asked"]["limit"] == 3
    )


def test_the_set_is_found_from_either_manifest_form(tmp_path: Path) -> None:
    set_dir = write_set(tmp_path / "vqa" / "test", [item("p/single", "s1", MASS)], {"p/single": "A"})
    assert manifest_set_dir({"vqa_dir": str(set_dir), "split": "test"}) == set_dir  # the split directory
    assert manifest_set_dir({"vqa_dir": str(set_dir.parent), "split": "test"}) == set_dir  # the root + split
    with pytest.raises(
        FileNotFoundError,
        match=r"vqa_dir='/nowhere': no question set found \(tried /nowhere/questions.jsonl, "
        r"/nowhere/test/questions.jsonl\)",
    ):
        manifest_set_dir({"vqa_dir": "/nowhere", "split": "test"})


def test_circular_evaluation_needs_all_four_rotations(tmp_path: Path) -> None:
    items = [item("x/single", "s1", MASS), item("y/single", "s2", MASS), item("z/single", "s3", MASS)]
    set_dir = write_set(tmp_path / "vqa" / "test", items, {"x/single": "A", "y/single": "B", "z/single": "C"})
    preds = {
        **{("x/single", r): "A" for r in range(4)},  # right in every rotation
        **{("y/single", r): "B" for r in range(3)},  # rotation 3 missing
        **{("z/single", r): ("C" if r != 2 else "D") for r in range(4)},
    }  # wrong in rotation 2
    s = score_run(write_run(tmp_path / "run", set_dir, preds, circular=True), n_boot=0)
    assert s["circular"] is True and s["strict"]["overall"] == pytest.approx(1 / 3)  # x only
    assert s["rotation0"]["strict"]["overall"] == 1.0  # rotation 0 alone: the paper's number, apart
    assert s["baselines"]["chance"] == 0.25**4 and s["baselines"]["constant_A"] == 0.0


def test_bad_runs_are_refused_with_the_file_and_key(tmp_path: Path) -> None:
    set_dir = _hand_set(tmp_path)
    run = write_run(tmp_path / "run", set_dir, {("a1/single", 0): "A"})
    (run / "predictions.jsonl").write_text((run / "predictions.jsonl").read_text() * 2)
    with pytest.raises(ValueError, match=r"predictions.jsonl:2: prediction for idx='a1/single' rotation=0 duplicates line 1"):
        item_results(run, set_dir)
    run2 = write_run(tmp_path / "run2", set_dir, {("nope/single", 0): "A"})
    with pytest.raises(ValueError, match=r"1 idx not in .*questions.jsonl, e.g. \['nope/single'\]"):
        item_results(run2, set_dir)
    other = write_set(tmp_path / "other" / "test", [item("q/single", "s1", MASS)], {"q/single": "A"})
    with pytest.raises(ValueError, match="predictions of another set"):
        item_results(run, other)


def test_bootstrap_matches_macro_accuracy_and_is_seeded() -> None:
    rng = np.random.default_rng(3)
    qids = [MASS, HEAVIEST, DENSITY, DISTANCE]
    rows = []
    for k in range(300):
        q = qids[k % 4]
        it = item(f"i{k}/single", f"s{k % 37}", q)
        rows.append((it.sequence_id, q, it.sub_category, it.category, float(rng.random() < 0.6)))
    table = build_table(rows)
    ref = macro_accuracy(
        {"question_id": r[1], "sub_category": r[2], "category": r[3], "correct": r[4] == 1.0} for r in rows
    )
    pe = point_estimate(table)
    assert pe["overall"] == pytest.approx(ref["overall"], abs=1e-12)
    assert pe["category"] == pytest.approx(ref["category"]) and pe["question_id"] == pytest.approx(
        ref["question_id"]
    )
    assert bootstrap_ci(table, 300, seed=5) == bootstrap_ci(table, 300, seed=5)
    assert bootstrap_ci(table, 300, seed=5)["overall"] != bootstrap_ci(table, 300, seed=6)["overall"]


def test_identical_sequences_give_a_zero_width_interval() -> None:
    rows = [
        (f"s{k}", MASS, "mass", "material_understanding", float(j == 0)) for k in range(20) for j in range(2)
    ]
    ci = bootstrap_ci(build_table(rows), n_boot=500, seed=0)
    assert ci["overall"] == [0.5, 0.5] and ci["overall_se"] == 0.0


def test_bernoulli_interval_matches_the_analytic_width() -> None:
    n, p = 2000, 0.3  # one item per sequence, exactly 600 right
    rows = [(f"s{k}", MASS, "mass", "material_understanding", float(k < p * n)) for k in range(n)]
    ci = bootstrap_ci(build_table(rows), n_boot=2000, seed=1)
    half = 1.96 * math.sqrt(p * (1 - p) / n)  # 0.0201
    lo, hi = ci["overall"]
    assert (hi - lo) / 2 == pytest.approx(half, rel=0.1)
    assert (lo + hi) / 2 == pytest.approx(p, abs=0.003)


def test_resampling_sequences_not_items_widens_the_interval_for_correlated_items() -> None:
    # 50 sequences of 10 items each, a sequence all right or all wrong: 50 independent draws, not 500
    rows = [
        (f"s{k}", MASS, "mass", "material_understanding", float(k % 2)) for k in range(50) for _ in range(10)
    ]
    lo, hi = bootstrap_ci(build_table(rows), n_boot=2000, seed=2)["overall"]
    assert (hi - lo) / 2 == pytest.approx(1.96 * math.sqrt(0.25 / 50), rel=0.12)  # 0.139, not 0.044
