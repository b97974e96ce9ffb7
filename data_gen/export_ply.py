"""Export a generated scene at one frame as a standard 3D Gaussian splat .ply (INRIA layout).

    python -m data_gen.export_ply data/newtphys/train/shard-00000.h5 --sequence train-000000 --frame 12 --out s.ply

The shard stores the resolved generation config and every sequence's seed, so
the scenario is drawn again, re-simulated (deterministic on CPU) and the
static scene plus every object's deformed surface Gaussians at ``frame`` are
written — the same splats the renderer used for that frame. Viewers of 3DGS
captures open the file directly.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import yaml

from data_gen.assets.gaussians_from_geometry import gaussians_from_scene
from data_gen.assets.ply_io import export_splats
from data_gen.assets.registry import get_scene_layout
from data_gen.gaussians import Gaussians, concatenate
from data_gen.generator import GenerationConfig
from data_gen.pipeline import SkinnedSurface, build_objects, simulate
from data_gen.scenario import sample_scenario
from data_gen.sim.threads import torch_threads
from newtphys import schema
from newtphys.shards import ShardReader


def scene_gaussians_at(shard: str | Path, sequence_id: str, frame: int) -> Gaussians:
    """Static scene + deformed object Gaussians of a generated sequence at ``frame`` (world frame, m).

    ``part_ids`` of the result hold the object id of each Gaussian (0 = static scene).
    """
    with ShardReader(shard) as reader:
        ws = reader.world_state(sequence_id)
        config = yaml.safe_load(reader.attrs[schema.FILE_ATTR_CONFIG] or "{}")
    if not 0 <= frame < ws.num_frames:
        raise ValueError(f"frame must be in [0, {ws.num_frames}) for sequence {sequence_id!r}, got {frame}")
    cfg = GenerationConfig.from_mapping(config)
    scenario = sample_scenario(cfg.scenario, sequence_id, ws.seed, ws.split, cfg.gravity, ws.num_frames, ws.fps,
                               tuple(ws.image_size))
    layout = get_scene_layout(scenario.scene)
    objects = build_objects(scenario, cfg.render)
    result = simulate(scenario, objects, layout, cfg.quality, cfg.skinning_cache_dir)
    scene = gaussians_from_scene(layout, spacing_m=cfg.render.scene_spacing_m)
    parts = [scene.with_part_ids(np.zeros(len(scene), np.int32))]  # here part ids hold object ids: 0 = scene
    tracks = {t.object_id: t for t in result.objects}
    with torch_threads(1):
        for o in objects:
            x, scales, rot = SkinnedSurface(o.surface, tracks[o.object_id]).at(frame)
            parts.append(Gaussians(means_m=x, scales_m=scales, rotations_wxyz=rot, colors_rgb=o.surface.colors_rgb,
                                   opacities=o.surface.opacities, part_ids=np.full(len(x), o.object_id, np.int32)))
    return concatenate(parts)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("shard", help="a generated shard (its config attribute holds the generation settings)")
    ap.add_argument("--sequence", required=True)
    ap.add_argument("--frame", type=int, default=0)
    ap.add_argument("--out", required=True, help="output .ply path")
    args = ap.parse_args(argv)
    g = scene_gaussians_at(args.shard, args.sequence, args.frame)
    export_splats(args.out, g)
    print(f"wrote {len(g)} Gaussians of {args.sequence} frame {args.frame} to {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
