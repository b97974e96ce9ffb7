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


@pytest.fixture(scope="session")
def push_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Question-generation data: 3 push sequences (2-4 objects sliding into each other), 25 frames at 64 x 80
    (shared by the VQA test modules)."""
    root = tmp_path_factory.mktemp("vqa_data")
    generate(root, ["split=test", "scenario=push", "num_sequences=3", "sequences_per_shard=3", "num_frames=25",
                    "image_size=[64,80]", "scenario.num_objects=[2,4]", "seed=1"])  # fmt: skip
    return root


def compose_vqa(data: Path, out: Path, *overrides: str):
    """``conf/generate_vqa.yaml`` for the test split of ``data``, writing under ``out``."""
    return compose_config("generate_vqa", [f"data_dir={data}", "split=test", f"out_dir={out}", "progress=false",
                                           *overrides])  # fmt: skip
