"""Counterfactual questions on a tiny scene (one push sequence, two objects, 16 frames at 32 x 40): the
factual scenario is drawn again from the shard, each twin differs in exactly one parameter, and every CF item's
answer is the twin's value (recomputed here from the twin's world state) and differs from the factual one by
at least the threshold. Only cf_gravity is simulated in the default run; all three in the slow test."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from data_gen.scenario import counterfactual
from data_gen.vqa.cli import run as run_vqa
from data_gen.vqa.generator import TWINS_DIR
from data_gen.vqa.rules import fmt, multi_window
from data_gen.vqa.variants.counterfactual import (
    CF_QUESTIONS, CounterfactualError, factual_scenario, shift_vector,
)  # fmt: skip
from data_gen.vqa.view import Box, SequenceView, box_distance
from newtphys import vqa_schema as vs
from newtphys.rotations import quat_to_matrix
from newtphys.shards import ShardReader, list_shards
from newtphys.vqa_validate import validate_question_set
from newtphys.world_state import WorldState
from tests.data_gen.conftest import compose_vqa, generate

TRACKED = ("sequence_id", "counterfactual_of", "change")
"""Scenario fields a twin changes by construction (its name and provenance)."""


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("vqa_cf_data")
    generate(root, ["split=test", "scenario=push", "num_sequences=1", "sequences_per_shard=1", "num_frames=16",
                    "image_size=[32,40]", "scenario.num_objects=[2,2]", "seed=2"])  # fmt: skip
    return root


def _view(data: Path) -> SequenceView:
    shard = list_shards(data / "test")[0]
    with ShardReader(shard) as r:
        sid = r.sequences()[0]
    return SequenceView(shard, sid, "test/" + shard.name)


def _changed_fields(a, b) -> dict[str, object]:
    """Scenario fields (objects field by field, as ``objects[<id>].<field>``) that differ, with b's value."""
    out: dict[str, object] = {}
    for f in dataclasses.fields(a):
        if f.name in TRACKED or f.name == "objects":
            continue
        if getattr(a, f.name) != getattr(b, f.name):
            out[f.name] = getattr(b, f.name)
    for oa, ob in zip(a.objects, b.objects):
        for f in dataclasses.fields(oa):
            if getattr(oa, f.name) != getattr(ob, f.name):
                out[f"objects[{oa.object_id}].{f.name}"] = getattr(ob, f.name)
    return out


def test_the_factual_scenario_is_drawn_again_and_each_twin_changes_one_parameter(tiny_data: Path) -> None:
    view = _view(tiny_data)
    scenario, _ = factual_scenario(view)
    ws = view.world_state
    assert scenario.seed == ws.seed and [o.asset for o in scenario.objects] == [o.name for o in ws.objects]
    g = counterfactual(scenario, "gravity", amount=0.1)
    assert set(_changed_fields(scenario, g)) == {"gravity_m_s2"}
    assert np.allclose(g.gravity_m_s2, 0.1 * np.asarray(ws.gravity), rtol=1e-12)
    d, side = shift_vector(view, scenario, 1, 0.15)
    s = counterfactual(scenario, "shift", object_id=1, amount=d.tolist())
    assert set(_changed_fields(scenario, s)) == {"objects[1].position_m"} and side in ("right", "left")
    moved = np.subtract(s.objects[0].position_m, scenario.objects[0].position_m)
    assert np.linalg.norm(moved) == pytest.approx(0.15, abs=1e-12) and moved[2] == 0.0
    r = counterfactual(scenario, "resize", object_id=2, amount=0.5)
    assert _changed_fields(scenario, r) == {"objects[2].size_m": scenario.objects[1].size_m * 0.5}


def test_a_world_state_the_shard_config_does_not_reproduce_is_an_error(tiny_data: Path) -> None:
    view = _view(tiny_data)
    view.world_state.objects[0].young_modulus *= 2.0
    with pytest.raises(CounterfactualError, match=r"test-000000.*differs from the world state at "
                                                  r"'objects\[1\]\.young_modulus'"):  # fmt: skip
        factual_scenario(view)


def _box(frame_state) -> Box:
    b = frame_state.extra["box"]
    return Box(np.asarray(b["center"]), np.asarray(b["extents"]), quat_to_matrix(np.asarray(b["rotation"])))


def _twin_value(question_id: str, twin: WorldState, view: SequenceView, t: int, objects: list[int]) -> float:
    """The answer from the twin's world state, by hand (not through SequenceView)."""
    state = {o.id: o for o in twin.frames[t].objects}
    if question_id == "F_KINEMATICS_SPEED_OBJECT":
        return float(np.linalg.norm(state[objects[0]].velocity))
    if question_id == "F_KINEMATICS_ACCEL_OBJECT":
        lo, hi = max(t - 1, 0), min(t + 1, twin.num_frames - 1)
        v = [np.asarray(next(o for o in twin.frames[k].objects if o.id == objects[0]).velocity) for k in (lo, hi)]
        return float(np.linalg.norm(v[1] - v[0]) * twin.fps / (hi - lo))
    if question_id == "F_KINEMATICS_DISTANCE_TRAVELED_INTERVAL":
        first = next(o for o in twin.frames[multi_window(t)[0]].objects if o.id == objects[0])
        return float(np.linalg.norm(np.subtract(state[objects[0]].position, first.position)))
    if question_id == "F_DISTANCE_OBJECT_OBJECT":
        return box_distance(_box(state[objects[0]]), _box(state[objects[1]]))
    return _box(state[objects[0]]).distance_to_point(view.camera_center(t))


