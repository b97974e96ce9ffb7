"""The warp kernels against the batched-torch reference terms (:mod:`data_gen.sim.energy`): contact (energy
per object, gradient and Newton matrix assembled into islands with cross blocks, per-sphere and per-pair
forces, on scenes with penetration, frozen friction, a frozen partner, a box and a static point cloud) and
the neo-Hookean points (energy, gradient, Hessian with the near-SPD eigen-clamp and strict projection)."""

import numpy as np
import pytest
import torch

from data_gen.sim.energy.contact_kernels import WarpContact
from data_gen.sim.energy.elastic import deformation_gradients, elastic, elastic_from_points, neo_hookean_hessian
from data_gen.sim.energy.elastic_kernel import WarpNeoHookean
from data_gen.sim.energy.pair_contact import FROZEN, PairSet, pair_contact
from data_gen.sim.energy.scene_contact import contact_start, scene_contact
from data_gen.sim.energy.scene_sdf import SceneDistance
from data_gen.sim.model import DofLayout
from data_gen.sim.static_scene import StaticBox, StaticPoints, StaticScene
from tests.sim.test_sim_batched_terms import _model

D = torch.float64


def random_rates(model, tm: torch.Tensor, seed: int, speed: float = 0.3) -> torch.Tensor:
    """Rates (n, 3, K) of the padded states ``tm``: per object ``speed`` (m/s scale) times a seeded normal draw,
    divided by its column count (zero on padding)."""
    gen = torch.Generator().manual_seed(seed)
    tmdot = torch.zeros_like(tm)
    for o in range(model.num_objects):
        cols = 4 * int(model.num_handles[o])
        tmdot[o, :, :cols] = speed * torch.randn(3, cols, generator=gen, dtype=D) / cols
    return tmdot


def _setup(scene: StaticScene, seed: int, handles: tuple[int, int, int] = (1, 3, 2)):
    """Three objects (1, 3 and 2 handles) near the scene; objects 0 and 2 form one island, 1 the other."""
    objs, model = _model(handles)
    gen = torch.Generator().manual_seed(seed)
    k = model.columns
    tm0 = torch.zeros(3, 3, k, dtype=D)
    tm0[:, 2, 3] = torch.tensor([0.30, 0.32, 0.45], dtype=D)  # lift so that some spheres touch the ground
    tm0[:, 0, 3] = torch.tensor([0.0, 0.6, 0.05], dtype=D)
    for o in range(3):
        cols = 4 * int(model.num_handles[o])
        tm0[o, :, :cols] += 0.02 * torch.randn(3, cols, generator=gen, dtype=D)
    tm = tm0.clone()
    for o in range(3):
        cols = 4 * int(model.num_handles[o])
        tm[o, :, :cols] += 0.01 * torch.randn(3, cols, generator=gen, dtype=D)
    tm[:, 2, 3] -= 0.04  # the state moved down during the step: deeper contact, friction slip
    island = torch.tensor([0, 1, 0])
    layout = DofLayout.build(model.num_handles, island, k)
    distance = SceneDistance(scene)
    stiffness = 5e3 * model.mass_kg
    start = contact_start(distance, model.sphere_positions(tm0), model.sphere_radius_m, model.sphere_valid, stiffness)
    x0 = model.sphere_positions(tm0)
    # pairs: every sphere of object 0 with every sphere of object 2 (same island), three against a frozen partner
    si, sj = torch.meshgrid(torch.arange(15), torch.arange(15), indexing="ij")
    si, sj = si.reshape(-1), sj.reshape(-1)
    n = si.numel()
    frozen = torch.zeros(n + 3, 3, dtype=D)
    frozen[n:] = x0[2, :3] + torch.tensor([0.0, 0.0, 0.02], dtype=D)
    obj_i = torch.cat([torch.zeros(n, dtype=torch.int64), torch.full((3,), 2)])
    sph_i = torch.cat([si, torch.arange(3)])
    obj_j = torch.cat([torch.full((n,), 2), torch.full((3,), FROZEN)])
    sph_j = torch.cat([sj, torch.zeros(3, dtype=torch.int64)])
    xi0 = x0[obj_i, sph_i]
    xj0 = torch.where((obj_j >= 0)[:, None], x0[obj_j.clamp(min=0), sph_j], frozen)
    delta = xi0 - xj0
    radius_sum = torch.full((n + 3,), 0.32, dtype=D)
    depth0 = radius_sum - delta.norm(dim=1)
    k_pair = torch.full((n + 3,), 2e3, dtype=D)
    lam = k_pair * depth0.clamp(min=0.0)
    pairs = PairSet(
        obj_i=obj_i, sph_i=sph_i, obj_j=obj_j, sph_j=sph_j, frozen_x_j=frozen, stiffness_n_m=k_pair,
        radius_sum_m=radius_sum, friction=torch.full((n + 3,), 0.4, dtype=D) * (lam > 0), normal_force_n=lam,
        normal0=delta / delta.norm(dim=1, keepdim=True), x0_i=xi0, x0_j=xj0,
    )  # fmt: skip
    return model, layout, distance, stiffness, start, pairs, tm


