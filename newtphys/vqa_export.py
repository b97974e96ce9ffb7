"""Question sets in the layouts of two evaluation harnesses (``python -m newtphys export-vqa DIR --format
vlmevalkit|lmms-eval --out OUT``).

* **VLMEvalKit**: ``OUT/<name>.tsv``, its custom multiple-choice layout (read from ``$LMUData/<name>.tsv``):
  ``index`` (row number), ``question``, ``A``-``D``, ``answer``, ``category``, ``l2-category`` (our
  sub-category), and ``image`` (base64 PNG; a Python list literal of them for a multi-image item, which
  VLMEvalKit parses) or ``image_path`` (absolute paths, same list rule); plus our ``idx``, ``question_id``,
  ``mode``, ``variant`` and ``sequence_id``.
* **lmms-eval**: a task directory for ``--include_path OUT``: ``<name>.yaml`` (the local JSONL as a
  ``json`` dataset, ``test_split``, the ``doc_to_*`` / ``process_results`` hooks, accuracy and macro
  accuracy), ``<name>.jsonl`` (one doc per item, images as absolute paths) and ``utils.py`` (a verbatim
  copy of :mod:`newtphys.vqa_scoring`, so both score with the same extraction and macro accuracy).

An option that is an image (``"<image>"``) is written as "image N", the N-th image the item shows.
``mode`` keeps only ``single`` items (for single-image models) or ``multi`` items.
"""

from __future__ import annotations

import ast
import base64
import csv
import json
import shutil
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from newtphys import vqa_scoring

FORMATS = ("vlmevalkit", "lmms-eval")
IMAGE_MODES = ("base64", "path")
VLMEVALKIT_COLUMNS = ("index", "question", "A", "B", "C", "D", "answer", "category", "l2-category")
EXTRA_COLUMNS = ("idx", "question_id", "mode", "variant", "sequence_id")


def option_texts(item: vs.QuestionItem) -> list[str]:
    """The item's option texts with each image option named by its position among the item's images."""
    n_question = len(item.images) - sum(o == vs.IMAGE_OPTION for o in item.options)
    out, k = [], n_question
    for o in item.options:
        if o == vs.IMAGE_OPTION:
            k += 1
            out.append(f"image {k}")
        else:
            out.append(o)
    return out


def load_set(set_dir: Path | str, mode: str | None = None) -> list[tuple[vs.QuestionItem, vs.AnswerRecord]]:
    """(item, answer) of a question set, in file order, optionally only one mode; a missing answer or image
    raises naming the set, the item and the path."""
    set_dir = Path(set_dir)
    if mode is not None and mode not in vs.MODES:
        raise ValueError(f"mode must be one of {list(vs.MODES)} or None, got {mode!r}")
    answers = vs.read_answers(set_dir)
    out = []
    for item in vs.read_items(set_dir):
        if mode is not None and item.mode != mode:
            continue
        if item.idx not in answers:
            raise KeyError(f"{set_dir / vs.ANSWERS_FILE}: no answer for item {item.idx!r}")
        for p in item.images:
            if not (set_dir / p).is_file():
                raise FileNotFoundError(f"{set_dir / vs.QUESTIONS_FILE}: item {item.idx!r}: image {p!r} missing")
        out.append((item, answers[item.idx]))
    if not out:
        raise ValueError(f"{set_dir}: no items to export (mode={mode!r})")
    return out


def _list_cell(values: list[str]) -> str:
    """One value as itself, several as a Python list literal (VLMEvalKit's ``toliststr`` reads both)."""
    return values[0] if len(values) == 1 else repr(values)


