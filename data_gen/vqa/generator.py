"""Write a question set from the shards of one split (what ``python generate_vqa.py`` runs).

Per sequence (in parallel, resumable): pick question frames, run every question function in each of its
modes, write the frames the items show as PNGs and the raw questions to ``parts/<sequence_id>.json``
(atomically: a finished part is skipped on a re-run). Then, in one pass over all parts in a fixed order:
assign the correct option's letter (balanced per question id and over the set), write ``questions.jsonl``,
``answers.jsonl`` and ``manifest.json``. Same shards + config + seed => byte-identical files.
"""

from __future__ import annotations

import json
import logging
import multiprocessing
import os
from collections import Counter, defaultdict
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from tqdm import tqdm

from data_gen.vqa.questions import REGISTRY, Context
from data_gen.vqa.rules import (
    MULTI_PREFIX,
    NotAnswerable,
    Question,
    integer_window,
    mention,
    multi_window,
    seed_of,
)
from data_gen.vqa.variants import REGISTRY as VARIANTS
from data_gen.vqa.variants import CounterfactualSettings, VariantInputs
from data_gen.vqa.view import SequenceView
from newtphys import __version__
from newtphys import vqa_schema as vs
from newtphys.vqa_prior import audit as blind_audit
from newtphys.shards import ShardReader, list_shards

log = logging.getLogger(__name__)

PARTS_DIR = "parts"
TWINS_DIR = "counterfactuals"
"""World states of the simulated counterfactual twins (provenance, and reused when a run is resumed)."""


@dataclass(frozen=True)
class VqaConfig:
    """Typed view of ``newtphys/conf/generate_vqa.yaml``."""

    data_dir: Path
    split: str
    out_dir: Path
    seed: int
    frames_per_sequence: int
    """Question frames drawn per sequence (each frame gets every question id)."""
    exclude_last_frames: int
    """The last frames of a sequence are not used as question frames."""
    min_visible_objects: int
    question_ids: tuple[str, ...] | None
    """None: the whole catalogue."""
    workers: int
    variants: tuple[str, ...]
    """Item variants to write (``newtphys.vqa_schema.VARIANTS``); ``base`` is the questions as generated."""
    counterfactual: CounterfactualSettings
    """Read only when ``variants`` holds a ``cf_*`` variant."""
    progress: bool = True
    config_yaml: str = ""

    @staticmethod
    def from_mapping(cfg: dict[str, Any], config_yaml: str = "") -> VqaConfig:
        known = {f for f in VqaConfig.__dataclass_fields__} - {"config_yaml"}
        unknown, missing = sorted(set(cfg) - known), sorted(known - set(cfg) - {"progress"})
        if unknown or missing:
            raise ValueError(f"generate_vqa config: unknown keys {unknown}, missing keys {missing}")
        ids = cfg["question_ids"]
        if ids is not None:
            bad = sorted(set(ids) - set(REGISTRY))
            if bad:
                raise ValueError(f"generate_vqa config: unknown question_ids {bad}; valid: {sorted(REGISTRY)}")
        for key, low in (("frames_per_sequence", 1), ("exclude_last_frames", 0), ("min_visible_objects", 0),
                         ("workers", 0), ("seed", 0)):  # fmt: skip
            if int(cfg[key]) < low:
                raise ValueError(f"generate_vqa config: {key} must be >= {low}, got {cfg[key]}")
        variants = cfg["variants"]
        if isinstance(variants, str) or not variants or len(set(variants)) != len(variants):
            raise ValueError(f"generate_vqa config: variants must be a non-empty list without repeats, got {variants!r}")
        bad = sorted(set(variants) - set(vs.VARIANTS))
        if bad:
            raise ValueError(f"generate_vqa config: unknown variants {bad}; valid: {list(vs.VARIANTS)}")
        return VqaConfig(
            data_dir=Path(cfg["data_dir"]), split=str(cfg["split"]), out_dir=Path(cfg["out_dir"]), seed=int(cfg["seed"]),
            frames_per_sequence=int(cfg["frames_per_sequence"]), exclude_last_frames=int(cfg["exclude_last_frames"]),
            min_visible_objects=int(cfg["min_visible_objects"]), question_ids=None if ids is None else tuple(ids),
            workers=int(cfg["workers"]), variants=tuple(str(v) for v in variants),
            counterfactual=CounterfactualSettings.from_mapping(dict(cfg["counterfactual"])),
            progress=bool(cfg.get("progress", True)), config_yaml=config_yaml,
        )  # fmt: skip

    @property
    def set_dir(self) -> Path:
        return self.out_dir / self.split


