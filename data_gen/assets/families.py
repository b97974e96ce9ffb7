"""Parametric object families: variants of a few composed shapes with their own dimensions, colours and textures.

The core library (``data_gen.assets.library``) holds 34 hand-built objects. These families add 75 more, so a
benchmark-scale dataset (11K sequences) repeats names and appearances less: balls, plush animals, soft
food and gel toys, cushions, containers, blocks, sports gear, tableware, tools, boxes, books and footwear.
Each variant is one row of ``FAMILY_SPECS``: a name (its display name is the name in words), a semantic
category of ``object_asset.CATEGORIES`` (none added: semantic ids do not change), a default material and
alternatives, one procedural texture per part id, the thinnest feature (sets the meshing resolution), a
builder with the variant's dimensions (m) and, for hollow variants, a wall thickness.

Shapes use the same primitives and composition as the core library; they are centred on their bounds by
the library builder. Nothing here draws random numbers: adding a family changed no random stream of the
scenarios that draw from the core library (``object_library: core``).
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from data_gen.assets.materials import RGB, ProceduralTexture
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
    Sphere,
    Torus,
    Union,
    place,
)
from newtphys.rotations import axis_angle_to_quat

X_AXIS, Y_AXIS = (1.0, 0.0, 0.0), (0.0, 1.0, 0.0)
ALONG_X = tuple(axis_angle_to_quat(Y_AXIS, np.deg2rad(90.0)).tolist())
ALONG_Y = tuple(axis_angle_to_quat(X_AXIS, np.deg2rad(90.0)).tolist())

# one row: category, default material, alternatives, textures per part, thinnest feature (m), builder, wall (m)
FamilyRow = tuple[str, str, tuple[str, ...], tuple[ProceduralTexture, ...], float, Callable[[], Shape], float | None]

WHITE: RGB = (0.95, 0.95, 0.95)
BLACK: RGB = (0.08, 0.08, 0.08)


def solid(rgb: RGB) -> ProceduralTexture:
    return ProceduralTexture("solid", (rgb,))


def tex(kind: str, colors: tuple[RGB, ...], period_m: float, axis: int = 0, contrast: float = 0.25,
        seed: int = 0) -> ProceduralTexture:
    return ProceduralTexture(kind, colors, period_m, axis, contrast, seed)


# --------------------------------------------------------------------------- #
# Builders (dimensions in m; each returns a closure so a row stays one line)
# --------------------------------------------------------------------------- #
def ball(radius: float, seam: float | None = None) -> Callable[[], Shape]:
    """A sphere; with ``seam`` a thin equatorial ring of part 1 (a seam or a band)."""
    if seam is None:
        return lambda: Sphere(radius)
    return lambda: Union((Sphere(radius), Torus(radius - 0.3 * seam, seam, 1)))


def ovoid(a: float, b: float, c: float) -> Callable[[], Shape]:
    return lambda: Ellipsoid((a, b, c))


def rounded_box(x: float, y: float, z: float, r: float) -> Callable[[], Shape]:
    """Half extents x, y, z and edge radius r."""
    return lambda: RoundedBox((x, y, z), r)


def banded_box(x: float, y: float, z: float, band: float) -> Callable[[], Shape]:
    """A box with a band (part 1) around its middle: a gift box's ribbon, a book's spine."""
    return lambda: Union((Box((x, y, z)), Box((x + 0.0008, band, z + 0.0008), 1)))


def lidded_box(x: float, y: float, z: float, lid: float) -> Callable[[], Shape]:
    """A box with a slightly wider lid (part 1) on top."""
    return lambda: Union((Box((x, y, z)), place(Box((x + 0.003, y + 0.003, lid), 1), (0.0, 0.0, z - lid + 0.001))))


def drum(r: float, h: float, rounding: float = 0.0) -> Callable[[], Shape]:
    """A cylinder of radius r and half height h, its edges rounded by ``rounding``."""
    if rounding > 0:
        return lambda: Offset(Cylinder(r - rounding, h - rounding), rounding)
    return lambda: Cylinder(r, h)


def can(r: float, h: float, lid: float) -> Callable[[], Shape]:
    """A cylinder with rims (part 1) at both ends."""
    return lambda: Union((Cylinder(r, h), place(Cylinder(r + 0.002, lid, 1), (0.0, 0.0, h - lid)),
                          place(Cylinder(r + 0.002, lid, 1), (0.0, 0.0, -h + lid))))


def bottle(r: float, h: float, neck_r: float, neck_h: float) -> Callable[[], Shape]:
    """A body cylinder with a rounded shoulder and a neck with a cap (part 1)."""
    def build() -> Shape:
        return Union((Offset(Cylinder(r - 0.004, h - 0.004), 0.004),
                      place(Ellipsoid((r, r, 0.6 * r)), (0.0, 0.0, h)),
                      place(Cylinder(neck_r, neck_h), (0.0, 0.0, h + 0.5 * r + neck_h)),
                      place(Cylinder(neck_r + 0.002, 0.5 * neck_h, 1), (0.0, 0.0, h + 0.5 * r + 2.2 * neck_h))))
    return build


def frustum(z0: float, z1: float, r0: float, r1: float, part_id: int = 0) -> Shape:
    """Solid cone frustum between heights z0 < z1 with radii r0 (at z0) and r1 (at z1), r0 != r1."""
    height = (z1 - z0) * max(r0, r1) / abs(r0 - r1)
    wide_z = z0 if r0 > r1 else z1
    apex_up = r0 > r1
    cone_z = wide_z + (height / 2 if apex_up else -height / 2)
    rot = (1.0, 0.0, 0.0, 0.0) if apex_up else tuple(axis_angle_to_quat(X_AXIS, np.deg2rad(180.0)).tolist())
    cone = place(Cone(max(r0, r1), height, part_id), (0.0, 0.0, cone_z), rot)
    slab = place(Box((max(r0, r1) * 1.5, max(r0, r1) * 1.5, (z1 - z0) / 2), part_id), (0.0, 0.0, (z0 + z1) / 2))
    return Intersection((cone, slab))


def marker_cone(r: float, height: float) -> Callable[[], Shape]:
    """A cone on a square base plate (part 1)."""
    return lambda: Union((place(Cone(r, height), (0.0, 0.0, 0.5 * height + 0.008)),
                          place(Box((1.1 * r, 1.1 * r, 0.008), 1), (0.0, 0.0, 0.0))))


def tapered(r_bottom: float, r_top: float, height: float) -> Callable[[], Shape]:
    """A solid frustum (flower pot, bucket seen closed, pudding, cone marker)."""
    return lambda: frustum(0.0, height, r_bottom, r_top)


def cup(r_bottom: float, r_top: float, height: float, wall: float, handle: bool = False) -> Callable[[], Shape]:
    """An open tapered cup (part 1 inside); with a handle (torus) on +x."""
    def build() -> Shape:
        outer = frustum(0.0, height, r_bottom, r_top)
        inner = frustum(wall, height + wall, r_bottom - wall, r_top - wall + wall * (r_top - r_bottom) / height, 1)
        body = Difference(outer, inner)
        if not handle:
            return body
        ring = place(Torus(0.28 * height, 0.12 * wall + 0.004), (0.5 * (r_bottom + r_top) + 0.2 * height, 0.0,
                                                                  0.5 * height), tuple(axis_angle_to_quat(X_AXIS, np.deg2rad(90.0)).tolist()))
        return Union((body, ring))
    return build


def disc(r: float, h: float, rim: float) -> Callable[[], Shape]:
    """A flat disc with a raised rim (part 1): saucers, lids, pucks."""
    return lambda: Union((Offset(Cylinder(r - h, 1e-4 + 0.0), h), place(Torus(r - rim, rim, 1), (0.0, 0.0, 0.5 * h))))


def ring(major: float, minor: float) -> Callable[[], Shape]:
    return lambda: Torus(major, minor)


def washer(r_out: float, r_in: float, h: float) -> Callable[[], Shape]:
    """A thick disc with a hole (weight plate, tape roll)."""
    return lambda: Difference(Cylinder(r_out, h), Cylinder(r_in, 2 * h, 1))


def rod(r: float, half_len: float, tip: float = 0.0) -> Callable[[], Shape]:
    """A capsule along x; with ``tip`` a cap cylinder (part 1) at +x."""
    if tip <= 0:
        return lambda: place(Capsule(r, half_len), rotation_wxyz=ALONG_X)
    return lambda: Union((place(Capsule(r, half_len), rotation_wxyz=ALONG_X),
                          place(Cylinder(r * 1.15, tip, 1), (half_len + 0.3 * r, 0.0, 0.0), ALONG_X)))


def dome(r: float, height: float) -> Callable[[], Shape]:
    """The top ``height`` of an ellipsoid (jelly dome, bread bun, mouse)."""
    return lambda: Intersection((Ellipsoid((r, r, height)), place(Box((r * 1.2, r * 1.2, height * 0.6)),
                                                                  (0.0, 0.0, height * 0.6))))


def wedge(x: float, y: float, z: float) -> Callable[[], Shape]:
    """The half of a box (half extents x, y, z) below its diagonal plane through (-x, ., -z) and (x, ., z):
    a triangular prism (cheese wedge, door stop, triangle block)."""
    def build() -> Shape:
        n = np.array([-z, 0.0, x]) / np.hypot(x, z)  # unit normal of the cut, pointing to the removed half
        big = 2.0 * max(x, y, z)
        rot = tuple(axis_angle_to_quat(Y_AXIS, float(np.arctan2(-z, x))).tolist())  # local z -> n
        return Intersection((Box((x, y, z)), place(Box((big, big, big)), tuple((-n * big).tolist()), rot)))
    return build


def arch(x: float, y: float, z: float, hole: float) -> Callable[[], Shape]:
    """A block with a half-cylinder cut from below (toy arch, bridge block)."""
    return lambda: Difference(Box((x, y, z)), place(Cylinder(hole, 2 * y, 1), (0.0, 0.0, -z), ALONG_Y))


def animal(body: tuple[float, float, float], head: float, ear: tuple[float, float, float],
           ear_gap: float, snout: float = 0.0) -> Callable[[], Shape]:
    """A plush animal: body ellipsoid, head sphere on top, two ears (part 1), optional snout (part 2)."""
    bx, by, bz = body

    def build() -> Shape:
        hz = bz + 0.7 * head
        parts: list[Shape] = [Ellipsoid(body), place(Sphere(head), (0.0, 0.0, hz))]
        for s in (-1.0, 1.0):
            parts.append(place(Ellipsoid(ear, 1), (0.0, s * ear_gap, hz + head + 0.6 * ear[2])))
            parts.append(place(Capsule(0.35 * by, 0.5 * bz), (0.55 * bx, s * 0.75 * by, -0.45 * bz),
                               ALONG_X))  # feet
        if snout > 0:
            parts.append(place(Sphere(snout, 2), (head * 0.9, 0.0, hz - 0.2 * head)))
        return Union(tuple(parts))
    return build


def octopus(head: float, leg: float) -> Callable[[], Shape]:
    def build() -> Shape:
        parts: list[Shape] = [place(Sphere(head), (0.0, 0.0, 0.8 * head))]
        for k in range(8):
            a = 2 * np.pi * k / 8
            parts.append(place(Capsule(0.28 * head, leg), (0.75 * head * np.cos(a), 0.75 * head * np.sin(a),
                                                           0.1 * head), tuple(axis_angle_to_quat(
                (-np.sin(a), np.cos(a), 0.0), np.deg2rad(70.0)).tolist()), ))
        return Union(tuple(parts))
    return build


def kettlebell(r: float) -> Callable[[], Shape]:
    return lambda: Union((Sphere(r), place(Torus(0.55 * r, 0.16 * r, 1), (0.0, 0.0, 1.05 * r), ALONG_Y)))


def teapot(r: float) -> Callable[[], Shape]:
    def build() -> Shape:
        spout = place(Capsule(0.14 * r, 0.45 * r), (1.05 * r, 0.0, 0.35 * r),
                      tuple(axis_angle_to_quat(Y_AXIS, np.deg2rad(50.0)).tolist()))
        handle = place(Torus(0.45 * r, 0.09 * r), (-1.0 * r, 0.0, 0.1 * r), ALONG_Y)
        lid = place(Sphere(0.18 * r, 1), (0.0, 0.0, 0.78 * r))
        return Union((Ellipsoid((r, r, 0.8 * r)), spout, handle, lid))
    return build


def pot(r: float, h: float, wall: float) -> Callable[[], Shape]:
    """A cooking pot: open cylinder (inside part 1) with two side handles."""
    def build() -> Shape:
        body = Difference(Cylinder(r, h), place(Cylinder(r - wall, h, 1), (0.0, 0.0, wall + 0.002)))
        handles = [place(Box((0.25 * r, 0.12 * r, 0.04 * r + 0.003)), (s * (r + 0.2 * r), 0.0, 0.7 * h))
                   for s in (-1.0, 1.0)]
        return Union((body, *handles))
    return build


def vase(r: float, h: float, neck: float) -> Callable[[], Shape]:
    return lambda: Union((Ellipsoid((r, r, h)), place(Cylinder(neck, 0.5 * h, 1), (0.0, 0.0, h))))


def tool(handle_r: float, handle_len: float, head: tuple[float, float, float]) -> Callable[[], Shape]:
    """A handle (capsule along x) with a box head (part 1) at +x: screwdriver, spatula, brush."""
    return lambda: Union((place(Capsule(handle_r, handle_len), rotation_wxyz=ALONG_X),
                          place(Box(head, 1), (handle_len + head[0], 0.0, 0.0))))


def vehicle(x: float, y: float, z: float, wheel: float) -> Callable[[], Shape]:
    """A toy vehicle: body box, cabin (part 1), four wheels (part 2)."""
    def build() -> Shape:
        parts: list[Shape] = [RoundedBox((x, y, z), 0.2 * z), place(RoundedBox((0.45 * x, 0.9 * y, 0.8 * z),
                                                                               0.2 * z, 1), (-0.2 * x, 0.0, 1.6 * z))]
        for sx in (-0.65, 0.65):
            for sy in (-1.0, 1.0):
                parts.append(place(Cylinder(wheel, 0.35 * wheel, 2), (sx * x, sy * (y + 0.2 * wheel), -z), ALONG_Y))
        return Union(tuple(parts))
    return build


def boot(length: float, height: float) -> Callable[[], Shape]:
    def build() -> Shape:
        sole = place(RoundedBox((length, 0.36 * length, 0.08 * length), 0.05 * length, 1),
                     (0.0, 0.0, -0.3 * height))
        foot = place(Ellipsoid((0.95 * length, 0.34 * length, 0.3 * height)), (0.05 * length, 0.0, -0.2 * height))
        shaft = place(Cylinder(0.3 * length, 0.5 * height), (-0.55 * length, 0.0, 0.25 * height))
        return Union((sole, foot, shaft))
    return build


def fruit(r: float, stem: float) -> Callable[[], Shape]:
    """A slightly squashed sphere with a stem (part 1)."""
    return lambda: Union((Ellipsoid((r, r, 0.9 * r)), place(Cylinder(0.08 * r, stem, 1), (0.0, 0.0, 0.9 * r + stem))))


def banana(r: float, length: float) -> Callable[[], Shape]:
    def build() -> Shape:
        parts = []
        for k, a in enumerate(np.linspace(-0.5, 0.5, 4)):
            c = (length * np.sin(a) * 0.5, 0.0, -length * 0.5 * (1 - np.cos(a)))
            parts.append(place(Capsule(r * (1.0 - 0.25 * abs(a)), 0.18 * length), c,
                               tuple(axis_angle_to_quat(Y_AXIS, np.pi / 2 + a).tolist())))
        return Union(tuple(parts))
    return build


def star_pillow(r: float, thick: float) -> Callable[[], Shape]:
    """Five rounded lobes around a centre disc (a star cushion)."""
    def build() -> Shape:
        parts: list[Shape] = [Offset(Cylinder(0.5 * r - thick, 1e-4), thick)]
        for k in range(5):
            a = 2 * np.pi * k / 5
            parts.append(place(Ellipsoid((0.55 * r, 0.25 * r, thick)), (0.5 * r * np.cos(a), 0.5 * r * np.sin(a), 0.0),
                               tuple(axis_angle_to_quat((0.0, 0.0, 1.0), a).tolist())))
        return Union(tuple(parts))
    return build


def stapler(x: float, y: float, z: float) -> Callable[[], Shape]:
    return lambda: Union((RoundedBox((x, y, 0.3 * z), 0.2 * z),
                          place(RoundedBox((0.95 * x, 0.8 * y, 0.35 * z), 0.2 * z, 1), (0.0, 0.0, 0.55 * z))))


def skateboard(x: float, y: float, wheel: float) -> Callable[[], Shape]:
    def build() -> Shape:
        parts: list[Shape] = [RoundedBox((x, y, 0.012), 0.008)]
        for sx in (-0.7, 0.7):
            for sy in (-0.7, 0.7):
                parts.append(place(Cylinder(wheel, 0.6 * wheel, 1), (sx * x, sy * y, -0.012 - 1.2 * wheel), ALONG_Y))
            parts.append(place(Box((0.015, 0.7 * y, 0.6 * wheel), 1), (sx * x, 0.0, -0.012 - 0.5 * wheel)))
        return Union(tuple(parts))
    return build


# --------------------------------------------------------------------------- #
# The families
# --------------------------------------------------------------------------- #
ORANGE: RGB = (0.90, 0.45, 0.10)
_SOFT = ("foam", "gel", "plush")
FAMILY_SPECS: dict[str, FamilyRow] = {
    # balls
    "beach_ball": ("ball", "plastic", ("plastic", "rubber"),
                   (tex("stripes", ((0.95, 0.2, 0.2), WHITE, (0.2, 0.4, 0.9), (0.98, 0.85, 0.1)), 0.05, 0),), 0.2,
                   ball(0.15), 0.002),
    "basketball": ("ball", "rubber", ("rubber", "leather"), (tex("noise", (ORANGE,), 0.01, contrast=0.15),
                                                               solid(BLACK)), 0.2, ball(0.12, 0.003), 0.004),
    "soccer_ball": ("ball", "leather", ("leather", "rubber"), (tex("checker", (WHITE, BLACK), 0.05),), 0.2,
                    ball(0.11), 0.004),
    "volleyball": ("ball", "leather", ("leather", "rubber"),
                   (tex("stripes", (WHITE, (0.95, 0.8, 0.1), (0.1, 0.3, 0.8)), 0.06, 2),), 0.2, ball(0.105), 0.003),
    "bowling_ball": ("ball", "plastic", ("plastic",), (tex("noise", ((0.15, 0.2, 0.6),), 0.03, contrast=0.4),),
                     0.2, ball(0.108), None),
    "stress_ball": ("ball", "foam", ("foam", "gel"), (tex("noise", ((0.95, 0.30, 0.55),), 0.01, contrast=0.1),),
                    0.06, ball(0.035), None),
    "bouncy_ball": ("ball", "rubber", ("rubber",), (tex("dots", ((0.2, 0.8, 0.3), (0.9, 0.9, 0.2)), 0.01),), 0.03,
                    ball(0.02), None),
    "golf_ball": ("ball", "plastic", ("plastic", "rubber"), (tex("dots", (WHITE, (0.85, 0.85, 0.85)), 0.004),),
                  0.04, ball(0.021), None),
    "marble": ("ball", "glass", ("glass",), (tex("noise", ((0.3, 0.6, 0.9),), 0.006, contrast=0.5),), 0.02,
               ball(0.008), None),
    "gel_ball": ("ball", "gel", ("gel",), (tex("noise", ((0.40, 0.85, 0.75),), 0.02, contrast=0.1),), 0.08,
                 ball(0.05), None),
    "foam_ball": ("ball", "foam", ("foam",), (tex("noise", ((0.98, 0.6, 0.1),), 0.005, contrast=0.2),), 0.12,
                  ball(0.07), None),
    "medicine_ball": ("ball", "rubber", ("rubber", "leather"), (solid((0.15, 0.15, 0.17)), solid((0.8, 0.1, 0.1))),
                      0.2, ball(0.14, 0.006), None),
    # plush animals (soft)
    "plush_bunny": ("plush_toy", "plush", ("plush", "fabric"), (tex("noise", (WHITE,), 0.006, contrast=0.1),
                                                                solid((0.95, 0.7, 0.75)), solid(BLACK)), 0.02,
                    animal((0.06, 0.05, 0.07), 0.05, (0.012, 0.02, 0.05), 0.022, 0.012), None),
    "plush_cat": ("plush_toy", "plush", ("plush", "fabric"), (tex("stripes", (ORANGE, (0.95, 0.7, 0.4)), 0.02, 2),
                                                              solid((0.95, 0.6, 0.3)), solid((0.9, 0.5, 0.6))),
                  0.02, animal((0.07, 0.05, 0.06), 0.05, (0.02, 0.02, 0.02), 0.03, 0.01), None),
    "plush_dog": ("plush_toy", "plush", ("plush", "fabric"), (tex("noise", ((0.55, 0.40, 0.28),), 0.008),
                                                              solid((0.35, 0.22, 0.14)), solid(BLACK)), 0.02,
                  animal((0.08, 0.055, 0.065), 0.055, (0.025, 0.012, 0.03), 0.05, 0.02), None),
    "plush_panda": ("plush_toy", "plush", ("plush", "fabric"), (solid(WHITE), solid(BLACK), solid(BLACK)), 0.02,
                    animal((0.075, 0.07, 0.08), 0.06, (0.02, 0.02, 0.02), 0.045, 0.015), None),
    "plush_frog": ("plush_toy", "plush", ("plush", "fabric"), (solid((0.3, 0.7, 0.25)), solid(WHITE),
                                                               solid((0.85, 0.3, 0.35))), 0.02,
                   animal((0.08, 0.07, 0.05), 0.05, (0.015, 0.015, 0.015), 0.03, 0.015), None),
    "plush_octopus": ("plush_toy", "plush", ("plush", "fabric"), (tex("dots", ((0.6, 0.3, 0.7), (0.8, 0.6, 0.9)),
                                                                      0.02),), 0.02, octopus(0.06, 0.05), None),
    "plush_elephant": ("plush_toy", "plush", ("plush", "fabric"), (solid((0.6, 0.62, 0.7)), solid((0.85, 0.7, 0.75)),
                                                                   solid((0.5, 0.52, 0.6))), 0.02,
                       animal((0.09, 0.07, 0.07), 0.06, (0.008, 0.045, 0.035), 0.06, 0.025), None),
    # soft food and gel toys
    "jelly_cube": ("food", "gel", ("gel",), (tex("noise", ((0.9, 0.2, 0.3),), 0.03, contrast=0.1),), 0.05,
                   rounded_box(0.04, 0.04, 0.04, 0.008), None),
    "jelly_dome": ("food", "gel", ("gel",), (tex("noise", ((0.3, 0.8, 0.3),), 0.03, contrast=0.1),), 0.05,
                   dome(0.06, 0.05), None),
    "pudding": ("food", "gel", ("gel", "foam"), (tex("noise", ((0.85, 0.65, 0.30),), 0.02, contrast=0.1),), 0.05,
                tapered(0.045, 0.035, 0.05), None),
    "marshmallow": ("food", "foam", ("foam",), (tex("noise", ((0.98, 0.95, 0.92),), 0.01, contrast=0.05),), 0.03,
                    drum(0.02, 0.02, 0.006), None),
    "bread_loaf": ("food", "foam", ("foam",), (tex("noise", ((0.78, 0.52, 0.25),), 0.02, contrast=0.2),), 0.08,
                   rounded_box(0.12, 0.06, 0.05, 0.035), None),
    "bread_bun": ("food", "foam", ("foam",), (tex("noise", ((0.85, 0.6, 0.3),), 0.02, contrast=0.2),), 0.05,
                  dome(0.05, 0.04), None),
    "cheese_wedge": ("food", "foam", ("foam", "gel"), (tex("dots", ((0.98, 0.85, 0.3), (0.9, 0.75, 0.2)), 0.012),),
                     0.02, wedge(0.06, 0.035, 0.03), None),
    "apple": ("food", "foam", ("foam", "gel"), (tex("noise", ((0.8, 0.1, 0.1),), 0.03, contrast=0.2),
                                                solid((0.35, 0.25, 0.1))), 0.008, fruit(0.04, 0.008), None),
    "orange_fruit": ("food", "foam", ("foam",), (tex("noise", (ORANGE,), 0.004, contrast=0.15),
                                                 solid((0.2, 0.5, 0.15))), 0.008, fruit(0.04, 0.004), None),
    "banana": ("food", "foam", ("foam", "gel"), (tex("noise", ((0.95, 0.85, 0.2),), 0.03, contrast=0.1),), 0.03,
               banana(0.017, 0.18), None),
    "egg": ("food", "ceramic", ("ceramic", "gel"), (tex("noise", ((0.95, 0.9, 0.8),), 0.01, contrast=0.05),), 0.05,
            ovoid(0.022, 0.022, 0.03), 0.001),
    "watermelon_slice": ("food", "gel", ("gel", "foam"), (tex("dots", ((0.9, 0.25, 0.3), BLACK), 0.015),), 0.03,
                         wedge(0.08, 0.02, 0.05), None),
    # cushions and bedding (soft)
    "square_cushion": ("bedding", "foam", ("foam", "fabric", "plush"),
                       (tex("checker", ((0.2, 0.5, 0.6), (0.9, 0.9, 0.85)), 0.05),), 0.08,
                       rounded_box(0.2, 0.2, 0.06, 0.05), None),
    "bolster": ("bedding", "foam", ("foam", "fabric", "plush"), (tex("stripes", ((0.8, 0.7, 0.5), WHITE), 0.04, 0),),
                0.1, rod(0.07, 0.2), None),
    "floor_cushion": ("bedding", "foam", ("foam", "plush"), (tex("noise", ((0.7, 0.3, 0.3),), 0.03),), 0.06,
                      drum(0.2, 0.05, 0.04), None),
    "star_pillow": ("bedding", "plush", ("plush", "fabric"), (solid((0.98, 0.85, 0.25)),), 0.04,
                    star_pillow(0.15, 0.035), None),
    "mattress_pad": ("bedding", "foam", ("foam",), (tex("tiles", ((0.95, 0.95, 0.98), (0.8, 0.85, 0.95)), 0.06),),
                     0.05, rounded_box(0.25, 0.15, 0.03, 0.02), None),
    # containers
    "soup_can": ("container", "metal", ("metal",), (tex("stripes", ((0.9, 0.9, 0.85), (0.8, 0.15, 0.1)), 0.05, 2),
                                                    solid((0.7, 0.7, 0.72))), 0.04, can(0.037, 0.05, 0.004), 0.0003),
    "paint_can": ("container", "metal", ("metal",), (solid((0.7, 0.72, 0.75)), solid((0.3, 0.3, 0.35))), 0.06,
                  can(0.06, 0.07, 0.006), 0.0004),
    "water_bottle": ("container", "plastic", ("plastic", "metal"), (solid((0.3, 0.6, 0.9)), solid(WHITE)), 0.02,
                     bottle(0.035, 0.09, 0.015, 0.015), 0.001),
    "wine_bottle": ("container", "glass", ("glass",), (solid((0.15, 0.35, 0.15)), solid((0.6, 0.1, 0.15))), 0.02,
                    bottle(0.037, 0.1, 0.013, 0.035), 0.003),
    "flower_pot": ("container", "ceramic", ("ceramic", "plastic"),
                   (tex("noise", ((0.75, 0.38, 0.22),), 0.03, contrast=0.1),), 0.05, tapered(0.05, 0.07, 0.12), None),
    "vase": ("container", "ceramic", ("ceramic", "glass"), (tex("stripes", ((0.2, 0.35, 0.7), WHITE), 0.03, 2),
                                                            solid((0.2, 0.35, 0.7))), 0.03, vase(0.07, 0.1, 0.03),
             0.004),
    "thermos": ("container", "metal", ("metal", "plastic"), (solid((0.6, 0.15, 0.15)), solid(BLACK)), 0.04,
                can(0.04, 0.12, 0.015), 0.001),
    "tin_box": ("box", "metal", ("metal",), (tex("checker", ((0.8, 0.1, 0.1), (0.95, 0.8, 0.2)), 0.03),
                                             solid((0.85, 0.7, 0.2))), 0.03, lidded_box(0.08, 0.06, 0.035, 0.01),
                0.0005),
    "lunch_box": ("container", "plastic", ("plastic",), (solid((0.2, 0.7, 0.4)), solid((0.95, 0.95, 0.3))), 0.04,
                  lidded_box(0.1, 0.07, 0.04, 0.012), 0.002),
    "bucket": ("container", "plastic", ("plastic", "metal"), (solid((0.2, 0.4, 0.8)), solid((0.15, 0.3, 0.6))), 0.008,
               cup(0.1, 0.13, 0.2, 0.006), None),
    # blocks and toys
    "cube_block": ("toy", "wood", ("wood", "plastic", "foam"), (tex("planks", ((0.9, 0.75, 0.5), (0.8, 0.65, 0.4)),
                                                                    0.01, 0),), 0.06, rounded_box(0.03, 0.03, 0.03, 0.002),
                   None),
    "cylinder_block": ("toy", "wood", ("wood", "plastic"), (solid((0.2, 0.5, 0.85)),), 0.05, drum(0.025, 0.04, 0.002),
                       None),
    "arch_block": ("toy", "wood", ("wood", "plastic"), (solid((0.9, 0.2, 0.2)), solid((0.9, 0.2, 0.2))), 0.02,
                   arch(0.06, 0.02, 0.035, 0.03), None),
    "triangle_block": ("toy", "wood", ("wood", "plastic", "foam"), (solid((0.95, 0.8, 0.1)),), 0.02,
                       wedge(0.04, 0.02, 0.03), None),
    "foam_cube": ("toy", "foam", ("foam",), (tex("checker", ((0.2, 0.6, 0.9), (0.95, 0.5, 0.1)), 0.03),), 0.1,
                  rounded_box(0.06, 0.06, 0.06, 0.01), None),
    "foam_cylinder": ("toy", "foam", ("foam",), (solid((0.9, 0.3, 0.6)),), 0.08, drum(0.05, 0.08, 0.01), None),
    "stacking_ring": ("toy", "plastic", ("plastic", "wood", "foam"), (solid((0.1, 0.6, 0.9)),), 0.03,
                      ring(0.05, 0.018), None),
    "toy_truck": ("toy", "plastic", ("plastic", "metal"), (solid((0.95, 0.75, 0.1)), solid((0.2, 0.5, 0.85)),
                                                           solid(BLACK)), 0.02, vehicle(0.09, 0.04, 0.03, 0.022),
                  None),
    "toy_bus": ("toy", "plastic", ("plastic", "metal"), (solid((0.9, 0.15, 0.15)), solid((0.85, 0.9, 0.95)),
                                                         solid(BLACK)), 0.02, vehicle(0.12, 0.04, 0.04, 0.02), None),
    "squishy_toy": ("toy", "gel", ("gel", "foam"), (tex("dots", ((0.95, 0.6, 0.8), WHITE), 0.015), solid(WHITE),
                                                    solid(BLACK)), 0.02,
                    animal((0.05, 0.045, 0.04), 0.04, (0.012, 0.012, 0.012), 0.02, 0.01), None),
    # sports
    "kettlebell": ("sports", "metal", ("metal",), (solid((0.2, 0.2, 0.22)), solid((0.25, 0.25, 0.27))), 0.03,
                   kettlebell(0.08), None),
    "weight_plate": ("sports", "metal", ("metal", "rubber"), (solid((0.15, 0.15, 0.17)), solid((0.3, 0.3, 0.3))),
                     0.03, washer(0.11, 0.025, 0.015), None),
    "hockey_puck": ("sports", "rubber", ("rubber",), (solid(BLACK),), 0.05, drum(0.038, 0.0127, 0.002), None),
    "cone_marker": ("sports", "plastic", ("plastic", "rubber"), (solid((0.98, 0.5, 0.1)), solid((0.9, 0.4, 0.1))),
                    0.016, marker_cone(0.06, 0.14), None),
    "skateboard": ("sports", "wood", ("wood", "plastic"), (tex("planks", ((0.75, 0.55, 0.35), (0.6, 0.4, 0.25)),
                                                               0.03, 0), solid((0.9, 0.9, 0.85))), 0.024,
                   skateboard(0.3, 0.1, 0.027), None),
    "yoga_mat_roll": ("sports", "foam", ("foam", "rubber"), (tex("noise", ((0.4, 0.75, 0.6),), 0.02),), 0.1,
                      rod(0.06, 0.22), None),
    # tableware
    "teacup": ("tableware", "ceramic", ("ceramic", "glass"), (solid(WHITE), solid((0.8, 0.5, 0.6))), 0.008,
               cup(0.03, 0.045, 0.06, 0.005, handle=True), None),
    "saucer": ("tableware", "ceramic", ("ceramic", "plastic"), (solid(WHITE), solid((0.2, 0.4, 0.8))), 0.01,
               disc(0.07, 0.006, 0.005), None),
    "teapot": ("tableware", "ceramic", ("ceramic", "metal"), (tex("dots", ((0.95, 0.95, 0.9), (0.3, 0.5, 0.8)), 0.02),
                                                              solid((0.3, 0.5, 0.8))), 0.02, teapot(0.08), None),
    "cooking_pot": ("tableware", "metal", ("metal", "ceramic"), (solid((0.7, 0.72, 0.75)), solid((0.5, 0.5, 0.52))),
                    0.008, pot(0.1, 0.07, 0.006), None),
    "plastic_tumbler": ("tableware", "plastic", ("plastic", "glass"), (solid((0.9, 0.4, 0.2)), solid((0.95, 0.6, 0.4))),
                        0.008, cup(0.03, 0.04, 0.11, 0.004), None),
    # tools and stationery
    "eraser": ("stationery", "rubber", ("rubber",), (solid((0.95, 0.6, 0.65)),), 0.02,
               rounded_box(0.025, 0.012, 0.008, 0.003), None),
    "marker_pen": ("stationery", "plastic", ("plastic",), (solid(WHITE), solid((0.1, 0.3, 0.8))), 0.02,
                   rod(0.009, 0.06, 0.02), None),
    "tape_roll": ("stationery", "plastic", ("plastic", "paper"), (tex("stripes", ((0.7, 0.6, 0.4), (0.8, 0.7, 0.5)),
                                                                      0.004, 2), solid((0.9, 0.9, 0.85))), 0.02,
                  washer(0.05, 0.035, 0.024), None),
    "stapler": ("stationery", "metal", ("metal", "plastic"), (solid((0.2, 0.2, 0.25)), solid((0.8, 0.1, 0.1))), 0.01,
                stapler(0.08, 0.02, 0.03), None),
    "screwdriver": ("tool", "plastic", ("plastic", "wood"), (solid((0.9, 0.3, 0.1)), solid((0.7, 0.7, 0.72))), 0.008,
                    tool(0.014, 0.05, (0.05, 0.004, 0.004)), None),
    "scrub_brush": ("cleaning", "wood", ("wood", "plastic"), (tex("planks", ((0.8, 0.6, 0.4), (0.7, 0.5, 0.3)), 0.02,
                                                                  0), solid((0.2, 0.5, 0.9))), 0.02,
                    stapler(0.07, 0.03, 0.03), None),
    "spray_bottle": ("cleaning", "plastic", ("plastic",), (solid((0.3, 0.7, 0.95)), solid(WHITE)), 0.02,
                     bottle(0.04, 0.08, 0.018, 0.03), 0.0015),
    "soap_bar": ("cleaning", "foam", ("foam", "gel"), (tex("noise", ((0.95, 0.9, 0.6),), 0.02, contrast=0.05),),
                 0.03, rounded_box(0.045, 0.03, 0.015, 0.01), None),
    # boxes, books, furniture, footwear
    "gift_box": ("box", "paper", ("paper",), (tex("dots", ((0.8, 0.1, 0.2), (0.95, 0.85, 0.2)), 0.02),
                                              solid((0.95, 0.85, 0.2))), 0.02, banded_box(0.07, 0.07, 0.05, 0.012),
                 0.0015),
    "shoe_box": ("box", "paper", ("paper",), (solid((0.9, 0.5, 0.2)), solid((0.95, 0.95, 0.9))), 0.03,
                 lidded_box(0.15, 0.09, 0.055, 0.015), 0.0015),
    "tissue_box": ("box", "paper", ("paper",), (tex("stripes", ((0.5, 0.75, 0.9), WHITE), 0.02, 0),), 0.05,
                   rounded_box(0.11, 0.06, 0.05, 0.004), 0.0015),
    "cereal_box": ("box", "paper", ("paper",), (tex("checker", ((0.95, 0.75, 0.1), (0.85, 0.2, 0.15)), 0.06),), 0.06,
                   rounded_box(0.095, 0.035, 0.14, 0.003), 0.0015),
    "notebook": ("book", "paper", ("paper",), (solid((0.1, 0.55, 0.4)), solid((0.95, 0.93, 0.86))), 0.015,
                 banded_box(0.105, 0.075, 0.008, 0.07), None),
    "dictionary": ("book", "paper", ("paper",), (solid((0.5, 0.1, 0.1)), solid((0.95, 0.93, 0.86))), 0.04,
                   banded_box(0.12, 0.085, 0.03, 0.08), None),
    "wooden_crate": ("furniture", "wood", ("wood", "plastic"), (tex("planks", ((0.8, 0.65, 0.45), (0.7, 0.55, 0.35)),
                                                                    0.04, 0), solid((0.6, 0.45, 0.3))), 0.05,
                     lidded_box(0.15, 0.1, 0.09, 0.02), None),
    "footstool": ("furniture", "wood", ("wood", "plastic"), (tex("planks", ((0.7, 0.5, 0.3), (0.6, 0.42, 0.25)), 0.05, 0),),
                  0.06, rounded_box(0.15, 0.1, 0.1, 0.02), None),
    "boot": ("footwear", "leather", ("leather", "rubber"), (tex("noise", ((0.35, 0.22, 0.12),), 0.01),
                                                            solid((0.15, 0.12, 0.1))), 0.02, boot(0.13, 0.16), None),
    "slipper": ("footwear", "plush", ("plush", "fabric", "foam"), (tex("noise", ((0.9, 0.8, 0.85),), 0.005,
                                                                       contrast=0.1), solid((0.7, 0.6, 0.65))), 0.02,
                boot(0.12, 0.05), None),
}


def family_names() -> list[str]:
    """Names of every family variant, sorted."""
    return sorted(FAMILY_SPECS)
