"""Loading polygon models into one plain triangle structure."""

from __future__ import annotations

import itertools
import json
import os
import re
import struct
import threading
import urllib.parse
import warnings

import numpy as np

from ..errors import InputNotFoundError, MeshError
from .references import Refused, check_rule, locate, resolver, why_not_read
# Mesh, Material and check_mesh are also public here, as in the loader's old geovox/mesh.py.
from ..mesh import (WRAP_MODES, Material, Mesh, build_mesh, check_mesh, texels,  # noqa: F401
                    transform_uv)


#: The diffuse colour trimesh gives a material the file does not colour.
TRIMESH_DEFAULT = np.array([102, 102, 102, 255])
#: The texel of the 2 x 2 image trimesh makes up for UVs without a texture.
TRIMESH_PLACEHOLDER = np.array([100, 100, 100, 255])


def _unit_colours(colours, n: int, problems=None):
    """(n, 3) float64 in [0, 1] from per-vertex colours as stored, or None.

    Floats are taken as they are; integers are normalised by their type's
    maximum (glTF's normalised 8- and 16-bit ``COLOR_0``; trimesh's uint8).
    A NaN or infinite colour counts as none (white, as in an OBJ), said in
    ``problems`` when given.
    """
    if colours is None:
        return None
    c = np.asarray(colours)
    if c.ndim != 2 or c.shape[1] < 3 or len(c) != n or c.dtype.kind not in "fui":
        return None
    scale = 1.0 if c.dtype.kind == "f" else float(np.iinfo(c.dtype).max)
    out = c[:, :3].astype(np.float64) / scale
    broken = ~np.isfinite(out).all(axis=1)
    if broken.any():
        out[broken] = 1.0
        if problems is not None:
            k = int(broken.sum())
            problems.append(f"NaN or infinite COLOR_0 on {k:,} {'vertex' if k == 1 else 'vertices'}"
                            f"; they count as having no colour (white)")
    return np.clip(out, 0.0, 1.0)


def _visual_parts(g, nfaces, materials, gltf=None, made=None, original=None):
    """Per-face material, corner UVs and vertex colours of one trimesh geometry.

    ``original`` is the scene's geometry ``g`` was copied from: trimesh's
    copies of textured visuals drop their vertex colours (glTF ``COLOR_0``).

    ``gltf`` holds what :func:`_gltf_rewrite` found for each material tag of
    a glTF file; ``made`` maps a tag to its :class:`Material`'s index in
    ``materials``, so primitives sharing a material share its texture.
    """
    visual = getattr(g, "visual", None)
    kind = getattr(visual, "kind", None)
    fm = np.full(nfaces, -1, dtype=np.int64)
    uv = vc = None
    source = g if original is None else original
    mat = getattr(visual, "material", None) if kind == "texture" else None
    fact = gltf["materials"].get(getattr(mat, "name", None)) if gltf and mat is not None else None
    if fact is not None:
        tag = mat.name
        if tag not in made:
            m = Material(name=fact["name"], kd=fact["kd"], wrap=fact["wrap"], vertex_tint=True)
            image = getattr(mat, "baseColorTexture", None)
            if image is not None:
                try:
                    m.image = texels(image)
                    m.texture_file = fact["file"]
                except Exception as exc:  # Pillow raises several types for bad images
                    gltf["problems"].append(_no_texture(fact, f"{type(exc).__name__}: {exc}"))
            elif fact["texture"] is not None:
                said = gltf.setdefault("said", [])
                refused = [line for name, line in said if name == fact.get("uri")]
                said[:] = [x for x in said if x[0] != fact.get("uri")]
                why = why_not_read(fact["uri"]) if refused else "it could not be loaded"
                gltf["problems"].append(_no_texture(fact, why))
            made[tag] = len(materials)
            materials.append(m)
        fm[:] = made[tag]
        if visual.uv is not None and len(visual.uv) == len(g.vertices):
            uv = np.asarray(visual.uv, dtype=np.float64)
            if fact["transform"] is not None:
                # KHR_texture_transform acts on glTF's UVs (V down); trimesh
                # has flipped V. Affine, so applying it to the corners is
                # the same as applying it to interpolated UVs.
                flip = np.array([1.0, -1.0]), np.array([0.0, 1.0])
                uv = transform_uv(uv * flip[0] + flip[1], fact["transform"]) * flip[0] + flip[1]
            uv = uv[g.faces]
        vc = _unit_colours(_vertex_attribute(source, "color"), len(g.vertices), gltf["problems"])
    elif kind == "texture":
        m = Material(name=getattr(mat, "name", None) or "material")
        image = getattr(mat, "image", None) or getattr(mat, "baseColorTexture", None)
        if image is not None and image.size == (2, 2) and np.all(
                np.asarray(image.convert("RGBA")) == TRIMESH_PLACEHOLDER):
            # trimesh.visual.material.empty_material's stand-in for a
            # texture the file does not have (a PLY with UVs only)
            image = None
        if image is not None:
            m.image = texels(image)
        if hasattr(mat, "baseColorFactor"):
            # A trimesh PBR material (glTF's model) made in Python: base colour
            # = factor x texture x vertex colour; the factor's default in the
            # glTF specification is white.
            factor = mat.baseColorFactor
            m.kd = (np.ones(3) if factor is None
                    else np.asarray(factor, dtype=np.float64)[:3] / 255.0)
            m.vertex_tint = True
            vc = _unit_colours(_vertex_attribute(source, "color"), len(g.vertices))
        else:
            colour = getattr(mat, "diffuse", None)
            # trimesh gives materials it makes up (a PLY's texture, UVs
            # without any) its default 0.4 grey: not the file's colour.
            if colour is not None and not np.array_equal(np.asarray(colour), TRIMESH_DEFAULT):
                m.kd = np.asarray(colour, dtype=np.float64)[:3] / 255.0
        fm[:] = len(materials)
        materials.append(m)
        if visual.uv is not None and len(visual.uv) == len(g.vertices):
            uv = np.asarray(visual.uv, dtype=np.float64)[g.faces]
    elif kind == "vertex":
        vc = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
    elif kind == "face" and len(visual.face_colors) == nfaces:
        # Face colours become flat per-face materials. (A PLY's colours of
        # polygons trimesh cut into triangles do not match its faces: see _ply_colours.)
        fc = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0
        uniq, inverse = np.unique(fc, axis=0, return_inverse=True)
        for colour in uniq:
            materials.append(Material(name="face colour", kd=colour))
        fm[:] = len(materials) - len(uniq) + inverse.reshape(-1)
    return fm, uv, vc


