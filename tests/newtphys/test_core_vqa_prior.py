"""The blind-prior audit on hand-built items: leave-one-sequence-out priors, the middle-value heuristic, the
Wilson interval and the chance flag."""

from __future__ import annotations

import pytest

from newtphys import vqa_schema as vs
from newtphys.vqa_prior import CHANCE, TextPrior, audit, middle_value, wilson_interval


def _item(idx: str, seq: str, qid: str, question: str, options: list[str]) -> vs.QuestionItem:
    spec = vs.question_spec(qid)
    return vs.QuestionItem(idx=idx, pair=idx, question_id=qid, category=spec.category,
                           sub_category=spec.sub_category, mode="single", variant="base", split="test",
                           sequence_id=seq, shard="test/shard-00000.h5", frames=(3,), images=("a.png",),
                           question=question, options=tuple(options), objects=(1,),
                           meta={"num_objects": 1, "num_visible": 1, "gravity_m_s2": 9.81})  # fmt: skip


def _answer(idx: str, letter: str) -> vs.AnswerRecord:
    return vs.AnswerRecord(idx, letter, None, "")


LEVEL2 = "F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_2"


def test_text_prior_uses_other_sequences_only() -> None:
    q = "What material is the jar made of?"
    items = [_item("a", "s1", LEVEL2, q, ["plastic", "glass", "metal", "wood"]),
             _item("b", "s2", LEVEL2, q, ["wood", "metal", "glass", "plastic"]),
             _item("c", "s3", LEVEL2, q, ["glass", "plastic", "wood", "metal"])]  # fmt: skip
    answers = {"a": _answer("a", "B"), "b": _answer("b", "C"), "c": _answer("c", "C")}  # glass, glass, wood
    prior = TextPrior(items, answers)
    assert prior.choose(items[0]) == 1  # glass: correct in s2 (its own s1 answer is not used)
    assert prior.choose(items[2]) == 0  # glass elsewhere: wrong here (wood), as a blind model would be
    lone = _item("d", "s9", "F_MASS_OBJECT", "What is the mass of the cup?", ["1 kg", "2 kg", "3 kg", "4 kg"])
    assert TextPrior([lone], {"d": _answer("d", "A")}).choose(lone) is None  # no evidence: abstain


def test_numeric_prior_picks_the_option_nearest_the_median_elsewhere_and_middle_value() -> None:
    q = "What is the mass of the mug?"
    items = [_item("a", "s1", "F_MASS_OBJECT", q, ["0.30 kg", "0.10 kg", "0.90 kg", "2.00 kg"]),
             _item("b", "s2", "F_MASS_OBJECT", q, ["0.05 kg", "0.32 kg", "1.10 kg", "3.00 kg"])]  # fmt: skip
    answers = {"a": _answer("a", "A"), "b": _answer("b", "B")}  # 0.30 and 0.32 kg
    prior = TextPrior(items, answers)
    assert prior.choose(items[0]) == 0 and prior.choose(items[1]) == 1
    assert middle_value(items[0]) == 0  # sorted 0.10, 0.30, 0.90, 2.00: the lower median is 0.30
    assert middle_value(_item("x", "s", LEVEL2, q, ["a", "b", "c", "d"])) is None


def test_wilson_interval_and_the_chance_flag() -> None:
    lo, hi = wilson_interval(8, 10)
    assert (lo, hi) == pytest.approx((0.4902, 0.9433), abs=1e-4)
    q = "From which angle was this image taken?"
    labels = ["high angle", "eye level", "low angle", "bird's-eye view"]
    items, answers = [], {}
    for k in range(12):  # every camera looks down at a high angle: the text alone answers it
        options = labels[k % 4:] + labels[: k % 4]
        items.append(_item(f"i{k}", f"s{k}", "F_VIEWPOINT_CAMERA_ANGLE", q, options))
        answers[f"i{k}"] = _answer(f"i{k}", vs.LETTERS[options.index("high angle")])
    report = audit(items, answers)["F_VIEWPOINT_CAMERA_ANGLE"]
    assert report["best"] == "text_prior" and report["best_accuracy"] == 1.0
    assert report["beats_chance"] and report["interval_95"][0] > CHANCE
