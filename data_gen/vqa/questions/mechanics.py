"""Mechanics: speed, acceleration, displacement, stability and collisions."""

from __future__ import annotations

import numpy as np

from data_gen.vqa.questions.registry import Context, question
from data_gen.vqa.rules import NotAnswerable, Question, fmt, multi_window, numeric_distractors, pick

STABLE_LAST_FRAMES = 20
"""The scene counts as at rest only in the final 20 frames of a sequence ..."""
STABLE_SPEED_M_S = 0.05
"""... when every object moves slower than this."""
STABILITY_LABELS = ("Everything has come to rest.", "Objects are still moving or settling.",
                    "Objects are speeding up.", "Nothing has moved at any time.")  # fmt: skip


@question("F_KINEMATICS_SPEED_OBJECT")
def speed(ctx: Context) -> Question:
    target = ctx.target()
    v = float(np.linalg.norm(ctx.view.velocity(ctx.frame, target)))
    return Question(f"How fast is the {ctx.name(target)} moving?", fmt(v, 2, "m/s"),
                    numeric_distractors(v, 2, "m/s", ctx.rng), round(v, 4), "m/s", (target,), f"{target}")


@question("F_KINEMATICS_ACCEL_OBJECT")
def acceleration(ctx: Context) -> Question:
    target = ctx.target()
    a = float(np.linalg.norm(ctx.view.acceleration(ctx.frame, target)))
    return Question(f"What is the magnitude of the acceleration of the {ctx.name(target)}?", fmt(a, 2, "m/s²"),
                    numeric_distractors(a, 2, "m/s²", ctx.rng), round(a, 4), "m/s^2", (target,), f"{target}")


@question("F_KINEMATICS_DISTANCE_TRAVELED_INTERVAL")
def displacement(ctx: Context) -> Question:
    target = ctx.target()
    first = multi_window(ctx.frame)[0]
    d = float(np.linalg.norm(ctx.view.position(ctx.frame, target) - ctx.view.position(first, target)))
    fps = ctx.view.world_state.fps
    return Question(
        f"How far did the centre of the {ctx.name(target)} move, in a straight line, between {first / fps:.2f} s and "
        f"{ctx.frame / fps:.2f} s?",
        fmt(d, 1, "m"), numeric_distractors(d, 1, "m", ctx.rng), round(d, 4), "m", (target,), f"{target}",
    )  # fmt: skip


@question("F_KINEMATICS_SYSTEM_STABILITY")
def stability(ctx: Context) -> Question:
    ids = ctx.view.object_ids
    fastest = max(float(np.linalg.norm(ctx.view.velocity(ctx.frame, i))) for i in ids)
    at_rest = ctx.frame >= ctx.view.num_frames - STABLE_LAST_FRAMES and fastest < STABLE_SPEED_M_S
    label = STABILITY_LABELS[0] if at_rest else STABILITY_LABELS[1]
    others = tuple(lab for lab in STABILITY_LABELS if lab != label)
    return Question("At the last frame, is the scene still settling or at rest?", label, others, bool(at_rest), "",
                    tuple(ids), "stability", meta={"fastest_m_s": round(fastest, 4)})  # fmt: skip


def _first_contact(ctx: Context, with_scene: bool) -> tuple[int, int, int]:
    """(frame, a, b) of the first object-object (or object-scene) contact onset whose objects are visible."""
    for ev in sorted(ctx.view.world_state.collisions, key=lambda e: (e.frame, e.objects)):
        a, b = ev.objects
        if (b == 0) != with_scene:
            continue
        if ctx.view.visible(ev.frame, a) and (with_scene or ctx.view.visible(ev.frame, b)):
            return ev.frame, a, b
    raise NotAnswerable("no_visible_contact")


@question("F_COLLISION_OBJECT_OBJECT_FRAME_SINGLE")
def collision_partner(ctx: Context) -> Question:
    frame, a, b = _first_contact(ctx, with_scene=False)
    touching = {c for i in (a, b) for c in ctx.view.state(frame, i).contacts} | {a, b}
    if len(touching - {0}) > 2:
        raise NotAnswerable("more_than_two_objects_in_contact")
    named, other = (a, b) if ctx.rng.random() < 0.5 else (b, a)
    if not (ctx.view.nameable(frame, named) and ctx.view.name(other)):
        raise NotAnswerable("contact_objects_not_nameable")
    pool = [ctx.view.name(i) for i in ctx.view.visible_ids(frame) if i not in touching and ctx.view.name(i)]
    distractors = list(pick(pool, [], ctx.rng, min(3, len(pool)))) if pool else []
    if len(distractors) < 3:
        distractors += pick(ctx.library_names_not_in_scene(), distractors + [ctx.name(other)], ctx.rng,
                            3 - len(distractors))  # fmt: skip
    return Question(f"Which object is the {ctx.name(named)} touching?", ctx.name(other), tuple(distractors), other, "",
                    (named, other), f"contact-{a}-{b}", shown_frames=(frame,))  # fmt: skip


def _contact_frame_question(ctx: Context, with_scene: bool) -> Question:
    frame, a, b = _first_contact(ctx, with_scene)
    shown = [frame - 8, frame - 6, frame - 4, frame - 2]
    if shown[0] < 0:
        raise NotAnswerable("contact_too_early")
    far = [t for t in range(ctx.view.num_frames) if abs(t - frame) >= 4 and t not in shown and t > shown[-1]]
    if len(far) < 3:
        raise NotAnswerable("too_few_distractor_frames")
    distractor_frames = tuple(int(t) for t in ctx.rng.choice(far, size=3, replace=False))
    if with_scene:
        text = f"Which frame shows the moment the {ctx.name(a)} first touches the floor or the scene?"
        objects: tuple[int, ...] = (a,)
    else:
        text = f"Which frame shows the moment the {ctx.name(a)} and the {ctx.name(b)} first touch?"
        objects = (a, b)
    return Question(text, f"frame {frame}", tuple(f"frame {t}" for t in distractor_frames), frame, "frame", objects,
                    f"contact-{a}-{b}", option_frames=(frame, *distractor_frames), shown_frames=tuple(shown))  # fmt: skip


@question("F_COLLISION_OBJECT_OBJECT_FRAME_MULTI")
def collision_frame(ctx: Context) -> Question:
    return _contact_frame_question(ctx, with_scene=False)


@question("F_COLLISION_OBJECT_SCENE_FRAME_MULTI")
def scene_contact_frame(ctx: Context) -> Question:
    return _contact_frame_question(ctx, with_scene=True)
