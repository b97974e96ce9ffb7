"""ClipDataset: clip indexing, values equal to the shards, layouts, resizing, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from torch.utils.data import DataLoader

from newtphys import schema
from newtphys.dataset import ClipDataset
from newtphys.shards import ShardError, ShardReader


def test_clip_count_and_values(synthetic_dataset: Path) -> None:
    split = synthetic_dataset / "train"
    # 4 sequences x 6 frames; K=3, frame_step=2 spans 5 frames -> starts {0, 1} with stride 1.
    ds = ClipDataset(split, clip_length=3, frame_step=2, targets=(schema.COLLISION, schema.GRAVITY, schema.DEPTH, schema.INSTANCES))
    assert len(ds) == 4 * 2
    item = ds[1]
    assert (item["sequence_id"], item["frame_index"]) == ("train-000000", 5)
    with ShardReader(split / "shard-00000.h5") as r:
        rgb = r.read("train-000000", schema.RGB)
        grav = r.read("train-000000", schema.GRAVITY)
        inst = r.read("train-000000", schema.INSTANCES)
        ws = r.world_state("train-000000")
    expected_frames = torch.from_numpy(rgb[[1, 3, 5]]).permute(0, 3, 1, 2).float() / 255
    torch.testing.assert_close(item["frames"], expected_frames, rtol=0, atol=0)
    torch.testing.assert_close(item[schema.GRAVITY], torch.from_numpy(grav[5]).permute(2, 0, 1))
    assert item[schema.INSTANCES].dtype == torch.int64
    assert torch.equal(item["object_mask"], torch.from_numpy(inst[5] > 0))
    assert item[schema.COLLISION].dtype == torch.float32 and set(item[schema.COLLISION].unique().tolist()) <= {0.0, 1.0}
    torch.testing.assert_close(item["gravity_world"], torch.tensor(ws.gravity, dtype=torch.float32))
    # Gravity force on object pixels = object mass x gravity vector, rotated into the camera frame.
    obj = ws.object_by_id(1)
    rot = item["world_to_camera"][:3, :3].double()
    expected = rot @ (obj.mass * torch.tensor(ws.gravity, dtype=torch.float64))
    on = item[schema.INSTANCES] == 1
    assert on.any()
    torch.testing.assert_close(item[schema.GRAVITY][:, on].double(), expected[:, None].expand(3, int(on.sum())),
                               rtol=1e-5, atol=1e-5)
    # Stride: stride 2 over K=2 (span 2, 6 frames) -> starts 0, 2, 4.
    assert len(ClipDataset(split, clip_length=2, stride=2)) == 4 * 3


def test_resize_keeps_labels_unblended(synthetic_dataset: Path) -> None:
    ds = ClipDataset(synthetic_dataset / "val", clip_length=2, targets=(schema.INSTANCES, schema.SCENE_FLOW), image_size=(64, 48))
    item = ds[0]
    assert item["frames"].shape == (2, 3, 64, 48)
    assert item[schema.SCENE_FLOW].shape == (3, 64, 48)
    assert set(item[schema.INSTANCES].unique().tolist()) <= {0, 1, 2}
    assert item["K"][0, 0] == pytest.approx(ds.readers[0].intrinsics("val-000000")[0, 0] * 48 / 32)


def test_dataloader_with_workers(synthetic_dataset: Path) -> None:
    ds = ClipDataset(synthetic_dataset / "test", clip_length=4)
    serial = [ds[i]["frames"] for i in range(len(ds))]
    loader = DataLoader(ds, batch_size=3, num_workers=2, shuffle=False)
    batches = torch.cat([b["frames"] for b in loader])
    assert torch.equal(batches, torch.stack(serial))


def test_errors(tmp_path: Path, synthetic_dataset: Path) -> None:
    with pytest.raises(ShardError, match="no shards"):
        ClipDataset(tmp_path)
    with pytest.raises(ShardError, match="does not exist"):
        ClipDataset(tmp_path / "nope")
    with pytest.raises(ShardError, match="spans 7 frames, longer than every sequence \\(longest has 6 frames\\)"):
        ClipDataset(synthetic_dataset / "train", clip_length=7)
    with pytest.raises(KeyError, match="valid maps"):
        ClipDataset(synthetic_dataset / "train", targets=("normals",))
    with pytest.raises(ValueError, match="clip_length must be >= 1, got 0"):
        ClipDataset(synthetic_dataset / "train", clip_length=0)
    with pytest.raises(ValueError, match="per-object"):
        ClipDataset(synthetic_dataset / "train", targets=(schema.AMODAL_INSTANCES,))
