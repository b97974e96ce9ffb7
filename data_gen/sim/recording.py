"""What a simulation run records: per-frame object tracks, contact events and run info.

Units: m, kg, s, N, Pa.  Object ids are 1-based; partner id 0 is the static scene and
``NO_PARTNER`` (-1) marks a cubature point without contact.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import torch

from data_gen.sim.contact_points import ContactPoints
from data_gen.sim import material as mat
from data_gen.sim.reduced import DTYPE, ReducedObject, deform, deformation_from_tmat, handle_permutation
from data_gen.sim.skinning import SkinningBasis
from newtphys.rotations import matrix_to_quat_one, rotation_from_cross_covariance


@dataclass
class ObjectTrack:
    """Per-frame record of one object (T frames, n cubature points, H handles).

    Attributes:
        object_id, name: 1-based id and name.
        basis: skinning basis; with ``handle_transforms`` it deforms any rest point (see :meth:`deform`).
        points_rest_m: (n,3) cubature rest positions in the object frame; volumes_m3, masses_kg: (n,).
        contact_points_rest_m: (k,3) contact sphere centres in the object frame (surface spheres, or the
            cubature points when the object had no surface samples); contact_radius_m: (k,) their radii.
        handle_transforms: (T, 12H) reduced state z (row-major 3x4 delta affine per handle).
        cubature_positions_m: (T,n,3) world positions; contact_positions_m: (T,k,3) sphere centres.
        gravity_force_n: (T,n,3) m_i g; contact_force_n: (T,n,3) total contact force (normal + friction).
        contact_partner: (T,n) int64 id of the dominant contact partner (0 scene, -1 none).
        hydrostatic_stress_pa: (T,n) tr(sigma)/3, negative = compression.  det_f: (T,n).
        com_m, velocity_m_s, angular_velocity_rad_s: (T,3); orientation_wxyz: (T,4).
        asleep: (T,) bool.
    """

    object_id: int
    name: str
    basis: SkinningBasis
    points_rest_m: np.ndarray
    volumes_m3: np.ndarray
    masses_kg: np.ndarray
    contact_points_rest_m: np.ndarray
    contact_radius_m: np.ndarray
    handle_transforms: np.ndarray
    cubature_positions_m: np.ndarray
    contact_positions_m: np.ndarray
    gravity_force_n: np.ndarray
    contact_force_n: np.ndarray
    contact_partner: np.ndarray
    hydrostatic_stress_pa: np.ndarray
    det_f: np.ndarray
    com_m: np.ndarray
    orientation_wxyz: np.ndarray
    velocity_m_s: np.ndarray
    angular_velocity_rad_s: np.ndarray
    asleep: np.ndarray

    @property
    def num_handles(self) -> int:
        return self.handle_transforms.shape[1] // 12

    @property
    def mass_kg(self) -> float:
        return float(self.masses_kg.sum())

    def deform(self, points_rest_m: np.ndarray | torch.Tensor, frame: int) -> tuple[np.ndarray, np.ndarray]:
        """World positions (m,3) and deformation gradients (m,3,3) of rest points at ``frame``."""
        if not 0 <= frame < self.handle_transforms.shape[0]:
            raise ValueError(
                f"frame={frame} is out of range; allowed: 0 <= frame < {self.handle_transforms.shape[0]}"
            )
        pts = torch.as_tensor(np.asarray(points_rest_m, dtype=np.float64))
        weights, grads = self.basis.evaluate(pts)
        x, F = deform(pts, weights, grads, torch.from_numpy(self.handle_transforms[frame]))
        return x.numpy(), F.numpy()


@dataclass
class ContactEvent:
    """One contact episode between objects a and b (b = 0: static scene), from onset to separation.

    ``frame`` is the first recorded frame at or after the onset; ``position_m``/``normal`` are taken
    at the step of peak force (normal points from b towards a); ``impulse_n_s`` integrates |F| dt
    over the episode.
    """

    frame: int
    objects: tuple[int, int]
    position_m: np.ndarray
    normal: np.ndarray
    impulse_n_s: float
    peak_force_n: float
    onset_time_s: float
    end_time_s: float

    def to_dict(self) -> dict:
        """The world-state ``collisions`` entry (docs/data_contract.md)."""
        return {
            "frame": int(self.frame),
            "objects": [int(self.objects[0]), int(self.objects[1])],
            "position": [float(v) for v in self.position_m],
            "normal": [float(v) for v in self.normal],
            "impulse": float(self.impulse_n_s),
            "peak_force": float(self.peak_force_n),
        }


class ContactEventTracker:
    """Turns per-step pair forces into one event per contact onset.

    A pair that separates for fewer than ``gap_steps`` consecutive steps continues the same event.
    """

    def __init__(self, dt_s: float, substeps_per_frame: int, gap_steps: int) -> None:
        self.dt = dt_s
        self.substeps = substeps_per_frame
        self.gap_steps = gap_steps
        self.open: dict[tuple[int, int], dict] = {}
        self.closed: list[ContactEvent] = []

    def update(self, step: int, pair_forces: dict[tuple[int, int], dict]) -> None:
        """Add step ``step`` (0-based, ends at (step + 1) dt): per pair impulse (N s), peak force, position, normal."""
        for key, entry in pair_forces.items():
            ev = self.open.get(key)
            if ev is None:
                onset = step + 1
                ev = {
                    "frame": -(-onset // self.substeps),
                    "onset": onset * self.dt,
                    "impulse": 0.0,
                    "peak": -1.0,
                    "pos": entry["position_m"],
                    "normal": entry["normal"],
                }
                self.open[key] = ev
            ev["impulse"] += entry["impulse_n_s"]
            if entry["peak_force_n"] > ev["peak"]:
                ev.update(peak=entry["peak_force_n"], pos=entry["position_m"], normal=entry["normal"])
            ev["last"] = step
        for key in list(self.open):
            if step - self.open[key]["last"] >= self.gap_steps:
                self._close(key)

    def finish(self) -> list[ContactEvent]:
        for key in list(self.open):
            self._close(key)
        return sorted(self.closed, key=lambda e: (e.frame, e.objects))

    def _close(self, key: tuple[int, int]) -> None:
        ev = self.open.pop(key)
        self.closed.append(
            ContactEvent(
                ev["frame"],
                key,
                np.asarray(ev["pos"]),
                np.asarray(ev["normal"]),
                ev["impulse"],
                ev["peak"],
                ev["onset"],
                (ev["last"] + 1) * self.dt,
            )
        )


@dataclass
class SimulationRunSummary:
    """What a simulation run did: settings, step counts, wall times (s) and solver counters; ``to_dict`` is
    the world state's ``simulation`` entry (``newtphys.world_state.SimulationInfo``)."""

    quality: str
    dt_s: float
    substeps: int
    newton_iterations: int
    wall_time_s: float
    num_steps: int
    max_newton_iterations_per_step: int
    awake_object_steps: int
    object_steps: int
    seed: int
    timings_s: dict[str, float] = field(default_factory=dict)
    counters: dict[str, int] = field(default_factory=dict)

    def to_dict(self) -> dict:
        return {
            "quality": self.quality,
            "dt": self.dt_s,
            "substeps": self.substeps,
            "newton_iterations": self.newton_iterations,
            "wall_time_s": self.wall_time_s,
            "num_steps": self.num_steps,
            "max_newton_iterations_per_step": self.max_newton_iterations_per_step,
            "awake_object_steps": self.awake_object_steps,
            "object_steps": self.object_steps,
            "seed": self.seed,
            "timings_s": dict(self.timings_s),
            "counters": dict(self.counters),
        }


