"""Materials as other formats state them (glTF/GLB, PLY, OFF), on small files made here.

Every case goes through ``geovox.voxelize`` (the Python API); a sample of them
also through ``geovox convert ... --color`` (the CLI, in process). The boxes
carry one UV (or colour) on every vertex, so every inside voxel must have
exactly one colour, whatever the nearest point. Texel centres are at
(i + 0.5) / 4 of a 4 x 4 texture, where bilinear sampling returns the texel
itself: the expected colours are exact. A colour the file does not state is
never taken for one it does: each default path has its own test.
"""

from __future__ import annotations

import base64
import io
import json
import os
import struct
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

import geovox
from geovox.cli import main
from geovox.errors import GeovoxWarning

from conftest import corpus

REPEAT, MIRROR, CLAMP = 10497, 33648, 33071


def texel(col, row):
    """Colour of texel (col, row) of the test texture (row 0 is the image's top)."""
    return (60 * col + 10, 60 * row + 10, 77)


def texture_png(size=4) -> bytes:
    img = np.array([[texel(c, r) for c in range(size)] for r in range(size)], np.uint8)
    out = io.BytesIO()
    Image.fromarray(img).save(out, format="PNG")
    return out.getvalue()


def centre(i):
    """glTF texture coordinate of the centre of texel i (of 4)."""
    return (i + 0.5) / 4


def box(offset=(0.0, 0.0, 0.0)):
    m = trimesh.creation.box(extents=(2, 2, 2))
    return (np.asarray(m.vertices) + 1 + np.asarray(offset)).astype(np.float32), \
        np.asarray(m.faces, dtype=np.uint32)


def write_gltf(path, primitives, materials=(), textures=(), samplers=(), images=(),
               extensions_used=()):
    """A glTF (``.gltf`` with an embedded buffer, or ``.glb``) of one mesh.

    ``primitives``: dicts with ``vertices`` (n, 3) float32, ``faces`` (m, 3)
    uint32, optional ``material`` index and ``attributes``: name -> array
    (float32 unless uint8/uint16, which are written normalised). ``images``:
    dicts as in glTF, or ``{"png": bytes}`` to embed in a buffer view (GLB)
    or a data URI (.gltf).
    """
    blob = bytearray()
    views, accessors = [], []

    def add(data: bytes) -> int:
        blob.extend(b"\0" * (-len(blob) % 4))
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
        blob.extend(data)
        return len(views) - 1

    def accessor(a, kind) -> int:
        a = np.ascontiguousarray(a)
        comp = {np.float32: 5126, np.uint8: 5121, np.uint16: 5123, np.uint32: 5125}[a.dtype.type]
        acc = {"bufferView": add(a.tobytes()), "componentType": comp, "count": len(a),
               "type": kind}
        if kind == "VEC3" and a.dtype == np.float32 and a.shape[1] == 3:
            acc["min"], acc["max"] = a.min(axis=0).tolist(), a.max(axis=0).tolist()
        if a.dtype in (np.uint8, np.uint16) and kind != "SCALAR":
            acc["normalized"] = True
        accessors.append(acc)
        return len(accessors) - 1

    glb = str(path).endswith(".glb")
    prims = []
    for p in primitives:
        attrs = {"POSITION": accessor(p["vertices"], "VEC3")}
        for name, a in p.get("attributes", {}).items():
            attrs[name] = accessor(a, {2: "VEC2", 3: "VEC3", 4: "VEC4"}[a.shape[1]])
        prim = {"attributes": attrs, "indices": accessor(p["faces"].reshape(-1), "SCALAR")}
        if "material" in p:
            prim["material"] = p["material"]
        prims.append(prim)
    imgs = []
    for im in images:
        if "png" in im:
            if glb:
                imgs.append({"bufferView": add(im["png"]), "mimeType": "image/png"})
            else:
                imgs.append({"uri": "data:image/png;base64,"
                             + base64.b64encode(im["png"]).decode()})
        else:
            imgs.append(im)
    header = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
              "nodes": [{"mesh": 0}], "meshes": [{"primitives": prims}],
              "accessors": accessors, "bufferViews": views}
    for key, value in (("materials", materials), ("textures", textures),
                       ("samplers", samplers), ("images", imgs)):
        if value:
            header[key] = list(value)
    if extensions_used:
        header["extensionsUsed"] = list(extensions_used)
    blob.extend(b"\0" * (-len(blob) % 4))
    if glb:
        header["buffers"] = [{"byteLength": len(blob)}]
        text = json.dumps(header).encode()
        text += b" " * (-len(text) % 4)
        data = (b"glTF" + struct.pack("<II", 2, 28 + len(text) + len(blob))
                + struct.pack("<I", len(text)) + b"JSON" + text
                + struct.pack("<I", len(blob)) + b"BIN\0" + bytes(blob))
        path.write_bytes(data)
    else:
        header["buffers"] = [{"byteLength": len(blob), "uri": "data:application/octet-stream;"
                              "base64," + base64.b64encode(bytes(blob)).decode()}]
        path.write_text(json.dumps(header))
    return path


def uv_box(u, v, **extra):
    """A box primitive whose every vertex has texture coordinates (u, v) (glTF's V, down)."""
    vert, faces = box()
    attrs = {"TEXCOORD_0": np.tile(np.float32([u, v]), (len(vert), 1))}
    attrs.update(extra.pop("attributes", {}))
    return dict(vertices=vert, faces=faces, attributes=attrs, **extra)


def textured(sampler=None, factor=None, tex_extra=None):
    """One material with the test texture (embedded PNG), and its texture tables."""
    ref = {"index": 0, **(tex_extra or {})}
    pbr = {"baseColorTexture": ref}
    if factor is not None:
        pbr["baseColorFactor"] = factor
    tex = {"source": 0}
    samplers = []
    if sampler is not None:
        tex["sampler"] = 0
        samplers = [sampler]
    return dict(materials=[{"name": "tex", "pbrMetallicRoughness": pbr}], textures=[tex],
                samplers=samplers, images=[{"png": texture_png()}])


def colours_of(path, res=10, **kw):
    """The distinct RGB colours of the inside voxels, through the Python API."""
    vol = geovox.voxelize(path, resolution=res, color=True, **kw)
    assert vol.inside_count > 0
    return {tuple(int(x) for x in c) for c in vol.colors[vol.occupancy, :3]}


def cli_colours(path, tmp_path, res=10):
    """The same through ``geovox convert PATH -o OUT.npz --color`` (in process)."""
    out = tmp_path / "out.npz"
    assert main(["convert", str(path), "-o", str(out), "-r", str(res), "--color"]) == 0
    d = np.load(out)
    inside = d["occupancy"] > 0
    return {tuple(int(x) for x in c) for c in d["colors"][inside, :3]}


# glTF: base colour texture, its coordinate set, wrap modes, V's direction.

@pytest.mark.parametrize("ext", [".gltf", ".glb"])
def test_texture_is_sampled_with_v_down_and_values_as_stored(tmp_path, ext):
    # glTF's V points down: (u, v) = texel (1, 2)'s centre is column 1, row 2
    # of the image as stored (row 0 on top). The texels' sRGB values come out
    # unchanged (no linearisation).
    path = write_gltf(tmp_path / f"t{ext}", [uv_box(centre(1), centre(2), material=0)],
                      **textured())
    assert colours_of(path) == {texel(1, 2)}
    assert cli_colours(path, tmp_path) == {texel(1, 2)}


@pytest.mark.parametrize("wrap_s,wrap_t,col,row", [
    (REPEAT, REPEAT, 1, 1),    # 1.375 -> 0.375
    (MIRROR, MIRROR, 2, 2),    # 1.375 -> 2 - 1.375 = 0.625
    (CLAMP, CLAMP, 3, 3),      # past the edge: the last texel
    (REPEAT, MIRROR, 1, 2),    # each axis its own mode
    (CLAMP, REPEAT, 3, 1),
])
def test_sampler_wrap_modes_per_axis(tmp_path, wrap_s, wrap_t, col, row):
    sampler = {"wrapS": wrap_s, "wrapT": wrap_t}
    path = write_gltf(tmp_path / "w.glb", [uv_box(1.375, 1.375, material=0)],
                      **textured(sampler=sampler))
    assert colours_of(path) == {texel(col, row)}


