"""3DGS .ply I/O: bit-exact round trips, encodings against hand values, up-axis conversion, bad files, meshes
(the PLY format itself in every encoding: tests/assets/test_assets_ply_format.py)."""

import warnings

import numpy as np
import pytest
import trimesh

from data_gen.assets.ply_io import (
    SH_C0,
    PlyFormatError,
    SplatPly,
    _sh_basis,
    encode_gaussians,
    export_splats,
    import_mesh,
    import_splats,
    points_inside_mesh,
    read_splat_ply,
    sh_rotation_matrix,
    transform_splats,
    up_axis_rotation,
    write_splat_ply,
)
from data_gen.gaussians import Gaussians
from newtphys.rotations import quat_to_matrix

FIELDS = ("positions", "normals", "f_dc", "f_rest", "opacity_logit", "log_scales", "rotations_wxyz")


def random_ply(n: int, k: int, seed: int = 0) -> SplatPly:
    rng = np.random.default_rng(seed)
    return SplatPly(
        rng.normal(size=(n, 3)),
        rng.normal(size=(n, 3)),
        rng.normal(size=(n, 3)),
        rng.normal(size=(n, 3, k)),
        rng.normal(size=n),
        rng.normal(size=(n, 3)) - 4.0,
        rng.normal(size=(n, 4)),
    )


def header_and_body(path) -> tuple[list[str], bytes]:
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    return raw[:end].decode().splitlines(), raw[end:]


@pytest.mark.parametrize("k", [0, 3, 8, 15])
def test_raw_round_trip_is_bit_exact(tmp_path, k):
    ply = random_ply(257, k)
    write_splat_ply(tmp_path / "a.ply", ply)
    back = read_splat_ply(tmp_path / "a.ply")
    for f in FIELDS:
        np.testing.assert_array_equal(getattr(back, f), getattr(ply, f))
    assert back.sh_degree == {0: 0, 3: 1, 8: 2, 15: 3}[k]
    lines, body = header_and_body(tmp_path / "a.ply")
    assert lines[1] == "format binary_little_endian 1.0" and lines[2] == "element vertex 257"
    assert len(body) == 257 * 4 * (17 + 3 * k)


def test_encodings_against_hand_values(tmp_path):
    g = Gaussians(
        means_m=[[1.0, 2.0, 3.0], [0.0, 0.0, 0.0]],
        scales_m=[[1.0, np.exp(-3.0), 0.5], [0.1, 0.1, 0.1]],
        rotations_wxyz=[[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]],
        colors_rgb=[[0.5, 0.5 + SH_C0, 0.5 - SH_C0], [1.0, 0.0, 0.25]],
        opacities=[0.5, 0.95],
        part_ids=[0, 0],
    )
    export_splats(tmp_path / "g.ply", g)
    lines, body = header_and_body(tmp_path / "g.ply")
    names = [ln.split()[-1] for ln in lines if ln.startswith("property")]
    assert names == [
        "x",
        "y",
        "z",
        "nx",
        "ny",
        "nz",
        "f_dc_0",
        "f_dc_1",
        "f_dc_2",
        "opacity",
        "scale_0",
        "scale_1",
        "scale_2",
        "rot_0",
        "rot_1",
        "rot_2",
        "rot_3",
    ]
    rows = np.frombuffer(body, "<f4").reshape(2, 17)
    np.testing.assert_allclose(rows[0, 6:9], [0.0, 1.0, -1.0], atol=1e-6)  # f_dc = (c - 0.5) / C0
    np.testing.assert_allclose(rows[1, 6:9], [0.5 / SH_C0, -0.5 / SH_C0, -0.25 / SH_C0], rtol=1e-6)
    np.testing.assert_allclose(
        rows[:, 9], [0.0, np.log(19.0)], atol=1e-6
    )  # logit(0.5) = 0, logit(0.95) = ln 19
    np.testing.assert_allclose(rows[0, 10:13], [0.0, -3.0, np.log(0.5)], atol=1e-6)  # natural log of sigma
    np.testing.assert_array_equal(rows[:, 0:3], [[1, 2, 3], [0, 0, 0]])
    np.testing.assert_array_equal(rows[:, 13:17], [[1, 0, 0, 0], [0, 1, 0, 0]])
    back, _ = import_splats(tmp_path / "g.ply")
    np.testing.assert_allclose(back.colors_rgb, g.colors_rgb, atol=1e-6)
    np.testing.assert_allclose(back.opacities, g.opacities, atol=1e-6)
    np.testing.assert_allclose(back.scales_m, g.scales_m, rtol=1e-6)
    np.testing.assert_array_equal(back.means_m, g.means_m)


