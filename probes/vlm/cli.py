"""``newtphys-evaluate-vlm`` / ``python evaluate_vlm.py``: one answerer on one question set.

    python evaluate_vlm.py vlm=qwen2_5_vl_7b vqa_dir=data/vqa/test
    python evaluate_vlm.py -m vlm=random,oracle,constant_letter,prior,qwen2_5_vl_3b vqa_dir=data/vqa/test
    python evaluate_vlm.py vlm=qwen2_5_vl_7b blind=true circular=true
    python evaluate_vlm.py -m hydra/launcher=vlm_slurm vlm=qwen2_5_vl_72b num_shards=4 'shard_index=range(0,4)'
    python -m probes.vlm.sharding merge results/vlm/vqa-test/qwen2_5_vl_72b     # join the shards, then score

Order: resolve the set directory -> build the answerer from ``cfg.vlm`` (``_target_``; a ``set_dir: null`` key is
filled with the set) -> wrap it in :class:`~probes.vlm.baselines.Blind` when ``blind=true`` -> answer into the
run directory (resuming; one shard's directory when ``num_shards > 1``) -> score into ``scores.json``
(:func:`probes.vlm.scoring.score_run`) -> log to W&B. Options: ``newtphys/conf/evaluate_vlm.yaml``.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import hydra
from omegaconf import DictConfig, OmegaConf

from newtphys.config import CONFIG_DIR
from probes.vlm.baselines import Blind
from probes.vlm.evaluate import EvalResult, evaluate
from probes.vlm.interface import Answerer
from probes.vlm.prompting import resolve_set_dir
from probes.vlm.scoring import score_run
from probes.vlm.sharding import check_shard, shard_dir

log = logging.getLogger(__name__)


def build_answerer(vlm_cfg: DictConfig | dict[str, Any], set_dir: Path) -> Answerer:
    """Instantiate ``vlm_cfg`` (its ``_target_``); a ``set_dir`` key left null gets the evaluated set."""
    plain = OmegaConf.to_container(vlm_cfg, resolve=True) if isinstance(vlm_cfg, DictConfig) else vlm_cfg
    node = OmegaConf.create(plain)
    if "_target_" not in node:
        raise ValueError(f"vlm config needs a _target_ (see newtphys/conf/vlm/); got keys {sorted(node)}")
    if "set_dir" in node and node.set_dir is None:
        node.set_dir = str(set_dir)
    return hydra.utils.instantiate(node)


def run_name(answerer: Answerer, circular: bool) -> str:
    return answerer.name + ("-circular" if circular else "")


def _flat(prefix: str, value: Any, out: dict[str, float]) -> None:
    if isinstance(value, bool):
        return
    if isinstance(value, (int, float)):
        out[prefix] = float(value)
    elif isinstance(value, dict):
        for k, v in value.items():
            if k != "question_id":  # one series per question id is too many for a dashboard
                _flat(f"{prefix}/{k}" if prefix else str(k), v, out)


def log_wandb(cfg: DictConfig, name: str, result: EvalResult, scores: dict[str, Any]) -> None:
    """One W&B run: the config, the manifest (model id, revision, dtype, weights) and the scores."""
    wcfg = cfg.get("wandb") or {}
    if not wcfg.get("enabled", False):
        return
    import wandb

    mode = "offline" if wcfg.get("offline", False) else None
    run = wandb.init(project=str(wcfg.get("project", "newtphys-vlm")), name=name, group=wcfg.get("group"),
                     job_type="vlm-eval", dir=str(result.run_dir), mode=mode, reinit="finish_previous",
                     tags=[result.manifest.model.get("weights", "?"), result.manifest.answerer],
                     config={"cfg": OmegaConf.to_container(cfg, resolve=True),
                             "manifest": json.loads(result.manifest.to_json())})  # fmt: skip
    flat: dict[str, float] = {}
    _flat("", scores, flat)
    run.log(flat)
    run.summary.update(flat)
    run.finish()


def pin_shard_gpu(shard_index: int, gpus: Any) -> str | None:
    """With ``shard_gpus`` listed, this job sees only ``gpus[shard_index % len(gpus)]`` (set before CUDA starts;
    submitit's local executor would give every job GPU 0). Returns the device set, or None."""
    if not gpus:
        return None
    gpus = list(gpus)
    device = str(gpus[shard_index % len(gpus)])
    os.environ["CUDA_VISIBLE_DEVICES"] = device
    return device


def run(cfg: DictConfig) -> dict[str, Any]:
    """One evaluation from a composed ``evaluate_vlm`` config (tests call this); returns run_dir, result and
    scores (none for one shard of a sharded run: merge the shards, :mod:`probes.vlm.sharding`)."""
    set_dir = resolve_set_dir(cfg.vqa_dir, cfg.get("split"))
    index, count = int(cfg.get("shard_index", 0)), int(cfg.get("num_shards", 1))
    check_shard(index, count)
    pin_shard_gpu(index, cfg.get("shard_gpus"))
    answerer = build_answerer(cfg.vlm, set_dir)
    if cfg.get("blind", False):
        answerer = Blind(answerer)
    circular = bool(cfg.get("circular", False))
    name = run_name(answerer, circular)
    default_dir = Path(cfg.results_dir) / f"{set_dir.parent.name}-{set_dir.name}" / name
    base_dir = Path(cfg.run_dir) if cfg.get("run_dir") else default_dir
    run_dir = base_dir if count == 1 else shard_dir(base_dir, index, count)
    result = evaluate(answerer, set_dir, run_dir, batch_size=int(cfg.batch_size), circular=circular,
                      limit=cfg.get("limit"), progress=bool(cfg.get("progress", True)), shard_index=index,
                      num_shards=count, extra={"batch_size": int(cfg.batch_size)})  # fmt: skip
    if count > 1:
        log.info("shard %d of %d done -> %s; merge with: python -m probes.vlm.sharding merge %s", index, count,
                 run_dir, base_dir)  # fmt: skip
        return {"run_dir": run_dir, "result": result, "scores": {}}
    log.info("%s: %d answered now, %d from earlier runs, %.1f s -> %s", name, result.answered, result.already_done,
             result.seconds, run_dir)  # fmt: skip
    scores = score_run(run_dir, set_dir, n_boot=int(cfg.get("n_boot", 1000))) if cfg.get("score", True) else {}
    if scores:
        best = scores["best_trivial"]
        log.info("%s strict macro accuracy %.4f (best trivial %s %.4f)", name, scores["strict"]["overall"],
                 best["name"], best["overall"])  # fmt: skip
    log_wandb(cfg, name, result, scores)
    return {"run_dir": run_dir, "result": result, "scores": scores}


@hydra.main(version_base="1.3", config_path=str(CONFIG_DIR), config_name="evaluate_vlm")
def main(cfg: DictConfig) -> None:
    out = run(cfg)
    print(f"wrote {out['run_dir']}")


if __name__ == "__main__":
    main()
