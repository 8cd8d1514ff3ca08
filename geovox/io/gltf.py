"""glTF 2.0 and GLB, read by geovox itself (no trimesh).

What is read:

* the container: GLB (its JSON and BIN chunks) or ``.gltf`` JSON, buffers in
  the BIN chunk, in ``data:`` URIs or in files found under the references
  rule (:mod:`geovox.io.references`; URLs are never fetched);
* accessors of every component type, ``normalized``, ``byteStride`` and
  ``sparse``, and accessors without a buffer view (zeros);
* ``KHR_mesh_quantization`` (integer positions and texture coordinates),
  ``KHR_draco_mesh_compression`` (DracoPy) and ``EXT_meshopt_compression``
  / ``KHR_meshopt_compression`` (the meshopt package), fallback buffers
  included;
* every primitive mode: triangles, strips and fans become triangles; points
  and lines are not surfaces (a file of nothing else says so);
* the scene's node hierarchy (``matrix`` or TRS) and
  ``EXT_mesh_gpu_instancing``; a transform that mirrors reverses its
  triangles, as the specification says;
* materials as colour and ``labels="material"`` use them (see
  :mod:`geovox.io.gltf_materials`);
* ``EXT_mesh_features``: each primitive's first feature ID set (an attribute,
  or implicit vertex IDs) as :attr:`geovox.mesh.Mesh.face_feature`, for
  ``labels="feature"`` (:func:`face_features`); IDs in textures are not read.

The Mesh is the one trimesh's reader and :func:`geovox.io.adaptor.from_trimesh`
made before: each node's primitive is a part (``node (mesh)``), in the order
trimesh's scene lists them (its node traversal: the last root first, each
node's last child first), with materials in order of first use. Where
trimesh is wrong -- sparse accessors (it reads the base values), normalized
integer texture coordinates and colours of quantized files, instancing (one
copy), line loops and strips -- this reader follows the specification.

A required extension geovox cannot read is one line naming it; anything that
breaks the format's own rules (a byte range past its buffer, an index past
its vertices, a node that is its own ancestor) is a file "damaged" in one
line; a size past :func:`geovox.io.limits.input_limit` is refused before it
is allocated. Instancing (``EXT_mesh_gpu_instancing``, a mesh that several
nodes use) is not held to that ratio of the file's size: what the scene's
copies will take is counted from the JSON before anything is decoded or
placed, and refused only past :func:`geovox.io.limits.scene_limit` (the
memory available).
"""

from __future__ import annotations

import json
import os
import struct
import urllib.parse

import numpy as np

from ..errors import MeshError
from ..mesh import build_mesh
from . import limits
from .gltf_scene import PER_COPY, copy_size, instances, is_int, placements, transform_points
from .kinds import kind
from .names import unique_name
from .references import data_uri, instead, locate, why_not_read

__all__ = ["read_gltf", "Document", "Damaged", "read_primitive", "strip_faces", "fan_faces", "unit_colours", "colours_or_white", "face_features", "unique_name", "READ",
           "NOT_GEOMETRY", "COMPONENTS"]

#: glTF component types: NumPy dtype (little-endian).
COMPONENTS = {5120: np.dtype("i1"), 5121: np.dtype("u1"), 5122: np.dtype("<i2"),
              5123: np.dtype("<u2"), 5125: np.dtype("<u4"), 5126: np.dtype("<f4")}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_INDEX_TYPES = (5121, 5123, 5125)
_POINTS, _LINES, _LOOP, _LINE_STRIP, _TRIANGLES, _STRIP, _FAN = range(7)
_MESHOPT = ("EXT_meshopt_compression", "KHR_meshopt_compression")

#: Extensions this reader reads (a file may require them).
READ = frozenset({"KHR_draco_mesh_compression", "KHR_mesh_quantization",
                  "EXT_mesh_gpu_instancing", "KHR_texture_transform",
                  "KHR_materials_pbrSpecularGlossiness", *_MESHOPT})
#: Prefixes of extensions that change neither geometry nor base colour
#: (lights, other material properties, metadata, other image formats): a file
#: that requires one still converts, coloured from what geovox reads.
NOT_GEOMETRY = ("KHR_materials_", "KHR_lights_", "KHR_texture_", "EXT_texture_",
                "KHR_xmp", "EXT_lights_", "MSFT_texture_dds", "EXT_mesh_features",
                "EXT_structural_metadata", "EXT_instance_features", "CESIUM_primitive_outline",
                "KHR_animation_pointer", "KHR_node_visibility", "MSFT_lod",
                "KHR_technique", "KHR_techniques_")


class Damaged(MeshError):
    """A glTF file that breaks the format's rules (its text says how)."""


