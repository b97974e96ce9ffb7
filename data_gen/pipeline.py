"""Scenario -> simulate -> render every map -> world state: one sequence of the data contract.

Steps (each reads the same :class:`~data_gen.scenario.Scenario`, none changes it):

1. **Objects** (:func:`build_objects`): the library asset is scaled and
   coloured; interior points (simulation only, never rendered) and surface
   Gaussians (rendering only) are sampled in the asset's local frame.
2. **Simulate** (:mod:`data_gen.sim`): reduced elastodynamics of all objects
   in the scene layout's static geometry under the scenario's gravity.
3. **Render** (:func:`render_sequence`): per frame, every surface Gaussian is
   moved through the skinning map (centre) and the local deformation gradient
   (covariance ``F Σ Fᵀ``, normal ``F⁻ᵀ n``); its colour is shaded by the
   layout's light with shadows (``render.lighting``, off: the baked colours,
   :mod:`data_gen.render.lighting`); RGB is alpha-composited, labels come from the
   nearest covering Gaussian (binarized opacity), depth is where the pixel ray
   meets that splat (its density peak), and each Gaussian carries
   the values of its nearest cubature point (contact, stress) and of its
   object (id, material, class, mass x g). Scene flow is the displacement of
   that Gaussian to the next frame; optical flow is its projection (via
   depth and both cameras: the formula of
   :func:`newtphys.consistency.optical_flow_from_scene_flow`, run per pixel by
   :mod:`data_gen.render.motion_maps`), so the two agree by construction.
4. **World state** (:func:`build_world_state`) from the simulation record and
   the rendered visibility.

A sequence that cannot be used raises :class:`SequenceRejected` with the
reason (NaN in the simulation, tunnelling, objects out of view); the
generator logs it and draws a replacement.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import torch
from scipy.spatial import cKDTree

from data_gen.assets import material_taxonomy
from data_gen.assets.gaussians_from_geometry import gaussians_from_object, gaussians_from_scene
from data_gen.assets.materials import get_material, material_id_table
from data_gen.assets.object_asset import ObjectAsset, semantic_class_table
from data_gen.assets.registry import get_object, get_scene_layout
from data_gen.assets.scene_layout import SceneLayout
from data_gen.assets.shapes import Scaled, Shape, Shell
from data_gen.assets.voxel_shape import VoxelShape
from data_gen.cameras import path_from_spec
from data_gen.display_names import color_name, display_names
from data_gen.gaussians import Gaussians
from data_gen.object_boxes import oriented_box
from data_gen.render.labels import LabelRasterizer, gather_labels
from data_gen.render.lighting import SHADOW_TESTS, SceneLighting, largest_extent_m
from data_gen.render.motion_maps import motion_maps
from data_gen.render.projection import run_in_threads
from data_gen.render.rgb import RgbRasterizer
from data_gen.render.splat_pose import SplatPoser
from data_gen.scenario import Scenario
from data_gen.sim.contact_points import SurfaceSamples
from data_gen.sim.energy_rise import MAX_ENERGY_RISE_FRACTION, run_energy_rise
from data_gen.sim.material import Material
from data_gen.sim.overlap import MAX_OVERLAP_FRACTION, deepest_overlap
from data_gen.sim.presets import QualityPreset
from data_gen.sim.recording import SimulationResult
from data_gen.sim.reduced import affine_basis, deformation_basis, displacement_from_tmat, tmat_from_z
from data_gen.sim.solver import SimulationError
from data_gen.sim.static_scene import StaticBox, StaticPoints, StaticScene
from data_gen.sim.threads import torch_threads
from data_gen.sim.world import SimObjectSpec, Simulator, UnsimulatableDraw
from newtphys import geometry, schema
from newtphys.rotations import quat_to_matrix
from newtphys.shards import SequenceArrays
from newtphys.world_state import (
    CameraPose,
    CollisionEvent,
    FrameState,
    ObjectFrameState,
    ObjectInfo,
    SceneInfo,
    SimulationInfo,
    WorldState,
)

log = logging.getLogger(__name__)

BACKGROUND_RGB = (0.62, 0.70, 0.80)
"""Sky colour behind the scene (linear RGB in [0, 1])."""


class SequenceRejected(RuntimeError):
    """This sequence cannot be used; ``reason`` is a short machine-readable tag."""

    def __init__(self, reason: str, detail: str) -> None:
        super().__init__(f"{reason}: {detail}")
        self.reason = reason
        self.detail = detail


@dataclass(frozen=True)
class RenderSettings:
    """How densely objects and the scene are covered by Gaussians and sampled by particles.

    The values live in ``newtphys/conf/generate.yaml`` (``render:``), their one source: load them with
    ``data_gen.configs.render_settings(**changes)``.
    """

    object_gaussians: int
    """Surface Gaussians per object."""
    interior_points: int
    """Simulation particles per object (volume and mass sampling)."""
    contact_surface_samples: int
    """Surface samples per object among which the preset's contact spheres are picked."""
    scene_spacing_m: float
    """Grid spacing of the static scene's Gaussians."""
    min_visible_objects: int
    """Objects that must be visible (>= min_visible_pixels) in the last frame."""
    min_visible_pixels: int
    device: str
    """Warp device: ``cpu`` or ``cuda``."""
    num_threads: int
    """CPU threads of one sequence: the renderer's row bands, and the draw's skinning bases trained side by side."""
    lighting: bool
    """Shade RGB with the scene's light (``data_gen.render.lighting``); false: colours as baked (unlit)."""
    shadows: bool
    """With lighting: objects (and a layout's boxes) cast shadows through a shadow map."""
    shadow_map_px: int
    """Side of the square shadow map, px."""
    shadow_bias_m: float
    """Constant depth bias of the shadow test, m (a slope-scaled term is added, ``render.shadow_map``)."""
    shadow_test: str
    """``pixel`` (each pixel's surface point, two RGB passes) or ``splat`` (each splat's centre, one pass)."""

    def __post_init__(self) -> None:
        if int(self.shadow_map_px) < 8:
            raise ValueError(f"render.shadow_map_px must be >= 8 px, got {self.shadow_map_px}")
        if self.shadow_test not in SHADOW_TESTS:
            raise ValueError(f"render.shadow_test must be one of {SHADOW_TESTS}, got {self.shadow_test!r}")
        if not (np.isfinite(self.shadow_bias_m) and self.shadow_bias_m >= 0.0):
            raise ValueError(f"render.shadow_bias_m must be a finite distance >= 0 m, got {self.shadow_bias_m}")


