"""Files a model refers to: one rule for OBJ, glTF, PLY and COLLADA (geovox.references).

The layout of every test: the model in ``tmp/model/obj/`` (or ``gltf/``),
its texture in ``tmp/model/textures/`` (a ``..`` reference), and a "secret"
file outside the model's folder in ``tmp/``. Under ``references="anywhere"``
(the default) ``../textures`` is read; under ``"folder"`` nothing outside
the model's own folder is read: the material falls back to its colour with
a warning naming the reference. URLs are never fetched.
"""

from __future__ import annotations

import base64
import json
import os
import warnings

import numpy as np
import pytest
import trimesh
from PIL import Image

import geovox
from geovox.cli import main
from geovox.errors import GeovoxWarning, MeshError, ParameterError
from geovox.io.references import locate

RED, BLUE = (255, 0, 0), (0, 0, 255)
# The material's own colour, which multiplies its texture: red stays red,
# blue becomes 0.6 blue, and the colour alone is pale yellow.
KD = (1.0, 1.0, 0.6)
OWN, DIM_BLUE = (255, 255, 153), (0, 0, 153)


def _png(path, rgb):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    Image.new("RGB", (4, 4), rgb).save(path)


def _obj(folder, mtllib="x.mtl", map_kd="../textures/red.png", mtl_folder=None):
    """A textured box in folder/box.obj with its MTL in mtl_folder (default: folder)."""
    os.makedirs(folder, exist_ok=True)
    box = trimesh.creation.box(extents=(1, 1, 1))
    lines = [f"mtllib {mtllib}"] + [f"v {x} {y} {z}" for x, y, z in box.vertices]
    lines += ["vt 0.5 0.5", "usemtl m"] + [f"f {a+1}/1 {b+1}/1 {c+1}/1" for a, b, c in box.faces]
    path = os.path.join(folder, "box.obj")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    mtl = os.path.join(mtl_folder or folder, os.path.basename(mtllib))
    os.makedirs(os.path.dirname(mtl), exist_ok=True)
    with open(mtl, "w") as f:
        f.write(f"newmtl m\nKd {KD[0]} {KD[1]} {KD[2]}\nmap_Kd {map_kd}\n")
    return path


def _gltf(folder, image_uri="../textures/red.png", buffer_uri="box.bin", embed=False):
    """A textured box in folder/box.gltf; its buffer is written to buffer_uri."""
    os.makedirs(folder, exist_ok=True)
    box = trimesh.creation.box(extents=(1, 1, 1))
    pos = box.vertices.astype("<f4")
    uv = np.full((len(pos), 2), 0.5, dtype="<f4")
    idx = box.faces.astype("<u4").reshape(-1)
    blob = pos.tobytes() + uv.tobytes() + idx.tobytes()
    if embed:
        buffer = {"byteLength": len(blob),
                  "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}
    else:
        with open(os.path.join(folder, buffer_uri), "wb") as f:
            f.write(blob)
        buffer = {"byteLength": len(blob), "uri": buffer_uri}
    n = len(pos)
    header = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "TEXCOORD_0": 1},
                                    "indices": 2, "material": 0}]}],
        "materials": [{"name": "m", "pbrMetallicRoughness": {
            "baseColorFactor": [*KD, 1.0], "baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}], "images": [{"uri": image_uri}],
        "buffers": [buffer],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": uv.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes + uv.nbytes,
                         "byteLength": idx.nbytes}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": n, "type": "VEC3",
             "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
            {"bufferView": 1, "componentType": 5126, "count": n, "type": "VEC2"},
            {"bufferView": 2, "componentType": 5125, "count": len(idx), "type": "SCALAR"}],
    }
    path = os.path.join(folder, "box.gltf")
    with open(path, "w") as f:
        json.dump(header, f)
    return path


def _colour(path, references, **kw):
    """The colours of the inside voxels (one colour), and the warnings said."""
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always", GeovoxWarning)
        vol = geovox.voxelize(path, resolution=4, backend="numpy", color=True,
                              references=references, **kw)
    colours = np.unique(vol.colors[vol.occupancy][:, :3], axis=0)
    assert len(colours) == 1, colours
    return tuple(int(c) for c in colours[0]), [str(w.message) for w in record]


