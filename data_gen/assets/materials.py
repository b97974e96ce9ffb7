"""Material classes as data: elastic ranges, density ranges, colour palettes, procedural textures.

Every material class carries the *true* physical ranges of a family of everyday
materials; the simulator may cap the stiffness it actually uses, but this table
does not. Ids are 1-based (uint8); 0 means "no material" (background).

Orders of magnitude (isotropic, room temperature) follow standard engineering
tables: M. F. Ashby, *Materials Selection in Mechanical Design* (Young's modulus
vs density charts), the CRC Handbook of Chemistry and Physics, and the
Engineering ToolBox tables of moduli, Poisson ratios and densities. Wood is
anisotropic; the range is the along-grain modulus. Paper is paperboard
(in-plane modulus), fabric and leather the tensile modulus of the sheet, plush
and foam the apparent (cellular) modulus of the filled body.

A material is sampled with `sample_material`: E log-uniform, nu and rho uniform,
all from the `numpy.random.Generator` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

RGB = tuple[float, float, float]


@dataclass(frozen=True)
class MaterialClass:
    """One family of materials: id, name, (min, max) ranges in SI units, a base colour palette."""

    id: int
    name: str
    young_modulus_pa: tuple[float, float]
    poisson_ratio: tuple[float, float]
    density_kg_m3: tuple[float, float]
    palette_rgb: tuple[RGB, ...]

    def __post_init__(self) -> None:
        if not 1 <= self.id <= 255:
            raise ValueError(f"material {self.name!r}: id must be in [1, 255] (0 = none), got {self.id}")
        _check_range(self.name, "young_modulus_pa", self.young_modulus_pa, 0.0, np.inf, open_low=True)
        _check_range(self.name, "poisson_ratio", self.poisson_ratio, 0.0, 0.5, open_high=True)
        _check_range(self.name, "density_kg_m3", self.density_kg_m3, 0.0, np.inf, open_low=True)
        if not self.palette_rgb:
            raise ValueError(f"material {self.name!r}: palette_rgb must hold at least one colour")
        pal = np.asarray(self.palette_rgb, np.float64)
        if pal.ndim != 2 or pal.shape[1] != 3 or pal.min() < 0.0 or pal.max() > 1.0:
            raise ValueError(
                f"material {self.name!r}: palette_rgb must be (k, 3) RGB in [0, 1], got {pal.tolist()}"
            )


def _check_range(
    owner: str,
    what: str,
    rng: tuple[float, float],
    low: float,
    high: float,
    open_low: bool = False,
    open_high: bool = False,
) -> None:
    lo, hi = rng
    ok_lo = lo > low if open_low else lo >= low
    ok_hi = hi < high if open_high else hi <= high
    if not (ok_lo and ok_hi and lo <= hi):
        lb = "(" if open_low else "["
        rb = ")" if open_high else "]"
        raise ValueError(
            f"material {owner!r}: {what} range {rng} must satisfy min <= max inside {lb}{low}, {high}{rb}"
        )


# --------------------------------------------------------------------------- #
# The table. E in Pa, nu dimensionless, rho in kg/m^3.
# --------------------------------------------------------------------------- #
MATERIALS: tuple[MaterialClass, ...] = (
    # Thermoplastics (PP, PE-HD, ABS, PS, PET): E ~1-3 GPa, nu ~0.35-0.42, rho 900-1400.
    MaterialClass(
        1,
        "plastic",
        (1.0e9, 3.0e9),
        (0.35, 0.42),
        (900.0, 1400.0),
        ((0.85, 0.12, 0.10), (0.10, 0.35, 0.80), (0.95, 0.80, 0.10), (0.15, 0.65, 0.25), (0.95, 0.95, 0.95)),
    ),
    # Aluminium 69 GPa .. steel 200-210 GPa; nu 0.27-0.34; rho 2700 (Al) .. 7900 (steel).
    MaterialClass(
        2,
        "metal",
        (5.0e10, 2.1e11),
        (0.27, 0.34),
        (2700.0, 7900.0),
        ((0.75, 0.75, 0.78), (0.55, 0.56, 0.60), (0.80, 0.62, 0.30), (0.35, 0.36, 0.40)),
    ),
    # Wood along the grain: pine ~9 GPa, oak ~12 GPa, beech ~14 GPa; nu ~0.3-0.4; rho 350-900.
    MaterialClass(
        3,
        "wood",
        (5.0e9, 1.5e10),
        (0.30, 0.40),
        (350.0, 900.0),
        ((0.72, 0.52, 0.30), (0.55, 0.36, 0.20), (0.85, 0.70, 0.48), (0.40, 0.25, 0.14)),
    ),
    # Household ceramics: earthenware/stoneware ~50 GPa .. porcelain ~100 GPa; nu 0.2-0.26; rho 2000-2600.
    MaterialClass(
        4,
        "ceramic",
        (5.0e10, 1.2e11),
        (0.20, 0.26),
        (2000.0, 2600.0),
        ((0.95, 0.94, 0.90), (0.30, 0.45, 0.60), (0.70, 0.35, 0.25), (0.20, 0.20, 0.22)),
    ),
    # Paper and paperboard (cardboard), in-plane: ~1-5 GPa (corrugated board apparent ~0.5 GPa); rho 600-1000.
    MaterialClass(
        5,
        "paper",
        (5.0e8, 5.0e9),
        (0.20, 0.35),
        (600.0, 1000.0),
        ((0.78, 0.62, 0.42), (0.92, 0.90, 0.85), (0.60, 0.45, 0.30)),
    ),
    # Natural and synthetic rubbers, small strain: 1-10 MPa; nearly incompressible nu 0.45-0.49; rho 900-1300.
    MaterialClass(
        6,
        "rubber",
        (1.0e6, 1.0e7),
        (0.45, 0.49),
        (900.0, 1300.0),
        ((0.95, 0.85, 0.10), (0.15, 0.15, 0.15), (0.85, 0.20, 0.20), (0.20, 0.45, 0.85)),
    ),
    # Polymer foams (PU, PE): apparent modulus 10 kPa .. 1 MPa; nu 0.1-0.35; rho 20-200.
    MaterialClass(
        7,
        "foam",
        (1.0e4, 1.0e6),
        (0.10, 0.35),
        (20.0, 200.0),
        ((0.95, 0.85, 0.35), (0.40, 0.75, 0.45), (0.90, 0.55, 0.20), (0.35, 0.60, 0.90)),
    ),
    # Woven/knitted textiles (cotton, polyester), tensile modulus: ~1-100 MPa; nu 0.2-0.4; bulk rho 200-600.
    MaterialClass(
        8,
        "fabric",
        (1.0e6, 1.0e8),
        (0.20, 0.40),
        (200.0, 600.0),
        ((0.85, 0.85, 0.90), (0.30, 0.40, 0.65), (0.75, 0.30, 0.35), (0.45, 0.60, 0.40)),
    ),
    # Plush / stuffed toys: fibre-fill apparent modulus ~1-100 kPa; nu 0.1-0.3; rho 20-150.
    MaterialClass(
        9,
        "plush",
        (1.0e3, 1.0e5),
        (0.10, 0.30),
        (20.0, 150.0),
        ((0.60, 0.42, 0.26), (0.92, 0.88, 0.80), (0.90, 0.60, 0.70), (0.55, 0.55, 0.58)),
    ),
    # Leather, tensile: ~10-100 MPa; nu 0.3-0.45; rho 800-1100.
    MaterialClass(
        10,
        "leather",
        (1.0e7, 1.0e8),
        (0.30, 0.45),
        (800.0, 1100.0),
        ((0.40, 0.24, 0.12), (0.12, 0.10, 0.09), (0.62, 0.40, 0.22)),
    ),
    # Soda-lime / borosilicate glass: 60-90 GPa; nu 0.2-0.25; rho 2200-2600.
    MaterialClass(
        11,
        "glass",
        (6.0e10, 9.0e10),
        (0.20, 0.25),
        (2200.0, 2600.0),
        ((0.80, 0.90, 0.92), (0.35, 0.60, 0.40), (0.55, 0.40, 0.25)),
    ),
    # Hydrogels (gelatin, agar, silicone gel): 1-100 kPa; nearly incompressible nu 0.45-0.49; rho 1000-1100.
    MaterialClass(
        12,
        "gel",
        (1.0e3, 1.0e5),
        (0.45, 0.49),
        (1000.0, 1100.0),
        ((0.30, 0.85, 0.55), (0.90, 0.30, 0.45), (0.95, 0.75, 0.25)),
    ),
)

_BY_NAME: dict[str, MaterialClass] = {m.name: m for m in MATERIALS}
_BY_ID: dict[int, MaterialClass] = {m.id: m for m in MATERIALS}


def list_materials() -> list[str]:
    """Names of all material classes, in id order."""
    return [m.name for m in MATERIALS]


def get_material(name_or_id: str | int) -> MaterialClass:
    """Look a material class up by name or id; unknown keys list the valid ones."""
    if isinstance(name_or_id, (int, np.integer)):
        if int(name_or_id) not in _BY_ID:
            raise KeyError(f"unknown material id {name_or_id}; valid ids are 1..{len(MATERIALS)}")
        return _BY_ID[int(name_or_id)]
    if name_or_id not in _BY_NAME:
        raise KeyError(f"unknown material {name_or_id!r}; valid materials: {', '.join(list_materials())}")
    return _BY_NAME[name_or_id]


def material_id_table() -> dict[str, str]:
    """World-state ``materials`` table: {"<id>": name}."""
    return {str(m.id): m.name for m in MATERIALS}


def sample_material(
    material_class: str | MaterialClass, rng: np.random.Generator
) -> tuple[float, float, float]:
    """Draw (young_modulus_pa, poisson_ratio, density_kg_m3); E log-uniform, nu and rho uniform."""
    mat = material_class if isinstance(material_class, MaterialClass) else get_material(material_class)
    e_lo, e_hi = mat.young_modulus_pa
    young = float(np.exp(rng.uniform(np.log(e_lo), np.log(e_hi))))
    young = min(max(young, e_lo), e_hi)  # guard exp/log round-off at the bounds
    nu = float(rng.uniform(*mat.poisson_ratio))
    rho = float(rng.uniform(*mat.density_kg_m3))
    return young, nu, rho


def sample_palette_color(
    material_class: str | MaterialClass, rng: np.random.Generator, jitter: float = 0.05
) -> RGB:
    """One colour of the material's palette with a small uniform jitter, clipped to [0, 1]."""
    mat = material_class if isinstance(material_class, MaterialClass) else get_material(material_class)
    if not 0.0 <= jitter <= 0.5:
        raise ValueError(f"jitter must be in [0, 0.5], got {jitter}")
    base = np.asarray(mat.palette_rgb[int(rng.integers(len(mat.palette_rgb)))], np.float64)
    c = np.clip(base + rng.uniform(-jitter, jitter, 3), 0.0, 1.0)
    return (float(c[0]), float(c[1]), float(c[2]))