def _vertex_attribute(g, key: str):
    """A geometry's textured-visual vertex attribute, or None."""
    store = getattr(getattr(g, "visual", None), "vertex_attributes", None)
    return store.get(key) if store is not None else None


def _no_texture(fact, why: str) -> str:
    return (f"cannot read the base colour texture {fact['texture']} of material "
            f"{fact['name']!r} ({why}); using its base colour factor")


# ---------------------------------------------------------------------------
# glTF materials.
#
# trimesh reads glTF geometry well but keeps only part of a material: the
# first texture coordinate set whatever `texCoord` says, no sampler (every
# texture would repeat), no KHR_texture_transform, the base colour factor
# rounded to 8 bits, specular-glossiness converted to metallic-roughness
# (which changes the diffuse colour), COLOR_0 without a material squeezed into
# 8 bits, and percent-escaped file names (`my%20map.png`) not found. So
# before trimesh parses a glTF file, geovox reads its JSON and rewrites it:
# each material is renamed to a tag looked up afterwards (with its factor,
# wrap modes and texture transform), a primitive's TEXCOORD_0 is pointed at
# the set its base colour texture uses, a specular-glossiness material's
# diffuse becomes its base colour, a primitive with COLOR_0 but no material
# gets glTF's default material (base colour factor white), and escaped URIs
# are unescaped where that names a file that exists.

_GLTF_TAG = "geovox-gltf-material-"


def _numbers(value, n: int):
    """``value`` as n floats if it is a list of n finite numbers, else None."""
    if not isinstance(value, list) or len(value) != n:
        return None
    if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        return None
    out = np.asarray(value, dtype=np.float64)
    return out if np.all(np.isfinite(out)) else None


def _uv_transform(tt: dict) -> np.ndarray:
    """(3, 3) float64: KHR_texture_transform's offset x rotation x scale."""
    offset = _numbers(tt.get("offset"), 2)
    scale = _numbers(tt.get("scale"), 2)
    rotation = tt.get("rotation", 0.0)
    ox, oy = offset if offset is not None else (0.0, 0.0)
    sx, sy = scale if scale is not None else (1.0, 1.0)
    r = float(rotation) if isinstance(rotation, (int, float)) and np.isfinite(rotation) else 0.0
    c, s = np.cos(r), np.sin(r)
    translate = np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1.0]])
    rotate = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])
    return translate @ rotate @ np.diag([sx, sy, 1.0])


def _base_colour_texture(fact: dict, ref, textures, samplers, images, folder: str, rule: str):
    """Fill ``fact``'s wrap, texture, uri, file and transform from a ``baseColorTexture`` reference.

    Returns the texture coordinate set it reads (an int), or None where
    ``ref`` names no texture of the file.
    """
    index = ref.get("index") if isinstance(ref, dict) else None
    if not (isinstance(index, int) and 0 <= index < len(textures)):
        return None
    tex = textures[index]
    sampler = tex.get("sampler")
    if isinstance(sampler, int) and 0 <= sampler < len(samplers):
        codes = (samplers[sampler].get(k, 10497) for k in ("wrapS", "wrapT"))
        fact["wrap"] = tuple(WRAP_MODES.get(c, "repeat") if isinstance(c, int)
                             else "repeat" for c in codes)
    source = tex.get("source")
    for e in (tex.get("extensions") or {}).values():
        if source is None and isinstance(e, dict):
            source = e.get("source")
    uri = (images[source].get("uri") if isinstance(source, int)
           and 0 <= source < len(images) else None)
    external = isinstance(uri, str) and not uri.startswith("data:")
    fact["texture"] = repr(uri) if external else f"(image {source}, embedded)"
    fact["uri"] = uri if external else None
    if external:
        fact["file"] = locate(uri, folder, rule)[0]
    n = ref.get("texCoord", 0)
    tt = (ref.get("extensions") or {}).get("KHR_texture_transform")
    if isinstance(tt, dict):
        fact["transform"] = _uv_transform(tt)
        n = tt.get("texCoord", n)
    return n if isinstance(n, int) else 0


