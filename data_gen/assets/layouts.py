"""Scene layout catalogue: procedural static stages (the ground plane z = 0 plus oriented boxes), as data.

Each builder returns a ``SceneLayout`` (``data_gen.assets.scene_layout``); adding
a layout is adding one builder to ``_LAYOUTS``.  Scenarios look layouts up
through ``data_gen.assets.registry.get_scene_layout``, which also loads captured
3DGS scenes (``ply:`` references, ``data_gen.assets.captured``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from data_gen.assets.materials import ProceduralTexture
from data_gen.assets.scene_layout import PlacementRegion, SceneBox, SceneLayout
from newtphys.rotations import axis_angle_to_quat

# --------------------------------------------------------------------------- #
# Layouts
# --------------------------------------------------------------------------- #
WOOD = ((0.72, 0.52, 0.30), (0.62, 0.42, 0.24), (0.80, 0.62, 0.40))
DARK_WOOD = ((0.45, 0.30, 0.18), (0.38, 0.25, 0.15), (0.52, 0.36, 0.22))


def _planks(colors: tuple = WOOD, period_m: float = 0.12, axis: int = 0, seed: int = 0) -> ProceduralTexture:
    return ProceduralTexture("planks", colors, period_m, axis, 0.3, seed)


def _region_above(
    name: str, box: SceneBox, margin_m: float, z_min_m: float, z_max_m: float
) -> PlacementRegion:
    """Region over an axis-aligned box's top face, shrunk by ``margin_m``, from top + z_min to top + z_max."""
    c, h = np.asarray(box.center_m), np.asarray(box.half_extents_m)
    top = c[2] + h[2]
    return PlacementRegion(
        name,
        (c[0] - h[0] + margin_m, c[1] - h[1] + margin_m, top + z_min_m),
        (c[0] + h[0] - margin_m, c[1] + h[1] - margin_m, top + z_max_m),
    )


def _empty_floor() -> SceneLayout:
    floor = ProceduralTexture("checker", ((0.80, 0.80, 0.78), (0.35, 0.35, 0.38)), 0.25)
    return SceneLayout(
        "empty_floor",
        "floor",
        floor,
        "ceramic",
        (),
        (PlacementRegion("floor", (-0.6, -0.6, 0.1), (0.6, 0.6, 0.9)),),
    )


def _table() -> SceneLayout:
    top = SceneBox("table_top", (0.0, 0.0, 0.735), (0.6, 0.4, 0.015), "wood", _planks(DARK_WOOD, 0.1))
    legs = tuple(
        SceneBox(
            f"table_leg_{i}",
            (0.55 * sx, 0.35 * sy, 0.36),
            (0.025, 0.025, 0.36),
            "wood",
            _planks(DARK_WOOD, 0.05, 2),
        )
        for i, (sx, sy) in enumerate(((-1, -1), (-1, 1), (1, -1), (1, 1)))
    )
    floor = _planks(WOOD, 0.15, 0, seed=3)
    regions = (
        _region_above("table_top", top, 0.12, 0.08, 0.6),
        PlacementRegion("floor_front", (0.8, -0.5, 0.1), (1.3, 0.5, 0.6)),
    )
    return SceneLayout("table", "table", floor, "wood", (top,) + legs, regions)


def _bench_steps() -> SceneLayout:
    grey = ProceduralTexture("noise", ((0.60, 0.60, 0.62),), 0.05, contrast=0.15, seed=5)
    bench = SceneBox("bench", (0.0, 0.6, 0.225), (0.6, 0.18, 0.225), "wood", _planks(WOOD, 0.06, 0, seed=1))
    steps = tuple(
        SceneBox(
            f"step_{i}", (0.0, -0.3 - 0.3 * i, 0.075 * (i + 1)), (0.5, 0.15, 0.075 * (i + 1)), "ceramic", grey
        )
        for i in range(3)
    )
    floor = ProceduralTexture("tiles", ((0.75, 0.72, 0.68), (0.30, 0.30, 0.30)), 0.3, seed=2)
    regions = (
        (_region_above("bench", bench, 0.08, 0.08, 0.6),)
        + tuple(_region_above(f"step_{i}", s, 0.05, 0.08, 0.5) for i, s in enumerate(steps))
        + (PlacementRegion("floor", (0.8, -0.6, 0.1), (1.3, 0.6, 0.6)),)
    )
    return SceneLayout("bench_steps", "bench_steps", floor, "ceramic", (bench,) + steps, regions)