@pytest.mark.parametrize(
    "scene",
    [
        StaticScene(),
        StaticScene(boxes=(StaticBox((0.6, 0.0, 0.1), (0.2, 0.3, 0.1), (0.95, 0.05, 0.2, 0.1)),)),
        StaticScene(points=StaticPoints(np.array([[0.0, 0.0, 0.05], [0.05, 0.0, 0.05], [0.6, 0.0, 0.1]]), 0.04, 0.1)),
    ],
    ids=["ground", "box", "points"],
)
def test_kernels_equal_the_torch_terms(scene):
    model, layout, distance, stiffness, start, pairs, tm = _setup(scene, seed=3)
    h2, smoothing = 1e-4, 2e-4
    valid = model.sphere_valid
    sphere_k = stiffness[:, None] * valid
    friction = torch.full((3,), 0.5, dtype=D)
    assert float(start.normal_force_n.gt(0).sum()) >= 5  # frozen scene friction is exercised

    # reference: the batched torch terms, assembled into islands
    x = model.sphere_positions(tm)
    sc = scene_contact(distance, x, model.sphere_b, model.sphere_radius_m, valid, sphere_k,
                       friction[:, None].expand_as(sphere_k).contiguous(), start, smoothing, True)  # fmt: skip
    pc = pair_contact(pairs, x, model.sphere_b, smoothing, True)
    assert int((pc.force_i_n.norm(dim=1) > 0).sum()) >= 20  # pairs touch
    ref_energy = sc.terms.energy + pc.energy
    ref_grad = layout.to_islands(h2 * (sc.terms.grad + pc.grad))
    ref_matrix = layout.assemble(h2 * (sc.terms.hess + pc.hess))
    ref_matrix = layout.assemble(h2 * pc.cross, pc.cross_rows, pc.cross_cols, out=ref_matrix)

    contact = WarpContact(
        scene, 4 * model.num_handles, model.sphere_rest_m, model.sphere_b, model.sphere_radius_m,
        layout.flat_index, layout.island_size, layout.num_islands,
    )  # fmt: skip
    # a first solve with other data and fewer pairs: the workspace must not keep anything of it
    contact.prepare(2.0 * sphere_k, torch.zeros_like(sphere_k), start.positions_m, start.normals, 3.0 * smoothing,
                    1.0, None)  # fmt: skip
    contact.evaluate(tm, True)
    contact.prepare(sphere_k, friction[:, None] * start.normal_force_n, start.positions_m, start.normals, smoothing,
                    h2, pairs)  # fmt: skip
    out = contact.evaluate(tm, True)
    grad, matrix = out.grad.clone(), out.hess.clone()
    assert torch.allclose(out.energy_j, ref_energy, rtol=1e-12, atol=1e-15)
    assert torch.allclose(grad, ref_grad, rtol=1e-10, atol=1e-12 * float(ref_grad.abs().max()))
    assert torch.allclose(matrix, ref_matrix, rtol=1e-10, atol=1e-12 * float(ref_matrix.abs().max()))
    assert float(ref_matrix[0, :12, 12:].abs().max()) > 0  # the cross blocks of objects 0 and 2 are there

    # forces of the final state (no derivatives): equal where a sphere or pair is active
    forces = contact.evaluate(tm)
    assert torch.allclose(forces.energy_j, ref_energy, rtol=1e-12, atol=1e-15)
    assert torch.allclose(forces.scene_force_n, sc.force_n * valid[:, :, None], rtol=1e-10, atol=1e-12)
    assert torch.allclose(forces.pair_force_i_n, pc.force_i_n, rtol=1e-10, atol=1e-12)
    active = sc.force_n.norm(dim=2) > 0
    assert torch.allclose(forces.scene_normals[active], sc.normals[active], atol=1e-12)

    # lifted clear of the scene: no penetration left, only the frozen friction of the start acts
    lifted = tm.clone()
    lifted[:, 2, 3] += 0.3
    x_up = model.sphere_positions(lifted)
    sc_up = scene_contact(distance, x_up, model.sphere_b, model.sphere_radius_m, valid, sphere_k,
                          friction[:, None].expand_as(sphere_k).contiguous(), start, smoothing, True)  # fmt: skip
    sdf_up = distance(x_up.reshape(-1, 3))[0].reshape(valid.shape)
    assert float(sc_up.terms.energy.sum()) > 0 and bool((sdf_up - model.sphere_radius_m)[valid].min() > 0)
    out_up = contact.evaluate(lifted, True)
    assert torch.allclose(out_up.energy_j - pair_contact(pairs, x_up, model.sphere_b, smoothing, False).energy,
                          sc_up.terms.energy, rtol=1e-10, atol=1e-15)  # fmt: skip


