"""The energy-gain check (data_gen.sim.energy_rise): hand-computed rises and scales, and the real blind spot it
was built for (the broad phase's old mean-velocity reach, put back on the batched path)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from data_gen.pipeline import SequenceRejected, check_simulation
from data_gen.sim.contacts import DTYPE, BroadPhase
from data_gen.sim.energy_rise import (
    MAX_ENERGY_RISE_FRACTION,
    largest_energy_rise,
    run_energy_rise,
    total_energy_j,
    weight_size_j,
)
from data_gen.sim.material import Material
from tests.sim.test_sim_collision import run_released_together


def test_the_rise_is_measured_above_the_running_minimum_against_an_offset_free_scale():
    total = np.array([10.0, 8.0, 9.0, 7.0, 7.5])  # J: a rise of 1 J at frame 2 (above 8), 0.5 J at frame 4
    rise = largest_energy_rise(total, [2.0], [0.1], -9.81)
    assert (rise.rise_j, rise.frame) == (1.0, 2)
    assert rise.scale_j == pytest.approx(3.0)  # released 10 - 7 = 3 J > m |g| L = 2 * 9.81 * 0.1 = 1.962 J
    assert rise.fraction == pytest.approx(1.0 / 3.0)
    shifted = largest_energy_rise(total + 1000.0, [2.0], [0.1], -9.81)  # z = 0 elsewhere: the same numbers
    assert (shifted.rise_j, shifted.frame, shifted.scale_j) == (rise.rise_j, rise.frame, rise.scale_j)
    heavy = largest_energy_rise(total, [2.0, 3.0], [0.1, 0.2], 9.81)  # 9.81 (0.2 + 0.6) = 7.848 J > 3 J released
    assert heavy.scale_j == pytest.approx(7.848) and heavy.fraction == pytest.approx(1.0 / 7.848)
    falling = largest_energy_rise(np.array([5.0, 4.0, 4.0, 1.0]), [1.0], [0.1], 9.81)
    assert (falling.rise_j, falling.frame, falling.fraction) == (0.0, 0, 0.0)
    assert weight_size_j([1.0, 2.0], [0.5, 0.25], -2.0) == pytest.approx(2.0)


def test_bad_energies_are_named():
    with pytest.raises(ValueError, match=r"lacks \['contact'\]"):
        total_energy_j({"kinetic": np.zeros(3), "elastic": np.zeros(3), "gravity": np.zeros(3)})
    with pytest.raises(ValueError, match="not finite at frame 2"):
        largest_energy_rise(np.array([1.0, 0.5, np.nan]), [1.0], [0.1], 9.81)
    with pytest.raises(ValueError, match="2 masses for 1 sizes"):
        weight_size_j([1.0, 2.0], [0.1], 9.81)


def _mean_velocity_reach(self, velocities, h_s):
    """The broad phase's reach before 2026-12-03 (faa53b5): speeds relative to the mean sphere velocity."""
    velocity = torch.cat([torch.zeros(int(self.offsets[k + 1] - self.offsets[k]), 3, dtype=DTYPE) if v is None else v
                          for k, v in enumerate(velocities)])  # fmt: skip
    return 1.5 * (velocity - velocity.mean(0)).norm(dim=1).numpy() * h_s + self.gravity_m_s2 * h_s**2


def test_the_check_rejects_the_broad_phase_blind_spot_and_passes_the_fixed_run(tmp_path, monkeypatch):
    """Two stiff boxes released together, the ground stopping the lower one (batched path, draft): with the old
    reach the upper box sinks into the lower one unseen and is pushed out, gaining energy (+61 J, 2.8 times the
    run's scale, measured; the fixed run gains 1 mJ, 5e-5 of it); the check rejects that run and passes the same run
    with the reach in the static scene's frame."""
    material = [Material(1e9, 0.3, 1000.0)] * 2
    fixed = run_released_together(1e9, False, tmp_path)
    check_simulation(fixed, material)
    good = run_energy_rise(fixed)
    assert good.fraction < 0.1 * MAX_ENERGY_RISE_FRACTION, good
    monkeypatch.setattr(BroadPhase, "reach", _mean_velocity_reach)
    blind = run_released_together(1e9, False, tmp_path)
    bad = run_energy_rise(blind)
    assert bad.fraction > 10 * MAX_ENERGY_RISE_FRACTION, bad
    assert bad.rise_j > 1.0  # joules, from nowhere
    # the overlap check misses it (the upper box sinks in and is pushed out between two recorded frames)
    with pytest.raises(SequenceRejected, match=rf"rose by {bad.rise_j:.3g} J above its lowest value by frame {bad.frame}") as err:
        check_simulation(blind, material)
    assert err.value.reason == "energy_gain"

