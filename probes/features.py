"""Frozen-backbone features: batched extraction and an on-disk per-frame cache.

Cache layout::

    <root>/<key_hash>/key.json                      the full cache key (backbone.cache_key(), dtype, format)
    <root>/<key_hash>/<ab>/<frame_hash>.pt          {"key_hash", "frame", "features": [fp16 (C, h, w), ...]}

``key_hash`` is a hash of the backbone's ``cache_key()`` (model id, weights,
image size, layers, normalisation, dtype, extras such as a diffusion timestep
and noise seed) plus the stored dtype and the cache format version.
``frame_hash`` is a hash of the frame identity: shard file path, the shard's
content fingerprint (size in bytes + mtime in ns), sequence id, frame index
and the frame resolution fed to the backbone. A rewritten shard therefore
gets new entries.

Every read checks the stored key and frame identity against the expected
ones; an entry that does not match is recomputed and overwritten, never
returned. A directory whose ``key.json`` disagrees with its hash is wiped and
rebuilt.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import torch
from torch import Tensor

from newtphys import shards

CACHE_FORMAT_VERSION: int = 1
_DTYPES: dict[str, torch.dtype] = {
    "float16": torch.float16,
    "bfloat16": torch.bfloat16,
    "float32": torch.float32,
}


def _hash(obj: Any) -> str:
    text = json.dumps(obj, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def resolve_dtype(name: str) -> torch.dtype:
    """Cache dtype by name; unknown names list the valid ones."""
    try:
        return _DTYPES[name]
    except KeyError:
        raise ValueError(f"unknown cache dtype {name!r}; valid: {', '.join(_DTYPES)}") from None


@torch.no_grad()
def clip_features(backbone: torch.nn.Module, frames: Tensor) -> list[Tensor]:
    """Backbone features of every frame of a batch of clips.

    frames: (B, K, 3, H, W) RGB in [0, 1]. Returns one (B, K, C_l, h_l, w_l) tensor per tapped layer.
    """
    if frames.ndim != 5 or frames.shape[2] != 3:
        raise ValueError(f"frames must be (B, K, 3, H, W), got shape {tuple(frames.shape)}")
    b, k = frames.shape[:2]
    maps = backbone.features(frames.flatten(0, 1))
    return [m.reshape(b, k, *m.shape[1:]) for m in maps]


@dataclass(frozen=True)
class FrameId:
    """Identity of one input frame: where it comes from and the resolution it was read at."""

    shard: str
    """Absolute path of the shard file."""
    fingerprint: str
    """Shard content fingerprint: ``<size bytes>-<mtime ns>``."""
    sequence_id: str
    frame_index: int
    image_size: tuple[int, int]
    """(H, W) of the frame handed to the backbone, pixels."""


def shard_fingerprint(path: str | os.PathLike) -> str:
    """``<size bytes>-<mtime ns>`` of a file (changes whenever the shard is rewritten)."""
    st = os.stat(path)
    return f"{st.st_size}-{st.st_mtime_ns}"


class ShardLocator:
    """Maps the sequences of one split directory to their shard files (from ``index.json``)."""

    def __init__(self, split_dir: str | os.PathLike) -> None:
        self.split_dir = Path(split_dir).resolve()
        index = shards.read_index(self.split_dir)
        self._shard_of: dict[str, Path] = {}
        for entry in index["shards"]:
            for seq in entry.get("sequences", []):
                self._shard_of[seq["id"]] = self.split_dir / entry["file"]
        self._fingerprints: dict[Path, str] = {}

    def frame_id(self, sequence_id: str, frame_index: int, image_size: tuple[int, int]) -> FrameId:
        try:
            path = self._shard_of[sequence_id]
        except KeyError:
            raise KeyError(f"sequence {sequence_id!r} is not listed in {self.split_dir}/index.json") from None
        if path not in self._fingerprints:
            self._fingerprints[path] = shard_fingerprint(path)
        return FrameId(
            str(path),
            self._fingerprints[path],
            sequence_id,
            int(frame_index),
            (int(image_size[0]), int(image_size[1])),
        )


@dataclass
class CacheStats:
    hits: int = 0
    misses: int = 0
    rebuilt: int = 0
    """Entries found on disk whose stored key or frame did not match (recomputed)."""


class FeatureCache:
    """Per-frame on-disk cache of frozen-backbone features for one backbone configuration."""

    def __init__(self, root: str | os.PathLike, backbone_key: dict, dtype: str = "float16") -> None:
        self.dtype = resolve_dtype(dtype)
        self.key = {"backbone": backbone_key, "dtype": dtype, "format": CACHE_FORMAT_VERSION}
        self.key_hash = _hash(self.key)
        self.dir = Path(root) / self.key_hash
        self.stats = CacheStats()
        self._prepare_dir()

    def _prepare_dir(self) -> None:
        key_file = self.dir / "key.json"
        expected = json.loads(json.dumps(self.key, sort_keys=True, default=str))
        if key_file.exists():
            try:
                stored = json.loads(key_file.read_text())
            except json.JSONDecodeError:
                stored = None
            if stored == expected:
                return
            shutil.rmtree(self.dir)  # stale or corrupt: rebuild from scratch
        self.dir.mkdir(parents=True, exist_ok=True)
        tmp = key_file.with_name(f"key.json.tmp{os.getpid()}")
        tmp.write_text(json.dumps(expected, indent=1, sort_keys=True))
        os.replace(tmp, key_file)

    def path(self, frame: FrameId) -> Path:
        h = _hash(asdict(frame))
        return self.dir / h[:2] / f"{h}.pt"

    def load(self, frame: FrameId) -> list[Tensor] | None:
        """Cached maps (C, h, w) of a frame, or None when absent or not matching (counted in stats)."""
        p = self.path(frame)
        if not p.exists():
            self.stats.misses += 1
            return None
        try:
            entry = torch.load(p, map_location="cpu", weights_only=True)
        except Exception:  # truncated or foreign file: treat as stale
            entry = None
        if (
            not isinstance(entry, dict)
            or entry.get("key_hash") != self.key_hash
            or entry.get("frame") != _frame_record(frame)
        ):
            self.stats.rebuilt += 1
            return None
        self.stats.hits += 1
        return list(entry["features"])

    def store(self, frame: FrameId, maps: list[Tensor]) -> None:
        """Write the maps (C, h, w) of one frame atomically, in the cache dtype."""
        p = self.path(frame)
        p.parent.mkdir(parents=True, exist_ok=True)
        entry = {
            "key_hash": self.key_hash,
            "frame": _frame_record(frame),
            "features": [m.detach().to("cpu", self.dtype).contiguous().clone() for m in maps],
        }
        tmp = p.with_name(f"{p.name}.tmp{os.getpid()}")
        torch.save(entry, tmp)
        os.replace(tmp, p)

    def disk_bytes(self) -> int:
        """Bytes of all feature files under this key's directory."""
        return sum(f.stat().st_size for f in self.dir.rglob("*.pt"))

    def num_entries(self) -> int:
        return sum(1 for _ in self.dir.rglob("*.pt"))


def _frame_record(frame: FrameId) -> dict:
    rec = asdict(frame)
    rec["image_size"] = list(rec["image_size"])
    return rec
