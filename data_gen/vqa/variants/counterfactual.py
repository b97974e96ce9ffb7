"""Counterfactual questions (``cf_gravity``, ``cf_shift``, ``cf_resize``): the factual sequence's images, the
answer from a simulated twin that differs in one thing.

The factual :class:`~data_gen.scenario.Scenario` is not stored in a shard, but everything that drew it is: the
shard's ``config`` file attribute holds the generation config (scenario ranges, frames, image size, quality,
render settings) and the world state holds the sequence's seed, split, frame count, fps and image size.
``sample_scenario`` is a pure function of these, so the scenario is drawn again rather than duplicated into
the shard (one source); the draw is checked against the stored world state (assets, materials, gravity) and a
mismatch (shards from an older generator) is an error naming the shard, the sequence and the field.
:func:`data_gen.scenario.counterfactual` then changes one thing and :func:`data_gen.pipeline.generate_sequence`
simulates and renders the twin with the shard's own quality preset.

Questions: speed, acceleration, displacement, object-object and object-camera distance, asked as "what would
it be if ...". One twin per sequence and change; ``cf_shift`` / ``cf_resize`` change one object, a seeded pick
among the objects these questions name, and apply where that object is nameable in the question's frame.
An item is emitted only where the answer changes significantly: by >= 50 % for speed and acceleration,
>= 20 % for distances (relative to the factual value), and its formatted text changes. The factual answer is
always one of the distractors: a model that ignores the premise picks it.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from data_gen.vqa.rules import NotAnswerable, fmt, multi_window, numeric_distractors, seed_of
from data_gen.vqa.variants.registry import VariantInputs, VariantOutput, derive, variant
from data_gen.vqa.view import SequenceView, box_distance
from newtphys import schema
from newtphys import vqa_schema as vs
from newtphys.shards import ShardReader
from newtphys.world_state import WorldState

log = logging.getLogger(__name__)

RATE_CHANGE = 0.5
"""Speed and acceleration: emitted when |cf - factual| >= this fraction of the factual value."""
DISTANCE_CHANGE = 0.2
"""Distances: the same with this fraction."""
CHANGES = {"cf_gravity": "gravity", "cf_shift": "shift", "cf_resize": "resize"}
"""Variant -> change of :func:`data_gen.scenario.counterfactual`."""


class CounterfactualError(RuntimeError):
    """The factual scenario cannot be drawn again from the shard (names the shard, sequence and field)."""


@dataclass(frozen=True)
class CfQuestion:
    """How one question id reads and answers under a counterfactual."""

    clause: str
    """Conditional wording; ``{a}``/``{b}``: the asked objects, ``{t0}``/``{t1}``: the interval (s)."""
    value: Callable[[SequenceView, int, tuple[int, ...]], float]
    """(view, question frame, asked objects) -> the answer in SI units."""
    decimals: int
    unit_text: str
    unit: str
    threshold: float
    at_moment: bool = True
    """The clause asks about the question's last frame (not an interval)."""


def _speed(v: SequenceView, t: int, o: tuple[int, ...]) -> float:
    return float(np.linalg.norm(v.velocity(t, o[0])))


def _acceleration(v: SequenceView, t: int, o: tuple[int, ...]) -> float:
    return float(np.linalg.norm(v.acceleration(t, o[0])))


def _displacement(v: SequenceView, t: int, o: tuple[int, ...]) -> float:
    return float(np.linalg.norm(v.position(t, o[0]) - v.position(multi_window(t)[0], o[0])))


def _object_distance(v: SequenceView, t: int, o: tuple[int, ...]) -> float:
    return box_distance(v.box(t, o[0]), v.box(t, o[1]))


def _camera_distance(v: SequenceView, t: int, o: tuple[int, ...]) -> float:
    return v.box(t, o[0]).distance_to_point(v.camera_center(t))


