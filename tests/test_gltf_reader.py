"""geovox's own glTF 2.0 / GLB reader (geovox.io.gltf): each feature on a file made here,
against trimesh's reading where trimesh reads it right, and against the truth (with how
trimesh is wrong) where it does not; and every malformed file in one line.

The files are boxes: a box's volume at a grid fitted to it is exact, so "the same volume"
is a strong check and "three boxes" or "a box three high" are analytic."""

from __future__ import annotations

import base64
import json
import struct
import sys
import warnings

import numpy as np
import pytest
import trimesh

import geovox
from geovox.cli import main
from geovox.errors import GeovoxError, MeshError
from geovox.io.adaptor import from_trimesh

R = 12


def _box(lo=(0.0, 0.0, 0.0), hi=(1.0, 1.0, 1.0)):
    b = trimesh.creation.box(bounds=[lo, hi])
    return np.asarray(b.vertices, np.float64), np.asarray(b.faces, np.int64)


class Builder:
    """A glTF of accessors over one buffer, written as GLB or as .gltf with a data URI."""

    def __init__(self):
        self.blob = bytearray()
        self.h = {"asset": {"version": "2.0"}, "buffers": [], "bufferViews": [],
                  "accessors": [], "meshes": [], "nodes": [], "scenes": [{"nodes": []}],
                  "scene": 0}

    def view(self, data: bytes, stride=None) -> int:
        self.blob += b"\0" * (-len(self.blob) % 4)
        v = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if stride:
            v["byteStride"] = stride
        self.blob += data
        self.h["bufferViews"].append(v)
        return len(self.h["bufferViews"]) - 1

    def accessor(self, array, component=None, view=None, offset=0, normalized=False,
                 kind=None, count=None) -> int:
        a = np.asarray(array)
        codes = {np.dtype("f4"): 5126, np.dtype("u1"): 5121, np.dtype("i1"): 5120,
                 np.dtype("u2"): 5123, np.dtype("i2"): 5122, np.dtype("u4"): 5125}
        width = 1 if a.ndim == 1 else a.shape[1]
        acc = {"componentType": component or codes[a.dtype], "count": count or len(a),
               "type": kind or {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}[width]}
        if view is None:
            view = self.view(a.astype(a.dtype.newbyteorder("<")).tobytes())
        if view is not False:
            acc["bufferView"], acc["byteOffset"] = view, offset
        if normalized:
            acc["normalized"] = True
        self.h["accessors"].append(acc)
        return len(self.h["accessors"]) - 1

    def mesh(self, attributes, indices=None, mode=None, material=None, node=None, **prim):
        p = {"attributes": attributes, **prim}
        if indices is not None:
            p["indices"] = indices
        if mode is not None:
            p["mode"] = mode
        if material is not None:
            p["material"] = material
        self.h["meshes"].append({"primitives": [p]})
        n = {"mesh": len(self.h["meshes"]) - 1, **(node or {})}
        self.h["nodes"].append(n)
        self.h["scenes"][0]["nodes"].append(len(self.h["nodes"]) - 1)
        return p

    def box(self, lo=(0, 0, 0), hi=(1, 1, 1), node=None):
        v, f = _box(lo, hi)
        return self.mesh({"POSITION": self.accessor(v.astype("f4"))},
                         self.accessor(f.reshape(-1).astype("u4")), node=node)

    def write(self, path, glb=None):
        path = str(path)
        glb = path.endswith(".glb") if glb is None else glb
        blob = bytes(self.blob) + b"\0" * (-len(self.blob) % 4)
        h = json.loads(json.dumps(self.h))
        if glb:
            h["buffers"].insert(0, {"byteLength": len(blob)})
            text = json.dumps(h).encode()
            text += b" " * (-len(text) % 4)
            data = (b"glTF" + struct.pack("<II", 2, 28 + len(text) + len(blob))
                    + struct.pack("<II", len(text), 0x4E4F534A) + text
                    + struct.pack("<II", len(blob), 0x004E4942) + blob)
        else:
            h["buffers"].insert(0, {"byteLength": len(blob), "uri": "data:application/"
                                    "octet-stream;base64," + base64.b64encode(blob).decode()})
            data = json.dumps(h).encode()
        with open(path, "wb") as f:
            f.write(data)
        return path


