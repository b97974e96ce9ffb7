"""Prove the VQA exports with the harnesses themselves, not with our reading of their formats.

Each harness runs in its own interpreter (its own virtual environment; never our .venv), fed a probe script
on stdin that prints one ``RESULT <json>`` line; this script compares what the harness saw with the question
set (items, images pixel for pixel, letters, accuracies computed here from answers.jsonl).

* **VLMEvalKit** (not on PyPI: a checkout, e.g. ``/tmp/vlmevalkit`` from ``git archive`` of a snapshot, and an
  interpreter with its requirements): ``build_dataset(<name>)`` with ``LMUData`` = the export directory must
  pick our TSV as a custom MCQ dataset; ``build_prompt`` of every row must give the item's images (decoded
  pixels equal to our PNGs) and its question and options; ``evaluate(..., model='exact_matching')`` of the
  true letters must score 1.0 and of "A" everywhere the share of answer A.
* **lmms-eval** (``pip install lmms-eval`` in its own venv): ``TaskManager(include_path=<task dir>)`` must
  index our task; every doc's ``doc_to_visual`` / ``doc_to_text`` / ``doc_to_target`` must give the item's
  images, prompt and letter; ``process_results`` of the true letters must aggregate to 1.0; and the CLI run
  ``lmms-eval --model dummy --model_args response=A --include_path ...`` must report the share of answer A
  as accuracy and the macro accuracy computed here.

Usage:
    python bench/check_vqa_exports.py SET_DIR --work WORK \\
        [--vlmevalkit /tmp/vlmevalkit --vlmevalkit-python /tmp/vlmeval_venv/bin/python] \\
        [--lmms-python /tmp/lmms_venv/bin/python]
(or NEWTPHYS_VLMEVALKIT, NEWTPHYS_VLMEVALKIT_PYTHON, NEWTPHYS_LMMS_PYTHON). A harness that is not given or
not found is skipped with a message saying what to provide; the exit status is 1 when a check fails.

Environments as last set up (Python 3.11): ``pip install lmms-eval`` (0.7.3) then ``pip install "filelock<4"``
(lmms-eval imports ``filelock._api``, which filelock 4 removed); VLMEvalKit: ``pip install -r
requirements.txt`` of the checkout plus ``rouge_score`` (imported by its dataset package, not listed).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
from PIL import Image

from newtphys import vqa_schema as vs
from newtphys.vqa_export import option_texts, write_lmms_eval, write_vlmevalkit
from newtphys.vqa_scoring import macro_accuracy

NAME = "newtphys_probe"

VLMEVALKIT_PROBE = r"""
import hashlib, json, os, sys
import numpy as np
from PIL import Image
checkout, lmu, name = sys.argv[1:4]
sys.path.insert(0, checkout)
os.environ["LMUData"] = lmu
from vlmeval.dataset import build_dataset
from vlmeval.smp import dump
ds = build_dataset(name)
out = {"class": type(ds).__name__, "len": len(ds), "rows": [], "eval": {}}
def pixels(p):
    with Image.open(p) as im:
        return hashlib.sha256(np.asarray(im.convert("RGB")).tobytes()).hexdigest()
for i in range(len(ds)):
    msgs = ds.build_prompt(i)
    out["rows"].append({"idx": str(ds.data.iloc[i]["idx"]),
                        "images": [pixels(m["value"]) for m in msgs if m["type"] == "image"],
                        "text": "\n".join(m["value"] for m in msgs if m["type"] == "text")})
for label in ("truth", "all_A"):
    data = ds.data.drop(columns=[c for c in ("image",) if c in ds.data]).copy()
    data["prediction"] = list(data["answer"]) if label == "truth" else ["A"] * len(data)
    path = os.path.join(lmu, f"probe_{label}_{name}.xlsx")
    dump(data, path)
    acc = ds.evaluate(path, model="exact_matching", nproc=1)
    out["eval"][label] = {str(k): (float(v) if not isinstance(v, str) else v) for k, v in acc.iloc[0].items()}
