"""The dynamic state of a simulation: what one implicit Euler step reads and replaces.

Together with the fixed :class:`data_gen.sim.model.Model` (what the objects are) and the energy terms
(:mod:`data_gen.sim.energy`), a :class:`State` is the third piece of the simulator's layout, as in warp's
and Newton's simulators: the solver (:class:`data_gen.sim.solver.ImplicitEulerSolver`) owns one and
advances it step by step; nothing else about an object changes over time except per-step force
bookkeeping.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class State:
    """Reduced coordinates, their rates and sleep flags of all objects, in body order.

    The solver replaces an object's ``q[k]`` and ``qdot[k]`` by new tensors after each solve (it never
    writes into them in place), so a tensor taken from a state stays what it was.

    Attributes:
        q: per object, its reduced coordinates (12 H,) in its q-ordering (affine handle entries:
            dimensionless deformation, m for the translation part).
        qdot: per object, the rate of ``q`` (12 H,), 1/s (m/s for the translation part).
        asleep: (n,) bool, frozen objects (no Newton work, ``qdot`` zero, contact forces held).
        slow_steps: (n,) int, consecutive steps each awake object has been slow and supported; it
            falls asleep when this reaches the preset's ``sleep_steps``.
    """

    q: list[torch.Tensor]
    qdot: list[torch.Tensor]
    asleep: np.ndarray
    slow_steps: np.ndarray

    def __post_init__(self) -> None:
        self.asleep = np.asarray(self.asleep, dtype=bool)
        self.slow_steps = np.asarray(self.slow_steps, dtype=np.int64)
        n = len(self.q)
        if len(self.qdot) != n or self.asleep.shape != (n,) or self.slow_steps.shape != (n,):
            raise ValueError(
                f"State of {n} objects needs {n} rates, (n,) sleep flags and slow-step counts; got "
                f"{len(self.qdot)} rates, asleep {self.asleep.shape}, slow_steps {self.slow_steps.shape}"
            )

    @classmethod
    def awake(cls, q: list[torch.Tensor], qdot: list[torch.Tensor]) -> State:
        """A state of all objects awake, none slow yet, at reduced coordinates q and rates qdot (1/s)."""
        n = len(q)
        return cls(list(q), list(qdot), np.zeros(n, dtype=bool), np.zeros(n, dtype=np.int64))

    @property
    def num_objects(self) -> int:
        """Number of objects."""
        return len(self.q)

    def copy(self) -> State:
        """An independent copy (tensors cloned, arrays copied): stepping from one leaves the other as is."""
        return State(
            [q.clone() for q in self.q],
            [qdot.clone() for qdot in self.qdot],
            self.asleep.copy(),
            self.slow_steps.copy(),
        )