def _gltf_rewrite(header: dict, path: str, rule: str = "anywhere", read_buffer=None) -> dict:
    """Rewrite a glTF JSON header in place for trimesh (see above).

    ``rule`` is how the files it names are found (see
    :mod:`geovox.io.references`); ``read_buffer(i) -> bytes`` reads buffer
    ``i``, for the triangle strips and fans rewritten into triangles (see
    :mod:`geovox.io.gltf`; None: they are left to trimesh).

    Returns
    -------
    dict
        ``materials``: tag -> facts of that material (``name``, ``kd`` (3,)
        float64, ``wrap``, ``transform`` (3, 3) float64 or None, ``texture``:
        a description of its base colour image, or None); ``problems``: lines
        for the mesh's problems.
    """
    folder = os.path.dirname(os.path.abspath(path))
    problems: list = []
    if read_buffer is not None:
        from .gltf import triangulate

        left = triangulate(header, read_buffer)
        if left:
            problems.append("; ".join(dict.fromkeys(left)))

    def listed(key):
        value = header.get(key)
        return [x if isinstance(x, dict) else {} for x in value] if isinstance(value, list) else []

    textures, samplers, images = listed("textures"), listed("samplers"), listed("images")
    for entry in images + listed("buffers"):
        uri = entry.get("uri")
        if isinstance(uri, str) and not uri.startswith("data:"):
            plain = urllib.parse.unquote(uri)
            if (plain != uri and not os.path.exists(os.path.join(folder, uri))
                    and os.path.exists(os.path.join(folder, plain))):
                entry["uri"] = plain
    materials = header.get("materials") if isinstance(header.get("materials"), list) else []
    primitives = [p for m in listed("meshes") if isinstance(m.get("primitives"), list)
                  for p in m["primitives"] if isinstance(p, dict)
                  and isinstance(p.get("attributes"), dict)]
    default = None
    for p in primitives:
        if "material" not in p and "COLOR_0" in p["attributes"]:
            if default is None:
                default = len(materials)
                materials.append({"name": "glTF default material"})
                header["materials"] = materials
            p["material"] = default
    facts, texcoord = {}, {}
    for i, mat in enumerate(materials):
        if not isinstance(mat, dict):
            continue
        name = mat.get("name") if isinstance(mat.get("name"), str) else f"material {i}"
        ext = mat.get("extensions")
        sg = ext.get("KHR_materials_pbrSpecularGlossiness") if isinstance(ext, dict) else None
        if isinstance(sg, dict):
            # The diffuse colour is this model's base colour; trimesh's
            # conversion to metallic-roughness would change it.
            pbr = {"baseColorFactor": sg.get("diffuseFactor", [1, 1, 1, 1])}
            if "diffuseTexture" in sg:
                pbr["baseColorTexture"] = sg["diffuseTexture"]
            mat["pbrMetallicRoughness"] = pbr
            del ext["KHR_materials_pbrSpecularGlossiness"]
        pbr = mat.get("pbrMetallicRoughness")
        pbr = pbr if isinstance(pbr, dict) else {}
        factor = _numbers(pbr.get("baseColorFactor", [1, 1, 1, 1]), 4)
        if factor is None:
            problems.append(f"material {name!r} has a baseColorFactor that is not 4 finite numbers "
                            f"({pbr.get('baseColorFactor')!r}); using white")
            factor = np.ones(4)
        fact = {"name": name, "kd": np.clip(factor[:3], 0.0, 1.0), "wrap": ("repeat", "repeat"),
                "transform": None, "texture": None, "file": None}
        n = _base_colour_texture(fact, pbr.get("baseColorTexture"), textures, samplers, images,
                                 folder, rule)
        if n is not None:
            texcoord[i] = n
        tag = _GLTF_TAG + str(i)
        mat["name"] = tag
        facts[tag] = fact
    missing = set()
    for p in primitives:
        n = texcoord.get(p.get("material"))
        if n is None or p.get("mode", 4) not in (4, 5):  # no texture, or not triangles
            continue
        attrs = p["attributes"]
        if f"TEXCOORD_{n}" in attrs:
            attrs["TEXCOORD_0"] = attrs[f"TEXCOORD_{n}"]
        else:
            # No such set: no UVs, so the texture cannot be placed.
            attrs.pop("TEXCOORD_0", None)
            missing.add((p["material"], n))
    for i, n in sorted(missing):
        problems.append(f"material {facts[_GLTF_TAG + str(i)]['name']!r} takes its base colour "
                        f"texture's coordinates from TEXCOORD_{n}, which a primitive using it "
                        f"does not have; those faces take the base colour factor")
    return {"materials": facts, "problems": problems}


def _gltf_file(path: str, rule: str = "anywhere", said=None):
    """A glTF file with its JSON rewritten by :func:`_gltf_rewrite`.

    ``rule`` is how the files it names are found; ``said`` collects the
    references refused (see :func:`geovox.io.references.resolver`).

    Returns
    -------
    (bytes, dict) or None
        The rewritten file and what :func:`_gltf_rewrite` returned; None for
        a file whose JSON cannot be read (trimesh then reads it as it is and
        says what is wrong).
    """
    with open(path, "rb") as f:
        data = f.read()
    glb = data[:4] == b"glTF"
    if glb:
        if len(data) < 20:
            return None
        version, _, n, kind = struct.unpack_from("<IIII", data, 4)
        if kind != 0x4E4F534A:  # "JSON"
            return None
        raw, tail = data[20:20 + n], memoryview(data)[20 + n:]
    else:
        raw, tail = data, None
    try:
        header = json.loads(raw.decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError, RecursionError):
        return None
    if not isinstance(header, dict):
        return None
    try:
        facts = _gltf_rewrite(header, path, rule, _buffer_reader(header, path, rule, tail))
    except (TypeError, AttributeError, KeyError, ValueError, IndexError):
        return None  # a header too odd to rewrite safely: trimesh reads the file as it is
    facts["said"] = said if said is not None else []
    text = json.dumps(header, separators=(",", ":")).encode("utf-8")
    if not glb:
        return text, facts
    text += b" " * (-len(text) % 4)  # chunks are 4-byte aligned, JSON padded with spaces
    head = b"glTF" + struct.pack("<IIII", version, 20 + len(text) + len(tail), len(text),
                                 0x4E4F534A)
    return b"".join([head, text, tail]), facts


def _buffer_reader(header: dict, path: str, rule: str, tail):
    """``read(i) -> bytes``: glTF buffer ``i`` (the GLB's BIN chunk, a ``data:`` URI or a file).

    ``tail`` is what follows a GLB's JSON chunk (None for a ``.gltf``).
    Raises :class:`geovox.io.gltf.Unreadable` where the buffer cannot be read,
    or its file is not read under ``rule``.
    """
    from .gltf import Unreadable

    folder = os.path.dirname(os.path.abspath(path))
    buffers = header.get("buffers") if isinstance(header.get("buffers"), list) else []

    def read(i):
        if not isinstance(i, int) or not 0 <= i < len(buffers) or not isinstance(buffers[i],
                                                                                   dict):
            raise Unreadable(f"buffer {i!r} does not exist")
        uri = buffers[i].get("uri")
        if uri is None:
            if tail is None or len(tail) < 8 or bytes(tail[4:8]) != b"BIN\0" or i != 0:
                raise Unreadable(f"buffer {i} has no data")
            return bytes(tail[8:8 + struct.unpack_from("<I", tail, 0)[0]])
        if not isinstance(uri, str):
            raise Unreadable(f"buffer {i} has a uri that is not text")
        if uri.startswith("data:"):
            at = uri.find("base64,")
            if at < 0:
                raise Unreadable(f"buffer {i} is a data URI without base64 data")
            import base64

            return base64.b64decode(uri[at + 7:])
        found, refused = locate(uri, folder, rule)
        if found is None:
            raise Unreadable(why_not_read(uri) if refused else f"{uri!r} is missing")
        with open(found, "rb") as f:
            return f.read()

    return read


