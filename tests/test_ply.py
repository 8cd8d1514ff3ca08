"""geovox.io.ply: every PLY read without trimesh, into the Mesh trimesh's reading made
(compared on volumes and triangles), and every malformed one refused in one line."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

import geovox
from geovox.errors import GeovoxError, MeshError
from geovox.io.adaptor import from_trimesh

from conftest import corpus


def trimesh_reading(path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return from_trimesh(trimesh.load(str(path), process=False), source=str(path))


def _same_triangles(a, b):
    """The same triangles, whatever their order and first corner."""
    def key(m):
        t = np.sort(m.triangles, axis=1).reshape(len(m.faces), 9)
        return t[np.lexsort(t.T[::-1])]
    assert len(a.faces) == len(b.faces)
    np.testing.assert_array_equal(key(a), key(b))


def _write(path, vertices, faces, order="<", vtypes=("float", "f4"), names="xyz",
           count=("uchar", "u1"), index=("int", "i4"), comments=("made for geovox's tests",),
           tail=b""):
    fmt = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    head = ["ply", f"format {fmt} 1.0"] + [f"comment {c}" for c in comments]
    head += [f"element vertex {len(vertices)}"] + [f"property {vtypes[0]} {n}" for n in names]
    head += [f"element face {len(faces)}",
             f"property list {count[0]} {index[0]} vertex_indices", "end_header"]
    vdt = np.dtype([(n, order + vtypes[1]) for n in names])
    v = np.zeros(len(vertices), vdt)
    for n in names:
        v[n] = vertices[:, "xyz".index(n)]
    fdt = np.dtype([("n", order + count[1]), ("i", order + index[1], (faces.shape[1],))])
    f = np.zeros(len(faces), fdt)
    f["n"], f["i"] = faces.shape[1], faces
    with open(path, "wb") as out:
        out.write(("\n".join(head) + "\n").encode() + v.tobytes() + f.tobytes() + tail)
    return str(path)


@pytest.fixture
def sphere():
    s = trimesh.creation.icosphere(subdivisions=3)
    return np.asarray(s.vertices), np.asarray(s.faces)


@pytest.mark.parametrize("encoding", ["binary", "ascii"])
def test_trimesh_export_reads_as_trimesh_reads_it(tmp_path, sphere, encoding):
    path = str(tmp_path / "s.ply")
    with open(path, "wb") as f:
        f.write(trimesh.Trimesh(*sphere, process=False).export(file_type="ply",
                                                               encoding=encoding))
    mesh = geovox.load_mesh(path)
    old = trimesh_reading(path)
    np.testing.assert_array_equal(mesh.vertices, old.vertices)
    np.testing.assert_array_equal(mesh.faces, old.faces)
    assert mesh.materials == old.materials and mesh.corner_uv is None


@pytest.mark.parametrize("layout", [
    dict(order=">"),
    dict(vtypes=("double", "f8")),
    dict(names="zxy"),
    dict(count=("uint8", "u1"), index=("uint", "u4")),
    dict(count=("int", "i4"), index=("ushort", "u2")),
    dict(count=("ushort", "u2"), index=("char", "i1")),
    dict(comments=()),
])
def test_layouts_read_as_trimesh_reads_them(tmp_path, sphere, layout):
    v, f = sphere
    if layout.get("index", ("", ""))[1] == "i1":  # indices up to 127
        ico = trimesh.creation.icosahedron()
        v, f = np.asarray(ico.vertices), np.asarray(ico.faces)
    v = v + np.array([1e3, -2.0, 0.5])  # float32 rounding shows up in every layout
    path = _write(tmp_path / "s.ply", v, f, **layout)
    mesh = geovox.load_mesh(path)
    old = trimesh_reading(path)
    np.testing.assert_array_equal(mesh.vertices, old.vertices)
    np.testing.assert_array_equal(mesh.faces, old.faces)


@pytest.mark.parametrize("end", [b"\r", b"\r\n"])
@pytest.mark.parametrize("fmt", ["binary", "ascii"])
def test_header_lines_ended_by_carriage_returns(tmp_path, sphere, end, fmt):
    # PLY's own definition speaks of carriage-return-terminated header lines;
    # trimesh's reader fails on them (UnicodeDecodeError or a wrong count).
    path = tmp_path / "lf.ply"
    path.write_bytes(trimesh.Trimesh(*sphere, process=False).export(file_type="ply",
                                                                    encoding=fmt))
    data = path.read_bytes()
    at = data.index(b"end_header\n") + len(b"end_header\n")
    cr = tmp_path / "cr.ply"
    cr.write_bytes(data[:at].replace(b"\n", end) + data[at:])
    a, b = geovox.load_mesh(str(path)), geovox.load_mesh(str(cr))
    np.testing.assert_array_equal(a.triangles, b.triangles)


def test_assimps_newline_cases():
    # a CRLF after end_header only; binary data whose first byte is a line feed
    a = geovox.load_mesh(corpus("assimp", "cube_binary_header_with_RN_newline.ply"))
    b = geovox.load_mesh(corpus("assimp", "cube_binary_starts_with_nl.ply"))
    assert a.bounds.tolist() == [[0, 0, 0], [1, 1, 1]] and len(a.faces) == 12
    assert len(b.faces) == 12
    np.testing.assert_allclose(b.bounds[1] - b.bounds[0], [1, 1, 1])
    for name in ("cube_binary_header_with_RN_newline.ply", "cube_uv.ply", "float-color.ply"):
        _same_triangles(geovox.load_mesh(corpus("assimp", name)),
                        trimesh_reading(corpus("assimp", name)))


def test_ascii_rows_with_words_past_their_end():
    # trimesh's fuze_ascii.ply: its face rows carry ten numbers more than the
    # header names; PLY's rows are lines, so they are not read.
    mesh = geovox.load_mesh(corpus("trimesh_models", "fuze_ascii.ply"))
    _same_triangles(mesh, trimesh_reading(corpus("trimesh_models", "fuze_ascii.ply")))
    assert mesh.corner_uv is not None and mesh.vertex_colors is not None


def test_polygons_of_several_sizes_fan_as_trimesh_cuts_them(tmp_path):
    ang = 2 * np.pi * np.arange(6) / 6
    ring = np.c_[1 + np.cos(ang), 1 + np.sin(ang)]
    v = np.r_[np.c_[ring, np.zeros(6)], np.c_[ring, np.full(6, 2.0)]]
    polys = [list(range(5, -1, -1)), list(range(6, 12))]
    polys += [[i, (i + 1) % 6, (i + 1) % 6 + 6, i + 6] for i in range(6)]
    lines = ["ply", "format ascii 1.0", f"element vertex {len(v)}", "property float x",
             "property float y", "property float z", f"element face {len(polys)}",
             "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(map(str, p)) for p in v] + [" ".join(map(str, [len(q)] + q)) for q in polys]
    path = tmp_path / "prism.ply"
    path.write_text("\n".join(lines) + "\n")
    mesh = geovox.load_mesh(str(path))
    assert len(mesh.faces) == 2 * 4 + 6 * 2
    want = geovox.voxelize(trimesh_reading(path), resolution=12).occupancy
    np.testing.assert_array_equal(geovox.voxelize(mesh, resolution=12).occupancy, want)


def test_other_elements_and_properties_are_skipped(tmp_path, sphere):
    v, f = sphere
    head = ["ply", "format binary_little_endian 1.0", "element camera 2",
            "property list uchar float k", "property int id",
            f"element vertex {len(v)}", "property uchar flag", "property float x",
            "property double nx", "property float y", "property float z",
            f"element face {len(f)}", "property int id", "property list uint short vertex_index",
            "end_header"]
    cam = np.zeros(2, [("n", "u1"), ("k", "<f4", (2,)), ("id", "<i4")])
    cam["n"] = 2
    vd = np.zeros(len(v), [("flag", "u1"), ("x", "<f4"), ("nx", "<f8"), ("y", "<f4"),
                           ("z", "<f4")])
    vd["x"], vd["y"], vd["z"] = v.T
    fd = np.zeros(len(f), [("id", "<i4"), ("n", "<u4"), ("i", "<i2", (3,))])
    fd["n"], fd["i"] = 3, f
    path = tmp_path / "extra.ply"
    path.write_bytes(("\n".join(head) + "\n").encode() + cam.tobytes() + vd.tobytes()
                     + fd.tobytes())
    mesh = geovox.load_mesh(str(path))
    np.testing.assert_array_equal(mesh.vertices, vd[["x", "y", "z"]].tolist())
    np.testing.assert_array_equal(mesh.faces, f)


def test_sizes_that_do_not_add_up_are_one_line(tmp_path, sphere):
    path = tmp_path / "s.ply"
    _write(path, *sphere)
    data = path.read_bytes()
    path.write_bytes(data[:-7])
    with pytest.raises(MeshError, match=r"announces 642 vertex, 1,280 face, but .*cut short"):
        geovox.load_mesh(str(path))
    path.write_bytes(data.replace(b"element face 1280", b"element face 99999999"))
    with pytest.raises(MeshError, match=r"99,999,999 face, but .*cut short"):
        geovox.load_mesh(str(path))
    text = tmp_path / "a.ply"
    text.write_bytes(trimesh.Trimesh(*sphere, process=False).export(file_type="ply",
                                                                    encoding="ascii"))
    text.write_bytes(text.read_bytes().replace(b"element vertex 642", b"element vertex 10000"))
    with pytest.raises(MeshError, match=r"10,000 vertex, 1,280 face, but .*cut short"):
        geovox.load_mesh(str(text))


def test_indices_out_of_range_and_point_clouds(tmp_path, sphere):
    v, f = sphere
    with pytest.raises(MeshError, match="faces index vertices that do not exist"):
        geovox.load_mesh(_write(tmp_path / "r.ply", v, np.r_[f, [[0, 1, len(v)]]]))
    with pytest.raises(MeshError, match=r"has no faces, only a point cloud \(642 points\)"):
        geovox.load_mesh(_write(tmp_path / "p.ply", v, f[:0]))


def test_every_mutation_is_read_or_refused_in_one_line(tmp_path):
    ico = trimesh.creation.icosahedron()
    v, f = np.asarray(ico.vertices), np.asarray(ico.faces)
    binary = _write(tmp_path / "b.ply", v, f)
    ascii_path = tmp_path / "a.ply"
    ascii_path.write_bytes(trimesh.Trimesh(v, f, process=False).export(file_type="ply",
                                                                       encoding="ascii"))
    tried = 0
    for source in (binary, str(ascii_path)):
        with open(source, "rb") as fh:
            data = fh.read()
        at = data.index(b"end_header")
        variants = [data[:k] for k in range(0, len(data), max(1, len(data) // 60))]
        for word in (b"12", b"20", b"float", b"uchar", b"int", b"vertex_indices", b"face",
                     b"ascii", b"binary_little_endian", b"1.0"):
            for bad in (b"-1", b"x", b"99999999999", b"0", b"list", b"double", b""):
                variants.append(data[:at].replace(word, bad, 1) + data[at:])
        for k, variant in enumerate(variants):
            path = tmp_path / "m.ply"
            path.write_bytes(variant)
            tried += 1
            try:
                geovox.load_mesh(str(path))
            except GeovoxError as exc:
                assert "\n" not in str(exc), (k, str(exc))
            except Exception as exc:
                raise AssertionError(f"variant {k}: {exc!r}") from exc
    assert tried > 200
