"""Camera trajectories as data: static, orbit, linear dolly, handheld (smooth jitter), pan.

A ``CameraPathSpec`` holds every number of a trajectory (all random draws are
made once, from the generator passed to ``sample_camera_spec`` / ``camera_path``);
``path_from_spec`` turns it into per-frame world-to-camera matrices (T, 4, 4),
OpenCV convention, world Z up (``newtphys.geometry.look_at``).

Every kind keeps ``look_target_m`` in view: static, orbit and dolly look at it;
handheld looks at it plus a jitter bounded to a small fraction of the distance;
pan yaws the view about the vertical by at most ``PAN_FOV_FRACTION`` of the
half horizontal field of view. Every kind can be rolled about its optical axis
(``roll_rad``, a handheld capture's tilted horizon): the image's up direction is
then no longer world up.

Where the camera starts is set by the horizontal distance and height above the
target (``radius_m``, ``height_m``); :func:`offset_from_pitch` turns a
line-of-sight distance and a downward pitch into those two.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from newtphys.geometry import look_at

CAMERA_KINDS = ("static", "orbit", "dolly", "handheld", "pan")
PAN_FOV_FRACTION = 0.6  # pan half-angle <= this x half the horizontal field of view
MAX_JITTER_FRACTION = 0.05  # handheld jitter amplitude <= this x camera-target distance
HANDHELD_FREQS_HZ = (0.2, 1.5)  # range of the jitter sinusoids' frequencies
HANDHELD_TERMS = 3  # sinusoids per axis
MAX_PITCH_DEG = 85.0  # steepest downward view: straight down leaves the image's up direction undefined
MAX_ROLL_DEG = 45.0  # largest tilt of the horizon


@dataclass(frozen=True)
class CameraPathSpec:
    """All parameters of a camera trajectory (SI units, angles in radians).

    The camera starts at ``look_target_m + (radius cos a, radius sin a, height)``
    with a = ``azimuth_rad``. ``orbit_rate_rad_s``: orbit angular speed (signed).
    ``dolly_end_ratio``: final / initial camera-target distance (linear in time).
    ``jitter_m`` and ``jitter_freqs_hz`` / ``jitter_phases_rad`` ((3, HANDHELD_TERMS)
    each, flattened) shape the handheld shake; ``pan_half_angle_rad`` and
    ``pan_period_s`` the pan sweep (sinusoidal yaw). ``roll_rad`` rotates the camera about
    its optical axis for the whole path: positive tilts the image's right edge (camera x)
    towards world down; 0 keeps the horizon level.
    """

    kind: str
    look_target_m: tuple[float, float, float]
    radius_m: float
    height_m: float
    azimuth_rad: float = 0.0
    orbit_rate_rad_s: float = 0.0
    dolly_end_ratio: float = 1.0
    jitter_m: float = 0.0
    jitter_freqs_hz: tuple[float, ...] = ()
    jitter_phases_rad: tuple[float, ...] = ()
    pan_half_angle_rad: float = 0.0
    pan_period_s: float = 4.0
    fov_x_deg: float = 60.0
    roll_rad: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in CAMERA_KINDS:
            raise ValueError(f"camera kind {self.kind!r} unknown; valid kinds: {', '.join(CAMERA_KINDS)}")
        t = np.asarray(self.look_target_m, np.float64)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"look_target_m must be 3 finite numbers (m), got {self.look_target_m}")
        if not (np.isfinite(self.radius_m) and self.radius_m > 0.0):
            raise ValueError(
                f"radius_m must be > 0 m (horizontal camera-target distance), got {self.radius_m}"
            )
        if not np.isfinite(self.height_m):
            raise ValueError(f"height_m must be finite (m above the target), got {self.height_m}")
        if not 0.25 <= self.dolly_end_ratio <= 4.0:
            raise ValueError(f"dolly_end_ratio must be in [0.25, 4], got {self.dolly_end_ratio}")
        if not 0.0 < self.fov_x_deg < 180.0:
            raise ValueError(f"fov_x_deg must be in (0, 180), got {self.fov_x_deg}")
        max_pan = PAN_FOV_FRACTION * np.deg2rad(self.fov_x_deg) / 2.0
        if not 0.0 <= self.pan_half_angle_rad <= max_pan + 1e-12:
            raise ValueError(
                f"pan_half_angle_rad must be in [0, {max_pan:.4f}] rad "
                f"({PAN_FOV_FRACTION} x half of fov_x {self.fov_x_deg} deg), got {self.pan_half_angle_rad}"
            )
        max_roll = np.deg2rad(MAX_ROLL_DEG)
        if not (np.isfinite(self.roll_rad) and abs(self.roll_rad) <= max_roll + 1e-12):
            raise ValueError(
                f"roll_rad must be in [-{max_roll:.4f}, {max_roll:.4f}] rad (+-{MAX_ROLL_DEG:g} deg), "
                f"got {self.roll_rad}"
            )
        if not self.pan_period_s > 0.0:
            raise ValueError(f"pan_period_s must be > 0 s, got {self.pan_period_s}")
        dist = float(np.hypot(self.radius_m, self.height_m))
        if not 0.0 <= self.jitter_m <= MAX_JITTER_FRACTION * dist * min(1.0, self.dolly_end_ratio):
            raise ValueError(
                f"jitter_m must be in [0, {MAX_JITTER_FRACTION} x camera distance "
                f"{dist * min(1.0, self.dolly_end_ratio):.3f} m], got {self.jitter_m}"
            )
        if len(self.jitter_freqs_hz) != len(self.jitter_phases_rad) or len(self.jitter_freqs_hz) not in (
            0,
            3 * HANDHELD_TERMS,
        ):
            raise ValueError(
                f"jitter_freqs_hz and jitter_phases_rad must both hold 0 or {3 * HANDHELD_TERMS} values, "
                f"got {len(self.jitter_freqs_hz)} and {len(self.jitter_phases_rad)}"
            )

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict of the spec."""
        return asdict(self)


