"""Typed settings from the shipped configs: every default has one source, the YAML under ``newtphys/conf``.

Tests, benches and library users load the same settings ``generate.py`` runs, and change what they need:

    >>> cfg = generation_config("scenario=push", "quality=standard")     # command-line style overrides
    >>> scenario = scenario_config("drop", scenes=("table",), num_objects=(2, 2))
    >>> settings = render_settings(object_gaussians=800)
"""

from __future__ import annotations

import dataclasses
from typing import Any

from omegaconf import OmegaConf

from data_gen.generator import GenerationConfig
from data_gen.pipeline import RenderSettings
from data_gen.scenario import ScenarioConfig
from newtphys.config import compose_config


def generation_config(*overrides: str) -> GenerationConfig:
    """``newtphys/conf/generate.yaml`` composed with ``overrides`` (as ``generate.py`` would run it)."""
    cfg = compose_config("generate", overrides)
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain.pop("hydra", None)
    return GenerationConfig.from_mapping(plain, config_yaml=OmegaConf.to_yaml(plain))


def scenario_config(name: str = "drop", **changes: Any) -> ScenarioConfig:
    """The shipped scenario ``name`` (``newtphys/conf/scenario/<name>.yaml``) with some fields changed."""
    return generation_config(f"scenario={name}").scenario.replace(**changes)


def render_settings(**changes: Any) -> RenderSettings:
    """The shipped ``render:`` settings of ``generate.yaml`` with some fields changed."""
    return dataclasses.replace(generation_config().render, **changes)
