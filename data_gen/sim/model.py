"""The fixed part of a simulation: every object's reduced model stacked into padded batch tensors.

Objects differ in handle count ``H`` (1 for near-rigid objects, up to the preset's cap for soft ones), in
cubature count and in contact-sphere count.  :class:`Model` pads them to common sizes so that one batched
tensor operation evaluates an energy term for many objects at once:

* handle columns ``K = 4 max(H)``: an object's affine-basis rows ``b`` (4H,) and deformation bases ``C``
  (4H,3) are zero beyond ``4H``; its reduced state in *padded q-ordering* is the (3, K) matrix ``Tm``
  with zero columns beyond ``4H`` (the unpadded q-ordering of :mod:`data_gen.sim.reduced` is the
  row-major flattening of the first ``4H`` columns);
* cubature points ``P = max`` count: padded points have zero volume (no energy, gradient or Hessian);
* contact spheres ``S = max`` count: padded spheres are masked (``sphere_valid``), radius 0.

:meth:`Model.select` takes the rows of some objects (e.g. the awake objects solved together);
:class:`DofLayout` maps their padded (3, K) states to and from the flat unpadded vectors that Newton's
method solves for, one vector per island.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np
import torch
from scipy.spatial import ConvexHull, QhullError

from data_gen.sim.contact_points import ContactPoints
from data_gen.sim.reduced import DTYPE, NEAR_SPD_TOLERANCE, ReducedObject


@dataclass(frozen=True)
class Model:
    """Padded per-object arrays (leading dimension: objects, in body order). Units: m, kg, Pa, m^3.

    Attributes:
        num_handles: (n,) int64 handle count H per object.
        mass_kg: (n,) object masses.
        mass_matrix: (n, 3K, 3K) reduced mass ``I3 (x) M4`` in padded q-ordering (identity on padding).
        mass_b_sum: (n, K) ``sum_p m_p b_p`` (gravity potential and centre of mass).
        cub_c: (n, P, K, 3) deformation bases ``C_i`` of the cubature points (a one-handle object, whose
            ``F`` is uniform, keeps one point with its whole volume).
        cub_volume_m3: (n, P) cubature volumes (0 on padding).
        mu_pa, lam_pa: (n,) Lamé parameters.
        spd_tolerance_pa: (n,) near-SPD test tolerance of the elastic blocks (``NEAR_SPD_TOLERANCE mu``).
        sphere_rest_m: (n, S, 3) contact sphere centres at rest (object frame).
        sphere_b: (n, S, K) affine basis rows of the sphere centres.
        sphere_radius_m: (n, S) radii (0 on padding).
        sphere_valid: (n, S) bool.
        sphere_extreme: (n, S) bool: spheres whose basis rows are vertices of the convex hull of the object's
            rows (every valid sphere where that hull is not computed: more than one handle, or degenerate).
            A norm of a linear map of the rows, such as a sphere's displacement ``|dTm b|``, is largest at
            one of them (convexity), so the largest sphere motion needs only these.
        friction: (n,) Coulomb coefficients.
    """

    num_handles: torch.Tensor
    mass_kg: torch.Tensor
    mass_matrix: torch.Tensor
    mass_b_sum: torch.Tensor
    cub_c: torch.Tensor
    cub_volume_m3: torch.Tensor
    mu_pa: torch.Tensor
    lam_pa: torch.Tensor
    spd_tolerance_pa: torch.Tensor
    sphere_rest_m: torch.Tensor
    sphere_b: torch.Tensor
    sphere_radius_m: torch.Tensor
    sphere_valid: torch.Tensor
    sphere_extreme: torch.Tensor
    friction: torch.Tensor

    @staticmethod
    def build(models: list[ReducedObject], contacts: list[ContactPoints], friction: list[float]) -> Model:
        """Stack the objects' reduced models and contact spheres (same order as the bodies)."""
        n = len(models)
        k = 4 * max((m.num_handles for m in models), default=1)
        # a one-handle object deforms affinely: F is the same at every cubature point, so one point
        # carrying the whole volume integrates its elastic energy exactly
        p = max([m.num_points for m in models if m.num_handles > 1] + [1])
        s = max((c.num_points for c in contacts), default=1)
        mass_matrix = torch.eye(3 * k, dtype=DTYPE).repeat(n, 1, 1)
        mass_b_sum = torch.zeros(n, k, dtype=DTYPE)
        cub_c = torch.zeros(n, p, k, 3, dtype=DTYPE)
        cub_volume = torch.zeros(n, p, dtype=DTYPE)
        sphere_rest = torch.zeros(n, s, 3, dtype=DTYPE)
        sphere_b = torch.zeros(n, s, k, dtype=DTYPE)
        sphere_radius = torch.zeros(n, s, dtype=DTYPE)
        sphere_valid = torch.zeros(n, s, dtype=torch.bool)
        sphere_extreme = torch.zeros(n, s, dtype=torch.bool)
        for o, (m, c) in enumerate(zip(models, contacts)):  # once, at set-up
            k_o = 4 * m.num_handles
            index = padded_index(m.num_handles, k)
            mass_matrix[o][index[:, None], index[None, :]] = m.mass_matrix
            mass_b_sum[o, :k_o] = m.mass_b_sum
            if m.num_handles == 1:
                cub_c[o, 0, :k_o] = m.c[0]
                cub_volume[o, 0] = m.volumes_m3.sum()
            else:
                cub_c[o, : m.num_points, :k_o] = m.c
                cub_volume[o, : m.num_points] = m.volumes_m3
            sphere_rest[o, : c.num_points] = c.rest_m
            sphere_b[o, : c.num_points, :k_o] = c.b
            sphere_radius[o, : c.num_points] = c.radius_m
            sphere_valid[o, : c.num_points] = True
            sphere_extreme[o, : c.num_points] = torch.from_numpy(extreme_rows(c.b.numpy()))
        mu = torch.tensor([m.mu_pa for m in models], dtype=DTYPE)
        return Model(
            num_handles=torch.tensor([m.num_handles for m in models], dtype=torch.int64),
            mass_kg=torch.tensor([m.mass_kg for m in models], dtype=DTYPE),
            mass_matrix=mass_matrix,
            mass_b_sum=mass_b_sum,
            cub_c=cub_c,
            cub_volume_m3=cub_volume,
            mu_pa=mu,
            lam_pa=torch.tensor([m.lam_pa for m in models], dtype=DTYPE),
            spd_tolerance_pa=NEAR_SPD_TOLERANCE * mu,
            sphere_rest_m=sphere_rest,
            sphere_b=sphere_b,
            sphere_radius_m=sphere_radius,
            sphere_valid=sphere_valid,
            sphere_extreme=sphere_extreme,
            friction=torch.tensor(list(friction), dtype=DTYPE),
        )

    @property
    def num_objects(self) -> int:
        return int(self.mass_kg.shape[0])

    @property
    def columns(self) -> int:
        """K = 4 max(H)."""
        return int(self.sphere_b.shape[2])

    def select(self, objects: torch.Tensor) -> Model:
        """The rows of ``objects`` (int64 indices), same padding."""
        return Model(**{f.name: getattr(self, f.name)[objects] for f in fields(self)})

    def sphere_positions(self, tm: torch.Tensor) -> torch.Tensor:
        """World sphere centres (n, S, 3), m, of padded states ``tm`` (n, 3, K): ``x = x0 + Tm b``."""
        return self.sphere_rest_m + self.sphere_b @ tm.transpose(1, 2)


