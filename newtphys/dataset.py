"""Torch dataset of K-frame clips over the shards of one split directory.

An item is the clip of frames ``[s, s + (K-1) * frame_step]`` (every
``frame_step``-th frame) of one sequence, with the requested maps of the LAST
frame as targets. Layouts (float32 unless stated):

=====================  ==================  =======================================
key                    shape               meaning
=====================  ==================  =======================================
``frames``             (K, 3, H, W)        RGB in [0, 1], not normalised
``object_mask``        (H, W) bool         instances > 0 at the last frame
``instances``          (H, W) int64        object ids, last frame (when requested)
``collision``          (H, W)              0/1
``depth``, ``stress``  (H, W)              m, Pa
``gravity``            (3, H, W)           N, camera frame of the last frame
``scene_flow``         (3, H, W)           m, camera frame of the last frame
``optical_flow``       (2, H, W)           px
label maps             (H, W) int64        semantic / material ids
``gravity_world``      (3,)                m/s^2, world frame
``world_to_camera``    (4, 4)              last frame
``K``                  (3, 3)              px (rescaled with ``image_size``)
``sequence_id``        str
``frame_index``        int                 index of the last frame
``split``              str
=====================  ==================  =======================================

With ``image_size`` set, frames are resized bilinearly and targets by
nearest neighbour (so ids, masks and vectors are never blended).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from newtphys import schema
from newtphys.shards import ShardError, ShardReader, list_shards, read_index

DEFAULT_TARGETS: tuple[str, ...] = (schema.COLLISION, schema.GRAVITY, schema.SCENE_FLOW)


@dataclass(frozen=True)
class ClipRef:
    shard: int
    sequence_id: str
    start: int
    """First frame of the clip."""


class ClipDataset(Dataset):
    """K-frame clips of a split directory (``<root>/<split>/shard-*.h5``)."""

    def __init__(
        self,
        split_dir: str | os.PathLike,
        clip_length: int = 4,
        stride: int = 1,
        frame_step: int = 1,
        targets: Sequence[str] = DEFAULT_TARGETS,
        image_size: int | tuple[int, int] | None = None,
    ) -> None:
        self.split_dir = Path(split_dir)
        for name, value, low in (("clip_length", clip_length, 1), ("stride", stride, 1), ("frame_step", frame_step, 1)):
            if int(value) < low:
                raise ValueError(f"ClipDataset: {name} must be >= {low}, got {value}")
        self.clip_length = int(clip_length)
        self.stride = int(stride)
        self.frame_step = int(frame_step)
        self.targets = tuple(targets)
        for name in self.targets:
            schema.get_map(name)  # unknown names list the valid ones
            if schema.MAPS[name].per_object:
                raise ValueError(f"ClipDataset: per-object map {name!r} cannot be a per-pixel target")
        if isinstance(image_size, int):
            image_size = (image_size, image_size)
        self.image_size = tuple(image_size) if image_size is not None else None
        if not self.split_dir.is_dir():
            raise ShardError(f"{self.split_dir}: split directory does not exist")
        shard_paths = list_shards(self.split_dir)
        if not shard_paths:
            raise ShardError(f"{self.split_dir}: no shards (expected files matching {schema.SHARD_GLOB})")
        self.readers = [ShardReader(p) for p in shard_paths]
        self.span = (self.clip_length - 1) * self.frame_step + 1
        self.clips = self._index_clips()

    def _sequence_lengths(self) -> list[list[tuple[str, int]]]:
        """(sequence, num_frames) per shard, from index.json when it matches the shards, else from the files."""
        names = [r.path.name for r in self.readers]
        try:
            entries = {e["file"]: e for e in read_index(self.split_dir)["shards"]}
        except ShardError:
            entries = {}
        out = []
        for reader, name in zip(self.readers, names):
            entry = entries.get(name)
            if entry is not None and entry.get("size_bytes") == reader.path.stat().st_size:
                out.append([(s["id"], int(s["num_frames"])) for s in entry["sequences"]])
            else:
                out.append([(sid, reader.num_frames(sid)) for sid in reader.sequences()])
        # Always check the schema version by touching each file once.
        for reader in self.readers:
            _ = reader.file
        return out

    def _index_clips(self) -> list[ClipRef]:
        clips: list[ClipRef] = []
        longest = 0
        for shard, seqs in enumerate(self._sequence_lengths()):
            for sid, t in seqs:
                longest = max(longest, t)
                clips.extend(ClipRef(shard, sid, s) for s in range(0, t - self.span + 1, self.stride))
        if not clips:
            raise ShardError(
                f"{self.split_dir}: clip_length={self.clip_length} with frame_step={self.frame_step} spans "
                f"{self.span} frames, longer than every sequence (longest has {longest} frames)"
            )
        return clips

    def __len__(self) -> int:
        return len(self.clips)

    # ------------------------------------------------------------------ #
    def _resize(self, x: torch.Tensor, mode: str) -> torch.Tensor:
        """Resize (..., C, H, W)-shaped tensors to image_size."""
        if self.image_size is None or tuple(x.shape[-2:]) == self.image_size:
            return x
        lead = x.shape[:-2]
        flat = x.reshape(-1, 1, *x.shape[-2:]).float()
        kwargs = {"align_corners": False} if mode == "bilinear" else {}
        out = F.interpolate(flat, size=self.image_size, mode=mode, **kwargs)
        return out.reshape(*lead, *self.image_size).to(x.dtype)

    def __getitem__(self, index: int) -> dict[str, Any]:
        ref = self.clips[index]
        reader = self.readers[ref.shard]
        last = ref.start + self.span - 1
        rgb = reader.read(ref.sequence_id, schema.RGB, ref.start, last + 1)[:: self.frame_step]
        frames = torch.from_numpy(np.ascontiguousarray(rgb.transpose(0, 3, 1, 2), dtype=np.float32) / np.float32(255.0))
        item: dict[str, Any] = {"frames": self._resize(frames, "bilinear")}
        instances = reader.read(ref.sequence_id, schema.INSTANCES, last, last + 1)[0]
        inst = self._resize(torch.from_numpy(instances.astype(np.int64)), "nearest")
        item["object_mask"] = inst > 0
        for name in self.targets:
            spec = schema.MAPS[name]
            if name == schema.INSTANCES:
                item[name] = inst
                continue
            arr = reader.read(ref.sequence_id, name, last, last + 1)[0]
            if arr.ndim == 3:  # (H, W, C) -> (C, H, W)
                arr = arr.transpose(2, 0, 1)
            dtype = np.int64 if spec.kind == schema.MapKind.LABEL else np.float32
            item[name] = self._resize(torch.from_numpy(np.ascontiguousarray(arr, dtype=dtype)), "nearest")
        ws = reader.world_state(ref.sequence_id)
        K = torch.from_numpy(reader.intrinsics(ref.sequence_id).astype(np.float32))
        if self.image_size is not None:
            h, w = ws.image_size
            scale = torch.tensor([self.image_size[1] / w, self.image_size[0] / h, 1.0])
            K = K * scale[:, None]
        item["K"] = K
        item["world_to_camera"] = torch.from_numpy(reader.world_to_camera(ref.sequence_id, last, last + 1)[0])
        item["gravity_world"] = torch.tensor(ws.gravity, dtype=torch.float32)
        item["sequence_id"] = ref.sequence_id
        item["frame_index"] = last
        item["split"] = ws.split
        return item