@pytest.fixture
def layout(tmp_path):
    """model/textures/red.png (inside the model's folder tree) and secret.png (outside)."""
    _png(tmp_path / "model" / "textures" / "red.png", RED)
    _png(tmp_path / "secret.png", BLUE)
    return tmp_path


# ----------------------------------------------------------------------------- the rule


def test_locate_under_each_rule(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "m" / "a.png").write_bytes(b"x")
    (tmp_path / "b.png").write_bytes(b"x")
    folder = str(tmp_path / "m")
    assert locate("a.png", folder, "folder") == (os.path.join(folder, "a.png"), False)
    assert locate("../b.png", folder, "anywhere") == (os.path.join(folder, "../b.png"), False)
    assert locate("../b.png", folder, "folder") == (None, True)
    assert locate(str(tmp_path / "b.png"), folder, "folder") == (None, True)
    assert locate(str(tmp_path / "b.png"), folder, "anywhere")[0] == str(tmp_path / "b.png")
    # A name leaving the folder whose bare name is beside the model: that file is read.
    assert locate("../../elsewhere/a.png", folder, "folder") == (os.path.join(folder, "a.png"),
                                                                 True)
    # URLs are never fetched, under either rule.
    for rule in ("anywhere", "folder"):
        assert locate("https://example.com/x.png", folder, rule) == (None, True)
        assert locate("file:///etc/hostname", folder, rule) == (None, True)


def test_a_link_inside_the_folder_pointing_out_is_not_followed(tmp_path):
    (tmp_path / "m").mkdir()
    (tmp_path / "b.png").write_bytes(b"x")
    os.symlink(tmp_path / "b.png", tmp_path / "m" / "link.png")
    folder = str(tmp_path / "m")
    assert locate("link.png", folder, "folder") == (None, True)
    assert locate("link.png", folder, "anywhere")[0] == os.path.join(folder, "link.png")


def test_a_bad_rule_is_a_parameter_error(tmp_path):
    with pytest.raises(ParameterError, match=r"`references` must be 'anywhere' or 'folder', "
                                             r"got 'everywhere'"):
        geovox.voxelize(trimesh.creation.box(), resolution=4, references="everywhere")
    with pytest.raises(ParameterError, match="`references`"):
        geovox.convert_many([], str(tmp_path / "out"), references="nowhere")


# ----------------------------------------------------------------------------- OBJ


def test_obj_texture_beside_the_model_folder(layout):
    path = _obj(str(layout / "model" / "obj"))
    assert _colour(path, "anywhere")[0] == RED


def test_obj_texture_outside_the_folder_is_not_read_under_folder(layout):
    # ../textures is outside model/obj, the OBJ's own folder.
    path = _obj(str(layout / "model" / "obj"))
    colour, said = _colour(path, "folder")
    assert colour == OWN  # the material's Kd
    line = [s for s in said if "../textures/red.png" in s]
    assert len(line) == 1 and "is not read" in line[0] and "outside the model's folder" in line[0]
    assert "using its Kd colour" in line[0]


@pytest.mark.parametrize("name", ["ABS", "../../secret.png", "file:///SECRET"])
def test_obj_escapes_and_urls_fall_back_to_the_colour(layout, name):
    secret = str(layout / "secret.png")
    name = {"ABS": secret, "file:///SECRET": "file://" + secret}.get(name, name)
    path = _obj(str(layout / "model" / "obj"), map_kd=name)
    colour, said = _colour(path, "folder")
    assert colour == OWN, said
    assert any(repr(name) in s and "is not read" in s for s in said), said
    why = {"/": "it is an absolute path", "f": "it is a URL", ".": "it lies outside"}[name[0]]
    assert any(why in s for s in said), said
    if name.startswith("file:"):
        # never fetched, whatever the rule
        assert _colour(path, "anywhere")[0] == OWN
    else:
        assert _colour(path, "anywhere")[0] == DIM_BLUE


