# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False, nonecheck=False
"""Compiled lattice search of the column rays, and linear checks of a mesh's edges.

:func:`scan` is :func:`geovox.backends.numpy.rasterise`'s NumPy scan
written as one loop: for every active triangle, every column centre in its
bounding box, in the same order (triangle, then ``j``, then ``i``); the
decision is :meth:`geovox.exact.Projection.edge_values`' exact ``int64``
edge functions, and depth and weights are
:meth:`geovox.exact.Projection.interpolate`'s float64 formula operation for
operation (built with ``-ffp-contract=off``, no fast-math; see setup.py), so
the hits are the NumPy scan's, array for array.

:func:`edge_checks`, :func:`duplicate_faces` and :func:`vertex_connected`
answer the questions :func:`geovox.inside.choose` asks of every mesh
(closed? an edge on more than two faces? two faces on the same three
vertices? one vertex-connected piece?) in time linear in the faces: keys
are bucketed by their lowest vertex (a counting sort) and settled with
per-vertex scratch arrays, so nothing is sorted. The NumPy code in
:mod:`geovox.inside` gives the same answers (it is the fallback where this
module is not built).

:func:`edge_sort`, :func:`components`, :func:`face_groups`,
:func:`proper_faces` and :func:`near_pairs` are the steps of
:func:`geovox.inside.repair.repair` (and of
:func:`geovox.inside.boundary_edges` of an open mesh) in linear time: the
edge table numbered as ``np.unique`` numbers it (a counting sort by the
lower vertex, then a few entries per bucket), the spanning forest's rounds
as the NumPy rounds run them (the same flips, even on a Moebius band),
duplicate faces and close vertices by hash tables. The repaired copy is the
NumPy path's, array for array.

The scans of issue 37 (millions of triangles, thousands of small holes) take
the later kernels: :func:`lex_faces` (the positions' lexicographic numbers
by the radix sort :func:`lex_order`), :func:`sweep_pairs` (the weld's
candidates along x), :func:`repair_edges` (edge table, duplicates, flips by
a union-find, the pieces' outward turns and the copy's open edges, with
32-bit tables) and :func:`boundary_loops` (the holes' loops); each gives the
arrays of the steps it replaces.
"""

import numpy as np

from libc.stdint cimport int32_t, int64_t, uint8_t, uint32_t, uint64_t
from libc.stdlib cimport free, malloc
from libc.string cimport memcpy, memset
from libc.math cimport fabs, floor, hypot, rint

#: Buckets of at most this many entries are settled by comparing every pair.
DEF SMALL = 16


def scan(const int64_t[:, :, ::1] coef, const int64_t[:, ::1] tie, const double[::1] area,
         const double[:, ::1] z, const int64_t[::1] imin, const int64_t[::1] imax,
         const int64_t[::1] jmin, const int64_t[::1] jmax, const int64_t[::1] tri,
         int64_t nu, column_mask=None, triangle_mask=None):
    """Every crossing of the lattice's rays with the active triangles.

    Parameters
    ----------
    coef : (m, 3, 3) int64
    tie : (m, 3) int64
    area : (m,) float64
    z : (m, 3) float64
    imin, imax, jmin, jmax, tri : (m,) int64
        A :class:`geovox.exact.Projection`'s arrays of the same names.
    nu : int
        Columns along ``u``.
    column_mask : (nu * nv,) bool, optional
        Only rays where this is True.
    triangle_mask : (m,) bool, optional
        Only these active triangles.

    Returns
    -------
    ray : (h,) int64
    depth : (h,) float64
    triangle : (h,) int64
    bary : (h, 2) float64
        As :class:`geovox.backends.base.Hits` holds them, in the NumPy scan's order.
    """
    cdef Py_ssize_t m = area.shape[0]
    cdef const uint8_t[::1] cmask
    cdef const uint8_t[::1] tmask
    cdef bint use_c = column_mask is not None
    cdef bint use_t = triangle_mask is not None
    if use_c:
        cmask = np.ascontiguousarray(column_mask, dtype=np.bool_).view(np.uint8)
    if use_t:
        tmask = np.ascontiguousarray(triangle_mask, dtype=np.bool_).view(np.uint8)
    cdef Py_ssize_t cap = 1024, h = 0, t
    ray_a = np.empty(cap, np.int64)
    depth_a = np.empty(cap, np.float64)
    tri_a = np.empty(cap, np.int64)
    bary_a = np.empty((cap, 2), np.float64)
    cdef int64_t[::1] o_ray = ray_a
    cdef double[::1] o_depth = depth_a
    cdef int64_t[::1] o_tri = tri_a
    cdef double[:, ::1] o_bary = bary_a
    cdef int64_t i, j, w0, w1, w2, r
    cdef int64_t a0, b0, c0, a1, b1, c1, a2, b2, c2
    cdef double l0, l1, l2, ar, zk, d0, d1, d2, s
    cdef int k
    for t in range(m):
        if use_t and not tmask[t]:
            continue
        a0, b0, c0 = coef[t, 0, 0], coef[t, 0, 1], coef[t, 0, 2]
        a1, b1, c1 = coef[t, 1, 0], coef[t, 1, 1], coef[t, 1, 2]
        a2, b2, c2 = coef[t, 2, 0], coef[t, 2, 1], coef[t, 2, 2]
        for j in range(jmin[t], jmax[t] + 1):
            for i in range(imin[t], imax[t] + 1):
                r = i + nu * j
                if use_c and not cmask[r]:
                    continue
                w0 = a0 + b0 * i + c0 * j
                if w0 <= 0:
                    continue
                w1 = a1 + b1 * i + c1 * j
                if w1 <= 0:
                    continue
                w2 = a2 + b2 * i + c2 * j
                if w2 <= 0:
                    continue
                if h == cap:
                    cap *= 2
                    ray_a = np.resize(ray_a, cap)
                    depth_a = np.resize(depth_a, cap)
                    tri_a = np.resize(tri_a, cap)
                    bary_a = np.resize(bary_a, (cap, 2))
                    o_ray, o_depth, o_tri, o_bary = ray_a, depth_a, tri_a, bary_a
                # Projection.interpolate: lam = (w - tie) / area; depth from
                # the vertex of largest weight (the first on ties, as argmax).
                ar = area[t]
                l0 = <double>(w0 - tie[t, 0]) / ar
                l1 = <double>(w1 - tie[t, 1]) / ar
                l2 = <double>(w2 - tie[t, 2]) / ar
                k = 0
                if l1 > l0:
                    k = 1
                if l2 > (l1 if k == 1 else l0):
                    k = 2
                zk = z[t, k]
                d0 = z[t, 0] - zk
                d1 = z[t, 1] - zk
                d2 = z[t, 2] - zk
                if k == 0:
                    d0 = 0.0
                elif k == 1:
                    d1 = 0.0
                else:
                    d2 = 0.0
                # One of the three terms is exactly +0.0, so NumPy's sum
                # over the length-3 axis rounds as this does in any order.
                s = l0 * d0
                s = s + l1 * d1
                s = s + l2 * d2
                o_ray[h] = r
                o_depth[h] = zk + s
                o_tri[h] = tri[t]
                o_bary[h, 0] = l1
                o_bary[h, 1] = l2
                h += 1
    return ray_a[:h].copy(), depth_a[:h].copy(), tri_a[:h].copy(), bary_a[:h].copy()


def column_boxes(const double[:, ::1] vertices, const int64_t[:, ::1] faces, int a, int b,
                 double u0, double du, double v0, double dv, double low, double top_u,
                 double top_v):
    """:func:`geovox.exact._column_boxes` in one pass: the same float64 operations.

    Parameters
    ----------
    vertices : (v, 3) float64
    faces : (n, 3) int64
        The triangles ``vertices[faces]`` (not gathered: a fine mesh's
        triangles are mostly dropped here).
    a, b : int
        The axes across the rays (``u`` and ``v``).
    u0, du, v0, dv : float
        The lattice's origin and spacing (column units are ``(x - u0) / du``).
    low, top_u, top_v : float
        A box is kept when ``hi >= low`` and ``lo <= top`` along both axes.

    Returns
    -------
    idx : (k,) int64
    lo_u, hi_u, lo_v, hi_v : (k,) float64
    """
    cdef Py_ssize_t t, k, n = faces.shape[0], h = 0
    idx_a = np.empty(n, np.int64)
    box_a = np.empty((4, n), np.float64)
    cdef int64_t[::1] idx = idx_a
    cdef double[:, ::1] box = box_a
    cdef double x, lu, hu, lv, hv
    cdef int64_t p
    for t in range(n):
        # np.minimum / np.maximum of the three, as in NumPy (finite values:
        # min and max are exact, in any order).
        p = faces[t, 0]
        lu = hu = (vertices[p, a] - u0) / du
        lv = hv = (vertices[p, b] - v0) / dv
        for k in range(1, 3):
            p = faces[t, k]
            x = (vertices[p, a] - u0) / du
            lu = x if x < lu else lu
            hu = x if x > hu else hu
            x = (vertices[p, b] - v0) / dv
            lv = x if x < lv else lv
            hv = x if x > hv else hv
        if hu >= low and lu <= top_u and hv >= low and lv <= top_v:
            idx[h] = t
            box[0, h], box[1, h], box[2, h], box[3, h] = lu, hu, lv, hv
            h += 1
    return (idx_a[:h].copy(), box_a[0, :h].copy(), box_a[1, :h].copy(), box_a[2, :h].copy(),
            box_a[3, :h].copy())


