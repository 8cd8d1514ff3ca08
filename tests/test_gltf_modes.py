"""glTF triangle strips (mode 5) and fans (mode 6), triangulated by geovox (geovox.io.gltf).

Winding is the glTF specification's (3.7.2.1): a closed shape built of fans
or strips must come out outward-facing, i.e. voxelise with parity as a
closed, consistently wound mesh with positive volume. Real files: the glTF
Asset Generator's Mesh_PrimitiveMode set (MIT), from assimp's test models
(tests/data/assimp, licence in tests/data/LICENSES/glTF-Asset-Generator.MIT.txt).
"""

from __future__ import annotations

import base64
import json
import os

import numpy as np
import pytest
import trimesh

import geovox
from geovox.cli import main
from geovox.errors import MeshError
from geovox.io.gltf import fan_faces, strip_faces

from conftest import corpus


def _signed_volume(vertices, faces):
    v = np.asarray(vertices, float)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


# ----------------------------------------------------------------------------- the rules


def test_strip_winding_is_the_specifications():
    # p_i = (v_i, v_{i+1+i%2}, v_{i+2-i%2}): every other triangle swaps its last two.
    assert strip_faces([10, 11, 12, 13, 14]).tolist() == [[10, 11, 12], [11, 13, 12],
                                                          [12, 13, 14]]


def test_fan_winding_is_the_specifications():
    # p_i = (v_{i+1}, v_{i+2}, v_0)
    assert fan_faces([7, 1, 2, 3]).tolist() == [[1, 2, 7], [2, 3, 7]]


def test_degenerate_triangles_are_dropped_and_short_lists_give_none():
    # Stitched strips repeat a vertex; those triangles draw nothing.
    # (0 1 2), (1 2 2), (2 2 3), (2 4 3): the middle two draw nothing.
    assert strip_faces([0, 1, 2, 2, 3, 4]).tolist() == [[0, 1, 2], [2, 4, 3]]
    assert strip_faces([0, 1]).shape == (0, 3) and fan_faces([5]).shape == (0, 3)


def test_strip_faces_share_one_orientation():
    # Consecutive strip triangles share an edge, which they must run in
    # opposite directions (consistent winding).
    tri = strip_faces(np.arange(12))
    for a, b in zip(tri[:-1], tri[1:]):
        ea = {(a[k], a[(k + 1) % 3]) for k in range(3)}
        eb = {(b[k], b[(k + 1) % 3]) for k in range(3)}
        shared = {(j, i) for i, j in ea} & eb
        assert len(shared) == 1


# ----------------------------------------------------------------------------- glTF files


def _octahedron():
    """Six vertices; top fan 0 -> ring, bottom fan 5 -> ring reversed: closed, outward."""
    v = np.array([[0, 0, 1], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], float)
    top = [0, 1, 2, 3, 4, 1]       # fan around +z, counter-clockwise seen from above
    bottom = [5, 1, 4, 3, 2, 1]    # fan around -z, counter-clockwise seen from below
    return v, top, bottom


def _tetrahedron_strip():
    """A closed tetrahedron as one strip of four triangles (0 1 2 3 0 1)."""
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    return v, [0, 2, 1, 3, 0, 2]


def _write(path, vertices, primitives, index_type=5125, glb=False):
    """A glTF (or GLB) with one mesh of the given ``(mode, indices or None)`` primitives."""
    dtype = {5121: "<u1", 5123: "<u2", 5125: "<u4"}[index_type]
    pos = np.asarray(vertices, "<f4")
    blob = bytearray(pos.tobytes())
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes}]
    accessors = [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                  "min": pos.min(0).tolist(), "max": pos.max(0).tolist()}]
    prims = []
    for mode, index in primitives:
        p = {"attributes": {"POSITION": 0}, "mode": mode}
        if index is not None:
            blob += b"\0" * (-len(blob) % 4)
            data = np.asarray(index, dtype).tobytes()
            views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
            accessors.append({"bufferView": len(views) - 1, "componentType": index_type,
                              "count": len(index), "type": "SCALAR"})
            blob += data
            p["indices"] = len(accessors) - 1
        prims.append(p)
    blob += b"\0" * (-len(blob) % 4)
    header = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
              "nodes": [{"mesh": 0}], "meshes": [{"primitives": prims}],
              "bufferViews": views, "accessors": accessors,
              "buffers": [{"byteLength": len(blob)}]}
    if glb:
        text = json.dumps(header).encode()
        text += b" " * (-len(text) % 4)
        body = (len(text).to_bytes(4, "little") + b"JSON" + text
                + len(blob).to_bytes(4, "little") + b"BIN\0" + bytes(blob))
        data = b"glTF" + (2).to_bytes(4, "little") + (12 + len(body)).to_bytes(4, "little") + body
        path.write_bytes(data)
    else:
        header["buffers"][0]["uri"] = ("data:application/octet-stream;base64,"
                                       + base64.b64encode(bytes(blob)).decode())
        path.write_text(json.dumps(header))
    return str(path)


