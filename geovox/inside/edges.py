"""The edge checks below every inside test: merged positions, the edge table, the holes.

Every module of :mod:`geovox.inside` starts from these questions about a
mesh's edges, asked of its faces over vertices merged by exact position:

* is it closed (every edge run as often one way as the other,
  :func:`boundary_edges` empty) and consistently wound (:func:`consistent`)?
* how many edges are open, and how many non-manifold (:func:`edge_counts`)?
* which directed edges are left over (:func:`boundary_edges`: the holes' rims)?
* do its closed pieces' boxes overlap (:func:`overlapping_pieces`)?

and the whole-array tools they share with the repair: the faces over their
positions numbered in lexicographic order (:func:`merged_faces`), the edge
table (:func:`sorted_edges`, :func:`manifold_pairs`) and connected
components (:func:`components`, :func:`face_pieces`).

Each step has a compiled twin in :mod:`geovox._lattice` (chosen as
:mod:`geovox.kernels` says) that gives the same arrays in linear time; the
NumPy code is the fallback. Results are cached on the mesh.
"""

from __future__ import annotations

import numpy as np

from ..kernels import lattice
from ..mesh import Mesh


def boundary_edges(mesh: Mesh) -> np.ndarray:
    """Directed edges without a partner running the other way (with multiplicity).

    Returns
    -------
    (k, 2) int64
        Vertex indices into ``mesh.vertices`` (merged by position), in the
        direction the faces traverse them. Empty for a closed mesh.
    """
    if "boundary" in mesh._cache:
        return mesh._cache["boundary"]
    if len(mesh.faces) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    kernel = lattice()
    if kernel is not None:
        # The common case first, in linear time (no sort).
        if is_closed(mesh):
            out = np.zeros((0, 2), dtype=np.int64)
            mesh._cache["boundary"] = out
            return out
        mesh._cache["boundary"] = out = _compiled_boundary(mesh, kernel)
        return out
    f = mesh.geometric_faces
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = e[e[:, 0] != e[:, 1]]  # degenerate faces repeat a vertex
    n = int(f.max()) + 1 if len(f) else 1
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    if kernel is None and _closed(e, lo, hi, n):
        out = np.zeros((0, 2), dtype=np.int64)
        mesh._cache["boundary"] = out
        return out
    key = lo * n + hi
    sign = np.where(e[:, 0] < e[:, 1], 1, -1)
    uniq, inverse = np.unique(key, return_inverse=True)
    inverse = inverse.reshape(-1)
    net = np.bincount(inverse, weights=sign, minlength=len(uniq)).astype(np.int64)
    # Whether some edge is used by more than two faces (see overlapping_pieces).
    mesh._cache["non_manifold"] = bool(len(inverse) and np.bincount(inverse).max() > 2)
    k = np.flatnonzero(net)
    a, b = uniq[k] // n, uniq[k] % n
    m = net[k]
    # net > 0: a -> b left over; net < 0: b -> a.
    src = np.where(m > 0, a, b)
    dst = np.where(m > 0, b, a)
    reps = np.abs(m)
    out = np.stack([np.repeat(src, reps), np.repeat(dst, reps)], axis=1)
    # Map merged vertex ids back to a representative original vertex.
    rep = np.zeros(n, dtype=np.int64)
    rep[mesh.geometric_faces.reshape(-1)] = mesh.faces.reshape(-1)
    out = rep[out]
    mesh._cache["boundary"] = out
    return out


def is_closed(mesh: Mesh) -> bool:
    """Whether every edge is run as often one way as the other (:func:`boundary_edges` empty).

    With the compiled kernel, one linear pass over the faces merged by
    position (:func:`geovox._lattice.edge_checks`: no sort, no list of
    edges) answers it and counts the open and non-manifold edges on the way
    (:func:`edge_counts`, :func:`non_manifold`); without it, the list.
    Cached on the mesh.
    """
    if "closed" not in mesh._cache:
        kernel = lattice()
        if "boundary" in mesh._cache or kernel is None or len(mesh.faces) == 0:
            mesh._cache["closed"] = len(boundary_edges(mesh)) == 0
        else:
            closed, non_manifold, n_open, n_many = kernel.edge_checks(position_faces(mesh, kernel))
            mesh._cache.update(closed=closed, non_manifold=non_manifold,
                               edge_counts=(n_open, n_many))
    return mesh._cache["closed"]


