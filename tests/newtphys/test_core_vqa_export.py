"""Exports of a hand-built question set: the VLMEvalKit TSV reads back to the same items, letters and PNG bytes;
the lmms-eval task directory's YAML, docs and hooks score hand-made replies as computed by hand; the prompt,
answer extraction and macro accuracy of newtphys.vqa_scoring on hand cases."""

from __future__ import annotations

import base64
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import yaml
from PIL import Image

from newtphys import vqa_schema as vs
from newtphys import vqa_scoring
from newtphys.cli import main as cli_main
from newtphys.vqa_export import read_vlmevalkit, write_lmms_eval, write_vlmevalkit

CAT = {"F_MASS_OBJECT": ("material_understanding", "mass"),
       "F_MASS_HEAVIEST_OBJECT": ("material_understanding", "mass"),
       "F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_1": ("temporal", "event_ordering")}  # fmt: skip


def _item(idx: str, qid: str, mode: str, frames: list[int], images: list[str], options: list[str]) -> dict:
    category, sub = CAT[qid]
    return {"idx": idx, "pair": idx.rsplit("/", 1)[0], "question_id": qid, "category": category,
            "sub_category": sub, "mode": mode, "variant": "base", "split": "test", "sequence_id": "test-000000",
            "shard": "test/shard-00000.h5", "frames": frames, "images": images, "question": f"Question {idx}?",
            "options": options, "objects": [1],
            "meta": {"num_objects": 2, "num_visible": 2, "gravity_m_s2": 9.81, "young_modulus_pa": 1e6}}  # fmt: skip


@pytest.fixture()
def question_set(tmp_path: Path) -> Path:
    """Three items: one image; three images; one image then four image options (frames 10-14)."""
    root = tmp_path / "vqa" / "test"
    for t in range(10, 15):
        path = root / "images" / "test-000000" / f"{t:06d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.full((4, 6, 3), 10 * t, np.uint8)).save(path)
    img = lambda t: f"images/test-000000/{t:06d}.png"  # noqa: E731
    items = [
        _item("s/F_MASS_OBJECT/1/single", "F_MASS_OBJECT", "single", [12], [img(12)],
              ["0.25 kg", "0.50 kg", "0.75 kg", "1.00 kg"]),
        _item("s/F_MASS_HEAVIEST_OBJECT/h/multi", "F_MASS_HEAVIEST_OBJECT", "multi", [10, 11, 12],
              [img(10), img(11), img(12)], ["mug", "ball", "shoe", "book"]),
        _item("s/NEXT/n/multi", "F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_1", "multi", [10],
              [img(10), img(13), img(11), img(14), img(12)], [vs.IMAGE_OPTION] * 4),
    ]  # fmt: skip
    answers = [{"idx": items[0]["idx"], "answer": "B", "value": 0.5, "unit": "kg"},
               {"idx": items[1]["idx"], "answer": "D", "value": 3, "unit": ""},
               {"idx": items[2]["idx"], "answer": "C", "value": 14, "unit": "frame"}]  # fmt: skip
    (root / vs.QUESTIONS_FILE).write_text("".join(json.dumps(i) + "\n" for i in items))
    (root / vs.ANSWERS_FILE).write_text("".join(json.dumps(a) + "\n" for a in answers))
    return root


def test_vlmevalkit_tsv_round_trips_items_letters_and_png_bytes(question_set: Path, tmp_path: Path) -> None:
    tsv = write_vlmevalkit(question_set, tmp_path / "LMUData", "newtphys_test")
    assert tsv == tmp_path / "LMUData" / "newtphys_test.tsv"
    header = tsv.read_text().splitlines()[0].split("\t")
    assert header[:10] == ["index", "question", "A", "B", "C", "D", "answer", "category", "l2-category", "image"]
    rows = read_vlmevalkit(tsv)
    items, answers = vs.read_items(question_set), vs.read_answers(question_set)
    assert [r["index"] for r in rows] == ["0", "1", "2"]
    for row, item in zip(rows, items):
        assert row["idx"] == item.idx and row["question"] == item.question
        assert row["answer"] == answers[item.idx].answer
        assert (row["category"], row["l2-category"]) == (item.category, item.sub_category)
        assert [base64.b64decode(b) for b in row["image"]] == [(question_set / p).read_bytes() for p in item.images]
    assert [rows[0][k] for k in "ABCD"] == ["0.25 kg", "0.50 kg", "0.75 kg", "1.00 kg"]
    # image options are named by their place among the item's images: 1 question image, then options 2-5
    assert [rows[2][k] for k in "ABCD"] == ["image 2", "image 3", "image 4", "image 5"]
    raw = tsv.read_text().splitlines()
    assert not raw[1].split("\t")[9].startswith("[") and raw[2].split("\t")[9].startswith("['")  # str vs list


