"""Sharded, resumable dataset generation (what ``python generate.py`` runs).

Sequence slot ``i`` of a split lives in shard ``i // sequences_per_shard``.
Its scenario is drawn from a seed derived from (run seed, split, i, attempt),
so a slot is reproducible on its own and independent of which job or shard
range generates it. A rejected draw (NaN, tunnelling, objects out of view,
impossible placement) is logged with its reason to the log and to
``<split>/rejections.jsonl`` and replaced by the next attempt.

Resume: a shard whose final file exists is complete (the writer renames it
only when whole) and is skipped; an index entry missing after a crash is
restored from the file.
"""

from __future__ import annotations

import json
import logging
import os
import time
from collections import Counter
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from data_gen.assets.meshing import enable_disk_cache
from data_gen.pipeline import RenderSettings, SequenceRejected, generate_sequence
from data_gen.scenario import Scenario, ScenarioConfig, ScenarioError, sample_scenario
from data_gen.sim.presets import QualityPreset
from newtphys import __version__, schema
from newtphys.shards import ShardReader, ShardWriter, read_index, update_index, ShardError
from newtphys.validate import validate_shard

log = logging.getLogger(__name__)

REJECTIONS_FILE = "rejections.jsonl"


@dataclass(frozen=True)
class GenerationConfig:
    """Typed view of newtphys/conf/generate.yaml (everything but the Hydra plumbing)."""

    out_dir: Path
    split: str
    gravity: str
    num_sequences: int
    sequences_per_shard: int
    shards: tuple[int, int] | None
    seed: int
    image_size: tuple[int, int]
    num_frames: int
    fps: float
    max_attempts: int
    scenario: ScenarioConfig
    quality: QualityPreset
    render: RenderSettings
    skinning_cache_dir: str | None = None
    progress: bool = True
    config_yaml: str = ""
    dry_run: bool = False
    """Draw and summarise every scenario without simulating (``data_gen.dry_run``)."""
    num_jobs: int | None = None
    """Cluster runs: the split's shards are cut into this many contiguous, disjoint ranges; ``job`` picks one."""
    job: int | None = None

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any], config_yaml: str = "") -> GenerationConfig:
        def need(key: str) -> Any:
            if key not in cfg:
                raise ValueError(f"generate config: missing key '{key}'")
            return cfg[key]

        split = str(need("split"))
        if split not in schema.SPLITS:
            raise ValueError(f"generate config: split {split!r} unknown; valid splits: {list(schema.SPLITS)}")
        gravity = str(need("gravity"))
        if gravity not in ("earth", "ood"):
            raise ValueError(f"generate config: gravity must be 'earth' or 'ood', got {gravity!r}")
        if (split == schema.Split.TEST_OOD_GRAVITY.value) != (gravity == "ood"):
            log.warning("split %r with gravity=%s: the contract's OOD split is test_ood_gravity with gravity=ood",
                        split, gravity)
        ints = {k: int(need(k)) for k in ("num_sequences", "sequences_per_shard", "seed", "num_frames", "max_attempts")}
        for k, v in ints.items():
            low = 0 if k == "seed" else 1
            if v < low:
                raise ValueError(f"generate config: {k} must be >= {low}, got {v}")
        size = tuple(int(v) for v in need("image_size"))
        if len(size) != 2 or min(size) < 8:
            raise ValueError(f"generate config: image_size must be [H, W] with both >= 8 px, got {list(size)}")
        shards = cfg.get("shards")
        num_shards = -(-ints["num_sequences"] // ints["sequences_per_shard"])
        if shards is not None:
            shards = (int(shards[0]), int(shards[1]))
            if not 0 <= shards[0] < shards[1] <= num_shards:
                raise ValueError(f"generate config: shards {list(shards)} must satisfy 0 <= first < stop <= {num_shards}")
        num_jobs, job = cfg.get("num_jobs"), cfg.get("job")
        if (num_jobs is None) != (job is None):
            raise ValueError(f"generate config: num_jobs and job go together, got num_jobs={num_jobs}, job={job}")
        if num_jobs is not None:
            num_jobs, job = int(num_jobs), int(job)
            if shards is not None:
                raise ValueError("generate config: give shards or num_jobs/job, not both")
            if not 1 <= num_jobs <= num_shards or not 0 <= job < num_jobs:
                raise ValueError(f"generate config: need 1 <= num_jobs <= {num_shards} (shards of the split) and "
                                 f"0 <= job < num_jobs, got num_jobs={num_jobs}, job={job}")
            shards = job_shard_range(num_shards, num_jobs, job)
        quality = dict(need("quality"))
        render = dict(need("render"))
        known = set(RenderSettings.__dataclass_fields__)
        if set(render) != known:
            raise ValueError(f"generate config: render keys: unknown {sorted(set(render) - known)}, "
                             f"missing {sorted(known - set(render))} (newtphys/conf/generate.yaml lists them all)")
        return GenerationConfig(
            out_dir=Path(str(need("out_dir"))), split=split, gravity=gravity,
            num_sequences=ints["num_sequences"], sequences_per_shard=ints["sequences_per_shard"], shards=shards,
            seed=ints["seed"], image_size=size, num_frames=ints["num_frames"], fps=float(need("fps")),
            max_attempts=ints["max_attempts"], scenario=ScenarioConfig.from_mapping(dict(need("scenario"))),
            quality=QualityPreset(**quality), render=RenderSettings(**render),
            skinning_cache_dir=cfg.get("skinning_cache_dir"), progress=bool(cfg.get("progress", True)),
            config_yaml=config_yaml, dry_run=bool(cfg.get("dry_run", False)), num_jobs=num_jobs, job=job,
        )

    @property
    def num_shards(self) -> int:
        return -(-self.num_sequences // self.sequences_per_shard)

    def shard_range(self) -> range:
        return range(*(self.shards or (0, self.num_shards)))


def job_shard_range(num_shards: int, num_jobs: int, job: int) -> tuple[int, int]:
    """[first, stop) shards of job ``job`` of ``num_jobs``: contiguous, disjoint, covering every shard, sizes
    differing by at most one (the first ``num_shards % num_jobs`` jobs take one more)."""
    base, extra = divmod(num_shards, num_jobs)
    first = job * base + min(job, extra)
    return first, first + base + (1 if job < extra else 0)


def slots_of(cfg: GenerationConfig) -> range:
    """Sequence slots of the config's shard range."""
    first, stop = cfg.shards or (0, cfg.num_shards)
    return range(first * cfg.sequences_per_shard, min(stop * cfg.sequences_per_shard, cfg.num_sequences))


def draw_scenario(cfg: GenerationConfig, slot: int, first_attempt: int = 0) -> tuple[Scenario, int, list[str]]:
    """The scenario of slot ``slot``: the first attempt from ``first_attempt`` on whose placement succeeds.
    Returns it, its attempt and the messages of the placements that failed; raises RuntimeError after
    ``max_attempts``. The generator and the dry run both draw through here."""
    sequence_id = f"{cfg.split}-{slot:06d}"
    failed: list[str] = []
    for attempt in range(first_attempt, cfg.max_attempts):
        seed = slot_seed(cfg.seed, cfg.split, slot, attempt)
        try:
            return (sample_scenario(cfg.scenario, sequence_id, seed, cfg.split, cfg.gravity, cfg.num_frames, cfg.fps,
                                    cfg.image_size), attempt, failed)
        except ScenarioError as e:
            failed.append(str(e))
    raise RuntimeError(f"{sequence_id}: no placement in attempts {first_attempt}..{cfg.max_attempts - 1}: "
                       f"{failed[-1] if failed else ''}; loosen the scenario or raise max_attempts")


def slot_seed(run_seed: int, split: str, slot: int, attempt: int) -> int:
    """Seed of one draw for one sequence slot (independent of jobs and shard ranges)."""
    ss = np.random.SeedSequence([run_seed, schema.SPLITS.index(split), slot, attempt])
    return int(ss.generate_state(1, np.uint32)[0])


@dataclass
class GenerationReport:
    written_shards: list[str] = field(default_factory=list)
    skipped_shards: list[str] = field(default_factory=list)
    sequences: int = 0
    rejections: Counter = field(default_factory=Counter)
    timings_s: Counter = field(default_factory=Counter)
    dry_run: dict[str, Any] | None = None
    """The statistics of a dry run (nothing generated)."""

    def summary(self) -> str:
        if self.dry_run is not None:
            return f"dry run: {self.dry_run['sequences']} scenarios drawn, nothing simulated ({self.dry_run['jsonl']})"
        per_seq = {k: v / max(self.sequences, 1) for k, v in self.timings_s.items()}
        times = ", ".join(f"{k} {v:.2f}" for k, v in per_seq.items())
        return (f"wrote {len(self.written_shards)} shard(s) ({self.sequences} sequences), skipped "
                f"{len(self.skipped_shards)} finished shard(s); rejections {dict(self.rejections) or 'none'}; "
                f"seconds per sequence: {times or 'n/a'}")


def _log_rejection(split_dir: Path, record: dict[str, Any]) -> None:
    split_dir.mkdir(parents=True, exist_ok=True)
    with open(split_dir / REJECTIONS_FILE, "a") as f:  # one short line per write: atomic with O_APPEND
        f.write(json.dumps(record) + "\n")


def _restore_index_entry(split_dir: Path, path: Path) -> None:
    try:
        listed = {e["file"] for e in read_index(split_dir)["shards"]}
    except ShardError:
        listed = set()
    if path.name not in listed:
        with ShardReader(path) as r:
            seqs = [(sid, r.num_frames(sid)) for sid in r.sequences()]
        update_index(split_dir, path.name, seqs, path.stat().st_size)
        log.info("restored the index entry of %s", path)


def default_cache_root() -> Path:
    """``$NEWTPHYS_CACHE_DIR`` or ``~/.cache/newtphys`` (skinning bases and meshes live below it)."""
    return Path(os.environ.get("NEWTPHYS_CACHE_DIR") or Path.home() / ".cache" / "newtphys")


def run_generation(cfg: GenerationConfig) -> GenerationReport:
    split_dir = cfg.out_dir / cfg.split
    if cfg.dry_run:  # draw and summarise only (data_gen.dry_run): nothing is meshed, simulated or written but JSONL
        from data_gen.dry_run import run_dry_run

        return GenerationReport(dry_run=run_dry_run(cfg))
    enable_disk_cache(default_cache_root() / "meshes")  # meshes are shared by parallel jobs and later runs
    report = GenerationReport()
    shard_ids = list(cfg.shard_range())
    todo = []
    for s in shard_ids:
        path = split_dir / schema.shard_filename(s)
        if path.is_file():
            _restore_index_entry(split_dir, path)
            report.skipped_shards.append(path.name)
        else:
            todo.append(s)
    total = sum(min(cfg.sequences_per_shard, cfg.num_sequences - s * cfg.sequences_per_shard) for s in todo)
    bar = tqdm(total=total, desc=f"generate {cfg.split}", unit="seq", disable=not cfg.progress)
    for s in todo:
        slots = range(s * cfg.sequences_per_shard, min((s + 1) * cfg.sequences_per_shard, cfg.num_sequences))
        with ShardWriter(cfg.out_dir, cfg.split, s, config_yaml=cfg.config_yaml, generator=f"newtphys {__version__}",
                         num_threads=cfg.render.num_threads) as writer:  # fmt: skip
            for slot in slots:
                seq = _generate_slot(cfg, slot, split_dir, report)
                writer.add_sequence(seq.world_state.sequence_id, seq.maps, seq.K, seq.world_to_camera, seq.world_state)
                report.sequences += 1
                bar.update(1)
                bar.set_postfix(rejected=sum(report.rejections.values()))
        problems = [p for p in validate_shard(writer.final_path) if p.severity == "error"]
        if problems:  # a bug, not bad luck: stop loudly rather than ship a broken shard
            writer.final_path.rename(writer.final_path.with_suffix(".h5.invalid"))
            raise RuntimeError("generated shard failed validation:\n" + "\n".join(map(str, problems)))
        report.written_shards.append(writer.final_path.name)
    bar.close()
    log.info(report.summary())
    return report


def _generate_slot(cfg: GenerationConfig, slot: int, split_dir: Path, report: GenerationReport):
    sequence_id = f"{cfg.split}-{slot:06d}"
    attempt = 0
    while attempt < cfg.max_attempts:
        try:
            scenario, attempt, failed = draw_scenario(cfg, slot, attempt)
        except RuntimeError as e:
            _reject(cfg, split_dir, report, sequence_id, cfg.max_attempts - 1, "placement", str(e))
            break
        for k, message in enumerate(failed):  # impossible placements before this attempt
            _reject(cfg, split_dir, report, sequence_id, attempt - len(failed) + k, "placement", message)
        try:
            t0 = time.perf_counter()
            seq, timings = generate_sequence(scenario, cfg.quality, cfg.render, cfg.skinning_cache_dir)
        except SequenceRejected as e:
            _reject(cfg, split_dir, report, sequence_id, attempt, e.reason, str(e))
            attempt += 1
            continue
        for k, v in timings.items():
            report.timings_s[k] += v
        report.timings_s["total_s"] += time.perf_counter() - t0
        return seq
    raise RuntimeError(
        f"{sequence_id}: {cfg.max_attempts} draws in a row were rejected ({dict(report.rejections)}); "
        f"see {split_dir / REJECTIONS_FILE}; loosen the scenario or raise max_attempts"
    )


def _reject(cfg: GenerationConfig, split_dir: Path, report: GenerationReport, sequence_id: str, attempt: int,
            reason: str, detail: str) -> None:
    seed = slot_seed(cfg.seed, cfg.split, int(sequence_id.rsplit("-", 1)[1]), attempt)
    report.rejections[reason] += 1
    log.warning("rejected %s attempt %d (seed %d): %s", sequence_id, attempt, seed, detail)
    _log_rejection(split_dir, {"sequence_id": sequence_id, "attempt": attempt, "seed": seed,
                               "reason": reason, "detail": detail, "pid": os.getpid()})
