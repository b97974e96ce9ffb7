"""Material taxonomy at three levels, for names people use: group (4), class (12), specific material.

* level 1 — a coarse group: metal, ceramic or glass, wood or fibre, polymer;
* level 2 — the material class of :mod:`data_gen.assets.materials` (plastic, metal, wood, ...);
* level 3 — the specific everyday material whose typical Young's modulus and density lie nearest the
  sampled ones (e.g. a 200 GPa, 7850 kg/m^3 metal is steel; a 70 GPa, 2700 kg/m^3 one aluminium).

Level 3 is derived from the sampled properties, not drawn, so adding it changed no random stream.
Prototype values (E in Pa, density in kg/m^3) are typical handbook values inside each class's range.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from data_gen.assets.materials import MATERIALS, get_material

GROUPS: dict[str, str] = {
    "metal": "metal",
    "ceramic": "ceramic or glass",
    "glass": "ceramic or glass",
    "wood": "wood or fibre",
    "paper": "wood or fibre",
    "fabric": "wood or fibre",
    "plush": "wood or fibre",
    "leather": "wood or fibre",
    "plastic": "polymer",
    "rubber": "polymer",
    "foam": "polymer",
    "gel": "polymer",
}
"""Level 2 (class) -> level 1 (group)."""

SPECIFIC: dict[str, tuple[tuple[str, float, float], ...]] = {
    "plastic": (("polyethylene", 1.0e9, 950.0), ("polypropylene", 1.5e9, 905.0), ("ABS plastic", 2.3e9, 1050.0),
                ("PET plastic", 2.8e9, 1380.0)),
    "metal": (("aluminium", 7.0e10, 2700.0), ("titanium", 1.1e11, 4500.0), ("steel", 2.0e11, 7850.0)),
    "wood": (("pine", 9.0e9, 500.0), ("oak", 1.2e10, 750.0), ("beech", 1.45e10, 720.0)),
    "ceramic": (("earthenware", 5.5e10, 2000.0), ("stoneware", 7.5e10, 2300.0), ("porcelain", 1.1e11, 2450.0)),
    "paper": (("corrugated cardboard", 6.0e8, 650.0), ("paperboard", 2.0e9, 800.0), ("printing paper", 4.0e9, 950.0)),
    "rubber": (("silicone rubber", 1.5e6, 1150.0), ("natural rubber", 2.5e6, 930.0), ("neoprene", 6.0e6, 1250.0)),
    "foam": (("polyurethane foam", 3.0e4, 35.0), ("memory foam", 1.0e5, 80.0), ("EVA foam", 6.0e5, 150.0)),
    "fabric": (("knitted cotton", 3.0e6, 250.0), ("woven cotton", 2.0e7, 400.0), ("polyester canvas", 8.0e7, 550.0)),
    "plush": (("polyester fibre fill", 5.0e3, 30.0), ("cotton stuffing", 5.0e4, 100.0)),
    "leather": (("suede", 2.0e7, 850.0), ("cowhide", 6.0e7, 1000.0)),
    "glass": (("borosilicate glass", 6.4e10, 2230.0), ("soda-lime glass", 7.2e10, 2500.0)),
    "gel": (("silicone gel", 3.0e3, 1000.0), ("gelatin", 1.5e4, 1050.0), ("agar", 6.0e4, 1020.0)),
}  # fmt: skip
"""Level 2 (class) -> level-3 prototypes (name, Young's modulus Pa, density kg/m^3)."""


@dataclass(frozen=True)
class MaterialTaxonomy:
    level_1: str
    """Coarse group (4)."""
    level_2: str
    """Material class (12)."""
    level_3: str
    """Specific material."""

    def to_dict(self) -> dict[str, str]:
        return {"level_1": self.level_1, "level_2": self.level_2, "level_3": self.level_3}


def classify(material_class: str, young_modulus_pa: float, density_kg_m3: float) -> MaterialTaxonomy:
    """The three levels of a sampled material: the level-3 prototype nearest in (log E, density), each axis
    scaled by the class's own range so that neither dominates."""
    mat = get_material(material_class)
    protos = SPECIFIC[mat.name]
    e_lo, e_hi = np.log10(mat.young_modulus_pa)
    r_lo, r_hi = mat.density_kg_m3
    log_e = np.log10([p[1] for p in protos])
    rho = np.array([p[2] for p in protos])
    d = ((log_e - np.log10(young_modulus_pa)) / max(e_hi - e_lo, 1e-9)) ** 2 + (
        (rho - density_kg_m3) / max(r_hi - r_lo, 1e-9)
    ) ** 2
    return MaterialTaxonomy(GROUPS[mat.name], mat.name, protos[int(np.argmin(d))][0])


def nominal(material_class: str) -> MaterialTaxonomy:
    """Levels of a class's middle material (for static scene parts, which have no sampled properties)."""
    mat = get_material(material_class)
    e = float(np.sqrt(mat.young_modulus_pa[0] * mat.young_modulus_pa[1]))
    return classify(mat.name, e, 0.5 * sum(mat.density_kg_m3))


def level_names(level: int) -> list[str]:
    """Every name of one level (distractor pools), in a fixed order."""
    if level == 1:
        return sorted(set(GROUPS.values()))
    if level == 2:
        return [m.name for m in MATERIALS]
    if level == 3:
        return [p[0] for m in MATERIALS for p in SPECIFIC[m.name]]
    raise ValueError(f"taxonomy level must be 1, 2 or 3, got {level}")