def test_obj_material_library_outside_the_folder(layout):
    lib = str(layout / "x.mtl")
    path = _obj(str(layout / "model"), mtllib="../x.mtl", map_kd="secret.png", mtl_folder=str(layout))
    assert _colour(path, "anywhere")[0] == DIM_BLUE
    with pytest.warns(GeovoxWarning) as record:
        vol = geovox.voxelize(path, resolution=4, backend="numpy", color=True,
                              references="folder")
    said = [str(w.message) for w in record]
    assert any("material file '../x.mtl'" in s and "is not read" in s for s in said), said
    assert not np.any(np.all(vol.colors[vol.occupancy][:, :3] == DIM_BLUE, axis=-1))
    assert os.path.exists(lib)


def test_obj_subfolder_material_naming_a_sibling_folder_stays_inside(layout):
    # model/box.obj -> mtl/x.mtl -> ../textures/red.png: all under model/.
    path = _obj(str(layout / "model"), mtllib="mtl/x.mtl", mtl_folder=str(layout / "model" / "mtl"))
    assert _colour(path, "folder")[0] == RED


def test_obj_windows_path_found_beside_the_model(layout):
    # An absolute path from another machine: its bare name beside the model
    # is inside the folder, so it is read under both rules (and said).
    _png(layout / "model" / "wood.png", RED)
    path = _obj(str(layout / "model"), map_kd="/home/someone/else/wood.png")
    colour, said = _colour(path, "folder")
    assert colour == RED
    assert any("'wood.png' beside the model is read instead" in s for s in said), said


# ----------------------------------------------------------------------------- glTF


def test_gltf_texture_in_a_sibling_folder_is_read_by_default(layout):
    # The same layout as the OBJ's: trimesh alone refuses it.
    path = _gltf(str(layout / "model" / "gltf"))
    assert _colour(path, "anywhere")[0] == RED


def test_gltf_texture_outside_the_folder_falls_back_to_the_factor(layout):
    path = _gltf(str(layout / "model" / "gltf"))
    colour, said = _colour(path, "folder")
    assert colour == OWN
    line = [s for s in said if "../textures/red.png" in s]
    assert len(line) == 1, said
    assert "outside the model's folder" in line[0] and "using its base colour factor" in line[0]
    assert "FilePathResolver" not in " ".join(said)


@pytest.mark.parametrize("rule", ["anywhere", "folder"])
def test_gltf_image_url_is_never_fetched(layout, rule):
    path = _gltf(str(layout / "model"), image_uri="https://example.com/red.png")
    colour, said = _colour(path, rule)
    assert colour == OWN
    assert any("'https://example.com/red.png'" in s and "never fetches URLs" in s
               for s in said), said


