"""Plain dense torch rasterizers (pixels x Gaussians in blocks, float64): cross-check and benchmark baseline.

They implement exactly the rules documented in ``rgb.py`` and ``labels.py``
with no binning, no bounding boxes and no sorting tricks beyond one stable
depth sort, so they are slow (O(pixels x Gaussians)) but easy to trust.
"""

from __future__ import annotations

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from data_gen.gaussians import Gaussians
from data_gen.render.labels import LABEL_COVER_ALPHA
from data_gen.render.projection import (
    DEFAULT_DILATION_PX2,
    DEFAULT_NEAR_M,
    SURFACE_DEPTH_SIGMAS,
    project_gaussians_torch,
)
from data_gen.render.rgb import ALPHA_MAX, ALPHA_MIN, T_MIN

#: Elements of one (pixels x Gaussians) block; bounds the reference's memory (8 bytes each, a few copies).
BLOCK_ELEMENTS = 2**22


def _pixel_centres(height: int, width: int) -> torch.Tensor:
    v, u = torch.meshgrid(
        torch.arange(height, dtype=torch.float64) + 0.5,
        torch.arange(width, dtype=torch.float64) + 0.5,
        indexing="ij",
    )
    return torch.stack([u.reshape(-1), v.reshape(-1)], 1)


def _mahalanobis(px: torch.Tensor, mean: torch.Tensor, conic: torch.Tensor) -> torch.Tensor:
    """(P, 2) pixels, (G, 2) means, (G, 3) conics -> (P, G) squared Mahalanobis distances."""
    dx = px[:, None, 0] - mean[None, :, 0]
    dy = px[:, None, 1] - mean[None, :, 1]
    return conic[:, 0] * dx * dx + 2.0 * conic[:, 1] * dx * dy + conic[:, 2] * dy * dy


