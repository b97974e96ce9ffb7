"""Spatial reasoning: distances between boxes and to the camera, sizes, image layout."""

from __future__ import annotations

import numpy as np

from data_gen.vqa.questions.registry import Context, question
from data_gen.vqa.rules import NotAnswerable, Question, fmt, numeric_distractors, pick
from data_gen.vqa.view import box_distance

UNIQUE_GAP = 1.2
"""A nearest/largest answer must beat the runner-up by this factor (and UNIQUE_MARGIN_M for distances)."""
UNIQUE_MARGIN_M = 0.02
RELATIONS = ("to the left of", "to the right of", "above", "below", "in front of", "behind")


def _two(ctx: Context) -> tuple[int, int]:
    ids = ctx.view.nameable_ids(ctx.frame)
    if len(ids) < 2:
        raise NotAnswerable("fewer_than_two_nameable")
    a, b = (int(i) for i in ctx.rng.choice(ids, size=2, replace=False))
    return a, b


def _unique_min(values: dict[int, float], reason: str) -> int:
    ranked = sorted(values.items(), key=lambda kv: kv[1])
    if len(ranked) < 2:
        raise NotAnswerable("fewer_than_two_visible")
    (best, d0), (_, d1) = ranked[0], ranked[1]
    if d1 < UNIQUE_GAP * d0 + UNIQUE_MARGIN_M:
        raise NotAnswerable(reason)
    return best


@question("F_DISTANCE_OBJECT_OBJECT")
def distance_object_object(ctx: Context) -> Question:
    a, b = _two(ctx)
    d = box_distance(ctx.view.box(ctx.frame, a), ctx.view.box(ctx.frame, b))
    return Question(
        f"What is the shortest distance between the {ctx.name(a)} and the {ctx.name(b)}, measured between their "
        "bounding boxes?",
        fmt(d, 2, "m"), numeric_distractors(d, 2, "m", ctx.rng), round(d, 4), "m", (a, b), f"{a}-{b}",
    )  # fmt: skip


@question("F_CLOSEST_OBJECT_OBJECT")
def closest_object_object(ctx: Context) -> Question:
    target = ctx.target()
    others = [i for i in ctx.view.nameable_ids(ctx.frame) if i != target]
    if len(others) < 2:
        raise NotAnswerable("fewer_than_two_other_nameable")
    box = ctx.view.box(ctx.frame, target)
    near = _unique_min({i: box_distance(box, ctx.view.box(ctx.frame, i)) for i in others}, "closest_not_unique")
    return Question(
        f"Which object is closest to the {ctx.name(target)}?",
        ctx.name(near), ctx.name_distractors([near], exclude_ids=[target]), near, "", (target, near), f"{target}",
    )


@question("F_DISTANCE_OBJECT_CAMERA_DISTANCE")
def distance_object_camera(ctx: Context) -> Question:
    target = ctx.target()
    d = ctx.view.box(ctx.frame, target).distance_to_point(ctx.view.camera_center(ctx.frame))
    return Question(
        f"How far is the {ctx.name(target)} from the camera?",
        fmt(d, 2, "m"), numeric_distractors(d, 2, "m", ctx.rng), round(d, 4), "m", (target,), f"{target}",
    )


@question("F_CLOSEST_OBJECT_CAMERA")
def closest_object_camera(ctx: Context) -> Question:
    ids = ctx.view.nameable_ids(ctx.frame)
    eye = ctx.view.camera_center(ctx.frame)
    near = _unique_min({i: ctx.view.box(ctx.frame, i).distance_to_point(eye) for i in ids}, "closest_not_unique")
    return Question(
        "Which object is closest to the camera?",
        ctx.name(near), ctx.name_distractors([near]), near, "", (near,), "camera",
    )


def _size_text(extents: np.ndarray) -> str:
    a, b, c = sorted((float(e) for e in extents), reverse=True)
    return f"{a:.2f} m x {b:.2f} m x {c:.2f} m"


@question("F_SIZE_OBJECT")
def size_object(ctx: Context) -> Question:
    target = ctx.target()
    extents = ctx.view.box(ctx.frame, target).extents_m
    answer = _size_text(extents)
    texts = [t for t in (_size_text(extents * f) for f in ctx.rng.permutation([0.4, 0.6, 0.75, 1.4, 1.8, 2.5]))
             if t != answer]  # fmt: skip
    if len(set(texts)) < 3:
        raise NotAnswerable("too_few_numeric_distractors")
    return Question(
        f"What are the dimensions of the {ctx.name(target)}, largest first?",
        answer, tuple(dict.fromkeys(texts))[:3], sorted(extents.round(4).tolist(), reverse=True), "m", (target,),
        f"{target}",
    )  # fmt: skip


@question("F_SIZE_OBJECT_BIGGER")
def size_object_bigger(ctx: Context) -> Question:
    ids = ctx.view.nameable_ids(ctx.frame)
    if len(ids) < 2:
        raise NotAnswerable("fewer_than_two_nameable")
    volumes = {i: -ctx.view.box(ctx.frame, i).volume_m3 for i in ids}
    ranked = sorted(volumes.items(), key=lambda kv: kv[1])
    if -ranked[1][1] * 1.1 > -ranked[0][1]:
        raise NotAnswerable("largest_not_unique")
    big = ranked[0][0]
    return Question(
        "Which object is the largest (by the volume of its bounding box)?",
        ctx.name(big), ctx.name_distractors([big]), big, "", tuple(ids), "largest",
    )


@question("F_LAYOUT_POSITION_OBJECT_OBJECT")
def layout_position(ctx: Context) -> Question:
    a, b = _two(ctx)
    (ra, da), (rb, db) = (_screen_rect(ctx, i) for i in (a, b))
    overlap = not (ra[2] < rb[0] or rb[2] < ra[0] or ra[3] < rb[1] or rb[3] < ra[1])
    if overlap:
        if abs(da - db) < 0.05:
            raise NotAnswerable("depth_too_close")
        relation = "in front of" if da < db else "behind"
    else:
        ca, cb = 0.5 * (ra[:2] + ra[2:]), 0.5 * (rb[:2] + rb[2:])
        dx, dy = ca - cb
        if max(abs(dx), abs(dy)) < 1.2 * min(abs(dx), abs(dy)):
            raise NotAnswerable("direction_ambiguous")
        if abs(dx) > abs(dy):
            relation = "to the left of" if dx < 0 else "to the right of"
        else:
            relation = "above" if dy < 0 else "below"
    return Question(
        f"In the image, where is the {ctx.name(a)} relative to the {ctx.name(b)}?",
        relation, pick([r for r in RELATIONS if r != relation], [relation], ctx.rng), relation, "", (a, b), f"{a}-{b}",
    )  # fmt: skip


def _screen_rect(ctx: Context, object_id: int) -> tuple[np.ndarray, float]:
    """Image rectangle (x0, y0, x1, y1) px of an object's projected box and its centre's depth, m."""
    box = ctx.view.box(ctx.frame, object_id)
    uv, z = ctx.view.project(ctx.frame, box.corners())
    if (z <= 0).any():
        raise NotAnswerable("behind_camera")
    _, depth = ctx.view.project(ctx.frame, box.center_m[None])
    return np.concatenate([uv.min(axis=0), uv.max(axis=0)]), float(depth[0])
