"""Train a probe on a frozen backbone: ``python train.py backbone=dinov2 task=gravity``."""

import hydra
from omegaconf import DictConfig


@hydra.main(version_base="1.3", config_path="conf", config_name="train")
def main(cfg: DictConfig) -> None:
    from probes.run import run

    run(cfg)


if __name__ == "__main__":
    main()
