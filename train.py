"""Train a probe on a frozen backbone: ``python train.py backbone=dinov2 task=gravity``.

The same command as the installed ``newtphys-train`` (``probes.train_cli``): it returns the monitored
validation metric to Hydra (sweepers optimise it).
"""

from probes.train_cli import main

if __name__ == "__main__":
    main()
