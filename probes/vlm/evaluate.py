"""The evaluation loop: a question set answered by one answerer into one run directory, resumably.

Work is the set's items (in file order) the run asks (:func:`probes.vlm.selection.asked_items`: single-image
models get only ``single`` items, models with an image limit only items within it, ``limit`` the first N),
of one shard when the run is sharded (:func:`probes.vlm.sharding.shard_items`: whole sequences), each once
(rotation 0) or, in circular mode, four times (rotations 0-3). The work list is cut into fixed chunks of
``batch_size`` by position; a chunk's items not yet in ``predictions.jsonl`` are answered as one batch and
appended (flushed and fsynced) before the next chunk starts. A re-run skips what is done, so a killed run
loses at most the batch in flight, and an uninterrupted run and a killed-and-resumed one answer the same
batches (same padding, same replies).
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from newtphys import vqa_schema as vs
from newtphys import vqa_scoring
from probes.vlm.interface import Answerer, PredictionRecord, RunManifest
from probes.vlm.predictions import PredictionStore
from probes.vlm.prompting import (
    ROTATIONS,
    build_prompt,
    prompt_template_sha256,
    question_set_sha256,
    to_set_letter,
)
from probes.vlm.selection import asked_items
from probes.vlm.sharding import check_shard, shard_items

log = logging.getLogger(__name__)


@dataclass
class EvalResult:
    run_dir: Path
    manifest: RunManifest
    items: int
    """Items this run (this shard) asks."""
    not_asked: dict[str, int]
    """Items of the set left out and why (:func:`probes.vlm.selection.asked_items`; other shards' not counted)."""
    answered: int
    """Predictions written by this call."""
    already_done: int
    """Predictions found from earlier runs."""
    seconds: float
    records: list[PredictionRecord] = field(default_factory=list)


def model_record(answerer: Answerer) -> dict[str, Any]:
    """``answerer.describe()`` plus what decides the items it is asked (``single_image_only``, ``max_images`` from
    the answerer or its spec), so a run directory tells by itself which items it should hold
    (:func:`probes.vlm.selection.asked_items`)."""
    model = dict(answerer.describe())
    single_only = getattr(answerer, "single_image_only", None)
    if single_only is not None:
        model.setdefault("single_image_only", bool(single_only))
    max_images = getattr(getattr(answerer, "spec", None), "max_images", None)
    if max_images is not None:
        model.setdefault("max_images", int(max_images))
    return model


def make_manifest(answerer: Answerer, set_dir: Path, circular: bool,
                  extra: dict[str, Any] | None = None) -> RunManifest:  # fmt: skip
    split = set_dir.name
    if (set_dir / vs.MANIFEST_FILE).is_file():
        split = vs.read_manifest(set_dir).get("split", split)
    return RunManifest(answerer=answerer.name, model=model_record(answerer), vqa_dir=str(set_dir.resolve()),
                       split=str(split), question_set_sha256=question_set_sha256(set_dir),
                       prompt_template_sha256=prompt_template_sha256(), circular=bool(circular),
                       extra=dict(extra or {}))  # fmt: skip


def to_record(prompt_options: tuple[str, ...], idx: str, rotation: int, gen: Any) -> PredictionRecord:
    """A reply -> its record, letters mapped back to the set's letter order."""
    strict = vqa_scoring.extract_letter(gen.text)
    lenient = vqa_scoring.extract_letter_lenient(gen.text, prompt_options)
    return PredictionRecord(idx=idx, rotation=rotation, raw=gen.text, letter=to_set_letter(strict, rotation),
                            letter_lenient=to_set_letter(lenient, rotation), latency_s=float(gen.latency_s),
                            tokens_in=gen.tokens_in, tokens_out=gen.tokens_out)  # fmt: skip


def _answer_pending(answerer: Answerer, set_dir: Path, store: PredictionStore, items: list[vs.QuestionItem],
                    circular: bool, batch_size: int, progress: bool) -> int:  # fmt: skip
    """Answer the batches of the work list that are not in ``store`` yet; returns how many predictions."""
    rotations = ROTATIONS if circular else (0,)
    work = [(item, r) for item in items for r in rotations]
    chunks = [work[i:i + batch_size] for i in range(0, len(work), batch_size)]
    pending_chunks = [[(it, r) for it, r in c if (it.idx, r) not in store.done] for c in chunks]
    pending_chunks = [c for c in pending_chunks if c]
    log.info("%s on %s: %d items x %d rotation(s); %d predictions done, %d batches to go", answerer.name, set_dir,
             len(items), len(rotations), len(store.done), len(pending_chunks))  # fmt: skip
    answered = 0
    bar = None
    if progress and pending_chunks:
        from tqdm import tqdm

        bar = tqdm(total=sum(len(c) for c in pending_chunks), desc=f"{answerer.name}", unit="prompt")
    try:
        for chunk in pending_chunks:
            prompts = [build_prompt(item, set_dir, r) for item, r in chunk]
            gens = answerer.answer(prompts)
            if len(gens) != len(prompts):
                raise RuntimeError(f"answerer {answerer.name!r} returned {len(gens)} replies for {len(prompts)} "
                                   "prompts")  # fmt: skip
            answered += store.append(to_record(p.options, p.idx, p.rotation, g) for p, g in zip(prompts, gens))
            if bar is not None:
                bar.update(len(chunk))
    finally:
        if bar is not None:
            bar.close()
    return answered


def evaluate(answerer: Answerer, set_dir: Path | str, run_dir: Path | str, *, batch_size: int = 8,
             circular: bool = False, limit: int | None = None, progress: bool = True,
             extra: dict[str, Any] | None = None, shard_index: int = 0, num_shards: int = 1) -> EvalResult:  # fmt: skip
    """Answer the set at ``set_dir`` with ``answerer`` into ``run_dir`` (resuming what is there).

    ``limit``: answer only the first ``limit`` asked items (smoke runs; recorded in the manifest).
    ``shard_index`` / ``num_shards``: answer only that shard's whole sequences (one job of a sharded run,
    recorded in the manifest; :func:`probes.vlm.sharding.merge_runs` joins the shards' run directories).
    """
    check_shard(shard_index, num_shards)
    if batch_size < 1:
        raise ValueError(f"batch_size must be >= 1, got {batch_size}")
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be >= 1 or null, got {limit}")
    set_dir = Path(set_dir)
    start = time.perf_counter()
    extra = {**(extra or {}), "limit": limit}
    if num_shards > 1:
        extra.update(shard_index=shard_index, num_shards=num_shards)
    manifest = make_manifest(answerer, set_dir, circular, extra)
    items, not_asked = asked_items(vs.read_items(set_dir), json.loads(manifest.to_json()))
    items = shard_items(items, shard_index, num_shards)
    with PredictionStore(run_dir) as store:
        before = store.open(manifest)
        answered = _answer_pending(answerer, set_dir, store, items, circular, batch_size, progress)
    return EvalResult(run_dir=Path(run_dir), manifest=manifest, items=len(items), not_asked=not_asked,
                      answered=answered, already_done=len(before), seconds=time.perf_counter() - start)  # fmt: skip
