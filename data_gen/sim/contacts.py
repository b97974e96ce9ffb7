"""The broad phase: which contact spheres of different objects may touch in a step, and the islands.

As in warp's and Newton's simulators, the broad phase runs outside the solver and hands it a
:class:`Contacts` object.  :class:`BroadPhase` is built once from the objects' contact spheres (their
per-sphere tables and a warp hash grid, :class:`~data_gen.sim.contact.PairFinder`); every step it finds

1. the candidate sphere pairs (:meth:`BroadPhase.candidates`): spheres on different objects whose gap
   is below a quarter of the largest radius plus, in a moving step, how far each sphere can close in
   during the step (:meth:`BroadPhase.reach`);
2. the object pairs they link (:meth:`BroadPhase.object_pairs`);
3. after the solver has woken sleepers (a decision about the dynamic state, left to the solver), the
   islands: awake objects linked by object pairs (:meth:`BroadPhase.contacts`).

Spheres are numbered globally: object ``k``'s spheres are rows ``offsets[k]:offsets[k+1]`` of the
concatenation of all objects' spheres.  Units: m, s, m/s.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from data_gen.sim.contact import PairFinder
from data_gen.sim.contact_points import ContactPoints
from data_gen.sim.reduced import DTYPE

# Candidate pairs are found within this fraction of the largest contact radius (on top of any reach).
CONTACT_MARGIN_RADII = 0.25


@dataclass(frozen=True, eq=False)
class Contacts:
    """What the broad phase found for one step.

    Attributes:
        pairs: (P, 2) int64 candidate sphere pairs, global sphere indices i < j on different objects,
            sorted lexicographically.
        object_pairs: (Q, 2) int64 distinct object pairs (a, c), a < c, linked by some candidate pair,
            sorted lexicographically.
        islands: the awake objects (indices) grouped by object pairs between awake objects, each island
            sorted, islands ordered by their smallest member; a sleeping object is in no island.
    """

    pairs: np.ndarray
    object_pairs: np.ndarray
    islands: list[list[int]]


class BroadPhase:
    """Per-sphere tables of all objects and the pair search over them (built once per simulation).

    Args:
        spheres: each object's contact spheres, in object order.
        gravity_m_s2: magnitude of gravity, m/s^2 (what it adds to a sphere's reach in a step).
        device: warp device of the hash grid.

    Attributes:
        num_objects: number of objects.
        offsets: (num_objects + 1,) first global sphere index of each object, then the total count.
        point_object: (S,) int64 object index of each global sphere.
        radii_all: (S,) contact sphere radii, m, all objects concatenated.
        finder: the warp hash grid search.
    """

    def __init__(self, spheres: Sequence[ContactPoints], gravity_m_s2: float, device: str = "cpu") -> None:
        self.num_objects = len(spheres)
        self.gravity_m_s2 = float(gravity_m_s2)
        self.finder = PairFinder(device=device)
        self.offsets = np.cumsum([0] + [s.num_points for s in spheres])
        self.point_object = (
            np.concatenate([np.full(s.num_points, k) for k, s in enumerate(spheres)])
            if spheres
            else np.zeros(0, dtype=np.int64)
        )
        self.radii_all = torch.cat([s.radius_m for s in spheres]) if spheres else torch.zeros(0)
        self._margin_m = CONTACT_MARGIN_RADII * float(self.radii_all.max()) if spheres else 0.0

    @property
    def margin_m(self) -> float:
        """Gap below which two spheres are candidates without any motion: a quarter of the largest
        radius, m (the radii are fixed: computed once)."""
        return self._margin_m

    def reach(self, velocities: Sequence[torch.Tensor | None], h_s: float) -> np.ndarray:
        """Per contact sphere (all objects, global order): how far it may close in on another in a step of
        ``h_s`` seconds, m.

        ``velocities``: per object its spheres' velocities (k, 3) m/s, None for a sleeping object (it
        does not move).  Two points close in by at most h |v_i - v_j| <= h (|v_i| + |v_j|): the speeds
        are taken in the static scene's frame, because the scene can stop either object within the step.
        (The mean point velocity as the common frame left objects released together blind to each other:
        the lower one stopped by the ground, the upper one closed its whole h |v| unseen and sank into
        it.)  1.5 x that (velocities change within the step) plus what gravity adds."""
        velocity = torch.cat(
            [
                torch.zeros(int(self.offsets[k + 1] - self.offsets[k]), 3, dtype=DTYPE) if v is None else v
                for k, v in enumerate(velocities)
            ]
        )
        return 1.5 * velocity.norm(dim=1).numpy() * h_s + self.gravity_m_s2 * h_s**2

    def candidates(
        self, positions: Sequence[torch.Tensor], velocities: Sequence[torch.Tensor | None] | None, h_s: float
    ) -> np.ndarray:
        """Candidate sphere pairs (P, 2) of global indices, i < j on different objects, sorted.

        ``positions``: per object its sphere centres (k, 3), m.  With ``velocities`` (per object (k, 3)
        m/s, None if asleep) the pairs that may touch during a step of ``h_s`` seconds (gap below the
        margin plus both spheres' :meth:`reach`); without, the pairs touching now, within the margin
        (forces and energies of the current state)."""
        if self.num_objects < 2:
            return np.zeros((0, 2), dtype=np.int64)
        x_all = torch.cat(list(positions)).numpy()
        reach = self.reach(velocities, h_s) if velocities is not None else None
        return self.finder.find(x_all, self.point_object, self.radii_all.numpy(), self.margin_m, reach)

    def within_reach(
        self,
        gi: np.ndarray,
        gj: np.ndarray,
        x_all: np.ndarray,
        velocities: Sequence[torch.Tensor | None],
        h_s: float,
    ) -> np.ndarray:
        """(P,) bool: which of the step's candidate pairs (global indices gi, gj) can touch within a
        shorter (sub)step of ``h_s`` seconds, from the current sphere centres ``x_all`` (S, 3), m."""
        reach = self.reach(velocities, h_s)
        radii = self.radii_all.numpy()
        d = x_all[gi] - x_all[gj]
        gap = np.sqrt((d * d).sum(1)) - radii[gi] - radii[gj]
        return gap < reach[gi] + reach[gj] + self.margin_m

    def object_pairs(self, pairs: np.ndarray) -> np.ndarray:
        """The distinct object pairs (a, c) of candidate sphere pairs, sorted lexicographically (a < c)."""
        n = self.num_objects
        linked = np.zeros((n, n), dtype=bool)
        if len(pairs):
            linked[self.point_object[pairs[:, 0]], self.point_object[pairs[:, 1]]] = True
        return np.argwhere(linked)

    def islands(self, object_pairs: np.ndarray, asleep: np.ndarray) -> list[list[int]]:
        """Awake objects (``asleep``: (num_objects,) bool) linked by object pairs between awake objects,
        each island sorted, islands by smallest member."""
        parent = list(range(self.num_objects))

        def root(k: int) -> int:
            while parent[k] != k:
                parent[k] = parent[parent[k]]
                k = parent[k]
            return k

        for a, c in object_pairs:
            if not asleep[a] and not asleep[c]:
                parent[root(a)] = root(c)
        groups: dict[int, list[int]] = {}
        for k in range(self.num_objects):
            if not asleep[k]:
                groups.setdefault(root(k), []).append(k)
        return [sorted(g) for _, g in sorted(groups.items(), key=lambda item: min(item[1]))]

    def contacts(self, pairs: np.ndarray, object_pairs: np.ndarray, asleep: np.ndarray) -> Contacts:
        """The step's :class:`Contacts` from its candidate pairs, their object pairs and the sleep flags
        after waking (``asleep``: (num_objects,) bool)."""
        return Contacts(pairs, object_pairs, self.islands(object_pairs, asleep))
