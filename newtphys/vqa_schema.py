"""The question-set contract: the files of a VQA set, its items and answers, and the question catalogue.

A question set lives in one directory per split of generated shards::

    <vqa_dir>/<split>/questions.jsonl    one item per line (no answers)
    <vqa_dir>/<split>/answers.jsonl      {"idx", "answer" (A-D), "value", "unit"} per line
    <vqa_dir>/<split>/images/<sequence_id>/<frame:06d>.png            RGB frames from the shards
    <vqa_dir>/<split>/images/<variant>/<sequence_id>/<...>.png        images changed by a variant
    <vqa_dir>/<split>/manifest.json      config, seed, package version, counts

The answers stay in their own file so that no evaluator reads them by accident. This module is the one
source of the field names, the catalogue (question id -> category, sub-category, modes) and the letters;
:mod:`newtphys.vqa_validate` checks a set against it. See ``docs/vqa_contract.md``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Iterator
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

QUESTIONS_FILE = "questions.jsonl"
ANSWERS_FILE = "answers.jsonl"
MANIFEST_FILE = "manifest.json"
IMAGES_DIR = "images"

LETTERS: tuple[str, ...] = ("A", "B", "C", "D")
MODES: tuple[str, ...] = ("single", "multi")
BASE_VARIANT = "base"
IMAGE_OPTION = "<image>"
"""Option text of an option that is an image (its path follows the question images in ``images``)."""

META_REQUIRED: tuple[str, ...] = ("num_objects", "num_visible", "gravity_m_s2")
"""Keys every item's ``meta`` holds; ``young_modulus_pa`` too when the item asks about one object."""

# category -> its sub-categories (aggregation: question_id -> sub_category -> category -> overall)
CATEGORIES: dict[str, tuple[str, ...]] = {
    "material_understanding": ("density", "mass", "material_identification", "poisson_ratio", "young_modulus"),
    "mechanics": ("collision", "kinematics"),
    "spatial_reasoning": ("distance", "layout", "size"),
    "view_point": ("camera_characteristics", "visibility"),
    "temporal": ("camera_motion", "event_ordering"),
    "persistence": ("object_count", "object_identity"),
}


@dataclass(frozen=True)
class QuestionSpec:
    """One question id of the catalogue: where it aggregates and in which modes it exists."""

    question_id: str
    sub_category: str
    modes: tuple[str, ...]
    in_analysis: bool = True
    """False for the ids the paper generated but left out of its analysis (reported apart)."""

    @property
    def category(self) -> str:
        return SUB_CATEGORY_TO_CATEGORY[self.sub_category]


SUB_CATEGORY_TO_CATEGORY: dict[str, str] = {s: c for c, subs in CATEGORIES.items() for s in subs}

_BOTH = ("single", "multi")
_MULTI = ("multi",)
_SINGLE = ("single",)


