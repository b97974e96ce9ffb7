"""``newtphys-generate-vqa`` / ``python generate_vqa.py``: write a question set from generated shards."""

from __future__ import annotations

import hydra
from omegaconf import DictConfig, OmegaConf

from data_gen.vqa.generator import VqaConfig, VqaReport, run_vqa_generation
from newtphys.config import CONFIG_DIR, compose_config


def typed(cfg: DictConfig) -> VqaConfig:
    """The typed config of a composed ``generate_vqa`` config (without the Hydra plumbing)."""
    plain = OmegaConf.to_container(cfg, resolve=True)
    for key in ("hydra", "paths", "run_name"):
        plain.pop(key, None)
    return VqaConfig.from_mapping(plain, config_yaml=OmegaConf.to_yaml(plain))


def vqa_config(*overrides: str) -> VqaConfig:
    """``newtphys/conf/generate_vqa.yaml`` composed with command-line style ``overrides``."""
    return typed(compose_config("generate_vqa", overrides))


def run(cfg: DictConfig) -> VqaReport:
    """Resolve the config and generate (tests call this with a composed config)."""
    return run_vqa_generation(typed(cfg))


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="generate_vqa")
def main(cfg: DictConfig) -> None:
    report = run(cfg)
    print(report.summary())
    print(f"wrote {cfg.out_dir}/{cfg.split}/questions.jsonl, answers.jsonl, manifest.json")


if __name__ == "__main__":
    main()
