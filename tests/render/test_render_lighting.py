"""Lighting: a box's shadow on the floor where geometry puts it, shading that turns with the object,
captured scenes relit by shadows only, and determinism."""

import dataclasses

import numpy as np
import pytest
from scipy import ndimage

from data_gen.assets.gaussians_from_geometry import box_gaussians, floor_gaussians
from data_gen.assets.materials import ProceduralTexture
from data_gen.assets.scene_layout import PlacementRegion, SceneBox, SceneLayout
from data_gen.gaussians import Gaussians, concatenate
from data_gen.render.labels import LabelRasterizer
from data_gen.render.lighting import SceneLighting
from data_gen.render.rgb import RgbRasterizer
from data_gen.render.shading import shade, shade_parts, shade_parts_on
from data_gen.render.shadow_map import fit_light_view
from data_gen.scene_light import SceneLight
from newtphys.geometry import intrinsics_from_fov, look_at
from newtphys.rotations import axis_angle_to_quat, quat_to_matrix

FLOOR_ALBEDO = 0.8
BOX_HALF_M = 0.1  # a 20 cm cube resting on the floor, centred on the z axis
LIGHT = SceneLight(direction=(1.0, 0.0, 1.0), intensity=0.75, ambient=0.35)  # 45 deg up, towards +x
H, W = 144, 192


def _solid(value: float) -> ProceduralTexture:
    return ProceduralTexture("solid", ((value, value, value),))


def box_on_floor() -> Gaussians:
    """Floor (part 0, 1 m half extent, 1 cm grid) and the cube (part 1) on it."""
    layout = SceneLayout("t", "floor", _solid(FLOOR_ALBEDO), "ceramic", (),
                         (PlacementRegion("r", (-0.5, -0.5, 0.1), (0.5, 0.5, 0.9)),), floor_half_extent_m=1.0)
    box = SceneBox("cube", (0.0, 0.0, BOX_HALF_M), (BOX_HALF_M,) * 3, "wood", _solid(0.5))
    return concatenate([floor_gaussians(layout, 0.01), box_gaussians(box, 0.01, 1)])


def top_view() -> tuple[np.ndarray, np.ndarray]:
    return intrinsics_from_fov(50.0, H, W), look_at((0.0, -0.3, 2.0), (0.0, 0.0, 0.0))


def floor_points(K: np.ndarray, w2c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World (x, y) (H, W) where each pixel centre's ray meets the floor z = 0."""
    u, v = np.meshgrid(np.arange(W) + 0.5, np.arange(H) + 0.5)
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1)
    d = d_cam @ w2c[:3, :3]  # R^T d
    eye = -w2c[:3, :3].T @ w2c[:3, 3]
    s = -eye[2] / d[..., 2]
    return eye[0] + s * d[..., 0], eye[1] + s * d[..., 1]


def render_lit(g: Gaussians, lighting: SceneLighting | None, K, w2c) -> np.ndarray:
    rasterizer = RgbRasterizer(H, W)
    if lighting is None:
        return rasterizer.render(g, K, w2c, background_rgb=(0.0, 0.0, 0.0))[0]
    index, depth = LabelRasterizer(H, W, depth_mode="surface").render(g, K, w2c)
    return lighting.render_rgb(rasterizer, g, K, w2c, index, depth, g.part_ids > 0)


