"""The package stands alone: a non-editable install (a wheel in a fresh virtual environment) runs a generation
from another directory with the configs it ships, and importing it changes no global matplotlib state."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
PACKAGES = ("newtphys", "data_gen", "probes")  # what pyproject.toml's package finder includes


def _clean_env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    return env | extra


def test_importing_the_package_sets_no_matplotlib_backend() -> None:
    code = ("import matplotlib, newtphys.viz, newtphys.stats, probes.report, data_gen.pipeline; "
            "print(matplotlib.get_backend())")  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], env=_clean_env(MPLBACKEND="svg"), cwd=REPO,
                         capture_output=True, text=True, timeout=300, check=True)  # fmt: skip
    assert out.stdout.strip().lower() == "svg"


@pytest.fixture(scope="module")
def wheel_venv(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A fresh venv with the wheel installed (--no-deps); the dependencies come from this interpreter's
    site-packages through a plain path entry, so the editable install of the checkout is NOT visible."""
    root = tmp_path_factory.mktemp("wheel_install")
    source = root / "source"  # a copy of what the build reads, so the checkout gets no build/ directory
    for name in PACKAGES:
        shutil.copytree(REPO / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
                    "-w", str(root / "dist"), str(source)], check=True, timeout=600, env=_clean_env())  # fmt: skip
    wheel = next((root / "dist").glob("newtphys-*.whl"))
    venv = root / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    site = Path(sysconfig.get_path("purelib", vars={"base": str(venv), "platbase": str(venv)}))
    (site / "zz_dependencies.pth").write_text(sysconfig.get_path("purelib") + "\n")
    subprocess.run([sys.executable, "-m", "pip", "--python", str(venv / "bin" / "python"), "install", "--quiet",
                    "--no-deps", "--no-index", str(wheel)], check=True, timeout=300, env=_clean_env())  # fmt: skip
    return venv


def test_wheel_install_generates_from_another_directory(wheel_venv: Path, tmp_path: Path) -> None:
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    python = wheel_venv / "bin" / "python"
    where = subprocess.run(
        [python, "-c", "import newtphys, data_gen, probes; from newtphys.config import CONFIG_DIR; "
         "from data_gen.sim.presets import available_presets; "
         "print(newtphys.__file__, data_gen.__file__, probes.__file__, CONFIG_DIR, *available_presets())"],
        cwd=elsewhere, env=_clean_env(), capture_output=True, text=True, timeout=300, check=True,
    ).stdout.split()  # fmt: skip
    installed = str(wheel_venv)
    assert all(p.startswith(installed) for p in where[:4]), where  # the wheel's copy, not the checkout's
    assert where[4:] == ["draft", "high", "reference", "standard"]
    proc = subprocess.run(
        [wheel_venv / "bin" / "newtphys-generate", "out_dir=data", "num_sequences=1", "num_frames=4",
         "image_size=[24,32]", "progress=false", "quality=standard", "scenario.num_objects=[1,1]",
         "scenario.objects=[toy_brick]", "render.object_gaussians=500", "render.interior_points=200",
         "render.contact_surface_samples=800"],
        cwd=elsewhere, env=_clean_env(WANDB_MODE="offline"), capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "wrote 1 shard(s) (1 sequences)" in proc.stdout
    shard = elsewhere / "data" / "train" / "shard-00000.h5"
    check = subprocess.run([wheel_venv / "bin" / "newtphys", "validate", str(shard)], cwd=elsewhere,
                           env=_clean_env(), capture_output=True, text=True, timeout=300)  # fmt: skip
    assert check.returncode == 0, check.stdout + check.stderr
    assert (elsewhere / "logs").is_dir()  # Hydra's run directory lands where the user runs it
