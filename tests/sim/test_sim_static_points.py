"""Static point clouds (captured scene geometry): union-of-balls distance through a warp hash grid,
cross-checked against brute force, and an object resting on a table known only by its samples."""

import numpy as np
import pytest

from data_gen.sim.contact_points import box_surface
from data_gen.sim.material import Material
from data_gen.sim.static_scene import StaticBox, StaticPoints, StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator


def test_single_point_distance_normal_and_search_bound():
    scene = StaticScene(ground=False, points=StaticPoints(np.array([[0.0, 0.0, 0.5]]), radius_m=0.02, search_m=0.1))
    pts = np.array(
        [
            [0.0, 0.0, 0.6],  # 0.1 above the point: at the search radius -> 0.08 either way
            [0.03, 0.04, 0.5],  # 0.05 away: 0.05 - 0.02
            [0.0, 0.0, 0.51],  # inside the ball: 0.01 - 0.02
            [0.5, 0.0, 0.5],  # beyond the search radius: the bound 0.1 - 0.02
        ]
    )
    sdf, normal = scene.query(pts)
    np.testing.assert_allclose(sdf, [0.08, 0.03, -0.01, 0.08], atol=1e-7)
    np.testing.assert_allclose(normal[1], [0.6, 0.8, 0.0], atol=1e-12)
    np.testing.assert_allclose(normal[2], [0.0, 0.0, 1.0], atol=1e-12)


def test_points_with_ground_and_boxes_warp_matches_torch():
    rng = np.random.default_rng(0)
    cloud = rng.uniform([-0.3, -0.3, 0.2], [0.3, 0.3, 0.25], (3000, 3))
    scene = StaticScene(
        ground=True, boxes=(StaticBox((1.0, 0.0, 0.1), (0.1, 0.1, 0.1)),), points=StaticPoints(cloud, 0.02)
    )
    pts = rng.uniform([-0.6, -0.6, -0.05], [1.2, 0.6, 0.6], (20000, 3))
    sdf, normal = scene.query(pts)
    sdf_t, normal_t = scene.query_torch(pts)
    np.testing.assert_allclose(sdf, sdf_t.numpy(), atol=1e-9)
    np.testing.assert_allclose(normal, normal_t.numpy(), atol=1e-9)
    # brute force: the union of balls is min_j |x - p_j| - r wherever that is below the search bound
    exact = np.min(np.linalg.norm(pts[:500, None] - cloud[None], axis=2), axis=1) - 0.02
    expected = np.minimum(np.minimum(exact, 0.1 - 0.02), pts[:500, 2])
    expected = np.minimum(expected, StaticScene(ground=False, boxes=scene.boxes).query(pts[:500])[0])
    np.testing.assert_allclose(sdf[:500], expected, atol=1e-9)


def test_static_points_reject_bad_input():
    with pytest.raises(ValueError, match="points_m"):
        StaticPoints(np.zeros((0, 3)), 0.01)
    with pytest.raises(ValueError, match="points_m"):
        StaticPoints(np.array([[0.0, np.nan, 0.0]]), 0.01)
    with pytest.raises(ValueError, match="radius_m"):
        StaticPoints(np.zeros((1, 3)), 0.0)
    with pytest.raises(ValueError, match="search_m"):
        StaticPoints(np.zeros((1, 3)), 0.05, search_m=0.05)


def test_box_rests_on_a_table_known_only_by_samples():
    """A table top sampled every 5 mm at z = 0.3 m with balls of r = 1 cm: the union's top lies between
    sqrt(r^2 - s^2/2) = 9.35 mm (cell centres) and 10 mm (on a sample) above the samples.  A box dropped
    onto it rests with its bottom in that band and the table carries its weight."""
    spacing, radius, top = 0.005, 0.01, 0.3
    u = np.arange(-0.2, 0.2 + 1e-9, spacing)
    grid = np.stack(np.meshgrid(u, u, indexing="ij"), -1).reshape(-1, 2)
    table = StaticPoints(np.column_stack([grid, np.full(len(grid), top)]), radius)
    half = (0.1, 0.08, 0.05)
    pts = np.random.default_rng(0).uniform(-1.0, 1.0, (1500, 3)) * np.asarray(half)
    box = SimObjectSpec(
        "box", pts, float(8 * np.prod(half)), Material(1e7, 0.3, 500.0),
        position_m=(0.0, 0.0, top + radius + half[2] + 0.01), surface=box_surface(half, 4000, 0),
    )
    res = Simulator(StaticScene(ground=True, points=table), [box], (0.0, 0.0, -9.81), "draft", seed=0).run(26, 25.0)
    track = res.objects[0]
    bottom = float(track.deform(np.zeros((1, 3)), 25)[0][0, 2]) - half[2]
    low = top + np.sqrt(radius**2 - spacing**2 / 2)
    assert low - 3e-4 < bottom < top + radius + 3e-4
    assert track.contact_force_n[25, :, 2].sum() == pytest.approx(track.mass_kg * 9.81, rel=0.02)
    assert res.objects[0].com_m[:, 2].min() > top  # never fell through the table
