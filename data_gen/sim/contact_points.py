"""Contact spheres on an object's surface, separate from its cubature points.

Cubature points integrate the elastic energy and sit inside the solid; using them as contact spheres
makes the contact geometry depend on the cubature count (a resting block hovers or sinks by up to
half a cubature spacing, a thin plate by centimetres).  When the caller knows the object's surface
(:class:`SurfaceSamples`: points, outward normals and area; optionally the solid's SDF), contact uses
spheres that touch the surface from inside instead:

* ``count`` surface samples are picked by farthest-point sampling: extremities (corners, rims) first,
  then evenly spread, so even a small count keeps the object's outline;
* every sphere gets the radius ``r = 0.5 sqrt(area / count)`` (half the sample spacing) and its
  centre is the sample moved inward by ``r`` along the normal, so its outermost point is the
  surface sample itself: a face resting on the ground sits at its true height, whatever ``count``;
* with an SDF, a sphere that would poke out of a thin part (a wall thinner than ``2 r``) shrinks
  until it fits inside the solid (``sdf(centre) <= -0.999 r``).

Without surface samples the contact spheres are the cubature points with radius half their spacing
(the older, approximate model).  :class:`ContactPoints` moves the sphere centres with the skinning
basis (``x = x0 + Tm b``) and maps per-sphere contact forces onto the nearest cubature points, where
the labels are read.  Units: m, N.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from data_gen.sim.reduced import DTYPE, affine_basis, displacement_from_tmat

SdfFn = Callable[[np.ndarray], np.ndarray]
_SHRINK_FACTORS = (1.0, 0.75, 0.5, 0.35, 0.25, 0.15, 0.1, 0.05)
_FIT_MARGIN = 0.999  # a sphere of radius s fits when sdf(centre) <= -0.999 s (inside the solid)


@dataclass(frozen=True)
class SurfaceSamples:
    """Samples of an object's surface in its own frame.

    Attributes:
        points_m: (s,3) points on the surface, m.
        normals: (s,3) outward unit normals.
        area_m2: total surface area, m^2 (> 0); sets the contact sphere spacing.
        sdf: optional signed distance of the solid (negative inside), (n,3) m -> (n,) m; used to
            shrink spheres in parts thinner than a sphere.  For a hollow object pass the SDF of its
            outer envelope (cavity counted as inside): spheres may then reach into the cavity but
            never out of the outer surface.
    """

    points_m: np.ndarray
    normals: np.ndarray
    area_m2: float
    sdf: SdfFn | None = None

    def __post_init__(self) -> None:
        pts = np.asarray(self.points_m, dtype=np.float64)
        nrm = np.asarray(self.normals, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 4 or not np.isfinite(pts).all():
            raise ValueError(f"SurfaceSamples.points_m must be finite with shape (s >= 4, 3); got {pts.shape}")
        if nrm.shape != pts.shape or not np.isfinite(nrm).all():
            raise ValueError(f"SurfaceSamples.normals must be finite with shape {pts.shape}; got {nrm.shape}")
        length = np.linalg.norm(nrm, axis=1)
        if np.abs(length - 1.0).max() > 1e-3:
            raise ValueError(
                f"SurfaceSamples.normals must be unit vectors; lengths range {length.min():.4g}..{length.max():.4g}"
            )
        if not (self.area_m2 > 0 and np.isfinite(self.area_m2)):
            raise ValueError(f"SurfaceSamples.area_m2={self.area_m2!r} is out of range; allowed: 0 < area < inf (m^2)")
        object.__setattr__(self, "points_m", pts)
        object.__setattr__(self, "normals", nrm / length[:, None])

    @classmethod
    def from_mesh(cls, mesh, count: int, seed: int, sdf: SdfFn | None = None) -> SurfaceSamples:
        """``count`` area-uniform samples of a trimesh surface with its face normals (seeded)."""
        import trimesh

        points, faces = trimesh.sample.sample_surface(mesh, int(count), seed=int(seed))
        return cls(np.asarray(points), np.asarray(mesh.face_normals[faces]), float(mesh.area), sdf)


def box_surface(half_extents_m, count: int, seed: int) -> SurfaceSamples:
    """Area-uniform samples of the surface of an axis-aligned box centred at the origin (with its SDF)."""
    half = np.asarray(half_extents_m, dtype=np.float64)
    areas = 4.0 * np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])  # per face of each axis
    rng = np.random.default_rng(seed)
    axis = rng.choice(3, size=count, p=areas / areas.sum())
    sign = rng.choice([-1.0, 1.0], size=count)
    pts = rng.uniform(-1.0, 1.0, (count, 3)) * half
    pts[np.arange(count), axis] = sign * half[axis]
    normals = np.zeros((count, 3))
    normals[np.arange(count), axis] = sign

    def sdf(x: np.ndarray) -> np.ndarray:
        q = np.abs(x) - half
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)

    return SurfaceSamples(pts, normals, float(2.0 * areas.sum()), sdf)


def sphere_surface(radius_m: float, count: int, seed: int) -> SurfaceSamples:
    """Area-uniform samples of a sphere of radius ``radius_m`` centred at the origin (with its SDF)."""
    rng = np.random.default_rng(seed)
    normals = rng.normal(size=(count, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return SurfaceSamples(
        radius_m * normals, normals, 4.0 * np.pi * radius_m**2, lambda x: np.linalg.norm(x, axis=1) - radius_m
    )


def surface_spheres(surface: SurfaceSamples, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Centres (k,3) m and radii (k,) m of up to ``min(count, s)`` spheres touching the surface from inside.

    With an SDF, samples where even a sphere of 5 % of the radius pokes out of the solid (right at an
    edge) are dropped.
    """
    if not isinstance(count, (int, np.integer)) or count < 1:
        raise ValueError(f"count={count!r} is out of range; allowed: integer >= 1")
    k = int(min(count, surface.points_m.shape[0]))
    pick = farthest_point_indices(surface.points_m, k)
    pts, nrm = surface.points_m[pick], surface.normals[pick]
    radius = np.full(k, 0.5 * np.sqrt(surface.area_m2 / k))
    if surface.sdf is not None:
        fitted = np.zeros(k, dtype=bool)
        out = radius.copy()
        # relative to the SDF at the sample itself, so a mesh that is not exactly on the zero level set
        # (marching cubes of a voxel solid) is judged by the level set through its own samples
        level = np.asarray(surface.sdf(pts))
        for factor in _SHRINK_FACTORS:  # loop over a few candidate radii, vectorised over spheres
            s = radius * factor
            fits = ~fitted & (np.asarray(surface.sdf(pts - s[:, None] * nrm)) <= level - _FIT_MARGIN * s)
            out[fits] = s[fits]
            fitted |= fits
        if fitted.sum() >= 4:  # samples within a few % of a sphere radius from an edge: their neighbours cover them
            pts, nrm, out = pts[fitted], nrm[fitted], out[fitted]
        radius = out
    return pts - radius[:, None] * nrm, radius