CF_QUESTIONS: dict[str, CfQuestion] = {
    "F_KINEMATICS_SPEED_OBJECT": CfQuestion("how fast would the {a} be moving", _speed, 2, "m/s", "m/s",
                                            RATE_CHANGE),
    "F_KINEMATICS_ACCEL_OBJECT": CfQuestion("what would be the magnitude of the acceleration of the {a}",
                                            _acceleration, 2, "m/s²", "m/s^2", RATE_CHANGE),
    "F_KINEMATICS_DISTANCE_TRAVELED_INTERVAL": CfQuestion(
        "how far would the centre of the {a} have moved, in a straight line, between {t0:.2f} s and {t1:.2f} s",
        _displacement, 1, "m", "m", DISTANCE_CHANGE, at_moment=False),
    "F_DISTANCE_OBJECT_OBJECT": CfQuestion(
        "what would be the shortest distance between the {a} and the {b}, measured between their bounding boxes",
        _object_distance, 2, "m", "m", DISTANCE_CHANGE),
    "F_DISTANCE_OBJECT_CAMERA_DISTANCE": CfQuestion("how far would the {a} be from the camera", _camera_distance,
                                                    2, "m", "m", DISTANCE_CHANGE),
}  # fmt: skip


# -- the factual scenario and its twin ------------------------------------------------------------------
def factual_scenario(view: SequenceView):
    """(Scenario, GenerationConfig) of the view's sequence, drawn again from the shard's config and the world
    state's seed, checked against the world state."""
    from data_gen.generator import GenerationConfig  # the simulator stack loads only when a twin is asked for
    from data_gen.scenario import sample_scenario

    with ShardReader(view.shard) as r:
        text = r.attrs.get(schema.FILE_ATTR_CONFIG, "")
    where = f"{view.shard}: sequence '{view.sequence_id}'"
    if not text:
        raise CounterfactualError(f"{view.shard}: file attribute '{schema.FILE_ATTR_CONFIG}' is empty: the generation "
                                  "config is needed to simulate counterfactual twins; regenerate with generate.py")
    try:
        gen = GenerationConfig.from_mapping(yaml.safe_load(text))
    except (ValueError, KeyError) as e:
        raise CounterfactualError(f"{view.shard}: file attribute '{schema.FILE_ATTR_CONFIG}' is not a usable "
                                  f"generation config here: {e}") from None  # fmt: skip
    ws = view.world_state
    scenario = sample_scenario(gen.scenario, ws.sequence_id, ws.seed, ws.split, gen.gravity, ws.num_frames, ws.fps,
                               tuple(ws.image_size))  # fmt: skip
    checks: list[tuple[str, Any, Any]] = [("gravity", tuple(ws.gravity), scenario.gravity_m_s2),
                                          ("len(objects)", len(ws.objects), len(scenario.objects))]  # fmt: skip
    for stored, drawn in zip(ws.objects, scenario.objects):
        checks += [(f"objects[{stored.id}].name", stored.name, drawn.asset),
                   (f"objects[{stored.id}].material", stored.material, drawn.material),
                   (f"objects[{stored.id}].young_modulus", stored.young_modulus, drawn.young_modulus_pa),
                   (f"objects[{stored.id}].density", stored.density, drawn.density_kg_m3)]  # fmt: skip
    for key, stored, drawn in checks:
        same = np.allclose(stored, drawn, rtol=1e-9, atol=0) if not isinstance(stored, str) else stored == drawn
        if not same:
            raise CounterfactualError(f"{where}: the scenario drawn again from the shard's config and seed {ws.seed} "
                                      f"differs from the world state at '{key}': stored {stored!r}, drawn {drawn!r} "
                                      "(shards from another generator version?)")  # fmt: skip
    return scenario, gen


def _bounding_spheres(scenario) -> dict[int, tuple[np.ndarray, float]]:
    """object id -> (world centre, radius) of its bounding sphere at t = 0 (the placement test's spheres)."""
    from data_gen.assets.registry import get_object
    from newtphys.rotations import quat_to_matrix

    out = {}
    for p in scenario.objects:
        lo, hi = np.asarray(get_object(p.asset, size_m=p.size_m).shape.bounds(), np.float64)
        centre = np.asarray(p.position_m) + quat_to_matrix(np.asarray(p.orientation_wxyz)) @ (0.5 * (lo + hi))
        out[p.object_id] = (centre, 0.5 * float(np.linalg.norm(hi - lo)))
    return out