def _compiled_boundary(mesh: Mesh, module) -> np.ndarray:
    """:func:`boundary_edges` of an open mesh by the compiled edge table, in the same order.

    The edges come numbered in ``(lower, higher)`` order of the positions'
    lexicographic numbers (:func:`geovox.inside.repair.merged_faces`), as
    the NumPy path's ``np.unique`` of the keys numbers them, from a counting
    sort (:func:`geovox._lattice.edge_sort`); the edge counts of
    :func:`edge_counts` come with them.
    """
    _, g, vertex = merged_faces(mesh)
    _, _, low, high, count, net = module.edge_sort(g)
    mesh._cache["non_manifold"] = bool(len(count) and count.max() > 2)
    mesh._cache["edge_counts"] = (int(np.count_nonzero(count == 1)),
                                  int(np.count_nonzero(count > 2)))
    k = np.flatnonzero(net)
    a, b, m = low[k], high[k], net[k]
    # net > 0: a -> b left over; net < 0: b -> a.
    src = np.where(m > 0, a, b)
    dst = np.where(m > 0, b, a)
    reps = np.abs(m)
    out = np.stack([np.repeat(src, reps), np.repeat(dst, reps)], axis=1)
    return vertex[out]  # the NumPy path's representatives: the last corner at each position


def position_faces(mesh: Mesh, module) -> np.ndarray:
    """(m, 3) int64: faces over vertices merged by exact position, numbered by a hash.

    The same merging as :attr:`Mesh.geometric_faces` in linear time, with
    another numbering: for the compiled checks, whose answers do not depend
    on it (a million vertices' lexicographic sort costs more than all of them).
    """
    if "position_faces" not in mesh._cache:
        if "geometric_faces" in mesh._cache:
            mesh._cache["position_faces"] = mesh.geometric_faces
        else:
            ids = module.merge_positions(mesh.vertices)
            mesh._cache["position_faces"] = ids[mesh.faces]
            mesh._cache["positions"] = int(ids.max()) + 1 if len(ids) else 0
    return mesh._cache["position_faces"]


def _closed(e, lo, hi, n) -> bool:
    """Whether every undirected edge is run as often one way as the other (one sort).

    Sorted by (edge, direction), a running +-1 sum returns to 0 at the end
    of every edge's run.
    """
    order = np.sort(2 * (lo * n + hi) + (e[:, 0] < e[:, 1]))
    net = np.cumsum(np.where(order & 1, 1, -1))
    ends = np.flatnonzero(np.r_[order[1:] >> 1 != order[:-1] >> 1, len(order) > 0])
    return not net[ends].any()


def edge_counts(mesh: Mesh):
    """``(open, non_manifold)``: edges used by one face, and edges used by more than two.

    Counted by the compiled kernel's edge checks (:func:`is_closed`), cached on the mesh.
    """
    if "edge_counts" in mesh._cache:
        return mesh._cache["edge_counts"]
    if lattice() is not None:
        is_closed(mesh)  # counts them
        return mesh._cache["edge_counts"]
    f = mesh.geometric_faces
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = e[e[:, 0] != e[:, 1]]
    n = np.int64(f.max()) + 1 if len(f) else np.int64(1)
    key = np.sort(np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1]))
    counts = np.diff(np.flatnonzero(np.r_[True, key[1:] != key[:-1], True]))
    return int(np.count_nonzero(counts == 1)), int(np.count_nonzero(counts > 2))


def consistent(mesh: Mesh) -> bool:
    """Closed and consistently wound: every edge has a partner running the other way,
    and no two faces use the same three vertices.

    The second condition catches double-sided models (every face also stored
    reversed), whose edges all have partners but whose every crossing counts
    twice under parity and cancels under the winding number.
    """
    if "consistent" not in mesh._cache:
        ok = is_closed(mesh)
        kernel = lattice()
        if ok and kernel is not None:
            ok = not kernel.duplicate_faces(position_faces(mesh, kernel))  # linear, no sort
        elif ok:
            s = np.sort(mesh.geometric_faces, axis=1)
            n = np.int64(s.max()) + 1 if len(s) else np.int64(1)
            if n < (1 << 21):  # three ids fit in one int64 key
                key = (s[:, 0] * n + s[:, 1]) * n + s[:, 2]
                key.sort()
                ok = not np.any(key[1:] == key[:-1])
            else:
                ok = len(np.unique(s, axis=0)) == len(s)
        mesh._cache["consistent"] = bool(ok)
    return mesh._cache["consistent"]