@dataclass
class SimulationResult:
    """Everything a run produced; frame t is at time t / fps."""

    fps: float
    num_frames: int
    gravity_m_s2: np.ndarray
    objects: list[ObjectTrack]
    collisions: list[ContactEvent]
    info: SimulationRunSummary
    energies_j: dict[str, np.ndarray]  # kinetic / elastic / contact / gravity, each (T,)

    @property
    def times_s(self) -> np.ndarray:
        return np.arange(self.num_frames) / self.fps


class RigidFrame(NamedTuple):
    """Rigid-body quantities of one object's inertia particles at one state (see :class:`InertiaMoments`).

    Attributes:
        com_m: (3,) centre of mass c = sum_p m_p x_p / M.
        velocity_m_s: (3,) centre-of-mass velocity v_c = sum_p m_p v_p / M.
        cross_covariance_m2: (3,3) Kabsch H = sum_p (m_p / M) (x_p - c)(r_p - c0)^T (``best_fit_rotation``'s).
        inertia_kg_m2: (3,3) inertia tensor about c, sum_p m_p (|x_p - c|^2 I - (x_p - c)(x_p - c)^T).
        angular_momentum_kg_m2_s: (3,) sum_p m_p (x_p - c) x (v_p - v_c).
        spin_j: sum_p m_p |v_p - v_c|^2 (twice the kinetic energy about the centre of mass), J.
    """

    com_m: np.ndarray
    velocity_m_s: np.ndarray
    cross_covariance_m2: np.ndarray
    inertia_kg_m2: np.ndarray
    angular_momentum_kg_m2_s: np.ndarray
    spin_j: float


