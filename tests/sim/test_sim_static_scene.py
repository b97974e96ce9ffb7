"""Static scene SDF: analytic values and warp kernel == torch reference."""

import numpy as np

from data_gen.sim.static_scene import StaticBox, StaticScene
from newtphys.rotations import quat_to_matrix


def test_ground_and_axis_aligned_box_analytic():
    scene = StaticScene(ground=True, boxes=(StaticBox((0.0, 0.0, 1.0), (0.5, 0.2, 0.1)),))
    pts = np.array(
        [
            [3.0, 0.0, 0.25],  # above ground only: 0.25
            [0.0, 0.0, 1.3],  # above the box top face (z = 1.1): 0.2
            [0.0, 0.0, 1.05],  # inside the box, 0.05 below its top face
            [0.8, 0.6, 1.0],  # outside, nearest an edge: sqrt(0.3^2 + 0.4^2) = 0.5
            [0.0, 0.0, -0.3],
        ]
    )  # under the ground: -0.3
    sdf, normal = scene.query(pts)
    np.testing.assert_allclose(sdf, [0.25, 0.2, -0.05, 0.5, -0.3], atol=1e-12)
    np.testing.assert_allclose(normal[[0, 1, 2, 4]], [[0, 0, 1]] * 4, atol=1e-12)
    np.testing.assert_allclose(normal[3], [0.6, 0.8, 0.0], atol=1e-12)


def test_rotated_box_warp_matches_torch_and_rotation():
    quat = np.array([0.9, 0.2, -0.3, 0.25])
    box = StaticBox((0.3, -0.2, 0.6), (0.4, 0.1, 0.25), tuple(quat))
    scene = StaticScene(ground=True, boxes=(box, StaticBox((1.0, 1.0, 0.2), (0.1, 0.2, 0.3))))
    pts = np.random.default_rng(0).uniform(-1.0, 2.0, (5000, 3))
    sdf, normal = scene.query(pts)
    sdf_t, normal_t = scene.query_torch(pts)
    np.testing.assert_allclose(sdf, sdf_t.numpy(), atol=1e-12)
    np.testing.assert_allclose(normal, normal_t.numpy(), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-12)
    # a point on the box's local +x axis, 0.3 m outside its face: distance 0.3, normal = R e_x
    rot = quat_to_matrix(quat)
    p = np.array(box.center_m) + rot @ np.array([0.7, 0.0, 0.0])
    d, n = StaticScene(ground=False, boxes=(box,)).query(p[None])
    np.testing.assert_allclose(d, [0.3], atol=1e-12)
    np.testing.assert_allclose(n[0], rot[:, 0], atol=1e-12)


def test_empty_scene_is_far():
    sdf, _ = StaticScene(ground=False).query(np.zeros((2, 3)))
    assert np.all(sdf > 1e20)


def test_ground_only_scene_answers_as_the_kernel_does():
    """A scene of the ground alone (or of nothing) is answered without a launch: the same distances and normals,
    bit for bit, as the kernel gives with a box too far away to matter."""
    rng = np.random.default_rng(3)
    pts = rng.normal(scale=2.0, size=(500, 3))
    far_box = StaticBox(center_m=(1e6, 0.0, 0.0), half_extents_m=(0.5, 0.5, 0.5))
    for ground in (True, False):
        sdf, normal = StaticScene(ground=ground).query(pts)
        sdf_k, normal_k = StaticScene(ground=ground, boxes=(far_box,)).query(pts)
        if ground:
            np.testing.assert_array_equal(sdf, sdf_k)
            np.testing.assert_array_equal(sdf, pts[:, 2])
        else:  # nothing: the empty scene's far distance (the kernel's box is nearer than that)
            assert np.all(sdf == 1e30) and np.all(sdf_k < 1e30)
        np.testing.assert_array_equal(normal, np.tile([0.0, 0.0, 1.0], (500, 1)))
        if ground:
            np.testing.assert_array_equal(normal, normal_k)
