"""Dataset statistics from world states only (no map is decoded): plots and a summary table.

``python -m newtphys stats DIR --out DIR/stats`` writes ``summary.md``,
``summary.json`` and ``stats.png`` (collisions per sequence, E / nu / rho /
mass distributions, object speeds, camera motion, materials pie, visibility,
gravity magnitudes per split).
"""

from __future__ import annotations

import json
import os
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from matplotlib.figure import Figure
import numpy as np  # noqa: E402
from tqdm import tqdm  # noqa: E402

from newtphys import schema  # noqa: E402
from newtphys.paper_stats import PAPER  # noqa: E402
from newtphys.shards import ShardReader, list_shards  # noqa: E402
from newtphys.world_state import WorldState  # noqa: E402


@dataclass
class DatasetStats:
    """Flat per-sequence / per-object / per-frame samples gathered from world states."""

    splits: Counter = field(default_factory=Counter)
    frames: int = 0
    collisions_per_sequence: list[int] = field(default_factory=list)
    objects_per_sequence: list[int] = field(default_factory=list)
    young_modulus_pa: list[float] = field(default_factory=list)
    poisson_ratio: list[float] = field(default_factory=list)
    density_kg_m3: list[float] = field(default_factory=list)
    mass_kg: list[float] = field(default_factory=list)
    materials: Counter = field(default_factory=Counter)
    categories: Counter = field(default_factory=Counter)
    speed_m_s: list[float] = field(default_factory=list)
    camera_speed_m_s: list[float] = field(default_factory=list)
    visible_fraction: list[float] = field(default_factory=list)
    gravity_m_s2: dict[str, list[float]] = field(default_factory=dict)
    collisions_per_object_by_scenario: dict[str, list[float]] = field(default_factory=dict)
    """Collision events per object of each sequence, by the scenario (mixture component) that drew it."""

    def add(self, ws: WorldState) -> None:
        self.splits[ws.split] += 1
        kind = str(ws.extra.get("scenario") or "unknown")
        self.collisions_per_object_by_scenario.setdefault(kind, []).append(len(ws.collisions) / max(len(ws.objects), 1))
        self.frames += ws.num_frames
        self.collisions_per_sequence.append(len(ws.collisions))
        self.objects_per_sequence.append(len(ws.objects))
        self.gravity_m_s2.setdefault(ws.split, []).append(ws.gravity_magnitude)
        for o in ws.objects:
            self.young_modulus_pa.append(o.young_modulus)
            self.poisson_ratio.append(o.poisson_ratio)
            self.density_kg_m3.append(o.density)
            self.mass_kg.append(o.mass)
            self.materials[o.material] += 1
            self.categories[o.category] += 1
        cams = np.array([f.camera.position for f in ws.frames])
        if len(cams) > 1:
            self.camera_speed_m_s += (np.linalg.norm(np.diff(cams, axis=0), axis=1) * ws.fps).tolist()
        for f in ws.frames:
            for o in f.objects:
                self.speed_m_s.append(float(np.linalg.norm(o.velocity)))
                if o.in_view:
                    self.visible_fraction.append(o.visible_fraction)

    def summary(self) -> dict[str, object]:
        def stat(xs: list[float]) -> dict[str, float]:
            a = np.asarray(xs, np.float64)
            if not a.size:
                return {}
            return {"min": float(a.min()), "median": float(np.median(a)), "mean": float(a.mean()), "max": float(a.max())}

        return {
            "sequences": dict(self.splits),
            "frames": self.frames,
            "objects": int(sum(self.objects_per_sequence)),
            "objects_per_sequence": stat(self.objects_per_sequence),
            "collisions_per_sequence": stat(self.collisions_per_sequence),
            "young_modulus_pa": stat(self.young_modulus_pa),
            "poisson_ratio": stat(self.poisson_ratio),
            "density_kg_m3": stat(self.density_kg_m3),
            "mass_kg": stat(self.mass_kg),
            "object_speed_m_s": stat(self.speed_m_s),
            "camera_speed_m_s": stat(self.camera_speed_m_s),
            "visible_fraction": stat(self.visible_fraction),
            "gravity_m_s2": {k: stat(v) for k, v in self.gravity_m_s2.items()},
            "materials": dict(self.materials.most_common()),
            "categories": dict(self.categories.most_common()),
            "collisions_per_object_by_scenario": {k: stat(v) | {"sequences": len(v)}
                                                  for k, v in sorted(self.collisions_per_object_by_scenario.items())},
            "paper_comparison": paper_comparison(self),
        }


SOFT_E_PA = 1.0e5
"""Objects below this Young's modulus count as soft (plush, gel, soft foam), Pa."""


def paper_comparison(stats: DatasetStats) -> list[dict[str, str]]:
    """Rows (quantity, this dataset, the paper) for the numbers the paper reports (``newtphys.paper_stats``)."""
    p = PAPER
    n = max(sum(stats.splits.values()), 1)
    coll = np.asarray(stats.collisions_per_sequence, np.float64)
    objs = np.asarray(stats.objects_per_sequence, np.float64)
    e = np.asarray(stats.young_modulus_pa, np.float64)
    rows = [
        ("sequences", f"{n}", f"{p.sequences}"),
        ("frames per sequence (mean)", f"{stats.frames / n:.1f}", f"{p.frames / p.sequences:.1f}"),
        ("collision events per sequence (mean, median)",
         f"{coll.mean():.1f}, {np.median(coll):.0f}" if coll.size else "-", f"~{p.collisions_per_sequence:g}"),
        ("objects per sequence (min-max, mean)",
         f"{objs.min():.0f}-{objs.max():.0f}, {objs.mean():.1f}" if objs.size else "-",
         f"1-{p.max_objects_per_scene}"),
        ("Young's modulus Pa (min, median, max)",
         f"{e.min():.1e}, {np.median(e):.1e}, {e.max():.1e}" if e.size else "-", f"from ~{p.min_young_modulus_pa:.0e}"),
        ("soft objects (E < 1e5 Pa)", f"{(e < SOFT_E_PA).mean():.0%}" if e.size else "-", "highly deformable objects"),
    ]
    return [{"quantity": q, "dataset": d, "paper": pp} for q, d, pp in rows]


