"""Meshing reuse: a scaled asset reuses its canonical mesh (one marching-tetrahedra run for every size)."""

import numpy as np
import pytest
from scipy.spatial import cKDTree

from data_gen.assets import meshing
from data_gen.assets.registry import get_object
from data_gen.assets.shapes import Box, Scaled, Sphere, mesh_sdf, place
from newtphys.rotations import axis_angle_to_quat


def test_random_sizes_mesh_once_and_scale_exactly():
    meshing.clear_mesh_cache()
    base = get_object("mug")
    canonical = base.to_mesh()
    misses = meshing._marched.cache_info().misses
    for size in np.random.default_rng(0).uniform(0.05, 0.5, 8):  # eight "sequences" of random sizes
        a = get_object("mug", size_m=float(size))
        s = a.shape.scale
        m = a.to_mesh()
        np.testing.assert_allclose(m.vertices, canonical.vertices * s, rtol=1e-12, atol=1e-15)
        np.testing.assert_array_equal(m.faces, canonical.faces)
        assert a.volume_m3() == pytest.approx(base.volume_m3() * s**3, rel=1e-12)
    assert meshing._marched.cache_info().misses == misses  # no re-meshing for any size


def test_reused_mesh_matches_remeshing_at_the_scaled_spacing():
    shape = Scaled(Sphere(0.1), 1.7)  # a smooth shape: remeshing at s * h gives the same grid scaled by s
    h = 0.0085
    reused = meshing.surface_mesh(shape, h)
    fresh = mesh_sdf(shape, spacing_m=h)
    assert len(reused.faces) == len(fresh.faces)
    gap, _ = cKDTree(fresh.vertices).query(reused.vertices)
    assert gap.max() < 0.01 * h  # same vertices up to the projection step's round-off (measured 1.2e-5 m)
    assert meshing.solid_volume_m3(shape, h) == pytest.approx(fresh.volume, rel=1e-9)
    assert fresh.volume == pytest.approx(4 / 3 * np.pi * 0.17**3, rel=0.005)


def test_transformed_and_nested_scaling_reuse():
    box = Box((0.1, 0.05, 0.02))
    q = axis_angle_to_quat((0.0, 0.0, 1.0), np.pi / 2)
    moved = place(box, (1.0, 2.0, 3.0), q)
    m = meshing.surface_mesh(moved, 0.01)
    lo, hi = m.bounds
    np.testing.assert_allclose(lo, [0.95, 1.9, 2.98], atol=0.004)  # x and y swapped by the 90 deg turn
    np.testing.assert_allclose(hi, [1.05, 2.1, 3.02], atol=0.004)
    assert meshing.solid_volume_m3(Scaled(Scaled(box, 2.0), 0.5), 0.01) == pytest.approx(
        meshing.solid_volume_m3(box, 0.01), rel=1e-12
    )
    with pytest.raises(ValueError, match="spacing_m"):
        meshing.surface_mesh(box, 0.0)


def test_disk_cache_round_trip_without_remeshing(tmp_path, monkeypatch):
    shape = Box((0.1, 0.05, 0.03))
    meshing.enable_disk_cache(tmp_path)
    try:
        meshing.clear_mesh_cache()
        first = meshing.surface_mesh(shape, 0.01)
        (entry,) = tmp_path.glob("mesh-*.npz")
        assert entry.name == f"mesh-{meshing.disk_cache_key(shape, 0.01)}.npz"
        meshing.clear_mesh_cache()

        def no_meshing(*args, **kwargs):
            raise AssertionError("re-meshed although the disk cache holds the mesh")

        monkeypatch.setattr(meshing, "mesh_sdf", no_meshing)
        again = meshing.surface_mesh(shape, 0.01)
        np.testing.assert_array_equal(again.vertices, first.vertices)
        np.testing.assert_array_equal(again.faces, first.faces)
        assert meshing.disk_cache_key(shape, 0.01) != meshing.disk_cache_key(Box((0.1, 0.05, 0.031)), 0.01)
    finally:
        meshing.enable_disk_cache(None)
        meshing.clear_mesh_cache()
