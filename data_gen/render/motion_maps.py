"""Per-pixel motion maps of one frame: scene flow and optical flow, from the label render's winners.

A pixel's winner (the label index: the splat whose surface the pixel shows, -1 for none) moves from its
centre at frame t to its centre at frame t + 1. That displacement, rotated into frame t's camera, is the
pixel's **scene flow** (m, camera frame of t; 0 where no splat). The **optical flow** is what the data
contract derives from depth and scene flow (:func:`newtphys.consistency.optical_flow_from_scene_flow`, the
validator's check): the pixel's surface point (depth along its ray), moved by the stored float32 scene flow,
projected with frame t + 1's camera, minus the pixel centre (px; 0 where the depth is 0 or the moved point is
behind the camera). The kernel subtracts the point's own projection at t, computed the same way as the one
at t + 1, instead of the pixel centre: the two differ by round-off (~1e-13 px), and a point that stays still
under a still camera then gets a flow of exactly 0. The numpy formula leaves ~1e-13 px residues there, which
are incompressible noise: they were ~30 % of the shard of a still-camera sequence at 1000 x 562.

Both run as one warp kernel on the render device, a thread per pixel, in float64 like the numpy formulas
(the maps are float32); at 1000 x 562 that is ~30 ms a frame on 2 CPU threads, against ~100 ms for the numpy
path it replaced. The numpy formulas stay the reference (``newtphys.consistency``), and the tests hold the
kernel to them.
"""

from __future__ import annotations

import numpy as np
import warp as wp
from numpy.typing import ArrayLike, NDArray

from data_gen.render.projection import run_in_threads
from newtphys import geometry


@wp.struct
class FlowCameras:
    """Frame t's and frame t + 1's cameras (float64): the pixel ray ``Kinv (u, v, 1)``, frame t's camera to
    world, its world to camera rotation, and frame t + 1's world to camera and intrinsics."""

    k_inv: wp.mat33d
    c2w_rotation: wp.mat33d
    c2w_translation: wp.vec3d
    w2c_rotation: wp.mat33d  # frame t: scene flow's frame
    w2c_translation: wp.vec3d
    next_rotation: wp.mat33d  # frame t + 1
    next_translation: wp.vec3d
    fx: wp.float64
    skew: wp.float64
    cx: wp.float64
    fy: wp.float64
    cy: wp.float64
    width: wp.int32


@wp.kernel
def motion_maps_kernel(
    index: wp.array(dtype=wp.int32),
    depth_m: wp.array(dtype=wp.float32),
    centres_m: wp.array(dtype=wp.vec3d),
    next_centres_m: wp.array(dtype=wp.vec3d),
    cams: FlowCameras,
    first: wp.int32,
    scene_flow: wp.array(dtype=wp.vec3f),
    optical_flow: wp.array(dtype=wp.vec2f),
):
    """Thread per pixel (row-major, from pixel ``first``): its scene flow (float32) and the optical flow that
    float32 scene flow implies (``newtphys.consistency.optical_flow_from_scene_flow``'s arithmetic, measured from
    the point's own projection at t: see the module docstring)."""
    k = first + wp.tid()
    i = index[k]
    flow = wp.vec3d()
    if i >= 0:
        flow = cams.w2c_rotation * (next_centres_m[i] - centres_m[i])
    stored = wp.vec3f(wp.float32(flow[0]), wp.float32(flow[1]), wp.float32(flow[2]))
    scene_flow[k] = stored
    z = wp.float64(depth_m[k])
    if z <= wp.float64(0.0):
        optical_flow[k] = wp.vec2f(0.0, 0.0)
        return
    u = wp.float64(k % cams.width) + wp.float64(0.5)
    v = wp.float64(k / cams.width) + wp.float64(0.5)
    point = cams.k_inv * wp.vec3d(u, v, wp.float64(1.0)) * z
    world = cams.c2w_rotation * point + cams.c2w_translation
    moved = world + cams.c2w_rotation * wp.vec3d(wp.float64(stored[0]), wp.float64(stored[1]), wp.float64(stored[2]))
    p = cams.next_rotation * moved + cams.next_translation
    if p[2] <= wp.float64(0.0):  # behind the next camera: no flow (the numpy formula's NaN, stored as 0)
        optical_flow[k] = wp.vec2f(0.0, 0.0)
        return
    # the flow is measured from the point's own projection at t, through the same arithmetic as at t + 1: that is
    # the pixel centre up to round-off (~1e-13 px), and a point that stays still under a still camera gets exactly 0
    # (not round-off noise, which gzip cannot compress)
    p0 = cams.w2c_rotation * world + cams.w2c_translation
    u0 = cams.fx * p0[0] / p0[2] + cams.skew * p0[1] / p0[2] + cams.cx
    v0 = cams.fy * p0[1] / p0[2] + cams.cy
    u1 = cams.fx * p[0] / p[2] + cams.skew * p[1] / p[2] + cams.cx
    v1 = cams.fy * p[1] / p[2] + cams.cy
    optical_flow[k] = wp.vec2f(wp.float32(u1 - u0), wp.float32(v1 - v0))


def _rigid(m: NDArray[np.float64]) -> tuple[wp.mat33d, wp.vec3d]:
    return wp.mat33d(*m[:3, :3].ravel().tolist()), wp.vec3d(*m[:3, 3].tolist())