# --------------------------------------------------------------------------- #
# Appearance: procedural textures (data + a vectorised colour function)
# --------------------------------------------------------------------------- #
TEXTURE_KINDS = ("solid", "checker", "stripes", "planks", "tiles", "noise", "dots")


@dataclass(frozen=True)
class ProceduralTexture:
    """A colour pattern over 3D points (m): ``kind`` in TEXTURE_KINDS, ``period_m`` the pattern size.

    ``colors`` are the pattern's RGB colours in [0, 1] (the first is the base).
    ``axis`` is the stripe/plank direction (0 = x, 1 = y, 2 = z). ``seed`` fixes
    the lattice noise, so a texture is a pure function of the points.
    """

    kind: str = "solid"
    colors: tuple[RGB, ...] = ((0.7, 0.7, 0.7),)
    period_m: float = 0.1
    axis: int = 0
    contrast: float = 0.25
    seed: int = 0

    def __post_init__(self) -> None:
        if self.kind not in TEXTURE_KINDS:
            raise ValueError(f"texture kind {self.kind!r} unknown; valid kinds: {', '.join(TEXTURE_KINDS)}")
        if not self.period_m > 0.0:
            raise ValueError(f"texture period_m must be > 0 m, got {self.period_m}")
        if self.axis not in (0, 1, 2):
            raise ValueError(f"texture axis must be 0, 1 or 2, got {self.axis}")
        if not 0.0 <= self.contrast <= 1.0:
            raise ValueError(f"texture contrast must be in [0, 1], got {self.contrast}")
        c = np.asarray(self.colors, np.float64)
        if c.ndim != 2 or c.shape[1] != 3 or len(c) == 0 or c.min() < 0.0 or c.max() > 1.0:
            raise ValueError(
                f"texture colors must be a non-empty (k, 3) RGB list in [0, 1], got {self.colors}"
            )

    def colors_at(self, points_m: ArrayLike) -> NDArray[np.float64]:
        """RGB (n, 3) in [0, 1] at points (n, 3), m."""
        p = np.asarray(points_m, np.float64).reshape(-1, 3)
        pal = np.asarray(self.colors, np.float64)
        c0 = pal[0]
        c1 = pal[1] if len(pal) > 1 else c0 * (1.0 - self.contrast)
        s = p / self.period_m
        if self.kind == "solid":
            return np.broadcast_to(c0, p.shape).copy()
        if self.kind == "checker":
            parity = (np.floor(s).astype(np.int64).sum(axis=1) & 1).astype(bool)
            return np.where(parity[:, None], c1, c0)
        if self.kind == "stripes":
            parity = (np.floor(s[:, self.axis]).astype(np.int64) & 1).astype(bool)
            return np.where(parity[:, None], c1, c0)
        if self.kind == "dots":
            frac = s - np.floor(s) - 0.5
            inside = np.linalg.norm(frac, axis=1) < 0.3
            return np.where(inside[:, None], c1, c0)
        if self.kind == "noise":
            n = _value_noise(s, self.seed)
            return np.clip(c0[None, :] * (1.0 + self.contrast * (2.0 * n[:, None] - 1.0)), 0.0, 1.0)
        if self.kind == "planks":
            return _planks(s, pal, self.axis, self.contrast, self.seed)
        # tiles: square tiles of the first colour with grout lines of the second colour
        grout = 0.06
        frac = s - np.floor(s)
        line = np.any((frac < grout) | (frac > 1.0 - grout), axis=1)
        n = _value_noise(np.floor(s), self.seed)  # per-tile shade
        tile = c0[None, :] * (1.0 + 0.5 * self.contrast * (2.0 * n[:, None] - 1.0))
        return np.clip(np.where(line[:, None], c1, tile), 0.0, 1.0)


