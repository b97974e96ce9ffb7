"""``newtphys-generate`` / ``python generate.py``: generate a dataset split from the shipped Hydra config.

    newtphys-generate split=train num_sequences=100
    newtphys-generate 'scenario.objects=["file:/data/duck.obj?scale=0.15&material=rubber&up=y"]'

See ``newtphys/conf/generate.yaml`` for every option; ``--help`` lists the config groups.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig, OmegaConf

from data_gen.generator import GenerationConfig, GenerationReport, run_generation
from newtphys.config import CONFIG_DIR


def run(cfg: DictConfig) -> GenerationReport:
    """Resolve the config and generate (tests call this with a composed config)."""
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain.pop("hydra", None)
    gen_cfg = GenerationConfig.from_mapping(plain, config_yaml=OmegaConf.to_yaml(plain))
    return run_generation(gen_cfg)


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="generate")
def main(cfg: DictConfig) -> None:
    report = run(cfg)
    print(report.summary())


if __name__ == "__main__":
    main()
