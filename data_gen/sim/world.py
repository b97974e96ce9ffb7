"""Scene-level simulator: object specs in, a recorded :class:`SimulationResult` out.

Each object is given by interior sample points in its own frame (m), its volume, a
:class:`Material` and an initial pose and velocity.  The simulator picks the handle count from the
stiffness (one affine handle for near-rigid objects), trains or loads the skinning basis, samples
cubature points, and runs implicit Euler (:mod:`data_gen.sim.solver`).  The initial pose is part of
the reduced state: handle 0 starts at ``T_0 = [R - I | p]`` so ``x = R x0 + p`` at t = 0.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch

from data_gen.sim.contact import PairFinder
from data_gen.sim.contact_points import ContactPoints, SurfaceSamples, surface_spheres
from data_gen.sim.cubature import sample_cubature
from data_gen.sim.material import Material
from data_gen.sim.presets import QualityPreset, load_preset
from data_gen.sim.recording import ContactEventTracker, FrameRecorder, SimulationRunSummary, SimulationResult
from data_gen.sim.reduced import DTYPE, ReducedObject, z_to_q
from data_gen.sim.skinning import (
    SkinningBasis,
    SkinningTrainingSettings,
    handles_for_stiffness,
    rigid_basis,
    train_skinning_basis,
)
from data_gen.sim.solver import ImplicitEulerSolver, SimBody, SimulationError
from data_gen.sim.state import State
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.threads import torch_threads
from newtphys.rotations import quat_to_matrix

__all__ = ["SimObjectSpec", "Simulator", "SimulationError", "UnsimulatableDraw", "object_handle_count"]

MAX_SELF_WEIGHT_STRAIN = 1.0  # rho |g| L / E above this: the object would collapse; refused


class UnsimulatableDraw(ValueError):
    """Well-formed objects that cannot be simulated as drawn: an object too soft to carry its own weight,
    one spawned inside the static scene, or two spawned overlapping. Generation rejects such a draw (with
    this message as the reason) instead of ending the run; malformed inputs stay plain ValueErrors."""


@dataclass(frozen=True)
class SimObjectSpec:
    """One object to simulate.

    Attributes:
        name: unique name (used in errors).
        points_rest_m: (n,3) interior sample points in the object frame, m (n >= 4).
        volume_m3: object volume, m^3 (> 0).
        material: E (Pa), nu, density (kg/m^3).
        position_m: world position of the object-frame origin at t = 0.
        orientation_wxyz: object-frame rotation at t = 0.
        velocity_m_s: initial velocity of the centre of mass.
        angular_velocity_rad_s: initial angular velocity about the centre of mass (world frame).
        friction_coefficient: Coulomb coefficient (>= 0); pairs use the geometric mean.
        num_handles: handle count; None picks it from the stiffness (capped by the preset).
        skinning_settings: training settings; None uses the defaults with the preset's step count.
        surface: samples of the object's surface (object frame); when given, contact uses
            ``preset.num_contact_points`` spheres touching the surface from inside (exact resting
            heights); None falls back to the cubature points as contact spheres (approximate).
    """

    name: str
    points_rest_m: np.ndarray
    volume_m3: float
    material: Material
    position_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    orientation_wxyz: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    velocity_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    angular_velocity_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    friction_coefficient: float = 0.5
    num_handles: int | None = None
    skinning_settings: SkinningTrainingSettings | None = field(default=None)
    surface: SurfaceSamples | None = field(default=None)


@dataclass
class _Prepared:
    spec: SimObjectSpec
    basis: SkinningBasis
    model: ReducedObject
    contact: ContactPoints
    q0: torch.Tensor
    qdot0: torch.Tensor


def object_handle_count(points_rest_m: np.ndarray, material: Material, max_handles: int) -> int:
    """Handles an object gets when its spec leaves ``num_handles`` unset: ``handles_for_stiffness`` of its material
    and size (the largest side of the particles' bounding box, m), capped at ``max_handles`` (the preset's)."""
    pts = np.asarray(points_rest_m, dtype=np.float64)
    size_m = float((pts.max(0) - pts.min(0)).max())
    return handles_for_stiffness(
        material.young_modulus_pa, material.density_kg_m3, size_m=size_m, max_handles=max_handles
    )


class Simulator:
    """Simulates objects in a static scene under gravity.

    Args:
        static_scene: the kinematic scene (ground plane and boxes).
        objects: object specs; ids are assigned 1.. in this order.
        gravity_m_s2: gravity vector (3,), m/s^2.
        preset: a :class:`QualityPreset` or its name.
        seed: seed of every random draw (cubature sampling, skinning training).
        device: warp device for the SDF and hash-grid kernels.
        skinning_cache_dir: cache directory of trained skinning bases (None: the default).
        num_threads: torch intra-op threads while stepping (restored afterwards).  The reduced
            system is small (tens to hundreds of DOFs per object), so 1 thread is fastest and avoids
            oversubscription when several simulations run side by side.
        fused_newton: solve islands with the fused Newton kernel (:mod:`data_gen.sim.fused_newton`); False: the
            batched :func:`~data_gen.sim.newton.minimise` (the reference path).
        training_threads: skinning bases trained side by side.
        device_newton: solve islands with :class:`~data_gen.sim.device_newton.DeviceNewton` (Newton's method as
            launches with a thread per element, the GPU's shape) on ``device``, instead of the fused kernel's
            sub-step launch (one-handle islands: the same results to round-off) and the split solve (deformable
            islands: the full Newton matrix every iteration); 3-5x slower on the CPU.
    """

    def __init__(
        self,
        static_scene: StaticScene,
        objects: list[SimObjectSpec],
        gravity_m_s2,
        preset: QualityPreset | str,
        seed: int,
        device: str = "cpu",
        skinning_cache_dir: str | None = None,
        num_threads: int = 1,
        fused_newton: bool = True,
        training_threads: int = 1,
        device_newton: bool = False,
    ) -> None:
        self.num_threads = int(num_threads)
        if not isinstance(training_threads, (int, np.integer)) or training_threads < 1:
            raise ValueError(f"training_threads={training_threads!r} must be an integer >= 1")
        self.training_threads = int(training_threads)
        self.fused_newton = bool(fused_newton)
        self.device_newton = bool(device_newton)
        self.scene = static_scene
        self.preset = load_preset(preset) if isinstance(preset, str) else preset
        self.gravity = np.asarray(gravity_m_s2, dtype=np.float64)
        if self.gravity.shape != (3,) or not np.all(np.isfinite(self.gravity)):
            raise ValueError(f"gravity_m_s2={gravity_m_s2!r} must be 3 finite numbers (m/s^2)")
        if not isinstance(seed, (int, np.integer)) or seed < 0:
            raise ValueError(f"seed={seed!r} must be an integer >= 0")
        self.seed = int(seed)
        self.device = device
        self.cache_dir = skinning_cache_dir
        names = [o.name for o in objects]
        if len(set(names)) != len(names):
            raise ValueError(f"object names must be unique; got {names}")
        t0 = time.perf_counter()
        with torch_threads(self.num_threads):
            bases = self._bases(objects)
            self.prepared = [self._prepare(k, spec, basis) for k, (spec, basis) in enumerate(zip(objects, bases))]
        self.setup_time_s = time.perf_counter() - t0
        self._check_spawn_overlaps()

    # ------------------------------------------------------------------ preparation
    def _object_seed(self, index: int) -> int:
        return int(np.random.SeedSequence([self.seed, index]).generate_state(1)[0])

    def _bases(self, objects: list[SimObjectSpec]) -> list[SkinningBasis]:
        """Every object's skinning basis (trained, or loaded from the cache), after validating every spec.

        The objects that need training train side by side in ``training_threads`` threads, each on one torch
        thread: every training is the same single-threaded computation either way, so the bases are the same
        bits, and a job given several CPUs does not leave all but one idle while a draw's bases train (about 2 s
        each at ``standard``)."""
        jobs: list[Callable[[], SkinningBasis]] = []
        for index, spec in enumerate(objects):  # loop over objects: validation and handle counts only
            _validate_spec(spec, self.gravity)
            pts = torch.as_tensor(np.asarray(spec.points_rest_m, dtype=np.float64))
            mat = spec.material
            num_h = spec.num_handles
            if num_h is None:
                num_h = object_handle_count(spec.points_rest_m, mat, self.preset.max_handles)
            if not isinstance(num_h, int) or num_h < 1:
                raise ValueError(f"object {spec.name!r}: num_handles={num_h!r} must be an integer >= 1")
            if num_h == 1:
                jobs.append(rigid_basis)
                continue
            settings = spec.skinning_settings or SkinningTrainingSettings(
                steps=max(1, self.preset.skinning_training_steps)
            )
            jobs.append(partial(train_skinning_basis, pts, num_h, mat.poisson_ratio, settings=settings,
                                seed=self._object_seed(index), cache_dir=self.cache_dir))  # fmt: skip
        workers = min(self.training_threads, sum(job is not rigid_basis for job in jobs))
        if workers <= 1:
            return [job() for job in jobs]
        with torch_threads(1), ThreadPoolExecutor(workers) as pool:  # one torch thread each, for the whole pool
            return list(pool.map(lambda job: job(), jobs))

    def _prepare(self, index: int, spec: SimObjectSpec, basis: SkinningBasis) -> _Prepared:
        pts = torch.as_tensor(np.asarray(spec.points_rest_m, dtype=np.float64))
        mat = spec.material
        seed = self._object_seed(index)
        num_h = basis.num_handles
        rot = quat_to_matrix(spec.orientation_wxyz)
        pos = np.asarray(spec.position_m, dtype=np.float64)

        def scene_side(points: torch.Tensor) -> torch.Tensor:
            """Distance (m) of rest points to the static scene at spawn, relative to the closest point."""
            sdf, _ = self.scene.query(points.numpy() @ rot.T + pos)
            return torch.from_numpy(sdf - sdf.min())

        cub_pos, cub_vol, radius = sample_cubature_points(
            pts, spec.volume_m3, self.preset.num_cubature_points, seed, contact_distance_fn=scene_side
        )
        weights, grads = basis.evaluate(cub_pos)
        mu, lam = mat.lame_pa
        # inertia from every particle (exact for the sample, independent of the cubature count)
        model = ReducedObject(
            cub_pos, cub_vol, mat.density_kg_m3, weights, grads, mu, lam,
            mass_points_rest=pts, mass_weights=basis.evaluate(pts)[0],
        )
        if spec.surface is None:
            contact = ContactPoints.build(cub_pos, radius, weights, cub_pos)
        else:
            centres, radii = surface_spheres(spec.surface, self.preset.num_contact_points)
            contact = ContactPoints.build(centres, radii, basis.evaluate(torch.from_numpy(centres))[0], cub_pos)
        omega = np.asarray(spec.angular_velocity_rad_s, dtype=np.float64)
        vel = np.asarray(spec.velocity_m_s, dtype=np.float64)
        com0 = model.com_rest_m.numpy()
        skew = np.array([[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]])
        z0 = torch.zeros(12 * num_h, dtype=DTYPE)
        z0[:12] = torch.from_numpy(np.concatenate([rot - np.eye(3), pos[:, None]], 1).reshape(-1))
        zdot0 = torch.zeros(12 * num_h, dtype=DTYPE)
        lin = vel - skew @ rot @ com0
        zdot0[:12] = torch.from_numpy(np.concatenate([skew @ rot, lin[:, None]], 1).reshape(-1))
        return _Prepared(spec, basis, model, contact, z_to_q(z0), z_to_q(zdot0))

    def _check_spawn_overlaps(self) -> None:
        """Refuse contact sphere centres inside the scene or spheres overlapping by more than their mean radius."""
        xs = []
        for p in self.prepared:
            x = p.contact.positions(p.q0)
            sdf, _ = self.scene.query(x.numpy())
            if sdf.min() < 0:
                raise UnsimulatableDraw(
                    f"object {p.spec.name!r}: position_m={tuple(p.spec.position_m)} places it "
                    f"inside the static scene (deepest point {-sdf.min():.4g} m below the surface)"
                )
            xs.append(x.numpy())
        # object pairs: a cubature centre closer to another object's centre than their mean radius
        pairs = PairFinder(self.device).find(
            np.concatenate(xs) if xs else np.zeros((0, 3)),
            np.concatenate([np.full(len(x), k) for k, x in enumerate(xs)]) if xs else np.zeros(0, dtype=int),
            np.concatenate([p.contact.radius_m.numpy() for p in self.prepared]) if xs else np.zeros(0),
            margin_m=0.0,
        )
        if len(pairs):
            x_all = np.concatenate(xs)
            r_all = np.concatenate([p.contact.radius_m.numpy() for p in self.prepared])
            owner = np.concatenate([np.full(len(x), k) for k, x in enumerate(xs)])
            gap = np.linalg.norm(x_all[pairs[:, 0]] - x_all[pairs[:, 1]], axis=1) - 0.5 * r_all[pairs].sum(1)
            if gap.min() < 0:
                a, c = owner[pairs[np.argmin(gap)]]
                pa, pc = self.prepared[a].spec, self.prepared[c].spec
                raise UnsimulatableDraw(
                    f"objects {pa.name!r} and {pc.name!r} are spawned overlapping "
                    f"(position_m {tuple(pa.position_m)} and {tuple(pc.position_m)})"
                )

    # ------------------------------------------------------------------ run
    def run(self, num_frames: int, fps: float = 25.0) -> SimulationResult:
        """Simulate ``num_frames`` frames (frame 0 = initial state) at ``fps`` frames per second."""
        if not isinstance(num_frames, (int, np.integer)) or num_frames < 1:
            raise ValueError(f"num_frames={num_frames!r} must be an integer >= 1")
        dt = self.preset.dt_s(fps)
        sub = self.preset.substeps_per_frame
        bodies = [
            SimBody(k + 1, p.spec.name, p.model, p.contact, p.spec.friction_coefficient)
            for k, p in enumerate(self.prepared)
        ]
        state = State.awake([p.q0.clone() for p in self.prepared], [p.qdot0.clone() for p in self.prepared])
        solver = ImplicitEulerSolver(
            bodies, state, self.scene, self.gravity, self.preset, dt, device=self.device,
            fused_newton=self.fused_newton, device_newton=self.device_newton,
        )
        recorder = FrameRecorder(
            [b.name for b in bodies],
            [b.object_id for b in bodies],
            [b.model for b in bodies],
            [b.contact for b in bodies],
            self.gravity,
        )
        tracker = ContactEventTracker(dt, sub, gap_steps=sub)
        with torch_threads(self.num_threads):
            return self._run(solver, recorder, tracker, bodies, num_frames, fps, dt, sub)

    def _run(
        self,
        solver: ImplicitEulerSolver,
        recorder: FrameRecorder,
        tracker: ContactEventTracker,
        bodies: list[SimBody],
        num_frames: int,
        fps: float,
        dt: float,
        sub: int,
    ) -> SimulationResult:
        t_start = time.perf_counter()
        solver.refresh_forces()
        self._record(recorder, solver)
        total_newton, max_newton, awake_steps = 0, 0, 0
        num_steps = sub * (int(num_frames) - 1)
        for step in range(num_steps):
            stats = solver.step(record_sphere_forces=(step + 1) % sub == 0)  # per-sphere records: frames only
            total_newton += stats.newton_iterations
            max_newton = max(max_newton, stats.newton_iterations)
            awake_steps += stats.awake_objects
            tracker.update(step, stats.pair_forces)
            if (step + 1) % sub == 0:
                self._record(recorder, solver)
        wall = time.perf_counter() - t_start
        info = SimulationRunSummary(
            quality=self.preset.name,
            dt_s=dt,
            substeps=sub,
            newton_iterations=total_newton,
            wall_time_s=wall,
            num_steps=num_steps,
            max_newton_iterations_per_step=max_newton,
            awake_object_steps=awake_steps,
            object_steps=num_steps * len(bodies),
            seed=self.seed,
            timings_s={"setup": self.setup_time_s, **solver.timings},
            counters=dict(solver.counters),
        )
        return SimulationResult(
            fps=float(fps),
            num_frames=int(num_frames),
            gravity_m_s2=self.gravity.copy(),
            objects=recorder.tracks([p.basis for p in self.prepared]),
            collisions=tracker.finish(),
            info=info,
            energies_j={k: np.asarray(v) for k, v in recorder.energies.items()},
        )

    @staticmethod
    def _record(recorder: FrameRecorder, solver: ImplicitEulerSolver) -> None:
        t0 = time.perf_counter()
        broad_phase_s = solver.timings["broad_phase"]  # the energies' pair search is the next step's broad phase
        b, state = solver.bodies, solver.state
        per_cubature = solver.cubature_contacts()
        recorder.record(
            list(state.q),
            list(state.qdot),
            [f for f, _ in per_cubature],
            [p for _, p in per_cubature],
            state.asleep.tolist(),
            solver.energies(),
            sphere_forces=[x.contact_force_n for x in b],
        )
        elapsed = time.perf_counter() - t0 - (solver.timings["broad_phase"] - broad_phase_s)
        solver.timings["recording"] = solver.timings.get("recording", 0.0) + elapsed


def _validate_spec(spec: SimObjectSpec, gravity: np.ndarray) -> None:
    name = spec.name
    mat = spec.material
    e, nu, rho = mat.young_modulus_pa, mat.poisson_ratio, mat.density_kg_m3
    if not (e > 0 and np.isfinite(e)):
        raise ValueError(
            f"object {name!r}: young_modulus_pa={e!r} is out of range; allowed: 0 < E < inf (Pa)"
        )
    if not 0.0 <= nu < 0.5:
        raise ValueError(f"object {name!r}: poisson_ratio={nu!r} is out of range; allowed: 0 <= nu < 0.5")
    if not (rho > 0 and np.isfinite(rho)):
        raise ValueError(f"object {name!r}: density_kg_m3={rho!r} is out of range; allowed: > 0")
    if not (spec.volume_m3 > 0 and np.isfinite(spec.volume_m3)):
        raise ValueError(f"object {name!r}: volume_m3={spec.volume_m3!r} is out of range; allowed: > 0 (m^3)")
    pts = np.asarray(spec.points_rest_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 4 or not np.all(np.isfinite(pts)):
        raise ValueError(
            f"object {name!r}: points_rest_m must be finite with shape (n >= 4, 3); got {pts.shape}"
        )
    if not spec.friction_coefficient >= 0:
        raise ValueError(f"object {name!r}: friction_coefficient={spec.friction_coefficient!r} must be >= 0")
    for key in ("position_m", "velocity_m_s", "angular_velocity_rad_s"):
        value = np.asarray(getattr(spec, key), dtype=np.float64)
        if value.shape != (3,) or not np.all(np.isfinite(value)):
            raise ValueError(f"object {name!r}: {key}={getattr(spec, key)!r} must be 3 finite numbers")
    size_m = float((pts.max(0) - pts.min(0)).max())
    strain = rho * float(np.linalg.norm(gravity)) * size_m / e
    if strain > MAX_SELF_WEIGHT_STRAIN:
        raise UnsimulatableDraw(
            f"object {name!r}: young_modulus_pa={e!r} is too soft for |g|={np.linalg.norm(gravity):.3g} "
            f"m/s^2 (self-weight strain rho g L / E = {strain:.3g} > {MAX_SELF_WEIGHT_STRAIN}); "
            f"allowed: E >= {rho * np.linalg.norm(gravity) * size_m / MAX_SELF_WEIGHT_STRAIN:.3g} Pa"
        )


def sample_cubature_points(
    points_rest: torch.Tensor, volume_m3: float, num_points: int, seed: int, contact_distance_fn=None
) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Cubature positions (k,3) m, volumes (k,) m^3 summing to ``volume_m3``, contact radii (k,) m.

    Uses sim part A's ``sample_cubature`` (Morton-clustered, ``contact_bias`` x denser where
    ``contact_distance_fn(points) -> (n,) m`` is small).  Each sphere's radius is half its own
    cubature spacing, ``0.5 * volume_i^(1/3)``, so neighbouring spheres just touch in both strata.
    """
    k = min(int(num_points), points_rest.shape[0])
    cub = sample_cubature(
        points_rest, k, seed=seed, volume_m3=float(volume_m3), contact_region=contact_distance_fn
    )
    pos = torch.as_tensor(cub.positions, dtype=DTYPE)
    vol = torch.as_tensor(cub.volumes_m3, dtype=DTYPE)
    radius = 0.5 * vol.numpy() ** (1.0 / 3.0)
    return pos, vol, radius