@pytest.mark.parametrize("shadow_test", ["pixel", "splat"])
def test_box_shadow_darkens_the_floor_where_geometry_puts_it(shadow_test: str) -> None:
    """Light 45 deg above the horizon towards +x: the shadow of the 20 cm cube on the floor is the strip
    x in [-0.1 - 0.2 tan(45 deg), -0.1] = [-0.3, -0.1], |y| <= 0.1 (the cube's top edge at x = -0.1,
    z = 0.2 reaches the floor 0.2 m further along -x). Floor pixels are told apart by the label map; each
    one's floor point is where its pixel ray meets z = 0."""
    g = box_on_floor()
    K, w2c = top_view()
    lighting = SceneLighting(LIGHT, shadows=True, shadow_map_px=512, shadow_bias_m=0.01, shadow_test=shadow_test)
    rgb = render_lit(g, lighting, K, w2c)
    index, _ = LabelRasterizer(H, W).render(g, K, w2c)
    box_px = (index >= 0) & (g.part_ids[np.maximum(index, 0)] == 1)
    # floor pixels away from the cube's outline (a pixel there blends the cube's edge splats into the floor)
    floor_px = (index >= 0) & ~ndimage.binary_dilation(box_px, iterations=3)
    x, y = floor_points(K, w2c)
    # the cube's edge splats cover ~1.13 sigma = 0.85 cm beyond its faces, and the light's camera (50 radii
    # away) widens the shadow by up to 0.6 cm; per splat, a pixel also blends splats ~2 sigma = 1.5 cm away
    margin = 0.04 if shadow_test == "splat" else 0.02
    inside = floor_px & (x > -0.3 + margin) & (x < -0.1 - margin) & (np.abs(y) < 0.1 - margin)
    outside = floor_px & ((x < -0.3 - margin) | (x > 0.1 + margin) | (np.abs(y) > 0.1 + margin))
    assert inside.sum() > 80 and outside.sum() > 3000
    shadowed = FLOOR_ALBEDO * LIGHT.ambient  # 0.28
    lit = FLOOR_ALBEDO * (LIGHT.ambient + LIGHT.intensity * np.sqrt(0.5))  # 0.704
    np.testing.assert_allclose(rgb[inside], shadowed, atol=2e-3)
    np.testing.assert_allclose(rgb[outside], lit, atol=2e-3)
    # unlit (the old behaviour): the floor keeps its albedo everywhere, no shadow
    unlit = render_lit(g, None, K, w2c)
    np.testing.assert_allclose(unlit[inside | outside], FLOOR_ALBEDO, atol=2e-3)
    # without shadows: shading only, the strip is as bright as the rest
    no_shadow = render_lit(g, SceneLighting(LIGHT, shadows=False, shadow_map_px=512, shadow_bias_m=0.01), K, w2c)
    np.testing.assert_allclose(no_shadow[inside], lit, atol=2e-3)


def test_shadow_follows_the_light_direction() -> None:
    """Light towards -y (45 deg up): the strip moves to y in [0.1, 0.3]; the old strip is lit."""
    g = box_on_floor()
    light = dataclasses.replace(LIGHT, direction=(0.0, -1.0, 1.0))
    lighting = SceneLighting(light, shadows=True, shadow_map_px=512, shadow_bias_m=0.01)
    c = lighting.colors(g, top_view()[1], g.part_ids > 0)
    x, y = g.means_m[:, 0], g.means_m[:, 1]
    floor = g.part_ids == 0
    new_strip = floor & (np.abs(x) < 0.08) & (y > 0.12) & (y < 0.28)
    old_strip = floor & (np.abs(y) < 0.08) & (x > -0.28) & (x < -0.12)
    np.testing.assert_allclose(c[new_strip], FLOOR_ALBEDO * light.ambient, atol=1e-6)
    np.testing.assert_allclose(c[old_strip], FLOOR_ALBEDO * (light.ambient + light.intensity * np.sqrt(0.5)),
                               atol=1e-6)


def _cube_object() -> Gaussians:
    """A 10 cm cube object at the origin: +y face part 1 ("A"), -y face part 2 ("B"), the others part 0;
    one albedo (0.6) everywhere; outward normals."""
    cube = box_gaussians(SceneBox("c", (0.0, 0.0, 0.0), (0.05,) * 3, "wood", _solid(0.6)), 0.01, 0)
    parts = np.where(cube.normals[:, 1] > 0.5, 1, np.where(cube.normals[:, 1] < -0.5, 2, 0))
    return cube.with_part_ids(parts)


