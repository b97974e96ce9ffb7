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