def sample_camera_spec(
    kind: str,
    look_target_m: ArrayLike,
    radius_m: float,
    height_m: float,
    rng: np.random.Generator,
    *,
    fov_x_deg: float = 60.0,
    orbit_speed_rad_s: float = 0.5,
    dolly_end_ratio: float = 0.6,
    jitter_m: float | None = None,
    pan_half_angle_rad: float | None = None,
    pan_period_s: float = 4.0,
    roll_rad: float = 0.0,
) -> CameraPathSpec:
    """Draw the random parts of a trajectory (start azimuth, orbit direction, jitter phases) from ``rng``.

    ``jitter_m`` defaults to 1% of the camera-target distance; ``pan_half_angle_rad``
    to the largest allowed (``PAN_FOV_FRACTION`` x half the horizontal fov).
    """
    if kind not in CAMERA_KINDS:
        raise ValueError(f"camera kind {kind!r} unknown; valid kinds: {', '.join(CAMERA_KINDS)}")
    target = [float(v) for v in np.asarray(look_target_m, np.float64).reshape(3)]
    azimuth = float(rng.uniform(0.0, 2.0 * np.pi))
    direction = float(rng.choice([-1.0, 1.0]))
    freqs = tuple(float(f) for f in rng.uniform(*HANDHELD_FREQS_HZ, size=3 * HANDHELD_TERMS))
    phases = tuple(float(p) for p in rng.uniform(0.0, 2.0 * np.pi, size=3 * HANDHELD_TERMS))
    dist = float(np.hypot(radius_m, height_m))
    base = CameraPathSpec(
        kind=kind,
        look_target_m=(target[0], target[1], target[2]),
        radius_m=radius_m,
        height_m=height_m,
        azimuth_rad=azimuth,
        fov_x_deg=fov_x_deg,
        roll_rad=roll_rad,
    )
    if kind == "orbit":
        return replace(base, orbit_rate_rad_s=direction * abs(orbit_speed_rad_s))
    if kind == "dolly":
        return replace(base, dolly_end_ratio=dolly_end_ratio)
    if kind == "handheld":
        amp = 0.01 * dist if jitter_m is None else jitter_m
        return replace(base, jitter_m=amp, jitter_freqs_hz=freqs, jitter_phases_rad=phases)
    if kind == "pan":
        max_pan = PAN_FOV_FRACTION * np.deg2rad(fov_x_deg) / 2.0
        half = max_pan if pan_half_angle_rad is None else pan_half_angle_rad
        return replace(base, pan_half_angle_rad=float(half), pan_period_s=pan_period_s)
    return base


