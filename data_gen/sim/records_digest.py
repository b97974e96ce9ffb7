"""A fingerprint of everything a simulation recorded: do two runs (two versions of the code) agree bit for bit?

Speed work on the solver is mostly reordering host work that must not change a single result. Comparing every
array of two runs needs both in one process; a digest can be printed by each version and compared by eye or in a
script. :func:`records_digest` hashes (SHA-256) every numeric array of every object's track in attribute order,
the energy series, the contact events and the Newton iteration count: one flipped bit anywhere changes it.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import fields

import numpy as np

from data_gen.sim.recording import SimulationResult


def _update_array(digest, name: str, value: np.ndarray) -> None:
    array = np.ascontiguousarray(value)
    digest.update(f"{name}:{array.dtype.str}:{array.shape}".encode())
    digest.update(array.tobytes())


def records_digest(result: SimulationResult) -> str:
    """SHA-256 (hex) of ``result``'s per-object arrays (names, dtypes, shapes and bytes), energies (J), contact
    events and total Newton iterations. Non-array attributes of a track (its name, its skinning basis) are left
    out; the object ids are in."""
    digest = hashlib.sha256()
    digest.update(f"frames:{result.num_frames}:fps:{result.fps!r}".encode())
    for track in result.objects:
        digest.update(f"object:{track.object_id}".encode())
        for name in (f.name for f in fields(track)):  # ObjectTrack's fields, in declaration order
            value = getattr(track, name)
            if isinstance(value, np.ndarray):
                _update_array(digest, name, value)
    for name in sorted(result.energies_j):
        _update_array(digest, f"energy:{name}", np.asarray(result.energies_j[name]))
    events = [event.to_dict() for event in result.collisions]
    digest.update(json.dumps(events, sort_keys=True, default=repr).encode())
    digest.update(f"newton:{int(result.info.newton_iterations)}".encode())
    return digest.hexdigest()


__all__ = ["records_digest"]