def test_wrap_below_zero(tmp_path):
    # u = -0.375: repeat -> 0.625 (col 2); mirror -> 0.375 (col 1); clamp -> col 0
    for (s, col) in ((REPEAT, 2), (MIRROR, 1), (CLAMP, 0)):
        path = write_gltf(tmp_path / f"n{s}.glb", [uv_box(-0.375, centre(0), material=0)],
                          **textured(sampler={"wrapS": s}))
        assert colours_of(path) == {texel(col, 0)}, s


def test_sampler_without_wrap_repeats(tmp_path):
    path = write_gltf(tmp_path / "d.glb", [uv_box(1.375, centre(0), material=0)],
                      **textured(sampler={"magFilter": 9729}))
    assert colours_of(path) == {texel(1, 0)}


def test_texcoord_1_is_used_when_the_texture_names_it(tmp_path):
    vert, _ = box()
    uv1 = np.tile(np.float32([centre(3), centre(2)]), (len(vert), 1))
    path = write_gltf(tmp_path / "t1.gltf",
                      [uv_box(centre(0), centre(0), material=0, attributes={"TEXCOORD_1": uv1})],
                      **textured(tex_extra={"texCoord": 1}))
    assert colours_of(path) == {texel(3, 2)}
    assert cli_colours(path, tmp_path) == {texel(3, 2)}
    # the same file naming set 0 takes set 0
    path = write_gltf(tmp_path / "t0.gltf",
                      [uv_box(centre(0), centre(0), material=0, attributes={"TEXCOORD_1": uv1})],
                      **textured(tex_extra={"texCoord": 0}))
    assert colours_of(path) == {texel(0, 0)}


def test_texcoord_set_the_primitive_lacks_warns_and_takes_the_factor(tmp_path):
    path = write_gltf(tmp_path / "t2.glb", [uv_box(centre(0), centre(0), material=0)],
                      **textured(factor=[0.2, 0.4, 0.6, 1], tex_extra={"texCoord": 1}))
    with pytest.warns(GeovoxWarning, match="TEXCOORD_1"):
        assert colours_of(path) == {(51, 102, 153)}
    # and a textured primitive without any coordinates
    vert, faces = box()
    path = write_gltf(tmp_path / "t3.glb", [dict(vertices=vert, faces=faces, material=0)],
                      **textured(factor=[0.2, 0.4, 0.6, 1]))
    with pytest.warns(GeovoxWarning, match="TEXCOORD_0"):
        assert colours_of(path) == {(51, 102, 153)}


def test_khr_texture_transform_offset_and_scale(tmp_path):
    # (0.125, 0.125) scaled by 2, then moved by (0.375, 0.125): (0.625, 0.375), texel (2, 1)
    tt = {"extensions": {"KHR_texture_transform": {"offset": [0.375, 0.125], "scale": [2, 2]}}}
    path = write_gltf(tmp_path / "tt.glb", [uv_box(centre(0), centre(0), material=0)],
                      extensions_used=["KHR_texture_transform"], **textured(tex_extra=tt))
    assert colours_of(path) == {texel(2, 1)}


# glTF: factors and vertex colours.

def test_base_colour_factor_exact_and_times_texture(tmp_path):
    path = write_gltf(tmp_path / "f.glb", [uv_box(centre(1), centre(2), material=0)],
                      **textured(factor=[0.5, 1.0, 0.25, 1.0]))
    r, g, b = texel(1, 2)
    assert colours_of(path) == {(round(r * 0.5), g, round(b * 0.25))}
    # the factor alone
    vert, faces = box()
    path = write_gltf(tmp_path / "g.glb", [dict(vertices=vert, faces=faces, material=0)],
                      materials=[{"pbrMetallicRoughness": {"baseColorFactor": [0.2, 0.502, 1, 1]}}])
    assert colours_of(path) == {(51, 128, 255)}


@pytest.mark.parametrize("dtype,value", [
    (np.float32, [0.2, 0.4, 0.6]),
    (np.uint8, [51, 102, 153, 255]),
    (np.uint16, [13107, 26214, 39321]),
])
def test_color_0_without_material_in_every_encoding(tmp_path, dtype, value):
    vert, faces = box()
    colour = np.tile(np.asarray(value, dtype), (len(vert), 1))
    path = write_gltf(tmp_path / "c.glb", [dict(vertices=vert, faces=faces,
                                                attributes={"COLOR_0": colour})])
    assert colours_of(path) == {(51, 102, 153)}


def test_color_0_times_factor_and_times_texture(tmp_path):
    vert, faces = box()
    # (products away from a half level, where rounding would depend on noise)
    colour = np.tile(np.float32([0.4, 1.0, 1.0]), (len(vert), 1))
    materials = [{"pbrMetallicRoughness": {"baseColorFactor": [1, 0.4, 1, 1]}}]
    path = write_gltf(tmp_path / "cf.glb", [dict(vertices=vert, faces=faces, material=0,
                                                 attributes={"COLOR_0": colour})],
                      materials=materials)
    assert colours_of(path) == {(102, 102, 255)}
    # COLOR_0 x factor x texture, as glTF's base colour is
    path = write_gltf(tmp_path / "cft.glb",
                      [uv_box(centre(1), centre(2), material=0, attributes={"COLOR_0": colour})],
                      **textured(factor=[1, 0.4, 1, 1]))
    r, g, b = texel(1, 2)
    assert colours_of(path) == {(round(r * 0.4), round(g * 0.4), b)}
    assert cli_colours(path, tmp_path) == {(round(r * 0.4), round(g * 0.4), b)}


def test_specular_glossiness_diffuse_factor_and_texture(tmp_path):
    sg = {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [0.2, 0.4, 0.6, 1.0],
                                                  "specularFactor": [1, 1, 1],
                                                  "glossinessFactor": 0.2}}
    vert, faces = box()
    path = write_gltf(tmp_path / "sg.glb", [dict(vertices=vert, faces=faces, material=0)],
                      materials=[{"name": "sg", "extensions": sg}],
                      extensions_used=["KHR_materials_pbrSpecularGlossiness"])
    assert colours_of(path) == {(51, 102, 153)}
    sg = {"KHR_materials_pbrSpecularGlossiness": {"diffuseFactor": [1, 0.5, 1, 1],
                                                  "diffuseTexture": {"index": 0}}}
    path = write_gltf(tmp_path / "sgt.gltf", [uv_box(centre(2), centre(1), material=0)],
                      materials=[{"name": "sg", "extensions": sg}], textures=[{"source": 0}],
                      images=[{"png": texture_png()}],
                      extensions_used=["KHR_materials_pbrSpecularGlossiness"])
    r, g, b = texel(2, 1)
    assert colours_of(path) == {(r, round(g * 0.5), b)}


# glTF: where images live, and several primitives.

def test_external_images_plain_and_percent_escaped(tmp_path):
    (tmp_path / "maps").mkdir()
    (tmp_path / "maps" / "my tex.png").write_bytes(texture_png())
    for uri in ("maps/my tex.png", "maps/my%20tex.png"):
        t = textured()
        t["images"] = [{"uri": uri}]
        path = write_gltf(tmp_path / "ext.gltf", [uv_box(centre(3), centre(0), material=0)], **t)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert colours_of(path) == {texel(3, 0)}, uri
        (material,) = geovox.load_mesh(path).materials
        assert material.texture_file.endswith("my tex.png")  # `geovox info`: texture found


def test_missing_external_image_warns_and_takes_the_factor(tmp_path):
    t = textured(factor=[0.2, 0.4, 0.6, 1.0])
    t["images"] = [{"uri": "gone.png"}]
    path = write_gltf(tmp_path / "gone.gltf", [uv_box(centre(3), centre(0), material=0)], **t)
    with pytest.warns(GeovoxWarning, match="gone.png"):
        assert colours_of(path) == {(51, 102, 153)}