def overlapping_pieces(mesh: Mesh) -> bool:
    """Whether two pieces (connected through shared edges) have overlapping boxes.

    Parity counts the space two closed parts share as outside; the winding
    number counts it twice. Only then do the two differ on a closed,
    consistently wound mesh, so only then is parity not enough.
    """
    if "overlap" in mesh._cache:
        return mesh._cache["overlap"]
    kernel = lattice()

    def proper(g):  # the faces that do not repeat a vertex
        return g[(g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 2] != g[:, 0])]

    g = proper(position_faces(mesh, kernel) if kernel is not None else mesh.geometric_faces)
    overlap = False
    single = True
    if len(g) > 1:
        # Cheap first: one vertex-connected component without non-manifold
        # edges is one piece. (A search in NumPy, not scipy's csgraph: on
        # the default path importing scipy.sparse alone costs about 0.2 s.)
        single = vertex_connected(g) and not non_manifold(mesh)
    if not single:
        g = proper(mesh.geometric_faces)
        edge, count, _ = edge_table(g, int(g.max()) + 1)
        # Pieces meet across manifold edges only: two closed parts that touch
        # along an edge (four faces on it) stay two pieces.
        n, label = face_pieces(len(g), manifold_pairs(edge, count))
        if n > 1:
            order = np.argsort(label, kind="stable")
            starts = np.r_[0, np.flatnonzero(np.diff(label[order])) + 1]
            pos = np.zeros((int(g.max()) + 1, 3))
            pos[mesh.geometric_faces.reshape(-1)] = mesh.vertices[mesh.faces.reshape(-1)]
            tri = pos[g[order]]
            lo = np.minimum.reduceat(tri.min(axis=1), starts, axis=0)
            hi = np.maximum.reduceat(tri.max(axis=1), starts, axis=0)
            overlap = _any_box_overlap(lo, hi)
    mesh._cache["overlap"] = overlap
    return overlap


def vertex_connected(faces: np.ndarray) -> bool:
    """Whether the faces' vertices form one connected graph (breadth-first, frontier at a time).

    Parameters
    ----------
    faces : (m, 3) int64, m >= 1

    A surface mesh's graph diameter is about the square root of its size,
    so the number of rounds stays in the hundreds even for millions of faces.
    The compiled kernel's union-find (:mod:`geovox.kernels`) gives the same
    answer in linear time.
    """
    kernel = lattice()
    if kernel is not None:
        return kernel.vertex_connected(faces)
    nv = int(faces.max()) + 1
    a = np.r_[faces[:, 0], faces[:, 1], faces[:, 2], faces[:, 1], faces[:, 2], faces[:, 0]]
    b = np.r_[faces[:, 1], faces[:, 2], faces[:, 0], faces[:, 0], faces[:, 1], faces[:, 2]]
    order = np.argsort(a, kind="stable")
    nbr = b[order]
    indptr = np.zeros(nv + 1, dtype=np.int64)
    np.cumsum(np.bincount(a, minlength=nv), out=indptr[1:])
    used = np.zeros(nv, dtype=bool)
    used[faces.reshape(-1)] = True
    seen = np.zeros(nv, dtype=bool)
    frontier = faces[:1, 0].copy()
    seen[frontier] = True
    count = 1
    while len(frontier):
        starts, counts = indptr[frontier], indptr[frontier + 1] - indptr[frontier]
        local = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)
        cand = nbr[np.repeat(starts, counts) + local]
        cand = cand[~seen[cand]]
        if len(cand) == 0:
            break
        seen[cand] = True
        frontier = np.flatnonzero(np.bincount(cand, minlength=0)) if len(cand) > nv // 8 \
            else np.unique(cand)
        count += len(frontier)
    return count == int(np.count_nonzero(used))


