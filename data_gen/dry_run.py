"""Preview a split before paying for it: draw every scenario without simulating, write them as JSONL, and
print their statistics beside the paper's (``python generate.py scenario=benchmark num_sequences=11000
dry_run=true``).

Slot ``i`` is drawn exactly as the generator draws it (:func:`data_gen.generator.draw_scenario`, same
seeds, same attempts after an impossible placement), so a line of the dry run is the scenario the real run
simulates for that slot unless the simulation itself rejects the draw (NaN, tunnelling, out of view): then
the real run moves on to the next attempt, which the dry run cannot know.

Collisions cannot be counted without simulating. The dry run estimates them from what the scenario fixes:
``collisions_per_object[kind] x objects`` (:data:`COLLISIONS_PER_OBJECT`, measured on generated sequences,
see the README's "Benchmark-scale data"); it is an estimate, labelled as such everywhere it is printed.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import time
from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from data_gen.assets.registry import get_object
from data_gen.scenario import Scenario
from newtphys import paper_stats

log = logging.getLogger(__name__)

DRY_RUN_FILE = "dry_run.jsonl"
DRY_RUN_SUMMARY = "dry_run_summary.json"

COLLISIONS_PER_OBJECT: dict[str, float] = {"drop": 1.39, "throw": 1.52, "push": 1.6, "pile": 2.91}
"""Collision events (contact onsets, scene included) per object per sequence, by scenario kind: the mean of
generated ``benchmark`` sequences (draft quality, 256 x 144, measured with ``newtphys stats``; issue 14):
drop 1.0, 1.5, 1.67 (3 sequences); throw 2.0, 1.25, 1.67, 1.67, 1.0 (5); push 1.13, 1.44, 2.38, 1.44 (4);
pile (objects stacked over one spot) 3.0, 2.9, 2.0, 2.89, 3.43, 3.4, 1.8, 2.8, 4.0 (9). Few sequences: an
estimate to compare mixtures with, not a measurement of the split; the README lists the sequences."""
SOFT_E_PA = 1.0e5
"""Young's modulus below which an object counts as soft (plush, gel, soft foam), Pa."""
VERY_SOFT_E_PA = 1.0e4


def scenario_kind(scenario: Scenario) -> str:
    """The component (``benchmark/pile`` -> ``pile``) or scenario name that drew it."""
    return (scenario.kind or "").rsplit("/", 1)[-1]


def estimated_collisions(scenario: Scenario) -> float:
    """Collision events expected from the scenario alone: per-object rate of its kind x objects (the mean
    rate for a kind without one)."""
    rate = COLLISIONS_PER_OBJECT.get(scenario_kind(scenario), float(np.mean(list(COLLISIONS_PER_OBJECT.values()))))
    return rate * len(scenario.objects)


VOLUME_SAMPLES = 40_000
"""Points of the Monte Carlo volume estimate (a 3 mm wall filling 3% of its box: ~3% standard error)."""
_VOLUMES: dict[str, float] = {}


def unit_volume(asset: str) -> float:
    """Volume of the material of library object ``asset`` per cubed largest extent (dimensionless): the
    fraction of seeded uniform points in its bounds where the SDF is negative, times the box volume. An
    estimate (the simulator meshes the shape, ~1 s per object): the dry run must stay fast."""
    if asset not in _VOLUMES:
        a = get_object(asset)
        lo, hi = (np.asarray(b, np.float64) for b in a.shape.bounds())
        p = np.random.default_rng(0).uniform(lo, hi, size=(VOLUME_SAMPLES, 3))
        inside = float((a.shape.sdf(p) < 0.0).mean())
        _VOLUMES[asset] = inside * float(np.prod(hi - lo)) / a.nominal_size_m**3
    return _VOLUMES[asset]


def object_mass_kg(asset: str, size_m: float, density_kg_m3: float) -> float:
    """Estimated mass, kg, of library object ``asset`` drawn at largest extent ``size_m`` (m)."""
    return float(density_kg_m3 * unit_volume(asset) * size_m**3)


def scenario_record(scenario: Scenario, attempt: int) -> dict[str, Any]:
    """One JSONL line: the whole scenario (``dataclasses.asdict``) plus what the statistics read."""
    return {
        "sequence_id": scenario.sequence_id,
        "attempt": attempt,
        "kind": scenario.kind,
        "duration_s": scenario.num_frames / scenario.fps,
        "masses_kg": [object_mass_kg(o.asset, o.size_m, o.density_kg_m3) for o in scenario.objects],
        "estimated_collisions": estimated_collisions(scenario),
        "scenario": dataclasses.asdict(scenario),
    }


