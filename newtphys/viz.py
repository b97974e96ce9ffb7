"""Pictures of shards: colourised maps, contact sheets, videos.

Each map kind of :mod:`newtphys.schema` has one colouriser (vectorised NumPy,
uint8 RGB out) and one legend description:

* depth — turbo, near = blue; black where there is no surface
* ids (instances, semantics, materials) — fixed palette, 0 = black
* collision — red over the (darkened) RGB frame
* gravity — diverging (RdBu) map of the image-down component g_y (N);
  positive = pointing down in the image
* stress — diverging (RdBu), symmetric about 0 Pa; blue = compression
* scene flow, optical flow — colour wheel of the image-plane direction,
  saturation = magnitude / max
* amodal maps — every object's full silhouette, palette-coloured, overlaid
"""

from __future__ import annotations

import colorsys
import os
from pathlib import Path

import matplotlib
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
import numpy as np  # noqa: E402
from matplotlib import cm, colors as mcolors
from PIL import Image, ImageDraw  # noqa: E402

from newtphys import schema  # noqa: E402
from newtphys.shards import ShardReader  # noqa: E402
from newtphys.world_state import WorldState  # noqa: E402


def palette(num: int = 256, seed: int = 7) -> np.ndarray:
    """(num, 3) uint8 distinct colours; index 0 is black (background)."""
    rng = np.random.default_rng(seed)
    hues = (np.arange(num) * 0.618033988749895 + rng.uniform()) % 1.0
    cols = np.array([colorsys.hsv_to_rgb(h, 0.65 + 0.35 * (i % 2), 0.95 - 0.25 * (i % 3 == 2)) for i, h in enumerate(hues)])
    out = (cols * 255).astype(np.uint8)
    out[0] = 0
    return out


_PALETTE = palette(4096)


def _cmap(name: str, values01: np.ndarray) -> np.ndarray:
    return (matplotlib.colormaps[name](np.clip(values01, 0, 1))[..., :3] * 255).astype(np.uint8)


def colorize_ids(ids: np.ndarray) -> np.ndarray:
    return _PALETTE[np.asarray(ids, np.int64) % len(_PALETTE)]


def colorize_depth(depth: np.ndarray, vmin: float | None = None, vmax: float | None = None) -> np.ndarray:
    valid = depth > 0
    if vmin is None or vmax is None:
        vals = depth[valid]
        vmin, vmax = (float(vals.min()), float(vals.max())) if vals.size else (0.0, 1.0)
    out = _cmap("turbo", (depth - vmin) / max(vmax - vmin, 1e-9))
    out[~valid] = 0
    return out


def colorize_signed(values: np.ndarray, limit: float | None = None, mask: np.ndarray | None = None) -> np.ndarray:
    """Diverging RdBu_r: red positive, blue negative, white 0."""
    if limit is None:
        limit = float(np.abs(values).max()) or 1.0
    out = _cmap("RdBu_r", 0.5 + 0.5 * values / limit)
    if mask is not None:
        out[~mask] = 40
    return out


def colorize_flow(flow_xy: np.ndarray, max_magnitude: float | None = None) -> np.ndarray:
    """Colour wheel: hue = direction in the image plane, saturation = magnitude / max."""
    dx, dy = flow_xy[..., 0], flow_xy[..., 1]
    mag = np.hypot(dx, dy)
    if max_magnitude is None:
        max_magnitude = float(mag.max()) or 1.0
    hue = (np.arctan2(-dy, -dx) / (2 * np.pi) + 0.5) % 1.0
    sat = np.clip(mag / max_magnitude, 0, 1)
    hsv = np.stack([hue, sat, np.ones_like(hue)], axis=-1)
    return (mcolors.hsv_to_rgb(hsv) * 255).astype(np.uint8)


def overlay_mask(rgb: np.ndarray, mask: np.ndarray, color=(255, 0, 0), alpha: float = 0.75) -> np.ndarray:
    base = (rgb.astype(np.float32) * 0.5).astype(np.float32)
    base[mask] = (1 - alpha) * rgb[mask] + alpha * np.asarray(color, np.float32)
    return base.astype(np.uint8)


def colorize_amodal(amodal: np.ndarray, ids: np.ndarray | None = None) -> np.ndarray:
    """(N, H, W) bool or ids -> palette colours of object n+1 (or of ``ids``) where set; later on top."""
    n, h, w = amodal.shape
    out = np.zeros((h, w, 3), np.uint8)
    for k in range(n):  # loop over objects, not pixels
        on = amodal[k] > 0
        col = colorize_ids(ids[k]) if ids is not None else _PALETTE[k + 1]
        blend = np.where(out.any(-1, keepdims=True), 0.5 * out + 0.5 * (col if col.ndim == 3 else col[None, None]), col)
        out = np.where(on[..., None], blend, out).astype(np.uint8)
    return out