@dataclass(frozen=True)
class InertiaMoments:
    """Mass moments of an object's inertia particles in its affine basis, formed once per object, so
    that each frame's rigid-body sums over the P particles become products of (3 + 4H)-sized matrices.

    The particles have rest positions r_p (m), affine basis rows b_p (4H,) (``model.mass_b``) and masses
    m_p (kg), M = sum_p m_p.  With the rest centre of mass c0 = sum_p m_p r_p / M, the mean basis row
    bbar = sum_p m_p b_p / M and the centred coordinates z_p = [r_p - c0, b_p - bbar] (3 + 4H,), a state
    Tm = q.reshape(3, 4H) (velocity Tmdot) places every particle at x_p = r_p + Tm b_p, so exactly

        c = c0 + Tm bbar,    v_c = Tmdot bbar,
        x_p - c = A z_p with A = [I3 | Tm],    v_p - v_c = Tmdot (b_p - bbar),

    and every centred second-order sum is a product with ``second_moment`` = sum_p m_p z_p z_p^T:
    sum_p m_p (x_p - c) z_p^T = A Z, whose first three columns give the Kabsch cross-covariance and whose
    basis columns times Tmdot^T give sum_p m_p (x_p - c)(v_p - v_c)^T.  The centring is done once on the
    particles, so no per-frame difference of large raw moments loses digits.

    Attributes:
        mass_kg: M (kg).
        com_rest_m: (3,) c0 (m).
        mean_basis: (4H,) bbar (m in the position entries, 1 in the homogeneous ones).
        second_moment: (3 + 4H, 3 + 4H) sum_p m_p z_p z_p^T (kg times the units of the two entries).
    """

    mass_kg: float
    com_rest_m: np.ndarray
    mean_basis: np.ndarray
    second_moment: np.ndarray

    @classmethod
    def of(cls, model: ReducedObject) -> InertiaMoments:
        """The moments of ``model``'s inertia particles (``mass_points_rest``, ``mass_b``,
        ``particle_masses_kg``)."""
        m = model.particle_masses_kg.numpy()
        rest = model.mass_points_rest.numpy()
        basis = model.mass_b.numpy()
        # one column sum (row after row, the same additions in every column) for the first moments and M,
        # so that a basis column equal to the masses' (handle 0's homogeneous entry, weight 1) has a mean
        # of exactly 1 and a uniform velocity is recorded exactly
        sums = (m[:, None] * np.concatenate([rest, basis, np.ones_like(m)[:, None]], axis=1)).sum(0)
        mass = float(sums[-1])
        com_rest = sums[:3] / mass
        mean_basis = sums[3:-1] / mass
        z = np.concatenate([rest - com_rest, basis - mean_basis], axis=1)
        second = (z * m[:, None]).T @ z
        return cls(mass, com_rest, mean_basis, 0.5 * (second + second.T))

    def frame(self, tm: np.ndarray, tm_dot: np.ndarray) -> RigidFrame:
        """Rigid-body quantities at the state ``tm`` (3, 4H) moving at ``tm_dot`` (3, 4H), both
        ``q.reshape(3, -1)`` of a q-ordered state (m, m/s)."""
        return rigid_frames(self.second_moment[None], self.com_rest_m[None], self.mean_basis[None],
                            np.array([self.mass_kg]), tm[None], tm_dot[None])[0]  # fmt: skip


def rigid_frames(second_moment: np.ndarray, com_rest_m: np.ndarray, mean_basis: np.ndarray, mass_kg: np.ndarray,
                 tm: np.ndarray, tm_dot: np.ndarray) -> list[RigidFrame]:  # fmt: skip
    """:meth:`InertiaMoments.frame` of m objects of equal handle counts at once: their moments stacked
    (``second_moment`` (m, 3 + 4H, 3 + 4H), ``com_rest_m`` (m, 3), ``mean_basis`` (m, 4H), ``mass_kg`` (m,)) and
    states ``tm`` / ``tm_dot`` (m, 3, 4H) (m, m/s)."""
    z = second_moment
    moment = z[:, :3] + tm @ z[:, 3:]  # A Z = sum_p m_p (x_p - c) z_p^T, (m, 3, 3 + 4H)
    spread = moment[:, :, :3] + moment[:, :, 3:] @ tm.transpose(0, 2, 1)  # sum_p m_p (x_p - c)(x_p - c)^T
    cross = moment[:, :, 3:] @ tm_dot.transpose(0, 2, 1)  # sum_p m_p (x_p - c)(v_p - v_c)^T
    angular_momentum = np.stack(
        [cross[:, 1, 2] - cross[:, 2, 1], cross[:, 2, 0] - cross[:, 0, 2], cross[:, 0, 1] - cross[:, 1, 0]], axis=1
    )
    trace = spread[:, 0, 0] + spread[:, 1, 1] + spread[:, 2, 2]
    inertia = trace[:, None, None] * np.eye(3) - spread
    spin = ((tm_dot @ z[:, 3:, 3:]) * tm_dot).reshape(len(z), -1).sum(1)
    com = com_rest_m + (tm @ mean_basis[:, :, None])[:, :, 0]
    velocity = (tm_dot @ mean_basis[:, :, None])[:, :, 0]
    return [
        RigidFrame(com[i], velocity[i], moment[i, :, :3] / mass_kg[i], inertia[i], angular_momentum[i], float(spin[i]))
        for i in range(len(z))
    ]