@dataclass
class SceneObject:
    """One scenario object, ready for simulation and rendering (local frame of the asset)."""

    object_id: int
    asset: ObjectAsset
    surface: Gaussians
    interior_points_m: np.ndarray
    volume_m3: float
    contact_surface: SurfaceSamples
    material: Material
    material_id: int
    semantic_id: int


def envelope_sdf(shape: Shape):
    """SDF of a shape's outer envelope for fitting contact spheres: a closed shell's cavity counts as
    inside (a 1 mm cardboard wall cannot hold a contact sphere of useful size, its envelope can).
    None for a voxelised splat solid: its distance transform underestimates depth (|grad| 0.6-0.8),
    which would shrink most spheres away (16 of 128 kept on a 10 cm splat ball); its spheres keep
    their full radius, touching the surface at their sample."""
    inner = shape.child if isinstance(shape, Scaled) else shape
    if isinstance(inner, VoxelShape):
        return None
    if isinstance(shape, Scaled) and isinstance(shape.child, Shell):
        return Scaled(shape.child.child, shape.scale).sdf
    if isinstance(shape, Shell):
        return shape.child.sdf
    return shape.sdf


def sim_static_scene(layout: SceneLayout) -> StaticScene:
    """The kinematic collision geometry of a layout: ground plane, oriented boxes and (captured scenes)
    the collision points of the captured geometry."""
    points = None
    if layout.collision_points_m is not None:
        points = StaticPoints(layout.collision_points_m, layout.collision_radius_m)
    return StaticScene(
        ground=True,
        boxes=tuple(StaticBox(tuple(b.center_m), tuple(b.half_extents_m), tuple(b.rotation_wxyz)) for b in layout.boxes),
        points=points,
    )


