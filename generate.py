"""Generate a NewtPhys dataset split: ``python generate.py split=train num_sequences=100``.

See conf/generate.yaml for every option; ``python generate.py --help`` lists the config groups.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig, OmegaConf

from data_gen.generator import GenerationConfig, run_generation


def run(cfg: DictConfig):
    """Resolve the config and generate (tests call this with a composed config)."""
    plain = OmegaConf.to_container(cfg, resolve=True)
    plain.pop("hydra", None)
    gen_cfg = GenerationConfig.from_mapping(plain, config_yaml=OmegaConf.to_yaml(plain))
    return run_generation(gen_cfg)


@hydra.main(version_base="1.3", config_path="conf", config_name="generate")
def main(cfg: DictConfig) -> None:
    report = run(cfg)
    print(report.summary())


if __name__ == "__main__":
    main()
