"""The recorder's moment-based rigid-body quantities equal the particle sums they replace.

``FrameRecorder`` forms, once per object, the mass moments of the inertia particles in the affine basis
(``InertiaMoments``); each frame then costs products of (3 + 4H)-sized matrices.  Here every recorded
per-frame value is compared with the particle-sum formulas the recorder used before (written out below,
or the point-cloud functions ``best_fit_rotation`` / ``angular_velocity`` / ``rigid_mean_hydrostatic_pa``)
on random states of one- and multi-handle objects, with and without separate inertia particles, and on
rotated, translated, spinning states whose exact answers are known.
"""

import numpy as np
import pytest
import torch

from data_gen.sim import material as mat
from data_gen.sim.contact_points import ContactPoints
from data_gen.sim.recording import (
    FrameRecorder,
    _object_frame,
    _object_frames,
    InertiaMoments,
    angular_velocity,
    det3,
    rigid_mean_hydrostatic_pa,
)
from data_gen.sim.reduced import ReducedObject, q_to_z, z_to_q
from newtphys.rotations import (
    axis_angle_to_quat,
    best_fit_rotation,
    matrix_to_quat,
    matrix_to_quat_one,
    quat_to_matrix,
    rotation_from_cross_covariance,
)

D = torch.float64
RTOL = 1e-12
GRAVITY = np.array([0.3, -0.2, -9.81])


