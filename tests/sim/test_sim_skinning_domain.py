"""One skinning basis per shape: scaling a basis, training on a shape's canonical points, the cache shared by
draws of different sizes and materials, and the Simulator's check that a domain fits its object."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.skinning import (
    DOMAIN_POISSON_RATIO,
    SkinningDomain,
    SkinningTrainingSettings,
    blend_basis,
    rigid_basis,
    train_domain_basis,
    train_skinning_basis,
)
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

TINY = SkinningTrainingSettings(steps=4, points_per_step=64, hidden_layers=1, width=8, checkpoint_every=2)


@pytest.fixture(autouse=True)
def _one_torch_thread():
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _block_points(n: int = 300, seed: int = 0) -> np.ndarray:
    """Uniform points in a 0.2 x 0.1 x 0.05 m block whose frame origin is off-centre (at one corner region)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(0.0, 1.0, (n, 3)) * np.array([0.2, 0.1, 0.05]) + np.array([0.02, -0.03, 0.01])


@pytest.mark.parametrize("kind", ["learned", "blend"])
def test_scaled_basis_is_the_same_field_on_the_scaled_shape(tmp_path: Path, kind: str) -> None:
    x = torch.from_numpy(_block_points())
    if kind == "learned":
        basis = train_skinning_basis(x, 4, 0.3, TINY, seed=3, cache_dir=tmp_path)
        assert basis.metadata["source"] == "learned"
    else:
        basis = blend_basis(x, 4, seed=3)
    s = 2.5
    big = basis.scaled(s)
    w, g = basis.evaluate(x)
    w_big, g_big = big.evaluate(s * x)
    # w'(s x) = w(x), grad w'(s x) = grad w(x) / s, to round-off
    torch.testing.assert_close(w_big, w, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(g_big, g / s, rtol=1e-10, atol=1e-10)
    assert big.metadata == basis.metadata
    assert basis.evaluate(x)[0].equal(w)  # the original is untouched


def test_scaled_rigid_basis_and_bad_scales() -> None:
    r = rigid_basis().scaled(3.0)
    assert r.is_rigid and r.num_handles == 1
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="scale"):
            rigid_basis().scaled(bad)


def test_domain_validates_its_fields() -> None:
    pts = _block_points(20)
    with pytest.raises(ValueError, match=r"points_m.*\(5, 2\)"):
        SkinningDomain(pts[:5, :2], 1.0, 0)
    with pytest.raises(ValueError, match="scale=0.0"):
        SkinningDomain(pts, 0.0, 0)
    with pytest.raises(ValueError, match="seed=-1"):
        SkinningDomain(pts, 1.0, -1)


def test_draws_of_one_shape_share_one_trained_basis(tmp_path: Path) -> None:
    """Two sizes and (through the fixed ratio) any material: one training, one cache file; each draw's basis is the
    canonical one scaled, so corresponding points get the same weights."""
    canonical = _block_points()
    small, large = SkinningDomain(canonical, 0.5, 11), SkinningDomain(canonical, 1.7, 11)
    a = train_domain_basis(small, 4, TINY, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.pt"))) == 1
    b = train_domain_basis(large, 4, TINY, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.pt"))) == 1  # the second draw trained nothing
    assert a.metadata["domain_scale"] == 0.5 and b.metadata["domain_scale"] == 1.7
    assert a.metadata["domain_poisson_ratio"] == DOMAIN_POISSON_RATIO
    x = torch.from_numpy(canonical)
    w_a, g_a = a.evaluate(0.5 * x)
    w_b, g_b = b.evaluate(1.7 * x)
    torch.testing.assert_close(w_a, w_b, rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(g_a * 0.5, g_b * 1.7, rtol=1e-10, atol=1e-10)
    # the same as training on the canonical points directly with the domain's seed and ratio
    direct = train_skinning_basis(x, 4, DOMAIN_POISSON_RATIO, TINY, seed=11, cache_dir=tmp_path)
    torch.testing.assert_close(a.evaluate(0.5 * x)[0], direct.evaluate(x)[0], rtol=1e-12, atol=1e-12)
    # another seed or handle count is another basis
    train_domain_basis(SkinningDomain(canonical, 1.0, 12), 4, TINY, cache_dir=tmp_path)
    train_domain_basis(small, 3, TINY, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("*.pt"))) == 3


def _spec(points: np.ndarray, domain: SkinningDomain | None, name: str = "block") -> SimObjectSpec:
    return SimObjectSpec(
        name=name, points_rest_m=points, volume_m3=0.2 * 0.1 * 0.05, material=Material(2e4, 0.45, 500.0),
        position_m=(0.0, 0.0, 0.3), num_handles=3, skinning_settings=TINY, skinning_domain=domain,
    )


def test_simulator_trains_on_the_domain_and_checks_the_particles_are_its_points(tmp_path: Path) -> None:
    canonical = _block_points(300, seed=1)
    draw = 1.5 * canonical  # the draw's particles: the domain's points scaled
    sim = Simulator(StaticScene(), [_spec(draw, SkinningDomain(canonical, 1.5, 5))], (0.0, 0.0, -9.81),
                    load_preset("draft"), seed=0, skinning_cache_dir=str(tmp_path))  # fmt: skip
    basis = sim.prepared[0].basis
    assert basis.metadata["domain_scale"] == 1.5
    expected = train_domain_basis(SkinningDomain(canonical, 1.5, 5), 3, TINY, cache_dir=tmp_path)
    x = torch.from_numpy(draw)
    torch.testing.assert_close(basis.evaluate(x)[0], expected.evaluate(x)[0], rtol=0, atol=0)
    assert len(list(tmp_path.glob("*.pt"))) == 1
    # particles that are not the domain's points scaled are refused, naming the object: a scale given for another
    # canonical size, another sample of the same shape, another count
    for name, points, domain, match in (
        ("big", draw, SkinningDomain(canonical, 0.75, 5), r"differ from the skinning_domain's points scaled by 0.75"),
        ("resampled", 1.5 * _block_points(300, seed=2), SkinningDomain(canonical, 1.5, 5), r"differ from"),
        ("fewer", draw[:200], SkinningDomain(canonical, 1.5, 5), r"shape \(200, 3\), its skinning_domain \(300, 3\)"),
    ):
        with pytest.raises(ValueError, match=rf"object '{name}'.*{match}"):
            Simulator(StaticScene(), [_spec(points, domain, name=name)], (0.0, 0.0, -9.81), load_preset("draft"),
                      seed=0, skinning_cache_dir=str(tmp_path))  # fmt: skip
