"""Benchmark variety: >= 100 library objects (the core 34 plus parametric families) and >= 20 scene layouts."""

from __future__ import annotations

import numpy as np
import pytest

from data_gen.assets.families import FAMILY_SPECS, family_names
from data_gen.assets.layout_variants import list_variant_layouts
from data_gen.assets.library import CORE_OBJECTS
from data_gen.assets.materials import list_materials
from data_gen.assets.registry import get_object, get_scene_layout, list_objects, list_scene_layouts, object_pool
from data_gen.display_names import words
from data_gen.pipeline import build_objects
from data_gen.configs import render_settings
from data_gen.scenario import ObjectPlacement, Scenario
from data_gen.cameras import CameraPathSpec

SAMPLE = ("plush_octopus", "cheese_wedge", "teacup")
"""Family objects with the most composed shapes (many parts, a cut wedge, a cup with a handle), built in the
default run (~3 s each); the slow run builds every other family object."""


def test_at_least_100_distinct_objects_with_names_and_materials() -> None:
    names = list_objects()
    assert len(names) == len(set(names)) == 34 + len(FAMILY_SPECS) >= 100
    assert tuple(object_pool("core")) == CORE_OBJECTS and len(CORE_OBJECTS) == 34
    assert sorted(object_pool("all")) == names and set(family_names()).isdisjoint(CORE_OBJECTS)
    display = [words(n) for n in names]
    assert len(set(display)) == len(display)  # every object has its own display name
    for name in family_names():
        a = get_object(name)
        assert a.name == name and a.default_material in a.allowed_materials
        assert set(a.allowed_materials) <= set(list_materials())
        lo, hi = a.shape.bounds()
        np.testing.assert_allclose(0.5 * (lo + hi), 0.0, atol=1e-9)
    # variety: many categories and materials, a real share of soft objects (plush, gel, foam by default)
    assert len({get_object(n).category for n in family_names()}) >= 12
    soft = [n for n in family_names() if get_object(n).default_material in ("plush", "gel", "foam")]
    assert len(soft) >= 25
    colours = {tuple(np.round(get_object(n).textures[0].colors[0], 2)) for n in family_names()}
    assert len(colours) >= 50  # appearances differ, not just shapes


def _scenario(assets: tuple[str, ...]) -> Scenario:
    placements = tuple(
        ObjectPlacement(object_id=k + 1, asset=a, size_m=0.15, material=get_object(a).default_material,
                        young_modulus_pa=1e6, poisson_ratio=0.3, density_kg_m3=500.0,
                        position_m=(0.4 * k, 0.0, 0.2), orientation_wxyz=(1.0, 0.0, 0.0, 0.0),
                        velocity_m_s=(0.0, 0.0, 0.0), angular_velocity_rad_s=(0.0, 0.0, 0.0), motion="drop",
                        color_seed=k)
        for k, a in enumerate(assets))
    return Scenario(sequence_id="t", seed=0, split="train", scene="empty_floor", objects=placements,
                    gravity_m_s2=(0.0, 0.0, -9.81), camera=CameraPathSpec("static", (0.0, 0.0, 0.1), 1.0, 0.5),
                    num_frames=2, fps=25.0, image_size=(16, 16))


def _check_built(names: tuple[str, ...]) -> None:
    settings = render_settings(object_gaussians=600, interior_points=300, contact_surface_samples=500)
    for name, obj in zip(names, build_objects(_scenario(names), settings)):
        g = obj.surface
        assert len(g) >= 300, name
        means = np.asarray(g.means_m)
        assert np.isfinite(means).all() and np.all(np.abs(obj.asset.shape.sdf(means)) < 0.02 * 0.15), name
        colours = np.asarray(g.colors_rgb)
        assert colours.min() >= 0.0 and colours.max() <= 1.0, name
        # interior (simulation) points: enough of them, all inside the material, volume ~ points x spacing^3
        assert len(obj.interior_points_m) >= 100 and (obj.asset.shape.sdf(obj.interior_points_m) < 0).all(), name
        assert obj.volume_m3 > 0 and len(obj.contact_surface.points_m) > 0, name


def test_sample_of_family_objects_build_gaussians_and_simulation_points() -> None:
    _check_built(SAMPLE)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(family_names()) - set(SAMPLE)))
def test_every_family_object_builds(name: str) -> None:
    _check_built((name,))


def test_at_least_20_layouts() -> None:
    names = list_scene_layouts()
    assert len(names) == len(set(names)) >= 20
    assert names[:6] == ["empty_floor", "table", "bench_steps", "shelf_wall", "ramp", "room_corner"]  # order kept
    assert names[6:] == list_variant_layouts()
    kinds = {get_scene_layout(n).kind for n in names}
    assert len(kinds) >= 10
    assert get_scene_layout("sofa") is get_scene_layout("sofa")  # built once per process


def test_enclosures_keep_objects_inside() -> None:
    for name in ("play_pen", "box_pit"):
        scene = get_scene_layout(name)
        region = scene.regions[0]
        half = max(abs(region.min_m[0]), abs(region.max_m[0]))
        # just outside the region, toward each wall: free; beyond the walls' inner face: inside a wall
        for axis in (0, 1):
            for sign in (-1.0, 1.0):
                p = np.zeros((1, 3))
                p[0, 2] = 0.1
                inner = next(b for b in scene.boxes if abs(b.center_m[axis]) > 0 and
                             np.sign(b.center_m[axis]) == sign and abs(b.center_m[1 - axis]) < 1e-9)
                face = abs(inner.center_m[axis]) - inner.half_extents_m[axis]
                assert face > half
                p[0, axis] = sign * (face + 0.005)
                assert scene.sdf(p)[0] == pytest.approx(-0.005, abs=1e-9)


def test_hollow_families_are_shells() -> None:
    hollow = [n for n, row in FAMILY_SPECS.items() if row[6] is not None]
    assert len(hollow) >= 10
    assert all(get_object(n).is_hollow == (FAMILY_SPECS[n][6] is not None) for n in family_names())
    a = get_object("soccer_ball")  # sphere r = 0.11 m, wall 4 mm: the wall's volume, not the ball's
    assert a.shape.thickness_m == 0.004
    from data_gen.dry_run import unit_volume

    exact = 4 / 3 * np.pi * (0.11**3 - 0.106**3) / a.nominal_size_m**3
    assert unit_volume("soccer_ball") == pytest.approx(exact, rel=0.05)  # Monte Carlo estimate (dry run)