def test_turning_the_object_turns_its_shading() -> None:
    """Light towards +y (elevation 30 deg: n . l = cos 30 deg for the +y face, -cos 30 deg for -y). At rest
    face A (+y) is lit and B (-y) has ambient only; turned 180 deg about the horizontal x axis, A faces -y
    and is dark, B faces +y and is lit. Unlit (baked) colours would not change at all."""
    light = SceneLight(direction=(0.0, np.cos(np.pi / 6), np.sin(np.pi / 6)), intensity=0.75, ambient=0.35)
    lit_value = 0.6 * (light.ambient + light.intensity * np.cos(np.pi / 6))
    dark_value = 0.6 * light.ambient
    cube = _cube_object()
    turn = np.eye(4)
    turn[:3, :3] = quat_to_matrix(axis_angle_to_quat(np.array([1.0, 0.0, 0.0]), np.pi))
    turned = cube.transformed(turn)
    np.testing.assert_allclose(turned.normals[cube.part_ids == 1], np.broadcast_to([0.0, -1.0, 0.0], (100, 3)),
                               atol=1e-6)
    camera = look_at((0.0, 0.6, 0.35), (0.0, 0.0, 0.0))  # sees the +y side and the top
    for g, bright, dark in ((cube, 1, 2), (turned, 2, 1)):
        c = SceneLighting(light, shadows=True, shadow_map_px=256, shadow_bias_m=0.005).colors(
            g, camera, np.ones(len(g), bool))
        np.testing.assert_allclose(c[g.part_ids == bright], lit_value, atol=1e-6)
        np.testing.assert_allclose(c[g.part_ids == dark], dark_value, atol=1e-6)
        # in the image, the face the camera sees (+y side, whichever part it is) is the lit one
        K = intrinsics_from_fov(40.0, H, W)
        index, _ = LabelRasterizer(H, W).render(g, K, camera)
        rgb = RgbRasterizer(H, W).render(dataclasses.replace(g, colors_rgb=c), K, camera)[0]
        seen = (index >= 0) & (g.part_ids[np.maximum(index, 0)] == bright)
        seen_core = ndimage.binary_erosion(seen, iterations=7)  # a pixel blends splats up to ~6 px away
        assert seen_core.sum() > 50
        back = (index >= 0) & (g.part_ids[np.maximum(index, 0)] == dark)  # only edge splats peeking past the rim
        assert back.sum() < 0.05 * seen.sum()
        np.testing.assert_allclose(rgb[seen_core], lit_value, atol=3e-3)


def test_two_sided_normals_face_the_camera_and_prelit_splats_keep_their_colour() -> None:
    """A splat with a normal of unknown sign (two-sided) is lit on the side the camera sees; a prelit
    (captured) splat keeps its colour when unshadowed and is scaled by shadowed / unshadowed light."""
    light = SceneLight(direction=(0.0, 0.0, 1.0), intensity=0.6, ambient=0.4)
    albedo = np.full((3, 3), 0.5)
    normals = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    centres = np.zeros((3, 3))
    cam = np.array([0.0, 0.0, 2.0])  # above: sees the upper side
    out = shade(albedo, normals, centres, cam, light, two_sided=[True, False, False])
    np.testing.assert_allclose(out[:, 0], [0.5, 0.5 * 0.4, 0.5], atol=1e-7)
    vis = np.array([1.0, 0.0, 0.5])
    out = shade(albedo, np.tile([0.0, 0.0, 1.0], (3, 1)), centres, cam, light, vis, prelit=[True, True, True])
    np.testing.assert_allclose(out[:, 0], [0.5, 0.5 * 0.4 / 1.0, 0.5 * 0.7 / 1.0], atol=1e-7)