_OFF_HEADER = re.compile(r"(ST)?(C)?(N)?(4)?(n)?OFF")


def _read_off(path: str, mesh: Mesh | None) -> Mesh | None:
    """An OFF file's colours, which trimesh's reader skips, and its polygons.

    ``mesh`` is what trimesh read from the file, returned as it is when the
    file has no colours; None where trimesh failed (its OFF reader stops on
    polygons of more than four corners), and then the file is read here.
    Colours: ``COFF`` vertex colours (``x y z [nx ny nz] r g b [a]``) and
    face colours (``n i1 ... in r g b [a]``), each as integers 0-255 or as
    numbers 0-1 (0-255 when any exceeds 1). Polygons are fanned here, so
    each triangle knows its face; a face without a colour in a file with
    face colours takes the default. Face colours are looked for when the
    first face has one. Returns None when the file cannot be read here either.
    """
    with open(path, "rb") as f:
        text = f.read().decode("utf-8", errors="replace")
    if "#" in text:
        text = re.sub(r"#[^\n]*", "", text)
    # Non-blank lines, as an iterator (C-level: an uncoloured file costs one
    # pass over its lines, not a split of each).
    content = filter(None, map(str.strip, text.splitlines()))
    first = next(content, "").split()
    head = _OFF_HEADER.fullmatch(first[0]) if first else None
    if head is None:
        return mesh
    try:
        counts = first[1:3] if len(first) > 1 else next(content, "").split()[:2]
        nv, nf = int(counts[0]), int(counts[1])
    except (IndexError, ValueError):
        return mesh
    if mesh is not None and len(mesh.vertices) != nv:
        return mesh
    if head.group(2) or mesh is None:
        vlines = [ln.split() for ln in itertools.islice(content, nv)]
    else:
        vlines = None
        next(itertools.islice(content, nv, nv), None)  # skip the vertices
    face = next(content, "").split()
    face_colours = bool(face) and face[0].isdigit() and len(face) >= 4 + int(face[0])
    if mesh is not None and vlines is None and not face_colours:
        return mesh
    flines = [face] + [ln.split() for ln in itertools.islice(content, nf - 1)] if face else []
    if mesh is None and (len(vlines) != nv or len(flines) != nf):
        raise MeshError(f"{path}: the OFF header announces {nv:,} vertices and {nf:,} faces, "
                        f"but the file has {len(vlines):,} and {len(flines):,}; it is cut short")

    problems = mesh.problems if mesh is not None else []

    def unit(rows):
        """(k, 3) float64 in [0, 1] and (k,) bool: which rows were finite.

        A NaN or infinite row becomes white (no colour, as in an OBJ) and
        does not decide the 0-255 scale; a word raises ValueError.
        """
        c = np.array(rows, dtype=np.float64)
        ok = np.isfinite(c).all(axis=1) if c.ndim == 2 else np.ones(len(c), dtype=bool)
        scale = 255.0 if c[ok].size and c[ok].max() > 1.0 else 1.0
        c[~ok] = scale
        return np.clip(c / scale, 0.0, 1.0), ok

    try:
        if mesh is None:
            vertices = np.array([ln[:3] for ln in vlines], dtype=np.float64).reshape(nv, 3)
        else:
            vertices = mesh.vertices
        faces = fm = None
        materials = []
        if mesh is None or face_colours:
            faces, fm, materials = _off_faces(flines, unit, face_colours, problems, path)
            if mesh is not None and fm is None:
                faces = None  # face colours unreadable: trimesh's faces, as without colours
    except ValueError:  # what cannot be read here: trimesh's result or its error
        return mesh
    vc = None
    if head.group(2):
        at = 3 + (1 if head.group(4) else 0) + (3 if head.group(3) else 0)
        try:
            vc, ok = unit([ln[at:at + 3] for ln in vlines])
        except ValueError:  # unreadable colours (words, or rows cut short): none
            vc = None
            problems.append(f"{path}: cannot read the COFF vertex colours; the vertices "
                            f"count as having none")
        if vc is not None and vc.shape != (nv, 3):
            vc = None  # fewer than three numbers after the position: no colours stated
        elif vc is not None and not ok.any():
            # no vertex states a colour: the file has none (the default), as for a PLY
            vc = None
            problems.append(f"{path}: NaN or infinite colour on all {nv:,} vertices; the file "
                            f"states no vertex colours, so the default colour is used")
        elif vc is not None and not ok.all():
            n = int((~ok).sum())
            problems.append(f"{path}: NaN or infinite colour on {n:,} "
                            f"{'vertex' if n == 1 else 'vertices'}; they count as having no "
                            f"colour (white)")
    if mesh is not None and vc is None and faces is None:
        return mesh
    return build_mesh(vertices, mesh.faces if faces is None else faces, path,
                      face_material=fm, materials=materials, vertex_colors=vc,
                      problems=problems)


