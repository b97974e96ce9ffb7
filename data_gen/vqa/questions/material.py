"""Material understanding: mass, density, Young's modulus, Poisson ratio, material identity."""

from __future__ import annotations

import math

from data_gen.assets import material_taxonomy
from data_gen.vqa.questions.registry import Context, question
from data_gen.vqa.rules import (
    NotAnswerable, Question, fmt, label_options, modulus_distractors, modulus_text, numeric_distractors, pick,
)  # fmt: skip

MASS_GAP = 1.1
"""Heaviest/lightest: at least a 10 % gap to the runner-up."""
MODULUS_SIMILAR_LOG10 = 0.3
MODULUS_HIGHEST_LOG10_GAP = 0.2
POISSON_SIMILAR = 0.02
POISSON_HIGHEST_GAP = 0.02
STIFFNESS_BINS = ((1e8, "rigid"), (1e7, "flexible"), (1e5, "soft"), (0.0, "very soft"))
BIN_EDGE_MARGIN = 0.2
"""High-level stiffness: skip objects within 20 % of a bin edge."""
POISSON_BINS = ((0.1, "It hardly gets any wider."), (0.4, "It gets somewhat wider."),
                (0.5, "It bulges out a lot, keeping its volume."))  # fmt: skip
POISSON_WRONG = "It gets narrower."


def _prop(ctx: Context, object_id: int, key: str) -> float:
    return float(getattr(ctx.view.info(object_id), key))


def _ranked(ctx: Context, key: str, reverse: bool) -> list[tuple[int, float]]:
    ids = ctx.view.nameable_ids(ctx.frame)
    if len(ids) < 2:
        raise NotAnswerable("fewer_than_two_nameable")
    return sorted(((i, _prop(ctx, i, key)) for i in ids), key=lambda kv: kv[1], reverse=reverse)


def _meta(ctx: Context, object_id: int) -> dict:
    return {"young_modulus_pa": _prop(ctx, object_id, "young_modulus")}


@question("F_MASS_OBJECT")
def mass_object(ctx: Context) -> Question:
    target = ctx.target()
    m = _prop(ctx, target, "mass")
    return Question(f"What is the mass of the {ctx.name(target)}?", fmt(m, 2, "kg"),
                    numeric_distractors(m, 2, "kg", ctx.rng), round(m, 6), "kg", (target,), f"{target}",
                    meta=_meta(ctx, target))  # fmt: skip


@question("F_PHYSICS_PROPERTY_DENSITY_OBJECT")
def density_object(ctx: Context) -> Question:
    target = ctx.target()
    rho = _prop(ctx, target, "density")
    return Question(f"What is the density of the material the {ctx.name(target)} is made of?",
                    fmt(rho, 1, "kg/m³"), numeric_distractors(rho, 1, "kg/m³", ctx.rng), round(rho, 3), "kg/m^3",
                    (target,), f"{target}", meta=_meta(ctx, target))  # fmt: skip


def _extreme(ctx: Context, key: str, reverse: bool, gap: float, text: str, reason: str) -> Question:
    ranked = _ranked(ctx, key, reverse)
    (best, v0), (_, v1) = ranked[0], ranked[1]
    hi, lo = (v0, v1) if reverse else (v1, v0)
    if hi < gap * lo:
        raise NotAnswerable(reason)
    ids = tuple(i for i, _ in ranked)
    return Question(text, ctx.name(best), ctx.name_distractors([best]), best, "", ids, f"{key}-{reverse}",
                    meta=_meta(ctx, best))


@question("F_MASS_HEAVIEST_OBJECT")
def heaviest(ctx: Context) -> Question:
    return _extreme(ctx, "mass", True, MASS_GAP, "Which object is the heaviest?", "mass_gap_below_10_percent")


@question("F_MASS_LIGHTEST_OBJECT")
def lightest(ctx: Context) -> Question:
    return _extreme(ctx, "mass", False, MASS_GAP, "Which object is the lightest?", "mass_gap_below_10_percent")


@question("F_PHYSICS_PROPERTY_DENSITY_OBJECT_RELATIVE")
def densest(ctx: Context) -> Question:
    return _extreme(ctx, "density", True, MASS_GAP, "Which object is made of the densest material?",
                    "density_gap_below_10_percent")