@dataclass
class SequenceJob:
    shard: str
    shard_relative: str
    sequence_id: str


@dataclass
class VqaReport:
    sequences: int = 0
    skipped_sequences: int = 0
    items: int = 0
    skips: Counter = field(default_factory=Counter)
    variant_skips: Counter = field(default_factory=Counter)
    """(variant, reason) -> base records the variant could not be made from."""

    def summary(self) -> str:
        return (f"{self.items} items from {self.sequences} sequences ({self.skipped_sequences} already done); "
                f"{sum(self.skips.values())} questions not answerable")  # fmt: skip


def question_frames(view: SequenceView, cfg: VqaConfig) -> list[int]:
    """Seeded choice of usable frames: a multi-frame window fits before them, the last frames are excluded and
    at least ``min_visible_objects`` objects are visible."""
    usable = []
    for t in range(view.num_frames - cfg.exclude_last_frames):
        try:
            multi_window(t)
        except NotAnswerable:
            continue
        if len(view.visible_ids(t)) >= cfg.min_visible_objects:
            usable.append(t)
    rng = np.random.default_rng(seed_of(cfg.seed, view.sequence_id, "frames"))
    if len(usable) <= cfg.frames_per_sequence:
        return usable
    return sorted(int(t) for t in rng.choice(usable, size=cfg.frames_per_sequence, replace=False))


def _image_path(sequence_id: str, frame: int) -> str:
    return f"{vs.IMAGES_DIR}/{sequence_id}/{frame:06d}.png"


def sequence_questions(view: SequenceView, cfg: VqaConfig) -> tuple[list[dict[str, Any]], Counter, set[int]]:
    """Raw records (before letters) of one sequence, skip counts per (question id, reason), frames to write."""
    records: list[dict[str, Any]] = []
    skips: Counter = Counter()
    frames_needed: set[int] = set()
    seen_keys: set[tuple[str, str, tuple[int, ...]]] = set()
    ws = view.world_state
    ids = cfg.question_ids or tuple(sorted(REGISTRY))
    for frame in question_frames(view, cfg):
        for qid in ids:
            spec = vs.question_spec(qid)
            ctx = Context(view, frame, np.random.default_rng(seed_of(cfg.seed, view.sequence_id, qid, frame)))
            try:
                q: Question = REGISTRY[qid](ctx)
            except NotAnswerable as e:
                skips[(qid, e.reason)] += 1
                continue
            shown_single = q.shown_frames if q.shown_frames is not None else (frame,)
            dedupe = (qid, q.key, tuple(shown_single))
            if dedupe in seen_keys:  # event-based questions are the same whatever the frame they were asked at
                continue
            seen_keys.add(dedupe)
            pair = f"{view.sequence_id}/{qid}/{q.key}/f{shown_single[-1]}"
            for mode in spec.modes:
                if q.shown_frames is not None:
                    shown = list(q.shown_frames)
                elif mode == "single":
                    shown = [frame]
                else:
                    shown = multi_window(frame)
                frames_needed.update(shown)
                frames_needed.update(q.option_frames or ())
                text = q.text if mode == "single" or spec.modes == ("multi",) else MULTI_PREFIX + q.text
                visible = view.visible_ids(shown[-1])
                meta = {"num_objects": len(ws.objects), "num_visible": len(visible),
                        "gravity_m_s2": round(ws.gravity_magnitude, 6), **q.meta}  # fmt: skip
                if len(q.objects) == 1 and "young_modulus_pa" not in meta:
                    meta["young_modulus_pa"] = view.info(q.objects[0]).young_modulus
                records.append({
                    "idx": f"{pair}/{mode}", "pair": pair, "question_id": qid, "category": spec.category,
                    "sub_category": spec.sub_category, "mode": mode, "variant": vs.BASE_VARIANT, "split": ws.split,
                    "sequence_id": view.sequence_id, "shard": view.shard_relative, "frames": shown,
                    "question_images": [_image_path(view.sequence_id, t) for t in shown],
                    "option_images": [_image_path(view.sequence_id, t) for t in (q.option_frames or ())],
                    "question": text, "correct": q.correct, "distractors": list(q.distractors), "value": q.value,
                    "unit": q.unit, "objects": [int(o) for o in q.objects], "meta": meta,
                    "order_key": seed_of(cfg.seed, view.sequence_id, qid, q.key, shown_single[-1]),
                    "named": _named(view, q), "option_frames": list(q.option_frames or ()),
                })  # fmt: skip
    return records, skips, frames_needed