def write_jsonl_atomic(path: Path, records: Iterable[dict[str, Any]]) -> Path:
    """Write one JSON object per line to ``path.tmp-<pid>``, then rename: a file under the final name is whole."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.tmp-{os.getpid()}")
    try:
        with open(tmp, "w") as f:
            for r in records:
                f.write(json.dumps(r) + "\n")
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _stat(xs: Sequence[float]) -> dict[str, float]:
    a = np.asarray(xs, np.float64)
    if not a.size:
        return {}
    q = np.quantile(a, [0.05, 0.5, 0.95])
    return {"min": float(a.min()), "p05": float(q[0]), "median": float(q[1]), "mean": float(a.mean()),
            "p95": float(q[2]), "max": float(a.max())}


@dataclass
class DryRunStats:
    """Per-sequence and per-object samples of a dry run."""

    sequences: int = 0
    objects_per_sequence: list[int] = field(default_factory=list)
    duration_s: list[float] = field(default_factory=list)
    frames: list[int] = field(default_factory=list)
    estimated_collisions: list[float] = field(default_factory=list)
    young_modulus_pa: list[float] = field(default_factory=list)
    mass_kg: list[float] = field(default_factory=list)
    kinds: Counter = field(default_factory=Counter)
    scenes: Counter = field(default_factory=Counter)
    assets: Counter = field(default_factory=Counter)
    materials: Counter = field(default_factory=Counter)
    cameras: Counter = field(default_factory=Counter)
    placement_rejections: int = 0

    def add(self, record: dict[str, Any]) -> None:
        s = record["scenario"]
        self.sequences += 1
        self.placement_rejections += int(record["attempt"])
        self.objects_per_sequence.append(len(s["objects"]))
        self.duration_s.append(float(record["duration_s"]))
        self.frames.append(int(s["num_frames"]))
        self.estimated_collisions.append(float(record["estimated_collisions"]))
        self.mass_kg += [float(m) for m in record["masses_kg"]]
        self.kinds[str(record["kind"])] += 1
        self.scenes[s["scene"]] += 1
        self.cameras[s["camera"]["kind"]] += 1
        for o in s["objects"]:
            self.young_modulus_pa.append(float(o["young_modulus_pa"]))
            self.assets[o["asset"]] += 1
            self.materials[o["material"]] += 1

    def summary(self) -> dict[str, Any]:
        e = np.asarray(self.young_modulus_pa, np.float64)
        static = self.cameras.get("static", 0)
        return {
            "sequences": self.sequences,
            "frames": int(sum(self.frames)),
            "objects": int(sum(self.objects_per_sequence)),
            "objects_per_sequence": _stat(self.objects_per_sequence),
            "duration_s": _stat(self.duration_s),
            "frames_per_sequence": _stat(self.frames),
            "estimated_collisions_per_sequence": _stat(self.estimated_collisions),
            "young_modulus_pa": _stat(self.young_modulus_pa),
            "soft_object_share": float((e < SOFT_E_PA).mean()) if e.size else 0.0,
            "very_soft_object_share": float((e < VERY_SOFT_E_PA).mean()) if e.size else 0.0,
            "mass_kg": _stat(self.mass_kg),
            "moving_camera_share": 1.0 - static / max(self.sequences, 1),
            "scenes_used": len(self.scenes),
            "objects_used": len(self.assets),
            "placement_rejections": self.placement_rejections,
            "kinds": dict(self.kinds.most_common()),
            "cameras": dict(self.cameras.most_common()),
            "scenes": dict(self.scenes.most_common()),
            "assets": dict(self.assets.most_common()),
            "materials": dict(self.materials.most_common()),
        }


def _fmt(v: float) -> str:
    return f"{v:.3g}" if abs(v) < 1e4 else f"{v:.2e}"


def format_summary(summary: dict[str, Any], seconds: float) -> str:
    """The statistics as a table beside the paper's numbers (``newtphys.paper_stats``)."""
    p = paper_stats.PAPER
    rows = [("sequences", f"{summary['sequences']}", f"{p.sequences}"),
            ("frames (total)", f"{summary['frames']}", f"{p.frames}")]

    def dist(name: str, key: str, paper: str) -> None:
        d = summary[key]
        if d:
            rows.append((name, f"{_fmt(d['min'])} / {_fmt(d['median'])} / {_fmt(d['mean'])} / {_fmt(d['max'])}", paper))

    dist("objects per sequence (min/median/mean/max)", "objects_per_sequence",
         f"1-{p.max_objects_per_scene}")
    dist("duration s (min/median/mean/max)", "duration_s",
         f"{p.min_duration_s:g}-{p.max_duration_s:g}, mean {p.mean_duration_s:.2f}")
    dist("frames per sequence", "frames_per_sequence", f"mean {p.frames / p.sequences:.1f}")
    dist("collisions per sequence (ESTIMATE, not simulated)", "estimated_collisions_per_sequence",
         f"~{p.collisions_per_sequence:g} (mean)")
    dist("Young's modulus Pa", "young_modulus_pa", f"from ~{p.min_young_modulus_pa:.0e}")
    rows.append(("soft objects (E < 1e5 Pa) / very soft (E < 1e4 Pa)",
                 f"{summary['soft_object_share']:.1%} / {summary['very_soft_object_share']:.1%}", "a real share"))
    dist("mass kg", "mass_kg", "-")
    rows.append(("moving-camera sequences", f"{summary['moving_camera_share']:.1%}", "static and moving"))
    rows.append(("scenes used", f"{summary['scenes_used']}", f"{p.scenes}"))
    rows.append(("objects used (distinct)", f"{summary['objects_used']}", f"{p.objects}"))
    w0 = max(len(r[0]) for r in rows)
    w1 = max(len(r[1]) for r in rows)
    lines = [f"{'quantity':<{w0}}  {'dry run':<{w1}}  paper", "-" * (w0 + w1 + 20)]
    lines += [f"{a:<{w0}}  {b:<{w1}}  {c}" for a, b, c in rows]
    lines.append(f"scenario kinds: {summary['kinds']}")
    lines.append(f"cameras: {summary['cameras']}")
    top = list(summary["scenes"].items())
    lines.append(f"scene use: most {top[0] if top else '-'}, least {top[-1] if top else '-'}")
    top = list(summary["assets"].items())
    lines.append(f"object use: most {top[0] if top else '-'}, least {top[-1] if top else '-'}")
    lines.append(f"placement redraws: {summary['placement_rejections']}; drawn in {seconds:.1f} s")
    return "\n".join(lines)


