"""The exact nearest triangle of every inside voxel, in whole arrays.

For each inside voxel centre ``x`` this finds the triangle ``T`` of the mesh
that minimises the Euclidean distance ``d(x, T)``, and the barycentric
coordinates of the closest point on it. Ties: of the triangles within
``TIE`` voxel sizes of the smallest distance, the one with the smallest
index. The answer is what a brute-force search over every triangle (with the
same float64 closest-point formula, :func:`closest`) gives; nothing is
estimated.

The search is a branch and bound over an octree of voxel cells, from cells of
``2**L`` voxels down to single voxels, each cell carrying the list of
triangles that can still be nearest to one of its voxel centres, as flat
(cell, triangle) pair arrays handled in bounded chunks. A triangle leaves a
cell's list only when a valid bound proves that, for every point ``x`` of
the cell's box, ``d(x, T) > d(x, surface) + MARGIN`` voxel sizes:

* **Top cells**: ``U = max over the box's corners of |k - v|`` for a mesh
  vertex ``v`` near the cell bounds ``d(x, surface)`` over the box (``|x - v|`` is convex);
  a triangle whose bounding box is farther than ``U`` from the cell's box is
  dropped.
* **Every cell, dominance by one surface point**: for any fixed point ``p``
  on the surface, ``d(x, T)**2 - |x - p|**2`` is a concave function of ``x``
  (``d(x, T)**2 - |x|**2 = min over q in T of (|q|**2 - 2 x.q)`` is a
  minimum of affine functions, and ``-|x - p|**2 + |x|**2`` is affine), so
  its minimum over a box is at one of the 8 corners. If it exceeds the
  margin there, ``d(x, T) > |x - p| >= d(x, surface)`` everywhere in the
  box. ``p`` is the closest point to the cell's centre on the candidate
  that looks nearest there. A lower bound of ``d(k, T)**2`` at the corners
  is enough (it only weakens the test), so the corners use the cheap
  :func:`lower_bound_sq`: the squared distance to the triangle's plane plus,
  for the edge that gives most, the squared distance to the edge's
  half-strip within the plane (inside the edge line and within the
  triangle's extent along the edge; the triangle lies in it, and plane
  normal, edge normal and edge direction are orthonormal, so the squared
  distance to the strip is a sum of squares). Exact wherever the closest
  point is on the face or an edge, and on acute and right triangles at
  their vertices too; below the distance only near the vertices of obtuse
  triangles (the edge line alone, used before, left every vertex region
  loose: 4.4 triangles a voxel were measured where 1.17 tie, spot 256³).
  Unlike a bound by ``d(centre, T) - half diagonal``, this one does not weaken with depth: a
  plane's neighbouring triangles are dropped once they are about
  ``sqrt(2)`` half-widths away sideways, however deep the cell.

At the voxels, the survivors of each 2-voxel cell are evaluated exactly.
Float errors are covered by the margin: ``MARGIN`` (1e-6 voxel sizes) is far
above the rounding of float64 arithmetic on coordinates of grids thousands
of voxels across (about 1e-13 voxel sizes; slivers below a relative area of
1e-6 are measured by their edges, see :func:`prepare`) and above ``TIE``, so
a dropped triangle is never the float argmin nor within ``TIE`` of it.

The compiled kernel (``geovox/_nearest.pyx``, :func:`run_kernel`) runs the
same search with these bounds and more (see its notes), in C with threads,
and gives the same answers bit for bit; this module's NumPy search is the
reference it is tested against and the fallback where it is not built
(:func:`kernel_module`, ``kernel="numpy"``).

All coordinates are taken relative to the whole grid's low corner, voxel
centres as ``(index + 0.5) * spacing`` with global indices, so a slab of a
grid computes every voxel bit for bit as the whole grid does.
"""

from __future__ import annotations

import numpy as np

from ..kernels import compiled, openmp_threads

#: Triangles within this many voxel sizes of the nearest are tied; the one
#: with the smallest index wins.
TIE = 1e-9
#: A triangle is dropped only when it is provably this many voxel sizes
#: farther than the surface everywhere in a cell (covers TIE and rounding:
#: about 1e-13 voxel sizes for coordinates within a few thousand voxels, and
#: below 4e-7 for the planes of the thinnest triangles measured by them).
MARGIN = 1e-6
#: Pairs (cell, triangle) handled at once: bounds the working memory (about
#: 0.6 KiB a pair at the widest step) whatever the grid. Measured on spot at
#: 256³ (paired whole-process runs, 2026-11-30): with the default threads,
#: 16384 and 32768 took 17 % and 11 % less wall time than 8192 (many small
#: steps contend for the GIL); with one thread 8192 took 11 % less CPU than
#: 32768 (a chunk's 31 gathered rows stay nearer the cache).
CHUNK = 1 << 14
#: Top cells are started this many (cell, triangle) pairs' worth at a time.
TOP_PAIRS = 1 << 21
#: Triangles per cluster for the top cells' first cut.
CLUSTER = 32

# The 8 corners of a box as signs of its half-extents, (8, 3).
_SIGNS = np.array([[(k >> a) & 1 for a in range(3)] for k in range(8)], float) * 2 - 1