cdef inline int64_t _floordiv(int64_t x, int64_t y) noexcept nogil:
    """Python's ``x // y`` for ``y > 0``."""
    cdef int64_t q = x / y
    if x % y != 0 and x < 0:
        q -= 1
    return q


def column_ranges(const double[::1] lo_u, const double[::1] hi_u, const double[::1] lo_v,
                  const double[::1] hi_v, int s, int64_t nu, int64_t nv):
    """Exact column ranges of the snapped boxes; only the boxes that hold a centre.

    :class:`geovox.exact.Projection`'s NumPy: ``lu = rint(lo_u * 2**s)``,
    ``imin = max(-((half - lu) // S), 0)``, ``imax = min((hu - half) // S,
    nu - 1)``, the same along ``v``, kept where ``imin <= imax`` and ``jmin
    <= jmax``.

    Returns
    -------
    seen : (k,) int64
        Indices of the boxes kept.
    imin, imax, jmin, jmax : (k,) int64
    """
    cdef Py_ssize_t t, n = lo_u.shape[0], h = 0
    cdef int64_t S = (<int64_t>1) << s
    cdef int64_t half = S // 2
    cdef double fs = <double>S
    seen_a = np.empty(n, np.int64)
    rng_a = np.empty((4, n), np.int64)
    cdef int64_t[::1] seen = seen_a
    cdef int64_t[:, ::1] rng = rng_a
    cdef int64_t i0, i1, j0, j1
    for t in range(n):
        i0 = -_floordiv(half - <int64_t>rint(lo_u[t] * fs), S)
        i1 = _floordiv(<int64_t>rint(hi_u[t] * fs) - half, S)
        j0 = -_floordiv(half - <int64_t>rint(lo_v[t] * fs), S)
        j1 = _floordiv(<int64_t>rint(hi_v[t] * fs) - half, S)
        i0 = i0 if i0 > 0 else 0
        j0 = j0 if j0 > 0 else 0
        i1 = i1 if i1 < nu - 1 else nu - 1
        j1 = j1 if j1 < nv - 1 else nv - 1
        if i0 <= i1 and j0 <= j1:
            seen[h] = t
            rng[0, h], rng[1, h], rng[2, h], rng[3, h] = i0, i1, j0, j1
            h += 1
    return (seen_a[:h].copy(), rng_a[0, :h].copy(), rng_a[1, :h].copy(), rng_a[2, :h].copy(),
            rng_a[3, :h].copy())


cdef inline int64_t _sign(int64_t x) noexcept nogil:
    return (x > 0) - (x < 0)


def edges(const double[:, ::1] vertices, const int64_t[:, ::1] faces, const int64_t[::1] idx,
          int a, int b, int c, double u0, double du, double v0, double dv, double w0, int s):
    """:func:`geovox.exact._edges` of the triangles ``faces[idx]``: the same operations.

    Returns
    -------
    sel : (m,) int64
        Indices into ``idx`` of the triangles of non-zero projected area.
    coef : (m, 3, 3) int64
    tie : (m, 3) int64
    area : (m,) float64
    edge_len : (m, 3) float64
    z : (m, 3) float64
        :class:`geovox.exact.Projection`'s arrays of those names.
    """
    cdef Py_ssize_t t, n = idx.shape[0], h = 0
    cdef int k, A
    cdef int64_t S = (<int64_t>1) << s
    cdef int64_t half = S // 2
    cdef double fs = <double>S
    sel_a = np.empty(n, np.int64)
    coef_a = np.empty((n, 3, 3), np.int64)
    tie_a = np.empty((n, 3), np.int64)
    area_a = np.empty(n, np.float64)
    len_a = np.empty((n, 3), np.float64)
    z_a = np.empty((n, 3), np.float64)
    cdef int64_t[::1] sel = sel_a
    cdef int64_t[:, :, ::1] coef = coef_a
    cdef int64_t[:, ::1] tie = tie_a
    cdef double[::1] area = area_a
    cdef double[:, ::1] elen = len_a
    cdef double[:, ::1] z = z_a
    cdef int64_t qu[3]
    cdef int64_t qv[3]
    cdef int64_t ex[3]
    cdef int64_t ey[3]
    cdef int64_t p, area2, sg, const, tie_sign, tk
    for t in range(n):
        for k in range(3):
            p = faces[idx[t], k]
            qu[k] = <int64_t>rint((vertices[p, a] - u0) / du * fs)
            qv[k] = <int64_t>rint((vertices[p, b] - v0) / dv * fs)
        for k in range(3):
            ex[k] = qu[(k + 2) % 3] - qu[(k + 1) % 3]
            ey[k] = qv[(k + 2) % 3] - qv[(k + 1) % 3]
        area2 = ex[0] * (qv[0] - qv[1]) - ey[0] * (qu[0] - qu[1])
        sg = _sign(area2)
        if sg == 0:
            continue  # zero projected area: never crossed
        for k in range(3):
            A = (k + 1) % 3
            const = ey[k] * qu[A] - ex[k] * qv[A]
            tie_sign = -_sign(ey[k]) if ey[k] != 0 else _sign(ex[k])
            tk = tie_sign == sg
            tie[h, k] = tk
            coef[h, k, 0] = (const + (ex[k] - ey[k]) * half) * sg + tk
            coef[h, k, 1] = -ey[k] * S * sg
            coef[h, k, 2] = ex[k] * S * sg
            elen[h, k] = hypot(<double>ex[k], <double>ey[k])
            z[h, k] = vertices[faces[idx[t], k], c] - w0
        area[h] = <double>(area2 if area2 > 0 else -area2)
        sel[h] = t
        h += 1
    return (sel_a[:h].copy(), coef_a[:h].copy(), tie_a[:h].copy(), area_a[:h].copy(),
            len_a[:h].copy(), z_a[:h].copy())


cdef _bucket(const int64_t[:, ::1] faces, int64_t n):
    """Undirected edges (degenerate ones dropped) bucketed by their lower vertex.

    Returns ``(start, hi, fwd)``: bucket ``v`` holds the edges ``start[v] <=
    e < start[v + 1]``, each with its higher vertex and whether a face runs
    it from low to high.
    """
    cdef Py_ssize_t f, k, m = faces.shape[0]
    cdef int64_t a, b, lo
    start_a = np.zeros(n + 1, np.int64)
    cdef int64_t[::1] start = start_a
    for f in range(m):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            if a != b:
                start[(a if a < b else b) + 1] += 1
    for k in range(n):
        start[k + 1] += start[k]
    hi_a = np.empty(start[n], np.int64)
    fwd_a = np.empty(start[n], np.uint8)
    pos_a = start_a[:n].copy()
    cdef int64_t[::1] hi = hi_a, pos = pos_a
    cdef uint8_t[::1] fwd = fwd_a
    for f in range(m):
        for k in range(3):
            a, b = faces[f, k], faces[f, (k + 1) % 3]
            if a != b:
                lo = a if a < b else b
                hi[pos[lo]] = b if a < b else a
                fwd[pos[lo]] = a < b
                pos[lo] += 1
    return start_a, hi_a, fwd_a


def edge_checks(faces):
    """``(closed, non_manifold, open, non_manifold_edges)`` of a mesh's faces, in linear time.

    Parameters
    ----------
    faces : (m, 3) int64
        Vertex indices (a face may repeat one: its degenerate edge is not an edge).

    Returns
    -------
    closed : bool
        Every undirected edge is run as often one way as the other
        (:func:`geovox.inside.edges.boundary_edges` is empty).
    non_manifold : bool
        Some undirected edge is used more than twice.
    open, non_manifold_edges : int
        The undirected edges used once, and more than twice
        (:func:`geovox.inside.edges.edge_counts`).
    """
    cdef const int64_t[:, ::1] fv = np.ascontiguousarray(faces, dtype=np.int64)
    cdef int64_t n = int(np.max(faces)) + 1 if len(faces) else 1
    start_a, hi_a, fwd_a = _bucket(fv, n)
    cdef int64_t[::1] start = start_a, hi = hi_a
    cdef uint8_t[::1] fwd = fwd_a
    net_a = np.zeros(n, np.int64)
    uses_a = np.zeros(n, np.int64)
    cdef int64_t[::1] net = net_a, uses = uses_a
    cdef bint closed = True, first
    cdef int64_t v, e, x, e2, a, b, net1, uses1, n_open = 0, n_many = 0
    with nogil:
        for v in range(n):
            a, b = start[v], start[v + 1]
            if b - a <= SMALL:
                # A few edges (the usual valence): compared in place, which
                # touches only this bucket's memory; each edge counted at
                # its first entry.
                for e in range(a, b):
                    x = hi[e]
                    net1, uses1 = 0, 0
                    first = True
                    for e2 in range(a, b):
                        if hi[e2] == x:
                            net1 += 1 if fwd[e2] else -1
                            uses1 += 1
                            if e2 < e:
                                first = False
                    if net1 != 0:
                        closed = False
                    if first:
                        n_open += uses1 == 1
                        n_many += uses1 > 2
                continue
            for e in range(a, b):
                x = hi[e]
                net[x] += 1 if fwd[e] else -1
                uses[x] += 1
            for e in range(start[v], start[v + 1]):
                x = hi[e]
                if net[x] != 0:
                    closed = False
                n_open += uses[x] == 1
                n_many += uses[x] > 2
                net[x] = 0
                uses[x] = 0
    return bool(closed), bool(n_many > 0), int(n_open), int(n_many)


