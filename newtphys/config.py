"""The shipped Hydra config tree (``newtphys/conf``) and composing it outside a Hydra app.

The configs travel inside the package, so a non-editable install (``pip install .``)
runs ``newtphys-generate`` / ``newtphys-train`` from any directory, and library code
(quality presets, benches, tests) reads the same files the command line composes:
every setting has one source, the YAML.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig

CONFIG_DIR: Path = Path(__file__).resolve().parent / "conf"
"""Root of the config tree: ``generate.yaml``, ``train.yaml`` and their groups."""


def compose_config(config_name: str, overrides: Sequence[str] = ()) -> DictConfig:
    """Compose ``<CONFIG_DIR>/<config_name>.yaml`` with command-line style ``overrides`` (as the CLI would)."""
    from hydra import compose, initialize_config_dir

    if not (CONFIG_DIR / f"{config_name}.yaml").is_file():
        names = sorted(p.stem for p in CONFIG_DIR.glob("*.yaml"))
        raise FileNotFoundError(f"no config {config_name!r} in {CONFIG_DIR}; available: {names}")
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        return compose(config_name=config_name, overrides=list(overrides))
