"""Bad input gets a ValueError that names the object and the parameter."""

from types import SimpleNamespace

import numpy as np
import pytest

from data_gen.sim.material import Material
from data_gen.sim.presets import load_preset
from data_gen.sim.static_scene import StaticBox, StaticScene
from data_gen.sim.world import SimObjectSpec, Simulator

PTS = np.stack(np.meshgrid(*[np.linspace(-0.075, 0.075, 3)] * 3, indexing="ij"), -1).reshape(-1, 3)


def fake_material(young, nu, rho=1000.0):
    """Bypasses Material's own checks, to reach the simulator's validation."""
    mu = young / (2 * (1 + nu)) if young > 0 else 0.0
    return SimpleNamespace(young_modulus_pa=young, poisson_ratio=nu, density_kg_m3=rho, lame_pa=(mu, 0.0))


def make(spec_kwargs, scene=None, others=()):
    scene = StaticScene() if scene is None else scene
    kwargs = dict(
        name="obj",
        points_rest_m=PTS,
        volume_m3=0.008,
        material=Material(1e6, 0.3, 1000.0),
        position_m=(0.0, 0.0, 0.5),
    )
    kwargs.update(spec_kwargs)
    return Simulator(scene, [SimObjectSpec(**kwargs), *others], (0.0, 0.0, -9.81), "draft", seed=0)


@pytest.mark.parametrize("young", [0.0, -1e5])
def test_nonpositive_young_modulus(young):
    with pytest.raises(ValueError, match="young_modulus_pa"):
        Material(young, 0.3, 1000.0)
    with pytest.raises(ValueError, match=r"object 'obj': young_modulus_pa"):
        make({"material": fake_material(young, 0.3)})


@pytest.mark.parametrize("nu", [0.5, 0.7, -0.1])
def test_poisson_ratio_out_of_range(nu):
    with pytest.raises(ValueError, match="poisson_ratio"):
        Material(1e6, nu, 1000.0)
    with pytest.raises(ValueError, match=r"object 'obj': poisson_ratio=.*0 <= nu < 0.5"):
        make({"material": fake_material(1e6, nu)})


@pytest.mark.parametrize("volume", [0.0, -1.0, float("nan")])
def test_zero_volume(volume):
    with pytest.raises(ValueError, match=r"object 'obj': volume_m3"):
        make({"volume_m3": volume})


def test_overlapping_objects():
    other = SimObjectSpec("other", PTS, 0.008, Material(1e6, 0.3, 1000.0), position_m=(0.05, 0.0, 0.5))
    with pytest.raises(ValueError, match=r"'obj' and 'other' are spawned overlapping"):
        make({}, others=[other])
    apart = SimObjectSpec("other", PTS, 0.008, Material(1e6, 0.3, 1000.0), position_m=(0.5, 0.0, 0.5))
    assert len(make({}, others=[apart]).prepared) == 2


def test_spawned_inside_the_static_scene():
    with pytest.raises(ValueError, match=r"object 'obj': position_m=.*inside the static scene"):
        make({"position_m": (0.0, 0.0, 0.0)})
    box = StaticBox((0.0, 0.0, 0.5), (0.3, 0.3, 0.05))
    with pytest.raises(ValueError, match="inside the static scene"):
        make({}, scene=StaticScene(boxes=(box,)))


def test_other_bad_inputs():
    with pytest.raises(ValueError, match="points_rest_m"):
        make({"points_rest_m": PTS[:3]})
    with pytest.raises(ValueError, match="friction_coefficient"):
        make({"friction_coefficient": -0.1})
    with pytest.raises(ValueError, match="velocity_m_s"):
        make({"velocity_m_s": (0.0, float("inf"), 0.0)})
    with pytest.raises(ValueError, match="unique"):
        make({}, others=[SimObjectSpec("obj", PTS, 0.008, Material(1e6, 0.3, 1000.0), position_m=(1, 0, 1))])
    with pytest.raises(ValueError, match="gravity_m_s2"):
        Simulator(StaticScene(), [], (0.0, -9.81), "draft", seed=0)
    with pytest.raises(
        ValueError, match=r"unknown quality preset 'ultra'.*'draft', 'high', 'reference', 'standard'"
    ):
        Simulator(StaticScene(), [], (0.0, 0.0, -9.81), "ultra", seed=0)
    with pytest.raises(ValueError, match="num_frames"):
        make({}).run(0, 25.0)
    with pytest.raises(ValueError, match="fps"):
        make({}).run(3, 0.0)
    with pytest.raises(ValueError, match="half_extents_m"):
        StaticBox((0, 0, 0), (0.1, 0.0, 0.1))
    with pytest.raises(ValueError, match="newton_iterations"):
        load_preset("draft").replace(newton_iterations=0)