def test_only_two_sided_normals_turn_to_the_camera() -> None:
    """The shading kernel's facing normals: exactly the two-sided normals that point away from the camera turned,
    every other row as given (the camera-facing test runs only on flagged rows), inputs unchanged."""
    rng = np.random.default_rng(5)
    normals = rng.normal(size=(200, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    centres = rng.uniform(-1.0, 1.0, (200, 3)).astype(np.float32)
    cam = np.array([0.3, -0.2, 4.0])
    two_sided = rng.uniform(size=200) < 0.3
    kept = normals.copy()
    albedo = np.full((200, 3), 0.5, np.float32)
    out = shade_parts_on(albedo, normals, centres, cam, LIGHT, two_sided=two_sided).facing.numpy()
    away = np.einsum("ij,ij->i", normals.astype(np.float64), cam - centres.astype(np.float64)) < 0.0
    expected = np.where((two_sided & away)[:, None], -normals, normals)
    np.testing.assert_array_equal(out, expected)
    assert (two_sided & away).sum() > 10 and (~two_sided & away).sum() > 10  # both kinds of rows occur
    np.testing.assert_array_equal(normals, kept)
    for flags in (None, np.zeros(200, bool)):
        np.testing.assert_array_equal(shade_parts_on(albedo, normals, centres, cam, LIGHT, two_sided=flags)
                                      .facing.numpy(), normals)  # fmt: skip
    np.testing.assert_array_equal(shade_parts_on(albedo, normals, centres, cam, LIGHT, two_sided=np.ones(200, bool))
                                  .facing.numpy(), np.where(away[:, None], -normals, normals))  # fmt: skip


def _shade_parts_float64(albedo, normals, centres, cam, light, prelit, two_sided):
    """The shading formulas (module docstring of data_gen.render.shading) in numpy float64, row by row as
    written: the reference the kernel must reproduce."""
    a, n = albedo.astype(np.float64), normals.astype(np.float64).copy()
    away = np.einsum("ij,ij->i", n, cam[None, :] - centres.astype(np.float64)) < 0.0
    n[two_sided & away] *= -1.0
    cos = np.maximum(n @ np.asarray(light.direction, np.float64), 0.0)
    key = light.intensity * cos[:, None] * np.asarray(light.color_rgb, np.float64)[None, :]
    amb = np.full_like(key, light.ambient)
    total = light.ambient + key
    ok = total > 0.0
    div = prelit[:, None] & ok
    amb = np.where(div, light.ambient / np.where(ok, total, 1.0), np.where(prelit[:, None], 1.0, amb))
    key = np.where(div, key / np.where(ok, total, 1.0), np.where(prelit[:, None], 0.0, key))
    return (np.clip(a * amb, 0.0, 1.0).astype(np.float32), np.clip(a * key, 0.0, 1.0).astype(np.float32))


def test_shading_kernel_matches_the_formulas_in_float64() -> None:
    """Coloured light, prelit and two-sided rows, albedo above 1 (clipped), normals facing away from the light
    (cos clamped at 0), a prelit row lit by nothing (ambient 0: all ambient): the kernel's parts are the float64
    formulas' bit for bit, and shade() = clip(ambient + visibility x direct)."""
    rng = np.random.default_rng(11)
    n = 5000
    albedo = rng.uniform(0.0, 1.3, (n, 3)).astype(np.float32)
    normals = rng.normal(size=(n, 3)).astype(np.float32)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    centres = rng.uniform(-1.0, 1.0, (n, 3)).astype(np.float32)
    cam = np.array([0.4, -2.0, 3.0])
    prelit, two_sided = rng.uniform(size=n) < 0.3, rng.uniform(size=n) < 0.4
    for light in (LIGHT, SceneLight(direction=(0.3, 0.2, 0.9327379053088815), intensity=1.3, ambient=0.27,
                                    color_rgb=(1.0, 0.83, 0.61)), SceneLight(ambient=0.0)):  # fmt: skip
        ambient, direct = shade_parts(albedo, normals, centres, cam, light, prelit, two_sided)
        want_ambient, want_direct = _shade_parts_float64(albedo, normals, centres, cam, light, prelit, two_sided)
        np.testing.assert_array_equal(ambient, want_ambient)
        np.testing.assert_array_equal(direct, want_direct)
        assert (direct == 0.0).sum() > n // 10 and (ambient == 1.0).sum() > 0  # unlit rows, clipped rows occur
        vis = rng.uniform(size=n)
        np.testing.assert_array_equal(shade(albedo, normals, centres, cam, light, vis, prelit, two_sided),
                                      np.clip(ambient + vis[:, None] * direct, 0.0, 1.0).astype(np.float32))
    with pytest.raises(ValueError, match=r"prelit must have shape \(5000,\)"):
        shade_parts(albedo, normals, centres, cam, LIGHT, prelit[:10])
    with pytest.raises(ValueError, match=r"normals must have shape \(5000, 3\)"):
        shade_parts(albedo, normals[:10], centres, cam, LIGHT)


def test_light_view_of_point_blocks_is_the_view_of_their_concatenation(monkeypatch) -> None:
    """fit_light_view reads a sequence of arrays (one per object and frame) block by block, never joined: the view
    is bit for bit the one of their concatenation, whatever the block size, with empty parts among them."""
    from data_gen.render import shadow_map

    rng = np.random.default_rng(3)
    parts = [rng.normal([0.2, -0.1, 0.4], 0.3, (n, 3)) for n in (700, 0, 1, 2500)] + [np.float32([[0.1, 2.0, 0.3]])]
    whole = fit_light_view(LIGHT.direction, np.concatenate(parts), 0.02, 512)
    for rows in (shadow_map.FIT_BLOCK_ROWS, 64, 1):
        monkeypatch.setattr(shadow_map, "FIT_BLOCK_ROWS", rows)
        view = fit_light_view(LIGHT.direction, parts, 0.02, 512)
        assert view.K.tobytes() == whole.K.tobytes() and view.world_to_light.tobytes() == whole.world_to_light.tobytes()
    assert fit_light_view(LIGHT.direction, [], 0.0, 64).K.tobytes() == fit_light_view(LIGHT.direction, np.zeros((0, 3)),
                                                                                       0.0, 64).K.tobytes()  # fmt: skip
    # the last part (a lone point far along +y) is what sets the field of view
    assert fit_light_view(LIGHT.direction, parts[:-1], 0.02, 512).K[0, 0] > 1.1 * whole.K[0, 0]


def test_light_view_sees_every_caster_and_lighting_is_deterministic() -> None:
    g = box_on_floor()
    casters = g.means_m[g.part_ids > 0]
    view = fit_light_view(LIGHT.direction, casters, 0.02, 256)
    p = casters @ view.world_to_light[:3, :3].T + view.world_to_light[:3, 3]
    uv = p[:, :2] / p[:, 2:] * view.K[0, 0] + view.K[0, 2]
    assert uv.min() > 0.0 and uv.max() < 256.0 and (p[:, 2] > 0).all()
    # the light's camera looks along -direction
    np.testing.assert_allclose(view.world_to_light[2, :3], -np.asarray(LIGHT.direction), atol=1e-12)
    K, w2c = top_view()
    first = SceneLighting(LIGHT, True, 256, 0.01).colors(g, w2c, g.part_ids > 0)
    second = SceneLighting(LIGHT, True, 256, 0.01, num_threads=1).colors(g, w2c, g.part_ids > 0)
    assert first.tobytes() == second.tobytes()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(direction=(1.0, 0.0, 0.0)), r"at least 5.0 deg up"),
        (dict(direction=(0.0, 0.0, 0.0)), r"not all 0"),
        (dict(intensity=-0.1), r"intensity must be in \[0, 4.0\]"),
        (dict(ambient=5.0), r"ambient must be in \[0, 4.0\]"),
        (dict(color_rgb=(1.0, 2.0, 0.0)), r"color_rgb must be 3 values in \[0, 1\]"),
    ],
)
def test_scene_light_rejects_bad_values(kwargs, match) -> None:
    with pytest.raises(ValueError, match=match):
        SceneLight(**kwargs)


