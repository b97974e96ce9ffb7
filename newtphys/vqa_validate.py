"""Check a VQA question set against the contract (``python -m newtphys validate-vqa DIR``).

One :class:`~newtphys.validate.Problem` per finding, naming the file, the item and the field: a missing
field, a wrong type, not exactly one correct option (an answer that is not one letter A-D), options that
are not four distinct texts, a duplicate idx, a missing image, answers that do not cover the items, a
single/multi pair whose letters differ, a question id or category outside the catalogue.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import fields
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from newtphys.validate import Problem

_TYPES: dict[str, type | tuple[type, ...]] = {
    "idx": str, "pair": str, "question_id": str, "category": str, "sub_category": str, "mode": str,
    "variant": str, "split": str, "sequence_id": str, "shard": str, "frames": list, "images": list,
    "question": str, "options": list, "objects": list, "meta": dict,
}  # fmt: skip


class _Checker:
    def __init__(self, set_dir: Path) -> None:
        self.set_dir = set_dir
        self.problems: list[Problem] = []

    def add(self, file: str, message: str, item: str = "", field: str = "", severity: str = "error") -> None:
        self.problems.append(Problem(str(self.set_dir / file), message, item, field, severity))

    def item(self, line: int, d: dict[str, Any]) -> None:
        f = vs.QUESTIONS_FILE
        idx = str(d.get("idx", f"line {line}"))
        for name, kind in _TYPES.items():
            if name not in d:
                self.add(f, "missing field", idx, name)
            elif not isinstance(d[name], kind) or (kind is str and not d[name]):
                self.add(f, f"must be a non-empty {kind.__name__ if isinstance(kind, type) else kind}, "
                            f"got {d[name]!r}", idx, name)  # fmt: skip
        extra = sorted(set(d) - set(_TYPES))
        if extra:
            self.add(f, f"unknown fields {extra}", idx, severity="warning")
        if any(not isinstance(d.get(n), _TYPES[n]) for n in _TYPES if n in d):
            return
        if not all(n in d for n in _TYPES):
            return
        try:
            spec = vs.question_spec(d["question_id"])
        except KeyError as e:
            self.add(f, str(e.args[0]), idx, "question_id")
            spec = None
        if spec is not None:
            if d["sub_category"] != spec.sub_category or d["category"] != spec.category:
                self.add(f, f"{d['question_id']} aggregates under {spec.category}/{spec.sub_category}, got "
                            f"{d['category']}/{d['sub_category']}", idx, "category")  # fmt: skip
            if d["mode"] not in spec.modes:
                self.add(f, f"mode {d['mode']!r} not one of {list(spec.modes)} for {d['question_id']}", idx, "mode")
        if d["variant"] not in vs.VARIANTS:
            self.add(f, f"unknown variant {d['variant']!r}; valid: {list(vs.VARIANTS)}", idx, "variant")
        elif d["variant"].startswith(vs.COUNTERFACTUAL_VARIANT_PREFIX) != d["question_id"].startswith(
                vs.COUNTERFACTUAL_PREFIX):
            self.add(f, f"counterfactual variants ({vs.COUNTERFACTUAL_VARIANT_PREFIX}*) and only they ask "
                        f"{vs.COUNTERFACTUAL_PREFIX}<id> questions: variant {d['variant']!r} with question_id "
                        f"{d['question_id']!r}", idx, "variant")  # fmt: skip
        if d["mode"] not in vs.MODES:
            self.add(f, f"mode must be one of {list(vs.MODES)}, got {d['mode']!r}", idx, "mode")
        options = d["options"]
        if len(options) != len(vs.LETTERS) or not all(isinstance(o, str) and o for o in options):
            self.add(f, f"must be exactly {len(vs.LETTERS)} non-empty texts, got {options!r}", idx, "options")
        else:
            texts = [o.strip().lower() for o in options if o != vs.IMAGE_OPTION]
            if len(set(texts)) != len(texts):
                self.add(f, f"options are not distinct after formatting: {options!r}", idx, "options")
            n_image_options = sum(o == vs.IMAGE_OPTION for o in options)
            if n_image_options and len(d["images"]) < n_image_options + 1:
                self.add(f, f"{n_image_options} image options need as many option images after the question "
                            f"images; images: {d['images']!r}", idx, "images")  # fmt: skip
        if not d["frames"] or not all(isinstance(t, int) and t >= 0 for t in d["frames"]):
            self.add(f, f"must be a non-empty list of frame indices >= 0, got {d['frames']!r}", idx, "frames")
        elif d["mode"] == "single" and len(d["frames"]) != 1:
            self.add(f, f"a single-frame item shows one frame, got {d['frames']!r}", idx, "frames")
        if not d["images"]:
            self.add(f, "an item shows at least one image", idx, "images")
        for image in d["images"]:
            if not isinstance(image, str) or not (self.set_dir / image).is_file():
                self.add(f, f"image {image!r} not found under {self.set_dir}", idx, "images")
        if not all(isinstance(o, int) and o >= 1 for o in d["objects"]):
            self.add(f, f"must be world-state object ids >= 1, got {d['objects']!r}", idx, "objects")
        missing_meta = [k for k in vs.META_REQUIRED if k not in d["meta"]]
        if missing_meta:
            self.add(f, f"meta lacks {missing_meta}", idx, "meta")


def validate_question_set(set_dir: Path | str) -> list[Problem]:
    """Every problem of the question set in ``set_dir`` (a ``<vqa_dir>/<split>`` directory)."""
    set_dir = Path(set_dir)
    c = _Checker(set_dir)
    for name in (vs.QUESTIONS_FILE, vs.ANSWERS_FILE, vs.MANIFEST_FILE):
        if not (set_dir / name).is_file():
            c.add(name, "file missing")
    if c.problems:
        return c.problems
    seen: dict[str, int] = {}
    pairs: dict[str, list[str]] = defaultdict(list)
    try:
        for line, d in vs.iter_jsonl(set_dir / vs.QUESTIONS_FILE):
            c.item(line, d)
            idx = d.get("idx")
            if isinstance(idx, str):
                if idx in seen:
                    c.add(vs.QUESTIONS_FILE, f"duplicate idx (also on line {seen[idx]})", idx, "idx")
                seen[idx] = line
                if isinstance(d.get("pair"), str):
                    pairs[d["pair"]].append(idx)
    except ValueError as e:
        c.add(vs.QUESTIONS_FILE, str(e))
    answers: dict[str, str] = {}
    answer_fields = [f.name for f in fields(vs.AnswerRecord)]
    try:
        for line, d in vs.iter_jsonl(set_dir / vs.ANSWERS_FILE):
            idx = str(d.get("idx", f"line {line}"))
            missing = [n for n in answer_fields if n not in d]
            if missing:
                c.add(vs.ANSWERS_FILE, f"missing fields {missing}", idx)
                continue
            if idx in answers:
                c.add(vs.ANSWERS_FILE, "duplicate answer", idx, "idx")
            if d["answer"] not in vs.LETTERS:
                c.add(vs.ANSWERS_FILE, f"not exactly one correct option: answer must be one of "
                                       f"{list(vs.LETTERS)}, got {d['answer']!r}", idx, "answer")  # fmt: skip
            answers[idx] = d["answer"]
    except ValueError as e:
        c.add(vs.ANSWERS_FILE, str(e))
    for idx in sorted(set(seen) - set(answers)):
        c.add(vs.ANSWERS_FILE, "item has no answer", idx)
    for idx in sorted(set(answers) - set(seen)):
        c.add(vs.ANSWERS_FILE, "answer for an item that does not exist", idx)
    for pair, members in sorted(pairs.items()):
        letters = {answers.get(i) for i in members if i in answers}
        if len(letters) > 1:
            c.add(vs.ANSWERS_FILE, f"the single/multi versions of pair {pair!r} carry different letters "
                                   f"{sorted(letters)} (items {members})", pair)  # fmt: skip
    return c.problems
