"""The NewtPhys paper's dataset numbers, the yardstick the benchmark scenario, its dry run and ``newtphys
stats`` print beside their own.

From the paper's dataset description: 11K sequences, 730K frames at 25 FPS, sequences up to 10 s, 53 scenes,
109 objects, up to 10 objects per scene, about 15 distinct collisions per sequence, moving cameras, highly
deformable objects down to low Young's moduli, frames of 1000 x 562 px. The mean duration is derived:
730K frames / 11K sequences / 25 FPS = 2.65 s. The shortest length (2 s) and the softest modulus (~1e3 Pa)
are the ranges issue 14 asks the benchmark scenario to cover.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class PaperStats:
    sequences: int
    frames: int
    fps: float
    min_duration_s: float
    max_duration_s: float
    scenes: int
    objects: int
    max_objects_per_scene: int
    collisions_per_sequence: float
    """Mean collision events per sequence (the paper: "about 15")."""
    min_young_modulus_pa: float
    image_size: tuple[int, int]
    """H, W pixels."""

    @property
    def mean_duration_s(self) -> float:
        return self.frames / self.sequences / self.fps


PAPER = PaperStats(sequences=11_000, frames=730_000, fps=25.0, min_duration_s=2.0, max_duration_s=10.0, scenes=53,
                   objects=109, max_objects_per_scene=10, collisions_per_sequence=15.0, min_young_modulus_pa=1.0e3,
                   image_size=(562, 1000))
