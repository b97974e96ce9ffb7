"""Asset pipeline benchmark: meshing, inside tests, surface Gaussians, splat .ply I/O.

Each row is timed against a baseline measured in the same run:

* inside test: warp generalised winding number vs trimesh's ray-based ``contains``;
* surface Gaussians: even (rejection-thinned) sampling vs plain uniform sampling
  (time and the binarised coverage of random surface points);
* splat .ply write/read vs a bare ``ndarray.tofile`` / ``np.fromfile`` of the same bytes;
* meshing: marching tetrahedra per library object (no baseline library here: the
  ratio is against the SDF grid evaluation alone); hollow objects mesh their outer
  surface and their cavity;
* per-sequence preparation (mesh + volume) of 10 sequences x 5 objects at random
  sizes: reusing the canonical mesh scaled by s (``data_gen.assets.meshing``, cold
  and warm cache) vs re-meshing every scaled object (the previous behaviour).

Usage: python bench/bench_assets.py   (writes bench/results/assets.json)
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree

from data_gen.assets.gaussians_from_geometry import gaussians_from_mesh
from data_gen.assets.meshing import clear_mesh_cache, solid_volume_m3, surface_mesh
from data_gen.assets.ply_io import encode_gaussians, points_inside_mesh, read_splat_ply, write_splat_ply
from data_gen.assets.registry import get_object, list_objects
from data_gen.assets.shapes import Scaled, Shape, Shell, mesh_sdf
from data_gen.gaussians import Gaussians
from newtphys.rotations import quat_to_matrix

RESULTS = Path(__file__).parent / "results" / "assets.json"
LIBRARY_PNG = Path(__file__).parent / "results" / "assets_library.png"


def timed(fn, repeat: int = 3):
    best, out = np.inf, None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def coverage(g: Gaussians, queries: np.ndarray, k: int = 16) -> float:
    _, idx = cKDTree(g.means_m).query(queries, k=k)
    rot = quat_to_matrix(g.rotations_wxyz[idx].astype(np.float64))
    local = np.einsum("nkji,nkj->nki", rot, queries[:, None, :] - g.means_m[idx])
    q = ((local / g.scales_m[idx]) ** 2).sum(-1)
    return float((g.opacities[idx] * np.exp(-q / 2) >= 0.5).any(axis=1).mean())


def _solid_parts(shape: Shape) -> list[Shape]:
    """The smooth solids meshed for a shape: itself, or a shell's outer surface and its cavity."""
    if isinstance(shape, Scaled):
        return [Scaled(p, shape.scale) for p in _solid_parts(shape.child)]
    if isinstance(shape, Shell):
        return [shape.outer, shape.cavity()]
    return [shape]


def remesh_prepare(shape: Shape, spacing_m: float) -> tuple[trimesh.Trimesh, float]:
    """Baseline: mesh every solid of the (scaled) shape from scratch; (visible mesh, material volume m^3)."""
    meshes = [mesh_sdf(p, spacing_m=spacing_m) for p in _solid_parts(shape)]
    return meshes[0], float(meshes[0].volume - sum(m.volume for m in meshes[1:]))


def bench_meshing() -> dict:
    rows = []
    for name in list_objects():
        a = get_object(name)
        h = a.mesh_spacing_m()
        t_mesh, mesh = timed(lambda a=a, h=h: remesh_prepare(a.shape, h)[0], repeat=1)
        lo, hi = a.shape.bounds()
        n = int(np.prod(np.ceil((hi - lo + 4 * h) / h) + 1))
        pts = np.random.default_rng(0).uniform(lo, hi, (n, 3))
        t_sdf, _ = timed(lambda a=a, pts=pts: a.shape.sdf(pts), repeat=1)
        rows.append(
            {
                "object": name,
                "faces": len(mesh.faces),
                "mesh_s": t_mesh,
                "sdf_grid_s": t_sdf,
                "watertight": bool(mesh.is_watertight),
            }
        )
    return {
        "rows": rows,
        "total_mesh_s": sum(r["mesh_s"] for r in rows),
        "total_sdf_grid_s": sum(r["sdf_grid_s"] for r in rows),
    }


