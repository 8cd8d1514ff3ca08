"""PLY files, read by geovox itself (no trimesh): every PLY a scanner or exporter writes.

* ASCII and both binary byte orders;
* header lines ended by CR, LF or CRLF (PLY's own definition speaks of
  carriage returns);
* elements and properties in any order, scalar properties of every type and
  lists of any count and index types; elements geovox does not use are
  skipped over;
* ``vertex``: ``x y z``, colours ``red green blue`` (``alpha`` is not used),
  texture coordinates ``texture_u texture_v``, ``u v`` or ``s t``;
* ``face``: a ``vertex_indices`` (or ``vertex_index``) list, polygons fanned
  into triangles, colours, and ``texcoord`` lists (six numbers a triangle);
* the texture image named by a ``comment TextureFile name`` line.

The Mesh is the one trimesh's reader and geovox's adaptor made before, with
colours as the file stores them: integers scaled by their type's maximum
(``ushort`` 65535 is white), floats 0-1 or 0-255 when one exceeds 1, a NaN
colour no colour. Vertex colours win over face colours; with texture
coordinates the texture (if any) replaces the vertex colours, as in an OBJ.
Sizes are checked against the bytes before anything is allocated, and a
file whose sizes do not add up is one line saying which.
"""

from __future__ import annotations

import os
import re

import numpy as np

from ..errors import MeshError
from ..mesh import Material, build_mesh
from .references import instead, locate, why_not_read

__all__ = ["read_ply", "parse_header", "TYPES", "MAX_HEADER"]

#: PLY scalar type names and their NumPy codes.
TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
#: The header is looked for in at most this many bytes.
MAX_HEADER = 1 << 20
_RGB = ("red", "green", "blue")
_UV_NAMES = (("texture_u", "texture_v"), ("u", "v"), ("s", "t"))
_END = re.compile(rb"end_header[ \t]*(\r\n|\r|\n)")


class Element:
    """One element of the header: ``name``, ``count`` and its ``properties``.

    ``properties`` is a list of ``(name, type code, list count type code or
    None)``; ``data`` is filled by the reader: ``{property: array}``, lists as
    ``(counts (k,) int64, values (sum,) array)``.
    """

    def __init__(self, name: str, count: int):
        self.name, self.count, self.properties, self.data = name, count, [], {}

    def fixed(self) -> bool:
        return all(p[2] is None for p in self.properties)


def parse_header(path: str, data: bytes) -> tuple:
    """``(format, [Element], comments, offset of the data)`` of a PLY file's header.

    Raises
    ------
    MeshError
        Not PLY, or a header line that cannot be read (naming it).
    """
    m = re.match(rb"ply[ \t]*(\r\n|\r|\n)", data)
    if m is None:
        raise MeshError(f"{path}: cannot be read as PLY: it does not start with 'ply'; the "
                        f"file is damaged or not PLY")
    end = _END.search(data, 0, MAX_HEADER)
    if end is None:
        raise MeshError(f"{path}: cannot be read as PLY: no end_header line in its first "
                        f"{MAX_HEADER:,} bytes; the file is damaged or not PLY")
    text = data[:end.start()].decode("latin-1")
    start = end.end()
    if end.group(1) == b"\r\n" and m.group(1) == b"\r":
        start -= 1  # a CR-ended header: the LF after it is the data's first byte
    fmt, elements, comments = None, [], []
    for number, line in enumerate(re.split(r"\r\n|\r|\n", text)[1:], 2):
        words = line.split()
        if not words:
            continue
        key = words[0]
        if key in ("comment", "obj_info"):
            comments.append(line.strip()[len(key):].strip())
        elif key == "format" and len(words) == 3 and words[1] in (
                "ascii", "binary_little_endian", "binary_big_endian"):
            fmt = words[1]
        elif key == "element" and len(words) == 3 and words[2].isdigit():
            elements.append(Element(words[1], int(words[2])))
        elif key == "property" and elements and len(words) == 3 and words[1] in TYPES:
            elements[-1].properties.append((words[2], TYPES[words[1]], None))
        elif (key == "property" and elements and len(words) == 5 and words[1] == "list"
              and words[2] in TYPES and words[3] in TYPES and TYPES[words[2]][0] in "iu"):
            elements[-1].properties.append((words[4], TYPES[words[3]], TYPES[words[2]]))
        elif key in ("element", "property", "format"):
            raise MeshError(f"{path}: cannot be read as PLY: header line {number} "
                            f"{line.strip()[:60]!r} cannot be read")
        # anything else (a comment's second line, as some exporters write) says nothing
    if fmt is None:
        raise MeshError(f"{path}: cannot be read as PLY: its header has no format line")
    return fmt, elements, comments, start


