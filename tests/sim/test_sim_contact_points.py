"""Surface contact spheres: geometry, exact resting heights, force bookkeeping, fast objects."""

import numpy as np
import pytest
import torch

from data_gen.sim.contact_points import (
    ContactPoints,
    CubatureGather,
    SurfaceSamples,
    box_surface,
    sphere_surface,
    surface_spheres,
)
from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.static_scene import StaticBox, StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

HALF = (0.1, 0.08, 0.05)


def box_points(half, n, seed):
    return np.random.default_rng(seed).uniform(-1.0, 1.0, (n, 3)) * np.asarray(half)


def box_spec(half, surface=True, young=1e7, position=None, **kw):
    pos = position or (0.0, 0.0, half[2] + 0.01)
    return SimObjectSpec(
        "box", box_points(half, 1500, 0), float(8 * np.prod(half)), Material(young, 0.3, 500.0),
        position_m=pos, surface=box_surface(half, 4000, 0) if surface else None, **kw,
    )


def origin_height(track, frame):
    """World z (m) of the object-frame origin (the box centre) at ``frame``."""
    return float(track.deform(np.zeros((1, 3)), frame)[0][0, 2])


def test_spheres_are_inside_and_touch_the_surface():
    surface = box_surface(HALF, 4000, seed=1)
    centres, radii = surface_spheres(surface, 256)
    sdf = surface.sdf(centres)
    assert np.all(sdf <= -0.999 * radii + 1e-12)  # inside the solid
    touching = np.abs(sdf + radii) < 1e-9  # outermost point on the surface
    assert touching.mean() > 0.95
    full = 0.5 * np.sqrt(surface.area_m2 / 256)
    assert np.isclose(radii.max(), full, rtol=1e-12)
    assert np.mean(np.isclose(radii, full)) > 0.6  # only spheres near edges shrink


def test_thin_plate_spheres_fit_the_thickness():
    half = (0.1, 0.1, 0.004)  # 8 mm plate: the unshrunk radius would be 0.5 sqrt(A / 128) = 9 mm
    surface = box_surface(half, 4000, seed=2)
    centres, radii = surface_spheres(surface, 128)
    assert 0.5 * np.sqrt(surface.area_m2 / 128) > 2 * half[2]
    assert radii.max() <= half[2] + 1e-12
    assert np.all(surface.sdf(centres) <= -0.999 * radii + 1e-12)


def test_sphere_surface_spheres_are_concentric_shells():
    surface = sphere_surface(0.07, 2000, seed=3)
    centres, radii = surface_spheres(surface, 128)
    np.testing.assert_allclose(np.linalg.norm(centres, axis=1) + radii, 0.07, atol=1e-12)


def test_surface_samples_reject_bad_input():
    pts = np.zeros((10, 3))
    with pytest.raises(ValueError, match="unit vectors"):
        SurfaceSamples(pts, np.zeros((10, 3)), 1.0)
    with pytest.raises(ValueError, match="area_m2"):
        SurfaceSamples(pts, np.tile([0.0, 0.0, 1.0], (10, 1)), 0.0)
    with pytest.raises(ValueError, match="shape"):
        SurfaceSamples(pts[:, :2], np.zeros((10, 2)), 1.0)


@pytest.mark.parametrize("preset", ["draft", "standard"])
def test_box_rests_at_its_true_height(preset):
    """With surface spheres a resting box's centre is at its half height (measured 0.04999-0.05000 m);
    with cubature spheres it hovered or sank by up to half a cubature spacing (0.0568-0.0618 m)."""
    res = Simulator(StaticScene(), [box_spec(HALF)], (0.0, 0.0, -9.81), preset, seed=0).run(26, 25.0)
    tr = res.objects[0]
    assert origin_height(tr, 25) == pytest.approx(HALF[2], abs=2e-4)
    # the recorded per-cubature contact forces carry the weight: sum = m g (resting, 1 s after a 1 cm drop)
    assert tr.contact_force_n[25, :, 2].sum() == pytest.approx(tr.mass_kg * 9.81, rel=0.02)


def test_resting_height_does_not_depend_on_the_cubature_count():
    heights = []
    for cubature in (32, 256):
        preset = load_preset("draft").replace(num_cubature_points=cubature)
        res = Simulator(StaticScene(), [box_spec(HALF)], (0.0, 0.0, -9.81), preset, seed=0).run(26, 25.0)
        heights.append(origin_height(res.objects[0], 25))
    assert abs(heights[0] - heights[1]) < 1e-4


