"""glTF triangle strips and fans, turned into plain triangles before trimesh reads a file.

glTF draws a primitive's vertices (in the order its ``indices`` give, or
0, 1, 2, ... without them) as separate triangles (mode 4), a strip (mode 5)
or a fan (mode 6). trimesh reads strips but skips fans, so a file of fans
would lose geometry. geovox rewrites every strip and fan primitive into
mode 4 with an index list of its own, in a buffer embedded in the JSON
(a ``data:`` URI), so that every triangle primitive converts. Winding
follows the glTF specification (3.7.2.1, "Topology types"), so the faces
keep the orientation the file gives them:

* strip: triangle i is ``(v[i], v[i + 1 + i % 2], v[i + 2 - i % 2])``;
* fan: triangle i is ``(v[i + 1], v[i + 2], v[0])``.

Triangles with a repeated vertex (the degenerate joins of stitched strips)
draw nothing and are left out.
"""

from __future__ import annotations

import base64

import numpy as np

_TRIANGLES, _STRIP, _FAN = 4, 5, 6
#: glTF index component types.
_INDEX_TYPES = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32}


class Unreadable(ValueError):
    """A strip or fan whose indices cannot be read; the primitive is left to trimesh."""


def strip_faces(index: np.ndarray) -> np.ndarray:
    """(n - 2, 3) int64 triangles of a triangle strip, glTF's winding, degenerate ones dropped.

    ``index`` : (n,) integer vertex indices in drawing order.
    """
    v = np.asarray(index, dtype=np.int64).reshape(-1)
    if len(v) < 3:
        return np.zeros((0, 3), dtype=np.int64)
    i = np.arange(len(v) - 2)
    odd = i % 2
    tri = np.stack([v[i], v[i + 1 + odd], v[i + 2 - odd]], axis=1)
    return _drop_degenerate(tri)


def fan_faces(index: np.ndarray) -> np.ndarray:
    """(n - 2, 3) int64 triangles of a triangle fan, glTF's winding, degenerate ones dropped.

    ``index`` : (n,) integer vertex indices in drawing order; ``index[0]`` is the hub.
    """
    v = np.asarray(index, dtype=np.int64).reshape(-1)
    if len(v) < 3:
        return np.zeros((0, 3), dtype=np.int64)
    i = np.arange(len(v) - 2)
    tri = np.stack([v[i + 1], v[i + 2], np.full(len(i), v[0])], axis=1)
    return _drop_degenerate(tri)


def _drop_degenerate(tri: np.ndarray) -> np.ndarray:
    keep = (tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])
    return tri[keep]


def _listed(header: dict, key: str) -> list:
    value = header.get(key)
    return value if isinstance(value, list) else []


def _indices(header: dict, primitive: dict, read_buffer) -> np.ndarray:
    """(n,) int64: the vertex indices a primitive draws, in order.

    Raises
    ------
    Unreadable
        A sparse or malformed accessor, or a buffer that cannot be read.
    """
    accessors = _listed(header, "accessors")
    if "indices" not in primitive:
        position = primitive["attributes"].get("POSITION")
        if not isinstance(position, int) or not 0 <= position < len(accessors):
            raise Unreadable("no POSITION accessor")
        count = accessors[position].get("count")
        if not isinstance(count, int) or count < 0:
            raise Unreadable("a POSITION accessor without a count")
        return np.arange(count, dtype=np.int64)
    k = primitive["indices"]
    if not isinstance(k, int) or not 0 <= k < len(accessors) or not isinstance(accessors[k], dict):
        raise Unreadable(f"indices {k!r} name no accessor")
    acc = accessors[k]
    dtype = _INDEX_TYPES.get(acc.get("componentType"))
    count, view = acc.get("count"), acc.get("bufferView")
    views = _listed(header, "bufferViews")
    if (dtype is None or "sparse" in acc or not isinstance(count, int) or count < 0
            or not isinstance(view, int) or not 0 <= view < len(views)):
        raise Unreadable("an index accessor geovox cannot read")
    bv = views[view]
    data = read_buffer(bv.get("buffer"))
    size = np.dtype(dtype).itemsize
    stride = bv.get("byteStride") or size
    start = int(bv.get("byteOffset", 0)) + int(acc.get("byteOffset", 0))
    end = start + (count - 1) * stride + size if count else start
    if start < 0 or end > len(data) or end - int(bv.get("byteOffset", 0)) > bv.get("byteLength",
                                                                                    len(data)):
        raise Unreadable("an index accessor reaching past its buffer")
    raw = np.frombuffer(data, dtype=np.uint8, count=end - start, offset=start)
    little = np.dtype(dtype).newbyteorder("<")  # glTF is little-endian
    if stride != size:
        raw = np.ascontiguousarray(
            np.lib.stride_tricks.as_strided(raw, shape=(count, size), strides=(stride, 1)))
    return raw.view(little).reshape(-1).astype(np.int64)


def triangulate(header: dict, read_buffer) -> list:
    """Rewrite every strip and fan primitive of a glTF header into plain triangles, in place.

    Parameters
    ----------
    header : dict
        The glTF JSON.
    read_buffer : callable
        ``read_buffer(i) -> bytes``: the bytes of buffer ``i``; raises
        :class:`Unreadable` (or OSError) where it cannot.

    Returns
    -------
    list of str
        One line per primitive left as it was (its indices could not be
        read); trimesh then reads or skips it, and geovox says so.
    """
    primitives = [p for m in _listed(header, "meshes") if isinstance(m, dict)
                  for p in (m.get("primitives") if isinstance(m.get("primitives"), list) else [])
                  if isinstance(p, dict) and isinstance(p.get("attributes"), dict)
                  and p.get("mode") in (_STRIP, _FAN)]
    if not primitives:
        return []
    left, chunks, offset = [], [], 0
    accessors = header.setdefault("accessors", [])
    views = header.setdefault("bufferViews", [])
    buffers = header.setdefault("buffers", [])
    target = len(buffers)
    for p in primitives:
        try:
            index = _indices(header, p, read_buffer)
        except (Unreadable, OSError, TypeError, ValueError) as exc:
            left.append(f"a triangle {'fan' if p['mode'] == _FAN else 'strip'} whose indices "
                        f"cannot be read ({exc})")
            continue
        tri = (fan_faces if p["mode"] == _FAN else strip_faces)(index)
        flat = tri.astype("<u4").reshape(-1).tobytes()
        views.append({"buffer": target, "byteOffset": offset, "byteLength": len(flat)})
        accessors.append({"bufferView": len(views) - 1, "componentType": 5125,
                          "count": 3 * len(tri), "type": "SCALAR"})
        p["indices"] = len(accessors) - 1
        p["mode"] = _TRIANGLES
        chunks.append(flat)
        offset += len(flat)
    if chunks:
        data = b"".join(chunks)
        buffers.append({"byteLength": len(data), "uri": "data:application/octet-stream;base64,"
                        + base64.b64encode(data).decode("ascii")})
    return left
