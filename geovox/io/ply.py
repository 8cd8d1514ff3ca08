"""Binary PLY files of plain triangles, read without trimesh.

Scans and photogrammetry come as binary PLY of millions of triangles; for
such a file, importing trimesh costs more than reading it. :func:`read_plain_ply`
reads the common plain case itself -- a ``vertex`` element of ``x``, ``y``,
``z`` only and a ``face`` element of one vertex-index list, every face a
triangle -- into the very :class:`~geovox.mesh.Mesh` the trimesh path
(``trimesh.load(path, process=False)`` then :func:`geovox.io.load.from_trimesh`)
makes: float64 vertices, int64 faces, no material (face_material -1), no UVs,
no colours, no problems. Anything else (ASCII, colours, normals, UVs, other
elements, polygons, indices out of range, a size that does not match the
header) returns None, and trimesh reads it as before, with its messages.
"""

from __future__ import annotations

import numpy as np

#: PLY scalar type names and their NumPy codes.
TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
#: The header is read from at most this many bytes.
MAX_HEADER = 1 << 16


def _header(path):
    """``(byte order, [(name, count, [(property, type, list count type)])], data offset)`` or None."""
    with open(path, "rb") as f:
        head = f.read(MAX_HEADER)
    end = head.find(b"end_header\n")
    if not head.startswith(b"ply\n") or end < 0 or b"\r" in head[:end]:
        return None
    try:
        lines = head[:end].decode("ascii").split("\n")[1:]
    except UnicodeDecodeError:
        return None
    order, elements = None, []
    for line in lines:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format" and len(words) == 3 and words[2] == "1.0":
            order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(words[1])
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) == 3 and words[1] in TYPES:
            elements[-1][2].append((words[2], TYPES[words[1]], None))
        elif (words[0] == "property" and elements and len(words) == 5 and words[1] == "list"
              and words[2] in TYPES and words[3] in TYPES):
            elements[-1][2].append((words[4], TYPES[words[3]], TYPES[words[2]]))
        else:
            return None
    if order is None:
        return None
    return order, elements, end + len(b"end_header\n")


def read_plain_ply(path: str):
    """The :class:`~geovox.mesh.Mesh` of a plain binary triangle PLY, or None for any other file.

    Parameters
    ----------
    path : str

    Returns
    -------
    Mesh or None
        None where the file is not the plain case (see the module's
        docstring): the caller reads it with trimesh.
    """
    from ..mesh import build_mesh

    head = _header(path)
    if head is None:
        return None
    order, elements, offset = head
    if [e[0] for e in elements] != ["vertex", "face"]:
        return None
    (_, nv, vprops), (_, nf, fprops) = elements
    names = [p[0] for p in vprops]
    if sorted(names) != ["x", "y", "z"] or any(p[2] is not None for p in vprops):
        return None
    if (len(fprops) != 1 or fprops[0][0] not in ("vertex_indices", "vertex_index")
            or fprops[0][2] is None or fprops[0][1][0] not in "iu" or fprops[0][2][0] not in "iu"
            or nv == 0 or nf == 0):
        return None
    if any(p[1][0] != "f" for p in vprops):
        return None
    vdt = np.dtype([(name, order + t) for name, t, _ in vprops])
    fdt = np.dtype([("n", order + fprops[0][2]), ("i", order + fprops[0][1], (3,))])
    with open(path, "rb") as f:
        f.seek(offset)
        data = f.read()
    if len(data) != nv * vdt.itemsize + nf * fdt.itemsize:
        return None  # polygons, a truncated file or trailing bytes: trimesh's to judge
    vrec = np.frombuffer(data, vdt, count=nv)
    frec = np.frombuffer(data, fdt, count=nf, offset=nv * vdt.itemsize)
    if np.any(frec["n"] != 3):
        return None
    vertices = np.empty((nv, 3), np.float64)
    for k, name in enumerate("xyz"):
        vertices[:, k] = vrec[name]
    faces = frec["i"].astype(np.int64)
    if faces.min() < 0 or faces.max() >= nv or not np.isfinite(vertices).all():
        return None
    return build_mesh(vertices, faces, path, face_material=np.full(nf, -1, np.int64),
                      materials=[], corner_uv=None, vertex_colors=None)
