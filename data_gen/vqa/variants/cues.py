"""Physical cues appended to the question text: how long the shown frames span, or the named object's mass
(exact, or rounded to half a kilogram). Images and options stay as they are.

* ``cue_duration``: multi-frame kinematics questions (speed, acceleration, displacement, stability), where
  the elapsed time is what a model must otherwise guess from the frame rate; from the frames' times.
* ``cue_mass_exact`` / ``cue_mass_approx``: questions naming exactly one object, except the mass questions
  themselves (the cue would be the answer).
"""

from __future__ import annotations

import math
from typing import Any

from data_gen.vqa.variants.registry import VariantInputs, VariantOutput, derive, named_once, variant

DURATION_SUB_CATEGORIES = ("kinematics",)
MASS_CUE_EXCLUDED_SUB_CATEGORIES = ("mass",)
MASS_APPROX_STEP_KG = 0.5


def duration_text(seconds: float) -> str:
    return f"The images span {seconds:.2f} seconds."


def mass_exact_text(name: str, mass_kg: float) -> str:
    return f"The {name} has a mass of {mass_kg:.2f} kg."


def approx_mass_kg(mass_kg: float) -> float:
    """``mass_kg`` rounded to the nearest multiple of 0.5 kg (halves round up)."""
    return MASS_APPROX_STEP_KG * math.floor(mass_kg / MASS_APPROX_STEP_KG + 0.5)


def mass_approx_text(name: str, mass_kg: float) -> str:
    rounded = approx_mass_kg(mass_kg)
    if rounded == 0.0:
        return f"The {name} has a mass of less than {MASS_APPROX_STEP_KG / 2:.2f} kg."
    return f"The {name} has a mass of about {rounded:.1f} kg."


@variant("cue_duration")
def cue_duration(inputs: VariantInputs, records: list[dict[str, Any]]) -> VariantOutput:
    out = VariantOutput()
    frames = inputs.view.world_state.frames
    for r in records:
        if r["mode"] != "multi" or r["sub_category"] not in DURATION_SUB_CATEGORIES:
            continue
        seconds = frames[r["frames"][-1]].time - frames[r["frames"][0]].time
        out.records.append(derive(r, "cue_duration", question=f"{r['question']} {duration_text(seconds)}",
                                  meta={**r["meta"], "cue_duration_s": round(seconds, 6)}))  # fmt: skip
    return out


def _mass_cue(name: str, text) -> None:
    @variant(name)
    def make(inputs: VariantInputs, records: list[dict[str, Any]]) -> VariantOutput:
        out = VariantOutput()
        for r in records:
            target = named_once(r)
            if target is None or r["sub_category"] in MASS_CUE_EXCLUDED_SUB_CATEGORIES:
                continue
            mass = float(inputs.view.info(target).mass)
            cue = text(inputs.view.name(target), mass)
            out.records.append(derive(r, name, question=f"{r['question']} {cue}",
                                      meta={**r["meta"], "cue_mass_kg": round(mass, 6)}))  # fmt: skip
        return out


_mass_cue("cue_mass_exact", mass_exact_text)
_mass_cue("cue_mass_approx", mass_approx_text)