def _short(path: str, elements, what: str) -> MeshError:
    counts = ", ".join(f"{e.count:,} {e.name}" for e in elements)
    return MeshError(f"{path}: the PLY header announces {counts}, but {what}; the file is cut "
                     f"short or its header is wrong")


# --------------------------------------------------------------------- binary


def _binary(path: str, data: memoryview, elements, order: str) -> None:
    at = 0
    for e in elements:
        if e.fixed():
            dt = np.dtype([(n, order + t) for n, t, _ in e.properties]) if e.properties \
                else np.dtype([])
            need = e.count * dt.itemsize
            if at + need > len(data):
                raise _short(path, elements, f"its {len(data):,} bytes of data end inside "
                                             f"element {e.name!r}")
            rec = np.frombuffer(data, dt, count=e.count, offset=at) if dt.itemsize else None
            e.data = {n: rec[n] for n, _, _ in e.properties} if rec is not None else {}
            at += need
        else:
            at = _binary_lists(path, data, e, order, at, elements)


def _binary_lists(path, data, e: Element, order: str, at: int, elements) -> int:
    """Read an element with list properties; the same length everywhere is one strided read."""
    sizes = [(np.dtype(order + t), None if c is None else np.dtype(order + c))
             for _, t, c in e.properties]
    if e.count == 0:
        e.data = {n: (np.zeros(0, np.int64), np.zeros(0, order + t)) if c else
                  np.zeros(0, order + t) for n, t, c in e.properties}
        return at
    # Guess every row is as long as the first; check every count against it.
    first, pos = [], at
    for item, count in sizes:
        if count is None:
            pos += item.itemsize
            continue
        if pos + count.itemsize > len(data):
            raise _short(path, elements, f"element {e.name!r} runs past the end of the file")
        k = int(np.frombuffer(data, count, count=1, offset=pos)[0])
        if k < 0:
            raise MeshError(f"{path}: element {e.name!r} has a list of {k} items; the file is "
                            f"damaged")
        first.append(k)
        pos += count.itemsize + k * item.itemsize
    row = pos - at
    fields, lens = [], iter(first)
    for (n, _, c), (item, count) in zip(e.properties, sizes):
        if c is None:
            fields.append((n, item))
        else:
            fields += [(n + "#n", count), (n, item, (next(lens),))]
    dt = np.dtype(fields)
    if at + row * e.count <= len(data):
        rec = np.frombuffer(data, dt, count=e.count, offset=at)
        lens = iter(first)
        if all(np.all(rec[n + "#n"] == next(lens)) for n, _, c in e.properties if c):
            lens = iter(first)
            for n, t, c in e.properties:
                if c is None:
                    e.data[n] = rec[n]
                else:
                    k = next(lens)
                    e.data[n] = (np.full(e.count, k, np.int64), rec[n].reshape(-1))
            return at + row * e.count
    return _binary_rows(path, data, e, sizes, at, elements)