@dataclass(frozen=True)
class ObjectFrameConstants:
    """What :func:`_object_frame` needs of one object that never changes between frames.

    Attributes:
        moments: the inertia particles' moments.
        volume_m3: object volume (sum of the cubature volumes).
        gravity_force_n: (n,3) m_i g at the cubature points, N (read-only; shared by every frame).
        z_from_q: (12H,) index with z = q[z_from_q] (``q_to_z``).
        contact_radius_m: (k,) contact sphere radii, m.
        uniform_f: whether every cubature point's deformation basis is C = [I; 0] exactly (one affine handle):
            F = I + Tm C is then the same matrix at every point, formed and its determinant taken once.
    """

    moments: InertiaMoments
    volume_m3: float
    gravity_force_n: np.ndarray
    z_from_q: np.ndarray
    contact_radius_m: np.ndarray
    uniform_f: bool = False

    @classmethod
    def of(
        cls, model: ReducedObject, contact: ContactPoints, gravity_m_s2: torch.Tensor
    ) -> ObjectFrameConstants:
        """The constants of ``model`` with contact spheres ``contact`` under gravity (3,) m/s^2."""
        gravity_force = (model.masses_kg[:, None] * gravity_m_s2[None, :]).numpy()
        gravity_force.setflags(write=False)
        return cls(
            InertiaMoments.of(model),
            float(model.volumes_m3.sum()),
            gravity_force,
            np.argsort(handle_permutation(model.num_handles).numpy()),
            contact.radius_m.numpy(),
            model.num_handles == 1 and bool((model.c == _IDENTITY_C.to(model.c.dtype)).all()),
        )


_IDENTITY_C = torch.cat([torch.eye(3), torch.zeros(1, 3)])  # (4, 3) deformation basis of one affine handle


