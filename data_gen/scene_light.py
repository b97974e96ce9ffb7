"""The light of a scene: one directional key light (a sun) plus uniform ambient light, as data.

A lit render (``data_gen.render.shading``) gives a splat with albedo ``a``, unit
normal ``n`` and shadow visibility ``v`` in [0, 1] the colour

    a * (ambient + intensity * color_rgb * max(0, n . direction) * v)

(clipped to [0, 1]), with ``direction`` the unit vector from the scene *towards*
the light (world frame, z up). Every scene layout carries one
(``SceneLayout.light``, default :data:`DEFAULT_LIGHT`); a captured ``ply:`` scene
takes its direction from the reference's ``light=<x>,<y>,<z>`` option (see
``data_gen.assets.captured``), so that inserted objects are lit and cast shadows
like the capture.

The defaults put a white sun 55 deg above the horizon; an upward floor then
receives ambient + intensity * sin(55 deg) = 0.35 + 0.75 * 0.82 = 0.96 of its
albedo (about the unlit render's brightness) and 0.35 in shadow.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

Vec3 = tuple[float, float, float]

#: Largest key intensity / ambient factor accepted (a factor of the albedo).
MAX_LIGHT_FACTOR = 4.0
#: The key light must stand at least this high above the horizon, degrees (shadows stay finite).
MIN_ELEVATION_DEG = 5.0


def direction_from_angles(azimuth_deg: float, elevation_deg: float) -> Vec3:
    """Unit vector towards a light at ``azimuth_deg`` (from +x towards +y) and ``elevation_deg`` above the horizon."""
    az, el = math.radians(azimuth_deg), math.radians(elevation_deg)
    return (math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el))


@dataclass(frozen=True)
class SceneLight:
    """Directional key light towards ``direction`` (normalised here), ``intensity`` and ``color_rgb``, plus
    ``ambient`` (factors of the albedo, dimensionless)."""

    direction: Vec3 = direction_from_angles(-35.0, 55.0)
    intensity: float = 0.75
    ambient: float = 0.35
    color_rgb: Vec3 = (1.0, 1.0, 1.0)

    def __post_init__(self) -> None:
        d = np.asarray(self.direction, np.float64)
        if d.shape != (3,) or not np.isfinite(d).all() or np.linalg.norm(d) < 1e-9:
            raise ValueError(f"SceneLight.direction must be 3 finite numbers, not all 0; got {self.direction}")
        d = d / np.linalg.norm(d)
        if math.degrees(math.asin(float(np.clip(d[2], -1.0, 1.0)))) < MIN_ELEVATION_DEG:
            raise ValueError(
                f"SceneLight.direction {tuple(self.direction)} points {math.degrees(math.asin(d[2])):.1f} deg above "
                f"the horizon; it must point at least {MIN_ELEVATION_DEG} deg up (towards the light, z up)"
            )
        object.__setattr__(self, "direction", tuple(float(v) for v in d))
        for name in ("intensity", "ambient"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= MAX_LIGHT_FACTOR):
                raise ValueError(f"SceneLight.{name} must be in [0, {MAX_LIGHT_FACTOR}], got {value}")
        c = np.asarray(self.color_rgb, np.float64)
        if c.shape != (3,) or not np.isfinite(c).all() or (c < 0).any() or (c > 1).any():
            raise ValueError(f"SceneLight.color_rgb must be 3 values in [0, 1], got {self.color_rgb}")
        object.__setattr__(self, "color_rgb", tuple(float(v) for v in c))

    @staticmethod
    def parse_direction(text: str, owner: str) -> Vec3:
        """``"x,y,z"`` -> a 3-tuple (validated by the constructor); errors name ``owner`` and the text."""
        parts = text.split(",")
        try:
            values = tuple(float(p) for p in parts)
        except ValueError:
            values = ()
        if len(values) != 3:
            raise ValueError(f"{owner}: light={text!r} must be three numbers x,y,z (towards the light, z up)")
        return (values[0], values[1], values[2])

    def with_direction(self, direction: ArrayLike) -> SceneLight:
        d = np.asarray(direction, np.float64).reshape(-1)
        if d.shape != (3,):
            raise ValueError(f"SceneLight direction must be 3 numbers, got {np.asarray(direction).tolist()}")
        return SceneLight((float(d[0]), float(d[1]), float(d[2])), self.intensity, self.ambient, self.color_rgb)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready record (world state ``scene.light``)."""
        return {
            "direction": list(self.direction),
            "intensity": self.intensity,
            "ambient": self.ambient,
            "color": list(self.color_rgb),
        }


DEFAULT_LIGHT = SceneLight()
