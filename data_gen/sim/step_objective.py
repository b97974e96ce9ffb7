"""The objective of one implicit Euler (sub)step of size ``h`` for a group of independent islands.

Per island, over the reduced states ``q`` of its objects (padded layout of :class:`Model`):

    f(q) = sum_o 1/2 (q_o - q_pred_o)^T M_o (q_o - q_pred_o)
           + h^2 [ elastic(q) + gravity potential(q) + scene contact + friction(q) + pair contact + friction(q) ]

with ``q_pred = q_n + h qdot_n``. Every term is evaluated once per call for all objects of all islands
(:mod:`data_gen.sim.energy`); the contact forces of the final state come from the same functions
(:meth:`StepObjective.forces`), so the recorder reads what the solver minimised.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from data_gen.sim.energy.contact_kernels import WarpContact
from data_gen.sim.energy.elastic import elastic_from_points, elastic_gradient, elastic_hessian
from data_gen.sim.energy.elastic_kernel import WarpNeoHookean
from data_gen.sim.energy.gravity import gravity
from data_gen.sim.energy.inertia import inertia
from data_gen.sim.energy.pair_contact import PairSet
from data_gen.sim.energy.scene_contact import contact_start
from data_gen.sim.energy.terms import ObjectTerms
from data_gen.sim.fused_newton import FusedNewton
from data_gen.sim.model import DofLayout, Model
from data_gen.sim.newton import Evaluation, Objective
from data_gen.sim.reduced import DTYPE
from data_gen.sim.energy.scene_sdf import SceneDistance

# largest island (unknowns) solved by FusedNewton: 100 one-handle objects
FUSED_MAX_ISLAND_DOFS = 1200
# largest padded matrix storage of one group (islands x N x N float64 entries, 128 MiB) that FusedNewton takes:
# it keeps the matrix and its factor for every island of the group at the size of the largest one
FUSED_MAX_MATRIX_ENTRIES = 1 << 24


@dataclass
class ContactForces:
    """Contact forces of one state: per sphere from the scene (n, S, 3) N with the scene normals (n, S, 3)
    and sphere positions (n, S, 3) m; per candidate pair the force on side i (P, 3) N and the unit normal
    j -> i (P, 3)."""

    scene_force_n: torch.Tensor
    scene_normals: torch.Tensor
    sphere_positions_m: torch.Tensor
    pair_force_i_n: torch.Tensor
    pair_normals: torch.Tensor


class SolveWorkspace:
    """What the objective of a fixed set of objects and islands needs whatever the step: the warp contact
    and neo-Hookean kernels with their buffers, the elastic groups (one-handle objects keep one cubature
    point) and per-island constants. The solver keeps one per group of islands and reuses it for every
    (sub)step that solves the same islands."""

    def __init__(self, model: Model, layout: DofLayout, scene: SceneDistance) -> None:
        self.contact = WarpContact(
            scene.scene, 4 * model.num_handles, model.sphere_rest_m, model.sphere_b, model.sphere_radius_m,
            layout.flat_index, layout.island_size, layout.num_islands,
        )  # fmt: skip
        rigid = model.num_handles == 1
        self.elastic_groups = []  # (objects, bases, kernel); one-handle objects keep their single cubature point
        for idx, width in ((torch.nonzero(rigid)[:, 0], 1), (torch.nonzero(~rigid)[:, 0], model.cub_c.shape[1])):
            if len(idx):
                cub_c = model.cub_c[idx][:, :width]
                points = WarpNeoHookean(4 * model.num_handles[idx], cub_c, model.cub_volume_m3[idx][:, :width],
                                        model.mu_pa[idx], model.lam_pa[idx], model.spd_tolerance_pa[idx])  # fmt: skip
                self.elastic_groups.append((idx, cub_c, points))
        n_isl, size = layout.num_islands, layout.island_size
        dofs = torch.zeros(n_isl, dtype=torch.int64).index_add_(0, layout.island, 12 * model.num_handles)
        self.padding = (torch.arange(size)[None, :] >= dofs[:, None]).to(DTYPE)  # (n_isl, N) unused entries
        self.island_mass_kg, self.min_median_radius_m = island_constants(model, layout)
        self.fused = (
            FusedNewton(model, layout, self.contact, self.island_mass_kg, self.min_median_radius_m)
            if bool(rigid.all()) and fused_fits(layout)
            else None
        )
        # islands of deformable objects only, on CPU: the objective's evaluations in one launch each
        # (StepObjective(kernel_evaluation=True)); built on first use. (The kernel runs an island in one thread:
        # on a GPU the per-sphere contact kernels and batched torch are the right shape.)
        self._evaluator_fits = (
            bool((~rigid).all()) and fused_fits(layout) and model.mass_kg.device.type == "cpu"
        )
        self._evaluator: FusedNewton | None = None
        self._model, self._layout = model, layout
        self._any_fused: FusedNewton | None = None

    @property
    def evaluator(self) -> FusedNewton | None:
        """The workspace's :class:`FusedNewton` for evaluations (no solves) of islands of deformable objects,
        on this workspace's contact buffers; None when some object has one handle (those islands take the fused
        solver) or the islands do not fit the kernel."""
        if self._evaluator is None and self._evaluator_fits:
            self._evaluator = FusedNewton(self._model, self._layout, self.contact, self.island_mass_kg,
                                          self.min_median_radius_m)  # fmt: skip
        return self._evaluator


    @property
    def any_fused(self) -> FusedNewton | None:
        """A :class:`FusedNewton` on this workspace's contact buffers for its objects whatever their handles (the
        fused solver's, the evaluator's, or one of its own for islands mixing one-handle and deformable objects),
        or None where the islands do not fit the kernels or the model is not on the CPU: what
        :class:`~data_gen.sim.device_newton.DeviceNewton` solves on."""
        if self.fused is not None:
            return self.fused
        if self.evaluator is not None:
            return self.evaluator
        if self._any_fused is None and fused_fits(self._layout) and self._model.mass_kg.device.type == "cpu":
            self._any_fused = FusedNewton(self._model, self._layout, self.contact, self.island_mass_kg,
                                          self.min_median_radius_m)  # fmt: skip
        return self._any_fused


def island_constants(model: Model, layout: DofLayout) -> tuple[torch.Tensor, torch.Tensor]:
    """Per island of ``layout``: its mass (kg) and the smallest median contact-sphere radius of its objects (m)."""
    n_isl = layout.num_islands
    mass = torch.zeros(n_isl, dtype=DTYPE).index_add_(0, layout.island, model.mass_kg)
    radii = torch.where(model.sphere_valid, model.sphere_radius_m, torch.tensor(float("nan"), dtype=DTYPE))
    median = radii.nanmedian(dim=1).values
    radius = torch.full((n_isl,), float("inf"), dtype=DTYPE).scatter_reduce(0, layout.island, median, reduce="amin")
    return mass, radius


def fused_fits(layout: DofLayout) -> bool:
    """Islands small enough for one thread's envelope Cholesky, matrices small enough to keep twice more."""
    n_isl, size = layout.num_islands, layout.island_size
    return 0 < size <= FUSED_MAX_ISLAND_DOFS and n_isl * size * size <= FUSED_MAX_MATRIX_ENTRIES