def build_objects(scenario: Scenario, settings: RenderSettings) -> list[SceneObject]:
    out = []
    mat_ids = {name: int(k) for k, name in material_id_table().items()}
    for p in scenario.objects:  # loop over objects
        rng = np.random.default_rng(p.color_seed)
        asset = get_object(p.asset, size_m=p.size_m).with_material_color(p.material, rng)
        surface = gaussians_from_object(asset, rng, count=settings.object_gaussians)
        volume = asset.volume_m3()
        spacing = (volume / settings.interior_points) ** (1.0 / 3.0)
        interior = asset.interior_points(spacing, rng)
        if len(interior) < 8:
            raise SequenceRejected("degenerate_object", f"object {p.object_id} ({p.asset}) has {len(interior)} interior points")
        # contact spheres touch this surface from inside (exact resting heights, see data_gen.sim.contact_points)
        contact_surface = SurfaceSamples.from_mesh(
            asset.to_mesh(), settings.contact_surface_samples, seed=p.color_seed, sdf=envelope_sdf(asset.shape)
        )
        out.append(SceneObject(
            object_id=p.object_id, asset=asset, surface=surface, interior_points_m=interior, volume_m3=volume,
            contact_surface=contact_surface,
            material=Material(p.young_modulus_pa, p.poisson_ratio, p.density_kg_m3),
            material_id=mat_ids[p.material], semantic_id=asset.semantic_id,
        ))
    return out


def simulate(scenario: Scenario, objects: list[SceneObject], layout: SceneLayout, preset: QualityPreset,
             skinning_cache_dir: str | None = None, training_threads: int = 1, device: str = "cpu",
             device_newton: bool = False) -> SimulationResult:  # fmt: skip
    """Simulate a scenario's objects (``training_threads``: threads that train the draw's skinning bases side by
    side, the same bases in every case; ``device`` and ``device_newton`` as :class:`Simulator`'s: the broad phase's
    device and the Newton solves' there); raises SequenceRejected for a draw whose simulation fails or is wrong."""
    specs = [
        SimObjectSpec(
            name=f"{o.object_id}:{o.asset.name}", points_rest_m=o.interior_points_m, volume_m3=o.volume_m3,
            material=o.material, position_m=p.position_m, orientation_wxyz=p.orientation_wxyz,
            velocity_m_s=p.velocity_m_s, angular_velocity_rad_s=p.angular_velocity_rad_s,
            surface=o.contact_surface,
        )
        for o, p in zip(objects, scenario.objects)
    ]
    try:
        sim = Simulator(sim_static_scene(layout), specs, scenario.gravity_m_s2, preset, seed=scenario.seed,
                        skinning_cache_dir=skinning_cache_dir, training_threads=training_threads, device=device,
                        device_newton=device_newton)  # fmt: skip
        result = sim.run(scenario.num_frames, scenario.fps)
    except SimulationError as e:
        raise SequenceRejected("simulation_failed", str(e)) from None
    except UnsimulatableDraw as e:  # e.g. an object too soft for its own weight: reject the draw, not the run
        raise SequenceRejected("unsimulatable", str(e)) from None
    check_simulation(result, [o.material for o in objects])
    return result


def check_simulation(result: SimulationResult, materials: list[Material]) -> None:
    """Reject a simulation whose labels would be wrong: non-finite positions, an object below the ground
    (tunnelling), two objects sunk into each other (contact spheres overlapping by more than
    ``MAX_OVERLAP_FRACTION`` of their radii's sum: a contact the solver missed), energy gained from nowhere (the
    recorded total rising by more than ``MAX_ENERGY_RISE_FRACTION`` of its offset-free scale,
    :mod:`data_gen.sim.energy_rise`: a missed contact pushed out later) or inverted material
    (det F <= 0: a soft object crushed past what the reduced model represents, e.g. E = 1 kPa hit by a heavy
    block).  Raises :class:`SequenceRejected` naming it."""
    for track, material in zip(result.objects, materials):
        pts = track.contact_positions_m
        if not np.isfinite(pts).all():
            raise SequenceRejected("nan", f"object {track.object_id} has non-finite positions")
        lowest = float(pts[..., 2].min())
        if lowest < -0.5 * float(track.contact_radius_m.max()) - 0.01:
            raise SequenceRejected("tunnelling", f"object {track.object_id} reached z = {lowest:.3f} m below the ground")
    tracks = result.objects
    overlap = deepest_overlap([t.object_id for t in tracks], [t.contact_positions_m for t in tracks],
                              [t.contact_radius_m for t in tracks])  # fmt: skip
    if overlap is not None and overlap.fraction > MAX_OVERLAP_FRACTION:
        a, c = overlap.object_ids
        raise SequenceRejected(
            "interpenetration", f"objects {a} and {c} overlap by {1e3 * overlap.depth_m:.1f} mm at frame {overlap.frame} "
            f"({overlap.fraction:.2f} of their contact spheres' radii; at most {MAX_OVERLAP_FRACTION})"
        )
    rise = run_energy_rise(result)
    if rise.fraction > MAX_ENERGY_RISE_FRACTION:
        raise SequenceRejected(
            "energy_gain", f"the total energy rose by {rise.rise_j:.3g} J above its lowest value by frame {rise.frame} "
            f"({rise.fraction:.3g} of the run's scale {rise.scale_j:.3g} J; at most {MAX_ENERGY_RISE_FRACTION}): "
            "a contact resolved too late"
        )
    for track, material in zip(result.objects, materials):
        det_min = float(track.det_f.min())
        if not det_min > 0.0:
            frame = int(np.argmin(track.det_f.min(axis=1)))
            raise SequenceRejected(
                "inverted", f"object {track.object_id} ({track.name}): det F = {det_min:.3g} <= 0 at frame {frame} "
                f"(young_modulus_pa={material.young_modulus_pa:.3g} is too soft for this impact)"
            )


