"""Stress of near-rigid (single-handle) objects from the mean stress theorem, checked against statics
and a spinning body in closed form."""

import numpy as np
import pytest

from data_gen.sim.contact_points import box_surface
from data_gen.sim.material import Material
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

HALF = np.array([0.1, 0.07, 0.05])  # m
RHO = 700.0


def box(young, **kw):
    pts = np.random.default_rng(0).uniform(-1, 1, (1500, 3)) * HALF
    return SimObjectSpec("block", pts, float(np.prod(2 * HALF)), Material(young, 0.3, RHO),
                         surface=box_surface(HALF, 3000, 0), **kw)


@pytest.mark.parametrize("preset", ["draft", "standard"])
def test_resting_rigid_block_has_the_static_mean_stress(preset):
    """Resting on a face of height L = 0.1 m: mean hydrostatic stress -rho g L / 6 = -114.4 Pa.  With the
    strain of the 10 GPa affine handle the draft preset recorded noise of up to 1e5 Pa in a demo scene."""
    res = Simulator(StaticScene(), [box(1e10, position_m=(0, 0, HALF[2] + 0.005))], (0, 0, -9.81), preset,
                    seed=0).run(26, 25.0)
    tr = res.objects[0]
    assert tr.num_handles == 1
    expected = -RHO * 9.81 * 2 * HALF[2] / 6
    np.testing.assert_allclose(tr.hydrostatic_stress_pa[25], expected, rtol=0.02)
    assert np.ptp(tr.hydrostatic_stress_pa[25]) == 0.0  # one affine handle: one uniform value


def test_spinning_rigid_block_is_in_centrifugal_tension():
    """Free spin omega about z, no gravity, no contact: mean hydrostatic stress
    = sum m |omega x r|^2 / (3 V) = rho omega^2 (a^2 + b^2) / 9 for half extents a, b (4.25 Pa here), up to
    the particle sample's second moments."""
    omega = 3.0
    spec = box(1e10, position_m=(0, 0, 1.0), angular_velocity_rad_s=(0.0, 0.0, omega))
    res = Simulator(StaticScene(ground=False), [spec], (0, 0, 0), "standard", seed=0).run(3, 25.0)
    tr = res.objects[0]
    expected = RHO * omega**2 * (HALF[0] ** 2 + HALF[1] ** 2) / 9
    np.testing.assert_allclose(tr.hydrostatic_stress_pa[0], expected, rtol=0.03)
    assert tr.contact_force_n[0].sum() == 0.0