def _off_faces(flines, unit, coloured_file: bool, problems: list, path: str):
    """Fanned faces (m, 3) of OFF face lines, face materials (m,) and their materials.

    A face colour that cannot be read (a word, NaN) leaves its face without
    one (the default colour) and is appended to ``problems``.

    Raises
    ------
    ValueError
        A face line whose indices cannot be read.
    """
    sizes = np.array([int(ln[0]) for ln in flines], dtype=np.int64)
    if np.any(sizes < 0) or any(len(ln) < 1 + k for ln, k in zip(flines, sizes.tolist())):
        raise ValueError("a face with fewer indices than it says")
    keep = sizes >= 3
    corners = np.array([int(i) for ln, k, ok in zip(flines, sizes.tolist(), keep) if ok
                        for i in ln[1:1 + k]], dtype=np.int64)
    first = np.r_[0, np.cumsum(sizes[keep])[:-1]]
    n_tri = sizes[keep] - 2
    poly = np.repeat(np.arange(len(first)), n_tri)
    j = np.arange(len(poly)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    c0 = first[poly]
    faces = corners[np.stack([c0, c0 + j, c0 + j + 1], axis=1)]
    if not coloured_file:
        return faces, None, []
    rest = [ln[1 + k:1 + k + 3] for ln, k in zip(flines, sizes.tolist())]
    has = np.array([len(r) == 3 for r in rest])
    try:
        fc, ok = unit([r if len(r) == 3 else ["0", "0", "0"] for r in rest])
    except ValueError:
        problems.append(f"{path}: cannot read the face colours; the faces count as having none")
        return faces, None, []
    if not ok.all():
        n = int((~ok).sum())
        problems.append(f"{path}: NaN or infinite colour on {n:,} face{'' if n == 1 else 's'}; "
                        f"{'it takes' if n == 1 else 'they take'} the default colour")
    fc, has = fc[keep][poly], (has & ok)[keep][poly]
    uniq, inverse = np.unique(fc, axis=0, return_inverse=True)
    materials = [Material(name="face colour", kd=c) for c in uniq]
    return faces, np.where(has, inverse.reshape(-1), -1), materials


_RGB = ("red", "green", "blue")


def _ply_unit(element, problems: list, what: tuple, path: str):
    """(k, 3) float64 colours in [0, 1] of a PLY element as stored, and (k,) bool: finite.

    Integers are scaled by their type's maximum (255 for ``uchar``, 65535 for
    ``ushort``; signed types read as the unsigned type of their size); floats
    are 0-1, or 0-255 when a finite one exceeds 1 (as for OFF). Rows with a
    NaN or infinite channel are not colours: NaN in the result, said in
    ``problems``. None when the element has no red, green and blue.
    """
    props = element.get("properties", {}) if isinstance(element, dict) else {}
    if not all(c in props for c in _RGB):
        return None
    try:
        cols = [np.asarray(element["data"][c]).reshape(-1) for c in _RGB]
        c = np.stack(cols, axis=1)
    except (KeyError, ValueError, TypeError, IndexError):
        return None
    if c.dtype.kind == "f":
        c = c.astype(np.float64)
        ok = np.isfinite(c).all(axis=1)
        scale = 255.0 if ok.any() and c[ok].max() > 1.0 else 1.0
    elif c.dtype.kind in "ui":
        c = c.astype(f"u{c.dtype.itemsize}")  # two's complement: char -1 is 255
        scale = float(np.iinfo(c.dtype).max)
        c = c.astype(np.float64)
        ok = np.ones(len(c), dtype=bool)
    else:
        return None
    out = np.clip(c / scale, 0.0, 1.0)
    out[~ok] = np.nan
    if not ok.all():
        k = int((~ok).sum())
        problems.append(f"{path}: NaN or infinite colour on {k:,} {what[k != 1]}")
    return out


def _ply_polygons(element):
    """(lengths (p,) int64, corners (sum,) int64) of a PLY face element's vertex lists, or None."""
    data = element.get("data") if isinstance(element, dict) else None
    for key in ("vertex_indices", "vertex_index"):
        try:
            lists = data[key]
        except (KeyError, ValueError, TypeError, IndexError):
            continue
        if getattr(lists, "dtype", None) is not None and lists.dtype.names:
            lists = lists[lists.dtype.names[-1]]  # binary: (count, indices)
        if isinstance(lists, np.ndarray) and lists.dtype != object and lists.ndim == 2:
            n, k = lists.shape
            return np.full(n, k, dtype=np.int64), lists.reshape(-1).astype(np.int64)
        rows = [np.asarray(r, dtype=np.int64).reshape(-1) for r in lists]
        lengths = np.array([len(r) for r in rows], dtype=np.int64)
        return lengths, (np.concatenate(rows) if rows else np.zeros(0, np.int64))
    return None


def _ply_colours(loaded, mesh: Mesh, path: str) -> Mesh:
    """A PLY's vertex or face colours as the file stores them.

    trimesh reads colour properties of any type, then squeezes them into
    8 bits for its visual: a NaN becomes 0 (black, a colour the file does not
    state), 16-bit values wrap (32768 becomes 0), floats above 1 clip to
    white, and colours of polygons it cut into triangles no longer match the
    triangles. Its raw reading (``metadata["_ply_raw"]``) keeps them as
    stored, so they are taken from there, for the visual trimesh chose
    (vertex or face colours); vertex colours beside UVs, which trimesh
    drops, are taken too (the texture, if any, replaces them, as in an OBJ).
    A NaN face colour leaves its face without a
    colour (the default); a NaN vertex colour counts as none (white, as in
    OBJ and OFF), and when every vertex's is NaN the file states no vertex
    colours at all (the default). Alpha is not used.
    """
    meta = getattr(loaded, "metadata", None)
    raw = meta.get("_ply_raw") if isinstance(meta, dict) else None
    kind = getattr(getattr(loaded, "visual", None), "kind", None)
    if not isinstance(raw, dict) or kind not in ("vertex", "face", "texture"):
        return mesh
    problems = mesh.problems
    element = raw.get("vertex" if kind == "texture" else kind)
    try:
        exact = all(np.dtype(element["properties"][c]) == np.uint8 for c in _RGB)
    except (KeyError, TypeError):
        exact = False
    if exact and kind == "vertex":
        return mesh  # 8-bit colours: trimesh's are the file's
    if kind in ("vertex", "texture"):
        vc = _ply_unit(raw.get("vertex"), problems, ("vertex", "vertices"), path)
        if vc is None or len(vc) != len(mesh.vertices):
            return mesh
        broken = np.isnan(vc).any(axis=1)
        if broken.all():
            problems[-1] += "; the file states no vertex colours, so the default colour is used"
            if kind == "texture":
                return mesh
            return build_mesh(mesh.vertices, mesh.faces, path, problems=problems)
        if broken.any():
            problems[-1] += (f"; {'it counts' if broken.sum() == 1 else 'they count'} as having "
                             f"no colour (white)")
            vc[broken] = 1.0
        mesh.vertex_colors = vc
        if kind == "texture":
            # trimesh keeps the UVs and drops the vertex colours. Its made-up
            # material (no texture, no colour) states nothing: the vertex
            # colours are the colour, as for a PLY without UVs.
            for m in mesh.materials:
                if m.image is None and m.kd is None:
                    m.defined = False
        return mesh
    fc = _ply_unit(raw.get("face"), problems, ("face", "faces"), path)
    polygons = _ply_polygons(raw.get("face"))
    if fc is None or polygons is None or len(fc) != len(polygons[0]):
        return mesh
    lengths, corners = polygons
    if np.all(lengths == 3) and len(lengths) == len(mesh.faces):
        if exact:
            return mesh
        faces, poly = mesh.faces, np.arange(len(lengths))
    else:
        # Fan each polygon, so each triangle knows its polygon (trimesh's own
        # cut of quads uses the same diagonal).
        first = np.r_[0, np.cumsum(lengths)[:-1]]
        keep = np.flatnonzero(lengths >= 3)
        n_tri = lengths[keep] - 2
        poly = np.repeat(keep, n_tri)
        j = np.arange(len(poly)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
        c0 = first[poly]
        faces = corners[np.stack([c0, c0 + j, c0 + j + 1], axis=1)]
    broken = np.isnan(fc).any(axis=1)
    if broken.any():
        problems[-1] += f"; {'it takes' if broken.sum() == 1 else 'they take'} the default colour"
    fc_ok = np.where(broken[:, None], 0.0, fc)
    uniq, inverse = np.unique(fc_ok[~broken], axis=0, return_inverse=True)
    key = np.full(len(fc), -1, dtype=np.int64)
    key[~broken] = inverse.reshape(-1)
    materials = [Material(name="face colour", kd=c) for c in uniq]
    return build_mesh(mesh.vertices, faces, path, face_material=key[poly], materials=materials,
                      problems=problems)


#: What a file type is, for messages ("cannot be read as glTF binary (.glb)").
FORMAT_NAMES = {
    ".glb": "glTF binary", ".gltf": "glTF", ".stl": "STL", ".ply": "PLY", ".off": "OFF",
    ".3mf": "3MF", ".dae": "COLLADA", ".zae": "COLLADA archive", ".3dxml": "3DXML",
    ".xaml": "XAML", ".xyz": "XYZ point", ".zip": "zip archive", ".gz": "compressed",
    ".bz2": "compressed", ".tar": "tar archive", ".obj": "OBJ", ".step": "STEP",
    ".stp": "STEP", ".ctm": "OpenCTM",
}

#: Files people try that are not meshes, with what to do instead.
NOT_A_MESH = {
    ".bin": "a glTF buffer, not a mesh; convert the .gltf file that refers to it",
    ".mtl": "an OBJ material library, not a mesh; convert the .obj file that uses it",
    ".binvox": "already a voxel grid (binvox), not a polygon mesh",
    ".png": "an image, not a mesh", ".jpg": "an image, not a mesh",
    ".jpeg": "an image, not a mesh", ".bmp": "an image, not a mesh",
    ".tga": "an image, not a mesh", ".dxf": "a 2-D drawing (DXF), not a 3-D mesh",
    ".svg": "a 2-D drawing (SVG), not a 3-D mesh",
}

#: Held while trimesh reads a file (see load_mesh).
_TRIMESH_LOAD = threading.Lock()

#: The pip name of each optional module trimesh's readers import.
PIP_NAMES = {"collada": "pycollada", "cascadio": "cascadio",
             "networkx": "networkx", "lxml": "lxml", "DracoPy": "DracoPy",
             "ezdxf": "ezdxf", "shapely": "shapely", "meshio": "meshio", "rtree": "rtree"}

# trimesh logs (and carries on) when it drops geometry it could not read; these
# messages mean the mesh it returns is missing parts, so geovox refuses it
# rather than voxelise placeholder zeros or half a model.
# Some are debug messages: a glTF triangle fan skipped, a broken file inside a
# zip left out of the scene, a glTF mesh dropped.
_LOST_GEOMETRY = re.compile(
    r"didn't decode, values are placeholder zeros|failed to process extension "
    r"KHR_draco_mesh_compression|PLY failed to populate|unable to load Rep|"
    r"unsupported format|included but not defined|unable to get faces|"
    r"skipping primitive with mode 6|failed to load file in zip|failed to load mesh")


def _kind(path: str) -> str:
    """``"glTF binary (.glb)"``: the format a file's extension claims, for messages."""
    ext = os.path.splitext(path)[1].lower()
    name = FORMAT_NAMES.get(ext)
    return f"{name} ({ext})" if name else (ext or "a file without an extension")


def _load_failure(path: str, exc: Exception) -> str:
    """One line saying, in words, why trimesh could not read ``path``."""
    ext = os.path.splitext(path)[1].lower()
    text = str(exc).strip().splitlines()[0].strip() if str(exc).strip() else ""
    missing = re.search(r"No module named '([\w.]+)'", text)
    if isinstance(exc, ImportError) and (getattr(exc, "name", None) or missing):
        # trimesh re-raises a stored ImportError for readers whose module is
        # missing, without its `name`; the text still names it.
        module = (exc.name or missing.group(1)).split(".")[0]
        pip = PIP_NAMES.get(module, module)
        return (f"{path}: reading {_kind(path)} files needs the Python package {pip!r}, which is "
                f"not installed (pip install {pip})")
    if isinstance(exc, Refused):
        return f"{path}: refers to a file that is not read: {exc}"
    if isinstance(exc, FileNotFoundError):
        missing = exc.filename or text.strip("'\"") or "a file"
        return f"{path}: refers to a file that is missing: {missing}"
    if ext in NOT_A_MESH:
        return f"{path}: this is {NOT_A_MESH[ext]}"
    if isinstance(exc, (NotImplementedError, KeyError)) and "not supported" in text:
        return (f"{path}: cannot be read as a mesh: geovox does not read "
                f"{ext + ' files' if ext else 'files without an extension'}; it reads "
                f"{' '.join(readable_extensions())}")
    detail = type(exc).__name__ + (f": {text[:120]}" if text else "")
    return (f"{path}: cannot be read as {_kind(path)}; the file is damaged or not what its "
            f"extension says (trimesh's reader stopped with {detail})")


def readable_extensions() -> list:
    """Extensions geovox reads: OBJ itself, the rest through trimesh (``.zip`` etc. included)."""
    import trimesh

    exts = {".obj"} | {"." + e.lower() for e in trimesh.available_formats()}
    return sorted(exts - set(NOT_A_MESH) - {".json", ".dict", ".dict64", ".npz", ".stl_ascii"})


def _no_faces(source: str, parts) -> str:
    """Why a file with no triangles cannot be voxelised, naming what it holds instead."""
    counts = {}
    for g in parts:
        kind = type(g).__name__
        if kind == "PointCloud":
            what = f"a point cloud ({len(g.vertices):,} points)"
        elif kind in ("Path2D", "Path3D"):
            n = len(g.entities)
            what = f"lines ({n:,} line {'piece' if n == 1 else 'pieces'})"
        elif kind == "Trimesh":
            what = f"a mesh with no faces ({len(g.vertices):,} vertices)"
        else:
            what = f"a {kind}"
        counts[what] = counts.get(what, 0) + 1
    if not counts:
        return f"{source}: contains no geometry (no vertices or faces could be read from it)"
    held = ", ".join(k if n == 1 else f"{n} x {k}" for k, n in counts.items())
    return (f"{source}: has no faces, only {held}; geovox voxelises the inside of a "
            f"triangle surface")


def from_trimesh(obj, source: str = "<trimesh>", *, _gltf=None) -> Mesh:
    """Convert a ``trimesh.Trimesh`` or ``trimesh.Scene`` (transforms applied),
    keeping each geometry's material, UVs and vertex colours.

    Point clouds and lines in a scene are skipped; a scene with no faces at
    all is a :class:`MeshError` that says what it holds instead. (``_gltf``:
    what :func:`_gltf_rewrite` found in the file trimesh read.)
    """
    import trimesh

    if isinstance(obj, trimesh.Scene):
        every = list(obj.dump(concatenate=False))
        parts = [g for g in every if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not parts:
            raise MeshError(_no_faces(source, every))
        originals = [obj.geometry.get(g.metadata.get("name")) for g in parts]
        # A scene's nodes are its parts (labels="part"): named after node and
        # mesh, so a mesh two nodes use gives two parts.
        part_names = [_part_name(g, k) for k, g in enumerate(parts)]
    elif isinstance(obj, trimesh.Trimesh):
        parts, originals, part_names = [obj], [obj], None
    elif isinstance(obj, trimesh.parent.Geometry):
        raise MeshError(_no_faces(source, [obj]))
    else:
        raise MeshError(f"{source}: contains no triangle mesh (got {type(obj).__name__})")
    verts, faces, fms, uvs, vcs, materials, offset, made = [], [], [], [], [], [], 0, {}
    have_uv = False
    for g, original in zip(parts, originals):
        f = np.asarray(g.faces, dtype=np.int64).reshape(-1, 3)
        verts.append(np.asarray(g.vertices, dtype=np.float64).reshape(-1, 3))
        faces.append(f + offset)
        offset += len(g.vertices)
        fm, uv, vc = _visual_parts(g, len(f), materials, _gltf, made, original)
        fms.append(fm)
        uvs.append(uv if uv is not None else np.full((len(f), 3, 2), np.nan))
        vcs.append(vc)
        have_uv |= uv is not None
    vertex_colors = None
    if any(vc is not None for vc in vcs):
        # White where a part has none: neutral under a material (glTF's
        # COLOR_0 default). A part with neither colours nor a material
        # states no colour: it gets geovox's default, not that white.
        plain = None
        for i, vc in enumerate(vcs):
            if vc is None:
                vcs[i] = np.ones((len(verts[i]), 3))
                if np.any(fms[i] < 0):
                    if plain is None:
                        plain = len(materials)
                        materials.append(Material(name="default"))
                    fms[i] = np.where(fms[i] < 0, plain, fms[i])
        vertex_colors = np.concatenate(vcs)
    mesh = build_mesh(
        np.concatenate(verts), np.concatenate(faces), source,
        face_material=np.concatenate(fms),
        materials=materials,
        corner_uv=np.concatenate(uvs) if have_uv else None,
        vertex_colors=vertex_colors,
        face_part=None if part_names is None else
        np.repeat(np.arange(len(faces), dtype=np.int64), [len(f) for f in faces]),
        parts=part_names or [],
    )
    if _gltf is not None:
        mesh.problems.extend(f"{source}: {p}" for p in _gltf["problems"])
    return mesh


def _part_name(g, k: int) -> str:
    """A scene geometry's part name: ``node (mesh)``, or whichever of them it has."""
    node, name = g.metadata.get("node"), g.metadata.get("name")
    if node and name and node != name:
        return f"{node} ({name})"
    return str(node or name or f"part {k + 1}")


#: Formats whose files trimesh reads from inside an archive of their own, not beside the model.
_SELF_CONTAINED = {".zip", ".tar", ".gz", ".bz2", ".zae", ".3dxml", ".3mf", ".xz", ".tgz"}


def _trimesh_load(path: str, rule: str = "anywhere") -> Mesh:
    """Read any non-OBJ file with trimesh; every failure becomes one MeshError line.

    The files the model names (glTF buffers and images, COLLADA and PLY
    textures) are read by geovox's resolver under ``rule``.
    """
    import logging

    import trimesh

    class _Collect(logging.Handler):
        """Keeps trimesh's log records while a file loads: ``(level, message)``."""

        def __init__(self):
            super().__init__(logging.DEBUG)
            self.records = []

        def emit(self, record):
            try:
                self.records.append((record.levelno, record.getMessage()))
            except Exception:  # a malformed record must not break loading
                self.records.append((record.levelno, str(record.msg)))

    ext = os.path.splitext(path)[1].lower()
    if ext in NOT_A_MESH:
        raise MeshError(f"{path}: this is {NOT_A_MESH[ext]}")
    # trimesh reports what it skipped through `logging` (some of it only at
    # debug level); without a handler Python prints its warnings on stderr.
    # While the file loads every record comes here instead, to be judged below.
    collect = _Collect()
    logger = logging.getLogger("trimesh")
    saved = logger.level, logger.propagate
    logger.addHandler(collect)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    try:
        # The lock: catch_warnings swaps process-wide filters, so two threads
        # of one Dask worker loading side by side would restore each other's.
        with _TRIMESH_LOAD, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NumPy noise from trimesh's parsers
            said: list = []
            gltf = _gltf_file(path, rule, said) if ext in (".gltf", ".glb") else None
            flat = None
            if ext == ".3mf":
                from . import threemf  # xml and zipfile: not imported for other files

                flat = threemf.flatten(path)
            if flat is not None:
                import io

                loaded = trimesh.load(io.BytesIO(flat), file_type="3mf", process=False)
            elif gltf is not None:
                import io

                loaded = trimesh.load(io.BytesIO(gltf[0]), file_type=ext[1:], process=False,
                                      resolver=resolver(path, rule, said))
            elif ext in _SELF_CONTAINED:
                loaded = trimesh.load(path, process=False)
            else:
                loaded = trimesh.load(path, process=False, resolver=resolver(path, rule, said))
    except MeshError:
        raise  # geovox's own line (a 3MF beam lattice, a part it does not have)
    except Exception as exc:  # trimesh raises many types for unreadable files
        own = _read_off(path, None) if ext == ".off" else None
        if own is not None:
            return own  # e.g. polygons of five corners or more, which trimesh cannot fan
        raise MeshError(_load_failure(path, exc)) from exc
    finally:
        logger.removeHandler(collect)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]
    lost = [m for _, m in collect.records if _LOST_GEOMETRY.search(m)]
    if any("draco" in m.lower() for m in lost):
        why = ("the DracoPy package is not installed (pip install DracoPy)"
               if any("No module named" in m or "import of DracoPy" in m for m in lost)
               else "DracoPy could not decode it (trimesh: " + "; ".join(lost) + ")")
        raise MeshError(f"{path}: its geometry is Draco-compressed (glTF extension "
                        f"KHR_draco_mesh_compression) and was not decoded: {why}")
    if lost:
        raise MeshError(f"{path}: part of the geometry could not be read, so the volume would "
                        f"be incomplete (trimesh: {'; '.join(dict.fromkeys(lost))})")
    try:
        mesh = from_trimesh(loaded, source=path, _gltf=gltf[1] if gltf else None)
        if ext == ".off":
            mesh = _read_off(path, mesh)
        elif ext == ".ply":
            mesh = _ply_colours(loaded, mesh, path)
        elif ext == ".dae":
            from .dae import regroup

            regroup(mesh, path)  # COLLADA nodes as parts (trimesh names its geometries)
    except MeshError:
        raise
    except Exception as exc:  # odd visuals or arrays trimesh accepted
        text = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else ""
        raise MeshError(
            f"{path}: trimesh read the file, but its geometry or materials could not be "
            f"taken over ({type(exc).__name__}{': ' + text if text else ''})") from exc
    logged = [m for level, m in collect.records if level >= logging.WARNING
              and not (said and m == "unable to load image!")]  # said below, in words
    mesh.problems.extend(f"{path}: {m}" for m in dict.fromkeys(logged))
    # References refused or read from beside the model that no material's
    # line has said (a COLLADA or PLY texture; a glTF's are said per material).
    mesh.problems.extend(f"{path}: {line}" for line in dict.fromkeys(x[1] for x in said))
    return mesh


def load_mesh(source, *, references: str = "anywhere") -> Mesh:
    """Load a mesh from a path, a trimesh object, or pass a :class:`Mesh` through.

    OBJ files are read by :mod:`geovox.io.obj`, plain binary triangle PLY
    files by :mod:`geovox.io.ply`, STL files (binary and ASCII) by
    :mod:`geovox.io.stl`; everything else by trimesh
    (the other STL and PLY files, OFF, glTF/GLB with Draco compression, 3MF, COLLADA, 3DXML,
    zip and tar archives of these, ...).

    Parameters
    ----------
    source : str, os.PathLike, Mesh, trimesh.Trimesh or trimesh.Scene
        A file, a trimesh object (a scene's transforms are applied), or a
        Mesh, returned as it is.
    references : {"anywhere", "folder"}
        Where the files a model names (OBJ materials and textures, glTF
        buffers and images, COLLADA and PLY textures) may be read from:
        anywhere, or only under the model's own folder (see
        :mod:`geovox.io.references`). URLs are never fetched.

    Returns
    -------
    Mesh
        ``vertices`` (n, 3) float64, ``faces`` (m, 3) int64, and the
        materials, UVs and colours the file states.

    Raises
    ------
    InputNotFoundError
        The path does not exist or is a folder.
    MeshError
        The file cannot be read as a mesh, has no faces (a point cloud, lines),
        or trimesh dropped part of its geometry while reading it. The message
        names the file and says what is wrong in words.
    """
    rule = check_rule(references)
    if isinstance(source, Mesh):
        return source
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        if not os.path.exists(path):
            raise InputNotFoundError(f"input file not found: {path}")
        if os.path.isdir(path):
            raise InputNotFoundError(f"input is a folder, not a mesh file: {path}")
        if os.path.getsize(path) == 0:
            raise MeshError(f"{path}: the file is empty")
        if path.lower().endswith(".obj"):
            from .obj import read_obj

            return check_mesh(read_obj(path, rule=rule))
        if path.lower().endswith(".ply"):
            from .ply import read_plain_ply

            # A plain binary triangle PLY without importing trimesh (the same Mesh).
            mesh = read_plain_ply(path)
            if mesh is not None:
                return mesh
        if path.lower().endswith(".stl"):
            from .stl import read_stl

            # An STL without importing trimesh (the same Mesh).
            mesh = read_stl(path)
            if mesh is not None:
                return mesh
        return _trimesh_load(path, rule)
    try:
        return from_trimesh(source, source=f"<{type(source).__name__}>")
    except MeshError:
        if type(source).__module__.startswith("trimesh"):
            raise  # a trimesh point cloud, lines or empty scene: the message says which
        raise MeshError(
            f"`mesh` must be a file path, a trimesh.Trimesh or a trimesh.Scene, "
            f"got {type(source).__name__}"
        ) from None
