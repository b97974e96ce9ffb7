"""Learned skinning basis (Simplicits-style) for the reduced simulator.

A basis maps rest positions x0 (m) to H skinning weights w_h(x0) and their
gradients grad w_h(x0) (1/m). Column 0 is the constant handle (w = 1,
grad w = 0); columns 1..H-1 come from a small ELU MLP evaluated on the rest
points rescaled to the bounding cube [-1, 1]^3 (same scale on every axis), or,
when that is better (see "Guard" below), from a linear-blend baseline. The
reduced kinematics that use it:

    x(x0) = x0 + sum_h w_h(x0) T_h [x0; 1],
    F(x0) = I + sum_h ( w_h(x0) T_h[:, :3] + T_h [x0; 1] grad w_h(x0)^T ).

Objective. Simplicits trains on the stable neo-Hookean energy of a few random
handle perturbations T_h ~ s N(0, 1) per step plus an orthogonality penalty.
That Monte-Carlo loss is noisy (10 draws per step) and measured here it barely
learned (bench/results/skinning.json, format v3). For small perturbations its
expectation has a closed form: with Hooke's law (the small-strain limit of the
stable neo-Hookean energy), independent entries of T_h and columns made
orthonormal under <a, b> = mean(a b),

    E[energy density] / s^2 = (2 mu + lam / 2) sum_{h >= 1} Q_hh,
    Q_hk = mean_x( 3 w_h w_k + w_h (y . g_k) + (y . g_h) w_k + (1 + |y|^2) g_h . g_k ),

with y = (x0 - centre) / L and g = L grad w (L the largest bounding-box side,
E = 1). The Poisson ratio only scales it, so the best subspace of this
objective does not depend on nu or E. ``expected_perturbation_energy`` is this
formula; ``perturbation_energy`` is the Monte-Carlo measure used by the bench.

Training (``_optimise``), all in the normalised frame:

1. Ritz output layer: for any hidden layers, the output layer that minimises the
   objective is a generalised eigenproblem (Q of the last hidden features
   against their Gram matrix, constant projected out); its H - 1 lowest
   eigenvectors are the output weights. Solved in float64 at initialisation,
   at every checkpoint and at the end.
2. Hidden layers: Adam (float32, one CPU thread) on the exact objective of a
   random batch of points, with the output layer re-solved on that batch every
   step (variable projection), so the gradient moves only the feature space.
   The learning rate decays exponentially to ``final_learning_rate`` over
   ``decay_steps`` and then stays there, independent of ``steps``, so a shorter
   run is a prefix of a longer one.
3. Held-out points: a seeded random ``validation_fraction`` of the points (20 %) is
   held out of training. Checkpoints every ``checkpoint_every`` steps fit the Ritz
   output layer on the training points and score the basis by its expected energy on
   the held-out points; the best checkpoint (the initial one included) is kept, and
   training stops after ``patience`` checkpoints without a better score. The kept
   features' output layer is then fitted again on all points. Scoring on the points
   trained on let a long run overfit them: an MLP can find a mode that is soft at
   ~1,000 particles and stiff between them (a teddy bear at H = 2: training energy
   16.7 -> 3.4 over 500 steps, energy on fresh points 17 -> 160). The simulator
   integrates on a subset of the particles and renders and collides at surface points
   between them, so the held-out score is the one that matters; it is lowest after
   25-100 steps on most shapes, which the early stop turns into 3-5x shorter training.
   With no points held out (``validation_fraction`` 0, or too few points) the score is
   the energy on all points, the training points, and a run never stops early but
   for ``patience``.

Guard: the shipped basis is compared, by ``expected_perturbation_energy`` on the
training points, with a linear-blend baseline (``blend_basis``: H normalised
Gaussian RBF weights at k-means centres) and the better one is kept; which one
is logged and stored in ``SkinningBasis.metadata`` (also in the cache file).

Every shipped basis has W^T W / n = I on the training points (column 0 = 1) to
round-off: the exact orthonormalisation is folded into the output layer (MLP)
or stored as a mix matrix (blend).

Trained bases are cached on disk as ``<cache_dir>/<sha256>.pt``. The default
cache directory is ``~/.cache/newtphys/skinning``; if the environment variable
``NEWTPHYS_CACHE_DIR`` is set, it is ``$NEWTPHYS_CACHE_DIR/skinning``. An
explicit ``cache_dir`` argument wins over both.

Determinism: all random draws (initial MLP weights, point subsets, blend
centres) come from ``torch.Generator`` objects seeded by ``seed``; on CPU with
the same torch build the weights are bit-identical (training runs on one
thread).
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import json
import logging
import math
import os
import tempfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import torch

from data_gen.sim.material import energy_density, lame_parameters
from data_gen.sim.threads import torch_threads

logger = logging.getLogger(__name__)

_CACHE_FORMAT = "newtphys-skinning-v5"
_DTYPE = torch.float64
_TRAIN_DTYPE = torch.float32
_RITZ_RTOL_F64 = 1e-12  # feature-Gram eigenvalues below this x the largest are treated as null (float64)
_RITZ_RTOL_F32 = 1e-6  # the same for float32 features inside a training step
_BLEND_LLOYD_ITERATIONS = 5  # k-means steps after farthest-point seeding of the blend centres


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class SkinningTrainingSettings:
    """Hyper-parameters of skinning training (all dimensionless).

    Attributes:
        steps: the most Adam steps on the hidden layers (0 is not allowed; 1 is nearly
            the Ritz fit of the random initial features); training stops earlier when the
            held-out energy stops improving (``patience``).
        learning_rate: initial Adam learning rate.
        final_learning_rate: learning rate reached at ``decay_steps`` (exponential
            decay), kept after that.
        decay_steps: length of the decay, in steps; independent of ``steps``.
        hidden_layers: number of hidden Linear+ELU layers after the input layer.
        width: hidden width; at least H - 1 for a learned basis (else the blend
            baseline is shipped).
        points_per_step: rest points sampled (without replacement) per step.
        checkpoint_every: steps between checkpoints (the best checkpoint is kept).
        validation_fraction: share of the points held out of training, in [0, 0.5]; a
            checkpoint is scored by the expected perturbation energy on them (its output
            layer fitted on the training points), so the basis kept is the best one away
            from the points it was fitted on. 0 (or fewer than ``max(8, 2 H)`` held-out
            points) scores on all points, the training points.
        patience: checkpoints without a better held-out score after which training stops.

    Defaults chosen on a 0.4 x 0.1 x 0.1 m beam, 2000 points, H = 6, one thread
    (expected perturbation energy, E = 1; bench/results/skinning.json): Ritz fit of the
    random init 530; 500 steps at lr 1e-3 -> 496 (7-8 s), at 3e-3 -> 495, at 1e-2 -> 502;
    1024 points per step -> 492 (11 s). At H = 12 the same settings give 1848 (init 1965).
    Validation and early stopping: on 12 ``pile`` draws (46 deformable objects, ~1,000
    particles each, scored on ~8,000 fresh points of the same shape) the energy on fresh
    points was lowest after 0-100 steps for 39 of them; the 500-step basis that training
    energy selected was 0-11 % above that best (median 2 %) on 45, and on a teddy bear at
    H = 2 10.4x above it: its training energy fell 16.7 -> 3.4 while the fresh points' rose
    17 -> 160 (a mode soft only at its particles).
    """

    steps: int = 500
    learning_rate: float = 1e-3
    final_learning_rate: float = 1e-4
    decay_steps: int = 500
    hidden_layers: int = 4
    width: int = 64
    points_per_step: int = 512
    checkpoint_every: int = 25
    validation_fraction: float = 0.2
    patience: int = 4

    def __post_init__(self) -> None:
        for name in ("steps", "decay_steps", "hidden_layers", "width", "points_per_step", "checkpoint_every",
                     "patience"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}={value!r} is out of range; allowed: integer >= 1")
        for name in ("learning_rate", "final_learning_rate"):
            value = getattr(self, name)
            if not (value > 0.0) or math.isinf(value):
                raise ValueError(f"{name}={value!r} is out of range; allowed: finite > 0")
        if not (0.0 <= self.validation_fraction <= 0.5):
            raise ValueError(f"validation_fraction={self.validation_fraction!r} is out of range; allowed: [0, 0.5]")

    def learning_rate_at(self, step: int) -> float:
        """Learning rate of (0-based) ``step``: lr0 (lr_end / lr0)^(min(step, decay_steps) / decay_steps)."""
        frac = min(step, self.decay_steps) / self.decay_steps
        return self.learning_rate * (self.final_learning_rate / self.learning_rate) ** frac


# --------------------------------------------------------------------------- MLP


class SkinningMLP(torch.nn.Module):
    """Linear(3, width)+ELU, hidden_layers x [Linear(width, width)+ELU], Linear(width, outputs).

    ``forward_with_jacobian`` propagates the input Jacobian alongside the values
    (forward-mode chain rule), so weight gradients come without a per-handle
    backward pass and stay differentiable w.r.t. the MLP parameters.
    """

    def __init__(self, outputs: int, hidden_layers: int, width: int, dtype: torch.dtype = _DTYPE) -> None:
        super().__init__()
        sizes = [3] + [width] * (hidden_layers + 1) + [outputs]
        self.layers = torch.nn.ModuleList(
            torch.nn.Linear(a, b, dtype=dtype) for a, b in zip(sizes[:-1], sizes[1:])
        )

    def reset_parameters(self, generator: torch.Generator) -> None:
        """Uniform(-1/sqrt(fan_in), 1/sqrt(fan_in)) init of weights and biases from ``generator``."""
        with torch.no_grad():
            for layer in self.layers:
                bound = 1.0 / math.sqrt(layer.in_features)
                layer.weight.copy_((torch.rand(layer.weight.shape, generator=generator, dtype=_DTYPE) * 2 - 1) * bound)
                layer.bias.copy_((torch.rand(layer.bias.shape, generator=generator, dtype=_DTYPE) * 2 - 1) * bound)

    def forward(self, u: torch.Tensor) -> torch.Tensor:
        h = u
        for layer in self.layers[:-1]:
            h = torch.nn.functional.elu(layer(h))
        return self.layers[-1](h)

    def features_with_jacobian(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Last hidden activations (n, width) and their Jacobian d h / d u, shape (n, width, 3)."""
        first = self.layers[0]
        a = first(u)
        # tangents stored as (3, n, features): each layer is then one large matmul
        da = first.weight.T[:, None, :].expand(3, u.shape[0], first.out_features)
        for layer in self.layers[1:-1]:
            h, dh = _elu_with_tangent(a, da)
            a = layer(h)
            da = dh @ layer.weight.T
        h, dh = _elu_with_tangent(a, da)
        return h, dh.permute(1, 2, 0)

    def forward_with_jacobian(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Values (n, outputs) and Jacobian d out / d u, shape (n, outputs, 3)."""
        h, dh = self.features_with_jacobian(u)
        last = self.layers[-1]
        return last(h), torch.einsum("nkj,ok->noj", dh, last.weight)


def _elu_with_tangent(a: torch.Tensor, da: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """ELU of pre-activations a (n, f) and the tangents da (3, n, f) pushed through it."""
    slope = torch.where(a > 0, torch.ones_like(a), torch.exp(torch.clamp(a, max=0.0)))
    return torch.nn.functional.elu(a), slope[None] * da


# --------------------------------------------------------------------------- basis


@dataclass(frozen=True)
class BlendWeights:
    """Linear-blend weights: H normalised Gaussian RBFs, then an H x H column mix.

    w_raw_h(x) = exp(-|x - c_h|^2 / (2 sigma^2)) / sum_k exp(-|x - c_k|^2 / (2 sigma^2));
    the basis columns are [1, w_raw_1 .. w_raw_{H-1}] @ mix (the raw weights sum to 1,
    so the constant and H - 1 of them span the same space as all H).

    Attributes:
        centres_m: (H, 3) RBF centres, m.
        width_m: sigma, m (> 0).
        mix: (H, H) upper-triangular mix with mix[0, 0] = 1 (makes the columns orthonormal).
    """

    centres_m: torch.Tensor
    width_m: float
    mix: torch.Tensor

    def on(self, device: torch.device) -> BlendWeights:
        """These weights with their tensors on ``device``."""
        if self.centres_m.device == device:
            return self
        return BlendWeights(self.centres_m.to(device), self.width_m, self.mix.to(device))

    def evaluate(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Weights (n, H) and gradients (n, H, 3), 1/m, at points x (n, 3) in m (on the weights' device)."""
        diff = x[:, None, :] - self.centres_m[None]  # (n, H, 3)
        d2 = (diff**2).sum(-1)
        # shift by the nearest centre's distance: the ratios are unchanged and nothing underflows
        logits = -(d2 - d2.min(dim=1, keepdim=True).values) / (2.0 * self.width_m**2)
        w = torch.softmax(logits, dim=1)
        dlog = -diff / self.width_m**2  # d log g_h / dx
        dw = w[:, :, None] * (dlog - torch.einsum("nh,nhk->nk", w, dlog)[:, None, :])
        ones, zeros = torch.ones_like(w[:, :1]), torch.zeros_like(dw[:, :1])
        raw_w, raw_g = torch.cat((ones, w[:, 1:]), 1), torch.cat((zeros, dw[:, 1:]), 1)
        return raw_w @ self.mix, torch.einsum("nhk,hm->nmk", raw_g, self.mix)


EVALUATE_CHUNK_ROWS = 1024
"""Points per chunk of :meth:`SkinningBasis.evaluate` on the CPU (10^5 points of a 5 x 64 MLP: 2.5 s in one
piece, 1.0 s in chunks of 512-2,048 rows, the same bytes; one CPU thread)."""


class SkinningBasis:
    """Skinning weights over an object's rest shape.

    Args:
        num_handles: H >= 1, including the constant handle 0.
        mlp: MLP with H - 1 outputs, or None for the rigid (H = 1) or blend basis.
        center_m: (3,) centre of the rest bounding box, m.
        half_extent_m: (3,) MLP input half-widths, m (> 0): input = (x0 - center) / half_extent.
        blend: linear-blend weights with H centres instead of an MLP (what the training
            guard ships when it beats the learned basis).
        metadata: how the basis was made, e.g. {"source": "learned" | "blend" | "rigid",
            "energy_learned": ..., "energy_blend": ...} (expected perturbation energies, E = 1).
    """

    def __init__(
        self,
        num_handles: int,
        mlp: SkinningMLP | None = None,
        center_m: torch.Tensor | None = None,
        half_extent_m: torch.Tensor | None = None,
        *,
        blend: BlendWeights | None = None,
        metadata: dict[str, str | float | int] | None = None,
    ) -> None:
        if num_handles < 1:
            raise ValueError(f"num_handles={num_handles!r} is out of range; allowed: >= 1")
        if mlp is not None and blend is not None:
            raise ValueError("give either mlp or blend, not both")
        has_weights = mlp is not None or blend is not None
        if has_weights != (num_handles > 1):
            raise ValueError(
                f"num_handles={num_handles} needs an MLP or blend weights iff num_handles > 1 "
                f"(got mlp={mlp is not None}, blend={blend is not None})"
            )
        if mlp is not None and (center_m is None or half_extent_m is None):
            raise ValueError("center_m and half_extent_m are required with an MLP")
        if blend is not None and tuple(blend.centres_m.shape) != (num_handles, 3):
            raise ValueError(f"blend.centres_m must have shape ({num_handles}, 3); got {tuple(blend.centres_m.shape)}")
        self.num_handles = num_handles
        self.mlp = mlp
        self.blend = blend
        self.center_m = None if center_m is None else center_m.to(_DTYPE)
        self.half_extent_m = None if half_extent_m is None else half_extent_m.to(_DTYPE)
        default_source = "rigid" if num_handles == 1 else ("blend" if blend is not None else "learned")
        self.metadata: dict[str, str | float | int] = {"source": default_source, **(metadata or {})}
        self._device_copies: dict[str, tuple[SkinningMLP, torch.Tensor, torch.Tensor]] = {}

    @property
    def is_rigid(self) -> bool:
        """True for the single affine handle (no MLP, no blend)."""
        return self.num_handles == 1

    def evaluate(self, points_rest: torch.Tensor, num_threads: int = 1) -> tuple[torch.Tensor, torch.Tensor]:
        """Weights (n, H) and gradients (n, H, 3) in 1/m, float64, at rest points (n, 3) in m, on the points'
        device.

        Column 0 is the constant handle: weight exactly 1, gradient exactly 0. On the CPU, more than
        ``EVALUATE_CHUNK_ROWS`` points are evaluated in chunks of that many rows (an MLP's (3, n, width) tangents
        of 10^5 points do not fit any cache: chunks are ~2.5x faster), each on one torch thread, ``num_threads``
        chunks at a time: the result does not depend on ``num_threads`` nor on the caller's torch threads.
        """
        x = _check_points(points_rest, "points_rest", keep_device=True)
        if x.device.type != "cpu" or x.shape[0] <= EVALUATE_CHUNK_ROWS:
            return self._evaluate(x)
        if num_threads < 1:
            raise ValueError(f"num_threads={num_threads!r} is out of range; allowed: >= 1")
        chunks = torch.split(x, EVALUATE_CHUNK_ROWS)
        with torch_threads(1):
            if num_threads == 1:
                parts = [self._evaluate(c) for c in chunks]
            else:
                with ThreadPoolExecutor(min(num_threads, len(chunks)), initializer=torch.set_num_threads,
                                        initargs=(1,)) as pool:  # fmt: skip
                    parts = list(pool.map(self._evaluate, chunks))  # (OpenMP's thread count is per thread)
        return torch.cat([w for w, _ in parts]), torch.cat([g for _, g in parts])

    def _evaluate(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """:meth:`evaluate` of checked points, in one piece."""
        n, device = x.shape[0], x.device
        ones = torch.ones(n, 1, dtype=_DTYPE, device=device)
        zeros = torch.zeros(n, 1, 3, dtype=_DTYPE, device=device)
        if self.blend is not None:
            w, g = self.blend.on(device).evaluate(x)
            return torch.cat((ones, w[:, 1:]), dim=1), torch.cat((zeros, g[:, 1:]), dim=1)
        if self.mlp is None:
            return ones, zeros
        with torch.no_grad():
            mlp, center, half = self._mlp_on(device)
            u = (x - center) / half
            w, dw_du = mlp.forward_with_jacobian(u)
            dw_dx = dw_du / half
        return torch.cat((ones, w), dim=1), torch.cat((zeros, dw_dx), dim=1)

    def _mlp_on(self, device: torch.device) -> tuple[SkinningMLP, torch.Tensor, torch.Tensor]:
        """The MLP and its input frame on ``device`` (the basis itself stays on the CPU, where it is trained and
        cached; a copy per device is made at the first evaluation there, e.g. a render on the GPU)."""
        assert self.mlp is not None and self.center_m is not None and self.half_extent_m is not None
        if device.type == "cpu":
            return self.mlp, self.center_m, self.half_extent_m
        key = str(device)
        if key not in self._device_copies:
            self._device_copies[key] = (copy.deepcopy(self.mlp).to(device), self.center_m.to(device),
                                        self.half_extent_m.to(device))  # fmt: skip
        return self._device_copies[key]

    def to_payload(self) -> dict:
        """Plain-data form (tensors, ints, floats, str) for ``torch.save`` / ``torch.load(weights_only=True)``."""
        payload: dict = {"num_handles": self.num_handles, "metadata": dict(self.metadata)}
        if self.blend is not None:
            payload["blend"] = {
                "centres_m": self.blend.centres_m.clone(),
                "width_m": float(self.blend.width_m),
                "mix": self.blend.mix.clone(),
            }
        elif self.mlp is not None:
            payload.update(
                hidden_layers=len(self.mlp.layers) - 2,
                width=self.mlp.layers[0].out_features,
                center_m=self.center_m.clone(),
                half_extent_m=self.half_extent_m.clone(),
                state_dict={k: v.detach().clone() for k, v in self.mlp.state_dict().items()},
            )
        return payload

    @classmethod
    def from_payload(cls, payload: dict) -> SkinningBasis:
        """Inverse of ``to_payload``; raises KeyError/RuntimeError on malformed payloads."""
        num_handles = int(payload["num_handles"])
        metadata = dict(payload.get("metadata", {}))
        if num_handles == 1:
            return rigid_basis()
        if "blend" in payload:
            b = payload["blend"]
            blend = BlendWeights(b["centres_m"].to(_DTYPE), float(b["width_m"]), b["mix"].to(_DTYPE))
            return cls(num_handles, blend=blend, metadata=metadata)
        mlp = SkinningMLP(num_handles - 1, int(payload["hidden_layers"]), int(payload["width"]))
        mlp.load_state_dict(payload["state_dict"])
        mlp.requires_grad_(False)
        return cls(num_handles, mlp, payload["center_m"], payload["half_extent_m"], metadata=metadata)


def rigid_basis() -> SkinningBasis:
    """The single constant handle: a pure affine body (H = 1), no training."""
    return SkinningBasis(1)


# --------------------------------------------------------------------------- handle count


def handles_for_stiffness(
    young_modulus_pa: float,
    density_kg_m3: float = 1000.0,
    size_m: float = 0.2,
    gravity_m_s2: float = 20.0,
    rigid_strain: float = 1e-4,
    handles_per_decade: float = 2.0,
    max_handles: int = 12,
) -> int:
    """Number of skinning handles an object needs, from its expected static strain.

    The strain scale is the base strain of a column of height ``size_m`` under
    its own weight, eps = rho g L / E (dimensionless), at the largest gravity of
    the data (20 m/s^2 on the OOD split). Below ``rigid_strain`` (default 1e-4:
    a 0.2 m object then deforms by < 20 um, far below a pixel, and its
    vibration modes, at omega ~ (pi / 2L) sqrt(E / rho) > 1e3 rad/s, are
    damped by implicit Euler within one 0.03 s step) one affine handle is
    enough. Above it, ``handles_per_decade`` handles are added per decade of
    strain, capped at ``max_handles``:

        H = min(max_handles, 1 + ceil(handles_per_decade * log10(eps / rigid_strain))).

    With the defaults: E >= 4e7 Pa -> 1, E = 1e6 Pa (rubber) -> 5,
    E = 1e4 Pa (jelly) -> 9, E = 1e3 Pa -> 11, E <= 1e2 Pa -> 12 (the cap).
    """
    _positive("young_modulus_pa", young_modulus_pa)
    _positive("density_kg_m3", density_kg_m3)
    _positive("size_m", size_m)
    _positive("gravity_m_s2", gravity_m_s2)
    _positive("rigid_strain", rigid_strain)
    _positive("handles_per_decade", handles_per_decade)
    if not isinstance(max_handles, int) or max_handles < 1:
        raise ValueError(f"max_handles={max_handles!r} is out of range; allowed: integer >= 1")
    strain = density_kg_m3 * gravity_m_s2 * size_m / young_modulus_pa
    if strain <= rigid_strain:
        return 1
    extra = math.ceil(handles_per_decade * math.log10(strain / rigid_strain) - 1e-12)
    return int(min(max_handles, 1 + max(extra, 1)))


# --------------------------------------------------------------------------- training


def train_skinning_basis(
    points_rest: torch.Tensor,
    num_handles: int,
    poisson_ratio: float,
    settings: SkinningTrainingSettings | None = None,
    seed: int = 0,
    cache_dir: str | os.PathLike | None = None,
) -> SkinningBasis:
    """Train (or load from cache) a skinning basis with ``num_handles`` handles.

    Args:
        points_rest: (n, 3) rest positions, m, n >= 4, non-degenerate bounding box.
        num_handles: H in [1, 64]; H = 1 returns ``rigid_basis()`` without training.
        poisson_ratio: nu in [0, 0.5); the energy uses E = 1 (the subspace is E-independent).
        settings: training hyper-parameters (defaults if None).
        seed: seed of every random draw of the training.
        cache_dir: cache directory; see the module docstring for the default.
    """
    settings = SkinningTrainingSettings() if settings is None else settings
    if not isinstance(num_handles, int) or not (1 <= num_handles <= 64):
        raise ValueError(f"num_handles={num_handles!r} is out of range; allowed: integer in [1, 64]")
    lame_parameters(1.0, poisson_ratio)  # validates poisson_ratio
    x = _check_points(points_rest, "points_rest")
    if x.shape[0] < max(4, num_handles):
        raise ValueError(f"points_rest has {x.shape[0]} points; allowed: >= max(4, num_handles) = {max(4, num_handles)}")
    if num_handles == 1:
        return rigid_basis()

    key = skinning_cache_key(x, num_handles, poisson_ratio, settings, seed)
    path = _cache_directory(cache_dir) / f"{key}.pt"
    cached = _load_cached(path, key)
    if cached is not None:
        logger.info("skinning cache hit: %s (H=%d, %s basis)", path, num_handles, cached.metadata.get("source"))
        return cached
    logger.info("skinning cache miss: training H=%d on %d points (%s)", num_handles, x.shape[0], path)
    basis = _optimise(x, num_handles, poisson_ratio, settings, seed)
    _save_cached(path, key, basis)
    return basis


def skinning_cache_key(
    points_rest: torch.Tensor, num_handles: int, poisson_ratio: float, settings: SkinningTrainingSettings, seed: int
) -> str:
    """SHA-256 hex digest of everything that determines a trained basis."""
    x = points_rest.detach().to(device="cpu", dtype=_DTYPE).contiguous()
    meta = {
        "format": _CACHE_FORMAT,
        "shape": list(x.shape),
        "num_handles": int(num_handles),
        "poisson_ratio": float(poisson_ratio).hex(),
        "settings": dataclasses.asdict(settings),
        "seed": int(seed),
        "torch": torch.__version__,
    }
    digest = hashlib.sha256(json.dumps(meta, sort_keys=True).encode())
    digest.update(x.numpy().tobytes())
    return digest.hexdigest()


def normalised_frame(points_rest: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, float]:
    """Bounding-box centre (3,) m, MLP input half-widths (3,) m and largest side L (m) of rest points.

    The MLP input is (x - centre) / half-width with the same half-width L / 2 on every
    axis (the bounding cube, not the box): per-axis rescaling would stretch thin axes,
    so the initial MLP functions would vary fastest across the thinnest dimension, the
    stiffest direction. Measured on a 0.4 x 0.1 x 0.1 m beam, 100 steps: perturbation
    energy 27.0 -> 15.8 (H = 2), 440 -> 299 (H = 4), 722 -> 653 (H = 6).
    """
    lo = points_rest.min(dim=0).values
    hi = points_rest.max(dim=0).values
    size = hi - lo
    longest = float(size.max())
    if not longest > 0.0:
        raise ValueError("points_rest spans zero volume (all points coincide); allowed: a non-degenerate point cloud")
    return 0.5 * (lo + hi), torch.full_like(size, 0.5 * longest), longest


def deformation_gradients(
    weights: torch.Tensor, grads: torch.Tensor, points: torch.Tensor, transforms: torch.Tensor
) -> torch.Tensor:
    """F for P sets of handle transforms, shape (P, n, 3, 3).

    Args:
        weights: (n, H); grads: (n, H, 3) in 1/[length]; points: (n, 3) in [length];
        transforms: (P, H, 3, 4) delta affine transforms T_h.
    """
    xh = torch.cat((points, torch.ones_like(points[:, :1])), dim=1)  # (n, 4)
    linear = torch.einsum("nh,phij->pnij", weights, transforms[..., :3])
    moved = torch.einsum("phic,nc->pnhi", transforms, xh)  # T_h [x; 1]
    outer = torch.einsum("pnhi,nhj->pnij", moved, grads)
    return torch.eye(3, dtype=weights.dtype) + linear + outer


def perturbation_energy(
    weights: torch.Tensor,
    grads: torch.Tensor,
    points: torch.Tensor,
    poisson_ratio: float,
    num_perturbations: int = 64,
    scale: float = 0.01,
    seed: int = 0,
) -> float:
    """Elastic energy per unit perturbation of a skinning subspace (dimensionless, E = 1).

    Quality measure of a basis that does not depend on how its columns are
    scaled or mixed: the columns are first made orthonormal under
    <a, b> = mean(a b) (column 0, the constant handle, kept), lengths are
    normalised by the largest bounding-box side, then the mean stable
    neo-Hookean energy density over ``num_perturbations`` random perturbations
    of the non-constant handles, T ~ scale N(0, 1), is divided by scale^2.
    Lower is better (a smoother, lower-frequency subspace).

    Args:
        weights (n, H), grads (n, H, 3) in 1/m, points (n, 3) in m, H >= 2.
    """
    y, longest, mix = _normalised_orthonormal_mix(weights, points)
    w_orth = weights @ mix
    g_orth = torch.einsum("nhk,hm->nmk", grads * longest, mix)
    gen = torch.Generator().manual_seed(seed)
    t = scale * torch.randn(num_perturbations, weights.shape[1], 3, 4, generator=gen, dtype=_DTYPE)
    t[:, 0] = 0.0
    F = deformation_gradients(w_orth, g_orth, y, t).reshape(-1, 3, 3)
    mu, lam = lame_parameters(1.0, poisson_ratio)
    return float(energy_density(F, mu, lam).mean()) / scale**2


def _normalised_orthonormal_mix(
    weights: torch.Tensor, points: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Shared set-up of the two energy measures: points in the normalised frame y (n, 3) (longest side
    = 1), the longest side (m), and the (H, H) mix that makes the columns orthonormal (column 0 kept)."""
    if weights.shape[1] < 2:
        raise ValueError(f"weights has {weights.shape[1]} columns; allowed: >= 2 (constant + learned)")
    center, _, longest = normalised_frame(points)
    mix = _orthonormalising_mix(weights.T @ weights / weights.shape[0], ridge=0.0)
    return (points - center) / longest, longest, mix


def expected_perturbation_energy(
    weights: torch.Tensor, grads: torch.Tensor, points: torch.Tensor, poisson_ratio: float
) -> float:
    """Closed-form expectation of ``perturbation_energy`` in the small-perturbation limit (E = 1).

    (2 mu + lam / 2) trace(Q) over the orthonormalised non-constant columns, with Q
    the energy form of the module docstring; deterministic, no sampling noise.

    Args:
        weights (n, H), grads (n, H, 3) in 1/m, points (n, 3) in m, H >= 2.
    """
    y, longest, mix = _normalised_orthonormal_mix(weights, points)
    return _energy_scale(poisson_ratio) * _mode_energy(weights, grads * longest, y, mix)


def blend_basis(points_rest: torch.Tensor, num_handles: int, seed: int = 0) -> SkinningBasis:
    """Linear-blend-skinning baseline: H normalised Gaussian RBF weights, columns orthonormalised.

    Centres: farthest-point seeding from a seeded random start, then
    ``_BLEND_LLOYD_ITERATIONS`` k-means steps over the points. Width sigma =
    (V / H)^(1/3) with V the bounding-box volume (each side at least 5 % of the
    longest), m. The columns are made orthonormal under mean(a b) on ``points_rest``.

    Args:
        points_rest: (n, 3) rest positions, m, n >= num_handles.
        num_handles: H in [2, n].
        seed: seed of the first centre.
    """
    x = _check_points(points_rest, "points_rest")
    n = x.shape[0]
    if not isinstance(num_handles, int) or not (2 <= num_handles <= n):
        raise ValueError(f"num_handles={num_handles!r} is out of range; allowed: integer in [2, {n}]")
    centres = _kmeans_centres(x, num_handles, seed)
    _, _, longest = normalised_frame(x)
    sides = (x.max(0).values - x.min(0).values).clamp(min=0.05 * longest)
    width = float((sides.prod() / num_handles) ** (1.0 / 3.0))
    raw = BlendWeights(centres, width, torch.eye(num_handles, dtype=_DTYPE))
    w, _ = raw.evaluate(x)
    mix = _orthonormalising_mix(w.T @ w / n, ridge=0.0)
    return SkinningBasis(num_handles, blend=BlendWeights(centres, width, mix))


def _kmeans_centres(x: torch.Tensor, k: int, seed: int) -> torch.Tensor:
    """k centres (k, 3), m: farthest-point seeding (loop over centres), then Lloyd steps."""
    gen = torch.Generator().manual_seed(int(seed))
    chosen = [int(torch.randint(x.shape[0], (1,), generator=gen))]
    dist = ((x - x[chosen[0]]) ** 2).sum(1)
    for _ in range(k - 1):
        chosen.append(int(torch.argmax(dist)))
        dist = torch.minimum(dist, ((x - x[chosen[-1]]) ** 2).sum(1))
    centres = x[chosen].clone()
    for _ in range(_BLEND_LLOYD_ITERATIONS):
        label = torch.cdist(x, centres).argmin(dim=1)
        counts = torch.bincount(label, minlength=k).to(_DTYPE)
        sums = torch.zeros_like(centres).index_add_(0, label, x)
        keep = counts > 0  # an empty cluster keeps its centre
        centres[keep] = sums[keep] / counts[keep, None]
    return centres


def _energy_scale(poisson_ratio: float) -> float:
    """2 mu + lam / 2 at E = 1: expected Hooke energy of one unit random 3x4 perturbation per |B|_F^2."""
    mu, lam = lame_parameters(1.0, poisson_ratio)
    return 2.0 * mu + 0.5 * lam


def _energy_form(w: torch.Tensor, g: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Q (K, K): mean_x of 3 w w^T + w (y.g)^T + (y.g) w^T + (1 + |y|^2) g g^T.

    w (n, K), g (n, K, 3) gradients in normalised length units, y (n, 3) normalised points.
    """
    yg = torch.einsum("nkj,nj->nk", g, y)
    r2 = 1.0 + (y**2).sum(1)
    cross = w.T @ yg
    grad_part = torch.einsum("nkj,nmj->km", g * r2[:, None, None], g)
    return (3.0 * w.T @ w + cross + cross.T + grad_part) / w.shape[0]


def _mode_energy(w: torch.Tensor, g: torch.Tensor, y: torch.Tensor, mix: torch.Tensor) -> float:
    """Sum of Q over the non-constant columns of w @ mix (orthonormalised by ``mix``), without the material scale:
    w (n, H), g (n, H, 3) in normalised length units, y (n, 3) normalised points, mix (H, H)."""
    return float(torch.trace((mix.T @ _energy_form(w, g, y) @ mix)[1:, 1:]))


def _ritz_output(
    h: torch.Tensor, dh: torch.Tensor, y: torch.Tensor, outputs: int, rtol: float
) -> tuple[torch.Tensor, torch.Tensor] | None:
    """Best output layer for features h (n, K) with gradients dh (n, K, 3) (normalised units).

    Returns (coef (K + 1, outputs), energies (outputs,)): the weights [1, h] @ coef are the
    ``outputs`` lowest modes of Q against the Gram matrix, orthogonal to the constant and
    orthonormal under mean(a b); energies are their Q values (without the material scale).
    None if the features span fewer than ``outputs`` directions beyond the constant.
    """
    n, k = h.shape
    mean = h.mean(0)
    centred = h - mean
    evals, evecs = torch.linalg.eigh(centred.T @ centred / n)
    keep = evals > rtol * evals.max().clamp(min=torch.finfo(h.dtype).tiny)
    if int(keep.sum()) < outputs:
        return None
    basis = torch.zeros(k + 1, int(keep.sum()), dtype=h.dtype)
    basis[1:] = evecs[:, keep] / evals[keep].sqrt()
    basis[0] = -(mean @ basis[1:])  # [1, h] @ basis = centred features, whitened
    w = torch.cat((torch.ones(n, 1, dtype=h.dtype), h), 1)
    g = torch.cat((torch.zeros(n, 1, 3, dtype=h.dtype), dh), 1)
    modes, vecs = torch.linalg.eigh(basis.T @ _energy_form(w, g, y) @ basis)
    return basis @ vecs[:, :outputs], modes[:outputs]


def _ritz_fit(mlp: SkinningMLP, y: torch.Tensor, input_scale: torch.Tensor) -> tuple[float, SkinningMLP] | None:
    """A float64 copy of ``mlp`` with the Ritz output layer on all points y; (sum of mode energies, copy)."""
    fitted = copy.deepcopy(mlp).to(_DTYPE).requires_grad_(False)
    with torch.no_grad():
        h, dh_du = fitted.features_with_jacobian(y * input_scale)
        out = _ritz_output(h, dh_du * input_scale, y, fitted.layers[-1].out_features, _RITZ_RTOL_F64)
        if out is None:
            return None
        coef, modes = out
        fitted.layers[-1].weight.copy_(coef[1:].T)
        fitted.layers[-1].bias.copy_(coef[0])
    return float(modes.sum()), fitted


def _optimise(
    x: torch.Tensor, num_handles: int, poisson_ratio: float, settings: SkinningTrainingSettings, seed: int
) -> SkinningBasis:
    """Ritz-initialised variable-projection Adam with best-checkpoint selection, then the blend guard.

    See the module docstring. Returns the better of the learned and the blend basis by
    ``expected_perturbation_energy`` on ``x``; the choice and both energies are in ``metadata``.
    """
    with torch_threads(1):
        center, half, longest = normalised_frame(x)
        y64 = (x - center) / longest  # uniform scale: the shape is preserved
        scale64 = longest / half  # MLP input u = y * scale in [-1, 1]^3
        learned = _train_learned(y64, scale64, num_handles, settings, seed)
        blend = blend_basis(x, num_handles, seed=seed)
        e_blend = expected_perturbation_energy(*blend.evaluate(x), x, poisson_ratio)
        if learned is None:
            logger.warning(
                "skinning H=%d: the MLP features span fewer than %d modes (width=%d); shipping the blend basis",
                num_handles, num_handles - 1, settings.width,
            )
            blend.metadata.update(energy_blend=e_blend, energy_learned=float("nan"), steps_kept=-1)
            return blend
        mlp = learned.mlp
        if learned.validation_points:  # the kept features' output layer, fitted again on every point
            refit = _ritz_fit(mlp, y64, scale64)
            mlp = mlp if refit is None else refit[1]
        n = x.shape[0]
        with torch.no_grad():
            for ridge in (1e-10, 0.0):  # the second, exact pass removes the ridge and round-off of the first
                weights = torch.cat((torch.ones(n, 1, dtype=_DTYPE), mlp(y64 * scale64)), dim=1)
                _fold_mix_into_last_layer(mlp, _orthonormalising_mix(weights.T @ weights / n, ridge))
        basis = SkinningBasis(num_handles, mlp, center, half)
        e_learned = expected_perturbation_energy(*basis.evaluate(x), x, poisson_ratio)
        shipped = basis if e_learned <= e_blend else blend
        shipped.metadata.update(
            energy_learned=e_learned, energy_blend=e_blend, steps_kept=learned.step, steps_run=learned.steps_run,
            validation_points=learned.validation_points,
        )
        if learned.validation_points:  # the kept checkpoint's score on the held-out points, E = 1
            shipped.metadata["energy_held_out"] = _energy_scale(poisson_ratio) * learned.score
        logger.info(
            "skinning H=%d: shipping the %s basis (expected perturbation energy, E=1: learned %.4g at step %d of %d "
            "run, blend %.4g)", num_handles, shipped.metadata["source"], e_learned, learned.step, learned.steps_run,
            e_blend,
        )
        return shipped


@dataclass(frozen=True)
class _TrainingOutcome:
    """What ``_train_learned`` kept: the best checkpoint (float64, its output layer fitted on the training points),
    the step it was taken at, the steps run (fewer than ``settings.steps`` after an early stop), its score (expected
    energy without the material scale, on the held-out points or, without them, on all points) and the number of
    held-out points (0: none)."""

    mlp: SkinningMLP
    step: int
    steps_run: int
    score: float
    validation_points: int


def _validation_split(
    y64: torch.Tensor, num_handles: int, fraction: float, gen: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor | None]:
    """(training points, held-out points or None): a random ``fraction`` of y64 held out, if that is at least
    max(8, 2 H) points and leaves at least max(4, H) to train on."""
    n = y64.shape[0]
    n_val = int(fraction * n)
    if n_val < max(8, 2 * num_handles) or n - n_val < max(4, num_handles):
        return y64, None
    order = torch.randperm(n, generator=gen)
    return y64[order[n_val:]], y64[order[:n_val]]


def _held_out_energy(mlp: SkinningMLP, y_val: torch.Tensor, input_scale: torch.Tensor) -> float:
    """Expected perturbation energy (E = 1, without the material scale) of ``mlp``'s basis on held-out points
    y_val (normalised frame), its columns made orthonormal there; inf when they are degenerate there."""
    n = y_val.shape[0]
    with torch.no_grad():
        w, dw_du = mlp.forward_with_jacobian(y_val * input_scale)
    w = torch.cat((torch.ones(n, 1, dtype=w.dtype), w), 1)
    g = torch.cat((torch.zeros(n, 1, 3, dtype=w.dtype), dw_du * input_scale), 1)
    try:
        mix = _orthonormalising_mix(w.T @ w / n, ridge=0.0)
    except RuntimeError:
        return math.inf
    value = _mode_energy(w, g, y_val, mix)
    return value if math.isfinite(value) else math.inf


def _train_learned(
    y64: torch.Tensor, scale64: torch.Tensor, num_handles: int, settings: SkinningTrainingSettings, seed: int
) -> _TrainingOutcome | None:
    """Train the hidden layers on the points not held out; keep the checkpoint with the best held-out score.

    A checkpoint's output layer is the Ritz fit on the training points; its score is the expected energy on the
    held-out points (``settings.validation_fraction``; all points when none are held out). Training stops after
    ``settings.patience`` checkpoints without a better score. None if the features cannot span H - 1 modes
    (width too small or degenerate points).
    """
    gen = torch.Generator().manual_seed(int(seed))
    outputs = num_handles - 1
    mlp = SkinningMLP(outputs, settings.hidden_layers, settings.width, dtype=_TRAIN_DTYPE)
    mlp.reset_parameters(gen)
    y_fit64, y_val64 = _validation_split(y64, num_handles, settings.validation_fraction, gen)

    def checkpoint() -> tuple[float, SkinningMLP] | None:
        fit = _ritz_fit(mlp, y_fit64, scale64)
        if fit is None or y_val64 is None:
            return fit
        return _held_out_energy(fit[1], y_val64, scale64), fit[1]

    best = checkpoint()
    if best is None:
        return None
    best_score, best_mlp = best
    best_step, since_best, done = 0, 0, 0
    y_all, scale = y_fit64.to(_TRAIN_DTYPE), scale64.to(_TRAIN_DTYPE)
    hidden = [p for layer in mlp.layers[:-1] for p in layer.parameters()]
    opt = torch.optim.Adam(hidden, lr=settings.learning_rate)
    n = y_all.shape[0]
    m = min(settings.points_per_step, n)
    ones = torch.ones(m, 1, dtype=_TRAIN_DTYPE)
    zeros = torch.zeros(m, 1, 3, dtype=_TRAIN_DTYPE)
    for step in range(settings.steps):
        for group in opt.param_groups:
            group["lr"] = settings.learning_rate_at(step)
        y = y_all[torch.randperm(n, generator=gen)[:m]] if m < n else y_all
        h, dh_du = mlp.features_with_jacobian(y * scale)
        dh = dh_du * scale
        with torch.no_grad():  # variable projection: the optimal output layer of this batch
            out = _ritz_output(h.to(_DTYPE), dh.to(_DTYPE), y.to(_DTYPE), outputs, _RITZ_RTOL_F32)
        if out is None:
            break  # the features collapsed on this batch; keep the best checkpoint so far
        coef = out[0].to(_TRAIN_DTYPE)
        weights = torch.cat((ones, h @ coef[1:] + coef[0]), dim=1)
        grads = torch.cat((zeros, torch.einsum("nkj,ko->noj", dh, coef[1:])), dim=1)
        mix = _orthonormalising_mix(weights.to(_DTYPE).T @ weights.to(_DTYPE) / m).to(_TRAIN_DTYPE)
        form = mix.T @ _energy_form(weights, grads, y) @ mix
        loss = torch.trace(form[1:, 1:])
        if not bool(torch.isfinite(loss)):
            raise RuntimeError(
                f"skinning training diverged (loss {float(loss)}); lower SkinningTrainingSettings.learning_rate"
            )
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        done = step + 1
        if done % settings.checkpoint_every == 0 or done == settings.steps:
            fit = checkpoint()
            if fit is not None and fit[0] < best_score:
                best_score, best_mlp = fit
                best_step, since_best = done, 0
            else:
                since_best += 1
                if since_best >= settings.patience:
                    break  # early stop: the held-out score has not improved for `patience` checkpoints
    return _TrainingOutcome(best_mlp, best_step, done, best_score, 0 if y_val64 is None else y_val64.shape[0])


def _orthonormalising_mix(gram: torch.Tensor, ridge: float = 1e-6) -> torch.Tensor:
    """Upper-triangular M with M^T (gram + r I) M = I, r = ridge x mean diagonal of gram.

    Column 0 (the constant handle, gram[0, 0] = 1) maps to itself when r = 0.
    The ridge keeps the Cholesky factor finite for near-collinear columns.
    """
    eye = torch.eye(gram.shape[0], dtype=gram.dtype)
    scale = float(torch.trace(gram.detach())) / gram.shape[0]
    for attempt in range(4):  # raise the ridge 100x per failed factorisation
        r = max(ridge, 1e-12 if attempt else 0.0) * 100.0**attempt * scale
        chol, info = torch.linalg.cholesky_ex(gram + r * eye)
        if int(info) == 0:
            break
    else:
        raise RuntimeError(
            f"skinning weights are degenerate (Gram matrix not positive definite, mean diagonal {scale:.3g}); "
            "training diverged: lower SkinningTrainingSettings.learning_rate"
        )
    return torch.linalg.solve_triangular(chol, eye, upper=False).T


def _fold_mix_into_last_layer(mlp: SkinningMLP, mix: torch.Tensor) -> None:
    """Rewrite the output layer so [1, w_new] = [1, w_old] @ mix (mix upper triangular, mix[0, 0] = 1)."""
    last = mlp.layers[-1]
    block = mix[1:, 1:]
    last.weight.copy_(block.T @ last.weight)
    last.bias.copy_(block.T @ last.bias + mix[0, 1:])


# --------------------------------------------------------------------------- cache


def _cache_directory(cache_dir: str | os.PathLike | None) -> Path:
    if cache_dir is not None:
        return Path(cache_dir)
    root = os.environ.get("NEWTPHYS_CACHE_DIR")
    base = Path(root) if root else Path.home() / ".cache" / "newtphys"
    return base / "skinning"


def _load_cached(path: Path, key: str) -> SkinningBasis | None:
    if not path.exists():
        return None
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
        if payload.get("key") != key or payload.get("format") != _CACHE_FORMAT:
            raise ValueError("key or format mismatch")
        return SkinningBasis.from_payload(payload["basis"])
    except Exception as exc:  # a corrupt or foreign file is rebuilt, never trusted
        logger.warning("skinning cache file %s is unreadable (%s); retraining", path, exc)
        return None


def _save_cached(path: Path, key: str, basis: SkinningBasis) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-", suffix=".pt")
    os.close(fd)
    try:
        torch.save({"format": _CACHE_FORMAT, "key": key, "basis": basis.to_payload()}, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


# --------------------------------------------------------------------------- validation


def _check_points(points: torch.Tensor, name: str, keep_device: bool = False) -> torch.Tensor:
    """``points`` (n, 3) checked, as float64 on the CPU (or on their own device with ``keep_device``)."""
    if not isinstance(points, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor of shape (n, 3); got {type(points).__name__}")
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3); got {tuple(points.shape)}")
    if not bool(torch.isfinite(points).all()):
        raise ValueError(f"{name} contains non-finite values; allowed: finite coordinates in m")
    return points.detach().to(device=points.device if keep_device else "cpu", dtype=_DTYPE)


def _positive(name: str, value: float) -> None:
    if not (value > 0.0) or math.isinf(value):
        raise ValueError(f"{name}={value!r} is out of range; allowed: finite > 0")