def test_contact_forces_map_onto_nearest_cubature_points():
    cub = torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], dtype=torch.float64)
    centres = np.array([[0.1, 0.0, 0.0], [0.2, 0.0, 0.0], [0.9, 0.0, 0.0]])
    cp = ContactPoints.build(centres, np.full(3, 0.05), torch.ones(3, 1, dtype=torch.float64), cub)
    assert cp.cubature_index.tolist() == [0, 0, 1]
    force = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 2.0], [0.0, 0.0, 4.0]], dtype=torch.float64)
    partner = torch.tensor([0, 3, -1])
    strength = torch.tensor([1.0, 2.0, 0.0], dtype=torch.float64)
    f, p = cp.to_cubature(force, partner, strength, no_partner=-1)
    np.testing.assert_allclose(f.numpy(), [[0.0, 0.0, 3.0], [0.0, 0.0, 4.0]])
    assert p.tolist() == [3, -1]  # strongest sphere's partner; no strength -> no partner


def test_cubature_gather_equals_each_objects_to_cubature():
    """``CubatureGather`` (all objects' spheres to their cubature points in one pass) gives every object what its
    own ``to_cubature`` gives, bit for bit: sums in the same order, the strongest sphere's partner, ties between
    equally strong spheres of one point, and points without contact."""
    gen = torch.Generator().manual_seed(2)
    contacts = []
    for n_cub, n_sph in ((5, 12), (3, 7), (6, 20)):
        cub = torch.rand(n_cub, 3, generator=gen, dtype=torch.float64)
        centres = torch.rand(n_sph, 3, generator=gen, dtype=torch.float64).numpy()
        contacts.append(ContactPoints.build(centres, np.full(n_sph, 0.05), torch.ones(n_sph, 1, dtype=torch.float64), cub))
    forces = [torch.randn(c.num_points, 3, generator=gen, dtype=torch.float64) for c in contacts]
    partners = [torch.randint(0, 6, (c.num_points,), generator=gen) for c in contacts]
    strengths = [torch.randint(0, 3, (c.num_points,), generator=gen).to(torch.float64) for c in contacts]
    gathered = CubatureGather(contacts).to_cubature(forces, partners, strengths, -1)
    ties = 0
    for k, c in enumerate(contacts):
        f, p = c.to_cubature(forces[k], partners[k], strengths[k], no_partner=-1)
        assert torch.equal(gathered[k][0], f) and torch.equal(gathered[k][1], p)
        for point in range(c.num_cubature):
            top = strengths[k][c.cubature_index == point]
            ties += int(len(top) > 1 and float(top.max()) > 0 and int((top == top.max()).sum()) > 1)
    assert ties > 0  # equally strong spheres of one point: the same one wins
    assert any(bool((g[1] == -1).any()) for g in gathered)  # points without contact
    assert CubatureGather([]).to_cubature([], [], [], -1) == []


def test_fast_ball_does_not_tunnel_through_a_thin_wall():
    """A 5 cm ball at 20 m/s reaches 40 cm per 20 ms `draft` step; the wall is 4 cm thick.  The sub-step
    count follows the reach past the preset's cap (counted), so the ball stops at the wall."""
    radius = 0.05
    rng = np.random.default_rng(0)
    pts = rng.uniform(-1, 1, (4000, 3))
    pts = pts[np.linalg.norm(pts, axis=1) < 1][:1500] * radius
    ball = SimObjectSpec(
        "ball", pts, 4 / 3 * np.pi * radius**3, Material(1e9, 0.3, 1000.0), position_m=(0.0, 0.0, 0.5),
        velocity_m_s=(20.0, 0.0, 0.0), surface=sphere_surface(radius, 2000, 0),
    )
    wall = StaticScene(ground=False, boxes=(StaticBox((0.5, 0.0, 0.5), (0.02, 0.5, 0.5)),))
    res = Simulator(wall, [ball], (0.0, 0.0, 0.0), "draft", seed=0).run(6, 25.0)
    x = res.objects[0].com_m[:, 0]
    assert x.max() < 0.48 - radius + 0.01  # never past the wall's front face by more than 1 cm
    assert res.info.counters["substep_cap_raised"] > 0