def _named(view: SequenceView, q: Question) -> list[int]:
    """The question's objects whose name its text mentions (the variants' "asked object")."""
    return [int(o) for o in q.objects if view.name(o) and mention(view.name(o)).search(q.text)]


def variant_records(view: SequenceView, records: list[dict[str, Any]], cfg: VqaConfig
                    ) -> tuple[list[dict[str, Any]], dict[str, np.ndarray], Counter]:  # fmt: skip
    """The records of every configured variant but ``base``, the images they show (path -> RGB) and the
    variants' skips per (variant, reason)."""
    out: list[dict[str, Any]] = []
    images: dict[str, np.ndarray] = {}
    skips: Counter = Counter()
    inputs = VariantInputs(view, cfg.seed, cfg.counterfactual, cfg.set_dir / TWINS_DIR)
    for name in cfg.variants:
        if name == vs.BASE_VARIANT:
            continue
        made = VARIANTS[name](inputs, records)
        out += made.records
        images.update(made.images)
        for reason, n in made.skips.items():
            skips[(name, reason)] += n
    return out, images, skips


def _write_png(path: Path, rgb: np.ndarray) -> None:
    if path.is_file():
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + f".tmp{os.getpid()}.png")
    Image.fromarray(rgb).save(tmp, optimize=False)
    tmp.replace(path)


def _atomic_json(path: Path, obj: Any) -> None:
    tmp = path.with_name(path.name + f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(obj, sort_keys=True))
    tmp.replace(path)


def _run_sequence(args: tuple[SequenceJob, VqaConfig]) -> tuple[str, bool]:
    job, cfg = args
    part = cfg.set_dir / PARTS_DIR / f"{job.sequence_id}.json"
    if part.is_file() and json.loads(part.read_text()).get("variants") == list(cfg.variants):
        return job.sequence_id, False  # done with the same variants (other variants: made again)
    view = SequenceView(Path(job.shard), job.sequence_id, job.shard_relative)
    records, skips, frames = sequence_questions(view, cfg)
    derived, images, variant_skips = variant_records(view, records, cfg)
    if frames:
        ordered = sorted(frames)
        for t, rgb in zip(ordered, view.read_rgb(ordered)):
            _write_png(cfg.set_dir / _image_path(job.sequence_id, t), rgb)
    for path, rgb in sorted(images.items()):
        _write_png(cfg.set_dir / path, rgb)
    _atomic_json(part, {"records": records + derived, "variants": list(cfg.variants),
                        "skips": [[q, r, n] for (q, r), n in sorted(skips.items())],
                        "variant_skips": [[v, r, n] for (v, r), n in sorted(variant_skips.items())]})  # fmt: skip
    return job.sequence_id, True


def list_jobs(cfg: VqaConfig) -> list[SequenceJob]:
    split_dir = cfg.data_dir / cfg.split
    shards = list_shards(split_dir)
    if not shards:
        raise FileNotFoundError(f"no shards under {split_dir} (expected {split_dir}/shard-*.h5; run generate.py first)")
    jobs = []
    for shard in shards:
        with ShardReader(shard) as r:
            for sid in r.sequences():
                jobs.append(SequenceJob(str(shard), str(shard.relative_to(cfg.data_dir)), sid))
    return jobs


