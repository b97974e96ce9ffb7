"""Scenarios: what happens in one sequence, drawn from a config and a seed.

A :class:`Scenario` is declarative and complete: scene layout name, every
object (asset, size, material parameters, pose, velocities), gravity, camera
path parameters, frame count and image size. The simulator, the renderer
and the shard writer all read the same scenario and never change it.
Every random draw derives from the sequence seed (one ``np.random.Generator``
per sequence; sub-streams per purpose), so a sequence is reproducible alone.

Counterfactuals (:func:`counterfactual`) copy a scenario and change exactly
one thing: gravity, one object's position, or one object's size.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from data_gen.assets.asset_uri import is_asset_reference
from data_gen.assets.captured import check_scene_reference
from data_gen.assets.imported import check_object_reference
from data_gen.assets.materials import sample_material
from data_gen.assets.registry import get_object, get_scene_layout, list_objects, list_scene_layouts, object_pool
from data_gen.cameras import CAMERA_KINDS, CameraPathSpec, path_from_spec, sample_camera_spec
from data_gen.cameras import MAX_PITCH_DEG, MAX_ROLL_DEG, offset_from_pitch
from newtphys import schema
from newtphys.rotations import axis_angle_to_quat, quat_to_matrix

MOTIONS = ("drop", "throw", "push")


class ScenarioError(ValueError):
    """A scenario config cannot produce a valid scenario (names the key and the value)."""


@dataclass(frozen=True)
class ObjectPlacement:
    object_id: int
    """1-based."""
    asset: str
    size_m: float
    """Largest bounding-box extent after scaling, m (a user asset at its given scale: its own extent)."""
    material: str
    young_modulus_pa: float
    poisson_ratio: float
    density_kg_m3: float
    position_m: tuple[float, float, float]
    """World position of the object-frame origin (the asset's local origin) at t = 0."""
    orientation_wxyz: tuple[float, float, float, float]
    velocity_m_s: tuple[float, float, float]
    angular_velocity_rad_s: tuple[float, float, float]
    motion: str
    color_seed: int


@dataclass(frozen=True)
class Scenario:
    sequence_id: str
    seed: int
    split: str
    scene: str
    objects: tuple[ObjectPlacement, ...]
    gravity_m_s2: tuple[float, float, float]
    camera: CameraPathSpec
    num_frames: int
    fps: float
    image_size: tuple[int, int]
    counterfactual_of: str | None = None
    change: str | None = None
    kind: str | None = None
    """Name of the scenario config (a mixture's component: ``<mixture>/<component>``) that drew it."""

    @property
    def gravity_magnitude(self) -> float:
        return float(np.linalg.norm(self.gravity_m_s2))


@dataclass(frozen=True)
class ScenarioConfig:
    """Ranges a scenario is drawn from. Ranges are closed [min, max].

    The values live in ``newtphys/conf/scenario/<name>.yaml`` (over ``base.yaml``), the one source of every
    default: load them with ``data_gen.configs.scenario_config(name, **changes)``. Objects and scenes are
    library names or user references (``file:``/``ply:`` objects, ``ply:`` captured scenes).
    """

    name: str
    scenes: tuple[str, ...]
    num_objects: tuple[int, int]
    objects: tuple[str, ...] | None
    """Library names or file:/ply: references to draw from (None: the whole library)."""
    size_m: tuple[float, float]
    """Largest extent of a drawn library object, m (imported objects keep their own scale unless resize=true)."""
    motions: Mapping[str, float]
    """Motion kind -> probability weight."""
    drop_height_m: tuple[float, float]
    """Clearance of the object's lowest point above its support at t = 0."""
    throw_speed_m_s: tuple[float, float]
    push_speed_m_s: tuple[float, float]
    spin_rad_s: tuple[float, float]
    random_orientation: bool
    camera_kinds: tuple[str, ...]
    camera_distance_m: tuple[float, float]
    """Camera-target distance at t = 0, m: along the line of sight when ``camera_pitch_deg`` is set,
    horizontal (with ``camera_height_m``) when it is None."""
    camera_height_m: tuple[float, float]
    """Camera height above the target at t = 0, m; used only when ``camera_pitch_deg`` is None."""
    camera_pitch_deg: tuple[float, float] | None
    """Downward angle of the line of sight at t = 0, deg: 0 level, up to MAX_PITCH_DEG (near top-down)."""
    camera_roll_deg: tuple[float, float]
    """Rotation about the optical axis, deg (a handheld capture's tilted horizon; 0: level)."""
    fov_x_deg: tuple[float, float]
    max_placement_tries: int
    object_library: str
    """Pool of ``objects: null``: ``core`` (the original 34 objects, whose draws earlier data pins) or ``all``
    (core plus the parametric families of ``data_gen.assets.families``)."""
    duration_s: tuple[float, float] | None
    """[min, max] sequence length, s, drawn per sequence (frames = round(duration x fps)); None: the run's
    ``num_frames`` for every sequence."""
    duration_mean_s: float | None
    """Mean of the drawn length, s: a power law truncated to ``duration_s`` with this mean (many short
    sequences, a tail of long ones; :func:`sample_duration_s`); None: uniform."""
    pile_radius_m: float | None
    """A pile: every object after the first is placed within this horizontal distance (m) of the first one's
    spot, in the same region, stacked by its drop height (objects land on each other); None: anywhere."""
    mixture: Mapping[str, Mapping[str, Any]] | None
    """Component name -> {weight: w, <any key above>: value}: each sequence first draws a component by weight,
    then is drawn from this config with the component's keys changed (None: not a mixture)."""

    @staticmethod
    def from_mapping(cfg: Mapping[str, Any]) -> ScenarioConfig:
        known = {f.name for f in dataclasses.fields(ScenarioConfig)}
        unknown = sorted(set(cfg) - known)
        if unknown:
            raise ScenarioError(f"scenario config: unknown keys {unknown}; known keys: {sorted(known)}")
        missing = sorted(known - set(cfg))
        if missing:
            raise ScenarioError(
                f"scenario config {cfg.get('name')!r}: missing keys {missing} (scenario files list them in "
                "newtphys/conf/scenario/base.yaml; load configs with data_gen.configs.scenario_config)"
            )
        kwargs = {k: (tuple(v) if isinstance(v, (list, tuple)) else v) for k, v in cfg.items()}
        if "motions" in kwargs:
            kwargs["motions"] = dict(cfg["motions"])
        if kwargs.get("mixture") is not None:
            kwargs["mixture"] = {str(k): dict(v) for k, v in dict(cfg["mixture"]).items()}
        out = ScenarioConfig(**kwargs)
        out.check()
        return out

    def replace(self, **changes: Any) -> ScenarioConfig:
        """A copy with some fields changed (sequences become tuples), checked again."""
        unknown = sorted(set(changes) - {f.name for f in dataclasses.fields(self)})
        if unknown:
            raise ScenarioError(f"scenario '{self.name}': unknown keys {unknown}")
        changes = {k: (tuple(v) if isinstance(v, list) else v) for k, v in changes.items()}
        out = dataclasses.replace(self, **changes)
        out.check()
        return out

    def check(self) -> None:
        if self.object_library not in OBJECT_LIBRARIES:
            raise ScenarioError(f"scenario '{self.name}': object_library must be one of {OBJECT_LIBRARIES}, "
                                f"got {self.object_library!r}")
        _check_duration(self)
        if self.pile_radius_m is not None and not (np.isfinite(self.pile_radius_m) and self.pile_radius_m >= 0):
            raise ScenarioError(f"scenario '{self.name}': pile_radius_m must be >= 0 m or null, got {self.pile_radius_m}")
        if self.mixture is not None:
            self.components()  # builds and checks every component
        _check_names(self.name, "scene", self.scenes, check_scene_reference, list_scene_layouts(),
                     "'ply:<captured scene .ply>?<options>'")
        _check_names(self.name, "object", self.objects or (), check_object_reference, list_objects(),
                     "'file:<mesh>?<options>' / 'ply:<3DGS object .ply>?<options>'")
        if self.max_placement_tries < 1:
            raise ScenarioError(f"scenario '{self.name}': max_placement_tries must be >= 1, got {self.max_placement_tries}")
        lo, hi = self.num_objects
        if not 1 <= lo <= hi <= 10:
            raise ScenarioError(f"scenario '{self.name}': num_objects must satisfy 1 <= min <= max <= 10, got {self.num_objects}")
        bad = sorted(set(self.motions) - set(MOTIONS))
        if bad or not self.motions or min(self.motions.values()) < 0 or sum(self.motions.values()) <= 0:
            raise ScenarioError(f"scenario '{self.name}': motions must map {MOTIONS} to weights >= 0, got {dict(self.motions)}")
        bad = sorted(set(self.camera_kinds) - set(CAMERA_KINDS))
        if bad or not self.camera_kinds:
            raise ScenarioError(f"scenario '{self.name}': unknown camera kinds {bad}; valid: {CAMERA_KINDS}")
        for key in ("size_m", "drop_height_m", "throw_speed_m_s", "push_speed_m_s", "spin_rad_s",
                    "camera_distance_m", "camera_height_m", "fov_x_deg"):
            lo, hi = getattr(self, key)
            if not (np.isfinite(lo) and np.isfinite(hi) and 0 <= lo <= hi):
                raise ScenarioError(f"scenario '{self.name}': {key} must be a range 0 <= min <= max, got {(lo, hi)}")
        for key, low, high in (("camera_pitch_deg", 0.0, MAX_PITCH_DEG), ("camera_roll_deg", -MAX_ROLL_DEG, MAX_ROLL_DEG)):
            bounds = getattr(self, key)
            if bounds is None and key == "camera_pitch_deg":  # None: placed by camera_height_m
                continue
            if len(bounds) != 2 or not (np.all(np.isfinite(bounds)) and low <= bounds[0] <= bounds[1] <= high):
                raise ScenarioError(f"scenario '{self.name}': {key} must be a range {low:g} <= min <= max <= {high:g} "
                                    f"(deg), got {tuple(bounds)}")


    def components(self) -> list[tuple[str, float, ScenarioConfig]]:
        """(name, probability, config) of each mixture component, in file order (empty: not a mixture)."""
        if self.mixture is None:
            return []
        if not isinstance(self.mixture, Mapping) or not self.mixture:
            raise ScenarioError(f"scenario '{self.name}': mixture must map component names to settings, "
                                f"got {self.mixture!r}")
        out = []
        for comp, settings in self.mixture.items():
            settings = dict(settings)
            weight = settings.pop("weight", None)
            if weight is None or not np.isfinite(float(weight)) or float(weight) < 0:
                raise ScenarioError(f"scenario '{self.name}': mixture component '{comp}' needs a weight >= 0, "
                                    f"got {weight!r}")
            if "mixture" in settings:
                raise ScenarioError(f"scenario '{self.name}': mixture component '{comp}' cannot hold a mixture")
            known = {f.name for f in dataclasses.fields(self)} - {"name"}
            unknown = sorted(set(settings) - known)
            if unknown:
                raise ScenarioError(f"scenario '{self.name}': mixture component '{comp}': unknown keys {unknown}; "
                                    f"known keys: {sorted(known)}")
            if "motions" in settings:  # a component's motions replace the mixture's (they do not merge)
                settings["motions"] = dict(settings["motions"])
            try:
                cfg = self.replace(name=f"{self.name}/{comp}", mixture=None, **settings)
            except ScenarioError as e:
                raise ScenarioError(f"mixture component '{comp}': {e}") from None
            out.append((str(comp), float(weight), cfg))
        total = sum(w for _, w, _ in out)
        if total <= 0:
            raise ScenarioError(f"scenario '{self.name}': mixture weights sum to 0")
        return [(n, w / total, c) for n, w, c in out]


OBJECT_LIBRARIES = ("core", "all")


def _check_duration(cfg: ScenarioConfig) -> None:
    if cfg.duration_s is None:
        if cfg.duration_mean_s is not None:
            raise ScenarioError(f"scenario '{cfg.name}': duration_mean_s needs duration_s")
        return
    if len(cfg.duration_s) != 2:
        raise ScenarioError(f"scenario '{cfg.name}': duration_s must be [min, max] s, got {cfg.duration_s}")
    lo, hi = (float(v) for v in cfg.duration_s)
    if not 0 < lo <= hi <= schema.MAX_SEQUENCE_SECONDS:
        raise ScenarioError(f"scenario '{cfg.name}': duration_s must satisfy 0 < min <= max <= "
                            f"{schema.MAX_SEQUENCE_SECONDS:g} s (the contract's longest sequence), got {(lo, hi)}")
    mean = cfg.duration_mean_s
    if mean is not None and not (lo < float(mean) < hi or lo == float(mean) == hi):
        raise ScenarioError(f"scenario '{cfg.name}': duration_mean_s must lie strictly inside duration_s "
                            f"{(lo, hi)}, got {mean}")


@functools.lru_cache(maxsize=64)
def duration_exponent(lo_s: float, hi_s: float, mean_s: float) -> float:
    """Exponent a of the power law p(d) ~ d^-(a+1) truncated to [lo_s, hi_s] whose mean is ``mean_s`` (bisection
    on a in [-50, 50]; the mean falls as a grows; a = 0 is log-uniform, a = -1 uniform)."""
    def mean(a: float) -> float:
        if abs(a) < 1e-9:
            return (hi_s - lo_s) / np.log(hi_s / lo_s)
        if abs(a - 1.0) < 1e-9:
            return lo_s * hi_s * np.log(hi_s / lo_s) / (hi_s - lo_s)
        return a / (a - 1.0) * (lo_s ** (1 - a) - hi_s ** (1 - a)) / (lo_s ** -a - hi_s ** -a)
    lo_a, hi_a = -50.0, 50.0
    for _ in range(200):
        mid = 0.5 * (lo_a + hi_a)
        if mean(mid) > mean_s:
            lo_a = mid
        else:
            hi_a = mid
    return 0.5 * (lo_a + hi_a)


def sample_duration_s(cfg: ScenarioConfig, rng: np.random.Generator) -> float:
    """One sequence length, s, in ``cfg.duration_s``: uniform when ``duration_mean_s`` is None, else a
    truncated power law p(d) ~ d^-(a+1) whose mean is ``duration_mean_s`` (many short sequences, a tail of
    long ones: for [2, 10] s and a 2.65 s mean, a = 4.0, median 2.38 s, 2.4% longer than 5 s)."""
    lo, hi = (float(v) for v in cfg.duration_s)
    u = float(rng.uniform())
    if cfg.duration_mean_s is None or hi <= lo:
        return lo + (hi - lo) * u
    a = duration_exponent(lo, hi, float(cfg.duration_mean_s))
    if abs(a) < 1e-9:
        return lo * (hi / lo) ** u
    return (lo ** -a - u * (lo ** -a - hi ** -a)) ** (-1.0 / a)  # inverse CDF


def sample_num_frames(cfg: ScenarioConfig, rng: np.random.Generator, fps: float, default: int) -> int:
    """Frames of one sequence: ``default`` when ``cfg.duration_s`` is None, else a drawn duration x fps
    (at least 2 frames, at most the contract's 10 s)."""
    if cfg.duration_s is None:
        return default
    frames = round(sample_duration_s(cfg, rng) * fps)
    return int(min(max(frames, 2), int(schema.MAX_SEQUENCE_SECONDS * fps)))


def _check_names(scenario: str, kind: str, names, check_reference, catalogue: list[str], reference_hint: str) -> None:
    """Each name is a catalogue entry or a user reference that passes its cheap checks (file, options)."""
    for name in names:
        if is_asset_reference(name):
            try:
                check_reference(name)
            except (ValueError, KeyError, FileNotFoundError) as e:
                raise ScenarioError(f"scenario '{scenario}': {kind} {name!r}: {_message(e)}") from None
        elif name not in catalogue:
            raise ScenarioError(
                f"scenario '{scenario}': unknown {kind} {name!r}; valid {kind}s: {catalogue} or {reference_hint}"
            )


def _message(error: Exception) -> str:
    """An exception's text (a KeyError's without the quotes its str adds)."""
    return str(error.args[0]) if isinstance(error, KeyError) and error.args else str(error)


SELF_WEIGHT_STRAIN_LIMIT = 0.8
"""Largest self-weight strain rho |g| L / E of a drawn object (L: its largest extent). The simulator refuses
objects above 1.0 (they would collapse under their own weight; ``data_gen/sim/world.py``), which ended the
whole job; 0.8 keeps a margin for the extent of its interior points."""


def min_young_modulus_pa(density_kg_m3: float, gravity_m_s2: float, size_m: float) -> float:
    """The softest modulus (Pa) an object of this density (kg/m^3) and largest extent (m) may have under
    gravity of this magnitude (m/s^2): drawn moduli below it are raised to it."""
    return density_kg_m3 * gravity_m_s2 * size_m / SELF_WEIGHT_STRAIN_LIMIT


def gravity_for_split(split: str, mode: str, rng: np.random.Generator) -> tuple[float, float, float]:
    """Earth: (0, 0, -9.81). OOD: magnitude uniform in OOD_GRAVITY_RANGE_M_S2, pointing down."""
    if mode == "earth":
        g = schema.EARTH_GRAVITY_M_S2
    elif mode == "ood":
        g = float(rng.uniform(*schema.OOD_GRAVITY_RANGE_M_S2))
    else:
        raise ScenarioError(f"gravity mode must be 'earth' or 'ood', got {mode!r} (split {split!r})")
    return (0.0, 0.0, -g)


def _random_quat(rng: np.random.Generator) -> tuple[float, float, float, float]:
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    q *= np.sign(q[0]) or 1.0
    return tuple(float(v) for v in q)


def _yaw_quat(rng: np.random.Generator) -> tuple[float, float, float, float]:
    q = axis_angle_to_quat((0.0, 0.0, 1.0), rng.uniform(0, 2 * np.pi))
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


def _uniform(rng: np.random.Generator, r: Sequence[float]) -> float:
    return float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])


