"""Persistence: objects entering or leaving view, and counting objects over a clip."""

from __future__ import annotations

from data_gen.vqa.questions.registry import Context, question
from data_gen.vqa.rules import NotAnswerable, Question, integer_question, multi_window, pick


def _visibility(ctx: Context) -> tuple[list[int], dict[int, list[bool]]]:
    window = multi_window(ctx.frame)
    return window, {i: [ctx.view.visible(t, i) for t in window] for i in ctx.view.object_ids}


@question("F_PERSISTENCE_OBJECT_PRESENT")
def visibility_changes(ctx: Context) -> Question:
    _, seen = _visibility(ctx)
    changing = [i for i, flags in seen.items() if len(set(flags)) > 1 and ctx.view.name(i)]
    if len(changing) != 1:
        raise NotAnswerable("no_unique_changing_object" if changing else "no_changing_object")
    target = changing[0]
    return Question("Which object appears or disappears during these frames?", ctx.name(target),
                    pick(ctx.library_names_not_in_scene(), [ctx.name(target)], ctx.rng), target, "", (target,),
                    "present")  # fmt: skip


@question("F_PERSISTENCE_OBJECT_DISAPPEAR")
def leaves_view(ctx: Context) -> Question:
    _, seen = _visibility(ctx)
    gone = [i for i, flags in seen.items() if flags[0] and not flags[-1] and ctx.view.name(i)]
    if len(gone) != 1:
        raise NotAnswerable("no_unique_disappearing_object" if gone else "no_disappearing_object")
    target = gone[0]
    return Question("Which object is visible at the start but no longer visible by the last frame?", ctx.name(target),
                    ctx.name_distractors([target]), target, "", (target,), "disappear")  # fmt: skip


@question("F_PERSISTENCE_TOTAL_COUNT")
def total_count(ctx: Context) -> Question:
    _, seen = _visibility(ctx)
    ever = sorted(i for i, flags in seen.items() if any(flags))
    if not ever:
        raise NotAnswerable("nothing_visible")
    return integer_question("How many different objects can be seen over all these frames?", len(ever), tuple(ever),
                            "total")


@question("F_PERSISTENCE_TOTAL_COUNT_HIDDEN")
def hidden_count(ctx: Context) -> Question:
    _, seen = _visibility(ctx)
    ever = {i for i, flags in seen.items() if any(flags)}
    now = {i for i, flags in seen.items() if flags[-1]}
    return integer_question("How many of the objects seen over these frames are not visible in the last frame?",
                            len(ever - now), tuple(sorted(ever)), "hidden")
