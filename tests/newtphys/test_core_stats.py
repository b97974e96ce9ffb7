"""`python -m newtphys stats`: numbers gathered from world states, plots written."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from newtphys.cli import main
from newtphys.shards import ShardReader, list_shards
from newtphys.stats import gather


def test_stats_match_world_states(synthetic_dataset: Path, tmp_path: Path) -> None:
    stats = gather(synthetic_dataset, progress=False)
    assert dict(stats.splits) == {"train": 4, "val": 4, "test": 4, "test_ood_gravity": 4}
    masses = []
    ood_g = []
    for split in ("train", "val", "test", "test_ood_gravity"):
        for shard in list_shards(synthetic_dataset / split):
            with ShardReader(shard) as r:
                for sid in r.sequences():
                    ws = r.world_state(sid)
                    masses += [o.mass for o in ws.objects]
                    if split == "test_ood_gravity":
                        ood_g.append(ws.gravity_magnitude)
    assert sorted(stats.mass_kg) == pytest.approx(sorted(masses))
    assert stats.frames == 16 * 6
    assert sorted(stats.gravity_m_s2["test_ood_gravity"]) == pytest.approx(sorted(ood_g))
    assert all(0.98 <= g <= 20.0 for g in ood_g)
    # Camera of the fixture dollies 0.02 m per frame at 25 FPS = 0.5 m/s.
    np.testing.assert_allclose(stats.camera_speed_m_s, 0.5, rtol=1e-4)

    out = tmp_path / "stats"
    assert main(["stats", str(synthetic_dataset), "--out", str(out)]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["objects"] == 32 and summary["materials"] == {"wood": 16, "rubber": 16}
    assert summary["mass_kg"]["max"] == pytest.approx(max(masses))
    assert Image.open(out / "stats.png").size[0] > 1000
    assert "| mass_kg |" in (out / "summary.md").read_text()
    assert main(["stats", str(tmp_path / "empty_dir_that_is_missing")]) == 1


def test_stats_print_collisions_objects_and_e_beside_the_paper(synthetic_dataset: Path, tmp_path: Path) -> None:
    from newtphys.paper_stats import PAPER
    from newtphys.stats import paper_comparison, write_stats

    stats = gather(synthetic_dataset, progress=False)
    rows = {r["quantity"]: r for r in paper_comparison(stats)}
    coll = np.array(stats.collisions_per_sequence, np.float64)
    e = np.array(stats.young_modulus_pa)
    assert rows["sequences"] == {"quantity": "sequences", "dataset": "16", "paper": "11000"}
    assert rows["collision events per sequence (mean, median)"]["dataset"] == f"{coll.mean():.1f}, {np.median(coll):.0f}"
    assert rows["collision events per sequence (mean, median)"]["paper"] == "~15"
    assert rows["objects per sequence (min-max, mean)"]["dataset"] == "2-2, 2.0"  # the fixture: 2 boxes each
    assert rows["objects per sequence (min-max, mean)"]["paper"] == "1-10"
    assert rows["Young's modulus Pa (min, median, max)"]["dataset"].startswith(f"{e.min():.1e}")
    assert rows["frames per sequence (mean)"]["paper"] == f"{PAPER.frames / PAPER.sequences:.1f}" == "66.4"
    summary = write_stats(synthetic_dataset, tmp_path / "s", progress=False)
    md = (tmp_path / "s" / "summary.md").read_text()
    assert "| collision events per sequence (mean, median) |" in md and "| ~15 |" in md
    assert summary["paper_comparison"][0]["paper"] == "11000"
