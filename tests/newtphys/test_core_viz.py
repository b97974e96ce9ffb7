"""Colourisers, contact sheet and video of `python -m newtphys view`."""

from __future__ import annotations

from pathlib import Path

import imageio.v3 as iio
import numpy as np
from PIL import Image

from newtphys import schema, viz
from newtphys.cli import main
from newtphys.shards import ShardReader


def test_colourisers_encode_values() -> None:
    depth = np.array([[0.0, 1.0], [2.0, 3.0]])
    d = viz.colorize_depth(depth)
    assert d[0, 0].tolist() == [0, 0, 0]  # no surface
    assert d[0, 1, 2] > d[0, 1, 0] and d[1, 1, 0] > d[1, 1, 2]  # near blue, far red (turbo)
    ids = viz.colorize_ids(np.array([0, 1, 2, 3]))
    assert ids[0].tolist() == [0, 0, 0]
    assert len({tuple(c) for c in ids[1:]}) == 3
    signed = viz.colorize_signed(np.array([-5.0, 0.0, 5.0]))
    assert signed[0, 2] > signed[0, 0]  # compression (negative) is blue
    assert signed[2, 0] > signed[2, 2]
    assert abs(int(signed[1, 0]) - int(signed[1, 2])) < 10  # zero is neutral
    flow = viz.colorize_flow(np.array([[0.0, 0.0], [1.0, 0.0], [-1.0, 0.0], [0.0, 1.0]]))
    assert flow[0].tolist() == [255, 255, 255]  # no motion is white
    assert len({tuple(c) for c in flow[1:]}) == 3  # directions get distinct hues
    mask = np.array([[True, False]])
    over = viz.overlay_mask(np.full((1, 2, 3), 100, np.uint8), mask)
    assert over[0, 0, 0] > 150 and over[0, 1].tolist() == [50, 50, 50]


def test_view_writes_sheet_and_video(synthetic_dataset: Path, tmp_path: Path) -> None:
    out = tmp_path / "pics" / "seq"
    assert main(["view", str(synthetic_dataset / "test"), "--sequence", "test-000003", "--out", str(out)]) == 0
    sheet = Image.open(out.with_suffix(".png"))
    assert sheet.size[0] > sheet.size[1] > 400
    video = iio.imread(out.with_suffix(".mp4"))
    assert video.shape[0] == 6  # every frame of the sequence
    with ShardReader(synthetic_dataset / "test" / "shard-00001.h5") as r:
        maps = r.read_sequence("test-000003").maps
    frames = viz.video_frames(dict(maps))
    # 13 maps in 5 columns -> 3 rows of 128 px tiles (32 px maps scaled x4) with 12 px title bars.
    assert frames.shape == (6, 3 * (128 + 12), 5 * 128, 3)
    # The rgb tile is the frame, upscaled by 4 without blending.
    np.testing.assert_array_equal(frames[2, 12 : 12 + 128 : 4, 0:128:4], maps[schema.RGB][2])
    assert main(["view", str(synthetic_dataset / "test"), "--sequence", "nope", "--out", str(out)]) == 1
