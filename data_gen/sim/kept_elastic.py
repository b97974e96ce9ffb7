"""Soft objects' elastic Newton matrices kept across (sub)steps (``QualityPreset.elastic_hessian_reuse``).

With ``lagged_elastic_hessian`` a solve forms each soft object's elastic matrix ``K`` once, at its predicted
start, and keeps it for its iterations (modified Newton, :class:`data_gen.sim.step_objective.StepObjective`).
``K`` depends only on the object's deformation gradients ``F`` at its cubature points, and between one
(sub)step and the next they move little, so a later solve may take the matrix again: :class:`KeptElasticMatrices`
keeps, per object, the last matrix formed and the ``F - I`` it was formed at, and hands it to a solve whose
``F - I`` differs from those by at most ``tolerance`` in every entry. The matrix only steers Newton's direction;
every solve still stops on the exact gradient at the preset's tolerance, so reuse changes the iterates (at the
level of that tolerance), not the minimum they converge to.
"""

from __future__ import annotations

import torch

from data_gen.sim.reduced import DTYPE


class KeptElasticMatrices:
    """Per object of a solver's model: the kept elastic matrix (3K, 3K) and its ``F - I`` (3, P * 3).

    Args:
        cub_c: the model's cubature bases ``C_i`` (n, P, K, 3): ``F_i - I = Tm C_i`` for padded states ``Tm``
            (n, 3, K).
        tolerance: the largest change of any entry of any point's ``F`` (dimensionless) at which a kept matrix
            still serves; must be > 0.
    """

    def __init__(self, cub_c: torch.Tensor, tolerance: float) -> None:
        if not tolerance > 0:
            raise ValueError(f"KeptElasticMatrices: tolerance={tolerance!r} must be > 0")
        n, p, k, _ = cub_c.shape
        self.tolerance = float(tolerance)
        self._basis = cub_c.permute(0, 2, 1, 3).reshape(n, k, p * 3).contiguous()  # [o, a, (i, j)]
        self._strain = torch.zeros(n, 3, p * 3, dtype=DTYPE)
        self._matrix = torch.zeros(n, 3 * k, 3 * k, dtype=DTYPE)
        self._kept = torch.zeros(n, dtype=torch.bool)
        self.formed = 0  # matrices formed and kept so far
        self.reused = 0  # solves' objects that took a kept matrix

    def strain(self, index: torch.Tensor, tm: torch.Tensor) -> torch.Tensor:
        """``F - I`` (n, 3, P * 3), entry [r, (i, j)], of objects ``index`` (n,) at padded states ``tm`` (n, 3, K)."""
        return torch.bmm(tm, self._basis[index])

    def lookup(self, index: torch.Tensor, strain: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor] | None:
        """For a solve of objects ``index`` at ``strain`` (:meth:`strain`): (mask (n,) bool, matrices
        (n, 3K, 3K), a new tensor): which objects' kept matrices serve, and every object's kept matrix (zero where
        none is kept). None when none of them has one."""
        kept = self._kept[index]
        if not bool(kept.any()):
            return None
        moved = (strain - self._strain[index]).abs().amax(dim=(1, 2))
        mask = kept & (moved <= self.tolerance)
        self.reused += int(mask.sum())
        return mask, self._matrix[index]

    def keep(self, index: torch.Tensor, strain: torch.Tensor, fresh: torch.Tensor, formed: torch.Tensor) -> None:
        """After a solve of objects ``index``: keep the matrices ``formed`` (n, 3K, 3K) of those it formed
        (``fresh`` (n,) bool) with the ``strain`` (:meth:`strain`) they were formed at."""
        if not bool(fresh.all()):
            rows = torch.nonzero(fresh)[:, 0]
            if not len(rows):
                return
            index, strain, formed = index[rows], strain[rows], formed[rows]
        self._strain[index] = strain
        self._matrix[index] = formed
        self._kept[index] = True
        self.formed += len(index)


__all__ = ["KeptElasticMatrices"]