def test_surface_gaussians_round_trip(tmp_path):
    rng = np.random.default_rng(4)
    q = rng.normal(size=(500, 4))
    g = Gaussians(
        means_m=rng.normal(size=(500, 3)),
        scales_m=rng.uniform(1e-4, 1e-1, (500, 3)),
        rotations_wxyz=q / np.linalg.norm(q, axis=1, keepdims=True),
        colors_rgb=rng.uniform(0, 1, (500, 3)),
        opacities=rng.uniform(0.05, 0.99, 500),
    )
    export_splats(tmp_path / "r.ply", g)
    back, raw = import_splats(tmp_path / "r.ply")
    np.testing.assert_array_equal(back.means_m, g.means_m)
    np.testing.assert_allclose(back.scales_m, g.scales_m, rtol=2e-6)
    np.testing.assert_allclose(back.colors_rgb, g.colors_rgb, atol=1e-6)
    np.testing.assert_allclose(back.opacities, g.opacities, atol=1e-6)
    np.testing.assert_allclose(back.rotations_wxyz, g.rotations_wxyz, atol=1e-6)
    assert raw.sh_degree == 0


def test_y_up_to_z_up_and_metric_scale(tmp_path):
    r = up_axis_rotation("y")
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, 1])
    np.testing.assert_allclose(np.linalg.det(r), 1.0)
    for axis in ("z", "y", "-y", "x", "-x", "-z"):
        up = np.zeros(3)
        up["xyz".index(axis[-1])] = -1.0 if axis.startswith("-") else 1.0
        np.testing.assert_allclose(up_axis_rotation(axis) @ up, [0, 0, 1], atol=1e-15)
        np.testing.assert_allclose(np.linalg.det(up_axis_rotation(axis)), 1.0)
    # a capture in centimetres, Y up: a splat 100 cm above the origin, elongated along Y
    g = Gaussians(
        means_m=[[0.0, 100.0, 0.0]], scales_m=[[1.0, 10.0, 1.0]], colors_rgb=[[0.2, 0.4, 0.6]], opacities=[0.9]
    )
    export_splats(tmp_path / "y.ply", g)
    z, _ = import_splats(tmp_path / "y.ply", scale=0.01, up_axis="y")
    np.testing.assert_allclose(z.means_m, [[0.0, 0.0, 1.0]], atol=1e-6)
    np.testing.assert_allclose(z.scales_m, [[0.01, 0.1, 0.01]], rtol=1e-6)
    long_axis_world = quat_to_matrix(z.rotations_wxyz[0].astype(np.float64))[:, 1]
    np.testing.assert_allclose(long_axis_world, [0, 0, 1], atol=1e-6)  # the long axis now points up