def flow_cameras(K: ArrayLike, world_to_camera: ArrayLike, next_world_to_camera: ArrayLike,
                 width_px: int) -> FlowCameras:  # fmt: skip
    """The kernel's :class:`FlowCameras` of intrinsics ``K`` (px) and frames t's and t + 1's world-to-camera
    4x4 (m), for images ``width_px`` wide."""
    k = np.asarray(K, np.float64)
    w2c, nxt = np.asarray(world_to_camera, np.float64), np.asarray(next_world_to_camera, np.float64)
    cams = FlowCameras()
    cams.k_inv = wp.mat33d(*np.linalg.inv(k).ravel().tolist())
    cams.c2w_rotation, cams.c2w_translation = _rigid(geometry.rigid_inverse(w2c))
    cams.w2c_rotation, cams.w2c_translation = _rigid(w2c)
    cams.next_rotation, cams.next_translation = _rigid(nxt)
    cams.fx, cams.skew, cams.cx = float(k[0, 0]), float(k[0, 1]), float(k[0, 2])
    cams.fy, cams.cy = float(k[1, 1]), float(k[1, 2])
    cams.width = int(width_px)
    return cams


def motion_maps(
    index: NDArray[np.integer],
    depth_m: NDArray[np.float32],
    centres_m: ArrayLike,
    next_centres_m: ArrayLike,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    next_world_to_camera: ArrayLike,
    device: str = "cpu",
    num_threads: int = 1,
    out: tuple[NDArray[np.float32], NDArray[np.float32]] | None = None,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """(scene flow (H, W, 3) float32 m in frame t's camera, optical flow (H, W, 2) float32 px) of one frame.

    ``index`` (H, W): frame t's label winners (-1: none); ``depth_m`` (H, W): frame t's depth (0: none);
    ``centres_m`` / ``next_centres_m`` (N, 3): every splat's centre at frames t and t + 1 (world, m); ``K``
    (3x3, px) and the two frames' world-to-camera 4x4 (m); ``num_threads``: CPU threads over pixel ranges (the
    same bytes for any count); ``out``: C-contiguous float32 (H, W, 3) and (H, W, 2) arrays to fill and return (on
    the CPU the kernel writes them in place). See the module docstring.
    """
    idx = np.ascontiguousarray(index, np.int32)
    h, w = idx.shape
    depth = np.ascontiguousarray(depth_m, np.float32)
    if depth.shape != (h, w):
        raise ValueError(f"motion_maps: depth_m must have the label index's shape {(h, w)}, got {depth.shape}")
    x0 = np.ascontiguousarray(centres_m, np.float64)
    x1 = np.ascontiguousarray(next_centres_m, np.float64)
    if x0.ndim != 2 or x0.shape[1] != 3 or x1.shape != x0.shape:
        raise ValueError(f"motion_maps: need centres (N, 3) at both frames, got {x0.shape} and {x1.shape}")
    if idx.size and int(idx.max()) >= len(x0):
        raise ValueError(f"motion_maps: label index {int(idx.max())} out of range for {len(x0)} splats")
    cpu = wp.get_device(device).is_cpu
    wp.load_module(__name__, device=device)  # here, before the threads launch it (warp keeps it: ~3 us once loaded)
    if out is not None:
        for a, c in zip(out, (3, 2)):
            if a.shape != (h, w, c) or a.dtype != np.float32 or not a.flags.c_contiguous:
                raise ValueError(f"motion_maps: out arrays must be C-contiguous float32 {(h, w, c)}, "
                                 f"got {a.dtype} {a.shape}")  # fmt: skip
    if out is not None and cpu:  # the kernel writes the caller's arrays
        flow3 = wp.array(out[0].reshape(-1, 3), dtype=wp.vec3f, device=device, copy=False)
        flow2 = wp.array(out[1].reshape(-1, 2), dtype=wp.vec2f, device=device, copy=False)
    else:
        flow3 = wp.empty(h * w, dtype=wp.vec3f, device=device)
        flow2 = wp.empty(h * w, dtype=wp.vec2f, device=device)
    inputs = [
        wp.array(idx.reshape(-1), dtype=wp.int32, device=device, copy=not cpu),
        wp.array(depth.reshape(-1), dtype=wp.float32, device=device, copy=not cpu),
        wp.array(x0, dtype=wp.vec3d, device=device, copy=not cpu),
        wp.array(x1, dtype=wp.vec3d, device=device, copy=not cpu),
        flow_cameras(K, world_to_camera, next_world_to_camera, w),
    ]
    parts = max(1, int(num_threads)) if cpu else 1
    bounds = np.linspace(0, h * w, parts + 1).astype(int)

    def launch(j: int) -> None:  # disjoint pixel ranges: CPU threads (warp releases the GIL)
        wp.launch(motion_maps_kernel, dim=int(bounds[j + 1] - bounds[j]), device=device,
                  inputs=[*inputs, int(bounds[j])], outputs=[flow3, flow2])  # fmt: skip

    run_in_threads(launch, parts)
    if out is None:
        return flow3.numpy().reshape(h, w, 3), flow2.numpy().reshape(h, w, 2)
    if not cpu:
        out[0][...] = flow3.numpy().reshape(h, w, 3)
        out[1][...] = flow2.numpy().reshape(h, w, 2)
    return out


__all__ = ["FlowCameras", "flow_cameras", "motion_maps", "motion_maps_kernel"]
