"""The per-cubature-point part of the stable neo-Hookean term as one warp kernel.

For every cubature point of every object (padded layout of :class:`data_gen.sim.model.Model`) one thread
forms ``F = I + Tm C_i`` and writes the volume-weighted energy ``V Psi(F)`` (J), first Piola stress
``V P`` (N m) and, with derivatives, the Hessian ``V d2Psi/dF2`` (9 x 9, row-major vec(F)) together with
the near-positive-definiteness test of :mod:`data_gen.sim.energy.elastic` (a Cholesky factorisation of
``H + tol I``; a failed pivot flags the block). A flagged block, and every block of a ``strict`` object, is
replaced by its projection onto the positive semi-definite cone, computed from the analytic eigensystem
(:func:`projected_neo_hookean_hessian`: a 3 x 3 SVD and a 3 x 3 eigenproblem instead of a 9 x 9 one); the
torch reference eigen-clamps the assembled block and the tests hold the two together. The formulas are
those of
:mod:`data_gen.sim.material` (the torch reference, which the tests compare against):

    Psi = mu/2 (I1 - 3) + lam'/2 (J - 1)^2 - mu (J - 1),       lam' = lam + mu,
    P   = mu F + (lam' (J - 1) - mu) cof F,
    H   = mu I9 + lam' g g^T + (lam' (J - 1) - mu) d2J/dF2,     g = vec(cof F),
    d2J/dF_ij dF_kl = eps_ikm eps_jln F_mn.

The reduction to reduced coordinates (a few batched matrix products) stays in torch
(:func:`data_gen.sim.energy.elastic.elastic_from_points`).
"""

from __future__ import annotations

import torch
import warp as wp


mat99d = wp.types.matrix(shape=(9, 9), dtype=wp.float64)


@wp.func
def _cofactor(f: wp.mat33d):
    """cof F = J F^-T: column j is the cross product of the other two columns of F."""
    c0 = wp.vec3d(f[0, 0], f[1, 0], f[2, 0])
    c1 = wp.vec3d(f[0, 1], f[1, 1], f[2, 1])
    c2 = wp.vec3d(f[0, 2], f[1, 2], f[2, 2])
    x0 = wp.cross(c1, c2)
    x1 = wp.cross(c2, c0)
    x2 = wp.cross(c0, c1)
    return wp.mat33d(x0[0], x1[0], x2[0], x0[1], x1[1], x2[1], x0[2], x1[2], x2[2])


@wp.func
def _levi_civita(i: int, k: int):
    """eps_ikm for i != k (m the third index): +1 when (i, k, m) is cyclic, -1 otherwise."""
    s = wp.float64(-1.0)
    if (k - i + 3) % 3 == 1:
        s = wp.float64(1.0)
    return s


@wp.func
def not_positive_definite(h: mat99d, shift: wp.float64):
    """1 when ``h + shift I`` has a non-positive (or NaN) Cholesky pivot, else 0."""
    lower = mat99d()
    bad = int(0)
    for j in range(9):
        if bad == 0:
            d = h[j, j] + shift
            for k in range(j):
                d = d - lower[j, k] * lower[j, k]
            if not (d > wp.float64(0.0)):
                bad = 1
            else:
                root = wp.sqrt(d)
                lower[j, j] = root
                for i in range(j + 1, 9):
                    v = h[i, j]
                    for k in range(j):
                        v = v - lower[i, k] * lower[j, k]
                    lower[i, j] = v / root
    return bad


@wp.func
def deformation_gradient(tm: wp.array3d(dtype=wp.float64), cub_c: wp.array4d(dtype=wp.float64), o: int, i: int,
                         columns: int):  # fmt: skip
    """``F = I + Tm C_i`` of cubature point i of object o (its first ``columns`` basis columns)."""
    f = wp.identity(n=3, dtype=wp.float64)
    for a in range(columns):
        for r in range(3):
            t = tm[o, r, a]
            for j in range(3):
                f[r, j] = f[r, j] + t * cub_c[o, i, a, j]
    return f


@wp.func
def neo_hookean_point(f: wp.mat33d, mu: wp.float64, lam: wp.float64, derivatives: int):
    """Energy density Psi (J/m^3), first Piola stress P (Pa) and, when ``derivatives``, the 9 x 9 Hessian
    d2Psi/dF2 (Pa, row-major vec(F); zero otherwise) of the stable neo-Hookean model at ``F``."""
    lam_s = lam + mu
    det = wp.determinant(f)
    jm1 = det - wp.float64(1.0)
    i1 = wp.ddot(f, f)
    psi = wp.float64(0.5) * mu * (i1 - wp.float64(3.0)) + wp.float64(0.5) * lam_s * jm1 * jm1 - mu * jm1
    cof = _cofactor(f)
    coef = lam_s * jm1 - mu
    h = mat99d()
    if derivatives != 0:
        for row in range(9):
            ri = row // 3
            rj = row % 3
            g_row = cof[ri, rj]
            for col in range(9):
                ck = col // 3
                cl = col % 3
                value = lam_s * g_row * cof[ck, cl]
                if ri != ck and rj != cl:
                    m = 3 - ri - ck
                    nn = 3 - rj - cl
                    value = value + coef * _levi_civita(ri, ck) * _levi_civita(rj, cl) * f[m, nn]
                if row == col:
                    value = value + mu
                h[row, col] = value
    return psi, mu * f + coef * cof, h