cdef inline void _sorted3(const int64_t *f, int64_t *p0, int64_t *p1, int64_t *p2) noexcept nogil:
    cdef int64_t a = f[0], b = f[1], c = f[2]
    if a > b:
        a, b = b, a
    if b > c:
        b, c = c, b
    if a > b:
        a, b = b, a
    p0[0], p1[0], p2[0] = a, b, c


def duplicate_faces(faces):
    """Whether two faces use the same three vertices (in any order), in linear time.

    Consecutive faces first (no memory: a file of one triangle repeated
    answers at its second face), then faces bucketed by their lowest
    vertex, chained by their middle one, and a stamp per highest vertex.

    Parameters
    ----------
    faces : (m, 3) int64
    """
    cdef const int64_t[:, ::1] fv = np.ascontiguousarray(faces, dtype=np.int64)
    cdef Py_ssize_t f, m = fv.shape[0]
    if m >= 2147483647:
        raise ValueError(f"duplicate_faces: {m} faces, at most 2^31 - 1")
    if m < 2:
        return False
    cdef const int64_t *F = &fv[0, 0]
    cdef int64_t p, q, r, p2, q2, r2
    _sorted3(F, &p2, &q2, &r2)
    for f in range(1, m):
        _sorted3(F + 3 * f, &p, &q, &r)
        if p == p2 and q == q2 and r == r2:
            return True
        p2, q2, r2 = p, q, r
    cdef int64_t n = int(np.max(faces)) + 1
    start_a = np.zeros(n + 1, np.int64)
    cdef int64_t[::1] start = start_a
    for f in range(m):
        _sorted3(F + 3 * f, &p, &q, &r)
        start[p + 1] += 1
    cdef int64_t v, e, g, x
    for v in range(n):
        start[v + 1] += start[v]
    member_a = np.empty(m, np.int32)
    pos_a = start_a[:n].copy()
    cdef int32_t[::1] member = member_a
    cdef int64_t[::1] pos = pos_a
    for f in range(m):
        _sorted3(F + 3 * f, &p, &q, &r)
        member[pos[p]] = <int32_t>f
        pos[p] += 1
    del pos_a
    # Within a bucket (same lowest vertex): faces chained by middle vertex,
    # then a stamp per highest vertex finds a repeat.
    head_a = np.full(n, -1, np.int32)
    nxt_a = np.empty(m, np.int32)
    stamp_a = np.full(n, -1, np.int64)
    cdef int32_t[::1] head = head_a, nxt = nxt_a
    cdef int64_t[::1] stamp = stamp_a
    cdef int64_t mark = 0, a, b, e2
    for v in range(n):
        a, b = start[v], start[v + 1]
        if b - a <= SMALL:
            for e in range(a, b):
                _sorted3(F + 3 * member[e], &p, &q, &r)
                for e2 in range(e + 1, b):
                    _sorted3(F + 3 * member[e2], &p2, &q2, &r2)
                    if q == q2 and r == r2:
                        return True
            continue
        for e in range(a, b):
            f = member[e]
            _sorted3(F + 3 * f, &p, &q, &r)
            nxt[f] = head[q]
            head[q] = <int32_t>f
        for e in range(start[v], start[v + 1]):
            _sorted3(F + 3 * member[e], &p, &q, &r)
            g = head[q]
            if g < 0:
                continue
            head[q] = -1
            while g >= 0:
                _sorted3(F + 3 * g, &p2, &q2, &x)
                if stamp[x] == mark:
                    return True
                stamp[x] = mark
                g = nxt[g]
            mark += 1
    return False


cdef inline int64_t _root(int64_t[::1] parent, int64_t x) noexcept nogil:
    while parent[x] != x:
        parent[x] = parent[parent[x]]  # path halving
        x = parent[x]
    return x


def vertex_connected(faces):
    """Whether the faces' vertices form one connected graph (union-find, linear).

    Parameters
    ----------
    faces : (m, 3) int64, m >= 1
    """
    cdef const int64_t[:, ::1] fv = np.ascontiguousarray(faces, dtype=np.int64)
    cdef Py_ssize_t f, m = fv.shape[0]
    cdef int64_t n = int(np.max(faces)) + 1
    parent_a = np.arange(n, dtype=np.int64)
    used_a = np.zeros(n, np.uint8)
    cdef int64_t[::1] parent = parent_a
    cdef uint8_t[::1] used = used_a
    cdef int64_t a, b, k, roots = 0
    for f in range(m):
        used[fv[f, 0]] = 1
        used[fv[f, 1]] = 1
        used[fv[f, 2]] = 1
        for k in range(2):
            a = _root(parent, fv[f, k])
            b = _root(parent, fv[f, k + 1])
            if a != b:
                if a < b:
                    parent[b] = a
                else:
                    parent[a] = b
    for a in range(n):
        if used[a] and parent[a] == a:
            roots += 1
    return roots == 1


cdef inline uint64_t _bits(double x) noexcept nogil:
    cdef uint64_t u
    if x == 0.0:
        x = 0.0  # -0.0 and 0.0 are one position
    memcpy(&u, &x, 8)
    return u


cdef inline uint64_t _position_hash(double x, double y, double z) noexcept nogil:
    cdef uint64_t h = _bits(x) * 0x9E3779B97F4A7C15ULL
    h = (h ^ (h >> 29) ^ _bits(y)) * 0xBF58476D1CE4E5B9ULL
    h = (h ^ (h >> 32) ^ _bits(z)) * 0x94D049BB133111EBULL
    return h ^ (h >> 31)


def merge_positions(vertices):
    """Vertices numbered by exact position (equal coordinates, one number), in linear time.

    A hash of the coordinates' bits; numbers in order of first appearance
    (not :attr:`geovox.mesh.Mesh.geometric_faces`' lexicographic order: this
    numbering serves questions that do not depend on it).

    The table holds a 32-bit vertex index a slot, twice as many slots as
    vertices (never more than half full: no growing, which cost a mesh of
    distinct vertices, a PLY's, twice the time): half the 64-bit table's
    memory (64 MB, not 128, at the 4.8 million vertices of a 1.6-million-
    triangle STL), and freed before the work that follows.

    Parameters
    ----------
    vertices : (n, 3) float64, finite; n < 2^31

    Returns
    -------
    (n,) int64
    """
    cdef const double[:, ::1] v = np.ascontiguousarray(vertices, dtype=np.float64)
    cdef Py_ssize_t i, n = v.shape[0]
    if n >= 2147483647:
        raise ValueError(f"merge_positions: {n} vertices, at most 2^31 - 1")
    out_a = np.empty(n, np.int64)
    if n == 0:
        return out_a
    cdef int64_t[::1] out = out_a
    cdef const double *p = &v[0, 0]
    cdef uint64_t size = 1024, mask, h
    while size < 2 * <uint64_t>n:
        size *= 2
    # A NumPy array, not malloc's: NumPy asks the kernel for huge pages for
    # it (madvise), and a table this size read at random misses the TLB on
    # small ones (0.17 s, not 0.14, at 4.8 million vertices here).
    table_a = np.full(size, -1, np.int32)
    cdef int32_t[::1] table_v = table_a
    cdef int32_t *table = &table_v[0]
    cdef int32_t k
    cdef int64_t count = 0
    mask = size - 1
    with nogil:
        for i in range(n):
            h = _position_hash(p[3 * i], p[3 * i + 1], p[3 * i + 2]) & mask
            while True:
                k = table[h]
                if k < 0:
                    table[h] = <int32_t>i
                    out[i] = count
                    count += 1
                    break
                if p[3 * k] == p[3 * i] and p[3 * k + 1] == p[3 * i + 1] \
                        and p[3 * k + 2] == p[3 * i + 2]:
                    out[i] = out[k]
                    break
                h = (h + 1) & mask
    return out_a


# ---------------------------------------------------------------------------
# The repair of open and messy meshes (geovox.inside.repair): the same arrays
# as its NumPy steps, in linear time (or a sort of a few entries per vertex).
# ---------------------------------------------------------------------------

cdef void _sort_bucket(int64_t[::1] hi, int64_t[::1] slot, int64_t[::1] tmp_h,
                       int64_t[::1] tmp_s, Py_ssize_t a, Py_ssize_t b) noexcept nogil:
    """Stable sort of ``hi[a:b]`` (carrying ``slot``): insertion for a few, else merging.

    ``tmp_h`` and ``tmp_s`` hold at least ``b - a`` entries (indexed from 0).
    """
    cdef Py_ssize_t i, j, w, lo, mid, hi_end, p, q
    cdef int64_t h, s
    if b - a <= SMALL:
        for i in range(a + 1, b):
            h, s = hi[i], slot[i]
            j = i - 1
            while j >= a and hi[j] > h:
                hi[j + 1], slot[j + 1] = hi[j], slot[j]
                j -= 1
            hi[j + 1], slot[j + 1] = h, s
        return
    # Bottom-up merge sort (a vertex on thousands of edges: a fan's apex).
    w = 1
    while w < b - a:
        lo = a
        while lo < b:
            mid = lo + w if lo + w < b else b
            hi_end = lo + 2 * w if lo + 2 * w < b else b
            p, q, i = lo, mid, lo - a
            while p < mid and q < hi_end:
                if hi[q] < hi[p]:
                    tmp_h[i], tmp_s[i] = hi[q], slot[q]
                    q += 1
                else:
                    tmp_h[i], tmp_s[i] = hi[p], slot[p]
                    p += 1
                i += 1
            while p < mid:
                tmp_h[i], tmp_s[i] = hi[p], slot[p]
                p += 1
                i += 1
            while q < hi_end:
                tmp_h[i], tmp_s[i] = hi[q], slot[q]
                q += 1
                i += 1
            lo = hi_end
        for i in range(a, b):
            hi[i], slot[i] = tmp_h[i - a], tmp_s[i - a]
        w *= 2