@dataclass(frozen=True)
class OneHandleGroup:
    """Objects of one affine handle (a uniform F, ``ObjectFrameConstants.uniform_f``) with the same numbers of
    cubature points P and contact spheres S: their frame records taken in batched array operations, the same
    formulas as :func:`_object_frame` applied to stacked (m, ...) arrays (one pass per frame instead of m).

    Attributes:
        members: (m,) object indices (recorder order).
        points_rest_m, points_b: (m, P, 3) cubature rest positions, m, and (m, P, 4) their basis rows.
        spheres_rest_m, spheres_b: (m, S, 3) contact sphere rest centres, m, and (m, S, 4) their basis rows.
        contact_radius_m: (m, S) m.
        second_moment, com_rest_m, mean_basis, mass_kg: the members' :class:`InertiaMoments`, stacked.
        volume_m3: (m,) m^3.  mu_pa, lam_pa: (m,) Lame parameters, Pa.
        z_from_q: (12,) the one-handle ``q_to_z`` index (the same for every member).
    """

    members: np.ndarray
    points_rest_m: torch.Tensor
    points_b: torch.Tensor
    spheres_rest_m: torch.Tensor
    spheres_b: torch.Tensor
    contact_radius_m: np.ndarray
    second_moment: np.ndarray
    com_rest_m: np.ndarray
    mean_basis: np.ndarray
    mass_kg: np.ndarray
    volume_m3: np.ndarray
    mu_pa: torch.Tensor
    lam_pa: torch.Tensor
    z_from_q: np.ndarray

    @classmethod
    def groups_of(cls, models: list[ReducedObject], contacts: list[ContactPoints],
                  constants: list[ObjectFrameConstants]) -> list[OneHandleGroup]:  # fmt: skip
        """The one-handle objects of a recorder, grouped by (P, S); objects of more handles are in none."""
        by_shape: dict[tuple[int, int], list[int]] = {}
        for k, (model, contact, const) in enumerate(zip(models, contacts, constants)):
            if const.uniform_f and model.num_handles == 1:
                by_shape.setdefault((model.num_points, contact.num_points), []).append(k)
        out = []
        for members in by_shape.values():
            ms = [models[k] for k in members]
            cs = [contacts[k] for k in members]
            mo = [constants[k].moments for k in members]
            out.append(cls(
                members=np.array(members),
                points_rest_m=torch.stack([m.points_rest for m in ms]),
                points_b=torch.stack([m.b for m in ms]),
                spheres_rest_m=torch.stack([c.rest_m for c in cs]),
                spheres_b=torch.stack([c.b for c in cs]),
                contact_radius_m=np.stack([constants[k].contact_radius_m for k in members]),
                second_moment=np.stack([x.second_moment for x in mo]),
                com_rest_m=np.stack([x.com_rest_m for x in mo]),
                mean_basis=np.stack([x.mean_basis for x in mo]),
                mass_kg=np.array([x.mass_kg for x in mo]),
                volume_m3=np.array([constants[k].volume_m3 for k in members]),
                mu_pa=torch.tensor([float(m.mu_pa) for m in ms], dtype=DTYPE),
                lam_pa=torch.tensor([float(m.lam_pa) for m in ms], dtype=DTYPE),
                z_from_q=constants[members[0]].z_from_q,
            ))  # fmt: skip
        return out

    def frames(self, qs: list[torch.Tensor], qdots: list[torch.Tensor],
               sphere_forces: list[torch.Tensor] | None) -> tuple[dict[str, np.ndarray], list[RigidFrame]]:  # fmt: skip
        """The members' per-frame arrays stacked (m, ...) (keys of :func:`_object_frame`'s record but the
        per-object constants and copies) and their :class:`RigidFrame`\\s; with ``sphere_forces`` (every
        object's, (S, 3) N) the stress from the mean stress theorem, else from the uniform F."""
        members = self.members
        q = torch.stack([qs[k] for k in members])  # (m, 12)
        tm = q.reshape(len(members), 3, 4)
        # positions member by member, as ReducedObject.positions and ContactPoints.positions take them (a batched
        # product may sum in another order: the records would move by an ulp)
        x = torch.stack([torch.mm(self.points_b[i], tm[i].T) for i in range(len(members))]).add_(self.points_rest_m)
        sphere_x = torch.stack([torch.mm(self.spheres_b[i], tm[i].T) for i in range(len(members))])
        sphere_x = sphere_x.add_(self.spheres_rest_m).numpy()  # (m, S, 3)
        tm_np = tm.numpy()
        tmdot = torch.stack([qdots[k] for k in members]).numpy().reshape(len(members), 3, 4)
        # F = I + Tm C with C = [I; 0]: I + Tm's first three columns (the products with C's zeros add nothing)
        f = np.eye(3) + tm_np[:, :, :3]
        det_f = det3(f)
        rigids = rigid_frames(self.second_moment, self.com_rest_m, self.mean_basis, self.mass_kg, tm_np, tmdot)
        if sphere_forces is not None:  # the mean stress theorem, per member
            mean = rigid_mean_hydrostatic_from_spin_pa(
                self.volume_m3, np.stack([r.com_m for r in rigids]), np.array([r.spin_j for r in rigids]), sphere_x,
                self.contact_radius_m, np.stack([sphere_forces[k].numpy() for k in members]),
            )  # fmt: skip
        else:  # the uniform F's hydrostatic stress
            mean = mat.hydrostatic_stress(torch.from_numpy(f), self.mu_pa, self.lam_pa).numpy()
        num_points = x.shape[1]
        arrays = {
            "handle_transforms": q.numpy()[:, self.z_from_q],
            "cubature_positions_m": x.numpy(),
            "contact_positions_m": sphere_x,
            "hydrostatic_stress_pa": np.repeat(mean[:, None], num_points, axis=1),
            "det_f": np.repeat(det_f[:, None], num_points, axis=1),
        }
        return arrays, rigids


