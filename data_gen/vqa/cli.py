"""``newtphys-generate-vqa`` / ``python generate_vqa.py``: write a question set from generated shards."""

from __future__ import annotations

import hydra
from omegaconf import DictConfig, OmegaConf

from data_gen.vqa.generator import VqaConfig, VqaReport, run_vqa_generation
from newtphys.config import CONFIG_DIR


def run(cfg: DictConfig) -> VqaReport:
    """Resolve the config and generate (tests call this with a composed config)."""
    plain = OmegaConf.to_container(cfg, resolve=True)
    for key in ("hydra", "paths", "run_name"):
        plain.pop(key, None)
    return run_vqa_generation(VqaConfig.from_mapping(plain, config_yaml=OmegaConf.to_yaml(plain)))


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="generate_vqa")
def main(cfg: DictConfig) -> None:
    report = run(cfg)
    print(report.summary())
    print(f"wrote {cfg.out_dir}/{cfg.split}/questions.jsonl, answers.jsonl, manifest.json")


if __name__ == "__main__":
    main()