def prepare(triangles: np.ndarray, origin: np.ndarray, closest_only: bool = False) -> dict:
    """Per-triangle constants for the bounds and the closest point.

    Parameters
    ----------
    triangles : (t, 3, 3) float64
    origin : (3,) float64
        The frame's origin (the whole grid's low corner).

    Returns
    -------
    dict of arrays
        ``a, ab, ac`` (t, 3); ``n`` (t, 3) unit normal; ``w`` (t, 7, 3): the
        unit normal, the three unit in-plane outward edge normals ``m``
        and the three edge directions ``n x m``; ``off`` (t, 7): their
        offsets (``x . w - off`` is the signed distance to the plane / edge
        line, or along the edge from the middle of the triangle's extent
        along it); ``hw`` (t, 3): half those extents; ``rows`` (31, t):
        ``w`` by component (row ``7 a + j`` is component ``a`` of direction
        ``j``), then ``off``, then ``hw``, for gathering contiguous rows
        per pair;
        ``g0, g1`` (t, 3): the dual basis giving the in-plane barycentrics;
        inverse squared edge lengths ``iab, iac, ibc`` (t,); ``flat`` (t,)
        bool, zero-area triangles (bounded below by 0 and evaluated by
        their edges); ``lo, hi`` (t, 3) bounding boxes. With
        ``closest_only``, what the closest point needs alone (no ``w``,
        ``off``, ``hw``, ``rows``: the search's bounds), the same values.
    """
    a = triangles[:, 0] - origin
    b = triangles[:, 1] - origin
    c = triangles[:, 2] - origin
    ab, ac, bc = b - a, c - a, c - b
    n = np.cross(ab, ac)
    area2 = np.einsum("ij,ij->i", n, n)
    scale2 = np.maximum(np.einsum("ij,ij->i", ab, ab), np.einsum("ij,ij->i", ac, ac))
    # A sliver's unit normal is only as good as rounding over its area
    # (direction error about 1e-16 / (area / longest edge^2)): below 1e-6 the
    # plane could misplace a point thousands of voxels away by more than the
    # margin, so such a triangle is bounded and measured by its edges alone.
    flat = ~(area2 > 1e-12 * scale2 * scale2) | ~np.isfinite(area2)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.where(flat[:, None], 0.0, n / np.sqrt(area2)[:, None])

        def edge_normal(e, inner):
            m = np.cross(e, n)
            m /= np.linalg.norm(m, axis=1, keepdims=True)
            # Outward: away from the opposite vertex.
            flip = np.einsum("ij,ij->i", m, inner) > 0
            m[flip] *= -1
            return np.where(flat[:, None], 0.0, m)

        if closest_only:
            return _closest_tables(a, b, c, ab, ac, bc, n, flat)
        m_ab = edge_normal(ab, ac)
        m_ac = edge_normal(ac, ab)
        m_bc = edge_normal(bc, a - b)
        # Along each edge: u = n x m (orthonormal with n and m by
        # construction, even for a sliver whose n is off its edges by 1e-10),
        # and the triangle's extent along it (all three vertices, so the slab
        # holds the triangle whatever its angles): centre and half-width.
        us, mids, hws = [], [], []
        for m in (m_ab, m_ac, m_bc):
            u = np.cross(n, m)
            pa, pb, pc = (np.einsum("ij,ij->i", u, v) for v in (a, b, c))
            lo_, hi_ = np.minimum(np.minimum(pa, pb), pc), np.maximum(np.maximum(pa, pb), pc)
            us.append(u)
            mids.append((lo_ + hi_) / 2)
            hws.append((hi_ - lo_) / 2)
        w = np.stack([n, m_ab, m_ac, m_bc] + us, axis=1)
        off = np.stack([np.einsum("ij,ij->i", n, a), np.einsum("ij,ij->i", m_ab, a),
                        np.einsum("ij,ij->i", m_ac, a), np.einsum("ij,ij->i", m_bc, b)] + mids,
                       axis=1)
        hw = np.stack(hws, axis=1)
        # The edge offsets of flat triangles: far inside, so their bound is 0.
        off[flat, 1:] = np.inf
        off[flat, 0] = 0.0
        off[flat, 4:] = 0.0
        hw[flat] = np.inf
        w[flat] = 0.0
        # The same by component, for gathering contiguous rows per pair:
        # rows 7 a + j hold component a of direction j; the 7 offsets after
        # them (rows 21-27), then the 3 half-widths (rows 28-30).
        rows = np.concatenate([w.transpose(2, 1, 0).reshape(21, -1), off.T, hw.T], axis=0)
    return {**_closest_tables(a, b, c, ab, ac, bc, n, flat),
            "w": w, "off": off, "hw": hw, "rows": rows}


def _closest_tables(a, b, c, ab, ac, bc, n, flat) -> dict:
    """:func:`prepare`'s closest-point tables: ``crow`` (for the closest point: a, ab, ac,
    g0, g1, n, iab, iac, ibc as rows), the dual basis, inverse squared edge lengths, boxes."""
    with np.errstate(divide="ignore", invalid="ignore"):
        dab = np.einsum("ij,ij->i", ab, ab)
        dac = np.einsum("ij,ij->i", ac, ac)
        dbc = np.einsum("ij,ij->i", bc, bc)
        x = np.einsum("ij,ij->i", ab, ac)
        det = dab * dac - x * x
        g0 = (dac[:, None] * ab - x[:, None] * ac) / det[:, None]
        g1 = (dab[:, None] * ac - x[:, None] * ab) / det[:, None]
        g0[flat] = 0.0
        g1[flat] = 0.0

        iab, iac, ibc = (np.where(v > 0, 1.0 / v, 0.0) for v in (dab, dac, dbc))
    crow = np.concatenate([a.T, ab.T, ac.T, g0.T, g1.T, n.T, np.stack([iab, iac, ibc])], axis=0)
    return {"a": a, "ab": ab, "ac": ac, "n": n, "crow": crow, "g0": g0, "g1": g1,
            "iab": iab, "iac": iac, "ibc": ibc, "flat": flat,
            "lo": np.minimum(np.minimum(a, b), c), "hi": np.maximum(np.maximum(a, b), c)}


