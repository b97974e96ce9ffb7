"""The object asset type: what the simulator and the renderer need to know about one object.

An ``ObjectAsset`` holds a unique name, a semantic category (ids 1-based in
``CATEGORIES`` order; 0 = background), a default material class and allowed
alternatives, a shape in metres (local frame: z up, bounds centred at the
origin), and one procedural texture per part id, or the colours of an imported
mesh, or captured splats.  The simulator takes ``interior_points`` +
``volume_m3`` + a sampled material; the renderer takes surface Gaussians made
from ``to_mesh`` and ``colors_at`` (``gaussians_from_geometry``) or ``splats``.

Hollow objects are closed ``Shell``s: ``volume_m3`` and ``interior_points``
describe the wall material only, while ``to_mesh`` (what is rendered) is the
outer surface only.  Assets are found by name through ``data_gen.assets.registry``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
import trimesh
from numpy.typing import ArrayLike, NDArray

from data_gen.assets.materials import ProceduralTexture, get_material, sample_palette_color
from data_gen.assets.mesh_shape import MeshColors
from data_gen.assets.meshing import solid_volume_m3, surface_mesh
from data_gen.assets.shapes import Scaled, Shape, Shell
from data_gen.gaussians import Gaussians

CATEGORIES: tuple[str, ...] = (
    "ball",
    "container",
    "tableware",
    "footwear",
    "toy",
    "plush_toy",
    "furniture",
    "book",
    "box",
    "sports",
    "food",
    "bedding",
    "cleaning",
    "stationery",
    "bag",
    "tool",
    "imported",  # meshes and splats brought in by users (appended last: earlier ids never change)
)
MIN_SIZE_M, MAX_SIZE_M = 0.005, 5.0


def semantic_id(category: str) -> int:
    """1-based semantic class id of ``category`` (0 is background)."""
    if category not in CATEGORIES:
        raise KeyError(f"unknown category {category!r}; valid categories: {', '.join(CATEGORIES)}")
    return CATEGORIES.index(category) + 1


def semantic_class_table() -> dict[str, str]:
    """World-state ``semantic_classes`` table: {"<id>": category}."""
    return {str(i + 1): c for i, c in enumerate(CATEGORIES)}


@dataclass(frozen=True)
class ObjectAsset:
    """One library object. Lengths in metres; ``textures[k]`` colours the surface owned by part id k."""

    name: str
    category: str
    shape: Shape
    default_material: str
    allowed_materials: tuple[str, ...]
    textures: tuple[ProceduralTexture, ...]
    min_feature_m: float  # thinnest part, sets the default meshing resolution (shell walls excluded)
    mesh_colors: MeshColors | None = field(default=None, compare=False)
    """Colours from an imported mesh's visuals (replace the textures when set)."""
    splats: Gaussians | None = field(default=None, compare=False)
    """Captured splats (local frame, m) rendered instead of sampled surface Gaussians when set."""
    normals_from_mesh: bool = False
    """Surface Gaussians take the mesh's normals instead of the SDF gradient (imported meshes)."""
    source: dict[str, str] | None = field(default=None, compare=False)
    """User assets: provenance (``{"file": file name, "sha256": digest}``); None for library objects."""
    keep_scale: bool = False
    """User assets at their given scale: scenario sampling keeps their size instead of drawing one."""

    def __post_init__(self) -> None:
        semantic_id(self.category)
        get_material(self.default_material)
        for m in self.allowed_materials:
            get_material(m)
        if self.default_material not in self.allowed_materials:
            raise ValueError(
                f"object {self.name!r}: default_material {self.default_material!r} "
                f"must be one of allowed_materials {self.allowed_materials}"
            )
        missing = [p for p in self.shape.part_ids() if not 0 <= p < len(self.textures)]
        if missing:
            raise ValueError(
                f"object {self.name!r}: part ids {missing} have no texture (have {len(self.textures)})"
            )
        if not self.min_feature_m > 0.0:
            raise ValueError(f"object {self.name!r}: min_feature_m must be > 0 m, got {self.min_feature_m}")

    @property
    def semantic_id(self) -> int:
        return semantic_id(self.category)

    @property
    def size_m(self) -> NDArray[np.float64]:
        """(3,) bounding-box size along x, y, z, m."""
        return self.shape.extent_m()

    @property
    def nominal_size_m(self) -> float:
        """Largest bounding-box extent, m."""
        return float(self.size_m.max())

    def scaled_to(self, size_m: float) -> ObjectAsset:
        """The same object scaled uniformly so that its largest extent is ``size_m``."""
        if not (np.isfinite(size_m) and MIN_SIZE_M <= size_m <= MAX_SIZE_M):
            raise ValueError(
                f"object {self.name!r}: size_m must be in [{MIN_SIZE_M}, {MAX_SIZE_M}] m, got {size_m}"
            )
        s = float(size_m) / self.nominal_size_m
        textures = tuple(replace(t, period_m=t.period_m * s) for t in self.textures)
        # one Scaled over the canonical shape, so every size reuses the canonical mesh (meshing.py)
        if isinstance(self.shape, Scaled):
            shape = Scaled(self.shape.child, self.shape.scale * s)
        else:
            shape = Scaled(self.shape, s)
        return replace(
            self,
            shape=shape,
            textures=textures,
            min_feature_m=self.min_feature_m * s,
            mesh_colors=None if self.mesh_colors is None else self.mesh_colors.scaled(s),
            splats=None if self.splats is None else self.splats.scaled(s),
        )

    def with_material_color(self, material: str, rng: np.random.Generator) -> ObjectAsset:
        """Recolour part 0's base colour from ``material``'s palette (other parts unchanged).

        Imported assets with their own colours (mesh colours or splats) keep them; the
        generator still advances by the same draws so downstream draws do not depend on it.
        """
        if material not in self.allowed_materials:
            raise ValueError(
                f"object {self.name!r}: material {material!r} not in allowed {self.allowed_materials}"
            )
        if self.mesh_colors is not None or self.splats is not None:
            sample_palette_color(material, rng)
            return self
        t0 = self.textures[0]
        colors = (sample_palette_color(material, rng),) + tuple(t0.colors[1:])
        return replace(self, textures=(replace(t0, colors=colors),) + self.textures[1:])

    def mesh_spacing_m(self) -> float:
        """Default meshing grid spacing: a quarter of the thinnest feature, between extent/200 and extent/64."""
        longest = self.nominal_size_m
        return float(np.clip(self.min_feature_m / 4.0, longest / 200.0, longest / 64.0))

    def to_mesh(self, spacing_m: float | None = None) -> trimesh.Trimesh:
        """The visible surface (a fresh copy), m: watertight for library objects; the outer wall only for
        shells; an imported mesh as loaded (possibly open)."""
        return surface_mesh(self.shape, spacing_m or self.mesh_spacing_m()).copy()

    def volume_m3(self) -> float:
        """Volume of the material, m^3 (the wall only for hollow objects; mass = density x this)."""
        return solid_volume_m3(self.shape, self.mesh_spacing_m())

    @property
    def is_hollow(self) -> bool:
        """True for closed shells (the shape, maybe scaled, is a ``Shell``)."""
        inner = self.shape.child if isinstance(self.shape, Scaled) else self.shape
        return isinstance(inner, Shell)

    def colors_at(self, points_m: ArrayLike, part_ids: ArrayLike | None = None) -> NDArray[np.float64]:
        """RGB (n, 3) in [0, 1] at local surface points (n, 3), m; part ids from the SDF when not given."""
        p = np.asarray(points_m, np.float64).reshape(-1, 3)
        if self.mesh_colors is not None:
            return self.mesh_colors.colors_at(p)
        parts = self.shape.sdf_and_part(p)[1] if part_ids is None else np.asarray(part_ids)
        out = np.zeros((len(p), 3))
        for k, tex in enumerate(self.textures):  # loop over parts, vectorised over points
            sel = parts == k
            if np.any(sel):
                out[sel] = tex.colors_at(p[sel])
        return out

    def interior_points(
        self, spacing_m: float, rng: np.random.Generator, jitter: float = 0.5
    ) -> NDArray[np.float64]:
        """Points (n, 3) strictly inside the solid on a grid of ``spacing_m`` jittered by ``jitter`` x spacing."""
        if not spacing_m > 0.0:
            raise ValueError(f"interior_points: spacing_m must be > 0 m, got {spacing_m}")
        if not 0.0 <= jitter <= 0.5:
            raise ValueError(f"interior_points: jitter must be in [0, 0.5], got {jitter}")
        lo, hi = self.shape.bounds()
        dims = np.floor((hi - lo) / spacing_m).astype(np.int64) + 1
        if np.prod(dims) > 8_000_000:
            raise ValueError(
                f"interior_points: spacing_m={spacing_m} gives {dims.tolist()} grid points (> 8e6)"
            )
        offset = lo + 0.5 * ((hi - lo) - (dims - 1) * spacing_m)
        axes = [offset[i] + spacing_m * np.arange(dims[i]) for i in range(3)]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
        grid = grid + rng.uniform(-jitter, jitter, grid.shape) * spacing_m
        return grid[self.shape.sdf(grid) < 0.0]