def unit_colours(colours, n: int, problems=None):
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


def colours_or_white(vcs: list, sizes: list, fms: list, plain):
    """(n, 3) float64 vertex colours of several parts, white where a part has none; or None.

    White is neutral under a material (glTF's ``COLOR_0`` default). A part
    with neither colours nor a material states no colour: its faces get the
    material ``plain()`` numbers (geovox's default), not that white.

    Parameters
    ----------
    vcs : list of (n_i, 3) float64 or None
        Each part's vertex colours; the Nones are replaced by white.
    sizes : list of int
        Each part's vertex count.
    fms : list of (m_i,) int64
        Each part's face materials (-1: none); replaced where a part without
        colours has faces without a material.
    plain : callable
        ``plain() -> int``, the index of a plain material; called only when one is needed.

    Returns
    -------
    (sum n_i, 3) float64 or None
        None when no part has colours (nothing is changed then).
    """
    if all(vc is None for vc in vcs):
        return None
    for i, vc in enumerate(vcs):
        if vc is None:
            vcs[i] = np.ones((sizes[i], 3))
            if np.any(fms[i] < 0):
                fms[i] = np.where(fms[i] < 0, plain(), fms[i])
    return np.concatenate(vcs)


# --------------------------------------------------------------------- strips and fans


def strip_faces(index: np.ndarray) -> np.ndarray:
    """(n - 2, 3) int64 triangles of a triangle strip, glTF's winding, degenerate ones dropped.

    Triangle i is ``(v[i], v[i + 1 + i % 2], v[i + 2 - i % 2])`` (glTF
    3.7.2.1); triangles with a repeated vertex (stitched strips) are left out.
    """
    v = np.asarray(index, dtype=np.int64).reshape(-1)
    if len(v) < 3:
        return np.zeros((0, 3), dtype=np.int64)
    i = np.arange(len(v) - 2)
    odd = i % 2
    return _drop_degenerate(np.stack([v[i], v[i + 1 + odd], v[i + 2 - odd]], axis=1))


def fan_faces(index: np.ndarray) -> np.ndarray:
    """(n - 2, 3) int64 triangles of a triangle fan: ``(v[i + 1], v[i + 2], v[0])``, degenerate ones dropped."""
    v = np.asarray(index, dtype=np.int64).reshape(-1)
    if len(v) < 3:
        return np.zeros((0, 3), dtype=np.int64)
    i = np.arange(len(v) - 2)
    return _drop_degenerate(np.stack([v[i + 1], v[i + 2], np.full(len(i), v[0])], axis=1))


def _drop_degenerate(tri: np.ndarray) -> np.ndarray:
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    return tri[keep]


# --------------------------------------------------------------------- the container


def _container(path: str, data: bytes):
    """``(header dict, BIN chunk or None)`` of a GLB or ``.gltf`` file."""
    if data[:4] == b"glTF":
        if len(data) < 20:
            raise Damaged(f"{path}: cannot be read as {kind(path)}: its GLB header is cut short "
                          f"({len(data)} bytes); the file is damaged")
        version, length, n, chunk = struct.unpack_from("<IIII", data, 4)
        if version == 1:
            raise MeshError(f"{path}: is glTF 1.0 binary; geovox reads glTF 2.0")
        if version != 2:
            raise Damaged(f"{path}: cannot be read as {kind(path)}: its header says version "
                          f"{version}; the file is damaged")
        if length > len(data):
            raise Damaged(f"{path}: cannot be read as {kind(path)}: its GLB header says "
                          f"{length:,} bytes, but the file has {len(data):,}; the file is cut "
                          f"short")
        if chunk != 0x4E4F534A or 20 + n > length:
            raise Damaged(f"{path}: cannot be read as {kind(path)}: its first chunk is not its "
                          f"JSON, or runs past the file; the file is damaged")
        raw, at, binary = data[20:20 + n], 20 + n, None
        while at + 8 <= length:
            size, chunk = struct.unpack_from("<II", data, at)
            if at + 8 + size > length:
                raise Damaged(f"{path}: cannot be read as {kind(path)}: a chunk of {size:,} "
                              f"bytes runs past the file's {length:,}; the file is cut short")
            if chunk == 0x004E4942 and binary is None:  # "BIN\0"
                binary = memoryview(data)[at + 8:at + 8 + size]
            at += 8 + size
    else:
        raw, binary = data, None
    try:
        header = json.loads(bytes(raw).decode("utf-8-sig"))
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        raise MeshError(f"{path}: cannot be read as {kind(path)}: its JSON does not parse "
                        f"({type(exc).__name__}: {str(exc)[:80]}); the file is damaged or "
                        f"not glTF") from None
    if not isinstance(header, dict):
        raise MeshError(f"{path}: cannot be read as {kind(path)}: its JSON is not an object; "
                        f"the file is damaged or not glTF")
    version = header.get("asset", {}).get("version") if isinstance(header.get("asset"),
                                                                    dict) else None
    if isinstance(version, str) and version.split(".")[0] not in ("2", ""):
        raise MeshError(f"{path}: is glTF {version}; geovox reads glTF 2.0")
    return header, binary