def sample_scenario(
    cfg: ScenarioConfig,
    sequence_id: str,
    seed: int,
    split: str,
    gravity_mode: str,
    num_frames: int,
    fps: float,
    image_size: tuple[int, int],
) -> Scenario:
    """Draw one scenario. Placement avoids initial overlap with bounding spheres; raises ScenarioError
    when ``max_placement_tries`` cannot place every object (an impossible placement).

    A mixture draws its component from its own stream, then the component's scenario from the same seed
    (so a component draws what it would alone); ``duration_s`` replaces ``num_frames`` by a drawn length.
    Both use streams of their own: configs without them draw exactly what they drew before."""
    ss = np.random.SeedSequence(seed)
    rng_scene, rng_obj, rng_cam, rng_g, rng_mix, rng_len = (np.random.default_rng(s) for s in ss.spawn(6))
    if cfg.mixture is not None:
        comps = cfg.components()
        k = int(rng_mix.choice(len(comps), p=np.array([w for _, w, _ in comps])))
        return sample_scenario(comps[k][2], sequence_id, seed, split, gravity_mode, num_frames, fps, image_size)
    num_frames = sample_num_frames(cfg, rng_len, fps, num_frames)
    if not 1 <= num_frames <= schema.MAX_SEQUENCE_SECONDS * fps:
        raise ScenarioError(
            f"num_frames must be in [1, {int(schema.MAX_SEQUENCE_SECONDS * fps)}] "
            f"({schema.MAX_SEQUENCE_SECONDS:g} s at {fps:g} FPS), got {num_frames}"
        )
    gravity = gravity_for_split(split, gravity_mode, rng_g)  # its own stream: drawing it first changes nothing
    scene_name = cfg.scenes[int(rng_scene.integers(len(cfg.scenes)))]
    scene = get_scene_layout(scene_name)
    pool = list(cfg.objects or object_pool(cfg.object_library))
    n = int(rng_obj.integers(cfg.num_objects[0], cfg.num_objects[1] + 1))
    motions = list(cfg.motions)
    weights = np.array([cfg.motions[m] for m in motions], np.float64)
    placed: list[tuple[np.ndarray, float]] = []  # (centre, bounding radius)
    aims: list[np.ndarray] = []
    objects: list[ObjectPlacement] = []
    for k in range(n):
        asset_name = pool[int(rng_obj.integers(len(pool)))]
        size = _uniform(rng_obj, cfg.size_m)  # drawn for every object, so the stream does not depend on the pool
        asset = get_object(asset_name)
        if asset.keep_scale:  # a user asset at its given scale keeps its size
            size = asset.nominal_size_m
        else:
            asset = asset.scaled_to(size)
        material = asset.allowed_materials[int(rng_obj.integers(len(asset.allowed_materials)))]
        E, nu, rho = sample_material(material, rng_obj)
        E = max(E, min_young_modulus_pa(rho, float(np.linalg.norm(gravity)), size))  # no draw: streams unchanged
        motion = motions[int(rng_obj.choice(len(motions), p=weights / weights.sum()))]
        orientation = _random_quat(rng_obj) if cfg.random_orientation and motion != "push" else _yaw_quat(rng_obj)
        lo, hi = (np.asarray(b, np.float64) for b in asset.shape.bounds())
        centre_local = 0.5 * (lo + hi)
        radius = 0.5 * float(np.linalg.norm(hi - lo))
        for _ in range(cfg.max_placement_tries):
            if cfg.pile_radius_m is not None and placed:  # a pile: over the first object's spot, in its region
                region = pile_region
                p = region.sample(1, rng_obj)[0]
                r, a = cfg.pile_radius_m * np.sqrt(rng_obj.uniform()), rng_obj.uniform(0.0, 2.0 * np.pi)
                p[:2] = np.clip(placed[0][0][:2] + r * np.array([np.cos(a), np.sin(a)]), region.min_m[:2],
                                region.max_m[:2])
            else:
                region = scene.regions[int(rng_obj.integers(len(scene.regions)))]
                p = region.sample(1, rng_obj)[0]
                pile_region = region
            support_z = float(region.min_m[2])
            clearance = 0.005 if motion == "push" else _uniform(rng_obj, cfg.drop_height_m)
            p[2] = support_z + radius + clearance
            if scene.collision_points_m is not None:  # captured furniture: drop from above what is below
                p[2] = max(p[2], scene.support_height(p, radius) + radius + clearance)
            ok = all(np.linalg.norm(p - c) > radius + r for c, r in placed)
            ok = ok and float(scene.sdf(p[None])[0]) > radius
            if ok:
                break
        else:
            raise ScenarioError(
                f"scenario '{cfg.name}', sequence {sequence_id}: cannot place object {k + 1} ({asset_name}, "
                f"size {size:.3f} m) without overlap in scene '{scene_name}' after {cfg.max_placement_tries} tries; "
                "lower num_objects or size_m"
            )
        placed.append((p, radius))
        aims.append(p.copy())  # what the camera should keep in view of this object
        origin = p - quat_to_matrix(orientation) @ centre_local  # put the bounding-box centre at p
        vel = np.zeros(3)
        if motion == "throw":
            to_centre = -p[:2] / (np.linalg.norm(p[:2]) + 1e-9)
            speed = _uniform(rng_obj, cfg.throw_speed_m_s)
            vel = np.array([*(0.8 * speed * to_centre), 0.6 * speed])
            # frame the flight: aim between the spawn point and the ballistic landing point (Earth g)
            fall = max(p[2] - support_z, 0.0)
            t_land = (vel[2] + np.sqrt(vel[2] ** 2 + 2.0 * schema.EARTH_GRAVITY_M_S2 * fall)) / schema.EARTH_GRAVITY_M_S2
            landing = p + np.array([vel[0] * t_land, vel[1] * t_land, -fall])
            aims[-1] = 0.5 * (p + landing)
        elif motion == "push":
            ang = rng_obj.uniform(0, 2 * np.pi)
            vel = _uniform(rng_obj, cfg.push_speed_m_s) * np.array([np.cos(ang), np.sin(ang), 0.0])
        spin = rng_obj.normal(size=3)
        spin *= _uniform(rng_obj, cfg.spin_rad_s) / (np.linalg.norm(spin) + 1e-12)
        objects.append(ObjectPlacement(
            object_id=k + 1, asset=asset_name, size_m=size, material=material, young_modulus_pa=float(E),
            poisson_ratio=float(nu), density_kg_m3=float(rho), position_m=tuple(float(v) for v in origin),
            orientation_wxyz=orientation, velocity_m_s=tuple(float(v) for v in vel),
            angular_velocity_rad_s=tuple(float(v) for v in spin) if motion != "push" else (0.0, 0.0, 0.0),
            motion=motion, color_seed=int(rng_obj.integers(2**31)),
        ))
    target = np.mean(aims, axis=0)
    target[2] = max(0.5 * target[2], 0.05)
    for _ in range(CAMERA_TRIES):
        kind = cfg.camera_kinds[int(rng_cam.integers(len(cfg.camera_kinds)))]
        if cfg.camera_pitch_deg is None:
            radius, height = _uniform(rng_cam, cfg.camera_distance_m), _uniform(rng_cam, cfg.camera_height_m)
        else:
            radius, height = offset_from_pitch(_uniform(rng_cam, cfg.camera_distance_m),
                                               _uniform(rng_cam, cfg.camera_pitch_deg))
        camera = sample_camera_spec(
            kind,
            target,
            radius_m=radius,
            height_m=height,
            rng=rng_cam,
            fov_x_deg=_uniform(rng_cam, cfg.fov_x_deg),
            roll_rad=float(np.deg2rad(_uniform(rng_cam, cfg.camera_roll_deg))),
        )
        if camera_view_is_clear(scene, camera, placed, num_frames, fps):
            break
    else:
        raise ScenarioError(
            f"scenario '{cfg.name}', sequence {sequence_id}: no camera path in {CAMERA_TRIES} draws sees the objects "
            f"past the static geometry of scene '{scene_name}' (camera_distance_m={tuple(cfg.camera_distance_m)})"
        )
    return Scenario(
        sequence_id=sequence_id, seed=seed, split=split, scene=scene_name, objects=tuple(objects),
        gravity_m_s2=gravity, camera=camera, num_frames=num_frames,
        fps=float(fps), image_size=(int(image_size[0]), int(image_size[1])), kind=cfg.name,
    )