def test_primitives_each_with_their_own_material(tmp_path):
    va, fa = box()
    vb, fb = box(offset=(2, 0, 0))
    uv = np.tile(np.float32([centre(2), centre(3)]), (len(vb), 1))
    t = textured()
    t["materials"] = [{"pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 1]}}] + t["materials"]
    t["materials"][1]["pbrMetallicRoughness"]["baseColorTexture"]["index"] = 0
    path = write_gltf(tmp_path / "two.glb", [
        dict(vertices=va, faces=fa, material=0),
        dict(vertices=vb, faces=fb, material=1, attributes={"TEXCOORD_0": uv})], **t)
    vol = geovox.voxelize(path, shape=(16, 8, 8), color=True)
    assert {tuple(c) for c in vol.colors[1:3, 3:5, 3:5, :3].reshape(-1, 3)} == {(255, 0, 0)}
    assert {tuple(c) for c in vol.colors[13:15, 3:5, 3:5, :3].reshape(-1, 3)} == {texel(2, 3)}


def test_primitives_sharing_a_material_share_its_texture(tmp_path):
    va, fa = box()
    vb, fb = box(offset=(2, 0, 0))
    uv = np.float32([centre(0), centre(0)])
    path = write_gltf(tmp_path / "shared.glb", [
        dict(vertices=va, faces=fa, material=0, attributes={"TEXCOORD_0": np.tile(uv, (24, 1))}),
        dict(vertices=vb, faces=fb, material=0, attributes={"TEXCOORD_0": np.tile(uv, (24, 1))})],
        **textured())
    mesh = geovox.load_mesh(path)
    assert len(mesh.materials) == 1 and mesh.materials[0].name == "tex"


# Default paths: what the file does not state.

def test_gltf_primitive_without_material_or_colours_is_the_default_grey(tmp_path):
    vert, faces = box()
    path = write_gltf(tmp_path / "none.glb", [dict(vertices=vert, faces=faces)])
    assert colours_of(path) == {(204, 204, 204)}
    assert cli_colours(path, tmp_path) == {(204, 204, 204)}


def test_gltf_material_without_factor_is_white_as_the_specification_says(tmp_path):
    vert, faces = box()
    path = write_gltf(tmp_path / "white.glb", [dict(vertices=vert, faces=faces, material=0)],
                      materials=[{"name": "plain"}])
    assert colours_of(path) == {(255, 255, 255)}


def test_uncoloured_part_beside_a_coloured_one_keeps_the_default(tmp_path):
    # One primitive with COLOR_0, one with nothing: the second must not take
    # the white that stands in for "no vertex colour" under a material.
    va, fa = box()
    vb, fb = box(offset=(2, 0, 0))
    red = np.tile(np.uint8([255, 0, 0, 255]), (len(va), 1))
    path = write_gltf(tmp_path / "mixed.glb", [
        dict(vertices=va, faces=fa, attributes={"COLOR_0": red}),
        dict(vertices=vb, faces=fb)])
    vol = geovox.voxelize(path, shape=(16, 8, 8), color=True)
    assert {tuple(c) for c in vol.colors[1:3, 3:5, 3:5, :3].reshape(-1, 3)} == {(255, 0, 0)}
    assert {tuple(c) for c in vol.colors[13:15, 3:5, 3:5, :3].reshape(-1, 3)} == {(204, 204, 204)}


def test_sixteen_bit_grey_texture_is_not_clipped_to_white(tmp_path):
    grey = np.full((4, 4), 257 * 100, np.uint16)  # 100 of 255
    out = io.BytesIO()
    Image.fromarray(grey).save(out, format="PNG")
    t = textured()
    t["images"] = [{"png": out.getvalue()}]
    path = write_gltf(tmp_path / "g16.glb", [uv_box(centre(1), centre(1), material=0)], **t)
    assert colours_of(path) == {(100, 100, 100)}


# PLY and OFF.

def _trimesh_box():
    m = trimesh.creation.box(extents=(2, 2, 2))
    m.apply_translation((1, 1, 1))
    return m


def test_ply_without_colours_uvs_only_vertex_and_face_colours(tmp_path):
    m = _trimesh_box()
    m.export(tmp_path / "plain.ply")
    assert colours_of(tmp_path / "plain.ply") == {(204, 204, 204)}
    m = _trimesh_box()
    m.visual = trimesh.visual.TextureVisuals(uv=m.vertices[:, :2] / 2)
    m.export(tmp_path / "uv.ply")
    assert colours_of(tmp_path / "uv.ply") == {(204, 204, 204)}
    assert cli_colours(tmp_path / "uv.ply", tmp_path) == {(204, 204, 204)}
    m = _trimesh_box()
    m.visual.vertex_colors = np.tile([10, 200, 30, 255], (len(m.vertices), 1))
    m.export(tmp_path / "vc.ply")
    assert colours_of(tmp_path / "vc.ply") == {(10, 200, 30)}
    m = _trimesh_box()
    m.visual.face_colors = np.tile([250, 5, 60, 255], (len(m.faces), 1))
    m.export(tmp_path / "fc.ply")
    assert cli_colours(tmp_path / "fc.ply", tmp_path) == {(250, 5, 60)}


BOX8 = np.array([[0, 0, 0], [2, 0, 0], [2, 2, 0], [0, 2, 0],
                 [0, 0, 2], [2, 0, 2], [2, 2, 2], [0, 2, 2.0]])
QUADS = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (2, 3, 7, 6), (1, 2, 6, 5), (0, 4, 7, 3)]


def write_off(path, header="OFF", vertex_extra="", face_extra=lambda i: ""):
    lines = [header, "# a comment", f"{len(BOX8)} {len(QUADS)} 0"]
    lines += [f"{x} {y} {z}{vertex_extra}" for x, y, z in BOX8]
    lines += ["4 " + " ".join(map(str, q)) + face_extra(i) for i, q in enumerate(QUADS)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_off_vertex_colours_integer_and_float(tmp_path):
    path = write_off(tmp_path / "vc.off", "COFF", " 10 200 30 255")
    assert colours_of(path) == {(10, 200, 30)}
    assert cli_colours(path, tmp_path) == {(10, 200, 30)}
    path = write_off(tmp_path / "vcf.off", "COFF", " 0.2 0.4 0.6 1.0")
    assert colours_of(path) == {(51, 102, 153)}
    path = write_off(tmp_path / "nvc.off", "CNOFF", " 0 0 1 0.2 0.4 0.6 1.0")
    assert colours_of(path) == {(51, 102, 153)}


def test_off_face_colours_each_face_its_own(tmp_path):
    # the top face (z = 2, quad 1) red, the rest blue
    path = write_off(tmp_path / "fc.off",
                     face_extra=lambda i: " 255 0 0" if i == 1 else " 0 0 255")
    vol = geovox.voxelize(path, resolution=10, color=True)
    assert vol.inside_count == 1000
    assert np.all(vol.colors[2:8, 2:8, 9, :3] == (255, 0, 0))
    assert np.all(vol.colors[:, :, 0, :3] == (0, 0, 255))


def test_off_without_colours_is_the_default_grey(tmp_path):
    path = write_off(tmp_path / "plain.off")
    assert colours_of(path) == {(204, 204, 204)}
    # a colour-map index (one number) is not a colour
    path = write_off(tmp_path / "index.off", face_extra=lambda i: " 3")
    assert colours_of(path) == {(204, 204, 204)}


def test_fuze_ply_has_the_colours_of_fuze_obj():
    # The PLY names the same texture and states no material colour: trimesh's
    # made-up 0.4 grey must not darken it.
    a = geovox.voxelize(corpus("fuze", "fuze.obj"), resolution=24, color=True)
    b = geovox.voxelize(corpus("fuze", "fuze.ply"), resolution=24, color=True)
    np.testing.assert_array_equal(a.occupancy, b.occupancy)
    diff = np.abs(a.colors.astype(int) - b.colors.astype(int))
    assert np.mean(diff[a.occupancy].max(axis=1) <= 2) > 0.99


def test_trimesh_objects_in_python_keep_their_pbr_colours():
    from trimesh.visual.material import PBRMaterial

    m = _trimesh_box()
    m.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(baseColorFactor=[255, 128, 0, 255]))
    vol = geovox.voxelize(m, resolution=8, color=True)
    assert {tuple(c) for c in vol.colors[vol.occupancy, :3]} == {(255, 128, 0)}


def test_glb_written_by_trimesh(tmp_path):
    from trimesh.visual.material import PBRMaterial

    m = _trimesh_box()
    m.visual.vertex_colors = np.tile([40, 80, 160, 255], (len(m.vertices), 1))
    m.export(tmp_path / "vc.glb")
    assert colours_of(tmp_path / "vc.glb") == {(40, 80, 160)}
    tex = Image.fromarray(np.full((8, 8, 3), (200, 100, 50), np.uint8))
    m = _trimesh_box()
    m.visual = trimesh.visual.TextureVisuals(
        uv=np.full((len(m.vertices), 2), 0.5),
        material=PBRMaterial(baseColorTexture=tex, baseColorFactor=[255, 51, 255, 255]))
    m.export(tmp_path / "tex.glb")
    assert colours_of(tmp_path / "tex.glb") == {(200, 20, 50)}
    a, b = _trimesh_box(), _trimesh_box()
    b.apply_translation((2, 0, 0))
    a.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(baseColorFactor=[255, 0, 0, 255]))
    b.visual = trimesh.visual.TextureVisuals(material=PBRMaterial(baseColorFactor=[0, 0, 255, 255]))
    trimesh.Scene([a, b]).export(tmp_path / "two.glb")
    vol = geovox.voxelize(tmp_path / "two.glb", shape=(16, 8, 8), color=True)
    assert np.all(vol.colors[1:3, 3:5, 3:5, :3] == (255, 0, 0))
    assert np.all(vol.colors[13:15, 3:5, 3:5, :3] == (0, 0, 255))