def write_vlmevalkit(set_dir: Path | str, out_dir: Path | str, name: str, image_mode: str = "base64",
                     mode: str | None = None) -> Path:  # fmt: skip
    """``out_dir/<name>.tsv`` in VLMEvalKit's custom MCQ layout; returns its path."""
    if image_mode not in IMAGE_MODES:
        raise ValueError(f"image_mode must be one of {list(IMAGE_MODES)}, got {image_mode!r}")
    set_dir, out = Path(set_dir), Path(out_dir) / f"{name}.tsv"
    out.parent.mkdir(parents=True, exist_ok=True)
    image_column = "image" if image_mode == "base64" else "image_path"
    tmp = out.with_name(out.name + ".tmp")
    with open(tmp, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f, delimiter="\t", lineterminator="\n")
        w.writerow([*VLMEVALKIT_COLUMNS, image_column, *EXTRA_COLUMNS])
        for index, (item, answer) in enumerate(load_set(set_dir, mode)):
            paths = [set_dir / p for p in item.images]
            images = ([base64.b64encode(p.read_bytes()).decode("ascii") for p in paths] if image_mode == "base64"
                      else [str(p.resolve()) for p in paths])  # fmt: skip
            w.writerow([index, item.question, *option_texts(item), answer.answer, item.category, item.sub_category,
                        _list_cell(images), item.idx, item.question_id, item.mode, item.variant, item.sequence_id])
    tmp.replace(out)
    return out


def read_vlmevalkit(tsv: Path | str) -> list[dict[str, Any]]:
    """Rows of an exported TSV with ``image`` / ``image_path`` as lists (for checks and round trips)."""
    with open(tsv, newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f, delimiter="\t"))
    for r in rows:
        for key in ("image", "image_path"):
            if key in r:
                r[key] = ast.literal_eval(r[key]) if r[key].startswith("[") else [r[key]]
    return rows


LMMS_EVAL_YAML = """\
# NewtPhys physics questions ({split}), exported by `python -m newtphys export-vqa --format lmms-eval`.
# Run: lmms-eval --include_path {out_dir} --tasks {name} --model <model> ...
task: {name}
dataset_path: json
dataset_kwargs:
  data_files:
    test: {data_file}
test_split: test
output_type: generate_until
doc_to_visual: !function utils.doc_to_visual
doc_to_text: !function utils.doc_to_text
doc_to_target: !function utils.doc_to_target
process_results: !function utils.process_results
generation_kwargs:
  max_new_tokens: 16
  temperature: 0
  do_sample: false
metric_list:
  - metric: accuracy
    aggregation: !function utils.aggregate_accuracy
    higher_is_better: true
  - metric: macro_accuracy
    aggregation: !function utils.aggregate_macro_accuracy
    higher_is_better: true
metadata:
  version: 1.0
"""


def write_lmms_eval(set_dir: Path | str, out_dir: Path | str, name: str, mode: str | None = None) -> Path:
    """The lmms-eval task directory ``out_dir`` (``<name>.yaml``, ``<name>.jsonl``, ``utils.py``); returns the
    YAML's path."""
    set_dir, out = Path(set_dir), Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    data = out / f"{name}.jsonl"
    pairs = load_set(set_dir, mode)
    vs.write_jsonl(data, (json.dumps({
        "idx": item.idx, "question": item.question, "options": option_texts(item),
        "images": [str((set_dir / p).resolve()) for p in item.images], "answer": answer.answer,
        "question_id": item.question_id, "category": item.category, "sub_category": item.sub_category,
        "mode": item.mode, "variant": item.variant, "sequence_id": item.sequence_id,
    }) for item, answer in pairs))  # fmt: skip
    shutil.copyfile(vqa_scoring.__file__, out / "utils.py")
    task = out / f"{name}.yaml"
    task.write_text(LMMS_EVAL_YAML.format(split=pairs[0][0].split, out_dir=out, name=name, data_file=data))
    return task


def export(set_dir: Path | str, fmt: str, out_dir: Path | str, name: str | None = None, image_mode: str = "base64",
           mode: str | None = None) -> Path:  # fmt: skip
    """Write ``set_dir`` in format ``fmt`` under ``out_dir``; ``name`` defaults to ``newtphys_<split>``."""
    if fmt not in FORMATS:
        raise ValueError(f"format must be one of {list(FORMATS)}, got {fmt!r}")
    name = name or f"newtphys_{Path(set_dir).resolve().name}"
    if fmt == "vlmevalkit":
        return write_vlmevalkit(set_dir, out_dir, name, image_mode, mode)
    return write_lmms_eval(set_dir, out_dir, name, mode)
