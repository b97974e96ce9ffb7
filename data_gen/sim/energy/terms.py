"""Containers of per-object and per-pair energy terms, and the chain rule from points to reduced states."""

from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class ObjectTerms:
    """Energy (n,) J per object; gradient (n, 3, K); Hessian blocks (n, 3K, 3K) (None when not asked)."""

    energy: torch.Tensor
    grad: torch.Tensor | None = None
    hess: torch.Tensor | None = None


@dataclass
class PairTerms:
    """Object-object contact of one evaluation.

    Attributes:
        energy: (n,) J, each pair's energy counted on its side-i object.
        grad: (n, 3, K) gradient on the solved objects (both sides).
        hess: (n, 3K, 3K) diagonal blocks.
        cross: (m, 3K, 3K) blocks d2E / dq_a dq_c for the object pairs ``cross_rows`` / ``cross_cols``
            (both directions are listed).
        force_i_n: (P, 3) contact + friction force on side i of every point pair, N.
    """

    energy: torch.Tensor
    grad: torch.Tensor | None
    hess: torch.Tensor | None
    cross: torch.Tensor | None
    cross_rows: torch.Tensor | None
    cross_cols: torch.Tensor | None
    force_i_n: torch.Tensor


def point_gradient(b: torch.Tensor, grad_x: torch.Tensor) -> torch.Tensor:
    """Chain rule for points moved by ``x = x0 + Tm b``: per-object sums of dE/dx (n, S, 3) into dE/dTm
    (n, 3, K), with bases ``b`` (n, S, K)."""
    return grad_x.transpose(1, 2) @ b


def point_hessian(b: torch.Tensor, hess_x: torch.Tensor, b_other: torch.Tensor | None = None) -> torch.Tensor:
    """Per-object sums of kron-structured point Hessians: ``K[r a, s c] = sum_i H_i[r, s] b_i[a] b'_i[c]``,
    (n, S, 3, 3) with bases (n, S, K) -> (n, 3K, 3K) in padded q-ordering."""
    b_other = b if b_other is None else b_other
    n, s, k = b.shape
    rhs = (hess_x.reshape(n, s, 9, 1) * b_other[:, :, None, :]).reshape(n, s, 9 * k)
    blocks = (b.transpose(1, 2) @ rhs).reshape(n, k, 3, 3, k).permute(0, 2, 1, 3, 4)
    return blocks.reshape(n, 3 * k, 3 * k)
