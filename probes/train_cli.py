"""``newtphys-train`` / ``python train.py``: train a probe on a frozen backbone from the shipped Hydra config.

    newtphys-train backbone=dinov2 task=gravity
    newtphys-train -m backbone=dino,dinov2,clip task=collision,gravity,scene_flow

Returns the monitored validation metric (e.g. ``val/f1`` or ``val/angular_error_deg``), so a Hydra
sweeper such as Optuna has a value to optimise; ``metrics.json`` in the run directory holds the rest.
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from newtphys.config import CONFIG_DIR


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="train")
def main(cfg: DictConfig) -> float:
    from probes.run import monitored_value, run

    return monitored_value(run(cfg))


if __name__ == "__main__":
    main()
