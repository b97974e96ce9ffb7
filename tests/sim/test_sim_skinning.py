"""Skinning basis: rigid case, handle count rule, training, determinism, cache."""

from __future__ import annotations

import logging
from pathlib import Path

import pytest
import torch

from data_gen.sim import skinning as sk
from data_gen.sim.skinning import (
    SkinningBasis,
    SkinningMLP,
    SkinningTrainingSettings,
    handles_for_stiffness,
    normalised_frame,
    perturbation_energy,
    rigid_basis,
    skinning_cache_key,
    train_skinning_basis,
)

# Reduced settings so the file runs in seconds; the assertions below hold for them.
FAST = SkinningTrainingSettings(
    steps=150, learning_rate=3e-3, final_learning_rate=3e-4, hidden_layers=2, width=32,
    points_per_step=256, perturbations_per_step=4,
)
NU = 0.3
H = 4


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """Run these small tensor ops on one thread: on the shared, oversubscribed CI CPU two
    intra-op threads made them ~10x slower (measured 0.64 s vs 0.05 s per cubature call)."""
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)


def _beam_points(n: int = 400, seed: int = 0) -> torch.Tensor:
    """Uniform points in a 0.4 x 0.1 x 0.1 m beam centred at (1, 2, 3) m."""
    g = torch.Generator().manual_seed(seed)
    size = torch.tensor([0.4, 0.1, 0.1], dtype=torch.float64)
    return (torch.rand(n, 3, generator=g, dtype=torch.float64) - 0.5) * size + torch.tensor([1.0, 2.0, 3.0])


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> tuple[torch.Tensor, SkinningBasis, Path]:
    cache = tmp_path_factory.mktemp("skin_cache")
    x = _beam_points()
    return x, train_skinning_basis(x, H, NU, FAST, seed=7, cache_dir=cache), cache


def test_rigid_basis_is_constant_handle() -> None:
    b = rigid_basis()
    w, g = b.evaluate(_beam_points(10))
    assert b.num_handles == 1 and b.is_rigid
    assert torch.equal(w, torch.ones(10, 1, dtype=torch.float64))
    assert torch.equal(g, torch.zeros(10, 1, 3, dtype=torch.float64))
    assert train_skinning_basis(_beam_points(10), 1, NU, FAST, seed=0, cache_dir="/nonexistent").is_rigid


def test_handles_for_stiffness_hand_values() -> None:
    # strain = rho g L / E = 1000 * 20 * 0.2 / E = 4000 Pa / E
    assert handles_for_stiffness(1e9) == 1
    assert handles_for_stiffness(4e7) == 1  # strain exactly 1e-4: still rigid
    assert handles_for_stiffness(3.9e7) == 2  # just above: first extra handle
    assert handles_for_stiffness(1e6) == 5  # strain 4e-3: 1 + ceil(2 * log10(40)) = 1 + 4
    assert handles_for_stiffness(1e4) == 9  # strain 0.4: 1 + ceil(2 * 3.602) = 9
    assert handles_for_stiffness(1e2) == 12  # capped
    assert handles_for_stiffness(1e4, max_handles=6) == 6
    counts = [handles_for_stiffness(e) for e in torch.logspace(1, 10, 40).tolist()]
    assert all(a >= b for a, b in zip(counts, counts[1:]))  # softer -> more handles
    with pytest.raises(ValueError, match="young_modulus_pa"):
        handles_for_stiffness(0.0)
    with pytest.raises(ValueError, match="max_handles"):
        handles_for_stiffness(1e6, max_handles=0)


def test_settings_and_inputs_are_validated() -> None:
    with pytest.raises(ValueError, match="steps"):
        SkinningTrainingSettings(steps=0)
    with pytest.raises(ValueError, match="learning_rate"):
        SkinningTrainingSettings(learning_rate=-1.0)
    with pytest.raises(ValueError, match="num_handles"):
        train_skinning_basis(_beam_points(), 0, NU, FAST)
    with pytest.raises(ValueError, match="poisson_ratio"):
        train_skinning_basis(_beam_points(), 3, 0.5, FAST)
    with pytest.raises(ValueError, match="points_rest"):
        train_skinning_basis(torch.zeros(10, 2, dtype=torch.float64), 3, NU, FAST)


def test_constant_handle_and_orthonormal_columns(trained) -> None:
    x, basis, _ = trained
    w, g = basis.evaluate(x)
    assert w.shape == (400, H) and g.shape == (400, H, 3)
    assert w.dtype == torch.float64 and g.dtype == torch.float64
    assert torch.equal(w[:, 0], torch.ones(400, dtype=torch.float64))
    assert torch.equal(g[:, 0], torch.zeros(400, 3, dtype=torch.float64))
    # columns are orthonormal under mean(a b) on the training points (folded into the last layer)
    gram = w.T @ w / x.shape[0]
    assert float((gram - torch.eye(H, dtype=torch.float64)).abs().max()) < 1e-9


def test_gradients_match_finite_differences(trained) -> None:
    x, basis, _ = trained
    pts = x[:50]
    _, g = basis.evaluate(pts)
    h = 1e-6  # m
    fd = torch.zeros_like(g)
    for k in range(3):
        d = torch.zeros(3, dtype=torch.float64)
        d[k] = h
        fd[:, :, k] = (basis.evaluate(pts + d)[0] - basis.evaluate(pts - d)[0]) / (2 * h)
    rel = float((g - fd).norm() / g.norm())
    assert rel < 1e-6
    # units: 1/m; a unit-RMS function across a 0.4 m beam has gradients of order 1-100 1/m
    assert 1.0 < float(g[:, 1:].abs().mean()) < 100.0


