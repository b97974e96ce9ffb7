"""Skinning basis: rigid case, handle count rule, training, determinism, cache."""

from __future__ import annotations

import dataclasses
import itertools
import logging
from pathlib import Path

import pytest
import torch

from data_gen.sim import skinning as sk
from data_gen.sim.skinning import (
    BlendWeights,
    SkinningBasis,
    SkinningMLP,
    SkinningTrainingSettings,
    blend_basis,
    expected_perturbation_energy,
    handles_for_stiffness,
    normalised_frame,
    perturbation_energy,
    rigid_basis,
    skinning_cache_key,
    train_skinning_basis,
)

# Reduced settings so the file runs in seconds; the assertions below hold for them.
FAST = SkinningTrainingSettings(
    steps=150, learning_rate=3e-3, final_learning_rate=3e-4, decay_steps=150, hidden_layers=2, width=32,
    points_per_step=256,
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

    Measured with FAST (format v4: Ritz output layer + variable-projection Adam): trained 153;
    its own init (seed 7) 469; other inits (seeds 0-4) 386-527 (format v3 trained: 312).
    Asserted: trained < 0.5 x its own init and below every other init.
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
    assert e_trained < 0.5 * energies[7]
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
    tiny = SkinningTrainingSettings(steps=2, hidden_layers=1, width=8, points_per_step=64)
    train_skinning_basis(x, 2, NU, tiny, seed=0)
    assert (tmp_path / "skinning" / f"{skinning_cache_key(x, 2, NU, tiny, 0)}.pt").is_file()


# --------------------------------------------------------------------------- closed-form objective


def _grid_box(counts: tuple[int, int, int], size_m: tuple[float, float, float]) -> torch.Tensor:
    """Cell centres of a regular grid filling a box centred at the origin, m (symmetric: odd moments are 0)."""
    axes = [(torch.arange(c, dtype=torch.float64) + 0.5) / c - 0.5 for c in counts]
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    return grid * torch.tensor(size_m, dtype=torch.float64)


def test_expected_energy_hand_value_for_a_linear_field() -> None:
    """w_1 = x (linear along the long axis) on a symmetric grid.

    Normalised coordinates y = x0 / L (L = longest side); mean(y_x) = 0, so orthonormalising
    only divides w by its RMS: w = y_x / s, g = e_x / s with s^2 = mean(y_x^2). The energy form is
    Q = mean(3 w^2 + 2 w (y . g) + (1 + |y|^2) |g|^2) = 3 + 2 + (1 + mean |y|^2) / s^2, times
    2 mu + lam / 2 (E = 1, nu = 0.3: mu = 1 / 2.6, lam = 0.3 / (1.3 * 0.4)).
    """
    x = _grid_box((10, 4, 4), (0.4, 0.1, 0.1))
    n = x.shape[0]
    w = torch.stack((torch.ones(n, dtype=torch.float64), x[:, 0]), 1)
    g = torch.zeros(n, 2, 3, dtype=torch.float64)
    g[:, 1, 0] = 1.0  # d x / d x, 1/m x m
    y = (x - x.mean(0)) / 0.4 * (0.4 / float((x.max(0).values - x.min(0).values).max()))
    s2 = float((y[:, 0] ** 2).mean())
    mu, lam = 1.0 / 2.6, 0.3 / (1.3 * 0.4)
    hand = (2 * mu + lam / 2) * (5.0 + (1.0 + float((y**2).sum(1).mean())) / s2)
    assert expected_perturbation_energy(w, g, x, NU) == pytest.approx(hand, rel=1e-12)
    # the Monte-Carlo measure agrees within its sampling error: 2000 draws spread +-4 % here (few
    # dominant Gaussian terms per draw), so average 5 x 2000 draws (~1.5 %)
    mc = sum(perturbation_energy(w, g, x, NU, num_perturbations=2000, scale=1e-3, seed=k) for k in range(5)) / 5
    assert mc == pytest.approx(hand, rel=0.03)


def test_expected_energy_matches_monte_carlo_on_a_trained_basis(trained) -> None:
    """Closed form vs 1000 random perturbations at scale 1e-3 (nonlinearity ~1e-3): measured within ~1 %."""
    x, basis, _ = trained
    w, g = basis.evaluate(x)
    exact = expected_perturbation_energy(w, g, x, NU)
    mc = perturbation_energy(w, g, x, NU, num_perturbations=1000, scale=1e-3, seed=5)
    assert mc == pytest.approx(exact, rel=0.03)
    assert basis.metadata["energy_learned"] == pytest.approx(exact, rel=1e-9)


# --------------------------------------------------------------------------- blend baseline and guard


def _lbs_like_bench(x: torch.Tensor, num_handles: int, volume_m3: float) -> tuple[torch.Tensor, torch.Tensor]:
    """The bench's linear-blend baseline: RBF centres from ``sample_cubature``, sigma = (V / H)^(1/3)."""
    from data_gen.sim.cubature import sample_cubature

    centres = sample_cubature(x, num_handles, seed=0, volume_m3=volume_m3).positions
    sigma = (volume_m3 / num_handles) ** (1.0 / 3.0)
    return BlendWeights(centres, sigma, torch.eye(num_handles, dtype=torch.float64)).evaluate(x)


def test_blend_basis_is_orthonormal_smooth_and_round_trips() -> None:
    x = _beam_points(300, seed=2)
    b = blend_basis(x, 5, seed=3)
    w, g = b.evaluate(x)
    assert b.metadata["source"] == "blend" and not b.is_rigid and b.mlp is None
    assert torch.equal(w[:, 0], torch.ones(300, dtype=torch.float64))
    assert torch.equal(g[:, 0], torch.zeros(300, 3, dtype=torch.float64))
    assert float((w.T @ w / 300 - torch.eye(5, dtype=torch.float64)).abs().max()) < 1e-10
    h = 1e-6  # m
    fd = torch.stack([(b.evaluate(x + d)[0] - b.evaluate(x - d)[0]) / (2 * h)
                      for d in torch.eye(3, dtype=torch.float64) * h], -1)
    assert float((g - fd).norm() / g.norm()) < 1e-6
    again = SkinningBasis.from_payload(b.to_payload())
    assert torch.equal(again.evaluate(x)[0], w) and torch.equal(again.evaluate(x)[1], g)
    assert again.metadata["source"] == "blend"
    assert torch.equal(blend_basis(x, 5, seed=3).evaluate(x)[0], w)  # deterministic


def test_guard_ships_the_blend_basis_when_the_learned_one_is_worse(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A learned basis replaced by a random-init MLP (energy ~2-3x the blend's) must not ship."""
    x = _beam_points(300, seed=4)

    def _random_mlp(y64, scale64, num_handles, settings, seed):
        mlp = SkinningMLP(num_handles - 1, settings.hidden_layers, settings.width)
        mlp.reset_parameters(torch.Generator().manual_seed(seed))
        return sk._TrainingOutcome(mlp, step=0, steps_run=0, score=0.0, validation_points=0)

    monkeypatch.setattr(sk, "_train_learned", _random_mlp)
    with caplog.at_level(logging.INFO, logger=sk.__name__):
        b = train_skinning_basis(x, 5, NU, FAST, seed=0, cache_dir=tmp_path)
    assert "shipping the blend basis" in caplog.text
    assert b.metadata["energy_blend"] < b.metadata["energy_learned"]
    w, g = b.evaluate(x)
    w_blend, g_blend = blend_basis(x, 5, seed=0).evaluate(x)  # what shipped is the blend baseline itself
    assert torch.equal(w, w_blend) and torch.equal(g, g_blend)
    assert expected_perturbation_energy(w, g, x, NU) == pytest.approx(b.metadata["energy_blend"], rel=1e-9)
    hit = train_skinning_basis(x, 5, NU, FAST, seed=0, cache_dir=tmp_path)  # from the cache
    assert hit.metadata == b.metadata and torch.equal(hit.evaluate(x)[0], w)


def test_too_narrow_mlp_falls_back_to_blend(tmp_path: Path) -> None:
    """width 2 cannot span H - 1 = 4 modes: the blend basis ships, orthonormal."""
    x = _beam_points(200, seed=5)
    narrow = SkinningTrainingSettings(steps=5, hidden_layers=1, width=2, points_per_step=64)
    b = train_skinning_basis(x, 5, NU, narrow, seed=0, cache_dir=tmp_path)
    w, _ = b.evaluate(x)
    assert b.metadata["source"] == "blend"
    assert float((w.T @ w / 200 - torch.eye(5, dtype=torch.float64)).abs().max()) < 1e-10


# --------------------------------------------------------------------------- quality vs the baseline and vs steps

REDUCED = SkinningTrainingSettings(points_per_step=256)  # default architecture and schedule, smaller batches


def test_beam_h8_learned_basis_beats_linear_blend(tmp_path: Path) -> None:
    """(a) 0.4 x 0.1 x 0.1 m beam, 600 points, H = 8, 50 steps (the bench uses 2000 points, 500 steps).

    Measured (expected energy, E = 1): learned 857 (Ritz init at step 0: 894); bench-style LBS
    1152; blend guard baseline 1175. Monte-Carlo measure (256 draws): learned 835, LBS 1123.
    Before this change (format v3) the bench measured learned 1291 vs LBS 1140 at H = 8.
    Asserted: learned ships and is <= 0.85 x LBS (closed form) and <= LBS (Monte-Carlo).
    """
    x = _beam_points(600, seed=0)
    b = train_skinning_basis(x, 8, NU, dataclasses.replace(REDUCED, steps=50), seed=0, cache_dir=tmp_path)
    w, g = b.evaluate(x)
    wl, gl = _lbs_like_bench(x, 8, volume_m3=0.4 * 0.1 * 0.1)
    assert b.metadata["source"] == "learned"
    assert expected_perturbation_energy(w, g, x, NU) <= 0.85 * expected_perturbation_energy(wl, gl, x, NU)
    assert perturbation_energy(w, g, x, NU, 256, seed=1) <= perturbation_energy(wl, gl, x, NU, 256, seed=1)
    assert b.metadata["energy_learned"] <= b.metadata["energy_blend"]


def test_beam_h6_more_steps_never_worse(tmp_path: Path) -> None:
    """(b) H = 6, 600 points: a shorter run is a prefix of a longer one and the best checkpoint
    is kept, so the expected energy cannot rise with steps (multiples of checkpoint_every).

    Measured (expected energy): 1 step 488, 25 -> 469, 50 -> 460, 100 -> 454; Monte-Carlo
    measure (256 draws): 477, 461, 455, 451.
    Asserted: non-increasing to round-off; 100 steps <= 0.96 x 1 step; the Monte-Carlo
    measure (sampling noise a few %) at 100 steps is at most 5 % above the one at 25 steps.
    """
    x = _beam_points(600, seed=0)
    energies, mc = [], []
    for steps in (1, 25, 50, 100):
        b = train_skinning_basis(x, 6, NU, dataclasses.replace(REDUCED, steps=steps), seed=0, cache_dir=tmp_path)
        w, g = b.evaluate(x)
        energies.append(expected_perturbation_energy(w, g, x, NU))
        mc.append(perturbation_energy(w, g, x, NU, 256, seed=1))
    for shorter, longer in itertools.pairwise(energies):
        assert longer <= shorter * (1 + 1e-9)
    assert energies[-1] <= 0.96 * energies[0]
    assert mc[-1] <= 1.05 * mc[1]


def test_held_out_points_stop_a_basis_overfitting_its_particles(tmp_path: Path) -> None:
    """(c) 250 points in the beam, H = 2, at most 300 steps. Scored on the points it trains on, training finds a
    mode soft at those points and stiff between them; scored on 20 % held-out points, it keeps the basis that is
    soft everywhere and stops early.

    Measured (expected energy on 4,000 fresh points of the beam, E = 1): selected on the training points 20.11
    (step 175 of 300; 11.43 on its own points); selected on held-out points 15.92 (step 0, stopped after 100).
    Asserted: held-out selection <= 0.85 x training selection on fresh points; it stopped before 300 steps and
    held out int(0.2 x 250) = 50 points; training selection ran all 300 steps.
    """
    x, fresh = _beam_points(250, seed=1), _beam_points(4000, seed=99)
    settings = dataclasses.replace(REDUCED, steps=300)
    on_training = train_skinning_basis(
        x, 2, NU, dataclasses.replace(settings, validation_fraction=0.0, patience=1000), seed=0, cache_dir=tmp_path
    )
    on_held_out = train_skinning_basis(x, 2, NU, settings, seed=0, cache_dir=tmp_path)
    fresh_energy = {name: expected_perturbation_energy(*b.evaluate(fresh), fresh, NU)
                    for name, b in (("training", on_training), ("held_out", on_held_out))}  # fmt: skip
    assert fresh_energy["held_out"] <= 0.85 * fresh_energy["training"]
    assert on_training.metadata["steps_run"] == 300 and on_training.metadata["validation_points"] == 0
    assert on_held_out.metadata["steps_run"] < 300 and on_held_out.metadata["validation_points"] == 50
    assert on_held_out.metadata["energy_held_out"] > 0.0 and "energy_held_out" not in on_training.metadata


def test_training_settings_reject_a_validation_fraction_out_of_range() -> None:
    for bad in (-0.1, 0.6):
        with pytest.raises(ValueError, match=r"validation_fraction=.* allowed: \[0, 0.5\]"):
            SkinningTrainingSettings(validation_fraction=bad)
    with pytest.raises(ValueError, match="patience=0"):
        SkinningTrainingSettings(patience=0)


def test_evaluation_in_chunks_on_threads_matches_one_piece(trained) -> None:
    """More than EVALUATE_CHUNK_ROWS points are evaluated in chunks, num_threads at a time: the same bytes for any
    thread count, and the values of one evaluation in one piece (rows are independent), for learned and blend
    weights."""
    _, basis, _ = trained
    x = _beam_points(n=2 * sk.EVALUATE_CHUNK_ROWS + 37, seed=9)
    for b in (basis, blend_basis(x, 5, seed=1)):
        whole = b._evaluate(x)
        chunked = [b.evaluate(x, num_threads=k) for k in (1, 2, 3)]
        for w, g in chunked[1:]:
            assert torch.equal(w, chunked[0][0]) and torch.equal(g, chunked[0][1])
        torch.testing.assert_close(chunked[0][0], whole[0], rtol=1e-13, atol=1e-15)
        torch.testing.assert_close(chunked[0][1], whole[1], rtol=1e-13, atol=1e-13)
        assert torch.equal(chunked[0][0][:, 0], torch.ones(len(x), dtype=torch.float64))
    with pytest.raises(ValueError, match=r"num_threads=0 is out of range"):
        basis.evaluate(x, num_threads=0)
