"""The VQA contract: a hand-built question set validates clean, and each kind of breakage is named exactly."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from newtphys import vqa_schema as vs
from newtphys.cli import main as cli_main
from newtphys.vqa_validate import validate_question_set


def _item(idx: str, mode: str, frames: list[int], images: list[str], **changes) -> dict:
    item = {
        "idx": idx, "pair": "seq-000000/F_MASS_OBJECT/o1/f12", "question_id": "F_MASS_OBJECT",
        "category": "material_understanding", "sub_category": "mass", "mode": mode, "variant": "base",
        "split": "test", "sequence_id": "test-000000", "shard": "test/shard-00000.h5", "frames": frames,
        "images": images, "question": "What is the mass of the red ball?",
        "options": ["0.25 kg", "0.50 kg", "0.75 kg", "1.00 kg"], "objects": [1],
        "meta": {"num_objects": 2, "num_visible": 2, "gravity_m_s2": 9.81, "young_modulus_pa": 1e6},
    }  # fmt: skip
    return item | changes


@pytest.fixture()
def question_set(tmp_path: Path) -> Path:
    root = tmp_path / "vqa" / "test"
    frames = [5, 7, 9, 11, 12]
    for t in frames:
        path = root / "images" / "test-000000" / f"{t:06d}.png"
        path.parent.mkdir(parents=True, exist_ok=True)
        Image.fromarray(np.full((8, 8, 3), 10 * t, np.uint8)).save(path)
    image = lambda t: f"images/test-000000/{t:06d}.png"  # noqa: E731
    items = [_item("q0", "single", [12], [image(12)]), _item("q1", "multi", frames, [image(t) for t in frames])]
    answers = [{"idx": "q0", "answer": "B", "value": 0.5, "unit": "kg"},
               {"idx": "q1", "answer": "B", "value": 0.5, "unit": "kg"}]  # fmt: skip
    _write(root, items, answers)
    return root


def _write(root: Path, items: list[dict], answers: list[dict]) -> None:
    (root / vs.QUESTIONS_FILE).write_text("".join(json.dumps(i) + "\n" for i in items))
    (root / vs.ANSWERS_FILE).write_text("".join(json.dumps(a) + "\n" for a in answers))
    (root / vs.MANIFEST_FILE).write_text(json.dumps({"counts": {}}))


def _load(root: Path) -> tuple[list[dict], list[dict]]:
    items = [d for _, d in vs.iter_jsonl(root / vs.QUESTIONS_FILE)]
    answers = [d for _, d in vs.iter_jsonl(root / vs.ANSWERS_FILE)]
    return items, answers


def test_a_valid_set_has_no_problem_and_reads_back(question_set: Path) -> None:
    assert validate_question_set(question_set) == []
    items = vs.read_items(question_set)
    assert [i.idx for i in items] == ["q0", "q1"] and items[1].frames == (5, 7, 9, 11, 12)
    assert vs.read_answers(question_set)["q1"].answer == "B"
    assert json.loads(items[0].to_json())["options"][1] == "0.50 kg"


def test_catalogue_has_every_category_and_the_papers_exclusions() -> None:
    assert len(vs.QUESTION_SPECS) >= 50
    assert {s.category for s in vs.QUESTION_SPECS.values()} == set(vs.CATEGORIES)
    assert {q for q, s in vs.QUESTION_SPECS.items() if not s.in_analysis} == {
        "F_OCCLUSION_PERCENTAGE_OBJECT", "F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_3", "F_CAMERA_ZOOM_BEHAVIOR",
        "F_FOCAL_LENGTH_CLASS"}  # fmt: skip
    temporal = [s for s in vs.QUESTION_SPECS.values() if s.category in ("temporal", "persistence")]
    assert temporal and all(s.modes == ("multi",) for s in temporal)
    assert vs.question_spec("CF_F_KINEMATICS_SPEED_OBJECT").sub_category == "kinematics"


@pytest.mark.parametrize(
    ("question_id", "category", "sub_category"),
    [("F_MASS_OBJECT", "material_understanding", "mass"), ("F_KINEMATICS_SPEED_OBJECT", "mechanics", "kinematics"),
     ("F_COLLISION_OBJECT_OBJECT_FRAME_MULTI", "mechanics", "collision"),
     ("F_LAYOUT_POSITION_OBJECT_OBJECT", "spatial_reasoning", "layout"),
     ("F_VIEWPOINT_CAMERA_ANGLE", "view_point", "camera_characteristics"),
     ("F_CAMERA_MOTION_DIRECTION", "temporal", "camera_motion"),
     ("F_PERSISTENCE_TOTAL_COUNT", "persistence", "object_count"),
     ("F_PHYSICS_PROPERTY_POISSON_HIGH_LEVEL", "material_understanding", "poisson_ratio")],
)  # fmt: skip
def test_aggregation_levels_of_known_ids(question_id: str, category: str, sub_category: str) -> None:
    spec = vs.question_spec(question_id)
    assert (spec.category, spec.sub_category) == (category, sub_category)


BREAKAGES = {
    "missing field": (lambda i, a: i[0].pop("question"), "q0/question: missing field"),
    "wrong type": (lambda i, a: i[0].update(frames="12"), "q0/frames: must be a non-empty list"),
    "not one correct option": (lambda i, a: a[0].update(answer="AB"), "not exactly one correct option"),
    "duplicate idx": (lambda i, a: i.append(dict(i[0])), "q0/idx: duplicate idx (also on line 1)"),
    "missing image": (lambda i, a: i[0].update(images=["images/nope.png"]), "image 'images/nope.png' not found"),
    "answers do not cover": (lambda i, a: a.pop(1), "q1: item has no answer"),
    "extra answer": (lambda i, a: a.append({"idx": "q9", "answer": "A", "value": 1, "unit": ""}),
                     "q9: answer for an item that does not exist"),
    "pair letters differ": (lambda i, a: a[1].update(answer="C"), "carry different letters ['B', 'C']"),
    "unknown question": (lambda i, a: i[0].update(question_id="F_NOPE"), "unknown question_id 'F_NOPE'"),
    "wrong category": (lambda i, a: i[0].update(sub_category="density"),
                       "F_MASS_OBJECT aggregates under material_understanding/mass"),
    "options not distinct": (lambda i, a: i[0].update(options=["1 kg", "2 kg", "1 KG ", "3 kg"]),
                             "options are not distinct after formatting"),
    "three options": (lambda i, a: i[0].update(options=["1 kg", "2 kg", "3 kg"]), "must be exactly 4"),
    "multi-only mode": (lambda i, a: i[0].update(question_id="F_TEMPORAL_SEQUENCE_IMAGES",
                                                 category="temporal", sub_category="event_ordering"),
                        "mode 'single' not one of ['multi']"),
    "meta incomplete": (lambda i, a: i[0]["meta"].pop("gravity_m_s2"), "meta lacks ['gravity_m_s2']"),
    "unknown variant": (lambda i, a: i[0].update(variant="roi_square"), "q0/variant: unknown variant 'roi_square'"),
    "factual id in a counterfactual variant": (lambda i, a: i[0].update(variant="cf_gravity"),
                                               "variant 'cf_gravity' with question_id 'F_MASS_OBJECT'"),
}


@pytest.mark.parametrize("breakage", sorted(BREAKAGES))
def test_each_breakage_is_named(question_set: Path, breakage: str, capsys) -> None:
    change, expected = BREAKAGES[breakage]
    items, answers = _load(question_set)
    change(items, answers)
    _write(question_set, items, answers)
    problems = [p for p in validate_question_set(question_set) if p.severity == "error"]
    assert any(expected in str(p) for p in problems), [str(p) for p in problems]
    assert cli_main(["validate-vqa", str(question_set.parent)]) == 1  # the VQA root finds the split
    out = capsys.readouterr().out.splitlines()
    assert out[-1] == f"checked 1 question set(s): {len(problems)} error(s), 0 warning(s)"
    assert len(out) == len(problems) + 1  # one line per problem


def test_the_contract_document_describes_every_variant() -> None:
    text = (Path(__file__).resolve().parents[2] / "docs" / "vqa_contract.md").read_text()
    section = text.split("## Variants", 1)[1].split("\n## ", 1)[0]
    assert [v for v in vs.VARIANTS if f"`{v}`" not in section] == []


def test_missing_files_are_named(tmp_path: Path) -> None:
    problems = validate_question_set(tmp_path)
    assert sorted(Path(p.file).name for p in problems) == sorted([vs.QUESTIONS_FILE, vs.ANSWERS_FILE,
                                                                  vs.MANIFEST_FILE])
