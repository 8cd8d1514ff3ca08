"""geovox.io.ply: plain binary triangle PLY read without trimesh, into the Mesh trimesh's path makes."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import geovox
from geovox.errors import MeshError
from geovox.io.load import _trimesh_load
from geovox.io.ply import read_plain_ply

from conftest import corpus


def _same(a, b):
    assert a.source == b.source
    for f in ("vertices", "faces", "face_material"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and np.array_equal(x, y), f
    assert a.materials == b.materials and a.problems == b.problems
    assert a.corner_uv is None and b.corner_uv is None
    assert a.vertex_colors is None and b.vertex_colors is None


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


def test_trimesh_export_reads_as_trimesh_reads_it(tmp_path, sphere):
    path = str(tmp_path / "s.ply")
    trimesh.Trimesh(*sphere, process=False).export(path)
    fast = read_plain_ply(path)
    assert fast is not None
    _same(fast, _trimesh_load(path))
    _same(geovox.load_mesh(path), fast)


@pytest.mark.parametrize("layout", [
    dict(order=">"),
    dict(vtypes=("double", "f8")),
    dict(names="zxy"),
    dict(count=("uint8", "u1"), index=("uint", "u4")),
    dict(count=("int", "i4"), index=("ushort", "u2")),
    dict(comments=()),
])
def test_layouts_read_as_trimesh_reads_them(tmp_path, sphere, layout):
    v, f = sphere
    v = v + np.array([1e3, -2.0, 0.5])  # float32 rounding shows up in every layout
    path = _write(tmp_path / "s.ply", v, f, **layout)
    fast = read_plain_ply(path)
    assert fast is not None
    _same(fast, _trimesh_load(path))


def test_unused_vertices_are_kept_as_trimesh_keeps_them(tmp_path, sphere):
    v, f = sphere
    path = _write(tmp_path / "s.ply", np.r_[v, [[9.0, 9.0, 9.0]]], f)
    fast = read_plain_ply(path)
    assert fast is not None and len(fast.vertices) == len(v) + 1
    _same(fast, _trimesh_load(path))


def test_other_files_are_left_to_trimesh(tmp_path, sphere):
    v, f = sphere
    quads = np.c_[f[:, :3], f[:, 2]]
    cases = {
        "colours": corpus("fuze", "fuze.ply"),
        "polygons": _write(tmp_path / "quads.ply", v, quads),
        "trailing": _write(tmp_path / "trailing.ply", v, f, tail=b"\0" * 4),
        "out_of_range": _write(tmp_path / "range.ply", v, np.r_[f, [[0, 1, len(v)]]]),
        "nan": _write(tmp_path / "nan.ply", np.r_[v, [[np.nan, 0.0, 0.0]]], f),
    }
    ascii_path = tmp_path / "ascii.ply"
    ascii_path.write_bytes(trimesh.Trimesh(v, f, process=False).export(file_type="ply",
                                                                       encoding="ascii"))
    cases["ascii"] = str(ascii_path)
    normals = tmp_path / "normals.ply"
    normals.write_bytes(trimesh.Trimesh(v, f, vertex_normals=v, process=False).export(
        file_type="ply", include_attributes=True))
    cases["normals"] = str(normals)
    for name, path in cases.items():
        assert read_plain_ply(path) is None, name
    # and load_mesh still reads them through trimesh, or says why not
    assert len(geovox.load_mesh(cases["polygons"]).faces) == 2 * len(f)
    assert len(geovox.load_mesh(cases["ascii"]).faces) == len(f)
    with pytest.raises(MeshError):
        geovox.load_mesh(cases["out_of_range"])


def test_truncated_file_is_left_to_trimesh(tmp_path, sphere):
    path = tmp_path / "s.ply"
    _write(path, *sphere)
    path.write_bytes(path.read_bytes()[:-7])
    assert read_plain_ply(str(path)) is None


def test_voxels_are_the_trimesh_paths_voxels(tmp_path, sphere):
    path = _write(tmp_path / "s.ply", *sphere, order=">")
    a = geovox.voxelize(path, resolution=40).occupancy
    b = geovox.voxelize(_trimesh_load(path), resolution=40).occupancy
    assert a.any() and np.array_equal(a, b)