class FrameRecorder:
    """Accumulates per-frame arrays of every object while the solver runs."""

    def __init__(
        self,
        names: list[str],
        ids: list[int],
        models: list[ReducedObject],
        contacts: list[ContactPoints],
        gravity_m_s2: np.ndarray,
    ) -> None:
        self.names, self.ids, self.models, self.contacts = names, ids, models, contacts
        self.gravity = torch.as_tensor(np.asarray(gravity_m_s2, dtype=np.float64))
        self.constants = [
            ObjectFrameConstants.of(model, contact, self.gravity) for model, contact in zip(models, contacts)
        ]
        self.groups = OneHandleGroup.groups_of(models, contacts, self.constants)
        self._grouped = np.zeros(len(models), dtype=bool)
        for group in self.groups:
            self._grouped[group.members] = True
        self.frames: list[list[dict]] = [[] for _ in models]
        self.energies: dict[str, list[float]] = {"kinetic": [], "elastic": [], "contact": [], "gravity": []}

    def record(
        self,
        qs: list[torch.Tensor],
        qdots: list[torch.Tensor],
        forces: list[torch.Tensor],
        partners: list[torch.Tensor],
        asleep: list[bool],
        energies: dict[str, float],
        sphere_forces: list[torch.Tensor] | None = None,
    ) -> None:
        """Append one frame.  ``forces``/``partners`` are per cubature point; ``sphere_forces`` (k,3) N per
        contact sphere, when given, set the stress of single-handle (near-rigid) objects, see
        :func:`rigid_mean_hydrostatic_pa`."""
        n = len(self.models)
        frames: list[dict] = [{} for _ in range(n)]
        rigids: list[RigidFrame | None] = [None] * n
        for group in self.groups:  # one-handle objects: batched per group
            arrays, group_rigids = group.frames(qs, qdots, sphere_forces)
            for i, k in enumerate(group.members):
                rigid = rigids[k] = group_rigids[i]
                frames[k] = {
                    "handle_transforms": arrays["handle_transforms"][i],
                    "cubature_positions_m": arrays["cubature_positions_m"][i],
                    "contact_positions_m": arrays["contact_positions_m"][i],
                    "gravity_force_n": self.constants[k].gravity_force_n,
                    "contact_force_n": forces[k].numpy().copy(),
                    "contact_partner": partners[k].numpy().copy(),
                    "hydrostatic_stress_pa": arrays["hydrostatic_stress_pa"][i],
                    "det_f": arrays["det_f"][i],
                    "com_m": rigid.com_m,
                    "orientation_wxyz": None,
                    "velocity_m_s": rigid.velocity_m_s,
                    "angular_velocity_rad_s": None,
                    "asleep": np.bool_(asleep[k]),
                }
        rest = np.flatnonzero(~self._grouped).tolist()
        if rest:  # the other objects: per-object geometry, their rigid sums and stresses in batched calls
            rest_frames, rest_rigids = _object_frames(
                [self.models[k] for k in rest], [self.contacts[k] for k in rest], [self.constants[k] for k in rest],
                [qs[k] for k in rest], [qdots[k] for k in rest], [forces[k] for k in rest],
                [partners[k] for k in rest], [asleep[k] for k in rest],
                None if sphere_forces is None else [sphere_forces[k] for k in rest],
            )  # fmt: skip
            for k, frame, rigid in zip(rest, rest_frames, rest_rigids):
                frames[k], rigids[k] = frame, rigid
        if rigids:  # orientations and angular velocities of all objects at once (batched SVD and least squares)
            rotations = rotation_from_cross_covariance(np.stack([r.cross_covariance_m2 for r in rigids]))
            omegas = angular_velocities_from_moments(
                torch.from_numpy(np.stack([r.inertia_kg_m2 for r in rigids])),
                torch.from_numpy(np.stack([r.angular_momentum_kg_m2_s for r in rigids])),
            ).numpy()
            for k, frame in enumerate(frames):
                frame["orientation_wxyz"] = matrix_to_quat_one(rotations[k])
                frame["angular_velocity_rad_s"] = omegas[k]
                self.frames[k].append(frame)
        for key, value in energies.items():
            self.energies[key].append(value)

    def tracks(self, bases: list[SkinningBasis]) -> list[ObjectTrack]:
        out = []
        for k, model in enumerate(self.models):
            fr = self.frames[k]
            stack = {key: np.stack([f[key] for f in fr]) for key in fr[0]}
            out.append(
                ObjectTrack(
                    object_id=self.ids[k],
                    name=self.names[k],
                    basis=bases[k],
                    points_rest_m=model.points_rest.numpy(),
                    volumes_m3=model.volumes_m3.numpy(),
                    masses_kg=model.masses_kg.numpy(),
                    contact_points_rest_m=self.contacts[k].rest_m.numpy(),
                    contact_radius_m=self.contacts[k].radius_m.numpy(),
                    **stack,
                )
            )
        return out


