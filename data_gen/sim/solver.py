"""Implicit Euler on the stacked reduced states of all objects, solved by Newton's method.

One step of size ``h`` (s) minimises, over the reduced states ``q`` of the awake objects,

    f(q) = sum_o 1/2 (q_o - q_pred_o)^T M_o (q_o - q_pred_o)
           + h^2 [ elastic(q) + gravity potential(q) + contact(q) + lagged friction(q) ],

with ``q_pred = q_n + h qdot_n``.  Newton with a backtracking Armijo line search and a dense float64
Cholesky solve, per *island*: awake objects linked by object-object contact candidates are solved
together, all others one by one (block diagonal).  Convergence is relative: a step stops when the
Newton update ``|dq|_M`` falls below ``tol`` times the motion scale of the step
(``|q_pred - q_n|_M + h^2 |g| sqrt(m)``).

Near contact an island's step is split into sub-steps (see :meth:`ImplicitEulerSolver.step`), and the
contact stiffness ``factor * mass / h^2`` follows the sub-step ``h``.

Newton safeguards: one update moves no contact sphere further than a trust radius (twice the step's
predicted motion plus a median contact radius; affine handles linearise rotations, so a thin stiff object
can otherwise be offered updates of metres), and when the preset's Armijo halvings fail the search keeps
halving for any decrease before giving up at the last accepted iterate.

Counters (``ImplicitEulerSolver.counters``, reported in ``SimulationRunSummary.counters``): island solves,
``unconverged_solves`` (stopped at ``newton_iterations`` above tolerance), ``line_search_failures``,
``line_search_extended``, ``trust_limited_steps``, ``strict_projections`` (indefinite Newton matrix:
every elastic block projected), ``substep_cap_raised`` and energy evaluations.

Sleeping: an awake object whose fastest cubature point moves slower than ``sleep_speed_m_s`` while it is
supported (in contact) for ``sleep_steps`` consecutive steps is frozen (no Newton work, its contact
forces held); it wakes when an object moving faster than that speed comes into contact range.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from data_gen.sim.contact import PairFinder, pair_contact, static_contact
from data_gen.sim.contact_points import ContactPoints
from data_gen.sim.energy.pair_contact import FROZEN, PairSet
from data_gen.sim.energy.scene_sdf import SceneDistance
from data_gen.sim.model import DofLayout, Model, padded_index
from data_gen.sim.newton import NewtonSettings, minimise
from data_gen.sim.presets import QualityPreset
from data_gen.sim.reduced import DTYPE, ReducedObject
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.step_objective import ContactForces, StepObjective

NO_PARTNER = -1  # contact partner id of a point without contact (0 is the static scene)
# Near contact a point may move at most this many of its contact radii per sub-step. Two approaching
# objects then close at most 2 radii (one sphere diameter) per sub-step, so a sphere cannot jump through
# its partner's layer of spheres; static boxes are solids (no thin shells), so 2 radii is safe there.
PAIR_REACH_RADII = 1.0
SCENE_REACH_RADII = 2.0
# The preset's ``max_contact_substeps`` is a cost cap; a point so fast that the cap would let it jump
# past its reach gets up to this many sub-steps instead (counted as ``substep_cap_raised``).
HARD_SUBSTEP_LIMIT = 64
_ARMIJO_C = 1e-4
# After the preset's Armijo halvings fail, keep halving up to this many more times for any decrease
# (a failed search leaves the island at its last accepted iterate).
_EXTRA_HALVINGS = 20


class SimulationError(RuntimeError):
    """A non-finite quantity appeared in the simulation; the message names object, step and quantity."""


@dataclass
class SimBody:
    """One simulated object: its reduced model, contact spheres and mutable state.

    Attributes:
        object_id: 1-based id (0 is the static scene).
        name: object name used in errors.
        model: reduced model at the cubature points.
        contact: contact spheres (k of them) moved by the same basis; per-point contact arrays below
            are per sphere.
        friction_coefficient: Coulomb coefficient (dimensionless, >= 0).
        q, qdot: reduced state (q-ordering) and its rate (1/s).
    """

    object_id: int
    name: str
    model: ReducedObject
    contact: ContactPoints
    friction_coefficient: float
    q: torch.Tensor
    qdot: torch.Tensor
    asleep: bool = False
    slow_steps: int = 0
    contact_force_n: torch.Tensor = field(init=False)  # (k,3) N per sphere, this step
    contact_partner: torch.Tensor = field(init=False)  # (k,) dominant partner id, NO_PARTNER if none
    static_force_n: torch.Tensor = field(init=False)  # (k,3) N from the scene (held while asleep)
    partner_strength_n: torch.Tensor = field(init=False)  # (k,) |force| of the dominant partner
    static_summary: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(init=False, default=None)

    def __post_init__(self) -> None:
        n = self.contact.num_points
        self.contact_force_n = torch.zeros(n, 3, dtype=DTYPE)
        self.static_force_n = torch.zeros(n, 3, dtype=DTYPE)
        self.contact_partner = torch.full((n,), NO_PARTNER, dtype=torch.int64)
        self.partner_strength_n = torch.zeros(n, dtype=DTYPE)

    def reset_step_forces(self) -> None:
        """Start a step's force bookkeeping from the (possibly frozen) static-scene forces."""
        self.contact_force_n = self.static_force_n.clone()
        self.partner_strength_n = self.static_force_n.norm(dim=1)
        self.contact_partner = torch.where(self.partner_strength_n > 0, 0, NO_PARTNER)

    @property
    def radius_m(self) -> torch.Tensor:
        """(k,) contact sphere radii, m."""
        return self.contact.radius_m

    def contact_positions(self, q: torch.Tensor | None = None) -> torch.Tensor:
        """(k,3) world sphere centres, m, of state q (default: the current state)."""
        return self.contact.positions(self.q if q is None else q)

    def cubature_contact(self) -> tuple[torch.Tensor, torch.Tensor]:
        """This step's contact force (n,3) N and dominant partner (n,) per cubature point."""
        return self.contact.to_cubature(
            self.contact_force_n, self.contact_partner, self.partner_strength_n, NO_PARTNER
        )


