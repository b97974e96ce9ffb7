"""How much energy a recorded run gained from nowhere: the check that catches a contact resolved too late.

Implicit Euler with penalty contact and lagged friction loses energy: a run's recorded total (kinetic + elastic +
contact + gravity potential) falls, or stays level, from frame to frame, up to round-off and the small gains of
a contact that starts between two sub-steps. A contact the solver missed is different: a sphere found deep
inside another object is pushed out by a stiff spring, and the push adds energy that was never there (0.85 J to
600 J in the broad phase's blind spot of 2026-12-03, two boxes of 2 kg each; the runs that went right gained at
most 1.6 mJ). The overlap check (:mod:`data_gen.sim.overlap`) sees such a contact only if a recorded frame falls
inside it; the energy gain stays in every later frame.

:func:`largest_energy_rise` measures the largest rise of the recorded total above its lowest value so far,
against a scale that does not depend on where z = 0 is: the larger of the energy the run released (first
total minus lowest total) and the weight of every object times its size (sum of m |g| L, L the largest extent
of its contact spheres), the energy of lifting each object by its own size.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from data_gen.sim.recording import SimulationResult

# The recorded energies (J per frame) whose sum is the run's total: SimulationResult.energies_j's keys.
ENERGY_TERMS = ("kinetic", "elastic", "contact", "gravity")

# A sequence is rejected when its recorded total rises above its lowest value so far by more than this fraction
# of the scale (see the module docstring and docs/sim_speed_history.md for the survey that set it).
MAX_ENERGY_RISE_FRACTION = 0.01


class EnergyRise(NamedTuple):
    """The largest energy gain of a run.

    Attributes:
        rise_j: the recorded total at ``frame`` minus its lowest value before it, J (0 when it never rises).
        frame: the frame at which that rise peaks.
        scale_j: the offset-free scale it is measured against, J.
    """

    rise_j: float
    frame: int
    scale_j: float

    @property
    def fraction(self) -> float:
        """``rise_j / scale_j`` (inf for a rise against a zero scale)."""
        if self.scale_j > 0.0:
            return self.rise_j / self.scale_j
        return float("inf") if self.rise_j > 0.0 else 0.0


def total_energy_j(energies_j: Mapping[str, np.ndarray]) -> np.ndarray:
    """(T,) the recorded total energy per frame, J; a missing term is a ValueError naming it."""
    missing = [k for k in ENERGY_TERMS if k not in energies_j]
    if missing:
        raise ValueError(f"energies_j lacks {missing}: a run records {list(ENERGY_TERMS)}")
    return sum(np.asarray(energies_j[k], dtype=np.float64) for k in ENERGY_TERMS)


def weight_size_j(masses_kg: Sequence[float], sizes_m: Sequence[float], gravity_m_s2: float) -> float:
    """sum_i m_i |g| L_i, J: the energy of lifting every object by its own size."""
    if len(masses_kg) != len(sizes_m):
        raise ValueError(f"{len(masses_kg)} masses for {len(sizes_m)} sizes")
    return float(sum(m * abs(gravity_m_s2) * s for m, s in zip(masses_kg, sizes_m)))


def largest_energy_rise(total_j: np.ndarray, masses_kg: Sequence[float], sizes_m: Sequence[float],
                        gravity_m_s2: float) -> EnergyRise:  # fmt: skip
    """The largest rise of ``total_j`` (T,) above its running minimum, with its frame and the scale max(energy
    released, :func:`weight_size_j`). Non-finite energies are a ValueError (the NaN check comes first)."""
    total = np.asarray(total_j, dtype=np.float64)
    if total.ndim != 1 or len(total) == 0:
        raise ValueError(f"total energy must be one value per frame, got shape {total.shape}")
    if not np.isfinite(total).all():
        raise ValueError(f"total energy is not finite at frame {int(np.argmin(np.isfinite(total)))}")
    above = total - np.minimum.accumulate(total)
    frame = int(np.argmax(above))
    released = float(total[0] - total.min())
    scale = max(released, weight_size_j(masses_kg, sizes_m, gravity_m_s2))
    return EnergyRise(float(above[frame]), frame, scale)


def run_energy_rise(result: SimulationResult) -> EnergyRise:
    """:func:`largest_energy_rise` of a recorded run: its total energy, each object's mass and size (the largest
    extent of its contact spheres' rest centres) and its gravity."""
    tracks = result.objects
    return largest_energy_rise(
        total_energy_j(result.energies_j), [float(t.masses_kg.sum()) for t in tracks],
        [float(np.ptp(t.contact_points_rest_m, axis=0).max()) for t in tracks], float(np.linalg.norm(result.gravity_m_s2)),
    )  # fmt: skip
