"""Signed distance to the static scene (ground plane and oriented boxes) as batched torch operations.

The same geometry as :meth:`data_gen.sim.static_scene.StaticScene.query` (the warp kernel), evaluated for
all boxes at once: a handful of tensor operations per query whatever the box count, on the tensors'
device, with no host round trip. Scenes with a static point cloud (captured ``ply:`` scenes) use the warp
kernel and its hash grid instead (:func:`scene_distance`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from data_gen.sim.static_scene import StaticScene

FAR_M = 1.0e30


@dataclass(frozen=True)
class BoxSceneSdf:
    """Ground (optional) and B boxes: centres (B, 3) m, rotations (B, 3, 3), half extents (B, 3) m."""

    ground: bool
    centres_m: torch.Tensor
    rotations: torch.Tensor
    halves_m: torch.Tensor

    @staticmethod
    def of(scene: StaticScene) -> BoxSceneSdf:
        centres, rots, halves = scene._box_arrays()
        return BoxSceneSdf(bool(scene.ground), torch.from_numpy(centres), torch.from_numpy(rots), torch.from_numpy(halves))

    def query(self, x_m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Signed distance (m,) m and outward unit normal (m, 3) of points (m, 3)."""
        m = x_m.shape[0]
        ground_d = x_m[:, 2] if self.ground else torch.full((m,), FAR_M, dtype=x_m.dtype)
        up = torch.zeros(m, 3, dtype=x_m.dtype)
        up[:, 2] = 1.0
        if self.centres_m.shape[0] == 0:
            return ground_d, up
        local = torch.einsum("mbk,bkj->mbj", x_m[:, None, :] - self.centres_m[None], self.rotations)
        q = local.abs() - self.halves_m[None]
        qo = q.clamp(min=0.0)
        outside = qo.norm(dim=2)
        inside = q.amax(dim=2).clamp(max=0.0)
        n_out = qo * torch.sign(local) / outside.clamp(min=1e-300)[:, :, None]
        axis = q.argmax(dim=2, keepdim=True)
        sign = torch.where(local.gather(2, axis) < 0, -1.0, 1.0).to(x_m.dtype)
        n_in = torch.zeros_like(local).scatter_(2, axis, sign)
        n_local = torch.where((outside > 0)[:, :, None], n_out, n_in)
        n_world = torch.einsum("mbj,bkj->mbk", n_local, self.rotations)
        d = torch.cat([ground_d[:, None], outside + inside], dim=1)  # ground first: it wins ties
        normals = torch.cat([up[:, None], n_world], dim=1)
        best = d.argmin(dim=1)
        return d.gather(1, best[:, None])[:, 0], normals[torch.arange(m), best]


class SceneDistance:
    """Signed distance and normals of points (m, 3) to one static scene: batched torch for box scenes, the
    warp kernel (with the point cloud's hash grid) for scenes with a static point cloud."""

    def __init__(self, scene: StaticScene) -> None:
        self.scene = scene
        self.boxes = None if scene.points is not None else BoxSceneSdf.of(scene)

    def __call__(self, x_m: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        if self.boxes is not None:
            return self.boxes.query(x_m)
        d, n = self.scene.query(x_m)
        return torch.from_numpy(np.asarray(d)), torch.from_numpy(np.asarray(n))
