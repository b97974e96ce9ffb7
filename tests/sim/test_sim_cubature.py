"""Cubature sampling: exact total volume, unbiased integrals, contact bias, determinism."""

from __future__ import annotations

import math

import pytest
import torch

from data_gen.sim.cubature import contact_mask, morton_codes, sample_cubature

SIZE = torch.tensor([0.4, 0.2, 0.1], dtype=torch.float64)  # box, m
VOLUME = 0.4 * 0.2 * 0.1  # m^3


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """Run these small tensor ops on one thread: on the shared, oversubscribed CI CPU two
    intra-op threads made them ~10x slower (measured 0.64 s vs 0.05 s per cubature call)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _grid_box(per_axis: tuple[int, int, int] = (40, 20, 10)) -> torch.Tensor:
    """Cell-centred regular grid filling [0, 0.4] x [0, 0.2] x [0, 0.1] m (its mean is the exact centroid)."""
    axes = [(torch.arange(k, dtype=torch.float64) + 0.5) / k * float(s) for k, s in zip(per_axis, SIZE)]
    return torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1).reshape(-1, 3)


def _random_box(n: int, seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 3, generator=g, dtype=torch.float64) * SIZE


def _integral(c, values: torch.Tensor) -> float:
    return float((c.volumes_m3 * values).sum())


@pytest.mark.parametrize("region", [None, 0.0])
def test_volumes_sum_to_object_volume(region) -> None:
    x = _random_box(5000, 0)
    c = sample_cubature(x, 300, seed=1, volume_m3=VOLUME, contact_region=region)
    assert c.num_points == 300
    assert float(c.volumes_m3.sum()) == pytest.approx(VOLUME, rel=1e-12)
    assert bool((c.volumes_m3 > 0).all())
    assert torch.equal(c.positions, x[c.indices])
    assert len(set(c.indices.tolist())) == 300  # no particle used twice


def test_linear_integral_exact_on_grid_even_when_biased() -> None:
    """Analytic: int_box (1 + 2x - 3y + 5z) dV = V (1 + 2*0.2 - 3*0.1 + 5*0.05) = 1.35 V.

    Stated tolerance: 1 % (measured: <= 0.3 %); first moments int x dV = 0.2 V within 1 %
    (measured <= 0.4 %) and int z dV = 0.05 V within 2 % (measured <= 1.4 %, z is the
    biased direction).
    """
    x = _grid_box()
    f = 1.0 + 2.0 * x[:, 0] - 3.0 * x[:, 1] + 5.0 * x[:, 2]
    analytic = 1.35 * VOLUME
    for seed in range(3):
        for region, bias in ((None, 1.0), (0.0, 4.0), (0.0, 16.0)):
            c = sample_cubature(x, 200, seed=seed, volume_m3=VOLUME, contact_region=region, contact_bias=bias)
            assert _integral(c, f[c.indices]) == pytest.approx(analytic, rel=0.01)
            # the first moments (centroid) too: int x dV = V * 0.2
            assert _integral(c, c.positions[:, 0]) == pytest.approx(0.2 * VOLUME, rel=0.01)
            assert _integral(c, c.positions[:, 2]) == pytest.approx(0.05 * VOLUME, rel=0.02)


def test_biased_estimator_is_unbiased_on_average() -> None:
    """Biased (bias 8 at the bottom) estimates of int z dV match the particle-cloud value.

    Measured over 40 seeds: mean error -0.15 %, worst 1.7 %. A naive (unweighted, V/m each)
    average over the same points is ~44 % low because the bottom is over-sampled.
    Asserted: mean within 0.5 %, each within 3 %, naive more than 30 % low.
    """
    x = _random_box(4000, 3)
    cloud = float(x[:, 2].mean()) * VOLUME
    estimates, naive = [], []
    for seed in range(40):
        c = sample_cubature(x, 100, seed=seed, volume_m3=VOLUME, contact_region=0.0, contact_bias=8.0)
        estimates.append(_integral(c, c.positions[:, 2]))
        naive.append(float(c.positions[:, 2].mean()) * VOLUME)
    assert sum(estimates) / 40 == pytest.approx(cloud, rel=0.005)
    assert all(e == pytest.approx(cloud, rel=0.03) for e in estimates)
    assert sum(naive) / 40 < 0.7 * cloud


def test_contact_region_is_denser_by_the_bias() -> None:
    x = _random_box(20000, 4)
    bias = 4.0
    c = sample_cubature(x, 500, seed=0, volume_m3=VOLUME, contact_region=0.0, contact_bias=bias)
    region = contact_mask(x, 0.0, 0.1 * 0.4)  # default distance: 10 % of the longest side
    n_r, n_rest = int(region.sum()), int((~region).sum())
    assert n_r > 0 and n_rest > 0
    assert torch.equal(region[c.indices], c.in_contact_region)
    m_r = int(c.in_contact_region.sum())
    density_ratio = (m_r / n_r) / ((500 - m_r) / n_rest)
    assert density_ratio == pytest.approx(bias, rel=0.02)  # rounding of m_r only
    # region volumes still sum to the region's share of V
    assert float(c.volumes_m3[c.in_contact_region].sum()) == pytest.approx(VOLUME * n_r / 20000, rel=1e-12)
    # contact radius = half the spacing in the denser region
    expected = 0.5 * (VOLUME * n_r / 20000 / m_r) ** (1.0 / 3.0)
    assert c.radius_m == pytest.approx(expected, rel=1e-12)


def test_callable_region_mask_or_distance() -> None:
    x = _random_box(3000, 5)
    corner = torch.tensor([0.4, 0.2, 0.1], dtype=torch.float64)
    by_distance = sample_cubature(
        x, 150, seed=2, volume_m3=VOLUME, contact_region=lambda p: (p - corner).norm(dim=1), contact_distance_m=0.1
    )
    by_mask = sample_cubature(
        x, 150, seed=2, volume_m3=VOLUME, contact_region=lambda p: (p - corner).norm(dim=1) <= 0.1
    )
    assert torch.equal(by_distance.indices, by_mask.indices)
    near = (by_distance.positions - corner).norm(dim=1) <= 0.1
    assert torch.equal(near, by_distance.in_contact_region)


def test_uniform_spacing_radius_and_determinism() -> None:
    x = _random_box(4000, 6)
    a = sample_cubature(x, 250, seed=9, volume_m3=VOLUME)
    b = sample_cubature(x, 250, seed=9, volume_m3=VOLUME)
    c = sample_cubature(x, 250, seed=10, volume_m3=VOLUME)
    assert torch.equal(a.indices, b.indices) and torch.equal(a.volumes_m3, b.volumes_m3)
    assert not torch.equal(a.indices, c.indices)
    assert a.radius_m == pytest.approx(0.5 * (VOLUME / 250) ** (1.0 / 3.0), rel=1e-12)
    assert not bool(a.in_contact_region.any())
    # each point carries a whole number of particles (V / n each), 16 on average
    particles = a.volumes_m3 / (VOLUME / 4000)
    assert torch.allclose(particles, particles.round(), atol=1e-9)
    assert float(particles.mean()) == pytest.approx(16.0, rel=1e-12)
    assert 4 <= float(particles.min()) and float(particles.max()) <= 40  # compact, balanced cells
    # spread: every octant of the box holds 1/8 of the points within a few percent
    octant = ((a.positions / SIZE) > 0.5).to(torch.int64) @ torch.tensor([1, 2, 4])
    counts = torch.bincount(octant, minlength=8)
    assert int(counts.min()) >= 25 and int(counts.max()) <= 38  # 31.25 expected


@pytest.mark.parametrize("num_points, region", [(1, 0.0), (1, None), (2, 0.0), (2, -5.0), (10, 10.0), (60, 0.0)])
def test_edge_allocations_keep_total_volume(num_points: int, region) -> None:
    x = _random_box(60, 8)
    c = sample_cubature(x, num_points, seed=0, volume_m3=VOLUME, contact_region=region, contact_bias=50.0)
    assert c.num_points == num_points
    assert float(c.volumes_m3.sum()) == pytest.approx(VOLUME, rel=1e-12)
    assert len(set(c.indices.tolist())) == num_points
    default_distance = 0.1 * float((x.max(0).values - x.min(0).values).max())  # 10 % of the longest side
    assert torch.equal(c.in_contact_region, contact_mask(x, region, default_distance)[c.indices])


def test_morton_codes_hand_values() -> None:
    lo = torch.zeros(3, dtype=torch.float64)
    cells = (1 << 20) - 1
    p = torch.tensor([[0.0, 0.0, 0.0], [1.0 / cells, 0.0, 0.0], [0.0, 1.0 / cells, 0.0], [0.0, 0.0, 1.0 / cells],
                      [1.0 / cells, 1.0 / cells, 1.0 / cells]], dtype=torch.float64)
    assert morton_codes(p, lo, 1.0).tolist() == [0, 1, 2, 4, 7]


def test_bad_inputs_raise() -> None:
    x = _random_box(100, 7)
    with pytest.raises(ValueError, match="num_points"):
        sample_cubature(x, 0, seed=0, volume_m3=VOLUME)
    with pytest.raises(ValueError, match="num_points"):
        sample_cubature(x, 101, seed=0, volume_m3=VOLUME)
    with pytest.raises(ValueError, match="volume_m3"):
        sample_cubature(x, 10, seed=0, volume_m3=0.0)
    with pytest.raises(ValueError, match="contact_bias"):
        sample_cubature(x, 10, seed=0, volume_m3=VOLUME, contact_region=0.0, contact_bias=0.5)
    with pytest.raises(ValueError, match="points_rest"):
        sample_cubature(x[:, :2], 10, seed=0, volume_m3=VOLUME)
    with pytest.raises(ValueError, match="contact_region"):
        sample_cubature(x, 10, seed=0, volume_m3=VOLUME, contact_region=math.nan)
