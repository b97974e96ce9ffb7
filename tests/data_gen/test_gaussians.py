"""The splat container: validation, covariances, deformation, rigid moves, scaling, concatenation."""

from __future__ import annotations

import numpy as np
import pytest

from data_gen.gaussians import Gaussians, concatenate


def _one(**overrides: object) -> Gaussians:
    fields: dict[str, object] = dict(
        means_m=[[0.0, 0.0, 2.0]], scales_m=[[0.1, 0.2, 0.3]], colors_rgb=[[1.0, 0.5, 0.0]], opacities=[0.8]
    )
    fields.update(overrides)
    return Gaussians(**fields)  # type: ignore[arg-type]


def test_covariance_from_scales_and_rotation() -> None:
    # 90 degrees about z maps the local x axis to world y: variances (0.01, 0.04, 0.09) -> (0.04, 0.01, 0.09).
    h = np.sqrt(0.5)
    g = _one(rotations_wxyz=[[h, 0.0, 0.0, h]])
    np.testing.assert_allclose(g.covariances()[0], np.diag([0.04, 0.01, 0.09]), atol=1e-7)
    # identity rotation when omitted; rotations are kept as given and normalised for use
    np.testing.assert_allclose(_one().covariances()[0], np.diag([0.01, 0.04, 0.09]), atol=1e-8)
    g2 = _one(rotations_wxyz=[[2.0, 0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(g2.rotations_wxyz, [[2.0, 0.0, 0.0, 0.0]])
    np.testing.assert_array_equal(g2.unit_rotations_wxyz, [[1.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(g2.covariances()[0], np.diag([0.01, 0.04, 0.09]), atol=1e-8)
    np.testing.assert_array_equal(_one().part_ids, [0])  # part ids default to 0


def test_deformation_gradient_maps_covariance() -> None:
    g = _one(scales_m=[[0.1, 0.1, 0.1]])
    f = np.array([[[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]])
    d = g.deformed(f)
    np.testing.assert_allclose(d.covariances()[0], np.diag([0.04, 0.01, 0.01]), atol=1e-8)
    # shear: F = I + e_x e_y^T -> Sigma = s^2 F F^T = s^2 [[2,1,0],[1,1,0],[0,0,1]]
    shear = np.eye(3)[None].copy()
    shear[0, 0, 1] = 1.0
    np.testing.assert_allclose(
        g.deformed(shear).covariances()[0], 0.01 * np.array([[2, 1, 0], [1, 1, 0], [0, 0, 1.0]]), atol=1e-8
    )
    moved = g.deformed(f, means_m=[[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(moved.means_m, [[1.0, 2.0, 3.0]])
    np.testing.assert_array_equal(moved.colors_rgb, g.colors_rgb)


def test_subset_keeps_rows() -> None:
    rng = np.random.default_rng(3)
    g = Gaussians(
        means_m=rng.normal(size=(5, 3)),
        scales_m=rng.uniform(0.1, 1, (5, 3)),
        colors_rgb=rng.uniform(0, 1, (5, 3)),
        opacities=rng.uniform(0, 1, 5),
    )
    s = g.subset(np.array([True, False, True, False, False]))
    assert len(s) == 2
    np.testing.assert_array_equal(s.means_m, g.means_m[[0, 2]])
    np.testing.assert_allclose(s.covariances(), g.covariances()[[0, 2]])


def test_derived_sets_hold_the_rows_and_colours_asked_for_and_check_the_new_colours() -> None:
    """A subset or a recoloured set is built without validating the checked fields again: it must hold exactly the
    fields a fresh, validated set of those rows would, and its cached unit rotations must be those rows' ones."""
    rng = np.random.default_rng(4)
    n = 7
    g = Gaussians(means_m=rng.normal(size=(n, 3)), scales_m=rng.uniform(0.1, 1, (n, 3)),
                  rotations_wxyz=rng.normal(size=(n, 4)) * 3.0, colors_rgb=rng.uniform(0, 1, (n, 3)),
                  opacities=rng.uniform(0, 1, n), part_ids=np.arange(n), normals=rng.normal(size=(n, 3)))  # fmt: skip
    unit = g.unit_rotations_wxyz  # cached now: a derived set carries its rows
    # the norms the build checked are the ones divided by (kept from __post_init__, released once used)
    np.testing.assert_array_equal(unit, g.rotations_wxyz / np.linalg.norm(g.rotations_wxyz, axis=1)[:, None])
    assert "_rotation_norms" not in g.__dict__
    rows = np.array([5, 1, 1, 3])
    for sel in (rows, rows.astype(np.int32), np.isin(np.arange(n), rows)):
        s = g.subset(sel)
        picked = np.arange(n)[sel]
        fresh = Gaussians(means_m=g.means_m[picked], scales_m=g.scales_m[picked], rotations_wxyz=g.rotations_wxyz[picked],
                          colors_rgb=g.colors_rgb[picked], opacities=g.opacities[picked], part_ids=g.part_ids[picked],
                          normals=g.normals[picked])  # fmt: skip
        for name in ("means_m", "scales_m", "rotations_wxyz", "colors_rgb", "opacities", "part_ids", "normals"):
            np.testing.assert_array_equal(getattr(s, name), getattr(fresh, name), err_msg=name)
        np.testing.assert_array_equal(s.unit_rotations_wxyz, unit[picked])
        np.testing.assert_array_equal(s.unit_rotations_wxyz, fresh.unit_rotations_wxyz)
    new_colors, old_colors = rng.uniform(0, 1, (n, 3)), g.colors_rgb.copy()
    r = g.with_colors(new_colors)
    np.testing.assert_array_equal(r.colors_rgb, new_colors.astype(np.float32))
    np.testing.assert_array_equal(r.means_m, g.means_m)
    np.testing.assert_array_equal(g.colors_rgb, old_colors)  # the source set is unchanged
    assert r.colors_rgb.dtype == np.float32 and r.colors_rgb.flags.c_contiguous
    bad = new_colors.copy()
    bad[2, 1] = 1.5
    with pytest.raises(ValueError, match=r"colors_rgb\[2\].*outside the allowed range"):
        g.with_colors(bad)
    with pytest.raises(ValueError, match=r"colors_rgb has 6 rows but means_m has 7"):
        g.with_colors(new_colors[:6])
    with pytest.raises(ValueError, match=r"boolean mask or integer indices, got dtype float64"):
        g.subset(np.array([0.0, 1.0]))
    assert len(g.subset(np.array([], dtype=int))) == 0
    assert len(g.subset(np.zeros(n, bool))) == 0
    run = (np.arange(n) >= 2) & (np.arange(n) < 6)  # one run of rows: views of the arrays, the same values
    view = g.subset(run)
    assert np.shares_memory(view.means_m, g.means_m) and view.means_m.flags.c_contiguous
    np.testing.assert_array_equal(view.rotations_wxyz, g.rotations_wxyz[2:6])
    np.testing.assert_array_equal(view.unit_rotations_wxyz, unit[2:6])
    assert not np.shares_memory(g.subset(run ^ (np.arange(n) == 3)).means_m, g.means_m)


@pytest.mark.parametrize(
    ("overrides", "message"),
    [
        (dict(means_m=[[0.0, np.nan, 2.0]]), r"means_m\[0\] is not finite"),
        (dict(opacities=[1.5]), r"opacities\[0\] = 1.5 is outside the allowed range \[0.0, 1.0\]"),
        (dict(colors_rgb=[[1.0, -0.1, 0.0]]), r"colors_rgb\[0\].*outside the allowed range"),
        (dict(scales_m=[[0.1, -0.2, 0.3]]), r"scales_m\[0\].*outside the allowed range"),
        (dict(means_m=[[0.0, 0.0]]), r"means_m must have shape \('N', 3\), got \(1, 2\)"),
        (dict(opacities=[0.5, 0.5]), r"opacities has 2 rows but means_m has 1"),
        (dict(rotations_wxyz=[[0.0, 0.0, 0.0, 0.0]]), r"rotations_wxyz\[0\].*zero norm"),
        (dict(covariances_m2=np.eye(3)[None]), r"exactly one of scales_m"),
        (
            dict(scales_m=None, covariances_m2=[np.diag([1.0, -1.0, 1.0])]),
            r"covariances_m2\[0\] is not positive",
        ),
        (dict(scales_m=None, covariances_m2=[[[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]]]), r"not symmetric"),
    ],
)
def test_bad_input_names_field_and_value(overrides: dict[str, object], message: str) -> None:
    with pytest.raises(ValueError, match=message):
        _one(**overrides)


def test_bad_row_is_named_among_good_ones() -> None:
    """The checks pass whole arrays in one reduction and look the offending row up only on failure: the row they
    name is the first bad one, not row 0."""
    n = 6
    good = dict(means_m=np.zeros((n, 3)), scales_m=np.full((n, 3), 0.01), colors_rgb=np.full((n, 3), 0.5),
                opacities=np.full(n, 0.5))  # fmt: skip
    Gaussians(**good)
    means = good["means_m"].copy()
    means[4, 2] = np.inf
    with pytest.raises(ValueError, match=r"means_m\[4\] is not finite: \[0.0, 0.0, inf\]"):
        Gaussians(**{**good, "means_m": means})
    opac = good["opacities"].copy()
    opac[[3, 5]] = [1.25, -1.0]
    with pytest.raises(ValueError, match=r"opacities\[3\] = 1.25 is outside the allowed range \[0.0, 1.0\]"):
        Gaussians(**{**good, "opacities": opac})
    colors = good["colors_rgb"].copy()
    colors[2, 1] = 1.5
    with pytest.raises(ValueError, match=r"colors_rgb\[2\] = \[0.5, 1.5, 0.5\] is outside"):
        Gaussians(**{**good, "colors_rgb": colors})


def test_bad_deformation_shape() -> None:
    with pytest.raises(ValueError, match=r"deformation_gradients must have shape \(1, 3, 3\), got \(3, 3\)"):
        _one().deformed(np.eye(3))


def test_rigid_transform_scaling_and_part_ids_by_hand() -> None:
    h = np.sqrt(0.5)
    g = Gaussians(
        means_m=[[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
        scales_m=[[0.1, 0.2, 0.3], [0.1, 0.1, 0.1]],
        rotations_wxyz=[[1.0, 0.0, 0.0, 0.0], [h, 0.0, 0.0, h]],
        colors_rgb=[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        opacities=[0.5, 1.0],
        part_ids=[3, 4],
    )
    m = np.eye(4)
    m[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # 90 degrees about z
    m[:3, 3] = [0.0, 0.0, 2.0]
    t = g.transformed(m)
    np.testing.assert_allclose(t.means_m, [[0.0, 1.0, 2.0], [0.0, 0.0, 3.0]], atol=1e-7)
    np.testing.assert_allclose(t.rotations_wxyz, [[h, 0, 0, h], [0, 0, 0, 1]], atol=1e-7)  # quarter + quarter turn
    np.testing.assert_allclose(t.covariances()[0], np.diag([0.04, 0.01, 0.09]), atol=1e-8)
    np.testing.assert_array_equal(t.part_ids, [3, 4])
    s = g.scaled(2.0)
    np.testing.assert_allclose(s.means_m, [[2.0, 0.0, 0.0], [0.0, 0.0, 2.0]])
    np.testing.assert_allclose(s.scales_m, [[0.2, 0.4, 0.6], [0.2, 0.2, 0.2]])
    d = g.deformed(np.broadcast_to(np.eye(3), (2, 3, 3)))
    np.testing.assert_allclose(d.transformed(m).covariances(), t.covariances(), atol=1e-8)
    np.testing.assert_array_equal(d.part_ids, [3, 4])
    np.testing.assert_array_equal(g.with_part_ids([7, 8]).part_ids, [7, 8])
    both = concatenate([g, g.subset([1])])
    assert len(both) == 3
    np.testing.assert_array_equal(both.part_ids, [3, 4, 4])
    np.testing.assert_array_equal(both.means_m[2], [0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="mix scales"):
        concatenate([g, d])
    with pytest.raises(ValueError, match=r"part_ids must have shape \(2,\), got \(3,\)"):
        g.with_part_ids([1, 2, 3])
    with pytest.raises(ValueError, match="scale factor must be a finite value > 0, got 0.0"):
        g.scaled(0.0)