# OBJ + MTL: map_Kd options.

def obj_centre(i):
    """OBJ texture coordinate v of the centre of texel row i (of 4): V points up."""
    return 1 - (i + 0.5) / 4


def obj_box(folder, mtl, u, v, material="m", name="b.obj", png=None):
    """A 2 x 2 x 2 box OBJ, every corner at texture coordinates (u, v), using ``material``."""
    (folder / "t.png").write_bytes(texture_png() if png is None else png)
    (folder / "a.mtl").write_text(mtl)
    m = _trimesh_box()
    lines = ["mtllib a.mtl", f"vt {u!r} {v!r}"] + [f"v {x} {y} {z}" for x, y, z in m.vertices]
    lines += [f"usemtl {material}"] + [f"f {a + 1}/1 {b + 1}/1 {c + 1}/1" for a, b, c in m.faces]
    (folder / name).write_text("\n".join(lines) + "\n")
    return folder / name


def quiet_colours(path, **kw):
    """colours_of, and the GeovoxWarning messages it gave."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        got = colours_of(path, **kw)
    return got, [str(w.message) for w in caught if issubclass(w.category, GeovoxWarning)]


@pytest.mark.parametrize("options,u,v,want", [
    # -o shifts the lookup: uv -> uv + o (Blender's and three.js's reading)
    ("-o 0.25 0 0", centre(0), obj_centre(0), texel(1, 0)),
    ("-o 0 -0.5", centre(0), obj_centre(0), texel(0, 2)),
    # -s scales it: uv -> s * uv; v's scale defaults to 1
    ("-s 2 2 1", centre(1) / 2, obj_centre(3) / 2, texel(1, 3)),
    ("-s 2", centre(1) / 2, obj_centre(2), texel(1, 2)),
    # both: uv -> s * uv + o, in either order on the line
    ("-s 0.5 0.5 -o 0.25 0.25", 0.75, 0.75, texel(2, 1)),
    ("-o 0.25 0.25 -s 0.5 0.5", 0.75, 0.75, texel(2, 1)),
    # after the transform the texture still repeats
    ("-o 3 -2", centre(3), obj_centre(1), texel(3, 1)),
])
def test_map_kd_offset_and_scale_move_the_lookup(tmp_path, options, u, v, want):
    path = obj_box(tmp_path, f"newmtl m\nmap_Kd {options} t.png\n", u, v)
    assert quiet_colours(path) == ({want}, [])


def test_map_kd_offset_and_scale_agree_with_khr_texture_transform(tmp_path):
    # The same move stated in glTF (V down, KHR_texture_transform) and in MTL (V up).
    t = textured(tex_extra={"extensions": {"KHR_texture_transform": {
        "offset": [0.25, 0.5], "scale": [0.5, 0.5]}}})
    gltf = write_gltf(tmp_path / "t.glb", [uv_box(0.75, 0.25, material=0)], **t)
    # glTF v' = 0.5 * 0.25 + 0.5 = 0.625 (row 2); in OBJ's V: 1 - 0.625 = 0.375 = 0.5 * 0.75 + 0
    obj = obj_box(tmp_path, "newmtl m\nmap_Kd -s 0.5 0.5 -o 0.25 0 t.png\n", 0.75, 0.75)
    assert colours_of(gltf) == colours_of(obj) == {texel(2, 2)}


def test_map_kd_clamp_on_is_one_copy_of_the_texture(tmp_path):
    # The MTL specification: "one copy of the texture is mapped onto the surface
    # [...]. Outside of the origin texture, the underlying material is unchanged."
    from geovox.io.mtl import read_mtl

    mtl = ("newmtl c\nKd 0.2 0.4 0.6\nmap_Kd -clamp on t.png\n"
           "newmtl w\nmap_Kd -clamp on t.png\n"
           "newmtl s\nmap_Kd -clamp on -s 0.5 0.5 t.png\n"
           "newmtl r\nmap_Kd -clamp off t.png\nnewmtl p\nmap_Kd t.png\n")
    path = obj_box(tmp_path, mtl, 1.375, 1.375, "c")
    mats = read_mtl(str(tmp_path / "a.mtl"), [])
    assert mats["c"].wrap == ("border", "border") and mats["c"].texture_file.endswith("t.png")
    assert mats["r"].wrap == mats["p"].wrap == ("repeat", "repeat")
    # off the texture: Kd alone (with Kd 1: white), not an edge texel
    assert colours_of(path) == {(51, 102, 153)}
    assert colours_of(obj_box(tmp_path, mtl, 1.375, 1.375, "w")) == {(255, 255, 255)}
    assert colours_of(obj_box(tmp_path, mtl, -0.01, centre(1), "w")) == {(255, 255, 255)}
    # on its edge and inside: the texture
    assert colours_of(obj_box(tmp_path, mtl, 1.0, 1.0, "w")) == {texel(3, 0)}
    assert colours_of(obj_box(tmp_path, mtl, centre(1), obj_centre(2), "w")) == {texel(1, 2)}
    # scaled by 0.5 the one copy covers uv up to 2
    assert colours_of(obj_box(tmp_path, mtl, 1.75, 1.75, "s")) == {texel(3, 0)}
    assert colours_of(obj_box(tmp_path, mtl, 2.5, 1.75, "s")) == {(255, 255, 255)}
    # off: repeats (1.375 -> 0.375)
    assert colours_of(obj_box(tmp_path, mtl, 1.375, 1.375, "r")) == {texel(1, 2)}


def test_map_kd_clamp_on_across_a_face_keeps_the_texture_inside(tmp_path):
    # One face spanning u from -1 to 2: the inside third is textured, the rest takes Kd.
    (tmp_path / "t.png").write_bytes(texture_png())
    (tmp_path / "a.mtl").write_text("newmtl m\nKd 1 1 1\nmap_Kd -clamp on t.png\n")
    mesh = geovox.load_mesh(obj_box(tmp_path, (tmp_path / "a.mtl").read_text(), 0.5, 0.5))
    from geovox.colour import load_textures, shade

    mesh.corner_uv[:] = [[-1.0, obj_centre(1)], [2.0, obj_centre(1)], [2.0, obj_centre(1)]]
    load_textures(mesh)
    u = np.linspace(0, 1, 301)  # barycentric weight of corner 1: uv = -1 + 3 u
    got = shade(mesh, np.zeros(len(u), np.int64), np.stack([u, np.zeros_like(u)], axis=1))
    uv = -1 + 3 * u
    inside = (uv >= 0) & (uv <= 1)
    edge = (np.abs(uv) < 1e-6) | (np.abs(uv - 1) < 1e-6)  # rounding decides these
    inside, outside = inside & ~edge, ~inside & ~edge
    assert np.all(got[outside] == 1.0) and outside.sum() == 200
    from geovox.colour.shading import sample_bilinear

    want = sample_bilinear(mesh.materials[0].image,
                           np.stack([uv[inside], np.full(inside.sum(), obj_centre(1))], axis=1),
                           ("clamp", "clamp"))
    np.testing.assert_allclose(got[inside], want, atol=1e-12)


@pytest.mark.parametrize("statement,file", [
    # every option of the specification at its neutral value, and a name with spaces
    ("-blendu on -blendv on -cc off -clamp off -mm 0 1 -o 0 0 0 -s 1 1 1 -t 0 0 0 my tex.png",
     "my tex.png"),
    ("my  tex.png", "my  tex.png"),  # inner spaces kept as written
    ("  -s 1 1 1   my tex.png  ", "my tex.png"),
    ('"my tex.png"', "my tex.png"),
    ("-o 0 0 12 monkeys.png", "12 monkeys.png"),  # a name that starts with a number
    ("-s 1 1 -o 0 0 0 -clamp off 12 monkeys.png", "12 monkeys.png"),
    ("-s 1 1 1 sub\\t.png", "sub/t.png"),  # Windows separators
    ("-o 0 0 -dash.png", "-dash.png"),  # a name that looks like an option
    ("-dash.png", "-dash.png"),
])
def test_map_kd_options_and_names_find_the_right_image(tmp_path, statement, file):
    from geovox.io.mtl import read_mtl

    (tmp_path / "sub").mkdir()
    for name in ("my tex.png", "my  tex.png", "12 monkeys.png", "sub/t.png", "-dash.png",
                 "tex.png"):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "a.mtl").write_text(f"newmtl m\nmap_Kd {statement}\n")
    problems = []
    mats = read_mtl(str(tmp_path / "a.mtl"), problems)
    assert mats["m"].texture_file == str(tmp_path / file)
    assert problems == [] and mats["m"].ignored_options == []
    assert mats["m"].uv_transform is None and mats["m"].wrap == ("repeat", "repeat")


def test_map_kd_statements_written_any_way_find_their_file_and_values(tmp_path_factory):
    # Property: options in any order, with any number of their values, before
    # a file name with spaces, leading digits or dashes inside, find that
    # file; -o/-s/-clamp get the values written (missing ones at their defaults).
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from geovox.io.mtl import _apply_map_options, _map_statement

    folder = tmp_path_factory.mktemp("names")
    number = st.floats(-4, 4, allow_nan=False).map(lambda x: round(x, 3))
    option = st.one_of(
        st.tuples(st.sampled_from(["-o", "-s", "-t"]), st.lists(number, min_size=1, max_size=3)),
        st.tuples(st.sampled_from(["-mm"]), st.lists(number, min_size=2, max_size=2)),
        st.tuples(st.sampled_from(["-clamp", "-blendu", "-blendv", "-cc"]),
                  st.sampled_from([["on"], ["off"]])),
        st.tuples(st.sampled_from(["-bm", "-boost", "-texres"]), st.lists(number, min_size=1,
                                                                          max_size=1)),
        st.tuples(st.just("-imfchan"), st.sampled_from([["r"], ["l"], ["m"]])))
    word = st.text("abcXYZ019_-.", min_size=1, max_size=6)
    name = st.lists(word, min_size=1, max_size=3).map(lambda w: " ".join(w) + ".png")

    @settings(max_examples=150, deadline=None)
    @given(st.lists(option, max_size=5), name)
    def check(options, file):
        (folder / file).write_bytes(b"")
        text = " ".join(" ".join([k] + [str(v) for v in vals]) for k, vals in options)
        try:
            found, parsed = _map_statement(f"{text} {file}", str(folder))
        finally:
            (folder / file).unlink()
        assert found == file
        m = Material()
        _apply_map_options(m, parsed)
        last = {k: vals for k, vals in options}
        o = [float(x) for x in last.get("-o", [])] + [0.0, 0.0]
        sc = [float(x) for x in last.get("-s", [])] + [1.0, 1.0]
        want = np.array([[sc[0], 0, o[0]], [0, sc[1], o[1]], [0, 0, 1]])
        got = np.eye(3) if m.uv_transform is None else m.uv_transform
        np.testing.assert_array_equal(got, want)
        clamp = last.get("-clamp", ["off"])[0] == "on"
        assert m.wrap == (("border",) * 2 if clamp else ("repeat",) * 2)

    from geovox.mesh import Material

    check()


def test_map_kd_options_not_applied_warn_once_each_naming_them(tmp_path):
    # Options geovox does not apply: the texture still loads and samples as
    # stored, and each option is one warning naming it and its materials.
    mtl = ("newmtl a\nmap_Kd -bm 0.5 -mm 0.2 0.8 t.png\n"
           "newmtl b\nmap_Kd -mm 0.1 2 -imfchan r -blendu off t.png\n"
           "newmtl c\nmap_Kd -cc on -t 1 0 0 -texres 512 -boost 2 -type sphere -foo 3 t.png\n"
           "newmtl d\nmap_Kd -o 0.25 t.png\n")
    (tmp_path / "t.png").write_bytes(texture_png())
    m = _trimesh_box()
    lines = ["mtllib a.mtl", f"vt {centre(1)} {obj_centre(2)}"]
    lines += [f"v {x} {y} {z}" for x, y, z in m.vertices]
    for i, (a, b, c) in enumerate(m.faces):
        lines += [f"usemtl {'abc'[i % 3]}", f"f {a + 1}/1 {b + 1}/1 {c + 1}/1"]
    (tmp_path / "a.mtl").write_text(mtl)
    (tmp_path / "o.obj").write_text("\n".join(lines) + "\n")
    got, said = quiet_colours(tmp_path / "o.obj")
    assert got == {texel(1, 2)}
    options = [s.split("map_Kd option ")[1].split("'")[1] for s in said]
    assert sorted(options) == sorted(["-bm 0.5", "-mm 0.2 0.8", "-imfchan r", "-blendu off",
                                      "-cc on", "-t 1 0 0", "-texres 512", "-boost 2",
                                      "-type sphere", "-foo 3"])
    mm = [s for s in said if "-mm" in s]
    assert len(mm) == 1 and "materials 'a', 'b'" in mm[0]
    assert any("-foo 3" in s and "not an option of the MTL specification" in s for s in said)
    # material d (unused here) says nothing; used, its -o is applied without a word
    got, said = quiet_colours(obj_box(tmp_path, mtl, centre(0), obj_centre(2), "d"))
    assert (got, said) == ({texel(1, 2)}, [])


def test_map_ka_is_not_read_and_says_so_with_ambient(tmp_path):
    mtl = "newmtl m\nKa 0.2 0.2 0.2\nmap_Ka -s 2 2 t.png\nmap_Kd t.png\n"
    path = obj_box(tmp_path, mtl, centre(1), obj_centre(2))
    assert quiet_colours(path) == ({texel(1, 2)}, [])  # ambient off: nothing to say
    got, said = quiet_colours(path, ambient=True)
    assert got == {tuple(min(255, c + 51) for c in texel(1, 2))}  # + Ka alone
    assert len(said) == 1 and "map_Ka" in said[0] and "'m'" in said[0]


def test_map_kd_options_on_fuze(tmp_path):
    # fuze's texture name has a space in it. Neutral options change nothing;
    # -s 2 3 -o 0.25 -0.5 gives what the same transform written into its vt lines gives.
    import shutil

    src = corpus("fuze", "fuze.obj")
    folder = os.path.dirname(src)
    for name in ("fuze.obj", "fuze uv.jpg"):
        shutil.copy(os.path.join(folder, name), tmp_path / name)
    mtl = Path(folder, "fuze.obj.mtl").read_text()
    assert "map_Kd fuze uv.jpg" in mtl

    def run(mtl_text, obj=tmp_path / "fuze.obj"):
        (tmp_path / "fuze.obj.mtl").write_text(mtl_text)
        vol = geovox.voxelize(obj, resolution=24, color=True)
        return vol.colors

    plain = geovox.voxelize(src, resolution=24, color=True).colors
    neutral = mtl.replace("map_Kd fuze uv.jpg", "map_Kd -blendu on -cc off -s 1 1 1 -o 0 0 0 "
                                                "-clamp off -mm 0 1 fuze uv.jpg")
    np.testing.assert_array_equal(run(neutral), plain)
    moved = run(mtl.replace("map_Kd fuze uv.jpg", "map_Kd -s 2 3 -o 0.25 -0.5 fuze uv.jpg"))
    lines = []
    for line in Path(src).read_text().splitlines():
        if line.startswith("vt "):
            u, v = (float(x) for x in line.split()[1:3])
            line = f"vt {2 * u + 0.25!r} {3 * v - 0.5!r}"
        lines.append(line)
    (tmp_path / "moved.obj").write_text("\n".join(lines) + "\n")
    np.testing.assert_array_equal(run(mtl, tmp_path / "moved.obj"), moved)
    assert not np.array_equal(moved, plain)


def test_map_kd_options_through_the_cli(tmp_path):
    path = obj_box(tmp_path, "newmtl m\nmap_Kd -s 0.5 0.5 -o 0.25 0.25 -clamp on t.png\n",
                   0.75, 0.75)
    assert cli_colours(path, tmp_path) == {texel(2, 1)}


def test_border_samples_like_clamp_on_the_texture():
    from geovox.colour.shading import on_texture, sample_bilinear

    rng = np.random.default_rng(7)
    img = rng.integers(0, 256, (4, 6, 3)).astype(np.uint8)
    uv = rng.uniform(-0.5, 1.5, (5000, 2))
    uv[:4] = [[0, 0], [1, 1], [0, 1], [1, 0]]
    np.testing.assert_array_equal(sample_bilinear(img, uv, ("border", "border")),
                                  sample_bilinear(img, uv, ("clamp", "clamp")))
    on = on_texture(uv, ("border", "repeat"))
    np.testing.assert_array_equal(on, (uv[:, 0] >= 0) & (uv[:, 0] <= 1))
    assert on[:4].all() and not on_texture(np.array([[np.nan, 0.5]]), ("repeat", "repeat"))[0]


# Texture pixel formats: the colour as stored, alpha not applied.

def encoded(image, fmt="PNG", **kw) -> bytes:
    out = io.BytesIO()
    image.save(out, format=fmt, **kw)
    return out.getvalue()


def png16(a: np.ndarray, colour_type: int) -> bytes:
    """A 16-bit PNG of ``a`` (h, w, channels) uint16 (Pillow writes none with colour)."""
    import struct
    import zlib

    h, w = a.shape[:2]
    rows = b"".join(b"\0" + a[y].astype(">u2").tobytes() for y in range(h))

    def chunk(kind, data):
        crc = struct.pack(">I", zlib.crc32(kind + data))
        return struct.pack(">I", len(data)) + kind + data + crc
    head = struct.pack(">IIBBBBB", w, h, 16, colour_type, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", head) + chunk(b"IDAT", zlib.compress(rows))
            + chunk(b"IEND", b""))


RGB4 = np.array([[texel(c, r) for c in range(4)] for r in range(4)], np.uint8)
GREY4 = RGB4[..., 0]  # 60 * col + 10
ALPHA4 = np.array([[0, 128, 255, 1]] * 4, np.uint8)  # fully transparent texels too


def _palette():
    im = Image.fromarray((np.arange(16).reshape(4, 4)).astype(np.uint8), "P")
    im.putpalette(RGB4.reshape(-1).tolist())
    return encoded(im, transparency=bytes([0, 64] + [255] * 14))


@pytest.mark.parametrize("name,png,want", [
    ("RGBA", lambda: encoded(Image.fromarray(np.dstack([RGB4, ALPHA4]), "RGBA")), RGB4),
    ("LA", lambda: encoded(Image.fromarray(np.dstack([GREY4, ALPHA4]), "LA")),
     np.repeat(GREY4[..., None], 3, axis=2)),
    ("L", lambda: encoded(Image.fromarray(GREY4, "L")), np.repeat(GREY4[..., None], 3, axis=2)),
    ("P with transparency", _palette, RGB4),
    ("RGB 16-bit", lambda: png16(RGB4.astype(np.uint16) * 257, 2), RGB4),
    ("RGBA 16-bit", lambda: png16(np.dstack([RGB4, ALPHA4]).astype(np.uint16) * 257, 6), RGB4),
    ("LA 16-bit", lambda: png16(np.dstack([GREY4, ALPHA4]).astype(np.uint16) * 257, 4),
     np.repeat(GREY4[..., None], 3, axis=2)),
    ("L 16-bit", lambda: png16(GREY4[..., None].astype(np.uint16) * 257, 0),
     np.repeat(GREY4[..., None], 3, axis=2)),
])
def test_texture_pixel_formats_give_their_colour_as_stored(tmp_path, name, png, want):
    data = png()
    # column 0 is fully transparent, column 1 half: their colours still count
    for col, row in ((0, 1), (1, 2), (3, 3)):
        path = obj_box(tmp_path, "newmtl m\nmap_Kd t.png\n", centre(col), obj_centre(row),
                       png=data)
        assert quiet_colours(path, res=6) == ({tuple(int(x) for x in want[row, col])}, [])


def test_grey_and_alpha_textures_in_gltf(tmp_path):
    for png, want in ((encoded(Image.fromarray(np.dstack([GREY4, ALPHA4]), "LA")), (130,) * 3),
                      (encoded(Image.fromarray(GREY4, "L")), (130,) * 3),
                      (encoded(Image.fromarray(np.dstack([RGB4, ALPHA4]), "RGBA")), texel(2, 1))):
        t = textured()
        t["images"] = [{"png": png}]
        path = write_gltf(tmp_path / "g.glb", [uv_box(centre(2), centre(1), material=0)], **t)
        assert colours_of(path) == {want}


def test_ktx2_texture_is_not_read_and_says_so(tmp_path):
    # KHR_texture_basisu: Pillow cannot decode KTX2, so the faces take the factor, with a warning.
    (tmp_path / "t.ktx2").write_bytes(b"\xabKTX 20\xbb\r\n\x1a\n" + bytes(100))
    t = textured(factor=[0.2, 0.4, 0.6, 1.0])
    t["textures"] = [{"extensions": {"KHR_texture_basisu": {"source": 0}}}]
    t["images"] = [{"uri": "t.ktx2", "mimeType": "image/ktx2"}]
    path = write_gltf(tmp_path / "k.gltf", [uv_box(centre(1), centre(1), material=0)],
                      extensions_used=["KHR_texture_basisu"], **t)
    got, said = quiet_colours(path)
    assert got == {(51, 102, 153)}
    assert len(said) == 1 and "'t.ktx2'" in said[0] and "base colour factor" in said[0]


def test_texels_of_other_pillow_modes():
    from geovox.mesh import texels

    rgba = Image.fromarray(np.array([[[200, 100, 50, 128]]], np.uint8), "RGBA")
    assert texels(rgba.convert("RGBa")).reshape(-1).tolist() in ([200, 100, 50], [199, 99, 49])
    la = Image.fromarray(np.array([[[90, 128]]], np.uint8), "LA")
    assert texels(la.convert("La")).reshape(-1).tolist() in ([90] * 3, [89] * 3)
    np.testing.assert_array_equal(texels(rgba.convert("PA")), texels(rgba.convert("P")))
    assert texels(Image.fromarray(np.array([[0.5, 1.0]], np.float32))).reshape(-1).tolist() == \
        [128] * 3 + [255] * 3
    assert texels(Image.fromarray(np.array([[90.0, 300]], np.float32))).reshape(-1).tolist() == \
        [90] * 3 + [255] * 3
    one_bit = Image.fromarray(np.array([[0, 255]], np.uint8)).convert("1")
    assert texels(one_bit).reshape(-1).tolist() == [0] * 3 + [255] * 3
    cmyk = Image.fromarray(np.array([[[200, 100, 50]]], np.uint8)).convert("CMYK")
    assert texels(cmyk).reshape(-1).tolist() == [200, 100, 50]


PLY_TYPES = {"uchar": "u1", "char": "i1", "ushort": "u2", "short": "i2", "uint": "u4",
             "int": "i4", "float": "f4", "double": "f8"}


def write_ply(path, fmt="ascii", vprops=(), vvals=None, fprops=(), fvals=None,
              vertices=None, polygons=None):
    """A PLY of ``vertices`` (default: the 2 x 2 x 2 box) and ``polygons``.

    ``vprops``/``fprops``: (type, name) after x y z / after the index list;
    ``vvals``/``fvals``: one row of values per vertex / face. ``fmt``:
    ``ascii``, ``binary_little_endian`` or ``binary_big_endian``.
    """
    if vertices is None:
        m = _trimesh_box()
        vertices, polygons = np.asarray(m.vertices), np.asarray(m.faces)
    head = ["ply", f"format {fmt} 1.0", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z"]
    head += [f"property {t} {n}" for t, n in vprops]
    head += [f"element face {len(polygons)}", "property list uchar int vertex_indices"]
    head += [f"property {t} {n}" for t, n in fprops] + ["end_header"]
    text = "\n".join(head) + "\n"
    if fmt == "ascii":
        rows = [" ".join(map(str, list(p) + (list(vvals[i]) if vprops else [])))
                for i, p in enumerate(vertices)]
        rows += [" ".join(map(str, [len(q)] + list(q) + (list(fvals[i]) if fprops else [])))
                 for i, q in enumerate(polygons)]
        path.write_text(text + "\n".join(rows) + "\n")
        return path
    e = "<" if "little" in fmt else ">"
    vd = np.dtype([(a, e + "f4") for a in "xyz"] + [(n, e + PLY_TYPES[t]) for t, n in vprops])
    v = np.zeros(len(vertices), vd)
    for k, a in enumerate("xyz"):
        v[a] = vertices[:, k]
    for k, (t, n) in enumerate(vprops):
        v[n] = np.asarray(vvals, dtype=np.float64)[:, k]
    k = len(polygons[0])
    fd = np.dtype([("n", "u1"), ("i", e + "i4", (k,))] + [(n, e + PLY_TYPES[t]) for t, n in fprops])
    f = np.zeros(len(polygons), fd)
    f["n"], f["i"] = k, polygons
    for j, (t, n) in enumerate(fprops):
        f[n] = np.asarray(fvals, dtype=np.float64)[:, j]
    path.write_bytes(text.encode() + v.tobytes() + f.tobytes())
    return path


RGB = ("red", "green", "blue")
RGBA = RGB + ("alpha",)
FORMATS = ["ascii", "binary_little_endian", "binary_big_endian"]


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("typ,names,value,want", [
    ("float", RGB, (0.2, 0.4, 0.6), (51, 102, 153)),
    ("double", RGB, (0.2, 0.4, 0.6), (51, 102, 153)),
    ("float", RGBA, (0.2, 0.4, 0.6, 0.0), (51, 102, 153)),  # alpha is not used
    ("float", RGB, (51, 102, 153), (51, 102, 153)),  # floats above 1: 0-255, as in OFF
    ("uchar", RGBA, (10, 200, 30, 0), (10, 200, 30)),
    ("ushort", RGB, (32768, 65535, 0), (128, 255, 0)),  # trimesh's 8 bits made 32768 0
    ("uint", RGB, (2 ** 31, 2 ** 32 - 1, 0), (128, 255, 0)),
])
@pytest.mark.parametrize("element", ["vertex", "face"])
def test_ply_colour_types(tmp_path, fmt, typ, names, value, want, element):
    props = [(typ, n) for n in names]
    n = 8 if element == "vertex" else 12
    kw = dict(vprops=props, vvals=[value] * n) if element == "vertex" else \
        dict(fprops=props, fvals=[value] * n)
    path = write_ply(tmp_path / "c.ply", fmt, **kw)
    assert quiet_colours(path) == ({want}, [])


@pytest.mark.parametrize("fmt", FORMATS)
def test_ply_nan_colours_are_not_black(tmp_path, fmt):
    # trimesh turns a NaN colour into 0: black, a colour the file does not state.
    rgb = [("float", n) for n in RGB]
    nan = [(np.nan,) * 3] * 8
    path = write_ply(tmp_path / "a.ply", fmt, rgb, nan)
    got, said = quiet_colours(path)
    assert got == {(204, 204, 204)}  # no vertex states a colour: the default
    assert len(said) == 1 and "NaN or infinite colour on 8 vertices" in said[0]
    one = [(0.2, 0.4, 0.6)] * 8
    one[0] = (np.nan, 0.4, 0.6)
    path = write_ply(tmp_path / "b.ply", fmt, rgb, one)
    with pytest.warns(GeovoxWarning, match="colour on 1 vertex; it counts as having no colour"):
        vol = geovox.voxelize(path, resolution=10, color=True)
    m = _trimesh_box()
    far = tuple(np.clip(np.floor((2 - m.vertices[0]) * 5), 0, 9).astype(int))
    near = tuple(np.clip(np.floor(m.vertices[0] * 5), 0, 9).astype(int))
    assert tuple(vol.colors[far][:3]) == (51, 102, 153)
    assert np.all(vol.colors[near][:3] >= (51, 102, 153)) and tuple(vol.colors[near][:3]) != \
        (51, 102, 153)  # towards white, never black
    # faces: a NaN face takes the default, the others keep theirs
    fc = [(0.0, 0.0, 1.0)] * 12
    top = [i for i, f in enumerate(m.faces) if np.all(m.vertices[f][:, 2] == 2)]
    for i in top:
        fc[i] = (np.nan, np.nan, np.nan)
    path = write_ply(tmp_path / "f.ply", fmt, fprops=rgb, fvals=fc)
    with pytest.warns(GeovoxWarning, match="colour on 2 faces; they take the default"):
        vol = geovox.voxelize(path, resolution=10, color=True)
    assert np.all(vol.colors[2:8, 2:8, 9, :3] == 204)
    assert np.all(vol.colors[:, :, 0, :3] == (0, 0, 255))


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("typ,red,blue", [("uchar", (255, 0, 0), (0, 0, 255)),
                                          ("float", (1.0, 0, 0), (0, 0, 1.0))])
def test_ply_quads_with_face_colours(tmp_path, fmt, typ, red, blue):
    # trimesh cuts the quads into triangles and its 6 face colours no longer
    # fit its 12 triangles: the load used to fail.
    path = write_ply(tmp_path / "q.ply", fmt, fprops=[(typ, n) for n in RGB],
                     fvals=[red if i == 1 else blue for i in range(6)], vertices=BOX8,
                     polygons=np.array(QUADS))
    vol = geovox.voxelize(path, resolution=10, color=True)
    assert vol.inside_count == 1000
    assert np.all(vol.colors[2:8, 2:8, 9, :3] == (255, 0, 0))
    assert np.all(vol.colors[:, :, 0, :3] == (0, 0, 255))


@pytest.mark.parametrize("fmt", FORMATS)
def test_ply_vertex_colours_beside_uvs(tmp_path, fmt):
    # trimesh keeps the UVs and drops the colours: without a texture they are the colour
    props = [("float", "s"), ("float", "t")] + [("uchar", n) for n in RGB]
    vals = [(centre(1), obj_centre(2), 10, 200, 30)] * 8
    path = write_ply(tmp_path / "uvc.ply", fmt, props, vals)
    assert quiet_colours(path) == ({(10, 200, 30)}, [])
    # with a texture (comment TextureFile), the texture, as in an OBJ
    (tmp_path / "t.png").write_bytes(texture_png())
    data = path.read_bytes().replace(b"1.0\n", b"1.0\ncomment TextureFile t.png\n", 1)
    (tmp_path / "tex.ply").write_bytes(data)
    assert quiet_colours(tmp_path / "tex.ply") == ({texel(1, 2)}, [])


def test_ply_polygons_of_every_size_with_face_colours(tmp_path):
    # The pentagonal prism of the OFF test below, as an ASCII PLY.
    ang = 2 * np.pi * np.arange(5) / 5
    ring = np.stack([1 + np.cos(ang), 1 + np.sin(ang)], axis=1)
    v = np.concatenate([np.c_[ring, np.zeros(5)], np.c_[ring, np.full(5, 2.0)]])
    polys = [list(range(4, -1, -1)), list(range(5, 10))]
    polys += [[i, (i + 1) % 5, (i + 1) % 5 + 5, i + 5] for i in range(5)]
    colours = [(255, 0, 0), (0, 255, 0)] + [(0, 0, 40 * (i + 1)) for i in range(5)]
    path = write_ply(tmp_path / "p.ply", fprops=[("uchar", n) for n in RGB], fvals=colours,
                     vertices=v, polygons=polys)
    prism = trimesh.Trimesh(v, trimesh.geometry.triangulate_quads(polys), process=False)
    want = geovox.voxelize(prism, resolution=12)
    got = geovox.voxelize(path, resolution=12, color=True)
    np.testing.assert_array_equal(got.occupancy, want.occupancy)
    top = got.colors[:, :, -1][got.occupancy[:, :, -1]]
    assert np.mean(np.all(top[:, :3] == (0, 255, 0), axis=1)) > 0.5
    bottom = got.colors[:, :, 0][got.occupancy[:, :, 0]]
    assert np.mean(np.all(bottom[:, :3] == (255, 0, 0), axis=1)) > 0.5


def test_mirror_wrap_is_repeat_over_the_unfolded_image():
    # Mirrored repeat over an image is plain repeat over the image unfolded
    # into its 2 x 2 mirror tile (period 2 in u and v): an independent check of
    # the texel arithmetic, off texel centres and across the folds.
    from geovox.colour.shading import sample_bilinear

    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (5, 7, 3)).astype(np.uint8)
    # rows run along glTF's V (down), which is 1 - v here
    unfolded = np.concatenate([img, img[::-1]], axis=0)
    unfolded = np.concatenate([unfolded, unfolded[:, ::-1]], axis=1)
    uv = rng.uniform(-4, 4, (20000, 2))
    uv[:200] = np.round(uv[:200] * 14) / 14  # on texel edges and centres too
    got = sample_bilinear(img, uv, ("mirror", "mirror"))
    # repeat over the unfolded image: u / 2 and glTF's V (1 - v) / 2
    want = sample_bilinear(unfolded, np.stack([uv[:, 0] / 2, 1 - (1 - uv[:, 1]) / 2], axis=1))
    np.testing.assert_allclose(got, want, atol=1e-9)


def test_clamp_wrap_holds_the_edge_texels():
    from geovox.colour.shading import sample_bilinear

    rng = np.random.default_rng(6)
    img = rng.integers(0, 256, (4, 6, 3)).astype(np.uint8)
    v = 1 - (2 + 0.5) / 4  # centre of row 2 (glTF's V down)
    for u, col in ((-7.0, 0), (0.5 / 6, 0), (1.0, 5), (3.3, 5)):
        got = sample_bilinear(img, np.array([[u, v]]), ("clamp", "clamp"))
        np.testing.assert_allclose(got[0] * 255, img[2, col], atol=1e-9)
    # the other axis keeps repeating when only u clamps
    got = sample_bilinear(img, np.array([[-7.0, v - 3.0]]), ("clamp", "repeat"))
    np.testing.assert_allclose(got[0] * 255, img[2, 0], atol=1e-9)


def test_off_pentagons_with_and_without_face_colours(tmp_path):
    # A pentagonal prism: two 5-gons and five quads, each face its colour.
    # trimesh's OFF reader stops on polygons of five corners; geovox reads
    # them, fanned so each triangle knows its face, and gets the volume of
    # the same prism triangulated by trimesh.
    ang = 2 * np.pi * np.arange(5) / 5
    ring = np.stack([1 + np.cos(ang), 1 + np.sin(ang)], axis=1)
    v = np.concatenate([np.c_[ring, np.zeros(5)], np.c_[ring, np.full(5, 2.0)]])
    polys = [list(range(4, -1, -1)), list(range(5, 10))]
    polys += [[i, (i + 1) % 5, (i + 1) % 5 + 5, i + 5] for i in range(5)]
    colours = [(255, 0, 0), (0, 255, 0)] + [(0, 0, 40 * (i + 1)) for i in range(5)]
    prism = trimesh.Trimesh(v, trimesh.geometry.triangulate_quads(polys), process=False)
    want = geovox.voxelize(prism, resolution=12)

    def write(name, coloured):
        lines = ["OFF", f"{len(v)} {len(polys)} 0"] + [f"{x} {y} {z}" for x, y, z in v]
        lines += [f"{len(p)} " + " ".join(map(str, p))
                  + (" %d %d %d" % colours[i] if coloured else "") for i, p in enumerate(polys)]
        (tmp_path / name).write_text("\n".join(lines) + "\n")
        return geovox.voxelize(tmp_path / name, resolution=12, color=True)

    coloured, plain = write("c.off", True), write("p.off", False)
    np.testing.assert_array_equal(coloured.occupancy, want.occupancy)
    np.testing.assert_array_equal(plain.occupancy, want.occupancy)
    assert np.all(plain.colors[plain.occupancy, :3] == 204)
    got = {tuple(int(x) for x in c) for c in coloured.colors[coloured.occupancy, :3]}
    assert got <= set(colours) and (0, 255, 0) in got and (255, 0, 0) in got
    top = coloured.colors[:, :, -1][coloured.occupancy[:, :, -1]]
    assert np.mean(np.all(top[:, :3] == (0, 255, 0), axis=1)) > 0.5


def test_truncated_off_is_still_an_error(tmp_path):
    # a five-corner face next to a quad (which trimesh cannot read) and five faces missing
    path = tmp_path / "cut.off"
    path.write_text("OFF\n10 7 0\n" + "".join(f"{i % 3} {i // 3} {i % 2}\n" for i in range(10))
                    + "5 0 1 2 3 4\n4 0 1 6 5\n")
    with pytest.raises(geovox.MeshError, match="announces 10 vertices and 7 faces.*has 10 and 2"):
        geovox.load_mesh(path)


def test_off_nan_and_unreadable_colours_warn_and_fall_back(tmp_path):
    # One NaN vertex colour must neither turn the 0-255 file into 0-1 (every
    # colour white) nor reach the uint8 cast: that vertex counts as white.
    path = write_off(tmp_path / "nan.off", "COFF", " 10 200 30 255")
    text = path.read_text().splitlines()
    text[3] = "0 0 0 nan 200 30 255"
    path.write_text("\n".join(text) + "\n")
    with pytest.warns(GeovoxWarning, match="NaN or infinite colour on 1 vertex;"):
        vol = geovox.voxelize(path, resolution=10, color=True)
    assert tuple(vol.colors[9, 9, 9, :3]) == (10, 200, 30)  # the corner far from vertex 0
    assert tuple(vol.colors[0, 0, 0, :3]) != (10, 200, 30)
    # NaN on every vertex: no colour stated, the default (not white, not black)
    path = write_off(tmp_path / "allnan.off", "COFF", " nan nan nan 255")
    with pytest.warns(GeovoxWarning, match="all 8 vertices; the file states no vertex colours"):
        assert colours_of(path) == {(204, 204, 204)}
    # A NaN face colour: that face takes the default, the others keep theirs.
    path = write_off(tmp_path / "fnan.off",
                     face_extra=lambda i: " nan 0 0" if i == 1 else " 0 0 255")
    with pytest.warns(GeovoxWarning, match="NaN or infinite colour on 1 face;"):
        vol = geovox.voxelize(path, resolution=10, color=True)
    assert np.all(vol.colors[2:8, 2:8, 9, :3] == 204)
    assert np.all(vol.colors[:, :, 0, :3] == (0, 0, 255))
    # Words where colours should be: no colours, said once, not a failed load.
    for name, header, vx, fx in [("w.off", "COFF", " red 0 0 255", lambda i: ""),
                                 ("fw.off", "OFF", "", lambda i: " x y z")]:
        path = write_off(tmp_path / name, header, vx, fx)
        with pytest.warns(GeovoxWarning, match="cannot read the (COFF vertex|face) colours"):
            assert colours_of(path) == {(204, 204, 204)}


def test_nan_color_0_counts_as_white_with_a_warning(tmp_path):
    vert, faces = box()
    colour = np.tile(np.float32([0.2, 0.4, 0.6]), (len(vert), 1))
    colour[0] = np.nan
    path = write_gltf(tmp_path / "cnan.glb", [dict(vertices=vert, faces=faces,
                                                   attributes={"COLOR_0": colour})])
    with pytest.warns(GeovoxWarning, match="NaN or infinite COLOR_0 on 1 vertex;"):
        vol = geovox.voxelize(path, resolution=10, color=True)
    assert np.all(vol.colors[vol.occupancy, 3] == 255)
    got = {tuple(int(x) for x in c) for c in vol.colors[vol.occupancy, :3]}
    assert (51, 102, 153) in got  # the other vertices keep their colour