def colorize(name: str, frame: np.ndarray, rgb: np.ndarray, limits: dict[str, float]) -> np.ndarray:
    """One frame of map ``name`` as (H, W, 3) uint8. ``limits`` holds per-sequence ranges."""
    if name == schema.RGB:
        return frame
    if name == schema.DEPTH:
        return colorize_depth(frame, limits.get("depth_min"), limits.get("depth_max"))
    if name in (schema.INSTANCES, schema.SEMANTIC_SEGMENTATION, schema.MATERIALS):
        return colorize_ids(frame)
    if name == schema.COLLISION:
        return overlay_mask(rgb, frame)
    if name == schema.GRAVITY:
        return colorize_signed(frame[..., 1], limits.get(name), np.linalg.norm(frame, axis=-1) > 0)
    if name == schema.STRESS:
        return colorize_signed(frame, limits.get(name), frame != 0)
    if name in (schema.SCENE_FLOW, schema.OPTICAL_FLOW):
        return colorize_flow(frame[..., :2], limits.get(name))
    if name == schema.AMODAL_INSTANCES:
        return colorize_amodal(frame)
    if name in (schema.AMODAL_MATERIALS, schema.AMODAL_SEMANTIC_SEGMENTATION):
        return colorize_amodal(frame > 0, frame)
    raise KeyError(f"no colouriser for map {name!r}")


LEGENDS: dict[str, str] = {
    schema.RGB: "colour",
    schema.DEPTH: "depth, m (turbo: near blue)",
    schema.INSTANCES: "object id",
    schema.SEMANTIC_SEGMENTATION: "semantic class",
    schema.MATERIALS: "material",
    schema.COLLISION: "in contact (red)",
    schema.GRAVITY: "gravity g_y, N (red = down in image)",
    schema.STRESS: "hydrostatic stress, Pa (blue = compression)",
    schema.SCENE_FLOW: "scene flow (x, y) direction wheel",
    schema.OPTICAL_FLOW: "optical flow direction wheel",
    schema.AMODAL_INSTANCES: "amodal silhouettes",
    schema.AMODAL_MATERIALS: "amodal materials",
    schema.AMODAL_SEMANTIC_SEGMENTATION: "amodal semantics",
}


def sequence_limits(maps: dict[str, np.ndarray]) -> dict[str, float]:
    """Per-sequence colour ranges so every frame of a sheet or video shares one scale."""
    lim: dict[str, float] = {}
    d = maps.get(schema.DEPTH)
    if d is not None and (d > 0).any():
        lim["depth_min"], lim["depth_max"] = float(d[d > 0].min()), float(d[d > 0].max())
    for name in (schema.GRAVITY, schema.STRESS):
        if name in maps:
            v = maps[name][..., 1] if name == schema.GRAVITY else maps[name]
            lim[name] = float(np.abs(v).max()) or 1.0
    for name in (schema.SCENE_FLOW, schema.OPTICAL_FLOW):
        if name in maps:
            lim[name] = float(np.linalg.norm(maps[name][..., :2], axis=-1).max()) or 1.0
    return lim


def _id_legend(ws: WorldState, name: str) -> list[tuple[int, str]]:
    if name == schema.INSTANCES:
        return [(o.id, o.name) for o in ws.objects]
    if name == schema.SEMANTIC_SEGMENTATION:
        return [(int(k), v) for k, v in ws.semantic_classes.items()]
    if name == schema.MATERIALS:
        return [(int(k), v) for k, v in ws.materials.items()]
    return []


