"""Reduced kinematics: explicit formula, rigid motions, uniform stretch, derivatives, mass matrix."""

import numpy as np
import torch

from data_gen.sim import material as mat
from data_gen.sim.reduced import ReducedObject, deform, q_to_z, z_to_q
from newtphys.rotations import quat_to_matrix

D = torch.float64


def random_object(num_points=40, num_handles=3, seed=0, young=1e5, nu=0.3):
    gen = torch.Generator().manual_seed(seed)
    x0 = torch.rand(num_points, 3, generator=gen, dtype=D) - 0.5
    w = torch.rand(num_points, num_handles, generator=gen, dtype=D)
    w[:, 0] = 1.0
    g = torch.randn(num_points, num_handles, 3, generator=gen, dtype=D)
    g[:, 0] = 0.0
    mu, lam = mat.lame_parameters(young, nu)
    vol = torch.full((num_points,), 1.0 / num_points, dtype=D)
    return ReducedObject(x0, vol, 1000.0, w, g, mu, lam), gen


def test_deform_matches_the_kinematics_formula():
    obj, gen = random_object()
    z = 0.1 * torch.randn(36, generator=gen, dtype=D)
    x, F = deform(obj.points_rest, obj.weights, obj.grads, z)
    T = z.reshape(3, 3, 4)
    xb = torch.cat([obj.points_rest, torch.ones(40, 1, dtype=D)], 1)
    x_ref = obj.points_rest + torch.einsum("ih,hrc,ic->ir", obj.weights, T, xb)
    F_ref = (
        torch.eye(3, dtype=D)
        + torch.einsum("ih,hrj->irj", obj.weights, T[:, :, :3])
        + torch.einsum("hrc,ic,ihj->irj", T, xb, obj.grads)
    )
    assert torch.allclose(x, x_ref, atol=1e-15, rtol=0)
    assert torch.allclose(F, F_ref, atol=1e-15, rtol=0)
    q = z_to_q(z)
    assert torch.equal(q_to_z(q), z)
    assert torch.allclose(obj.positions(q), x_ref, atol=1e-15, rtol=0)


def test_rigid_translation_and_rotation_have_zero_energy():
    obj, _ = random_object()
    rot = quat_to_matrix(np.array([0.8, 0.1, -0.5, 0.3]))
    z = torch.zeros(36, dtype=D)
    z[:12] = torch.from_numpy(np.concatenate([rot - np.eye(3), [[1.5], [-2.0], [0.7]]], 1).reshape(-1))
    q = z_to_q(z)
    assert abs(obj.elastic_energy(q)) < 1e-9 * obj.mu_pa
    assert obj.elastic_gradient(q).abs().max() < 1e-8 * obj.mu_pa
    x = obj.positions(q)
    assert torch.allclose(
        x, obj.points_rest @ torch.from_numpy(rot).T + torch.tensor([1.5, -2.0, 0.7], dtype=D), atol=1e-14
    )


def test_uniform_stretch_gives_analytic_energy_and_stress():
    young, nu = 1e6, 0.3
    obj, _ = random_object(young=young, nu=nu)
    stretch = 1e-4
    z = torch.zeros(36, dtype=D)
    z[0] = stretch  # T_0[0, 0]: x-stretch by (1 + stretch), same for every point
    q = z_to_q(z)
    F = obj.deformation_gradients(q)
    assert torch.allclose(F, torch.diag(torch.tensor([1 + stretch, 1.0, 1.0], dtype=D)).expand(40, 3, 3))
    mu, lam = obj.mu_pa, obj.lam_pa
    # small strain: energy = V (mu + lam/2) eps^2, stress sigma_xx = (2 mu + lam) eps, sigma_yy = lam eps
    assert abs(obj.elastic_energy(q) - (mu + lam / 2) * stretch**2) < 2e-3 * (mu + lam / 2) * stretch**2
    sigma = mat.cauchy_stress(F, mu, lam)[0]
    assert abs(sigma[0, 0] - (2 * mu + lam) * stretch) < 2e-3 * (2 * mu + lam) * stretch
    assert abs(sigma[1, 1] - lam * stretch) < 2e-3 * (2 * mu + lam) * stretch
    hyd = obj.cauchy_hydrostatic(q)
    assert torch.allclose(hyd, torch.full_like(hyd, (2 * mu + 3 * lam) * stretch / 3), rtol=2e-3)