@pytest.mark.parametrize("glb", [False, True])
@pytest.mark.parametrize("index_type", [5121, 5123, 5125])
def test_a_closed_shape_of_fans_is_inside_correct(tmp_path, glb, index_type):
    v, top, bottom = _octahedron()
    path = _write(tmp_path / ("octa.glb" if glb else "octa.gltf"), v,
                  [(6, top), (6, bottom)], index_type, glb)
    mesh = geovox.load_mesh(path)
    assert len(mesh.faces) == 8
    assert _signed_volume(mesh.vertices, mesh.faces) == pytest.approx(4 / 3)  # outward
    vol = geovox.voxelize(path, resolution=16, backend="numpy")
    assert vol.inside == "parity"  # closed and consistently wound, as built
    assert vol.inside_count == geovox.voxelize(
        trimesh.Trimesh(v, [[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 1], [5, 2, 1], [5, 3, 2],
                            [5, 4, 3], [5, 1, 4]]), resolution=16, backend="numpy").inside_count


@pytest.mark.parametrize("glb", [False, True])
def test_a_closed_strip_is_inside_correct(tmp_path, glb):
    v, strip = _tetrahedron_strip()
    path = _write(tmp_path / ("tet.glb" if glb else "tet.gltf"), v, [(5, strip)], glb=glb)
    mesh = geovox.load_mesh(path)
    assert len(mesh.faces) == 4
    assert _signed_volume(mesh.vertices, mesh.faces) == pytest.approx(1 / 6)
    assert geovox.voxelize(path, resolution=8, backend="numpy").inside == "parity"


def test_a_fan_without_indices_draws_its_vertices_in_order(tmp_path):
    # Vertices listed in fan order: hub first, then the ring.
    v, top, _ = _octahedron()
    path = _write(tmp_path / "fan.gltf", v[top], [(6, None)])
    mesh = geovox.load_mesh(path)
    assert len(mesh.faces) == 4
    normals = np.cross(*np.swapaxes(np.diff(mesh.vertices[mesh.faces], axis=1), 0, 1))
    assert np.all(normals[:, 2] > 0)  # every triangle faces up, away from the solid below


def test_fan_with_unreadable_indices_is_still_refused(tmp_path):
    # An index accessor past its buffer: the file is damaged, and geovox says so
    # rather than voxelise half the model.
    v, top, _ = _octahedron()
    path = tmp_path / "bad.gltf"
    _write(path, v, [(4, [0, 1, 2]), (6, top)])
    header = json.loads(path.read_text())
    header["accessors"][2]["count"] = 10_000
    path.write_text(json.dumps(header))
    with pytest.raises(MeshError, match=r"bad\.gltf: cannot be read as glTF.*reaches byte .*"
                                        r"the file is damaged"):
        geovox.load_mesh(str(path))


def test_triangles_strips_and_fans_in_one_mesh(tmp_path):
    v, _, bottom = _octahedron()
    path = _write(tmp_path / "mixed.gltf", v, [(4, [0, 1, 2, 0, 2, 3, 0, 3, 4, 0, 4, 1]),
                                               (6, bottom)])
    vol = geovox.voxelize(path, resolution=16, backend="numpy")
    assert vol.inside == "parity"


# ----------------------------------------------------------------------------- real files


@pytest.mark.parametrize("name", ["Mesh_PrimitiveMode_05.gltf", "Mesh_PrimitiveMode_12.gltf"])
def test_asset_generator_fans_convert(name, tmp_path, capsys):
    # 05: a fan without indices; 12: a fan with indices [0, 3, 2, 1]. Both a
    # unit square in z = 0 facing +z (the camera), as the triangle list (06) is.
    path = corpus("assimp", name)
    mesh = geovox.load_mesh(path)
    assert len(mesh.faces) == 2
    tri = mesh.vertices[mesh.faces]
    assert np.allclose(tri[..., 2], 0)
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(normal[:, 2] > 0)
    area = 0.5 * np.linalg.norm(normal, axis=1).sum()
    assert area == pytest.approx(1.0)
    assert main(["convert", path, "-o", str(tmp_path / "v.raw"), "-r", "8"]) == 0
    assert "skipping primitive" not in capsys.readouterr().err


@pytest.mark.parametrize("name,what", [("Mesh_PrimitiveMode_00.gltf", "a point cloud"),
                                       ("Mesh_PrimitiveMode_01.gltf", "lines")])
def test_points_and_lines_keep_their_one_line_refusal(name, what, tmp_path, capsys):
    status = main(["convert", corpus("assimp", name), "-o", str(tmp_path / "v.raw"), "-r", "8"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1, err
    assert f"has no faces, only {what}" in err


def test_strip_sample_matches_trimesh(tmp_path):
    # Mesh_PrimitiveMode_04 (tests/data/wild, trimesh's copy): trimesh's own
    # strip reading gives the same two triangles, the same way round.
    path = corpus("wild", "Mesh_PrimitiveMode_04.gltf")
    mine = geovox.load_mesh(path)
    theirs = trimesh.load(path, force="mesh", process=False)
    assert np.allclose(mine.vertices, theirs.vertices)

    def canonical(faces):
        return sorted(tuple(np.roll(f, -int(np.argmin(f)))) for f in np.asarray(faces).tolist())

    assert canonical(mine.faces) == canonical(theirs.faces)
    assert os.path.basename(path) == "Mesh_PrimitiveMode_04.gltf"