class Document:
    """A parsed glTF file: its JSON, and its buffers, views and accessors read on demand.

    Parameters
    ----------
    path : str
    data : bytes
        The file's bytes.
    rule : {"anywhere", "folder"}
        Where its buffer and image files may be read from.
    limit : geovox.io.limits.Limit
        ``max_input_size``; with the file's size, sets :attr:`cap`.
    """

    def __init__(self, path: str, data: bytes, rule: str = "anywhere",
                 limit: limits.Limit = limits.Limit()):
        self.path, self.rule, self.limit = path, rule, limit
        self.folder = os.path.dirname(os.path.abspath(path))
        self.header, self.binary = _container(path, data)
        self.stored = len(data)  # with the buffer files it reads
        self.cap = limit.of(self.stored)
        self.spent = 0
        self.scene_cap = limit.scene()  # what placed copies may take: memory, not file size
        self.placed = 0
        self.problems: list = []
        self.refused: list = []  # (uri, line) of references not read
        self._buffers, self._views, self._accessors = {}, {}, {}
        self._check_required()
        self._check_files()

    # -- the JSON ---------------------------------------------------------

    def listed(self, key: str) -> list:
        value = self.header.get(key, [])
        if not isinstance(value, list):
            raise self.damaged(f"its {key!r} is not a list")
        return value

    def item(self, key: str, index, what: str) -> dict:
        items = self.listed(key)
        if not is_int(index) or not 0 <= index < len(items) or not isinstance(items[index],
                                                                                dict):
            raise self.damaged(f"{what} names {key[:-1]} {index!r}, which does not exist "
                               f"({len(items)} in the file)")
        return items[index]

    def damaged(self, why: str) -> Damaged:
        return Damaged(f"{self.path}: cannot be read as {kind(self.path)}: {why}; the file is "
                       f"damaged")

    def spend(self, nbytes: float, what: str) -> None:
        """Count ``nbytes`` about to be allocated; refuse past :attr:`cap`."""
        self.spent += nbytes
        if self.spent > self.cap:
            raise self.limit.refuse(self.path, what, self.spent, self.cap)

    def place(self, nbytes: float, what: str) -> None:
        """Count ``nbytes`` of placed copies about to be built; refuse past :attr:`scene_cap`."""
        self.placed += nbytes
        if self.scene_cap is not None and self.placed > self.scene_cap:
            raise self.limit.refuse_scene(self.path, what, self.placed, self.scene_cap)

    def _check_required(self) -> None:
        required = self.header.get("extensionsRequired", [])
        for name in required if isinstance(required, list) else []:
            if isinstance(name, str) and name not in READ and not name.startswith(NOT_GEOMETRY):
                raise MeshError(f"{self.path}: requires the glTF extension {name}, which geovox "
                                f"does not read")

    def _check_files(self) -> None:
        """Name the first buffer file that is missing or not read, before reading any."""
        for entry in self.listed("buffers"):
            uri = entry.get("uri") if isinstance(entry, dict) else None
            if isinstance(uri, str) and not uri.startswith("data:"):
                self._locate(uri)

    def _locate(self, uri: str) -> str:
        found, refused = locate(urllib.parse.unquote(uri), self.folder, self.rule)
        if found is None and urllib.parse.unquote(uri) != uri:
            found, refused = locate(uri, self.folder, self.rule)
        if refused and found is None:
            raise MeshError(f"{self.path}: refers to a file that is not read: {uri!r} is not "
                            f"read: {why_not_read(uri)}")
        if found is None:
            raise MeshError(f"{self.path}: refers to a file that is missing: {uri}")
        if refused and (uri, instead(uri, found)) not in self.refused:
            self.refused.append((uri, instead(uri, found)))
        return found

    # -- bytes --------------------------------------------------------------

    def buffer(self, i) -> memoryview:
        """Buffer ``i``'s bytes (the GLB's BIN chunk, a data URI or a file)."""
        entry = self.item("buffers", i, "a buffer view")
        if i in self._buffers:
            return self._buffers[i]
        uri = entry.get("uri")
        if uri is None:
            if self.binary is None or i != 0:
                if (entry.get("extensions") or {}).get("EXT_meshopt_compression", {}).get(
                        "fallback") or (entry.get("extensions") or {}).get(
                        "KHR_meshopt_compression", {}).get("fallback"):
                    raise MeshError(f"{self.path}: its geometry is meshopt-compressed and the "
                                    f"meshopt package is not installed (pip install meshopt)")
                raise self.damaged(f"buffer {i} has no data (no uri, and no GLB binary chunk)")
            data = self.binary
        elif not isinstance(uri, str):
            raise self.damaged(f"buffer {i} has a uri that is not text")
        elif uri.startswith("data:"):
            try:
                data = memoryview(data_uri(uri))
            except ValueError:
                raise self.damaged(f"buffer {i} is a data URI whose base64 does not decode") \
                    from None
        else:
            data = memoryview(self.file(uri))
        length = entry.get("byteLength")
        if not is_int(length) or length < 0:
            raise self.damaged(f"buffer {i} has no byteLength")
        if len(data) < length:
            raise self.damaged(f"buffer {i} says it holds {length:,} bytes, but "
                               f"{len(data):,} are there (cut short)")
        self._buffers[i] = data
        return data

    def file(self, uri: str) -> bytes:
        """A file the model names, under the references rule (a refusal is a MeshError)."""
        found = self._locate(uri)
        self.stored += os.path.getsize(found)
        self.cap = self.limit.of(self.stored)
        with open(found, "rb") as f:
            return f.read()

    def view(self, i) -> tuple:
        """``(bytes, byteStride or None)`` of buffer view ``i`` (meshopt decoded)."""
        bv = self.item("bufferViews", i, "an accessor or image")
        if i in self._views:
            return self._views[i]
        stride = bv.get("byteStride")
        if stride is not None and (not is_int(stride) or stride <= 0):
            raise self.damaged(f"buffer view {i} has byteStride {stride!r}")
        ext = bv.get("extensions") if isinstance(bv.get("extensions"), dict) else {}
        packed = next((ext[k] for k in _MESHOPT if isinstance(ext.get(k), dict)), None)
        if packed is not None:
            data = self._meshopt(i, packed)
            if data is not None:
                self._views[i] = (data, stride or packed.get("byteStride"))
                return self._views[i]
        data = self._slice(bv.get("buffer"), bv.get("byteOffset", 0), bv.get("byteLength"),
                           f"buffer view {i}")
        self._views[i] = (data, stride)
        return self._views[i]

    def _slice(self, buffer, offset, length, what: str) -> memoryview:
        data = self.buffer(buffer)
        if not (is_int(offset) and is_int(length) and offset >= 0 and length >= 0):
            raise self.damaged(f"{what} has no byte range (byteOffset {offset!r}, byteLength "
                               f"{length!r})")
        if offset + length > len(data):
            raise self.damaged(f"{what} reaches byte {offset + length:,} of buffer {buffer}, "
                               f"which holds {len(data):,}")
        return data[offset:offset + length]

    def _meshopt(self, i, packed: dict):
        """A meshopt-compressed view's decoded bytes, or None to read its fallback."""
        try:
            import meshopt
        except ImportError:
            return None  # the fallback buffer, or buffer() says what to install
        count, size = packed.get("count"), packed.get("byteStride")
        mode, filt = packed.get("mode"), packed.get("filter", "NONE")
        if not (is_int(count) and is_int(size) and count > 0 and size > 0) or mode not in (
                "ATTRIBUTES", "TRIANGLES", "INDICES") or filt not in (
                "NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL", "COLOR"):
            raise self.damaged(f"buffer view {i}'s meshopt compression has count {count!r}, "
                               f"byteStride {size!r}, mode {mode!r}")
        self.spend(count * size, f"buffer view {i} (meshopt, {count:,} x {size} bytes)")
        source = self._slice(packed.get("buffer"), packed.get("byteOffset", 0),
                             packed.get("byteLength"), f"buffer view {i}'s meshopt data")
        try:
            out = meshopt.decode_gltf_buffer(bytes(source), count, size, mode,
                                             None if filt == "NONE" else filt)
        except (ValueError, RuntimeError) as exc:
            raise self.damaged(f"buffer view {i}'s meshopt data does not decode ({exc})") \
                from None
        return memoryview(np.ascontiguousarray(out).view(np.uint8).reshape(-1))

    # -- accessors ------------------------------------------------------------

    def accessor(self, i, what: str) -> np.ndarray:
        """Accessor ``i`` as a (count, width) array: its stored type, or float64 when normalized."""
        acc = self.item("accessors", i, what)
        if i in self._accessors:
            return self._accessors[i]
        dtype = COMPONENTS.get(acc.get("componentType")) if is_int(acc.get("componentType")) \
            else None
        width = _WIDTH.get(acc.get("type")) if isinstance(acc.get("type"), str) else None
        count = acc.get("count")
        if dtype is None or width is None or not is_int(count) or count < 0:
            raise self.damaged(f"accessor {i} has componentType {acc.get('componentType')!r}, "
                               f"type {acc.get('type')!r} and count {count!r}")
        size = dtype.itemsize * width
        self.spend(count * max(size, 8 * width), f"accessor {i} ({count:,} x {acc.get('type')})")
        view = acc.get("bufferView")
        if view is None:
            out = np.zeros((count, width), dtype)
        else:
            data, stride = self.view(view)
            stride = stride or size
            offset = acc.get("byteOffset", 0)
            if not is_int(offset) or offset < 0:
                raise self.damaged(f"accessor {i} has byteOffset {offset!r}")
            end = offset + (count - 1) * stride + size if count else offset
            if end > len(data):
                raise self.damaged(f"accessor {i} ({count:,} x {size} bytes, stride {stride}) "
                                   f"reaches byte {end:,} of buffer view {view}, which holds "
                                   f"{len(data):,}")
            raw = np.frombuffer(data, np.uint8, count=end - offset, offset=offset)
            if count and stride != size:
                raw = np.lib.stride_tricks.as_strided(raw, (count, size), (stride, 1))
            out = np.ascontiguousarray(raw).view(dtype).reshape(count, width)
        if isinstance(acc.get("sparse"), dict):
            out = self._sparse(i, acc["sparse"], out.copy(), count)
        if acc.get("normalized") is True and dtype.kind in "iu":
            top = float(np.iinfo(dtype).max)
            out = out.astype(np.float64) / top
            if dtype.kind == "i":
                out = np.maximum(out, -1.0)
        self._accessors[i] = out
        return out

    def _sparse(self, i, sparse: dict, out: np.ndarray, count: int) -> np.ndarray:
        k = sparse.get("count")
        idx, val = sparse.get("indices"), sparse.get("values")
        if not (is_int(k) and 0 < k <= count and isinstance(idx, dict) and isinstance(val, dict)
                and is_int(idx.get("componentType")) and idx["componentType"] in _INDEX_TYPES):
            raise self.damaged(f"accessor {i} has a sparse part that does not add up")
        itype = COMPONENTS[idx["componentType"]]
        where = self._packed(idx, k, itype, 1, f"accessor {i}'s sparse indices")
        values = self._packed(val, k, out.dtype, out.shape[1], f"accessor {i}'s sparse values")
        where = where.reshape(-1).astype(np.int64)
        if where.size and where.max() >= count:
            raise self.damaged(f"accessor {i}'s sparse indices reach {int(where.max()):,} of "
                               f"{count:,} elements")
        out[where] = values
        return out

    def _packed(self, part: dict, k: int, dtype, width: int, what: str) -> np.ndarray:
        data, _ = self.view(part.get("bufferView"))
        offset = part.get("byteOffset", 0)
        n = k * dtype.itemsize * width
        if not is_int(offset) or offset < 0 or offset + n > len(data):
            raise self.damaged(f"{what} run past their buffer view")
        return np.frombuffer(data, dtype, count=k * width, offset=offset).reshape(k, width)