print("RESULT " + json.dumps(out))
"""

LMMS_PROBE = r"""
import hashlib, json, sys
import numpy as np
task_dir, name = sys.argv[1:3]
from lmms_eval.tasks import TaskManager, get_task_dict
tm = TaskManager("WARNING", include_path=task_dir)
task = get_task_dict([name], tm)[name]
docs = list(task.test_docs())
out = {"indexed": name in tm.all_tasks, "len": len(docs), "rows": [], "truth": {}}
records = {}
for doc in docs:
    images = task.doc_to_visual(doc)
    text = task.doc_to_text(doc)
    target = task.doc_to_target(doc)
    out["rows"].append({"idx": doc["idx"], "target": target, "text": text,
                        "images": [hashlib.sha256(np.asarray(im.convert("RGB")).tobytes()).hexdigest() for im in images]})
    for metric, value in task.process_results(doc, [target]).items():
        records.setdefault(metric, []).append(value)
aggregation = task.aggregation()
out["truth"] = {metric: float(aggregation[metric](values)) for metric, values in records.items()}
print("RESULT " + json.dumps(out))
"""


def _pixels(path: Path) -> str:
    with Image.open(path) as im:
        return hashlib.sha256(np.asarray(im.convert("RGB")).tobytes()).hexdigest()


def _run_probe(python: str, code: str, *args: str, env: dict[str, str] | None = None) -> dict:
    proc = subprocess.run([python, "-", *args], input=code, capture_output=True, text=True,
                          env={**os.environ, **(env or {})}, timeout=1800)  # fmt: skip
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
    if proc.returncode != 0 or not lines:
        raise RuntimeError(f"probe in {python} failed (exit {proc.returncode}):\n{proc.stderr[-4000:]}")
    return json.loads(lines[-1].removeprefix("RESULT "))


class Report:
    def __init__(self) -> None:
        self.failures = 0

    def check(self, ok: bool, what: str) -> None:
        self.failures += not ok
        print(f"  [{'ok' if ok else 'FAIL'}] {what}")


def _expected(set_dir: Path) -> tuple[list[vs.QuestionItem], dict[str, vs.AnswerRecord]]:
    return vs.read_items(set_dir), vs.read_answers(set_dir)


def check_vlmevalkit(set_dir: Path, work: Path, checkout: Path, python: str, report: Report) -> None:
    lmu = work / "LMUData"
    tsv = write_vlmevalkit(set_dir, lmu, NAME)
    print(f"VLMEvalKit: exported {tsv} ({tsv.stat().st_size / 1e6:.1f} MB); probing with {python}, checkout {checkout}")
    got = _run_probe(python, VLMEVALKIT_PROBE, str(checkout), str(lmu), NAME)
    items, answers = _expected(set_dir)
    report.check(got["class"] == "CustomMCQDataset", f"build_dataset({NAME!r}) -> {got['class']}")
    report.check(got["len"] == len(items), f"{got['len']} rows for {len(items)} items")
    rows = {r["idx"]: r for r in got["rows"]}
    images_ok = all(rows[i.idx]["images"] == [_pixels(set_dir / p) for p in i.images] for i in items)
    report.check(images_ok, "every row's prompt images decode to the item's PNG pixels, in order")
    text_ok = all(i.question in rows[i.idx]["text"] and all(f"{k}. {o}" in rows[i.idx]["text"]
                  for k, o in zip(vs.LETTERS, option_texts(i))) for i in items)  # fmt: skip
    report.check(text_ok, "every prompt holds the question and 'A. <option>' ... 'D. <option>'")
    share_a = sum(a.answer == "A" for a in answers.values()) / len(answers)
    truth, all_a = got["eval"]["truth"]["Overall"], got["eval"]["all_A"]["Overall"]
    report.check(abs(truth - 1.0) < 1e-9, f"exact-matching accuracy of the true letters: {truth:.4f} (expect 1)")
    report.check(abs(all_a - share_a) < 1e-9, f"exact-matching accuracy of 'A' everywhere: {all_a:.4f} "
                                              f"(share of answer A: {share_a:.4f})")  # fmt: skip


def check_lmms_eval(set_dir: Path, work: Path, python: str, report: Report) -> None:
    task_dir = work / "lmms_task"
    task = write_lmms_eval(set_dir, task_dir, NAME)
    print(f"lmms-eval: exported {task}; probing with {python}")
    env = {"HF_HUB_OFFLINE": "1", "HF_DATASETS_OFFLINE": "1", "HF_HOME": str(work / "hf_home")}
    got = _run_probe(python, LMMS_PROBE, str(task_dir), NAME, env=env)
    items, answers = _expected(set_dir)
    report.check(got["indexed"] and got["len"] == len(items), f"TaskManager indexes {NAME}: {got['len']} docs")
    rows = {r["idx"]: r for r in got["rows"]}
    report.check(all(rows[i.idx]["images"] == [_pixels(set_dir / p) for p in i.images] for i in items),
                 "doc_to_visual gives the item's images, pixel for pixel, in order")
    report.check(all(rows[i.idx]["target"] == answers[i.idx].answer for i in items), "doc_to_target = answers.jsonl")
    report.check(all(rows[i.idx]["text"].startswith(i.question + "\nA. ") for i in items),
                 "doc_to_text starts with the question, then 'A. ...'")
    report.check(got["truth"] == {"accuracy": 1.0, "macro_accuracy": 1.0},
                 f"process_results + aggregation of the true letters: {got['truth']}")
    out = work / "lmms_out"
    cli = Path(python).with_name("lmms-eval")
    proc = subprocess.run([str(cli), "--model", "dummy", "--model_args", "response=A", "--tasks", NAME,
                           "--include_path", str(task_dir), "--output_path", str(out), "--batch_size", "1"],
                          capture_output=True, text=True, env={**os.environ, **env}, timeout=1800)  # fmt: skip
    results = sorted(out.rglob("*results*.json"))
    if proc.returncode != 0 or not results:
        report.check(False, f"lmms-eval CLI run (exit {proc.returncode}): {proc.stderr[-2000:]}")
        return
    table = [ln for ln in (proc.stdout + proc.stderr).splitlines() if ln.startswith("|")]
    print("  " + "\n  ".join(table))
    metrics = json.loads(results[-1].read_text())["results"][NAME]
    share_a = sum(a.answer == "A" for a in answers.values()) / len(answers)
    macro = macro_accuracy([{"question_id": i.question_id, "sub_category": i.sub_category, "category": i.category,
                             "correct": answers[i.idx].answer == "A"} for i in items])["overall"]  # fmt: skip
    acc, mac = metrics["accuracy,none"], metrics["macro_accuracy,none"]
    report.check(abs(acc - share_a) < 1e-9, f"CLI, dummy model answering 'A': accuracy {acc:.4f} = share of A {share_a:.4f}")
    report.check(abs(mac - macro) < 1e-9, f"CLI, dummy model answering 'A': macro accuracy {mac:.4f} = ours {macro:.4f}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("set_dir", type=Path, help="a question-set directory (<vqa_dir>/<split>)")
    p.add_argument("--work", type=Path, required=True, help="scratch directory for the exports and the runs")
    p.add_argument("--vlmevalkit", default=os.environ.get("NEWTPHYS_VLMEVALKIT"), help="VLMEvalKit checkout")
    p.add_argument("--vlmevalkit-python", default=os.environ.get("NEWTPHYS_VLMEVALKIT_PYTHON"),
                   help="interpreter with VLMEvalKit's requirements")
    p.add_argument("--lmms-python", default=os.environ.get("NEWTPHYS_LMMS_PYTHON"),
                   help="interpreter of a venv with lmms-eval installed")
    args = p.parse_args(argv)
    if not (args.set_dir / vs.QUESTIONS_FILE).is_file():
        p.error(f"{args.set_dir} holds no {vs.QUESTIONS_FILE}")
    args.work.mkdir(parents=True, exist_ok=True)
    report = Report()
    if args.vlmevalkit and args.vlmevalkit_python and (Path(args.vlmevalkit) / "vlmeval").is_dir() and Path(
            args.vlmevalkit_python).is_file():
        check_vlmevalkit(args.set_dir, args.work, Path(args.vlmevalkit), args.vlmevalkit_python, report)
    else:
        print("VLMEvalKit: skipped (give --vlmevalkit CHECKOUT, a directory holding vlmeval/, and "
              "--vlmevalkit-python, an interpreter with its requirements)")
    if args.lmms_python and Path(args.lmms_python).is_file():
        check_lmms_eval(args.set_dir, args.work, args.lmms_python, report)
    else:
        print("lmms-eval: skipped (give --lmms-python, the interpreter of a venv where `pip install lmms-eval` ran)")
    print(f"{report.failures} check(s) failed")
    return 1 if report.failures else 0


if __name__ == "__main__":
    sys.exit(main())
