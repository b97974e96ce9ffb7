"""Simulation quality presets: typed view of ``newtphys/conf/quality/<name>.yaml``."""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path

import yaml

from newtphys.config import CONFIG_DIR

PRESET_DIR = CONFIG_DIR / "quality"


@dataclass(frozen=True)
class QualityPreset:
    """Numerical settings of one quality level.

    ``dt_s = 1 / (fps * substeps_per_frame)``; contact stiffness per contact sphere is
    ``contact_stiffness_factor * object_mass_kg / dt_s**2`` (N/m).  ``num_contact_points`` is the
    number of surface contact spheres per object (used when the object comes with surface samples).
    ``lagged_elastic_hessian``: a soft object's elastic Newton matrix is formed once per (sub)step and kept for
    its later iterations (modified Newton, :class:`data_gen.sim.step_objective.StepObjective`), instead of at
    every iteration.
    ``elastic_hessian_reuse`` (with ``lagged_elastic_hessian``; 0 turns it off): a soft object's kept matrix also
    serves its later (sub)steps while no entry of any of its cubature points' deformation gradients (at the
    solve's predicted start) differs from those it was formed at by more than this (dimensionless); the matrix
    is only Newton's step direction, so every solve still meets ``newton_tolerance`` on the exact gradient.
    """

    name: str
    num_cubature_points: int
    num_contact_points: int
    max_handles: int
    substeps_per_frame: int
    max_contact_substeps: int
    newton_iterations: int
    newton_tolerance: float
    line_search_steps: int
    contact_stiffness_factor: float
    friction_smoothing_m_s: float
    skinning_training_steps: int
    sleep_speed_m_s: float
    sleep_steps: int
    lagged_elastic_hessian: bool = False
    elastic_hessian_reuse: float = 0.0

    def __post_init__(self) -> None:
        positive_ints = (
            "num_cubature_points",
            "num_contact_points",
            "max_handles",
            "substeps_per_frame",
            "max_contact_substeps",
            "newton_iterations",
            "line_search_steps",
            "sleep_steps",
        )
        for key in positive_ints:
            value = getattr(self, key)
            if int(value) != value or value < 1:
                raise ValueError(f"preset {self.name!r}: {key}={value!r} must be an integer >= 1")
        for key in ("newton_tolerance", "contact_stiffness_factor", "friction_smoothing_m_s"):
            value = getattr(self, key)
            if not value > 0:
                raise ValueError(f"preset {self.name!r}: {key}={value!r} must be > 0")
        if not isinstance(self.lagged_elastic_hessian, bool):
            raise ValueError(
                f"preset {self.name!r}: lagged_elastic_hessian={self.lagged_elastic_hessian!r} must be true or false"
            )
        if not 0.0 <= self.elastic_hessian_reuse < float("inf"):
            raise ValueError(
                f"preset {self.name!r}: elastic_hessian_reuse={self.elastic_hessian_reuse!r} must be finite and >= 0"
            )
        if self.elastic_hessian_reuse > 0 and not self.lagged_elastic_hessian:
            raise ValueError(
                f"preset {self.name!r}: elastic_hessian_reuse={self.elastic_hessian_reuse!r} needs "
                "lagged_elastic_hessian: true (without it the matrix is formed at every iteration)"
            )
        if self.sleep_speed_m_s < 0:
            raise ValueError(f"preset {self.name!r}: sleep_speed_m_s={self.sleep_speed_m_s!r} must be >= 0")
        if self.skinning_training_steps < 0:
            raise ValueError(
                f"preset {self.name!r}: skinning_training_steps={self.skinning_training_steps!r} must be >= 0"
            )

    def dt_s(self, fps: float) -> float:
        """Simulation time step (s) at a given frame rate (frames/s)."""
        if not fps > 0:
            raise ValueError(f"fps={fps!r} must be > 0")
        return 1.0 / (fps * self.substeps_per_frame)

    def replace(self, **changes: object) -> QualityPreset:
        """Copy with some fields changed (validated again)."""
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        unknown = set(changes) - set(values)
        if unknown:
            raise ValueError(f"unknown preset fields {sorted(unknown)}; valid: {sorted(values)}")
        values.update(changes)
        return QualityPreset(**values)  # type: ignore[arg-type]


def available_presets(preset_dir: Path = PRESET_DIR) -> list[str]:
    """Names of the presets found in ``preset_dir``."""
    return sorted(p.stem for p in preset_dir.glob("*.yaml"))


def load_preset(name: str, preset_dir: Path = PRESET_DIR) -> QualityPreset:
    """Load ``newtphys/conf/quality/<name>.yaml``; unknown names list the valid ones."""
    path = preset_dir / f"{name}.yaml"
    if not path.is_file():
        raise ValueError(f"unknown quality preset {name!r}; valid presets: {available_presets(preset_dir)}")
    data = yaml.safe_load(path.read_text())
    known = {f.name for f in fields(QualityPreset)}
    unknown = set(data) - known
    missing = known - set(data)
    if unknown or missing:
        raise ValueError(
            f"preset file {path}: unknown keys {sorted(unknown)}, missing keys {sorted(missing)}"
        )
    return QualityPreset(**data)