def test_pixel_and_point_lookups_agree_and_pixels_turned_away_count_as_lit() -> None:
    """The per-pixel kernel places each floor pixel where its ray meets its splat and gives the same
    visibility as the per-point kernel at that point; a pixel whose winner faces away from the light is lit."""
    g = box_on_floor()
    K, w2c = top_view()
    lighting = SceneLighting(LIGHT, shadows=True, shadow_map_px=512, shadow_bias_m=0.01)
    lighting.colors(g, w2c, g.part_ids > 0)  # fits the view and draws the map
    mapper = lighting.mapper
    assert mapper is not None
    index, depth = LabelRasterizer(H, W, depth_mode="surface").render(g, K, w2c)
    normals = g.surface_normals()
    per_pixel = mapper.pixel_visibility(K, w2c, index, depth, normals, LIGHT.direction)
    floor = (index >= 0) & (g.part_ids[np.maximum(index, 0)] == 0)
    x, y = floor_points(K, w2c)
    points = np.stack([x[floor], y[floor], np.zeros(int(floor.sum()))], 1)
    per_point = mapper.visibility(points, np.tile([0.0, 0.0, 1.0], (len(points), 1)), LIGHT.direction)
    assert (per_pixel[floor] == 0.0).sum() > 100 and (per_pixel[floor] == 1.0).sum() > 1000
    # the two kernels see the same point up to float32 rounding of the depth: equal but at rare texel borders
    assert np.mean(np.abs(per_pixel[floor] - per_point) < 1e-6) > 0.995
    away = -np.abs(normals)  # every component <= 0: n . l <= 0 for the light (0.71, 0, 0.71)
    np.testing.assert_array_equal(mapper.pixel_visibility(K, w2c, index, depth, away, LIGHT.direction), 1.0)
    np.testing.assert_array_equal(per_pixel[index < 0], 1.0)
