"""More scene layouts (18, after the 6 of ``data_gen.assets.layouts``): living room, kitchen, play and gym stages.

Same building blocks as the first catalogue (ground plane z = 0 plus oriented ``SceneBox``es, with free
``PlacementRegion``s above supports), so every layout collides, renders and exports like the others.
Layouts with walls around the drop area (play pen, box pit, hallway) make objects meet walls and each
other more often; furniture (sofa, bed, desk, counter) gives soft and raised supports. The registry
(``data_gen.assets.registry``) lists these after the first catalogue, so earlier layout names keep their
places.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from data_gen.assets.layouts import DARK_WOOD, WOOD, _planks, _region_above
from data_gen.assets.materials import ProceduralTexture
from data_gen.assets.scene_layout import PlacementRegion, SceneBox, SceneLayout
from newtphys.rotations import axis_angle_to_quat

PAINT = ProceduralTexture("noise", ((0.88, 0.86, 0.80),), 0.15, contrast=0.05, seed=21)
CONCRETE = ProceduralTexture("noise", ((0.62, 0.62, 0.60),), 0.08, contrast=0.2, seed=22)
CARPET = ProceduralTexture("noise", ((0.55, 0.30, 0.28),), 0.01, contrast=0.25, seed=23)
GRASS = ProceduralTexture("noise", ((0.32, 0.55, 0.25),), 0.02, contrast=0.35, seed=24)
FABRIC = ProceduralTexture("noise", ((0.30, 0.40, 0.60),), 0.01, contrast=0.15, seed=25)
TILES = ProceduralTexture("tiles", ((0.92, 0.92, 0.90), (0.55, 0.58, 0.60)), 0.2, seed=26)
RUBBER_MAT = ProceduralTexture("noise", ((0.15, 0.16, 0.18),), 0.02, contrast=0.2, seed=27)


def _table_like(name: str, top_center: tuple[float, float, float], top_half: tuple[float, float, float],
                leg_half: float, texture: ProceduralTexture) -> tuple[SceneBox, ...]:
    """A table top and four legs reaching the floor."""
    cx, cy, cz = top_center
    hx, hy, hz = top_half
    leg_h = 0.5 * (cz - hz)
    top = SceneBox(f"{name}_top", top_center, top_half, "wood", texture)
    legs = tuple(SceneBox(f"{name}_leg_{i}", (cx + sx * (hx - 2 * leg_half), cy + sy * (hy - 2 * leg_half), leg_h),
                          (leg_half, leg_half, leg_h), "wood", _planks(DARK_WOOD, 0.05, 2))
                 for i, (sx, sy) in enumerate(((-1, -1), (-1, 1), (1, -1), (1, 1))))
    return (top,) + legs


def _floor_region(name: str, lo_xy: tuple[float, float], hi_xy: tuple[float, float], top: float = 0.8,
                  base: float = 0.0) -> PlacementRegion:
    return PlacementRegion(name, (lo_xy[0], lo_xy[1], base + 0.1), (hi_xy[0], hi_xy[1], base + top))


def _walls_around(half: float, height: float, thick: float, texture: ProceduralTexture,
                  material: str = "wood") -> tuple[SceneBox, ...]:
    """Four walls enclosing the square [-half, half]^2 (inner faces at +-half)."""
    h, t = height / 2, thick / 2
    return (SceneBox("wall_n", (0.0, half + t, h), (half + thick, t, h), material, texture),
            SceneBox("wall_s", (0.0, -half - t, h), (half + thick, t, h), material, texture),
            SceneBox("wall_e", (half + t, 0.0, h), (t, half, h), material, texture),
            SceneBox("wall_w", (-half - t, 0.0, h), (t, half, h), material, texture))


def _coffee_table() -> SceneLayout:
    boxes = _table_like("coffee_table", (0.0, 0.0, 0.43), (0.5, 0.3, 0.02), 0.03, _planks(WOOD, 0.08, 0, seed=31))
    return SceneLayout("coffee_table", "table", CARPET, "fabric", boxes,
                       (_region_above("coffee_table_top", boxes[0], 0.08, 0.08, 0.5),
                        _floor_region("floor_front", (0.7, -0.5), (1.2, 0.5))))


def _desk_wall() -> SceneLayout:
    wall = SceneBox("wall", (-0.9, 0.0, 1.1), (0.05, 1.6, 1.1), "ceramic", PAINT)
    boxes = _table_like("desk", (-0.45, 0.0, 0.74), (0.35, 0.7, 0.02), 0.03, _planks(DARK_WOOD, 0.1, 1, seed=32))
    return SceneLayout("desk_wall", "table", _planks(WOOD, 0.15, 0, seed=33), "wood", (wall,) + boxes,
                       (_region_above("desk_top", boxes[0], 0.08, 0.08, 0.5),
                        _floor_region("floor", (0.2, -0.8), (1.0, 0.8))))


def _kitchen_counter() -> SceneLayout:
    wall = SceneBox("wall", (0.0, 0.95, 1.2), (1.6, 0.05, 1.2), "ceramic", TILES)
    cabinet = SceneBox("cabinet", (0.0, 0.6, 0.44), (1.2, 0.3, 0.44), "wood", _planks(WOOD, 0.3, 2, seed=34))
    top = SceneBox("counter_top", (0.0, 0.58, 0.9), (1.25, 0.33, 0.02), "ceramic",
                   ProceduralTexture("noise", ((0.2, 0.2, 0.22),), 0.03, contrast=0.3, seed=35))
    return SceneLayout("kitchen_counter", "counter", TILES, "ceramic", (wall, cabinet, top),
                       (_region_above("counter_top", top, 0.1, 0.08, 0.45),
                        _floor_region("floor", (-0.8, -0.8), (0.8, 0.1))))


def _two_tables() -> SceneLayout:
    a = _table_like("table_a", (-0.45, 0.0, 0.72), (0.3, 0.35, 0.02), 0.025, _planks(WOOD, 0.08, 0, seed=36))
    b = _table_like("table_b", (0.45, 0.0, 0.45), (0.3, 0.35, 0.02), 0.025, _planks(DARK_WOOD, 0.08, 1, seed=37))
    return SceneLayout("two_tables", "table", CONCRETE, "ceramic", a + b,
                       (_region_above("table_a_top", a[0], 0.07, 0.08, 0.5),
                        _region_above("table_b_top", b[0], 0.07, 0.08, 0.5),
                        _floor_region("floor_front", (-0.6, -1.1), (0.6, -0.55))))


def _steep_ramp() -> SceneLayout:
    angle = np.deg2rad(30.0)
    half_len, half_thick = 0.55, 0.02
    rot = tuple(axis_angle_to_quat((0.0, 1.0, 0.0), angle).tolist())
    cz = half_len * np.sin(angle) + half_thick * np.cos(angle)
    ramp = SceneBox("ramp", (0.0, 0.0, float(cz)), (half_len, 0.3, half_thick), "wood",
                    _planks(WOOD, 0.1, 0, seed=38), rot)
    x_inner = -half_len * np.cos(angle) + 0.1
    support_top = float(cz - half_thick / np.cos(angle) - x_inner * np.tan(angle))
    support = SceneBox("ramp_support", (x_inner - 0.05, 0.0, 0.5 * support_top), (0.05, 0.3, 0.5 * support_top),
                       "wood", _planks(DARK_WOOD, 0.1, 2, seed=39))
    x0, x1 = -0.4, -0.22
    z_top = float(cz + half_thick / np.cos(angle) - x0 * np.tan(angle))
    return SceneLayout("steep_ramp", "ramp", GRASS, "wood", (ramp, support),
                       (PlacementRegion("ramp_top", (x0, -0.2, z_top + 0.08), (x1, 0.2, z_top + 0.45)),
                        _floor_region("floor", (0.8, -0.6), (1.3, 0.6))))


def _ramp_to_wall() -> SceneLayout:
    angle = np.deg2rad(15.0)
    half_len, half_thick = 0.6, 0.02
    rot = tuple(axis_angle_to_quat((0.0, 1.0, 0.0), angle).tolist())
    cz = half_len * np.sin(angle) + half_thick * np.cos(angle)
    ramp = SceneBox("ramp", (0.0, 0.0, float(cz)), (half_len, 0.35, half_thick), "wood",
                    _planks(WOOD, 0.1, 0, seed=40), rot)
    x_inner = -half_len * np.cos(angle) + 0.1
    support_top = float(cz - half_thick / np.cos(angle) - x_inner * np.tan(angle))
    support = SceneBox("ramp_support", (x_inner - 0.05, 0.0, 0.5 * support_top), (0.05, 0.35, 0.5 * support_top),
                       "wood", _planks(DARK_WOOD, 0.1, 2, seed=41))
    wall = SceneBox("stop_wall", (1.2, 0.0, 0.2), (0.05, 0.8, 0.2), "wood", _planks(DARK_WOOD, 0.1, 1, seed=42))
    x0, x1 = -0.45, -0.2
    z_top = float(cz + half_thick / np.cos(angle) - x0 * np.tan(angle))
    return SceneLayout("ramp_to_wall", "ramp", CONCRETE, "ceramic", (ramp, support, wall),
                       (PlacementRegion("ramp_top", (x0, -0.25, z_top + 0.08), (x1, 0.25, z_top + 0.45)),
                        _floor_region("floor", (0.7, -0.6), (1.0, 0.6))))


def _long_stairs() -> SceneLayout:
    steps = tuple(SceneBox(f"step_{i}", (0.0, -0.25 * i, 0.06 * (i + 1)), (0.6, 0.125, 0.06 * (i + 1)),
                           "wood", _planks(WOOD, 0.06, 0, seed=43 + i)) for i in range(5))
    regions = tuple(_region_above(f"step_{i}", s, 0.04, 0.08, 0.5) for i, s in enumerate(steps)) + (
        _floor_region("floor", (-0.6, 0.3), (0.6, 0.9)),)
    return SceneLayout("long_stairs", "stairs", CARPET, "fabric", steps, regions)


def _sofa() -> SceneLayout:
    seat = SceneBox("sofa_seat", (0.0, 0.3, 0.22), (0.8, 0.35, 0.22), "fabric", FABRIC)
    back = SceneBox("sofa_back", (0.0, 0.75, 0.45), (0.8, 0.1, 0.45), "fabric", FABRIC)
    arms = tuple(SceneBox(f"sofa_arm_{i}", (s * 0.9, 0.35, 0.32), (0.1, 0.4, 0.32), "fabric", FABRIC)
                 for i, s in enumerate((-1.0, 1.0)))
    return SceneLayout("sofa", "sofa", _planks(WOOD, 0.12, 0, seed=48), "wood", (seat, back) + arms,
                       (PlacementRegion("sofa_seat", (-0.65, 0.05, 0.52), (0.65, 0.5, 0.9)),
                        _floor_region("floor", (-0.7, -0.8), (0.7, -0.2))))


def _bed() -> SceneLayout:
    frame = SceneBox("bed_frame", (0.0, 0.0, 0.15), (0.75, 1.0, 0.15), "wood", _planks(DARK_WOOD, 0.1, 1, seed=49))
    mattress = SceneBox("mattress", (0.0, 0.0, 0.4), (0.72, 0.97, 0.1), "fabric",
                        ProceduralTexture("stripes", ((0.92, 0.92, 0.95), (0.75, 0.8, 0.9)), 0.08, 0))
    head = SceneBox("headboard", (0.0, 1.05, 0.6), (0.75, 0.05, 0.6), "wood", _planks(WOOD, 0.1, 0, seed=50))
    return SceneLayout("bed", "bed", CARPET, "fabric", (frame, mattress, head),
                       (_region_above("mattress", mattress, 0.1, 0.08, 0.5),
                        _floor_region("floor", (1.0, -0.8), (1.5, 0.6))))


def _play_pen() -> SceneLayout:
    walls = _walls_around(0.6, 0.25, 0.04, ProceduralTexture("stripes", ((0.9, 0.3, 0.3), (0.95, 0.95, 0.9)),
                                                             0.1, 0), "plastic")
    return SceneLayout("play_pen", "enclosure", ProceduralTexture("checker", ((0.3, 0.6, 0.9), (0.95, 0.8, 0.2)),
                                                                  0.3), "foam", walls,
                       (_floor_region("pen", (-0.5, -0.5), (0.5, 0.5), top=0.9),))


def _box_pit() -> SceneLayout:
    walls = _walls_around(0.4, 0.18, 0.03, _planks(WOOD, 0.06, 0, seed=51))
    return SceneLayout("box_pit", "enclosure", CONCRETE, "ceramic", walls,
                       (_floor_region("pit", (-0.3, -0.3), (0.3, 0.3), top=0.9),))


def _hallway() -> SceneLayout:
    walls = tuple(SceneBox(f"wall_{i}", (0.0, s * 0.55, 1.1), (2.0, 0.05, 1.1), "ceramic", PAINT)
                  for i, s in enumerate((-1.0, 1.0)))
    return SceneLayout("hallway", "room", _planks(WOOD, 0.12, 0, seed=52), "wood", walls,
                       (_floor_region("hall", (-0.8, -0.4), (0.8, 0.4)),))


def _pedestal() -> SceneLayout:
    column = SceneBox("pedestal", (0.0, 0.0, 0.45), (0.2, 0.2, 0.45), "ceramic",
                      ProceduralTexture("noise", ((0.95, 0.94, 0.9),), 0.05, contrast=0.05, seed=53))
    return SceneLayout("pedestal", "pedestal", TILES, "ceramic", (column,),
                       (_region_above("pedestal_top", column, 0.06, 0.08, 0.5),
                        _floor_region("floor", (0.4, -0.6), (1.0, 0.6))))


def _bookshelf() -> SceneLayout:
    back = SceneBox("back", (-0.6, 0.0, 0.9), (0.03, 0.7, 0.9), "wood", _planks(DARK_WOOD, 0.1, 2, seed=54))
    sides = tuple(SceneBox(f"side_{i}", (-0.38, s * 0.7, 0.9), (0.18, 0.02, 0.9), "wood",
                           _planks(DARK_WOOD, 0.1, 2, seed=55)) for i, s in enumerate((-1.0, 1.0)))
    boards = tuple(SceneBox(f"board_{i}", (-0.38, 0.0, 0.02 + 0.42 * i), (0.18, 0.68, 0.015), "wood",
                            _planks(WOOD, 0.08, 1, seed=56 + i)) for i in range(4))
    regions = tuple(_region_above(f"board_{i}", b, 0.04, 0.06, 0.25) for i, b in enumerate(boards[1:], 1)) + (
        _floor_region("floor", (0.0, -0.7), (0.8, 0.7)),)
    return SceneLayout("bookshelf", "shelf", _planks(WOOD, 0.14, 0, seed=60), "wood", (back,) + sides + boards,
                       regions)


def _obstacle_floor() -> SceneLayout:
    spots = ((-0.5, 0.3, 0.12), (0.4, 0.45, 0.08), (0.1, -0.5, 0.15), (-0.45, -0.4, 0.06))
    boxes = tuple(SceneBox(f"crate_{i}", (x, y, h), (0.12, 0.12, h), "wood", _planks(WOOD, 0.05, i % 2, seed=61 + i))
                  for i, (x, y, h) in enumerate(spots))
    return SceneLayout("obstacle_floor", "floor", CONCRETE, "ceramic", boxes,
                       (_floor_region("floor", (-0.25, -0.25), (0.25, 0.25), top=0.9),
                        _region_above("crate_0", boxes[0], 0.02, 0.08, 0.5)))


def _stage() -> SceneLayout:
    platform = SceneBox("platform", (0.0, 0.2, 0.1), (0.8, 0.5, 0.1), "wood", _planks(DARK_WOOD, 0.12, 0, seed=65))
    return SceneLayout("stage", "platform", CARPET, "fabric", (platform,),
                       (_region_above("platform", platform, 0.1, 0.08, 0.7),
                        _floor_region("floor", (-0.7, -0.9), (0.7, -0.45))))


def _patio() -> SceneLayout:
    bench = SceneBox("garden_bench", (0.0, 0.6, 0.22), (0.6, 0.2, 0.22), "wood", _planks(WOOD, 0.05, 0, seed=66))
    return SceneLayout("patio", "outdoor", GRASS, "fabric", (bench,),
                       (_region_above("bench", bench, 0.06, 0.08, 0.5),
                        _floor_region("lawn", (-0.6, -0.7), (0.6, 0.25))))


def _gym_floor() -> SceneLayout:
    mats = tuple(SceneBox(f"mat_{i}", (x, 0.0, 0.02), (0.35, 0.6, 0.02), "foam", RUBBER_MAT)
                 for i, x in enumerate((-0.38, 0.38)))
    return SceneLayout("gym_floor", "floor", _planks(WOOD, 0.1, 1, seed=67), "wood", mats,
                       tuple(_region_above(f"mat_{i}", m, 0.05, 0.08, 0.8) for i, m in enumerate(mats)))


def _low_wall_corner() -> SceneLayout:
    wall_x = SceneBox("low_wall_x", (-0.8, 0.0, 0.2), (0.05, 1.0, 0.2), "ceramic", CONCRETE)
    wall_y = SceneBox("low_wall_y", (0.1, -0.8, 0.2), (0.85, 0.05, 0.2), "ceramic", CONCRETE)
    return SceneLayout("low_wall_corner", "room", GRASS, "fabric", (wall_x, wall_y),
                       (_floor_region("corner", (-0.65, -0.65), (-0.1, -0.1), top=0.9),
                        _floor_region("floor", (-0.1, -0.1), (0.6, 0.6))))


VARIANT_LAYOUTS: dict[str, Callable[[], SceneLayout]] = {
    "coffee_table": _coffee_table,
    "desk_wall": _desk_wall,
    "kitchen_counter": _kitchen_counter,
    "two_tables": _two_tables,
    "steep_ramp": _steep_ramp,
    "ramp_to_wall": _ramp_to_wall,
    "long_stairs": _long_stairs,
    "sofa": _sofa,
    "bed": _bed,
    "play_pen": _play_pen,
    "box_pit": _box_pit,
    "hallway": _hallway,
    "pedestal": _pedestal,
    "bookshelf": _bookshelf,
    "obstacle_floor": _obstacle_floor,
    "stage": _stage,
    "patio": _patio,
    "gym_floor": _gym_floor,
    "low_wall_corner": _low_wall_corner,
}


def list_variant_layouts() -> list[str]:
    """Names of these layouts, in catalogue order."""
    return list(VARIANT_LAYOUTS)


def variant_layout(name: str) -> SceneLayout:
    """The layout ``name`` of this catalogue; an unknown name lists the valid ones."""
    if name not in VARIANT_LAYOUTS:
        raise KeyError(f"unknown scene layout {name!r}; valid layouts: {', '.join(list_variant_layouts())}")
    return VARIANT_LAYOUTS[name]()