@wp.func
def _add_mode(h: mat99d, u: wp.mat33d, d: wp.mat33d, v: wp.mat33d, weight: wp.float64):
    """``h + weight vec(Q) vec(Q)^T`` with ``Q = U D V^T`` (row-major vec)."""
    q = u * d * wp.transpose(v)
    for a in range(9):
        qa = weight * q[a // 3, a % 3]
        for b in range(9):
            h[a, b] = h[a, b] + qa * q[b // 3, b % 3]
    return h


@wp.func
def projected_neo_hookean_hessian(f: wp.mat33d, mu: wp.float64, lam: wp.float64):
    """The 9 x 9 Hessian of :func:`neo_hookean_point` (Pa) with its negative eigenvalues set to zero, from its
    analytic eigensystem (Smith, de Goes and Kim 2019: the energy is isotropic, so with ``F = U S V^T``, U
    and V rotations and S signed, ``U X V^T`` is an eigenvector wherever X is one at S).

    At S = diag(s0, s1, s2), with ``c = lam' (J - 1) - mu``: the twist and flip modes
    ``(E_ab -+ E_ba) / sqrt 2`` have eigenvalues ``mu +- c s_m`` (m the third index), and the three scaling
    modes are the eigenvectors of ``A = mu I + lam' g g^T + c [[0, s2, s1], [s2, 0, s0], [s1, s0, 0]]`` with
    ``g = (s1 s2, s0 s2, s0 s1)`` on the diagonal matrices. The result equals the eigen-clamp of the
    assembled Hessian (the projection onto the positive semi-definite cone is unique)."""
    u = wp.mat33d()
    sig = wp.vec3d()
    v = wp.mat33d()
    wp.svd3(f, u, sig, v)  # U and V are rotations; the last singular value carries the sign of det F
    lam_s = lam + mu
    jm1 = sig[0] * sig[1] * sig[2] - wp.float64(1.0)
    c = lam_s * jm1 - mu
    h = mat99d()
    root_half = wp.sqrt(wp.float64(0.5))
    for m in range(3):
        a = (m + 1) % 3
        b = (m + 2) % 3
        flip = mu - c * sig[m]  # (E_ab + E_ba) / sqrt 2
        twist = mu + c * sig[m]  # (E_ab - E_ba) / sqrt 2
        d = wp.mat33d()
        d[a, b] = root_half
        d[b, a] = root_half
        if flip > wp.float64(0.0):
            h = _add_mode(h, u, d, v, flip)
        d[b, a] = -root_half
        if twist > wp.float64(0.0):
            h = _add_mode(h, u, d, v, twist)
    g = wp.vec3d(sig[1] * sig[2], sig[0] * sig[2], sig[0] * sig[1])
    scaling = mu * wp.identity(n=3, dtype=wp.float64) + lam_s * wp.outer(g, g)
    scaling = scaling + c * wp.mat33d(
        wp.float64(0.0), sig[2], sig[1], sig[2], wp.float64(0.0), sig[0], sig[1], sig[0], wp.float64(0.0)
    )
    vectors = wp.mat33d()
    values = wp.vec3d()
    wp.eig3(scaling, vectors, values)
    for k in range(3):
        if values[k] > wp.float64(0.0):
            d = wp.mat33d()
            for i in range(3):
                d[i, i] = vectors[i, k]
            h = _add_mode(h, u, d, v, values[k])
    return h


@wp.kernel
def neo_hookean_points_kernel(
    tm: wp.array3d(dtype=wp.float64),
    columns: wp.array(dtype=wp.int32),
    cub_c: wp.array4d(dtype=wp.float64),
    volume: wp.array2d(dtype=wp.float64),
    mu_pa: wp.array(dtype=wp.float64),
    lam_pa: wp.array(dtype=wp.float64),
    tolerance_pa: wp.array(dtype=wp.float64),
    strict: wp.array(dtype=wp.int32),
    derivatives: int,
    energy: wp.array2d(dtype=wp.float64),
    piola: wp.array2d(dtype=wp.mat33d),
    hess: wp.array2d(dtype=mat99d),
    needs_projection: wp.array2d(dtype=wp.int32),
):
    """Point (o, i): writes ``energy`` (n, P) J, ``piola`` (n, P) V P and, when ``derivatives``, ``hess``
    (n, P) V H and ``needs_projection`` (n, P) (1 where ``H + tol I`` is not positive definite); such blocks
    and all blocks of objects with ``strict`` (n,) set are written projected."""
    o, i = wp.tid()
    v = volume[o, i]
    if v == wp.float64(0.0):
        return
    f = deformation_gradient(tm, cub_c, o, i, int(columns[o]))
    psi, piola_i, h = neo_hookean_point(f, mu_pa[o], lam_pa[o], derivatives)
    energy[o, i] = v * psi
    piola[o, i] = v * piola_i
    if derivatives == 0:
        return
    flagged = not_positive_definite(h, tolerance_pa[o])
    needs_projection[o, i] = flagged
    if flagged != 0 or strict[o] != 0:
        h = projected_neo_hookean_hessian(f, mu_pa[o], lam_pa[o])
    hess[o, i] = v * h


class WarpNeoHookean:
    """Per-point neo-Hookean quantities of a fixed set of objects (one solve), with persistent buffers and
    recorded launches.

    Args:
        columns: (n,) 4 H; cub_c: (n, P, K, 3) bases; volume_m3: (n, P) (0 on padding); mu_pa, lam_pa,
            tolerance_pa: (n,) Pa.
    """

    def __init__(self, columns: torch.Tensor, cub_c: torch.Tensor, volume_m3: torch.Tensor, mu_pa: torch.Tensor,
                 lam_pa: torch.Tensor, tolerance_pa: torch.Tensor) -> None:  # fmt: skip
        wp.init()  # idempotent; not at import, so importing the package prints nothing
        n, p, k, _ = cub_c.shape
        device = "cuda:0" if str(cub_c.device) == "cuda" else str(cub_c.device)
        like = dict(dtype=cub_c.dtype, device=cub_c.device)
        self.tm = torch.zeros(n, 3, k, **like)
        self.energy = torch.zeros(n, p, **like)
        self.piola = torch.zeros(n, p, 3, 3, **like)
        self.hess = torch.zeros(n, p, 9, 9, **like)
        self.needs_projection = torch.zeros(n, p, dtype=torch.int32, device=cub_c.device)
        self.strict = torch.zeros(n, dtype=torch.int32, device=cub_c.device)
        self._any_strict = False
        self._constants = [columns.to(torch.int32).contiguous(), cub_c.contiguous(), volume_m3.contiguous(),
                           mu_pa.contiguous(), lam_pa.contiguous(), tolerance_pa.contiguous(), self.strict]  # fmt: skip
        self._device, self._dim = device, (n, p)
        self._launch = None  # recorded on the first evaluation (a fused solve never evaluates here)
        self._derivatives = True

    def _record(self) -> None:
        """Record the launch over the buffers (its arguments are packed once)."""
        arrays = [wp.from_torch(self.tm)] + [wp.from_torch(t) for t in self._constants]
        outputs = [wp.from_torch(self.energy), wp.from_torch(self.piola, dtype=wp.mat33d),
                   wp.from_torch(self.hess, dtype=mat99d), wp.from_torch(self.needs_projection)]  # fmt: skip
        self._arguments = [arrays, outputs]  # the recorded launch holds raw pointers to these
        self._derivatives_index = len(arrays)
        self._launch = wp.launch(neo_hookean_points_kernel, dim=self._dim, inputs=[*arrays, int(self._derivatives),
                                 *outputs], device=self._device, record_cmd=True)  # fmt: skip

    def evaluate(self, tm: torch.Tensor, derivatives: bool,
                 strict: torch.Tensor | None = None) -> tuple[torch.Tensor, ...]:  # fmt: skip
        """Energies (n, P) J, V P (n, P, 3, 3), V H (n, P, 9, 9) (near-SPD-failing blocks, and every block of
        the ``strict`` (n,) bool objects, projected) and the near-SPD test's flags (n, P) bool at the padded
        states ``tm`` (n, 3, K). The tensors are buffers: the next evaluation overwrites them."""
        self.tm.copy_(tm)
        if strict is not None:
            self.strict.copy_(strict)
            self._any_strict = True
        elif self._any_strict:
            self.strict.zero_()
            self._any_strict = False
        if self._launch is None:
            self._derivatives = derivatives
            self._record()
        elif derivatives != self._derivatives:
            self._launch.set_param_at_index(self._derivatives_index, int(derivatives))
            self._derivatives = derivatives
        self._launch.launch()
        return self.energy, self.piola, self.hess, self.needs_projection.bool()


__all__ = [
    "WarpNeoHookean", "deformation_gradient", "mat99d", "neo_hookean_point", "neo_hookean_points_kernel",
    "not_positive_definite", "projected_neo_hookean_hessian",
]