def _object_frames(
    models: list[ReducedObject],
    contacts: list[ContactPoints],
    constants: list[ObjectFrameConstants],
    qs: list[torch.Tensor],
    qdots: list[torch.Tensor],
    forces: list[torch.Tensor],
    partners: list[torch.Tensor],
    asleep: list[bool],
    sphere_forces: list[torch.Tensor] | None,
) -> tuple[list[dict], list[RigidFrame]]:
    """The frame records of several objects (but their orientations and angular velocities, None here) and their
    rigid-body moments: each object's positions and deformation gradients (a one-handle object with ``C = [I; 0]``
    has one F, its determinant repeated); the rigid-body sums of objects with the same basis width in one
    :func:`rigid_frames` call; the hydrostatic stresses from the deformation gradients in one call over all their
    points, or, for a one-handle object given its sphere forces, from the mean stress theorem. The same
    elementwise formulas as for one object at a time (:func:`_object_frame`), bit for bit."""
    n = len(models)
    geometry = []  # per object: cubature positions, F (None: uniform), det F, sphere centres
    for model, contact, const, q in zip(models, contacts, constants, qs):
        x = model.positions(q)
        if const.uniform_f:  # the same F at every point: one point's, its determinant repeated
            F = None
            det_f = np.full(model.num_points, det3(deformation_from_tmat(model.c[:1], model.tmat(q)).numpy())[0])
        else:
            F = model.deformation_gradients(q)
            det_f = det3(F.numpy())
        geometry.append((x, F, det_f, contact.positions(q)))
    rigids: list[RigidFrame | None] = [None] * n
    by_width: dict[int, list[int]] = {}
    for k, model in enumerate(models):
        by_width.setdefault(constants[k].moments.mean_basis.shape[0], []).append(k)
    for members in by_width.values():
        mo = [constants[k].moments for k in members]
        stacked = rigid_frames(
            np.stack([m.second_moment for m in mo]), np.stack([m.com_rest_m for m in mo]),
            np.stack([m.mean_basis for m in mo]), np.array([m.mass_kg for m in mo]),
            np.stack([qs[k].numpy().reshape(3, -1) for k in members]),
            np.stack([qdots[k].numpy().reshape(3, -1) for k in members]),
        )  # fmt: skip
        for k, rigid in zip(members, stacked):
            rigids[k] = rigid
    stresses: list[np.ndarray | None] = [None] * n
    from_f = []  # objects whose stress comes from their deformation gradients
    for k, model in enumerate(models):
        if sphere_forces is not None and model.num_handles == 1:  # the mean stress theorem
            mean = rigid_mean_hydrostatic_from_spin_pa(
                constants[k].volume_m3, rigids[k].com_m, rigids[k].spin_j, geometry[k][3].numpy(),
                constants[k].contact_radius_m, sphere_forces[k].numpy(),
            )  # fmt: skip
            stresses[k] = np.full(model.num_points, mean)
        else:
            from_f.append(k)
    if from_f:
        fs = [models[k].deformation_gradients(qs[k]) if geometry[k][1] is None else geometry[k][1] for k in from_f]
        counts = [len(f) for f in fs]
        per_point = [
            torch.cat([torch.as_tensor(getattr(models[k], name), dtype=DTYPE).expand(c) for k, c in zip(from_f, counts)])
            for name in ("mu_pa", "lam_pa")
        ]
        all_stress = mat.hydrostatic_stress(torch.cat(fs), *per_point).numpy()
        for k, part in zip(from_f, np.split(all_stress, np.cumsum(counts)[:-1])):
            stresses[k] = part
    frames = []
    for k in range(n):
        x, _, det_f, sphere_x = geometry[k]
        frames.append({
            "handle_transforms": qs[k].numpy()[constants[k].z_from_q],
            "cubature_positions_m": x.numpy(),
            "contact_positions_m": sphere_x.numpy(),
            "gravity_force_n": constants[k].gravity_force_n,
            "contact_force_n": forces[k].numpy().copy(),
            "contact_partner": partners[k].numpy().copy(),
            "hydrostatic_stress_pa": stresses[k],
            "det_f": det_f,
            "com_m": rigids[k].com_m,
            "orientation_wxyz": None,  # FrameRecorder.record fills these two for all objects at once
            "velocity_m_s": rigids[k].velocity_m_s,
            "angular_velocity_rad_s": None,
            "asleep": np.bool_(asleep[k]),
        })  # fmt: skip
    return frames, rigids


def _object_frame(
    model: ReducedObject,
    contact: ContactPoints,
    constants: ObjectFrameConstants,
    q: torch.Tensor,
    qdot: torch.Tensor,
    force: torch.Tensor,
    partner: torch.Tensor,
    asleep: bool,
    sphere_force: torch.Tensor | None,
) -> tuple[dict, RigidFrame]:
    """One object's frame record, but its orientation and angular velocity (None here), and its rigid-body
    moments (from which :meth:`FrameRecorder.record` derives those two for all objects at once):
    :func:`_object_frames` of this object alone."""
    frames, rigids = _object_frames([model], [contact], [constants], [q], [qdot], [force], [partner], [asleep],
                                    None if sphere_force is None else [sphere_force])  # fmt: skip
    return frames[0], rigids[0]