def non_manifold(mesh: Mesh) -> bool:
    """Whether some edge is used by more than two faces (cached by boundary_edges when it can)."""
    if "non_manifold" not in mesh._cache:
        if lattice() is not None:
            is_closed(mesh)  # finds it
            return mesh._cache["non_manifold"]
        f = mesh.geometric_faces
        e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
        e = e[e[:, 0] != e[:, 1]]
        n = np.int64(f.max()) + 1 if len(f) else np.int64(1)
        key = np.sort(np.minimum(e[:, 0], e[:, 1]) * n + np.maximum(e[:, 0], e[:, 1]))
        mesh._cache["non_manifold"] = bool(np.any(key[2:] == key[:-2]))
    return mesh._cache["non_manifold"]


def _any_box_overlap(lo, hi, block: int = 512) -> bool:
    """Whether any two of the boxes ``[lo, hi]`` (``(n, 3)``) share interior points."""
    n = len(lo)
    for s in range(0, n, block):
        a_lo, a_hi = lo[s:s + block, None], hi[s:s + block, None]
        inter = np.all((a_lo < hi[None]) & (lo[None] < a_hi), axis=2)
        i = np.arange(s, min(s + block, n))[:, None]
        if np.any(inter & (np.arange(n)[None] > i)):
            return True
    return False


def edge_table(faces: np.ndarray, nv: int):
    """Undirected edges of ``faces`` and who uses them.

    Parameters
    ----------
    faces : (k, 3) int64
        Faces over merged vertex ids ``< nv``, no repeated vertex in a face.

    Returns
    -------
    edge : (3k,) int64
        Undirected edge id of edge ``j`` (from vertex ``j`` to ``j + 1``) of
        face ``f``, at position ``3 f + j``.
    count : (e,) int64
        Faces using each undirected edge.
    forward : (3k,) bool
        The face runs the edge from its lower to its higher vertex id.
    """
    return sorted_edges(faces, nv)[:3]


def sorted_edges(faces: np.ndarray, nv: int):
    """:func:`edge_table`, and the slots sorted by edge (then slot).

    Edges are numbered in order of their ``(lower, higher)`` vertex ids
    either way: by ``np.unique`` of the keys, or by the compiled kernel's
    counting sort (:func:`geovox._lattice.edge_sort`, linear), which gives
    the same arrays.

    Returns
    -------
    edge, count, forward
        As :func:`edge_table`.
    order : (3k,) int64
        ``np.argsort(edge, kind="stable")``.
    """
    a = faces.reshape(-1)
    b = faces[:, [1, 2, 0]].reshape(-1)
    kernel = lattice()
    if kernel is not None:
        order, edge, _, _, count, _ = kernel.edge_sort(faces)
        return edge, count, a < b, order
    key = np.minimum(a, b) * np.int64(nv) + np.maximum(a, b)
    _, edge, count = np.unique(key, return_inverse=True, return_counts=True)
    edge = edge.reshape(-1)
    return edge, count, a < b, np.argsort(edge, kind="stable")


def manifold_pairs(edge: np.ndarray, count: np.ndarray, order: np.ndarray | None = None):
    """The two face-edge slots of every edge used by exactly two faces.

    Parameters
    ----------
    edge, count
        As :func:`edge_table` gives them.
    order : (3k,) int64, optional
        The slots sorted by edge (:func:`sorted_edges`); sorted here when absent.

    Returns
    -------
    (p, 2) int64
        Slots ``3 f + j`` (see :func:`edge_table`), one row per manifold edge.
    """
    if order is None:
        order = np.argsort(edge, kind="stable")
    e = edge[order]
    two = count[e] == 2
    slots = order[two]
    # Sorted by edge, the two slots of each manifold edge are adjacent.
    return slots.reshape(-1, 2)


def face_pieces(nf: int, pairs: np.ndarray):
    """Connected pieces of faces joined through the given manifold edges.

    Returns
    -------
    count : int
    label : (nf,) int64
        Numbered in the order of each piece's first face.
    """
    f = pairs // 3
    n, label, _ = components(nf, f[:, 0], f[:, 1])
    return n, label


