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

from data_gen.sim.contact import PairFinder, friction_terms, pair_contact, penalty_from_sdf, static_contact
from data_gen.sim.contact_points import ContactPoints
from data_gen.sim.presets import QualityPreset
from data_gen.sim.reduced import DTYPE, ReducedObject, scatter_point_gradient, scatter_point_hessian
from data_gen.sim.static_scene import StaticScene

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
        self.timings: dict[str, float] = {"broad_phase": 0.0, "newton": 0.0, "forces": 0.0}
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
        for island in islands:
            num_sub = self._island_substeps(island, positions, pairs)
            stats.substeps = max(stats.substeps, num_sub)
            self.h = self.dt / num_sub
            for _ in range(num_sub):
                t0 = time.perf_counter()
                pair_set = self._island_pairs(island, pairs, positions)
                stats.newton_iterations += self._solve_island(island, pair_set, positions, self.h)
                for k in island:
                    positions[k] = self.bodies[k].contact_positions()
                t1 = time.perf_counter()
                self._record_island_forces(island, pair_set, stats, supported)
                self.timings["newton"] += t1 - t0
                self.timings["forces"] += time.perf_counter() - t1
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
        for island in self._islands(pairs):
            self._record_island_forces(island, self._island_pairs(island, pairs, positions), stats, supported)
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

    # ------------------------------------------------------------------ Newton
    def _solve_island(self, island: list[int], ps: _PairSet, positions: list[torch.Tensor], h: float) -> int:
        bodies = [self.bodies[k] for k in island]
        local = {k: a for a, k in enumerate(island)}
        self.counters["island_solves"] += 1
        self.counters["island_object_solves"] += len(island)
        sizes = [b.model.num_dofs for b in bodies]
        offs = np.cumsum([0] + sizes)
        point_offs = np.cumsum([0] + [b.contact.num_points for b in bodies])
        q_n = torch.cat([b.q for b in bodies])
        q_pred = torch.cat([b.q + h * b.qdot for b in bodies])
        mass = torch.block_diag(*[b.model.mass_matrix for b in bodies])
        # lagged friction and contact data frozen at the start of the step
        starts = []
        for k in island:
            b = self.bodies[k]
            pc, depth, normal = static_contact(
                positions[k], b.radius_m, _scalar(self.stiffness(k)), self.scene
            )
            lam = self.stiffness(k) * depth.clamp(min=0.0)
            starts.append((positions[k], lam, normal))
        total_mass = sum(b.model.mass_kg for b in bodies)
        motion = (q_pred - q_n) @ (mass @ (q_pred - q_n))
        scale = (
            float(torch.sqrt(motion))
            + h * h * float(self.gravity.norm()) * np.sqrt(total_mass)
            + 1e-9 * np.sqrt(total_mass)
        )
        smoothing_m = self.preset.friction_smoothing_m_s * h

        def split(q: torch.Tensor) -> list[torch.Tensor]:
            return [q[offs[a] : offs[a + 1]] for a in range(len(bodies))]

        def evaluate(q: torch.Tensor, derivs: bool, strict: bool = False):
            self.counters["evaluations_with_derivatives" if derivs else "evaluations"] += 1
            dq = q - q_pred
            m_dq = mass @ dq
            value = 0.5 * float(dq @ m_dq)
            grad = m_dq.clone() if derivs else None
            hess = mass.clone() if derivs else None
            qs = split(q)
            xs = {k: bodies[a].contact_positions(qs[a]) for a, k in enumerate(island)}
            sdf_all, normal_all = self.scene.query(torch.cat(list(xs.values())))  # one query per island
            sdf_all, normal_all = torch.from_numpy(sdf_all), torch.from_numpy(normal_all)
            for a, b in enumerate(bodies):
                model, qa = b.model, qs[a]
                sl = slice(offs[a], offs[a + 1])
                x = xs[island[a]]
                pts = slice(point_offs[a], point_offs[a + 1])
                e = model.elastic_energy(qa) + model.gravity_energy(qa, self.gravity)
                pc, _, _ = penalty_from_sdf(
                    sdf_all[pts], normal_all[pts], b.radius_m, _scalar(self.stiffness(island[a]))
                )
                e += pc.energy
                terms = [pc]
                x_start, lam, n0 = starts[a]
                if b.friction_coefficient > 0 and bool((lam > 0).any()):
                    fr = friction_terms(x - x_start, lam, n0, _scalar(b.friction_coefficient), smoothing_m)
                    e += fr.energy
                    terms.append(fr)
                value += h * h * e
                if derivs:
                    g = model.elastic_gradient(qa) + model.gravity_gradient(self.gravity)
                    kmat = model.elastic_hessian(qa, strict=strict)
                    for t in terms:
                        act = t.hess_x.abs().sum(dim=(1, 2)) > 0
                        if bool(act.any()):
                            g = g + scatter_point_gradient(b.contact.b[act], t.grad_x[act])
                            kmat = kmat + scatter_point_hessian(b.contact.b[act], t.hess_x[act])
                    grad[sl] += h * h * g
                    hess[sl, sl] += h * h * kmat
            if len(ps.obj_i):
                value += (
                    h * h * self._pair_terms(ps, xs, local, bodies, offs, grad, hess, derivs, smoothing_m)
                )
            return value, grad, hess

        q = q_n + h * torch.cat([b.qdot for b in bodies])
        # Trust region on point motion: one Newton update moves no contact sphere further than twice the
        # step's predicted motion plus a median contact radius.  An affine handle linearises rotations, so
        # a thin stiff object (tiny inertia about its long axis, elastic curvature ~0 along rotations) can
        # get Newton updates of metres that a plain backtracking search cannot shrink enough.
        trust_m = (
            2.0 * _max_point_motion(bodies, offs, q - q_n)
            + h * h * float(self.gravity.norm())
            + min(float(b.radius_m.median()) for b in bodies)
        )
        iterations, converged = 0, False
        for it in range(self.preset.newton_iterations):
            value, grad, hess = evaluate(q, True)
            self._check_finite(island, split(grad), "objective gradient")
            dq = self._newton_direction(hess, grad)
            if dq is None:  # a near-SPD elastic block made the matrix indefinite: project every block
                self.counters["strict_projections"] += 1
                value, grad, hess = evaluate(q, True, strict=True)
                dq = self._newton_direction(hess, grad)
            if dq is None:
                names = ", ".join(self.bodies[k].name for k in island)
                raise SimulationError(
                    f"step {self.step_index}: Newton matrix of objects [{names}] is not "
                    f"positive definite (non-finite or degenerate cubature)"
                )
            iterations = it + 1
            slope = float(grad @ dq)
            alpha = min(1.0, trust_m / max(_max_point_motion(bodies, offs, dq), 1e-300))
            if alpha < 1.0:
                self.counters["trust_limited_steps"] += 1
            accepted = False
            for trial_index in range(self.preset.line_search_steps + _EXTRA_HALVINGS):
                trial, _, _ = evaluate(q + alpha * dq, False)
                if trial_index < self.preset.line_search_steps:
                    accepted = trial <= value + _ARMIJO_C * alpha * slope + 1e-14 * abs(value)
                else:  # Armijo failed within the preset's budget: any decrease beats standing still
                    accepted = trial < value
                if accepted:
                    if trial_index >= self.preset.line_search_steps:
                        self.counters["line_search_extended"] += 1
                    break
                alpha *= 0.5
            if not accepted:
                self.counters["line_search_failures"] += 1
                break
            q = q + alpha * dq
            step_norm = alpha * float(torch.sqrt((dq @ (mass @ dq)).clamp(min=0.0)))
            if step_norm <= self.preset.newton_tolerance * scale:
                converged = True
                break
        if not converged:
            self.counters["unconverged_solves"] += 1
        qs = split(q)
        self._check_finite(island, qs, "reduced state q")
        for a, b in enumerate(bodies):
            b.qdot = (qs[a] - b.q) / h
            b.q = qs[a].clone()
        return iterations

    @staticmethod
    def _newton_direction(hess: torch.Tensor, grad: torch.Tensor) -> torch.Tensor | None:
        """Solve hess dq = -grad by Cholesky (a 1e-10 relative ridge if needed); None if not PD."""
        hess = 0.5 * (hess + hess.T)
        chol, info = torch.linalg.cholesky_ex(hess)
        if int(info) != 0:
            ridge = 1e-10 * float(hess.diagonal().abs().max())
            chol, info = torch.linalg.cholesky_ex(hess + ridge * torch.eye(hess.shape[0], dtype=DTYPE))
        if int(info) != 0:
            return None
        return -torch.cholesky_solve(grad[:, None], chol)[:, 0]

    def _check_finite(self, island: list[int], parts: list[torch.Tensor], quantity: str) -> None:
        for k, part in zip(island, parts):
            if not bool(torch.isfinite(part).all()):
                raise SimulationError(
                    f"object {self.bodies[k].name!r} (id {self.bodies[k].object_id}), "
                    f"step {self.step_index}: non-finite {quantity}"
                )

    def _pair_terms(
        self, ps: _PairSet, xs: dict, local: dict, bodies, offs, grad, hess, derivs: bool, smoothing_m: float
    ) -> float:
        """Object-object contact and friction; adds h^2-free derivatives scaled by h^2 into grad/hess."""
        h2 = self.h * self.h
        xi, xj = self._gather(ps, xs)
        pc = pair_contact(xi, xj, ps.radius_sum_m, ps.stiffness_n_m)
        energy = pc.energy
        g_i, h_ij = pc.grad_i, pc.hess
        fric = (ps.mu > 0) & (ps.lam_n > 0)
        if bool(fric.any()):
            slip = (xi - ps.x0_i) - (xj - ps.x0_j)
            fr = friction_terms(slip, ps.lam_n * fric, ps.normal0, ps.mu, smoothing_m)
            energy += fr.energy
            g_i, h_ij = g_i + fr.grad_x, h_ij + fr.hess_x
        if not derivs:
            return energy
        active = h_ij.abs().sum(dim=(1, 2)) > 0
        obj_pairs = np.unique(np.stack([ps.obj_i[active.numpy()], ps.obj_j[active.numpy()]], 1), axis=0)
        for a, c in obj_pairs:  # loop over object pairs
            sel = torch.from_numpy((ps.obj_i == a) & (ps.obj_j == c)) & active
            bi = self.bodies[a].contact.b[torch.from_numpy(ps.loc_i)[sel]]
            bj = self.bodies[c].contact.b[torch.from_numpy(ps.loc_j)[sel]]
            gi, hp = g_i[sel], h_ij[sel]
            sa = slice(offs[local[a]], offs[local[a] + 1])
            grad[sa] += h2 * scatter_point_gradient(bi, gi)
            hess[sa, sa] += h2 * scatter_point_hessian(bi, hp)
            if c in local:
                sc = slice(offs[local[c]], offs[local[c] + 1])
                grad[sc] -= h2 * scatter_point_gradient(bj, gi)
                hess[sc, sc] += h2 * scatter_point_hessian(bj, hp)
                cross = scatter_point_hessian(bi, hp, bj)
                hess[sa, sc] -= h2 * cross
                hess[sc, sa] -= h2 * cross.T
        return energy

    def _gather(self, ps: _PairSet, xs: dict) -> tuple[torch.Tensor, torch.Tensor]:
        """Positions of both sides of every pair: island objects from ``xs``, the others (asleep) frozen."""
        x_all = torch.cat([xs[k] if k in xs else b.contact_positions() for k, b in enumerate(self.bodies)])
        return x_all[ps.global_i], x_all[ps.global_j]

    # ------------------------------------------------------------------ force recording
    def _record_island_forces(
        self, island: list[int], ps: _PairSet, stats: StepStats, supported: np.ndarray
    ) -> None:
        """Per-point contact forces (N) on the final state, dominant partner ids, per-pair totals."""
        h = self.h
        smoothing_m = self.preset.friction_smoothing_m_s * h
        xs = {}
        for k in island:
            b = self.bodies[k]
            x = b.contact_positions()
            xs[k] = x
            pc, depth, normal = static_contact(x, b.radius_m, _scalar(self.stiffness(k)), self.scene)
            force = -pc.grad_x
            x_start, lam0, n0 = b.contact_positions(b.q - h * b.qdot), None, None
            if b.friction_coefficient > 0:
                _, depth0, n0 = static_contact(x_start, b.radius_m, _scalar(self.stiffness(k)), self.scene)
                lam0 = self.stiffness(k) * depth0.clamp(min=0.0)
                if bool((lam0 > 0).any()):
                    fr = friction_terms(x - x_start, lam0, n0, _scalar(b.friction_coefficient), smoothing_m)
                    force = force - fr.grad_x
            b.static_force_n = force
            b.reset_step_forces()  # pair forces are added below
            in_contact = force.norm(dim=1) > 0
            if bool(in_contact.any()):
                supported[k] = True
                mag = force.norm(dim=1)
                total = force.sum(0).numpy()
                pos = ((mag[:, None] * x).sum(0) / mag.sum()).numpy()
                nrm = ((mag[:, None] * normal).sum(0)).numpy()
                b.static_summary = (total, pos, nrm / max(float(np.linalg.norm(nrm)), 1e-300))
                stats.add_pair_force((b.object_id, 0), *b.static_summary, self.h)
            else:
                b.static_summary = None
        if not len(ps.obj_i):
            return
        xi, xj = self._gather(ps, xs)
        pc = pair_contact(xi, xj, ps.radius_sum_m, ps.stiffness_n_m)
        f_i = -pc.grad_i
        fric = (ps.mu > 0) & (ps.lam_n > 0)
        if bool(fric.any()):
            slip = (xi - ps.x0_i) - (xj - ps.x0_j)
            f_i = f_i - friction_terms(slip, ps.lam_n * fric, ps.normal0, ps.mu, smoothing_m).grad_x
        self._accumulate_pair_forces(
            ps.obj_i, ps.loc_i, ps.obj_j, ps.loc_j, xi, xj, f_i, pc.normal_ji, stats, supported
        )

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


def _max_point_motion(bodies: list[SimBody], offsets: np.ndarray, dq: torch.Tensor) -> float:
    """Largest contact-sphere displacement (m) of the island's objects under a state change dq."""
    return max(
        float(b.contact.velocities(dq[offsets[a] : offsets[a + 1]]).norm(dim=1).max()) for a, b in enumerate(bodies)
    )


def _assign_partner(body: SimBody, local: torch.Tensor, magnitude: torch.Tensor, partner_id: int) -> None:
    """Points whose force from ``partner_id`` (N) exceeds their strongest contact so far take it as partner."""
    best = torch.zeros(body.contact.num_points, dtype=DTYPE)
    best.scatter_reduce_(0, local, magnitude, reduce="amax", include_self=True)
    take = best > body.partner_strength_n
    body.contact_partner = torch.where(take, partner_id, body.contact_partner)
    body.partner_strength_n = torch.maximum(best, body.partner_strength_n)


def _scalar(value: float) -> torch.Tensor:
    return torch.tensor(value, dtype=DTYPE)
