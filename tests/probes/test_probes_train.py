"""End to end: the real Hydra config, shrunk to CPU size, trains probes on the synthetic fixture.

* run(cfg) writes a checkpoint without backbone weights, W&B offline files and
  metrics.json with both test splits;
* a decoder beats the best constant predictor on the split it was trained on;
* a 2 x 2 multirun through train.py gives one result (and one W&B run) per job;
* bad input (no shards, old schema, clip too long, unknown task or backbone) fails clearly.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import h5py
import lightning as L
import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import MissingConfigException
from omegaconf import DictConfig, open_dict
from torch.utils.data import DataLoader

from newtphys import schema
from newtphys.config import CONFIG_DIR
from probes.baselines import evaluate_baselines
from probes.datamodule import DataConfigError
from probes.run import METRICS_FILENAME, build, run

REPO = Path(__file__).resolve().parents[2]
CONF = CONFIG_DIR
# vit_tiny with random weights, 4 blocks, 64 px input (4 x 4 feature grid): cheap on CPU
TINY_BACKBONE = [  # backbone=vit_tiny is the default of conf/train.yaml
    "backbone.pretrained=false",
    "backbone.image_size=64",
    "backbone.layers=[1,3]",
    "+backbone.arch_overrides={depth:4}",
]


def _compose(tmp: Path, data_root: Path, overrides: list[str]) -> DictConfig:
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(
            "train",
            overrides=[
                *TINY_BACKBONE,
                f"data.data_root={data_root}",
                f"paths.cache_dir={tmp / 'cache'}",
                f"paths.log_dir={tmp / 'logs'}",
                "trainer=cpu",
                "trainer.max_epochs=2",
                "trainer.enable_progress_bar=false",
                "trainer.enable_model_summary=false",
                "trainer.log_every_n_steps=1",
                "data.num_workers=0",
                "data.batch_size=4",
                *overrides,
            ],
        )
    with open_dict(cfg):
        cfg.paths.output_dir = str(tmp / "run")
    return cfg


# --------------------------------------------------------------------------- #
def test_run_writes_checkpoint_wandb_files_and_metrics(
    synthetic_dataset: Path, tmp_path: Path, one_thread, monkeypatch
):
    monkeypatch.setenv("WANDB_MODE", "offline")
    cfg = _compose(
        tmp_path,
        synthetic_dataset,
        ["task=gravity", "decoder=dpt", "decoder.width=16", "logger=wandb", "logger.wandb.offline=true"],
    )
    metrics = run(cfg)
    out = Path(cfg.paths.output_dir)
    assert json.loads((out / METRICS_FILENAME).read_text()) == metrics
    assert metrics["backbone"] == "vit_tiny" and metrics["backbone_pretrained"] is False
    assert metrics["task"] == "gravity" and metrics["decoder"] == "DPTHead"
    for split in ("val", "test", "test_ood_gravity"):
        ang = metrics[split]["gravity_angular_error_deg"]
        mag = metrics[split]["gravity_magnitude_error_n"]
        assert 0.0 <= ang <= 180.0 and mag >= 0.0
        # the trivial baselines of every split, scored with the same metrics, and the probe's skill over them
        base = metrics["baselines"][split]["constant"]
        best = metrics["best_baseline"][split]["gravity_magnitude_error_n"]
        assert best == {"baseline": "constant", "value": base["gravity_magnitude_error_n"]}
        assert metrics["skill"][split]["gravity_magnitude_error_n"] == pytest.approx(
            1.0 - mag / base["gravity_magnitude_error_n"]
        )
    assert set(metrics["baselines"]) == {"val", "test", "test_ood_gravity"}
    # calibrated on val (trust 0 = the train constant is on the grid): at least the constant there
    assert metrics["skill"]["val"]["gravity_angular_error_deg"] >= -1e-6
    assert metrics["skill"]["val"]["gravity_magnitude_error_n"] >= -1e-6
    assert set(metrics["decision"]) == {"trust_direction", "trust_magnitude"}
    assert metrics["monitor"] == "val/skill" and len(metrics["baseline_fit"]["direction"]) == 3
    # checkpoint: decoder weights + backbone name/config, no frozen backbone weights
    ckpt = torch.load(metrics["best_checkpoint"], map_location="cpu", weights_only=False)
    keys = list(ckpt["state_dict"])
    assert keys and all(k.startswith("decoder.") for k in keys)
    assert ckpt["hyper_parameters"]["backbone_config"]["name"] == "vit_tiny"
    assert ckpt["hyper_parameters"]["backbone_config"]["pretrained"] is False
    # W&B offline run files (the logged config's pretrained flag is checked through the CSV logger below:
    # W&B writes its config record asynchronously, so the bytes of the run file are not a stable check)
    runs = list((out / "wandb").glob("offline-run-*"))
    assert len(runs) == 1 and len(list(runs[0].glob("*.wandb"))) == 1
    # the feature cache was filled once: 4 splits x 4 sequences x 6 frames
    entries = list((tmp_path / "cache").rglob("*.pt"))
    assert len(entries) == 4 * 4 * 6


def test_csv_logger_and_checkpoint_reload(synthetic_dataset: Path, tmp_path: Path, one_thread):
    cfg = _compose(
        tmp_path,
        synthetic_dataset,
        ["task=collision", "logger=csv", "data.feature_cache=false", "trainer.max_epochs=1"],
    )
    metrics = run(cfg)
    out = Path(cfg.paths.output_dir)
    assert (out / "csv" / "metrics.csv").is_file()
    hparams = (out / "csv" / "hparams.yaml").read_text()
    assert "backbone_pretrained: false" in hparams
    assert 0.0 <= metrics["test"]["collision_f1"] <= 1.0
    assert 0.0 <= metrics["test_ood_gravity"]["collision_f1"] <= 1.0
    assert set(metrics["baselines"]["test"]) == {"all_negative", "all_positive", "train_rate"}
    # the threshold calibrated on val travels in the checkpoint; validation F1 is the calibrated one,
    # so it is at least the all-positive F1 (threshold 0 is on the grid)
    assert 0.0 <= metrics["decision"]["threshold"] < 1.0
    assert metrics["val"]["collision_f1"] >= metrics["baselines"]["val"]["all_positive"]["collision_f1"] - 1e-12
    assert "baseline/val/all_positive/collision_f1" in (out / "csv" / "metrics.csv").read_text()
    # the decoder reloads into a freshly built module (backbone rebuilt from config, not from the checkpoint)
    parts = build(cfg)
    ckpt = torch.load(metrics["best_checkpoint"], map_location="cpu", weights_only=False)
    missing, unexpected = parts.model.load_state_dict(ckpt["state_dict"], strict=False)
    assert not unexpected and all(k.startswith("backbone.") for k in missing)
    parts.model.on_load_checkpoint(ckpt)
    assert parts.task.threshold == ckpt["task_decision"]["threshold"] == metrics["decision"]["threshold"]


# --------------------------------------------------------------------------- #
def _evaluate(task, predictions_and_targets) -> dict[str, float]:
    metrics = task.metrics()
    for pred, target, mask in predictions_and_targets:
        for m in metrics.values():
            m.update(pred, target, mask)
    return {k: m.compute().item() for k, m in metrics.items()}


@pytest.mark.parametrize("task_name", ["collision", "gravity", "scene_flow"])
def test_learning_is_real_beats_best_constant_predictor(
    synthetic_dataset: Path, tmp_path: Path, one_thread, task_name: str
):
    # the fixture's boxes weigh 3-25 kg (gravity 30-250 N): scale the gravity head to ~100 N
    task_overrides = {"gravity": ["task.params.target_scale_n=100", "optimizer.lr=1e-2"]}.get(task_name, [])
    cfg = _compose(
        tmp_path,
        synthetic_dataset,
        [
            f"task={task_name}",
            "logger=csv",
            "optimizer.lr=5e-3",
            "data.batch_size=8",
            "data.cache_in_memory=true",
            *task_overrides,
        ],
    )
    parts = build(cfg)
    trainer = L.Trainer(
        max_steps=150,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        limit_val_batches=0,
        num_sanity_val_steps=0,
    )
    trainer.fit(parts.model, datamodule=parts.datamodule)

    task, model = parts.task, parts.model.eval()
    loader = DataLoader(parts.datamodule.dataset("train"), batch_size=64)
    batch = next(iter(loader))  # the whole (12-clip) train split
    target, mask = batch[task.target_key], batch["object_mask"]
    with torch.no_grad():
        pred = task.predict(model(batch))
    probe = _evaluate(task, [(pred, target, mask)])
    print(f"learning[{task_name}]: probe {probe}")
    # the trivial baselines fitted on train, scored on the same (train) clips with the same metrics
    baselines = evaluate_baselines(task.name, task.metrics, [(target, mask)], {"train": [(target, mask)]}).scores[
        "train"
    ]
    print(f"learning[{task_name}]: trivial baselines {baselines}")

    if task_name == "collision":
        best_constant = max(b["collision_f1"] for b in baselines.values())  # all-positive: 2p / (1 + p)
        p = (target.bool() & mask).sum().item() / mask.sum().item()
        assert best_constant == pytest.approx(2 * p / (1 + p), rel=1e-6)
        assert probe["collision_f1"] > best_constant + 0.15, (probe, baselines)
    elif task_name == "gravity":
        base = baselines["constant"]
        # the fixture's camera barely rotates, so the constant's direction is already almost exact
        # (~0.03 deg); the magnitude (mass of each box) must be learned from appearance
        assert probe["gravity_magnitude_error_n"] < 0.75 * base["gravity_magnitude_error_n"], (probe, base)
        assert probe["gravity_angular_error_deg"] < 15.0
    else:
        base = baselines["zero"]["scene_flow_epe_m"]
        speed = (target.norm(dim=1)[mask]).mean().item()
        assert base == pytest.approx(speed, rel=0.2)  # all-zero EPE = mean |flow| (per image, then images)
        assert probe["scene_flow_epe_m"] < 0.6 * base, (probe, base)


# --------------------------------------------------------------------------- #
def test_multirun_two_backbones_by_two_tasks(synthetic_dataset: Path, tmp_path: Path):
    sweep_dir = tmp_path / "sweep"
    env = {
        **os.environ,
        "WANDB_MODE": "offline",
        "WANDB_SILENT": "true",
        "HF_HUB_OFFLINE": "1",
        "OMP_NUM_THREADS": "1",
        "PYTHONPATH": str(REPO),
    }
    cmd = [
        sys.executable,
        str(REPO / "train.py"),
        "-m",
        *[o for o in TINY_BACKBONE if not o.startswith("backbone.layers")],
        "backbone.layers=[3],[1,3]",  # two backbones: the same tiny ViT tapped at other layers
        "task=collision,scene_flow",
        f"data.data_root={synthetic_dataset}",
        f"paths.cache_dir={tmp_path / 'cache'}",
        f"paths.log_dir={tmp_path / 'logs'}",
        f"hydra.sweep.dir={sweep_dir}",
        "trainer=cpu",
        "trainer.max_epochs=1",
        "trainer.enable_progress_bar=false",
        "trainer.enable_model_summary=false",
        "data.num_workers=0",
        "data.batch_size=6",
        "logger=wandb",
        "logger.wandb.offline=true",
    ]
    proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-4000:]
    results = sorted(sweep_dir.glob(f"*/{METRICS_FILENAME}"))
    assert len(results) == 4
    combos = set()
    for path in results:
        m = json.loads(path.read_text())
        combos.add((tuple(m["backbone_layers"]), m["task"]))
        assert m["test"] and m["test_ood_gravity"]
        assert len(list((path.parent / "wandb").glob("offline-run-*"))) == 1  # one W&B run per job
    assert combos == {
        ((3,), "collision"),
        ((1, 3), "collision"),
        ((3,), "scene_flow"),
        ((1, 3), "scene_flow"),
    }


# --------------------------------------------------------------------------- #
@pytest.fixture()
def copied_dataset(synthetic_dataset: Path, tmp_path: Path) -> Path:
    root = tmp_path / "data_copy"
    shutil.copytree(synthetic_dataset, root)
    return root


def test_empty_data_dir_is_a_clear_error(tmp_path: Path):
    for split in schema.SPLITS:
        (tmp_path / "empty" / split).mkdir(parents=True)
    cfg = _compose(tmp_path, tmp_path / "empty", [])
    with pytest.raises(DataConfigError, match=r"no shards \(expected files matching shard-\*\.h5\)"):
        build(cfg)
    cfg = _compose(tmp_path, tmp_path / "does_not_exist", [])
    with pytest.raises(DataConfigError, match="does not exist"):
        build(cfg)


def test_old_schema_version_is_a_clear_error(copied_dataset: Path, tmp_path: Path):
    shard = sorted((copied_dataset / "val").glob("shard-*.h5"))[0]
    with h5py.File(shard, "r+") as f:
        f.attrs[schema.FILE_ATTR_SCHEMA_VERSION] = schema.SCHEMA_VERSION - 1
    cfg = _compose(tmp_path, copied_dataset, [])
    with pytest.raises(DataConfigError, match=rf"schema_version {schema.SCHEMA_VERSION - 1}.*regenerate"):
        build(cfg)


def test_clip_longer_than_sequences_is_a_clear_error(synthetic_dataset: Path, tmp_path: Path):
    cfg = _compose(tmp_path, synthetic_dataset, ["data.clip_length=7"])  # fixture sequences have 6 frames
    with pytest.raises(DataConfigError, match="clip_length=7.*longer than every sequence.*6 frames"):
        build(cfg)


def test_unknown_task_and_backbone_list_the_valid_ones(synthetic_dataset: Path, tmp_path: Path):
    with pytest.raises(MissingConfigException, match=r"(?s)task.*collision.*gravity.*scene_flow"):
        _compose(tmp_path, synthetic_dataset, ["task=stress"])
    with pytest.raises(MissingConfigException, match=r"(?s)backbone.*dinov2.*vit_tiny"):
        _compose(tmp_path, synthetic_dataset, ["backbone=resnet"])
    cfg = _compose(tmp_path, synthetic_dataset, [])
    with open_dict(cfg):
        cfg.task.name = "stress"
    with pytest.raises(ValueError, match="valid tasks: collision, gravity, scene_flow"):
        build(cfg)


def test_train_main_returns_the_monitored_validation_metric(synthetic_dataset: Path, tmp_path: Path, one_thread):
    """A Hydra sweeper (e.g. Optuna) optimises what the task function returns: train.py's main returns the
    monitored validation metric of the run, the same number metrics.json records."""
    from probes.train_cli import main

    cfg = _compose(tmp_path, synthetic_dataset, ["task=gravity", "logger=csv"])
    value = main.__wrapped__(cfg)  # the function @hydra.main wraps, called with a composed config
    metrics = json.loads((tmp_path / "run" / METRICS_FILENAME).read_text())
    assert metrics["monitor"] == "val/skill" and isinstance(value, float)  # skill over the best trivial baseline
    assert value == metrics["skill"]["val"]["mean"] and value == value  # finite: the tiny probe trained two epochs