def _binary_rows(path, data, e: Element, sizes, at: int, elements) -> int:
    """Rows of lists of different lengths, one at a time (polygons of several sizes)."""
    buf = np.frombuffer(data, np.uint8)
    out = {n: [] for n, _, _ in e.properties}
    for _ in range(e.count):
        for (n, _, c), (item, count) in zip(e.properties, sizes):
            if c is None:
                end = at + item.itemsize
                if end > len(buf):
                    raise _short(path, elements, f"element {e.name!r} runs past the end of "
                                                 f"the file")
                out[n].append(buf[at:end])
                at = end
                continue
            if at + count.itemsize > len(buf):
                raise _short(path, elements, f"element {e.name!r} runs past the end of the file")
            k = int(buf[at:at + count.itemsize].view(count)[0])
            if k < 0:
                raise MeshError(f"{path}: element {e.name!r} has a list of {k} items; the file "
                                f"is damaged")
            at += count.itemsize
            end = at + k * item.itemsize
            if end > len(buf):
                raise _short(path, elements, f"element {e.name!r} runs past the end of the file")
            out[n].append((k, buf[at:end]))
            at = end
    for (n, _, c), (item, _) in zip(e.properties, sizes):
        if c is None:
            e.data[n] = np.concatenate(out[n]).view(item)
        else:
            counts = np.array([k for k, _ in out[n]], np.int64)
            values = np.concatenate([b for _, b in out[n]]).view(item)
            e.data[n] = (counts, values)
    return at


# --------------------------------------------------------------------- ASCII


def _ascii(path: str, data: memoryview, elements) -> None:
    """Each element's rows, one line each (PLY's ASCII layout; words past a row's end are not read)."""
    lines = [ln for ln in bytes(data).decode("latin-1").splitlines() if ln.strip()]
    at = 0
    for e in elements:
        rows = lines[at:at + e.count]
        if len(rows) < e.count:
            raise _short(path, elements, f"its {len(lines):,} lines of data end inside element "
                                         f"{e.name!r}")
        at += e.count
        if e.count == 0:
            e.data = {n: (np.zeros(0, np.int64), np.zeros(0, t)) if c else np.zeros(0, t)
                      for n, t, c in e.properties}
        elif not _ascii_block(path, rows, e):
            _ascii_rows(path, rows, e, elements)


def _numbers(path: str, words) -> np.ndarray:
    try:
        return np.array(words, dtype=np.float64)
    except ValueError:
        bad = next(w for w in words if not _is_number(w))
        raise MeshError(f"{path}: its ASCII data holds {bad[:30]!r}, which is not a number; the "
                        f"file is damaged") from None


def _is_number(word: str) -> bool:
    try:
        float(word)
        return True
    except ValueError:
        return False


def _as(values: np.ndarray, code: str) -> np.ndarray:
    """Numbers read as text, in the property's type (a ``float`` is rounded to 32 bits, as
    trimesh's reader and the format have it)."""
    return values.astype(code)


def _layout(path: str, first: np.ndarray, e: Element) -> list:
    """The first row's list lengths (the guess for every row)."""
    lens, pos = [], 0
    for _, _, c in e.properties:
        if c is not None:
            k = first[pos] if pos < len(first) else -1
            if not (k >= 0 and k == int(k)):
                raise MeshError(f"{path}: element {e.name!r} has a list of {k} items; the file "
                                f"is damaged")
            lens.append(int(k))
            pos += 1 + int(k)
        else:
            pos += 1
    return lens


def _ascii_block(path: str, rows: list, e: Element) -> bool:
    """Read rows that all have the first row's layout, at once; False where they do not."""
    first = _numbers(path, rows[0].split())
    lens = _layout(path, first, e)
    width = len(e.properties) + sum(lens)
    words = " ".join(rows).split()
    if len(words) != width * len(rows):
        return False
    block = _numbers(path, words).reshape(len(rows), width)
    j, it, cols = 0, iter(lens), {}
    for n, t, c in e.properties:
        if c is None:
            cols[n] = _as(block[:, j], t)
            j += 1
            continue
        k = next(it)
        if not np.all(block[:, j] == k):
            return False
        cols[n] = (np.full(len(rows), k, np.int64), _as(block[:, j + 1:j + 1 + k], t).reshape(-1))
        j += 1 + k
    e.data = cols
    return True