@dataclass
class StepStats:
    """What one step cost and found."""

    newton_iterations: int = 0
    islands: int = 0
    awake_objects: int = 0
    candidate_pairs: int = 0
    substeps: int = 1
    pair_forces: dict[tuple[int, int], dict] = field(default_factory=dict)

    def add_pair_force(
        self,
        key: tuple[int, int],
        force_n: np.ndarray,
        position_m: np.ndarray,
        normal: np.ndarray,
        h_s: float,
    ) -> None:
        """Accumulate a pair's contact force (N, on the smaller id) over a (sub)step of h_s seconds."""
        entry = self.pair_forces.setdefault(
            key, {"impulse_n_s": 0.0, "peak_force_n": -1.0, "position_m": position_m, "normal": normal}
        )
        magnitude = float(np.linalg.norm(force_n))
        entry["impulse_n_s"] += magnitude * h_s
        if magnitude > entry["peak_force_n"]:
            entry.update(peak_force_n=magnitude, position_m=position_m, normal=normal)


@dataclass
class _PairSet:
    """Candidate point pairs of one island: i on an island object, j on an island or sleeping object."""

    obj_i: np.ndarray
    loc_i: np.ndarray
    obj_j: np.ndarray
    loc_j: np.ndarray
    stiffness_n_m: torch.Tensor
    radius_sum_m: torch.Tensor
    mu: torch.Tensor
    lam_n: torch.Tensor
    normal0: torch.Tensor
    x0_i: torch.Tensor
    x0_j: torch.Tensor
    global_i: torch.Tensor  # rows into the concatenation of all objects' points
    global_j: torch.Tensor


