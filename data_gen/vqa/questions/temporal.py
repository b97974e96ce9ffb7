"""Temporal: ordering frames, predicting the next / previous / missing frame, camera motion and zoom."""

from __future__ import annotations

import itertools

import numpy as np

from data_gen.vqa.questions.registry import Context, question
from data_gen.vqa.rules import NotAnswerable, Question, label_options, multi_window, pick

MOTION_M = 0.02
"""Frames only make an ordering question when something (an object or the camera) moves this much."""
DISTRACTOR_MIN_GAP = 4
"""Distractor frames lie at least this many frames from the answer and outside the shown frames."""
CAMERA_DEAD_ZONE_M = 0.05
DIRECTIONS = {"forward": (0, 1), "backward": (0, -1), "right": (1, 1), "left": (1, -1), "up": (2, 1), "down": (2, -1)}
ZOOM_LABELS = ("The camera zooms in.", "The camera zooms out.", "The zoom does not change.",
               "The camera zooms in, then out.")  # fmt: skip
ZOOM_DEG = 5.0


def _moves(ctx: Context, first: int, last: int) -> bool:
    v = ctx.view
    objects = max((float(np.linalg.norm(v.position(last, i) - v.position(first, i))) for i in v.object_ids), default=0)
    camera = float(np.linalg.norm(v.camera_center(last) - v.camera_center(first)))
    return max(objects, camera) >= MOTION_M


def _image_question(ctx: Context, text: str, answer: int, shown: list[int], key: str) -> Question:
    if min(shown) < 0 or not 0 <= answer < ctx.view.num_frames:
        raise NotAnswerable("frames_out_of_range")
    if not _moves(ctx, min(shown + [answer]), max(shown + [answer])):
        raise NotAnswerable("nothing_moves")
    far = [t for t in range(ctx.view.num_frames) if abs(t - answer) >= DISTRACTOR_MIN_GAP and
           not min(shown) <= t <= max(shown)]  # fmt: skip
    if len(far) < 3:
        raise NotAnswerable("too_few_distractor_frames")
    distractors = tuple(int(t) for t in ctx.rng.choice(far, size=3, replace=False))
    return Question(text, f"frame {answer}", tuple(f"frame {t}" for t in distractors), answer, "frame", (), key,
                    option_frames=(answer, *distractors), shown_frames=tuple(shown))  # fmt: skip


@question("F_TEMPORAL_SEQUENCE_IMAGES")
def order_frames(ctx: Context) -> Question:
    window = multi_window(ctx.frame, 4)
    if not _moves(ctx, window[0], window[-1]):
        raise NotAnswerable("nothing_moves")
    order = [int(i) for i in ctx.rng.permutation(4)]
    shown = tuple(window[i] for i in order)
    # answer: the images' numbers (1-4, as shown) in the order the frames happened
    answer = "-".join(str(order.index(i) + 1) for i in range(4))
    perms = ["-".join(str(k) for k in p) for p in itertools.permutations((1, 2, 3, 4))]
    return Question("The four images are shown out of order, numbered 1 to 4 as shown. In which order were they "
                    "taken?", answer, pick(perms, [answer], ctx.rng), answer, "", (), "order", shown_frames=shown)


def _next(ctx: Context, stride: int) -> Question:
    shown = [ctx.frame - (3 - i) * stride for i in range(4)]
    return _image_question(ctx, "Which image comes next, continuing the sequence at the same pace?",
                           ctx.frame + stride, shown, f"next-{stride}")


@question("F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_1")
def next_1(ctx: Context) -> Question:
    return _next(ctx, 1)


@question("F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_2")
def next_2(ctx: Context) -> Question:
    return _next(ctx, 2)


@question("F_TEMPORAL_PREDICTION_NEXT_IMAGE_GRANULARITY_5")
def next_5(ctx: Context) -> Question:
    return _next(ctx, 5)


@question("F_TEMPORAL_PREDICTION_PREVIOUS_IMAGE")
def previous(ctx: Context) -> Question:
    stride = 2
    shown = [ctx.frame - (3 - i) * stride for i in range(4)]
    return _image_question(ctx, "Which image came just before these, at the same pace?", shown[0] - stride, shown,
                           "previous")


@question("F_TEMPORAL_PREDICTION_MISSING_IMAGE")
def missing(ctx: Context) -> Question:
    stride = 2
    run = [ctx.frame - (4 - i) * stride for i in range(5)]
    gap = int(ctx.rng.integers(1, 4))  # one of the three inner frames is removed
    shown = [t for i, t in enumerate(run) if i != gap]
    return _image_question(ctx, "One image is missing from this evenly spaced sequence. Which one?", run[gap], shown,
                           f"missing-{gap}")


def _direction(ctx: Context, a: int, b: int, frame: int) -> str:
    forward, right, up = ctx.view.camera_axes(frame)
    d = ctx.view.camera_center(b) - ctx.view.camera_center(a)
    along = np.array([d @ forward, d @ right, d @ up])
    axis = int(np.argmax(np.abs(along)))
    if abs(along[axis]) < CAMERA_DEAD_ZONE_M:
        raise NotAnswerable("camera_moves_too_little")
    sign = 1 if along[axis] > 0 else -1
    return next(name for name, (ax, s) in DIRECTIONS.items() if ax == axis and s == sign)


@question("F_CAMERA_MOTION_DIRECTION")
def camera_motion(ctx: Context) -> Question:
    window = multi_window(ctx.frame)
    mid = window[len(window) // 2]
    first, second = _direction(ctx, window[0], mid, window[0]), _direction(ctx, mid, window[-1], mid)
    answer = f"{first}, then {second}"
    labels = [f"{x}, then {y}" for x in DIRECTIONS for y in DIRECTIONS]
    return Question("How does the camera move over these frames (relative to where it points)?", answer,
                    pick(labels, [answer], ctx.rng), answer, "", (), "camera")


@question("F_CAMERA_ZOOM_BEHAVIOR")
def camera_zoom(ctx: Context) -> Question:
    window = multi_window(ctx.frame)
    fovs = np.array([ctx.view.fov_x_deg(t) for t in window])
    change = fovs[-1] - fovs[0]
    if change < -ZOOM_DEG:
        label = ZOOM_LABELS[0]
    elif change > ZOOM_DEG:
        label = ZOOM_LABELS[1]
    elif fovs.min() < fovs[0] - ZOOM_DEG:
        label = ZOOM_LABELS[3]
    else:
        label = ZOOM_LABELS[2]
    return Question("What does the camera's zoom do over these frames?", label, label_options(label, ZOOM_LABELS,
                    ctx.rng), round(float(change), 3), "deg", (), "zoom")  # fmt: skip
