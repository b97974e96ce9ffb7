"""Variants of the questions (``newtphys.vqa_schema.VARIANTS``), one small module per idea; importing this
package registers them all (``REGISTRY``: variant name -> function over one sequence's base records)."""

from data_gen.vqa.variants import counterfactual, cues, levels, masking, referring  # noqa: F401
from data_gen.vqa.variants.registry import REGISTRY, CounterfactualSettings, VariantInputs, VariantOutput

__all__ = ["REGISTRY", "CounterfactualSettings", "VariantInputs", "VariantOutput"]