def test_view_dependent_colour_rotates_with_the_scene():
    ply = random_ply(20, 15, seed=3)
    r = up_axis_rotation("y")
    out = transform_splats(ply, 1.0, "y")
    d = np.random.default_rng(5).normal(size=(64, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    before = np.einsum("mk,nck->nmc", _sh_basis(d, 3), ply.f_rest.astype(np.float64))
    after = np.einsum("mk,nck->nmc", _sh_basis(d @ r.T, 3), out.f_rest.astype(np.float64))
    np.testing.assert_allclose(after, before, atol=1e-5)  # colour seen along R d after = along d before
    m = sh_rotation_matrix(np.eye(3), 3)
    np.testing.assert_allclose(m, np.eye(15), atol=1e-10)


def _write_header(path, lines, body=b""):
    path.write_bytes(("\n".join(lines) + "\n").encode() + body)


def test_bad_files_name_the_problem(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.ply"):
        read_splat_ply(tmp_path / "nope.ply")
    (tmp_path / "junk.ply").write_bytes(b"hello world")
    with pytest.raises(PlyFormatError, match="junk.ply.*not a .ply"):
        read_splat_ply(tmp_path / "junk.ply")
    good = random_ply(3, 0)
    write_splat_ply(tmp_path / "g.ply", good)
    lines, body = header_and_body(tmp_path / "g.ply")
    _write_header(tmp_path / "ascii.ply", [lines[0], "format ascii 1.0"] + lines[2:], body)
    with pytest.raises(PlyFormatError, match=r"ascii.ply: ascii body: token 0 .* is not a number; the body is not text"):
        read_splat_ply(tmp_path / "ascii.ply")
    _write_header(
        tmp_path / "noopac.ply",
        [ln.replace("property float opacity", "property float opacityx") for ln in lines],
        body,
    )
    with pytest.raises(PlyFormatError, match="missing required vertex properties.*'opacity'"):
        read_splat_ply(tmp_path / "noopac.ply")
    _write_header(tmp_path / "short.ply", lines, body[:-8])
    with pytest.raises(PlyFormatError, match="truncated"):
        read_splat_ply(tmp_path / "short.ply")
    rows = np.frombuffer(body, "<f4").reshape(3, 17).copy()
    rows[1, 11] = np.nan  # scale_1 of vertex 1
    _write_header(tmp_path / "nan.ply", lines, rows.tobytes())
    with pytest.raises(PlyFormatError, match="nan.ply.*'scale_1'.*vertex 1"):
        read_splat_ply(tmp_path / "nan.ply")
    odd = lines[:9] + [f"property float f_rest_{i}" for i in range(5)] + lines[9:]
    _write_header(tmp_path / "rest.ply", odd, np.zeros((3, 22), "<f4").tobytes())
    with pytest.raises(PlyFormatError, match="f_rest"):
        read_splat_ply(tmp_path / "rest.ply")
    with pytest.raises(ValueError, match="scale"):
        import_splats(tmp_path / "g.ply", scale=0.0)
    with pytest.raises(ValueError, match="up_axis"):
        import_splats(tmp_path / "g.ply", up_axis="w")
    with pytest.raises(ValueError, match="scales_m"):
        export_splats(
            tmp_path / "z.ply",
            Gaussians(means_m=np.zeros((1, 3)), scales_m=-np.ones((1, 3)), colors_rgb=np.zeros((1, 3)), opacities=[1.0]),
        )
    assert encode_gaussians(
        Gaussians(means_m=np.zeros((1, 3)), scales_m=np.ones((1, 3)), colors_rgb=np.zeros((1, 3)), opacities=[1.0])
    ).opacity_logit[0] == pytest.approx(
        np.log((1 - 1e-6) / 1e-6), rel=1e-5
    )  # opacity 1 is clipped before the logit


def test_mesh_import_scale_up_axis_and_watertight(tmp_path):
    box = trimesh.creation.box((10.0, 20.0, 30.0))  # centimetres, Y up: 20 cm tall
    box.export(tmp_path / "box.obj")
    imp = import_mesh(tmp_path / "box.obj", scale=0.01, up_axis="y")
    assert imp.watertight
    np.testing.assert_allclose(imp.mesh.extents, [0.1, 0.3, 0.2], atol=1e-9)
    assert imp.mesh.volume == pytest.approx(0.1 * 0.2 * 0.3, rel=1e-9)
    assert list(imp.contains([[0, 0, 0], [0, 0, 0.15]])) == [True, False]


def test_open_mesh_warns_and_uses_winding_number(tmp_path):
    sphere = trimesh.creation.icosphere(3, radius=1.0)
    keep = sphere.triangles_center[:, 2] < 0.9  # cut a cap: a hole too large to fill
    open_mesh = trimesh.Trimesh(sphere.vertices, sphere.faces[keep])
    open_mesh.export(tmp_path / "open.ply")
    with pytest.warns(UserWarning, match="not watertight"):
        imp = import_mesh(tmp_path / "open.ply")
    assert not imp.watertight
    p = np.random.default_rng(0).uniform(-1.2, 1.2, (4000, 3))
    r = np.linalg.norm(p, axis=1)
    far = np.abs(r - 1.0) > 0.03  # away from the tessellated surface
    assert np.mean(imp.contains(p[far]) == (r[far] < 1.0)) > 0.99


def test_bad_mesh_files(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.obj"):
        import_mesh(tmp_path / "missing.obj")
    (tmp_path / "empty.obj").write_text("# nothing here\n")
    with pytest.raises(ValueError, match="empty.obj"):
        import_mesh(tmp_path / "empty.obj")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert points_inside_mesh(trimesh.creation.box(), np.zeros((0, 3))).shape == (0,)