def _check_cf_items(set_dir: Path, view: SequenceView, variant: str) -> int:
    items = vs.read_items(set_dir)
    answers = vs.read_answers(set_dir)
    by_idx = {i.idx: i for i in items}
    cf = [i for i in items if i.variant == variant]
    change = variant.removeprefix("cf_")
    (twin_file,) = (set_dir / TWINS_DIR).glob(f"*-cf-{change}.json")
    twin = WorldState.from_dict(json.loads(twin_file.read_text())["world_state"])
    factual = view.world_state
    for a, b in zip(twin.objects, factual.objects):  # same objects and materials
        assert (a.name, a.material, a.young_modulus, a.poisson_ratio) == (b.name, b.material, b.young_modulus,
                                                                           b.poisson_ratio)  # fmt: skip
    for item in cf:
        base = by_idx[f"{item.pair.removesuffix('/' + variant)}/{item.mode}"]
        qid = base.question_id
        assert item.question_id == vs.COUNTERFACTUAL_PREFIX + qid and item.images == base.images
        meta = item.meta["counterfactual"]
        assert meta["change"] == change
        assert meta["factual_value"] == pytest.approx(answers[base.idx].value, abs=2e-4)
        value = answers[item.idx].value
        assert value == pytest.approx(_twin_value(qid, twin, view, item.frames[-1], base.objects), abs=1e-4)
        q = CF_QUESTIONS[qid]
        rel = abs(value - meta["factual_value"]) / abs(meta["factual_value"]) if meta["factual_value"] else np.inf
        assert rel >= q.threshold - 1e-3, (item.idx, value, meta)
        letter = vs.LETTERS.index(answers[item.idx].answer)
        assert item.options[letter] == fmt(value, q.decimals, q.unit_text)
        assert fmt(meta["factual_value"], q.decimals, q.unit_text) in item.options  # the premise-blind answer
    return len(cf)


def test_cf_gravity_items_answer_from_the_simulated_twin(tiny_data: Path, tmp_path: Path) -> None:
    run_vqa(compose_vqa(tiny_data, tmp_path, "workers=1", "exclude_last_frames=2", "variants=[base,cf_gravity]"))
    set_dir = tmp_path / "test"
    assert validate_question_set(set_dir) == []
    view = _view(tiny_data)
    (twin_file,) = (set_dir / TWINS_DIR).glob("*.json")
    twin = WorldState.from_dict(json.loads(twin_file.read_text())["world_state"])
    assert np.allclose(twin.gravity, 0.1 * np.asarray(view.world_state.gravity), rtol=1e-9)
    for a, b in zip(twin.frames[0].objects, view.world_state.frames[0].objects):  # same start, other gravity
        assert np.allclose(a.position, b.position, atol=1e-6) and np.allclose(a.velocity, b.velocity, atol=1e-6)
    assert _check_cf_items(set_dir, view, "cf_gravity") >= 2
    manifest = vs.read_manifest(set_dir)
    assert manifest["counts"]["variant"]["cf_gravity"] >= 2
    assert any(k.startswith("CF_") for k in manifest["counts"]["question_id"])


@pytest.mark.slow
def test_all_three_counterfactuals_end_to_end(tiny_data: Path, tmp_path: Path) -> None:
    run_vqa(compose_vqa(tiny_data, tmp_path, "workers=1", "exclude_last_frames=2",
                        "variants=[base,cf_gravity,cf_shift,cf_resize]"))  # fmt: skip
    set_dir = tmp_path / "test"
    assert validate_question_set(set_dir) == []
    view = _view(tiny_data)
    for variant in ("cf_gravity", "cf_shift", "cf_resize"):
        _check_cf_items(set_dir, view, variant)
    for change in ("shift", "resize"):
        (path,) = (set_dir / TWINS_DIR).glob(f"*-cf-{change}.json")
        kept = json.loads(path.read_text())
        twin, obj = WorldState.from_dict(kept["world_state"]), kept["counterfactual"]["object"]
        for a, b in zip(twin.objects, view.world_state.objects):
            if change == "resize":
                assert np.allclose(a.size, np.asarray(b.size) * (0.5 if a.id == obj else 1.0), rtol=1e-9)
            else:
                assert np.allclose(a.size, b.size)
        if change == "shift":
            for a, b in zip(twin.frames[0].objects, view.world_state.frames[0].objects):
                moved = float(np.linalg.norm(np.subtract(a.position, b.position)))
                assert moved == pytest.approx(0.15 if a.id == obj else 0.0, abs=1e-6)
    assert vs.read_manifest(set_dir)["variant_skips"]  # counted: changes below the threshold
