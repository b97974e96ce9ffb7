"""The transformers adapter on three real architectures at tiny size with RANDOM weights, built offline:
Qwen2-VL and Idefics3 (generic adapter: chat template with one image slot per image) and PaliGemma (family
adapter: single image, no chat template, a task prefix); the processor's visual tokens per image as computed
by hand, left-padded batches that reply as single prompts do, single-image models given only single items,
and a run whose manifest says the weights are random."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from newtphys import vqa_schema as vs
from probes.vlm.evaluate import evaluate
from probes.vlm.interface import PREDICTIONS_FILE
from probes.vlm.predictions import read_predictions
from probes.vlm.prompting import build_prompt
from probes.vlm.scoring import score_run
from probes.vlm.tiny import FIXTURE_NOTE, build_tiny_answerer

# visual tokens of one 24 x 32 px image (conftest's images):
#   Qwen2-VL: inside the pixel budget [16^2, 32^2] and a multiple of 4 px patch x 2 merge = 8 px, so kept at
#   24 x 32 -> 6 x 8 patches of 4 px -> 48 / (2 x 2 merge) = 12 tokens;
#   Idefics3: resized to a 32 px tile (no splitting) -> (32 / 8)^2 patches / 2^2 pixel shuffle = 4 tokens;
#   PaliGemma: resized to 32 x 32 px -> (32 / 8)^2 = 16 tokens
TOKENS_PER_IMAGE = {"qwen2_vl": 12, "idefics3": 4, "paligemma": 16}
IMAGE_SLOT = {"qwen2_vl": "<|vision_start|><|image_pad|><|vision_end|>", "idefics3": "<image>", "paligemma": None}


@pytest.mark.parametrize("arch", ["qwen2_vl", "idefics3", "paligemma"])
def test_tiny_architecture_prompts_batches_and_manifest(arch: str, vlm_set: Path, tiny_cache: Path, tmp_path: Path,
                                                        one_thread):  # fmt: skip
    answerer = build_tiny_answerer(arch, cache_dir=str(tiny_cache))
    items = vs.read_items(vlm_set)
    single_only = arch == "paligemma"
    prompts = [build_prompt(item, vlm_set) for item in items[:6] if not single_only or item.mode == "single"]
    n_images = [len(p.images) for p in prompts]
    assert n_images == ([1, 1, 1] if single_only else [1, 3, 1, 3, 1, 6])  # the last: 2 + 4 option images
    for p, n in zip(prompts, n_images):
        text = answerer.render(p)
        if IMAGE_SLOT[arch] is None:  # the processor puts the image tokens in front of the task prefix
            assert text == "answer en " + p.text
        else:
            assert text.count(IMAGE_SLOT[arch]) == n
            assert text.index(IMAGE_SLOT[arch]) < text.index(items[0].question[:10])
    batch = answerer.inputs(prompts)
    image_token = answerer.model.config.image_token_id
    per_prompt = (batch["input_ids"] == image_token).sum(dim=1).tolist()
    assert per_prompt == [TOKENS_PER_IMAGE[arch] * n for n in n_images]
    assert (batch["attention_mask"][:, 0] == 0).any() and (batch["attention_mask"][:, -1] == 1).all()  # left pad

    batched = answerer.answer(prompts)
    single = [answerer.answer([p])[0] for p in prompts]
    assert [g.text for g in batched] == [g.text for g in single]  # padding does not change greedy replies
    assert [g.tokens_in for g in batched] == [g.tokens_in for g in single]
    assert all(1 <= g.tokens_out <= 8 for g in batched)  # max_new_tokens of the fixtures

    result = evaluate(answerer, vlm_set, tmp_path / arch, batch_size=4, progress=False)
    manifest = json.loads((tmp_path / arch / "manifest.json").read_text())
    assert manifest["model"]["weights"] == "random" and manifest["model"]["fixture"] == FIXTURE_NOTE
    assert manifest["model"]["id"] == f"newtphys/tiny-random-{arch}" and manifest["model"]["parameters"] > 10_000
    assert result.answered == (9 if single_only else 18)
    assert result.not_asked == {"multi": 9 if single_only else 0, "too_many_images": 0, "mode": 0, "limit": 0}
    preds = read_predictions(tmp_path / arch / PREDICTIONS_FILE)
    assert [p.raw for p in preds[: len(prompts)]] == [g.text for g in batched]
    scores = score_run(tmp_path / arch, vlm_set, n_boot=0)
    # reported beside the trivial predictors (macro, by hand): all 18 items: A and D 5/18 (test_vlm_baselines),
    # B 1/4, C 7/36; the 9 single items (answers mass A B C, size C C C, material A A B): A (mass 1/3 + material
    # 2/3) / 2 and size 0 -> 1/4, B 1/6, C (1/3 + 0) / 2 and size 1 -> 7/12, D 0
    expected = ({"constant_A": 1 / 4, "constant_B": 1 / 6, "constant_C": 7 / 12, "constant_D": 0.0} if single_only else
                {"constant_A": 5 / 18, "constant_B": 1 / 4, "constant_C": 7 / 36, "constant_D": 5 / 18})  # fmt: skip
    assert scores["weights"] == "random"
    for name, value in expected.items():
        assert scores["baselines"][name] == pytest.approx(value)
    assert scores["best_trivial"]["overall"] == max(scores["baselines"].values())
    assert scores["best_trivial"]["overall"] >= max(expected.values())
    assert 0.0 <= scores["strict"]["overall"] <= 1.0


def test_tiny_weights_are_seeded(tiny_cache: Path, tmp_path: Path):
    import torch

    a = build_tiny_answerer("idefics3", seed=0, cache_dir=str(tiny_cache)).model.state_dict()
    b = build_tiny_answerer("idefics3", seed=0, cache_dir=str(tmp_path)).model.state_dict()  # built anew
    c = build_tiny_answerer("idefics3", seed=1, cache_dir=str(tmp_path)).model.state_dict()
    key = next(k for k in a if "embed_tokens" in k)
    assert torch.equal(a[key], b[key]) and not torch.equal(a[key], c[key])


def test_blind_paligemma_is_refused_with_the_reason(vlm_set: Path, tiny_cache: Path):
    from probes.vlm.baselines import Blind

    blind = Blind(build_tiny_answerer("paligemma", cache_dir=str(tiny_cache)))
    with pytest.raises(ValueError, match="exactly one image per prompt; blind=true cannot remove it"):
        blind.answer([build_prompt(vs.read_items(vlm_set)[0], vlm_set)])