def _specs() -> dict[str, QuestionSpec]:
    rows: list[tuple[str, str, tuple[str, ...], bool]] = [
        # spatial reasoning
        ("F_DISTANCE_OBJECT_OBJECT", "distance", _BOTH, True),
        ("F_CLOSEST_OBJECT_OBJECT", "distance", _BOTH, True),
        ("F_DISTANCE_OBJECT_CAMERA_DISTANCE", "distance", _BOTH, True),
        ("F_CLOSEST_OBJECT_CAMERA", "distance", _BOTH, True),
        ("F_SIZE_OBJECT", "size", _BOTH, True),
        ("F_SIZE_OBJECT_BIGGER", "size", _BOTH, True),
        ("F_LAYOUT_POSITION_OBJECT_OBJECT", "layout", _BOTH, True),
        # mechanics
        ("F_KINEMATICS_SPEED_OBJECT", "kinematics", _BOTH, True),
        ("F_KINEMATICS_ACCEL_OBJECT", "kinematics", _BOTH, True),
        ("F_KINEMATICS_DISTANCE_TRAVELED_INTERVAL", "kinematics", _BOTH, True),
        ("F_KINEMATICS_SYSTEM_STABILITY", "kinematics", _MULTI, True),
        ("F_COLLISION_OBJECT_OBJECT_FRAME_SINGLE", "collision", _SINGLE, True),
        ("F_COLLISION_OBJECT_OBJECT_FRAME_MULTI", "collision", _MULTI, True),
        ("F_COLLISION_OBJECT_SCENE_FRAME_MULTI", "collision", _MULTI, True),
        # material understanding
        ("F_MASS_OBJECT", "mass", _BOTH, True),
        ("F_MASS_HEAVIEST_OBJECT", "mass", _BOTH, True),
        ("F_MASS_LIGHTEST_OBJECT", "mass", _BOTH, True),
        ("F_PHYSICS_PROPERTY_DENSITY_OBJECT", "density", _BOTH, True),
        ("F_PHYSICS_PROPERTY_DENSITY_OBJECT_RELATIVE", "density", _BOTH, True),
        ("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_METRIC_PREFIX", "young_modulus", _BOTH, True),
        ("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_SIMILAR", "young_modulus", _BOTH, True),
        ("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_SIMILAR_NON_TECHNICAL", "young_modulus", _BOTH, True),
        ("F_PHYSICS_PROPERTY_YOUNG_MODULUS_HIGHEST", "young_modulus", _BOTH, True),
        ("F_PHYSICS_PROPERTY_YOUNG_MODULUS_HIGHEST_NON_TECHNICAL", "young_modulus", _BOTH, True),
        ("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_HIGH_LEVEL", "young_modulus", _BOTH, True),
        ("F_PHYSICS_PROPERTY_POISSON_RATIO_OBJECT", "poisson_ratio", _BOTH, True),
        ("F_PHYSICS_PROPERTY_POISSON_RATIO_OBJECT_SIMILAR", "poisson_ratio", _BOTH, True),
        ("F_PHYSICS_PROPERTY_POISSON_RATIO_OBJECT_SIMILAR_NON_TECHNICAL", "poisson_ratio", _BOTH, True),
        ("F_PHYSICS_PROPERTY_POISSON_RATIO_HIGHEST", "poisson_ratio", _BOTH, True),
        ("F_PHYSICS_PROPERTY_POISSON_RATIO_HIGHEST_NON_TECHNICAL", "poisson_ratio", _BOTH, True),
        ("F_PHYSICS_PROPERTY_POISSON_HIGH_LEVEL", "poisson_ratio", _BOTH, True),
        ("F_MATERIAL_IDENTIFICATION_SIMILAR_OBJECT", "material_identification", _BOTH, True),
        ("F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_1", "material_identification", _BOTH, True),
        ("F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_2", "material_identification", _BOTH, True),
        ("F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_3", "material_identification", _BOTH, False),
        # viewpoint
        ("F_VISIBILITY_OBJECT", "visibility", _BOTH, True),
        ("F_VISIBILITY_OBJECT_COUNT", "visibility", _BOTH, True),
        ("F_OCCLUSION_PERCENTAGE_OBJECT", "visibility", _BOTH, False),
        ("F_VIEWPOINT_CAMERA_ANGLE", "camera_characteristics", _BOTH, True),
        ("F_FOCAL_LENGTH_CLASS", "camera_characteristics", _BOTH, False),
        # temporal
        ("F_TEMPORAL_SEQUENCE_IMAGES", "event_ordering", _MULTI, True),
        ("F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_1", "event_ordering", _MULTI, True),
        ("F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_2", "event_ordering", _MULTI, True),
        ("F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_5", "event_ordering", _MULTI, True),
        ("F_TEMPORAL_PREDICTION_PREVIOUS_IMAGE", "event_ordering", _MULTI, True),
        ("F_TEMPORAL_PREDICTION_MISSING_IMAGE", "event_ordering", _MULTI, True),
        ("F_CAMERA_MOTION_DIRECTION", "camera_motion", _MULTI, True),
        ("F_CAMERA_ZOOM_BEHAVIOR", "camera_motion", _MULTI, False),
        # persistence
        ("F_PERSISTENCE_OBJECT_PRESENT", "object_identity", _MULTI, True),
        ("F_PERSISTENCE_OBJECT_DISAPPEAR", "object_identity", _MULTI, True),
        ("F_PERSISTENCE_TOTAL_COUNT", "object_count", _MULTI, True),
        ("F_PERSISTENCE_TOTAL_COUNT_HIDDEN", "object_count", _MULTI, True),
    ]
    return {qid: QuestionSpec(qid, sub, modes, analysed) for qid, sub, modes, analysed in rows}


QUESTION_SPECS: dict[str, QuestionSpec] = _specs()

VARIANTS: dict[str, str] = {
    "base": "the question as generated: the object's name, unchanged frames",
    # name / red circle / image location: the seven combinations are base (name only) and these six
    "roi_circle": "name + a red circle around the named object on the question images; text '(circled in red)'",
    "location": "name + 'located at the top-left of the image' (3 x 3 grid of the question's last frame)",
    "roi_circle_location": "name + red circle + location",
    "roi_only": "red circle, no name: 'the object circled in red'",
    "location_only": "location, no name: 'the object located at the top-left of the image'",
    "roi_location_only": "red circle + location, no name",
    "roi_masked": "the named object covered by a filled black disc on the question images (text unchanged)",
    "black_image": "every image (question and option images) all black (text unchanged)",
    "cue_duration": "multi-frame kinematics items + 'The images span 3.52 seconds.'",
    "cue_mass_exact": "items naming one object (not mass questions) + 'The <name> has a mass of 2.35 kg.'",
    "cue_mass_approx": "as cue_mass_exact with the mass rounded to 0.5 kg ('about 2.5 kg')",
    "level_child": "density-relative, Young's-modulus and Poisson-ratio questions (multi) worded for a child",
    "level_teen": "... worded for a teenager",
    "level_undergrad": "... worded for an undergraduate",
    "level_graduate": "... worded for a graduate student",
    "level_expert": "... worded for a physicist",
    "cf_gravity": "CF_<id>: factual images, answer from the simulated twin with gravity x 0.1",
    "cf_shift": "CF_<id>: factual images, answer from the twin with one object started 0.15 m to the side",
    "cf_resize": "CF_<id>: factual images, answer from the twin with one object at half size",
}
"""Variant name -> what it changes (docs/vqa_contract.md). Every item names its variant; a variant's items
share the letter order of the base item they derive from, except counterfactuals (own ids, own answers)."""
COUNTERFACTUAL_VARIANT_PREFIX = "cf_"
COUNTERFACTUAL_PREFIX = "CF_"
"""Counterfactual question ids are ``CF_<QUESTION_ID>`` and aggregate like their factual id."""