def _object(num_handles: int, seed: int, num_mass_points: int | None) -> tuple[ReducedObject, ContactPoints]:
    """A random reduced object: 40 cubature points of random volumes (so unequal cubature masses) in a
    box off the origin, and optionally ``num_mass_points`` separate inertia particles."""
    gen = torch.Generator().manual_seed(seed)
    n = 40
    x0 = torch.rand(n, 3, generator=gen, dtype=D) * torch.tensor([0.3, 0.2, 0.1], dtype=D) + 0.05
    w = torch.rand(n, num_handles, generator=gen, dtype=D)
    w[:, 0] = 1.0
    g = 0.3 * torch.randn(n, num_handles, 3, generator=gen, dtype=D)
    g[:, 0] = 0.0
    vol = (0.5 + torch.rand(n, generator=gen, dtype=D)) * 1e-4
    mu, lam = mat.lame_parameters(1e6, 0.3)
    extra = {}
    if num_mass_points is not None:
        mp = torch.rand(num_mass_points, 3, generator=gen, dtype=D) * torch.tensor([0.3, 0.2, 0.1], dtype=D)
        mp = mp + 0.05
        mw = torch.rand(num_mass_points, num_handles, generator=gen, dtype=D)
        mw[:, 0] = 1.0
        extra = {"mass_points_rest": mp, "mass_weights": mw}
    obj = ReducedObject(x0, vol, 900.0, w, g, mu, lam, **extra)
    centres = x0[: n // 2].numpy()
    contact = ContactPoints.build(centres, np.full(len(centres), 0.01), w[: n // 2], x0)
    return obj, contact


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def _rigid_state(
    obj: ReducedObject, quat: np.ndarray, com_m: np.ndarray, velocity_m_s: np.ndarray, omega_rad_s: np.ndarray
) -> tuple[torch.Tensor, torch.Tensor]:
    """q, qdot (q-ordering) of a rigid motion through handle 0: rotation ``quat`` about the rest centre of
    mass, centre of mass at ``com_m`` moving at ``velocity_m_s``, spinning at ``omega_rad_s``."""
    rot = quat_to_matrix(quat)
    c0 = obj.com_rest_m.numpy()
    t = com_m - rot @ c0  # x = R r + t
    w = _skew(omega_rad_s) @ rot  # xdot = W r + tdot, with the centre of mass moving at velocity_m_s
    tdot = velocity_m_s - w @ c0
    z = np.zeros(obj.num_dofs)
    zdot = np.zeros(obj.num_dofs)
    z[:12] = np.concatenate([rot - np.eye(3), t[:, None]], axis=1).reshape(-1)
    zdot[:12] = np.concatenate([w, tdot[:, None]], axis=1).reshape(-1)
    return z_to_q(torch.from_numpy(z)), z_to_q(torch.from_numpy(zdot))


def _random_state(obj: ReducedObject, seed: int) -> tuple[torch.Tensor, torch.Tensor]:
    """A rotated, translated, spinning state with a random deformation and deformation rate on top."""
    rng = np.random.default_rng(seed)
    quat = np.concatenate([[2.0], rng.normal(size=3)])  # w > 0: far from the quaternion sign flip
    q, qdot = _rigid_state(obj, quat / np.linalg.norm(quat), rng.normal(size=3) + [1.0, -2.0, 3.0],
                           rng.normal(size=3), 3.0 * rng.normal(size=3))
    q = q + 0.05 * torch.from_numpy(rng.normal(size=obj.num_dofs))
    qdot = qdot + 0.5 * torch.from_numpy(rng.normal(size=obj.num_dofs))
    return q, qdot


def _reference(obj: ReducedObject, q: torch.Tensor, qdot: torch.Tensor) -> dict:
    """What the recorder computed before the moments: sums over every inertia particle."""
    xp = obj.mass_points_rest + obj.mass_b @ q.reshape(3, -1).T
    vp = obj.mass_b @ qdot.reshape(3, -1).T
    mp = obj.particle_masses_kg
    com = (mp[:, None] * xp).sum(0) / obj.mass_kg
    vcom = (mp[:, None] * vp).sum(0) / obj.mass_kg
    rel_x, rel_v = xp - com, vp - vcom
    r2 = (rel_x * rel_x).sum(1)
    outer = rel_x[:, :, None] * rel_x[:, None, :]
    inertia = (mp[:, None, None] * (r2[:, None, None] * torch.eye(3, dtype=D) - outer)).sum(0)
    w = (mp / mp.sum()).numpy()
    rest = obj.mass_points_rest.numpy()
    ca, cb = w @ rest, w @ xp.numpy()
    return {
        "xp": xp, "vp": vp, "com": com, "vcom": vcom,
        "inertia": inertia.numpy(),
        "angular_momentum": (mp[:, None] * torch.linalg.cross(rel_x, rel_v, dim=1)).sum(0).numpy(),
        "cross_covariance": np.einsum("n,ni,nj->ij", w, xp.numpy() - cb, rest - ca),
        "spin": float((mp * (rel_v**2).sum(1)).sum()),
        "orientation": matrix_to_quat(best_fit_rotation(rest, xp.numpy(), mp.numpy())),
        "omega": angular_velocity(rel_x, rel_v, mp).numpy(),
    }


def _assert_rel(new: np.ndarray, ref: np.ndarray, rtol: float = RTOL) -> None:
    """|new - ref| <= rtol |ref| entrywise-max (relative to the largest entry of ref)."""
    new, ref = np.asarray(new, np.float64), np.asarray(ref, np.float64)
    assert new.shape == ref.shape
    scale = float(np.abs(ref).max())
    assert scale > 0.0
    err = float(np.abs(new - ref).max())
    assert err <= rtol * scale, f"max |new - ref| = {err:.3e} > {rtol:.0e} * {scale:.3e}"


CASES = [(1, None), (3, None), (1, 500), (4, 700)]  # (handles, inertia particles: None = the cubature points)


@pytest.mark.parametrize("num_handles,num_mass_points", CASES)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_moments_give_the_particle_sums(num_handles, num_mass_points, seed):
    obj, _ = _object(num_handles, seed, num_mass_points)
    moments = InertiaMoments.of(obj)
    q, qdot = _random_state(obj, 100 + seed)
    ref = _reference(obj, q, qdot)
    frame = moments.frame(q.numpy().reshape(3, -1), qdot.numpy().reshape(3, -1))
    _assert_rel(frame.com_m, ref["com"].numpy())
    _assert_rel(frame.velocity_m_s, ref["vcom"].numpy())
    _assert_rel(frame.inertia_kg_m2, ref["inertia"])
    _assert_rel(frame.angular_momentum_kg_m2_s, ref["angular_momentum"])
    _assert_rel(frame.cross_covariance_m2, ref["cross_covariance"])
    assert abs(frame.spin_j - ref["spin"]) <= RTOL * ref["spin"]
    rotation = rotation_from_cross_covariance(frame.cross_covariance_m2)
    _assert_rel(matrix_to_quat_one(rotation), ref["orientation"])
    # the state moves: these are not near-zero values compared loosely
    assert np.linalg.norm(ref["angular_momentum"]) > 1e-3 * obj.mass_kg * 0.01 and ref["spin"] > 0.0
    assert moments.mass_kg == pytest.approx(obj.mass_kg, rel=RTOL)
    _assert_rel(moments.com_rest_m, obj.com_rest_m.numpy())


@pytest.mark.parametrize("num_handles,num_mass_points", CASES)
def test_recorded_frame_equals_the_particle_sum_formulas(num_handles, num_mass_points):
    obj, contact = _object(num_handles, 7, num_mass_points)
    q, qdot = _random_state(obj, 11)
    gen = torch.Generator().manual_seed(3)
    force = torch.randn(obj.num_points, 3, generator=gen, dtype=D)
    partner = torch.randint(-1, 3, (obj.num_points,), generator=gen)
    sphere_force = torch.randn(contact.num_points, 3, generator=gen, dtype=D)
    sphere_force[0] = 0.0  # a sphere without contact
    rec = FrameRecorder(["obj"], [1], [obj], [contact], GRAVITY)
    rec.record([q], [qdot], [force], [partner], [False], {"kinetic": 1.0}, sphere_forces=[sphere_force])
    rec.record([q], [qdot], [force], [partner], [True], {"kinetic": 2.0})
    with_spheres, without = rec.frames[0]
    ref = _reference(obj, q, qdot)

    for fr in (with_spheres, without):
        _assert_rel(fr["com_m"], ref["com"].numpy())
        _assert_rel(fr["velocity_m_s"], ref["vcom"].numpy())
        _assert_rel(fr["orientation_wxyz"], ref["orientation"])
        _assert_rel(fr["angular_velocity_rad_s"], ref["omega"])
        np.testing.assert_array_equal(fr["handle_transforms"], q_to_z(q).numpy())
        np.testing.assert_array_equal(fr["cubature_positions_m"], obj.positions(q).numpy())
        np.testing.assert_array_equal(fr["contact_positions_m"], contact.positions(q).numpy())
        gravity_force = obj.masses_kg.numpy()[:, None] * GRAVITY[None, :]
        np.testing.assert_array_equal(fr["gravity_force_n"], gravity_force)
        np.testing.assert_array_equal(fr["contact_force_n"], force.numpy())
        np.testing.assert_array_equal(fr["contact_partner"], partner.numpy())
        np.testing.assert_allclose(
            fr["det_f"], torch.linalg.det(obj.deformation_gradients(q)).numpy(), rtol=1e-13, atol=0.0
        )
    assert not with_spheres["asleep"] and without["asleep"]
    np.testing.assert_array_equal(without["hydrostatic_stress_pa"], obj.cauchy_hydrostatic(q).numpy())
    if num_handles == 1:  # near-rigid: the mean stress theorem from the sphere forces and the spin
        mean = rigid_mean_hydrostatic_pa(
            float(obj.volumes_m3.sum()), ref["com"], obj.particle_masses_kg, ref["vp"] - ref["vcom"],
            contact.positions(q), contact.radius_m, sphere_force,
        )
        assert with_spheres["hydrostatic_stress_pa"].shape == (obj.num_points,)
        np.testing.assert_allclose(with_spheres["hydrostatic_stress_pa"], mean, rtol=RTOL, atol=0.0)
        assert abs(mean) > 0.0
    else:
        stress = obj.cauchy_hydrostatic(q).numpy()
        np.testing.assert_array_equal(with_spheres["hydrostatic_stress_pa"], stress)
    # the stacked tracks are the per-frame values (and own their memory: the cached gravity is read-only)
    track = rec.tracks([None])[0]
    np.testing.assert_array_equal(track.com_m[1], without["com_m"])
    track.gravity_force_n[0, 0, 0] = 0.0
    assert rec.constants[0].gravity_force_n[0, 0] != 0.0
    assert rec.energies["kinetic"] == [1.0, 2.0]


@pytest.mark.parametrize("num_handles,num_mass_points", CASES)
def test_rigid_spinning_state_is_recorded_exactly(num_handles, num_mass_points):
    obj, contact = _object(num_handles, 5, num_mass_points)
    quat = axis_angle_to_quat(np.array([1.0, -2.0, 0.5]), 2.3)
    com = np.array([4.0, -1.5, 2.5])
    vel = np.array([0.7, 0.2, -3.0])
    omega = np.array([-4.0, 1.0, 6.0])
    q, qdot = _rigid_state(obj, quat, com, vel, omega)
    zeros = torch.zeros(obj.num_points, 3, dtype=D)
    rec = FrameRecorder(["obj"], [1], [obj], [contact], GRAVITY)
    rec.record([q], [qdot], [zeros], [torch.full((obj.num_points,), -1)], [False], {})
    fr = rec.frames[0][0]
    np.testing.assert_allclose(fr["com_m"], com, rtol=0.0, atol=1e-14 * np.abs(com).max())
    np.testing.assert_allclose(fr["velocity_m_s"], vel, rtol=0.0, atol=1e-13 * np.abs(omega).max())
    np.testing.assert_allclose(fr["orientation_wxyz"], quat, rtol=0.0, atol=1e-14)
    omega_tol = 1e-12 * np.abs(omega).max()
    np.testing.assert_allclose(fr["angular_velocity_rad_s"], omega, rtol=0.0, atol=omega_tol)
    np.testing.assert_allclose(fr["det_f"], 1.0, rtol=0.0, atol=1e-14)
    ref = _reference(obj, q, qdot)
    _assert_rel(fr["angular_velocity_rad_s"], ref["omega"])
    _assert_rel(fr["orientation_wxyz"], ref["orientation"])


def test_uniform_translation_and_rest_are_recorded_exactly():
    """A translating rest-shaped object: the recorded velocity is the translation bit for bit (the mean
    homogeneous basis entry of handle 0 is exactly 1), the orientation the identity (to round-off: the
    SVD of the symmetric rest covariance) and the spin exactly 0."""
    for num_handles, num_mass_points in CASES:
        obj, contact = _object(num_handles, 9, num_mass_points)
        identity, velocity = np.array([1.0, 0.0, 0.0, 0.0]), np.array([2.0, -1.0, 0.5])
        q, qdot = _rigid_state(obj, identity, np.zeros(3), velocity, np.zeros(3))
        moments = InertiaMoments.of(obj)
        frame = moments.frame(q.numpy().reshape(3, -1), qdot.numpy().reshape(3, -1))
        assert moments.mean_basis[3] == 1.0
        np.testing.assert_array_equal(frame.velocity_m_s, velocity)
        rotation = rotation_from_cross_covariance(frame.cross_covariance_m2)
        np.testing.assert_allclose(matrix_to_quat_one(rotation), identity, rtol=0.0, atol=1e-15)
        assert frame.spin_j == 0.0


def test_single_matrix_helpers_match_the_batched_functions():
    rng = np.random.default_rng(4)
    rots = quat_to_matrix(rng.normal(size=(300, 4)))
    # all four Shepperd pivots and their ties: identity and the half turns about each axis
    rots = np.concatenate([rots, np.eye(3)[None], np.diag([1.0, -1.0, -1.0])[None],
                           np.diag([-1.0, 1.0, -1.0])[None], np.diag([-1.0, -1.0, 1.0])[None]])
    one = np.stack([matrix_to_quat_one(r) for r in rots])
    np.testing.assert_array_equal(one, matrix_to_quat(rots))  # bit for bit
    pivots = [np.trace(rots, axis1=1, axis2=2), rots[:, 0, 0], rots[:, 1, 1], rots[:, 2, 2]]
    pick = np.argmax(np.stack(pivots, 1), 1)
    assert set(pick.tolist()) == {0, 1, 2, 3}
    with pytest.raises(ValueError, match=r"shape \(3, 3\)"):
        matrix_to_quat_one(np.eye(4))
    with pytest.raises(ValueError, match="finite"):
        matrix_to_quat_one(np.full((3, 3), np.nan))
    # Kabsch from the cross-covariance equals the point-cloud fit, also for a reflected cloud
    rest = rng.normal(size=(50, 3))
    w = rng.random(50) + 0.1
    for moved in (rest @ rots[0].T + 2.0, rest * [-1.0, 1.0, 1.0]):
        wn = w / w.sum()
        h = np.einsum("n,ni,nj->ij", wn, moved - wn @ moved, rest - wn @ rest)
        fit = best_fit_rotation(rest, moved, w)
        np.testing.assert_allclose(rotation_from_cross_covariance(h), fit, atol=1e-14)
        np.testing.assert_allclose(rotation_from_cross_covariance(3.0 * h), fit, atol=1e-14)  # scale-free
    assert np.linalg.det(rotation_from_cross_covariance(np.diag([1.0, 1.0, -1.0]))) == pytest.approx(1.0)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 3, 3\)"):
        rotation_from_cross_covariance(np.eye(2))
    f = np.eye(3) + 0.3 * rng.normal(size=(100, 3, 3))
    np.testing.assert_allclose(det3(f), np.linalg.det(f), rtol=1e-13, atol=1e-15)


def _random_frame_inputs(models: list[ReducedObject], contacts: list[ContactPoints], seed: int,
                         gen: torch.Generator) -> tuple[list, list, list, list, list, list]:  # fmt: skip
    """One frame's recorder inputs for these objects: random states (seeds ``seed + k``), per cubature point random
    forces (N) and partners, per sphere random forces (N) (all from ``gen``), every other object asleep."""
    states = [_random_state(o, seed + k) for k, o in enumerate(models)]
    qs, qdots = [s_[0] for s_ in states], [s_[1] for s_ in states]
    forces = [torch.randn(o.num_points, 3, generator=gen, dtype=D) for o in models]
    partners = [torch.randint(-1, 3, (o.num_points,), generator=gen) for o in models]
    sphere = [torch.randn(c.num_points, 3, generator=gen, dtype=D) for c in contacts]
    return qs, qdots, forces, partners, sphere, [bool(k % 2) for k in range(len(models))]


def test_one_handle_groups_record_what_the_per_object_frames_record():
    """``FrameRecorder`` takes the frames of one-handle objects batched per (cubature points, spheres) group
    (``OneHandleGroup``): every recorded array of every object equals, bit for bit, what the recorder without
    groups records (``_object_frames``, itself ``_object_frame`` object by object: the next test), with and without
    sphere forces, for two groups
    of one-handle objects (40 and 30 cubature points) beside a 3-handle object that is in no group."""
    objs = [_object(1, 21, None), _object(3, 22, None), _object(1, 23, 15), _object(1, 24, None)]
    small = _object(1, 25, None)[0]
    # a one-handle object with 30 cubature points: its own group
    x0 = small.points_rest[:30]
    w = torch.ones(30, 1, dtype=D)
    obj5 = ReducedObject(x0, small.volumes_m3[:30], 700.0, w, torch.zeros(30, 1, 3, dtype=D), small.mu_pa, small.lam_pa)
    objs.append((obj5, ContactPoints.build(x0[:12].numpy(), np.full(12, 0.02), w[:12], x0)))
    models, contacts = [o for o, _ in objs], [c for _, c in objs]
    n = len(objs)
    names, ids = [f"o{k}" for k in range(n)], list(range(1, n + 1))
    grouped = FrameRecorder(names, ids, models, contacts, GRAVITY)
    single = FrameRecorder(names, ids, models, contacts, GRAVITY)
    single.groups, single._grouped = [], np.zeros(n, dtype=bool)
    assert sorted(len(g.members) for g in grouped.groups) == [1, 3]  # 40-point and 30-point one-handle objects
    assert not grouped._grouped[1]
    gen = torch.Generator().manual_seed(5)
    for frame in range(3):
        qs, qdots, forces, partners, sphere, asleep = _random_frame_inputs(models, contacts, 100 * frame, gen)
        sphere[0][:3] = 0.0  # spheres without contact
        for rec in (grouped, single):
            rec.record(qs, qdots, forces, partners, asleep, {}, sphere_forces=sphere if frame != 1 else None)
    for k in range(n):
        for a, b in zip(grouped.frames[k], single.frames[k]):
            assert a.keys() == b.keys()
            for key in a:
                np.testing.assert_array_equal(a[key], b[key], err_msg=f"object {k} {key}")
    stress = [f["hydrostatic_stress_pa"][0] for f in grouped.frames[0]]
    assert stress[0] != stress[1]  # with sphere forces (mean stress theorem) and without (the uniform F)



def test_batched_frames_of_several_objects_equal_the_per_object_frames():
    """``FrameRecorder`` takes the objects in no one-handle group (``_object_frames``) with their rigid-body sums
    batched per basis width and their stresses in one call over all their points: every recorded array equals, bit
    for bit, what ``_object_frame`` records object by object, for objects of 3, 2, 3 and 1 handles (two widths
    shared), one with separate inertia particles, one of another material (its stress differs), with and without
    sphere forces (the one-handle object then takes the mean stress theorem)."""
    objs = [_object(3, 31, None), _object(2, 32, 12), _object(3, 33, None), _object(2, 34, None)]
    soft = objs[2][0]
    mu, lam = mat.lame_parameters(3e5, 0.45)
    objs[2] = (ReducedObject(soft.points_rest, soft.volumes_m3, 900.0, soft.weights, soft.grads, mu, lam), objs[2][1])
    one = _object(1, 35, None)[0]  # a one-handle object whose basis is not [I; 0] (a grouped one would be)
    grads = 0.3 * torch.randn(one.num_points, 1, 3, generator=torch.Generator().manual_seed(35), dtype=D)
    objs.append((ReducedObject(one.points_rest, one.volumes_m3, 900.0, one.weights, grads, one.mu_pa, one.lam_pa),
                 _object(1, 35, None)[1]))  # fmt: skip
    models, contacts = [o for o, _ in objs], [c for _, c in objs]
    n = len(objs)
    recorder = FrameRecorder([f"o{k}" for k in range(n)], list(range(1, n + 1)), models, contacts, GRAVITY)
    assert not recorder._grouped.any()
    gen = torch.Generator().manual_seed(6)
    for frame in range(2):
        qs, qdots, forces, partners, sphere, asleep = _random_frame_inputs(models, contacts, 200 * frame, gen)
        sphere = sphere if frame == 0 else None
        batched, batched_rigid = _object_frames(models, contacts, recorder.constants, qs, qdots, forces, partners,
                                                asleep, sphere)  # fmt: skip
        for k in range(n):
            single, rigid = _object_frame(models[k], contacts[k], recorder.constants[k], qs[k], qdots[k], forces[k],
                                          partners[k], asleep[k], None if sphere is None else sphere[k])  # fmt: skip
            assert batched[k].keys() == single.keys()
            for key in single:
                np.testing.assert_array_equal(batched[k][key], single[key], err_msg=f"object {k} {key}")
            for a, b in zip(batched_rigid[k], rigid):
                np.testing.assert_array_equal(a, b, err_msg=f"object {k} rigid frame")
        stress = [f["hydrostatic_stress_pa"] for f in batched]
        assert not np.allclose(stress[2], stress[0])  # the other material
        if sphere is not None:  # the one-handle object: one mean stress from its sphere forces
            assert np.unique(stress[4]).size == 1