def extreme_rows(b: np.ndarray) -> np.ndarray:
    """(k,) bool: which of an object's sphere basis rows ``b`` (k, 4H) are vertices of their convex hull.

    For one affine handle the rows are ``[x0; 1]`` and the hull is the 3-D hull of the rest centres (qhull);
    otherwise, or when that hull is degenerate (fewer than four points, all in a plane), every row counts.
    qhull treats points within round-off of a facet as on it, so the largest ``|dTm b|`` over the vertices
    equals the largest over all rows to about 1e-15 relative."""
    every = np.ones(len(b), dtype=bool)
    if b.ndim != 2 or b.shape[1] != 4 or len(b) < 5 or np.ptp(b[:, 3]) != 0.0:
        return every
    try:
        vertices = ConvexHull(b[:, :3]).vertices
    except QhullError:
        return every
    out = np.zeros(len(b), dtype=bool)
    out[vertices] = True
    return out


def padded_index(num_handles: int, columns: int) -> torch.Tensor:
    """Positions (12H,) of an object's unpadded q-ordering ``q[r 4H + a]`` in the padded (3, K) layout."""
    r = torch.arange(3)[:, None]
    a = torch.arange(4 * num_handles)[None, :]
    return (r * columns + a).reshape(-1)


@dataclass(frozen=True)
class DofLayout:
    """Where the padded (3, K) states of some objects live in per-island flat vectors.

    Attributes:
        island: (n,) island slot of each object.
        flat_index: (n, 3K) index into the (num_islands * N) flat island vectors, -1 on padded entries.
        num_islands, island_size: N = the largest island's unpadded DOF count.
        one_island_per_object: derived: island ``o`` holds object ``o`` alone (per-island sums and maxima
            are the per-object values).

    The layout is fixed for a solve, so the gather / scatter indices of :meth:`to_objects`,
    :meth:`to_islands` and :meth:`assemble` are derived once (``__post_init__``) and every conversion is
    one or two indexing operations.
    """

    island: torch.Tensor
    flat_index: torch.Tensor
    num_islands: int
    island_size: int
    # the diagonal blocks' positions in the island matrices and their entries' positions in the blocks
    _diagonal: tuple[torch.Tensor, torch.Tensor | None] | None = field(
        default=None, repr=False, compare=False
    )
    # derived in __post_init__ (gather / scatter indices of the conversions)
    _valid: torch.Tensor = field(init=False, repr=False, compare=False)
    _all_valid: bool = field(init=False, repr=False, compare=False)
    _gather: torch.Tensor = field(init=False, repr=False, compare=False)
    _scatter: torch.Tensor = field(init=False, repr=False, compare=False)
    _used: torch.Tensor | None = field(init=False, repr=False, compare=False)
    one_island_per_object: bool = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        valid = self.flat_index >= 0
        flat = self.flat_index.reshape(-1)
        all_valid = bool(valid.all())
        # to_objects: padded entry p reads island entry _gather[p] (0 where padded; masked by _valid)
        gather = flat if all_valid else flat.clamp(min=0)
        # to_islands: island entry f reads padded entry _scatter[f] (0 where unused; masked by _used)
        total = self.num_islands * self.island_size
        scatter = torch.full((total,), -1, dtype=torch.int64)
        positions = torch.arange(flat.shape[0])
        scatter[flat[valid.reshape(-1)]] = positions[valid.reshape(-1)]
        used = scatter >= 0
        all_used = bool(used.all())
        n = int(self.island.shape[0])
        per_object = self.num_islands == n and bool(torch.equal(self.island, torch.arange(n)))
        for name, value in (
            ("_valid", valid), ("_all_valid", all_valid), ("_gather", gather),
            ("_scatter", scatter if all_used else scatter.clamp(min=0)),
            ("_used", None if all_used else used),
            ("one_island_per_object", per_object),
        ):  # fmt: skip
            object.__setattr__(self, name, value)

    @staticmethod
    def build(num_handles: torch.Tensor, island: torch.Tensor, columns: int) -> DofLayout:
        """The layout of objects with ``num_handles`` (n,) in islands ``island`` (n,) (slots 0..max): an
        island's objects follow each other in object order, each in its unpadded q-ordering."""
        n = int(num_handles.shape[0])
        num_islands = int(island.max()) + 1 if n else 0
        width = 4 * num_handles  # (n,) unpadded columns 4H
        dofs = 3 * width
        # offset of each object in its island: the DOFs of the island's earlier objects
        same = island[:, None] == island[None, :]
        earlier = torch.arange(n)[None, :] < torch.arange(n)[:, None]
        offsets = (dofs[None, :] * (same & earlier)).sum(1)
        sizes = torch.zeros(max(num_islands, 1), dtype=torch.int64).index_add_(0, island, dofs)
        size = int(sizes.max()) if n else 0
        # padded entry (r, a) of object o, a < 4H: unpadded entry r 4H + a (see padded_index)
        r = torch.arange(3)[None, :, None]
        a = torch.arange(columns)[None, None, :]
        local = r * width[:, None, None] + a
        flat = torch.where(a < width[:, None, None], (island * size + offsets)[:, None, None] + local, -1)
        return DofLayout(island, flat.reshape(n, 3 * columns), num_islands, size)

    @property
    def valid(self) -> torch.Tensor:
        """(n, 3K) bool: entries of the padded layout that are degrees of freedom."""
        return self._valid

    def to_islands(self, padded: torch.Tensor) -> torch.Tensor:
        """Padded per-object vectors (n, 3, K) -> island vectors (num_islands, N) (a new tensor; zeros on the
        unused entries of smaller islands)."""
        out = padded.reshape(-1).index_select(0, self._scatter)
        if self._used is not None:
            out = torch.where(self._used, out, torch.zeros((), dtype=out.dtype))
        return out.reshape(self.num_islands, self.island_size)

    def to_objects(self, flat: torch.Tensor) -> torch.Tensor:
        """Island vectors (num_islands, N) -> padded per-object vectors (n, 3, K) (a new tensor; zeros on
        padding)."""
        out = flat.reshape(-1).index_select(0, self._gather).reshape(self.flat_index.shape)
        if not self._all_valid:
            out = torch.where(self._valid, out, torch.zeros((), dtype=flat.dtype))
        return out.reshape(self.flat_index.shape[0], 3, -1)

    def _block_index(self, rows: torch.Tensor, cols: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Flat positions in the (num_islands, N, N) matrices of blocks (rows[m], cols[m]) and their mask."""
        size = self.island_size
        fr = self.flat_index[rows]  # (m, 3K) flat = island * N + local
        fc = self.flat_index[cols]
        island = (fr.clamp(min=0) // max(size, 1))[:, :1]
        local_r = fr - island * size
        local_c = fc - island * size
        mask = (fr >= 0)[:, :, None] & (fc >= 0)[:, None, :]
        index = (island[:, :, None] * size + local_r[:, :, None]) * size + local_c[:, None, :]
        return index[mask], mask

    def assemble(self, blocks: torch.Tensor, rows: torch.Tensor | None = None, cols: torch.Tensor | None = None,
                 out: torch.Tensor | None = None) -> torch.Tensor:
        """Add object blocks (m, 3K, 3K) at (rows[m], cols[m]) (default: the diagonal) into island matrices
        (num_islands, N, N); padded rows/columns are dropped. Cross blocks must pair objects of one island."""
        n_isl, size = self.num_islands, self.island_size
        if rows is None and self.one_island_per_object and self._all_valid:
            # island o is object o with N = 3K in the same order: the matrices are the blocks themselves
            # (``x + 0.0`` as the scatter into zeros below would give, fresh)
            square = blocks.reshape(n_isl, size, size)
            return square + 0.0 if out is None else out.reshape(n_isl, size, size).add_(square)
        out = torch.zeros(n_isl * size * size, dtype=blocks.dtype) if out is None else out.reshape(-1)
        if rows is None:  # the diagonal blocks: the same positions on every call
            if self._diagonal is None:
                objects = torch.arange(self.flat_index.shape[0])
                index, mask = self._block_index(objects, objects)
                source = None if bool(mask.all()) else torch.nonzero(mask.reshape(-1))[:, 0]
                object.__setattr__(self, "_diagonal", (index, source))
            index, source = self._diagonal
            values = blocks.reshape(-1) if source is None else blocks.reshape(-1).index_select(0, source)
        else:
            index, mask = self._block_index(rows, rows if cols is None else cols)
            values = blocks[mask]
        out.index_add_(0, index, values)
        return out.reshape(n_isl, size, size)
