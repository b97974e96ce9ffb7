"""Question variants on the shared push data: every variant changes exactly what it should (text, images or
both), keeps the base item's options and letter, and its marks sit where the object is (red ring around the
object's silhouette, black disc over it, 3 x 3 location word, cue numbers from the world state)."""

from __future__ import annotations

import functools
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from data_gen.vqa.cli import run as run_vqa
from data_gen.vqa.variants.cues import approx_mass_kg, mass_approx_text
from data_gen.vqa.variants.levels import LEVEL_TEXTS, LEVELS
from data_gen.vqa.variants.referring import REFERENCES
from newtphys import schema
from newtphys import vqa_schema as vs
from newtphys.shards import ShardReader
from newtphys.vqa_validate import validate_question_set
from tests.data_gen.conftest import compose_vqa

IMAGE_AND_TEXT_VARIANTS = [v for v in vs.VARIANTS if not v.startswith(vs.COUNTERFACTUAL_VARIANT_PREFIX)]
# which item fields each variant may change (everything else equals the base item's)
CHANGES: dict[str, set[str]] = {
    "roi_circle": {"question", "images"}, "roi_circle_location": {"question", "images", "meta"},
    "roi_only": {"question", "images"}, "roi_location_only": {"question", "images", "meta"},
    "location": {"question", "meta"}, "location_only": {"question", "meta"},
    "roi_masked": {"images"}, "black_image": {"images"},
    "cue_duration": {"question", "meta"}, "cue_mass_exact": {"question", "meta"}, "cue_mass_approx": {"question", "meta"},
    **{level: {"question"} for level in LEVELS},
}  # fmt: skip