class ImplicitEulerSolver:
    """Advances a list of :class:`SimBody` by implicit Euler steps of ``dt_s`` seconds."""

    def __init__(
        self,
        bodies: list[SimBody],
        scene: StaticScene,
        gravity_m_s2: np.ndarray,
        preset: QualityPreset,
        dt_s: float,
        device: str = "cpu",
    ) -> None:
        self.bodies = bodies
        self.scene = scene
        self.gravity = torch.as_tensor(np.asarray(gravity_m_s2, dtype=np.float64))
        self.preset = preset
        self.dt = float(dt_s)
        self.finder = PairFinder(device=device)
        self.offsets = np.cumsum([0] + [b.contact.num_points for b in bodies])
        self.point_object = (
            np.concatenate([np.full(b.contact.num_points, k) for k, b in enumerate(bodies)])
            if bodies
            else np.zeros(0, dtype=np.int64)
        )
        self.radii_all = torch.cat([b.radius_m for b in bodies]) if bodies else torch.zeros(0)
        self.h = self.dt  # current (sub)step, s
        self.step_index = 0
        self.timings: dict[str, float] = {"broad_phase": 0.0, "newton": 0.0}
        self.model = Model.build(
            [b.model for b in bodies], [b.contact for b in bodies], [b.friction_coefficient for b in bodies]
        )
        self.scene_distance = SceneDistance(scene)
        self._padded_index = [padded_index(b.model.num_handles, self.model.columns) for b in bodies]
        self.counters: dict[str, int] = dict.fromkeys(
            (
                "evaluations",
                "evaluations_with_derivatives",
                "strict_projections",
                "line_search_failures",
                "island_solves",
                "island_object_solves",
                "substep_cap_raised",
                "trust_limited_steps",
                "line_search_extended",
                "unconverged_solves",
            ),
            0,
        )

    # ------------------------------------------------------------------ public
    def stiffness(self, k: int) -> float:
        """Scene contact stiffness of object k per contact sphere: factor * mass / h^2 (N/m)."""
        return self.preset.contact_stiffness_factor * self.bodies[k].model.mass_kg / self.h**2

    def step(self) -> StepStats:
        """Advance all objects by ``dt_s``; raises SimulationError on non-finite values.

        Contact candidates are found once per step (hash grid, margin covering the step's motion) and
        split the awake objects into islands.  Each island near contact is split into sub-steps so that
        none of its contact spheres moves more than ``PAIR_REACH_RADII`` contact radii per sub-step (at
        most ``preset.max_contact_substeps`` unless needed): penalty contact cannot stop a sphere that jumps past its
        partner within one step.  Islands in free flight take the full step.
        """
        stats = StepStats()
        self.h = self.dt
        t0 = time.perf_counter()
        positions = [b.contact_positions() for b in self.bodies]
        speeds = [
            float(b.contact.velocities(b.qdot).norm(dim=1).max()) if not b.asleep else 0.0
            for b in self.bodies
        ]
        pairs = self._candidate_pairs(positions, moving=True)
        self.timings["broad_phase"] += time.perf_counter() - t0
        stats.candidate_pairs = len(pairs)
        self._wake(pairs, speeds)
        islands = self._islands(pairs)
        stats.islands = len(islands)
        stats.awake_objects = sum(len(isl) for isl in islands)
        for b in self.bodies:
            if not b.asleep:
                b.static_force_n = torch.zeros_like(b.static_force_n)
            b.reset_step_forces()
        supported = np.zeros(len(self.bodies), dtype=bool)
        by_substeps: dict[int, list[list[int]]] = {}
        for island in islands:  # islands that need the same sub-steps are solved together
            by_substeps.setdefault(self._island_substeps(island, positions, pairs), []).append(island)
        for num_sub, group in sorted(by_substeps.items()):
            stats.substeps = max(stats.substeps, num_sub)
            self.h = self.dt / num_sub
            members = [k for island in group for k in island]
            for _ in range(num_sub):
                t0 = time.perf_counter()
                pair_set = self._island_pairs(members, pairs, positions)
                stats.newton_iterations += self._solve_group(group, pair_set, self.h, stats, supported)
                for k in members:
                    positions[k] = self.bodies[k].contact_positions()
                self.timings["newton"] += time.perf_counter() - t0
        self.h = self.dt
        self._record_sleeping_contacts(pairs, positions, stats)
        self._update_sleep(islands, supported)
        self.step_index += 1
        return stats

    def _island_substeps(self, island: list[int], positions: list[torch.Tensor], pairs: np.ndarray) -> int:
        """Sub-steps so that no point moves more than PAIR_REACH_RADII radii (near another object) or
        SCENE_REACH_RADII radii (near the static scene only) per sub-step.

        The radius is the object's median contact radius (tiny spheres fitted into edges are covered by
        their neighbours).  Usually at most ``preset.max_contact_substeps``; beyond that cap only when
        the reach demands it, up to ``HARD_SUBSTEP_LIMIT``."""
        paired = set(self.point_object[pairs].ravel().tolist()) if len(pairs) else set()
        worst = 0.0
        for k in island:  # loop over objects
            b = self.bodies[k]
            reach = float(b.contact.velocities(b.qdot).norm(dim=1).max()) * self.dt
            r_min = float(b.radius_m.median())
            if k in paired:
                worst = max(worst, reach / (PAIR_REACH_RADII * r_min))
                continue
            sdf, _ = self.scene.query(positions[k])
            if bool(((sdf - b.radius_m.numpy()) < 2.0 * reach).any()):
                worst = max(worst, reach / (SCENE_REACH_RADII * r_min))
        needed = max(1, int(np.ceil(worst)))
        if needed <= self.preset.max_contact_substeps:
            return needed
        self.counters["substep_cap_raised"] += 1
        return min(HARD_SUBSTEP_LIMIT, needed)

    def refresh_forces(self) -> StepStats:
        """Contact forces of the current state without stepping (used for the initial frame)."""
        stats = StepStats()
        positions = [b.contact_positions() for b in self.bodies]
        pairs = self._candidate_pairs(positions, moving=False)
        supported = np.zeros(len(self.bodies), dtype=bool)
        for b in self.bodies:
            b.reset_step_forces()
        islands = self._islands(pairs)
        if islands:
            members = [k for island in islands for k in island]
            self._record_current_forces(islands, self._island_pairs(members, pairs, positions), stats, supported)
        return stats

    def energies(self) -> dict[str, float]:
        """Kinetic, elastic, contact and gravity potential energy (J) of the current state."""
        kin = sum(b.model.kinetic_energy(b.qdot) for b in self.bodies)
        ela = sum(b.model.elastic_energy(b.q) for b in self.bodies)
        grav = sum(b.model.gravity_energy(b.q, self.gravity) for b in self.bodies)
        positions = [b.contact_positions() for b in self.bodies]
        con = 0.0
        for k, b in enumerate(self.bodies):
            pc, _, _ = static_contact(positions[k], b.radius_m, _scalar(self.stiffness(k)), self.scene)
            con += pc.energy
        pairs = self._candidate_pairs(positions, moving=False)
        if len(pairs):
            oi, oj = self.point_object[pairs[:, 0]], self.point_object[pairs[:, 1]]
            x_all = torch.cat(positions)
            k = torch.from_numpy(self._pair_tables()[0][oi, oj])
            rs = self.radii_all[pairs[:, 0]] + self.radii_all[pairs[:, 1]]
            con += pair_contact(x_all[pairs[:, 0]], x_all[pairs[:, 1]], rs, k).energy
        return {"kinetic": kin, "elastic": ela, "contact": con, "gravity": grav}

    # ------------------------------------------------------------------ broad phase, islands, sleep
    def _candidate_pairs(self, positions: list[torch.Tensor], moving: bool) -> np.ndarray:
        """Sphere pairs on different objects that may touch during the coming step (``moving``) or
        touch now, within a quarter radius (not moving: forces and energies of the current state)."""
        if len(self.bodies) < 2:
            return np.zeros((0, 2), dtype=np.int64)
        x_all = torch.cat(positions).numpy()
        r_max = float(self.radii_all.max())
        reach = self._reach(self.h) if moving else None
        return self.finder.find(x_all, self.point_object, self.radii_all.numpy(), 0.25 * r_max, reach)

    def _reach(self, h: float) -> np.ndarray:
        """Per contact sphere (all objects, global order): how far it may close in on another in a step of
        h seconds, m.  Two points close in by at most h |v_i - v_j| <= h (|v_i - u| + |v_j - u|) for
        any common velocity u; u = the mean point velocity keeps the bound tight for objects falling
        together.  1.5 x that (velocities change within the step) plus what gravity adds."""
        velocity = torch.cat(
            [
                torch.zeros(b.contact.num_points, 3, dtype=DTYPE) if b.asleep else b.contact.velocities(b.qdot)
                for b in self.bodies
            ]
        )
        relative_speed = (velocity - velocity.mean(0)).norm(dim=1).numpy()
        return 1.5 * relative_speed * h + float(self.gravity.norm()) * h**2

    def _wake(self, pairs: np.ndarray, speeds: list[float]) -> None:
        if not len(pairs):
            return
        obj_pairs = np.unique(self.point_object[pairs], axis=0)
        for a, c in obj_pairs:  # loop over object pairs
            for mover, sleeper in ((a, c), (c, a)):
                if (
                    self.bodies[sleeper].asleep
                    and not self.bodies[mover].asleep
                    and speeds[mover] > self.preset.sleep_speed_m_s
                ):
                    self.bodies[sleeper].asleep = False
                    self.bodies[sleeper].slow_steps = 0

    def _islands(self, pairs: np.ndarray) -> list[list[int]]:
        parent = list(range(len(self.bodies)))

        def root(k: int) -> int:
            while parent[k] != k:
                parent[k] = parent[parent[k]]
                k = parent[k]
            return k

        if len(pairs):
            for a, c in np.unique(self.point_object[pairs], axis=0):
                if not self.bodies[a].asleep and not self.bodies[c].asleep:
                    parent[root(a)] = root(c)
        groups: dict[int, list[int]] = {}
        for k, b in enumerate(self.bodies):
            if not b.asleep:
                groups.setdefault(root(k), []).append(k)
        return [sorted(g) for _, g in sorted(groups.items(), key=lambda item: min(item[1]))]

    def _update_sleep(self, islands: list[list[int]], supported: np.ndarray) -> None:
        threshold = self.preset.sleep_speed_m_s
        for island in islands:
            for k in island:
                b = self.bodies[k]
                speed = float(b.contact.velocities(b.qdot).norm(dim=1).max())
                if threshold > 0 and speed < threshold and supported[k]:
                    b.slow_steps += 1
                else:
                    b.slow_steps = 0
                if b.slow_steps >= self.preset.sleep_steps:
                    b.asleep = True
                    b.qdot = torch.zeros_like(b.qdot)

    def _pair_tables(self) -> tuple[np.ndarray, np.ndarray]:
        """Per object pair: contact stiffness (N/m) = factor * reduced mass / h^2 (a sleeping partner counts
        as infinitely heavy) and friction coefficient sqrt(mu_a mu_c)."""
        mass = np.array([b.model.mass_kg for b in self.bodies])
        asleep = np.array([b.asleep for b in self.bodies])
        reduced = mass[:, None] * mass[None, :] / (mass[:, None] + mass[None, :])
        reduced = np.where(asleep[None, :], mass[:, None], np.where(asleep[:, None], mass[None, :], reduced))
        mu = np.array([b.friction_coefficient for b in self.bodies])
        return self.preset.contact_stiffness_factor * reduced / self.h**2, np.sqrt(mu[:, None] * mu[None, :])

    def _island_pairs(self, island: list[int], pairs: np.ndarray, positions: list[torch.Tensor]) -> _PairSet:
        members = np.asarray(island)
        sel = pairs if len(pairs) else np.zeros((0, 2), dtype=np.int64)
        inside = np.isin(self.point_object[sel], members)  # (P, 2)
        sel = sel[inside.any(axis=1)]
        swap = ~inside[inside.any(axis=1), 0]  # orient every pair so that side i is an island member
        gi = np.where(swap, sel[:, 1], sel[:, 0])
        gj = np.where(swap, sel[:, 0], sel[:, 1])
        if len(gi) and self.h < self.dt:
            # a sub-step: keep the step's candidates that can touch within this (shorter) sub-step
            x_np = torch.cat(positions).numpy()
            reach = self._reach(self.h)
            radii = self.radii_all.numpy()
            gap = np.linalg.norm(x_np[gi] - x_np[gj], axis=1) - radii[gi] - radii[gj]
            near = gap < reach[gi] + reach[gj] + 0.25 * float(radii.max())
            gi, gj = gi[near], gj[near]
        oi, oj = self.point_object[gi], self.point_object[gj]
        li, lj = gi - self.offsets[oi], gj - self.offsets[oj]
        x_all = torch.cat(positions) if positions else torch.zeros(0, 3, dtype=DTYPE)
        stiffness, friction = self._pair_tables()
        k = torch.from_numpy(stiffness[oi, oj])
        mu = torch.from_numpy(friction[oi, oj])
        rs = self.radii_all[gi] + self.radii_all[gj]
        x0i, x0j = x_all[gi], x_all[gj]
        start = pair_contact(x0i, x0j, rs, k) if len(gi) else None
        lam = (k * start.depth_m.clamp(min=0.0)) if start is not None else torch.zeros(0, dtype=DTYPE)
        n0 = start.normal_ji if start is not None else torch.zeros(0, 3, dtype=DTYPE)
        return _PairSet(
            oi, li, oj, lj, k, rs, mu, lam, n0, x0i, x0j, torch.from_numpy(gi), torch.from_numpy(gj)
        )

    # ------------------------------------------------------------------ Newton on a group of islands
    def _padded_states(self, objects: list[int]) -> tuple[torch.Tensor, torch.Tensor]:
        """Padded (n, 3, K) states q and rates qdot of some bodies."""
        k = self.model.columns
        tm = torch.zeros(len(objects), 3 * k, dtype=DTYPE)
        tmdot = torch.zeros_like(tm)
        for slot, o in enumerate(objects):  # once per solve
            index = self._padded_index[o]
            tm[slot, index] = self.bodies[o].q
            tmdot[slot, index] = self.bodies[o].qdot
        return tm.reshape(-1, 3, k), tmdot.reshape(-1, 3, k)

    def _group_pairs(self, objects: list[int], slot_of: np.ndarray, ps: _PairSet, model: Model) -> PairSet:
        """The candidate pairs of a solve in solved-object slots (sleeping partners frozen)."""
        obj_j = slot_of[ps.obj_j]
        frozen = obj_j < 0
        x_frozen = torch.zeros(len(obj_j), 3, dtype=DTYPE)
        if frozen.any():
            x_frozen[torch.from_numpy(frozen)] = ps.x0_j[torch.from_numpy(frozen)]
        return PairSet(
            obj_i=torch.from_numpy(slot_of[ps.obj_i]),
            sph_i=torch.from_numpy(ps.loc_i),
            obj_j=torch.from_numpy(np.where(frozen, FROZEN, obj_j)),
            sph_j=torch.from_numpy(ps.loc_j),
            frozen_x_j=x_frozen,
            stiffness_n_m=ps.stiffness_n_m,
            radius_sum_m=ps.radius_sum_m,
            friction=ps.mu * (ps.lam_n > 0),
            normal_force_n=ps.lam_n,
            normal0=ps.normal0,
            x0_i=ps.x0_i,
            x0_j=ps.x0_j,
        )

    def _solve_group(self, islands: list[list[int]], ps: _PairSet, h: float, stats: StepStats,
                     supported: np.ndarray) -> int:
        """One implicit Euler (sub)step of size h for several independent islands at once; records the
        contact forces of the final state. Returns the Newton iterations summed over the islands."""
        objects = [k for island in islands for k in island]
        island_slot = torch.tensor([a for a, island in enumerate(islands) for _ in island], dtype=torch.int64)
        slot_of = np.full(len(self.bodies), -1, dtype=np.int64)
        slot_of[objects] = np.arange(len(objects))
        self.counters["island_solves"] += len(islands)
        self.counters["island_object_solves"] += len(objects)
        model = self.model.select(torch.tensor(objects, dtype=torch.int64))
        layout = DofLayout.build(model.num_handles, island_slot, model.columns)
        tm_n, tmdot = self._padded_states(objects)
        objective = StepObjective(
            model, layout, self.scene_distance, self.gravity, tm_n, tmdot, h,
            self.preset.contact_stiffness_factor, self.preset.friction_smoothing_m_s * h,
            self._group_pairs(objects, slot_of, ps, model),
        )  # fmt: skip

        def check_gradient(grad: torch.Tensor) -> None:
            bad = ~torch.isfinite(layout.to_objects(grad).reshape(len(objects), -1)).all(1)
            if bool(bad.any()):
                self._check_finite([objects[int(torch.nonzero(bad)[0])]], [torch.tensor([float("nan")])],
                                   "objective gradient")  # fmt: skip

        def indefinite(still: torch.Tensor) -> None:
            island = islands[int(torch.nonzero(still)[0])]
            names = ", ".join(self.bodies[k].name for k in island)
            raise SimulationError(
                f"step {self.step_index}: Newton matrix of objects [{names}] is not "
                f"positive definite (non-finite or degenerate cubature)"
            )

        q0 = layout.to_islands(tm_n + h * tmdot)
        result = minimise(
            objective, q0, objective.motion_scale(), objective.trust_radius(),
            NewtonSettings(self.preset.newton_iterations, self.preset.newton_tolerance, self.preset.line_search_steps),
            on_gradient=check_gradient, on_indefinite=indefinite,
        )  # fmt: skip
        for key, value in result.counters.items():
            self.counters[key] += value
        tm = layout.to_objects(result.q)
        for slot, o in enumerate(objects):
            q = tm[slot].reshape(-1)[self._padded_index[o]]
            self._check_finite([o], [q], "reduced state q")
        for slot, o in enumerate(objects):
            b = self.bodies[o]
            q = tm[slot].reshape(-1)[self._padded_index[o]].clone()
            b.qdot = (q - b.q) / h
            b.q = q
        self._record_group_forces(objects, objective.forces(tm), ps, objective.pairs, model, h, stats, supported)
        return int(result.iterations.sum())

    def _record_current_forces(self, islands: list[list[int]], ps: _PairSet, stats: StepStats,
                               supported: np.ndarray) -> None:
        """Contact forces of the current state without stepping (the initial frame): the step that led
        here is taken to have started at ``q - h qdot``."""
        objects = [k for island in islands for k in island]
        slot_of = np.full(len(self.bodies), -1, dtype=np.int64)
        slot_of[objects] = np.arange(len(objects))
        model = self.model.select(torch.tensor(objects, dtype=torch.int64))
        island_slot = torch.tensor([a for a, island in enumerate(islands) for _ in island], dtype=torch.int64)
        layout = DofLayout.build(model.num_handles, island_slot, model.columns)
        tm, tmdot = self._padded_states(objects)
        h = self.h
        objective = StepObjective(
            model, layout, self.scene_distance, self.gravity, tm - h * tmdot, tmdot, h,
            self.preset.contact_stiffness_factor, self.preset.friction_smoothing_m_s * h,
            self._group_pairs(objects, slot_of, ps, model),
        )  # fmt: skip
        self._record_group_forces(objects, objective.forces(tm), ps, objective.pairs, model, h, stats, supported)

    def _check_finite(self, objects: list[int], parts: list[torch.Tensor], quantity: str) -> None:
        for k, part in zip(objects, parts):
            if not bool(torch.isfinite(part).all()):
                raise SimulationError(
                    f"object {self.bodies[k].name!r} (id {self.bodies[k].object_id}), "
                    f"step {self.step_index}: non-finite {quantity}"
                )

    # ------------------------------------------------------------------ force recording
    def _record_group_forces(self, objects: list[int], forces: ContactForces, ps: _PairSet, pairs: PairSet,
                             model: Model, h: float, stats: StepStats, supported: np.ndarray) -> None:
        """Per-sphere contact forces (N) of the final state, dominant partner ids, per-pair totals, from
        the forces the objective evaluated (nothing is recomputed here)."""
        force = forces.scene_force_n * model.sphere_valid[:, :, None]
        mag = force.norm(dim=2)  # (n, S)
        total = force.sum(1)
        weight = mag.sum(1).clamp(min=1e-300)
        x = forces.sphere_positions_m
        pos = (mag[:, :, None] * x).sum(1) / weight[:, None]
        nrm = (mag[:, :, None] * forces.scene_normals).sum(1)
        nrm = nrm / nrm.norm(dim=1, keepdim=True).clamp(min=1e-300)
        touching = (mag > 0).any(1).numpy()
        total_np, pos_np, nrm_np = total.numpy(), pos.numpy(), nrm.numpy()
        for slot, o in enumerate(objects):  # once per (sub)step: bookkeeping only
            b = self.bodies[o]
            b.static_force_n = force[slot, : b.contact.num_points].clone()
            b.reset_step_forces()  # pair forces are added below
            if touching[slot]:
                supported[o] = True
                b.static_summary = (total_np[slot], pos_np[slot], nrm_np[slot])
                stats.add_pair_force((b.object_id, 0), *b.static_summary, h)
            else:
                b.static_summary = None
        if pairs.num_pairs == 0:
            return
        xi, xj = pairs.positions(x)
        self._accumulate_pair_forces(
            ps.obj_i, ps.loc_i, ps.obj_j, ps.loc_j, xi, xj, forces.pair_force_i_n, forces.pair_normals, stats,
            supported,
        )  # fmt: skip

    def _record_sleeping_contacts(
        self, pairs: np.ndarray, positions: list[torch.Tensor], stats: StepStats
    ) -> None:
        """Frozen scene contacts of sleeping objects and normal forces between two sleeping objects."""
        for b in self.bodies:
            if b.asleep and b.static_summary is not None:
                stats.add_pair_force((b.object_id, 0), *b.static_summary, self.h)
        if not len(pairs):
            return
        oi, oj = self.point_object[pairs[:, 0]], self.point_object[pairs[:, 1]]
        asleep = np.array([b.asleep for b in self.bodies])
        both = asleep[oi] & asleep[oj]
        if not both.any():
            return
        gi, gj = pairs[both, 0], pairs[both, 1]
        oi, oj = oi[both], oj[both]
        x_all = torch.cat(positions)
        mass = np.array([b.model.mass_kg for b in self.bodies])
        k = torch.from_numpy(
            self.preset.contact_stiffness_factor * np.minimum(mass[oi], mass[oj]) / self.h**2
        )
        pc = pair_contact(x_all[gi], x_all[gj], self.radii_all[gi] + self.radii_all[gj], k)
        self._accumulate_pair_forces(
            oi,
            gi - self.offsets[oi],
            oj,
            gj - self.offsets[oj],
            x_all[gi],
            x_all[gj],
            -pc.grad_i,
            pc.normal_ji,
            stats,
            np.zeros(len(self.bodies), dtype=bool),
        )

    def _accumulate_pair_forces(
        self,
        obj_i: np.ndarray,
        loc_i: np.ndarray,
        obj_j: np.ndarray,
        loc_j: np.ndarray,
        xi: torch.Tensor,
        xj: torch.Tensor,
        f_i: torch.Tensor,
        normal_ji: torch.Tensor,
        stats: StepStats,
        supported: np.ndarray,
    ) -> None:
        """Add pair forces (N, on side i; side j gets the opposite) to per-point records and pair totals."""
        mag = f_i.norm(dim=1)
        act = mag > 0
        if not bool(act.any()):
            return
        act_np = act.numpy()
        for a, c in np.unique(np.stack([obj_i[act_np], obj_j[act_np]], 1), axis=0):  # loop over object pairs
            sel = torch.from_numpy((obj_i == a) & (obj_j == c)) & act
            li = torch.from_numpy(loc_i)[sel]
            lj = torch.from_numpy(loc_j)[sel]
            fa = f_i[sel]
            m = mag[sel]
            ba, bc = self.bodies[a], self.bodies[c]
            ba.contact_force_n.index_add_(0, li, fa)
            # a sleeping partner collects the average over the island's sub-steps
            bc.contact_force_n.index_add_(0, lj, -fa * (self.h / self.dt if bc.asleep else 1.0))
            _assign_partner(ba, li, m, bc.object_id)
            _assign_partner(bc, lj, m, ba.object_id)
            supported[a] = True
            if bc.asleep:
                supported[c] = True
            pos = ((m[:, None] * 0.5 * (xi[sel] + xj[sel])).sum(0) / m.sum()).numpy()
            nrm = (m[:, None] * normal_ji[sel]).sum(0).numpy()
            total = fa.sum(0).numpy()
            if ba.object_id > bc.object_id:  # events are keyed (smaller id, larger id), force on the smaller
                total, nrm = -total, -nrm
            key = (min(ba.object_id, bc.object_id), max(ba.object_id, bc.object_id))
            stats.add_pair_force(key, total, pos, nrm / max(float(np.linalg.norm(nrm)), 1e-300), self.h)


def _assign_partner(body: SimBody, local: torch.Tensor, magnitude: torch.Tensor, partner_id: int) -> None:
    """Points whose force from ``partner_id`` (N) exceeds their strongest contact so far take it as partner."""
    best = torch.zeros(body.contact.num_points, dtype=DTYPE)
    best.scatter_reduce_(0, local, magnitude, reduce="amax", include_self=True)
    take = best > body.partner_strength_n
    body.contact_partner = torch.where(take, partner_id, body.contact_partner)
    body.partner_strength_n = torch.maximum(best, body.partner_strength_n)


def _scalar(value: float) -> torch.Tensor:
    return torch.tensor(value, dtype=DTYPE)
