"""The question registry and what every question function receives."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from data_gen.display_names import words
from data_gen.vqa.rules import NotAnswerable, Question, pick
from data_gen.vqa.view import SequenceView
from newtphys.vqa_schema import QUESTION_SPECS


@dataclass(frozen=True)
class Context:
    """One question's inputs: the sequence, the question's frame (its "last frame") and a seeded rng."""

    view: SequenceView
    frame: int
    rng: np.random.Generator

    def target(self, candidates: list[int] | None = None) -> int:
        """A seeded pick among the objects a question may name at this frame."""
        ids = self.view.nameable_ids(self.frame) if candidates is None else candidates
        if not ids:
            raise NotAnswerable("no_nameable_object")
        return int(ids[int(self.rng.integers(len(ids)))])

    def name(self, object_id: int) -> str:
        name = self.view.name(object_id)
        if name is None:
            raise NotAnswerable("ambiguous_name")
        return name

    def name_distractors(self, correct_ids: list[int], count: int = 3, scene_first: bool = True,
                         exclude_ids: list[int] | None = None) -> tuple[str, ...]:  # fmt: skip
        """Names of other visible objects of the scene first (seeded order), then library object names that
        are not in the scene."""
        taken = {*correct_ids, *(exclude_ids or [])}
        scene = [self.view.name(i) for i in self.view.visible_ids(self.frame) if i not in taken] if scene_first else []
        scene = [n for n in scene if n is not None]
        chosen = list(pick(scene, [], self.rng, min(count, len(scene)))) if scene else []
        if len(chosen) < count:
            chosen += list(pick(self.library_names_not_in_scene(), chosen + [self.view.name(i) or "" for i in taken],
                                self.rng, count - len(chosen)))  # fmt: skip
        return tuple(chosen)

    def library_names_not_in_scene(self) -> list[str]:
        from data_gen.assets.registry import list_objects

        present = {o.name for o in self.view.world_state.objects}
        present_words = {self.view.name(o.id) for o in self.view.world_state.objects} | {words(n) for n in present}
        return [words(n) for n in list_objects() if n not in present and words(n) not in present_words]


QuestionFunction = Callable[[Context], Question]
REGISTRY: dict[str, QuestionFunction] = {}


def question(question_id: str) -> Callable[[QuestionFunction], QuestionFunction]:
    """Register ``fn`` as the generator of ``question_id`` (an id of the catalogue)."""
    if question_id not in QUESTION_SPECS:
        raise KeyError(f"{question_id!r} is not in the catalogue (newtphys.vqa_schema.QUESTION_SPECS)")

    def register(fn: QuestionFunction) -> QuestionFunction:
        if question_id in REGISTRY:
            raise KeyError(f"{question_id} registered twice")
        REGISTRY[question_id] = fn
        return fn

    return register