def shift_vector(view: SequenceView, scenario, object_id: int, distance_m: float) -> tuple[np.ndarray, str]:
    """The horizontal shift of ``object_id`` along the first camera's right (else left) axis whose bounding
    sphere stays clear of the other objects' and of the scene; raises NotAnswerable when both are blocked."""
    from data_gen.assets.registry import get_scene_layout

    right = view.camera_axes(0)[1].copy()
    right[2] = 0.0
    right /= np.linalg.norm(right)
    spheres = _bounding_spheres(scenario)
    centre, radius = spheres[object_id]
    layout = get_scene_layout(scenario.scene)
    for side, sign in (("right", 1.0), ("left", -1.0)):
        d = sign * distance_m * right
        moved = centre + d
        clear = all(np.linalg.norm(moved - c) > radius + r for i, (c, r) in spheres.items() if i != object_id)
        if clear and float(layout.sdf(moved[None])[0]) > radius:
            return d, side
    raise NotAnswerable("shift_blocked")


def twin_view(view: SequenceView, scenario, gen, change: str, object_id: int | None, amount: Any, device: str,
              twin_dir: Path) -> SequenceView:
    """The counterfactual twin (``counterfactual(scenario, change, object_id, amount)``) simulated and rendered
    with the shard's quality preset on ``device``, its world state kept in ``twin_dir`` (and read from there
    when the same change was simulated before); NotAnswerable when the pipeline rejects it. The twin shares
    the factual camera path, so the view uses the factual intrinsics and extrinsics."""
    from data_gen.pipeline import SequenceRejected, generate_sequence
    from data_gen.scenario import ScenarioError, counterfactual

    twin = counterfactual(scenario, change, amount=amount, **({} if object_id is None else {"object_id": object_id}))
    record_path = twin_dir / f"{twin.sequence_id}.json"
    how = {"change": change, "amount": amount, "object": object_id}
    if record_path.is_file() and (kept := json.loads(record_path.read_text()))["counterfactual"] == how:
        ws = WorldState.from_dict(kept["world_state"])
    else:
        settings = dataclasses.replace(gen.render, device=device, min_visible_objects=0)  # the twin is never shown
        t0 = time.perf_counter()
        try:
            seq, _ = generate_sequence(twin, gen.quality, settings, gen.skinning_cache_dir)
        except (SequenceRejected, ScenarioError) as e:
            raise NotAnswerable(f"twin_rejected_{getattr(e, 'reason', 'scenario')}") from None
        log.info("%s: %s twin simulated in %.1f s", view.sequence_id, change, time.perf_counter() - t0)
        ws = seq.world_state
        twin_dir.mkdir(parents=True, exist_ok=True)
        tmp = record_path.with_name(record_path.name + f".tmp{os.getpid()}")
        tmp.write_text(json.dumps({"counterfactual": how, "world_state": ws.to_dict()}, sort_keys=True))
        tmp.replace(record_path)
    return SequenceView.from_arrays(ws, view.K, view.world_to_camera, view.shard, view.shard_relative)


# -- wording ----------------------------------------------------------------------------------------------
def _times(x: float) -> str:
    return f"{x:.3g}"


def premise(change: str, amount: Any, name: str | None, side: str = "") -> str:
    if change == "gravity":
        strength = f"{_times(1.0 / amount)} times weaker" if amount < 1 else f"{_times(amount)} times stronger"
        return f"Suppose gravity had been {strength} from the start, with everything else the same."
    if change == "shift":
        d = float(np.linalg.norm(amount))
        return (f"Suppose the {name} had started {d:.2f} m further to the {side} (as seen from the camera at the "
                "start), with everything else the same.")  # fmt: skip
    size = "half as large" if amount == 0.5 else f"{_times(amount)} times as large"
    return f"Suppose the {name} had been {size} in every direction (same material), with everything else the same."