def gather(root: str | os.PathLike, progress: bool = True) -> DatasetStats:
    """World states of every shard under ``root`` (a split directory or a dataset root)."""
    root = Path(root)
    shards = list_shards(root) + [s for d in sorted(root.iterdir()) if d.is_dir() for s in list_shards(d)]
    if not shards:
        raise FileNotFoundError(f"{root}: no shards found (expected {schema.SHARD_GLOB} here or in split directories)")
    stats = DatasetStats()
    for path in tqdm(shards, desc="stats", unit="shard", disable=not progress):
        with ShardReader(path) as r:
            for sid in r.sequences():
                stats.add(r.world_state(sid))
    return stats


def _markdown(summary: dict[str, object]) -> str:
    lines = ["| quantity | min | median | mean | max |", "|---|---|---|---|---|"]
    for key, val in summary.items():
        if isinstance(val, dict) and val and set(val) == {"min", "median", "mean", "max"}:
            lines.append(f"| {key} | " + " | ".join(f"{val[k]:.4g}" for k in ("min", "median", "mean", "max")) + " |")
    for split, val in summary["gravity_m_s2"].items():  # type: ignore[union-attr]
        lines.append(f"| gravity ({split}) m/s² | " + " | ".join(f"{val[k]:.4g}" for k in ("min", "median", "mean", "max")) + " |")
    head = [f"sequences: {summary['sequences']}, frames: {summary['frames']}, objects: {summary['objects']}", ""]
    tail = ["", f"materials: {summary['materials']}", "", f"categories: {summary['categories']}"]
    paper = ["", "beside the paper's dataset:", "", "| quantity | this dataset | paper |", "|---|---|---|"]
    paper += [f"| {r['quantity']} | {r['dataset']} | {r['paper']} |" for r in summary.get("paper_comparison", [])]
    return "\n".join(head + lines + tail + paper) + "\n"


def plot(stats: DatasetStats, out_png: Path) -> Path:
    fig = Figure(figsize=(13, 11))  # no pyplot: importing this module sets no backend
    axes = fig.subplots(3, 3)
    ax = axes.ravel()

    def hist(a, data, title, xlabel, log=False):
        data = np.asarray(data, np.float64)
        if data.size:
            lo, hi = float(data.min()), float(data.max())
            if log and lo > 0 and hi > lo * 1.01:
                a.hist(data, bins=np.logspace(np.log10(lo), np.log10(hi), 25), color="#4477aa")
                a.set_xscale("log")
            else:  # also covers (near-)constant samples, which need an explicit range
                pad = max(hi - lo, 0.1 * max(abs(lo), abs(hi)), 1e-9)
                a.hist(data, bins=25, range=(lo - 0.05 * pad, hi + 0.05 * pad), color="#4477aa")
                a.ticklabel_format(axis="x", useOffset=False)
        a.set_title(title, fontsize=10)
        a.set_xlabel(xlabel)

    hist(ax[0], stats.collisions_per_sequence, "collision events per sequence", "events")
    ax[0].axvline(PAPER.collisions_per_sequence, color="#cc3311", ls="--", label="paper (~15)")
    ax[0].legend(fontsize=8)
    hist(ax[1], stats.young_modulus_pa, "Young's modulus", "E (Pa)", log=True)
    hist(ax[2], stats.poisson_ratio, "Poisson ratio", "ν")
    hist(ax[3], stats.density_kg_m3, "density", "ρ (kg/m³)", log=True)
    hist(ax[4], stats.mass_kg, "mass", "m (kg)", log=True)
    hist(ax[5], stats.speed_m_s, "object speed (all frames)", "|v| (m/s)")
    hist(ax[6], stats.camera_speed_m_s, "camera speed", "m/s")
    hist(ax[7], stats.visible_fraction, "visible fraction of in-view objects", "fraction")
    if stats.materials:
        names, counts = zip(*stats.materials.most_common())
        ax[8].pie(counts, labels=names, autopct="%1.0f%%", textprops={"fontsize": 8})
    ax[8].set_title("materials", fontsize=10)
    g = stats.gravity_m_s2
    fig.suptitle("NewtPhys dataset statistics — gravity per split (m/s²): "
                 + ", ".join(f"{k} {np.min(v):.2f}–{np.max(v):.2f}" for k, v in g.items()), fontsize=11)
    fig.tight_layout()
    out_png.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_png, dpi=110)
    return out_png


def write_stats(root: str | os.PathLike, out_dir: str | os.PathLike, progress: bool = True) -> dict[str, object]:
    stats = gather(root, progress)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    summary = stats.summary()
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    (out / "summary.md").write_text(_markdown(summary))
    plot(stats, out / "stats.png")
    return summary