def edge_sort(faces):
    """Undirected edges numbered in ``(low, high)`` vertex order, and their face-edge slots.

    What ``np.unique`` of the keys ``low * n + high`` and a stable argsort
    of the slots by edge give (:func:`geovox.inside.repair.edge_table`,
    :func:`~geovox.inside.repair.manifold_pairs`), in linear time: slots
    bucketed by their lower vertex (a counting sort), then each bucket's few
    entries sorted by the higher vertex.

    Parameters
    ----------
    faces : (m, 3) int64, non-negative

    Returns
    -------
    order : (q,) int64
        The slots ``3 f + j`` (edge ``j`` of face ``f`` runs from vertex
        ``j`` to ``j + 1``) that are not degenerate (two equal vertices),
        sorted by edge, then slot.
    edge : (3m,) int64
        Edge number of each slot; -1 for a degenerate one.
    low, high : (e,) int64
        Each edge's vertices, ``low < high``.
    count : (e,) int64
        Slots on each edge.
    net : (e,) int64
        Slots running it from low to high, less those running it back.
    """
    cdef const int64_t[:, ::1] fv = np.ascontiguousarray(faces, dtype=np.int64)
    cdef Py_ssize_t m = fv.shape[0], f, i, v, big = 0
    cdef int k
    cdef int64_t n = int(np.max(faces)) + 1 if m else 1
    cdef int64_t a, b, lo, e, s
    start_a = np.zeros(n + 1, np.int64)
    cdef int64_t[::1] start = start_a
    for f in range(m):
        for k in range(3):
            a, b = fv[f, k], fv[f, (k + 1) % 3]
            if a != b:
                start[(a if a < b else b) + 1] += 1
    for v in range(n):
        if start[v + 1] > big:
            big = start[v + 1]
        start[v + 1] += start[v]
    cdef Py_ssize_t q = start[n]
    # Each bucket entry: the higher vertex, and the slot times 2 plus
    # whether the face runs the edge from low to high.
    packed_a = np.empty(q, np.int64)
    bh_a = np.empty(q, np.int64)
    pos_a = start_a[:n].copy()
    cdef int64_t[::1] packed = packed_a, bh = bh_a, pos = pos_a
    for f in range(m):  # in slot order: each bucket starts sorted by slot
        for k in range(3):
            a, b = fv[f, k], fv[f, (k + 1) % 3]
            if a != b:
                lo = a if a < b else b
                packed[pos[lo]] = 2 * (3 * f + k) + (a < b)
                bh[pos[lo]] = b if a < b else a
                pos[lo] += 1
    th_a = np.empty(big if big > SMALL else 0, np.int64)
    ts_a = np.empty(big if big > SMALL else 0, np.int64)
    cdef int64_t[::1] th = th_a, ts = ts_a
    for v in range(n):
        if start[v + 1] - start[v] > 1:
            _sort_bucket(bh, packed, th, ts, start[v], start[v + 1])
    order_a = np.empty(q, np.int64)
    edge_a = np.full(3 * m, -1, np.int64)
    low_a = np.empty(q, np.int64)
    high_a = np.empty(q, np.int64)
    count_a = np.zeros(q, np.int64)
    net_a = np.zeros(q, np.int64)
    cdef int64_t[::1] order = order_a, edge = edge_a, low = low_a, high = high_a
    cdef int64_t[::1] count = count_a, net = net_a
    e = -1
    for v in range(n):
        for i in range(start[v], start[v + 1]):
            if i == start[v] or bh[i] != bh[i - 1]:
                e += 1
                low[e], high[e] = v, bh[i]
            s = packed[i] >> 1
            order[i] = s
            edge[s] = e
            count[e] += 1
            net[e] += 1 if packed[i] & 1 else -1
    e += 1
    return order_a, edge_a, low_a[:e], high_a[:e], count_a[:e], net_a[:e]


def components(int64_t n, a_in, b_in, odd_in=None):
    """:func:`geovox.inside.repair.components`, round for round, in compiled loops.

    The same forest (each round hooks every root to its smallest
    neighbouring root, through the first such edge in the given order), so
    the same parities even where they contradict (a Moebius band).

    Parameters
    ----------
    n : int
    a_in, b_in : (e,) int64
    odd_in : (e,) bool, optional

    Returns
    -------
    count : int
    label : (n,) int64
    parity : (n,) bool
    """
    a_a = np.array(a_in, dtype=np.int64, copy=True).reshape(-1)
    b_a = np.array(b_in, dtype=np.int64, copy=True).reshape(-1)
    o_a = (np.zeros(len(a_a), np.uint8) if odd_in is None
           else np.array(odd_in, dtype=np.uint8, copy=True).reshape(-1))
    root_a = np.arange(n, dtype=np.int64)
    x_a = np.zeros(n, np.uint8)
    best_a = np.full(n, -1, np.int64)
    hooked_a = np.empty(n, np.int64)
    nx_a = np.empty(n, np.uint8)
    nlo_a = np.empty(n, np.int64)
    cdef int64_t[::1] ea = a_a, eb = b_a, root = root_a, best = best_a, hooked = hooked_a
    cdef int64_t[::1] nlo = nlo_a
    cdef uint8_t[::1] od = o_a, x = x_a, nx = nx_a
    cdef Py_ssize_t live = ea.shape[0], i, w, t, nh
    cdef int64_t ra, rb, lo, hi, j, v, p
    with nogil:
        while live > 0:
            w = 0
            for i in range(live):
                if root[ea[i]] != root[eb[i]]:
                    ea[w], eb[w], od[w] = ea[i], eb[i], od[i]
                    w += 1
            live = w
            if live == 0:
                break
            nh = 0
            for i in range(live):
                ra, rb = root[ea[i]], root[eb[i]]
                lo, hi = (ra, rb) if ra < rb else (rb, ra)
                j = best[hi]
                if j < 0:
                    best[hi] = i
                    hooked[nh] = hi
                    nh += 1
                elif lo < (root[ea[j]] if root[ea[j]] < root[eb[j]] else root[eb[j]]):
                    best[hi] = i
            # Every hooked root's new pointer and parity from the round's
            # old values (as NumPy's whole-array assignment reads them).
            for t in range(nh):
                i = best[hooked[t]]
                ra, rb = root[ea[i]], root[eb[i]]
                nlo[t] = ra if ra < rb else rb
                nx[t] = x[ea[i]] ^ x[eb[i]] ^ od[i]
            for t in range(nh):
                hi = hooked[t]
                x[hi] = nx[t]
                root[hi] = nlo[t]
                best[hi] = -1
            # Pointers only go to smaller nodes: in increasing order, each
            # node's pointer is already final when the node is reached.
            for v in range(n):
                p = root[v]
                if p != v:
                    x[v] ^= x[p]
                    root[v] = root[p]
    label_a = np.empty(n, np.int64)
    cdef int64_t[::1] label = label_a
    cdef int64_t count = 0
    for v in range(n):
        if root[v] == v:
            label[v] = count
            count += 1
        else:
            label[v] = label[root[v]]
    return int(count), label_a, x_a.astype(bool)


cdef inline uint64_t _mix3(uint64_t x, uint64_t y, uint64_t z) noexcept nogil:
    cdef uint64_t h = x * 0x9E3779B97F4A7C15ULL
    h = (h ^ (h >> 29) ^ y) * 0xBF58476D1CE4E5B9ULL
    h = (h ^ (h >> 32) ^ z) * 0x94D049BB133111EBULL
    return h ^ (h >> 31)