def assign_letters(records: list[dict[str, Any]]) -> dict[str, int]:
    """pair -> position (0-3) of the correct option, balanced per question id and over the whole set.

    Per question id the pairs, in their SHA-256 order, take consecutive positions from a start, so every id's
    letters are balanced to within one pair. Each id's start keeps the set's letter counts as even as
    possible (the smallest sum of squared counts; ties go to the start seeded by the id); a pair counts once
    per item showing its letter (single, multi, the variants that keep it). Ids whose positions are partly
    forced go first: a count question's window of consecutive integers cannot start below 0, so an answer
    ``v < 3`` can only sit at positions ``0..v`` (:func:`integer_window`). Records of a variant that keeps
    its base question's letters (``letter_pair``) take no position of their own."""
    by_qid: dict[str, dict[str, dict[str, Any]]] = defaultdict(dict)
    weight: Counter[str] = Counter()  # items showing each pair's letter (single, multi, the variants keeping it)
    for r in records:
        weight[r.get("letter_pair", r["pair"])] += 1
        if r.get("letter_pair", r["pair"]) == r["pair"]:  # variants of a question take its letters
            by_qid[r["question_id"]][r["pair"]] = r
    n = len(vs.LETTERS)

    def landed(record: dict[str, Any], position: int) -> int:
        """Where the answer lands when ``position`` is asked for."""
        if record["meta"].get("ordered_integer_options"):
            value = int(record["value"])
            return integer_window(value, position).index(value)
        return position

    def forced(qid: str) -> bool:
        return any(landed(r, p) != p for r in by_qid[qid].values() for p in range(n))

    counts = [0] * n
    positions: dict[str, int] = {}
    for qid in sorted(by_qid, key=lambda q: (not forced(q), q)):
        pairs = sorted(by_qid[qid], key=lambda p: (by_qid[qid][p]["order_key"], p))
        seeded = seed_of(qid) % n
        best: tuple[int, int, list[int]] | None = None
        for shift in range(n):  # starts in the seeded order: ties keep the earliest
            start = (seeded + shift) % n
            asked = [(start + k) % n for k in range(len(pairs))]
            after = list(counts)
            for pair, position in zip(pairs, asked):
                after[landed(by_qid[qid][pair], position)] += weight[pair]
            score = sum(c * c for c in after)
            if best is None or score < best[0]:
                best = (score, start, asked)
        assert best is not None
        for pair, position in zip(pairs, best[2]):
            positions[pair] = position
            counts[landed(by_qid[qid][pair], position)] += weight[pair]
    return positions


def finalize(record: dict[str, Any], position: int) -> tuple[vs.QuestionItem, vs.AnswerRecord]:
    """The item and answer of a raw record with the correct option at ``position``."""
    if record["meta"].get("ordered_integer_options"):
        window = integer_window(int(record["value"]), position)
        options = [str(v) for v in window]
        position = window.index(int(record["value"]))
        option_images: list[str] = []
    else:
        options = list(record["distractors"])
        options.insert(position, record["correct"])
        option_images = list(record["option_images"])
        if option_images:
            option_images = option_images[1:]
            option_images.insert(position, record["option_images"][0])
            options = [vs.IMAGE_OPTION] * len(vs.LETTERS)
    item = vs.QuestionItem(
        idx=record["idx"], pair=record["pair"], question_id=record["question_id"], category=record["category"],
        sub_category=record["sub_category"], mode=record["mode"], variant=record["variant"], split=record["split"],
        sequence_id=record["sequence_id"], shard=record["shard"], frames=tuple(record["frames"]),
        images=tuple(record["question_images"] + option_images), question=record["question"],
        options=tuple(options), objects=tuple(record["objects"]),  # type: ignore[arg-type]
        meta={k: v for k, v in record["meta"].items() if k != "ordered_integer_options"},
    )  # fmt: skip
    return item, vs.AnswerRecord(record["idx"], vs.LETTERS[position], record["value"], record["unit"])