# --------------------------------------------------------------------- primitives


class Primitive:
    """One primitive read once: ``positions`` (n, 3) float64, ``faces`` (m, 3) int64, and its
    ``uv`` (n, 2) float64 or None (flipped to V up), ``colours`` (n, 3) float64 or None, and
    ``material`` index or None. ``kind``: "triangles", "points" or "lines". ``features``:
    (m,) int64 feature IDs of the faces (-1: none), or None (see :func:`face_features`)."""

    __slots__ = ("positions", "faces", "uv", "colours", "material", "kind", "name", "features")


def _draco(doc: Document, prim: dict, where: str) -> dict:
    """``{attribute name: array, "indices": faces}`` of a Draco-compressed primitive."""
    ext = prim["extensions"]["KHR_draco_mesh_compression"]
    if not isinstance(ext, dict) or not isinstance(ext.get("attributes"), dict):
        raise doc.damaged(f"{where}'s Draco extension names no attributes")
    data, _ = doc.view(ext.get("bufferView"))
    count = doc.item("accessors", prim["attributes"].get("POSITION"), where).get("count")
    if is_int(count):
        doc.spend(count * 64, f"{where} (Draco, {count:,} vertices)")
    try:
        import DracoPy
    except ImportError:
        raise MeshError(f"{doc.path}: its geometry is Draco-compressed (glTF extension "
                        f"KHR_draco_mesh_compression) and was not decoded: the DracoPy package "
                        f"is not installed (pip install DracoPy)") from None
    try:
        decoded = DracoPy.decode(bytes(data))
    except Exception as exc:  # DracoPy raises its own and RuntimeError types
        raise doc.damaged(f"{where}'s Draco data does not decode ({type(exc).__name__})") \
            from None
    names = {ident: name for name, ident in ext["attributes"].items() if is_int(ident)}
    out = {}
    for attr in getattr(decoded, "attributes", []):
        name = names.get(attr.get("unique_id"))
        if name is not None:
            a = np.asarray(attr["data"])
            out[name] = a.reshape(len(a), -1)
    faces = getattr(decoded, "faces", None)
    if faces is not None:
        out["indices"] = np.asarray(faces).reshape(-1, 1)
    return out