CAMERA_TRIES = 50
CAMERA_CLEARANCE_M = 0.05  # the camera keeps this far from static geometry
_CHECK_FRAMES = 12  # camera positions checked along a path
_RAY_SAMPLES = 48  # sdf samples along each line of sight


def camera_view_is_clear(
    scene, camera: CameraPathSpec, placed: Sequence[tuple[np.ndarray, float]], num_frames: int, fps: float
) -> bool:
    """Whether, along the whole path, the camera stays ``CAMERA_CLEARANCE_M`` outside the static geometry
    and sees at least one object's spawn centre: the segment to it, up to the object's bounding radius,
    stays outside walls, boxes and the floor (a camera behind a room's wall saw nothing and its sequence
    was simulated for nothing, then rejected as out of view)."""
    frames = np.unique(np.linspace(0, num_frames - 1, min(num_frames, _CHECK_FRAMES)).round().astype(int))
    w2c = path_from_spec(camera, num_frames, fps, frames)
    eyes = np.einsum("fji,fj->fi", w2c[:, :3, :3], -w2c[:, :3, 3])  # camera centres -R^T t, (F, 3)
    if float(scene.sdf(eyes).min()) < CAMERA_CLEARANCE_M:
        return False
    centres = np.array([c for c, _ in placed])  # (O, 3)
    radii = np.array([r for _, r in placed])  # (O,)
    offset = eyes[:, None] - centres[None]  # (F, O, 3)
    distance = np.linalg.norm(offset, axis=2)  # (F, O)
    outside = distance > radii[None]
    # segments from the eye to each object's bounding sphere, sampled (F, O, S, 3), one sdf query for all
    ends = centres[None] + offset * (radii[None] / np.maximum(distance, 1e-12))[..., None]
    t = np.linspace(0.0, 1.0, _RAY_SAMPLES)[None, None, :, None]
    rays = eyes[:, None, None] + t * (ends - eyes[:, None])[:, :, None]
    free = scene.sdf(rays.reshape(-1, 3)).reshape(rays.shape[:3]).min(axis=2) > 0.0  # (F, O)
    return bool((free & outside).any(axis=1).all())


