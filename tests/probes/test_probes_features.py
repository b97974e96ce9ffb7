"""Feature cache: written once, reused, keyed by backbone and frame identity, stale entries rebuilt."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import torch

from newtphys import schema
from newtphys.dataset import ClipDataset
from probes.backbones import build_backbone
from probes.datamodule import CachedFeatureDataset
from probes.features import FeatureCache, clip_features
from tests.fixtures.synthetic_scene import write_fixture_split

NUM_SEQUENCES, NUM_FRAMES = 2, 5


class CountingBackbone(torch.nn.Module):
    """Delegates to a real backbone and counts the frames it embeds."""

    def __init__(self, inner: torch.nn.Module) -> None:
        super().__init__()
        self.inner = inner
        self.frames_seen = 0

    def features(self, frames: torch.Tensor) -> list[torch.Tensor]:
        self.frames_seen += int(frames.shape[0])
        return self.inner.features(frames)

    def cache_key(self) -> dict:
        return self.inner.cache_key()


def _tiny_backbone(layers=(0, 1)) -> CountingBackbone:
    return CountingBackbone(
        build_backbone(
            "vit_tiny", pretrained=False, image_size=32, layers=list(layers), arch_overrides={"depth": 2}
        )
    )


@pytest.fixture()
def split_dir(tmp_path: Path) -> Path:
    return write_fixture_split(
        tmp_path / "data",
        schema.Split.TRAIN.value,
        num_sequences=NUM_SEQUENCES,
        sequences_per_shard=1,
        num_frames=NUM_FRAMES,
        seed=3,
    )


def _cached(split_dir: Path, cache_root: Path, backbone: CountingBackbone, clip_length: int = 3):
    clips = ClipDataset(split_dir, clip_length=clip_length, targets=(schema.COLLISION,))
    cache = FeatureCache(cache_root, backbone.cache_key())
    return CachedFeatureDataset(clips, cache, backbone)


def test_fill_computes_each_frame_once_and_reuses_across_runs(split_dir: Path, tmp_path: Path):
    bb = _tiny_backbone()
    ds = _cached(split_dir, tmp_path / "cache", bb)
    # clips of 3 frames over 5-frame sequences use every frame: 2 sequences x 5 frames
    assert ds.fill() == NUM_SEQUENCES * NUM_FRAMES
    assert bb.frames_seen == NUM_SEQUENCES * NUM_FRAMES
    assert ds.cache.num_entries() == NUM_SEQUENCES * NUM_FRAMES
    # a later run (new cache object, new dataset, same key) computes nothing
    bb2 = _tiny_backbone()
    ds2 = _cached(split_dir, tmp_path / "cache", bb2)
    assert ds2.fill() == 0
    item = ds2[len(ds2) - 1]
    assert bb2.frames_seen == 0 and ds2.cache.stats.hits == 3 and ds2.cache.stats.misses == 0
    assert "frames" not in item


def test_cached_features_equal_fresh_features_in_fp16(split_dir: Path, tmp_path: Path):
    bb = _tiny_backbone()
    ds = _cached(split_dir, tmp_path / "cache", bb)
    ds.fill()
    item = ds[1]
    frames = ds.clips[1]["frames"]
    fresh = clip_features(bb.inner, frames.unsqueeze(0))
    assert len(item["features"]) == 2
    for cached, ref in zip(item["features"], fresh):
        assert cached.dtype == torch.float16
        assert cached.shape == ref.shape[1:] == (3, 192, 2, 2)  # (K, C, h, w): 32 px / patch 16
        rel = (cached.float() - ref[0]).abs().max() / ref.abs().max()
        assert rel < 2e-3  # fp16 rounding only
    # fp16 on disk: 2 layers x 192 x 2 x 2 x 2 bytes = 3072 bytes of payload per frame
    per_frame = ds.cache.disk_bytes() / ds.cache.num_entries()
    assert 3072 <= per_frame < 3072 + 4096


def test_other_backbone_key_uses_other_entries(split_dir: Path, tmp_path: Path):
    a = _cached(split_dir, tmp_path / "cache", _tiny_backbone(layers=(0, 1)))
    a.fill()
    b_bb = _tiny_backbone(layers=(1,))
    b = _cached(split_dir, tmp_path / "cache", b_bb)
    assert b.cache.key_hash != a.cache.key_hash
    assert b.fill() == NUM_SEQUENCES * NUM_FRAMES and b_bb.frames_seen == NUM_SEQUENCES * NUM_FRAMES


def test_entry_with_mismatching_stored_key_is_rebuilt_not_reused(split_dir: Path, tmp_path: Path):
    bb = _tiny_backbone()
    ds = _cached(split_dir, tmp_path / "cache", bb)
    ds.fill()
    fid = ds.frame_ids(0, (32, 32))[0]
    path = ds.cache.path(fid)
    entry = torch.load(path, weights_only=True)
    good = [t.clone() for t in entry["features"]]
    entry["key_hash"] = "someone-elses-key"
    entry["features"] = [torch.full_like(t, 7.0) for t in entry["features"]]  # poisoned values
    torch.save(entry, path)
    bb.frames_seen = 0
    assert ds.cache.load(fid) is None and ds.cache.stats.rebuilt == 1
    item = ds[0]
    assert bb.frames_seen == 1  # only the stale frame was recomputed
    for got, want in zip(item["features"], good):
        # recomputed alone, the frame goes through the backbone in a batch of one instead of the fill's batch:
        # float32 sums in another order can move a float16 entry by one unit in its last place (6e-5 here)
        assert not bool((got[0] == 7.0).any())  # none of the poisoned values is served
        torch.testing.assert_close(got[0], want, rtol=2e-3, atol=1e-4)
    assert ds.cache.load(fid) is not None  # overwritten with a valid entry


def test_key_file_mismatch_wipes_the_directory(split_dir: Path, tmp_path: Path):
    bb = _tiny_backbone()
    ds = _cached(split_dir, tmp_path / "cache", bb)
    ds.fill()
    key_file = ds.cache.dir / "key.json"
    stored = json.loads(key_file.read_text())
    stored["backbone"]["layers"] = [5]
    key_file.write_text(json.dumps(stored))
    cache = FeatureCache(tmp_path / "cache", bb.cache_key())
    assert cache.num_entries() == 0
    assert json.loads(key_file.read_text())["backbone"]["layers"] == [0, 1]


def test_rewritten_shard_gets_new_entries(split_dir: Path, tmp_path: Path):
    ds = _cached(split_dir, tmp_path / "cache", _tiny_backbone())
    ds.fill()
    shard = sorted(split_dir.glob("shard-*.h5"))[0]
    st = shard.stat()
    os.utime(shard, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))  # "rewritten" one second later
    bb = _tiny_backbone()
    ds2 = _cached(split_dir, tmp_path / "cache", bb)
    assert ds2.fill() == NUM_FRAMES  # that shard's one sequence only
    assert bb.frames_seen == NUM_FRAMES


def test_bad_cache_dtype_lists_valid():
    with pytest.raises(ValueError, match="valid: float16, bfloat16, float32"):
        FeatureCache("/tmp/unused-cache-dir-probes", {"a": 1}, dtype="int8")