def _blocks(num_pixels: int, num_gaussians: int) -> tuple[int, int]:
    g = max(1, min(num_gaussians, 4096))
    return max(1, BLOCK_ELEMENTS // g), g


def render_rgb_torch(
    gaussians: Gaussians,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    height: int,
    width: int,
    background_rgb: ArrayLike = (0.0, 0.0, 0.0),
    near_m: float = DEFAULT_NEAR_M,
    dilation_px2: float = DEFAULT_DILATION_PX2,
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Dense reference of :func:`data_gen.render.rgb.render_rgb`: (rgb (H, W, 3), alpha (H, W)) float32."""
    proj = project_gaussians_torch(
        gaussians, K, world_to_camera, height, width, ALPHA_MIN, near_m, dilation_px2
    )
    vis = torch.nonzero(proj["visible"]).reshape(-1)
    order = vis[torch.sort(proj["depth_m"][vis], stable=True).indices]  # ties keep index order
    mean, conic = proj["mean_px"][order], proj["conic"][order]
    opacity = torch.as_tensor(gaussians.opacities, dtype=torch.float64)[order]
    color = torch.as_tensor(gaussians.colors_rgb, dtype=torch.float64)[order]
    bg = torch.as_tensor(np.asarray(background_rgb, np.float64))
    pixels = _pixel_centres(height, width)
    n_pix, n = len(pixels), len(order)
    p_block, g_block = _blocks(n_pix, n)
    rgb = torch.zeros(n_pix, 3, dtype=torch.float64)
    trans = torch.ones(n_pix, dtype=torch.float64)
    for p0 in range(0, n_pix, p_block):  # blocks of pixels
        px = pixels[p0 : p0 + p_block]
        c_acc = torch.zeros(len(px), 3, dtype=torch.float64)
        t = torch.ones(len(px), dtype=torch.float64)
        done = torch.zeros(len(px), dtype=torch.bool)
        for g0 in range(0, n, g_block):  # chunks of depth-sorted Gaussians
            sl = slice(g0, g0 + g_block)
            q = _mahalanobis(px, mean[sl], conic[sl])
            alpha = torch.clamp(opacity[sl] * torch.exp(-0.5 * q), max=ALPHA_MAX)
            alpha = torch.where(alpha >= ALPHA_MIN, alpha, torch.zeros_like(alpha))
            one_minus = 1.0 - alpha
            excl = torch.cumprod(torch.cat([torch.ones_like(t)[:, None], one_minus[:, :-1]], 1), 1)
            t_before = t[:, None] * excl
            stop = (alpha > 0) & (t_before * one_minus < T_MIN)
            stopped_before = (torch.cumsum(stop.to(torch.int64), 1) - stop.to(torch.int64)) > 0
            use = ~done[:, None] & ~stopped_before & ~stop & (alpha > 0)
            c_acc += (torch.where(use, t_before * alpha, 0.0)) @ color[sl]
            any_stop = stop.any(1)
            first = torch.argmax(stop.to(torch.int64), 1)
            t_stop = t_before.gather(1, first[:, None])[:, 0]
            t_all = t_before[:, -1] * one_minus[:, -1]
            t = torch.where(done, t, torch.where(any_stop, t_stop, t_all))
            done = done | any_stop
        rgb[p0 : p0 + p_block] = c_acc
        trans[p0 : p0 + p_block] = t
    out = rgb + trans[:, None] * bg
    return (
        out.reshape(height, width, 3).to(torch.float32).numpy(),
        (1.0 - trans).reshape(height, width).to(torch.float32).numpy(),
    )


def render_label_index_torch(
    gaussians: Gaussians,
    K: ArrayLike,
    world_to_camera: ArrayLike,
    height: int,
    width: int,
    include: ArrayLike | None = None,
    near_m: float = DEFAULT_NEAR_M,
    dilation_px2: float = DEFAULT_DILATION_PX2,
    depth_mode: str = "center",
) -> tuple[NDArray[np.int32], NDArray[np.float32]]:
    """Dense reference of :func:`data_gen.render.labels.render_label_index`: (index, depth_m)."""
    proj = project_gaussians_torch(
        gaussians, K, world_to_camera, height, width, LABEL_COVER_ALPHA, near_m, dilation_px2
    )
    keep = proj["visible"]
    if include is not None:
        keep = keep & torch.as_tensor(np.asarray(include, bool))
    idx = torch.nonzero(keep).reshape(-1)
    mean, conic, q_cut = proj["mean_px"][idx], proj["conic"][idx], proj["q_cut"][idx]
    depth32 = proj["depth_m"][idx].to(torch.float32)
    key = (depth32.view(torch.int32).to(torch.int64) << 32) | idx  # positive floats: bits sort like values
    empty = torch.iinfo(torch.int64).max
    pixels = _pixel_centres(height, width)
    n_pix, n = len(pixels), len(idx)
    p_block, g_block = _blocks(n_pix, n)
    best = torch.full((n_pix,), empty, dtype=torch.int64)
    for p0 in range(0, n_pix, p_block):  # blocks of pixels
        px = pixels[p0 : p0 + p_block]
        run = torch.full((len(px),), empty, dtype=torch.int64)
        for g0 in range(0, n, g_block):  # chunks of Gaussians (any order)
            sl = slice(g0, g0 + g_block)
            covered = _mahalanobis(px, mean[sl], conic[sl]) <= q_cut[sl]
            cand = torch.where(covered, key[sl][None, :], torch.full_like(covered, empty, dtype=torch.int64))
            run = torch.minimum(run, cand.min(1).values)
        best[p0 : p0 + p_block] = run
    hit = best != empty
    index = torch.where(hit, best & 0xFFFFFFFF, torch.full_like(best, -1)).to(torch.int32)
    depth = torch.where(
        hit, (best >> 32).to(torch.int32).view(torch.float32), torch.zeros((), dtype=torch.float32)
    )
    if depth_mode == "surface":
        surface = _surface_depth(proj, K, pixels, index.long().clamp_min(0)).clamp_min(near_m)
        depth = torch.where(hit, surface.float(), depth)
    return index.reshape(height, width).numpy(), depth.reshape(height, width).numpy()


def _surface_depth(
    proj: dict[str, torch.Tensor], K: ArrayLike, pixels: torch.Tensor, idx: torch.Tensor
) -> torch.Tensor:
    """Per pixel: camera z of the density peak of Gaussian ``idx`` along the pixel ray (float64)."""
    k = torch.as_tensor(np.asarray(K, np.float64))
    rays = torch.stack(
        [
            (pixels[:, 0] - k[0, 2]) / k[0, 0],
            (pixels[:, 1] - k[1, 2]) / k[1, 1],
            torch.ones(len(pixels), dtype=torch.float64),
        ],
        1,
    )
    sigma = proj["cov_cam"][idx]
    centre = proj["mean_cam"][idx]
    # adj(Sigma) = det(Sigma) Sigma^-1, finite for flat splats; t* = d^T adj p / d^T adj d
    adj = torch.stack(
        [torch.linalg.cross(sigma[:, 1], sigma[:, 2]), torch.linalg.cross(sigma[:, 2], sigma[:, 0]),
         torch.linalg.cross(sigma[:, 0], sigma[:, 1])], 1,
    )  # fmt: skip
    num = torch.einsum("pi,pij,pj->p", rays, adj, centre)
    den = torch.einsum("pi,pij,pj->p", rays, adj, rays)
    z = centre[:, 2]
    half = float(SURFACE_DEPTH_SIGMAS) * torch.sqrt(torch.diagonal(sigma, dim1=1, dim2=2).sum(1))
    peak = torch.where(den > 0, num / torch.where(den > 0, den, torch.ones_like(den)), z)
    return torch.minimum(torch.maximum(peak, z - half), z + half)
