"""Hand-built question sets for the VLM evaluation tests (exact answers known by construction), and the tiny
random-weight VLM fixtures built once per session into a temporary cache."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from newtphys import vqa_schema as vs

SEQUENCES = ("seq-a", "seq-b", "seq-c")
# (question_id, mode, number of question images, options); answers below
TEMPLATES = (
    ("F_MASS_OBJECT", "single", 1, ("0.25 kg", "0.50 kg", "0.75 kg", "1.00 kg")),
    ("F_MASS_OBJECT", "multi", 3, ("0.25 kg", "0.50 kg", "0.75 kg", "1.00 kg")),
    ("F_SIZE_OBJECT", "single", 1, ("5 cm", "10 cm", "20 cm", "40 cm")),
    ("F_SIZE_OBJECT", "multi", 3, ("5 cm", "10 cm", "20 cm", "40 cm")),
    ("F_MATERIAL_IDENTIFICATION_SIMILAR_OBJECT", "single", 1, ("wood", "metal", "foam", "rubber")),
    ("F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_1", "multi", 2, (vs.IMAGE_OPTION,) * 4),
)
ANSWERS = "ABCDAA" "BBCDAB" "CACDBD"
"""Correct letters of the 18 items (sequence-major, template order): A 5, B 5, C 4, D 4."""


def item_idx(seq: str, k: int) -> str:
    qid, mode = TEMPLATES[k][0], TEMPLATES[k][1]
    return f"{seq}/{qid}/t{k}/{mode}"


def write_question_set(root: Path, *, images: bool = True, size_hw: tuple[int, int] = (24, 32)) -> Path:
    """18 items (3 sequences x 6 templates: single and multi, text and image options) with ANSWERS; PNGs of
    distinct flat colours when ``images``."""
    root.mkdir(parents=True, exist_ok=True)
    items, answers = [], []
    for s, seq in enumerate(SEQUENCES):
        for k, (qid, mode, n_q, options) in enumerate(TEMPLATES):
            spec = vs.question_spec(qid)
            n_images = n_q + sum(o == vs.IMAGE_OPTION for o in options)
            paths = [f"images/{seq}/{k:02d}-{j}.png" for j in range(n_images)]
            if images:
                for j, p in enumerate(paths):
                    (root / p).parent.mkdir(parents=True, exist_ok=True)
                    colour = np.array([40 * s + 10, 30 * k + 5, 25 * j + 3], np.uint8)
                    Image.fromarray(np.broadcast_to(colour, (*size_hw, 3)).copy()).save(root / p)
            idx = item_idx(seq, k)
            items.append(vs.QuestionItem(
                idx=idx, pair=f"{seq}/{qid}/t{k}", question_id=qid, category=spec.category,
                sub_category=spec.sub_category, mode=mode, variant="base", split="test", sequence_id=seq,
                shard="test/shard-00000.h5", frames=tuple(range(n_q)), images=tuple(paths),
                question=f"What is asked by template {'abcdef'[k]} about the red ball?", options=options, objects=(1,),
                meta={"num_objects": 2, "num_visible": 2, "gravity_m_s2": 9.81}))  # fmt: skip
            answers.append(vs.AnswerRecord(idx=idx, answer=ANSWERS[6 * s + k], value=None, unit=""))
    vs.write_jsonl(root / vs.QUESTIONS_FILE, [i.to_json() for i in items])
    vs.write_jsonl(root / vs.ANSWERS_FILE, [a.to_json() for a in answers])
    (root / vs.MANIFEST_FILE).write_text(json.dumps({"split": "test", "note": "hand-built test set"}))
    return root


def write_synthetic_records(root: Path, n: int, seed: int = 0) -> Path:
    """``n`` text-only single items over four question ids, answers drawn uniformly (no image files: for
    answerers that never open images)."""
    rng = np.random.default_rng(seed)
    qids = ("F_MASS_OBJECT", "F_SIZE_OBJECT", "F_DISTANCE_OBJECT_OBJECT", "F_VISIBILITY_OBJECT")
    items, answers = [], []
    for i in range(n):
        qid = qids[i % len(qids)]
        spec = vs.question_spec(qid)
        idx = f"syn-{i:05d}"
        items.append(vs.QuestionItem(
            idx=idx, pair=idx, question_id=qid, category=spec.category, sub_category=spec.sub_category,
            mode="single", variant="base", split="test", sequence_id=f"seq-{i // 8:04d}", shard="x.h5", frames=(0,),
            images=("images/none.png",), question=f"Question {i}?", options=(f"{i}a", f"{i}b", f"{i}c", f"{i}d"),
            objects=(1,), meta={"num_objects": 1, "num_visible": 1, "gravity_m_s2": 9.81}))  # fmt: skip
        answers.append(vs.AnswerRecord(idx=idx, answer=vs.LETTERS[int(rng.integers(4))], value=None, unit=""))
    root.mkdir(parents=True, exist_ok=True)
    vs.write_jsonl(root / vs.QUESTIONS_FILE, [i.to_json() for i in items])
    vs.write_jsonl(root / vs.ANSWERS_FILE, [a.to_json() for a in answers])
    return root


@pytest.fixture(scope="session")
def vlm_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The 18-item hand-built set (read only: tests write their runs elsewhere)."""
    return write_question_set(tmp_path_factory.mktemp("vlm_set") / "vqa" / "test")


@pytest.fixture(scope="session")
def tiny_cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Cache directory of the tiny random-weight VLMs, built once per session (about a second each)."""
    from probes.vlm.tiny import TINY_ARCHS, tiny_model_dir

    root = tmp_path_factory.mktemp("tiny_vlm")
    for arch in TINY_ARCHS:
        tiny_model_dir(arch, 0, root)
    return root