def test_neo_hookean_kernel_equals_the_torch_elastic_term_including_projection():
    objs, model = _model(handles=(1, 3, 2))
    gen = torch.Generator().manual_seed(11)
    k = model.columns
    tm = torch.zeros(3, 3, k, dtype=D)
    for o in range(3):
        cols = 4 * int(model.num_handles[o])
        tm[o, :, :cols] = 0.05 * torch.randn(3, cols, generator=gen, dtype=D)
    tm[1, :, :4] += 0.9 * torch.randn(3, 4, generator=gen, dtype=D)  # large deformation: some blocks indefinite
    args = (model.cub_c, model.cub_volume_m3, model.mu_pa, model.lam_pa, model.spd_tolerance_pa)
    points = WarpNeoHookean(4 * model.num_handles, *args)
    for strict in (None, torch.tensor([False, True, False])):
        ref = elastic(*args, tm, True, strict)
        energy, piola, hess, flags = points.evaluate(tm, True, strict)
        got = elastic_from_points(model.cub_c, energy, piola, hess)
        assert torch.allclose(got.energy, ref.energy, rtol=1e-12, atol=0)
        assert torch.allclose(got.grad, ref.grad, rtol=1e-10, atol=1e-10 * float(ref.grad.abs().max()))
        assert torch.allclose(got.hess, ref.hess, rtol=1e-9, atol=1e-10 * float(ref.hess.abs().max()))
    assert bool(flags[1].any()) and not bool(flags[0].any())  # the deformed object needed the eigen-clamp
    # the kernel's analytic projection equals the eigen-clamp block by block, including an inverted F
    # (det F < 0: the SVD's last singular value negative) and a strongly compressed one
    energy, _, hess, flags = points.evaluate(tm, True, torch.tensor([True, True, True]))
    f = deformation_gradients(model.cub_c, tm)
    volume = model.cub_volume_m3
    for o, i in [(0, 0), (1, 0), (1, 5), (2, 3)]:
        h = neo_hookean_hessian(f[o, i][None], float(model.mu_pa[o]), float(model.lam_pa[o]))[0]
        h = 0.5 * (h + h.T)
        values, vectors = torch.linalg.eigh(h)
        clamped = (vectors * values.clamp(min=0.0)) @ vectors.T
        assert torch.allclose(hess[o, i] / volume[o, i], clamped, rtol=0, atol=1e-9 * float(h.abs().max()))
    inverted = tm.clone()
    inverted[0, 2, 2] = -2.5  # F_zz = 1 - 2.5
    energy, _, hess, flags = points.evaluate(inverted, True)
    f = deformation_gradients(model.cub_c, inverted)
    assert float(torch.linalg.det(f[0, 0])) < 0 and bool(flags[0, 0])
    h = neo_hookean_hessian(f[0, 0][None], float(model.mu_pa[0]), float(model.lam_pa[0]))[0]
    values, vectors = torch.linalg.eigh(0.5 * (h + h.T))
    assert float(values.min()) < 0  # indefinite: the projection is exercised
    clamped = (vectors * values.clamp(min=0.0)) @ vectors.T
    assert torch.allclose(hess[0, 0] / volume[0, 0], clamped, rtol=0, atol=1e-9 * float(h.abs().max()))
    energy, _, _, _ = points.evaluate(tm, False)
    assert torch.allclose(energy.sum(1), ref.energy, rtol=1e-12, atol=0)
