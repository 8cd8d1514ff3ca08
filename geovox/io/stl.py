"""STL files read without trimesh.

STL is the format of many data sets (Thingi10K is all STL) and of most CAD
exports; for such a file, importing trimesh costs more than reading it.
:func:`read_stl` reads the common cases itself into the
:class:`~geovox.mesh.Mesh` the trimesh path (``trimesh.load(path,
process=False)`` then :func:`geovox.io.load.from_trimesh`) makes, indexed:
the same triangles bit for bit (float64), but equal corners are one vertex,
in order of first appearance (:func:`indexed`; trimesh's path keeps three
vertices a facet, six times too many for a closed scan); no material
(face_material -1), no UVs, no colours, no problems, and no parts but for
several ASCII solids (below).

It follows trimesh's (5.2) ``trimesh/exchange/stl.py`` rule for telling the
two kinds apart: a file is binary when its size is exactly 84 bytes plus 50
for each of the facets its header counts, whatever the header says (a
binary header may well start with ``solid``); anything else is ASCII.

An ASCII file is cut into solids as trimesh cuts it (``solid`` ...
``endsolid``, case-insensitive), and a solid's vertices are what trimesh
reads: every number in the text from each ``vertex`` to the end of its line,
in order, three to a vertex and three vertices to a facet (the ``facet``,
``normal``, ``outer loop`` lines play no part). The reader takes the file
only when each of those lines holds nothing but plain decimal numbers (any
spacing, tabs, CRLF, upper-case keywords), so that trimesh could not read
anything else out of it. Several solids with facets are trimesh's scene of
them: one part each, named as trimesh names them (the rest of the ``solid``
line; ``name_1``, ``geometry_1``, ... where that is taken or empty), and each
one's vertices merged as trimesh's processing merges them.

Everything else returns None and trimesh reads it as before, with its
messages: a binary file of no facets, a file of no solids with facets, NaN or
infinite coordinates, ``nan``, ``inf`` or any other word in a vertex line, a
number count that makes no whole triangles, text that is not UTF-8, solids
named ``world...`` (trimesh's scene may rename their nodes).
"""

from __future__ import annotations

import re

import numpy as np

from .names import unique_name

__all__ = ["read_stl", "indexed", "RECORD", "HEADER"]

#: One facet of a binary STL: normal, three corners, the attribute word (little-endian).
RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
#: The 80-byte header and the uint32 facet count.
HEADER = 84

#: What trimesh reads of a vertex line: the text from ``vertex`` to the end of
#: the line (it cuts at "\n" only), here only where it holds nothing but
#: numbers' characters and the blanks NumPy's ``fromstring`` takes for a
#: space ("\r" of CRLF among them).
_VERTEX = re.compile(r"vertex([ \t\r\x0b\x0c0-9eE.+-]*)\n")


def _binary(data: bytes):
    """(n, 3) float64 corners of a binary STL, None when it is not one, or False when trimesh must say."""
    if len(data) < HEADER:
        return None
    count = int(np.frombuffer(data, "<u4", count=1, offset=80)[0])
    if len(data) - HEADER != count * RECORD.itemsize:
        return None  # not binary by trimesh's rule: read as ASCII
    if count == 0:
        return False  # trimesh: a scene of no geometry, its message
    facets = np.frombuffer(data, RECORD, count=count, offset=HEADER)
    return facets["corners"].reshape(-1, 3).astype(np.float64)


def _solids(text: str):
    """``[(start, lower-cased text)]`` of each solid, as trimesh's ``load_stl_ascii`` cuts it, or None."""
    lower = text.lower()
    solids, position = [], 0
    while True:
        start = lower.find("solid", position)
        end = lower.find("endsolid", position)
        position = end + len("endsolid")
        if start < 0 or end < 0:
            return solids
        if start > end:
            return None  # trimesh: "`endsolid` precedes `solid`!"
        solids.append((start, lower[start:end]))


def _ascii(data: bytes):
    """``{name: (n, 3) float64 vertices}`` of each solid with facets, or False (trimesh reads it)."""
    try:
        text = data.decode("utf-8").strip()
    except UnicodeDecodeError:
        return False  # trimesh guesses an encoding
    solids = _solids(text)
    if solids is None:
        return False
    found = {}
    for start, solid in solids:
        lines = _VERTEX.findall(solid)
        if len(lines) != solid.count("vertex"):
            # a ``vertex`` whose line trimesh would read otherwise: a word on
            # it, two on one line, in the solid's name, no line end
            return False
        try:
            # Python's float takes exactly the plain decimal numbers these
            # characters can spell, and rounds them as NumPy's fromstring
            # (trimesh's parser) does; "1-2", "1e" or "." fail here.
            vertices = np.array(" ".join(lines).split(), dtype=np.float64)
        except ValueError:
            return False
        if len(vertices) < 3:
            continue  # trimesh skips a solid of fewer than three numbers
        if len(vertices) % 9 or "\n" not in solid:
            return False  # trimesh: "incorrect number of vertices", or no whole triangle
        # trimesh's name: the rest of the ``solid`` line, in the file's case
        name = text[start:start + solid.find("\n")][6:].strip()
        found[unique_name(name, found)] = vertices.reshape(-1, 3)
    return found or False  # no facets: trimesh's message