def bench_scaled_meshing(sequences: int = 10, objects: int = 5, size_m=(0.1, 0.3), seed: int = 0) -> dict:
    """Mesh + volume of every object of ``sequences`` x ``objects`` random (name, size) draws."""
    rng = np.random.default_rng(seed)
    names = list_objects()
    draws = [
        (names[int(rng.integers(len(names)))], float(rng.uniform(*size_m)))
        for _ in range(sequences * objects)
    ]
    assets = [get_object(n, size_m=s) for n, s in draws]

    def reuse() -> list[float]:
        return [
            solid_volume_m3(a.shape, a.mesh_spacing_m())
            + 0 * len(surface_mesh(a.shape, a.mesh_spacing_m()).faces)
            for a in assets
        ]

    def remesh() -> list[float]:
        return [remesh_prepare(a.shape, a.mesh_spacing_m())[1] for a in assets]

    clear_mesh_cache()
    t_cold, v_reuse = timed(reuse, repeat=1)
    t_warm, _ = timed(reuse, repeat=1)
    t_remesh, v_remesh = timed(remesh, repeat=1)
    rel = np.abs(np.asarray(v_reuse) / np.asarray(v_remesh) - 1.0)
    return {
        "sequences": sequences,
        "objects_per_sequence": objects,
        "distinct_objects": len({n for n, _ in draws}),
        "remesh_s": t_remesh,
        "reuse_cold_s": t_cold,
        "reuse_warm_s": t_warm,
        "speedup_cold": t_remesh / t_cold,
        "speedup_warm": t_remesh / max(t_warm, 1e-9),
        "volume_max_rel_diff": float(rel.max()),
    }


def bench_inside() -> dict:
    a = get_object("mug")
    mesh = a.to_mesh()
    pts = np.random.default_rng(1).uniform(*a.shape.bounds(), (300, 3))
    points_inside_mesh(mesh, pts[:10])  # compile / load the kernel outside the timing
    t_warp, inside_w = timed(lambda: points_inside_mesh(mesh, pts))
    t_ray, inside_r = timed(lambda: mesh.contains(pts), repeat=1)
    return {
        "faces": len(mesh.faces),
        "points": len(pts),
        "warp_winding_s": t_warp,
        "trimesh_contains_s": t_ray,
        "speedup": t_ray / t_warp,
        "agreement": float(np.mean(inside_w == inside_r)),
    }


def bench_gaussians() -> dict:
    rows = []
    for name in ("ball", "mug", "teddy_bear"):
        a = get_object(name)
        mesh = a.to_mesh()
        spacing = a.nominal_size_m / 60.0
        queries, _ = trimesh.sample.sample_surface(mesh, 5000, seed=np.random.default_rng(9))
        t_even, g_even = timed(
            lambda m=mesh, s=spacing: gaussians_from_mesh(m, np.random.default_rng(0), spacing_m=s, even=True)
        )
        t_plain, g_plain = timed(
            lambda m=mesh, s=spacing: gaussians_from_mesh(
                m, np.random.default_rng(0), spacing_m=s, even=False
            )
        )
        rows.append(
            {
                "object": name,
                "gaussians": len(g_even),
                "even_s": t_even,
                "plain_s": t_plain,
                "even_coverage": coverage(g_even, queries),
                "plain_coverage": coverage(g_plain, queries),
            }
        )
    return {"rows": rows}


def bench_ply(n: int = 1_000_000) -> dict:
    rng = np.random.default_rng(2)
    q = rng.normal(size=(n, 4))
    g = Gaussians(
        means_m=rng.normal(size=(n, 3)),
        scales_m=rng.uniform(1e-3, 1e-2, (n, 3)),
        rotations_wxyz=q / np.linalg.norm(q, axis=1, keepdims=True),
        colors_rgb=rng.uniform(0, 1, (n, 3)),
        opacities=rng.uniform(0.1, 0.99, n),
    )
    ply = encode_gaussians(g)
    raw = np.zeros((n, 17), np.float32)
    with tempfile.TemporaryDirectory() as d:
        path, bare = os.path.join(d, "g.ply"), os.path.join(d, "g.bin")
        t_write, _ = timed(lambda: write_splat_ply(path, ply))
        t_read, _ = timed(lambda: read_splat_ply(path))
        t_bare_w, _ = timed(lambda: raw.tofile(bare))
        t_bare_r, _ = timed(lambda: np.fromfile(bare, np.float32))
        size_mb = os.path.getsize(path) / 1e6
    return {
        "gaussians": n,
        "file_mb": size_mb,
        "write_s": t_write,
        "read_s": t_read,
        "bare_write_s": t_bare_w,
        "bare_read_s": t_bare_r,
        "write_vs_bare": t_write / t_bare_w,
        "read_vs_bare": t_read / t_bare_r,
    }