def _shelf_wall() -> SceneLayout:
    wall = SceneBox(
        "wall",
        (-0.5, 0.0, 1.0),
        (0.05, 1.5, 1.0),
        "ceramic",
        ProceduralTexture("noise", ((0.85, 0.83, 0.78),), 0.1, contrast=0.06, seed=7),
    )
    boards = tuple(
        SceneBox(
            f"shelf_{i}",
            (-0.3, 0.0, 0.35 + 0.45 * i),
            (0.15, 0.6, 0.012),
            "wood",
            _planks(WOOD, 0.08, 1, seed=10 + i),
        )
        for i in range(3)
    )
    floor = ProceduralTexture("tiles", ((0.55, 0.45, 0.35), (0.2, 0.18, 0.15)), 0.4, seed=4)
    regions = tuple(_region_above(f"shelf_{i}", b, 0.04, 0.06, 0.3) for i, b in enumerate(boards)) + (
        PlacementRegion("floor", (0.1, -0.8, 0.1), (0.9, 0.8, 0.7)),
    )
    return SceneLayout("shelf_wall", "shelf", floor, "ceramic", (wall,) + boards, regions)


RAMP_ANGLE_DEG = 20.0


def _ramp() -> SceneLayout:
    angle = np.deg2rad(RAMP_ANGLE_DEG)
    half_len, half_thick = 0.6, 0.02
    # the plank rises toward -x: rotate about +y by +angle (x axis tilts down at +x)
    rot = tuple(axis_angle_to_quat((0.0, 1.0, 0.0), angle).tolist())
    cz = half_len * np.sin(angle) + half_thick * np.cos(angle)  # lowest corner touches z = 0
    ramp = SceneBox(
        "ramp", (0.0, 0.0, float(cz)), (half_len, 0.3, half_thick), "wood", _planks(WOOD, 0.1, 0, seed=8), rot
    )
    # a block under the high end whose top meets the plank's underside z = cz - t / cos - x tan at its inner edge
    x_inner = -half_len * np.cos(angle) + 0.1
    support_top = float(cz - half_thick / np.cos(angle) - x_inner * np.tan(angle))
    support = SceneBox(
        "ramp_support",
        (x_inner - 0.05, 0.0, 0.5 * support_top),
        (0.05, 0.3, 0.5 * support_top),
        "wood",
        _planks(DARK_WOOD, 0.1, 2, seed=9),
    )
    floor = ProceduralTexture("noise", ((0.45, 0.55, 0.40),), 0.2, contrast=0.25, seed=6)
    # top surface height along x: z_top(x) = cz + t/cos - x tan(angle); region over the upper third
    x0, x1 = -0.45, -0.2
    z_top = float(cz + half_thick / np.cos(angle) - x0 * np.tan(angle))
    regions = (
        PlacementRegion("ramp_top", (x0, -0.2, z_top + 0.08), (x1, 0.2, z_top + 0.5)),
        PlacementRegion("floor", (0.8, -0.6, 0.1), (1.3, 0.6, 0.6)),
    )
    return SceneLayout("ramp", "ramp", floor, "wood", (ramp, support), regions)


def _room_corner() -> SceneLayout:
    paint = ProceduralTexture("noise", ((0.90, 0.88, 0.82),), 0.15, contrast=0.05, seed=11)
    paint2 = ProceduralTexture("noise", ((0.70, 0.80, 0.88),), 0.15, contrast=0.05, seed=12)
    wall_x = SceneBox("wall_x", (-1.05, 0.0, 1.2), (0.05, 1.5, 1.2), "ceramic", paint)
    wall_y = SceneBox("wall_y", (0.4, -1.05, 1.2), (1.5, 0.05, 1.2), "ceramic", paint2)
    skirting = SceneBox("skirting", (-0.99, 0.0, 0.04), (0.01, 1.5, 0.04), "wood", _planks(DARK_WOOD, 0.1, 1))
    floor = _planks(WOOD, 0.14, 0, seed=13)
    regions = (
        PlacementRegion("corner", (-0.85, -0.85, 0.1), (-0.2, -0.2, 0.9)),
        PlacementRegion("floor", (-0.2, -0.2, 0.1), (0.6, 0.6, 0.7)),
    )
    return SceneLayout("room_corner", "room", floor, "wood", (wall_x, wall_y, skirting), regions)


_LAYOUTS: dict[str, Callable[[], SceneLayout]] = {
    "empty_floor": _empty_floor,
    "table": _table,
    "bench_steps": _bench_steps,
    "shelf_wall": _shelf_wall,
    "ramp": _ramp,
    "room_corner": _room_corner,
}


def list_layouts() -> list[str]:
    """Names of all procedural layouts, in catalogue order."""
    return list(_LAYOUTS)


def layout(name: str) -> SceneLayout:
    """The procedural layout ``name``; an unknown name lists the valid ones."""
    if name not in _LAYOUTS:
        raise KeyError(f"unknown scene layout {name!r}; valid layouts: {', '.join(list_layouts())}")
    return _LAYOUTS[name]()
