"""Learned skinning basis (Simplicits-style) for the reduced simulator.

A basis maps rest positions x0 (m) to H skinning weights w_h(x0) and their
gradients grad w_h(x0) (1/m). Column 0 is the constant handle (w = 1,
grad w = 0); columns 1..H-1 come from a small ELU MLP evaluated on the rest
points rescaled to the bounding cube [-1, 1]^3 (same scale on every axis). The reduced kinematics that use it:

    x(x0) = x0 + sum_h w_h(x0) T_h [x0; 1],
    F(x0) = I + sum_h ( w_h(x0) T_h[:, :3] + T_h [x0; 1] grad w_h(x0)^T ).

Training minimises the stable neo-Hookean energy (``material.py``) of random
handle perturbations, with E normalised to 1 and lengths normalised by the
object's largest bounding-box side, plus an orthogonality penalty
MSE(W^T W / n, I). Neither term depends on E, density or object size, so one
basis serves every Young's modulus for a given shape, Poisson ratio and seed.

Departure from Simplicits: the energy of each step is evaluated on the batch's
weights after making them orthonormal (a Cholesky mix, differentiable), so the
energy term measures the subspace, not the column scale; the penalty only
keeps the raw columns well conditioned. After training the exact
orthonormalisation on all rest points is folded into the output layer, so a
trained basis satisfies W^T W / n = I (column 0 = 1) to round-off.

Trained bases are cached on disk as ``<cache_dir>/<sha256>.pt``. The default
cache directory is ``~/.cache/newtphys/skinning``; if the environment variable
``NEWTPHYS_CACHE_DIR`` is set, it is ``$NEWTPHYS_CACHE_DIR/skinning``. An
explicit ``cache_dir`` argument wins over both.

Determinism: all random draws (initial MLP weights, point subsets,
perturbations) come from ``torch.Generator`` objects seeded by ``seed``; on CPU
with the same torch build and thread count the weights are bit-identical.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import torch

from data_gen.sim.material import energy_density, lame_parameters
from data_gen.sim.threads import torch_threads

logger = logging.getLogger(__name__)

_CACHE_FORMAT = "newtphys-skinning-v3"
_DTYPE = torch.float64
_TRAIN_DTYPE = torch.float32


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class SkinningTrainingSettings:
    """Hyper-parameters of skinning training (all dimensionless).

    Attributes:
        steps: Adam steps.
        learning_rate: initial Adam learning rate.
        final_learning_rate: learning rate at the last step (exponential decay).
        hidden_layers: number of hidden Linear+ELU layers after the input layer.
        width: hidden width.
        points_per_step: rest points sampled (without replacement) per step.
        perturbations_per_step: random handle perturbations per step.
        perturbation_scale: std of the entries of each perturbed 3x4 T_h, in
            normalised length units (object's largest side = 1).
        orthogonality_weight: weight of MSE(W^T W / n, I) against the mean
            elastic energy density (E = 1).

    Defaults chosen on a 0.4 x 0.1 x 0.1 m beam, 2000 points, H = 6, nu = 0.3
    (perturbation energy, lower is better; random init ~1260): 300 steps at
    lr 3e-3 -> 743, 1000 at 3e-3 -> 678, 2000 at 3e-3 -> 647, 1000 at 1e-2 -> 626,
    500 at 1e-2 -> 605 (the default).
    """

    steps: int = 500
    learning_rate: float = 1e-2
    final_learning_rate: float = 1e-3
    hidden_layers: int = 4
    width: int = 64
    points_per_step: int = 512
    perturbations_per_step: int = 10
    perturbation_scale: float = 0.1
    orthogonality_weight: float = 100.0

    def __post_init__(self) -> None:
        for name in ("steps", "hidden_layers", "width", "points_per_step", "perturbations_per_step"):
            value = getattr(self, name)
            if not isinstance(value, int) or value < 1:
                raise ValueError(f"{name}={value!r} is out of range; allowed: integer >= 1")
        for name in ("learning_rate", "final_learning_rate", "perturbation_scale", "orthogonality_weight"):
            value = getattr(self, name)
            if not (value > 0.0) or math.isinf(value):
                raise ValueError(f"{name}={value!r} is out of range; allowed: finite > 0")


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

    def forward_with_jacobian(self, u: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Values (n, outputs) and Jacobian d out / d u, shape (n, outputs, 3)."""
        first = self.layers[0]
        a = first(u)
        # tangents stored as (3, n, features): each layer is then one large matmul
        da = first.weight.T[:, None, :].expand(3, u.shape[0], first.out_features)
        for layer in self.layers[1:]:
            h = torch.nn.functional.elu(a)
            slope = torch.where(a > 0, torch.ones_like(a), torch.exp(torch.clamp(a, max=0.0)))
            dh = slope[None] * da
            a = layer(h)
            da = dh @ layer.weight.T
        return a, da.permute(1, 2, 0)


# --------------------------------------------------------------------------- basis


class SkinningBasis:
    """Skinning weights over an object's rest shape.

    Args:
        num_handles: H >= 1, including the constant handle 0.
        mlp: MLP with H - 1 outputs, or None for the rigid (H = 1) basis.
        center_m: (3,) centre of the rest bounding box, m.
        half_extent_m: (3,) MLP input half-widths, m (> 0): input = (x0 - center) / half_extent.
    """

    def __init__(
        self,
        num_handles: int,
        mlp: SkinningMLP | None = None,
        center_m: torch.Tensor | None = None,
        half_extent_m: torch.Tensor | None = None,
    ) -> None:
        if num_handles < 1:
            raise ValueError(f"num_handles={num_handles!r} is out of range; allowed: >= 1")
        if (mlp is None) != (num_handles == 1):
            raise ValueError(f"num_handles={num_handles} needs an MLP iff num_handles > 1 (got mlp={mlp is not None})")
        if mlp is not None and (center_m is None or half_extent_m is None):
            raise ValueError("center_m and half_extent_m are required with an MLP")
        self.num_handles = num_handles
        self.mlp = mlp
        self.center_m = None if center_m is None else center_m.to(_DTYPE)
        self.half_extent_m = None if half_extent_m is None else half_extent_m.to(_DTYPE)

    @property
    def is_rigid(self) -> bool:
        """True for the single affine handle (no MLP)."""
        return self.mlp is None

    def evaluate(self, points_rest: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Weights (n, H) and gradients (n, H, 3) in 1/m, float64, at rest points (n, 3) in m.

        Column 0 is the constant handle: weight exactly 1, gradient exactly 0.
        """
        x = _check_points(points_rest, "points_rest")
        n = x.shape[0]
        ones = torch.ones(n, 1, dtype=_DTYPE)
        zeros = torch.zeros(n, 1, 3, dtype=_DTYPE)
        if self.mlp is None:
            return ones, zeros
        with torch.no_grad():
            u = (x - self.center_m) / self.half_extent_m
            w, dw_du = self.mlp.forward_with_jacobian(u)
            dw_dx = dw_du / self.half_extent_m
        return torch.cat((ones, w), dim=1), torch.cat((zeros, dw_dx), dim=1)

    def to_payload(self) -> dict:
        """Plain-data form (tensors, ints, floats) for ``torch.save`` / ``torch.load(weights_only=True)``."""
        if self.mlp is None:
            return {"num_handles": 1}
        return {
            "num_handles": self.num_handles,
            "hidden_layers": len(self.mlp.layers) - 2,
            "width": self.mlp.layers[0].out_features,
            "center_m": self.center_m.clone(),
            "half_extent_m": self.half_extent_m.clone(),
            "state_dict": {k: v.detach().clone() for k, v in self.mlp.state_dict().items()},
        }

    @classmethod
    def from_payload(cls, payload: dict) -> "SkinningBasis":
        """Inverse of ``to_payload``; raises KeyError/RuntimeError on malformed payloads."""
        num_handles = int(payload["num_handles"])
        if num_handles == 1:
            return rigid_basis()
        mlp = SkinningMLP(num_handles - 1, int(payload["hidden_layers"]), int(payload["width"]))
        mlp.load_state_dict(payload["state_dict"])
        mlp.requires_grad_(False)
        return cls(num_handles, mlp, payload["center_m"], payload["half_extent_m"])


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
    if x.shape[0] < 4:
        raise ValueError(f"points_rest has {x.shape[0]} points; allowed: >= 4")
    if num_handles == 1:
        return rigid_basis()

    key = skinning_cache_key(x, num_handles, poisson_ratio, settings, seed)
    path = _cache_directory(cache_dir) / f"{key}.pt"
    cached = _load_cached(path, key)
    if cached is not None:
        logger.info("skinning cache hit: %s (H=%d)", path, num_handles)
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
    if weights.shape[1] < 2:
        raise ValueError(f"weights has {weights.shape[1]} columns; allowed: >= 2 (constant + learned)")
    center, _, longest = normalised_frame(points)
    y = (points - center) / longest
    g = grads * longest
    n = weights.shape[0]
    mix = _orthonormalising_mix(weights.T @ weights / n, ridge=0.0)
    w_orth = weights @ mix
    g_orth = torch.einsum("nhk,hm->nmk", g, mix)
    gen = torch.Generator().manual_seed(seed)
    t = scale * torch.randn(num_perturbations, weights.shape[1], 3, 4, generator=gen, dtype=_DTYPE)
    t[:, 0] = 0.0
    F = deformation_gradients(w_orth, g_orth, y, t).reshape(-1, 3, 3)
    mu, lam = lame_parameters(1.0, poisson_ratio)
    return float(energy_density(F, mu, lam).mean()) / scale**2


def _optimise(
    x: torch.Tensor, num_handles: int, poisson_ratio: float, settings: SkinningTrainingSettings, seed: int
) -> SkinningBasis:
    """Adam on mean energy density (orthonormalised batch) + w_orth * MSE(W^T W / n, I).

    Runs in float32 on one CPU thread (see ``data_gen.sim.threads``); the finished
    MLP is converted to float64 and its columns are made exactly orthonormal
    on all rest points by folding a triangular mix into the output layer.
    """
    with torch_threads(1):
        gen = torch.Generator().manual_seed(int(seed))
        center, half, longest = normalised_frame(x)
        y64 = (x - center) / longest  # uniform scale: the shape is preserved
        input_scale64 = longest / half  # u = y * input_scale in [-1, 1]^3
        y_all, input_scale = y64.to(_TRAIN_DTYPE), input_scale64.to(_TRAIN_DTYPE)
        mlp = SkinningMLP(num_handles - 1, settings.hidden_layers, settings.width, dtype=_TRAIN_DTYPE)
        mlp.reset_parameters(gen)
        mu, lam = lame_parameters(1.0, poisson_ratio)
        opt = torch.optim.Adam(mlp.parameters(), lr=settings.learning_rate)
        decay = (settings.final_learning_rate / settings.learning_rate) ** (1.0 / max(settings.steps - 1, 1))
        sched = torch.optim.lr_scheduler.ExponentialLR(opt, gamma=decay)
        n = x.shape[0]
        m = min(settings.points_per_step, n)
        eye_h = torch.eye(num_handles, dtype=_TRAIN_DTYPE)
        ones = torch.ones(m, 1, dtype=_TRAIN_DTYPE)
        zeros = torch.zeros(m, 1, 3, dtype=_TRAIN_DTYPE)
        for _ in range(settings.steps):
            idx = torch.randperm(n, generator=gen)[:m]
            y = y_all[idx]
            w_free, dw_du = mlp.forward_with_jacobian(y * input_scale)
            weights = torch.cat((ones, w_free), dim=1)
            grads = torch.cat((zeros, dw_du * input_scale), dim=1)
            t = settings.perturbation_scale * torch.randn(
                settings.perturbations_per_step, num_handles, 3, 4, generator=gen, dtype=_DTYPE
            ).to(_TRAIN_DTYPE)
            t[:, 0] = 0.0  # the constant handle is not perturbed
            gram = weights.T @ weights / m
            w64 = weights.to(_DTYPE)  # float64 Gram: positive definite with the ridge
            mix = _orthonormalising_mix(w64.T @ w64 / m).to(_TRAIN_DTYPE)
            w_orth = weights @ mix
            g_orth = torch.einsum("nhk,hj->njk", grads, mix)
            F = deformation_gradients(w_orth, g_orth, y, t).reshape(-1, 3, 3)
            elastic = energy_density(F, mu, lam).mean()
            orth = ((gram - eye_h) ** 2).mean()
            loss = elastic + settings.orthogonality_weight * orth
            if not bool(torch.isfinite(loss)):
                raise RuntimeError(
                    f"skinning training diverged (loss {float(loss)}); lower SkinningTrainingSettings.learning_rate"
                )
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sched.step()
        mlp = mlp.to(_DTYPE).requires_grad_(False)
        with torch.no_grad():
            for ridge in (1e-10, 0.0):  # the second, exact pass removes the ridge and round-off of the first
                w_free = mlp(y64 * input_scale64)
                weights = torch.cat((torch.ones(n, 1, dtype=_DTYPE), w_free), dim=1)
                _fold_mix_into_last_layer(mlp, _orthonormalising_mix(weights.T @ weights / n, ridge))
    return SkinningBasis(num_handles, mlp, center, half)


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
            "training diverged: lower SkinningTrainingSettings.learning_rate or raise orthogonality_weight"
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


def _check_points(points: torch.Tensor, name: str) -> torch.Tensor:
    if not isinstance(points, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor of shape (n, 3); got {type(points).__name__}")
    if points.ndim != 2 or points.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3); got {tuple(points.shape)}")
    if not bool(torch.isfinite(points).all()):
        raise ValueError(f"{name} contains non-finite values; allowed: finite coordinates in m")
    return points.detach().to(device="cpu", dtype=_DTYPE)


def _positive(name: str, value: float) -> None:
    if not (value > 0.0) or math.isinf(value):
        raise ValueError(f"{name}={value!r} is out of range; allowed: finite > 0")
