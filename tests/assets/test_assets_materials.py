"""Materials table: ranges, determinism of sampling, lookup errors, procedural textures."""

import numpy as np
import pytest

from data_gen.assets.materials import (
    MATERIALS,
    MaterialClass,
    ProceduralTexture,
    get_material,
    list_materials,
    material_id_table,
    sample_material,
    sample_palette_color,
)

REQUIRED = ("plastic", "metal", "wood", "ceramic", "paper", "rubber", "foam", "fabric", "plush", "leather")


def test_required_classes_and_ids():
    names = list_materials()
    assert set(REQUIRED) <= set(names)
    ids = [m.id for m in MATERIALS]
    assert ids == list(range(1, len(MATERIALS) + 1))  # 1-based, consecutive, unique
    assert material_id_table()["1"] == names[0]
    for m in MATERIALS:
        assert 0.0 <= m.poisson_ratio[0] <= m.poisson_ratio[1] < 0.5
        assert 0.0 < m.young_modulus_pa[0] < m.young_modulus_pa[1]
        assert 0.0 < m.density_kg_m3[0] < m.density_kg_m3[1]


@pytest.mark.parametrize(
    "name, lo, hi",
    [
        ("foam", 1e4, 1e6),
        ("rubber", 1e6, 1e7),
        ("plastic", 1e9, 3e9),
        ("wood", 5e9, 1.5e10),
        ("metal", 5e10, 2.1e11),
    ],
)
def test_young_modulus_orders_of_magnitude(name, lo, hi):
    e_lo, e_hi = get_material(name).young_modulus_pa
    assert lo <= e_lo < e_hi <= hi


def test_sampling_deterministic_and_inside_ranges():
    for m in MATERIALS:
        a = [sample_material(m.name, np.random.default_rng(7)) for _ in range(3)]
        assert a[0] == a[1] == a[2]
        rng = np.random.default_rng(1)
        draws = np.array([sample_material(m, rng) for _ in range(500)])
        assert np.all((draws[:, 0] >= m.young_modulus_pa[0]) & (draws[:, 0] <= m.young_modulus_pa[1]))
        assert np.all((draws[:, 1] >= m.poisson_ratio[0]) & (draws[:, 1] <= m.poisson_ratio[1]))
        assert np.all((draws[:, 2] >= m.density_kg_m3[0]) & (draws[:, 2] <= m.density_kg_m3[1]))


def test_young_modulus_is_log_uniform():
    m = get_material("foam")  # 1e4 .. 1e6: log-midpoint 1e5, linear midpoint ~5e5
    rng = np.random.default_rng(3)
    e = np.array([sample_material(m, rng)[0] for _ in range(4000)])
    assert abs(np.median(np.log10(e)) - 5.0) < 0.1
    assert abs(np.mean(np.log10(e) < 4.5) - 0.25) < 0.03  # a quarter of the log span


def test_unknown_material_lists_valid_names():
    with pytest.raises(KeyError, match="plastic"):
        get_material("unobtainium")
    with pytest.raises(KeyError, match="1..12"):
        get_material(99)


def test_bad_material_range_names_field():
    with pytest.raises(ValueError, match="poisson_ratio"):
        MaterialClass(1, "bad", (1.0, 2.0), (0.3, 0.5), (1.0, 2.0), ((0.5, 0.5, 0.5),))
    with pytest.raises(ValueError, match="young_modulus_pa"):
        MaterialClass(1, "bad", (0.0, 2.0), (0.3, 0.4), (1.0, 2.0), ((0.5, 0.5, 0.5),))


def test_palette_color_deterministic_in_unit_range():
    a = sample_palette_color("wood", np.random.default_rng(5))
    b = sample_palette_color("wood", np.random.default_rng(5))
    assert a == b and all(0.0 <= c <= 1.0 for c in a)
    palette = np.asarray(get_material("wood").palette_rgb)
    assert np.min(np.abs(palette - np.asarray(a)).max(axis=1)) <= 0.05 + 1e-12


def test_texture_hand_values():
    c0, c1 = (0.9, 0.1, 0.1), (0.1, 0.1, 0.9)
    checker = ProceduralTexture("checker", (c0, c1), period_m=1.0)
    got = checker.colors_at([[0.5, 0.5, 0.5], [1.5, 0.5, 0.5], [1.5, 1.5, 0.5], [-0.5, 0.5, 0.5]])
    np.testing.assert_allclose(got, [c0, c1, c0, c1])
    stripes = ProceduralTexture("stripes", (c0, c1), period_m=0.1, axis=2)
    np.testing.assert_allclose(stripes.colors_at([[9.0, 9.0, 0.05], [9.0, 9.0, 0.15]]), [c0, c1])
    solid = ProceduralTexture("solid", (c0,))
    np.testing.assert_allclose(solid.colors_at(np.zeros((4, 3))), np.tile(c0, (4, 1)))
    for kind in ("noise", "planks", "tiles", "dots"):
        t = ProceduralTexture(kind, (c0, c1), period_m=0.2, seed=4)
        p = np.random.default_rng(0).uniform(-1, 1, (500, 3))
        col = t.colors_at(p)
        assert col.shape == (500, 3) and col.min() >= 0.0 and col.max() <= 1.0
        np.testing.assert_array_equal(col, t.colors_at(p))  # a pure function of the points
        assert col.std(axis=0).max() > 0.01  # actually patterned


def test_texture_bad_input():
    with pytest.raises(ValueError, match="period_m"):
        ProceduralTexture("checker", ((0.5, 0.5, 0.5),), period_m=0.0)
    with pytest.raises(ValueError, match="kind"):
        ProceduralTexture("marble")