def cf_text(q: CfQuestion, record: dict[str, Any], view: SequenceView, premise_text: str) -> str:
    frame = record["frames"][-1]
    names = [view.name(o) for o in record["objects"]]
    fps = view.world_state.fps
    clause = q.clause.format(a=names[0], b=names[1] if len(names) > 1 else "", t0=multi_window(frame)[0] / fps,
                             t1=frame / fps)  # fmt: skip
    multi = record["mode"] == "multi"
    lead = "The frames show, in order, what actually happened." if multi else "The image shows what actually happened."
    moment = (" at the moment of the last frame" if multi else " at the moment the image was taken") if q.at_moment else ""
    return f"{lead} {premise_text} In that case, {clause}{moment}?"


# -- the variants -------------------------------------------------------------------------------------------
def _changed(q: CfQuestion, factual: float, cf: float) -> float | None:
    """Relative change when significant (threshold and a different formatted answer), else None."""
    if fmt(factual, q.decimals) == fmt(cf, q.decimals):
        return None
    rel = abs(cf - factual) / abs(factual) if factual != 0 else float("inf")
    return rel if rel >= q.threshold else None


def _make(name: str, change: str) -> None:
    @variant(name)
    def make(inputs: VariantInputs, records: list[dict[str, Any]]) -> VariantOutput:
        out = VariantOutput()
        view, settings = inputs.view, inputs.counterfactual
        candidates = [r for r in records if r["question_id"] in CF_QUESTIONS]
        target: int | None = None
        if change != "gravity":
            named = sorted({o for r in candidates for o in r["named"]})
            if not named:
                return out
            target = named[int(np.random.default_rng(seed_of(inputs.seed, view.sequence_id, name)).integers(len(named)))]
            candidates = [r for r in candidates if view.nameable(r["frames"][-1], target)]
        if not candidates:
            return out
        if "factual" not in inputs.memo:
            inputs.memo["factual"] = factual_scenario(view)
        scenario, gen = inputs.memo["factual"]
        side = ""
        try:
            if change == "gravity":
                amount: Any = settings.gravity_scale
            elif change == "shift":
                vector, side = shift_vector(view, scenario, target, settings.shift_m)
                amount = vector.tolist()
            else:
                amount = settings.resize_factor
            twin = twin_view(view, scenario, gen, change, target, amount, settings.device, inputs.twin_dir)
        except NotAnswerable as e:
            out.skips[e.reason] += len(candidates)
            return out
        premise_text = premise(change, amount, None if target is None else view.name(target), side)
        for r in candidates:
            q = CF_QUESTIONS[r["question_id"]]
            frame, asked = r["frames"][-1], tuple(r["objects"])
            factual, cf = q.value(view, frame, asked), q.value(twin, frame, asked)
            rel = _changed(q, factual, cf)
            if rel is None:
                out.skips["change_below_threshold"] += 1
                continue
            rng = np.random.default_rng(seed_of(inputs.seed, r["pair"], name))
            answer, factual_text = fmt(cf, q.decimals, q.unit_text), fmt(factual, q.decimals, q.unit_text)
            try:
                distractors = [d for d in numeric_distractors(cf, q.decimals, q.unit_text, rng) if d != factual_text]
            except NotAnswerable as e:
                out.skips[e.reason] += 1
                continue
            distractors = [factual_text, *distractors][:3]
            qid = vs.COUNTERFACTUAL_PREFIX + r["question_id"]
            record = derive(
                r, name, question_id=qid, question=cf_text(q, r, view, premise_text), correct=answer,
                distractors=distractors, value=float(cf), unit=q.unit,  # unrounded: the answer text is fmt(value)
                objects=list(dict.fromkeys([*asked, *([] if target is None else [target])])),
                meta={**r["meta"], "counterfactual": {"change": change, "amount": amount, "object": target,
                                                      "factual_value": float(factual),
                                                      "relative_change": round(rel, 4) if np.isfinite(rel) else None}},
                order_key=seed_of(inputs.seed, r["pair"], name),
            )  # fmt: skip
            record["letter_pair"] = record["pair"]  # a question of its own: its own balanced letters
            out.records.append(record)
        return out


for _name, _change in CHANGES.items():
    _make(_name, _change)