def contact_sheet(
    maps: dict[str, np.ndarray],
    world_state: WorldState,
    out_path: str | os.PathLike,
    frame_indices: list[int] | None = None,
    map_names: tuple[str, ...] = schema.MAP_NAMES,
) -> Path:
    """PNG grid: one row per selected frame, one column per map, legends and colour bars below."""
    t = world_state.num_frames
    if frame_indices is None:
        frame_indices = sorted({int(round(x)) for x in np.linspace(0, t - 1, min(4, t))})
    bad = [i for i in frame_indices if not 0 <= i < t]
    if bad:
        raise ValueError(f"frame indices {bad} outside [0, {t}) of sequence '{world_state.sequence_id}'")
    lim = sequence_limits(maps)
    rows, cols = len(frame_indices), len(map_names)
    fig = Figure(figsize=(1.9 * cols, 1.9 * rows + 1.6))  # no pyplot: importing this module sets no backend
    axes = fig.subplots(rows + 1, cols, squeeze=False, gridspec_kw={"height_ratios": [1] * rows + [0.8]})
    for r, fi in enumerate(frame_indices):
        rgb = maps[schema.RGB][fi]
        for c, name in enumerate(map_names):
            ax = axes[r, c]
            ax.imshow(colorize(name, maps[name][fi], rgb, lim), interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(name.replace("_", "\n", 1) if len(name) > 14 else name, fontsize=7)
            if c == 0:
                ax.set_ylabel(f"frame {fi}\n{fi / world_state.fps:.2f} s", fontsize=7)
    for c, name in enumerate(map_names):  # legend row
        ax = axes[rows, c]
        ax.axis("off")
        ax.text(0.5, 1.0, LEGENDS[name], ha="center", va="top", fontsize=5.5, wrap=True, transform=ax.transAxes)
        entries = _id_legend(world_state, name)
        for k, (idx, label) in enumerate(entries[:6]):
            col = colorize_ids(np.array(idx)) / 255.0
            ax.add_patch(Rectangle((0.02, 0.62 - 0.12 * k), 0.08, 0.09, color=col, transform=ax.transAxes))
            ax.text(0.14, 0.66 - 0.12 * k, f"{idx}: {label}", fontsize=5, va="center", transform=ax.transAxes)
        scale = {schema.DEPTH: ("turbo", lim.get("depth_min", 0), lim.get("depth_max", 1)),
                 schema.GRAVITY: ("RdBu_r", -lim.get(schema.GRAVITY, 1), lim.get(schema.GRAVITY, 1)),
                 schema.STRESS: ("RdBu_r", -lim.get(schema.STRESS, 1), lim.get(schema.STRESS, 1))}.get(name)
        if scale is not None:
            cax = ax.inset_axes([0.05, 0.35, 0.9, 0.12])
            sm = cm.ScalarMappable(norm=mcolors.Normalize(scale[1], scale[2]), cmap=scale[0])
            cb = fig.colorbar(sm, cax=cax, orientation="horizontal")
            cb.ax.tick_params(labelsize=5)
        elif name in (schema.SCENE_FLOW, schema.OPTICAL_FLOW):
            unit = "m" if name == schema.SCENE_FLOW else "px"
            ax.text(0.5, 0.45, f"max |flow| = {lim.get(name, 0):.3g} {unit}", ha="center", fontsize=5,
                    transform=ax.transAxes)
    fig.suptitle(f"{world_state.sequence_id} ({world_state.split}, g = {world_state.gravity_magnitude:.2f} m/s²)",
                 fontsize=9)
    fig.tight_layout()
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path, dpi=130)
    return out_path


def video_frames(maps: dict[str, np.ndarray], map_names: tuple[str, ...] = schema.MAP_NAMES,
                 columns: int = 5, min_tile: int = 128) -> np.ndarray:
    """(T, H', W', 3) uint8: every map of every frame tiled in a labelled grid."""
    lim = sequence_limits(maps)
    t, h, w = maps[schema.RGB].shape[:3]
    scale = max(1, int(np.ceil(min_tile / max(h, w))))
    th, tw, bar = h * scale, w * scale, 12
    rows = int(np.ceil(len(map_names) / columns))
    out = np.zeros((t, rows * (th + bar), columns * tw, 3), np.uint8)
    for fi in range(t):
        rgb = maps[schema.RGB][fi]
        canvas = Image.new("RGB", (columns * tw, rows * (th + bar)))
        draw = ImageDraw.Draw(canvas)
        for k, name in enumerate(map_names):
            r, c = divmod(k, columns)
            tile = colorize(name, maps[name][fi], rgb, lim)
            tile = np.repeat(np.repeat(tile, scale, 0), scale, 1)
            canvas.paste(Image.fromarray(tile), (c * tw, r * (th + bar) + bar))
            draw.text((c * tw + 2, r * (th + bar)), name, fill=(255, 255, 255))
        out[fi] = np.asarray(canvas)
    return out


def write_video(frames: np.ndarray, out_path: str | os.PathLike, fps: float) -> Path:
    """MP4 when an ffmpeg backend is installed (imageio-ffmpeg), else GIF (the suffix is changed)."""
    import imageio.v2 as imageio

    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    if out_path.suffix.lower() == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401

            h, w = frames.shape[1:3]
            pad = ((0, 0), (0, (-h) % 16), (0, (-w) % 16), (0, 0))
            imageio.mimwrite(out_path, np.pad(frames, pad), fps=fps, macro_block_size=16)
            return out_path
        except ImportError:
            out_path = out_path.with_suffix(".gif")
    imageio.mimwrite(out_path, list(frames), duration=1.0 / fps, loop=0)
    return out_path


def view_sequence(shard: str | os.PathLike, sequence_id: str | None, out: str | os.PathLike,
                  video: bool = True) -> list[Path]:
    """Contact sheet PNG (and video) of one sequence of a shard; returns the written paths."""
    with ShardReader(shard) as reader:
        sid = sequence_id or reader.sequences()[0]
        seq = reader.read_sequence(sid)
    out = Path(out)
    sheet = contact_sheet(dict(seq.maps), seq.world_state, out.with_suffix(".png"))
    written = [sheet]
    if video:
        written.append(write_video(video_frames(dict(seq.maps)), out.with_suffix(".mp4"), seq.world_state.fps))
    return written