def _merged(vertices):
    """``(vertices, faces)`` of one solid of a scene, its vertices merged as trimesh merges them.

    trimesh makes a scene of an ASCII file's solids and processes each one
    (``Trimesh(process=True)``): vertices equal to 8 decimals become one, kept
    where they first occur, in the order they first occur
    (``grouping.merge_vertices``). None where the scaled coordinates would
    not fit the int64 trimesh casts them to.
    """
    scaled = vertices * (10 ** 8)
    if not np.abs(scaled).max() < 2.0 ** 62:
        return None
    _, first, inverse = np.unique(scaled.round().astype(np.int64), axis=0, return_index=True,
                                  return_inverse=True)
    order = first.argsort()
    rank = order.argsort()
    return vertices[first[order]], rank[inverse.reshape(-1)].reshape(-1, 3)


def indexed(corners: np.ndarray):
    """``(vertices, faces)`` of a triangle soup: equal corners one vertex, in order of first appearance.

    An STL repeats each vertex in every facet that uses it (six times, in a
    closed mesh); merged, a scan of millions of triangles holds a sixth of
    the vertices, and everything after the reading (the closedness checks,
    the repair's edge tables) works on those. Only equal coordinates merge,
    so the triangles are the file's, bit for bit; where a corner has a
    ``-0.0`` (equal to ``0.0``, but not the same bits) nothing is merged.

    Parameters
    ----------
    corners : (3m, 3) float64, finite
        The facets' corners in file order.

    Returns
    -------
    vertices : (n, 3) float64
        The distinct corners, in order of first appearance.
    faces : (m, 3) int64
    """
    nf = len(corners) // 3
    if np.signbit(corners[corners == 0]).any():
        return corners, np.arange(3 * nf, dtype=np.int64).reshape(nf, 3)
    try:
        from .._lattice import merge_positions
    except ImportError:  # built without a compiler: the same numbering by a sort
        merge_positions = _merge_positions
    ids = merge_positions(corners)
    # Numbered in order of first appearance: a vertex first appears where the
    # running maximum of the ids grows.
    top = np.maximum.accumulate(ids)
    first = np.flatnonzero(np.r_[len(ids) > 0, top[1:] > top[:-1]])
    return corners[first], ids.reshape(nf, 3)


def _merge_positions(corners: np.ndarray) -> np.ndarray:
    """:func:`geovox._lattice.merge_positions` by NumPy: ids by exact position, in order of first appearance."""
    _, first, inverse = np.unique(np.ascontiguousarray(corners).view(np.dtype((np.void, 24))),
                                  return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


def _scene(solids: dict, path: str):
    """The Mesh ``from_trimesh`` makes of trimesh's scene of several solids (one part each), or None."""
    from ..mesh import build_mesh

    if any(name.lower().startswith("world") for name in solids):
        return None  # trimesh's scene names its base frame "world": nodes may be renamed
    verts, faces, offset = [], [], 0
    for vertices in solids.values():
        merged = _merged(vertices)
        if merged is None:
            return None
        verts.append(merged[0])
        faces.append(merged[1] + offset)
        offset += len(merged[0])
    sizes = [len(f) for f in faces]
    return build_mesh(np.concatenate(verts), np.concatenate(faces), path,
                      face_material=np.full(sum(sizes), -1, np.int64), materials=[],
                      corner_uv=None, vertex_colors=None, parts=list(solids),
                      face_part=np.repeat(np.arange(len(sizes), dtype=np.int64), sizes))


def read_stl(path: str):
    """The :class:`~geovox.mesh.Mesh` of a binary or ASCII STL, or None.

    Parameters
    ----------
    path : str

    Returns
    -------
    Mesh or None
        ``vertices`` (n, 3) float64, the distinct corners in order of first
        appearance, and ``faces`` (m, 3) int64 (:func:`indexed`); for several
        ASCII solids, each solid's vertices merged as trimesh merges them, ``parts`` (their names)
        and ``face_part`` (m,) int64. None where
        the file is not a case this reader takes (see the module's
        docstring): the caller reads it with trimesh.
    """
    from ..mesh import build_mesh

    with open(path, "rb") as f:
        data = f.read()
    vertices = _binary(data)
    if vertices is not None:
        del data  # the file's bytes, before the vertices are merged
    else:
        solids = _ascii(data)
        if solids is False or not all(np.isfinite(v).all() for v in solids.values()):
            return None
        if len(solids) > 1:
            return _scene(solids, path)
        vertices = next(iter(solids.values()))
    if vertices is False or not np.isfinite(vertices).all():
        return None
    vertices, faces = indexed(vertices)
    return build_mesh(vertices, faces, path, face_material=np.full(len(faces), -1, np.int64),
                      materials=[], corner_uv=None, vertex_colors=None)