def face_groups(faces):
    """Faces grouped by their three vertices (in any order), groups numbered by first appearance.

    Faces bucketed by their lowest vertex (a counting sort, as
    :func:`duplicate_faces`), each bucket settled in place: in face order, a
    face joins the group of the first earlier face with its other two
    vertices (a few faces a bucket: compared pairwise; a fan's apex: chained
    by middle vertex, then a stamp per highest vertex). Linear, and its
    memory is a few per-vertex arrays, not a hash table of every face.

    Parameters
    ----------
    faces : (k, 3) int64
        No vertex repeated within a face.

    Returns
    -------
    first : (g,) int64
        The first face of each group, increasing.
    group : (k,) int64
        The group of each face.
    parity : (k,) bool
        After its lowest vertex, the face's next vertex is lower than its
        last (its winding relative to the sorted order).
    """
    cdef const int64_t[:, ::1] fv = np.ascontiguousarray(faces, dtype=np.int64)
    cdef Py_ssize_t k = fv.shape[0], f, e, e2
    cdef int64_t n = int(np.max(faces)) + 1 if k else 1
    start_a = np.zeros(n + 1, np.int64)
    if k >= 2147483647:
        raise ValueError(f"face_groups: {k} faces, at most 2^31 - 1")
    member_a = np.empty(k, np.int32)
    rep_a = np.empty(k, np.int32)
    parity_a = np.empty(k, np.uint8)
    cdef int64_t[::1] start = start_a
    cdef int32_t[::1] member = member_a, rep = rep_a
    cdef uint8_t[::1] parity = parity_a
    cdef int64_t a, b, c, a2, b2, c2, v, g, mark = 0
    cdef int rot
    cdef const int64_t *F = &fv[0, 0] if k else NULL
    head_a = np.full(n, -1, np.int32)
    nxt_a = np.empty(k, np.int32)
    stamp_a = np.full(n, -1, np.int64)
    firstof_a = np.empty(n, np.int32)
    cdef int32_t[::1] head = head_a, nxt = nxt_a, firstof = firstof_a
    cdef int64_t[::1] stamp = stamp_a
    with nogil:
        for f in range(k):
            _sorted3(F + 3 * f, &a, &b, &c)
            start[a + 1] += 1
            rot = 0 if F[3 * f] <= F[3 * f + 1] and F[3 * f] <= F[3 * f + 2] else (
                1 if F[3 * f + 1] <= F[3 * f + 2] else 2)
            parity[f] = F[3 * f + (rot + 1) % 3] < F[3 * f + (rot + 2) % 3]
        for v in range(n):
            start[v + 1] += start[v]
        for f in range(k):  # in face order: each bucket ascending
            _sorted3(F + 3 * f, &a, &b, &c)
            member[start[a]] = <int32_t>f
            start[a] += 1
        for v in range(n - 1, -1, -1):  # back to the buckets' starts
            start[v + 1] = start[v]
        start[0] = 0
        for v in range(n):
            if start[v + 1] - start[v] <= SMALL:
                for e in range(start[v], start[v + 1]):
                    f = member[e]
                    rep[f] = <int32_t>f
                    _sorted3(F + 3 * f, &a, &b, &c)
                    for e2 in range(start[v], e):
                        g = member[e2]
                        _sorted3(F + 3 * g, &a2, &b2, &c2)
                        if b2 == b and c2 == c:
                            rep[f] = rep[g]
                            break
                continue
            for e in range(start[v + 1] - 1, start[v] - 1, -1):  # chains by middle vertex, ascending
                f = member[e]
                _sorted3(F + 3 * f, &a, &b, &c)
                nxt[f] = head[b]
                head[b] = <int32_t>f
            for e in range(start[v], start[v + 1]):
                _sorted3(F + 3 * member[e], &a, &b, &c)
                g = head[b]
                if g < 0:
                    continue
                head[b] = -1
                while g >= 0:
                    _sorted3(F + 3 * g, &a2, &b2, &c2)
                    if stamp[c2] != mark:
                        stamp[c2] = mark
                        firstof[c2] = <int32_t>g
                    rep[g] = firstof[c2]
                    g = nxt[g]
                mark += 1
    first_a = np.empty(k, np.int64)
    group_a = np.empty(k, np.int64)
    cdef int64_t[::1] first = first_a, group = group_a
    cdef int64_t count = 0
    with nogil:
        for f in range(k):
            if rep[f] == f:
                first[count] = f
                group[f] = count
                count += 1
            else:
                group[f] = group[rep[f]]
    return first_a[:count].copy(), group_a, parity_a.astype(bool)


def proper_faces(const double[:, ::1] pos, const int64_t[:, ::1] faces):
    """Faces with three distinct vertices and a cross product not exactly 0.

    ``np.cross`` of the edges from vertex 0, operation for operation (each
    component a product less a product, no fused multiply-add).

    Parameters
    ----------
    pos : (n, 3) float64
    faces : (k, 3) int64

    Returns
    -------
    (k,) bool
    """
    cdef Py_ssize_t k = faces.shape[0], f
    out_a = np.empty(k, np.uint8)
    cdef uint8_t[::1] out = out_a
    cdef int64_t i0, i1, i2
    cdef double a0, a1, a2, b0, b1, b2
    with nogil:
        for f in range(k):
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            if i0 == i1 or i1 == i2 or i2 == i0:
                out[f] = 0
                continue
            a0, a1, a2 = pos[i1, 0] - pos[i0, 0], pos[i1, 1] - pos[i0, 1], pos[i1, 2] - pos[i0, 2]
            b0, b1, b2 = pos[i2, 0] - pos[i0, 0], pos[i2, 1] - pos[i0, 1], pos[i2, 2] - pos[i0, 2]
            out[f] = (a1 * b2 - a2 * b1 != 0) or (a2 * b0 - a0 * b2 != 0) or (a0 * b1 - a1 * b0 != 0)
    return out_a.astype(bool)


cdef inline int64_t _probe(int64_t[::1] table, const int64_t[:, ::1] cell, uint64_t mask,
                           int64_t c0, int64_t c1, int64_t c2) noexcept nogil:
    """The slot of cell ``(c0, c1, c2)`` in ``table``, or of the empty entry where it would go."""
    cdef uint64_t h = _mix3(<uint64_t>c0, <uint64_t>c1, <uint64_t>c2) & mask
    cdef int64_t k
    while True:
        k = table[h]
        if k < 0 or (cell[k, 0] == c0 and cell[k, 1] == c1 and cell[k, 2] == c2):
            return <int64_t>h
        h = (h + 1) & mask