def read_primitive(doc: Document, prim: dict, where: str, materials) -> Primitive:
    """One primitive's geometry, texture coordinates and colours.

    ``materials`` (:class:`geovox.io.gltf_materials.Materials`) says which
    TEXCOORD set the primitive's base colour texture reads, and its transform.
    """
    attrs = prim.get("attributes")
    if not isinstance(attrs, dict) or "POSITION" not in attrs:
        raise doc.damaged(f"{where} has no POSITION attribute")
    mode = prim.get("mode", _TRIANGLES)
    if not is_int(mode) or mode not in range(7):
        raise doc.damaged(f"{where} has mode {mode!r}")
    ext = prim.get("extensions") if isinstance(prim.get("extensions"), dict) else {}
    decoded = _draco(doc, prim, where) if "KHR_draco_mesh_compression" in ext else {}

    def attribute(name):
        if name in decoded:
            return decoded[name]
        return doc.accessor(attrs[name], f"{where}'s {name}")

    p = Primitive()
    positions = attribute("POSITION")
    if positions.shape[1] != 3:
        raise doc.damaged(f"{where}'s POSITION is not 3-vectors")
    p.positions = positions.astype(np.float64)
    p.material = prim.get("material")
    n = len(positions)
    if mode in (_POINTS, _LINES, _LOOP, _LINE_STRIP):
        p.kind, p.faces = ("points" if mode == _POINTS else "lines"), np.zeros((0, 3), np.int64)
        p.uv = p.colours = p.features = None
        p.name = mode
        return p
    p.kind = "triangles"
    if "indices" in decoded:
        index = decoded["indices"].reshape(-1)
    elif prim.get("indices") is not None:
        acc = doc.item("accessors", prim["indices"], where)
        if not is_int(acc.get("componentType")) or acc["componentType"] not in _INDEX_TYPES \
                or acc.get("type") != "SCALAR":
            raise doc.damaged(f"{where}'s indices are not unsigned integers")
        index = doc.accessor(prim["indices"], f"{where}'s indices").reshape(-1)
    else:
        index = None
    if index is not None:
        index = index.astype(np.int64)
        if index.size and (index.max() >= n):
            raise doc.damaged(f"{where}'s indices reach vertex {int(index.max()):,}, but it has "
                              f"{n:,}")
    if mode == _TRIANGLES:
        flat = np.arange(n, dtype=np.int64) if index is None else index
        if len(flat) % 3:
            raise doc.damaged(f"{where} draws triangles from {len(flat):,} indices, which is "
                              f"not a multiple of 3")
        p.faces = flat.reshape(-1, 3)
    else:
        flat = np.arange(n, dtype=np.int64) if index is None else index
        p.faces = (strip_faces if mode == _STRIP else fan_faces)(flat)
    texture_set, transform = materials.texcoord(p.material)
    name = f"TEXCOORD_{texture_set}" if texture_set is not None else "TEXCOORD_0"
    p.uv = None
    if name in attrs or name in decoded:
        uv = attribute(name)
        if uv.shape[1] >= 2 and len(uv) == n:
            # trimesh's flip, in the accessor's type (V down to V up), then
            # KHR_texture_transform in glTF's V (see gltf_materials).
            uv = uv[:, :2].copy()
            uv[:, 1] = 1.0 - uv[:, 1]
            p.uv = uv.astype(np.float64)
            if transform is not None:
                from ..mesh import transform_uv

                flip = np.array([1.0, -1.0]), np.array([0.0, 1.0])
                p.uv = transform_uv(p.uv * flip[0] + flip[1], transform) * flip[0] + flip[1]
    elif texture_set is not None:
        materials.missing_set(p.material, texture_set)
    p.colours = None
    if "COLOR_0" in attrs or "COLOR_0" in decoded:
        colours = attribute("COLOR_0")
        if len(colours) == n:
            p.colours = colours
    p.features = face_features(doc, ext.get("EXT_mesh_features"), p.faces, n,
                               lambda name: attribute(name) if name in attrs or name in decoded
                               else None, where)
    return p


