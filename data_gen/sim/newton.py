"""Newton's method on many independent islands at once, with a trust region and a backtracking line search.

Each island ``i`` minimises its own objective ``f_i(q_i)``; the islands share one batched evaluation
(:class:`Objective`) but every decision is per island: the Newton direction (batched Cholesky of the
(islands, N, N) matrices, a relative ridge where needed, and an all-blocks-projected re-evaluation for an
island whose matrix is still indefinite), the trust radius on contact-sphere motion, the Armijo search
(then plain decrease for ``extra_halvings`` more halvings), and convergence (``alpha |dq|_M <= tol scale_i``;
an update that is already that small is taken whole without a search).
A converged or stalled island stops moving while the others go on.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from dataclasses import dataclass

import torch

ARMIJO_C = 1e-4
EXTRA_HALVINGS = 20


@dataclass
class Evaluation:
    """Objective per island (n_isl,); gradient (n_isl, N) and matrix (n_isl, N, N) when asked."""

    value: torch.Tensor
    grad: torch.Tensor | None = None
    hess: torch.Tensor | None = None


class Objective(ABC):
    """What :func:`minimise` needs from a step: evaluations and sizes, all in island vectors (n_isl, N)."""

    @abstractmethod
    def evaluate(self, q: torch.Tensor, derivatives: bool, strict_islands: torch.Tensor | None = None) -> Evaluation:
        """Objective per island at ``q``; with ``derivatives`` also gradient and Newton matrix (``strict_islands``:
        islands whose elastic blocks are all projected to positive semi-definite)."""

    @abstractmethod
    def mass_norm(self, dq: torch.Tensor) -> torch.Tensor:
        """|dq|_M per island."""

    @abstractmethod
    def point_motion(self, dq: torch.Tensor) -> torch.Tensor:
        """Largest contact-sphere displacement (m) per island under the state change dq."""

    def update_norms(self, dq: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(:meth:`point_motion`, :meth:`mass_norm`) of one update dq; an objective may share their work."""
        return self.point_motion(dq), self.mass_norm(dq)


@dataclass
class NewtonSettings:
    iterations: int
    tolerance: float
    line_search_steps: int


@dataclass
class NewtonResult:
    q: torch.Tensor
    iterations: torch.Tensor  # (n_isl,) Newton iterations taken
    converged: torch.Tensor
    counters: dict[str, int]


_EYES: dict[tuple[int, torch.dtype], torch.Tensor] = {}


def _eye(n: int, dtype: torch.dtype) -> torch.Tensor:
    """A cached (n, n) identity (read only)."""
    eye = _EYES.get((n, dtype))
    if eye is None:
        eye = _EYES[(n, dtype)] = torch.eye(n, dtype=dtype)
    return eye


def cholesky_direction(hess: torch.Tensor, grad: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor | None]:
    """:func:`newton_direction`, with ``ok`` None when every matrix was positive definite (the common case:
    no masking, one host sync)."""
    hess = torch.add(hess, hess.transpose(1, 2)).mul_(0.5)
    chol, info = torch.linalg.cholesky_ex(hess)
    if not bool(info.any()):  # info: 0 where the factorisation succeeded
        # two triangular solves: cholesky_solve's result bit for bit, in half its time at these sizes
        y = torch.linalg.solve_triangular(chol, grad[:, :, None], upper=False)
        return torch.linalg.solve_triangular(chol.mT, y, upper=True)[:, :, 0].neg_(), None
    bad = info != 0
    ridge = 1e-10 * hess[bad].diagonal(dim1=1, dim2=2).abs().amax(dim=1)
    eye = _eye(hess.shape[1], hess.dtype)
    chol_r, info_r = torch.linalg.cholesky_ex(hess[bad] + ridge[:, None, None] * eye)
    chol = chol.clone()
    chol[bad] = chol_r
    ok = torch.ones_like(bad)
    ok[bad] = info_r == 0
    safe = torch.where(ok[:, None, None], chol, eye)
    dq = -torch.cholesky_solve(grad[:, :, None], safe)[:, :, 0]
    return torch.where(ok[:, None], dq, torch.zeros((), dtype=dq.dtype)), ok