def volume(source, bounds=(0, 0, 0, 1, 1, 1), resolution=R):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return geovox.voxelize(source, resolution=resolution, bounds=bounds,
                               backend="numpy").occupancy


def trimesh_reading(path):
    """What geovox read through trimesh before (trimesh.load, then the adaptor)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return from_trimesh(trimesh.load(path, process=False), source=path)


def full(shape=(R, R, R)):
    return np.ones(shape, bool)


# ----------------------------------------------------------------------------- accessors


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_plain_box_is_trimeshs_box(tmp_path, ext):
    b = Builder()
    b.box()
    path = b.write(tmp_path / f"box{ext}")
    mesh = geovox.load_mesh(path)
    old = trimesh_reading(path)
    assert np.array_equal(mesh.triangles, old.triangles) and mesh.parts == old.parts
    assert volume(mesh).all()


def test_interleaved_attributes_with_a_byte_stride(tmp_path):
    v, f = _box()
    rows = np.zeros(len(v), [("p", "<f4", 3), ("n", "<f4", 3), ("uv", "<f4", 2)])
    rows["p"], rows["n"], rows["uv"] = v, -v, v[:, :2]
    b = Builder()
    view = b.view(rows.tobytes(), stride=rows.dtype.itemsize)
    b.mesh({"POSITION": b.accessor(v.astype("f4"), view=view, offset=0),
            "NORMAL": b.accessor(v.astype("f4"), view=view, offset=12),
            "TEXCOORD_0": b.accessor(v[:, :2].astype("f4"), view=view, offset=24)},
           b.accessor(f.reshape(-1).astype("u2")))
    path = b.write(tmp_path / "strided.glb")
    mesh = geovox.load_mesh(path)
    np.testing.assert_array_equal(mesh.triangles, trimesh_reading(path).triangles)
    np.testing.assert_array_equal(mesh.triangles, v[f])


def test_sparse_accessor_moves_the_vertices_it_names(tmp_path):
    # The base box is 1 high; the sparse part lifts its four top corners to z = 3.
    v, f = _box()
    top = np.flatnonzero(v[:, 2] == 1).astype("u2")
    lifted = v[top] + [0, 0, 2]
    b = Builder()
    b.box()
    pos = b.h["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
    b.h["accessors"][pos]["sparse"] = {
        "count": len(top),
        "indices": {"bufferView": b.view(top.tobytes()), "componentType": 5123},
        "values": {"bufferView": b.view(lifted.astype("<f4").tobytes())}}
    path = b.write(tmp_path / "sparse.glb")
    assert volume(path, (0, 0, 0, 1, 1, 3)).all()
    # trimesh reads the base values and leaves the sparse part out: a box 1 high
    assert trimesh_reading(path).bounds[1, 2] == 1.0


def test_sparse_accessor_without_a_buffer_view_starts_from_zeros(tmp_path):
    v, f = _box()
    b = Builder()
    pos = b.accessor(np.zeros((8, 3), "f4"), view=False)
    b.h["accessors"][pos]["sparse"] = {
        "count": 8, "indices": {"bufferView": b.view(np.arange(8, dtype="<u4").tobytes()),
                                "componentType": 5125},
        "values": {"bufferView": b.view(v.astype("<f4").tobytes())}}
    b.mesh({"POSITION": pos}, b.accessor(f.reshape(-1).astype("u4")))
    assert volume(b.write(tmp_path / "zeros.gltf")).all()


def test_quantized_positions_scaled_by_their_node(tmp_path):
    # KHR_mesh_quantization: int16 positions 0..100, the node scales them by 1/100.
    v, f = _box()
    b = Builder()
    b.mesh({"POSITION": b.accessor((v * 100).astype("i2"))},
           b.accessor(f.reshape(-1).astype("u1")), node={"scale": [0.01, 0.01, 0.01]})
    b.h["extensionsUsed"] = b.h["extensionsRequired"] = ["KHR_mesh_quantization"]
    path = b.write(tmp_path / "q.glb")
    mesh = geovox.load_mesh(path)
    assert volume(mesh).all()
    np.testing.assert_array_equal(mesh.triangles, trimesh_reading(path).triangles)


def test_normalized_positions_and_texture_coordinates(tmp_path):
    # Normalized int16 (32767 is 1.0) and uint8 texture coordinates (255 is 1.0).
    v, f = _box()
    b = Builder()
    b.mesh({"POSITION": b.accessor((v * 32767).astype("i2"), normalized=True),
            "TEXCOORD_0": b.accessor((v[:, :2] * 255).astype("u1"), normalized=True)},
           b.accessor(f.reshape(-1).astype("u2")))
    b.h["extensionsRequired"] = ["KHR_mesh_quantization"]
    path = b.write(tmp_path / "n.glb")
    mesh = geovox.load_mesh(path)
    assert volume(mesh).all()
    assert mesh.bounds.tolist() == [[0, 0, 0], [1, 1, 1]]
    # trimesh does not apply `normalized`: its box is 32767 wide
    assert trimesh_reading(path).bounds[1, 0] == 32767


def test_every_component_type_reads(tmp_path):
    v, f = _box()
    for dtype in ("u1", "i1", "u2", "i2", "u4", "f4"):
        b = Builder()
        if dtype == "u4":  # no uint32 positions in glTF: indices then
            b.mesh({"POSITION": b.accessor(v.astype("f4"))}, b.accessor(f.reshape(-1).astype(dtype)))
        else:
            b.mesh({"POSITION": b.accessor(v.astype(dtype))},
                   b.accessor(f.reshape(-1).astype("u1")))
        assert volume(b.write(tmp_path / f"{dtype}.glb")).all(), dtype


# ----------------------------------------------------------------------------- the scene


def test_node_hierarchy_matrix_and_trs(tmp_path):
    b = Builder()
    b.box()
    m = np.eye(4)
    m[:3, 3] = [2, 0, 0]
    b.h["nodes"][0]["children"] = [1]
    b.h["nodes"][0]["matrix"] = m.T.reshape(-1).tolist()
    # its child: a half-turn about z, then moved by (1, 1, 0): back on the parent's box
    b.h["meshes"].append(b.h["meshes"][0])
    b.h["nodes"].append({"mesh": 1, "translation": [1, 1, 0], "rotation": [0, 0, 1, 0]})
    path = b.write(tmp_path / "tree.glb")
    mesh = geovox.load_mesh(path)
    assert len(mesh.parts) == 2
    np.testing.assert_allclose(mesh.bounds, [[2, 0, 0], [3, 1, 1]], atol=1e-12)
    assert volume(mesh, (2, 0, 0, 3, 1, 1)).all()
    old = trimesh_reading(path)
    np.testing.assert_array_equal(np.sort(mesh.triangles.reshape(-1, 9), axis=0),
                                  np.sort(old.triangles.reshape(-1, 9), axis=0))
    assert mesh.parts == old.parts


def test_mirroring_node_reverses_the_faces(tmp_path):
    b = Builder()
    b.box(node={"scale": [-1, 1, 1]})
    mesh = geovox.load_mesh(b.write(tmp_path / "mirror.glb"))
    t = mesh.triangles
    normals = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    outward = np.einsum("ij,ij->i", normals, t.mean(axis=1) - [-0.5, 0.5, 0.5])
    assert np.all(outward > 0)  # still wound outward after the mirror


def test_gpu_instancing_places_every_instance(tmp_path):
    b = Builder()
    b.box()
    t = b.accessor(np.array([[0, 0, 0], [2, 0, 0], [4, 0, 0]], "f4"))
    b.h["nodes"][0]["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": t}}}
    b.h["extensionsUsed"] = b.h["extensionsRequired"] = ["EXT_mesh_gpu_instancing"]
    path = b.write(tmp_path / "inst.glb")
    mesh = geovox.load_mesh(path)
    assert len(mesh.faces) == 36 and mesh.bounds[1, 0] == 5
    occ = volume(path, (0, 0, 0, 5, 1, 1), resolution=(20))
    assert occ.sum() == 3 * occ.size // 5
    # trimesh places the mesh once
    assert len(trimesh_reading(path).faces) == 12


def test_a_cycle_in_the_node_graph_is_one_line(tmp_path, capsys):
    b = Builder()
    b.box()
    b.h["nodes"].append({"children": [0]})
    b.h["nodes"][0]["children"] = [1]
    path = b.write(tmp_path / "cycle.gltf")
    with pytest.raises(MeshError, match="its own ancestor.*damaged"):
        geovox.load_mesh(path)
    assert main(["info", path]) == 2
    assert capsys.readouterr().err.count("\n") == 1


def test_assimps_recursive_nodes_are_refused():
    from conftest import corpus

    with pytest.raises(MeshError, match="cycle"):
        geovox.load_mesh(corpus("assimp", "RecursiveNodes.gltf"))


# ----------------------------------------------------------------------------- instancing


ROWS = 36  # 36 x 36 spheres: past what the file-size rule allowed, a 60 kB file


def _forest(rows=ROWS):
    """A forest and its copies placed by hand: ``(Builder, [(vertices, faces)])``.

    A sphere stored once as a triangle soup (960 vertices, 320 faces) placed
    ``rows`` x ``rows`` times by one node's ``EXT_mesh_gpu_instancing``
    (translation, rotation, scale, all three), under a parent node that
    moves it; and a box that 40 nodes share. The copies are made here with
    trimesh's transformations from the values as the file stores them (float32)."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    soup = np.asarray(sphere.vertices)[np.asarray(sphere.faces).reshape(-1)].astype("f4")
    b = Builder()
    b.mesh({"POSITION": b.accessor(soup)})
    rng = np.random.default_rng(41)
    i, j = np.meshgrid(np.arange(rows), np.arange(rows), indexing="ij")
    t = np.stack([2.5 * i.ravel(), 2.5 * j.ravel(), np.zeros(rows * rows)], axis=1).astype("f4")
    q = rng.normal(size=(rows * rows, 4))
    q = (q / np.linalg.norm(q, axis=1)[:, None]).astype("f4")
    s = rng.uniform(0.5, 1.0, (rows * rows, 3)).astype("f4")
    b.h["nodes"][0]["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": {
        "TRANSLATION": b.accessor(t), "ROTATION": b.accessor(q), "SCALE": b.accessor(s)}}}
    b.h["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    b.h["nodes"].append({"children": [0], "translation": [0.3, 0.2, 1.1]})
    b.h["scenes"][0]["nodes"] = [1]
    parent = trimesh.transformations.translation_matrix([0.3, 0.2, 1.1])
    placed = []
    for k in range(rows * rows):
        m = (parent @ trimesh.transformations.translation_matrix(t[k].astype(float))
             @ trimesh.transformations.quaternion_matrix(q[k, [3, 0, 1, 2]].astype(float))
             @ np.diag(np.append(s[k].astype(float), 1.0)))
        placed.append((trimesh.transform_points(soup.astype(float), m),
                       np.arange(len(soup)).reshape(-1, 3)))
    v, f = _box((-0.4, -0.4, -0.4), (0.4, 0.4, 0.4))
    b.h["meshes"].append({"primitives": [{
        "attributes": {"POSITION": b.accessor(v.astype("f4"))},
        "indices": b.accessor(f.reshape(-1).astype("u4"))}]})
    for k in range(40):
        b.h["nodes"].append({"mesh": 1, "translation": [2.2 * k, -2.0, 1.1]})
        b.h["scenes"][0]["nodes"].append(len(b.h["nodes"]) - 1)
        placed.append((v + [2.2 * k, -2.0, 1.1], f))
    return b, placed


def test_an_instanced_forest_converts_as_its_copies_flattened_by_hand(tmp_path):
    from geovox.io import limits

    b, placed = _forest()
    path = b.write(tmp_path / "forest.glb")
    size = __import__("os").path.getsize(path)
    mesh = geovox.load_mesh(path)
    assert len(mesh.faces) == sum(len(f) for _, f in placed) == ROWS * ROWS * 320 + 40 * 12
    assert len(mesh.parts) == len(placed)
    # the rule before issue 41 counted 48 bytes a vertex and 24 a face against the file's
    # limit (100 times its size, at least 64 MiB), and refused this 60 kB file
    assert 48 * len(mesh.vertices) + 24 * len(mesh.faces) > limits.input_limit(size)
    flat = trimesh.util.concatenate([trimesh.Trimesh(v, f, process=False) for v, f in placed])
    flat.export(tmp_path / "flat.ply")
    by_hand = geovox.load_mesh(str(tmp_path / "flat.ply"))
    np.testing.assert_allclose(np.sort(mesh.triangles.reshape(-1, 9), axis=0),
                               np.sort(by_hand.triangles.reshape(-1, 9), axis=0), atol=1e-9)
    bounds = tuple(mesh.bounds[0] - 0.1) + tuple(mesh.bounds[1] + 0.1)
    occ = volume(path, bounds, resolution=64)
    assert occ.sum() > 0.05 * occ.size
    np.testing.assert_array_equal(occ, volume(str(tmp_path / "flat.ply"), bounds, resolution=64))


def test_what_a_scene_of_copies_takes_is_what_is_counted(tmp_path):
    # The scene rule counts PER_VERTEX bytes a vertex, PER_FACE a face and PER_COPY a copy:
    # the peak while reading stays within that and the decoded buffers. The reader before
    # issue 41 took about three times as much.
    import tracemalloc

    from geovox.io.gltf_scene import PER_COPY, PER_FACE, PER_VERTEX

    b, placed = _forest(rows=20)
    path = b.write(tmp_path / "forest.glb")
    tracemalloc.start()
    try:
        mesh = geovox.load_mesh(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    counted = PER_VERTEX * len(mesh.vertices) + PER_FACE * len(mesh.faces) + PER_COPY * len(placed)
    assert peak <= counted + 10 * __import__("os").path.getsize(path)


def test_a_scene_of_copies_is_held_to_memory_and_max_input_size(tmp_path, monkeypatch):
    from geovox.io import limits

    path = _forest()[0].write(tmp_path / "forest.glb")
    with pytest.raises(MeshError, match=r"forest\.glb: its scene's 1,336 mesh copies would take "
                                        r"5\d\.\d MB, more than 10\.0 MB \(max_input_size"):
        geovox.load_mesh(path, max_input_size=10**7)
    monkeypatch.setattr(limits, "available_memory", lambda: 80 * 10**6)
    with pytest.raises(MeshError, match=r"more than 40\.0 MB \(50% of the memory available now; "
                                        r"--max-input-size sets it\); not read"):
        geovox.load_mesh(path)


def test_a_billion_copies_are_refused_before_they_are_placed(tmp_path, capsys):
    import time

    b = Builder()
    b.box()
    b.h["nodes"][0]["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": {
        "TRANSLATION": b.accessor(np.zeros((1, 3), "f4"), view=False, count=10**9)}}}
    billion = b.write(tmp_path / "billion.glb")
    # and nodes that share a child (glTF allows one parent; geovox reads it as two
    # paths): 2**30 paths from the root to one box, in a file of 31 nodes
    b = Builder()
    b.box()
    b.h["nodes"] = [{"children": [k + 1, k + 1]} for k in range(30)] + [{"mesh": 0}]
    b.h["scenes"][0]["nodes"] = [0]
    shared = b.write(tmp_path / "shared.gltf")
    for path, copies in ((billion, "1,000,000,000"), (shared, "1,073,741,824")):
        start = time.perf_counter()
        with pytest.raises(MeshError, match=rf"its scene's {copies} mesh copies would take "
                                            rf".* more than .*; not read"):
            geovox.load_mesh(path)
        assert time.perf_counter() - start < 5.0  # counted, not walked (a walk takes hours)
        assert main(["convert", path, "-o", str(tmp_path / "v.raw")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err and copies in err
        assert not (tmp_path / "v.raw").exists()


# ----------------------------------------------------------------------------- compression


def _draco_glb(path):
    pytest.importorskip("DracoPy")
    sphere = trimesh.creation.icosphere(subdivisions=2)
    path.write_bytes(trimesh.exchange.gltf.export_glb(trimesh.Scene(sphere),
                                                      extension_draco=True))
    return str(path)


def test_draco_is_decoded_as_trimesh_decodes_it(tmp_path):
    path = _draco_glb(tmp_path / "d.glb")
    mesh = geovox.load_mesh(path)
    np.testing.assert_array_equal(mesh.triangles, trimesh_reading(path).triangles)


def draco_with_features(tmp_path):
    """A Draco-compressed sphere whose primitive has an EXT_mesh_features set over a
    ``_FEATURE_ID_0`` accessor outside the Draco stream and without a buffer view (zeros)."""
    path = _draco_glb(tmp_path / "f.glb")
    with open(path, "rb") as f:
        data = f.read()
    n = struct.unpack_from("<I", data, 12)[0]
    h = json.loads(data[20:20 + n])
    prim = h["meshes"][0]["primitives"][0]
    h["accessors"].append({"componentType": 5126, "count": h["accessors"][
        prim["attributes"]["POSITION"]]["count"], "type": "SCALAR"})
    prim["attributes"]["_FEATURE_ID_0"] = len(h["accessors"]) - 1
    prim.setdefault("extensions", {})["EXT_mesh_features"] = {
        "featureIds": [{"featureCount": 1, "attribute": 0}]}
    h["extensionsUsed"] = h.get("extensionsUsed", []) + ["EXT_mesh_features"]
    text = json.dumps(h).encode()
    text += b" " * (-len(text) % 4)
    tail = data[20 + n:]
    out = tmp_path / "features.glb"
    out.write_bytes(b"glTF" + struct.pack("<II", 2, 20 + len(text) + len(tail))
                    + struct.pack("<II", len(text), 0x4E4F534A) + text + tail)
    return str(out)


def test_draco_with_mesh_features_converts(tmp_path):
    # EXT_mesh_features' feature ids are not decoded by trimesh, which then
    # warned that values were placeholder zeros; geovox reads the geometry.
    mesh = geovox.load_mesh(draco_with_features(tmp_path))
    assert len(mesh.faces) == 320


def _meshopt_box(tmp_path, required=True, fallback=True):
    meshopt = pytest.importorskip("meshopt")
    v, f = _box()
    b = Builder()
    plain = b.accessor(v.astype("f4"))  # the fallback's data (when it has any)
    index = b.accessor(f.reshape(-1).astype("u4"))
    packed_v = meshopt.encode_gltf_buffer(np.ascontiguousarray(
        np.c_[v, np.zeros(8)].astype("f4")), "ATTRIBUTES")
    packed_i = meshopt.encode_gltf_buffer(f.reshape(-1).astype("u4"), "TRIANGLES")
    b.blob += b"\0" * (-len(b.blob) % 4)
    at = len(b.blob)
    b.blob += packed_v + b"\0" * (-len(packed_v) % 4)
    at_i = len(b.blob)
    b.blob += packed_i
    # the views' own buffer (1): the fallback, which holds no data where `fallback` is set
    for k, (acc, start, size, count, stride, mode) in enumerate(
            [(plain, at, len(packed_v), 8, 16, "ATTRIBUTES"),
             (index, at_i, len(packed_i), 36, 4, "TRIANGLES")]):
        view = b.h["accessors"][acc]["bufferView"]
        bv = b.h["bufferViews"][view]
        bv["buffer"] = 1 if fallback else 0
        if mode == "ATTRIBUTES":
            bv["byteStride"] = 16
            bv["byteLength"] = 8 * 16
            if not fallback:
                # the plain copy, laid out as the compressed one decodes (stride 16)
                rows = np.c_[v, np.zeros(8)].astype("<f4").tobytes()
                bv["byteOffset"] = len(b.blob) + (-len(b.blob) % 4)
                b.blob += b"\0" * (-len(b.blob) % 4) + rows
        bv["extensions"] = {"EXT_meshopt_compression": {
            "buffer": 0, "byteOffset": start, "byteLength": size, "byteStride": stride,
            "count": count, "mode": mode}}
    b.h["buffers"].append({"byteLength": 1 << 10, "extensions": {
        "EXT_meshopt_compression": {"fallback": True}}} if fallback else None)
    if not fallback:
        b.h["buffers"].pop()
        for bv in b.h["bufferViews"]:
            bv["buffer"] = 0
    b.mesh({"POSITION": plain}, index)
    b.h["extensionsUsed"] = ["EXT_meshopt_compression"]
    if required:
        b.h["extensionsRequired"] = ["EXT_meshopt_compression"]
    return b


def test_meshopt_compressed_box(tmp_path):
    b = _meshopt_box(tmp_path)
    path = b.write(tmp_path / "mo.glb")
    mesh = geovox.load_mesh(path)
    assert volume(mesh).all()
    v, f = _box()
    # meshopt's index codec may start a triangle at another corner: the same triangles
    key = np.sort(np.sort(mesh.triangles.reshape(-1, 3, 3), axis=1).reshape(-1, 9), axis=0)
    assert np.array_equal(key, np.sort(np.sort(v[f], axis=1).reshape(-1, 9), axis=0))
    # trimesh reads no meshopt: it stops on the fallback buffer that has no uri
    with pytest.raises(Exception):
        trimesh_reading(path)


def test_meshopt_khr_name_reads_too(tmp_path):
    b = _meshopt_box(tmp_path)
    text = json.dumps(b.h).replace("EXT_meshopt_compression", "KHR_meshopt_compression")
    b.h = json.loads(text)
    assert volume(b.write(tmp_path / "khr.glb")).all()


def test_meshopt_without_the_package(tmp_path, monkeypatch):
    path = _meshopt_box(tmp_path).write(tmp_path / "mo.glb")
    optional = _meshopt_box(tmp_path, required=False, fallback=False).write(tmp_path / "fb.glb")
    monkeypatch.setitem(sys.modules, "meshopt", None)
    with pytest.raises(MeshError, match=r"meshopt-compressed.*pip install meshopt"):
        geovox.load_mesh(path)
    # an optional compression with real fallback data reads the fallback
    assert volume(optional).all()


# ----------------------------------------------------------------------------- extensions


def test_required_extension_geovox_does_not_read_is_named(tmp_path, capsys):
    b = Builder()
    b.box()
    b.h["extensionsRequired"] = b.h["extensionsUsed"] = ["EXT_made_up_geometry"]
    path = b.write(tmp_path / "req.glb")
    assert main(["info", path]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "requires the glTF extension EXT_made_up_geometry" in err
    assert "damaged" not in err


def test_required_material_extension_still_converts(tmp_path):
    b = Builder()
    b.box()
    b.h["extensionsRequired"] = ["KHR_materials_unlit", "KHR_texture_basisu"]
    assert volume(b.write(tmp_path / "unlit.glb")).all()


# ----------------------------------------------------------------------------- bad files


def _valid(tmp_path):
    b = Builder()
    b.box()
    b.box((2, 0, 0), (3, 1, 1))
    return b


MUTATIONS = [-1, 0, 1, 3, 7, 2**31, 2**40, 2**62, 1.5, "x", None, [], {}, True, 1e300]


def _fields(h):
    for key in ("accessors", "bufferViews", "buffers", "meshes", "nodes", "scenes"):
        for i, item in enumerate(h[key]):
            for field in item:
                yield key, i, field
    for i, m in enumerate(h["meshes"]):
        for field in m["primitives"][0]:
            yield "prim", i, field


@pytest.mark.parametrize("ext", [".glb", ".gltf"])
def test_every_mutated_field_is_read_or_refused_in_one_line(tmp_path, ext):
    b = _valid(tmp_path)
    tried = 0
    for key, i, field in list(_fields(b.h)):
        for value in MUTATIONS:
            h = json.loads(json.dumps(b.h))
            target = h["meshes"][i]["primitives"][0] if key == "prim" else h[key][i]
            target[field] = value
            bad = Builder()
            bad.h, bad.blob = h, b.blob
            path = bad.write(tmp_path / f"m{ext}")
            tried += 1
            try:
                geovox.load_mesh(path)
            except GeovoxError as exc:
                assert "\n" not in str(exc) and str(exc).startswith(path), (key, field, value)
            except Exception as exc:  # anything else is a bug
                raise AssertionError(f"{key}[{i}].{field} = {value!r}: {exc!r}") from exc
    assert tried > 300


def test_truncated_glb_is_refused_in_one_line(tmp_path):
    with open(_valid(tmp_path).write(tmp_path / "ok.glb"), "rb") as f:
        data = f.read()
    for cut in list(range(0, 64, 3)) + list(range(64, len(data), 17)):
        path = tmp_path / "cut.glb"
        path.write_bytes(data[:cut])
        try:
            geovox.load_mesh(str(path))
        except GeovoxError as exc:
            assert "\n" not in str(exc), cut
            if cut >= 20:
                assert "cut short" in str(exc) or "damaged" in str(exc), (cut, str(exc))


def test_byte_lengths_that_lie(tmp_path):
    b = _valid(tmp_path)
    b.h["bufferViews"][0]["byteLength"] = 10**6
    with pytest.raises(MeshError, match="reaches byte 1,000,000 of buffer 0.*damaged"):
        geovox.load_mesh(b.write(tmp_path / "lie.glb"))
    b = _valid(tmp_path)
    b.h["accessors"][0]["count"] = 10**6
    with pytest.raises(MeshError, match="accessor 0.*reaches byte.*damaged"):
        geovox.load_mesh(b.write(tmp_path / "lie2.glb"))


def test_absurd_counts_are_refused_before_allocating(tmp_path):
    # an accessor without a buffer view is zeros: 2**40 of them is 13 TB
    b = _valid(tmp_path)
    pos = b.h["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
    del b.h["accessors"][pos]["bufferView"]
    b.h["accessors"][pos]["count"] = 2**40
    with pytest.raises(MeshError, match="would take .* more than .*not read"):
        geovox.load_mesh(b.write(tmp_path / "huge.glb"))
    b = _valid(tmp_path)
    b.h["nodes"][0]["extensions"] = {"EXT_mesh_gpu_instancing": {"attributes": {
        "TRANSLATION": b.accessor(np.zeros((1, 3), "f4"), view=False, count=2**33)}}}
    with pytest.raises(MeshError, match="would take .* more than"):
        geovox.load_mesh(b.write(tmp_path / "instances.glb"))


def test_max_input_size_bounds_what_a_file_decodes_to(tmp_path):
    path = _valid(tmp_path).write(tmp_path / "ok.glb")
    assert len(geovox.load_mesh(path).faces) == 24
    with pytest.raises(MeshError, match="max_input_size"):
        geovox.load_mesh(path, max_input_size=100)


def test_buffer_shorter_than_it_says(tmp_path):
    b = _valid(tmp_path)
    b.blob = b.blob[:40]
    path = b.write(tmp_path / "short.gltf")
    with open(path) as f:
        h = json.load(f)
    h["buffers"][0]["byteLength"] = 4000
    with open(path, "w") as f:
        json.dump(h, f)
    with pytest.raises(MeshError, match="buffer 0 says it holds 4,000 bytes, but 40 are there"):
        geovox.load_mesh(path)


def test_tinygltfs_bounds_checking_files():
    from conftest import corpus

    for name in ("integer-out-of-bounds", "invalid-buffer-index", "invalid-buffer-view-index",
                 "invalid-primitive-indices"):
        with pytest.raises(MeshError) as info:
            geovox.load_mesh(corpus("tinygltf", name + ".gltf"))
        assert "\n" not in str(info.value)
