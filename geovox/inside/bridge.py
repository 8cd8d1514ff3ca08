"""Small caps for the winding number of an open mesh: minimum-area triangulations of its holes.

The winding number of an open mesh M does not depend on the caps K that
:mod:`geovox.inside.caps` closes it with (``w_M = w_{M+K} - w_K`` for any K whose
boundary is M's, reversed), but the cost of summing ``w_K`` does. A fan from
a loop's centroid spans a slit-like or twisted loop with far more area than
it needs (the libigl truck: 3.4 units of fan area over loops whose net area
vectors add up to 1.2): its long spokes reach voxels all over the model,
where each must be summed exactly, and its large unsigned solid angle leaves
bounds undecided. A minimum-area triangulation of each loop's polygon
(the classic O(n³) dynamic programme over its vertices, no new vertices)
zips a slit shut along its length: 1.5 units on the truck, and the compiled
kernel does a quarter of the work at 128³ for the same voxels.

Only loops of at most :data:`TRIANGULATE_UP_TO` edges are triangulated (the
programme's cost grows as n³); longer loops, and boundary pieces that do not
split into closed loops, keep their fan.
"""

from __future__ import annotations

import numpy as np

from .captree import winding_kernel

#: Loops up to this many edges are capped by a minimum-area triangulation;
#: longer ones by a fan (the programme is n³/6 steps: 1.3 million at 200).
TRIANGULATE_UP_TO = 200
#: Loops of one length are triangulated together, in groups whose tables
#: (loops times n² entries) stay below this.
TABLE_ENTRIES = 1 << 21


def loop_order(vid: np.ndarray, piece: np.ndarray):
    """Each closed loop's edges in the order they run, where the piece is one.

    ``piece`` labels from :func:`geovox.inside.caps.loops`: each label whose
    edges balance at every position (as many arrive as leave) is one cycle
    of the successor map "the k-th edge arriving at a position continues
    with the k-th edge leaving it" (the map that split the pieces into
    loops, restricted to the loop: it is order-preserving at every
    position, so restricted it pairs the loop's own k-th arrival and k-th
    departure).

    Parameters
    ----------
    vid : (k, 2) int64
        Each boundary edge's start and end, as position ids.
    piece : (k,) int64
        Each edge's loop (0 .. p-1).

    Returns
    -------
    rank : (k,) int64
        Each edge's place in its loop (0 for the loop's lowest edge index),
        or -1 where its piece does not balance (it keeps a fan).
    """
    k = len(vid)
    nv = np.int64(vid.max()) + 1
    kout = piece * nv + vid[:, 0]
    kin = piece * nv + vid[:, 1]
    out_order = np.argsort(kout, kind="stable")
    in_order = np.argsort(kin, kind="stable")
    # Each piece has as many departures as arrivals, so its edges fill the
    # same index range of both sorted keys: they match there exactly when
    # the piece balances at every position.
    bad = np.zeros(int(piece.max()) + 1, bool)
    bad[piece[out_order][kout[out_order] != kin[in_order]]] = True
    nxt = np.empty(k, np.int64)
    nxt[in_order] = out_order
    ok = ~bad[piece]
    # List ranking on the cycles, broken before each loop's lowest edge.
    first = np.full(len(bad), k, np.int64)
    np.minimum.at(first, piece, np.arange(k))
    succ = nxt.copy()
    dist = np.ones(k, np.int64)
    end = ok & (nxt == first[piece])
    succ[end] = np.flatnonzero(end)
    dist[end] = 0
    succ[~ok] = np.flatnonzero(~ok)
    dist[~ok] = 0
    for _ in range(max(1, int(np.ceil(np.log2(max(k, 2)))) + 1)):
        dist = dist + dist[succ]
        succ = succ[succ]
    size = np.bincount(piece, minlength=len(bad))
    return np.where(ok, size[piece] - 1 - dist, -1)