def test_trained_subspace_beats_random_init(trained) -> None:
    """Energy per unit perturbation (E = 1): the trained basis vs random-init MLPs.

    Measured with FAST: trained 312; its own init (seed 7) 469; other inits (seeds 0-4)
    386-527. Asserted: trained < 0.75 x its own init and below every other init.
    """
    x, basis, _ = trained
    w, g = basis.evaluate(x)
    e_trained = perturbation_energy(w, g, x, NU, seed=1)
    center, half, _ = normalised_frame(x)
    energies = {}
    for seed in (7, 0, 1, 2, 3, 4):
        mlp = SkinningMLP(H - 1, FAST.hidden_layers, FAST.width)
        mlp.reset_parameters(torch.Generator().manual_seed(seed))  # seed 7: the trained basis's start
        w0, g0 = SkinningBasis(H, mlp, center, half).evaluate(x)
        energies[seed] = perturbation_energy(w0, g0, x, NU, seed=1)
    assert e_trained < 0.75 * energies[7]
    assert e_trained < min(energies.values())


def test_perturbation_energy_is_invariant_to_column_mixing(trained) -> None:
    x, basis, _ = trained
    w, g = basis.evaluate(x)
    mix = torch.eye(H, dtype=torch.float64)
    mix[1:, 1:] = torch.tensor([[2.0, 0.5, 0.0], [0.0, -1.0, 0.3], [0.1, 0.0, 3.0]], dtype=torch.float64)
    mix[0, 1:] = torch.tensor([0.2, -0.7, 1.1], dtype=torch.float64)
    e1 = perturbation_energy(w, g, x, NU, seed=3)
    # orthonormalisation of a mixed basis recovers the same span; the draw differs only by a rotation
    # within it, so the expected energy agrees; with 64 draws the spread is a few percent
    e2 = perturbation_energy(w @ mix, torch.einsum("nhk,hj->njk", g, mix), x, NU, seed=3)
    assert e2 == pytest.approx(e1, rel=0.15)


def test_training_is_deterministic(tmp_path: Path, trained) -> None:
    x, basis, _ = trained
    again = train_skinning_basis(x, H, NU, FAST, seed=7, cache_dir=tmp_path / "fresh")
    w1, g1 = basis.evaluate(x)
    w2, g2 = again.evaluate(x)
    assert torch.equal(w1, w2) and torch.equal(g1, g2)
    other = train_skinning_basis(x, H, NU, FAST, seed=8, cache_dir=tmp_path / "fresh")
    assert not torch.equal(other.evaluate(x)[0], w1)


def test_cache_hit_returns_identical_weights_without_training(
    trained, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    x, basis, cache = trained
    files = list(cache.glob("*.pt"))
    assert len(files) == 1 and files[0].stem == skinning_cache_key(x, H, NU, FAST, 7)

    def _fail(*args, **kwargs):
        raise AssertionError("cache hit must not retrain")

    monkeypatch.setattr(sk, "_optimise", _fail)
    with caplog.at_level(logging.INFO, logger=sk.__name__):
        hit = train_skinning_basis(x, H, NU, FAST, seed=7, cache_dir=cache)
    assert "cache hit" in caplog.text
    assert torch.equal(hit.evaluate(x)[0], basis.evaluate(x)[0])
    assert torch.equal(hit.evaluate(x)[1], basis.evaluate(x)[1])


def test_corrupt_cache_file_is_rebuilt(tmp_path: Path, trained, monkeypatch: pytest.MonkeyPatch) -> None:
    x, basis, cache = trained
    key = skinning_cache_key(x, H, NU, FAST, 7)
    (tmp_path / f"{key}.pt").write_bytes(b"not a torch file")
    calls = []
    real = sk._optimise

    def _counting(*args, **kwargs):
        calls.append(1)
        return real(*args, **kwargs)

    monkeypatch.setattr(sk, "_optimise", _counting)
    rebuilt = train_skinning_basis(x, H, NU, FAST, seed=7, cache_dir=tmp_path)
    assert len(calls) == 1
    assert torch.equal(rebuilt.evaluate(x)[0], basis.evaluate(x)[0])
    # the file was replaced by a valid one: the next call is a hit
    train_skinning_basis(x, H, NU, FAST, seed=7, cache_dir=tmp_path)
    assert len(calls) == 1


def test_cache_key_depends_on_every_input(trained) -> None:
    x, _, _ = trained
    k = skinning_cache_key(x, H, NU, FAST, 7)
    assert len(k) == 64
    assert k == skinning_cache_key(x.clone(), H, NU, FAST, 7)
    x2 = x.clone()
    x2[0, 0] += 1e-12
    variants = {
        skinning_cache_key(x2, H, NU, FAST, 7),
        skinning_cache_key(x, H + 1, NU, FAST, 7),
        skinning_cache_key(x, H, 0.31, FAST, 7),
        skinning_cache_key(x, H, NU, SkinningTrainingSettings(steps=151), 7),
        skinning_cache_key(x, H, NU, FAST, 8),
    }
    assert len(variants) == 5 and k not in variants


def test_env_var_sets_default_cache_dir(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEWTPHYS_CACHE_DIR", str(tmp_path))
    x = _beam_points(64, seed=3)
    tiny = SkinningTrainingSettings(steps=2, hidden_layers=1, width=8, points_per_step=64, perturbations_per_step=1)
    train_skinning_basis(x, 2, NU, tiny, seed=0)
    assert (tmp_path / "skinning" / f"{skinning_cache_key(x, 2, NU, tiny, 0)}.pt").is_file()