def newton_direction(hess: torch.Tensor, grad: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Solve ``hess dq = -grad`` per island by Cholesky (with a 1e-10 relative ridge where needed).

    Returns dq (n_isl, N) and a (n_isl,) bool: True where the matrix was positive definite."""
    dq, ok = cholesky_direction(hess, grad)
    return dq, torch.ones(dq.shape[0], dtype=torch.bool) if ok is None else ok


def minimise(
    objective: Objective,
    q0: torch.Tensor,
    scale: torch.Tensor,
    trust_m: torch.Tensor,
    settings: NewtonSettings,
    on_gradient: Callable[[torch.Tensor], None] | None = None,
    on_indefinite: Callable[[torch.Tensor], None] | None = None,
) -> NewtonResult:
    """Minimise every island from ``q0`` (n_isl, N).

    Args:
        scale: (n_isl,) motion scale of the step; an island converges when its update's mass norm falls
            below ``settings.tolerance * scale``.
        trust_m: (n_isl,) the largest contact-sphere displacement one update may make, m.
        on_gradient: called with every gradient (checks finiteness; may raise).
        on_indefinite: called with the (n_isl,) mask of islands whose matrix stays indefinite after the
            strict projection (should raise).
    """
    counters = dict.fromkeys(
        ("evaluations", "evaluations_with_derivatives", "strict_projections", "line_search_failures",
         "line_search_extended", "trust_limited_steps", "unconverged_solves"), 0)  # fmt: skip
    n_isl = q0.shape[0]
    q = q0.clone()
    threshold = settings.tolerance * scale  # an update of mass norm below this has converged
    active = torch.ones(n_isl, dtype=torch.bool)
    all_active = True  # every island still active (known on the host: masks can be skipped)
    converged = torch.zeros(n_isl, dtype=torch.bool)
    iterations = torch.zeros(n_isl, dtype=torch.int64)
    iterations_all_active = 0  # taken while every island was active (added to ``iterations`` at the end)
    trust_limited = torch.zeros((), dtype=torch.int64)  # summed as a tensor, read once at the end
    carried: Evaluation | None = None  # derivatives at the accepted point, from the line search's first trial
    for _ in range(settings.iterations):
        if carried is None:
            ev = objective.evaluate(q, True)
            counters["evaluations_with_derivatives"] += 1
        else:
            ev, carried = carried, None
        if on_gradient is not None:
            on_gradient(ev.grad)
        dq, ok = cholesky_direction(ev.hess, ev.grad)
        failed = None if ok is None else active & ~ok
        if failed is not None and bool(failed.any()):  # a near-SPD elastic block made the matrix indefinite
            counters["strict_projections"] += int(failed.sum())  # project every block of those islands
            strict = objective.evaluate(q, True, strict_islands=failed)
            counters["evaluations_with_derivatives"] += 1
            dq_s, ok_s = newton_direction(strict.hess[failed], strict.grad[failed])
            if not bool(ok_s.all()):
                still = failed.clone()
                still[failed] = ~ok_s
                if on_indefinite is not None:
                    on_indefinite(still)
                raise RuntimeError("Newton matrix not positive definite")
            dq[failed] = dq_s
            ev.value[failed] = strict.value[failed]
            ev.grad[failed] = strict.grad[failed]
        if all_active:
            iterations_all_active += 1
        else:
            iterations += active
            dq = dq * active[:, None]
        motion, mass = objective.update_norms(dq)  # mass: |dq|_M, also the step norm's factor below
        alpha = torch.clamp(trust_m / motion.clamp(min=1e-300), max=1.0)
        whole = alpha >= 1.0
        trust_limited += (alpha < 1.0 if all_active else active & (alpha < 1.0)).sum()
        # an update already below the tolerance is taken whole, without a search: the island has converged
        small = whole & (mass <= threshold) if all_active else active & whole & (mass <= threshold)
        accepted = small if all_active else ~active | small  # islands done, or converging now, need no search
        all_accepted = bool(accepted.all())
        searches = 0 if all_accepted else settings.line_search_steps + EXTRA_HALVINGS
        slope = (ev.grad * dq).sum(1) if searches else None  # directional derivative, for the Armijo test
        trial_q = None  # the point of the latest trial
        for trial_index in range(searches):
            # islands accepted earlier sit at their accepted alpha (their values are not looked at); the first
            # trial is evaluated with derivatives: when every island takes it, the next iteration starts there
            first = trial_index == 0
            trial_q = q + alpha[:, None] * dq
            trial_ev = objective.evaluate(trial_q, first)
            trial = trial_ev.value
            counters["evaluations_with_derivatives" if first else "evaluations"] += 1
            if trial_index < settings.line_search_steps:
                ok_t = trial <= ev.value + ARMIJO_C * alpha * slope + 1e-14 * ev.value.abs()
            else:  # Armijo failed within the preset's budget: any decrease beats standing still
                ok_t = trial < ev.value
            newly = ok_t & ~accepted
            if trial_index >= settings.line_search_steps:
                counters["line_search_extended"] += int(newly.sum())
            accepted = accepted | newly
            if bool(accepted.all()):
                all_accepted = True
                if first:
                    carried = trial_ev
                break
            alpha = torch.where(accepted, alpha, 0.5 * alpha)
        if all_accepted:  # no island failed its search: the moving islands are the active ones
            failed_ls = None
            moving = active
            if trial_q is not None:  # the search stopped right after its trial at the final alpha (dq = 0 on
                q = trial_q  # inactive islands): the accepted point is that trial's point
            else:
                q = q + (alpha if all_active else alpha * moving)[:, None] * dq
        else:
            failed_ls = active & ~accepted
            counters["line_search_failures"] += int(failed_ls.sum())
            moving = active & accepted
            q = q + (alpha * moving)[:, None] * dq
        converging = (alpha * mass <= threshold) | small
        # every island moves when all are active and none failed its search
        done = converging if all_active and failed_ls is None else moving & converging
        converged |= done
        if failed_ls is not None:
            active = active & ~done & ~failed_ls
        else:
            active = ~done if all_active else active & ~done
        num_active = int(active.sum())
        if num_active == 0:
            break
        all_active = num_active == n_isl
    iterations += iterations_all_active
    counters["trust_limited_steps"] += int(trust_limited)
    counters["unconverged_solves"] += int((~converged).sum())
    return NewtonResult(q, iterations, converged, counters)