def camera_matrices(scenario: Scenario) -> tuple[np.ndarray, np.ndarray]:
    """(K (3, 3), world_to_camera (T, 4, 4)) of the scenario's camera path."""
    h, w = scenario.image_size
    K = geometry.intrinsics_from_fov(scenario.camera.fov_x_deg, h, w)
    return K, path_from_spec(scenario.camera, scenario.num_frames, scenario.fps)


class SkinnedSurface:
    """An object's surface Gaussians driven by its simulated handles.

    Skinning weights, the affine basis b and the deformation basis C of every
    surface Gaussian are evaluated once; each frame then costs two small
    matrix products (x = x0 + Tm b, F = I + Tm C). A deformed splat's
    covariance (F R S)(F R S)^T is stored back as rotation + scales through the
    SVD of F R S, so it stays a valid Gaussian by construction: one warp launch
    per frame on ``device`` (:class:`~data_gen.render.splat_pose.SplatPoser`).

    On a CUDA ``device`` the bases are evaluated and kept there (torch, float64: the skinning MLP with its
    Jacobian at 10^5 splats is seconds of one CPU thread), and only the posed splats come back to the host.
    """

    def __init__(self, surface: Gaussians, track, device: str = "cpu", num_threads: int = 1) -> None:
        on = torch_device_of(device)
        x0 = torch.as_tensor(surface.means_m, dtype=torch.float64).to(on)
        w, g = track.basis.evaluate(x0, num_threads=num_threads)
        self.x0 = x0
        self.b = affine_basis(x0, w.to(torch.float64))
        self.c = deformation_basis(x0, w.to(torch.float64), g.to(torch.float64))
        rot = torch.as_tensor(quat_to_matrix(surface.rotations_wxyz.astype(np.float64))).to(on)
        self.rs = rot * torch.as_tensor(surface.scales_m, dtype=torch.float64).to(on)[:, None, :]
        self.n0 = surface.surface_normals()
        self.track = track
        self.device = device
        # built here, on the caller's thread: render_sequence poses objects on parallel threads, and building posers
        # there (warp's module load and launch recording at once on two threads) crashed a process about 1 in 6
        self._poser = SplatPoser(self.x0, self.b, self.c, self.rs, self.n0, self.device)

    def tmat(self, frame: int) -> torch.Tensor:
        """The handle matrix Tm (3, 4H) at ``frame``."""
        return tmat_from_z(torch.as_tensor(self.track.handle_transforms[frame], dtype=torch.float64))

    def means_at(self, frame: int) -> np.ndarray:
        """World centres (n, 3) m at ``frame`` (no covariance: cheap)."""
        return (self.x0 + displacement_from_tmat(self.b, self.tmat(frame).to(self.x0.device))).cpu().numpy()

    def at(self, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World centres (n, 3) m, scales (n, 3) m and rotations (n, 4) wxyz at ``frame``."""
        return self.pose(frame)[:3]

    def pose(self, frame: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`at` plus the unit normals (n, 3) at ``frame``: F^-T n0, renormalised (F = dx/dx0 holds the
        object's rotation and deformation)."""
        return self._poser.pose(self.tmat(frame))


def torch_device_of(device: str) -> torch.device:
    """The torch device holding a warp ``device``'s data ("cpu", "cuda", "cuda:1"); the CPU when torch has no
    CUDA (warp's kernels then still run there, on inputs copied up)."""
    if device.startswith("cuda") and torch.cuda.is_available():
        return torch.device(device)
    return torch.device("cpu")


def scene_lighting(layout: SceneLayout, settings: RenderSettings, objects: list[SceneObject],
                   skinned: list[SkinnedSurface], scene_g: Gaussians, t_count: int) -> SceneLighting | None:
    """The sequence's :class:`SceneLighting` (None when ``settings.lighting`` is off), its light view fitted to
    every position the casters take: the layout's boxes and every object's surface centres over all frames."""
    if not settings.lighting:
        return None
    lighting = SceneLighting(layout.light, settings.shadows, settings.shadow_map_px, settings.shadow_bias_m,
                             settings.device, settings.num_threads, settings.shadow_test)
    points = [np.zeros((0, 3))]
    radius = 0.0
    if layout.splats is None and (scene_g.part_ids > 0).any():
        boxes = scene_g.subset(scene_g.part_ids > 0)
        points.append(boxes.means_m)
        radius = largest_extent_m(boxes)
    for o, sk in zip(objects, skinned):  # loop over objects and frames
        points.extend(sk.means_at(t) for t in range(t_count))
        radius = max(radius, largest_extent_m(o.surface))
    lighting.fit(points, radius)  # (read block by block: 10^6 splats x 50 frames are never joined)
    return lighting


def skinned_surfaces(objects: list[SceneObject], result: SimulationResult, device: str = "cpu",
                     num_threads: int = 1) -> list[SkinnedSurface]:  # fmt: skip
    """Every object's :class:`SkinnedSurface` (its skinning basis evaluated at every surface splat, once per
    sequence: the renderer and the world state share them), on ``num_threads`` CPU threads (the same bytes for
    any count)."""
    tracks = {t.object_id: t for t in result.objects}
    return [SkinnedSurface(o.surface, tracks[o.object_id], device, num_threads) for o in objects]


def render_sequence(scenario: Scenario, objects: list[SceneObject], layout: SceneLayout, result: SimulationResult,
                    settings: RenderSettings, skinned: list[SkinnedSurface] | None = None,
                    ) -> tuple[dict[str, np.ndarray], np.ndarray, np.ndarray]:  # fmt: skip
    """Every map of the contract for every frame: (maps, K float32, world_to_camera float32). ``skinned``: the
    objects' :func:`skinned_surfaces` (built here when None)."""
    K, w2c = camera_matrices(scenario)
    h, w = scenario.image_size
    t_count, n_obj = scenario.num_frames, len(objects)
    maps = {name: np.zeros(spec.expected_shape(t_count, h, w, n_obj), spec.dtype) for name, spec in schema.MAPS.items()}
    scene_g = gaussians_from_scene(layout, spacing_m=settings.scene_spacing_m)
    scene_mats = np.array([get_material(layout.floor_material).id] + [get_material(b.material).id for b in layout.boxes],
                          np.uint8)
    n_scene = len(scene_g)
    sizes = [len(o.surface) for o in objects]
    offsets = np.concatenate([[n_scene], n_scene + np.cumsum(sizes)]).astype(int)
    instance = np.concatenate([np.zeros(n_scene, np.uint16)] + [np.full(s, o.object_id, np.uint16) for o, s in zip(objects, sizes)])
    material = np.concatenate([scene_mats[scene_g.part_ids]] + [np.full(s, o.material_id, np.uint8) for o, s in zip(objects, sizes)])
    semantic = np.concatenate([np.zeros(n_scene, np.uint16)] + [np.full(s, o.semantic_id, np.uint16) for o, s in zip(objects, sizes)])
    tracks = {t.object_id: t for t in result.objects}
    if skinned is None:
        skinned = skinned_surfaces(objects, result, settings.device, settings.num_threads)
    # Nearest cubature point of every surface Gaussian, in the rest frame (fixed for the sequence).
    nearest = [cKDTree(tracks[o.object_id].points_rest_m).query(o.surface.means_m.astype(np.float64))[1] for o in objects]
    gravity = np.asarray(scenario.gravity_m_s2, np.float64)
    mass_of_id = np.zeros(max([o.object_id for o in objects], default=0) + 1)
    for o in objects:
        mass_of_id[o.object_id] = tracks[o.object_id].mass_kg
    colors = np.concatenate([scene_g.colors_rgb] + [o.surface.colors_rgb for o in objects])
    opac = np.concatenate([scene_g.opacities] + [o.surface.opacities for o in objects])
    n_all = len(instance)
    positions = np.zeros((t_count, n_all, 3))
    positions[:, :n_scene] = scene_g.means_m
    scales = np.concatenate([scene_g.scales_m, np.zeros((n_all - n_scene, 3), np.float32)])
    rotations = np.concatenate([scene_g.rotations_wxyz, np.zeros((n_all - n_scene, 4), np.float32)])
    normals = np.concatenate([scene_g.surface_normals(), np.zeros((n_all - n_scene, 3), np.float32)])
    lighting = scene_lighting(layout, settings, objects, skinned, scene_g, t_count)
    # casters: objects, and a layout's boxes (part > 0; the floor cannot shadow anything above it); a captured
    # scene neither casts nor is relit (its light is in its colours), see data_gen.render.lighting
    captured = layout.splats is not None
    casters = np.concatenate([np.zeros(n_scene, bool) if captured else scene_g.part_ids > 0, np.ones(n_all - n_scene, bool)])
    prelit = np.concatenate([np.full(n_scene, captured), np.zeros(n_all - n_scene, bool)])
    # normals of unknown sign (a splat's shortest axis: splat files without nx ny nz) are lit two-sided
    two_sided = np.concatenate([np.full(n, g.normals is None) for n, g in
                                zip([n_scene] + sizes, [scene_g] + [o.surface for o in objects])])
    rgb_r = RgbRasterizer(h, w, settings.device, settings.num_threads)
    lab_r = LabelRasterizer(h, w, settings.device, settings.num_threads, depth_mode="surface")
    index_all = np.zeros((t_count, h, w), np.int32)
    pose_workers = settings.num_threads if settings.device == "cpu" else 1
    object_ids = [o.object_id for o in objects]
    weight = mass_of_id[:, None] * gravity  # (ids, 3) N, world frame: every pixel of an id has its object's
    amodal_materials, amodal_semantics = (  # per object (objects, 1, 1), in the maps' dtypes
        np.array([getattr(o, f) for o in objects], schema.MAPS[m].dtype).reshape(-1, 1, 1)
        for f, m in (("material_id", schema.AMODAL_MATERIALS), ("semantic_id", schema.AMODAL_SEMANTIC_SEGMENTATION)))
    for t in range(t_count):  # loop over frames
        contact = np.zeros(n_all, bool)
        stress = np.zeros(n_all, np.float32)
        def pose_object(k: int, t: int = t) -> None:  # one warp launch: objects are posed on parallel threads
            sl = slice(offsets[k], offsets[k + 1])
            positions[t, sl], scales[sl], rotations[sl], normals[sl] = skinned[k].pose(t)

        run_in_threads(pose_object, n_obj, pose_workers)
        for k, o in enumerate(objects):  # loop over objects
            sl = slice(offsets[k], offsets[k + 1])
            tr = tracks[o.object_id]
            contact[sl] = tr.contact_partner[t][nearest[k]] >= 0
            stress[sl] = tr.hydrostatic_stress_pa[t][nearest[k]]
        g = Gaussians(means_m=positions[t], scales_m=scales, rotations_wxyz=rotations, colors_rgb=colors,
                      opacities=opac, normals=normals)
        index, depth = lab_r.render(g, K, w2c[t])
        if lighting is None:
            rgb, _ = rgb_r.render(g, K, w2c[t], background_rgb=BACKGROUND_RGB)
        else:
            rgb = lighting.render_rgb(rgb_r, g, K, w2c[t], index, depth, casters, prelit, two_sided, BACKGROUND_RGB)
        maps[schema.RGB][t] = np.clip(np.round(rgb * 255.0), 0, 255).astype(np.uint8)
        index_all[t] = index
        maps[schema.DEPTH][t] = depth
        ids = gather_labels(index, instance)
        maps[schema.INSTANCES][t] = ids
        maps[schema.MATERIALS][t] = gather_labels(index, material)
        maps[schema.SEMANTIC_SEGMENTATION][t] = gather_labels(index, semantic)
        maps[schema.COLLISION][t] = gather_labels(index, contact, False)
        maps[schema.STRESS][t] = gather_labels(index, stress)
        np.take(geometry.rotate_vectors(w2c[t], weight).astype(np.float32), ids, axis=0, out=maps[schema.GRAVITY][t])
        if n_obj:
            masks = lab_r.render_group_masks(g, K, w2c[t], instance, object_ids, projected=True)  # as rendered above
            maps[schema.AMODAL_INSTANCES][t] = masks
            np.multiply(masks, amodal_materials, out=maps[schema.AMODAL_MATERIALS][t])  # (objects, H, W): id or 0
            np.multiply(masks, amodal_semantics, out=maps[schema.AMODAL_SEMANTIC_SEGMENTATION][t])
    for t in range(t_count - 1):  # each pixel's winner moved to frame t + 1; the optical flow that implies
        motion_maps(index_all[t], maps[schema.DEPTH][t], positions[t], positions[t + 1], K, w2c[t], w2c[t + 1],
                    settings.device, settings.num_threads, out=(maps[schema.SCENE_FLOW][t], maps[schema.OPTICAL_FLOW][t]))
    return maps, K.astype(np.float32), w2c.astype(np.float32)


def camera_fov_deg(K: np.ndarray, image_size: tuple[int, int]) -> dict[str, float]:
    """Horizontal and vertical field of view, degrees, of intrinsics ``K`` (px) at ``image_size`` (H, W)."""
    h, w = image_size
    return {"fov_x_deg": float(np.degrees(2.0 * np.arctan2(0.5 * w, K[0, 0]))),
            "fov_y_deg": float(np.degrees(2.0 * np.arctan2(0.5 * h, K[1, 1])))}


def build_world_state(scenario: Scenario, objects: list[SceneObject], layout: SceneLayout, result: SimulationResult,
                      maps: dict[str, np.ndarray], K: np.ndarray, world_to_camera: np.ndarray,
                      wall_time_s: float, lit: bool = True, surfaces: list[SkinnedSurface] | None = None) -> WorldState:
    """The world-state JSON of a generated sequence (data contract), with what questions read: per frame and
    object the oriented box of the deformed object, per frame the camera's field of view, per object a
    display name unique in the scene, its colour word and its material taxonomy (scene materials too), and,
    when the RGB was ``lit``, the scene's light. ``surfaces``: the objects' :func:`skinned_surfaces` (the
    renderer's, built here when None)."""
    tracks = {t.object_id: t for t in result.objects}
    if surfaces is None:
        surfaces = skinned_surfaces(objects, result)
    fov = camera_fov_deg(K, scenario.image_size)
    frames = []
    for t in range(scenario.num_frames):
        pos, quat = geometry.camera_pose(world_to_camera[t].astype(np.float64))
        objs = []
        for k, o in enumerate(objects):
            tr = tracks[o.object_id]
            box = oriented_box(surfaces[k].means_at(t), tr.orientation_wxyz[t])
            visible = int((maps[schema.INSTANCES][t] == o.object_id).sum())
            amodal = int(maps[schema.AMODAL_INSTANCES][t, k].sum())
            partners = sorted({int(p) for p in np.unique(tr.contact_partner[t]) if p >= 0})
            objs.append(ObjectFrameState(
                id=o.object_id, position=tuple(tr.com_m[t].tolist()),
                orientation=tuple(float(v) for v in tr.orientation_wxyz[t]),
                velocity=tuple(tr.velocity_m_s[t].tolist()), angular_velocity=tuple(tr.angular_velocity_rad_s[t].tolist()),
                visible_pixels=visible, visible_fraction=min(1.0, visible / amodal) if amodal else 0.0,
                in_view=amodal > 0, contacts=partners, extra={"box": box},
            ))
        camera = CameraPose(tuple(pos.tolist()), tuple(quat.tolist()), extra=fov)
        frames.append(FrameState(t, t / scenario.fps, camera, objs))
    colours = [o.surface.colors_rgb.astype(np.float64).mean(axis=0) for o in objects]
    names = display_names([o.asset.name for o in objects], colours, [o.asset.nominal_size_m for o in objects])
    scene_materials = [layout.floor_material] + [b.material for b in layout.boxes]
    info = result.info.to_dict()
    sim_info = SimulationInfo(
        quality=info.pop("quality"), dt=info.pop("dt"), substeps=info.pop("substeps"),
        newton_iterations=info.pop("newton_iterations"), wall_time_s=info.pop("wall_time_s"),
        extra={**info, "pipeline_wall_time_s": wall_time_s},
    )
    return WorldState(
        schema_version=schema.SCHEMA_VERSION, sequence_id=scenario.sequence_id, seed=scenario.seed,
        split=scenario.split, fps=scenario.fps, num_frames=scenario.num_frames, image_size=scenario.image_size,
        gravity=tuple(float(v) for v in scenario.gravity_m_s2),
        scene=SceneInfo(name=layout.name, kind=layout.kind,
                        extra={"camera": scenario.camera.kind,
                               "materials": [{"name": m, **material_taxonomy.nominal(m).to_dict()} for m in scene_materials]}
                        | ({"source": layout.source} if layout.source else {})
                        | ({"light": layout.light.to_dict()} if lit else {})),
        materials=material_id_table(), semantic_classes=semantic_class_table(),
        objects=[
            ObjectInfo(
                id=o.object_id, name=o.asset.name, category=o.asset.category, material=p.material,
                young_modulus=p.young_modulus_pa, poisson_ratio=p.poisson_ratio, density=p.density_kg_m3,
                mass=tracks[o.object_id].mass_kg, volume=o.volume_m3, size=tuple(o.asset.size_m.tolist()),
                num_handles=tracks[o.object_id].num_handles,
                num_cubature_points=int(len(tracks[o.object_id].points_rest_m)),
                extra={"motion": p.motion, "display_name": name, "color": color_name(colour),
                       "material_taxonomy": material_taxonomy.classify(p.material, p.young_modulus_pa,
                                                                       p.density_kg_m3).to_dict()}
                | ({"source": o.asset.source} if o.asset.source else {}),
            )
            for o, p, name, colour in zip(objects, scenario.objects, names, colours)
        ],
        frames=frames,
        collisions=[CollisionEvent(**_event_fields(e.to_dict())) for e in result.collisions],
        simulation=sim_info,
        extra={k: v for k, v in (("counterfactual_of", scenario.counterfactual_of), ("change", scenario.change),
                                 ("scenario", scenario.kind)) if v},
    )


def _event_fields(d: dict) -> dict:
    return {"frame": d["frame"], "objects": tuple(d["objects"]), "position": tuple(d["position"]),
            "normal": tuple(d["normal"]), "impulse": d["impulse"], "peak_force": d["peak_force"]}


def generate_sequence(scenario: Scenario, preset: QualityPreset, settings: RenderSettings,
                      skinning_cache_dir: str | None = None) -> tuple[SequenceArrays, dict[str, float]]:
    """One sequence of the contract, plus wall times (s) of its stages. Raises SequenceRejected."""
    t0 = time.perf_counter()
    layout = get_scene_layout(scenario.scene)
    objects = build_objects(scenario, settings)
    t1 = time.perf_counter()
    result = simulate(scenario, objects, layout, preset, skinning_cache_dir, training_threads=settings.num_threads)
    t2 = time.perf_counter()
    with torch_threads(1):  # the per-frame products are small: one thread beats a contended pool; and torch's products
        # of 10^5 rows on 3 threads differ from 1 or 2 in the last bit (seen on this machine): the bases' evaluation at
        # every splat runs fixed chunks of rows, each on one torch thread, render.num_threads of them at a time (a
        # sequence must not depend on render.num_threads)
        skinned = skinned_surfaces(objects, result, settings.device, settings.num_threads)
        maps, K, w2c = render_sequence(scenario, objects, layout, result, settings, skinned)
    t3 = time.perf_counter()
    visible = [int((maps[schema.INSTANCES][-1] == o.object_id).sum()) >= settings.min_visible_pixels for o in objects]
    if sum(visible) < min(settings.min_visible_objects, len(objects)):
        raise SequenceRejected("out_of_view", f"{sum(visible)} of {len(objects)} objects visible in the last frame "
                                              f"(need {settings.min_visible_objects} with >= {settings.min_visible_pixels} px)")
    for name, arr in maps.items():
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            raise SequenceRejected("nan", f"map {name} has non-finite values")
    ws = build_world_state(scenario, objects, layout, result, maps, K, w2c, time.perf_counter() - t0,
                           lit=settings.lighting, surfaces=skinned)
    timings = {"prepare_s": t1 - t0, "simulate_s": t2 - t1, "sim_setup_s": float(result.info.timings_s["setup"]),
               "render_s": t3 - t2}  # (the simulator's set-up, skinning bases included, is part of simulate_s)
    return SequenceArrays(maps, K, w2c, ws), timings
