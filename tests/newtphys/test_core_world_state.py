"""World-state JSON: exact round trip, precise errors, physical validation."""

from __future__ import annotations

import json

import pytest

from newtphys.world_state import WorldState, WorldStateError
from tests.fixtures.synthetic_scene import render_fixture_sequence


@pytest.fixture(scope="module")
def state() -> WorldState:
    return render_fixture_sequence("seq-a", "train", seed=3, num_frames=3, image_size=(8, 8))[3]


def test_round_trip_is_exact(state: WorldState) -> None:
    text = state.to_json()
    back = WorldState.from_json(text)
    assert back == state
    assert back.to_json() == text
    assert isinstance(back.image_size, tuple) and back.image_size == (8, 8)
    assert back.objects[0].mass == pytest.approx(state.objects[0].density * state.objects[0].volume, rel=1e-12)


def test_added_fields_are_kept(state: WorldState) -> None:
    data = json.loads(state.to_json())
    data["objects"][0]["initial_speed"] = 1.5
    data["simulation"]["cubature_total"] = 300
    data["scene"]["layout"] = {"boxes": 2}
    back = WorldState.from_dict(data)
    assert back.objects[0].extra == {"initial_speed": 1.5}
    assert back.simulation.extra == {"cubature_total": 300}
    assert json.loads(back.to_json()) == data


@pytest.mark.parametrize(
    "mutate, key, phrase",
    [
        (lambda d: d["objects"][1].pop("mass"), "objects[1].mass", "missing"),
        (lambda d: d.__setitem__("fps", "25"), "fps", "expected a number, got '25'"),
        (lambda d: d.__setitem__("num_frames", 2.0), "num_frames", "expected an integer"),
        (lambda d: d["objects"][0].__setitem__("poisson_ratio", 0.5), "objects[0].poisson_ratio", "[0, 0.5)"),
        (lambda d: d["objects"][0].__setitem__("young_modulus", -1.0), "objects[0].young_modulus", "must be > 0"),
        (lambda d: d["frames"][1]["objects"][0].__setitem__("id", 9), "frames[1].objects[0].id", "not in 'objects'"),
        (lambda d: d["frames"][0]["camera"].__setitem__("rotation", [1, 1, 0, 0]), "frames[0].camera.rotation", "unit norm"),
        (lambda d: d.__setitem__("gravity", [0, 0]), "gravity", "expected 3 items, got 2"),
        (lambda d: d["frames"].pop(), "frames", "num_frames is 3"),
        (lambda d: d["collisions"][0].__setitem__("objects", [1, 7]), "collisions[0].objects", "unknown object ids [7]"),
        (lambda d: d.__setitem__("schema_version", 0), "schema_version", "unsupported version 0"),
    ],
)
def test_errors_name_sequence_and_key(state: WorldState, mutate, key: str, phrase: str) -> None:
    data = json.loads(state.to_json())
    mutate(data)
    with pytest.raises(WorldStateError) as info:
        WorldState.from_dict(data)
    msg = str(info.value)
    assert "sequence 'seq-a'" in msg
    assert f"key '{key}'" in msg
    assert phrase in msg


def test_non_finite_and_bad_json_rejected(state: WorldState) -> None:
    text = state.to_json().replace('"fps": 25.0', '"fps": NaN')
    with pytest.raises(WorldStateError, match="finite"):
        WorldState.from_json(text)
    with pytest.raises(WorldStateError, match="not valid JSON"):
        WorldState.from_json("{", sequence_id="x")
