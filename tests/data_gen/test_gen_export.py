"""Export of a generated scene frame to a 3DGS .ply: re-simulated exactly, readable by the .ply reader."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from data_gen.assets.ply_io import read_splat_ply
from data_gen.export_ply import main, scene_gaussians_at
from newtphys.shards import ShardReader


def test_export_matches_the_generated_world_state(generated_root: Path, tmp_path: Path) -> None:
    shard = generated_root / "train" / "shard-00000.h5"
    with ShardReader(shard) as r:
        ws = r.world_state("train-000000")
    frame = ws.num_frames - 1
    g = scene_gaussians_at(shard, "train-000000", frame)
    for obj, state in zip(ws.objects, ws.frames[frame].objects):
        pts = g.means_m[g.part_ids == obj.id].astype(np.float64)
        assert len(pts) > 100
        # Surface splats surround the simulated centre of mass: within one bounding-box diagonal of it,
        # and their bounding box contains it (the COM of a solid lies inside its hull).
        assert np.linalg.norm(pts - np.asarray(state.position), axis=1).max() <= np.linalg.norm(obj.size) + 1e-3
        assert np.all(pts.min(0) - 1e-3 <= np.asarray(state.position))
        assert np.all(np.asarray(state.position) <= pts.max(0) + 1e-3)
    out = tmp_path / "scene.ply"
    assert main([str(shard), "--sequence", "train-000000", "--frame", str(frame), "--out", str(out)]) == 0
    ply = read_splat_ply(out)
    np.testing.assert_allclose(ply.positions, g.means_m, atol=1e-6)
    np.testing.assert_allclose(np.exp(ply.log_scales), g.scales_m, rtol=1e-5)