def test_vlmevalkit_paths_and_single_mode(question_set: Path, tmp_path: Path) -> None:
    tsv = write_vlmevalkit(question_set, tmp_path, "only_single", image_mode="path", mode="single")
    rows = read_vlmevalkit(tsv)
    assert len(rows) == 1 and "image" not in rows[0]
    assert rows[0]["image_path"] == [str((question_set / "images/test-000000/000012.png").resolve())]


def _utils(task_dir: Path):
    spec = importlib.util.spec_from_file_location("newtphys_task_utils", task_dir / "utils.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class _FunctionTagLoader(yaml.SafeLoader):
    pass


_FunctionTagLoader.add_constructor("!function", lambda loader, node: ("!function", loader.construct_scalar(node)))


def test_lmms_eval_task_directory_scores_hand_made_replies(question_set: Path, tmp_path: Path) -> None:
    task = write_lmms_eval(question_set, tmp_path / "task", "newtphys_test")
    cfg = yaml.load(task.read_text(), Loader=_FunctionTagLoader)
    assert cfg["task"] == "newtphys_test" and cfg["dataset_path"] == "json" and cfg["test_split"] == "test"
    assert Path(cfg["dataset_kwargs"]["data_files"]["test"]) == (tmp_path / "task" / "newtphys_test.jsonl").resolve()
    for hook in ("doc_to_visual", "doc_to_text", "doc_to_target", "process_results"):
        assert cfg[hook] == ("!function", f"utils.{hook}")
    assert [m["metric"] for m in cfg["metric_list"]] == ["accuracy", "macro_accuracy"]
    assert (tmp_path / "task" / "utils.py").read_bytes() == Path(vqa_scoring.__file__).read_bytes()
    docs = [json.loads(line) for line in (tmp_path / "task" / "newtphys_test.jsonl").read_text().splitlines()]
    utils = _utils(tmp_path / "task")
    assert [utils.doc_to_target(d) for d in docs] == ["B", "D", "C"]
    assert [len(utils.doc_to_visual(d)) for d in docs] == [1, 3, 5]
    assert utils.doc_to_visual(docs[0])[0].getpixel((0, 0)) == (120, 120, 120)  # frame 12: 10 * 12
    assert utils.doc_to_text(docs[0]) == ("Question s/F_MASS_OBJECT/1/single?\nA. 0.25 kg\nB. 0.50 kg\nC. 0.75 kg\n"
                                          f"D. 1.00 kg\n{vqa_scoring.ANSWER_INSTRUCTION}")  # fmt: skip
    replies = ["The answer is B.", "a", "(C)"]  # right, wrong, right
    results = [utils.process_results(d, [r]) for d, r in zip(docs, replies)]
    acc = utils.aggregate_accuracy([r["accuracy"] for r in results])
    macro = utils.aggregate_macro_accuracy([r["macro_accuracy"] for r in results])
    assert acc == pytest.approx(2 / 3)
    # mass: ids 1.0 and 0.0 -> 0.5; material_understanding 0.5; temporal 1.0 -> overall 0.75
    assert macro == pytest.approx(0.75)


def test_answer_extraction_takes_a_letter_alone_or_at_the_end() -> None:
    cases = {"B": "B", " c ": "C", "A.": "A", "The answer is (d).": "D", "Answer: B": "B", "**C**": "C",
             "I cannot tell": None, "BC": None, "": None, "E": None, "Option B because it is heavier": None}  # fmt: skip
    assert {r: vqa_scoring.extract_letter(r) for r in cases} == cases


def test_macro_accuracy_averages_ids_then_sub_categories_then_categories() -> None:
    rows = [("q1", "s1", "c1", True), ("q1", "s1", "c1", False), ("q2", "s1", "c1", True),
            ("q3", "s2", "c1", False), ("q4", "s3", "c2", True)]  # fmt: skip
    out = vqa_scoring.macro_accuracy(
        [{"question_id": q, "sub_category": s, "category": c, "correct": ok} for q, s, c, ok in rows])
    assert out["question_id"] == {"q1": 0.5, "q2": 1.0, "q3": 0.0, "q4": 1.0}
    assert out["sub_category"] == {"s1": 0.75, "s2": 0.0, "s3": 1.0}
    assert out["category"] == {"c1": 0.375, "c2": 1.0} and out["overall"] == pytest.approx(0.6875)


def test_export_command_writes_both_formats(question_set: Path, tmp_path: Path, capsys) -> None:
    assert cli_main(["export-vqa", str(question_set), "--format", "vlmevalkit", "--out", str(tmp_path / "v")]) == 0
    assert (tmp_path / "v" / "newtphys_test.tsv").is_file()
    assert cli_main(["export-vqa", str(question_set.parent), "--format", "lmms-eval", "--out", str(tmp_path / "l"),
                     "--name", "np_t", "--mode", "multi"]) == 0  # fmt: skip
    assert len((tmp_path / "l" / "np_t.jsonl").read_text().splitlines()) == 2
    assert "wrote" in capsys.readouterr().out