def lower_bound_sq(x: np.ndarray, t: np.ndarray, tris: dict) -> np.ndarray:
    """A lower bound of the squared distance from points to triangles.

    Squared distance to the plane plus the largest over the edges of the
    squared in-plane distance to the edge's half-strip (inside the edge
    line, within the triangle's extent along the edge): exact where the
    closest point lies on the face or on an edge, and at the vertices of
    acute and right triangles; below it only near the vertices of obtuse
    triangles. 0 for flat triangles.

    Parameters
    ----------
    x : (n, 3) float64
    t : (n,) int
    tris : dict from :func:`prepare`

    Returns
    -------
    (n,) float64
    """
    s = np.einsum("nij,nj->ni", tris["w"][t], x) - tris["off"][t]
    return _bound_from_signed(s, tris["hw"][t])


def _corner_bounds(rows, base, half):
    """(8, p) lower bounds of the squared distance at the box's 8 corners.

    ``rows`` (31, p): the pairs' triangle rows (see :func:`prepare`),
    ``base`` (7, p) signed distances at the box centre, ``half`` (3,)
    half-extents; corner ``k`` is ``centre + _SIGNS[k] * half``. One corner
    at a time on contiguous (7, p) rows, small temporaries.
    """
    dx = rows[0:7] * half[0]
    dy = rows[7:14] * half[1]
    dz = rows[14:21] * half[2]
    hw = rows[28:31]
    plus, minus = dy + dz, dy - dz
    out = np.empty((8, base.shape[1]))
    v = np.empty_like(base)
    e = np.empty((3, base.shape[1]))
    f = np.empty_like(e)
    for k in range(8):
        # _SIGNS[k] = (+-1 by bit 0, bit 1, bit 2) for x, y, z.
        (np.add if k & 1 else np.subtract)(base, dx, out=v)
        if k & 2:
            v += plus if k & 4 else minus
        else:
            v -= minus if k & 4 else plus
        _strip_sq(v, hw, e, f)
        o = out[k]
        np.maximum(e[0], e[1], out=o)
        np.maximum(o, e[2], out=o)
        o += v[0] * v[0]
    return out


def _strip_sq(v, hw, e, f):
    """Per edge, the squared in-plane distance to its half-strip, into ``e`` (3, p).

    ``v`` (7, p) signed distances (plane, 3 edge lines, 3 along-edge from
    the extent's centre); ``hw`` (3, p) half-extents along the edges;
    ``f`` (3, p) scratch.
    """
    np.maximum(v[1:4], 0.0, out=e)
    e *= e
    np.abs(v[4:7], out=f)
    f -= hw
    np.maximum(f, 0.0, out=f)
    f *= f
    e += f


def _bound_from_signed(s, hw):
    """(…, 7) signed distances and (…, 3) half-widths -> (…) squared-distance lower bound."""
    e = np.maximum(s[..., 1:4], 0.0) ** 2 + np.maximum(np.abs(s[..., 4:7]) - hw, 0.0) ** 2
    return e.max(axis=-1) + np.square(s[..., 0])


def closest(x: np.ndarray, t: np.ndarray, tris: dict):
    """Exact closest points on triangles: squared distance and barycentrics.

    Parameters
    ----------
    x : (n, 3) float64
    t : (n,) int
    tris : dict from :func:`prepare`

    Returns
    -------
    d2 : (n,) float64
        Squared distance.
    uv : (n, 2) float64
        Weights of vertices 1 and 2 of the closest point (vertex 0 has
        ``1 - u - v``).
    """
    R = tris["crow"][:, t]  # (21, n): rows gathered once, then contiguous row arithmetic
    X = np.ascontiguousarray(x.T)
    ap = X - R[0:3]
    s = ap[0] * R[9] + ap[1] * R[10] + ap[2] * R[11]
    r = ap[0] * R[12] + ap[1] * R[13] + ap[2] * R[14]
    face = (s >= 0) & (r >= 0) & (s + r <= 1) & ~tris["flat"][t]
    # Face: distance to the plane (exactly |ap - s ab - r ac| up to rounding).
    h = ap[0] * R[15] + ap[1] * R[16] + ap[2] * R[17]
    d2 = h * h
    uv = np.empty((len(t), 2))
    uv[:, 0] = s
    uv[:, 1] = r
    out = np.flatnonzero(~face)
    if len(out):
        Ro = R[:, out]
        apo, ab, ac = ap[:, out], Ro[3:6], Ro[6:9]

        def segment(start, e, inv):
            # Closest point of the segment start + w e (w in [0, 1]) to the origin of start.
            w = np.clip((start[0] * e[0] + start[1] * e[1] + start[2] * e[2]) * inv, 0.0, 1.0)
            d = start - w * e
            return w, d[0] * d[0] + d[1] * d[1] + d[2] * d[2]

        # Otherwise the nearest of the three edges (segments).
        w1, best = segment(apo, ab, Ro[18])
        bu, bv = w1, np.zeros_like(w1)
        w2, d = segment(apo, ac, Ro[19])
        take = d < best
        best = np.where(take, d, best)
        bu = np.where(take, 0.0, bu)
        bv = np.where(take, w2, bv)
        w3, d = segment(apo - ab, ac - ab, Ro[20])
        take = d < best
        best = np.where(take, d, best)
        bu = np.where(take, 1.0 - w3, bu)
        bv = np.where(take, w3, bv)
        d2[out] = best
        uv[out, 0] = bu
        uv[out, 1] = bv
    return d2, uv


