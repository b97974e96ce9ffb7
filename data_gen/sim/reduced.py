"""Reduced (Simplicits) kinematics of one object: precomputation and energies in float64.

State: handle h has a 3x4 delta affine ``T_h``; the reduced state ``z`` (12 H,) concatenates the
row-major flattened ``T_h``.  With the homogeneous rest point ``xb = [x0; 1]``:

    x(x0) = x0 + sum_h w_h(x0) T_h xb
    F(x0) = I + sum_h ( w_h T_h[:, :3] + T_h xb grad w_h^T )

Both are linear in the 3 x 4H matrix ``Tm = [T_0 | T_1 | ...]``:

    x_i = x0_i + Tm b_i,        b_i = stacked w_h xb          (4H,)
    F_i = I + Tm C_i,            C_i[4h + c, j] = w_h delta_cj + xb_c dw_h/dx_j    (4H, 3)

so ``dx/dz = I3 (x) b_i^T`` and ``dF/dz = I3 (x) C_i^T`` in the *T-ordering* ``q = vec_rowmajor(Tm)``
(index ``3``-row major: ``q[r * 4H + a] = Tm[r, a]``).  The solver works in ``q``; ``z`` and ``q``
differ by a fixed permutation (``z_to_q`` / ``q_to_z``).  The reduced mass is ``I3 (x) M4`` with
``M4 = sum_i m_i b_i b_i^T``; every quantity is assembled from (4H)-sized blocks.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from data_gen.sim import material as mat

DTYPE = torch.float64


def handle_permutation(num_handles: int) -> torch.Tensor:
    """Index ``perm`` with ``q = z[perm]`` (z: handle-major row-major 3x4; q: row-major 3 x 4H)."""
    r = torch.arange(3)[:, None, None]
    h = torch.arange(num_handles)[None, :, None]
    c = torch.arange(4)[None, None, :]
    return (h * 12 + r * 4 + c).reshape(-1)


def z_to_q(z: torch.Tensor) -> torch.Tensor:
    """Reorder reduced states (..., 12H) from z-ordering to q-ordering."""
    return z[..., handle_permutation(z.shape[-1] // 12)]


def q_to_z(q: torch.Tensor) -> torch.Tensor:
    """Inverse of :func:`z_to_q`."""
    perm = handle_permutation(q.shape[-1] // 12)
    out = torch.empty_like(q)
    out[..., perm] = q
    return out


def homogeneous(points_rest: torch.Tensor) -> torch.Tensor:
    """[x0; 1] for rest points (n,3) -> (n,4)."""
    return torch.cat([points_rest, torch.ones_like(points_rest[:, :1])], dim=1)


def affine_basis(points_rest: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
    """b_i = stacked w_h [x0; 1], shape (n, 4H)."""
    return (weights[:, :, None] * homogeneous(points_rest)[:, None, :]).reshape(points_rest.shape[0], -1)


def deformation_basis(points_rest: torch.Tensor, weights: torch.Tensor, grads: torch.Tensor) -> torch.Tensor:
    """C_i with F_i = I + Tm C_i, shape (n, 4H, 3)."""
    n, num_h = weights.shape
    xb = homogeneous(points_rest)
    eye = torch.zeros(4, 3, dtype=points_rest.dtype, device=points_rest.device)
    eye[:3, :3] = torch.eye(3, dtype=points_rest.dtype, device=points_rest.device)
    c = weights[:, :, None, None] * eye + xb[:, None, :, None] * grads[:, :, None, :]
    return c.reshape(n, 4 * num_h, 3)


def tmat_from_z(z: torch.Tensor) -> torch.Tensor:
    """Tm (3, 4H) from a reduced state z (12H,)."""
    return z_to_q(z).reshape(3, -1)


def deform(
    points_rest: torch.Tensor, weights: torch.Tensor, grads: torch.Tensor, z: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """World positions x (n,3) m and deformation gradients F (n,3,3) of any rest points.

    Args:
        points_rest: (n,3) rest positions, m (float64).
        weights: (n,H) skinning weights (handle 0 constant 1).
        grads: (n,H,3) spatial gradients of the weights, 1/m.
        z: (12H,) reduced state.
    """
    x0 = torch.as_tensor(points_rest, dtype=DTYPE)
    tm = tmat_from_z(torch.as_tensor(z, dtype=DTYPE))
    x = x0 + displacement_from_tmat(affine_basis(x0, weights.to(DTYPE)), tm)
    F = deformation_from_tmat(deformation_basis(x0, weights.to(DTYPE), grads.to(DTYPE)), tm)
    return x, F


class PointDeformer:
    """Moves a fixed set of rest points (e.g. an object's surface Gaussians) for many states z.

    Precomputes ``b_i`` (n,4H) and ``C_i`` (n,4H,3) once, so each frame costs two matrix products:
    ``x = x0 + b Tm^T`` and ``F = I + Tm C``.

    Args:
        points_rest: (n,3) rest positions, m; weights (n,H) and grads (n,H,3) of the object's basis.
    """

    def __init__(self, points_rest: torch.Tensor, weights: torch.Tensor, grads: torch.Tensor) -> None:
        self.points_rest = torch.as_tensor(points_rest, dtype=DTYPE)
        self.b = affine_basis(self.points_rest, torch.as_tensor(weights, dtype=DTYPE))
        self.c = deformation_basis(
            self.points_rest, torch.as_tensor(weights, dtype=DTYPE), torch.as_tensor(grads, dtype=DTYPE)
        )

    def positions(self, z: torch.Tensor) -> torch.Tensor:
        """World positions (n,3) m for the reduced state z (12H,)."""
        return self.points_rest + displacement_from_tmat(self.b, tmat_from_z(torch.as_tensor(z, dtype=DTYPE)))

    def deformation_gradients(self, z: torch.Tensor) -> torch.Tensor:
        """Deformation gradients (n,3,3) for the reduced state z (12H,)."""
        return deformation_from_tmat(self.c, tmat_from_z(torch.as_tensor(z, dtype=DTYPE)))


def displacement_from_tmat(b: torch.Tensor, tm: torch.Tensor) -> torch.Tensor:
    """u_i = x_i - x0_i = Tm b_i (float64, never formed as a difference of positions), (n,3)."""
    return b @ tm.T


def deformation_from_tmat(c: torch.Tensor, tm: torch.Tensor) -> torch.Tensor:
    """F_i = I + Tm C_i, (n,3,3)."""
    return torch.eye(3, dtype=tm.dtype, device=tm.device) + tm @ c


def scatter_point_gradient(b: torch.Tensor, grad_x: torch.Tensor) -> torch.Tensor:
    """Chain rule dE/dq from per-point dE/dx (n,3) -> (3*4H,) in q-ordering."""
    return (grad_x.T @ b).reshape(-1)


def scatter_point_hessian(
    b_a: torch.Tensor, hess_x: torch.Tensor, b_b: torch.Tensor | None = None
) -> torch.Tensor:
    """Reduced Hessian block sum_i kron-structured (b_a_i, H_i, b_b_i) -> (3*4Ha, 3*4Hb).

    ``hess_x`` (n,3,3) is d^2E/dx_a dx_b per pair of points with bases ``b_a`` (n,4Ha), ``b_b`` (n,4Hb):
    ``K[r, a, s, b] = sum_i H_i[r, s] b_a_i[a] b_b_i[b]``, as one matrix product.
    """
    b_b = b_a if b_b is None else b_b
    n, ka, kb = b_a.shape[0], b_a.shape[1], b_b.shape[1]
    rhs = (hess_x.reshape(n, 9, 1) * b_b[:, None, :]).reshape(n, 9 * kb)
    k = (b_a.T @ rhs).reshape(ka, 3, 3, kb).permute(1, 0, 2, 3)
    return k.reshape(3 * ka, 3 * kb)


NEAR_SPD_TOLERANCE = 0.05  # blocks with eigenvalues >= -0.05 mu skip the eigen-projection

# d^2 det(F) / dF_ij dF_kl = eps_ikm eps_jln F_mn as one (81, 9) matrix acting on vec(F) (row-major)
_LEVI = torch.zeros(3, 3, 3, dtype=DTYPE)
for _a, _b, _c in ((0, 1, 2), (1, 2, 0), (2, 0, 1)):
    _LEVI[_a, _b, _c], _LEVI[_a, _c, _b] = 1.0, -1.0
_DET_HESSIAN_MAP = torch.einsum("ikm,jln->ijklmn", _LEVI, _LEVI).reshape(81, 9)


def neo_hookean_hessian(F: torch.Tensor, mu_pa: float, lam_pa: float) -> torch.Tensor:
    """Exact stable neo-Hookean Hessian d2Psi/dF2 (n,9,9), row-major vec(F), Pa.

    Same formula as :func:`data_gen.sim.material.hessian` (``project_spd=False``; tested equal) with
    d2J/dF2 as one matrix product instead of a three-operand einsum (the solver's hot loop).
    """
    n = F.shape[0]
    lam_s = lam_pa + mu_pa
    g = mat.cofactor(F).reshape(n, 9)
    coef = lam_s * (torch.linalg.det(F) - 1.0) - mu_pa
    d2j = (F.reshape(n, 9) @ _DET_HESSIAN_MAP.T).reshape(n, 9, 9)
    h = lam_s * g[:, :, None] * g[:, None, :] + coef[:, None, None] * d2j
    h.diagonal(dim1=1, dim2=2).add_(mu_pa)
    return h


def project_blocks_spd(h: torch.Tensor, tolerance: float, strict: bool = False) -> torch.Tensor:
    """Clamp negative eigenvalues of symmetric blocks (n,k,k) at 0; blocks passing a Cholesky test of
    ``h + tolerance I`` are left unchanged unless ``strict``."""
    h = 0.5 * (h + h.transpose(1, 2))
    if strict:
        bad = torch.ones(h.shape[0], dtype=torch.bool)
    else:
        eye = torch.eye(h.shape[1], dtype=h.dtype)
        bad = torch.linalg.cholesky_ex(h + tolerance * eye).info != 0
    if bool(bad.any()):
        evals, evecs = torch.linalg.eigh(h[bad])
        h = h.clone()
        h[bad] = (evecs * evals.clamp(min=0.0)[:, None, :]) @ evecs.transpose(1, 2)
    return h


@dataclass
class ReducedObject:
    """Precomputed float64 reduced model of one object at its cubature points.

    Attributes:
        points_rest: (n,3) cubature rest positions, m.
        volumes_m3: (n,) cubature volumes, m^3 (sum = object volume).
        density_kg_m3: mass density.
        weights: (n,H), grads: (n,H,3) skinning weights and gradients (1/m).
        mu_pa, lam_pa: Lamé parameters, Pa.
        mass_points_rest: optional (P,3) particles that integrate the inertia (the object's full
            uniform sample, each of volume V / P) with ``mass_weights`` (P,H).  The reduced mass
            matrix, gravity term and centre of mass then come from all P particles (computed once),
            so the rigid-body inertia does not depend on the cubature count; the elastic energy
            still uses the n cubature points.  Default: the cubature points.
    """

    points_rest: torch.Tensor
    volumes_m3: torch.Tensor
    density_kg_m3: float
    weights: torch.Tensor
    grads: torch.Tensor
    mu_pa: float
    lam_pa: float
    mass_points_rest: torch.Tensor | None = None
    mass_weights: torch.Tensor | None = None

    def __post_init__(self) -> None:
        self.points_rest = torch.as_tensor(self.points_rest, dtype=DTYPE)
        self.volumes_m3 = torch.as_tensor(self.volumes_m3, dtype=DTYPE)
        self.weights = torch.as_tensor(self.weights, dtype=DTYPE)
        self.grads = torch.as_tensor(self.grads, dtype=DTYPE)
        n = self.points_rest.shape[0]
        if self.weights.shape[0] != n or self.grads.shape[:2] != self.weights.shape:
            raise ValueError(
                f"weights {tuple(self.weights.shape)} / grads {tuple(self.grads.shape)} "
                f"do not match {n} points"
            )
        self.b = affine_basis(self.points_rest, self.weights)
        self.c = deformation_basis(self.points_rest, self.weights, self.grads)
        self.c_rows = self.c.transpose(1, 2).reshape(-1, self.c.shape[1]).contiguous()  # [(i, j), a]
        self.c_cols = self.c.permute(1, 0, 2).reshape(self.c.shape[1], -1).contiguous()  # [a, (i, j)]
        self.masses_kg = self.density_kg_m3 * self.volumes_m3  # per cubature point (gravity labels)
        if (self.mass_points_rest is None) != (self.mass_weights is None):
            raise ValueError("mass_points_rest and mass_weights must be given together")
        if self.mass_points_rest is None:
            self.mass_points_rest, self.mass_b, particle_kg = self.points_rest, self.b, self.masses_kg
        else:
            self.mass_points_rest = torch.as_tensor(self.mass_points_rest, dtype=DTYPE)
            p = self.mass_points_rest.shape[0]
            if tuple(self.mass_weights.shape) != (p, self.weights.shape[1]):
                raise ValueError(f"mass_weights {tuple(self.mass_weights.shape)} do not match {p} mass points")
            self.mass_b = affine_basis(self.mass_points_rest, torch.as_tensor(self.mass_weights, dtype=DTYPE))
            particle_kg = torch.full((p,), self.density_kg_m3 * float(self.volumes_m3.sum()) / p, dtype=DTYPE)
        self.particle_masses_kg = particle_kg  # (P,) masses of the inertia particles
        m4 = (self.mass_b * particle_kg[:, None]).T @ self.mass_b
        self.mass_matrix = torch.kron(torch.eye(3, dtype=DTYPE), m4)
        self.mass_kg = float(particle_kg.sum())
        self.com_rest_m = (particle_kg[:, None] * self.mass_points_rest).sum(0) / self.mass_kg
        self.mass_b_sum = (particle_kg[:, None] * self.mass_b).sum(0)  # sum_p m_p b_p, (4H,)

    @property
    def num_handles(self) -> int:
        return self.weights.shape[1]

    @property
    def num_dofs(self) -> int:
        return 12 * self.num_handles

    @property
    def num_points(self) -> int:
        return self.points_rest.shape[0]

    def tmat(self, q: torch.Tensor) -> torch.Tensor:
        return q.reshape(3, -1)

    def displacements(self, q: torch.Tensor) -> torch.Tensor:
        """x - x0 at the cubature points (n,3), m."""
        return displacement_from_tmat(self.b, self.tmat(q))

    def positions(self, q: torch.Tensor) -> torch.Tensor:
        return self.points_rest + self.displacements(q)

    def deformation_gradients(self, q: torch.Tensor) -> torch.Tensor:
        return deformation_from_tmat(self.c, self.tmat(q))

    # ------------------------------------------------------------------ energies (J) in q
    def elastic_energy(self, q: torch.Tensor) -> float:
        F = self.deformation_gradients(q)
        return float((self.volumes_m3 * mat.energy_density(F, self.mu_pa, self.lam_pa)).sum())

    def elastic_gradient(self, q: torch.Tensor) -> torch.Tensor:
        F = self.deformation_gradients(q)
        P = mat.first_piola(F, self.mu_pa, self.lam_pa) * self.volumes_m3[:, None, None]
        # grad[r, a] = sum_i sum_j P_i[r, j] C_i[a, j]
        return (P.permute(1, 0, 2).reshape(3, -1) @ self.c_rows).reshape(-1)

    def elastic_hessian(
        self, q: torch.Tensor, project_spd: bool = True, strict: bool = False
    ) -> torch.Tensor:
        """Elastic Hessian in q, (12H, 12H).

        With ``project_spd`` the per-point 9x9 blocks are made (near) positive semi-definite: blocks
        whose eigenvalues are all above ``-NEAR_SPD_TOLERANCE * mu`` (a batched Cholesky test, ~15x
        cheaper than an eigendecomposition) are kept as they are, the others are eigen-clamped at 0.
        ``strict`` clamps every block (used when the assembled Newton matrix is not positive definite).
        """
        F = self.deformation_gradients(q)
        h = neo_hookean_hessian(F, self.mu_pa, self.lam_pa)
        if project_spd:
            h = project_blocks_spd(h, NEAR_SPD_TOLERANCE * self.mu_pa, strict)
        n, k4 = self.num_points, self.c.shape[1]
        h = h * self.volumes_m3[:, None, None]
        # K[r, a, s, b] = sum_i sum_jk H_i[(r, j), (s, k)] C_i[a, j] C_i[b, k], as two matrix products
        right = (h.reshape(n, 27, 3) @ self.c.transpose(1, 2)).reshape(n, 3, 3, 3 * k4)  # [i, r, j, (s, b)]
        right = right.permute(0, 2, 1, 3).reshape(n * 3, 3 * 3 * k4)  # [(i, j), (r, s, b)]
        k = (self.c_cols @ right).reshape(k4, 3, 3, k4).permute(1, 0, 2, 3)  # [r, a, s, b]
        return k.reshape(self.num_dofs, self.num_dofs)

    def gravity_energy(self, q: torch.Tensor, gravity_m_s2: torch.Tensor) -> float:
        """Potential -sum_i m_i g . u_i (J), relative to the rest configuration."""
        return -float(gravity_m_s2 @ (self.tmat(q) @ self.mass_b_sum))

    def gravity_gradient(self, gravity_m_s2: torch.Tensor) -> torch.Tensor:
        return -torch.outer(gravity_m_s2, self.mass_b_sum).reshape(-1)

    def kinetic_energy(self, qdot: torch.Tensor) -> float:
        return 0.5 * float(qdot @ (self.mass_matrix @ qdot))

    def point_velocities(self, qdot: torch.Tensor) -> torch.Tensor:
        return displacement_from_tmat(self.b, self.tmat(qdot))

    def cauchy_hydrostatic(self, q: torch.Tensor) -> torch.Tensor:
        """Signed hydrostatic Cauchy stress at the cubature points (n,), Pa."""
        return mat.hydrostatic_stress(self.deformation_gradients(q), self.mu_pa, self.lam_pa)