def _draw_records(cfg, slots: Sequence[int]) -> list[dict[str, Any]]:
    from data_gen.generator import draw_scenario

    out = []
    for slot in slots:
        scenario, attempt, _ = draw_scenario(cfg, slot)
        out.append(scenario_record(scenario, attempt))
    return out


PARALLEL_MIN_SLOTS = 400
"""Dry runs of at least this many slots draw in one process per CPU (slots are independent: same lines)."""


def run_dry_run(cfg, progress: bool | None = None, workers: int | None = None) -> dict[str, Any]:
    """Draw every slot of ``cfg`` (a ``GenerationConfig``; its shard range when set), write
    ``<out_dir>/<split>/dry_run.jsonl`` and ``dry_run_summary.json``, print the table; returns the summary.
    ``workers``: processes (default: the CPUs, for >= ``PARALLEL_MIN_SLOTS`` slots); the lines do not depend on it."""
    from concurrent.futures import ProcessPoolExecutor

    from data_gen.generator import slots_of

    t0 = time.perf_counter()
    slots = list(slots_of(cfg))
    if workers is None:
        workers = min(os.cpu_count() or 1, 16) if len(slots) >= PARALLEL_MIN_SLOTS else 1
    chunks = [slots[i:i + 50] for i in range(0, len(slots), 50)]
    show = cfg.progress if progress is None else progress
    records: list[dict[str, Any]] = []
    with tqdm(total=len(slots), desc=f"dry run {cfg.split}", unit="seq", disable=not show) as bar:
        if workers <= 1:
            for chunk in chunks:
                records += _draw_records(cfg, chunk)
                bar.update(len(chunk))
        else:
            with ProcessPoolExecutor(max_workers=workers) as pool:
                for chunk, part in zip(chunks, pool.map(_draw_records, [cfg] * len(chunks), chunks)):
                    records += part
                    bar.update(len(chunk))
    stats = DryRunStats()
    for rec in records:
        stats.add(rec)
    split_dir = cfg.out_dir / cfg.split
    path = write_jsonl_atomic(split_dir / DRY_RUN_FILE, records)
    seconds = time.perf_counter() - t0
    summary = stats.summary() | {"seconds": seconds, "workers": workers, "jsonl": str(path)}
    tmp = split_dir / f"{DRY_RUN_SUMMARY}.tmp-{os.getpid()}"
    tmp.write_text(json.dumps(summary, indent=1))
    os.replace(tmp, split_dir / DRY_RUN_SUMMARY)
    print(format_summary(summary, seconds))
    print(f"wrote {path} ({len(records)} scenarios, {workers} process(es)) and {split_dir / DRY_RUN_SUMMARY}")
    return summary
