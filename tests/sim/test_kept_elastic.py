"""Soft objects' elastic Newton matrices kept across (sub)steps (``QualityPreset.elastic_hessian_reuse``,
:class:`data_gen.sim.kept_elastic.KeptElasticMatrices`): the deformation gradients the reuse test compares, which
objects a lookup hands a kept matrix, the objective that takes them (only the others' matrices formed), and
whole soft simulations that reuse most matrices and still converge every solve to the same steps as without."""

import numpy as np
import pytest
import torch

from data_gen.sim.energy.elastic import deformation_gradients
from data_gen.sim.kept_elastic import KeptElasticMatrices
from data_gen.sim.presets import available_presets, load_preset
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.step_objective import StepObjective
from tests.sim.test_sim_warp_kernels import _setup, random_rates

D = torch.float64
GRAVITY = torch.tensor([0.0, 0.0, -9.81], dtype=D)
H_S = 0.01


def _random_kept(n: int = 4, p: int = 6, k: int = 8, tolerance: float = 0.1, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    cub_c = torch.randn(n, p, k, 3, generator=gen, dtype=D)
    return KeptElasticMatrices(cub_c, tolerance), cub_c, gen


def test_strain_is_the_deformation_gradient_minus_the_identity():
    kept, cub_c, gen = _random_kept()
    tm = 0.05 * torch.randn(4, 3, 8, generator=gen, dtype=D)
    index = torch.tensor([2, 0, 3, 1])
    strain = kept.strain(index, tm)  # (n, 3, P * 3): [r, (i, j)]
    expected = deformation_gradients(cub_c[index], tm) - torch.eye(3, dtype=D)  # (n, P, 3, 3): [i, r, j]
    torch.testing.assert_close(strain.reshape(4, 3, 6, 3).permute(0, 2, 1, 3), expected, rtol=1e-14, atol=1e-16)


def test_lookup_hands_back_the_matrices_of_objects_whose_gradients_moved_at_most_the_tolerance():
    kept, _, gen = _random_kept(tolerance=0.1)
    index = torch.tensor([0, 1, 2])
    strain = 0.05 * torch.randn(3, 3, 18, generator=gen, dtype=D)
    assert kept.lookup(index, strain) is None  # nothing kept yet
    formed = torch.randn(3, 24, 24, generator=gen, dtype=D)
    kept.keep(index, strain, torch.ones(3, dtype=torch.bool), formed)
    assert (kept.formed, kept.reused) == (3, 0)

    later = strain.clone()
    later[0, 1, 5] += 0.1  # object 0: one entry moved by exactly the tolerance (kept)
    later[1, 2, 17] -= 0.1 + 1e-9  # object 1: just beyond it (formed anew)
    later[2] += 0.04 * (2 * torch.rand(3, 18, generator=gen, dtype=D) - 1)  # object 2: every entry a little
    mask, matrices = kept.lookup(index, later)
    assert mask.tolist() == [True, False, True]
    assert torch.equal(matrices, formed)  # every object's kept matrix (the solve forms the unmasked ones)
    assert kept.reused == 2
    # an object never kept gets none, whatever its gradients; the order of the lookup is the solve's
    mask, matrices = kept.lookup(torch.tensor([3, 2]), torch.stack([later[0], later[2]]))
    assert mask.tolist() == [False, True]
    assert torch.equal(matrices[1], formed[2]) and torch.equal(matrices[0], torch.zeros(24, 24, dtype=D))


def test_keep_replaces_only_the_matrices_formed_anew():
    kept, _, gen = _random_kept()
    index = torch.tensor([1, 3])
    strain = 0.01 * torch.randn(2, 3, 18, generator=gen, dtype=D)
    first = torch.randn(2, 24, 24, generator=gen, dtype=D)
    kept.keep(index, strain, torch.ones(2, dtype=torch.bool), first)
    moved = strain + torch.tensor([0.0, 0.5], dtype=D)[:, None, None]  # object 3 moved beyond the tolerance
    mask, matrices = kept.lookup(index, moved)
    assert mask.tolist() == [True, False]
    second = matrices.clone()
    second[1] = torch.randn(24, 24, generator=gen, dtype=D)  # what the solve formed for object 3
    kept.keep(index, moved, ~mask, second)  # only object 3's was formed
    assert kept.formed == 3
    # object 1 kept its first strain and matrix, object 3 its new ones: now object 1 moves beyond the tolerance
    mask, matrices = kept.lookup(index, moved + torch.tensor([0.3, 0.0], dtype=D)[:, None, None])
    assert mask.tolist() == [False, True]
    assert torch.equal(matrices[0], first[0]) and torch.equal(matrices[1], second[1])


def test_tolerance_must_be_positive():
    with pytest.raises(ValueError, match="tolerance=0.0 must be > 0"):
        KeptElasticMatrices(torch.zeros(1, 1, 4, 3, dtype=D), 0.0)


def _soft_step(seed: int = 3):
    """A step of three deformable objects (3, 2 and 4 handles; two islands; scene and pair contact) and its
    predicted state (island vectors)."""
    model, layout, distance, _, _, pairs, tm = _setup(StaticScene(), seed, (3, 2, 4))
    tmdot = random_rates(model, tm, seed + 1)

    def objective(reused=None) -> StepObjective:
        return StepObjective(model, layout, distance, GRAVITY, tm, tmdot, H_S, 20.0, 0.01 * H_S, pairs,
                             lagged_elastic_hessian=True, kernel_evaluation=True,
                             reused_elastic_hessian=reused)  # fmt: skip

    return objective, model, layout, layout.to_islands(tm + H_S * tmdot)


def test_objective_takes_the_reused_matrices_and_forms_only_the_others():
    objective, model, layout, q0 = _soft_step()
    fresh = objective()
    reference = fresh.evaluate(q0, True)
    formed = fresh.formed_elastic_hessian  # every object's K at q0, (n, 3K, 3K)
    assert formed is not None and float(formed.abs().amax()) > 0.0
    gen = torch.Generator().manual_seed(9)
    other = formed + 0.3 * float(formed.abs().amax()) * torch.randn(formed.shape, generator=gen, dtype=D)
    other = 0.5 * (other + other.transpose(1, 2))
    cases = {"all": [True, True, True], "some": [True, False, True], "none": [False, False, False]}
    for name, flags in cases.items():
        mask = torch.tensor(flags)
        given = objective((mask, other.clone()))
        ev = given.evaluate(q0, True)
        expected_k = torch.where(mask[:, None, None], other, formed)
        torch.testing.assert_close(given.formed_elastic_hessian, expected_k, rtol=1e-14, atol=0.0)
        # the matrix: the reference's with each reused object's elastic block swapped, h^2 (K_given - K_formed)
        expected = reference.hess + layout.assemble(given.h2 * (expected_k - formed))
        scale = float(reference.hess.abs().amax())
        torch.testing.assert_close(ev.hess, expected, rtol=0.0, atol=1e-12 * scale, msg=name)
        assert torch.equal(ev.value, reference.value) and torch.equal(ev.grad, reference.grad), name
        if name != "none":
            assert float((ev.hess - reference.hess).abs().amax()) > 1e-6 * scale  # not a vacuous check


def _soft_column(preset, tmp_path):
    from data_gen.sim.world import Simulator
    from tests.sim.test_sim_column import staggered_soft_column

    sim = Simulator(StaticScene(), staggered_soft_column(), (0.0, 0.0, -9.81), preset, seed=0,
                    skinning_cache_dir=str(tmp_path))  # fmt: skip
    return sim.run(13, fps=25.0)


def test_soft_simulation_reuses_most_matrices_and_lands_where_it_does_without(tmp_path):
    """Three soft boxes dropped into a staggered column (draft, fused kernel, 0.5 s: falling, landing on the ground
    and on each other): with the preset's reuse most solves take kept matrices, every solve still converges,
    and the boxes stay within 0.1 mm of the run that forms every matrix (the two runs'
    iterates differ at the level of the Newton tolerance, the piles they build do not)."""
    draft = load_preset("draft")
    assert draft.elastic_hessian_reuse > 0
    reusing = _soft_column(draft, tmp_path)
    forming = _soft_column(draft.replace(elastic_hessian_reuse=0.0), tmp_path)
    c = reusing.info.counters
    assert forming.info.counters["elastic_matrices_reused"] == 0
    assert c["elastic_matrices_reused"] > c["elastic_matrices_formed"] > 0, c
    for run in (reusing, forming):
        assert run.info.counters["unconverged_solves"] == 0
    gap = max(float(np.abs(a.com_m - b.com_m).max()) for a, b in zip(reusing.objects, forming.objects))
    travel = max(float(np.abs(a.com_m[-1] - a.com_m[0]).max()) for a in forming.objects)
    assert travel > 0.04  # the top box fell onto the others (measured 5.2 cm)
    assert gap < 1e-4, gap  # measured 7.0e-6 m, 63 matrices reused against 25 formed


def test_shipped_presets_reuse_the_kept_matrix_wherever_they_lag_it():
    values = {name: load_preset(name).elastic_hessian_reuse for name in available_presets()}
    assert values == {"draft": 0.02, "high": 0.02, "reference": 0.0, "standard": 0.02}
    with pytest.raises(ValueError, match="needs lagged_elastic_hessian"):
        load_preset("reference").replace(elastic_hessian_reuse=0.1)
    with pytest.raises(ValueError, match="must be finite and >= 0"):
        load_preset("draft").replace(elastic_hessian_reuse=-0.1)


@pytest.mark.parametrize("refresh_after", [None, 2])
def test_solver_keeps_each_objects_matrix_formed_where_it_was_formed(tmp_path, monkeypatch, refresh_after):
    """In a real soft run every matrix the solver keeps is that object's elastic Newton matrix at the state it
    was formed at: the solve's predicted start, or, in a solve that started from kept matrices and still ran after
    ``REUSED_MATRIX_REFRESH`` iterations (set to 2 here so that some do), the state it had reached then (every
    object formed anew there). Checked against the batched ``elastic`` terms at that state, to round-off, for
    every object formed, in whatever slot the solve held it."""
    import data_gen.sim.fused_newton as fused_module
    import data_gen.sim.solver as solver_module
    from data_gen.sim.energy.elastic import elastic

    if refresh_after is not None:
        monkeypatch.setattr(fused_module, "REUSED_MATRIX_REFRESH", refresh_after)

    solvers, checked = [], []
    original_init = solver_module.ImplicitEulerSolver.__init__

    def capture_solver(self, *args, **kwargs):
        original_init(self, *args, **kwargs)
        solvers.append(self)

    class CheckedKept(KeptElasticMatrices):
        def strain(self, index, tm):
            self.last_tm = tm.clone()
            return super().strain(index, tm)

        def keep(self, index, strain, fresh, formed):
            m = solvers[-1].model
            rows = index[fresh]
            if not len(rows):  # every object reused its matrix
                return super().keep(index, strain, fresh, formed)
            expected = elastic(m.cub_c[rows], m.cub_volume_m3[rows], m.mu_pa[rows], m.lam_pa[rows],
                               m.spd_tolerance_pa[rows], self.last_tm[fresh], True).hess  # fmt: skip
            scale = float(expected.abs().amax())
            torch.testing.assert_close(formed[fresh], expected, rtol=0.0, atol=1e-9 * scale)
            checked.append(len(rows))
            super().keep(index, strain, fresh, formed)

    monkeypatch.setattr(solver_module.ImplicitEulerSolver, "__init__", capture_solver)
    monkeypatch.setattr(solver_module, "KeptElasticMatrices", CheckedKept)
    result = _soft_column(load_preset("draft"), tmp_path)
    counters = result.info.counters
    assert sum(checked) == counters["elastic_matrices_formed"] > 0
    assert counters["elastic_matrices_reused"] > 0
    if refresh_after is not None:  # (the default refreshes a few solves of this run too)
        assert counters["elastic_matrices_refreshed"] > 0, counters
    assert counters["unconverged_solves"] == 0

