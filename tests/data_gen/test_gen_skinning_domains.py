"""Canonical skinning domains: a shape's points scaled to a draw lie inside the drawn shape (the library scales
shapes about their frame origin), the domain does not depend on the draw, and the pipeline simulates a draw on
its shape's points with that domain."""

from __future__ import annotations

import numpy as np
import pytest

from data_gen.assets.registry import get_object, object_pool
from data_gen.configs import render_settings, scenario_config
from data_gen.pipeline import build_objects
from data_gen.scenario import sample_scenario
from data_gen.sim.world import _check_domain
from data_gen.skinning_domains import shape_seed, skinning_domain

PILE_OBJECTS = ("teddy_bear", "pillow", "sponge", "ball", "rubber_duck", "yoga_block", "tennis_ball", "bag")


def test_shape_seed_is_fixed_by_the_name() -> None:
    assert shape_seed("ball") == shape_seed("ball")
    assert shape_seed("ball") != shape_seed("pillow")
    assert 0 <= shape_seed("teddy_bear") < 2**31


def _draw_fits(name: str, size_m: float) -> None:
    """The shape's canonical points scaled to ``size_m`` lie inside the shape drawn at that size (its SDF < 0) and
    span its bounding box to within a tenth of its size (tips hold no grid point): a draw is the canonical shape
    scaled about its origin."""
    domain = skinning_domain(name, size_m, 1000)
    asset = get_object(name, size_m)
    pts = np.asarray(domain.points_m) * domain.scale
    assert float(asset.shape.sdf(pts).max()) < 1e-9 * size_m, name
    lo, hi = asset.shape.bounds()
    assert np.abs(pts.min(0) - lo).max() < 0.1 * size_m and np.abs(pts.max(0) - hi).max() < 0.1 * size_m, name


@pytest.mark.parametrize("name", PILE_OBJECTS[:4])
def test_draws_at_two_sizes_share_the_domain_and_fit_it(name: str) -> None:
    a, b = skinning_domain(name, 0.1, 1000), skinning_domain(name, 0.25, 1000)
    assert a.points_m is b.points_m  # one canonical point set per shape (computed once per process)
    assert a.seed == b.seed == shape_seed(name)
    assert b.scale / a.scale == pytest.approx(2.5, rel=1e-12)
    assert a.scale * get_object(name).nominal_size_m == pytest.approx(0.1, rel=1e-12)
    _draw_fits(name, 0.1)
    _draw_fits(name, 0.25)


@pytest.mark.slow
def test_every_core_object_fits_its_domain() -> None:
    for name in object_pool("core"):  # loop over shapes
        _draw_fits(name, 0.23)


def test_pipeline_objects_carry_their_shapes_domain() -> None:
    cfg = scenario_config("pile", scenes=("empty_floor",), num_objects=(4, 4))
    settings = render_settings()
    scenario = sample_scenario(cfg, "dom-000000", 1000, "train", "earth", 3, 25.0, (64, 64))
    objects = build_objects(scenario, settings)
    for o, p in zip(objects, scenario.objects):
        d = o.skinning_domain
        assert d is not None and d.seed == shape_seed(p.asset)
        assert d.scale * get_object(p.asset).nominal_size_m == pytest.approx(p.size_m, rel=1e-12)
        # the draw's particles are the shape's points scaled (what the domain's basis was trained on)
        np.testing.assert_array_equal(o.interior_points_m, np.asarray(d.points_m) * d.scale)
        _check_domain(p.asset, o.interior_points_m, d, float(np.ptp(o.interior_points_m, axis=0).max()))