def _jitter(spec: CameraPathSpec, times_s: NDArray[np.float64], phase_shift: float) -> NDArray[np.float64]:
    """Smooth zero-mean shake (T, 3), m: per axis a sum of sinusoids scaled so each axis peaks at <= jitter_m."""
    if spec.jitter_m == 0.0 or not spec.jitter_freqs_hz:
        return np.zeros((len(times_s), 3))
    f = np.asarray(spec.jitter_freqs_hz).reshape(3, HANDHELD_TERMS)
    ph = np.asarray(spec.jitter_phases_rad).reshape(3, HANDHELD_TERMS) + phase_shift
    waves = np.sin(2.0 * np.pi * f[None] * times_s[:, None, None] + ph[None])  # (T, 3, terms)
    return spec.jitter_m * waves.sum(axis=2) / HANDHELD_TERMS


def path_from_spec(spec: CameraPathSpec, num_frames: int, fps: float,
                   frames: ArrayLike | None = None) -> NDArray[np.float64]:
    """World-to-camera matrices (num_frames, 4, 4) of ``spec`` sampled at ``fps`` frames per second; with
    ``frames`` (indices in [0, num_frames)) only those frames' matrices (len(frames), 4, 4), the same values."""
    if num_frames < 1:
        raise ValueError(f"num_frames must be >= 1, got {num_frames}")
    if not (np.isfinite(fps) and fps > 0.0):
        raise ValueError(f"fps must be > 0, got {fps}")
    index = np.arange(num_frames) if frames is None else np.asarray(frames, np.int64)
    if index.ndim != 1 or not len(index) or index.min() < 0 or index.max() >= num_frames:
        raise ValueError(f"frames must be indices in [0, {num_frames}), got {frames}")
    t = index / float(fps)
    target = np.asarray(spec.look_target_m, np.float64)
    azimuth = spec.azimuth_rad + (spec.orbit_rate_rad_s * t if spec.kind == "orbit" else 0.0 * t)
    offset = np.stack(
        [spec.radius_m * np.cos(azimuth), spec.radius_m * np.sin(azimuth), np.full_like(t, spec.height_m)],
        axis=1,
    )
    if spec.kind == "dolly":
        duration = max((num_frames - 1) / float(fps), 1e-12)
        offset *= (1.0 + (spec.dolly_end_ratio - 1.0) * t / duration)[:, None]
    eyes = target + offset
    looks = np.broadcast_to(target, eyes.shape).copy()
    if spec.kind == "handheld":
        eyes += _jitter(spec, t, 0.0)
        looks += _jitter(spec, t, np.pi / 3.0)
    if spec.kind == "pan":
        yaw = spec.pan_half_angle_rad * np.sin(2.0 * np.pi * t / spec.pan_period_s)
        rel = looks - eyes
        c, s = np.cos(yaw), np.sin(yaw)
        looks = eyes + np.stack(
            [c * rel[:, 0] - s * rel[:, 1], s * rel[:, 0] + c * rel[:, 1], rel[:, 2]], axis=1
        )
    w2c = np.stack([look_at(e, g) for e, g in zip(eyes, looks)])  # loop over frames
    if spec.roll_rad != 0.0:  # new camera axes x' = c x + s y, y' = -s x + c y: rows of world-to-camera
        c, s = np.cos(spec.roll_rad), np.sin(spec.roll_rad)
        roll = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        w2c[:, :3, :] = roll @ w2c[:, :3, :]
    return w2c


def offset_from_pitch(distance_m: float, pitch_deg: float) -> tuple[float, float]:
    """(radius_m, height_m) of a camera ``distance_m`` from its target along a line of sight
    ``pitch_deg`` below the horizontal (0 level, at most ``MAX_PITCH_DEG``)."""
    if not (np.isfinite(distance_m) and distance_m > 0.0):
        raise ValueError(f"distance_m must be > 0 m, got {distance_m}")
    if not 0.0 <= pitch_deg <= MAX_PITCH_DEG:
        raise ValueError(f"pitch_deg must be in [0, {MAX_PITCH_DEG:g}] deg (downward), got {pitch_deg}")
    p = np.deg2rad(pitch_deg)
    return float(distance_m * np.cos(p)), float(distance_m * np.sin(p))


def camera_path(
    kind: str,
    num_frames: int,
    fps: float,
    look_target_m: ArrayLike,
    radius_m: float,
    height_m: float,
    rng: np.random.Generator,
    **options: Any,
) -> NDArray[np.float64]:
    """World-to-camera (num_frames, 4, 4) for ``kind`` in CAMERA_KINDS; ``options`` go to ``sample_camera_spec``."""
    spec = sample_camera_spec(kind, look_target_m, radius_m, height_m, rng, **options)
    return path_from_spec(spec, num_frames, fps)