@question("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_METRIC_PREFIX")
def modulus_value(ctx: Context) -> Question:
    target = ctx.target()
    e = _prop(ctx, target, "young_modulus")
    return Question(f"What is the Young's modulus of the {ctx.name(target)}?", modulus_text(e),
                    modulus_distractors(e, ctx.rng), e, "Pa", (target,), f"{target}", meta=_meta(ctx, target))


def _similar(ctx: Context, key: str, close: float, log: bool, text: str) -> Question:
    target = ctx.target()
    v = _prop(ctx, target, key)
    f = (lambda x: math.log10(x)) if log else (lambda x: x)
    others = [i for i in ctx.view.visible_ids(ctx.frame) if i != target]
    inside = [i for i in others if abs(f(_prop(ctx, i, key)) - f(v)) <= close]
    if len(inside) != 1:
        raise NotAnswerable("no_unique_similar_object" if inside else "no_similar_object")
    answer = inside[0]
    outside = [i for i in others if i not in inside]
    return Question(text.format(name=ctx.name(target)), ctx.name(answer),
                    ctx.name_distractors([answer], exclude_ids=[target, *inside]), answer, "", (target, answer),
                    f"{target}", meta=_meta(ctx, target) | {"band_outside": outside})  # fmt: skip


@question("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_SIMILAR")
def modulus_similar(ctx: Context) -> Question:
    return _similar(ctx, "young_modulus", MODULUS_SIMILAR_LOG10, True,
                    "Which object has a Young's modulus closest to that of the {name}?")


@question("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_SIMILAR_NON_TECHNICAL")
def modulus_similar_lay(ctx: Context) -> Question:
    return _similar(ctx, "young_modulus", MODULUS_SIMILAR_LOG10, True,
                    "Which object would feel about as stiff as the {name} if you pressed on it?")


def _top_by_difference(ctx: Context, key: str, gap: float, log: bool, reason: str, text: str) -> Question:
    """The visible object with the highest ``key``, ahead of the runner-up by ``gap`` (in log10 when ``log``)."""
    ranked = _ranked(ctx, key, True)
    scale = math.log10 if log else float
    if scale(ranked[0][1]) - scale(ranked[1][1]) < gap:
        raise NotAnswerable(reason)
    best = ranked[0][0]
    return Question(text, ctx.name(best), ctx.name_distractors([best]), best, "", tuple(i for i, _ in ranked),
                    f"{key}-highest", meta=_meta(ctx, best))  # fmt: skip


def _highest_log(ctx: Context, text: str) -> Question:
    return _top_by_difference(ctx, "young_modulus", MODULUS_HIGHEST_LOG10_GAP, True, "modulus_gap_below_0.2_decades",
                              text)


@question("F_PHYSICS_PROPERTY_YOUNG_MODULUS_HIGHEST")
def stiffest(ctx: Context) -> Question:
    return _highest_log(ctx, "Which object has the highest Young's modulus?")


@question("F_PHYSICS_PROPERTY_YOUNG_MODULUS_HIGHEST_NON_TECHNICAL")
def stiffest_lay(ctx: Context) -> Question:
    return _highest_log(ctx, "Which object is the hardest to squash?")


@question("F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_HIGH_LEVEL")
def stiffness_class(ctx: Context) -> Question:
    target = ctx.target()
    e = _prop(ctx, target, "young_modulus")
    for edge, _ in STIFFNESS_BINS[:-1]:
        if abs(e - edge) <= BIN_EDGE_MARGIN * edge:
            raise NotAnswerable("within_20_percent_of_a_bin_edge")
    label = next(lab for edge, lab in STIFFNESS_BINS if e >= edge)
    labels = [lab for _, lab in STIFFNESS_BINS]
    return Question(f"How stiff is the {ctx.name(target)}?", label, label_options(label, labels, ctx.rng), e, "Pa",
                    (target,), f"{target}", meta=_meta(ctx, target))  # fmt: skip


@question("F_PHYSICS_PROPERTY_POISSON_RATIO_OBJECT")
def poisson_value(ctx: Context) -> Question:
    target = ctx.target()
    nu = _prop(ctx, target, "poisson_ratio")
    answer = fmt(nu, 2)
    pool = [fmt(nu * k, 2) for k in (0.0, 1 / 3, 2 / 3, 4 / 3, 5 / 3, 2.0) if 0.04 < nu * k <= 0.5]
    return Question(f"What is the Poisson's ratio of the {ctx.name(target)}?", answer, pick(pool, [answer], ctx.rng),
                    round(nu, 4), "", (target,), f"{target}", meta=_meta(ctx, target))  # fmt: skip


