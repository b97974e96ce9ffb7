"""Shard read speed: a 4-frame clip with every map, HDF5 shard vs uncompressed .npy.

Writes a shard of analytic test-fixture sequences at 128x128, then times
reading random 4-frame clips of every map (what ClipDataset does per item,
plus the amodal maps) from the shard and the same arrays from one
uncompressed .npy file per map (memory-mapped), in the same run. Prints a
table and the ratio, writes bench/results/shards.json.

    python bench/bench_shards.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the test fixture lives in tests/, not in the package

from newtphys import schema  # noqa: E402
from newtphys.dataset import ClipDataset  # noqa: E402
from newtphys.shards import COMPRESSION_LEVEL, ShardReader  # noqa: E402
from tests.fixtures.synthetic_scene import write_fixture_split  # noqa: E402

CLIP = 4


def _time(fn, reps: int) -> float:
    fn()  # warm-up (file open, page cache)
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t0) / reps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args()
    reps = 30 if args.quick else 200
    frames = 16 if args.quick else 32
    rng = np.random.default_rng(0)
    rows: list[tuple[str, float, int]] = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for codec, level in (("gzip", 1), ("gzip", 4), ("lzf", None), (None, None)):
            label = f"{codec or 'none'}{'-' + str(level) if level else ''}"
            kwargs = {"compression": codec} | ({"compression_level": level} if level else {})
            split = write_fixture_split(tmp / label, "train", num_sequences=2, sequences_per_shard=2,
                                        num_frames=frames, image_size=(128, 128), **kwargs)
            shard = split / "shard-00000.h5"
            reader = ShardReader(shard)
            sid = reader.sequences()[0]
            it = iter(rng.integers(0, frames - CLIP, size=10_000))

            def read_h5() -> None:
                s = int(next(it))
                for n in schema.MAP_NAMES:
                    reader.read(sid, n, s, s + CLIP)

            rows.append((f"hdf5 {label}, all 13 maps", _time(read_h5, reps), shard.stat().st_size))
            if codec == "gzip" and level == COMPRESSION_LEVEL:
                ds = ClipDataset(split, clip_length=CLIP)
                idx = iter(rng.integers(0, len(ds), size=10_000))
                item_time = _time(lambda: ds[int(next(idx))], reps)
                seq = reader.read_sequence(sid)
                npy_dir = tmp / "npy"
                npy_dir.mkdir()
                for name, arr in seq.maps.items():
                    np.save(npy_dir / f"{name}.npy", arr)
                npy = {n: np.load(npy_dir / f"{n}.npy", mmap_mode="r") for n in schema.MAP_NAMES}
                it2 = iter(rng.integers(0, frames - CLIP, size=10_000))

                def read_npy() -> None:
                    s = int(next(it2))
                    for n in schema.MAP_NAMES:
                        np.array(npy[n][s : s + CLIP])

                npy_time = _time(read_npy, reps)
                raw_size = sum(a.nbytes for a in seq.maps.values()) * 2
                bytes_clip = sum(a[:CLIP].nbytes for a in seq.maps.values())
        rows.append(("uncompressed .npy (mmap), all 13 maps", npy_time, raw_size))
        rows.append((f"ClipDataset item, gzip-{COMPRESSION_LEVEL} (rgb x4 + 3 targets)", item_time, 0))
    base = rows[0][1]
    print(f"clip of {CLIP} frames at 128x128 ({bytes_clip / 2**20:.2f} MiB decoded, all maps); {reps} reads each; "
          f"shard = 2 sequences x {frames} frames")
    print(f"{'reader':<48} {'ms / clip':>10} {'shard MiB':>10} {'x npy time':>11}")
    for name, t, size in rows:
        print(f"{name:<48} {t * 1e3:>10.2f} {size / 2**20 if size else float('nan'):>10.2f} {t / npy_time:>11.1f}")
    print(f"default (gzip-{COMPRESSION_LEVEL}) vs npy: {base / npy_time:.1f}x slower, {raw_size / rows[0][2]:.1f}x smaller on disk")
    out = ROOT / "bench" / "results" / "shards.json"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "clip_frames": CLIP, "image_size": [128, 128], "reps": reps, "machine": platform.platform(),
        "ms_per_clip": {name: t * 1e3 for name, t, _ in rows}, "bytes": {name: b for name, _, b in rows},
        "ratio_default_over_npy": base / npy_time,
    }, indent=1))
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