def question_spec(question_id: str) -> QuestionSpec:
    """The catalogue entry of ``question_id`` (``CF_`` ids resolve to their factual id)."""
    base = question_id.removeprefix(COUNTERFACTUAL_PREFIX)
    if base not in QUESTION_SPECS:
        raise KeyError(f"unknown question_id {question_id!r}; valid ids: {', '.join(sorted(QUESTION_SPECS))}")
    return QUESTION_SPECS[base]


@dataclass(frozen=True)
class QuestionItem:
    """One line of ``questions.jsonl`` (no answer)."""

    idx: str
    """Unique in the set."""
    pair: str
    """Shared by the single- and multi-frame versions of one question (same letter order)."""
    question_id: str
    category: str
    sub_category: str
    mode: str
    """``single`` (one image) or ``multi`` (a clip of frames)."""
    variant: str
    split: str
    sequence_id: str
    shard: str
    """Shard path relative to the data directory."""
    frames: tuple[int, ...]
    """Frame indices shown, in order; the last one is "the last frame" of the question."""
    images: tuple[str, ...]
    """Image paths relative to the set directory: question images, then option images."""
    question: str
    options: tuple[str, str, str, str]
    """Option texts in letter order A-D; ``"<image>"`` where the option is an image."""
    objects: tuple[int, ...]
    """World-state ids of the objects the question names or asks about."""
    meta: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> str:
        d = asdict(self)
        return json.dumps({k: (list(v) if isinstance(v, tuple) else v) for k, v in d.items()}, sort_keys=False)

    @staticmethod
    def from_dict(d: dict[str, Any]) -> QuestionItem:
        names = [f.name for f in fields(QuestionItem)]
        missing = [n for n in names if n not in d]
        if missing:
            raise KeyError(f"question item {d.get('idx', '?')!r}: missing fields {missing}")
        values = {n: d[n] for n in names}
        for n in ("frames", "images", "options", "objects"):
            values[n] = tuple(values[n]) if isinstance(values[n], list) else values[n]
        return QuestionItem(**values)


@dataclass(frozen=True)
class AnswerRecord:
    """One line of ``answers.jsonl``: the correct letter and the value behind it (``unit``: SI or "")."""

    idx: str
    answer: str
    value: Any
    unit: str

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def split_dir(vqa_dir: Path | str, split: str) -> Path:
    return Path(vqa_dir) / split


def iter_jsonl(path: Path) -> Iterator[tuple[int, dict[str, Any]]]:
    """(line number, object) per non-empty line; a malformed line raises ValueError naming file and line."""
    with open(path) as f:
        for n, line in enumerate(f, 1):
            if not line.strip():
                continue
            try:
                obj = json.loads(line)
            except json.JSONDecodeError as e:
                raise ValueError(f"{path}:{n}: not JSON ({e.msg})") from None
            if not isinstance(obj, dict):
                raise ValueError(f"{path}:{n}: a line must be a JSON object, got {type(obj).__name__}")
            yield n, obj


def read_items(set_dir: Path | str) -> list[QuestionItem]:
    """Every item of ``<set_dir>/questions.jsonl``."""
    return [QuestionItem.from_dict(d) for _, d in iter_jsonl(Path(set_dir) / QUESTIONS_FILE)]


def read_answers(set_dir: Path | str) -> dict[str, AnswerRecord]:
    """idx -> answer of ``<set_dir>/answers.jsonl``."""
    return {d["idx"]: AnswerRecord(**d) for _, d in iter_jsonl(Path(set_dir) / ANSWERS_FILE)}


def read_manifest(set_dir: Path | str) -> dict[str, Any]:
    return json.loads((Path(set_dir) / MANIFEST_FILE).read_text())


def write_jsonl(path: Path, lines: Iterable[str]) -> None:
    """Write lines atomically (temporary name, then rename): a half-written file never appears."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w") as f:
        for line in lines:
            f.write(line + "\n")
    tmp.replace(path)