@question("F_PHYSICS_PROPERTY_POISSON_RATIO_OBJECT_SIMILAR")
def poisson_similar(ctx: Context) -> Question:
    return _similar(ctx, "poisson_ratio", POISSON_SIMILAR, False,
                    "Which object has a Poisson's ratio closest to that of the {name}?")


@question("F_PHYSICS_PROPERTY_POISSON_RATIO_OBJECT_SIMILAR_NON_TECHNICAL")
def poisson_similar_lay(ctx: Context) -> Question:
    return _similar(ctx, "poisson_ratio", POISSON_SIMILAR, False,
                    "Squeezed from above, which object would bulge sideways about as much as the {name}?")


def _poisson_highest(ctx: Context, text: str) -> Question:
    return _top_by_difference(ctx, "poisson_ratio", POISSON_HIGHEST_GAP, False, "poisson_gap_below_0.02", text)


@question("F_PHYSICS_PROPERTY_POISSON_RATIO_HIGHEST")
def poisson_highest(ctx: Context) -> Question:
    return _poisson_highest(ctx, "Which object has the highest Poisson's ratio?")


@question("F_PHYSICS_PROPERTY_POISSON_RATIO_HIGHEST_NON_TECHNICAL")
def poisson_highest_lay(ctx: Context) -> Question:
    return _poisson_highest(ctx, "Pressed from above, which object would bulge out sideways the most?")


@question("F_PHYSICS_PROPERTY_POISSON_HIGH_LEVEL")
def poisson_class(ctx: Context) -> Question:
    target = ctx.target()
    nu = _prop(ctx, target, "poisson_ratio")
    label = next(lab for edge, lab in POISSON_BINS if nu <= edge)
    labels = [lab for _, lab in POISSON_BINS] + [POISSON_WRONG]
    return Question(f"If you squeeze the {ctx.name(target)} from top to bottom, what happens to its width?", label,
                    label_options(label, labels, ctx.rng), round(nu, 4), "", (target,), f"{target}",
                    meta=_meta(ctx, target))  # fmt: skip


def _taxonomy(ctx: Context, object_id: int) -> dict[str, str]:
    return ctx.view.info(object_id).extra["material_taxonomy"]


@question("F_MATERIAL_IDENTIFICATION_SIMILAR_OBJECT")
def material_similar(ctx: Context) -> Question:
    target = ctx.target()
    group = _taxonomy(ctx, target)["level_1"]
    others = [i for i in ctx.view.visible_ids(ctx.frame) if i != target]
    same = [i for i in others if _taxonomy(ctx, i)["level_1"] == group]
    if len(same) != 1:
        raise NotAnswerable("no_unique_same_group_object" if same else "no_same_group_object")
    return Question(f"Which object is made of the same kind of material as the {ctx.name(target)}?",
                    ctx.name(same[0]), ctx.name_distractors([same[0]], exclude_ids=[target]), same[0], "",
                    (target, same[0]), f"{target}", meta=_meta(ctx, target))  # fmt: skip


def _material_level(ctx: Context, level: int, text: str) -> Question:
    target = ctx.target()
    answer = _taxonomy(ctx, target)[f"level_{level}"]
    pool = material_taxonomy.level_names(level)
    if level == 3:  # the scene's own materials first
        scene = [m["level_3"] for m in ctx.view.world_state.scene.extra.get("materials", [])]
        pool = list(dict.fromkeys([*scene, *pool]))
    return Question(text.format(name=ctx.name(target)), answer, pick(pool, [answer], ctx.rng), answer, "",
                    (target,), f"{target}", meta=_meta(ctx, target))  # fmt: skip


@question("F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_1")
def material_level_1(ctx: Context) -> Question:
    return _material_level(ctx, 1, "Which broad family of materials is the {name} made of?")


@question("F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_2")
def material_level_2(ctx: Context) -> Question:
    return _material_level(ctx, 2, "What material is the {name} made of?")


@question("F_MATERIAL_IDENTIFICATION_OBJECT_LEVEL_3")
def material_level_3(ctx: Context) -> Question:
    return _material_level(ctx, 3, "Which specific material is the {name} made of?")