def components(n: int, a: np.ndarray, b: np.ndarray, odd: np.ndarray | None = None):
    """Connected components of a graph, in NumPy (no scipy: importing it costs 0.2-0.4 s).

    Union by hooking each root to the smallest root it has an edge to, then
    pointer jumping to the roots, in whole-array rounds until no edge joins
    two roots. With ``odd``, each edge also carries a parity (its two ends
    disagree), and each node gets its parity relative to its component's
    root along the forest that the hooking builds; an edge whose ends
    already share a root is not used, so where the parities contradict (a
    Moebius band) the forest's choice stands.

    Parameters
    ----------
    n : int
        Nodes ``0 .. n - 1``.
    a, b : (e,) int64
        Edges.
    odd : (e,) bool, optional

    Returns
    -------
    count : int
    label : (n,) int64
        Component of each node, numbered in the order of their smallest node
        (as ``scipy.sparse.csgraph.connected_components`` numbers them).
    parity : (n,) bool
        Each node's parity relative to the smallest node of its component
        (all False without ``odd``).

    Notes
    -----
    The compiled kernel (:func:`geovox._lattice.components`) runs the same
    rounds in loops, so it gives the same arrays, parities included.
    """
    kernel = lattice()
    if kernel is not None:
        return kernel.components(int(n), a, b, odd)
    root = np.arange(n, dtype=np.int64)
    x = np.zeros(n, dtype=bool)
    a, b = np.asarray(a, np.int64), np.asarray(b, np.int64)
    odd = np.zeros(len(a), dtype=bool) if odd is None else np.asarray(odd, bool)
    while len(a):
        ra, rb = root[a], root[b]
        live = ra != rb
        a, b, odd, ra, rb = a[live], b[live], odd[live], ra[live], rb[live]
        if len(a) == 0:
            break
        lo, hi = np.minimum(ra, rb), np.maximum(ra, rb)
        # One edge per hooked root: the one to its smallest neighbouring root.
        # Roots only ever point to smaller ones, so no cycle can form.
        order = np.lexsort((lo, hi))
        first = order[np.r_[True, hi[order][1:] != hi[order][:-1]]]
        x[hi[first]] = x[a[first]] ^ x[b[first]] ^ odd[first]
        root[hi[first]] = lo[first]
        # Every node to its root, carrying the parity along (a root points to
        # itself with parity False: a fixed point).
        while True:
            up = root[root]
            if np.array_equal(up, root):
                break
            x ^= x[root]
            root = up
    uniq, label = np.unique(root, return_inverse=True)
    return len(uniq), label.reshape(-1).astype(np.int64), x


def merged_faces(mesh: Mesh):
    """The faces over the vertices they use, merged by position, in lexicographic order.

    ``np.unique(mesh.geometric_faces, return_inverse=True)``, cached on the
    mesh: with the compiled kernel, the positions are merged by a hash
    (:func:`geovox._lattice.merge_positions`) and only the distinct ones a
    face uses are sorted; without it, :attr:`Mesh.geometric_faces` is
    renumbered by a count (no second sort).

    Returns
    -------
    n : int
        Distinct positions the faces use.
    faces : (m, 3) int64
        Each corner's position, numbered ``0 .. n - 1`` in lexicographic
        order of ``(x, y, z)``.
    vertex : (n,) int64
        At each position, the vertex of the last corner there (vertices at
        one position differ at most in the sign of a zero).
    """
    if "merged_faces" not in mesh._cache:
        kernel = lattice()
        sorted_ids = kernel is None or "geometric_faces" in mesh._cache
        if not sorted_ids:  # a hash's numbers: the used positions sorted (a radix sort)
            ids = position_faces(mesh, kernel)
            mesh._cache["merged_faces"] = kernel.lex_faces(
                np.ascontiguousarray(ids), np.ascontiguousarray(mesh.faces, dtype=np.int64),
                np.ascontiguousarray(mesh.vertices, dtype=np.float64), int(ids.max()) + 1)
            return mesh._cache["merged_faces"]
        # Already lexicographic: renumbered by a count.
        ids, nid = mesh.geometric_faces, len(mesh.vertices)
        flat = ids.reshape(-1)
        used = np.zeros(nid, dtype=bool)
        used[flat] = True
        one = np.zeros(nid, dtype=np.int64)
        one[flat] = mesh.faces.reshape(-1)  # the last corner at each position
        where = np.flatnonzero(used)
        rank = np.cumsum(used) - 1
        vertex = np.empty(len(where), dtype=np.int64)
        vertex[rank[where]] = one[where]
        mesh._cache["merged_faces"] = (len(where), rank[ids], vertex)
    return mesh._cache["merged_faces"]
