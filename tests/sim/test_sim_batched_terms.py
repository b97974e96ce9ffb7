"""The batched solver's pieces against the per-object reference formulas and finite differences:
padding round trips, island assembly, elastic / contact / pair terms, the torch scene SDF and the
Newton minimiser on a quadratic with a known minimum."""

import numpy as np
import torch

from data_gen.sim import material as mat
from data_gen.sim.contact_points import ContactPoints
from data_gen.sim.energy.elastic import elastic
from data_gen.sim.energy.gravity import gravity
from data_gen.sim.energy.pair_contact import FROZEN, PairSet, pair_contact
from data_gen.sim.energy.scene_sdf import BoxSceneSdf
from data_gen.sim.model import DofLayout, Model, padded_index
from data_gen.sim.newton import Evaluation, NewtonSettings, Objective, minimise
from data_gen.sim.reduced import ReducedObject, scatter_point_hessian
from data_gen.sim.static_scene import StaticBox, StaticScene

D = torch.float64


def _object(num_handles: int, seed: int, num_points: int = 30, young: float = 1e5) -> tuple[ReducedObject, ContactPoints]:
    gen = torch.Generator().manual_seed(seed)
    x0 = torch.rand(num_points, 3, generator=gen, dtype=D) - 0.5
    w = torch.rand(num_points, num_handles, generator=gen, dtype=D)
    w[:, 0] = 1.0
    g = 0.3 * torch.randn(num_points, num_handles, 3, generator=gen, dtype=D)
    g[:, 0] = 0.0
    mu, lam = mat.lame_parameters(young, 0.3)
    vol = torch.full((num_points,), 1e-3 / num_points, dtype=D)
    obj = ReducedObject(x0, vol, 1000.0, w, g, mu, lam)
    centres = x0[: num_points // 2].numpy()
    contact = ContactPoints.build(centres, np.full(len(centres), 0.02), w[: num_points // 2], x0)
    return obj, contact


def _model(handles=(1, 3, 2)):
    objs = [_object(h, seed=k) for k, h in enumerate(handles)]
    return objs, Model.build([o for o, _ in objs], [c for _, c in objs], [0.5] * len(objs))


def _padded(model: Model, qs: list[torch.Tensor]) -> torch.Tensor:
    k = model.columns
    tm = torch.zeros(len(qs), 3 * k, dtype=D)
    for o, q in enumerate(qs):
        tm[o, padded_index(q.shape[0] // 12, k)] = q
    return tm.reshape(len(qs), 3, k)


def test_padded_states_move_spheres_like_each_object_and_layout_round_trips():
    objs, model = _model()
    gen = torch.Generator().manual_seed(5)
    qs = [0.05 * torch.randn(o.num_dofs, generator=gen, dtype=D) for o, _ in objs]
    tm = _padded(model, qs)
    x = model.sphere_positions(tm)
    for o, ((_, contact), q) in enumerate(zip(objs, qs)):
        n = contact.num_points
        assert torch.allclose(x[o, :n], contact.positions(q), atol=1e-15, rtol=0)
        assert not model.sphere_valid[o, n:].any()
    layout = DofLayout.build(model.num_handles, torch.tensor([0, 1, 0]), model.columns)
    flat = layout.to_islands(tm)
    assert flat.shape == (2, 12 * (1 + 2))  # island 0 holds the 1- and 2-handle objects, island 1 the 3-handle one
    assert torch.equal(layout.to_objects(flat), tm)
    assert torch.equal(flat[0, :12], qs[0]) and torch.equal(flat[0, 12:36], qs[2]) and torch.equal(flat[1], qs[1])


def test_batched_elastic_and_gravity_equal_the_per_object_reference():
    objs, model = _model()
    gen = torch.Generator().manual_seed(7)
    qs = [0.05 * torch.randn(o.num_dofs, generator=gen, dtype=D) for o, _ in objs]
    tm = _padded(model, qs)
    terms = elastic(model.cub_c, model.cub_volume_m3, model.mu_pa, model.lam_pa, model.spd_tolerance_pa, tm, True)
    g = torch.tensor([0.0, 0.0, -9.81], dtype=D)
    grav = gravity(model.mass_b_sum, g, tm, True)
    for o, ((obj, _), q) in enumerate(zip(objs, qs)):
        index = padded_index(obj.num_handles, model.columns)
        assert abs(float(terms.energy[o]) - obj.elastic_energy(q)) <= 1e-12 * max(1.0, abs(obj.elastic_energy(q)))
        assert torch.allclose(terms.grad[o].reshape(-1)[index], obj.elastic_gradient(q), rtol=1e-10, atol=1e-10)
        ref = obj.elastic_hessian(q)
        assert torch.allclose(terms.hess[o][index[:, None], index[None, :]], ref, rtol=1e-9, atol=1e-9 * float(ref.abs().max()))
        assert abs(float(grav.energy[o]) - obj.gravity_energy(q, g)) < 1e-12
        assert torch.allclose(grav.grad[o].reshape(-1)[index], obj.gravity_gradient(g), atol=1e-12)


def test_one_handle_object_keeps_one_cubature_point_with_the_exact_energy():
    obj, contact = _object(1, seed=3, young=1e9)
    model = Model.build([obj], [contact], [0.5])
    assert model.cub_c.shape[1] == 1 and float(model.cub_volume_m3[0, 0]) == float(obj.volumes_m3.sum())
    q = 1e-3 * torch.arange(12, dtype=D)
    tm = _padded(model, [q])
    terms = elastic(model.cub_c, model.cub_volume_m3, model.mu_pa, model.lam_pa, model.spd_tolerance_pa, tm, False)
    assert abs(float(terms.energy[0]) - obj.elastic_energy(q)) <= 1e-12 * obj.elastic_energy(q)


def test_pair_contact_gradient_matches_finite_differences_and_blocks_the_reference_assembly():
    objs, model = _model(handles=(1, 2))
    tm = torch.zeros(2, 3, model.columns, dtype=D)
    tm[1, :, 3] = torch.tensor([0.05, 0.0, 0.0], dtype=D)  # object 1 shifted 5 cm along x (handle-0 translation)
    x = model.sphere_positions(tm)
    # every sphere of object 0 against every sphere of object 1, plus three against a frozen partner
    si, sj = torch.meshgrid(torch.arange(15), torch.arange(15), indexing="ij")
    si, sj = si.reshape(-1), sj.reshape(-1)
    n = si.numel()
    frozen = torch.zeros(n + 3, 3, dtype=D)
    frozen[n:] = x[0, :3] + torch.tensor([0.0, 0.0, 0.03], dtype=D)
    zeros = torch.zeros(n + 3, 3, dtype=D)
    pairs = PairSet(
        obj_i=torch.zeros(n + 3, dtype=torch.int64), sph_i=torch.cat([si, torch.arange(3)]),
        obj_j=torch.cat([torch.ones(n, dtype=torch.int64), torch.full((3,), FROZEN)]),
        sph_j=torch.cat([sj, torch.zeros(3, dtype=torch.int64)]), frozen_x_j=frozen,
        stiffness_n_m=torch.full((n + 3,), 1e4, dtype=D), radius_sum_m=torch.full((n + 3,), 0.3, dtype=D),
        friction=torch.zeros(n + 3, dtype=D), normal_force_n=torch.zeros(n + 3, dtype=D),
        normal0=zeros, x0_i=zeros, x0_j=zeros,
    )  # fmt: skip
    terms = pair_contact(pairs, x, model.sphere_b, 1e-4, True)
    layout = DofLayout.build(model.num_handles, torch.zeros(2, dtype=torch.int64), model.columns)
    matrix = layout.assemble(terms.hess)
    matrix = layout.assemble(terms.cross, terms.cross_rows, terms.cross_cols, out=matrix)[0]
    grad = layout.to_islands(terms.grad)[0]
    q = layout.to_islands(tm)[0]

    # reference: the per-object-pair Gauss-Newton assembly of the previous solver (k n n^T per active pair)
    (_, c0), (_, c1) = objs
    xi, xj = c0.positions(q[:12]), torch.cat([c1.positions(q[12:])[sj], frozen[n:]])
    xi = xi[torch.cat([si, torch.arange(3)])]
    delta = xi - xj
    dist = delta.norm(dim=1)
    nrm = delta / dist[:, None]
    active = (0.3 - dist > 0).to(D)
    assert 20 < int(active[:n].sum()) < n and int(active[n:].sum()) == 3  # some object pairs touch, some do not
    h = (1e4 * active)[:, None, None] * nrm[:, :, None] * nrm[:, None, :]
    bi = c0.b[torch.cat([si, torch.arange(3)])]
    bj = c1.b[sj]
    ref = torch.zeros(36, 36, dtype=D)
    ref[:12, :12] = scatter_point_hessian(bi, h)
    ref[12:, 12:] = scatter_point_hessian(bj, h[:n])
    cross = -scatter_point_hessian(bi[:n], h[:n], bj)
    ref[:12, 12:], ref[12:, :12] = cross, cross.T
    assert torch.allclose(matrix, ref, rtol=1e-12, atol=1e-9)

    def energy(qv):
        t = layout.to_objects(qv[None])
        return float(pair_contact(pairs, model.sphere_positions(t), model.sphere_b, 1e-4, False).energy.sum())

    eps = 1e-7
    for d in range(q.shape[0]):
        e = torch.zeros_like(q)
        e[d] = eps
        fd = (energy(q + e) - energy(q - e)) / (2 * eps)
        assert abs(fd - float(grad[d])) <= 1e-5 * float(grad.abs().max())


def test_box_scene_sdf_equals_the_warp_kernel():
    scene = StaticScene(boxes=(StaticBox((0.0, 0.6, 0.15), (0.5, 0.1, 0.15)), StaticBox((0.3, -0.2, 0.1), (0.1, 0.2, 0.1), (0.9, 0.1, 0.3, 0.2))))
    rng = np.random.default_rng(0)
    p = rng.uniform(-1, 1, (5000, 3))
    p[:, 2] = rng.uniform(-0.1, 0.5, 5000)
    d_ref, n_ref = scene.query(p)
    d, n = BoxSceneSdf.of(scene).query(torch.from_numpy(p))
    assert np.abs(d.numpy() - d_ref).max() < 1e-14
    assert np.abs(n.numpy() - n_ref).max() < 1e-12


class _Quadratic(Objective):
    """Two islands, f_i(q) = 1/2 (q - c_i)^T A_i (q - c_i) with known minima."""

    def __init__(self):
        self.a = torch.stack([torch.diag(torch.tensor([1.0, 10.0], dtype=D)), torch.tensor([[4.0, 1.0], [1.0, 3.0]], dtype=D)])
        self.c = torch.tensor([[1.0, -2.0], [0.5, 0.25]], dtype=D)

    def evaluate(self, q, derivatives, strict_islands=None):
        r = q - self.c
        ar = (self.a @ r[:, :, None])[:, :, 0]
        value = 0.5 * (r * ar).sum(1)
        return Evaluation(value, ar, self.a.clone()) if derivatives else Evaluation(value)

    def mass_norm(self, dq):
        return dq.norm(dim=1)

    def point_motion(self, dq):
        return dq.abs().amax(dim=1)


def test_newton_reaches_each_islands_minimum_and_respects_the_trust_radius():
    obj = _Quadratic()
    q0 = torch.zeros(2, 2, dtype=D)
    res = minimise(obj, q0, torch.ones(2, dtype=D), torch.tensor([10.0, 10.0], dtype=D), NewtonSettings(10, 1e-12, 8))
    assert torch.allclose(res.q, obj.c, atol=1e-12) and bool(res.converged.all())
    assert res.iterations.tolist() == [2, 2]  # one exact step, one step that confirms convergence
    # a trust radius of 0.5: the first update of island 0 (|dq|_inf = 2) is cut to a quarter
    res = minimise(obj, q0, torch.ones(2, dtype=D), torch.tensor([0.5, 10.0], dtype=D), NewtonSettings(1, 1e-12, 8))
    assert torch.allclose(res.q[0], 0.25 * obj.c[0], atol=1e-14)
    assert torch.allclose(res.q[1], obj.c[1], atol=1e-14)
    assert res.counters["trust_limited_steps"] == 1


def _reference_to_islands(layout: DofLayout, padded: torch.Tensor) -> torch.Tensor:
    """The layout conversions by boolean masks (the definition the precomputed indices must reproduce)."""
    out = torch.zeros(layout.num_islands * layout.island_size, dtype=padded.dtype)
    mask = layout.flat_index >= 0
    out[layout.flat_index[mask]] = padded.reshape(mask.shape)[mask]
    return out.reshape(layout.num_islands, layout.island_size)


def _reference_to_objects(layout: DofLayout, flat: torch.Tensor) -> torch.Tensor:
    mask = layout.flat_index >= 0
    out = flat.reshape(-1)[layout.flat_index.clamp(min=0)]
    out = torch.where(mask, out, torch.zeros((), dtype=flat.dtype))
    return out.reshape(layout.flat_index.shape[0], 3, -1)


def _reference_assemble(layout: DofLayout, blocks: torch.Tensor) -> torch.Tensor:
    n_isl, size = layout.num_islands, layout.island_size
    out = torch.zeros(n_isl, size, size, dtype=blocks.dtype)
    for o in range(layout.flat_index.shape[0]):
        f = layout.flat_index[o]
        mask = f >= 0
        local = f[mask] - int(layout.island[o]) * size
        out[int(layout.island[o]), local[:, None], local[None, :]] += blocks[o][mask][:, mask]
    return out


def test_layout_fast_paths_equal_the_masked_conversions_on_mixed_and_uniform_layouts():
    gen = torch.Generator().manual_seed(11)
    cases = [
        ((1, 3, 2), (0, 1, 0)),  # padded columns and an unused tail in island 1
        ((2, 2, 2), (0, 1, 2)),  # one island per object, nothing padded: the matrices are the blocks
        ((2, 2, 2, 2), (0, 0, 1, 2)),  # no padded column, islands of different sizes
        ((1, 3, 2), (0, 1, 2)),  # one island per object with padded columns
        ((1, 1, 1), (0, 0, 0)),  # a single island
    ]
    for handles, islands in cases:
        _, model = _model(handles)
        layout = DofLayout.build(model.num_handles, torch.tensor(islands), model.columns)
        assert layout.one_island_per_object == (islands == tuple(range(len(handles))))
        k = model.columns
        tm = torch.randn(len(handles), 3 * k, generator=gen, dtype=D) * layout.valid
        tm = tm.reshape(len(handles), 3, k)
        flat = layout.to_islands(tm)
        assert torch.equal(flat, _reference_to_islands(layout, tm))
        noise = torch.randn(flat.shape, generator=gen, dtype=D)
        assert torch.equal(layout.to_objects(noise), _reference_to_objects(layout, noise))
        assert torch.equal(layout.to_objects(flat), tm)
        blocks = torch.randn(len(handles), 3 * k, 3 * k, generator=gen, dtype=D)
        expected = _reference_assemble(layout, blocks)
        assert torch.allclose(layout.assemble(blocks), expected, rtol=0, atol=1e-15)
        assert torch.allclose(layout.assemble(blocks, out=expected.clone()), 2 * expected, rtol=0, atol=1e-14)


class _Quartic(_Quadratic):
    """Island 0 the quadratic of :class:`_Quadratic`; island 1 adds ``(q - c)_0^4``, which takes Newton
    several more iterations: the islands stop at different iterations."""

    def evaluate(self, q, derivatives, strict_islands=None):
        ev = super().evaluate(q, derivatives, strict_islands)
        r = (q - self.c)[1, 0]
        ev.value[1] += r**4
        if derivatives:
            ev.grad[1, 0] += 4 * r**3
            ev.hess[1, 0, 0] += 12 * r**2
        return ev


def test_newton_islands_converge_at_their_own_iteration_and_stop_moving():
    obj = _Quartic()
    q0 = torch.zeros(2, 2, dtype=D)
    trust = torch.tensor([10.0, 10.0], dtype=D)
    res = minimise(obj, q0, torch.ones(2, dtype=D), trust, NewtonSettings(50, 1e-10, 8))
    assert bool(res.converged.all()) and res.counters["unconverged_solves"] == 0
    assert res.iterations[0] == 2 and res.iterations[1] > 3  # island 0 stopped while island 1 went on
    assert torch.allclose(res.q[0], obj.c[0], atol=1e-12)
    assert torch.allclose(res.q[1], obj.c[1], atol=1e-6)
    grad = obj.evaluate(res.q, True).grad
    assert float(grad[1].abs().max()) < 1e-8
    assert res.counters["trust_limited_steps"] == 0 and res.counters["line_search_failures"] == 0