def test_gltf_buffer_outside_the_folder(layout, capsys):
    folder = layout / "model" / "gltf"
    folder.mkdir(parents=True)
    path = _gltf(str(folder), buffer_uri="../../data.bin", image_uri="red.png")
    _png(folder / "red.png", RED)
    assert geovox.load_mesh(path).faces.shape == (12, 3)  # anywhere: read
    with pytest.raises(MeshError) as info:
        geovox.load_mesh(path, references="folder")
    text = str(info.value)
    assert text.startswith(f"{path}: refers to a file that is not read: '../../data.bin'")
    assert "outside the model's folder" in text and "FilePathResolver" not in text
    # The CLI: one line, exit 2.
    status = main(["convert", path, "-o", str(layout / "v.raw"), "-r", "4",
                   "--references", "folder"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "'../../data.bin'" in err, err


def test_glb_with_an_embedded_texture_is_the_same_under_both_rules(tmp_path):
    box = trimesh.creation.box(extents=(1, 1, 1))
    path = tmp_path / "box.glb"
    path.write_bytes(trimesh.Scene(box).export(file_type="glb"))
    a = geovox.voxelize(str(path), resolution=6, backend="numpy")
    b = geovox.voxelize(str(path), resolution=6, backend="numpy", references="folder")
    assert np.array_equal(a.occupancy, b.occupancy)


# ----------------------------------------------------------------------------- PLY, COLLADA


def _ply(path, texture):
    """An ASCII PLY box with UVs naming ``texture`` (trimesh asks its resolver for it)."""
    box = trimesh.creation.box(extents=(1, 1, 1))
    lines = ["ply", "format ascii 1.0", f"comment TextureFile {texture}",
             f"element vertex {len(box.vertices)}", "property float x", "property float y",
             "property float z", "property float s", "property float t",
             f"element face {len(box.faces)}", "property list uchar int vertex_indices",
             "end_header"]
    lines += [f"{x} {y} {z} 0.5 0.5" for x, y, z in box.vertices]
    lines += [f"3 {a} {b} {c}" for a, b, c in box.faces]
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return str(path)


def test_ply_texture_outside_the_folder(layout):
    path = _ply(layout / "model" / "ply" / "box.ply", "../textures/red.png")
    assert _colour(path, "anywhere")[0] == RED
    colour, said = _colour(path, "folder")
    assert colour != RED
    assert any("'../textures/red.png' is not read" in s for s in said), said


def _dae(path, image):
    """A COLLADA box whose diffuse texture is the file ``image`` (made with pycollada)."""
    import collada
    from collada import geometry, material, scene, source

    box = trimesh.creation.box(extents=(1, 1, 1))
    m = collada.Collada()
    img = material.CImage("img", image)
    surface = material.Surface("surf", img)
    sampler = material.Sampler2D("samp", surface)
    effect = material.Effect("effect", [surface, sampler], "lambert",
                             diffuse=material.Map(sampler, "UVSET0"))
    mat = material.Material("mat", "m", effect)
    m.images.append(img)
    m.effects.append(effect)
    m.materials.append(mat)
    v = source.FloatSource("verts", box.vertices.reshape(-1), ("X", "Y", "Z"))
    uv = source.FloatSource("uv", np.full(2 * len(box.vertices), 0.5), ("S", "T"))
    geom = geometry.Geometry(m, "g", "box", [v, uv])
    inputs = source.InputList()
    inputs.addInput(0, "VERTEX", "#verts")
    inputs.addInput(1, "TEXCOORD", "#uv", set="0")
    geom.primitives.append(geom.createTriangleSet(np.repeat(box.faces.reshape(-1), 2), inputs,
                                                  "mat"))
    m.geometries.append(geom)
    node = scene.Node("n", children=[scene.GeometryNode(geom, [scene.MaterialNode("mat", mat,
                                                                                  inputs=[])])])
    m.scenes.append(scene.Scene("s", [node]))
    m.scene = m.scenes[0]
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "wb") as f:
        m.write(f)
    return str(path)


def test_collada_texture_outside_the_folder(layout):
    pytest.importorskip("collada")
    path = _dae(layout / "model" / "dae" / "box.dae", "../../secret.png")
    assert _colour(path, "anywhere")[0] == BLUE
    colour, said = _colour(path, "folder")
    assert colour != BLUE
    assert any("'../../secret.png' is not read" in s for s in said), said


# ----------------------------------------------------------------------------- every entry point


def test_every_entry_point_takes_the_rule(layout, tmp_path, capsys):
    path = _obj(str(layout / "model" / "obj"))
    out = tmp_path / "out"
    # convert_to (slab by slab)
    with pytest.warns(GeovoxWarning, match="is not read"):
        geovox.convert_to(path, str(tmp_path / "a.h5"), resolution=4, color=True,
                          references="folder")
    # convert_many (and so a cluster's tasks, which carry the same options)
    results = geovox.convert_many([path], str(out), resolution=4, color=True,
                                  references="folder")
    # The summary's cell holds the warnings in a few words; Result.warnings holds them whole.
    assert results[0].status == "ok" and any("is not read" in w for w in results[0].warnings)
    results = geovox.convert_many([path], str(tmp_path / "out2"), resolution=4, color=True)
    assert results[0].status == "ok" and not any("is not read" in w for w in results[0].warnings)
    # the CLI
    assert main(["convert", path, "-o", str(tmp_path / "c.raw"), "-r", "4", "--color",
                 "--references", "folder"]) == 0
    assert "is not read" in capsys.readouterr().err
    assert main(["info", path, "--references", "folder"]) == 0
    assert main(["info", path]) == 0
