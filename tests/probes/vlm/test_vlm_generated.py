"""End to end on a generated (simulated) question set: one push sequence is simulated and rendered, questions
are written by generate_vqa, and the set is answered by two tiny random-weight VLM architectures and the
baselines through the command line's ``run``, then scored: oracle 1.0, constant letters at the letter shares
of the headline scope (base items of the analysed question ids, the paper's), the tiny models' manifests and
scores say random weights.

Measured: 28.5 s on 2 shared CPU cores under load (18.5 s simulation, VQA and tiny-model build; 10 s answering
and scoring), 13.5 s on a quieter moment (8.8 s + 4.7 s); near the budget of a default test: marked slow."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from newtphys import vqa_schema as vs
from newtphys.config import compose_config
from newtphys.vqa_scoring import macro_accuracy

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def generated_set(tmp_path_factory: pytest.TempPathFactory) -> Path:
    from generate_vqa import run as generate_vqa
    from tests.data_gen.conftest import compose_vqa, generate

    root = tmp_path_factory.mktemp("vlm_generated")
    generate(root / "data", ["split=test", "scenario=push", "quality=draft", "num_sequences=1",
                             "sequences_per_shard=1", "num_frames=12", "image_size=[32,40]",
                             "scenario.num_objects=[2,2]", "seed=1"])  # fmt: skip
    generate_vqa(compose_vqa(root / "data", root / "vqa", "workers=1", "exclude_last_frames=3",
                             "frames_per_sequence=1"))  # fmt: skip
    return root / "vqa" / "test"


def test_generated_set_answered_by_tiny_vlms_and_baselines(generated_set: Path, tiny_cache: Path, tmp_path: Path,
                                                           one_thread):  # fmt: skip
    from probes.vlm.cli import run

    items = vs.read_items(generated_set)
    answers = vs.read_answers(generated_set)
    assert len(items) >= 30 and {i.mode for i in items} == {"single", "multi"}
    common = [f"vqa_dir={generated_set}", f"results_dir={tmp_path}", "progress=false", "wandb.offline=true",
              "batch_size=4"]  # fmt: skip
    scores = {}
    for vlm in ("oracle", "random", "prior", "constant_letter", "tiny_qwen2_vl", "tiny_idefics3"):
        extra = [f"vlm.cache_dir={tiny_cache}"] if vlm.startswith("tiny") else []
        out = run(compose_config("evaluate_vlm", [f"vlm={vlm}", *common, *extra]))
        scores[vlm] = out["scores"]
        manifest = json.loads((out["run_dir"] / "manifest.json").read_text())
        assert out["result"].items == len(items)
        if vlm.startswith("tiny"):
            assert manifest["model"]["weights"] == "random" and scores[vlm]["weights"] == "random"
            assert list((out["run_dir"] / "wandb").glob("offline-run-*"))
    assert scores["oracle"]["strict"]["overall"] == 1.0
    # the headline scope (the paper's): every item is answered, but the headline covers the base items of the
    # analysed question ids only; the ids the paper set apart and the variants are scored apart
    analysed = [i for i in items if vs.question_spec(i.question_id).in_analysis]
    head = [i for i in analysed if i.variant == vs.BASE_VARIANT]
    variants = [i for i in analysed if i.variant != vs.BASE_VARIANT]
    apart = [i for i in items if not vs.question_spec(i.question_id).in_analysis and i.variant == vs.BASE_VARIANT]
    assert head and apart and len(head) < len(items)  # the scope differs from "all items" on this set
    share_a = macro_accuracy([{"question_id": i.question_id, "sub_category": i.sub_category, "category": i.category,
                               "correct": answers[i.idx].answer == "A"} for i in head])["overall"]  # fmt: skip
    assert scores["constant_letter"]["strict"]["overall"] == pytest.approx(share_a)
    for s in scores.values():
        assert s["baselines"]["constant_A"] == pytest.approx(share_a) and s["items"] == len(head)
        assert s["excluded_from_analysis"]["n_items"] == len(apart)
        assert sum(v["n_items"] for v in s["variants"].values()) == len(variants)