def plot_library(path: Path) -> None:
    """Contact sheet of every library object as coloured surface-Gaussian centres (painter-sorted scatter)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from data_gen.assets.gaussians_from_geometry import gaussians_from_object

    names = list_objects()
    cols = 6
    fig = plt.figure(figsize=(4 * cols, 3.4 * int(np.ceil(len(names) / cols))))
    elev, azim = 25.0, -60.0
    view = np.array(
        [
            np.cos(np.deg2rad(elev)) * np.cos(np.deg2rad(azim)),
            np.cos(np.deg2rad(elev)) * np.sin(np.deg2rad(azim)),
            np.sin(np.deg2rad(elev)),
        ]
    )
    for i, name in enumerate(names):  # loop over objects
        a = get_object(name)
        g = gaussians_from_object(a, np.random.default_rng(0), count=6000)
        order = np.argsort(g.means_m @ view)
        ax = fig.add_subplot(int(np.ceil(len(names) / cols)), cols, i + 1, projection="3d")
        m = g.means_m[order]
        ax.scatter(m[:, 0], m[:, 1], m[:, 2], c=g.colors_rgb[order], s=3, depthshade=False)
        ax.view_init(elev, azim)
        half = float(a.size_m.max()) / 2
        ax.set_xlim(-half, half)
        ax.set_ylim(-half, half)
        ax.set_zlim(-half, half)
        ax.set_title(f"{name} ({a.category}, {a.default_material}, {a.nominal_size_m:.2f} m)", fontsize=9)
        ax.set_axis_off()
    fig.tight_layout()
    fig.savefig(path, dpi=60)
    plt.close(fig)


def main() -> None:
    results = {
        "meshing": bench_meshing(),
        "scaled_meshing": bench_scaled_meshing(),
        "inside": bench_inside(),
        "gaussians": bench_gaussians(),
        "ply": bench_ply(),
        "cpu_count": os.cpu_count(),
        "load_avg_1min": os.getloadavg()[0],
    }
    m = results["meshing"]
    print(
        f"meshing: {len(m['rows'])} objects, total {m['total_mesh_s']:.2f} s marching tetrahedra + projection "
        f"vs {m['total_sdf_grid_s']:.2f} s for the SDF grid alone "
        f"(ratio {m['total_mesh_s'] / m['total_sdf_grid_s']:.2f})"
    )
    slow = sorted(m["rows"], key=lambda r: -r["mesh_s"])[:5]
    print("  slowest: " + ", ".join(f"{r['object']} {r['mesh_s']:.2f} s / {r['faces']} faces" for r in slow))
    sm = results["scaled_meshing"]
    print(
        f"per-sequence mesh + volume, {sm['sequences']} sequences x {sm['objects_per_sequence']} objects at random "
        f"sizes ({sm['distinct_objects']} distinct objects): re-mesh {sm['remesh_s']:.2f} s, reuse canonical "
        f"mesh x s: cold cache {sm['reuse_cold_s']:.2f} s ({sm['speedup_cold']:.1f}x), warm {sm['reuse_warm_s']:.4f} s "
        f"({sm['speedup_warm']:.0f}x); max volume difference {sm['volume_max_rel_diff']:.1e}"
    )
    i = results["inside"]
    print(
        f"inside test ({i['points']} points, {i['faces']} faces): warp winding {i['warp_winding_s']:.3f} s, "
        f"trimesh contains {i['trimesh_contains_s']:.3f} s -> {i['speedup']:.1f}x, agreement {i['agreement']:.4f}"
    )
    print(
        f"{'object':12s} {'gaussians':>9s} {'even s':>8s} {'plain s':>8s} {'ratio':>6s} {'even cov':>9s} {'plain cov':>9s}"
    )
    for r in results["gaussians"]["rows"]:
        print(
            f"{r['object']:12s} {r['gaussians']:9d} {r['even_s']:8.3f} {r['plain_s']:8.3f} "
            f"{r['even_s'] / r['plain_s']:6.2f} {r['even_coverage']:9.4f} {r['plain_coverage']:9.4f}"
        )
    p = results["ply"]
    print(
        f"splat .ply, {p['gaussians']} Gaussians ({p['file_mb']:.0f} MB): write {p['write_s']:.3f} s "
        f"({p['write_vs_bare']:.2f}x bare tofile), read {p['read_s']:.3f} s ({p['read_vs_bare']:.2f}x bare fromfile)"
    )
    print(
        f"machine: {results['cpu_count']} CPUs, 1-min load average {results['load_avg_1min']:.1f} (shared machine)"
    )
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=2))
    plot_library(LIBRARY_PNG)
    print(f"wrote {RESULTS} and {LIBRARY_PNG}")


if __name__ == "__main__":
    main()
