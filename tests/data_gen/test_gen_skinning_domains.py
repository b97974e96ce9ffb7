"""Canonical skinning domains: every draw of a library shape fits its shape's domain (the library scales shapes
about their frame origin), the domain does not depend on the draw, and the pipeline hands it to the simulator."""

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


def _draw_fits(name: str, size_m: float, seed: int) -> None:
    """A draw of ``name`` at ``size_m``, sampled as the pipeline samples it, fits the domain (else ValueError)."""
    domain = skinning_domain(name, size_m, 1000)
    asset = get_object(name, size_m)
    pts = asset.interior_points((asset.volume_m3() / 1000) ** (1.0 / 3.0), np.random.default_rng(seed))
    _check_domain(name, pts, domain, float((pts.max(0) - pts.min(0)).max()))


@pytest.mark.parametrize("name", PILE_OBJECTS[:4])
def test_draws_at_two_sizes_share_the_domain_and_fit_it(name: str) -> None:
    a, b = skinning_domain(name, 0.1, 1000), skinning_domain(name, 0.25, 1000)
    assert a.points_m is b.points_m  # one canonical point set per shape (computed once per process)
    assert a.seed == b.seed == shape_seed(name)
    assert b.scale / a.scale == pytest.approx(2.5, rel=1e-12)
    assert a.scale * get_object(name).nominal_size_m == pytest.approx(0.1, rel=1e-12)
    _draw_fits(name, 0.1, 1)
    _draw_fits(name, 0.25, 2)


@pytest.mark.slow
def test_every_core_object_fits_its_domain() -> None:
    for name in object_pool("core"):  # loop over shapes
        _draw_fits(name, 0.23, 3)


def test_pipeline_objects_carry_their_shapes_domain() -> None:
    cfg = scenario_config("pile", scenes=("empty_floor",), num_objects=(4, 4))
    settings = render_settings()
    scenario = sample_scenario(cfg, "dom-000000", 1000, "train", "earth", 3, 25.0, (64, 64))
    objects = build_objects(scenario, settings)
    for o, p in zip(objects, scenario.objects):
        d = o.skinning_domain
        assert d is not None and d.seed == shape_seed(p.asset)
        assert d.scale * get_object(p.asset).nominal_size_m == pytest.approx(p.size_m, rel=1e-12)
        pts = o.interior_points_m
        _check_domain(p.asset, pts, d, float((pts.max(0) - pts.min(0)).max()))
        # the draw's own points are not the domain's: the basis no longer depends on the draw's sample
        assert len(pts) != len(d.points_m) or not np.allclose(pts, d.points_m * d.scale)