def min_area_triangles(poly: np.ndarray) -> np.ndarray:
    """Minimum-area triangulations of polygons of one length, together.

    The total area of triangles over the polygon's own vertices is least
    (ties go to the lowest middle vertex); the polygons need not be planar
    or simple.

    Parameters
    ----------
    poly : (m, n, 3) float64, n >= 3
        ``m`` polygons' vertices in order.

    Returns
    -------
    (m, n - 2, 3) int64
        Each polygon's triangles as vertex indices ``(i, k, j)``, ``i < k < j``:
        oriented as the polygon runs.
    """
    m, n = poly.shape[:2]
    cost = np.zeros((m, n, n))
    arg = np.zeros((m, n, n), np.int64)
    for d in range(2, n):
        i = np.arange(n - d)
        j = i + d
        k = i[:, None] + np.arange(1, d)[None]  # (n - d, d - 1)
        a = poly[:, k] - poly[:, i][:, :, None]
        b = (poly[:, j] - poly[:, i])[:, :, None]
        cx = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
        cy = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
        cz = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
        total = cost[:, i[:, None], k] + cost[:, k, j[:, None]] + 0.5 * np.sqrt(
            cx * cx + cy * cy + cz * cz)
        best = total.argmin(axis=2)  # (m, n - d)
        cost[:, i, j] = total.min(axis=2)  # the entry at ``best``
        arg[:, i, j] = k[i, best]
    # Unfold the choices, every polygon at once: intervals (i, j) to split.
    found = []
    lp, li, lj = np.arange(m), np.zeros(m, np.int64), np.full(m, n - 1)
    while len(lp):
        kk = arg[lp, li, lj]
        found.append(np.stack([lp, li, kk, lj], axis=1))
        left, right = kk - li >= 2, lj - kk >= 2
        lp, li, lj = (np.concatenate([lp[left], lp[right]]), np.concatenate([li[left], kk[right]]),
                      np.concatenate([kk[left], lj[right]]))
    found = np.concatenate(found)
    found = found[np.argsort(found[:, 0], kind="stable")]  # n - 2 triangles a polygon
    return found[:, 1:].reshape(m, n - 2, 3)


def loop_caps(pos: np.ndarray, edges: np.ndarray, vid: np.ndarray, piece: np.ndarray,
              rank: np.ndarray | None = None):
    """Cap triangles over the boundary: a minimum-area triangulation per loop, else a fan.

    Parameters
    ----------
    pos : (v, 3) float64
        The mesh's vertices.
    edges : (k, 2) int64
        Boundary edges ``a -> b`` (vertex indices), as the faces run them.
    vid : (k, 2) int64
        The same edges as position ids.
    piece : (k,) int64
        Each edge's loop (see :func:`loop_order`).
    rank : (k,) int64, optional
        :func:`loop_order` of them, where it is known (the compiled
        :func:`geovox._lattice.boundary_loops` gives both).

    Returns
    -------
    triangles : (t, 3, 3) float64
        Oriented so that the mesh and its caps are closed: a loop's polygon
        runs as its edges do, and its triangles run the other way (as the
        fan ``(centroid, b, a)`` over each edge ``a -> b`` does).
    tri_piece : (t,) int64
        The loop each belongs to.
    """
    module = winding_kernel()
    # The compiled programme gives the same triangles (about 12 times faster).
    triangulate = min_area_triangles if module is None else module.min_area_triangles
    if rank is None:
        rank = loop_order(vid, piece)
    npieces = int(piece.max()) + 1
    size = np.bincount(piece, minlength=npieces)
    tri = np.ones(npieces, bool)
    tri[piece[rank < 0]] = False
    tri &= size <= TRIANGULATE_UP_TO
    fan = ~tri[piece]
    parts, labels = [], []
    if fan.any():
        e = np.flatnonzero(fan)
        mid = (pos[edges[e, 0]] + pos[edges[e, 1]]) / 2
        cnt = np.bincount(piece[e], minlength=npieces)
        centroid = np.stack([np.bincount(piece[e], weights=mid[:, c], minlength=npieces)
                             for c in range(3)], axis=1) / np.maximum(cnt, 1)[:, None]
        parts.append(np.stack([centroid[piece[e]], pos[edges[e, 1]], pos[edges[e, 0]]], axis=1))
        labels.append(piece[e])
    # Each loop's edges by place: the polygon of their starting vertices.
    if rank.min() >= 0:  # every (loop, place) once: placed, not sorted
        e = np.empty(len(piece), np.int64)
        e[(np.cumsum(size) - size)[piece] + rank] = np.arange(len(piece))
        e = e[~fan[e]]
    else:
        e = np.flatnonzero(~fan)
        e = e[np.lexsort((rank[e], piece[e]))]
    for n in np.unique(size[tri]):
        if n < 3:  # a loop a -> b -> a bounds nothing
            continue
        loops = np.flatnonzero(tri & (size == n))
        group = max(1, TABLE_ENTRIES // (n * n))
        for s in range(0, len(loops), group):
            lp = loops[s:s + group]
            at = _loop_slots(e, piece, lp, n)
            poly = pos[edges[at, 0]]  # (len(lp), n, 3)
            t = triangulate(np.ascontiguousarray(poly, dtype=np.float64))
            rows = np.arange(len(lp))[:, None, None]
            parts.append(poly[rows, t[..., ::-1]].reshape(-1, 3, 3))
            labels.append(np.repeat(lp, n - 2))
    if not parts:
        return np.zeros((0, 3, 3)), np.zeros(0, np.int64)
    return np.concatenate(parts), np.concatenate(labels).astype(np.int64)


def _loop_slots(e: np.ndarray, piece: np.ndarray, loops: np.ndarray, n: int) -> np.ndarray:
    """(len(loops), n) int64: the edges of each loop in ``loops``, in order (``e`` sorted by loop, place)."""
    first = np.searchsorted(piece[e], loops)
    return e[first[:, None] + np.arange(n)[None]]
