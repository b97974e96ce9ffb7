"""Contact: hash-grid pairs vs brute force, penalty and friction derivatives."""

import numpy as np
import torch

from data_gen.sim.contact import PairFinder, friction_terms, pair_contact, static_contact
from data_gen.sim.static_scene import StaticScene

D = torch.float64


def test_pair_finder_matches_brute_force_and_skips_same_object():
    rng = np.random.default_rng(1)
    pts = rng.uniform(0.0, 1.0, (1500, 3))
    ids = rng.integers(1, 5, 1500)
    radii = rng.uniform(0.01, 0.03, 1500)
    pairs = PairFinder().find(pts, ids, radii, margin_m=0.01)
    dist = np.linalg.norm(pts[:, None] - pts[None], axis=-1)
    want = (dist < radii[:, None] + radii[None] + 0.01) & (ids[:, None] != ids[None])
    i, j = np.nonzero(np.triu(want, 1))
    assert len(pairs) == len(i) > 50
    assert np.array_equal(pairs, np.stack([i, j], 1))  # sorted, deterministic


def test_static_penalty_energy_force_and_depth():
    x = torch.tensor([[0.0, 0.0, 0.004], [1.0, 0.0, 0.02]], dtype=D)
    pc, depth, normal = static_contact(
        x, torch.full((2,), 0.01, dtype=D), torch.tensor(1e4, dtype=D), StaticScene()
    )
    np.testing.assert_allclose(depth.numpy(), [0.006, -0.01], atol=1e-15)
    assert abs(pc.energy - 0.5 * 1e4 * 0.006**2) < 1e-15
    np.testing.assert_allclose(-pc.grad_x.numpy(), [[0, 0, 60.0], [0, 0, 0]], atol=1e-12)  # force = k d n
    np.testing.assert_allclose(pc.hess_x[0].numpy(), np.diag([0, 0, 1e4]), atol=1e-12)


def test_pair_penalty_gradient_by_finite_differences():
    gen = torch.Generator().manual_seed(0)
    xi = torch.rand(20, 3, generator=gen, dtype=D) * 0.05
    xj = xi + 0.03 * torch.randn(20, 3, generator=gen, dtype=D)
    rs = torch.full((20,), 0.04, dtype=D)
    k = torch.tensor(3e3, dtype=D)
    pc = pair_contact(xi, xj, rs, k)
    assert (pc.depth_m > 0).sum() > 5
    d = torch.randn(20, 3, generator=gen, dtype=D)
    eps = 1e-7
    fd = (pair_contact(xi + eps * d, xj, rs, k).energy - pair_contact(xi - eps * d, xj, rs, k).energy) / (
        2 * eps
    )
    assert abs(fd - float((pc.grad_i * d).sum())) < 1e-6 * abs(fd)
    # equal and opposite: moving both spheres together changes nothing
    assert abs(pair_contact(xi + 0.1, xj + 0.1, rs, k).energy - pc.energy) < 1e-12


def test_friction_is_coulomb_beyond_the_smoothing_and_tangential():
    normal = torch.tensor([[0.0, 0.0, 1.0]] * 3, dtype=D)
    slip = torch.tensor([[0.01, 0.0, 0.5], [0.0, 1e-5, 0.0], [-0.003, 0.004, 0.0]], dtype=D)
    lam = torch.tensor([10.0, 10.0, 2.0], dtype=D)
    fr = friction_terms(slip, lam, normal, torch.tensor(0.5, dtype=D), smoothing_m=1e-4)
    force = -fr.grad_x
    # sliding: |f| = mu * lam along -slip_tangential; the normal slip component is ignored
    np.testing.assert_allclose(force[0].numpy(), [-5.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(force[2].numpy(), [0.6, -0.8, 0.0], atol=1e-12)
    # sticking (slip below the smoothing length): linear spring mu lam / eps
    np.testing.assert_allclose(force[1].numpy(), [0.0, -0.5 * 10.0 * 1e-5 / 1e-4, 0.0], atol=1e-12)
    energy = 0.5 * 10 * (0.01 - 0.5e-4) + 0.5 * 10 * (1e-5) ** 2 / (2e-4) + 0.5 * 2 * (0.005 - 0.5e-4)
    assert abs(fr.energy - energy) < 1e-12