def face_features(doc: Document, spec, faces: np.ndarray, n: int, attribute, where: str):
    """(m,) int64: each face's feature ID in a primitive's first ``EXT_mesh_features`` set, or None.

    A face takes its first vertex's ID (the extension gives IDs per vertex;
    a feature's triangles carry one ID at all three corners). The set's IDs
    are the ``_FEATURE_ID_k`` attribute its ``attribute`` names, or, with
    neither attribute nor texture, the vertex index (the extension's
    implicit IDs). IDs in a texture are not read: the faces get none, said in
    ``doc.problems``. ``nullFeatureId`` and negative IDs are -1 (no feature).

    Parameters
    ----------
    doc : Document
    spec : dict or None
        The primitive's ``extensions.EXT_mesh_features``.
    faces : (m, 3) int64
    n : int
        The primitive's vertex count.
    attribute : callable
        ``attribute(name) -> (n, w) array or None``: the primitive's attribute of that name.
    where : str
        The primitive, as messages name it.

    Returns
    -------
    (m,) int64 or None
        None where the primitive has no feature ID set.
    """
    sets = spec.get("featureIds") if isinstance(spec, dict) else None
    if not isinstance(sets, list) or not sets or not isinstance(sets[0], dict):
        return None
    first = sets[0]
    if "attribute" in first:
        k = first["attribute"]
        ids = attribute(f"_FEATURE_ID_{k}") if is_int(k) else None
        if ids is None:
            raise doc.damaged(f"{where}'s feature IDs name attribute {k!r}, which it does not have")
        if ids.shape[1] != 1 or len(ids) != n:
            raise doc.damaged(f"{where}'s _FEATURE_ID_{k} is not one number a vertex")
        ids = ids[:, 0]
        if ids.dtype.kind == "f":
            if not np.all(np.isfinite(ids) & (ids == np.rint(ids))):
                raise doc.damaged(f"{where}'s _FEATURE_ID_{k} holds numbers that are not whole")
            ids = np.clip(ids, -1, 2.0 ** 62)
        vertex = ids.astype(np.int64)
    elif "texture" in first:
        doc.problems.append(f"{where}'s feature IDs are in a texture, which geovox does not read; "
                            f"its faces have no feature")
        return np.full(len(faces), -1, np.int64)
    else:
        vertex = np.arange(n, dtype=np.int64)
    out = vertex[faces[:, 0]]
    null = first.get("nullFeatureId")
    if is_int(null):
        out[out == null] = -1
    out[out < 0] = -1
    return out


