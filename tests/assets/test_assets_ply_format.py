"""The PLY format in every encoding: splat clouds and meshes read identically from ascii, binary little and
big endian files; every scalar type and its alias against hand values; list properties; malformed files."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from data_gen.assets.ply_format import ENCODINGS, PlyFormatError, PlyList, read_ply, write_ply
from data_gen.assets.ply_io import import_mesh, import_splats, read_ply_mesh, read_splat_ply, write_splat_ply
from tests.assets.test_assets_ply_io import FIELDS, random_ply

# (type name in the header, NumPy type, hand values at the type's limits)
TYPES = [
    ("char", "i1", [-128, 0, 127]),
    ("int8", "i1", [-5, 1, 2]),
    ("uchar", "u1", [0, 128, 255]),
    ("uint8", "u1", [7, 8, 9]),
    ("short", "i2", [-32768, -1, 32767]),
    ("int16", "i2", [3, -3, 300]),
    ("ushort", "u2", [0, 1, 65535]),
    ("uint16", "u2", [40000, 2, 3]),
    ("int", "i4", [-(2**31), 0, 2**31 - 1]),
    ("int32", "i4", [-7, 70000, 7]),
    ("uint", "u4", [0, 2**31, 2**32 - 1]),
    ("uint32", "u4", [1, 2, 3]),
    ("float", "f4", [1.5, -0.1, 3.4028235e38]),
    ("float32", "f4", [1e-38, 2.0, -7.25]),
    ("double", "f8", [1.0 / 3.0, -1e300, 5e-324]),
    ("float64", "f8", [0.1, 0.2, 0.3]),
]


def _hand_file(path, encoding: str) -> None:
    """One element with a property of every type name (aliases included), written without write_ply."""
    header = ["ply", f"format {encoding} 1.0", "comment every scalar type", "element thing 3"]
    header += [f"property {name} p_{name}" for name, _, _ in TYPES] + ["end_header"]
    if encoding == "ascii":
        rows = [" ".join(repr(np.asarray(values, code)[i].item()) for _, code, values in TYPES) for i in range(3)]
        body = ("\n".join(rows) + "\n").encode()
    else:
        order = "<" if encoding == "binary_little_endian" else ">"
        rec = np.empty(3, np.dtype([(f"p_{name}", order + code) for name, code, _ in TYPES]))
        for name, code, values in TYPES:
            rec[f"p_{name}"] = np.asarray(values, code)
        body = rec.tobytes()
    path.write_bytes(("\n".join(header) + "\n").encode() + body)


@pytest.mark.parametrize("encoding", ENCODINGS)
def test_every_scalar_type_and_alias_reads_its_hand_values(tmp_path, encoding: str) -> None:
    _hand_file(tmp_path / "t.ply", encoding)
    data = read_ply(tmp_path / "t.ply")
    assert data.header.encoding == encoding and data.header.comments == ("every scalar type",)
    thing = data.element("thing")
    for name, code, values in TYPES:
        col = thing[f"p_{name}"]
        assert isinstance(col, np.ndarray) and col.dtype == np.dtype(code), name
        np.testing.assert_array_equal(col, np.asarray(values, code), err_msg=name)


def test_splat_cloud_reads_identically_from_every_encoding(tmp_path) -> None:
    ply = random_ply(300, 8, seed=7)  # SH degree 2: 24 f_rest values per splat
    for encoding in ENCODINGS:
        write_splat_ply(tmp_path / f"{encoding}.ply", ply, encoding)
        back = read_splat_ply(tmp_path / f"{encoding}.ply")
        for f in FIELDS:  # bit-exact: ascii holds the shortest text that round-trips a float32
            np.testing.assert_array_equal(getattr(back, f), getattr(ply, f), err_msg=f"{encoding} {f}")
    text = (tmp_path / "ascii.ply").read_text().splitlines()
    assert text[1] == "format ascii 1.0" and len(text) == text.index("end_header") + 1 + 300
    g_ascii, _ = import_splats(tmp_path / "ascii.ply", scale=0.5, up_axis="y")
    g_big, _ = import_splats(tmp_path / "binary_big_endian.ply", scale=0.5, up_axis="y")
    for f in ("means_m", "scales_m", "rotations_wxyz", "colors_rgb", "opacities"):
        np.testing.assert_array_equal(getattr(g_ascii, f), getattr(g_big, f))


def test_ascii_splat_file_by_hand(tmp_path) -> None:
    """Two splats typed double/uchar/short, a row split over two lines: values as written."""
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2"]
    names += ["rot_0", "rot_1", "rot_2", "rot_3"]
    header = ["ply", "format ascii 1.0", "element vertex 2"]
    header += [f"property {'double' if n in 'xyz' else 'short' if n.startswith('rot') else 'float'} {n}" for n in names]
    body = "1.5 -2 3 0 0 0 0 -1 -2 -3 1 0 0 0\n0.25 0.5 0.75\n1 1 1 2.5 0 0 0 0 0 1 0\n"
    (tmp_path / "h.ply").write_text("\n".join(header + ["end_header"]) + "\n" + body)
    ply = read_splat_ply(tmp_path / "h.ply")
    np.testing.assert_array_equal(ply.positions, [[1.5, -2.0, 3.0], [0.25, 0.5, 0.75]])
    np.testing.assert_array_equal(ply.log_scales, [[-1, -2, -3], [0, 0, 0]])
    np.testing.assert_array_equal(ply.rotations_wxyz, [[1, 0, 0, 0], [0, 0, 1, 0]])
    np.testing.assert_array_equal(ply.opacity_logit, [0.0, 2.5])
    np.testing.assert_array_equal(ply.normals, np.zeros((2, 3)))  # no nx ny nz: zeros


def _mesh_columns() -> tuple[dict, dict]:
    """A unit square pyramid with a pentagon skirt: a quad base, triangles and a pentagon, coloured."""
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 1], [0.5, -0.5, 0]], np.float32)
    counts = np.array([4, 3, 3, 3, 3, 5])
    idx = np.array([3, 2, 1, 0, 0, 1, 4, 1, 2, 4, 2, 3, 4, 3, 0, 4, 0, 5, 1, 2, 3], np.int32)
    vertex = {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2], "red": np.arange(6, dtype=np.uint8) * 40,
              "green": np.full(6, 200, np.uint8), "blue": np.arange(6, dtype=np.uint8)}  # fmt: skip
    return vertex, {"vertex_indices": PlyList(counts, idx)}


def test_mesh_reads_identically_from_every_encoding_with_hand_triangulation(tmp_path) -> None:
    vertex, face = _mesh_columns()
    meshes = {}
    for encoding in ENCODINGS:
        write_ply(tmp_path / f"{encoding}.ply", {"vertex": vertex, "face": face}, encoding)
        data = read_ply(tmp_path / f"{encoding}.ply")
        polys = data.element("face")["vertex_indices"]
        assert isinstance(polys, PlyList)
        np.testing.assert_array_equal(polys.counts, [4, 3, 3, 3, 3, 5])
        np.testing.assert_array_equal(polys.values, face["vertex_indices"].values)
        np.testing.assert_array_equal(data.element("vertex")["red"], vertex["red"])
        meshes[encoding] = read_ply_mesh(tmp_path / f"{encoding}.ply")
    # triangles first, then the quad's (0, 1, 2) and (2, 3, 0) halves, then the pentagon's fan
    expected = [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [3, 2, 1], [1, 0, 3], [0, 5, 1], [0, 1, 2], [0, 2, 3]]
    for encoding, mesh in meshes.items():
        np.testing.assert_array_equal(mesh.faces, expected, err_msg=encoding)
        np.testing.assert_array_equal(mesh.vertices, np.column_stack([vertex[c] for c in "xyz"]))
        np.testing.assert_array_equal(mesh.visual.vertex_colors[:, 0], vertex["red"])
    # trimesh's own reader agrees on the ascii file (its binary reader needs lists of one length)
    other = trimesh.load(tmp_path / "ascii.ply", force="mesh")
    np.testing.assert_array_equal(other.faces, meshes["binary_little_endian"].faces)
    np.testing.assert_array_equal(other.visual.vertex_colors, meshes["ascii"].visual.vertex_colors)


def test_import_mesh_reads_ascii_and_big_endian_ply_the_same(tmp_path) -> None:
    box = trimesh.creation.box((10.0, 20.0, 30.0))  # centimetres, Y up
    box.export(tmp_path / "ascii.ply", encoding="ascii")
    faces = PlyList(np.full(len(box.faces), 3), box.faces.astype(np.int32).ravel())
    cols = {c: box.vertices[:, i].astype(np.float64) for i, c in enumerate("xyz")}
    write_ply(tmp_path / "big.ply", {"vertex": cols, "face": {"vertex_index": faces}}, "binary_big_endian")
    a = import_mesh(tmp_path / "ascii.ply", scale=0.01, up_axis="y")
    b = import_mesh(tmp_path / "big.ply", scale=0.01, up_axis="y")
    assert a.watertight and b.watertight
    np.testing.assert_allclose(a.mesh.extents, [0.1, 0.3, 0.2], atol=1e-9)
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_array_equal(a.mesh.faces, b.mesh.faces)


def test_lists_of_varying_length_in_long_binary_and_ascii_files(tmp_path) -> None:
    """Rows placed by pointer doubling (no loop over rows): 5000 polygons of 3-6 vertices, extra columns."""
    rng = np.random.default_rng(0)
    counts = rng.integers(3, 7, 5000)
    lists = {"vertex_indices": PlyList(counts, rng.integers(0, 10**6, counts.sum()).astype(np.uint32)),
             "flag": rng.integers(0, 255, 5000).astype(np.uint8),
             "weights": PlyList(counts[::-1].copy(), rng.normal(size=counts.sum()).astype(np.float32))}  # fmt: skip
    for encoding in ENCODINGS:
        write_ply(tmp_path / "l.ply", {"face": lists}, encoding)
        face = read_ply(tmp_path / "l.ply").element("face")
        for key in ("vertex_indices", "weights"):
            np.testing.assert_array_equal(face[key].counts, lists[key].counts)
            np.testing.assert_array_equal(face[key].values, lists[key].values)
        np.testing.assert_array_equal(face["flag"], lists["flag"])


def _header(lines: list[str]) -> bytes:
    return ("\n".join(["ply"] + lines + ["end_header"]) + "\n").encode()


BAD_FILES = [
    (_header(["format binary_middle_endian 1.0", "element vertex 0"]), r"format 'binary_middle_endian 1.0' not supported"),
    (_header(["format ascii 2.0", "element vertex 0"]), r"line 2: format 'ascii 2.0' not supported; need one of ascii 1.0"),
    (_header(["element vertex 1", "property float x"]), r"the header has no 'format' line"),
    (_header(["format ascii 1.0", "element vertex 1", "property float128 x"]), r"line 4: unknown type 'float128'; allowed: char"),
    (_header(["format ascii 1.0", "property float x"]), r"line 3: property 'property float x' before any element"),
    (_header(["format ascii 1.0", "element vertex many"]), r"line 3: malformed element line"),
    (_header(["format ascii 1.0", "element face 1", "property list float int v"]), r"list count type 'float' must be an integer"),
    (_header(["format ascii 1.0", "element vertex 1", "property float x", "property int x"]), r"property 'x' of element 'vertex' declared twice"),
    (_header(["format ascii 1.0", "vertices 3"]), r"line 3: unknown keyword 'vertices'"),
    (_header(["format ascii 1.0", "element vertex 2", "property float x"]) + b"1.0\n", r"truncated: element 'vertex' needs 2 tokens"),
    (_header(["format ascii 1.0", "element vertex 1", "property float x"]) + b"1 2\n", r"holds 1 numbers more than its header"),
    (_header(["format ascii 1.0", "element vertex 1", "property uchar x"]) + b"2.5\n", r"property 'x': ascii value 2.5 is not a uchar"),
    (_header(["format ascii 1.0", "element vertex 1", "property uchar x"]) + b"256\n", r"is not a uchar \(an integer in \[0, 255\]\)"),
    (_header(["format binary_little_endian 1.0", "element vertex 2", "property double x"]) + bytes(12), r"truncated: element 'vertex' needs 16 bytes"),
    (_header(["format binary_little_endian 1.0", "element face 2", "property list uchar int v"]) + bytes([3]) + bytes(12) + bytes([3]) + bytes(4),
     r"element 'face' \(header: 2 rows\) cannot be read past row 1"),
    (_header(["format ascii 1.0", "element face 1", "property list char int v"]) + b"-1\n", r"element 'face' \(header: 1 rows\) ends at row 0"),
    (b"hello", r"not a .ply file"),
    (b"ply\nformat ascii 1.0\nelement v 1\nproperty float x\xff\nend_header\n", r"non-ASCII bytes"),
]  # fmt: skip


@pytest.mark.parametrize(("content", "message"), BAD_FILES)
def test_malformed_files_name_the_file_and_the_problem(tmp_path, content: bytes, message: str) -> None:
    path = tmp_path / "broken.ply"
    path.write_bytes(content)
    with pytest.raises(PlyFormatError, match=r"broken\.ply: .*" + message):
        read_ply(path)


def test_mesh_errors_name_the_face(tmp_path) -> None:
    cols = {"x": np.zeros(3, np.float32), "y": np.zeros(3, np.float32), "z": np.zeros(3, np.float32)}
    write_ply(tmp_path / "far.ply", {"vertex": cols, "face": {"vertex_indices": PlyList([3, 3], np.array([0, 1, 2, 0, 1, 7], np.int32))}})
    with pytest.raises(PlyFormatError, match=r"far.ply: face 1 refers to vertex 7; the file has vertices 0..2"):
        read_ply_mesh(tmp_path / "far.ply")
    write_ply(tmp_path / "line.ply", {"vertex": cols, "face": {"vertex_indices": PlyList([3, 2], np.array([0, 1, 2, 0, 1], np.int32))}})
    with pytest.raises(PlyFormatError, match=r"line.ply: face 1 has 2 vertices; a face needs at least 3"):
        read_ply_mesh(tmp_path / "line.ply")
    write_ply(tmp_path / "cloud.ply", {"vertex": cols})
    with pytest.raises(ValueError, match=r"cloud.ply: no triangles found"):
        import_mesh(tmp_path / "cloud.ply")
    with pytest.raises(PlyFormatError, match=r"cloud.ply: no element 'face'; elements: \['vertex'\]"):
        read_ply(tmp_path / "cloud.ply").element("face")


@pytest.mark.parametrize("uv_on", ["vertex", "face"])
def test_textured_mesh_matches_trimesh(tmp_path, uv_on: str) -> None:
    import PIL.Image

    PIL.Image.new("RGB", (4, 4), (200, 30, 60)).save(tmp_path / "tex.png")
    box = trimesh.creation.box()
    v = box.vertices.astype(np.float32)
    uv = np.column_stack([v[:, 0] + 0.5, v[:, 1] + 0.5]).astype(np.float32)  # per-vertex uv in [0, 1]
    vertex = {"x": v[:, 0], "y": v[:, 1], "z": v[:, 2]}
    face = {"vertex_indices": PlyList(np.full(12, 3), box.faces.astype(np.int32).ravel())}
    if uv_on == "vertex":
        vertex |= {"s": uv[:, 0], "t": uv[:, 1]}
    else:
        face["texcoord"] = PlyList(np.full(12, 6), uv[box.faces].reshape(-1))
    write_ply(tmp_path / "t.ply", {"vertex": vertex, "face": face}, "ascii", comments=("TextureFile tex.png",))
    ours, theirs = read_ply_mesh(tmp_path / "t.ply"), trimesh.load(tmp_path / "t.ply", force="mesh")
    assert isinstance(ours.visual, trimesh.visual.TextureVisuals) and ours.visual.material.image.size == (4, 4)
    np.testing.assert_array_equal(ours.faces, theirs.faces)
    np.testing.assert_array_equal(ours.vertices, theirs.vertices)
    np.testing.assert_allclose(ours.visual.uv, theirs.visual.uv)
    np.testing.assert_array_equal(ours.visual.to_color().vertex_colors[:, :3], np.tile([200, 30, 60], (len(ours.vertices), 1)))