def _ascii_rows(path: str, rows: list, e: Element, elements) -> None:
    """Rows of different layouts (polygons of several sizes, words past the end), one by one."""
    out = {n: [] for n, _, _ in e.properties}
    for row in rows:
        values = _numbers(path, row.split())
        at = 0
        for n, _, c in e.properties:
            if at >= len(values):
                raise _short(path, elements, f"a row of element {e.name!r} ends early")
            if c is None:
                out[n].append(values[at])
                at += 1
                continue
            k = values[at]
            if not (k >= 0 and k == int(k)) or at + 1 + int(k) > len(values):
                raise _short(path, elements, f"a list of element {e.name!r} runs past its row")
            out[n].append(values[at + 1:at + 1 + int(k)])
            at += 1 + int(k)
    for n, t, c in e.properties:
        if c is None:
            e.data[n] = _as(np.array(out[n], np.float64), t)
        else:
            counts = np.array([len(x) for x in out[n]], np.int64)
            values = np.concatenate(out[n]) if out[n] else np.zeros(0)
            e.data[n] = (counts, _as(values, t))


# --------------------------------------------------------------------- the mesh


def _unit(columns, problems: list, what: tuple, path: str):
    """(k, 3) float64 colours in [0, 1] as stored (NaN rows: no colour, said), or None."""
    c = np.stack([np.asarray(x).reshape(-1) for x in columns], axis=1)
    if c.dtype.kind == "f":
        c = c.astype(np.float64)
        ok = np.isfinite(c).all(axis=1)
        scale = 255.0 if ok.any() and c[ok].max() > 1.0 else 1.0
    else:
        c = c.astype(f"u{c.dtype.itemsize}")  # two's complement: char -1 is 255
        scale = float(np.iinfo(c.dtype).max)
        c = c.astype(np.float64)
        ok = np.ones(len(c), dtype=bool)
    out = np.clip(c / scale, 0.0, 1.0)
    out[~ok] = np.nan
    if not ok.all():
        k = int((~ok).sum())
        problems.append(f"{path}: NaN or infinite colour on {k:,} {what[k != 1]}")
    return out


