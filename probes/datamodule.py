"""Lightning datamodule over the NewtPhys splits, serving frames or cached backbone features.

Batches (default collate) hold the dataset's keys (``object_mask`` (B, H, W),
the task target, ``sequence_id``, ``frame_index`` ...) plus either

* ``frames``: (B, K, 3, H, W) RGB in [0, 1] (no feature cache), or
* ``features``: one (B, K, C_l, h_l, w_l) tensor per tapped layer, in the
  cache dtype (feature cache on; ``frames`` is dropped).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset, Subset

from newtphys import schema
from newtphys.dataset import ClipDataset
from newtphys.shards import ShardError
from probes.features import FeatureCache, FrameId, shard_fingerprint

EVAL_SPLITS: tuple[str, ...] = (schema.Split.TEST.value, schema.Split.TEST_OOD_GRAVITY.value)


class DataConfigError(ValueError):
    """The data directory or the clip settings cannot serve a probing run."""


class CachedFeatureDataset(Dataset):
    """A :class:`ClipDataset` whose frames are replaced by cached backbone features.

    Missing or stale cache entries are computed with ``backbone`` on first access
    (``fill`` computes them all up front, batched).
    """

    def __init__(
        self, clips: ClipDataset, cache: FeatureCache, backbone: torch.nn.Module, keep_in_memory: bool = False
    ) -> None:
        self.clips = clips
        self.cache = cache
        self.backbone = backbone
        self.keep_in_memory = keep_in_memory
        """Also keep loaded frames in RAM (small datasets, many epochs); per worker process."""
        self._memory: dict[FrameId, list[torch.Tensor]] = {}
        self._fingerprints = {r.path: shard_fingerprint(r.path) for r in clips.readers}

    def __len__(self) -> int:
        return len(self.clips)

    def frame_ids(self, index: int, image_size: tuple[int, int]) -> list[FrameId]:
        """Identities of the K frames of clip ``index`` (oldest first)."""
        ref = self.clips.clips[index]
        path = self.clips.readers[ref.shard].path
        return [
            FrameId(
                str(path.resolve()),
                self._fingerprints[path],
                ref.sequence_id,
                ref.start + k * self.clips.frame_step,
                image_size,
            )
            for k in range(self.clips.clip_length)
        ]

    def _compute(self, frames: torch.Tensor) -> list[list[torch.Tensor]]:
        """Features of (N, 3, H, W) frames -> per frame, list of (C, h, w) maps."""
        device = next(self.backbone.parameters()).device
        maps = self.backbone.features(frames.to(device))
        return [[m[i] for m in maps] for i in range(frames.shape[0])]

    def fill(self, batch_frames: int = 32) -> int:
        """Compute and store every frame without a cache file; returns how many were computed.

        Files whose stored key or frame identity does not match are detected (and recomputed) when read.
        """
        pending: dict[str, tuple[FrameId, torch.Tensor]] = {}
        computed = 0
        seen: set[FrameId] = set()

        def flush() -> int:
            if not pending:
                return 0
            ids, frames = zip(*pending.values())
            for fid, maps in zip(ids, self._compute(torch.stack(frames))):
                self.cache.store(fid, maps)
            n = len(pending)
            pending.clear()
            return n

        for i in range(len(self.clips)):
            ref = self.clips.clips[i]
            reader = self.clips.readers[ref.shard]
            size = self._image_size(reader, ref.sequence_id)
            ids = self.frame_ids(i, size)
            todo = [k for k, fid in enumerate(ids) if fid not in seen and not self.cache.path(fid).exists()]
            seen.update(ids)
            if not todo:
                continue
            frames = self.clips[i]["frames"]
            for k in todo:
                pending[str(ids[k])] = (ids[k], frames[k])
            if len(pending) >= batch_frames:
                computed += flush()
        return computed + flush()

    def _image_size(self, reader: Any, sequence_id: str) -> tuple[int, int]:
        if self.clips.image_size is not None:
            return (int(self.clips.image_size[0]), int(self.clips.image_size[1]))
        h, w = reader.world_state(sequence_id).image_size
        return (int(h), int(w))

    def _load(self, fid: FrameId) -> list[torch.Tensor] | None:
        if fid in self._memory:
            return self._memory[fid]
        maps = self.cache.load(fid)
        if maps is not None and self.keep_in_memory:
            self._memory[fid] = maps
        return maps

    def __getitem__(self, index: int) -> dict[str, Any]:
        item = self.clips[index]
        frames = item.pop("frames")
        ids = self.frame_ids(index, (int(frames.shape[-2]), int(frames.shape[-1])))
        loaded = {k: maps for k, fid in enumerate(ids) if (maps := self._load(fid)) is not None}
        missing = [k for k in range(len(ids)) if k not in loaded]
        if missing:  # absent or stale entries: compute now and store
            with torch.no_grad():
                fresh = self._compute(frames[missing])
            for k, maps in zip(missing, fresh, strict=True):
                self.cache.store(ids[k], maps)
                loaded[k] = [m.to(self.cache.dtype).cpu() for m in maps]
                if self.keep_in_memory:
                    self._memory[ids[k]] = loaded[k]
        per_frame = [loaded[k] for k in range(len(ids))]
        item["features"] = [torch.stack([f[layer] for f in per_frame]) for layer in range(len(per_frame[0]))]
        return item


class ProbeDataModule(L.LightningDataModule):
    """Train/val/test/test_ood_gravity clips of ``<data_root>/<split>/`` for one probing task."""

    def __init__(
        self,
        data_root: str | os.PathLike,
        targets: Sequence[str] = (schema.COLLISION, schema.GRAVITY, schema.SCENE_FLOW),
        clip_length: int = 4,
        stride: int = 1,
        frame_step: int = 1,
        image_size: int | Sequence[int] | None = None,
        batch_size: int = 8,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        feature_cache: bool = False,
        cache_dir: str | os.PathLike | None = None,
        cache_dtype: str = "float16",
        cache_in_memory: bool = False,
        backbone: torch.nn.Module | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        if batch_size < 1:
            raise DataConfigError(f"data.batch_size must be >= 1, got {batch_size}")
        if num_workers < 0:
            raise DataConfigError(f"data.num_workers must be >= 0, got {num_workers}")
        if feature_cache and (cache_dir is None or backbone is None):
            raise DataConfigError("data.feature_cache=true needs data.cache_dir and a backbone")
        self.data_root = Path(data_root)
        self.targets = tuple(targets)
        self.clip_length = int(clip_length)
        self.stride = int(stride)
        self.frame_step = int(frame_step)
        self.image_size = (
            None
            if image_size is None
            else (
                (int(image_size), int(image_size))
                if isinstance(image_size, int)
                else tuple(int(s) for s in image_size)
            )
        )
        self.batch_size = int(batch_size)
        self.eval_batch_size = int(eval_batch_size or batch_size)
        self.num_workers = int(num_workers)
        self.feature_cache = bool(feature_cache)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        self.cache_dtype = cache_dtype
        self.cache_in_memory = bool(cache_in_memory)
        self.backbone = backbone
        self.seed = int(seed)
        self.datasets: dict[str, Dataset] = {}
        self._clip_sets: dict[str, Dataset] = {}  # opened by check(), not yet filled
        self.cache: FeatureCache | None = None

    # ------------------------------------------------------------------ #
    def split_dir(self, split: str) -> Path:
        if split not in schema.SPLITS:
            raise DataConfigError(f"unknown split {split!r}; valid splits: {', '.join(schema.SPLITS)}")
        return self.data_root / split

    def build_split(self, split: str) -> Dataset:
        """Dataset of one split (clip dataset, wrapped by the feature cache when enabled)."""
        split_dir = self.split_dir(split)
        if not self.data_root.is_dir():
            raise DataConfigError(f"data.data_root={str(self.data_root)!r} does not exist")
        try:
            clips = ClipDataset(
                split_dir,
                clip_length=self.clip_length,
                stride=self.stride,
                frame_step=self.frame_step,
                targets=self.targets,
                image_size=self.image_size,
            )
        except ShardError as e:
            raise DataConfigError(f"split {split!r} (data.data_root={str(self.data_root)!r}): {e}") from None
        if not self.feature_cache:
            return clips
        if self.cache_dir is None or self.backbone is None:  # checked in __init__; narrows the types
            raise DataConfigError("data.feature_cache=true needs data.cache_dir and a backbone")
        if self.cache is None:
            self.cache = FeatureCache(self.cache_dir, self.backbone.cache_key(), self.cache_dtype)
        return CachedFeatureDataset(clips, self.cache, self.backbone, self.cache_in_memory)

    def check(self) -> None:
        """Open every split (no feature extraction): clear errors for missing, old or too-short data."""
        for split in schema.SPLITS:
            if split not in self._clip_sets:
                self._clip_sets[split] = self.build_split(split)

    def clip_dataset(self, split: str) -> ClipDataset:
        """The split's clips without backbone features (frames, targets, object masks)."""
        ds = self._clip_sets.get(split)
        if ds is None:
            ds = self.datasets[split] if split in self.datasets else self.build_split(split)
        return ds.clips if isinstance(ds, CachedFeatureDataset) else ds

    def last_frames(self, split: str) -> Dataset:
        """The last frame of every clip of a split (in clip order) as one-frame clips: its targets and object
        mask without reading the clip's earlier frames or extracting features."""
        clips = self.clip_dataset(split)
        frames = ClipDataset(
            self.split_dir(split), clip_length=1, targets=self.targets, image_size=self.image_size
        )
        index = {(c.shard, c.sequence_id, c.start): i for i, c in enumerate(frames.clips)}
        last = clips.span - 1
        return Subset(frames, [index[(c.shard, c.sequence_id, c.start + last)] for c in clips.clips])

    def target_batches(self, split: str, key: str) -> Iterator[tuple[torch.Tensor, torch.Tensor]]:
        """(target ``key``, object mask) batches of the clips of a split, in a fixed order: what trivial
        baselines are fitted and scored on (:mod:`probes.baselines`)."""
        loader = DataLoader(
            self.last_frames(split),
            batch_size=self.eval_batch_size,
            shuffle=False,
            num_workers=self.num_workers,
        )
        for batch in loader:
            yield batch[key], batch["object_mask"]

    def dataset(self, split: str) -> Dataset:
        """The split's dataset, built on first use; with the cache on, missing frames are extracted first."""
        if split not in self.datasets:
            ds = self._clip_sets.pop(split, None)
            if ds is None:
                ds = self.build_split(split)
            if isinstance(ds, CachedFeatureDataset):
                ds.fill()
            self.datasets[split] = ds
        return self.datasets[split]

    def setup(self, stage: str | None = None) -> None:
        wanted = {
            "fit": ("train", "val"),
            "validate": ("val",),
            "test": EVAL_SPLITS,
            "predict": EVAL_SPLITS,
            None: schema.SPLITS,
        }[stage]
        for split in wanted:
            self.dataset(split)

    # ------------------------------------------------------------------ #
    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        generator = torch.Generator().manual_seed(self.seed)
        return DataLoader(
            self.dataset(split),
            batch_size=self.batch_size if shuffle else self.eval_batch_size,
            shuffle=shuffle,
            num_workers=self.num_workers,
            generator=generator if shuffle else None,
            persistent_workers=self.num_workers > 0,
        )

    def train_dataloader(self) -> DataLoader:
        return self._loader(schema.Split.TRAIN.value, shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(schema.Split.VAL.value, shuffle=False)

    def test_dataloader(self) -> list[DataLoader]:
        """One loader per evaluation split, in the order of ``EVAL_SPLITS``."""
        return [self._loader(s, shuffle=False) for s in EVAL_SPLITS]
