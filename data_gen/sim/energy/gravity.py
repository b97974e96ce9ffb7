"""Gravity potential ``-sum_p m_p g . u_p = -g . Tm (sum_p m_p b_p)`` per object, J (linear in q)."""

from __future__ import annotations

import torch

from data_gen.sim.energy.terms import ObjectTerms


def gravity(mass_b_sum: torch.Tensor, gravity_m_s2: torch.Tensor, tm: torch.Tensor, derivatives: bool) -> ObjectTerms:
    """``mass_b_sum`` (n, K) kg, gravity (3,) m/s^2, states (n, 3, K)."""
    # (g^T Tm) mass_b_sum per object as one batched product (the same sums as einsum's, at half its overhead)
    energy = -torch.bmm(mass_b_sum[:, None, :], (gravity_m_s2 @ tm)[:, :, None]).reshape(-1)
    if not derivatives:
        return ObjectTerms(energy)
    grad = -gravity_m_s2[None, :, None] * mass_b_sum[:, None, :]
    return ObjectTerms(energy, grad, None)  # zero Hessian