# --------------------------------------------------------------------- the file


def read_gltf(path: str, *, rule: str = "anywhere", limit: limits.Limit = limits.Limit()):
    """The :class:`~geovox.mesh.Mesh` of a glTF 2.0 or GLB file.

    Parameters
    ----------
    path : str
    rule : {"anywhere", "folder"}
        Where buffer and image files may be read from (see
        :mod:`geovox.io.references`).
    limit : geovox.io.limits.Limit
        ``max_input_size``: the most bytes the file may grow to once decoded
        (default: see :func:`geovox.io.limits.input_limit`).

    Returns
    -------
    Mesh
        Every triangle primitive of every node instance, transforms applied;
        parts, materials, texture coordinates and ``COLOR_0`` as trimesh's
        reader and geovox's adaptor gave them.

    Raises
    ------
    MeshError
        One line: damaged, a required extension geovox does not read, a
        missing or refused buffer, no faces, or a size past the limit.
    """
    from .gltf_materials import Materials

    with open(path, "rb") as f:
        data = f.read()
    doc = Document(path, data, rule, limit)
    del data
    materials = Materials(doc)
    meshes = doc.listed("meshes")
    # Each primitive's name, as trimesh's reader names its geometries.
    geometry, counts, taken = {}, {}, set()
    for k, m in enumerate(meshes):
        prims = m.get("primitives") if isinstance(m, dict) else None
        if not isinstance(prims, list):
            raise doc.damaged(f"mesh {k} has no primitives list")
        own = m.get("name") if isinstance(m.get("name"), str) else "GLTF"
        for j in range(len(prims)):
            geometry[k, j] = unique_name(own, taken, counts)
            taken.add(geometry[k, j])
    # Each primitive is decoded once (the file-size rule bounds that); its
    # copies are counted against memory before one is placed (the scene rule).
    placed, copies = placements(doc)
    read = {}
    for mesh in placed:
        for j, prim in enumerate(meshes[mesh]["primitives"]):
            if not isinstance(prim, dict):
                raise doc.damaged(f"mesh {mesh} primitive {j} is not an object")
            read[mesh, j] = read_primitive(doc, prim, f"mesh {mesh} primitive {j}", materials)
    need = sum(n * (PER_COPY + sum(copy_size(read[mesh, j])
                                   for j in range(len(meshes[mesh]["primitives"]))))
               for mesh, n in copies.items())
    total = sum(copies.values())
    doc.place(need, f"its scene's {total:,} mesh {'copy' if total == 1 else 'copies'}")
    parts = []
    for node, node_name, mesh, matrix in instances(doc):
        for j in range(len(meshes[mesh]["primitives"])):
            name = geometry[mesh, j]
            label = (name if node_name is None or node_name == name
                     else f"{node_name} ({name})")
            parts.append((read[mesh, j], matrix, label))
    return _assemble(doc, parts, materials)