@pytest.fixture(scope="module")
def variant_set(push_data: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("vqa_variants")
    run_vqa(compose_vqa(push_data, out, "workers=1", f"variants=[{','.join(IMAGE_AND_TEXT_VARIANTS)}]"))
    return out / "test"


@pytest.fixture(scope="module")
def loaded(variant_set: Path):
    items = vs.read_items(variant_set)
    return items, vs.read_answers(variant_set), {i.idx: i for i in items}


def _base_idx(item: vs.QuestionItem) -> str:
    return f"{item.pair.removesuffix('/' + item.variant)}/{item.mode}"


def _rgb(set_dir: Path, path: str) -> np.ndarray:
    with Image.open(set_dir / path) as im:
        return np.asarray(im.convert("RGB"))


def _maps(push_data: Path, item: vs.QuestionItem, frame: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """(instance ids (H, W), amodal masks (N, H, W), object ids) of ``frame`` read from the shard."""
    return _read_maps(str(push_data / item.shard), item.sequence_id, frame)


@functools.cache
def _read_maps(shard: str, sequence_id: str, frame: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    with ShardReader(shard) as r:
        ids = [o.id for o in r.world_state(sequence_id).objects]
        return (r.read(sequence_id, schema.INSTANCES, frame, frame + 1)[0],
                r.read(sequence_id, schema.AMODAL_INSTANCES, frame, frame + 1)[0], ids)  # fmt: skip


@functools.cache
def _world_state(shard: str, sequence_id: str):
    with ShardReader(shard) as r:
        return r.world_state(sequence_id)


def test_every_variant_validates_changes_only_its_fields_and_keeps_the_base_letter(variant_set: Path, loaded) -> None:
    items, answers, by_idx = loaded
    assert validate_question_set(variant_set) == []
    counts = Counter(i.variant for i in items)
    assert set(counts) == set(IMAGE_AND_TEXT_VARIANTS), counts
    for item in items:
        if item.variant == vs.BASE_VARIANT:
            continue
        base = by_idx[_base_idx(item)]
        assert answers[item.idx].answer == answers[base.idx].answer and item.options == base.options, item.idx
        changed = {f for f in ("question", "images", "meta", "frames", "objects", "question_id", "category")
                   if getattr(item, f) != getattr(base, f)}  # fmt: skip
        assert changed <= CHANGES[item.variant], (item.idx, changed)
        if "question" in CHANGES[item.variant]:
            assert item.question != base.question, item.idx
    shares = Counter(answers[i.idx].answer for i in items)
    assert all(0.22 <= shares[k] / len(items) <= 0.28 for k in vs.LETTERS), shares
    for name in ("roi_circle", "roi_masked", "black_image", "cue_mass_exact"):  # letters balanced inside a variant
        letters = Counter(answers[i.idx].answer for i in items if i.variant == name)
        assert min(letters.values()) >= 0.18 * counts[name], (name, letters)


def test_seven_reference_combinations_word_the_object_as_they_should(loaded) -> None:
    items, _, by_idx = loaded
    assert len(REFERENCES) + 1 == 7  # with base (name only)
    seen = Counter()
    for item in items:
        if item.variant not in REFERENCES:
            continue
        ref, base, q = REFERENCES[item.variant], by_idx[_base_idx(item)], item.question
        assert ("(circled in red)" in q or "circled in red" in q) == ref.circle, q
        assert ("located at the " in q) == ref.location, q
        assert ("the object " in q) == (not ref.name), q
        assert any(f"/{vs.IMAGES_DIR}/roi_circle/" in f"/{p}" for p in item.images) == ref.circle, item.images
        if ref.name:  # the name stays where it was
            assert q.split(" (circled")[0].split(" located")[0] in base.question
        seen[item.variant] += 1
    assert set(seen) == set(REFERENCES) and len(set(seen.values())) == 1  # one item per base item each


def test_the_red_ring_surrounds_the_named_object_and_never_touches_it(variant_set: Path, push_data: Path, loaded) -> None:
    items, _, by_idx = loaded
    checked = 0
    for item in items:
        if item.variant != "roi_circle" or item.mode != "single":
            continue
        base, t, target = by_idx[_base_idx(item)], item.frames[-1], item.objects[0]
        _, amodal, ids = _maps(push_data, item, t)
        mask = amodal[ids.index(target)]
        before, after = _rgb(variant_set, base.images[0]), _rgb(variant_set, item.images[0])
        red = np.all(after == (255, 0, 0), axis=-1) & np.any(after != before, axis=-1)
        assert red.sum() > 0 and not (red & mask).any(), item.idx
        ys, xs = np.nonzero(mask)
        cy, cx = ys.mean() + 0.5, xs.mean() + 0.5  # a second path: the mask's centroid and farthest pixel
        reach = np.hypot(xs + 0.5 - cx, ys + 0.5 - cy).max() + 0.71
        ry, rx = np.nonzero(red)
        d = np.hypot(rx + 0.5 - cx, ry + 0.5 - cy)
        in_ring = (d >= reach) & (d <= 1.5 * 1.3 * reach + 3.0)
        assert in_ring.mean() >= 0.9, (item.idx, reach, np.percentile(d, [5, 50, 95]))
        outside = ~np.any(after != before, axis=-1) | red  # nothing but the ring changed
        assert outside.all(), item.idx
        checked += 1
    assert checked >= 10


def test_the_masked_disc_covers_the_object_and_only_around_it(variant_set: Path, push_data: Path, loaded) -> None:
    items, _, by_idx = loaded
    checked = 0
    for item in items:
        if item.variant != "roi_masked":
            continue
        base = by_idx[_base_idx(item)]
        target = item.objects[0]
        for k, t in enumerate(item.frames):
            _, amodal, ids = _maps(push_data, item, t)
            mask = amodal[ids.index(target)]
            if not mask.any():
                assert item.images[k] == base.images[k]  # out of view: the frame is shown as it was
                continue
            after, before = _rgb(variant_set, item.images[k]), _rgb(variant_set, base.images[k])
            assert (after[mask] == 0).all(), item.idx
            ys, xs = np.nonzero(mask)
            h, w = mask.shape
            yy, xx = np.mgrid[0:h, 0:w]
            far = np.hypot(xx - xs.mean(), yy - ys.mean()) > 2.0 * np.hypot(np.ptp(xs) + 1, np.ptp(ys) + 1)
            assert (after[far] == before[far]).all(), item.idx
            checked += 1
    assert checked >= 20


def test_location_word_is_the_grid_cell_of_the_visible_pixels(push_data: Path, loaded) -> None:
    items, _, _ = loaded
    words = [["top-left", "top", "top-right"], ["left", "centre", "right"], ["bottom-left", "bottom", "bottom-right"]]
    checked = 0
    for item in items:
        if item.variant != "location":
            continue
        instances, _, _ = _maps(push_data, item, item.frames[-1])
        ys, xs = np.nonzero(instances == item.objects[0])
        h, w = instances.shape
        word = words[min(int(3 * (ys.mean() + 0.5) / h), 2)][min(int(3 * (xs.mean() + 0.5) / w), 2)]
        where = "last frame" if item.mode == "multi" else "image"
        assert f"located at the {word} of the {where}" in item.question, (item.question, word)
        checked += 1
    assert checked >= 10


def test_cues_carry_the_world_state_numbers(push_data: Path, loaded) -> None:
    items, _, by_idx = loaded
    checked = Counter()
    for item in items:
        if not item.variant.startswith("cue_"):
            continue
        base = by_idx[_base_idx(item)]
        assert item.question.startswith(base.question + " ")
        ws = _world_state(str(push_data / item.shard), item.sequence_id)
        if item.variant == "cue_duration":
            assert item.mode == "multi" and item.sub_category == "kinematics"
            span = (item.frames[-1] - item.frames[0]) / ws.fps
            assert item.question.endswith(f"The images span {span:.2f} seconds.")
        else:
            assert item.sub_category != "mass"
            o = ws.object_by_id(item.objects[0])
            name = o.extra["display_name"]
            expected = (f"The {name} has a mass of {o.mass:.2f} kg." if item.variant == "cue_mass_exact"
                        else mass_approx_text(name, o.mass))  # fmt: skip
            assert item.question.endswith(expected), item.question
        checked[item.variant] += 1
    assert set(checked) == {"cue_duration", "cue_mass_exact", "cue_mass_approx"}, checked


def test_approximate_mass_rounds_to_half_a_kilogram() -> None:
    assert [approx_mass_kg(m) for m in (2.35, 2.2, 2.25, 0.74, 0.2)] == [2.5, 2.0, 2.5, 0.5, 0.0]
    assert mass_approx_text("mug", 2.35) == "The mug has a mass of about 2.5 kg."
    assert mass_approx_text("mug", 0.2) == "The mug has a mass of less than 0.25 kg."


def test_expertise_levels_reword_one_multi_frame_question_five_ways(push_data: Path, loaded) -> None:
    items, _, by_idx = loaded
    by_base: dict[str, dict[str, str]] = {}
    for item in items:
        if item.variant in LEVELS:
            assert item.mode == "multi" and item.question_id in LEVEL_TEXTS
            by_base.setdefault(_base_idx(item), {})[item.variant] = item.question
    assert by_base, "no level items"
    for base_idx, texts in by_base.items():
        assert set(texts) == set(LEVELS) and len(set(texts.values())) == 5
        base = by_idx[base_idx]
        assert base.question not in texts.values()
        if "{name}" in LEVEL_TEXTS[base.question_id][0]:  # a question naming its object names it at every level
            name = _world_state(str(push_data / base.shard), base.sequence_id).object_by_id(base.objects[0]).extra[
                "display_name"]
            assert name in base.question and all(f"the {name}" in t for t in texts.values()), (name, texts)


def test_black_images_are_black_and_replace_every_image(variant_set: Path, loaded) -> None:
    items, _, by_idx = loaded
    for item in items:
        if item.variant != "black_image":
            continue
        base = by_idx[_base_idx(item)]
        assert len(item.images) == len(base.images)
        for p, q in zip(item.images, base.images):
            assert p.startswith(f"{vs.IMAGES_DIR}/black_image/")
            img = _rgb(variant_set, p)
            assert img.shape == _rgb(variant_set, q).shape and not img.any()


def test_unknown_variant_is_an_error_naming_it(push_data: Path, tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"unknown variants \['roi_square'\]"):
        run_vqa(compose_vqa(push_data, tmp_path, "variants=[base,roi_square]"))