def rigid_mean_hydrostatic_pa(
    volume_m3: float,
    com_m: torch.Tensor,
    particle_masses_kg: torch.Tensor,
    particle_rel_velocity_m_s: torch.Tensor,
    sphere_x: torch.Tensor,
    sphere_r: torch.Tensor,
    sphere_f: torch.Tensor,
) -> float:
    """Volume-averaged hydrostatic Cauchy stress (Pa, negative = compression) of a near-rigid body from
    the forces acting on it (the mean stress theorem), not from its (tiny, solver-limited) strain.

    For a body of volume V with contact forces f_s acting at x_s (the point of sphere s that faces the
    force: centre - radius * f_s / |f_s|), centre of mass c, particle velocities v_p relative to the
    centre of mass's:
    ``tr(mean sigma) / 3 = (sum_s (x_s - c) . f_s + sum_p m_p |v_p - v_c|^2) / (3 V)``; the second sum
    is twice the rotational kinetic energy (centrifugal tension); gravity, uniform, adds nothing about
    the centre of mass.  A block of height L resting on a face gets ``-rho g L / 6``.  A single
    affine handle has a uniform strain, so this one number is its stress field; its strain, on the
    other hand, is E / (rho g L) times more sensitive to the Newton tolerance than the motion (a
    10 GPa block kept a spurious 1e5 Pa with the draft tolerance; measured).
    """
    spin = float((particle_masses_kg * (particle_rel_velocity_m_s**2).sum(1)).sum())
    return rigid_mean_hydrostatic_from_spin_pa(
        volume_m3, com_m.numpy(), spin, sphere_x.numpy(), sphere_r.numpy(), sphere_f.numpy()
    )


def rigid_mean_hydrostatic_from_spin_pa(
    volume_m3: float | np.ndarray,
    com_m: np.ndarray,
    spin: float | np.ndarray,
    sphere_x: np.ndarray,
    sphere_r: np.ndarray,
    sphere_f: np.ndarray,
) -> float | np.ndarray:
    """:func:`rigid_mean_hydrostatic_pa` on NumPy arrays with the particle sum ``spin`` = sum_p m_p
    |v_p - v_c|^2 (J) given (from :class:`InertiaMoments`, say): volume (m^3), centre of mass (3,) m,
    sphere centres (k,3) m, radii (k,) m and forces (k,3) N; the result in Pa. Leading batch axes (m, ...) on every
    argument give one result per object (m,)."""
    magnitude = np.sqrt((sphere_f * sphere_f).sum(-1))[..., None]
    where = sphere_x - sphere_r[..., None] * sphere_f / np.maximum(magnitude, 1e-300)
    product = (where - com_m[..., None, :]) * sphere_f
    virial = product.reshape(*product.shape[:-2], -1).sum(-1)
    return (virial + spin) / (3.0 * volume_m3)


def det3(f: np.ndarray) -> np.ndarray:
    """Determinants (...,) of 3x3 matrices (..., 3, 3) by cofactor expansion along the first row."""
    return (
        f[..., 0, 0] * (f[..., 1, 1] * f[..., 2, 2] - f[..., 1, 2] * f[..., 2, 1])
        - f[..., 0, 1] * (f[..., 1, 0] * f[..., 2, 2] - f[..., 1, 2] * f[..., 2, 0])
        + f[..., 0, 2] * (f[..., 1, 0] * f[..., 2, 1] - f[..., 1, 1] * f[..., 2, 0])
    )


def angular_velocity(rel_pos: torch.Tensor, rel_vel: torch.Tensor, masses: torch.Tensor) -> torch.Tensor:
    """omega (rad/s) = I^-1 L about the centre of mass (points relative to COM, velocities relative to COM)."""
    ang_mom = (masses[:, None] * torch.linalg.cross(rel_pos, rel_vel, dim=1)).sum(0)
    r2 = (rel_pos * rel_pos).sum(1)
    inertia = (
        masses[:, None, None]
        * (r2[:, None, None] * torch.eye(3, dtype=DTYPE) - rel_pos[:, :, None] * rel_pos[:, None, :])
    ).sum(0)
    return angular_velocity_from_moments(inertia, ang_mom)


def angular_velocity_from_moments(
    inertia_kg_m2: torch.Tensor, angular_momentum_kg_m2_s: torch.Tensor
) -> torch.Tensor:
    """omega (rad/s) = I^-1 L (least squares, so a degenerate inertia still gives an answer) from the inertia
    tensor (3,3) kg m^2 and angular momentum (3,) kg m^2/s about the centre of mass."""
    return torch.linalg.lstsq(inertia_kg_m2, angular_momentum_kg_m2_s[:, None]).solution[:, 0]


def angular_velocities_from_moments(
    inertia_kg_m2: torch.Tensor, angular_momentum_kg_m2_s: torch.Tensor
) -> torch.Tensor:
    """:func:`angular_velocity_from_moments` of a batch: inertia tensors (n, 3, 3) kg m^2 and angular momenta
    (n, 3) kg m^2/s give omegas (n, 3) rad/s."""
    return torch.linalg.lstsq(inertia_kg_m2, angular_momentum_kg_m2_s[:, :, None]).solution[:, :, 0]