def test_gradient_and_hessian_match_finite_differences():
    obj, gen = random_object(num_handles=2)
    q = 0.05 * torch.randn(24, generator=gen, dtype=D)
    grad = obj.elastic_gradient(q)
    direction = torch.randn(24, generator=gen, dtype=D)
    eps = 1e-6
    fd = (obj.elastic_energy(q + eps * direction) - obj.elastic_energy(q - eps * direction)) / (2 * eps)
    assert abs(fd - float(grad @ direction)) < 1e-6 * abs(fd) + 1e-9
    # the exact (unprojected) Hessian is the derivative of the gradient
    q_small = 1e-3 * torch.randn(24, generator=gen, dtype=D)
    hess = obj.elastic_hessian(q_small, project_spd=False)
    fd_h = (
        obj.elastic_gradient(q_small + eps * direction) - obj.elastic_gradient(q_small - eps * direction)
    ) / (2 * eps)
    assert torch.allclose(hess @ direction, fd_h, rtol=1e-5, atol=1e-6 * float(fd_h.abs().max()))
    # the projected one (what Newton uses) is positive semi-definite and close to it
    projected = obj.elastic_hessian(q_small, strict=True)
    assert torch.linalg.eigvalsh(projected).min() > -1e-8 * float(hess.abs().max())
    assert float((projected - hess).abs().max()) < 0.01 * float(hess.abs().max())
    # the default (blocks within -5 % mu kept unprojected) is at most slightly indefinite
    assert torch.linalg.eigvalsh(obj.elastic_hessian(q_small)).min() > -1e-3 * float(hess.abs().max())


def test_mass_matrix_and_gravity_are_consistent():
    obj, gen = random_object()
    v = torch.tensor([0.3, -1.2, 2.0], dtype=D)
    qdot = torch.zeros(36, dtype=D)
    qdot[torch.tensor([3, 4 * 3 + 3, 8 * 3 + 3])] = v  # translation column of handle 0 in q-ordering
    assert torch.allclose(obj.point_velocities(qdot), v.expand(40, 3))
    assert abs(obj.kinetic_energy(qdot) - 0.5 * obj.mass_kg * float(v @ v)) < 1e-12
    g = torch.tensor([0.0, 0.0, -9.81], dtype=D)
    # gravity force = M * (g as a translation rate): exact free fall in one Newton step
    g_q = torch.zeros(36, dtype=D)
    g_q[torch.tensor([3, 15, 27])] = g
    assert torch.allclose(-obj.gravity_gradient(g), obj.mass_matrix @ g_q, atol=1e-12)
    assert abs(obj.mass_kg - 1000.0) < 1e-9


def test_fast_hessian_equals_material_hessian_and_projection_is_psd():
    from data_gen.sim.reduced import neo_hookean_hessian, project_blocks_spd

    gen = torch.Generator().manual_seed(3)
    F = torch.eye(3, dtype=D) + 0.3 * torch.randn(50, 3, 3, generator=gen, dtype=D)
    mu, lam = mat.lame_parameters(1e5, 0.4)
    ours = neo_hookean_hessian(F, mu, lam)
    ref = mat.hessian(F, mu, lam, project_spd=False)
    assert torch.allclose(ours, ref, rtol=1e-12, atol=1e-9 * mu)
    strict = project_blocks_spd(ours, 0.05 * mu, strict=True)
    assert torch.allclose(strict, mat.hessian(F, mu, lam, project_spd=True), rtol=1e-9, atol=1e-7 * mu)
    loose = project_blocks_spd(ours, 0.05 * mu)
    assert torch.linalg.eigvalsh(loose).min() > -0.05 * mu
    assert torch.linalg.eigvalsh(strict).min() > -1e-9 * mu


def test_point_deformer_matches_deform():
    from data_gen.sim.reduced import PointDeformer

    obj, gen = random_object()
    z = 0.1 * torch.randn(36, generator=gen, dtype=D)
    x, F = deform(obj.points_rest, obj.weights, obj.grads, z)
    deformer = PointDeformer(obj.points_rest, obj.weights, obj.grads)
    assert torch.equal(deformer.positions(z), x)
    assert torch.equal(deformer.deformation_gradients(z), F)
