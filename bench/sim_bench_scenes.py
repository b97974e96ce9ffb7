"""The fixed benchmark scenes of the simulator benches (shared by bench_sim_quality / bench_sim_scaling).

Every scene is deterministic: geometry from fixed seeds, placement by hand.
"""

from __future__ import annotations

import numpy as np

from data_gen.sim.contact_points import box_surface, sphere_surface
from data_gen.sim.material import Material
from data_gen.sim.skinning import SkinningTrainingSettings
from data_gen.sim.static_scene import StaticBox, StaticScene
from data_gen.sim.world import SimObjectSpec

QUICK_TRAINING = SkinningTrainingSettings(steps=100, points_per_step=256, hidden_layers=2, width=32)
SURFACE_SAMPLES = 4000  # analytic surface samples per object (contact spheres are picked among them)


def box_points(half_extents_m, num_points: int, seed: int) -> np.ndarray:
    """Uniform random interior points of a box centred at the origin (m)."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.0, 1.0, (num_points, 3)) * np.asarray(half_extents_m)


def ball_points(radius_m: float, num_points: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-1.0, 1.0, (4 * num_points, 3))
    pts = pts[np.linalg.norm(pts, axis=1) <= 1.0][:num_points]
    return pts * radius_m


def _box(
    name,
    half,
    young,
    pos,
    vel=(0.0, 0.0, 0.0),
    spin=(0.0, 0.0, 0.0),
    quat=(1.0, 0.0, 0.0, 0.0),
    nu=0.3,
    rho=1000.0,
    seed=0,
    training=None,
    points=1500,
):
    pts = box_points(half, points, seed)
    vol = float(np.prod(2 * np.asarray(half)))
    return SimObjectSpec(
        name,
        pts,
        vol,
        Material(young, nu, rho),
        position_m=pos,
        orientation_wxyz=quat,
        velocity_m_s=vel,
        angular_velocity_rad_s=spin,
        skinning_settings=training,
        surface=box_surface(half, SURFACE_SAMPLES, seed),
    )


def _ball(
    name, radius, young, pos, vel=(0.0, 0.0, 0.0), nu=0.3, rho=1000.0, seed=0, training=None, points=1500
):
    pts = ball_points(radius, points, seed)
    return SimObjectSpec(
        name,
        pts,
        4.0 / 3.0 * np.pi * radius**3,
        Material(young, nu, rho),
        position_m=pos,
        velocity_m_s=vel,
        skinning_settings=training,
        surface=sphere_surface(radius, SURFACE_SAMPLES, seed),
    )


def _single_placement(scene_name: str, variant: int) -> None:
    if variant:
        raise ValueError(f"{scene_name} has one variant; got variant={variant}")


def rigid_drop(
    training: SkinningTrainingSettings | None = None, variant: int = 0
) -> tuple[StaticScene, list[SimObjectSpec]]:
    """One stiff box dropped, tilted and spinning, from 0.6 m onto the ground.

    ``variant`` 0 is the hand-placed drop; variant k > 0 draws the spin (rad/s, N(0, 2^2) per axis) and a
    uniformly random orientation from seed k.  Where a tumbling box lands on an edge or corner decides its
    bounce, so the bench averages errors over several variants instead of trusting one drop."""
    spin, quat = (1.0, 2.0, 0.5), (0.96, 0.2, 0.1, 0.0)
    if variant:
        rng = np.random.default_rng(variant)
        spin = tuple(float(v) for v in rng.normal(0.0, 2.0, 3))
        q = rng.normal(size=4)
        quat = tuple(float(v) for v in q / np.linalg.norm(q))
    return StaticScene(), [
        _box("crate", (0.1, 0.08, 0.06), 1e9, (0.0, 0.0, 0.6), spin=spin, quat=quat, seed=1, training=training)
    ]


def mixed_five(
    training: SkinningTrainingSettings | None = None, variant: int = 0
) -> tuple[StaticScene, list[SimObjectSpec]]:
    """Five objects (two soft, three stiff) thrown at each other over the ground, next to a static box.
    (One placement: ``variant`` must be 0.)"""
    _single_placement("mixed_five", variant)
    scene = StaticScene(boxes=(StaticBox((0.0, 0.6, 0.15), (0.5, 0.1, 0.15)),))
    return scene, [
        _box(
            "soft_a",
            (0.08, 0.08, 0.08),
            2e5,
            (-0.5, 0.0, 0.3),
            vel=(2.0, 0.0, 0.5),
            seed=2,
            training=training,
        ),
        _box(
            "stiff_b",
            (0.06, 0.1, 0.05),
            1e9,
            (0.5, 0.0, 0.3),
            vel=(-2.0, 0.0, 0.5),
            seed=3,
            training=training,
        ),
        _ball("ball_c", 0.07, 1e8, (0.0, -0.5, 0.4), vel=(0.0, 1.5, 0.0), seed=4, training=training),
        _ball("soft_d", 0.08, 5e5, (0.0, 0.0, 0.9), seed=5, training=training),
        _box(
            "stiff_e",
            (0.05, 0.05, 0.12),
            1e10,
            (0.3, -0.3, 0.15),
            quat=(0.92, 0.0, 0.0, 0.38),
            seed=6,
            training=training,
        ),
    ]


def soft_pile_ten(
    training: SkinningTrainingSettings | None = None, variant: int = 0
) -> tuple[StaticScene, list[SimObjectSpec]]:
    """Ten identical soft boxes dropped in a staggered column: they pile up on the ground.
    (One placement: ``variant`` must be 0.)"""
    _single_placement("soft_pile_ten", variant)
    objs = []
    for k in range(10):
        x = 0.05 * ((k % 3) - 1)
        y = 0.04 * ((k % 2) - 0.5)
        objs.append(
            _box(f"soft_{k}", (0.07, 0.07, 0.05), 1e5, (x, y, 0.08 + 0.13 * k), seed=10, training=training)
        )
    return StaticScene(), objs


SCENES = {"rigid_drop": rigid_drop, "mixed_five": mixed_five, "soft_pile_ten": soft_pile_ten}
# How many variants of each scene the quality bench averages over (cheap scenes get more).
SCENE_VARIANTS = {"rigid_drop": 5, "mixed_five": 1, "soft_pile_ten": 1}
