"""Small generated datasets shared by the data_gen tests (simulated, draft quality, tiny images)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
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


# --------------------------------------------------------------------------- #
# Label scenes: one explicit scenario, seen by two moving cameras
# --------------------------------------------------------------------------- #
LABEL_FRAMES = 16
LABEL_IMAGE_SIZE = (64, 80)
LABEL_CAMERAS = ("orbit", "handheld")
"""orbit yaws the view 3.4 deg and moves the eye 36 mm per frame (a vector rotated with the wrong frame's
camera shows in its horizontal part); handheld (shaky, 5 % jitter at 1.5-3 Hz) also tilts it by up to
0.8 deg per frame, which is what the camera-frame gravity map needs: yaw about the vertical leaves a
vertical vector unchanged."""


def _placement(object_id: int, asset: str, size_m: float, material: str, young_modulus_pa: float,
               poisson_ratio: float, density_kg_m3: float, position_m: tuple[float, float, float],
               velocity_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0), motion: str = "drop"):
    from data_gen.scenario import ObjectPlacement

    return ObjectPlacement(
        object_id=object_id, asset=asset, size_m=size_m, material=material, young_modulus_pa=young_modulus_pa,
        poisson_ratio=poisson_ratio, density_kg_m3=density_kg_m3, position_m=position_m,
        orientation_wxyz=(1.0, 0.0, 0.0, 0.0), velocity_m_s=velocity_m_s,
        angular_velocity_rad_s=(0.0, 0.0, 0.0), motion=motion, color_seed=100 + object_id,
    )


def label_scenario(camera_kind: str):
    """Four objects on the empty floor, no spin, every one in view for all frames:

    1. a wooden block (0.16 x 0.08 x 0.048 m, rigid) dropped 4 cm: free fall, lands at frame 3, rests;
    2. a small book (0.12 x 0.08 x 0.017 m, rigid) dropped 6 cm onto the block: object-object contact from
       frame 3; thin, so the contact band is visible on its sides (5-11 collision pixels per frame);
    3. a book (0.2 m, rigid) pushed along the floor at 1 m/s: slides 11 cm and stops (horizontal scene flow);
    4. a foam yoga block (8 cm, soft: 3 handles) dropped 3 cm onto the floor: rests.
    Objects 1 and 4 differ in material and class from each other and from the books.
    """
    from data_gen.cameras import HANDHELD_TERMS, CameraPathSpec
    from data_gen.scenario import Scenario

    objects = (
        _placement(1, "wooden_block", 0.16, "wood", 1.0e10, 0.35, 600.0, (0.0, 0.0, 0.024 + 0.04)),
        _placement(2, "book", 0.12, "paper", 2.0e9, 0.3, 800.0, (0.0, 0.0, 0.048 + 0.0087 + 0.06)),
        _placement(3, "book", 0.2, "paper", 2.0e9, 0.3, 800.0, (-0.12, -0.2, 0.0145 + 0.002),
                   velocity_m_s=(1.0, 0.0, 0.0), motion="push"),
        _placement(4, "yoga_block", 0.08, "foam", 3.0e5, 0.3, 150.0, (0.17, -0.17, 0.0174 + 0.03)),
    )
    look = dict(look_target_m=(0.0, -0.08, 0.04), radius_m=0.6, height_m=0.4, azimuth_rad=-1.2,
                fov_x_deg=55.0)
    if camera_kind == "orbit":
        camera = CameraPathSpec(kind="orbit", orbit_rate_rad_s=1.5, **look)
    elif camera_kind == "handheld":
        rng = np.random.default_rng(0)
        camera = CameraPathSpec(
            kind="handheld", jitter_m=0.05 * float(np.hypot(0.6, 0.4)),
            jitter_freqs_hz=tuple(float(f) for f in rng.uniform(1.5, 3.0, 3 * HANDHELD_TERMS)),
            jitter_phases_rad=tuple(float(p) for p in rng.uniform(0.0, 2.0 * np.pi, 3 * HANDHELD_TERMS)),
            **look,
        )
    else:
        raise ValueError(f"camera_kind must be one of {LABEL_CAMERAS}, got {camera_kind!r}")
    return Scenario(
        sequence_id=f"labels-{camera_kind}", seed=5, split="train", scene="empty_floor", objects=objects,
        gravity_m_s2=(0.0, 0.0, -9.81), camera=camera, num_frames=LABEL_FRAMES, fps=25.0,
        image_size=LABEL_IMAGE_SIZE,
    )


@pytest.fixture(scope="session")
def label_sequences(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """{camera kind: SequenceArrays} of :func:`label_scenario`, generated at draft quality by the pipeline,
    written to a shard and read back (what a user of the data sees). About 10 s on 2 CPU cores."""
    from data_gen.configs import render_settings
    from data_gen.pipeline import generate_sequence
    from data_gen.sim.presets import load_preset
    from newtphys.shards import ShardReader, ShardWriter

    out = tmp_path_factory.mktemp("labels")
    settings = render_settings(object_gaussians=1500, interior_points=600, scene_spacing_m=0.04)
    with ShardWriter(out, split="train", shard_index=0) as writer:
        for kind in LABEL_CAMERAS:
            seq, _ = generate_sequence(label_scenario(kind), load_preset("draft"), settings)
            ws = seq.world_state
            writer.add_sequence(ws.sequence_id, seq.maps, seq.K, seq.world_to_camera, ws)
    with ShardReader(out / "train" / "shard-00000.h5") as reader:
        return {kind: reader.read_sequence(f"labels-{kind}") for kind in LABEL_CAMERAS}


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
