"""Models as data: every record is valid and has its YAML; weights resolve from the HF cache (with the
snapshot's commit recorded) and give the backbones' clear error offline; remote-code models are refused
before any download; single-image models get only ``single`` items; PaliGemma renders without a chat
template."""

from __future__ import annotations

import inspect
import json
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from newtphys.config import CONFIG_DIR
from probes.backbones.weights import WeightsUnavailableError
from probes.vlm.evaluate import evaluate
from probes.vlm.hf_adapter import PaliGemmaAnswerer, build_hf_answerer, resolve_snapshot
from probes.vlm.interface import Generation, Prompt
from probes.vlm.predictions import read_predictions
from probes.vlm.scoring import score_run
from probes.vlm.specs import SPECS, VLMSpec, get_spec

FAMILIES = {"qwen2_vl", "qwen2_5_vl", "llava_onevision", "llava_next", "internvl", "idefics3", "smolvlm", "paligemma"}


def test_records_cover_the_families_and_every_native_record_has_its_yaml():
    assert FAMILIES <= {s.family for s in SPECS.values()}
    assert {s.name for s in SPECS.values() if s.needs_remote_code} == {"internvl2_5_8b", "phi3_5_vision", "minicpm_v2_6"}
    accepted = set(inspect.signature(build_hf_answerer).parameters)
    for name, spec in SPECS.items():
        path = CONFIG_DIR / "vlm" / f"{name}.yaml"
        if spec.needs_remote_code:
            assert not path.exists()
            continue
        cfg = yaml.safe_load(path.read_text())
        assert cfg["_target_"] == "probes.vlm.hf_adapter.build_hf_answerer" and cfg["name"] == name
        assert set(cfg) - {"_target_"} <= accepted
        assert spec.hf_id.count("/") == 1 and spec.max_images in (None, 1)
        assert spec.single_image_only == (spec.max_images == 1)
    assert get_spec("paligemma2_3b").chat_template == "none" and get_spec("qwen2_5_vl_7b").multi_image
    with pytest.raises(KeyError, match="valid names: .*qwen2_5_vl_7b"):
        get_spec("gpt5")
    with pytest.raises(ValueError, match="single-image model has max_images 1"):
        VLMSpec("x", "a/b", "f", "AutoModelForImageTextToText", 1.0, multi_image=False, max_images=4)


def test_offline_without_weights_gives_the_clear_error(tmp_path: Path, monkeypatch):
    monkeypatch.setenv("HF_HOME", str(tmp_path / "hf"))
    monkeypatch.delenv("HF_HUB_CACHE", raising=False)
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    with pytest.raises(WeightsUnavailableError) as err:
        build_hf_answerer("smolvlm_256m")
    msg = str(err.value)
    assert "'HuggingFaceTB/SmolVLM-256M-Instruct'" in msg and "HF_HUB_OFFLINE=1" in msg
    assert str(tmp_path / "hf" / "hub") in msg and "huggingface-cli download" in msg and "vlm.weights_path" in msg
    monkeypatch.setenv("HF_HUB_OFFLINE", "0")
    with pytest.raises(WeightsUnavailableError, match="gated"):  # allow_download=False: no network attempt either
        build_hf_answerer("paligemma2_3b", allow_download=False)
    with pytest.raises(ValueError, match="remote code"):  # refused before any download
        build_hf_answerer("phi3_5_vision")
    with pytest.raises(WeightsUnavailableError, match="must be a directory holding config.json"):
        build_hf_answerer("qwen2_vl_2b", weights_path=str(tmp_path))


def test_a_cached_snapshot_resolves_with_its_commit(tmp_path: Path, monkeypatch):
    commit = "0123456789abcdef0123456789abcdef01234567"
    repo = tmp_path / "hub" / "models--Qwen--Qwen2-VL-2B-Instruct"
    snap = repo / "snapshots" / commit
    snap.mkdir(parents=True)
    (snap / "config.json").write_text("{}")
    (repo / "refs").mkdir()
    (repo / "refs" / "main").write_text(commit)
    monkeypatch.setenv("HF_HUB_CACHE", str(tmp_path / "hub"))
    monkeypatch.setenv("HF_HUB_OFFLINE", "1")
    path, revision = resolve_snapshot(get_spec("qwen2_vl_2b"), None, None, allow_download=False)
    assert path == snap and revision == commit


class _SingleImageModel:
    """A stand-in for a single-image model: records what it is asked."""

    name = "single"
    single_image_only = True
    spec = SimpleNamespace(max_images=1)

    def __init__(self):
        self.seen: list[Prompt] = []

    def describe(self):
        return {"id": "single", "weights": "none"}

    def answer(self, prompts):
        self.seen += prompts
        return [Generation("A", 0.0) for _ in prompts]


def test_single_image_models_get_only_single_items(vlm_set: Path, tmp_path: Path):
    model = _SingleImageModel()
    result = evaluate(model, vlm_set, tmp_path / "r", batch_size=4, progress=False)
    assert result.items == 9 and result.not_asked == {"multi": 9, "too_many_images": 0, "mode": 0, "limit": 0}
    assert all(len(p.images) == 1 and p.idx.endswith("/single") for p in model.seen)
    assert len(read_predictions(tmp_path / "r" / "predictions.jsonl")) == 9
    manifest = json.loads((tmp_path / "r" / "manifest.json").read_text())
    # the manifest carries what decides the selection, so scoring and the shard merge recompute it
    assert manifest["model"]["single_image_only"] is True and manifest["model"]["max_images"] == 1
    scores = score_run(tmp_path / "r", vlm_set, n_boot=0)
    assert scores["items"] == 9 and scores["coverage"]["not_asked"]["multi"] == 9


def test_paligemma_renders_a_task_prefix_without_chat_template():
    prompt = Prompt("i", (Path("a.png"),), "Q?\nA. x\nB. y\nC. z\nD. w\nReply ...", ("x", "y", "z", "w"))
    fake = SimpleNamespace(spec=get_spec("paligemma2_3b"))
    assert PaliGemmaAnswerer.render(fake, prompt) == "answer en Q?\nA. x\nB. y\nC. z\nD. w\nReply ..."


def test_every_vlm_config_composes_and_names_a_callable_target():
    import hydra
    from hydra import compose, initialize_config_dir

    names = sorted(p.stem for p in (CONFIG_DIR / "vlm").glob("*.yaml"))
    assert {"random", "oracle", "constant_letter", "prior", "tiny_qwen2_vl", "tiny_idefics3", "tiny_paligemma"} <= set(names)
    with initialize_config_dir(config_dir=str(CONFIG_DIR), version_base="1.3"):
        for name in names:
            cfg = compose(config_name="evaluate_vlm", overrides=[f"vlm={name}"])
            assert cfg.vlm.name == name and callable(hydra.utils.get_method(cfg.vlm._target_))
            assert cfg.run_name == f"vlm-{name}"
