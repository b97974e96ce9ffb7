"""Object library: everyday-like objects built from composed primitives, as data.

Each entry of ``_SPECS`` declares an object: its semantic category, default and
alternative material classes, one procedural texture per part id, the thinnest
feature (which sets the meshing resolution), a builder of its shape (local
frame, z up, centred on its bounds) and, for hollow objects (bottle, can, jar,
cardboard box, bag, balls, rubber duck, traffic cone), a wall thickness: those
become closed ``Shell``s.  ``library_object(name)`` builds the ``ObjectAsset``
(cached); adding an object is adding one entry.

Scenarios look objects up through ``data_gen.assets.registry.get_object``, which
also resolves user assets (``file:`` meshes and ``ply:`` splat objects).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from data_gen.assets.families import FAMILY_SPECS
from data_gen.assets.materials import RGB, ProceduralTexture
from data_gen.assets.object_asset import ObjectAsset
from data_gen.assets.shapes import (
    Box,
    Capsule,
    Cone,
    Cylinder,
    Difference,
    Ellipsoid,
    Intersection,
    Offset,
    RoundedBox,
    Shape,
    Shell,
    Sphere,
    Torus,
    Union,
    place,
)
from newtphys.rotations import axis_angle_to_quat


# --------------------------------------------------------------------------- #
# Building blocks
# --------------------------------------------------------------------------- #
def _solid(rgb: RGB) -> ProceduralTexture:
    return ProceduralTexture("solid", (rgb,))


X_AXIS, Y_AXIS = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
_ALONG_X = axis_angle_to_quat(Y_AXIS, np.deg2rad(90.0))  # maps local z to world x
# maps local z to world -y (axial shapes are symmetric)
_ALONG_Y = axis_angle_to_quat(X_AXIS, np.deg2rad(90.0))


def _centred(shape: Shape) -> Shape:
    lo, hi = shape.bounds()
    c = 0.5 * (lo + hi)
    return place(shape, tuple(-c)) if np.linalg.norm(c) > 1e-12 else shape


def _frustum(z0: float, z1: float, r0: float, r1: float, part_id: int = 0) -> Shape:
    """Solid cone frustum between heights z0 < z1 with radii r0 (at z0) and r1 (at z1), r0 != r1."""
    height = (z1 - z0) * max(r0, r1) / abs(r0 - r1)
    wide_z = z0 if r0 > r1 else z1
    apex_up = r0 > r1
    cone_center_z = wide_z + (height / 2 if apex_up else -height / 2)
    rot = (1.0, 0.0, 0.0, 0.0) if apex_up else axis_angle_to_quat(X_AXIS, np.deg2rad(180.0))
    cone = place(Cone(max(r0, r1), height, part_id), (0.0, 0.0, cone_center_z), rot)
    slab = place(
        Box((max(r0, r1) * 1.5, max(r0, r1) * 1.5, (z1 - z0) / 2), part_id), (0.0, 0.0, (z0 + z1) / 2)
    )
    return Intersection((cone, slab))


@dataclass(frozen=True)
class _Spec:
    category: str
    default_material: str
    alternatives: tuple[str, ...]
    textures: tuple[ProceduralTexture, ...]
    min_feature_m: float
    build: Callable[[], Shape]
    wall_m: float | None = None  # closed hollow object: wall thickness, m (None = solid)


WHITE, BLACK, RED = (0.95, 0.95, 0.95), (0.08, 0.08, 0.08), (0.85, 0.12, 0.10)


def _ball() -> Shape:
    return Sphere(0.11)


def _tennis_ball() -> Shape:
    return Union((Sphere(0.033), Torus(0.0325, 0.002, 1)))


def _rugby_ball() -> Shape:
    return place(Ellipsoid((0.07, 0.07, 0.14)), rotation_wxyz=_ALONG_X)


def _mug() -> Shape:
    body = Cylinder(0.04, 0.05)
    handle = place(Torus(0.025, 0.006), (0.045, 0.0, 0.0), axis_angle_to_quat(X_AXIS, np.deg2rad(90.0)))
    cavity = place(Cylinder(0.034, 0.05, 1), (0.0, 0.0, 0.008))
    return Difference(Union((body, handle)), cavity)


def _bottle() -> Shape:
    return Union(
        (
            Cylinder(0.035, 0.08),
            place(Cylinder(0.0355, 0.03, 2), (0.0, 0.0, -0.01)),
            place(Ellipsoid((0.035, 0.035, 0.035)), (0.0, 0.0, 0.08)),
            place(Cylinder(0.013, 0.025), (0.0, 0.0, 0.115)),
            place(Cylinder(0.015, 0.01, 1), (0.0, 0.0, 0.14)),
        )
    )


def _can() -> Shape:
    return Offset(Cylinder(0.030, 0.058), 0.003)


def _shoe() -> Shape:
    sole = place(RoundedBox((0.14, 0.05, 0.012), 0.008, 1), (0.0, 0.0, -0.03))
    upper = Intersection(
        (
            place(Ellipsoid((0.125, 0.045, 0.05)), (0.005, 0.0, -0.02)),
            place(Box((0.2, 0.1, 0.05)), (0.0, 0.0, 0.02)),
        )
    )
    collar = place(Cylinder(0.04, 0.025), (-0.075, 0.0, 0.01))
    return Union((sole, upper, collar))


def _toy_car() -> Shape:
    parts: list[Shape] = [
        RoundedBox((0.08, 0.035, 0.02), 0.006),
        place(RoundedBox((0.04, 0.03, 0.016), 0.006, 1), (-0.01, 0.0, 0.03)),
    ]
    for x in (-0.05, 0.05):
        for y in (-0.036, 0.036):
            parts.append(place(Cylinder(0.016, 0.007, 2), (x, y, -0.018), _ALONG_Y))
    return Union(tuple(parts))


def _rubber_duck() -> Shape:
    return Union(
        (
            Ellipsoid((0.05, 0.04, 0.035)),
            place(Sphere(0.027), (0.03, 0.0, 0.045)),
            place(Ellipsoid((0.016, 0.012, 0.005), 1), (0.058, 0.0, 0.04)),
            place(Sphere(0.005, 2), (0.05, 0.012, 0.056)),
            place(Sphere(0.005, 2), (0.05, -0.012, 0.056)),
            place(
                Ellipsoid((0.012, 0.008, 0.018)),
                (-0.048, 0.0, 0.022),
                axis_angle_to_quat(Y_AXIS, np.deg2rad(-30.0)),
            ),
        )
    )


def _teddy_bear() -> Shape:
    parts: list[Shape] = [
        Ellipsoid((0.065, 0.065, 0.085)),
        place(Sphere(0.06), (0.0, 0.0, 0.13)),
        place(Ellipsoid((0.028, 0.022, 0.018), 1), (0.053, 0.0, 0.118)),
        place(Sphere(0.008, 2), (0.08, 0.0, 0.124)),
    ]
    for y in (-1.0, 1.0):
        parts.append(place(Sphere(0.022), (0.0, 0.045 * y, 0.18)))
        tilt = axis_angle_to_quat(X_AXIS, np.deg2rad(30.0 * y))
        parts.append(place(Capsule(0.02, 0.03), (0.02, 0.07 * y, 0.03), tilt))
        parts.append(place(Capsule(0.025, 0.025), (0.04, 0.04 * y, -0.075), _ALONG_X))
    return Union(tuple(parts))


def _stool() -> Shape:
    parts: list[Shape] = [
        place(Cylinder(0.15, 0.015), (0.0, 0.0, 0.43)),
        place(Torus(0.127, 0.01, 1), (0.0, 0.0, 0.15)),
    ]
    for x in (-0.09, 0.09):
        for y in (-0.09, 0.09):
            parts.append(place(Cylinder(0.016, 0.22), (x, y, 0.2)))
    return Union(tuple(parts))


def _book() -> Shape:
    return Union((Box((0.11, 0.075, 0.016)), place(Box((0.108, 0.076, 0.0145), 1), (0.003, 0.0, 0.0))))


def _cardboard_box() -> Shape:
    return Union((Box((0.15, 0.11, 0.1)), Box((0.1505, 0.025, 0.1005), 1)))


def _dumbbell() -> Shape:
    return Union(
        (
            place(Cylinder(0.014, 0.11), rotation_wxyz=_ALONG_X),
            place(Cylinder(0.05, 0.025, 1), (0.1, 0.0, 0.0), _ALONG_X),
            place(Cylinder(0.05, 0.025, 1), (-0.1, 0.0, 0.0), _ALONG_X),
        )
    )


def _donut() -> Shape:
    icing = Intersection((Torus(0.045, 0.0235, 1), place(Box((0.1, 0.1, 0.05), 1), (0.0, 0.0, 0.055))))
    return Union((Torus(0.045, 0.022), icing))


def _ring_toy() -> Shape:
    return Torus(0.08, 0.012)


def _pillow() -> Shape:
    return Intersection((RoundedBox((0.25, 0.17, 0.07), 0.06), Ellipsoid((0.3, 0.22, 0.075))))


def _sponge() -> Shape:
    return Union(
        (
            place(RoundedBox((0.055, 0.035, 0.015), 0.004), (0.0, 0.0, -0.005)),
            place(RoundedBox((0.055, 0.035, 0.005), 0.002, 1), (0.0, 0.0, 0.0135)),
        )
    )


def _bowl() -> Shape:
    shell = Intersection((Sphere(0.08), place(Box((0.1, 0.1, 0.0375)), (0.0, 0.0, -0.0375))))
    return Difference(shell, place(Sphere(0.072, 1), (0.0, 0.0, 0.0)))


def _plate() -> Shape:
    return Union((Offset(Cylinder(0.105, 0.003), 0.004), place(Torus(0.1, 0.006, 1), (0.0, 0.0, 0.004))))


def _traffic_cone() -> Shape:
    return Union(
        (place(Cone(0.09, 0.3), (0.0, 0.0, 0.015)), place(Box((0.11, 0.11, 0.01), 1), (0.0, 0.0, -0.14)))
    )


def _pencil() -> Shape:
    return Union(
        (
            place(Cylinder(0.0035, 0.08), rotation_wxyz=_ALONG_X),
            place(Cone(0.0035, 0.02, 1), (0.089, 0.0, 0.0), _ALONG_X),
            place(Cylinder(0.0036, 0.008, 2), (-0.086, 0.0, 0.0), _ALONG_X),
        )
    )


def _bag() -> Shape:
    return Union(
        (
            RoundedBox((0.16, 0.06, 0.12), 0.03),
            place(Torus(0.07, 0.008, 1), (0.0, 0.0, 0.12), axis_angle_to_quat(X_AXIS, np.deg2rad(90.0))),
        )
    )


def _wooden_block() -> Shape:
    return Box((0.05, 0.025, 0.015))


def _dice() -> Shape:
    return RoundedBox((0.008, 0.008, 0.008), 0.0015)


def _paper_cup() -> Shape:
    outer = _frustum(0.0, 0.09, 0.028, 0.04)
    inner = _frustum(0.005, 0.1, 0.0235, 0.0365, 1)
    return Difference(outer, inner)


def _frisbee() -> Shape:
    return Difference(Offset(Cylinder(0.1, 0.01), 0.005), place(Cylinder(0.09, 0.01, 1), (0.0, 0.0, -0.008)))


def _rolling_pin() -> Shape:
    return Union(
        (
            place(Cylinder(0.03, 0.13), rotation_wxyz=_ALONG_X),
            place(Capsule(0.012, 0.04, 1), (0.175, 0.0, 0.0), _ALONG_X),
            place(Capsule(0.012, 0.04, 1), (-0.175, 0.0, 0.0), _ALONG_X),
        )
    )


def _hammer() -> Shape:
    return Union((Capsule(0.013, 0.13), place(Box((0.06, 0.017, 0.017), 1), (0.0, 0.0, 0.15))))


def _flashlight() -> Shape:
    return Union(
        (
            place(Cylinder(0.017, 0.08), rotation_wxyz=_ALONG_X),
            place(Cylinder(0.025, 0.02, 1), (0.09, 0.0, 0.0), _ALONG_X),
            place(Cylinder(0.02, 0.0025, 2), (0.1105, 0.0, 0.0), _ALONG_X),
        )
    )


def _jar() -> Shape:
    return Union((Offset(Cylinder(0.04, 0.055), 0.005), place(Cylinder(0.047, 0.012, 1), (0.0, 0.0, 0.066))))


def _toy_brick() -> Shape:
    parts: list[Shape] = [Box((0.016, 0.008, 0.0048))]
    for x in (-0.012, -0.004, 0.004, 0.012):
        for y in (-0.004, 0.004):
            parts.append(place(Cylinder(0.0024, 0.0011), (x, y, 0.0055)))
    return Union(tuple(parts))


def _spinning_top() -> Shape:
    return Union(
        (
            place(Cone(0.03, 0.04), (0.0, 0.0, -0.02), axis_angle_to_quat(X_AXIS, np.deg2rad(180.0))),
            place(Cylinder(0.03, 0.006), (0.0, 0.0, 0.004)),  # overlaps the cone: no touching faces
            place(Cylinder(0.005, 0.015, 1), (0.0, 0.0, 0.023)),
        )
    )


def _yoga_block() -> Shape:
    return RoundedBox((0.115, 0.075, 0.05), 0.008)


def _tex(
    kind: str, colors: tuple[RGB, ...], period_m: float, axis: int = 0, contrast: float = 0.25, seed: int = 0
) -> ProceduralTexture:
    return ProceduralTexture(kind, colors, period_m, axis, contrast, seed)


_PLASTICS = ("plastic", "rubber")
# name -> _Spec(category, default material, allowed materials, texture per part id, thinnest feature (m), builder)
_SPECS: dict[str, _Spec] = {
    "ball": _Spec(
        "ball",
        "rubber",
        ("rubber", "leather", "plastic", "foam"),
        (_tex("checker", (WHITE, BLACK), 0.07),),
        0.2,
        _ball,
        wall_m=0.003,
    ),
    "tennis_ball": _Spec(
        "ball",
        "rubber",
        ("rubber", "fabric"),
        (_tex("noise", ((0.80, 0.90, 0.20),), 0.01, contrast=0.15), _solid(WHITE)),
        0.006,
        _tennis_ball,
        wall_m=0.0035,
    ),
    "rugby_ball": _Spec(
        "ball",
        "leather",
        ("leather", "rubber"),
        (_tex("noise", ((0.55, 0.30, 0.15),), 0.02, contrast=0.2),),
        0.14,
        _rugby_ball,
        wall_m=0.003,
    ),
    "mug": _Spec(
        "container",
        "ceramic",
        ("ceramic", "plastic", "metal", "glass"),
        (_solid((0.20, 0.40, 0.70)), _solid((0.93, 0.93, 0.90))),
        0.006,
        _mug,
    ),
    "bottle": _Spec(
        "container",
        "plastic",
        ("plastic", "glass"),
        (_solid((0.55, 0.80, 0.90)), _solid((0.10, 0.30, 0.80)), _tex("stripes", (RED, WHITE), 0.02, 2)),
        0.02,
        _bottle,
        wall_m=0.0008,
    ),
    "can": _Spec(
        "container",
        "metal",
        ("metal",),
        (_tex("stripes", (RED, (0.85, 0.85, 0.88)), 0.04, 2),),
        0.06,
        _can,
        wall_m=0.0003,
    ),
    "shoe": _Spec(
        "footwear",
        "leather",
        ("leather", "fabric", "rubber"),
        (_tex("noise", ((0.40, 0.24, 0.12),), 0.01), _solid((0.92, 0.90, 0.85))),
        0.02,
        _shoe,
    ),
    "toy_car": _Spec(
        "toy",
        "plastic",
        ("plastic", "metal", "wood"),
        (_solid(RED), _solid((0.6, 0.8, 0.95)), _solid(BLACK)),
        0.014,
        _toy_car,
    ),
    "rubber_duck": _Spec(
        "toy",
        "rubber",
        _PLASTICS,
        (_solid((0.98, 0.85, 0.10)), _solid((0.95, 0.50, 0.05)), _solid(BLACK)),
        0.01,
        _rubber_duck,
        wall_m=0.0015,
    ),
    "teddy_bear": _Spec(
        "plush_toy",
        "plush",
        ("plush", "fabric"),
        (
            _tex("noise", ((0.60, 0.42, 0.26),), 0.006, contrast=0.2),
            _solid((0.85, 0.75, 0.60)),
            _solid(BLACK),
        ),
        0.016,
        _teddy_bear,
    ),
    "stool": _Spec(
        "furniture",
        "wood",
        ("wood", "metal", "plastic"),
        (_tex("planks", ((0.72, 0.52, 0.30), (0.62, 0.44, 0.26)), 0.05, 0), _solid((0.40, 0.25, 0.14))),
        0.02,
        _stool,
    ),
    "book": _Spec(
        "book",
        "paper",
        ("paper",),
        (_solid((0.15, 0.30, 0.55)), _tex("stripes", ((0.95, 0.93, 0.86), (0.85, 0.83, 0.76)), 0.002, 2)),
        0.029,
        _book,
    ),
    "cardboard_box": _Spec(
        "box",
        "paper",
        ("paper",),
        (_tex("noise", ((0.78, 0.62, 0.42),), 0.02, contrast=0.1), _solid((0.75, 0.70, 0.55))),
        0.05,
        _cardboard_box,
        wall_m=0.0015,
    ),
    "dumbbell": _Spec(
        "sports",
        "metal",
        ("metal", "rubber"),
        (_solid((0.6, 0.6, 0.62)), _solid((0.12, 0.12, 0.12))),
        0.028,
        _dumbbell,
    ),
    "donut": _Spec(
        "food",
        "foam",
        ("foam", "rubber", "plastic", "gel"),
        (_solid((0.85, 0.60, 0.30)), _tex("dots", ((0.95, 0.55, 0.70), (0.30, 0.70, 0.90)), 0.012)),
        0.04,
        _donut,
    ),
    "ring_toy": _Spec(
        "toy",
        "plastic",
        ("plastic", "rubber", "wood"),
        (_tex("stripes", ((0.2, 0.7, 0.3), (0.95, 0.85, 0.1)), 0.03, 0),),
        0.024,
        _ring_toy,
    ),
    "pillow": _Spec(
        "bedding",
        "fabric",
        ("fabric", "plush", "foam"),
        (_tex("stripes", ((0.85, 0.85, 0.92), (0.35, 0.45, 0.70)), 0.04, 0),),
        0.1,
        _pillow,
    ),
    "sponge": _Spec(
        "cleaning",
        "foam",
        ("foam",),
        (_tex("noise", ((0.95, 0.85, 0.35),), 0.004, contrast=0.3), _solid((0.20, 0.55, 0.25))),
        0.01,
        _sponge,
    ),
    "bowl": _Spec(
        "tableware",
        "ceramic",
        ("ceramic", "plastic", "wood", "glass"),
        (_solid((0.70, 0.35, 0.25)), _solid((0.95, 0.94, 0.90))),
        0.008,
        _bowl,
    ),
    "plate": _Spec(
        "tableware",
        "ceramic",
        ("ceramic", "plastic"),
        (_solid((0.96, 0.96, 0.94)), _solid((0.20, 0.35, 0.70))),
        0.012,
        _plate,
    ),
    "traffic_cone": _Spec(
        "sports",
        "rubber",
        ("rubber", "plastic"),
        (_tex("stripes", ((0.98, 0.45, 0.05), WHITE), 0.06, 2), _solid((0.15, 0.15, 0.15))),
        0.02,
        _traffic_cone,
        wall_m=0.003,
    ),
    "pencil": _Spec(
        "stationery",
        "wood",
        ("wood", "plastic"),
        (_solid((0.98, 0.80, 0.10)), _solid((0.90, 0.75, 0.55)), _solid((0.95, 0.55, 0.60))),
        0.004,
        _pencil,
    ),
    "bag": _Spec(
        "bag",
        "leather",
        ("leather", "fabric"),
        (_tex("noise", ((0.45, 0.25, 0.12),), 0.01), _solid((0.2, 0.12, 0.06))),
        0.016,
        _bag,
        wall_m=0.0015,
    ),
    "wooden_block": _Spec(
        "toy",
        "wood",
        ("wood",),
        (_tex("planks", ((0.85, 0.70, 0.48), (0.78, 0.60, 0.40)), 0.01, 0),),
        0.03,
        _wooden_block,
    ),
    "dice": _Spec(
        "toy", "plastic", ("plastic", "wood"), (_tex("dots", (WHITE, BLACK), 0.0053),), 0.016, _dice
    ),
    "paper_cup": _Spec(
        "container",
        "paper",
        ("paper", "plastic"),
        (_tex("stripes", (WHITE, (0.2, 0.5, 0.8)), 0.015, 2), _solid(WHITE)),
        0.006,
        _paper_cup,
    ),
    "frisbee": _Spec(
        "sports",
        "plastic",
        ("plastic", "rubber"),
        (_solid((0.95, 0.35, 0.10)), _solid((0.85, 0.30, 0.08))),
        0.01,
        _frisbee,
    ),
    "rolling_pin": _Spec(
        "tool",
        "wood",
        ("wood", "metal"),
        (_tex("noise", ((0.85, 0.70, 0.50),), 0.02), _solid((0.70, 0.52, 0.32))),
        0.024,
        _rolling_pin,
    ),
    "hammer": _Spec(
        "tool",
        "wood",
        ("wood", "metal"),
        (_tex("noise", ((0.72, 0.52, 0.30),), 0.02), _solid((0.45, 0.45, 0.50))),
        0.026,
        _hammer,
    ),
    "flashlight": _Spec(
        "tool",
        "metal",
        ("metal", "plastic"),
        (_solid((0.15, 0.15, 0.18)), _solid((0.55, 0.56, 0.60)), _solid((0.95, 0.95, 0.80))),
        0.005,
        _flashlight,
    ),
    "jar": _Spec(
        "container",
        "glass",
        ("glass", "ceramic", "plastic"),
        (_solid((0.75, 0.88, 0.90)), _solid((0.85, 0.75, 0.20))),
        0.024,
        _jar,
        wall_m=0.0025,
    ),
    "toy_brick": _Spec("toy", "plastic", ("plastic",), (_solid((0.85, 0.12, 0.10)),), 0.0018, _toy_brick),
    "spinning_top": _Spec(
        "toy",
        "wood",
        ("wood", "plastic", "metal"),
        (_tex("stripes", ((0.9, 0.2, 0.2), (0.95, 0.85, 0.2)), 0.008, 2), _solid((0.6, 0.4, 0.2))),
        0.01,
        _spinning_top,
    ),
    "yoga_block": _Spec(
        "sports",
        "foam",
        ("foam", "wood"),
        (_tex("noise", ((0.45, 0.35, 0.75),), 0.02, contrast=0.1),),
        0.1,
        _yoga_block,
    ),
}


CORE_OBJECTS: tuple[str, ...] = tuple(sorted(_SPECS))
"""The 34 hand-built objects (``object_library: core``); the parametric families add the rest."""
_ALL_SPECS: dict[str, _Spec] = {**_SPECS, **{name: _Spec(*row) for name, row in FAMILY_SPECS.items()}}
if len(_ALL_SPECS) != len(_SPECS) + len(FAMILY_SPECS):
    raise RuntimeError(f"family names repeat core names: {sorted(set(_SPECS) & set(FAMILY_SPECS))}")
LIBRARIES = ("core", "all")


@functools.cache
def _build(name: str) -> ObjectAsset:
    spec = _ALL_SPECS[name]
    alternatives = (
        spec.alternatives
        if spec.default_material in spec.alternatives
        else ((spec.default_material,) + spec.alternatives)
    )
    shape = _centred(spec.build())
    return ObjectAsset(
        name,
        spec.category,
        shape if spec.wall_m is None else Shell(shape, spec.wall_m),
        spec.default_material,
        alternatives,
        spec.textures,
        spec.min_feature_m,
    )


def list_library_objects(library: str = "all") -> list[str]:
    """Names of the library objects, sorted: ``all`` (core and families) or ``core`` (the hand-built 34)."""
    if library not in LIBRARIES:
        raise ValueError(f"object library must be one of {LIBRARIES}, got {library!r}")
    return sorted(_ALL_SPECS) if library == "all" else list(CORE_OBJECTS)


def library_object(name: str) -> ObjectAsset:
    """The library object ``name`` at its canonical size; an unknown name lists the valid ones."""
    if name not in _ALL_SPECS:
        raise KeyError(f"unknown object {name!r}; valid objects: {', '.join(list_library_objects())}")
    return _build(name)
