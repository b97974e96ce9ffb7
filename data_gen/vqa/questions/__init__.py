"""One small function per question id, registered by :func:`registry.question`; importing this package
registers them all (``REGISTRY``: question id -> function)."""

from data_gen.vqa.questions import material, mechanics, persistence, spatial, temporal, viewpoint  # noqa: F401
from data_gen.vqa.questions.registry import REGISTRY, Context

__all__ = ["REGISTRY", "Context"]