def rigid_fused_workspace(model: Model, layout: DofLayout, scene: SceneDistance) -> FusedNewton | None:
    """A :class:`FusedNewton` of one-handle objects with contact buffers of its own (no objective is built on
    them: it serves :meth:`FusedNewton.solve_substeps` only, and :meth:`FusedNewton.relayout` regroups it), or
    None when the islands do not fit (:func:`fused_fits`)."""
    if not bool((model.num_handles == 1).all()) or not fused_fits(layout):
        return None
    contact = WarpContact(
        scene.scene, 4 * model.num_handles, model.sphere_rest_m, model.sphere_b, model.sphere_radius_m,
        layout.flat_index, layout.island_size, layout.num_islands,
    )  # fmt: skip
    return FusedNewton(model, layout, contact, *island_constants(model, layout))


class StepObjective(Objective):
    """Objective, gradient and Newton matrix of one (sub)step, per island (see the module docstring).

    ``workspace`` is the :class:`SolveWorkspace` of ``model`` and ``layout`` (built here when omitted).

    With ``lagged_elastic_hessian`` the objects of more than one handle keep the elastic part of the Newton
    matrix formed at this objective's first evaluation with derivatives (or at its latest one with projected
    blocks) for every later evaluation; their energies and gradients stay exact. Newton's method becomes a
    modified Newton method: the same minimum and convergence test, each iteration without the per-point
    9 x 9 Hessians and their reduction, which cost most of a soft object's evaluation. One objective serves one
    (sub)step, so every step starts from a fresh matrix unless ``reused_elastic_hessian`` = (mask (n,) bool,
    matrices (n, 3K, 3K)) hands it the kept matrices of an earlier (sub)step for the objects in ``mask`` (the
    solver's choice, :attr:`QualityPreset.elastic_hessian_reuse`; only where the first evaluation forms the
    matrix from the elastic kernel's point Hessians, :meth:`_kept_matrix_at`): then only the others' are formed,
    and :attr:`formed_elastic_hessian` holds every object's matrix of this objective. One-handle objects always
    get theirs formed (it is one point's: nothing to save)."""

    def __init__(
        self,
        model: Model,
        layout: DofLayout,
        scene: SceneDistance,
        gravity_m_s2: torch.Tensor,
        tm_n: torch.Tensor,
        tmdot: torch.Tensor,
        h_s: float,
        stiffness_factor: float,
        smoothing_m: float,
        pairs: PairSet,
        workspace: SolveWorkspace | None = None,
        lagged_elastic_hessian: bool = False,
        kernel_evaluation: bool = False,
        reused_elastic_hessian: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> None:
        self.model, self.layout, self.scene, self.pairs = model, layout, scene, pairs
        self.lagged_elastic_hessian = lagged_elastic_hessian
        self._reused_elastic_hessian = reused_elastic_hessian
        # every object's kept elastic matrix (n, 3K, 3K), once :meth:`_kept_matrix_at` has formed or reused it;
        # which of them this objective formed (n,) bool, and at which states (n, 3, K)
        self.formed_elastic_hessian: torch.Tensor | None = None
        self.formed_elastic_mask: torch.Tensor | None = None
        self.formed_elastic_tm: torch.Tensor | None = None
        self.refreshed_elastic_hessian = False  # formed anew during the solve (refresh_kept_matrix)
        self._kept_elastic_hessian: dict[int, torch.Tensor] = {}  # per elastic group (lagged_elastic_hessian)
        self._base: tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None = None  # (M, K, M + h^2 K assembled)
        # M + h^2 K with every object's elastic blocks the kept ones (what a kernel evaluation adds its contact
        # matrix to), None until then
        self._kept_base: torch.Tensor | None = None
        self.gravity = gravity_m_s2
        self.h, self.h2 = h_s, h_s * h_s
        self.tm_n = tm_n
        self.tm_pred = tm_n + h_s * tmdot
        self.smoothing_m = smoothing_m
        self.scene_stiffness_n_m = stiffness_factor * model.mass_kg / self.h2
        self.sphere_stiffness_n_m = self.scene_stiffness_n_m[:, None] * model.sphere_valid
        self.start = contact_start(
            scene, model.sphere_positions(tm_n), model.sphere_radius_m, model.sphere_valid, self.scene_stiffness_n_m
        )
        self.workspace = workspace if workspace is not None else SolveWorkspace(model, layout, scene)
        self.contact = self.workspace.contact
        self.contact.prepare(
            self.sphere_stiffness_n_m, model.friction[:, None] * self.start.normal_force_n, self.start.positions_m,
            self.start.normals, smoothing_m, self.h2, pairs if pairs.num_pairs else None,
        )  # fmt: skip
        self.elastic_groups = self.workspace.elastic_groups
        self.padding = self.workspace.padding
        self.evaluator = self.workspace.evaluator if kernel_evaluation else None
        self.island_mass_kg = self.workspace.island_mass_kg
        self.min_median_radius_m = self.workspace.min_median_radius_m

    # -- sizes of the step
    def _per_island(self, per_object: torch.Tensor, reduce: str = "sum") -> torch.Tensor:
        """Per-object values (n,) reduced per island (``sum`` or a ``scatter_reduce`` reduction that starts
        from 0, such as ``amax`` of non-negative sizes)."""
        if self.layout.one_island_per_object:  # island o is object o: 0 + x (sum) and max(0, x) (amax)
            if reduce == "sum":
                return per_object + 0.0
            if reduce == "amax":
                return per_object.clamp(min=0.0)
        out = torch.zeros(self.layout.num_islands, dtype=DTYPE)
        if reduce == "sum":
            return out.index_add_(0, self.layout.island, per_object)
        return out.scatter_reduce(0, self.layout.island, per_object, reduce=reduce, include_self=True)

    def _object_mass_norm2(self, dtm: torch.Tensor) -> torch.Tensor:
        """Squared mass norm ``dtm^T M dtm`` per object (n,) of padded state changes ``dtm`` (n, 3, K)."""
        flat = dtm.reshape(dtm.shape[0], -1, 1)
        return (flat[:, :, 0] * (self.model.mass_matrix @ flat)[:, :, 0]).sum(1)

    def mass_norm(self, dq: torch.Tensor) -> torch.Tensor:
        return self._mass_norm_objects(self.layout.to_objects(dq))

    def _mass_norm_objects(self, dtm: torch.Tensor) -> torch.Tensor:
        """|dtm|_M per island of padded changes ``dtm`` (n, 3, K)."""
        return self._per_island(self._object_mass_norm2(dtm)).clamp(min=0.0).sqrt()

    def point_motion(self, dq: torch.Tensor) -> torch.Tensor:
        return self._point_motion_objects(self.layout.to_objects(dq))

    def update_norms(self, dq: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`point_motion` and :meth:`mass_norm` of dq from one conversion to the objects' layout."""
        dtm = self.layout.to_objects(dq)
        return self._point_motion_objects(dtm), self._mass_norm_objects(dtm)

    def _point_motion_objects(self, dtm: torch.Tensor) -> torch.Tensor:
        """Largest contact-sphere displacement (m) per island of padded changes ``dtm`` (n, 3, K)."""
        # padded spheres have zero basis rows (Model.build): they do not move, no mask needed
        move = torch.linalg.vector_norm(self.model.sphere_b @ dtm.transpose(1, 2), dim=2)
        return self._per_island(move.amax(dim=1), reduce="amax")

    def motion_scale(self) -> torch.Tensor:
        """|q_pred - q_n|_M + h^2 |g| sqrt(m) + 1e-9 sqrt(m) per island (the convergence yardstick)."""
        motion = self._per_island(self._object_mass_norm2(self.tm_pred - self.tm_n)).clamp(min=0.0).sqrt()
        root_mass = self.island_mass_kg.sqrt()
        return motion + self.h2 * float(self.gravity.norm()) * root_mass + 1e-9 * root_mass

    def trust_radius(self) -> torch.Tensor:
        """Largest sphere displacement of one Newton update, m: twice the step's predicted motion, plus
        what gravity adds, plus the island's smallest median contact radius. An affine handle linearises
        rotations, so a thin stiff object can otherwise be offered updates of metres."""
        predicted = self._point_motion_objects(self.tm_pred - self.tm_n)
        return 2.0 * predicted + self.h2 * float(self.gravity.norm()) + self.min_median_radius_m

    @property
    def kept_matrix(self) -> torch.Tensor | None:
        """``M + h^2 K`` per island (n_isl, N, N) with every object's kept elastic blocks (what a kernel
        evaluation's contact part is added to), or None until an evaluation with derivatives has kept them (only
        with ``lagged_elastic_hessian``, ``kernel_evaluation`` and deformable objects); read only."""
        return self._kept_base

    # -- evaluation
    def evaluate(self, q: torch.Tensor, derivatives: bool, strict_islands: torch.Tensor | None = None) -> Evaluation:
        """The objective per island at ``q`` (n_isl, N); with ``derivatives`` its gradient and Newton matrix (the
        islands in ``strict_islands`` with every elastic block projected).

        With ``kernel_evaluation`` (islands of deformable objects), an evaluation without derivatives, and one
        with derivatives once the kept elastic blocks make the matrix's inertia and elastic part constant
        (``lagged_elastic_hessian``), is one launch of the fused kernel (:meth:`FusedNewton.evaluate_bound`):
        the same terms, summed in another order (about 1e-15 relative). With one group of deformable objects
        the first evaluation with derivatives forms those blocks from the elastic kernel's point Hessians alone
        (:meth:`_kept_matrix_at`) and launches too; otherwise it takes the batched terms below and keeps them."""
        if self.evaluator is not None and strict_islands is None:
            if derivatives and self._kept_base is None and self._keeps_one_elastic_group():
                self._kept_base = self._kept_matrix_at(q)  # the first evaluation: M + h^2 K formed and kept
            if not derivatives or self._kept_base is not None:
                value, grad, hess = self.evaluator.evaluate_bound(self, q, derivatives)
                if not derivatives:
                    return Evaluation(value)
                return Evaluation(value, grad, torch.add(self._kept_base, hess))
        m = self.model
        tm = self.layout.to_objects(q)
        strict = None if strict_islands is None else strict_islands[self.layout.island]
        it = inertia(m.mass_matrix, tm - self.tm_pred, derivatives)
        el = self._elastic(tm, derivatives, strict)
        gr = gravity(m.mass_b_sum, self.gravity, tm, derivatives)
        contact = self.contact.evaluate(tm, derivatives)
        value = self._per_island(it.energy + self.h2 * (el.energy + gr.energy + contact.energy_j))
        if not derivatives:
            return Evaluation(value)
        grad = self.layout.to_islands(it.grad + self.h2 * (el.grad + gr.grad)) + contact.grad
        base = self._base_matrix(it.hess, el.hess)
        if self.evaluator is not None and self._all_elastic_kept(el.hess):
            self._kept_base = base
        return Evaluation(value, grad, torch.add(base, contact.hess))  # contact: h^2

    def _keeps_one_elastic_group(self) -> bool:
        """Whether the first evaluation with derivatives keeps the whole elastic matrix: one elastic group, of
        deformable objects, with ``lagged_elastic_hessian``."""
        return self.lagged_elastic_hessian and len(self.elastic_groups) == 1 and self.elastic_groups[0][1].shape[1] > 1

    def _kept_matrix_at(self, q: torch.Tensor) -> torch.Tensor:
        """``M + h^2 K`` per island at ``q`` (n_isl, N), K kept (:meth:`_keeps_one_elastic_group`): the point
        Hessians of the elastic kernel reduced to the objects' matrices, without the energy and gradient terms
        (the kernel evaluation that follows computes those)."""
        reused = self._reused_elastic_hessian
        tm = self.layout.to_objects(q)
        if reused is None or not bool(reused[0].any()):
            kept = self._formed_at(tm, None, None)
        elif bool(reused[0].all()):  # every object's matrix from an earlier (sub)step
            kept = reused[1]
        else:  # only the objects without a reusable matrix get theirs formed (reused[1]: a new tensor per solve)
            kept = self._formed_at(tm, torch.nonzero(~reused[0])[:, 0], reused[1])
        self._keep_formed(kept, None if reused is None else ~reused[0], tm)
        return self._base_matrix(self.model.mass_matrix, kept)

    def _formed_at(self, tm: torch.Tensor, rows: torch.Tensor | None, kept: torch.Tensor | None) -> torch.Tensor:
        """Elastic matrices (n, 3K, 3K) formed at states ``tm`` from the elastic kernel's point Hessians: every
        object's (``rows`` None), or those of ``rows`` written into ``kept`` (returned)."""
        _, cub_c, points = self.elastic_groups[0]
        _, _, point_hess, _ = points.evaluate(tm, True)
        if rows is None:
            return elastic_hessian(cub_c, point_hess)
        kept[rows] = elastic_hessian(cub_c[rows], point_hess[rows])
        return kept

    @property
    def reuses_elastic_hessian(self) -> bool:
        """Whether some object's kept elastic matrix is an earlier (sub)step's (until a refresh forms it here)."""
        return self.formed_elastic_mask is not None and not bool(self.formed_elastic_mask.all())

    def _keep_formed(self, kept: torch.Tensor, mask: torch.Tensor | None, tm: torch.Tensor) -> None:
        """Keep ``kept`` (n, 3K, 3K) as every object's elastic matrix, formed at states ``tm`` where ``mask``
        (n,) (None: every object)."""
        self._kept_elastic_hessian[0] = self.formed_elastic_hessian = kept
        self.formed_elastic_mask = torch.ones(kept.shape[0], dtype=torch.bool) if mask is None else mask
        self.formed_elastic_tm = tm

    def refresh_kept_matrix(self, q: torch.Tensor) -> torch.Tensor:
        """The elastic matrices this objective took from earlier (sub)steps formed anew at ``q`` (n_isl, N) and
        kept from now on (a solve that started from them and has not converged after a few iterations, see
        :meth:`FusedNewton.solve_split`; the others stay those formed at its start); returns the new
        ``M + h^2 K`` per island (also :attr:`kept_matrix`)."""
        tm = self.layout.to_objects(q)
        stale = torch.nonzero(~self.formed_elastic_mask)[:, 0]
        kept = self._formed_at(tm, stale, self.formed_elastic_hessian.clone())
        formed_tm = self.formed_elastic_tm.clone()
        formed_tm[stale] = tm[stale]
        self._keep_formed(kept, None, formed_tm)
        self.refreshed_elastic_hessian = True
        self._kept_base = self._base_matrix(self.model.mass_matrix, self._kept_elastic_hessian[0])
        return self._kept_base

    def _all_elastic_kept(self, elastic_hess: torch.Tensor) -> bool:
        """Whether ``elastic_hess`` is the kept matrix of every object (one deformable group, lagged)."""
        return len(self.elastic_groups) == 1 and elastic_hess is self._kept_elastic_hessian.get(0)

    def _base_matrix(self, inertia_hess: torch.Tensor, elastic_hess: torch.Tensor) -> torch.Tensor:
        """The island matrices of inertia and elasticity (``M + h^2 K``, identity rows on padding), read only.
        Kept while both blocks are the same tensors: with ``lagged_elastic_hessian`` and only soft objects the
        elastic blocks are the kept ones and the mass matrix is constant, so a step assembles them once.
        (Padding adds 1 where every other term is 0, so adding it before the contact matrix is exact.)"""
        cached = self._base
        if cached is not None and cached[0] is inertia_hess and cached[1] is elastic_hess:
            return cached[2]
        base = self.layout.assemble(inertia_hess + self.h2 * elastic_hess)
        base.diagonal(dim1=1, dim2=2).add_(self.padding)
        self._base = (inertia_hess, elastic_hess, base)
        return base

    def _elastic(self, tm: torch.Tensor, derivatives: bool, strict: torch.Tensor | None) -> ObjectTerms:
        """Elastic terms of all objects, evaluated per group of equal cubature width."""
        m = self.model
        n, k = tm.shape[0], m.columns
        if len(self.elastic_groups) == 1 and len(self.elastic_groups[0][0]) == n:  # one group: every object in order
            return self._group_elastic(0, tm, derivatives, strict)
        out = ObjectTerms(
            torch.zeros(n, dtype=DTYPE),
            torch.zeros(n, 3, k, dtype=DTYPE) if derivatives else None,
            torch.zeros(n, 3 * k, 3 * k, dtype=DTYPE) if derivatives else None,
        )
        for g, (idx, _, _) in enumerate(self.elastic_groups):  # at most two groups: rigid and deformable
            part = self._group_elastic(g, tm[idx], derivatives, None if strict is None else strict[idx])
            out.energy[idx] = part.energy
            if derivatives:
                out.grad[idx] = part.grad
                out.hess[idx] = part.hess
        return out

    def _group_elastic(self, g: int, tm: torch.Tensor, derivatives: bool, strict: torch.Tensor | None) -> ObjectTerms:
        """Elastic terms of elastic group ``g`` at its objects' states ``tm``; with ``lagged_elastic_hessian``
        and a deformable group, the kept matrix after the first evaluation with derivatives (a projected
        evaluation, ``strict`` given, forms and keeps a new one)."""
        _, cub_c, points = self.elastic_groups[g]
        lag = self.lagged_elastic_hessian and derivatives and cub_c.shape[1] > 1  # one-handle groups: one point
        kept = self._kept_elastic_hessian.get(g) if lag and strict is None else None
        if kept is not None:
            energy, piola, _, _ = points.evaluate(tm, False)
            return ObjectTerms(energy.sum(1), elastic_gradient(cub_c, piola), kept)
        energy, piola, hess, _ = points.evaluate(tm, derivatives, strict)
        out = elastic_from_points(cub_c, energy, piola, hess if derivatives else None)
        if lag:
            self._kept_elastic_hessian[g] = out.hess
        return out

    def forces(self, tm: torch.Tensor) -> ContactForces:
        """Contact and friction forces of the state ``tm`` (n, 3, K) (the solver's final state)."""
        out = self.contact.evaluate(tm)
        x = self.model.sphere_positions(tm)
        return ContactForces(
            out.scene_force_n.clone(), out.scene_normals.clone(), x, out.pair_force_i_n.clone(), out.pair_normals.clone()
        )


__all__ = ["ContactForces", "SolveWorkspace", "StepObjective"]