def farthest_point_indices(points_m: np.ndarray, count: int) -> np.ndarray:
    """Indices (count,) of a farthest-point sampling of ``points_m`` (n,3), deterministic.

    Starts at the point farthest from the centroid, then repeatedly takes the point farthest from all
    chosen ones: extremities (corners, tips, rims) come first, so even a small count keeps an object's
    outline, and the chosen points are evenly spread (no two closer than the final covering radius).
    """
    x = torch.from_numpy(np.ascontiguousarray(points_m, dtype=np.float64))
    n = x.shape[0]
    count = int(min(count, n))
    chosen = torch.empty(count, dtype=torch.int64)
    chosen[0] = torch.argmax((x - x.mean(0)).norm(dim=1))
    dist = (x - x[chosen[0]]).norm(dim=1)
    for i in range(1, count):  # loop over picks, vectorised over points
        chosen[i] = torch.argmax(dist)
        dist = torch.minimum(dist, (x - x[chosen[i]]).norm(dim=1))
    return chosen.numpy()


@dataclass
class ContactPoints:
    """Contact spheres of one object, moved by the object's skinning basis.

    Attributes:
        rest_m: (k,3) sphere centres in the object's rest frame, m.
        radius_m: (k,) sphere radii, m.
        b: (k,4H) affine skinning basis rows (``x = x0 + Tm b``).
        cubature_index: (k,) nearest cubature point of each sphere (rest frame); forces go there.
        num_cubature: number of cubature points of the object.
    """

    rest_m: torch.Tensor
    radius_m: torch.Tensor
    b: torch.Tensor
    cubature_index: torch.Tensor
    num_cubature: int

    @classmethod
    def build(
        cls, centres_m: np.ndarray | torch.Tensor, radii_m: np.ndarray | torch.Tensor, weights: torch.Tensor,
        cubature_rest_m: torch.Tensor,
    ) -> ContactPoints:
        """From sphere centres (k,3), radii (k,), the basis weights at the centres (k,H) and the cubature
        rest positions (m,3)."""
        rest = torch.as_tensor(np.asarray(centres_m, dtype=np.float64))
        cub = np.asarray(cubature_rest_m, dtype=np.float64)
        index = torch.from_numpy(cKDTree(cub).query(rest.numpy())[1].astype(np.int64))
        return cls(
            rest, torch.as_tensor(np.asarray(radii_m, dtype=np.float64)),
            affine_basis(rest, torch.as_tensor(weights, dtype=DTYPE)), index, int(cub.shape[0]),
        )

    @property
    def num_points(self) -> int:
        return int(self.rest_m.shape[0])

    def positions(self, q: torch.Tensor) -> torch.Tensor:
        """World sphere centres (k,3), m, for the reduced state q (q-ordering)."""
        return self.rest_m + displacement_from_tmat(self.b, q.reshape(3, -1))

    def velocities(self, qdot: torch.Tensor) -> torch.Tensor:
        """Sphere centre velocities (k,3), m/s."""
        return displacement_from_tmat(self.b, qdot.reshape(3, -1))

    def to_cubature(
        self, force_n: torch.Tensor, partner: torch.Tensor, strength_n: torch.Tensor, no_partner: int
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """Per-cubature-point contact force (m,3) N (sum of its spheres) and dominant partner id (m,)
        (the partner of its sphere with the strongest contact; ``no_partner`` where none)."""
        return spheres_to_points(self.cubature_index, self.num_cubature, force_n, partner, strength_n, no_partner)


def spheres_to_points(index: torch.Tensor, num_points: int, force_n: torch.Tensor, partner: torch.Tensor,
                      strength_n: torch.Tensor, no_partner: int) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
    """Sphere records onto points: sphere s goes to point ``index[s]`` (< ``num_points``). Per point the summed
    force (num_points, 3) N of its spheres (in sphere order) and the partner of its strongest sphere (strength >
    0; ``no_partner`` where none)."""
    force = torch.zeros(num_points, 3, dtype=DTYPE).index_add_(0, index, force_n)
    best = torch.zeros(num_points, dtype=DTYPE).scatter_reduce(0, index, strength_n, reduce="amax", include_self=True)
    is_best = (strength_n > 0) & (strength_n == best[index])
    out = torch.full((num_points,), no_partner, dtype=torch.int64)
    out[index[is_best]] = partner[is_best]
    return force, out


class CubatureGather:
    """:meth:`ContactPoints.to_cubature` of several objects at once: their spheres' forces, partners and
    strengths concatenated (object order) go to their cubature points through one global index (each object's
    ``cubature_index`` plus the cubature points of the objects before it). Each point sums the same spheres in
    the same order and takes the same partner, so the per-object results are equal bit for bit."""

    def __init__(self, contacts: list[ContactPoints]) -> None:
        counts = [c.num_cubature for c in contacts]
        offsets = [0]
        for count in counts:
            offsets.append(offsets[-1] + count)
        self.counts = counts
        self.total = offsets[-1]
        self.index = (
            torch.cat([c.cubature_index + offsets[k] for k, c in enumerate(contacts)])
            if contacts
            else torch.zeros(0, dtype=torch.int64)
        )

    def to_cubature(self, force_n: list[torch.Tensor], partner: list[torch.Tensor], strength_n: list[torch.Tensor],
                    no_partner: int) -> list[tuple[torch.Tensor, torch.Tensor]]:  # fmt: skip
        """Per object its (m,3) N cubature forces and (m,) dominant partners from its spheres' (k,3) forces, (k,)
        partners and (k,) strengths (N)."""
        if not self.counts:
            return []
        force, out = spheres_to_points(self.index, self.total, torch.cat(force_n), torch.cat(partner),
                                       torch.cat(strength_n), no_partner)  # fmt: skip
        return list(zip(force.split(self.counts), out.split(self.counts)))

