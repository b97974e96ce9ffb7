"""Post-simulation checks of the pipeline: what makes a sequence rejected, and the reason it names."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from data_gen.pipeline import SequenceRejected, check_simulation
from data_gen.sim.contact_points import box_surface
from data_gen.sim.material import Material
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

MATERIAL = Material(1e7, 0.3, 500.0)


@pytest.fixture(scope="module")
def resting_box():
    half = (0.05, 0.05, 0.05)
    pts = np.random.default_rng(0).uniform(-1, 1, (800, 3)) * half
    spec = SimObjectSpec("box", pts, 1e-3, MATERIAL, position_m=(0, 0, 0.06), surface=box_surface(half, 2000, 0))
    return Simulator(StaticScene(), [spec], (0, 0, -9.81), "draft", seed=0).run(6, 25.0)


def test_a_clean_simulation_passes(resting_box):
    check_simulation(resting_box, [MATERIAL])
    assert resting_box.objects[0].det_f.min() > 0.99  # a resting 10 MPa box barely strains


def test_inverted_material_is_rejected_with_object_frame_and_modulus(resting_box):
    bad = copy.deepcopy(resting_box)
    bad.objects[0].det_f[3, 7] = -0.02  # what a 1 kPa jelly crushed by an 8 kg block reached
    with pytest.raises(SequenceRejected, match=r"det F = -0.02 <= 0 at frame 3 \(young_modulus_pa=1e\+07") as err:
        check_simulation(bad, [MATERIAL])
    assert err.value.reason == "inverted"


@pytest.mark.parametrize(
    "plant,reason",
    [(lambda p: p.__setitem__((2, 0, 0), np.nan), "nan"), (lambda p: p.__setitem__((4, 0, 2), -0.3), "tunnelling")],
)
def test_non_finite_and_tunnelling_are_rejected(resting_box, plant, reason):
    bad = copy.deepcopy(resting_box)
    plant(bad.objects[0].contact_positions_m)
    with pytest.raises(SequenceRejected) as err:
        check_simulation(bad, [MATERIAL])
    assert err.value.reason == reason


def test_hollow_objects_get_contact_spheres_inside_their_envelope():
    """A cardboard box is a closed 1 mm shell: fitted against the wall itself no sphere of useful size
    fits (all 128 kept their 25.6 mm radius and poked out); against the envelope they touch the outside."""
    from data_gen.assets.registry import get_object
    from data_gen.pipeline import envelope_sdf
    from data_gen.sim.contact_points import SurfaceSamples, surface_spheres

    asset = get_object("cardboard_box")
    assert asset.is_hollow
    envelope = envelope_sdf(asset.shape)
    mesh = asset.to_mesh()
    surface = SurfaceSamples.from_mesh(mesh, 4000, seed=0, sdf=envelope)
    centres, radii = surface_spheres(surface, 128)
    assert len(radii) > 100
    assert np.all(envelope(centres) <= -0.999 * radii + 1e-9)
    assert np.median(radii) == pytest.approx(0.5 * np.sqrt(mesh.area / 128), rel=1e-9)
    assert (centres[:, 2] - radii).min() == pytest.approx(mesh.bounds[0, 2], abs=1e-4)  # rests on its true bottom
    assert asset.shape.sdf(centres).max() > 0.005  # most of each sphere lies in the cavity, as intended


def test_a_draw_the_simulator_cannot_run_is_rejected_not_fatal(monkeypatch):
    """An object too soft for its own weight (rho g L / E = 1000 * 9.81 * 0.1 / 50 ~ 20 > 1; E must be >= ~980 Pa) is refused by the
    simulator; generation turns that into a rejected draw with the simulator's reason."""
    from data_gen import pipeline
    from data_gen.sim.world import UnsimulatableDraw

    half = (0.05, 0.05, 0.05)
    pts = np.random.default_rng(0).uniform(-1, 1, (200, 3)) * half
    soft = SimObjectSpec("jelly", pts, 1e-3, Material(50.0, 0.3, 1000.0), position_m=(0, 0, 0.06))
    with pytest.raises(UnsimulatableDraw, match=r"jelly.*too soft.*allowed: E >= 9[78][0-9] Pa"):
        Simulator(StaticScene(), [soft], (0, 0, -9.81), "draft", seed=0)
    assert issubclass(UnsimulatableDraw, ValueError)  # callers catching ValueError keep working

    def build_simulator(*args, **kwargs):
        return Simulator(StaticScene(), [soft], (0, 0, -9.81), "draft", seed=0)

    monkeypatch.setattr(pipeline, "Simulator", build_simulator)
    monkeypatch.setattr(pipeline, "sim_static_scene", lambda layout: StaticScene())

    class _Scenario:
        objects, gravity_m_s2, seed, num_frames, fps = [], (0.0, 0.0, -9.81), 0, 2, 25.0

    with pytest.raises(SequenceRejected) as err:
        pipeline.simulate(_Scenario(), [], None, None)
    assert err.value.reason == "unsimulatable" and "too soft" in err.value.detail