def run_vqa_generation(cfg: VqaConfig) -> VqaReport:
    (cfg.set_dir / PARTS_DIR).mkdir(parents=True, exist_ok=True)
    jobs = list_jobs(cfg)
    report = VqaReport()
    work = [(j, cfg) for j in jobs]
    bar = tqdm(total=len(work), desc=f"questions {cfg.split}", unit="seq", disable=not cfg.progress)
    if cfg.workers > 1 and len(work) > 1:
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(min(cfg.workers, len(work))) as pool:
            for _, fresh in pool.imap_unordered(_run_sequence, work):
                report.skipped_sequences += not fresh
                bar.update(1)
    else:
        for w in work:
            report.skipped_sequences += not _run_sequence(w)[1]
            bar.update(1)
    bar.close()
    records: list[dict[str, Any]] = []
    for job in jobs:  # a fixed order: the files do not depend on which worker finished first
        part = json.loads((cfg.set_dir / PARTS_DIR / f"{job.sequence_id}.json").read_text())
        records += part["records"]
        for qid, reason, n in part["skips"]:
            report.skips[(qid, reason)] += n
        for name, reason, n in part["variant_skips"]:
            report.variant_skips[(name, reason)] += n
    positions = assign_letters(records)
    emitted = [r for r in records if r["variant"] in cfg.variants]  # base records also carry the variants' letters
    finals = [finalize(r, positions[r.get("letter_pair", r["pair"])]) for r in emitted]
    finals.sort(key=lambda f: f[0].idx)
    vs.write_jsonl(cfg.set_dir / vs.QUESTIONS_FILE, (item.to_json() for item, _ in finals))
    vs.write_jsonl(cfg.set_dir / vs.ANSWERS_FILE, (answer.to_json() for _, answer in finals))
    report.sequences = len(jobs)
    report.items = len(finals)
    _atomic_json(cfg.set_dir / vs.MANIFEST_FILE, manifest(cfg, [f[0] for f in finals], [f[1] for f in finals], report))
    log.info(report.summary())
    return report


def manifest(cfg: VqaConfig, items: Sequence[vs.QuestionItem], answers: Sequence[vs.AnswerRecord],
             report: VqaReport) -> dict[str, Any]:  # fmt: skip
    """Counts per category, sub-category, question id, mode, letter and number of objects; skips per id/reason;
    the blind-prior audit (per question id: how well the text alone answers, and whether that beats chance)."""
    def count(values) -> dict[str, int]:
        return dict(sorted(Counter(str(v) for v in values).items()))

    skipped: dict[str, dict[str, int]] = defaultdict(dict)
    for (qid, reason), n in sorted(report.skips.items()):
        skipped[qid][reason] = n
    variant_skipped: dict[str, dict[str, int]] = defaultdict(dict)
    for (name, reason), n in sorted(report.variant_skips.items()):
        variant_skipped[name][reason] = n
    produced = {i.question_id for i in items}
    base = [(i, a) for i, a in zip(items, answers) if i.variant == vs.BASE_VARIANT]
    blind = blind_audit([i for i, _ in base], {a.idx: a for _, a in base})  # on the base items: no image cues
    return {
        "package_version": __version__, "seed": cfg.seed, "split": cfg.split, "config": cfg.config_yaml,
        "num_items": len(items), "num_sequences": report.sequences,
        "counts": {
            "category": count(i.category for i in items), "sub_category": count(i.sub_category for i in items),
            "question_id": count(i.question_id for i in items), "mode": count(i.mode for i in items),
            "letter": count(a.answer for a in answers), "num_objects": count(i.meta["num_objects"] for i in items),
            "variant": count(i.variant for i in items),
            "letter_per_variant": {v: count(a.answer for i, a in zip(items, answers) if i.variant == v)
                                   for v in sorted({i.variant for i in items})},
        },
        "variants": list(cfg.variants), "skips": dict(skipped), "variant_skips": dict(variant_skipped),
        "question_ids_without_items": sorted(set(cfg.question_ids or REGISTRY) - produced),
        "blind_prior": blind,
        "blind_solvable_question_ids": sorted(q for q, r in blind.items() if r["beats_chance"]),
    }  # fmt: skip
