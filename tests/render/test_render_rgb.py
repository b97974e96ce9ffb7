"""RGB rasterizer: analytic single splat, depth-ordered compositing, warp == torch reference, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from data_gen.gaussians import Gaussians
from data_gen.render.reference_torch import render_rgb_torch
from data_gen.render.rgb import ALPHA_MIN, RgbRasterizer, render_rgb
from newtphys.geometry import intrinsics_from_fov, look_at

N_SIDE = 33  # odd: the principal point is the centre of pixel (16, 16)
BG = (0.2, 0.3, 0.4)


def _random_scene(n: int, seed: int) -> tuple[Gaussians, np.ndarray, np.ndarray, int, int]:
    rng = np.random.default_rng(seed)
    h, w = 36, 52
    g = Gaussians(
        means_m=rng.uniform(-1.0, 1.0, (n, 3)),
        scales_m=rng.uniform(0.01, 0.12, (n, 3)),
        rotations_wxyz=rng.normal(size=(n, 4)),
        colors_rgb=rng.uniform(0, 1, (n, 3)),
        opacities=rng.uniform(0.05, 1.0, n),
    )
    return g, intrinsics_from_fov(65.0, h, w), look_at((2.5, -2.0, 1.5), (0.0, 0.0, 0.0)), h, w


def test_single_gaussian_matches_analytic_alpha() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    z, s, opacity, color = 2.0, 0.1, 0.8, np.array([1.0, 0.5, 0.0])
    g = Gaussians(means_m=[[0.0, 0.0, z]], scales_m=[[s] * 3], colors_rgb=[color], opacities=[opacity])
    rgb, alpha = render_rgb(g, K, np.eye(4), N_SIDE, N_SIDE, background_rgb=BG)
    # centre pixel: q = 0 -> alpha = opacity, colour = o c + (1 - o) bg
    np.testing.assert_allclose(rgb[16, 16], opacity * color + (1 - opacity) * np.array(BG), atol=1e-6)
    # every pixel: alpha = o exp(-r^2 / (2 sigma^2)), sigma^2 = (f s / z)^2 + 0.3 px^2, zero below 1/255
    sigma2 = (K[0, 0] * s / z) ** 2 + 0.3
    r, c = np.mgrid[0:N_SIDE, 0:N_SIDE]
    a = opacity * np.exp(-((r - 16.0) ** 2 + (c - 16.0) ** 2) / (2 * sigma2))
    a = np.where(a >= ALPHA_MIN, a, 0.0)
    np.testing.assert_allclose(alpha, a, atol=2e-6)
    np.testing.assert_allclose(rgb, a[..., None] * color + (1 - a[..., None]) * np.array(BG), atol=2e-6)


def test_near_gaussian_is_composited_first() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    red, blue = np.array([1.0, 0, 0]), np.array([0, 0, 1.0])
    # listed far first: the renderer must sort by depth
    g = Gaussians(
        means_m=[[0.0, 0.0, 3.0], [0.0, 0.0, 2.0]],
        scales_m=[[0.2] * 3, [0.1] * 3],
        colors_rgb=[blue, red],
        opacities=[0.9, 0.95],
    )
    rgb, alpha = render_rgb(g, K, np.eye(4), N_SIDE, N_SIDE, background_rgb=BG)
    # centre: 0.95 red + 0.05 * 0.9 blue + 0.05 * 0.1 bg
    np.testing.assert_allclose(rgb[16, 16], 0.95 * red + 0.045 * blue + 0.005 * np.array(BG), atol=1e-6)
    np.testing.assert_allclose(alpha[16, 16], 1 - 0.005, atol=1e-6)


def test_saturated_pixel_stops_before_transmittance_drops_below_1e_4() -> None:
    K = intrinsics_from_fov(60.0, N_SIDE, N_SIDE)
    # alphas 0.99 (clamped from 1), 0.98, 0.99: T 1 -> 0.01 -> 2e-4 -> (2e-6 < 1e-4: third is skipped)
    colors = np.eye(3)
    g = Gaussians(
        means_m=[[0.0, 0.0, 2.0], [0.0, 0.0, 2.5], [0.0, 0.0, 3.0]],
        scales_m=np.full((3, 3), 0.1),
        colors_rgb=colors,
        opacities=[1.0, 0.98, 1.0],
    )
    rgb, alpha = render_rgb(g, K, np.eye(4), N_SIDE, N_SIDE, background_rgb=(0, 0, 0))
    np.testing.assert_allclose(rgb[16, 16], [0.99, 0.01 * 0.98, 0.0], atol=1e-6)
    np.testing.assert_allclose(alpha[16, 16], 1 - 2e-4, atol=1e-6)


def test_warp_rgb_matches_torch_reference() -> None:
    g, K, w2c, h, w = _random_scene(700, seed=3)
    rgb, alpha = render_rgb(g, K, w2c, h, w, background_rgb=BG)
    rgb_t, alpha_t = render_rgb_torch(g, K, w2c, h, w, background_rgb=BG)
    assert 0.3 < (alpha > 0.5).mean() < 1.0
    # float32 sequential products (warp) vs float64 cumprod (torch): measured ~2e-6
    assert np.abs(rgb - rgb_t).max() < 1e-4
    assert np.abs(alpha - alpha_t).max() < 1e-4


def test_band_layouts_and_threads_give_identical_images() -> None:
    g, K, w2c, h, w = _random_scene(500, seed=6)
    ref = RgbRasterizer(h, w, num_threads=1).render(g, K, w2c, BG)
    # row bands over 2 or 3 threads (CPU), one kernel thread per row and the tile-binned per-pixel
    # pipeline (the two CUDA launch layouts, run here on CPU): all bit-identical
    layouts = (
        dict(num_threads=2),
        dict(num_threads=3),
        dict(num_threads=1, rows_per_band=1),
        dict(num_threads=1, pipeline="tiles"),
    )
    for kw in layouts:
        out = RgbRasterizer(h, w, **kw).render(g, K, w2c, BG)  # type: ignore[arg-type]
        assert out[0].tobytes() == ref[0].tobytes() and out[1].tobytes() == ref[1].tobytes()
    again = RgbRasterizer(h, w, num_threads=1).render(g, K, w2c, BG)
    assert again[0].tobytes() == ref[0].tobytes()


@pytest.mark.parametrize("pipeline", ["bands", "tiles"])
def test_reused_renderer_and_empty_view(pipeline: str) -> None:
    g, K, w2c, h, w = _random_scene(300, seed=7)
    r = RgbRasterizer(h, w, pipeline=pipeline)
    first = r.render(g, K, w2c, BG)
    # looking away from the scene: every Gaussian is behind the camera and culled
    empty_rgb, empty_alpha = r.render(g, K, look_at((2.5, -2.0, 1.5), (5.0, -4.0, 3.0)), BG)
    np.testing.assert_allclose(empty_rgb, np.broadcast_to(np.float32(BG), empty_rgb.shape))
    np.testing.assert_array_equal(empty_alpha, 0.0)
    assert r.render(g, K, w2c, BG)[0].tobytes() == first[0].tobytes()  # buffers fully reset
    bigger, _, _, _, _ = _random_scene(900, seed=8)  # buffers grow
    np.testing.assert_allclose(
        r.render(bigger, K, w2c, BG)[0], render_rgb_torch(bigger, K, w2c, h, w, BG)[0], atol=1e-4
    )


def test_bad_render_options() -> None:
    g, K, w2c, h, w = _random_scene(10, seed=0)
    with pytest.raises(
        ValueError, match=r"background_rgb must be 3 values in \[0, 1\], got \[0.0, 2.0, 0.0\]"
    ):
        render_rgb(g, K, w2c, h, w, background_rgb=(0.0, 2.0, 0.0))
    with pytest.raises(ValueError, match=r"rows_per_band must be >= 1 or None, got 0"):
        RgbRasterizer(h, w, rows_per_band=0)
    with pytest.raises(ValueError, match=r"pipeline must be one of \('auto', 'bands', 'tiles'\), got 'gpu'"):
        RgbRasterizer(h, w, pipeline="gpu")


@pytest.mark.parametrize("pipeline", ["bands", "tiles"])
def test_no_gaussians_gives_background(pipeline: str) -> None:
    g = Gaussians(
        means_m=np.zeros((0, 3)), scales_m=np.zeros((0, 3)), colors_rgb=np.zeros((0, 3)), opacities=[]
    )
    rgb, alpha = RgbRasterizer(8, 10, pipeline=pipeline).render(
        g, intrinsics_from_fov(60.0, 8, 10), np.eye(4), BG
    )
    np.testing.assert_array_equal(rgb, np.broadcast_to(np.float32(BG), (8, 10, 3)))
    np.testing.assert_array_equal(alpha, 0.0)


@pytest.mark.parametrize("layout", [dict(num_threads=2), dict(num_threads=1, pipeline="tiles"),
                                    dict(num_threads=1, rows_per_band=1)])  # fmt: skip
def test_two_colourings_in_one_pass_are_the_two_renders(layout: dict) -> None:
    """render_two composites a second colouring with the same weights: each image is bit for bit what a render of
    that colouring gives (on the band and the tile pipelines), and a plain render after it is unchanged."""
    g, K, w2c, h, w = _random_scene(400, seed=12)
    second = np.random.default_rng(13).uniform(0, 1, (len(g), 3))
    r = RgbRasterizer(h, w, **layout)
    first, other, alpha = r.render_two(g, second, K, w2c, BG, (0.0, 0.1, 0.0))
    ref_first, ref_alpha = RgbRasterizer(h, w, **layout).render(g, K, w2c, BG)
    ref_other, _ = RgbRasterizer(h, w, **layout).render(g.with_colors(second), K, w2c, (0.0, 0.1, 0.0))
    assert first.tobytes() == ref_first.tobytes() and other.tobytes() == ref_other.tobytes()
    assert alpha.tobytes() == ref_alpha.tobytes()
    assert not np.array_equal(first, other)
    assert r.render(g, K, w2c, BG)[0].tobytes() == ref_first.tobytes()  # the second colouring leaves no trace
    with pytest.raises(ValueError, match=r"colors_rgb\[0\] .*outside the allowed range"):
        r.render_two(g, np.full((len(g), 3), 1.5), K, w2c, BG)
    with pytest.raises(ValueError, match="background_rgb must be 3 values"):
        r.render_two(g, second, K, w2c, BG, (2.0, 0.0, 0.0))
