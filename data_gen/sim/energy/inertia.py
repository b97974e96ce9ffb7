"""Inertia of implicit Euler: ``1/2 (q - q_pred)^T M (q - q_pred)`` per object (kg m^2 / unit q^2 = J / h^2
scaling is applied by the caller: this term is *not* multiplied by h^2)."""

from __future__ import annotations

import torch

from data_gen.sim.energy.terms import ObjectTerms


def inertia(mass_matrix: torch.Tensor, dq: torch.Tensor, derivatives: bool) -> ObjectTerms:
    """``mass_matrix`` (n, 3K, 3K), ``dq = tm - tm_pred`` (n, 3, K)."""
    flat = dq.reshape(dq.shape[0], -1, 1)
    m_dq = (mass_matrix @ flat)[:, :, 0]
    energy = 0.5 * (flat[:, :, 0] * m_dq).sum(1)
    if not derivatives:
        return ObjectTerms(energy)
    return ObjectTerms(energy, m_dq.reshape(dq.shape), mass_matrix)
