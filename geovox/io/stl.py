"""STL files read without trimesh.

STL is the format of many data sets (Thingi10K is all STL) and of most CAD
exports; for such a file, importing trimesh costs more than reading it.
:func:`read_stl` reads the common cases itself into the very
:class:`~geovox.mesh.Mesh` the trimesh path (``trimesh.load(path,
process=False)`` then :func:`geovox.io.load.from_trimesh`) makes: float64
vertices, three for each facet in file order (no vertex is merged), int64
faces ``0, 1, 2, 3, ...``, no material (face_material -1), no UVs, no
colours, no parts, no problems.

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
anything else out of it. Everything else returns None and trimesh reads it
as before, with its messages: several solids holding facets (trimesh makes a
scene of them, one part each, and merges each one's vertices), a binary file
of no facets, a file of no solids, NaN or infinite coordinates, ``nan``,
``inf`` or any other word in a vertex line, a number count that makes no
whole triangles, text that is not UTF-8.
"""

from __future__ import annotations

import re

import numpy as np

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
    """The lower-cased text of each solid, as trimesh's ``load_stl_ascii`` cuts it, or None."""
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
        solids.append(lower[start:end])


def _ascii(data: bytes):
    """(n, 3) float64 vertices of a one-solid ASCII STL, or False when trimesh must read it."""
    try:
        text = data.decode("utf-8").strip()
    except UnicodeDecodeError:
        return False  # trimesh guesses an encoding
    solids = _solids(text)
    if solids is None:
        return False
    found = []
    for solid in solids:
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
        if len(vertices) % 9:
            return False  # trimesh: "incorrect number of vertices", or no whole triangle
        found.append(vertices.reshape(-1, 3))
    if len(found) != 1:
        return False  # no facets (trimesh's message), or several solids: a trimesh scene
    return found[0]


def read_stl(path: str):
    """The :class:`~geovox.mesh.Mesh` of a binary or one-solid ASCII STL, or None.

    Parameters
    ----------
    path : str

    Returns
    -------
    Mesh or None
        ``vertices`` (3m, 3) float64, three per facet in file order, and
        ``faces`` (m, 3) int64 ``[[0, 1, 2], [3, 4, 5], ...]``; None where
        the file is not a case this reader takes (see the module's
        docstring): the caller reads it with trimesh.
    """
    from ..mesh import build_mesh

    with open(path, "rb") as f:
        data = f.read()
    vertices = _binary(data)
    if vertices is None:
        vertices = _ascii(data)
    if vertices is False or not np.isfinite(vertices).all():
        return None
    nf = len(vertices) // 3
    return build_mesh(vertices, np.arange(3 * nf, dtype=np.int64).reshape(nf, 3), path,
                      face_material=np.full(nf, -1, np.int64), materials=[], corner_uv=None,
                      vertex_colors=None)
