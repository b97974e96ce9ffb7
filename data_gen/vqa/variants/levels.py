"""One question at five levels of expertise (``level_child`` ... ``level_expert``): the density-relative,
Young's-modulus and Poisson-ratio questions, multi-frame items only. Same images, options and letters as the
base item; only the question's wording changes (the multi-frame lead-in is kept)."""

from __future__ import annotations

from typing import Any

from data_gen.vqa.rules import MULTI_PREFIX
from data_gen.vqa.variants.registry import VariantInputs, VariantOutput, derive, variant

LEVELS = ("level_child", "level_teen", "level_undergrad", "level_graduate", "level_expert")

# question id -> one wording per level, in LEVELS order; "{name}" is the object the question names
LEVEL_TEXTS: dict[str, tuple[str, str, str, str, str]] = {
    "F_PHYSICS_PROPERTY_DENSITY_OBJECT_RELATIVE": (
        "If all of these things were made the same size, which one would be the heaviest?",
        "Which object is made of the stuff that packs the most mass into the same amount of space?",
        "Which object is made of the material with the highest mass density?",
        "Which object's material has the largest mass per unit volume, in kg/m³?",
        "Comparing the volumetric mass densities ρ = m/V of the objects' materials, which object has the largest ρ?",
    ),
    "F_PHYSICS_PROPERTY_YOUNG_MODULUS_HIGHEST": (
        "Which thing would be the hardest to squish with your hands?",
        "If you pushed hard on each object, which one would bend or squash the least?",
        "Which object is made of the stiffest material, the one with the highest Young's modulus?",
        ("Which object has the highest Young's modulus, i.e. needs the most stress per unit of strain when "
         "stretched or compressed?"),
        "Assuming linear isotropic elasticity, which object's material has the largest elastic modulus E = σ/ε?",
    ),
    "F_PHYSICS_PROPERTY_YOUNG_MODULUS_OBJECT_SIMILAR": (
        "Which thing is about as soft or as hard as the {name}?",
        "Which object would give way about as much as the {name} if you pushed on it?",
        "Which object is made of a material about as stiff as the {name}'s, going by Young's modulus?",
        "Which object's Young's modulus lies within about a factor of two of the {name}'s?",
        "On a logarithmic scale, which object's elastic modulus E lies within about 0.3 decades of the {name}'s?",
    ),
    "F_PHYSICS_PROPERTY_POISSON_RATIO_HIGHEST": (
        "If you squished each of these things from the top, which one would get the fattest at the sides?",
        "Pressed down from above, which object would spread out sideways the most?",
        "Which object's material has the largest Poisson's ratio, the sideways stretch per unit of squeeze?",
        "Which object has the highest Poisson's ratio ν, the negative ratio of transverse to axial strain?",
        ("Under small uniaxial compression, which object's material shows the largest ratio of lateral to axial "
         "strain magnitude (Poisson's ratio ν, at most 0.5 for an incompressible solid)?"),
    ),
    "F_PHYSICS_PROPERTY_POISSON_RATIO_OBJECT_SIMILAR": (
        ("If you squished the {name} and the other things from the top, which one would bulge at the sides "
         "about as much as the {name}?"),
        "Squeezed from above, which object would spread sideways about as much as the {name}?",
        "Which object has a Poisson's ratio close to that of the {name}?",
        "Which object's Poisson's ratio differs from the {name}'s by less than 0.02?",
        ("Which object's material has a Poisson's ratio ν within 0.02 of the {name}'s, i.e. nearly the same "
         "ratio of lateral to axial strain?"),
    ),
}


def level_text(question_id: str, level: str, name: str | None) -> str:
    """The wording of ``question_id`` at ``level`` (``name``: the object it names, when it names one)."""
    template = LEVEL_TEXTS[question_id][LEVELS.index(level)]
    if "{name}" in template and not name:
        raise ValueError(f"{question_id} at {level} names an object, but the record names none")
    return template.format(name=name)


def _make(level: str) -> None:
    @variant(level)
    def make(inputs: VariantInputs, records: list[dict[str, Any]]) -> VariantOutput:
        out = VariantOutput()
        for r in records:
            if r["mode"] != "multi" or r["question_id"] not in LEVEL_TEXTS:
                continue
            name = inputs.view.name(r["named"][0]) if r["named"] else None
            text = MULTI_PREFIX + level_text(r["question_id"], level, name)
            out.records.append(derive(r, level, question=text))
        return out


for _level in LEVELS:
    _make(_level)