@pytest.fixture(scope="module")
def two_boxes_side_by_side():
    """Two 10 cm boxes resting 2 cm apart on the ground (no contact between them)."""
    half = (0.05, 0.05, 0.05)
    pts = np.random.default_rng(0).uniform(-1, 1, (400, 3)) * half
    specs = [SimObjectSpec(f"box{k}", pts, 1e-3, MATERIAL, position_m=(0.12 * k, 0, 0.05), surface=box_surface(half, 2000, k))
             for k in range(2)]  # fmt: skip
    return Simulator(StaticScene(), specs, (0, 0, -9.81), "draft", seed=0).run(4, 25.0)


def test_two_objects_sunk_into_each_other_are_rejected_with_the_depth(two_boxes_side_by_side):
    """A contact the solver missed shows as spheres of two objects overlapping deeply: beyond half the sum of
    their radii the sequence is rejected, naming the objects, the depth and the frame; below it, it passes.
    Planted: two spheres per object (radii 1 and 1.5 cm), apart except at frame 2, where box 2's first sphere
    sits above box 1's first by (1 - fraction) x 2.5 cm."""
    from data_gen.sim.overlap import deepest_overlap

    check_simulation(two_boxes_side_by_side, [MATERIAL, MATERIAL])
    a, b = two_boxes_side_by_side.objects
    assert deepest_overlap([1, 2], [a.contact_positions_m, b.contact_positions_m], [a.contact_radius_m, b.contact_radius_m]) is None
    frames = a.contact_positions_m.shape[0]
    for fraction, rejected in ((0.4, False), (0.6, True)):
        bad = copy.deepcopy(two_boxes_side_by_side)
        a, b = bad.objects
        a.contact_radius_m, b.contact_radius_m = np.array([0.01, 0.01]), np.array([0.015, 0.01])
        a.contact_positions_m = np.tile([[0.0, 0.0, 0.1], [1.0, 0.0, 0.1]], (frames, 1, 1))
        b.contact_positions_m = np.tile([[0.0, 0.5, 0.1], [5.0, 0.0, 0.1]], (frames, 1, 1))
        b.contact_positions_m[2, 0] = [0.0, 0.0, 0.1 + (1.0 - fraction) * 0.025]
        found = deepest_overlap([1, 2], [a.contact_positions_m, b.contact_positions_m], [a.contact_radius_m, b.contact_radius_m])
        assert found.object_ids == (1, 2) and found.frame == 2
        assert found.fraction == pytest.approx(fraction, rel=1e-9)
        assert found.depth_m == pytest.approx(fraction * 0.025, rel=1e-9)
        if not rejected:
            check_simulation(bad, [MATERIAL, MATERIAL])
            continue
        with pytest.raises(SequenceRejected, match=r"objects 1 and 2 overlap by 15.0 mm at frame 2 \(0.60 of") as err:
            check_simulation(bad, [MATERIAL, MATERIAL])
        assert err.value.reason == "interpenetration"
