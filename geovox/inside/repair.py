"""Repairing a copy of a mesh before its inside is decided by winding numbers.

The generalised winding number assumes faces wound consistently, each piece
facing out. Models from the wild break that: faces wound both ways, every
face stored twice (once each way, as double-sided game assets are), duplicate
and degenerate faces. :func:`repair` makes a copy that satisfies the
assumption, in whole-array steps (no loop per face or per piece):

1. vertices merged by position: equal ones, and those closer than ``WELD``
   times the model's size (an unwelded seam is a crack no ray can pass,
   but it would leave open edges whose caps span the whole seam);
2. degenerate faces dropped (a repeated vertex, or zero area);
3. duplicates collapsed to the first one: the same three vertices in either
   order, so the two sides of a double-sided face become one face;
4. faces turned to agree with their neighbours across every manifold edge
   (an edge of exactly two faces): a spanning forest of the face graph,
   built by hooking roots in whole-array rounds, carries each face's flip
   relative to its piece's first face (:func:`components`);
5. each piece (connected through manifold edges) turned outward: its signed
   volume measured about the centroid of its boundary edges' midpoints must
   be positive. For a closed piece that is its signed volume; for an open one
   it is the signed volume of the piece closed by a fan from that centroid,
   the same kind of cap :mod:`geovox.inside` bridges holes with, so a bowl
   faces out of the solid its rim bridges to (a flat sheet, volume 0, is
   kept as it is).

Every step is whole-array NumPy, or, with the compiled kernel
(:mod:`geovox._lattice`, chosen as :mod:`geovox.kernels` says), a loop in
linear time that gives the same arrays: hash tables instead of sorts for the
positions, the close pairs and the duplicates, a counting sort for the edge
table, the forest's rounds as loops. Only the distinct positions are sorted
(the copy's vertex ids are their lexicographic order). Results are cached on
the mesh (:func:`merged_faces`, and ``boundary_edges`` counts the open and
non-manifold edges as it goes), and the copy is made with its merged faces
known, so nothing is computed twice.

The copy keeps, for each of its faces, the original face it came from and
whether its vertices 1 and 2 were swapped, so crossings found on the copy are
crossings of the original triangles (with their barycentric weights swapped
back), which is what colour and density need.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backends.base import Hits
from ..kernels import lattice
from ..mesh import Mesh
from .edges import components, manifold_pairs, merged_faces, sorted_edges


@dataclass
class Repair:
    """A repaired copy of a mesh and what was done to make it.

    Attributes
    ----------
    mesh : Mesh
        The copy: merged vertices, faces consistently oriented and outward.
    face : (k,) int64
        Index in the original mesh's faces of each face of the copy.
    swapped : (k,) bool
        The copy's face has the original's vertices 1 and 2 swapped.
    piece : (k,) int64
        The piece (connected through manifold edges) of each face of the copy.
    merged_vertices : int
        Vertices removed by merging by position.
    welded : int
        Of those, vertices merged with a distinct one closer than ``WELD``.
    degenerate : int
        Faces dropped as degenerate.
    duplicates : int
        Faces dropped as exact duplicates (same vertices, same winding).
    opposite : int
        Faces dropped as the reversed side of another (double-sided faces).
    inner : int
        Of the faces left after that, those dropped as the kept side of an
        inner wall between closed parts (see :func:`_inner_walls`); with
        their reversed sides (counted in ``opposite``) nothing of the wall is left.
    flipped : int
        Faces of the copy wound the other way from the original.
    pieces : int
        Pieces connected through manifold edges.
    closed_pieces : int
        Pieces with every edge shared by exactly two faces.
    outward : int
        Pieces turned over as a whole to face outward.
    """

    mesh: Mesh
    face: np.ndarray
    swapped: np.ndarray
    piece: np.ndarray
    merged_vertices: int = 0
    welded: int = 0
    degenerate: int = 0
    duplicates: int = 0
    opposite: int = 0
    inner: int = 0
    flipped: int = 0
    pieces: int = 0
    closed_pieces: int = 0
    outward: int = 0

    @property
    def changed(self) -> bool:
        """Whether the copy differs from the original in anything but vertex numbering."""
        return bool(self.degenerate or self.duplicates or self.opposite or self.flipped
                    or self.welded or self.inner)

    def describe(self) -> str:
        """One phrase saying what was repaired, for warnings and ``geovox info``."""
        parts = [f"{self.flipped:,} faces flipped to agree with their neighbours and face outward"]
        if self.duplicates or self.opposite:
            parts.append(f"{self.duplicates + self.opposite:,} duplicate faces dropped "
                         f"({self.opposite:,} of them the reversed side of a double-sided face)")
        if self.inner:
            parts.append(f"{self.inner:,} double-sided faces dropped on both sides as inner walls "
                         f"between closed parts")
        if self.welded:
            parts.append(f"{self.welded:,} vertices welded to a neighbour closer than "
                         f"{WELD:g} of the model's size")
        if self.degenerate:
            parts.append(f"{self.degenerate:,} degenerate faces dropped")
        parts.append(f"{self.pieces:,} pieces ({self.closed_pieces:,} closed, "
                     f"{self.outward:,} turned outward as a whole)")
        return "; ".join(parts)

    def original_hits(self, hits):
        """Crossings of the copy's faces as crossings of the original triangles.

        Parameters
        ----------
        hits : geovox.backends.base.Hits
            Crossings of ``self.mesh``.

        Returns
        -------
        Hits
            The same crossings, ``triangle`` indexing the original faces and
            ``bary`` the original vertices 1 and 2.
        """
        swap = self.swapped[hits.triangle]
        bary = np.where(swap[:, None], hits.bary[:, ::-1], hits.bary)
        return Hits(hits.ray, hits.depth, self.face[hits.triangle], bary)


#: Vertices closer than this fraction of the model's size are one vertex: seams
#: left unwelded by float32 round-off (a crack no ray can pass) are closed.
WELD = 1e-6


def close_pairs(pos: np.ndarray, tol: float, lex_sorted: bool = False) -> np.ndarray:
    """Pairs of points at most ``tol`` apart, each once (as scipy's ``query_pairs``).

    A hash grid of cells ``tol`` wide, in NumPy: two such points lie in the
    same cell or in neighbouring ones, so each point looks up its own cell
    and 13 of its 26 neighbours (the other 13 look it up).

    Parameters
    ----------
    pos : (n, 3) float64
    tol : float, > 0
    lex_sorted : bool
        The points are in lexicographic order (the repair's positions): the
        compiled kernel then finds the candidates by a sweep along x
        (:func:`geovox._lattice.sweep_pairs`), with no table.

    Returns
    -------
    (p, 2) int64
        ``i < j`` in each row; the rows in no particular order (the compiled
        kernel's hash table of cells, :func:`geovox._lattice.near_pairs`,
        finds the same pairs in another order).
    """
    n = len(pos)
    if n < 2 or not tol > 0:
        return np.zeros((0, 2), np.int64)
    # Column by column: NumPy's axis-0 reduction of an (n, 3) array is ten times slower.
    low = np.array([pos[:, k].min() for k in range(3)])

    def cells(p):  # >= 1: no wrap at -1
        return np.floor((p - low) / tol).astype(np.int64) + 1

    dims = cells(np.array([pos[:, k].max() for k in range(3)])) + 2  # the largest cells (monotonic)
    if float(dims[0]) * float(dims[1]) * float(dims[2]) >= 2.0 ** 62:  # one key would overflow
        from scipy.spatial import cKDTree

        return np.sort(cKDTree(pos).query_pairs(tol, output_type="ndarray").astype(np.int64), axis=1)
    kernel = lattice()
    if kernel is not None:
        # Candidates through a hash table of coarser cells (no sort): a
        # superset of the pairs that pass the tests below.
        pos = np.ascontiguousarray(pos, dtype=np.float64)
        # A sweep of float32 coordinates (an STL) meets a few dozen points a
        # window; past 64 a point it gives up (a CAD model's flat side) for the table.
        pairs = kernel.sweep_pairs(pos, tol, 64 * n + 1024) if lex_sorted else None
        if pairs is None:
            pairs = kernel.near_pairs(pos, low, tol, 16 * tol)
        # Of those, the pairs in neighbouring cells of this grid, as below.
        near = np.abs(cells(pos[pairs[:, 0]]) - cells(pos[pairs[:, 1]])) <= 1
        return _within(pos, pairs[np.all(near, axis=1)], tol)
    q = cells(pos)
    key = (q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]
    order = np.argsort(key, kind="stable")
    sk = key[order]
    offs = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1)
                     if (i, j, k) >= (0, 0, 0)], dtype=np.int64)
    out = []
    for o in (offs[:, 0] * dims[1] + offs[:, 1]) * dims[2] + offs[:, 2]:
        t = key + o
        lo = np.searchsorted(sk, t, "left")
        cnt = np.searchsorted(sk, t, "right") - lo
        # In its own cell a point finds itself: pairs there need two points.
        i = np.flatnonzero(cnt > (1 if o == 0 else 0))
        if len(i) == 0:
            continue
        c = cnt[i]
        local = np.arange(int(c.sum())) - np.repeat(np.cumsum(c) - c, c)
        ii, jj = np.repeat(i, c), order[np.repeat(lo[i], c) + local]
        keep = ii < jj if o == 0 else np.ones(len(ii), bool)
        out.append(np.stack([ii[keep], jj[keep]], axis=1))
    if not out:
        return np.zeros((0, 2), np.int64)
    return _within(pos, np.concatenate(out), tol)


def _within(pos, pairs, tol):
    """The pairs of points at most ``tol`` apart, lower index first: (p, 2) int64."""
    d = pos[pairs[:, 0]] - pos[pairs[:, 1]]
    pairs = pairs[np.einsum("ij,ij->i", d, d) <= tol * tol]
    return np.sort(pairs, axis=1)


def _weld(g, pos, tol):
    """Merge vertices within ``tol`` of each other (transitively); ``pos`` in lexicographic order.

    Returns
    -------
    faces : (k, 3) int64 over the merged vertices
    pos : (n, 3) float64, the first position of each group
    welded : int
        Vertices merged away.
    """
    pairs = close_pairs(pos, tol, lex_sorted=True)
    if len(pairs) == 0:
        return g, pos, 0
    n = len(pos)
    k, label, _ = components(n, pairs[:, 0], pairs[:, 1])
    first = np.zeros(k, dtype=np.int64)
    first[label[::-1]] = np.arange(n)[::-1]
    return label[g], pos[first], n - k


def _inner_walls(faces: np.ndarray, both: np.ndarray, nv: int) -> np.ndarray:
    """Which faces stored both ways round are inner walls between closed parts.

    Two closed parts that share a face (two halves of a die, each closed by
    its own copy of the cut) store it twice, once each way round. Collapsed
    to one side, as for a double-sided shell, it would leave a single sheet
    inside the solid whose solid angle (up to 1/2) is added to every point
    near it; on both sides the two copies cancel in the winding number, and
    the parts join into one closed surface. A wall (the two-sided faces
    connected through their edges) is dropped on both sides when every edge
    it shares with the other faces is used by at least two of them (the rest
    stays closed along the wall's rim) and there is such an edge (a wall
    with none is a double-sided shell or sheet of its own: one side stays).

    Parameters
    ----------
    faces : (k, 3) int64
        Faces without duplicates, over merged vertex ids ``< nv``.
    both : (k,) bool
        The face was also stored the other way round.

    Returns
    -------
    (k,) bool
        Faces of walls to drop.
    """
    drop = np.zeros(len(faces), dtype=bool)
    if not both.any():
        return drop
    edge, count, _, slots = sorted_edges(faces, nv)
    slot_face = np.repeat(np.arange(len(faces)), 3)
    two = both[slot_face]
    # Per edge: the faces outside any wall that use it.
    outside = np.bincount(edge[~two], minlength=len(count))
    # Walls: two-sided faces joined through shared edges (their slots, by edge).
    w_slots = np.flatnonzero(two)
    order = slots[two[slots]]
    e = edge[order]
    link = np.flatnonzero(e[1:] == e[:-1])
    idx = np.flatnonzero(both)
    local = np.full(len(faces), -1)
    local[idx] = np.arange(len(idx))
    n, wall, _ = components(len(idx), local[slot_face[order[link]]], local[slot_face[order[link + 1]]])
    w_of_slot = wall[local[slot_face[w_slots]]]
    o = outside[edge[w_slots]]
    bad = np.bincount(w_of_slot, weights=o == 1, minlength=n) > 0
    rim = np.bincount(w_of_slot, weights=o >= 2, minlength=n) > 0
    drop[idx] = (rim & ~bad)[wall]
    return drop


def _proper(pos: np.ndarray, g: np.ndarray) -> np.ndarray:
    """(k,) bool: the faces that are not degenerate (a repeated vertex, or a cross product exactly 0)."""
    kernel = lattice()
    if kernel is not None:
        return kernel.proper_faces(np.ascontiguousarray(pos), np.ascontiguousarray(g))
    t = pos[g]
    cross = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    repeated = (g[:, 0] == g[:, 1]) | (g[:, 1] == g[:, 2]) | (g[:, 2] == g[:, 0])
    return ~repeated & np.any(cross != 0, axis=1)


def _face_groups(w: np.ndarray, nv: int):
    """Faces with the same vertex set, groups numbered in order of their first face.

    Parameters
    ----------
    w : (k, 3) int64
        Faces without a repeated vertex, over vertex ids ``< nv``.

    Returns
    -------
    first : (g,) int64
        Each group's first face (increasing).
    group : (k,) int64
    parity : (k,) bool
        Each face's winding relative to its sorted vertex order (even or
        odd permutation).
    """
    kernel = lattice()
    if kernel is not None:
        return kernel.face_groups(w)  # a hash of the sorted rows: linear, the same groups
    s = np.sort(w, axis=1)
    if nv < (1 << 21):  # three ids in one int64 key: a flat unique, far faster than by rows
        key = (s[:, 0] * np.int64(nv) + s[:, 1]) * np.int64(nv) + s[:, 2]
        _, first, inverse = np.unique(key, return_index=True, return_inverse=True)
    else:
        _, first, inverse = np.unique(s, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first)
    renumber = np.empty(len(first), dtype=np.int64)
    renumber[order] = np.arange(len(first))
    rot = np.argmin(w, axis=1)
    nxt = w[np.arange(len(w)), (rot + 1) % 3]
    prv = w[np.arange(len(w)), (rot + 2) % 3]
    return first[order], renumber[inverse.reshape(-1)], nxt < prv


def _unique_faces(g: np.ndarray, nv: int):
    """The faces of ``g`` that stay: duplicates collapsed to the first, inner walls dropped.

    Duplicates have the same vertex set; the first face of each set stays.
    Vertex sets stored both ways round keep one side, unless they make up an
    inner wall (see :func:`_inner_walls`), which goes on both sides.

    Returns
    -------
    face : (k,) int64
        Indices into ``g`` of the faces that stay, increasing.
    duplicates, opposite, inner : int
        Faces dropped as exact duplicates, as reversed sides, as inner walls.
    """
    first, inverse, parity = _face_groups(g, nv)
    dropped = np.ones(len(g), dtype=bool)
    dropped[first] = False
    same = parity == parity[first[inverse]]
    duplicates = int(np.count_nonzero(dropped & same))
    opposite = int(np.count_nonzero(dropped & ~same))
    both = np.zeros(len(first), dtype=bool)
    both[inverse[~same]] = True
    wall = _inner_walls(g[first], both, nv) if both.any() else np.zeros(len(first), bool)
    return first[~wall], duplicates, opposite, int(np.count_nonzero(wall))


def _orient(f: np.ndarray, nv: int, pos: np.ndarray, centre: np.ndarray):
    """Orient the faces ``f`` (turned in place) across manifold edges and each piece outward.

    The NumPy steps of :func:`repair` after the duplicates (the compiled
    kernel's :func:`geovox._lattice.repair_edges` gives the same arrays):
    the edge table, the spanning forest's flips (:func:`components`), then
    each piece's signed volume about the centroid of its open edges'
    midpoints (each open slot's vertex and the next one round its face, as
    flipped), or of its faces' centroids where it has none, from ``centre``.

    Returns
    -------
    label : (nf,) int64
    swapped : (nf,) bool
    pieces, closed_pieces, outward : int
    boundary : (k, 2) int64
        The copy's open edges.
    open, non_manifold_edges : int
    """
    edge, count, forward, slots = sorted_edges(f, nv)
    pairs = manifold_pairs(edge, count, slots)
    # Two faces agree across an edge when they run it in opposite directions.
    fp = pairs // 3
    npieces, label, flip = components(len(f), fp[:, 0], fp[:, 1],
                                      forward[pairs[:, 0]] == forward[pairs[:, 1]])
    ends = _edge_ends(f, count, slots)
    f[flip, 1], f[flip, 2] = f[flip, 2], f[flip, 1]
    turn, closed_piece = _outward(f, pos, centre, edge, count, label, npieces)
    t = turn[label]
    f[t, 1], f[t, 2] = f[t, 2], f[t, 1]
    swapped = flip ^ t
    boundary = _open_edges(edge, count, forward ^ np.repeat(swapped, 3), ends)
    return (label, swapped, npieces, int(np.count_nonzero(closed_piece)),
            int(np.count_nonzero(turn)), boundary, int(np.count_nonzero(count == 1)),
            int(np.count_nonzero(count > 2)))


def _outward(f, pos, centre, edge, count, label, npieces):
    """``(turn, closed)`` per piece: its signed volume is negative; no edge of it is open or
    non-manifold (see :func:`_orient`)."""
    nf = len(f)
    open_slot = count[edge] == 1
    bad_slot = count[edge] != 2
    slot_face = np.repeat(np.arange(nf), 3)
    closed_piece = np.bincount(label[slot_face[bad_slot]], minlength=npieces) == 0
    o = np.flatnonzero(open_slot)  # each open slot's vertex and the next one round its face
    a, b = f.reshape(-1)[o], f.reshape(-1)[o - o % 3 + (o % 3 + 1) % 3]
    mid = (pos[a] + pos[b]) / 2 - centre
    lab_open = label[slot_face[open_slot]]
    n_open = np.bincount(lab_open, minlength=npieces)
    c = np.stack([np.bincount(lab_open, weights=mid[:, k], minlength=npieces) for k in range(3)], 1)
    vt = pos[f] - centre
    fc = vt.mean(axis=1)
    n_face = np.bincount(label, minlength=npieces)
    c_all = np.stack([np.bincount(label, weights=fc[:, k], minlength=npieces) for k in range(3)], 1)
    c = np.where((n_open > 0)[:, None], c / np.maximum(n_open, 1)[:, None],
                 c_all / np.maximum(n_face, 1)[:, None])
    rel = vt - c[label][:, None, :]
    det = np.einsum("ij,ij->i", rel[:, 0], np.cross(rel[:, 1], rel[:, 2]))
    volume = np.bincount(label, weights=det, minlength=npieces)
    return volume < 0, closed_piece


#: How ``np.einsum("ij,ij->i")`` associates a three-term dot product here
#: (found once, see :func:`_einsum_order`).
_EINSUM_ORDER: list = []


def _einsum_order() -> int:
    """How NumPy's arithmetic in :func:`_outward` goes here, for the compiled kernel to follow.

    ``np.einsum("ij,ij->i")`` sums a row's three products in an order of its
    own (SIMD lanes: ``(p0 + p2) + p1`` on this machine's NumPy 2.4); the
    compiled :func:`geovox._lattice.repair_edges` follows it so that the
    pieces' volumes, and the turns of the flat pieces whose volume is only
    rounding, are NumPy's bit for bit. Rows where the three associations
    differ tell which it is (0: ``(p0 + p1) + p2``, 1: ``(p0 + p2) + p1``,
    2: ``p0 + (p1 + p2)``); random rows then check it, with ``np.cross``
    and ``mean(axis=1)`` against their formulas. -1 where anything differs:
    the NumPy steps run instead.
    """
    if not _EINSUM_ORDER:
        big = 1e16
        probe = np.einsum("ij,ij->i", np.array([[big, 1.0, -big], [1.0, big, -big]]), np.ones((2, 3)))
        order = {(1.0, 0.0): 1, (0.0, 1.0): 2, (0.0, 0.0): 0}.get(tuple(probe.tolist()), -1)
        # Rows of every magnitude, from a fixed formula (importing numpy.random costs 15 ms).
        x = np.sin(np.arange(257 * 12) * 12.9898) * 43758.5453
        x -= np.floor(x) + 0.5
        a = x[:771].reshape(257, 3) * 10.0 ** np.arange(-8, 8)[np.arange(771) % 16].reshape(257, 3)
        b = x[771:].reshape(257, 3, 3)
        p = a * b[:, 0]
        sums = ((p[:, 0] + p[:, 1]) + p[:, 2], (p[:, 0] + p[:, 2]) + p[:, 1],
                p[:, 0] + (p[:, 1] + p[:, 2]))
        cross = np.stack([a[:, 1] * b[:, 1, 2] - a[:, 2] * b[:, 1, 1],
                          a[:, 2] * b[:, 1, 0] - a[:, 0] * b[:, 1, 2],
                          a[:, 0] * b[:, 1, 1] - a[:, 1] * b[:, 1, 0]], 1)
        mean = (((0.0 + b[:, 0]) + b[:, 1]) + b[:, 2]) / 3
        if order < 0 or not (np.array_equal(np.einsum("ij,ij->i", a, b[:, 0]), sums[order])
                             and np.array_equal(np.cross(a, b[:, 1]), cross)
                             and np.array_equal(b.mean(axis=1), mean)):
            order = -1
        _EINSUM_ORDER.append(order)
    return _EINSUM_ORDER[0]


def _edge_ends(f: np.ndarray, count: np.ndarray, slots: np.ndarray) -> np.ndarray:
    """(2, e) int64: each edge's lower and higher vertex, from its first slot (see :func:`sorted_edges`)."""
    s = slots[np.cumsum(count) - count]
    flat = f.reshape(-1)
    a, b = flat[s], flat[s - s % 3 + (s % 3 + 1) % 3]
    return np.stack([np.minimum(a, b), np.maximum(a, b)])


def _open_edges(edge, count, forward, ends) -> np.ndarray:
    """(k, 2) int64: the open edges of faces with this edge table, run as the faces run them.

    The same arrays as :func:`geovox.inside.edges.boundary_edges` of the
    repaired copy (its vertices are its merged positions, numbered in
    order; turning faces over changes only the directions they run their
    edges, so the copy needs no second table).

    Parameters
    ----------
    edge, count
        As :func:`geovox.inside.edges.edge_table` gives them.
    forward : (3k,) bool
        Each slot's edge is run from its lower to its higher vertex by its
        face (as turned).
    ends : (2, e) int64
        :func:`_edge_ends`.
    """
    net = np.bincount(edge, weights=np.where(forward, 1, -1), minlength=len(count)).astype(np.int64)
    k = np.flatnonzero(net)
    m = net[k]
    # net > 0: low -> high left over; net < 0: high -> low.
    src = np.where(m > 0, ends[0, k], ends[1, k])
    dst = np.where(m > 0, ends[1, k], ends[0, k])
    reps = np.abs(m)
    return np.stack([np.repeat(src, reps), np.repeat(dst, reps)], axis=1)


def repair(mesh: Mesh) -> Repair:
    """A consistently oriented, outward-facing copy of ``mesh`` (see the module notes).

    Parameters
    ----------
    mesh : Mesh

    Returns
    -------
    Repair
    """
    _, g, vertex = merged_faces(mesh)
    # From here the repair alone holds the faces over merged positions: they
    # and the checks' hashed ones leave the mesh's cache (two arrays the size
    # of the faces; asked again, they are made again), and where no face is
    # dropped, these rows are the ones the repair turns.
    mesh._cache.pop("merged_faces", None)
    mesh._cache.pop("position_faces", None)
    pos = mesh.vertices[vertex]
    g, pos, welded = _weld(g, pos, WELD * mesh.scale)
    nv = len(pos)
    # Every merged vertex is used (pos holds only those): a count, not a sort.
    used = np.zeros(len(mesh.vertices), bool)
    used[mesh.faces.reshape(-1)] = True
    merged = int(np.count_nonzero(used)) - nv
    del used

    keep = np.flatnonzero(_proper(pos, g))
    degenerate = len(g) - len(keep)
    if len(keep) == 0:  # nothing with an area: nothing encloses anything
        return Repair(mesh=Mesh(pos, np.zeros((0, 3), np.int64), source=mesh.source),
                      face=keep, swapped=np.zeros(0, bool), piece=np.zeros(0, np.int64),
                      merged_vertices=int(merged), welded=int(welded), degenerate=int(degenerate))
    f = g if degenerate == 0 else g[keep]
    del g

    kernel = lattice()
    order = _einsum_order() if kernel is not None else -1
    centre = pos.mean(axis=0)
    # Compiled, the edge table finds duplicates on its way (faces sharing an
    # edge and its third vertex; it then turns no face): only then are they
    # collapsed and the table made again; a scan has none and pays no pass for them.
    face, duplicates, opposite, inner = keep, 0, 0, 0
    done = None if order < 0 else kernel.repair_edges(f, nv, pos, centre, order)
    if done is None or (isinstance(done, int) and done == kernel.DUPLICATES):
        stay, duplicates, opposite, inner = _unique_faces(f, nv)
        face, f = keep[stay], f[stay]
        done = None if order < 0 else kernel.repair_edges(f, nv, pos, centre, order)
    if not isinstance(done, tuple):  # NumPy, or a Moebius band: the rounds' forest decides its flips
        done = _orient(f, nv, pos, centre)
    label, swapped, npieces, closed_pieces, outward, boundary, n_open, n_many = done
    # The copy's arrays with room after them for its caps (at most one cap
    # triangle an open edge, three vertices each): the mesh closed by them
    # (geovox.inside.caps.capped) is then the copy's arrays and a few rows
    # more, not a second copy of every face (untouched room costs nothing).
    room = (np.empty((nv + 3 * len(boundary), 3)), np.empty((len(f) + len(boundary), 3), np.int64))
    room[0][:nv], room[1][:len(f)] = pos, f
    pos, f = room[0][:nv], room[1][:len(f)]
    out = Mesh(pos, f, source=mesh.source)
    # Its vertices are distinct and in lexicographic order (the first of
    # each merged group, in order): merging them by position numbers them
    # as they are, so the lexicographic sort of that is not needed; its
    # edges are the table's, turned (see _orient).
    out._cache.update(geometric_faces=f, boundary=boundary, non_manifold=n_many > 0,
                      edge_counts=(n_open, n_many), room=room)
    return Repair(mesh=out, face=face, swapped=swapped, piece=label, merged_vertices=int(merged),
                  welded=int(welded), degenerate=int(degenerate), duplicates=duplicates,
                  opposite=opposite, inner=inner, flipped=int(np.count_nonzero(swapped)),
                  pieces=npieces, closed_pieces=closed_pieces, outward=outward)
