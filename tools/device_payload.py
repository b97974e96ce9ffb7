"""Build ``.devsite/``: what a lent GPU machine (the `device` tool) needs to run ``bench/bench_cuda.py``.

That machine reaches no package registry. Its image has torch, numpy, scipy, h5py, matplotlib and the rest of
the ML stack, but not warp nor a few pure-Python packages this project imports. A call carries at most 64 MiB,
and the warp-lang wheel alone is ~150 MB. So this script:

1. downloads the warp-lang wheel of the version installed here (``pip download``, manylinux x86_64), and packs
   its ``warp/`` package (without examples and tests) and dist-info into one ``xz -9`` archive (~100 MB, a few
   minutes on 2 cores), split into parts of at most ``--part-mib`` MiB: ``.devsite/p1``, ``.devsite/p2``, ...;
2. copies the pure-Python packages missing there from this environment into ``.devsite/site``.

``.devsite/`` is added to ``.git/info/exclude``. It prints the device calls to make: each call carries one part,
in a row (the machine stays warm about 30 s between calls, and what a call writes under /tmp stays), the last one
unpacks everything and runs the bench. ``docs/gpu_checks.md`` walks through it.

    python tools/device_payload.py
"""

from __future__ import annotations

import argparse
import importlib.metadata
import importlib.util
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / ".devsite"
MISSING_THERE = ("hydra", "omegaconf", "antlr4", "trimesh", "rtree")
"""Packages this project imports that the device image lacked on 2026-12-04 (its list: the device tool's
KINDS.md); copied from this environment (pure Python, or with their own bundled libraries: rtree.libs)."""
PLATFORMS = ("manylinux_2_28_x86_64", "manylinux_2_34_x86_64", "manylinux_2_17_x86_64", "manylinux2014_x86_64")


def _exclude_devsite() -> None:
    exclude = ROOT / ".git" / "info" / "exclude"
    exclude.parent.mkdir(parents=True, exist_ok=True)
    lines = exclude.read_text().splitlines() if exclude.exists() else []
    if "/.devsite/" not in lines:
        exclude.write_text("\n".join([*lines, "/.devsite/"]) + "\n")


def _warp_archive(work: Path, version: str) -> Path:
    subprocess.run([sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--python-version",
                    "3.12", "--implementation", "cp", *[a for p in PLATFORMS for a in ("--platform", p)], "-d",
                    str(work), f"warp-lang=={version}"], check=True)  # fmt: skip
    wheel = next(work.glob("warp_lang-*.whl"))
    unpacked = work / "unpacked"
    with zipfile.ZipFile(wheel) as z:
        names = [n for n in z.namelist() if not n.startswith(("warp/examples/", "warp/tests/"))]
        z.extractall(unpacked, members=names)
    archive = work / "warp.tar.xz"
    tops = sorted(p.name for p in unpacked.iterdir())
    subprocess.run(f"tar -C {unpacked} -cf - {' '.join(tops)} | xz -9 -T0 > {archive}", shell=True, check=True)
    return archive


def _split(archive: Path, part_bytes: int) -> list[Path]:
    parts = []
    with archive.open("rb") as f:
        k = 1
        while chunk := f.read(part_bytes):
            folder = OUT / f"p{k}"
            folder.mkdir(parents=True)
            path = folder / f"warp.tar.xz.part{k:02d}"
            path.write_bytes(chunk)
            parts.append(path)
            k += 1
    return parts


def _copy_site() -> None:
    site = OUT / "site"
    site.mkdir(parents=True)
    for name in MISSING_THERE:
        spec = importlib.util.find_spec(name)
        if spec is None or spec.origin is None:
            raise SystemExit(f"device_payload: package {name!r} is not installed here (needed there)")
        package = Path(spec.origin).parent
        shutil.copytree(package, site / name, ignore=shutil.ignore_patterns("__pycache__"))
        libs = package.parent / f"{name}.libs"
        if libs.is_dir():
            shutil.copytree(libs, site / libs.name)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--part-mib", type=int, default=50, help="largest part, MiB (the repository travels too)")
    args = ap.parse_args()
    version = importlib.metadata.version("warp-lang")
    if OUT.exists():
        shutil.rmtree(OUT)
    OUT.mkdir()
    _exclude_devsite()
    with tempfile.TemporaryDirectory() as tmp:
        archive = _warp_archive(Path(tmp), version)
        parts = _split(archive, args.part_mib << 20)
    _copy_site()
    print(f"warp-lang {version}: {len(parts)} parts in {OUT}; site packages: {', '.join(MISSING_THERE)}")
    unpack = ("[ -d /tmp/site/warp ] || { mkdir -p /tmp/site && cat /tmp/dl/warp.tar.xz.part* | xz -d -T0 | "
              "tar -x -C /tmp/site && cp -r .devsite/site/* /tmp/site/ || exit 3; }; "
              "export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1; ")  # fmt: skip
    for k, part in enumerate(parts, 1):
        carry = [f".devsite/p{k}"] + ([".devsite/site"] if k == len(parts) else [])
        command = f"mkdir -p /tmp/dl && cp .devsite/p{k}/* /tmp/dl/"
        if k == len(parts):
            command += ("; " + unpack + "python3 bench/bench_cuda.py --profile-render --out $OUT/cuda.json 2>&1 | "
                        "grep -v '^Module ' | tee $OUT/log.txt")  # fmt: skip
        print(f"\ncall {k}: carry={carry}\n  {command}")


if __name__ == "__main__":
    main()