def _fan(counts: np.ndarray, corners: np.ndarray) -> tuple:
    """(triangles (m, 3) int64, polygon of each (m,) int64): polygons fanned from their first corner."""
    if counts.size and np.all(counts == 3):
        return corners.reshape(-1, 3).astype(np.int64), np.arange(len(counts))
    first = np.r_[0, np.cumsum(counts)[:-1]]
    keep = np.flatnonzero(counts >= 3)
    n_tri = counts[keep] - 2
    poly = np.repeat(keep, n_tri)
    j = np.arange(len(poly)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    c0 = first[poly]
    return corners.astype(np.int64)[np.stack([c0, c0 + j, c0 + j + 1], axis=1)], poly


def read_ply(path: str, *, rule: str = "anywhere"):
    """The :class:`~geovox.mesh.Mesh` of a PLY file.

    Parameters
    ----------
    path : str
    rule : {"anywhere", "folder"}
        Where the texture a ``comment TextureFile`` names may be read from.

    Every array is checked against the bytes that hold it before it is made,
    so a PLY needs no limit beyond its own size (``max_input_size`` bounds that).

    Raises
    ------
    MeshError
        One line: not PLY, a header line that cannot be read, sizes that do
        not add up, an index past the vertices, or no faces.
    """
    with open(path, "rb") as f:
        data = f.read()
    fmt, elements, comments, offset = parse_header(path, data)
    body = memoryview(data)[offset:]
    if fmt == "ascii":
        _ascii(path, body, elements)
    else:
        _binary(path, body, elements, "<" if fmt == "binary_little_endian" else ">")
    del body
    return _mesh(path, {e.name: e for e in elements}, comments, rule)


def _mesh(path: str, by_name: dict, comments: list, rule: str):
    vertex, face = by_name.get("vertex"), by_name.get("face")
    if vertex is None or vertex.count == 0:
        raise MeshError(f"{path}: contains no geometry (no vertices or faces could be read "
                        f"from it)")
    if not all(k in vertex.data and not isinstance(vertex.data[k], tuple) for k in "xyz"):
        raise MeshError(f"{path}: its vertices have no x, y and z")
    vertices = np.column_stack([vertex.data[k].astype(np.float64) for k in "xyz"])
    lists = None
    if face is not None:
        lists = next((face.data[k] for k in ("vertex_indices", "vertex_index")
                      if isinstance(face.data.get(k), tuple)), None)
    if lists is None or face.count == 0:
        raise MeshError(f"{path}: has no faces, only a point cloud ({len(vertices):,} points); "
                        f"geovox voxelises the inside of a triangle surface")
    counts, corners = lists
    if corners.dtype.kind == "f" and not np.all(corners == np.floor(corners)):
        raise MeshError(f"{path}: its faces' vertex indices are not whole numbers")
    faces, poly = _fan(counts, corners)
    problems: list = []
    extra = {"face_material": np.full(len(faces), -1, np.int64), "materials": []}
    uv = _corner_uv(vertex, face, faces, poly, counts)
    vcols = (_unit([vertex.data[c] for c in _RGB], problems, ("vertex", "vertices"), path)
             if all(c in vertex.data for c in _RGB) else None)
    if uv is not None:
        m = Material(name="material_0")
        image = _texture(path, comments, rule, problems)
        if image is not None:
            m.image = image
        extra.update(face_material=np.zeros(len(faces), np.int64), materials=[m],
                     corner_uv=uv)
        if vcols is not None:
            vc = _vertex_colours(vcols, problems)
            if vc is not None:
                extra["vertex_colors"] = vc
                m.defined = m.image is not None
    elif vcols is not None:
        vc = _vertex_colours(vcols, problems)
        if vc is not None:
            extra["vertex_colors"] = vc
    elif all(c in face.data for c in _RGB):
        fc = _unit([face.data[c] for c in _RGB], problems, ("face", "faces"), path)
        broken = np.isnan(fc).any(axis=1)
        if broken.any():
            problems[-1] += (f"; {'it takes' if broken.sum() == 1 else 'they take'} the default "
                             f"colour")
        uniq, inverse = np.unique(fc[~broken], axis=0, return_inverse=True)
        key = np.full(len(fc), -1, dtype=np.int64)
        key[~broken] = inverse.reshape(-1)
        extra.update(face_material=key[poly],
                     materials=[Material(name="face colour", kd=c) for c in uniq])
    return build_mesh(vertices, faces, path, problems=problems, **extra)


def _vertex_colours(vc: np.ndarray, problems: list):
    broken = np.isnan(vc).any(axis=1)
    if broken.all():
        problems[-1] += "; the file states no vertex colours, so the default colour is used"
        return None
    if broken.any():
        problems[-1] += (f"; {'it counts' if broken.sum() == 1 else 'they count'} as having "
                         f"no colour (white)")
        vc[broken] = 1.0
    return vc


def _corner_uv(vertex: Element, face: Element, faces, poly, counts):
    """(m, 3, 2) float64 texture coordinates of the triangles' corners, or None."""
    tex = face.data.get("texcoord")
    if isinstance(tex, tuple) and np.all(tex[0] == 2 * counts):
        per = tex[1].astype(np.float64).reshape(-1, 2)
        first = np.r_[0, np.cumsum(counts)[:-1]]
        # the triangles' corners, as positions in the polygons' corner list
        c0 = first[poly]
        j = np.arange(len(poly)) - np.searchsorted(poly, poly) + 1
        at = np.stack([c0, c0 + j, c0 + j + 1], axis=1)
        return per[at]
    for u, v in _UV_NAMES:
        if u in vertex.data and v in vertex.data:
            uv = np.column_stack([vertex.data[u], vertex.data[v]]).astype(np.float64)
            return uv[faces]
    return None


def _texture(path: str, comments: list, rule: str, problems: list):
    """The texels of the image a ``comment TextureFile`` names, or None (said in problems)."""
    name = next((c.split(None, 1)[1] for c in comments
                 if c.startswith("TextureFile") and len(c.split(None, 1)) == 2), None)
    if name is None:
        return None
    found, refused = locate(name, os.path.dirname(os.path.abspath(path)), rule)
    if refused and found is None:
        problems.append(f"{path}: {name!r} is not read: {why_not_read(name)}")
        return None
    if found is None:
        problems.append(f"{path}: cannot read the texture {name!r} (it is missing)")
        return None
    if refused:
        problems.append(f"{path}: {instead(name, found)}")
    try:
        from PIL import Image

        from ..mesh import texels

        with Image.open(found) as image:
            return texels(image)
    except Exception as exc:  # Pillow raises several types for bad images
        problems.append(f"{path}: cannot read the texture {name!r} ({type(exc).__name__})")
        return None
