"""Small generated datasets shared by the data_gen tests (simulated, draft quality, tiny images)."""

from __future__ import annotations

from pathlib import Path

import pytest
from newtphys.config import compose_config

SMALL = [
    "num_frames=12",
    "image_size=[48,64]",
    "progress=false",
    "render.object_gaussians=1500",
    "render.interior_points=600",
    "render.scene_spacing_m=0.04",
    "scenario.num_objects=[1,2]",
    "scenario.camera_distance_m=[0.7,0.9]",
]


def compose_generate(overrides: list[str]):
    return compose_config("generate", SMALL + overrides)


def generate(out_dir: Path, overrides: list[str]):
    from generate import run

    return run(compose_generate([f"out_dir={out_dir}"] + overrides))


@pytest.fixture(scope="session")
def generated_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """train: 2 sequences (earth gravity); test_ood_gravity: 1 sequence (gravity=ood)."""
    root = tmp_path_factory.mktemp("generated")
    generate(root, ["split=train", "num_sequences=2", "sequences_per_shard=1", "seed=3"])
    generate(root, ["split=test_ood_gravity", "gravity=ood", "num_sequences=1", "sequences_per_shard=1", "seed=3"])
    return root