COUNTERFACTUAL_CHANGES = ("gravity", "shift", "resize")


def counterfactual(
    scenario: Scenario, change: str, object_id: int = 1, amount: float | Sequence[float] | None = None
) -> Scenario:
    """A copy of ``scenario`` that differs in exactly one thing.

    * ``gravity``: gravity magnitude scaled by ``amount`` (default 0.5: lower gravity);
    * ``shift``: object ``object_id`` translated by ``amount`` (3-vector, m; default (0.1, 0, 0));
    * ``resize``: object ``object_id`` scaled by ``amount`` (default 0.8) about its origin.
    """
    sid = f"{scenario.sequence_id}-cf-{change}"
    if change == "gravity":
        s = 0.5 if amount is None else float(amount)  # type: ignore[arg-type]
        if not s > 0:
            raise ScenarioError(f"counterfactual gravity scale must be > 0, got {s}")
        g = tuple(float(v) * s for v in scenario.gravity_m_s2)
        return dataclasses.replace(scenario, sequence_id=sid, gravity_m_s2=g, counterfactual_of=scenario.sequence_id,
                                   change=change)
    ids = [o.object_id for o in scenario.objects]
    if object_id not in ids:
        raise ScenarioError(f"counterfactual: no object {object_id} in {scenario.sequence_id} (ids {ids})")
    objs = list(scenario.objects)
    k = ids.index(object_id)
    if change == "shift":
        d = np.asarray((0.1, 0.0, 0.0) if amount is None else amount, np.float64)
        if d.shape != (3,):
            raise ScenarioError(f"counterfactual shift must be a 3-vector in m, got {amount!r}")
        objs[k] = dataclasses.replace(objs[k], position_m=tuple(float(v) for v in np.asarray(objs[k].position_m) + d))
    elif change == "resize":
        s = 0.8 if amount is None else float(amount)  # type: ignore[arg-type]
        if not s > 0:
            raise ScenarioError(f"counterfactual resize factor must be > 0, got {s}")
        objs[k] = dataclasses.replace(objs[k], size_m=objs[k].size_m * s)
    else:
        raise ScenarioError(f"unknown counterfactual change {change!r}; valid: {COUNTERFACTUAL_CHANGES}")
    return dataclasses.replace(scenario, sequence_id=sid, objects=tuple(objs), counterfactual_of=scenario.sequence_id,
                               change=change)