def _no_faces(doc: Document, parts: list) -> str:
    counts = {}
    for p, _, _ in parts:
        if p.kind == "points":
            what = f"a point cloud ({len(p.positions):,} points)"
        elif p.kind == "lines":
            n = len(p.positions) // 2 if p.name == _LINES else max(len(p.positions) - 1, 0)
            what = f"lines ({n:,} line {'piece' if n == 1 else 'pieces'})"
        else:
            what = f"a mesh with no faces ({len(p.positions):,} vertices)"
        counts[what] = counts.get(what, 0) + 1
    if not counts:
        return f"{doc.path}: contains no geometry (no vertices or faces could be read from it)"
    held = ", ".join(k if n == 1 else f"{n} x {k}" for k, n in counts.items())
    return (f"{doc.path}: has no faces, only {held}; geovox voxelises the inside of a "
            f"triangle surface")


def _assemble(doc: Document, parts: list, materials):
    """One Mesh of the instances, as :func:`geovox.io.adaptor.from_trimesh` made it.

    Each array is allocated once at its full size and every copy is written
    into it: a scene of many copies then takes its size once, not twice (a
    list of pieces and their concatenation), and no texture coordinates are
    made for a scene without any.
    """
    solid = [(p, m, label) for p, m, label in parts if p.kind == "triangles" and len(p.faces)]
    if not solid:
        raise MeshError(_no_faces(doc, parts))
    vsizes = [len(p.positions) for p, _, _ in solid]
    sizes = [len(p.faces) for p, _, _ in solid]
    vstart = np.concatenate([[0], np.cumsum(vsizes)])
    fstart = np.concatenate([[0], np.cumsum(sizes)])
    index = [materials.index(p.material, p.colours is not None) for p, _, _ in solid]
    have_uv = any(p.uv is not None and i is not None for (p, _, _), i in zip(solid, index))
    any_feature = any(p.features is not None for p, _, _ in solid)
    verts = np.empty((vstart[-1], 3))
    faces = np.empty((fstart[-1], 3), dtype=np.int64)
    fm = np.empty(fstart[-1], dtype=np.int64)
    uvs = np.full((fstart[-1], 3, 2), np.nan) if have_uv else None
    features = np.full(fstart[-1], -1, np.int64) if any_feature else None
    vcs = []
    for k, (p, matrix, _) in enumerate(solid):
        f = p.faces
        if np.linalg.det(matrix[:3, :3]) < 0:
            f = f[:, ::-1]  # a mirror turns the faces inside out
        v0, f0, f1 = vstart[k], fstart[k], fstart[k + 1]
        verts[v0:vstart[k + 1]] = transform_points(p.positions, matrix)
        np.add(f, v0, out=faces[f0:f1])
        fm[f0:f1] = -1 if index[k] is None else index[k]
        if have_uv and p.uv is not None and index[k] is not None:
            uvs[f0:f1] = p.uv[f]
        if any_feature and p.features is not None:
            features[f0:f1] = p.features
        vcs.append(unit_colours(p.colours, len(p.positions), doc.problems)
                   if index[k] is not None else None)
    fms = [fm[fstart[k]:fstart[k + 1]] for k in range(len(solid))]
    vertex_colors = colours_or_white(vcs, vsizes, fms, materials.plain)
    for k, piece in enumerate(fms):  # colours_or_white replaces the pieces it changes
        if piece.base is not fm:
            fm[fstart[k]:fstart[k + 1]] = piece
    labels = [label for _, _, label in solid]
    problems = materials.problems() + doc.problems + [line for _, line in doc.refused]
    return build_mesh(
        verts, faces, doc.path,
        face_material=fm, materials=materials.made,
        corner_uv=uvs, vertex_colors=vertex_colors,
        face_part=np.repeat(np.arange(len(sizes), dtype=np.int64), sizes), parts=labels,
        problems=[f"{doc.path}: {p}" for p in dict.fromkeys(problems)],
        face_feature=features)