def pick(d2: np.ndarray, t: np.ndarray, point: np.ndarray, n: int, h: float) -> np.ndarray:
    """The tie rule: the winning candidate of each point.

    Parameters
    ----------
    d2 : (c,) float64
        Squared distances of the candidates.
    t : (c,) int
        Triangle of each candidate.
    point : (c,) int
        Point of each candidate, in ``range(n)``.
    n : int
        Number of points.
    h : float
        The voxel size ``TIE`` is measured in.

    Returns
    -------
    (k,) int64
        Index of each point's winner among the candidates (points without
        candidates have none): of those within ``TIE * h`` of the point's
        smallest distance, the one with the smallest triangle (the first
        such candidate).
    """
    d = np.sqrt(d2)
    low = np.full(n, np.inf)
    np.minimum.at(low, point, d)
    near = d <= low[point] + TIE * h
    big = np.iinfo(np.int64).max
    best_t = np.full(n, big)
    np.minimum.at(best_t, point, np.where(near, t, big))
    pos = np.full(n, len(d2))
    np.minimum.at(pos, point, np.where(near & (t == best_t[point]), np.arange(len(d2)), len(d2)))
    return pos[pos < len(d2)]


def brute_force(points: np.ndarray, tris: dict, h: float, block: int = 1 << 16):
    """Nearest triangle of each point over every triangle (the reference).

    Parameters
    ----------
    points : (n, 3) float64
        In the frame of ``tris``.
    tris : dict from :func:`prepare`
    h : float
        Voxel size for the tie rule.

    Returns
    -------
    tri : (n,) int64
    uv : (n, 2) float64
    """
    nt = len(tris["a"])
    out_t = np.empty(len(points), np.int64)
    out_uv = np.empty((len(points), 2))
    per = max(1, block // nt)
    for s in range(0, len(points), per):
        p = points[s:s + per]
        x = np.repeat(p, nt, axis=0)
        t = np.tile(np.arange(nt), len(p))
        d2, uv = closest(x, t, tris)
        w = pick(d2, t, np.repeat(np.arange(len(p)), nt), len(p), h)
        out_t[s:s + per] = t[w]
        out_uv[s:s + per] = uv[w]
    return out_t, out_uv


def _pyramid(occupancy: np.ndarray, levels: int) -> list:
    """``has[L]``: which cells of ``2**L`` voxels hold an inside voxel, for L = 0..levels.

    The grid is padded to a multiple of ``2**levels`` so every cell's
    children are cells of the level below.
    """
    s = 1 << levels
    shape = tuple(-(-n // s) * s for n in occupancy.shape)
    if shape == occupancy.shape:
        level = occupancy
    else:
        level = np.zeros(shape, bool)
        level[tuple(slice(0, n) for n in occupancy.shape)] = occupancy
    has = [level]
    for _ in range(levels):
        nx, ny, nz = (n // 2 for n in level.shape)
        level = level.reshape(nx, 2, ny, 2, nz, 2).any(axis=(1, 3, 5))
        has.append(level)
    return has


def _cell_chunks(pc):
    """``(start, end)`` slices of the sorted cells ``pc``: about ``CHUNK`` long, whole cells.

    A voxel's candidates must all be settled together (the tie rule and
    the bound from the first measured one see all of them), and one cell
    can hold more than ``CHUNK`` pairs.
    """
    s = 0
    while s < len(pc):
        e = s + CHUNK
        if e < len(pc):
            e = int(np.searchsorted(pc, pc[e], side="left"))
            if e == s:
                e = int(np.searchsorted(pc, pc[s], side="right"))
        yield s, min(e, len(pc))
        s = e


class _Search:
    """The branch and bound over one block's inside voxels (see the module notes)."""

    def __init__(self, tris, occupancy, spacing, z0, levels, emit, same=None, pyramid=True):
        self.tris = tris
        n = len(tris["a"])
        self.same = np.full(n, -1, np.int64) if same is None else np.asarray(same, np.int64)
        self.any_same = bool((self.same >= 0).any())
        self.h = np.asarray(spacing, float)
        self.hmin = float(self.h.min())
        self.z0 = int(z0)
        self.levels = levels
        # The compiled kernel finds inside cells itself (pyramid=False).
        self.has = _pyramid(occupancy, levels) if pyramid else None
        self.emit = emit
        self.m = MARGIN * self.hmin

    def centres(self, cells, level):
        """(m, 3) float64 centre of each cell's box of voxel centres (frame coordinates)."""
        s = 1 << level
        c = cells * s + (s / 2.0)
        c = c.astype(float)
        c[:, 2] += self.z0
        return c * self.h

    def top(self, cells):
        """(cell, triangle) pairs for top cells: triangles whose box is within reach."""
        L = self.levels
        half = ((1 << L) - 1) / 2.0 * self.h
        centre = self.centres(cells, L)
        if not hasattr(self, "_cl"):
            self._clusters()
        v = self.start_points(centre)
        corners = centre[:, None, :] + _SIGNS * half
        reach = np.sqrt(np.max(np.sum((corners - v[:, None, :]) ** 2, axis=2), axis=1)) + self.m
        lo, hi = centre - half, centre + half
        pcs, pts = [], []
        clo, chi, members, cstart = self._cl
        per = max(1, CHUNK // len(clo))
        for s in range(0, len(cells), per):
            e = min(s + per, len(cells))
            gap = np.maximum(np.maximum(clo[None] - hi[s:e, None], lo[s:e, None] - chi[None]), 0)
            near = np.einsum("ijk,ijk->ij", gap, gap) <= reach[s:e, None] ** 2
            ci, cl = np.nonzero(near)
            # Expand the clusters to their triangles, then test each triangle's box.
            n = cstart[cl + 1] - cstart[cl]
            rep = np.repeat(np.arange(len(ci)), n)
            local = np.arange(len(rep)) - np.repeat(np.cumsum(n) - n, n)
            t = members[cstart[cl][rep] + local]
            c = ci[rep] + s
            gap = np.maximum(np.maximum(self.tris["lo"][t] - hi[c], lo[c] - self.tris["hi"][t]), 0)
            ok = np.einsum("ij,ij->i", gap, gap) <= reach[c] ** 2
            pcs.append(c[ok])
            pts.append(t[ok])
        return np.concatenate(pcs), np.concatenate(pts)

    def start_points(self, centre):
        """(m, 3) a surface point near each centre: the nearest of a sample of vertices.

        Any surface point gives valid bounds; a near one gives tight ones.
        """
        rep = self._rep
        best = np.full(len(centre), np.inf)
        out = np.zeros((len(centre), 3))
        per = max(1, CHUNK // len(rep))
        for s in range(0, len(centre), per):
            d = np.sum((centre[s:s + per, None, :] - rep[None]) ** 2, axis=2)
            i = d.argmin(axis=1)
            best[s:s + per] = d[np.arange(len(i)), i]
            out[s:s + per] = rep[i]
        return out

    def _clusters(self):
        """Triangles grouped ``CLUSTER`` at a time in Morton order of their centres, with boxes."""
        lo, hi = self.tris["lo"], self.tris["hi"]
        mid = (lo + hi) / 2
        span = mid.max(axis=0) - mid.min(axis=0)
        q = ((mid - mid.min(axis=0)) / np.where(span > 0, span, 1) * 1023).astype(np.int64)
        code = np.zeros(len(q), np.int64)
        for bit in range(10):
            for a in range(3):
                code |= ((q[:, a] >> bit) & 1) << (3 * bit + a)
        members = np.argsort(code, kind="stable")
        cstart = np.r_[np.arange(0, len(members), CLUSTER), len(members)]
        clo = np.minimum.reduceat(lo[members], cstart[:-1], axis=0)
        chi = np.maximum.reduceat(hi[members], cstart[:-1], axis=0)
        self._cl = (clo, chi, members, cstart)
        # Start points: a vertex of every eighth triangle in Morton order.
        self._rep = self.tris["a"][members[::8]]

    def prune(self, cells, level, pc, pt, near):
        """Drop the pairs a surface point dominates over their cell.

        Parameters
        ----------
        cells : (m, 3) int64
            Cells at ``level``.
        pc, pt : (p,) int64
            The pairs: cell (ascending) and triangle.
        near : (m, 3) float64
            A surface point near each cell (its parent's).

        Returns
        -------
        keep : (p,) bool
        near : (m, 3) float64
            The surface point nearest each cell's centre among its
            candidates (or the one given, where none is nearer).
        """
        keep = np.empty(len(pc), bool)
        near = near.copy()
        half = ((1 << level) - 1) / 2.0 * self.h
        for s in range(0, len(pc), CHUNK):
            c, t = pc[s:s + CHUNK], pt[s:s + CHUNK]
            cu, group, w, base, p, r2 = self._surface_point(cells, level, c, t, near)
            r = np.sqrt(r2.max(axis=1))
            thresh = 2 * self.m * r + self.m * self.m
            low = _corner_bounds(w, base, half)
            low -= r2.T[:, group]
            keep[s:s + CHUNK] = low.min(axis=0) <= thresh[group]
        return keep, near

    def _surface_point(self, cells, level, c, t, near, search=True):
        """A chunk's pairs: signed distances at the cell centres, and each cell's surface point.

        Returns the chunk's cells ``cu`` (g,), each pair's ``group`` (p,),
        the pairs' triangle rows ``w`` (31, p) (see :func:`prepare`), the
        signed distances at the centres ``base`` (7, p), the surface points ``p`` (g, 3)
        (also written into ``near``) and the squared distances ``r2``
        (g, 8) from each cell's corners to its point. Without ``search``,
        the point given in ``near`` is kept.
        """
        tris = self.tris
        first = np.flatnonzero(np.r_[True, c[1:] != c[:-1]])
        cu = c[first]
        centre = self.centres(cells[cu], level)
        group = np.repeat(np.arange(len(first)), np.diff(np.r_[first, len(c)]))
        w = tris["rows"][:, t]  # (31, p)
        cg = centre[group]
        base = w[0:7] * cg[:, 0]
        base += w[7:14] * cg[:, 1]
        base += w[14:21] * cg[:, 2]
        base -= w[21:28]  # (7, p)
        # The nearest surface point to the centre: only candidates whose
        # bound there beats the given point can be nearer.
        p = near[cu]
        best = np.sum((centre - p) ** 2, axis=1) if search else None
        try_ = ()
        if search:
            e = np.empty((3, len(c)))
            _strip_sq(base, w[28:31], e, np.empty_like(e))
            low = np.maximum(e[0], e[1], out=e[0])
            np.maximum(low, e[2], out=low)
            low += base[0] * base[0]
            try_ = np.flatnonzero(low < best[group])
        if len(try_):
            g = group[try_]
            d2, uv = closest(centre[g], t[try_], tris)
            low = np.full(len(first), np.inf)
            np.minimum.at(low, g, d2)
            win = d2 == low[g]
            win &= d2 < best[g]
            gw, tw, uvw = g[win], t[try_[win]], uv[win]
            p[gw] = tris["a"][tw] + uvw[:, :1] * tris["ab"][tw] + uvw[:, 1:] * tris["ac"][tw]
            near[cu] = p
        half = ((1 << level) - 1) / 2.0 * self.h
        corners = centre[:, None, :] + _SIGNS * half
        r2 = np.sum((corners - p[:, None, :]) ** 2, axis=2)
        return cu, group, w, base, p, r2

    def bottom(self, cells, pc, pt, near):
        """Cells of 2 voxels a side: their corners are the voxel centres.

        The corner bounds are the voxels' own bounds, so each voxel keeps
        the candidates whose bound beats the cell's surface point, then
        the exact closest point on the one with the lowest bound settles
        which others need measuring exactly.
        """
        half = 0.5 * self.h
        offs = ((_SIGNS + 1) // 2).astype(np.int64)  # corner k -> voxel offset
        for s, e in _cell_chunks(pc):
            c, t = pc[s:e], pt[s:e]
            cu, group, w, base, p, r2 = self._surface_point(cells, 1, c, t, near, search=False)
            vox = cells[cu][:, None, :] * 2 + offs  # (g, 8, 3)
            inside = self.has[0][vox[..., 0], vox[..., 1], vox[..., 2]]
            limit = r2 + self._slack(r2)
            limit[~inside] = -1.0
            low = _corner_bounds(w, base, half)  # (8, p)
            k, j = np.nonzero(low <= limit.T[:, group])
            vid = group[j] * 8 + k  # voxel of the chunk
            self._settle_voxels(vox.reshape(-1, 3), vid, t[j], low[k, j])

    def _settle_voxels(self, vox, vid, t, low):
        """Exact nearest among each voxel's candidates (``vid`` indexes ``vox``).

        The candidate with the lowest bound is measured, then every other
        one whose bound is within the slack of its distance (so every one
        within ``TIE`` of the nearest). The half-strip bound is exact except
        near obtuse corners, so this measures about as many as tie: 1.20 per
        inside voxel on spot at 128³ for 1.17 tied, where the edge-line
        bound alone measured 4.7 (measuring in ascending bound order with a
        running minimum then still measured 4.0, and its sort cost more than
        it saved once the bound was tight).
        """
        n = len(vox)
        x = self.centres(vox, 0)
        least = np.full(n, np.inf)
        np.minimum.at(least, vid, low)
        pos = np.arange(len(vid))
        first = np.full(n, len(vid))
        np.minimum.at(first, vid, np.where(low <= least[vid], pos, len(vid)))
        has = np.flatnonzero(first < len(vid))
        f = first[has]
        d2f, uvf = closest(x[has], t[f], self.tris)
        bound = np.full(n, -1.0)
        bound[has] = d2f + self._slack(d2f)
        rest = low <= bound[vid]
        rest[f] = False  # measured already
        rest = np.flatnonzero(rest)
        d2, uv = closest(x[vid[rest]], t[rest], self.tris)
        # Candidate order (voxel, then as listed) is kept: the tie rule
        # looks at triangle indices only.
        vid, t = np.r_[vid[f], vid[rest]], np.r_[t[f], t[rest]]
        d2, uv = np.r_[d2f, d2], np.r_[uvf, uv]
        w = pick(d2, t, vid, n, self.hmin)
        self.emit(vox[vid[w]], t[w], uv[w])

    def descend(self, cells, level, pc, pt, near):
        """Prune the pairs of ``cells`` at ``level``, then go down, chunk by chunk."""
        if level == 1:
            self.bottom(cells, pc, pt, near)
            return
        keep, near = self.prune(cells, level, pc, pt, near)
        pc, pt = pc[keep], pt[keep]
        pc, pt = self.settle(cells, level, pc, pt)
        # Children that hold inside voxels, per cell.
        kids = cells[:, None, :] * 2 + ((_SIGNS + 1) // 2).astype(np.int64)  # (m, 8, 3)
        below = self.has[level - 1]
        inside = below[kids[..., 0], kids[..., 1], kids[..., 2]]
        nkid = inside.sum(axis=1)
        npair = np.bincount(pc, minlength=len(cells))
        work = nkid * npair
        # Groups of whole cells with at most CHUNK child pairs (or one cell).
        ends = np.cumsum(work)
        s = 0
        while s < len(cells):
            e = int(np.searchsorted(ends, (ends[s - 1] if s else 0) + CHUNK, side="right"))
            e = max(e, s + 1)
            self._children(cells[s:e], kids[s:e], inside[s:e], level - 1, pc, pt, s, e,
                           near[s:e])
            s = e

    def settle(self, cells, level, pc, pt):
        """Finish the cells whose answer is known; return the other cells' pairs.

        A cell with one candidate left: every voxel's nearest triangle is it
        (only the closest point remains to find). A cell whose candidates
        all have the same ``same`` key (>= 0): every voxel takes that
        colour, reported as the first such triangle with ``uv = 0``.
        """
        if len(pc) == 0:
            return pc, pt
        first = np.flatnonzero(np.r_[True, pc[1:] != pc[:-1]])
        count = np.diff(np.r_[first, len(pc)])
        done = count == 1
        key = self.same[pt]
        if self.any_same:
            k_lo = np.minimum.reduceat(key, first)
            k_hi = np.maximum.reduceat(key, first)
            same = (k_lo == k_hi) & (k_lo >= 0)
        else:
            same = np.zeros(len(first), bool)
        done |= same
        if not done.any():
            return pc, pt
        which = first[done]
        cell, tri, flat = pc[which], pt[which], same[done]
        # The inside voxels of those cells, a bounded number at a time.
        s = 1 << level
        offs = np.stack(np.meshgrid(*[np.arange(s)] * 3, indexing="ij"), -1).reshape(-1, 3)
        per = max(1, CHUNK // len(offs))
        for a in range(0, len(cell), per):
            vox = (cells[cell[a:a + per], None, :] * s + offs).reshape(-1, 3)
            t = np.repeat(tri[a:a + per], len(offs))
            f = np.repeat(flat[a:a + per], len(offs))
            ok = self.has[0][vox[:, 0], vox[:, 1], vox[:, 2]]
            vox, t, f = vox[ok], t[ok], f[ok]
            uv = np.zeros((len(t), 2))
            need = np.flatnonzero(~f)
            if len(need):
                uv[need] = closest(self.centres(vox[need], 0), t[need], self.tris)[1]
            self.emit(vox, t, uv)
        rest = np.repeat(~done, count)
        return pc[rest], pt[rest]

    def _children(self, cells, kids, inside, below, pc, pt, s, e, near):
        lo, hi = np.searchsorted(pc, [s, e])
        c, t = pc[lo:hi] - s, pt[lo:hi]
        kid_cells = kids[inside]  # (k, 3), cell-major
        nkid = inside.sum(axis=1)
        kid_near = np.repeat(near, nkid, axis=0)
        kid_start = np.r_[0, np.cumsum(nkid)]
        npair = np.bincount(c, minlength=len(cells))
        pair_start = np.r_[0, np.cumsum(npair)]
        count = nkid * npair
        total = int(count.sum())
        if total == 0:
            return
        parent = np.repeat(np.arange(len(cells)), count)
        local = np.arange(total) - np.repeat(np.cumsum(count) - count, count)
        np_ = npair[parent]
        child = kid_start[parent] + local // np_
        tri = t[pair_start[parent] + local % np_]
        self.descend(kid_cells, below, child, tri, kid_near)

    def _slack(self, d2):
        """What a squared distance ``d2`` may be exceeded by within MARGIN: 2 m d + m^2."""
        return 2 * self.m * np.sqrt(d2) + self.m * self.m


def kernel_module():
    """The compiled kernel (``geovox._nearest``), or None for the NumPy search.

    As the running conversion's kernel choice says (:attr:`Options.kernel
    <geovox.Options.kernel>`; see :func:`geovox.kernels.compiled`): ``auto``
    uses the compiled one where it was built (see setup.py).

    Raises
    ------
    ParameterError
        An unknown choice, or ``compiled`` where it was not built.
    """
    return compiled("_nearest", "nearest-surface")


def _kernel_tables(triangles, origin) -> tuple:
    """The compiled kernel's triangle rows, zero-area flags and cluster arrays (see run_kernel)."""
    tris = prepare(np.asarray(triangles, float), origin)
    search = _Search(tris, None, np.ones(3), 0, 3, None, pyramid=False)
    search._clusters()  # depends on the triangles alone
    clo, chi, members, cstart = search._cl
    c3 = np.ascontiguousarray
    return (c3(tris["crow"].T), tris["flat"].view(np.uint8),
            (c3(tris["lo"]), c3(tris["hi"]), c3(clo), c3(chi), c3(members, np.int64),
             c3(cstart, np.int64), c3(search._rep)))


def kernel_tables(triangles, origin, cache=None) -> tuple:
    """The compiled kernel's triangle tables in the frame of ``origin``, kept in ``cache``.

    ``(rows, flat, clusters)``: see :func:`run_kernel`; ``clusters[0]`` and
    ``clusters[1]`` are the triangles' boxes (t, 3).
    """
    key = ("nearest-kernel", np.asarray(origin, float).tobytes())
    tables = cache.get(key) if cache is not None else None
    if tables is None:
        tables = _kernel_tables(triangles, origin)
        if cache is not None:
            cache[key] = tables
    return tables


def band_tables(triangles, origin, cache=None) -> tuple:
    """``(rows, flat, lo, hi)``: the band engine's triangle tables, kept in ``cache``.

    The rows of :func:`prepare` (``crow``), zero-area flags and boxes; the
    search's own tables where ``cache`` holds them already, else only what
    the closest point needs (no bounds, no clusters).
    """
    full = cache.get(("nearest-kernel", np.asarray(origin, float).tobytes())) \
        if cache is not None else None
    if full is not None:
        rows, flat, clusters = full
        return rows, flat, clusters[0], clusters[1]
    key = ("band-kernel", np.asarray(origin, float).tobytes())
    tables = cache.get(key) if cache is not None else None
    if tables is None:
        tris = prepare(np.asarray(triangles, float), origin, closest_only=True)
        c3 = np.ascontiguousarray
        tables = (c3(tris["crow"].T), tris["flat"].view(np.uint8), c3(tris["lo"]),
                  c3(tris["hi"]))
        if cache is not None:
            cache[key] = tables
    return tables


def run_kernel(module, triangles, occupancy, spacing, *, origin, z0=0, jobs=1, output,
               cache=None):
    """The compiled search over one block (same answers as :func:`nearest_inside`'s NumPy one).

    Parameters
    ----------
    module : the compiled module (from :func:`kernel_module`)
    triangles, occupancy, spacing, origin, z0, jobs
        As for :func:`nearest_inside`.
    output : callable
        ``output(kernel)`` sets where the answers go: ``kernel.raw_output``
        or ``kernel.colour_output`` (see ``geovox/_nearest.pyx``).
    cache : dict, optional
        Where the per-triangle tables are kept for the next block of the same
        triangles and frame (a mesh's own cache: the slabs of a grid share
        them; spot at 1024³, 16 slabs, computed them 16 times).
    """
    occupancy = np.asarray(occupancy, bool)
    if not occupancy.any() or len(triangles) == 0:
        return
    shape = occupancy.shape
    occ = occupancy.reshape(-1, order="F")  # a view when F-contiguous, as the pipeline's are
    occ = np.ascontiguousarray(occ).view(np.uint8)
    origin = np.asarray(origin, float)
    rows, flat, clusters = kernel_tables(triangles, origin, cache)
    spacing = np.asarray(spacing, float)
    hmin = float(spacing.min())
    levels = max(3, int(np.ceil(np.log2(max(shape) / 16.0))))
    kernel = module.Kernel(rows, flat, occ, shape, int(z0), tuple(float(h) for h in spacing),
                           MARGIN * hmin, TIE * hmin)
    output(kernel)
    kernel.clusters(*clusters)
    jobs = openmp_threads(jobs)
    cells = np.argwhere(module.top_cells(occ, shape, levels, jobs)).astype(np.int64)
    kernel.run(np.ascontiguousarray(cells), levels, jobs)


def nearest_inside(triangles, occupancy, spacing, *, origin, z0=0, jobs=1, emit, same=None):
    """Exact nearest triangle and closest-point barycentrics of every inside voxel.

    Parameters
    ----------
    triangles : (t, 3, 3) float64
    occupancy : (nx, ny, nz) bool
        The block's inside voxels.
    spacing : (3,) float64
        The whole grid's voxel size.
    origin : (3,) float64
        The whole grid's low corner; voxel ``(i, j, k)`` of the block has
        its centre at ``origin + ((i, j, k + z0) + 0.5) * spacing``.
    z0 : int
        The block's first layer in the whole grid.
    jobs : int
        Threads; the result does not depend on it.
    emit : callable
        Called as ``emit(voxels, triangle, uv)`` for disjoint sets of inside
        voxels (possibly from several threads at once): ``voxels`` (n, 3)
        int64 block indices, ``triangle`` (n,) int64, ``uv`` (n, 2) float64.
    same : (t,) int, optional
        Triangles with the same key >= 0 are interchangeable (the same
        constant colour): where every candidate of a cell shares a key, its
        voxels are reported with the first such triangle and ``uv = 0``
        without finding which one is nearest (NumPy search only: the
        compiled one answers here with the nearest triangles, and skips
        such cells only when it shades, see ``Kernel.same_colours``).
        Default: all distinct.

    The search is the compiled one or the NumPy one as the running
    conversion's kernel choice says (:func:`kernel_module`); the answers are
    the same. The compiled one answers into arrays over the whole block (20
    bytes a voxel) before calling ``emit``; the colour step does not use this
    function with it (it shades in the kernel, see
    :func:`geovox.colour.exact_colours`).
    """
    from ..parallel import for_blocks

    occupancy = np.asarray(occupancy, bool)
    if not occupancy.any() or len(triangles) == 0:
        return
    module = kernel_module()
    if module is not None:
        n = occupancy.size
        tri = np.full(n, -1, np.int32)
        uv = np.zeros((n, 2))
        run_kernel(module, triangles, occupancy, spacing, origin=origin, z0=z0, jobs=jobs,
                   output=lambda k: k.raw_output(tri, uv))
        inside = np.flatnonzero(occupancy.reshape(-1, order="F"))
        for s in range(0, len(inside), CHUNK):
            lin = inside[s:s + CHUNK]
            vox = np.stack(np.unravel_index(lin, occupancy.shape, order="F"), axis=1)
            emit(vox, tri[lin].astype(np.int64), uv[lin])
        return
    origin = np.asarray(origin, float)
    tris = prepare(np.asarray(triangles, float), origin)
    # Top cells about 16 to a side of the grid (at least 2 voxels).
    levels = max(3, int(np.ceil(np.log2(max(occupancy.shape) / 16.0))))
    search = _Search(tris, occupancy, spacing, z0, levels, emit, same)
    cells = np.argwhere(search.has[levels])
    search.top(cells[:1])  # builds the shared clusters once, before the threads
    parts = max(1, min(len(cells), 4 * jobs))
    step = -(-len(cells) // parts)

    # Top cells a few at a time: a deep cell of a big mesh can keep most
    # triangles, so this bounds the first pair arrays (about 16 bytes a pair).
    batch = max(1, TOP_PAIRS // len(triangles))

    def run(s, e):
        for a in range(s, e, batch):
            sub = cells[a:min(a + batch, e)]
            pc, pt = search.top(sub)
            order = np.argsort(pc, kind="stable")
            near = search.start_points(search.centres(sub, levels))
            search.descend(sub, levels, pc[order], pt[order], near)

    for_blocks(run, len(cells), step, jobs)