def _hash01(cells: NDArray[np.int64], seed: int) -> NDArray[np.float64]:
    """Deterministic pseudo-random value in [0, 1) per integer lattice cell (n, 3)."""
    c = cells.astype(np.uint64)
    h = (c[:, 0] * np.uint64(73856093)) ^ (c[:, 1] * np.uint64(19349663)) ^ (c[:, 2] * np.uint64(83492791))
    h ^= np.uint64(seed * 2654435761 % (2**32))
    h = (h ^ (h >> np.uint64(13))) * np.uint64(0x5BD1E995)
    h ^= h >> np.uint64(15)
    return (h % np.uint64(1 << 24)).astype(np.float64) / float(1 << 24)


def _value_noise(s: NDArray[np.float64], seed: int) -> NDArray[np.float64]:
    """Trilinear lattice value noise in [0, 1] at scaled points s (n, 3)."""
    base = np.floor(s).astype(np.int64)
    f = s - base
    w = f * f * (3.0 - 2.0 * f)  # smoothstep weights
    out = np.zeros(len(s))
    for corner in range(8):  # eight lattice corners, vectorised over points
        off = np.array([(corner >> 0) & 1, (corner >> 1) & 1, (corner >> 2) & 1], np.int64)
        wc = np.prod(np.where(off[None, :] == 1, w, 1.0 - w), axis=1)
        out += wc * _hash01(base + off, seed)
    return out


def _planks(
    s: NDArray[np.float64], pal: NDArray[np.float64], axis: int, contrast: float, seed: int
) -> NDArray[np.float64]:
    """Wood planks: boards along ``axis``, one board per period across it, shade per board + grain."""
    across = (axis + 1) % 3
    board = np.floor(s[:, across]).astype(np.int64)
    length = 4.0  # board length in periods
    offset = _hash01(np.stack([board, board * 0, board * 0 + 1], 1), seed)
    seg = np.floor(s[:, axis] / length + offset).astype(np.int64)
    shade = _hash01(np.stack([board, seg, board * 0], 1), seed + 1)
    base = pal[np.minimum((shade * len(pal)).astype(np.int64), len(pal) - 1)]
    grain = 0.5 + 0.5 * np.sin(2.0 * np.pi * (s[:, across] * 6.0 + 0.8 * _value_noise(s * 2.0, seed)))
    frac = s[:, across] - board
    seam = (frac < 0.03) | (frac > 0.97)
    col = base * (1.0 - 0.5 * contrast * grain[:, None])
    col = np.where(seam[:, None], col * 0.5, col)
    return np.clip(col, 0.0, 1.0)
