"""Recorded stress of a soft (multi-handle) object, which comes from its strain, checked against statics."""

import numpy as np

from data_gen.sim.contact_points import box_surface
from data_gen.sim.material import Material
from data_gen.sim.static_scene import StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

HALF = np.array([0.1, 0.07, 0.05])  # m
RHO = 700.0


def test_resting_soft_block_is_in_compression(tmp_path):
    """A 300 kPa block resting on a face of height L = 0.1 m: by the mean stress theorem its volume-mean
    hydrostatic stress is -rho g L / 6 = -114.4 Pa. The reduced field (4 handles, 64 cubature points on
    draft) gives -82 Pa, compressive at every cubature point (min -121, max -51 Pa); a sign error in the
    recorded strain path shows as tension."""
    pts = np.random.default_rng(0).uniform(-1, 1, (1500, 3)) * HALF
    spec = SimObjectSpec("block", pts, float(np.prod(2 * HALF)), Material(3e5, 0.3, RHO),
                         surface=box_surface(HALF, 3000, 0), position_m=(0, 0, HALF[2] + 0.005))
    res = Simulator(StaticScene(), [spec], (0, 0, -9.81), "draft", seed=0,
                    skinning_cache_dir=str(tmp_path)).run(26, 25.0)
    tr = res.objects[0]
    assert tr.num_handles > 1  # the strain path, not the rigid mean-stress path
    assert np.linalg.norm(tr.velocity_m_s[25]) < 1e-3  # at rest
    stress, volume = tr.hydrostatic_stress_pa[25], tr.volumes_m3
    expected = -RHO * 9.81 * 2 * HALF[2] / 6
    mean = float((stress * volume).sum() / volume.sum())
    assert 1.3 * expected <= mean <= 0.5 * expected, (mean, expected)
    assert volume[stress < 0].sum() >= 0.9 * volume.sum()
