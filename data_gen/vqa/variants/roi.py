"""Image marks of the ROI variants: a red ring around an object, a black disc over it, and where it lies on a
3 x 3 grid of the image. Pure functions of a mask and an image (pixel centres at (x + 0.5, y + 0.5))."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RING_RGB = (255, 0, 0)
RING_SCALE = 1.5
"""The ring's radius: this many times the radius of the object's enclosing circle ..."""
RING_GAP_PX = 1.0
"""... and at least its width plus this many pixels outside that circle (tiny objects keep a gap)."""
RING_WIDTH_FRACTION = 0.006
"""Ring width: this fraction of the image's longer side, at least 2 px (6 px at 1000 x 562)."""
DISC_MARGIN_PX = 1.0
"""The masking disc reaches this far beyond the enclosing circle."""
GRID_WORDS = (("top-left", "top", "top-right"), ("left", "centre", "right"),
              ("bottom-left", "bottom", "bottom-right"))  # fmt: skip
"""Location of a point on a 3 x 3 grid of the image, [row][column]."""


@dataclass(frozen=True)
class Circle:
    cx: float
    cy: float
    radius: float
    """Pixels (x right, y down; pixel (i, j) covers [j, j + 1) x [i, i + 1))."""


def enclosing_circle(mask: np.ndarray) -> Circle | None:
    """A circle around every pixel of ``mask`` (H, W): centred on the mask's bounding box, through its farthest
    pixel corner. None for an empty mask."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    cx = 0.5 * (float(xs.min()) + float(xs.max()) + 1.0)
    cy = 0.5 * (float(ys.min()) + float(ys.max()) + 1.0)
    dx = np.maximum(np.abs(xs - cx), np.abs(xs + 1.0 - cx))  # farthest corner of each pixel
    dy = np.maximum(np.abs(ys - cy), np.abs(ys + 1.0 - cy))
    return Circle(cx, cy, float(np.sqrt(dx * dx + dy * dy).max()))


def ring_width_px(image_size: tuple[int, int]) -> float:
    return max(2.0, round(RING_WIDTH_FRACTION * max(image_size)))


def ring_radius_px(circle: Circle, width_px: float) -> float:
    return max(RING_SCALE * circle.radius, circle.radius + width_px + RING_GAP_PX)


def _distance(image_size: tuple[int, int], cx: float, cy: float) -> np.ndarray:
    h, w = image_size
    y, x = np.mgrid[0:h, 0:w]
    return np.hypot(x + 0.5 - cx, y + 0.5 - cy)


def draw_ring(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A copy of ``rgb`` (H, W, 3) uint8 with a red ring around ``mask`` (unchanged when the mask is empty)."""
    out = rgb.copy()
    circle = enclosing_circle(mask)
    if circle is None:
        return out
    width = ring_width_px(rgb.shape[:2])
    radius = ring_radius_px(circle, width)
    d = _distance(rgb.shape[:2], circle.cx, circle.cy)
    out[(d <= radius) & (d > radius - width)] = RING_RGB
    return out


def draw_disc(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """A copy of ``rgb`` with a filled black disc over every pixel of ``mask``."""
    out = rgb.copy()
    circle = enclosing_circle(mask)
    if circle is None:
        return out
    out[_distance(rgb.shape[:2], circle.cx, circle.cy) <= circle.radius + DISC_MARGIN_PX] = 0
    return out


def grid_location(mask: np.ndarray) -> str | None:
    """Cell of the 3 x 3 image grid holding the centroid of ``mask`` ("top-left" ... "bottom-right")."""
    ys, xs = np.nonzero(mask)
    if len(xs) == 0:
        return None
    h, w = mask.shape
    col = min(int(3.0 * (xs.mean() + 0.5) / w), 2)
    row = min(int(3.0 * (ys.mean() + 0.5) / h), 2)
    return GRID_WORDS[row][col]
