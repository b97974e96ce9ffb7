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
every elastic block projected), ``substep_cap_raised``, energy evaluations, ``fused_island_solves`` (island
solves done by :class:`~data_gen.sim.fused_newton.FusedNewton`), ``fused_handed_back`` (group solves it
handed back to :func:`minimise`), ``split_island_solves`` (deformable island solves done by
:meth:`~data_gen.sim.fused_newton.FusedNewton.solve_split`) and ``split_handed_back`` (group solves it handed
back), ``device_island_solves`` / ``device_handed_back`` (the same for :class:`~data_gen.sim.device_newton.DeviceNewton`,
with ``device_newton``), ``device_graphs_captured`` / ``device_graphs_reused`` (its solves' graphs, where it
captures them: CUDA).

Sleeping: an awake object whose fastest cubature point moves slower than ``sleep_speed_m_s`` while it is
supported (in contact) for ``sleep_steps`` consecutive steps is frozen (no Newton work, its contact
forces held); it wakes when an object moving faster than that speed comes into contact range.

Layout (as in warp's and Newton's simulators): the fixed description of the objects is the stacked
:class:`~data_gen.sim.model.Model` (plus each :class:`SimBody`'s reduced model and contact spheres), the
energy terms live in :mod:`data_gen.sim.energy` (summed by :class:`StepObjective`), and the dynamic state
(reduced coordinates ``q``, rates ``qdot``, sleep flags and slow-step counts) is the solver's one
:class:`~data_gen.sim.state.State`, ``ImplicitEulerSolver.state``: every step reads it and replaces the
entries of the objects it solved.  The broad phase is outside the solver:
:class:`~data_gen.sim.contacts.BroadPhase` (``ImplicitEulerSolver.broad_phase``, built once: the per-sphere
tables ``offsets``, ``point_object``, ``radii_all`` and the hash grid) finds each step's candidate sphere
pairs and object pairs and, once the solver has woken sleepers, the islands: the step's
:class:`~data_gen.sim.contacts.Contacts`.  The solver then sub-steps, minimises (:func:`minimise`) and
records forces.  A :class:`SimBody` holds one object's fixed description and the step's contact force
bookkeeping, no state.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from functools import partial

import numpy as np
import torch
import warp as wp

from data_gen.sim.contact import NonFiniteInput, pair_contact, pair_depth
from data_gen.sim.contact_points import ContactPoints, CubatureGather
from data_gen.sim.contacts import BroadPhase, Contacts
from data_gen.sim.energy import point_terms
from data_gen.sim.energy.elastic import elastic
from data_gen.sim.energy.pair_contact import FROZEN, PairSet
from data_gen.sim.energy.scene_sdf import SceneDistance
from data_gen.sim.model import DofLayout, Model, padded_index
from data_gen.sim.newton import NewtonSettings, minimise
from data_gen.sim.presets import QualityPreset
from data_gen.sim.reduced import DTYPE, ReducedObject
from data_gen.sim.state import State
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.device_newton import DeviceNewton
from data_gen.sim.fused_newton import FusedNewton, SubstepResult
from data_gen.sim.kept_elastic import KeptElasticMatrices
from data_gen.sim.step_objective import (
    ContactForces,
    SolveWorkspace,
    StepObjective,
    fused_fits,
    island_constants,
    rigid_fused_workspace,
)

NO_PARTNER = -1  # contact partner id of a point without contact (0 is the static scene)
# Near contact a point may move at most this many of its contact radii per sub-step. Two approaching
# objects then close at most 2 radii (one sphere diameter) per sub-step, so a sphere cannot jump through
# its partner's layer of spheres; static boxes are solids (no thin shells), so 2 radii is safe there.
PAIR_REACH_RADII = 1.0
SCENE_REACH_RADII = 2.0
# The preset's ``max_contact_substeps`` is a cost cap; a point so fast that the cap would let it jump
# past its reach gets up to this many sub-steps instead (counted as ``substep_cap_raised``).
HARD_SUBSTEP_LIMIT = 64
# At most this many sub-steps of a group go through one fused launch (its per-sub-step force buffers are kept
# with the group's workspace); a step that needs more solves its sub-steps one by one.
FUSED_MAX_SUBSTEPS = 16
_ARMIJO_C = 1e-4
# After the preset's Armijo halvings fail, keep halving up to this many more times for any decrease
# (a failed search leaves the island at its last accepted iterate).
_EXTRA_HALVINGS = 20
# Solves set up for at most this many distinct groups of islands are kept (selected model rows, DOF
# layout), holding at most this many times the memory of the whole model: the same islands are solved in
# every sub-step and, while the scene settles, step after step.
_GROUP_CACHE_SIZE = 64
_GROUP_CACHE_MODELS = 8
# Fused workspaces are kept for at most this many distinct sequences of awake one-handle objects.
_FUSED_CACHE_SIZE = 8


class SimulationError(RuntimeError):
    """A non-finite quantity appeared in the simulation; the message names object, step and quantity."""


@dataclass
class SimBody:
    """One simulated object's fixed description and its per-step contact force bookkeeping.

    Its dynamic state (reduced coordinates, rates, sleep flags) is not here: it lives in the solver's
    :class:`~data_gen.sim.state.State` (``ImplicitEulerSolver.state``), at this body's index.

    Attributes:
        object_id: 1-based id (0 is the static scene).
        name: object name used in errors.
        model: reduced model at the cubature points.
        contact: contact spheres (k of them) moved by the same basis; per-point contact arrays below
            are per sphere.
        friction_coefficient: Coulomb coefficient (dimensionless, >= 0).
        contact_force_n, contact_partner, static_force_n, partner_strength_n, static_summary: the
            current step's contact forces (rewritten every step; the scene's are held while asleep).
    """

    object_id: int
    name: str
    model: ReducedObject
    contact: ContactPoints
    friction_coefficient: float
    contact_force_n: torch.Tensor = field(init=False)  # (k,3) N per sphere, this step
    contact_partner: torch.Tensor = field(init=False)  # (k,) dominant partner id, NO_PARTNER if none
    static_force_n: torch.Tensor = field(init=False)  # (k,3) N from the scene (held while asleep)
    partner_strength_n: torch.Tensor = field(init=False)  # (k,) |force| of the dominant partner
    static_summary: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(init=False, default=None)
    # the last contact_positions: (q tensor, its version, sphere centres); read-only for the callers
    _positions_cache: tuple[torch.Tensor, int, torch.Tensor] | None = field(init=False, default=None, repr=False)

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

    def contact_positions(self, q: torch.Tensor) -> torch.Tensor:
        """(k,3) world sphere centres, m, of reduced coordinates q (this body's entry of a State); kept while
        ``q`` is the same tensor, unmodified (the step, its islands and the recorder ask again). Read-only."""
        cached = self._positions_cache
        if cached is not None and cached[0] is q and cached[1] == q._version:
            return cached[2]
        x = self.contact.positions(q)
        self._positions_cache = (q, q._version, x)
        return x

    def cache_contact_positions(self, q: torch.Tensor, x_m: torch.Tensor) -> torch.Tensor:
        """Keep ``x_m`` (k,3) m, computed elsewhere as :meth:`contact_positions` computes it (a batched solve's
        result), as the sphere centres of ``q``; returns it."""
        self._positions_cache = (q, q._version, x_m)
        return x_m


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

    def add_pair_force_series(
        self,
        keys: list[tuple[int, int]],
        force_n: np.ndarray,
        position_m: np.ndarray,
        normal: np.ndarray,
        present: np.ndarray,
        h_s: float,
    ) -> None:
        """:meth:`add_pair_force` of every entry ``[j, k]`` with ``present[j, k]`` ((J, K) bool; forces,
        positions and normals (J, K, 3), key ``keys[k]``), called in sub-step order j and within a sub-step in
        key order k, with the same sums (impulses added sub-step by sub-step, the first strongest force kept),
        computed for all keys at once."""
        seen = present.any(0)
        if not seen.any():
            return
        num_sub, count = present.shape
        magnitude = np.sqrt((force_n[..., None, :] @ force_n[..., :, None])[..., 0, 0])  # np.linalg.norm of each
        impulse = np.zeros(count)
        peak = np.full(count, -1.0)
        best = np.zeros(count, dtype=np.int64)
        for j in range(num_sub):  # in order: the same additions as one call per entry
            here = present[j]
            impulse = np.where(here, impulse + magnitude[j] * h_s, impulse)
            stronger = here & (magnitude[j] > peak)
            peak = np.where(stronger, magnitude[j], peak)
            best = np.where(stronger, j, best)
        first = np.where(seen, present.argmax(0), num_sub)
        for k in np.lexsort((np.arange(count), first))[: int(seen.sum())]:  # the order the keys appear in
            key = keys[k]
            if key in self.pair_forces:  # met earlier in the step: added entry by entry
                for j in np.flatnonzero(present[:, k]):
                    self.add_pair_force(key, force_n[j, k], position_m[j, k], normal[j, k], h_s)
                continue
            j = best[k]
            self.pair_forces[key] = {
                "impulse_n_s": float(impulse[k]),
                "peak_force_n": float(peak[k]),
                "position_m": position_m[j, k],
                "normal": normal[j, k],
            }


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
    lam_n: torch.Tensor | None  # None: start data left to the fused sub-steps (``_pair_set_without_start``)
    normal0: torch.Tensor | None
    x0_i: torch.Tensor | None
    x0_j: torch.Tensor
    global_i: torch.Tensor  # rows into the concatenation of all objects' points
    global_j: torch.Tensor


@dataclass(frozen=True)
class _GroupSetup:
    """What a solve of some islands needs besides the states; it depends only on the islands.

    Attributes:
        objects: body indices in solve order (island by island); index: the same as a tensor.
        slot_of: (num bodies,) solve slot of each body, -1 if not solved.
        model: the objects' rows of the solver's :class:`Model`; layout: their :class:`DofLayout`.
        padded: (sum 12 H,) positions of the objects' concatenated unpadded q-orderings in the flattened
            padded (n, 3, K) states.
        sizes: 12 H per object (its q length).
        workspace: the objective's kernels and buffers for these islands (built at their first solve).
    """

    objects: list[int]
    index: torch.Tensor
    slot_of: np.ndarray
    model: Model
    layout: DofLayout
    padded: torch.Tensor
    sizes: list[int]
    workspace: SolveWorkspace | None = None

    def objective_workspace(self, scene: SceneDistance) -> SolveWorkspace:
        """The :class:`SolveWorkspace` of these islands, built on first use."""
        if self.workspace is None:
            object.__setattr__(self, "workspace", SolveWorkspace(self.model, self.layout, scene))
        return self.workspace

    @property
    def nbytes(self) -> int:
        """Memory of the selected model rows, bytes."""
        return _model_bytes(self.model)


class ImplicitEulerSolver:
    """Advances the :class:`State` of a list of :class:`SimBody` by implicit Euler steps of ``dt_s``
    seconds.

    Args:
        bodies: the objects (fixed description and force bookkeeping).
        state: their initial dynamic state, in the same order; the solver owns it (``self.state``) and
            replaces its entries step by step.
        scene: the static scene; gravity_m_s2: (3,) m/s^2; preset: solver settings; dt_s: step, s;
        device: warp device of the broad phase.
        fused_newton: solve groups of one-handle objects with :class:`~data_gen.sim.fused_newton.FusedNewton`
            (one warp launch per solve) instead of :func:`~data_gen.sim.newton.minimise`.
        device_newton: with ``fused_newton``, solve the groups of one-handle objects, and those of deformable ones,
            with :class:`~data_gen.sim.device_newton.DeviceNewton` (Newton's method as launches with a thread per
            element: the GPU's shape; for deformable objects the full Newton matrix every iteration, no kept elastic
            blocks; one-handle islands all their sub-steps in one schedule, as the fused sub-step launch), on
            ``device`` (a GPU: the workspace's model and step data are copied there, the states come back once per
            solve or step).
    """

    def __init__(
        self,
        bodies: list[SimBody],
        state: State,
        scene: StaticScene,
        gravity_m_s2: np.ndarray,
        preset: QualityPreset,
        dt_s: float,
        device: str = "cpu",
        fused_newton: bool = True,
        device_newton: bool = False,
    ) -> None:
        if state.num_objects != len(bodies):
            raise ValueError(f"state holds {state.num_objects} objects for {len(bodies)} bodies")
        self.bodies = bodies
        self.state = state
        self.scene = scene
        self.gravity = torch.as_tensor(np.asarray(gravity_m_s2, dtype=np.float64))
        self.preset = preset
        self.dt = float(dt_s)
        self.fused_newton = bool(fused_newton)
        self.device_newton = self.fused_newton and bool(device_newton)
        self.device = device
        self.broad_phase = BroadPhase([b.contact for b in bodies], float(self.gravity.norm()), device)
        self._cubature_gather = CubatureGather([b.contact for b in bodies])
        self.step_index = 0
        self.timings: dict[str, float] = {"broad_phase": 0.0, "newton": 0.0}
        self.model = Model.build(
            [b.model for b in bodies], [b.contact for b in bodies], [b.friction_coefficient for b in bodies]
        )
        self.scene_distance = SceneDistance(scene)
        self._padded_index = [padded_index(b.model.num_handles, self.model.columns) for b in bodies]
        width = 3 * self.model.columns  # every object's q entries in the flattened padded (n, 3, K) states
        self._all_padded = (
            torch.cat([index + o * width for o, index in enumerate(self._padded_index)])
            if bodies
            else torch.zeros(0, dtype=torch.int64)
        )
        self._median_radius_m = [float(b.radius_m.median()) for b in bodies]
        self._object_id = np.array([b.object_id for b in bodies], dtype=np.int64)
        self._one_handle = [b.model.num_handles == 1 for b in bodies]
        self._groups: OrderedDict[tuple, _GroupSetup] = OrderedDict()
        self._groups_bytes = 0
        self._rigid_workspaces: OrderedDict[tuple[int, ...], list] = OrderedDict()  # [FusedNewton, its layout]
        self._candidate_cache: tuple[tuple, np.ndarray] | None = None  # see _step_candidates
        self._groups_max_bytes = _GROUP_CACHE_MODELS * _model_bytes(self.model)
        self._pair_table_cache: tuple[tuple[float, bytes], tuple[np.ndarray, np.ndarray]] | None = None
        # per object: (qdot tensor, its version, sphere velocities (n, 3) m/s, fastest speed m/s)
        self._velocity_cache: list[tuple[torch.Tensor, int, torch.Tensor, float] | None] = [None] * len(bodies)
        self._record_spheres = True  # this step keeps per-sphere force records (see step)
        # soft objects' elastic Newton matrices kept across (sub)steps (preset.elastic_hessian_reuse)
        self._kept_elastic = (
            KeptElasticMatrices(self.model.cub_c, preset.elastic_hessian_reuse)
            if preset.elastic_hessian_reuse > 0 and self.fused_newton and not all(self._one_handle)
            else None
        )
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
                "fused_island_solves",
                "fused_handed_back",
                "split_island_solves",
                "split_handed_back",
                "device_island_solves",
                "device_handed_back",
                "device_graphs_captured",
                "device_graphs_reused",
                "elastic_matrices_formed",
                "elastic_matrices_reused",
                "elastic_matrices_refreshed",
            ),
            0,
        )

    # ------------------------------------------------------------------ public
    def stiffness(self, k: int, h_s: float) -> float:
        """Scene contact stiffness of object k per contact sphere in a (sub)step of ``h_s`` s: factor * mass / h^2
        (N/m)."""
        return self.preset.contact_stiffness_factor * self.bodies[k].model.mass_kg / h_s**2

    def step(self, record_sphere_forces: bool = True) -> StepStats:
        """Advance all objects by ``dt_s``; raises SimulationError on non-finite values.

        ``record_sphere_forces=False`` skips the per-sphere records (each body's ``contact_force_n``,
        ``contact_partner``, ``partner_strength_n``: they keep an earlier step's values) for a step whose
        records nobody reads (the simulator records every ``substeps_per_frame``-th step); the step's
        statistics (per object pair forces, support, the scene forces a sleeper keeps) are the same.

        The broad phase (:class:`~data_gen.sim.contacts.BroadPhase`, once per step: hash grid, margin
        covering the step's motion) finds the contact candidates; sleepers in candidate contact with a fast
        object are woken, then the candidates split the awake objects into islands (the step's
        :class:`~data_gen.sim.contacts.Contacts`).  Each island near contact is split into sub-steps so that
        none of its contact spheres moves more than ``PAIR_REACH_RADII`` contact radii per sub-step (at
        most ``preset.max_contact_substeps`` unless needed): penalty contact cannot stop a sphere that jumps past its
        partner within one step.  Islands in free flight take the full step.
        """
        stats = StepStats()
        positions = self._contact_positions()
        speeds = [None if asleep else self._max_speed(k) for k, asleep in enumerate(self.state.asleep)]
        pairs = self._step_candidates(positions)  # (its search counts as broad phase time)
        object_pairs = self.broad_phase.object_pairs(pairs)
        self._wake(object_pairs, speeds)  # changes the sleep flags the islands are built from
        contacts = self.broad_phase.contacts(pairs, object_pairs, self.state.asleep)
        islands = contacts.islands
        stats.candidate_pairs = len(contacts.pairs)
        stats.islands = len(islands)
        stats.awake_objects = sum(len(isl) for isl in islands)
        self._record_spheres = record_sphere_forces
        if record_sphere_forces:  # a sleeper's records start from its frozen scene forces; every awake object is
            for b, asleep in zip(self.bodies, self.state.asleep):  # in an island, whose solve writes its records
                if asleep:  # and its scene forces anew
                    b.reset_step_forces()
        supported = np.zeros(len(self.bodies), dtype=bool)
        by_substeps: dict[tuple[int, bool], list[list[int]]] = {}
        for island, num_sub in zip(islands, self._island_substeps(contacts, positions, speeds)):
            # islands that need the same sub-steps: one solve; with the fused solver, islands of one-handle
            # objects only (FusedNewton's) apart from the others
            rigid = self.fused_newton and all(self._one_handle[k] for k in island)
            by_substeps.setdefault((num_sub, rigid), []).append(island)
        keys = sorted(by_substeps)
        # the islands of one-handle objects, whatever their sub-steps, in one fused launch; each sub-step
        # class's records are taken at its place in the sorted order (the events come out in the same order)
        t0 = time.perf_counter()
        records = self._solve_rigid_substeps([(key[0], by_substeps[key]) for key in keys if key[1]],
                                             contacts.pairs, positions, stats, supported)  # fmt: skip
        self.timings["newton"] += time.perf_counter() - t0
        for num_sub, rigid in keys:
            group = by_substeps[(num_sub, rigid)]
            stats.substeps = max(stats.substeps, num_sub)
            h = self.dt / num_sub
            if rigid and num_sub in records:
                t0 = time.perf_counter()
                records[num_sub]()
                self.timings["newton"] += time.perf_counter() - t0
                continue
            members = [k for island in group for k in island]
            member_pairs = self._member_pairs(members, contacts.pairs)
            for _ in range(num_sub):
                t0 = time.perf_counter()
                pair_set = self._island_pairs(*member_pairs, positions, h)
                stats.newton_iterations += self._solve_group(group, pair_set, h, stats, supported)
                for k in members:
                    positions[k] = self.bodies[k].contact_positions(self.state.q[k])
                self.timings["newton"] += time.perf_counter() - t0
        self._record_sleeping_contacts(contacts.pairs, positions, stats, self.dt)
        self._update_sleep(islands, supported)
        self.step_index += 1
        return stats

    def _sphere_velocities(self, k: int) -> tuple[torch.Tensor, float]:
        """Contact sphere velocities (n, 3) m/s of object k at its current rate and the fastest one's
        speed, m/s; kept while its ``qdot`` is the same tensor, unmodified (sleep checks, the next step's
        broad phase and sub-steps ask again)."""
        qdot = self.state.qdot[k]
        cached = self._velocity_cache[k]
        if cached is not None and cached[0] is qdot and cached[1] == qdot._version:
            return cached[2], cached[3]
        velocity = self.bodies[k].contact.velocities(qdot)
        speed = float(velocity.norm(dim=1).max())
        self._velocity_cache[k] = (qdot, qdot._version, velocity, speed)
        return velocity, speed

    def _max_speed(self, k: int) -> float:
        """Fastest contact sphere of object k, m/s."""
        return self._sphere_velocities(k)[1]

    def _sphere_velocity_list(self) -> list[torch.Tensor | None]:
        """Per object: its contact sphere velocities (k, 3) m/s at the current rate, None if asleep (what
        the broad phase's reach reads)."""
        asleep = self.state.asleep
        return [None if asleep[k] else self._sphere_velocities(k)[0] for k in range(len(self.bodies))]

    def _island_substeps(
        self,
        contacts: Contacts,
        positions: list[torch.Tensor],
        speeds: list[float | None],
    ) -> list[int]:
        """Per island of ``contacts``: sub-steps so that no point moves more than PAIR_REACH_RADII radii
        (near another object) or SCENE_REACH_RADII radii (near the static scene only) per sub-step.

        The radius is the object's median contact radius (tiny spheres fitted into edges are covered by
        their neighbours).  Usually at most ``preset.max_contact_substeps``; beyond that cap only when
        the reach demands it, up to ``HARD_SUBSTEP_LIMIT``.  ``speeds``: the objects' fastest sphere (m/s)
        at the start of the step, None for those asleep then.  The objects without object candidates
        query the scene together, once."""
        islands = contacts.islands
        paired = set(contacts.object_pairs.ravel().tolist())
        reach = {
            k: (self._max_speed(k) if speeds[k] is None else speeds[k]) * self.dt
            for island in islands
            for k in island
        }
        alone = [k for island in islands for k in island if k not in paired]
        near_scene: dict[int, bool] = {}
        if alone:
            sdf, _ = self.scene.query(torch.cat([positions[k] for k in alone]))
            ends = np.cumsum([self.bodies[k].contact.num_points for k in alone])
            for k, gap in zip(alone, np.split(sdf, ends[:-1])):  # loop over objects
                near_scene[k] = bool(((gap - self.bodies[k].radius_m.numpy()) < 2.0 * reach[k]).any())
        out = []
        for island in islands:
            worst = 0.0
            for k in island:  # loop over objects
                r_min = self._median_radius_m[k]
                if k in paired:
                    worst = max(worst, reach[k] / (PAIR_REACH_RADII * r_min))
                elif near_scene[k]:
                    worst = max(worst, reach[k] / (SCENE_REACH_RADII * r_min))
            needed = max(1, int(np.ceil(worst)))
            if needed <= self.preset.max_contact_substeps:
                out.append(needed)
                continue
            self.counters["substep_cap_raised"] += 1
            out.append(min(HARD_SUBSTEP_LIMIT, needed))
        return out

    def refresh_forces(self) -> StepStats:
        """Contact forces of the current state without stepping (used for the initial frame)."""
        stats = StepStats()
        positions = self._contact_positions()
        pairs = self.broad_phase.candidates(positions, None, self.dt)
        supported = np.zeros(len(self.bodies), dtype=bool)
        for b in self.bodies:
            b.reset_step_forces()
        bp = self.broad_phase
        islands = bp.contacts(pairs, bp.object_pairs(pairs), self.state.asleep).islands
        if islands:
            members = [k for island in islands for k in island]
            ps = self._island_pairs(*self._member_pairs(members, pairs), positions, self.dt)
            self._record_current_forces(islands, ps, self.dt, stats, supported)
        return stats

    def cubature_contacts(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Per body this step's contact force (n,3) N and dominant partner (n,) per cubature point
        (:meth:`ContactPoints.to_cubature` of its sphere records), all objects in one pass (the same values)."""
        b = self.bodies
        return self._cubature_gather.to_cubature(
            [x.contact_force_n for x in b], [x.contact_partner for x in b], [x.partner_strength_n for x in b],
            NO_PARTNER,
        )  # fmt: skip

    def energies(self) -> dict[str, float]:
        """Kinetic, elastic, contact and gravity potential energy (J) of the current state (its pair search is
        the next step's broad phase, :meth:`_step_candidates`)."""
        state = self.state
        kin = sum(b.model.kinetic_energy(qdot) for b, qdot in zip(self.bodies, state.qdot))
        ela = sum(self._elastic_energies_j().tolist())
        grav = sum(b.model.gravity_energy(q, self.gravity) for b, q in zip(self.bodies, state.q))
        positions = self._contact_positions()
        con = 0.0
        if self.bodies:  # scene contact: one query for all spheres, summed object by object
            sdf, normal = self.scene.query(torch.cat(positions))
            stiffness = torch.cat(
                [torch.full((b.contact.num_points,), self.stiffness(k, self.dt), dtype=DTYPE) for k, b in enumerate(self.bodies)]
            )
            energy, _, _ = point_terms.penalty(
                self.broad_phase.radii_all - torch.from_numpy(sdf), torch.from_numpy(normal), stiffness, False
            )
            for part in energy.split([b.contact.num_points for b in self.bodies]):  # loop over objects
                con += float(part.sum())
        # pairs in contact: among the next step's candidates (a superset; the next step reuses them)
        pairs = self._step_candidates(positions)
        if len(pairs):
            x_np = torch.cat(positions).numpy()
            d = x_np[pairs[:, 0]] - x_np[pairs[:, 1]]
            radii = self.broad_phase.radii_all.numpy()
            pairs = pairs[np.sqrt((d * d).sum(1)) < radii[pairs[:, 0]] + radii[pairs[:, 1]]]
        if len(pairs):
            point_object, radii_all = self.broad_phase.point_object, self.broad_phase.radii_all
            oi, oj = point_object[pairs[:, 0]], point_object[pairs[:, 1]]
            x_all = torch.cat(positions)
            k = torch.from_numpy(self._pair_tables(self.dt)[0][oi, oj])
            rs = radii_all[pairs[:, 0]] + radii_all[pairs[:, 1]]
            con += pair_contact(x_all[pairs[:, 0]], x_all[pairs[:, 1]], rs, k).energy
        return {"kinetic": kin, "elastic": ela, "contact": con, "gravity": grav}

    # ------------------------------------------------------------------ sphere positions, waking, sleep
    def _step_candidates(self, positions: list[torch.Tensor]) -> np.ndarray:
        """The broad phase's candidate pairs of a step of ``dt`` from the current state (sphere centres
        ``positions``, velocities at the current rates, sleep flags); kept while the states, rates and flags are
        the same (the energies of a recorded frame ask first, the step after it reuses them)."""
        state = self.state
        # the tensors themselves (compared with `is`: kept alive here, no new tensor can take their place)
        key = (list(state.q), [q._version for q in state.q], list(state.qdot), [v._version for v in state.qdot],
               state.asleep.tobytes(), self.dt)  # fmt: skip
        cached = self._candidate_cache
        if cached is not None and _same_state_key(cached[0], key):
            return cached[1]
        t0 = time.perf_counter()
        try:
            pairs = self.broad_phase.candidates(positions, self._sphere_velocity_list(), self.dt)
        except NonFiniteInput as e:  # (the states are checked after every solve: a guard, not a path)
            raise SimulationError(f"step {self.step_index}: broad phase: {e}") from None
        self.timings["broad_phase"] += time.perf_counter() - t0
        self._candidate_cache = (key, pairs)
        return pairs

    def _elastic_energies_j(self) -> torch.Tensor:
        """(n,) elastic energy of each object at the current state, J: one batched evaluation over the
        solver's model (a one-handle object's uniform F on its single cubature point of the whole volume)."""
        n, k = len(self.bodies), self.model.columns
        tm = torch.zeros(n * 3 * k, dtype=DTYPE)
        if n:
            tm[self._all_padded] = torch.cat(list(self.state.q))
        m = self.model
        return elastic(m.cub_c, m.cub_volume_m3, m.mu_pa, m.lam_pa, m.spd_tolerance_pa, tm.reshape(n, 3, k), False).energy

    def _contact_positions(self) -> list[torch.Tensor]:
        """Per object: (k,3) world contact sphere centres, m, of the current state."""
        return [b.contact_positions(q) for b, q in zip(self.bodies, self.state.q)]

    def _wake(self, object_pairs: np.ndarray, speeds: list[float | None]) -> None:
        """Wake sleepers in candidate contact with an object that was awake at the start of the step and is
        faster than the sleep speed (``speeds``, m/s, None for objects asleep then: one woken here has
        no speed and wakes nobody)."""
        asleep, slow_steps = self.state.asleep, self.state.slow_steps
        for a, c in object_pairs:  # loop over object pairs
            for mover, sleeper in ((a, c), (c, a)):
                speed = speeds[mover]
                if (
                    asleep[sleeper]
                    and not asleep[mover]
                    and speed is not None
                    and speed > self.preset.sleep_speed_m_s
                ):
                    asleep[sleeper] = False
                    slow_steps[sleeper] = 0

    def _update_sleep(self, islands: list[list[int]], supported: np.ndarray) -> None:
        """Count the slow, supported steps of the islands' objects; put to sleep (rate zeroed) those slow
        for ``preset.sleep_steps`` steps."""
        threshold = self.preset.sleep_speed_m_s
        state = self.state
        for island in islands:
            for k in island:
                speed = self._max_speed(k)
                if threshold > 0 and speed < threshold and supported[k]:
                    state.slow_steps[k] += 1
                else:
                    state.slow_steps[k] = 0
                if state.slow_steps[k] >= self.preset.sleep_steps:
                    state.asleep[k] = True
                    state.qdot[k] = torch.zeros_like(state.qdot[k])

    def _pair_tables(self, h_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Per object pair: contact stiffness (N/m) = factor * reduced mass / h^2 in a (sub)step of ``h_s`` s (a
        sleeping partner counts as infinitely heavy) and friction coefficient sqrt(mu_a mu_c).  Kept while h and
        the sleep flags stay the same (every sub-step of a step)."""
        asleep = self.state.asleep.copy()
        key = (h_s, asleep.tobytes())
        if self._pair_table_cache is not None and self._pair_table_cache[0] == key:
            return self._pair_table_cache[1]
        mass = np.array([b.model.mass_kg for b in self.bodies])
        reduced = mass[:, None] * mass[None, :] / (mass[:, None] + mass[None, :])
        reduced = np.where(asleep[None, :], mass[:, None], np.where(asleep[:, None], mass[None, :], reduced))
        mu = np.array([b.friction_coefficient for b in self.bodies])
        tables = self.preset.contact_stiffness_factor * reduced / h_s**2, np.sqrt(mu[:, None] * mu[None, :])
        self._pair_table_cache = (key, tables)
        return tables

    def _member_pairs(self, members: list[int], pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The candidate point pairs (global indices gi, gj) touching some of ``members``, oriented so that
        side i is on a member."""
        is_member = np.zeros(len(self.bodies), dtype=bool)
        is_member[members] = True
        sel = pairs if len(pairs) else np.zeros((0, 2), dtype=np.int64)
        inside = is_member[self.broad_phase.point_object[sel]]  # (P, 2)
        if inside[:, 0].all():  # every pair's side i is a member already (every awake object in one solve)
            return sel[:, 0], sel[:, 1]
        touching = inside[:, 0] | inside[:, 1]
        sel = sel[touching]
        swap = ~inside[touching, 0]  # orient every pair so that side i is an island member
        return np.where(swap, sel[:, 1], sel[:, 0]), np.where(swap, sel[:, 0], sel[:, 1])

    def _island_pairs(self, gi: np.ndarray, gj: np.ndarray, positions: list[torch.Tensor], h_s: float,
                      within_substep: bool = True) -> _PairSet:  # fmt: skip
        """The pair set of a (sub)step of ``h_s`` s from the members' candidate pairs (:meth:`_member_pairs`) and
        the current sphere positions (m), with its start data; in a sub-step, only the pairs that can touch within
        it unless not ``within_substep`` (all the step's candidates). The fused sub-steps, which compute the start
        data in their launch, take :meth:`_pair_set_without_start` instead."""
        x_all = torch.cat(positions) if positions else torch.zeros(0, 3, dtype=DTYPE)
        if len(gi) and h_s < self.dt and within_substep:
            # a sub-step: keep the step's candidates that can touch within this (shorter) sub-step
            near = self.broad_phase.within_reach(gi, gj, x_all.numpy(), self._sphere_velocity_list(), h_s)
            gi, gj = gi[near], gj[near]
        oi, li, oj, lj, k, mu, rs = self._pair_columns(gi, gj, h_s)
        gi_t, gj_t = torch.from_numpy(gi), torch.from_numpy(gj)
        x0j = x_all[gj_t]
        x0i = x_all[gi_t]
        if len(gi):  # the frozen normal force and normal of the start state
            depth, n0 = pair_depth(x0i, x0j, rs)
            lam = k * depth.clamp(min=0.0)
        else:
            lam, n0 = torch.zeros(0, dtype=DTYPE), torch.zeros(0, 3, dtype=DTYPE)
        return _PairSet(oi, li, oj, lj, k, rs, mu, lam, n0, x0i, x0j, gi_t, gj_t)

    def _pair_columns(self, gi: np.ndarray, gj: np.ndarray, h_s: float) -> tuple:
        """Per pair (global sphere indices gi, gj): objects and local spheres (oi, li, oj, lj), contact stiffness
        (N/m) in a (sub)step of ``h_s`` s and friction coefficient, and the radius sum (m)."""
        bp = self.broad_phase
        oi, oj = bp.point_object[gi], bp.point_object[gj]
        stiffness, friction = self._pair_tables(h_s)
        radii = bp.radii_all.numpy()
        rs = torch.from_numpy(radii[gi] + radii[gj])
        flat = oi * stiffness.shape[1] + oj  # (one gather per table instead of a two-index one)
        k, mu = torch.from_numpy(stiffness.ravel().take(flat)), torch.from_numpy(friction.ravel().take(flat))
        return oi, gi - bp.offsets[oi], oj, gj - bp.offsets[oj], k, mu, rs

    def _pair_set_without_start(self, gi: np.ndarray, gj: np.ndarray, positions: list[torch.Tensor],
                                h_s: float, members: list[int]) -> _PairSet:  # fmt: skip
        """:meth:`_island_pairs` of a whole step's candidates (they serve every sub-step) without start data (the
        fused sub-steps compute them: ``x0_i``, ``normal0``, ``lam_n`` None): ``x0_j`` holds side j's position where side j is off the island objects ``members`` (a sleeping
        partner, frozen in the solve) and zero elsewhere (nothing reads it there)."""
        oi, li, oj, lj, k, mu, rs = self._pair_columns(gi, gj, h_s)
        gi_t, gj_t = torch.from_numpy(gi), torch.from_numpy(gj)
        x0j = torch.zeros(len(gj), 3, dtype=DTYPE)
        member = np.zeros(len(self.bodies), dtype=bool)
        member[members] = True
        off = np.flatnonzero(~member[oj])
        if len(off):
            rows = torch.from_numpy(off)
            x0j[rows] = torch.cat(positions)[gj_t[rows]]
        return _PairSet(oi, li, oj, lj, k, rs, mu, None, None, None, x0j, gi_t, gj_t)

    # ------------------------------------------------------------------ Newton on a group of islands
    def _group_setup(self, islands: list[list[int]], sorted_objects: bool = False) -> _GroupSetup:
        """The objects, selected model rows and DOF layout of a solve of ``islands`` (cached per islands). The
        objects come island by island, or with ``sorted_objects`` in ascending order (the same objects grouped
        otherwise keep their slots; an island's objects and its unknowns are in the same order either way)."""
        key = (sorted_objects, *(tuple(island) for island in islands))
        setup = self._groups.get(key)
        if setup is not None:
            self._groups.move_to_end(key)
            return setup
        island_of = {k: a for a, island in enumerate(islands) for k in island}
        objects = sorted(island_of) if sorted_objects else [k for island in islands for k in island]
        island_slot = torch.tensor([island_of[k] for k in objects], dtype=torch.int64)
        slot_of = np.full(len(self.bodies), -1, dtype=np.int64)
        slot_of[objects] = np.arange(len(objects))
        index = torch.tensor(objects, dtype=torch.int64)
        model = self.model.select(index)
        width = 3 * self.model.columns
        padded = [self._padded_index[o] + slot * width for slot, o in enumerate(objects)]
        setup = _GroupSetup(
            objects=objects,
            index=index,
            slot_of=slot_of,
            model=model,
            layout=DofLayout.build(model.num_handles, island_slot, model.columns),
            padded=torch.cat(padded) if padded else torch.zeros(0, dtype=torch.int64),
            sizes=[int(index.shape[0]) for index in padded],
        )
        self._groups[key] = setup
        self._groups_bytes += setup.nbytes
        while len(self._groups) > 1 and (
            len(self._groups) > _GROUP_CACHE_SIZE or self._groups_bytes > self._groups_max_bytes
        ):  # drop the least recently used
            self._groups_bytes -= self._groups.popitem(last=False)[1].nbytes
        return setup

    def _padded_states(self, setup: _GroupSetup) -> tuple[torch.Tensor, torch.Tensor]:
        """Padded (n, 3, K) states q and rates qdot of a solve's bodies."""
        n, k = len(setup.objects), self.model.columns
        tm = torch.zeros(n * 3 * k, dtype=DTYPE)
        tmdot = torch.zeros_like(tm)
        if n:
            tm[setup.padded] = torch.cat([self.state.q[o] for o in setup.objects])
            tmdot[setup.padded] = torch.cat([self.state.qdot[o] for o in setup.objects])
        return tm.reshape(n, 3, k), tmdot.reshape(n, 3, k)

    def _group_pairs(self, objects: list[int], slot_of: np.ndarray, ps: _PairSet) -> PairSet:
        """The candidate pairs of a solve in solved-object slots (sleeping partners frozen); without start data in
        ``ps`` (``lam_n`` None) the pair set's start data are None too (left to the fused sub-steps' launch)."""
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
            friction=None if ps.lam_n is None else ps.mu * (ps.lam_n > 0),
            normal_force_n=ps.lam_n,
            normal0=ps.normal0,
            x0_i=ps.x0_i,
            x0_j=None if ps.lam_n is None else ps.x0_j,
        )

    def _solve_group(self, islands: list[list[int]], ps: _PairSet, h: float, stats: StepStats,
                     supported: np.ndarray) -> int:
        """One implicit Euler (sub)step of size h for several independent islands at once; records the
        contact forces of the final state. Returns the Newton iterations summed over the islands."""
        setup = self._group_setup(islands)
        objects, slot_of, model, layout = setup.objects, setup.slot_of, setup.model, setup.layout
        self.counters["island_solves"] += len(islands)
        self.counters["island_object_solves"] += len(objects)
        tm_n, tmdot = self._padded_states(setup)
        kept = self._kept_elastic if not self.device_newton else None  # (the device solve keeps no matrices)
        if kept is not None and not any(self._one_handle[k] for k in objects):  # (one group of soft objects)
            strain = kept.strain(setup.index, tm_n + h * tmdot)  # at the predicted start, where K is formed
            reused = kept.lookup(setup.index, strain)
        else:
            strain = reused = None
        objective = StepObjective(
            model, layout, self.scene_distance, self.gravity, tm_n, tmdot, h,
            self.preset.contact_stiffness_factor, self.preset.friction_smoothing_m_s * h,
            self._group_pairs(objects, slot_of, ps), setup.objective_workspace(self.scene_distance),
            lagged_elastic_hessian=self.preset.lagged_elastic_hessian, kernel_evaluation=self.fused_newton,
            reused_elastic_hessian=reused,
        )  # fmt: skip

        def check_gradient(grad: torch.Tensor) -> None:
            if bool(torch.isfinite(grad).all()):
                return
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
        settings = NewtonSettings(
            self.preset.newton_iterations, self.preset.newton_tolerance, self.preset.line_search_steps
        )
        # one-handle islands: the whole solve in one launch; deformable islands with a kept elastic matrix: the
        # kernel iterates, the host factorises (both compute the step's convergence scale and trust radius)
        fused = objective.workspace.fused if self.fused_newton else None
        split = objective.evaluator if fused is None and self.preset.lagged_elastic_hessian else None
        # with device_newton: every group on a FusedNewton workspace of its objects (for deformable ones the full
        # Newton matrix every iteration: no kept elastic blocks)
        on_device = objective.workspace.any_fused if self.device_newton else None
        result, kind = None, None
        if on_device is not None:
            result, kind = self._device_newton_of(on_device).solve(objective, q0, None, None, settings), "device"
        elif fused is not None:
            result, kind = fused.solve(objective, q0, None, None, settings), "fused"
        elif split is not None:
            result, kind = split.solve_split(objective, q0, None, None, settings), "split"
        if kind is not None:
            self.counters[f"{kind}_handed_back" if result is None else f"{kind}_island_solves"] += (
                1 if result is None else len(islands)
            )
        # the solve's last state is its workspace's (fused, split or the device schedule's)
        kernel = on_device if on_device is not None else fused if fused is not None else split
        from_kernel = kernel is not None and result is not None  # the recorder reads the forces the kernel computes
        if result is None:  # not fused, or an island needs what only minimise does (projection, the error)
            result = minimise(objective, q0, objective.motion_scale(), objective.trust_radius(), settings,
                              on_gradient=check_gradient, on_indefinite=indefinite)  # fmt: skip
        for key, value in result.counters.items():
            self.counters[key] += value
        if strain is not None and objective.formed_elastic_hessian is not None:
            if objective.refreshed_elastic_hessian:  # formed anew during the solve, at its states then
                strain = kept.strain(setup.index, objective.formed_elastic_tm)
                self.counters["elastic_matrices_refreshed"] += 1
            kept.keep(setup.index, strain, objective.formed_elastic_mask, objective.formed_elastic_hessian)
            self.counters["elastic_matrices_formed"] = kept.formed
            self.counters["elastic_matrices_reused"] = kept.reused
        tm = layout.to_objects(result.q)
        q = tm.reshape(-1)[setup.padded]  # the objects' unpadded states, concatenated
        if not bool(torch.isfinite(q).all()):
            self._check_finite(objects, list(q.split(setup.sizes)), "reduced state q")
        qdot = (q - torch.cat([self.state.q[o] for o in objects])) / h
        for o, q_o, qdot_o in zip(objects, q.split(setup.sizes), qdot.split(setup.sizes)):  # once per solve
            self.state.q[o] = q_o
            self.state.qdot[o] = qdot_o
        forces = kernel.forces() if from_kernel else objective.forces(tm)
        self._record_group_forces(objects, forces, ps, objective.pairs, model.sphere_valid, h, stats, supported)
        return int(result.iterations.sum())

    def _device_newton_of(self, workspace: FusedNewton) -> DeviceNewton:
        """The :class:`DeviceNewton` of a fused workspace (kept with it), on the broad phase's device: a GPU next
        to the CPU workspace gets copies."""
        if workspace.device_newton is None:
            here = wp.get_device(self.device) == wp.get_device(workspace.device)
            workspace.device_newton = DeviceNewton(workspace, device=None if here else self.device,
                                                   timings=self.timings, counters=self.counters)  # fmt: skip
        return workspace.device_newton

    def _solve_rigid_substeps(self, parts: list[tuple[int, list[list[int]]]], pairs_all: np.ndarray,
                              positions: list[torch.Tensor], stats: StepStats,
                              supported: np.ndarray) -> dict[int, Callable[[], None]]:  # fmt: skip
        """Every sub-step of the one-handle islands ``parts`` ((sub-steps, islands) in sorted order) in one fused
        launch (:meth:`FusedNewton.solve_substeps`, each island with its own sub-step): the step's candidate
        pairs of each part (stiffness and friction of its sub-step) serve all its sub-steps, the states and
        ``positions`` end at the new states. Returns per sub-step count a callable that records that part's
        contact forces of each sub-step as :meth:`_solve_group` records them (to be called at the part's place in
        the step). Parts left out (an empty dict when none is left): those beyond ``FUSED_MAX_SUBSTEPS``, and all
        of them when the launch needs ``minimise`` somewhere unless, launched part by part, some part does
        not; the caller solves those sub-step by sub-step."""
        parts = [(n, group) for n, group in parts if n <= FUSED_MAX_SUBSTEPS]
        if not parts:
            return {}
        launched = self._launch_rigid_parts(parts, pairs_all, positions, stats, supported)
        if launched is not None or len(parts) == 1:
            return launched or {}
        records: dict[int, Callable[[], None]] = {}
        for part in parts:  # one part needs minimise: the others still take one launch each
            records.update(self._launch_rigid_parts([part], pairs_all, positions, stats, supported) or {})
        return records

    def _rigid_workspace(self, setup: _GroupSetup) -> FusedNewton | None:
        """The fused workspace of ``setup``'s objects (in its order), regrouped into its islands: one per object
        sequence (the awake one-handle objects of a pile change far less often than their islands), kept for the
        ``_FUSED_CACHE_SIZE`` sequences used last; None when the islands do not fit the kernel."""
        key = tuple(setup.objects)
        entry = self._rigid_workspaces.get(key)
        if entry is None:
            fused = rigid_fused_workspace(setup.model, setup.layout, self.scene_distance)
            if fused is None:
                return None
            self._rigid_workspaces[key] = [fused, setup.layout]
            while len(self._rigid_workspaces) > _FUSED_CACHE_SIZE:
                self._rigid_workspaces.popitem(last=False)
            return fused
        self._rigid_workspaces.move_to_end(key)
        fused, layout = entry
        if layout is not setup.layout:
            if not fused_fits(setup.layout):
                return None
            fused.relayout(setup.layout, *island_constants(setup.model, setup.layout))
            entry[1] = setup.layout
        return fused

    def _launch_rigid_parts(self, parts: list[tuple[int, list[list[int]]]], pairs_all: np.ndarray,
                            positions: list[torch.Tensor], stats: StepStats,
                            supported: np.ndarray) -> dict[int, Callable[[], None]] | None:  # fmt: skip
        """:meth:`_solve_rigid_substeps` in one launch; None (nothing changed) when the group has no fused
        workspace or a sub-step of some island needs ``minimise``."""
        islands = [island for _, group in parts for island in group]
        setup = self._group_setup(islands, sorted_objects=True)  # slots kept while the awake objects are
        fused = self._rigid_workspace(setup)
        if fused is None:
            return None
        objects, slot_of, model = setup.objects, setup.slot_of, setup.model
        # each part's candidate pairs with its sub-step's stiffness (contiguous rows) and its objects' slots
        # and its object pairs: each part's candidate pairs grouped by (object i, object j), groups numbered
        # part by part in sorted order (the statistics' sums per group come out of the launch)
        part_pairs, slots, rows, group_ranges, group_objects, pair_group = [], [], [], [], [], []
        p0 = g0 = 0
        nb = len(self.bodies)
        for num_sub, group in parts:
            members = [k for island in group for k in island]
            ps = self._pair_set_without_start(*self._member_pairs(members, pairs_all), positions, self.dt / num_sub,
                                              members)  # fmt: skip
            part_pairs.append(ps)
            slots.append(torch.from_numpy(slot_of[members]))
            rows.append((p0, p0 + len(ps.obj_i)))
            p0 = rows[-1][1]
            keys, local = _distinct_codes(ps.obj_i * nb + ps.obj_j, nb * nb)
            pair_group.append(local + g0)
            group_ranges.append((g0, g0 + len(keys)))
            group_objects.append((keys // nb, keys % nb))
            g0 += len(keys)
        ps = part_pairs[0] if len(parts) == 1 else _concat_pair_sets(part_pairs)
        pairs = self._group_pairs(objects, slot_of, ps)
        tm_n, tmdot = self._padded_states(setup)
        settings = NewtonSettings(
            self.preset.newton_iterations, self.preset.newton_tolerance, self.preset.line_search_steps
        )
        h_island = [self.dt / num_sub for num_sub, group in parts for _ in group]
        h_of = {k: self.dt / num_sub for num_sub, group in parts for island in group for k in island}
        h_object = torch.tensor([h_of[k] for k in objects], dtype=DTYPE)  # each object's sub-step, s
        scene_k = self.preset.contact_stiffness_factor * model.mass_kg / (h_object * h_object)
        kind = "device" if self.device_newton else "fused"
        substeps = self._device_newton_of(fused) if self.device_newton else fused  # (the same call on either)
        result = substeps.solve_substeps(
            tm_n, tmdot, h_island, [num_sub for num_sub, group in parts for _ in group], self.gravity, settings,
            scene_k, [self.preset.friction_smoothing_m_s * h for h in h_island], pairs, ps.mu,
            self.broad_phase.margin_m, np.concatenate(pair_group),
        )  # fmt: skip
        if result is None:
            self.counters[f"{kind}_handed_back"] += 1
            return None
        for key, value in result.counters.items():
            self.counters[key] += value
        for num_sub, group in parts:
            self.counters["island_solves"] += num_sub * len(group)
            self.counters["island_object_solves"] += num_sub * sum(len(island) for island in group)
            self.counters[f"{kind}_island_solves"] += num_sub * len(group)
        stats.newton_iterations += int(result.iterations.sum())
        q = result.tm.reshape(-1)[setup.padded]
        qdot = result.tmdot.reshape(-1)[setup.padded]
        if not bool(torch.isfinite(q).all()):
            self._check_finite(objects, list(q.split(setup.sizes)), "reduced state q")
        # every object's sphere centres and velocities at once (one-handle objects: (S, 4) basis rows each),
        # left in the bodies' and the solver's caches as contact_positions / _sphere_velocities would compute them
        x_all = model.sphere_rest_m + torch.bmm(model.sphere_b, result.tm.transpose(1, 2))  # (n, S, 3) m
        v_all = torch.bmm(model.sphere_b, result.tmdot.transpose(1, 2))  # (n, S, 3) m/s (padded rows: 0)
        speeds = v_all.norm(dim=2).amax(1).tolist()  # fastest sphere per object, m/s
        for slot, (o, q_o, qdot_o) in enumerate(zip(objects, q.split(setup.sizes), qdot.split(setup.sizes))):
            self.state.q[o] = q_o
            self.state.qdot[o] = qdot_o
            k = self.bodies[o].contact.num_points
            positions[o] = self.bodies[o].cache_contact_positions(q_o, x_all[slot, :k])
            self._velocity_cache[o] = (qdot_o, qdot_o._version, v_all[slot, :k], speeds[slot])

        def record(num_sub: int, part_ps: _PairSet, part_slots: torch.Tensor, row_range: tuple[int, int],
                   group_range: tuple[int, int], part_groups: tuple[np.ndarray, np.ndarray]) -> None:  # fmt: skip
            h = self.dt / num_sub
            sub = result.part(part_slots, row_range, num_sub, group_range)
            part_objects = [objects[slot] for slot in part_slots.tolist()]  # island by island
            valid = model.sphere_valid[part_slots]
            self._record_substep_statistics(part_objects, sub, part_groups, valid, h, stats, supported)
            if self._record_spheres:
                self._record_substep_sphere_forces(part_objects, sub, part_ps, valid, h)

        return {
            num_sub: partial(record, num_sub, part_ps, part_slots, row_range, group_range, part_groups)
            for (num_sub, _), part_ps, part_slots, row_range, group_range, part_groups
            in zip(parts, part_pairs, slots, rows, group_ranges, group_objects)
        }

    def _record_substep_statistics(self, objects: list[int], result: SubstepResult,
                                   groups: tuple[np.ndarray, np.ndarray], sphere_valid: torch.Tensor, h: float,
                                   stats: StepStats, supported: np.ndarray) -> None:  # fmt: skip
        """What :meth:`_record_group_forces` records for each sub-step of ``result`` in a step whose per-sphere
        records nobody reads, from the launch's force sums (``result.scene_sums`` per object, ``pair_sums`` per
        group of pairs, the groups' objects ``groups`` = (object i, object j) in sorted order): the step
        statistics (per sub-step and object pair, in the same order), support, and each object's scene forces and
        summary of the last sub-step (kept if it falls asleep)."""
        scene = result.scene_sums.numpy()  # (J, n, 10)
        touching = scene[..., 9] > 0  # (J, n): some sphere pushed by the scene
        total_np = scene[..., 0:3]
        pos_np = scene[..., 3:6] / np.maximum(scene[..., 9:10], 1e-300)
        nrm_np = scene[..., 6:9]
        nrm_np = nrm_np / np.maximum(np.sqrt((nrm_np[..., None, :] @ nrm_np[..., :, None])[..., 0]), 1e-300)
        ids = [self.bodies[o].object_id for o in objects]
        pair_sums = result.pair_sums.numpy()  # (J, G, 10)
        active = pair_sums[..., 9] > 0  # (J, G): some pair of the group pushed
        group_a, group_c = groups
        if active.any():
            live = active.any(0)
            supported[group_a[live]] = True
            sleeping_c = group_c[live][self.state.asleep[group_c[live]]]
            supported[sleeping_c] = True
        supported[np.asarray(objects)[touching.any(0)]] = True
        # sub-step by sub-step the scene contacts, then the object pairs, all at once
        pair_keys, pair_total, pair_pos, pair_nrm = self._object_pair_entries(group_a, group_c, pair_sums)
        stats.add_pair_force_series(
            [(int(i), 0) for i in ids] + pair_keys,
            np.concatenate([total_np, pair_total], axis=1),
            np.concatenate([pos_np, pair_pos], axis=1),
            np.concatenate([nrm_np, pair_nrm], axis=1),
            np.concatenate([touching, active], axis=1),
            h,
        )
        last = touching.shape[0] - 1
        force = result.scene_force_at(last) * sphere_valid[:, :, None]  # (n, S, 3)
        for slot, o in enumerate(objects):  # what an object that falls asleep now keeps
            b = self.bodies[o]
            b.static_force_n = force[slot, : b.contact.num_points]
            b.static_summary = (
                (total_np[last, slot], pos_np[last, slot], nrm_np[last, slot]) if touching[last, slot] else None
            )

    def _record_substep_sphere_forces(self, objects: list[int], result: SubstepResult, ps: _PairSet,
                                      sphere_valid: torch.Tensor, h_s: float) -> None:  # fmt: skip
        """The per-sphere records (contact force, partner and its strength) that one :meth:`_record_group_forces`
        call per sub-step of ``result`` leaves (the statistics: :meth:`_record_substep_statistics`): each call
        starts the records of ``objects`` anew, so theirs are the last sub-step's; a sleeping partner collects
        the pair forces of every sub-step, in order, so earlier sub-steps add only their pairs with a sleeping
        side j."""
        last = result.num_substeps - 1
        asleep_j = self.state.asleep[ps.obj_j]  # (P,) bool
        any_asleep_j = bool(asleep_j.any())
        for j in range(last + 1):  # (the two stacked forces it reads, not every field of result.forces)
            if j == last:  # the records start from this sub-step's scene forces
                force = result.scene_force_at(j) * sphere_valid[:, :, None]
                self._start_sphere_records(objects, force, force.norm(dim=2))
            if not len(asleep_j) or (j < last and not any_asleep_j):  # earlier sub-steps: sleeping partners only
                continue
            pair_force = result.pair_force_i_n[j]
            live = (pair_force != 0).any(1)
            if j < last:
                live = live & torch.from_numpy(asleep_j)
            rows = torch.nonzero(live)[:, 0]
            if len(rows):
                r = rows.numpy()
                self._accumulate_pair_forces(ps.obj_i[r], ps.loc_i[r], ps.obj_j[r], ps.loc_j[r], None, None,
                                             pair_force[rows], None, h_s, None, None)  # fmt: skip

    def _start_sphere_records(self, objects: list[int], force: torch.Tensor, magnitude: torch.Tensor) -> None:
        """:meth:`SimBody.reset_step_forces` of ``objects`` at once, from their scene forces (n, S, 3) N and
        magnitudes (n, S) N (the records keep views of ``force``): partner the scene where a force acts."""
        partner = torch.where(magnitude > 0, 0, NO_PARTNER)
        for slot, o in enumerate(objects):  # bookkeeping only
            b = self.bodies[o]
            k = b.contact.num_points
            b.contact_force_n = force[slot, :k]
            b.partner_strength_n = magnitude[slot, :k]
            b.contact_partner = partner[slot, :k]

    def _record_current_forces(self, islands: list[list[int]], ps: _PairSet, h: float, stats: StepStats,
                               supported: np.ndarray) -> None:  # fmt: skip
        """Contact forces of the current state without stepping (the initial frame): the step of ``h`` s that
        led here is taken to have started at ``q - h qdot``."""
        setup = self._group_setup(islands)
        objects, slot_of, model, layout = setup.objects, setup.slot_of, setup.model, setup.layout
        tm, tmdot = self._padded_states(setup)
        objective = StepObjective(
            model, layout, self.scene_distance, self.gravity, tm - h * tmdot, tmdot, h,
            self.preset.contact_stiffness_factor, self.preset.friction_smoothing_m_s * h,
            self._group_pairs(objects, slot_of, ps), setup.objective_workspace(self.scene_distance),
        )  # fmt: skip
        self._record_group_forces(objects, objective.forces(tm), ps, objective.pairs, model.sphere_valid, h, stats,
                                  supported)  # fmt: skip

    def _check_finite(self, objects: list[int], parts: list[torch.Tensor], quantity: str) -> None:
        for k, part in zip(objects, parts):
            if not bool(torch.isfinite(part).all()):
                raise SimulationError(
                    f"object {self.bodies[k].name!r} (id {self.bodies[k].object_id}), "
                    f"step {self.step_index}: non-finite {quantity}"
                )

    # ------------------------------------------------------------------ force recording
    def _record_group_forces(self, objects: list[int], forces: ContactForces, ps: _PairSet, pairs: PairSet,
                             sphere_valid: torch.Tensor, h: float, stats: StepStats, supported: np.ndarray) -> None:
        """Per-sphere contact forces (N) of the final state, dominant partner ids, per-pair totals, from
        the forces the objective evaluated (nothing is recomputed here)."""
        force = forces.scene_force_n * sphere_valid[:, :, None]
        mag = force.norm(dim=2)  # (n, S)
        total = force.sum(1)
        weight = mag.sum(1).clamp(min=1e-300)
        x = forces.sphere_positions_m
        pos = (mag[:, :, None] * x).sum(1) / weight[:, None]
        nrm = (mag[:, :, None] * forces.scene_normals).sum(1)
        nrm = nrm / nrm.norm(dim=1, keepdim=True).clamp(min=1e-300)
        touching = (mag > 0).any(1).numpy()
        total_np, pos_np, nrm_np = total.numpy(), pos.numpy(), nrm.numpy()
        record = self._record_spheres
        if record:  # the step's forces start from the scene's, pair forces are added below
            self._start_sphere_records(objects, force.clone(), mag)
        for slot, o in enumerate(objects):  # once per (sub)step: bookkeeping only
            b = self.bodies[o]
            b.static_force_n = force[slot, : b.contact.num_points]  # (kept by an object that falls asleep now)
            if touching[slot]:
                supported[o] = True
                b.static_summary = (total_np[slot], pos_np[slot], nrm_np[slot])
                stats.add_pair_force((b.object_id, 0), *b.static_summary, h)
            else:
                b.static_summary = None
        if pairs.num_pairs == 0:
            return
        rows = torch.nonzero((forces.pair_force_i_n != 0).any(1))[:, 0]  # the pairs in contact (in order)
        if not len(rows):
            return
        obj_j, frozen = pairs.obj_j[rows], pairs.obj_j[rows] < 0
        xi = x[pairs.obj_i[rows], pairs.sph_i[rows]]
        xj = torch.where(frozen[:, None], pairs.frozen_x_j[rows], x[obj_j.clamp(min=0), pairs.sph_j[rows]])
        r = rows.numpy()
        self._accumulate_pair_forces(
            ps.obj_i[r], ps.loc_i[r], ps.obj_j[r], ps.loc_j[r], xi, xj, forces.pair_force_i_n[rows],
            forces.pair_normals[rows], h, stats, supported,
        )  # fmt: skip

    def _record_sleeping_contacts(
        self, pairs: np.ndarray, positions: list[torch.Tensor], stats: StepStats, h_s: float
    ) -> None:
        """Frozen scene contacts of sleeping objects and normal forces between two sleeping objects over a step
        of ``h_s`` s."""
        asleep = self.state.asleep
        for b, sleeping in zip(self.bodies, asleep):
            if sleeping and b.static_summary is not None:
                stats.add_pair_force((b.object_id, 0), *b.static_summary, h_s)
        if not len(pairs):
            return
        bp = self.broad_phase
        oi, oj = bp.point_object[pairs[:, 0]], bp.point_object[pairs[:, 1]]
        both = asleep[oi] & asleep[oj]
        if not both.any():
            return
        gi, gj = pairs[both, 0], pairs[both, 1]
        oi, oj = oi[both], oj[both]
        x_all = torch.cat(positions)
        mass = np.array([b.model.mass_kg for b in self.bodies])
        k = torch.from_numpy(
            self.preset.contact_stiffness_factor * np.minimum(mass[oi], mass[oj]) / h_s**2
        )
        pc = pair_contact(x_all[gi], x_all[gj], bp.radii_all[gi] + bp.radii_all[gj], k)
        self._accumulate_pair_forces(
            oi,
            gi - bp.offsets[oi],
            oj,
            gj - bp.offsets[oj],
            x_all[gi],
            x_all[gj],
            -pc.grad_i,
            pc.normal_ji,
            h_s,
            stats,
            np.zeros(len(self.bodies), dtype=bool),
        )

    def _accumulate_pair_forces(
        self,
        obj_i: np.ndarray,
        loc_i: np.ndarray,
        obj_j: np.ndarray,
        loc_j: np.ndarray,
        xi: torch.Tensor | None,
        xj: torch.Tensor | None,
        f_i: torch.Tensor,
        normal_ji: torch.Tensor | None,
        h_s: float,
        stats: StepStats | None,
        supported: np.ndarray | None,
    ) -> None:
        """Add pair forces (N, on side i; side j gets the opposite) of a (sub)step of ``h_s`` s to per-point
        records and pair totals.

        One pass over all pairs, grouped by object pair (a, c) (sorted): a's spheres get the force on side
        i, c's the opposite (a sleeping c collects the average over the island's sub-steps); a sphere's
        partner is the object whose force on it (the largest of its pairs, N) is strongest, the first such
        object pair winning ties, and only if stronger than the contact it already has.  Each sphere's
        forces are added in the order of a loop over the object pairs, then their point pairs.  Per
        object pair the step statistics get the total force (on the smaller id), the force-weighted
        position and the normal (from the smaller id's side). Without ``stats`` only the per-point records."""
        mag_t = f_i.norm(dim=1)  # (the partner strengths: the same norm as the scene forces')
        mag = mag_t.numpy()
        rows = np.flatnonzero(mag > 0)
        if not len(rows):
            return
        oi, oj = obj_i[rows], obj_j[rows]
        n = len(self.bodies)
        keys, group = _distinct_codes(oi * n + oj, n * n)  # object pairs (a, c), sorted
        obj_a, obj_c = keys // n, keys % n
        fa, m = f_i.numpy()[rows], mag[rows]

        asleep = self.state.asleep
        if self._record_spheres:
            self._add_sphere_records(obj_a, obj_c, oi, oj, loc_i[rows], loc_j[rows], group, fa, m, h_s)
        if stats is None:
            return
        supported[obj_a] = True
        supported[obj_c[asleep[obj_c]]] = True

        # per object pair: total force on a (N), force-weighted contact position (m) and normal c -> a
        weighted = np.concatenate(
            [fa, m[:, None] * 0.5 * (xi.numpy()[rows] + xj.numpy()[rows]), m[:, None] * normal_ji.numpy()[rows], m[:, None]],
            axis=1,
        )
        sums = np.zeros((len(keys), 10))
        np.add.at(sums, group, weighted)
        self._add_object_pair_statistics(obj_a, obj_c, sums, stats, h_s)

    def _add_object_pair_statistics(self, obj_a: np.ndarray, obj_c: np.ndarray, sums: np.ndarray,
                                    stats: StepStats, h_s: float) -> None:  # fmt: skip
        """Per object pair (a, c) (in order): ``sums`` (10,) = total force on a (N), force-weighted sum of
        contact positions (N m), of normals c -> a (N), and the force magnitudes (N); added to the step
        statistics (:meth:`_object_pair_entries`)."""
        keys, total, pos, nrm = self._object_pair_entries(obj_a, obj_c, sums)
        stats.add_pair_force_series(keys, total[None], pos[None], nrm[None], np.ones((1, len(keys)), dtype=bool), h_s)

    def _object_pair_entries(self, obj_a: np.ndarray, obj_c: np.ndarray,
                             sums: np.ndarray) -> tuple[list[tuple[int, int]], np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
        """The step statistics' entries of object pairs (a, c) (G,) from their sums (..., G, 10) (as
        :meth:`_add_object_pair_statistics` reads them): keys (smaller id, larger id) and, per pair, the total force
        on the smaller id (N), the force-weighted contact position (m; zero where no force acts) and the unit
        normal from the smaller id's side (..., G, 3)."""
        id_a, id_c = self._object_id[obj_a], self._object_id[obj_c]
        flip = np.where(id_a > id_c, -1.0, 1.0)[:, None]  # events are keyed (smaller id, larger id)
        total = sums[..., 0:3] * flip
        weight = sums[..., 9:10]
        pos = np.divide(sums[..., 3:6], weight, out=np.zeros_like(total), where=weight > 0)
        nrm = sums[..., 6:9] * flip
        nrm = nrm / np.maximum(np.sqrt((nrm[..., None, :] @ nrm[..., :, None])[..., 0]), 1e-300)
        keys = list(zip(np.minimum(id_a, id_c).tolist(), np.maximum(id_a, id_c).tolist()))
        return keys, total, pos, nrm


    def _add_sphere_records(self, obj_a: np.ndarray, obj_c: np.ndarray, oi: np.ndarray, oj: np.ndarray,
                            loc_i: np.ndarray, loc_j: np.ndarray, group: np.ndarray, fa: np.ndarray,
                            m: np.ndarray, h_s: float) -> None:  # fmt: skip
        """The per-sphere part of :meth:`_accumulate_pair_forces` (its rules) for the active pairs: object
        pairs (obj_a, obj_c) sorted, per pair its objects oi, oj, spheres loc_i, loc_j, object pair
        ``group``, force on side i ``fa`` (N) and its magnitude ``m``."""
        n = len(self.bodies)
        asleep = self.state.asleep
        # records of the objects involved, concatenated (numpy views of their tensors)
        involved = np.unique(np.concatenate([obj_a, obj_c]))
        counts = [self.bodies[o].contact.num_points for o in involved]
        first = np.zeros(n, dtype=np.int64)
        first[involved] = np.cumsum([0] + counts[:-1])
        dest = np.concatenate([first[oi] + loc_i, first[oj] + loc_j])
        rank = np.concatenate([2 * group, 2 * group + 1])  # object pair, then side i before side j
        order = np.argsort(rank, kind="stable")
        scale_j = np.where(asleep[oj], h_s / self.dt, 1.0)
        force = np.concatenate([self.bodies[o].contact_force_n.numpy() for o in involved])
        np.add.at(force, dest[order], np.concatenate([fa, -fa * scale_j[:, None]])[order])  # in that order
        strength = np.concatenate([self.bodies[o].partner_strength_n.numpy() for o in involved])
        partner = np.concatenate([self.bodies[o].contact_partner.numpy() for o in involved])
        m2 = np.concatenate([m, m])
        best = np.zeros_like(strength)
        np.maximum.at(best, dest, m2)
        wins = (m2 == best[dest]) & (m2 > strength[dest])
        none = 2 * len(obj_a)
        winner = np.full(len(partner), none, dtype=np.int64)
        np.minimum.at(winner, dest[wins], rank[wins])
        # partner id per rank: side i (2 g) is pushed by c, side j (2 g + 1) by a
        partner_of_rank = np.stack([self._object_id[obj_c], self._object_id[obj_a]], 1).reshape(-1)
        taken = winner < none
        partner = np.where(taken, partner_of_rank[np.minimum(winner, none - 1)], partner)
        strength = np.maximum(best, strength)
        ends = np.cumsum(counts)[:-1]
        for o, f_o, s_o, p_o in zip(
            involved, np.split(force, ends), np.split(strength, ends), np.split(partner, ends)
        ):  # loop over objects
            b = self.bodies[o]
            b.contact_force_n = torch.from_numpy(f_o)
            b.partner_strength_n = torch.from_numpy(s_o)
            b.contact_partner = torch.from_numpy(p_o)


def _distinct_codes(codes: np.ndarray, size: int) -> tuple[np.ndarray, np.ndarray]:
    """``np.unique(codes, return_inverse=True)`` for integer codes in [0, size): the sorted distinct codes and
    each code's index among them, by marking a table of ``size`` slots instead of sorting."""
    present = np.zeros(size, dtype=bool)
    present[codes] = True
    rank = np.cumsum(present) - 1
    return np.flatnonzero(present), rank[codes]


def _same_state_key(a: tuple, b: tuple) -> bool:
    """Whether two :meth:`ImplicitEulerSolver._step_candidates` keys name the same state: the same tensors
    (identity: the cache keeps them alive, so no new tensor can take their place) at the same versions."""
    return (
        len(a[0]) == len(b[0]) and all(x is y for x, y in zip(a[0], b[0])) and a[1] == b[1]
        and all(x is y for x, y in zip(a[2], b[2])) and a[3] == b[3] and a[4] == b[4] and a[5] == b[5]
    )  # fmt: skip


def _concat_pair_sets(sets: list[_PairSet]) -> _PairSet:
    """The pair sets of several solves, one after the other (numpy fields by ``np.concatenate``, tensors by
    ``torch.cat``)."""
    values = {}
    for f in fields(_PairSet):
        parts = [getattr(ps, f.name) for ps in sets]
        if parts[0] is None:  # start data left to the launch (all or none of the sets have it)
            values[f.name] = None
        else:
            values[f.name] = np.concatenate(parts) if isinstance(parts[0], np.ndarray) else torch.cat(parts)
    return _PairSet(**values)


def _model_bytes(model: Model) -> int:
    """Memory of a model's tensors, bytes."""
    return sum(getattr(model, f.name).nbytes for f in fields(model))