def near_pairs(const double[:, ::1] pos, const double[::1] low, double tol, double width):
    """Pairs of points whose coordinates differ by at most about ``tol`` on every axis.

    Candidates for :func:`geovox.inside.repair.close_pairs` (the caller
    applies its exact tests), through a hash table of cells ``width`` wide
    (several ``tol``): a point looks up its own cell and, on each axis, the
    neighbouring one only where it lies within ``tol`` of that side, so most
    points look up one or two cells (random memory reads, which dominate).

    Parameters
    ----------
    pos : (n, 3) float64
    low : (3,) float64
        At most every coordinate.
    tol, width : float
        ``0 < tol < width``.

    Returns
    -------
    (p, 2) int64
        ``i < j`` in each row, in no particular order; every pair within
        ``1.001 tol`` on every axis is among them.
    """
    cdef Py_ssize_t n = pos.shape[0], i
    cdef uint64_t size = 16
    while size < 2 * <uint64_t>n:
        size *= 2
    cell_a = np.empty((n, 3), np.int64)
    reach_a = np.zeros((n, 3, 2), np.uint8)  # per axis: look left, look right
    table_a = np.full(size, -1, np.int64)   # a cell's slot: a point in it
    head_a = np.full(size, -1, np.int64)    # the cell's points, chained
    nxt_a = np.full(n, -1, np.int64)
    cdef int64_t[:, ::1] cell = cell_a
    cdef uint8_t[:, :, ::1] reach = reach_a
    cdef int64_t[::1] table = table_a, head = head_a, nxt = nxt_a
    cdef uint64_t mask = size - 1
    cdef int64_t h, j, di, dj, dk, cap = 64, np_ = 0
    cdef int a
    cdef double u, f, near = 1.01 * tol, dx, dy, dz, limit = 2.0 * tol * tol
    out_a = np.empty((cap, 2), np.int64)
    cdef int64_t[:, ::1] out = out_a
    for i in range(n):
        for a in range(3):
            u = (pos[i, a] - low[a]) / width
            cell[i, a] = <int64_t>floor(u)
            f = (u - floor(u)) * width
            reach[i, a, 0] = f <= near
            reach[i, a, 1] = width - f <= near
        h = _probe(table, cell, mask, cell[i, 0], cell[i, 1], cell[i, 2])
        if table[h] < 0:
            table[h] = i
        nxt[i] = head[h]
        head[h] = i
    for i in range(n):
        for di in range(-1, 2):
            if di != 0 and not reach[i, 0, (di + 1) // 2]:
                continue
            for dj in range(-1, 2):
                if dj != 0 and not reach[i, 1, (dj + 1) // 2]:
                    continue
                for dk in range(-1, 2):
                    if dk != 0 and not reach[i, 2, (dk + 1) // 2]:
                        continue
                    h = _probe(table, cell, mask, cell[i, 0] + di, cell[i, 1] + dj,
                               cell[i, 2] + dk)
                    if table[h] < 0:
                        continue
                    j = head[h]
                    while j >= 0:
                        if j > i:
                            dx = pos[i, 0] - pos[j, 0]
                            dy = pos[i, 1] - pos[j, 1]
                            dz = pos[i, 2] - pos[j, 2]
                            if dx * dx + dy * dy + dz * dz <= limit:
                                if np_ == cap:
                                    cap *= 2
                                    grown = np.empty((cap, 2), np.int64)
                                    grown[:np_] = out_a[:np_]
                                    out_a = grown
                                    out = out_a
                                out[np_, 0], out[np_, 1] = i, j
                                np_ += 1
                        j = nxt[j]
    return out_a[:np_].copy()


# ---------------------------------------------------------------------------
# The repair of open scans (issue 37): the lexicographic numbering, the edge
# table, the faces' orientations and the pieces' outward turns in one pass
# each, with 32-bit tables; the same arrays as the steps above (and their
# NumPy twins in geovox.inside.repair) wherever they apply.
# ---------------------------------------------------------------------------

cdef inline uint64_t _order_key(double x) noexcept nogil:
    """A key whose unsigned order is the order of ``x`` (finite; -0.0 is 0.0)."""
    cdef uint64_t u
    if x == 0.0:
        x = 0.0
    memcpy(&u, &x, 8)
    if u >> 63:
        return ~u
    return u | (<uint64_t>1 << 63)


cdef inline bint _yz_less(const double *v, int64_t a, int64_t b) noexcept nogil:
    """Row ``a`` before row ``b`` by (y, z) (equal rows: neither)."""
    if v[3 * a + 1] != v[3 * b + 1]:
        return v[3 * a + 1] < v[3 * b + 1]
    return v[3 * a + 2] < v[3 * b + 2]


cdef void _sort_run(const double *v, int64_t *idx, int64_t *buf, Py_ssize_t n) noexcept nogil:
    """Stable sort of ``idx[:n]`` by the rows' (y, z): insertion for a few, else merging."""
    cdef Py_ssize_t i, j, w, lo, mid, hi, p, q, o
    cdef int64_t x
    if n <= 16:
        for i in range(1, n):
            x = idx[i]
            j = i - 1
            while j >= 0 and _yz_less(v, x, idx[j]):
                idx[j + 1] = idx[j]
                j -= 1
            idx[j + 1] = x
        return
    w = 1
    while w < n:
        lo = 0
        while lo < n:
            mid = lo + w if lo + w < n else n
            hi = lo + 2 * w if lo + 2 * w < n else n
            p, q, o = lo, mid, lo
            while p < mid and q < hi:
                if _yz_less(v, idx[q], idx[p]):
                    buf[o] = idx[q]
                    q += 1
                else:
                    buf[o] = idx[p]
                    p += 1
                o += 1
            while p < mid:
                buf[o] = idx[p]
                p += 1
                o += 1
            while q < hi:
                buf[o] = idx[q]
                q += 1
                o += 1
            lo = hi
        for i in range(n):
            idx[i] = buf[i]
        w *= 2


def lex_order(const double[:, ::1] v):
    """``np.lexsort((v[:, 2], v[:, 1], v[:, 0]))``: rows in lexicographic order, stable.

    A least-significant-digit radix sort of the x coordinates' order keys
    (8 bits a pass; a pass whose digit is the same everywhere is skipped),
    then each run of equal x sorted by (y, z), stably: near linear, where
    ``np.lexsort`` sorts three times (0.5 s for 800,000 positions here).

    Parameters
    ----------
    v : (n, 3) float64, finite

    Returns
    -------
    (n,) int64
    """
    cdef Py_ssize_t n = v.shape[0], i, j
    order_a = np.arange(n, dtype=np.int64)
    if n < 2:
        return order_a
    tmp_a = np.empty(n, np.int64)
    key_a = np.empty(n, np.uint64)
    kt_a = np.empty(n, np.uint64)
    cdef int64_t[::1] order = order_a, tmp = tmp_a
    cdef uint64_t[::1] key = key_a, kt = kt_a
    cdef int64_t count[257]
    cdef const double *p = &v[0, 0]
    cdef int shift, d
    cdef int64_t c, total
    with nogil:
        for i in range(n):
            key[i] = _order_key(p[3 * i])
        for shift in range(0, 64, 8):
            memset(count, 0, sizeof(count))
            for i in range(n):
                count[((key[i] >> shift) & 0xFF) + 1] += 1
            if count[((key[0] >> shift) & 0xFF) + 1] == n:
                continue  # one digit everywhere: nothing moves
            total = 0
            for d in range(256):
                c = count[d + 1]
                count[d + 1] = total
                total += c
            for i in range(n):
                d = (key[i] >> shift) & 0xFF
                c = count[d + 1]
                tmp[c] = order[i]
                kt[c] = key[i]
                count[d + 1] = c + 1
            for i in range(n):
                order[i] = tmp[i]
                key[i] = kt[i]
        i = 0
        while i < n:  # runs of one x: by (y, z)
            j = i + 1
            while j < n and key[j] == key[i]:
                j += 1
            if j - i > 1:
                _sort_run(p, &order[i], &tmp[0], j - i)
            i = j
    return order_a


cdef inline int32_t _find(int32_t *parent, uint8_t *par, int32_t x, uint8_t *px) noexcept nogil:
    """The root of ``x``, and into ``px`` its parity relative to the root; the path compressed."""
    cdef int32_t r = x, y, up
    cdef uint8_t acc = 0, rest, old
    while parent[r] != r:
        acc ^= par[r]
        r = parent[r]
    y, rest = x, acc
    while parent[y] != y:
        up, old = parent[y], par[y]
        parent[y], par[y] = r, rest
        rest ^= old
        y = up
    px[0] = acc
    return r


cdef inline void _enter(int64_t *start, uint32_t *ent, int64_t a, int64_t b, int64_t c,
                        int64_t s) noexcept nogil:
    """Slot ``s`` (edge a -> b of a face whose third vertex is c) into its lower vertex's bucket.

    A record: the higher vertex, 2 s + (the face runs the edge from low to
    high), the third vertex.
    """
    cdef int64_t lo = a if a < b else b
    cdef int64_t e = 3 * start[lo]  # the bucket's next entry (start moves on; set back after)
    ent[e] = <uint32_t>(b if a < b else a)
    ent[e + 1] = <uint32_t>(2 * s + (a < b))
    ent[e + 2] = <uint32_t>c
    start[lo] += 1


cdef void _sort_entries(uint32_t *ent, uint32_t *tmp, Py_ssize_t n) noexcept nogil:
    """Stable sort of ``n`` records (three words each) by their first word: insertion for a few,
    else merging through ``tmp``."""
    cdef Py_ssize_t i, j, w, lo, mid, end, p, q, o
    cdef uint32_t h, s, x
    if n <= SMALL:
        for i in range(1, n):
            h, s, x = ent[3 * i], ent[3 * i + 1], ent[3 * i + 2]
            j = i - 1
            while j >= 0 and ent[3 * j] > h:
                ent[3 * j + 3], ent[3 * j + 4], ent[3 * j + 5] = ent[3 * j], ent[3 * j + 1], ent[3 * j + 2]
                j -= 1
            ent[3 * j + 3], ent[3 * j + 4], ent[3 * j + 5] = h, s, x
        return
    w = 1
    while w < n:
        lo = 0
        while lo < n:
            mid = lo + w if lo + w < n else n
            end = lo + 2 * w if lo + 2 * w < n else n
            p, q, o = lo, mid, lo
            while p < mid and q < end:
                if ent[3 * q] < ent[3 * p]:
                    tmp[3 * o], tmp[3 * o + 1], tmp[3 * o + 2] = ent[3 * q], ent[3 * q + 1], ent[3 * q + 2]
                    q += 1
                else:
                    tmp[3 * o], tmp[3 * o + 1], tmp[3 * o + 2] = ent[3 * p], ent[3 * p + 1], ent[3 * p + 2]
                    p += 1
                o += 1
            while p < mid:
                tmp[3 * o], tmp[3 * o + 1], tmp[3 * o + 2] = ent[3 * p], ent[3 * p + 1], ent[3 * p + 2]
                p += 1
                o += 1
            while q < end:
                tmp[3 * o], tmp[3 * o + 1], tmp[3 * o + 2] = ent[3 * q], ent[3 * q + 1], ent[3 * q + 2]
                q += 1
                o += 1
            lo = end
        for i in range(3 * n):
            ent[i] = tmp[i]
        w *= 2


cdef inline double _dot3(double p0, double p1, double p2, int order) noexcept nogil:
    """``p0 + p1 + p2`` associated as NumPy's ``einsum("ij,ij->i")`` does (see repair_edges)."""
    if order == 0:
        return (p0 + p1) + p2
    if order == 1:
        return (p0 + p2) + p1
    return p0 + (p1 + p2)


#: repair_edges' answers where it leaves the work to its caller.
DUPLICATES = 1
CONTRADICTION = 2


def repair_edges(int64_t[:, ::1] f, int64_t nv, const double[:, ::1] pos,
                 const double[::1] centre, int order):
    """The repair's steps after the duplicates, over the kept faces, in one pass each.

    What :func:`geovox.inside.repair.repair` computes from
    :func:`edge_sort`, :func:`components` and its NumPy steps, array for
    array, with a fraction of their memory (32-bit tables, no per-slot
    arrays kept): the edge table bucketed by each edge's lower vertex; the
    faces' orientations, by a union-find with parities over the manifold
    edges (the root of a piece is its lowest face, so the parities and the
    pieces' numbers are those of :func:`components`' rounds wherever the
    parities agree; where they contradict, a Moebius band, the forest's
    choice decides, and this returns ``CONTRADICTION`` for the caller to run the rounds);
    each piece turned outward by its signed volume about the centroid of its
    open edges' midpoints (or of its faces), with NumPy's arithmetic
    operation for operation: the sums in face order (``np.bincount``),
    ``np.cross``'s products, and the dot product associated as ``order``
    says ``np.einsum`` associates it (0: ``(p0 + p1) + p2``, 1:
    ``(p0 + p2) + p1``, 2: ``p0 + (p1 + p2)``; the caller finds out); and
    the copy's open edges with their final directions.

    Two faces with the same vertex set (a duplicate, or the other side of a
    double-sided face) share every edge and its third vertex: where some do,
    this returns ``DUPLICATES`` before it turns any face, for the caller to
    collapse them first (:func:`face_groups`) and call again; a scan has
    none, and needs no pass of its own to find that out.

    Parameters
    ----------
    f : (nf, 3) int64, written
        Faces over vertex ids ``< nv`` (lexicographic), no repeated vertex.
        Turned in place (vertices 1 and 2 swapped) where the repair turns
        them (not where this returns a code).
    nv : int
    pos : (nv, 3) float64
    centre : (3,) float64
        ``pos.mean(axis=0)`` (NumPy's: the origin of the volumes).
    order : int

    Returns
    -------
    ``DUPLICATES``, ``CONTRADICTION`` (the flips contradict: a Moebius band),
    or a tuple:
    label : (nf,) int64
        Each face's piece, numbered by their lowest face.
    swapped : (nf,) bool
        Vertices 1 and 2 swapped.
    pieces, closed_pieces, outward : int
    boundary : (k, 2) int64
        The copy's open edges (:func:`geovox.inside.edges.boundary_edges` of it).
    open, non_manifold_edges : int
        Edges used once, and more than twice.
    """
    cdef Py_ssize_t nf = f.shape[0], i, t, q2, j2
    if nf >= (1 << 30) or nv >= 2147483647:
        raise ValueError(f"repair_edges: {nf} faces over {nv} vertices, too many for its tables")
    cdef int j
    cdef int64_t a, b, lo, v, e0, e1, run, big = 0
    start_a = np.zeros(nv + 1, np.int64)
    cdef int64_t[::1] start = start_a
    cdef int64_t *F = &f[0, 0]
    cdef int64_t u0, u1, u2
    with nogil:
        for i in range(nf):  # each face's three edges, by their lower vertex
            u0, u1, u2 = F[3 * i], F[3 * i + 1], F[3 * i + 2]
            start[(u0 if u0 < u1 else u1) + 1] += 1
            start[(u1 if u1 < u2 else u2) + 1] += 1
            start[(u2 if u2 < u0 else u0) + 1] += 1
        for v in range(nv):
            if start[v + 1] > big:
                big = start[v + 1]
            start[v + 1] += start[v]
    cdef Py_ssize_t q = start[nv]
    # Per entry of a bucket: the higher vertex, the slot (2 (3 face + j) +
    # whether the face runs the edge from low to high) and the face's third
    # vertex (two faces on an edge with the same third one are duplicates).
    # One record of three 32-bit words an entry, so that filling a bucket
    # touches one cache line, not three.
    ent_a = np.empty((q if q else 1, 3), np.uint32)
    cdef uint32_t[:, ::1] ent = ent_a
    tmp_a = np.empty((big if big > SMALL else 1, 3), np.uint32)
    cdef uint32_t[:, ::1] tmp = tmp_a
    parent_a = np.arange(nf, dtype=np.int32)
    par_a = np.zeros(nf, np.uint8)
    flags_a = np.zeros(nf, np.uint8)  # bits 0-2: slot j is open (one face); bit 3: a slot not on two
    cdef int32_t[::1] parent = parent_a
    cdef uint8_t[::1] par = par_a, flags = flags_a
    cdef int32_t ra, rb, fa, fb
    cdef uint8_t pa, pb, odd
    cdef bint contradiction = False, duplicates = False
    cdef int64_t n_open = 0, n_many = 0
    with nogil:
        for i in range(nf):  # in slot order: every bucket starts sorted by slot
            u0, u1, u2 = F[3 * i], F[3 * i + 1], F[3 * i + 2]
            _enter(&start[0], &ent[0, 0], u0, u1, u2, 3 * i)
            _enter(&start[0], &ent[0, 0], u1, u2, u0, 3 * i + 1)
            _enter(&start[0], &ent[0, 0], u2, u0, u1, 3 * i + 2)
        for v in range(nv - 1, -1, -1):  # each bucket's start back
            start[v + 1] = start[v]
        start[0] = 0
        for v in range(nv):
            if start[v + 1] - start[v] > 1:
                _sort_entries(&ent[start[v], 0], &tmp[0, 0], start[v + 1] - start[v])
        for v in range(nv):
            e0 = start[v]
            while e0 < start[v + 1]:
                e1 = e0 + 1
                while e1 < start[v + 1] and ent[e1, 0] == ent[e0, 0]:
                    e1 += 1
                run = e1 - e0
                for t in range(e0, e1 - 1):  # one third vertex twice: one vertex set
                    for q2 in range(t + 1, e1):
                        if ent[t, 2] == ent[q2, 2]:
                            duplicates = True
                if run == 2:
                    fa, fb = <int32_t>((ent[e0, 1] >> 1) // 3), <int32_t>((ent[e0 + 1, 1] >> 1) // 3)
                    odd = (ent[e0, 1] & 1) == (ent[e0 + 1, 1] & 1)
                    ra = _find(&parent[0], &par[0], fa, &pa)
                    rb = _find(&parent[0], &par[0], fb, &pb)
                    if ra == rb:
                        if (pa ^ pb) != odd:
                            contradiction = True
                    elif ra < rb:
                        parent[rb], par[rb] = ra, pa ^ pb ^ odd
                    else:
                        parent[ra], par[ra] = rb, pa ^ pb ^ odd
                else:
                    n_open += run == 1
                    n_many += run > 2
                    for t in range(e0, e1):
                        fa = <int32_t>((ent[t, 1] >> 1) // 3)
                        flags[fa] |= 8
                        if run == 1:
                            flags[fa] |= 1 << ((ent[t, 1] >> 1) % 3)
                e0 = e1
    del tmp_a
    if duplicates:
        return DUPLICATES
    if contradiction:
        return CONTRADICTION
    # Outward (repair's NumPy step): per piece, the centroid c of its open
    # edges' midpoints (each open slot's vertex and the next one round the
    # face, as turned), else of its faces' centroids, then the signed volume
    # of its faces about c. Every sum runs in face order, as np.bincount's.
    label_a = np.empty(nf, np.int64)
    flip_a = np.empty(nf, np.uint8)
    cdef int64_t[::1] label = label_a
    cdef uint8_t[::1] flip = flip_a
    cdef int64_t npieces = 0
    sums_a = np.zeros((nf if nf else 1, 3), np.float64)  # per piece (at most nf); trimmed below
    nopen_a = np.zeros(nf if nf else 1, np.int64)
    bad_a = np.zeros(nf if nf else 1, np.uint8)
    cdef double[:, ::1] sums = sums_a
    cdef int64_t[::1] nopen = nopen_a
    cdef uint8_t[::1] bad = bad_a
    cdef const double *P = &pos[0, 0]
    cdef double c0 = centre[0], c1 = centre[1], c2 = centre[2]
    cdef int64_t l
    with nogil:
        for i in range(nf):  # roots are their pieces' lowest faces: numbered in order
            ra = _find(&parent[0], &par[0], <int32_t>i, &pa)
            flip[i] = pa
            if ra == i:
                label[i] = npieces
                npieces += 1
            else:
                label[i] = label[ra]
            if pa:
                F[3 * i + 1], F[3 * i + 2] = F[3 * i + 2], F[3 * i + 1]
            l = label[i]
            if flags[i] & 8:
                bad[l] = 1
            for j in range(3):
                if flags[i] & (1 << j):
                    a, b = F[3 * i + j], F[3 * i + (j + 1) % 3]
                    sums[l, 0] += (P[3 * a] + P[3 * b]) / 2 - c0
                    sums[l, 1] += (P[3 * a + 1] + P[3 * b + 1]) / 2 - c1
                    sums[l, 2] += (P[3 * a + 2] + P[3 * b + 2]) / 2 - c2
                    nopen[l] += 1
    del parent_a, par_a
    all_a = np.zeros((npieces, 3), np.float64)
    nface_a = np.zeros(npieces, np.int64)
    vol_a = np.zeros(npieces, np.float64)
    cdef double[:, ::1] alls = all_a
    cdef int64_t[::1] nface = nface_a
    cdef double[::1] vol = vol_a
    cdef double r[9]
    cdef double x0, x1, x2
    with nogil:
        for i in range(nf):  # faces' centroids: only a piece without open edges uses them
            l = label[i]
            if nopen[l] > 0:
                continue
            u0, u1, u2 = F[3 * i], F[3 * i + 1], F[3 * i + 2]
            # vt.mean(axis=1): a sum from 0.0, in order, over 3
            alls[l, 0] += (((0.0 + (P[3 * u0] - c0)) + (P[3 * u1] - c0)) + (P[3 * u2] - c0)) / 3
            alls[l, 1] += (((0.0 + (P[3 * u0 + 1] - c1)) + (P[3 * u1 + 1] - c1))
                           + (P[3 * u2 + 1] - c1)) / 3
            alls[l, 2] += (((0.0 + (P[3 * u0 + 2] - c2)) + (P[3 * u1 + 2] - c2))
                           + (P[3 * u2 + 2] - c2)) / 3
            nface[l] += 1
        for l in range(npieces):
            for j in range(3):
                if nopen[l] > 0:
                    sums[l, j] = sums[l, j] / <double>nopen[l]
                else:
                    sums[l, j] = alls[l, j] / <double>(nface[l] if nface[l] > 1 else 1)
        for i in range(nf):
            l = label[i]
            for j in range(3):
                u0 = F[3 * i + j]
                r[3 * j] = (P[3 * u0] - c0) - sums[l, 0]
                r[3 * j + 1] = (P[3 * u0 + 1] - c1) - sums[l, 1]
                r[3 * j + 2] = (P[3 * u0 + 2] - c2) - sums[l, 2]
            x0 = r[4] * r[8] - r[5] * r[7]  # np.cross(rel[:, 1], rel[:, 2])
            x1 = r[5] * r[6] - r[3] * r[8]
            x2 = r[3] * r[7] - r[4] * r[6]
            vol[l] += _dot3(r[0] * x0, r[1] * x1, r[2] * x2, order)
    turn_a = vol_a < 0
    cdef uint8_t[::1] turn = turn_a.view(np.uint8)
    swapped_a = np.empty(nf, np.uint8)
    cdef uint8_t[::1] swapped = swapped_a
    cdef int64_t nb = 0, net, m
    with nogil:
        for i in range(nf):
            swapped[i] = flip[i] ^ turn[label[i]]
            if turn[label[i]]:
                F[3 * i + 1], F[3 * i + 2] = F[3 * i + 2], F[3 * i + 1]
        # The copy's open edges: each edge's net direction with the faces as
        # turned (a turned face runs each of its edges the other way).
        for v in range(nv):
            e0 = start[v]
            while e0 < start[v + 1]:
                e1 = e0 + 1
                net = (1 if (ent[e0, 1] & 1) ^ swapped[(ent[e0, 1] >> 1) // 3] else -1)
                while e1 < start[v + 1] and ent[e1, 0] == ent[e0, 0]:
                    net += 1 if (ent[e1, 1] & 1) ^ swapped[(ent[e1, 1] >> 1) // 3] else -1
                    e1 += 1
                nb += net if net > 0 else -net
                e0 = e1
    boundary_a = np.empty((nb, 2), np.int64)
    cdef int64_t[:, ::1] boundary = boundary_a
    nb = 0
    with nogil:
        for v in range(nv):
            e0 = start[v]
            while e0 < start[v + 1]:
                e1 = e0 + 1
                net = (1 if (ent[e0, 1] & 1) ^ swapped[(ent[e0, 1] >> 1) // 3] else -1)
                while e1 < start[v + 1] and ent[e1, 0] == ent[e0, 0]:
                    net += 1 if (ent[e1, 1] & 1) ^ swapped[(ent[e1, 1] >> 1) // 3] else -1
                    e1 += 1
                # net > 0: low -> high left over; net < 0: high -> low.
                for m in range(net if net > 0 else -net):
                    boundary[nb, 0] = v if net > 0 else <int64_t>ent[e0, 0]
                    boundary[nb, 1] = <int64_t>ent[e0, 0] if net > 0 else v
                    nb += 1
                e0 = e1
    closed = int(npieces - np.count_nonzero(bad_a[:npieces]))
    return (label_a, swapped_a.view(bool), int(npieces), closed,
            int(np.count_nonzero(turn_a)), boundary_a, int(n_open), int(n_many))


def sweep_pairs(const double[:, ::1] pos, double tol, int64_t budget):
    """Pairs of points within about ``tol`` on every axis, of points sorted by x.

    Candidates for :func:`geovox.inside.repair.close_pairs` (the caller
    applies its exact tests) where the points come in lexicographic order
    (the repair's positions): each point is compared with those after it
    until x has grown by more than ``tol`` (times 1.01), in order, so a scan
    whose vertices are farther apart than ``tol`` costs one comparison a
    point and no table. Many points with one x (a flat side of a CAD model)
    would make that quadratic: past ``budget`` comparisons this gives up
    (returns None) and the caller uses :func:`near_pairs`.

    Parameters
    ----------
    pos : (n, 3) float64, x non-decreasing
    tol : float, > 0
    budget : int

    Returns
    -------
    (p, 2) int64 or None
        ``i < j`` in each row; every pair within ``1.001 tol`` on every axis is among them.
    """
    cdef Py_ssize_t n = pos.shape[0], i, j
    cdef double reach = 1.01 * tol
    cdef int64_t seen = 0, np_ = 0, cap = 64
    out_a = np.empty((cap, 2), np.int64)
    cdef int64_t[:, ::1] out = out_a
    for i in range(n):
        j = i + 1
        while j < n and pos[j, 0] - pos[i, 0] <= reach:
            seen += 1
            if fabs(pos[j, 1] - pos[i, 1]) <= reach and fabs(pos[j, 2] - pos[i, 2]) <= reach:
                if np_ == cap:
                    cap *= 2
                    grown = np.empty((cap, 2), np.int64)
                    grown[:np_] = out_a[:np_]
                    out_a = grown
                    out = out_a
                out[np_, 0], out[np_, 1] = i, j
                np_ += 1
            j += 1
        if seen > budget:
            return None
    return out_a[:np_].copy()


def lex_faces(const int64_t[:, ::1] ids, const int64_t[:, ::1] faces,
              const double[:, ::1] vertices, int64_t nid):
    """:func:`geovox.inside.edges.merged_faces` from faces over positions numbered by a hash.

    Parameters
    ----------
    ids : (m, 3) int64
        Each corner's position number ``< nid`` (:func:`merge_positions`).
    faces : (m, 3) int64
        Each corner's vertex.
    vertices : (n, 3) float64
    nid : int

    Returns
    -------
    n : int
        Positions the faces use.
    g : (m, 3) int64
        Each corner's position, numbered ``0 .. n - 1`` in lexicographic order.
    vertex : (n,) int64
        At each position, the vertex of the last corner there.
    """
    cdef Py_ssize_t m = ids.shape[0], i, c
    one_a = np.full(nid, -1, np.int64)
    cdef int64_t[::1] one = one_a
    cdef int64_t n = 0, x
    with nogil:
        for i in range(m):
            for c in range(3):
                one[ids[i, c]] = faces[i, c]
        for x in range(nid):
            n += one[x] >= 0
    where_a = np.flatnonzero(one_a >= 0)
    cdef int64_t[::1] where = where_a
    used_a = np.empty((n, 3), np.float64)
    cdef double[:, ::1] used = used_a
    with nogil:
        for i in range(n):
            x = one[where[i]]
            used[i, 0], used[i, 1], used[i, 2] = vertices[x, 0], vertices[x, 1], vertices[x, 2]
    order_a = lex_order(used_a)
    del used_a
    cdef int64_t[::1] order = order_a
    rank_a = np.empty(nid, np.int64)
    vertex_a = np.empty(n, np.int64)
    g_a = np.empty((m, 3), np.int64)
    cdef int64_t[::1] rank = rank_a, vertex = vertex_a
    cdef int64_t[:, ::1] g = g_a
    with nogil:
        for i in range(n):
            rank[where[order[i]]] = i
            vertex[i] = one[where[order[i]]]
        for i in range(m):
            for c in range(3):
                g[i, c] = rank[ids[i, c]]
    return int(n), g_a, vertex_a


def boundary_loops(const int64_t[:, ::1] vid, int64_t nv):
    """The boundary's closed loops, where every position balances: ``(loop, place)`` of each edge.

    :func:`geovox.inside.caps.loops` and :func:`geovox.inside.bridge.loop_order`
    in one linear pass: at each position the k-th edge arriving (by index)
    is continued by the k-th edge leaving (two counting sorts), and each
    cycle of that map is walked from its lowest edge, so loops are numbered
    by their lowest edge and each edge's place counts from it.

    Parameters
    ----------
    vid : (k, 2) int64
        Each boundary edge's start and end position (``< nv``).
    nv : int

    Returns
    -------
    None where some position has as many edges arriving as leaving not,
    else ``loop, place`` : (k,) int64 each.
    """
    cdef Py_ssize_t k = vid.shape[0], i, j
    cout_a = np.zeros(nv + 1, np.int64)
    cin_a = np.zeros(nv + 1, np.int64)
    cdef int64_t[::1] cout = cout_a, cin = cin_a
    cdef int64_t v
    with nogil:
        for i in range(k):
            cout[vid[i, 0] + 1] += 1
            cin[vid[i, 1] + 1] += 1
    if not np.array_equal(cout_a, cin_a):
        return None
    nxt_a = np.empty(k, np.int64)
    order_a = np.empty(k, np.int64)
    cdef int64_t[::1] nxt = nxt_a, order = order_a
    loop_a = np.full(k, -1, np.int64)
    place_a = np.empty(k, np.int64)
    cdef int64_t[::1] loop = loop_a, place = place_a
    cdef int64_t count = 0, r
    with nogil:
        for v in range(nv):
            cout[v + 1] += cout[v]
        for v in range(nv + 1):
            cin[v] = cout[v]
        for i in range(k):  # the edges leaving each position, by index
            order[cout[vid[i, 0]]] = i
            cout[vid[i, 0]] += 1
        for i in range(k):  # the j-th arriving at a position: the j-th leaving it
            nxt[i] = order[cin[vid[i, 1]]]
            cin[vid[i, 1]] += 1
        for i in range(k):
            if loop[i] >= 0:
                continue
            j, r = i, 0
            while loop[j] < 0:
                loop[j] = count
                place[j] = r
                r += 1
                j = nxt[j]
            count += 1
    return loop_a, place_a
