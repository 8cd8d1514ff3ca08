"""Embree backend: embreex through trimesh's ray module finds the candidates.

Embree traces in float32, and a multi-hit loop that restarts each ray just
past its last hit reports a crossing twice, or not at all, where a ray runs
through an edge or vertex shared by several triangles (trimesh's own loop
does exactly that). So Embree is used here only to *find* which triangles
each ray meets; every decision is settled by the exact shared predicate in
:mod:`geovox.exact`:

1. Multi-hit loop with :meth:`RayMeshIntersector.intersects_first`, each ray
   restarted a small step past its last hit (in a centred, scaled copy of
   the mesh so float32 keeps its precision).
2. Every reported pair is tested exactly. Where Embree's answer could be
   wrong -- the exact test rejects it, or the ray passes within a hair of an
   edge -- every triangle sharing a vertex with the reported one is tested
   too, which recovers the neighbours a restart skipped.
3. Triangles that overlap another one in (nearly) the same plane -- duplicated
   faces, coincident faces of touching parts, folds -- or touch it without
   sharing a vertex (T-junctions) would hide each other from a restart that
   steps past the first: their crossings are found by the exact rasteriser
   instead of by Embree. Pieces of a flat region that meet only at shared
   vertices and edges are left to step 2. Only pairs that a ray of the
   lattice being cast can see are settled, and the scene holds only the
   triangles its rays pass near when they are few: both are set up once per
   lattice (:meth:`EmbreeBackend.setup`), so a coarse grid pays for the few
   triangles it meets, not for the whole mesh.
4. A ray with an odd number of exact crossings (impossible on a closed mesh
   when no crossing was lost), or one that ran out of restarts, is redone by
   the exact NumPy rasteriser.

The result equals the NumPy backend's whenever step 1 meets each crossing or
one of its vertex neighbours; the remaining exception would need two
crossings of unrelated, non-coplanar triangles closer together than the
restart step (1e-6 of the mesh size) on the same ray, twice.
"""

from __future__ import annotations

import threading

import numpy as np

from ..exact import Projection
from ..grid import Columns
from .base import Backend, Hits
from .numpy import rasterise

#: Restart step past a hit, as a fraction of the mesh's bounding-box diagonal.
STEP = 1e-6
#: Rays closer than this to an edge (in columns, or in 1e-5 mesh sizes,
#: whichever is larger) have their hit's vertex neighbours tested exactly.
NEAR_EDGE = 1e-3
#: Restarts per ray before the ray is handed to the exact rasteriser.
MAX_RESTARTS = 2000
#: A lattice whose rays can meet at most this share of the mesh's triangles
#: gets a scene of those alone (see :meth:`EmbreeBackend.setup`).
SUBSET_SCENE = 0.75
#: Per-lattice set-ups kept with a mesh (one per axis of a colour run).
KEEP_LATTICES = 3

_SETUP_LOCK = threading.Lock()


def _vertex_faces(geometric_faces: np.ndarray):
    """CSR map vertex -> faces using it: ``(offsets, faces)``."""
    flat = geometric_faces.reshape(-1)
    order = np.argsort(flat, kind="stable")
    faces = order // 3
    counts = np.bincount(flat, minlength=int(flat.max()) + 1)
    offsets = np.r_[0, np.cumsum(counts)]
    return offsets, faces


def _expand(ray, tri, geometric_faces, offsets, vfaces):
    """All (ray, face) pairs where face shares a vertex with tri."""
    verts = geometric_faces[tri].reshape(-1)  # (3n,)
    rays3 = np.repeat(ray, 3)
    n = offsets[verts + 1] - offsets[verts]
    r = np.repeat(rays3, n)
    start = np.repeat(offsets[verts], n)
    local = np.arange(int(n.sum()), dtype=np.int64) - np.repeat(np.cumsum(n) - n, n)
    return r, vfaces[start + local]


#: Candidate pairs generated and tested at a time (bounds the memory of the
#: coplanar check; a flat fan of N triangles all meeting at its hub has
#: about N^2 / 2 of them).
PAIR_CHUNK = 1 << 19


#: A lattice whose triangles' boxes hold at most this many column centres
#: per triangle (plus 100 k) is paired ray by ray, a finer one by boxes (see
#: :func:`coplanar_overlaps`).
COLUMN_ENTRIES = 8


#: Meshes of at most this many triangles have every pair settled, for
#: every lattice at once (see :func:`_check`).
FEW = 32


#: Boxes in one hash cell beyond which the cell's boxes are reported as
#: crowded instead of paired (see :func:`box_pair_chunks`).
MAX_RUN = 1024


def box_pair_chunks(lo: np.ndarray, hi: np.ndarray, tol: float = 0.0, chunk: int = PAIR_CHUNK,
                    crowded: list | None = None):
    """Yield ``(k, 2)`` arrays of index pairs ``a < b`` whose axis-aligned boxes overlap.

    A uniform grid hash: each box is entered in the cells it covers and only
    boxes sharing a cell are compared, so large flat regions made of many
    triangles cost in proportion to their neighbourhoods, not to the square
    of their size. The cell is about the median box size, grown while a few
    huge boxes would fill too many cells. Pairs are generated at most
    ``chunk`` at a time; each overlapping pair appears exactly once.

    Parameters
    ----------
    lo, hi : (n, 3) float ndarray
        Box corners; boxes within ``tol`` of each other count as overlapping.
    crowded : list, optional
        If given, a cell holding more than ``MAX_RUN`` boxes (the hub of a
        big flat fan, where every box meets every other) is not paired: the
        indices of its boxes are appended to this list instead, as one array.
    """
    n = len(lo)
    if n < 2:
        return
    lo = lo - tol
    hi = hi + tol
    base = lo.min(axis=0)
    extent = hi - lo
    cell = max(float(np.median(extent.max(axis=1))), float(extent.max()) * 1e-3, 1e-300)
    while True:
        c0 = ((lo - base) / cell).astype(np.int64)  # floor: the values are >= 0
        c1 = ((hi - base) / cell).astype(np.int64)
        ext = c1 - c0 + 1
        count = ext[:, 0] * ext[:, 1] * ext[:, 2]
        if count.sum() <= 16 * n + 100_000:
            break
        cell *= 2.0
    dims = c1.max(axis=0) + 1
    # (box, cell) entries: each box's covered cells, enumerated in x, y, z.
    box = np.repeat(np.arange(n), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    ex, ey = ext[box, 0], ext[box, 1]
    ix = local % ex
    local //= ex
    iy = local % ey
    iz = local // ey
    key = ((c0[box, 2] + iz) * dims[1] + c0[box, 1] + iy) * dims[0] + c0[box, 0] + ix
    # A pair of boxes shares every cell of the intersection of their cell
    # ranges; it is kept in one: the low corner of that intersection, where
    # along each axis one of the two boxes begins. Each entry notes along
    # which axes its box begins in its cell (bits x, y, z), so the test is
    # one OR of two bytes, before any coordinate is read: most candidate
    # pairs are such repeats.
    begins = ((ix == 0) | ((iy == 0) << 1) | ((iz == 0) << 2)).astype(np.uint8)
    if int(dims.prod()) < 2**31:
        key = key.astype(np.int32)
    order = np.argsort(key, kind="stable")
    # 32-bit entry and box numbers where they fit: less memory to stream.
    idx = np.int32 if len(key) < 2**31 - chunk else np.int64
    key, box, begins = key[order], box[order].astype(idx), begins[order]
    # All pairs within each cell: entry p pairs with the later entries of its run.
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    run = np.diff(np.r_[start, len(key)])
    later = np.repeat(start + run, run) - np.arange(len(key)) - 1
    if crowded is not None:
        full = np.repeat(run > MAX_RUN, run)
        if full.any():
            crowded.append(np.unique(box[full]))
            later[full] = 0
    cols = [(np.ascontiguousarray(lo[:, i]), np.ascontiguousarray(hi[:, i])) for i in range(3)]
    ends = np.cumsum(later)
    e0 = 0
    while e0 < len(key):
        # Entries e0 .. e1 give at most `chunk` pairs (or one entry's worth).
        e1 = max(e0 + 1, int(np.searchsorted(ends, (ends[e0 - 1] if e0 else 0) + chunk, "right")))
        lat = later[e0:e1]
        first = np.repeat(np.arange(e0, e1, dtype=idx), lat)
        second = np.arange(int(lat.sum()), dtype=idx) - np.repeat(
            (np.cumsum(lat) - lat - np.arange(e0 + 1, e1 + 1)).astype(idx), lat)
        e0 = e1
        once = (begins[first] | begins[second]) == 7
        a, b = box[first[once]], box[second[once]]
        for l, h in cols:  # one axis at a time: 1-D gathers, fewer pairs each time
            keep = (l[a] <= h[b]) & (l[b] <= h[a])
            a, b = a[keep], b[keep]
        if len(a):
            yield np.column_stack([np.minimum(a, b), np.maximum(a, b)])


def _separation(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Signed 2-D separation of triangle pairs (separating-axis theorem).

    ``p``, ``q``: (k, 3, 2). Positive: the gap between them; negative: how
    deep their interiors overlap; zero: touching.
    """
    px, py = [p[:, i, 0] for i in range(3)], [p[:, i, 1] for i in range(3)]
    qx, qy = [q[:, i, 0] for i in range(3)], [q[:, i, 1] for i in range(3)]
    sep = np.full(len(p), -np.inf)
    for tx, ty in ((px, py), (qx, qy)):
        for i in range(3):
            ax, ay = ty[i] - ty[(i + 1) % 3], tx[(i + 1) % 3] - tx[i]  # edge normal
            length = np.hypot(ax, ay)
            good = length > 0
            ax, ay = ax / np.where(good, length, 1.0), ay / np.where(good, length, 1.0)
            sp = [px[v] * ax + py[v] * ay for v in range(3)]
            sq = [qx[v] * ax + qy[v] * ay for v in range(3)]
            gap = np.maximum(np.minimum(np.minimum(sq[0], sq[1]), sq[2])
                             - np.maximum(np.maximum(sp[0], sp[1]), sp[2]),
                             np.minimum(np.minimum(sp[0], sp[1]), sp[2])
                             - np.maximum(np.maximum(sq[0], sq[1]), sq[2]))
            np.maximum(sep, np.where(good, gap, -np.inf), out=sep)
    return sep


def _normals(mesh) -> np.ndarray:
    """(m, 3) float64: ``(v1 - v0) x (v2 - v0)`` per face, kept with the mesh."""
    if "normals" not in mesh._cache:
        t = mesh.triangles
        mesh._cache["normals"] = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return mesh._cache["normals"]


#: How far (as a fraction of the mesh size) a triangle's bounding box is
#: grown when deciding which column rays can meet it: a hundred times
#: Embree's float32 error on the scaled mesh (about 1e-7 of its size), so no
#: ray that Embree could report on a triangle is left out.
REACH = 1e-5


def _coords(mesh, axis: int):
    """The triangles' vertex coordinates along ``axis``: three (m,) float64 arrays."""
    x = np.ascontiguousarray(mesh.vertices[:, axis])
    f = mesh.faces
    return x[f[:, 0]], x[f[:, 1]], x[f[:, 2]]


def _extent(mesh, axis: int):
    """(lo, hi): each triangle's smallest and largest coordinate along ``axis``, (m,) float64."""
    x0, x1, x2 = _coords(mesh, axis)
    return np.minimum(np.minimum(x0, x1), x2), np.maximum(np.maximum(x0, x1), x2)


def reach(mesh, columns: Columns):
    """Column rays each triangle can meet: its box grown by ``REACH``.

    Returns
    -------
    i0, i1, j0, j1 : (m,) int64
        Inclusive ranges of column indices whose centres lie in the grown box
        (clipped to the lattice); empty (``i0 > i1`` or ``j0 > j1``) where
        no ray of this lattice comes near the triangle.
    """
    pad = REACH * mesh.scale
    out = []
    for ax, o, d, n in ((columns.u_axis, columns.u0, columns.du, columns.nu),
                        (columns.v_axis, columns.v0, columns.dv, columns.nv)):
        lo, hi = _extent(mesh, ax)
        # Column i's centre is at o + (i + 0.5) d. Clipped as floats, so
        # that a far-away triangle's huge quotient never reaches the cast.
        with np.errstate(over="ignore"):
            first = np.ceil((lo - pad - o) / d - 0.5)
            last = np.floor((hi + pad - o) / d - 0.5)
        out.append(np.minimum(np.maximum(first, 0.0), float(n)).astype(np.int64))
        out.append(np.minimum(np.maximum(last, -1.0), float(n - 1)).astype(np.int64))
    return out[0], out[1], out[2], out[3]


def _column_entries(mesh, columns, ranges, ok):
    """(triangle, column) entries: each triangle of ``ok`` with each column
    centre that lies within ``REACH`` of it across the rays.

    Returns ``(tri, col)``: (e,) int64 arrays, ``tri`` indexing ``ok``,
    ``col`` the ray ``i + nu * j``.
    """
    i0, i1, j0, j1 = (r[ok] for r in ranges)
    ci, cj = i1 - i0 + 1, j1 - j0 + 1
    count = ci * cj
    k = np.repeat(np.arange(len(ok)), count)
    local = np.arange(len(k)) - np.repeat(np.cumsum(count) - count, count)
    cik = ci[k]
    row = local // cik
    ii = i0[k] + local - row * cik
    jj = j0[k] + row
    # Keep the column centres within the triangle grown by the reach: each
    # edge line's signed distance above -pad, in column units (a disc of
    # radius REACH across the rays lies within pad = REACH / min(du, dv)
    # of its centre there, whatever the voxels' shape).
    u = [(x[ok] - columns.u0) / columns.du - 0.5 for x in _coords(mesh, columns.u_axis)]
    w = [(x[ok] - columns.v0) / columns.dv - 0.5 for x in _coords(mesh, columns.v_axis)]
    area = (u[1] - u[0]) * (w[2] - w[0]) - (w[1] - w[0]) * (u[2] - u[0])
    edges = []
    for e in range(3):
        a, b = (e + 1) % 3, (e + 2) % 3
        eu, ew = u[b] - u[a], w[b] - w[a]
        edges.append((a, eu, ew, np.sqrt(eu * eu + ew * ew)))
    longest = np.maximum(np.maximum(edges[0][3], edges[1][3]), edges[2][3])
    # Slivers across the rays (and points) keep every column of their box:
    # their orientation could be rounding's.
    good = np.abs(area) > 1e-6 * longest * longest + 1e-9
    pad = REACH * mesh.scale / min(columns.du, columns.dv)
    keep = np.ones(len(k), dtype=bool)
    for a, eu, ew, length in edges:
        s = np.where(good, np.sign(area) / np.where(length > 0, length, 1.0), 0.0)
        nu, nw = -ew * s, eu * s  # inner unit normal (zero for slivers: passes)
        off = -(nu * u[a] + nw * w[a])
        keep &= nu[k] * ii + nw[k] * jj + off[k] >= -pad
    return k[keep], (ii + columns.nu * jj)[keep]


def _column_pair_chunks(tri, col, lo, hi, crowded: list, chunk: int = PAIR_CHUNK):
    """Yield ``(k, 2)`` arrays of pairs ``a < b`` of triangles that share a
    column and whose depth ranges ``[lo, hi]`` (per triangle, (m,) float)
    overlap.

    ``tri``, ``col``: the entries of :func:`_column_entries`; the pairs index
    ``lo`` and ``hi`` as ``tri`` does. Entries are
    sorted by column, then depth, and each is paired with the later entries
    of its column that begin before it ends; a pair sharing several columns
    is yielded once per chunk it appears in (the flags it sets are the same).
    An entry with more than ``MAX_RUN`` such partners (the hub of a big flat
    fan) is not paired: its triangle and its partners' are appended to
    ``crowded`` instead.
    """
    if len(tri) < 2:
        return
    m = np.int64(len(lo))
    base = float(lo[tri].min())
    span = 2.0 * (float(hi[tri].max()) - base) or 1.0  # keys of one column stay apart
    # One float key: column, then depth. Keys round by about 2**-52 of
    # col * span; the margin lets the sweep reach further than that (more
    # pairs, settled exactly afterwards, never fewer).
    key = col * span + (lo[tri] - base)
    order = np.argsort(key)
    key, tri, col = key[order], tri[order], col[order]
    margin = float(col[-1] + 1) * span * 2.0**-40
    end = np.searchsorted(key, col * span + (hi[tri] - base) + margin, side="right")
    later = end - np.arange(len(key)) - 1
    full = later > MAX_RUN
    if full.any():
        # Every entry from a crowded one to its last partner.
        cover = np.zeros(len(key) + 1, dtype=np.int64)
        np.add.at(cover, np.flatnonzero(full), 1)
        np.add.at(cover, end[full], -1)
        crowded.append(np.unique(tri[np.cumsum(cover[:-1]) > 0]))
        later[full] = 0
    ends = np.cumsum(later)
    e0 = 0
    while e0 < len(key):
        e1 = max(e0 + 1, int(np.searchsorted(ends, (ends[e0 - 1] if e0 else 0) + chunk, "right")))
        lat = later[e0:e1]
        first = np.repeat(np.arange(e0, e1), lat)
        second = first + 1 + np.arange(len(first)) - np.repeat(np.cumsum(lat) - lat, lat)
        e0 = e1
        same = col[first] == col[second]
        a, b = tri[first[same]], tri[second[same]]
        if len(a):
            pairs = np.unique(np.minimum(a, b) * m + np.maximum(a, b))
            yield np.column_stack([pairs // m, pairs % m])


def _hiding(mesh, a: np.ndarray, b: np.ndarray, unit: np.ndarray, plane: float, tol: float) -> np.ndarray:
    """(k,) bool: pairs of triangles ``a[i], b[i]`` that a restart could hide from each other.

    They count when they lie in (nearly) the same plane -- every vertex of
    each within ``plane`` of the other's plane -- and either their interiors
    overlap (the same triangle twice, folds, coincident faces of touching
    parts) or they touch without sharing a vertex (a T-junction). Pairs that
    only meet at a shared vertex or edge do not count: a ray through a
    shared point has its hit's vertex neighbours tested anyway. The cheap
    topological tests run first, the plane test only on what they leave.
    """
    t, g = mesh.triangles, mesh.geometric_faces
    ga = [g[a, i] for i in range(3)]
    gb = [g[b, i] for i in range(3)]
    # match[i][j]: vertex i of a is vertex j of b.
    match = [[x == y for y in gb] for x in ga]
    in_b = np.column_stack([m[0] | m[1] | m[2] for m in match])  # (k, 3): a's vertex i is b's
    n_shared = in_b.sum(axis=1)
    maybe = n_shared != 2
    # Sharing an edge: the interiors overlap exactly when the third vertices
    # lie on the same side of it (sides in a's plane; a pair that is not
    # coplanar fails the plane test below anyway).
    edge = np.flatnonzero(~maybe)
    if len(edge):
        ae, be = a[edge], b[edge]
        ib = in_b[edge]
        third_a = np.argmin(ib, axis=1)  # a's vertex not in b
        in_a = np.column_stack([match[0][j][edge] | match[1][j][edge] | match[2][j][edge] for j in range(3)])
        third_b = np.argmin(in_a, axis=1)
        e0 = t[ae, (third_a + 1) % 3]
        axis_e = t[ae, (third_a + 2) % 3] - e0
        pa, pb = t[ae, third_a], t[be, third_b]
        ua = unit[ae]
        side_a = np.einsum("ij,ij->i", np.cross(axis_e, pa - e0), ua)
        side_b = np.einsum("ij,ij->i", np.cross(axis_e, pb - e0), ua)
        maybe[edge] = side_a * side_b > 0
    cand = np.flatnonzero(maybe)
    hide = np.zeros(len(a), dtype=bool)
    if not len(cand):
        return hide
    ac, bc = a[cand], b[cand]

    def near(x, y):  # every vertex of x within `plane` of y's plane
        u, o = unit[y], t[y, 0]
        return np.logical_and.reduce([np.abs(np.einsum("ij,ij->i", t[x, v] - o, u)) <= plane
                                      for v in range(3)])

    same = near(ac, bc)
    same[same] = near(bc[same], ac[same])
    cand, ac, bc = cand[same], ac[same], bc[same]
    ns = n_shared[cand]
    h = ns >= 2  # the same triangle twice, or a fold over a shared edge
    # Otherwise, in a's plane (dropping the coordinate a's normal is
    # largest along): overlapping interiors, or touching with no vertex in
    # common.
    rest = np.flatnonzero(ns < 2)
    if len(rest):
        ar, br = ac[rest], bc[rest]
        drop = np.argmax(np.abs(unit[ar]), axis=1)
        keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]
        rows = np.arange(len(ar))[:, None, None]
        cols = np.arange(3)[None, :, None]
        sep = _separation(t[ar][rows, cols, keep[:, None, :]], t[br][rows, cols, keep[:, None, :]])
        h[rest] = (sep < -tol) | ((sep <= tol) & (ns[rest] == 0))
    hide[cand] = h
    return hide


def coplanar_overlaps(mesh, columns: Columns | None = None) -> np.ndarray:
    """(m,) bool: triangles that a restart past another, coplanar one could hide.

    A restart just past a hit skips every triangle the ray meets at (nearly)
    the same depth. Where that is a neighbour sharing a vertex with the hit,
    the vertex-neighbour test of step 2 finds it; what it cannot find is a
    coplanar triangle that overlaps the hit or touches it without sharing a
    vertex (see :func:`_hiding`). Such pairs' triangles are flagged, and their
    crossings are found by the exact rasteriser instead.

    With ``columns``, only pairs that one of its rays can see are settled:
    a ray that passes near neither triangle of a pair, or meets them at
    depths further apart than a restart step, cannot lose either to the
    other, so this is as exact for that lattice as settling every pair. On a
    coarse lattice (a few column centres in each triangle's box) the pairs
    come from (triangle, ray) entries, the rays that pass within ``REACH`` of
    the triangle itself, sorted by ray and depth: two triangles that share
    an edge then rarely share a ray, and a mesh of flat 16-triangle patches
    at 256³ settles 2.4 k pairs instead of 636 k. On a finer lattice, from
    boxes in column units that must hold one column centre together.
    Without ``columns``, every pair whose boxes meet is settled: the flags
    for every lattice at once.
    """
    return _check(mesh, columns)[0]


def _check(mesh, columns: Columns | None):
    """``(flags, near)``: :func:`coplanar_overlaps`, and (m,) bool marking
    the triangles some ray of ``columns`` passes within ``REACH`` of (every
    triangle with an area where ``columns`` is None or the mesh has at most
    ``FEW`` triangles)."""
    t = mesh.triangles
    m = len(t)
    flags = np.zeros(m, dtype=bool)
    n = _normals(mesh)
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    unit = n / np.where(length > 0, length, 1.0)[:, None]
    tol = 1e-9 * mesh.scale
    plane = 2 * STEP * mesh.scale
    ok = length > 0
    crowded: list = []
    near = ok.copy()
    if len(t) <= FEW:
        # A handful of triangles: every pair, for every lattice (more flags
        # than a lattice needs is always safe), without the per-lattice
        # bookkeeping that would cost more than the pairs.
        ok = np.flatnonzero(ok)
        chunks = iter([np.argwhere(np.triu(np.ones((len(ok), len(ok)), dtype=bool), 1))])
    elif columns is None:
        ok = np.flatnonzero(ok)
        chunks = box_pair_chunks(t[ok].min(axis=1) - plane, t[ok].max(axis=1) + plane, crowded=crowded)
    else:
        ranges = reach(mesh, columns)
        i0, i1, j0, j1 = ranges
        near &= (i0 <= i1) & (j0 <= j1)
        ok = np.flatnonzero(near)
        w_lo, w_hi = _extent(mesh, columns.axis)
        w_lo, w_hi = w_lo - plane, w_hi + plane
        cells = ((i1 - i0 + 1) * (j1 - j0 + 1))[ok].sum()
        if cells <= COLUMN_ENTRIES * len(ok) + 100_000:
            # A coarse lattice: each triangle near a few rays. Pair them
            # ray by ray, keeping only rays that pass within the reach of
            # the triangle itself (most neighbours then share no ray).
            tri, col = _column_entries(mesh, columns, ranges, ok)
            near[:] = False
            near[ok[tri]] = True
            chunks = _column_pair_chunks(tri, col, w_lo[ok], w_hi[ok], crowded)
        else:
            # A fine lattice: boxes in column units (along the rays too, so
            # the hash cells stay about cubic).
            d = min(columns.du, columns.dv)
            lo = np.column_stack([i0[ok], j0[ok], w_lo[ok] / d])
            hi = np.column_stack([i1[ok], j1[ok], w_hi[ok] / d])
            chunks = box_pair_chunks(lo, hi, crowded=crowded)
    for pairs in chunks:
        a, b = ok[pairs[:, 0]], ok[pairs[:, 1]]
        hide = _hiding(mesh, a, b, unit, plane, tol)
        flags[a[hide]] = True
        flags[b[hide]] = True
    for boxes in crowded:
        flags[ok[boxes]] = True
    return flags, near


class EmbreeBackend(Backend):
    """Embree (embreex, via trimesh.ray.ray_pyembree) with exact verification."""

    name = "embree"

    def __init__(self):
        # Importing here keeps `import geovox` working where embreex is absent.
        import importlib

        # Raises ImportError where embreex is missing or has no working build.
        self._ray_pyembree = importlib.import_module("trimesh.ray.ray_pyembree")

    def _scene(self, mesh, faces=None):
        """A trimesh ray intersector over the mesh, or over the triangles ``faces`` only.

        Built in a centred copy scaled to a diagonal of 100, so that float32
        keeps its precision; only the vertices the triangles use are copied
        (embreex copies them one by one).
        """
        import trimesh

        centre, factor, _ = self._frame(mesh)
        f, v = mesh.faces, mesh.vertices
        if faces is not None:
            f = f[faces]
            used = np.zeros(len(v), dtype=bool)
            used[f] = True
            f = (np.cumsum(used) - 1)[f]
            v = v[used]
        local = trimesh.Trimesh((v - centre) * factor, f, process=False, validate=False)
        return self._ray_pyembree.RayMeshIntersector(local, scale_to_box=False)

    @staticmethod
    def _frame(mesh):
        """``(centre, factor, v0)``: the scaled copy's frame and each triangle's first vertex in it."""
        if "embree_frame" not in mesh._cache:
            centre = mesh.bounds.mean(axis=0)
            factor = 100.0 / mesh.scale
            mesh._cache["embree_frame"] = (centre, factor, (mesh.triangles[:, 0] - centre) * factor)
        return mesh._cache["embree_frame"]

    def setup(self, mesh, columns: Columns):
        """The per-lattice set-up: ``(intersector, faces, flagged)``, kept with the mesh.

        ``flagged`` (m,) bool: :func:`coplanar_overlaps` for this lattice.
        ``faces``: the mesh triangles the intersector holds, in its order --
        only those some ray of this lattice passes near (see :func:`_check`) when they are
        at most ``SUBSET_SCENE`` of the mesh (a coarse lattice: a smaller
        scene to copy and build), else ``None`` for one scene of the whole
        mesh, shared by every lattice. A triangle left out is one no ray
        comes within ``REACH`` of, so Embree could never report it.
        """
        key = (columns.axis, columns.u0, columns.v0, columns.du, columns.dv, columns.nu, columns.nv)
        # One set-up at a time: a colour run casts two axes on threads.
        with _SETUP_LOCK:
            kept = mesh._cache.setdefault("embree_lattices", {})
            if key not in kept:
                flagged, near = _check(mesh, columns)
                seen = np.flatnonzero(near)
                if len(seen) > SUBSET_SCENE * len(mesh.faces):
                    if "embree" not in mesh._cache:
                        mesh._cache["embree"] = self._scene(mesh)
                    state = (mesh._cache["embree"], None, flagged)
                elif len(seen):
                    state = (self._scene(mesh, seen), seen, flagged)
                else:
                    state = (None, seen, flagged)
                while len(kept) >= KEEP_LATTICES:
                    kept.pop(next(iter(kept)))
                kept[key] = state
            return kept[key]

    def cast(self, mesh, columns: Columns, jobs: int = 1) -> Hits:
        proj = Projection(mesh.triangles, columns)
        if len(proj) == 0:
            return Hits.empty()
        intersector, faces, flagged = self.setup(mesh, columns)
        if faces is not None and len(faces) == 0:
            return Hits.empty()  # no ray passes near a triangle: nothing to cross
        centre, factor, v0 = self._frame(mesh)
        # Depths along a ray use only ratios of the normal's components,
        # so the unscaled normal (shared with the coplanar check) serves.
        normal = _normals(mesh)
        nu = columns.nu
        ax, ua, va = columns.axis, columns.u_axis, columns.v_axis

        # Only columns inside the projected bounding box of the active triangles.
        i0, i1 = int(proj.imin.min()), int(proj.imax.max())
        j0, j1 = int(proj.jmin.min()), int(proj.jmax.max())
        ii, jj = np.meshgrid(np.arange(i0, i1 + 1), np.arange(j0, j1 + 1), indexing="ij")
        rays = (ii + nu * jj).reshape(-1)
        n = len(rays)

        origin = np.zeros((n, 3))
        origin[:, ua] = (columns.centres_u()[rays % nu] - centre[ua]) * factor
        origin[:, va] = (columns.centres_v()[rays // nu] - centre[va]) * factor
        lo = (mesh.bounds[0, ax] - centre[ax]) * factor - 1.0  # outside the mesh
        direction = np.zeros((n, 3))
        direction[:, ax] = 1.0
        step = STEP * 100.0  # the scaled mesh has a diagonal of 100

        # The restart loop runs on chunks of rays in threads (Embree releases
        # the GIL while tracing); each ray's hits do not depend on the chunking.
        chunks = [np.arange(a, min(a + -(-n // max(1, jobs)), n))
                  for a in range(0, n, -(-n // max(1, jobs)))] if n else []

        def trace(sel):
            return self._trace(intersector, faces, origin[sel], direction[sel], rays[sel], lo, step,
                               v0, normal, ax, ua, va)

        if jobs > 1 and len(chunks) > 1:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=jobs) as pool:
                results = list(pool.map(trace, chunks))
        else:
            results = [trace(c) for c in chunks]
        ray = np.concatenate([r[0] for r in results]) if results else np.zeros(0, np.int64)
        tri = np.concatenate([r[1] for r in results]) if results else np.zeros(0, np.int64)
        stuck = np.concatenate([r[2] for r in results]) if results else np.zeros(0, np.int64)
        recheck = np.zeros(columns.count, dtype=bool)
        for r in results:
            recheck[r[3]] = True
        hits = self._verify(mesh, proj, columns, ray, tri, recheck)
        # Coplanar overlapping triangles: found exactly, by scanning.
        if flagged.any():
            hits = hits.take(~flagged[hits.triangle])
            hits = Hits.concatenate([hits, rasterise(proj, triangle_mask=flagged[proj.tri],
                                                     jobs=jobs)])

        # Rays with odd parity (or stuck) are redone exactly.
        counts = np.bincount(hits.ray, minlength=columns.count)
        redo = (counts % 2 == 1)
        redo[stuck] = True
        if redo.any():
            keep = ~redo[hits.ray]
            exact = rasterise(proj, column_mask=redo, jobs=jobs)
            hits = Hits.concatenate([hits.take(keep), exact])
        return hits

    @staticmethod
    def _trace(intersector, faces, origin, direction, rays, lo, step, v0, normal, ax, ua, va):
        """Multi-hit restart loop for a set of rays.

        ``faces``: mesh triangle of each of the intersector's, or ``None``
        where it holds the whole mesh.

        Returns the recorded (ray, triangle) pairs, the rays that ran out of
        restarts, and the rays that met a hit behind their restart point.
        """
        n = len(rays)
        pos = np.full(n, lo)
        offset = np.full(n, step)
        last = np.full(n, -1, dtype=np.int64)
        behind = np.zeros(n, dtype=bool)
        live = np.arange(n)
        found_ray, found_tri = [], []
        for _ in range(MAX_RESTARTS):
            if len(live) == 0:
                break
            o = origin[live]
            o[:, ax] = pos[live]
            tri = intersector.intersects_first(o, direction[live])
            hit = tri >= 0
            live, tri, o = live[hit], tri[hit], o[hit]
            if len(live) == 0:
                break
            if faces is not None:
                tri = faces[tri]
            # Where the hit lies along the ray, in float64 from its plane.
            nz = normal[tri, ax]
            with np.errstate(divide="ignore", invalid="ignore"):
                d = v0[tri, ax] - (normal[tri, ua] * (o[:, ua] - v0[tri, ua])
                                   + normal[tri, va] * (o[:, va] - v0[tri, va])) / nz
            d = np.where(np.isfinite(d), d, pos[live])
            # A hit behind the restart point may be one already recorded.
            behind[live[d < pos[live]]] = True
            repeat = tri == last[live]
            found_ray.append(rays[live[~repeat]])
            found_tri.append(tri[~repeat])
            # A repeat means float32 put the old hit past our restart point:
            # step further each time; otherwise restart just past the hit.
            offset[live] = np.where(repeat, offset[live] * 2.0, step)
            pos[live] = np.maximum(pos[live], d) + offset[live]
            last[live] = tri
        stuck = rays[live] if len(live) else np.zeros(0, np.int64)
        ray = np.concatenate(found_ray) if found_ray else np.zeros(0, np.int64)
        tri = np.concatenate(found_tri) if found_tri else np.zeros(0, np.int64)
        return ray, tri, stuck, rays[behind]

    def _verify(self, mesh, proj, columns, ray, tri, recheck) -> Hits:
        """Exact crossings among Embree's pairs and, where unsure, their vertex neighbours.

        ``recheck`` (per ray, bool) marks rays that may hold a pair twice.
        """
        t = proj.local[tri]
        active = t >= 0
        ray, tri, t = ray[active], tri[active], t[active]
        nu = columns.nu
        hit, depth, bary, w = proj.crossings(t, ray % nu, ray // nu)
        tol = max(NEAR_EDGE, 1e-5 * mesh.scale / min(columns.du, columns.dv))
        unsure = ~hit | (proj.edge_distance(t, w) < tol)
        parts = [Hits(ray[hit], depth[hit], tri[hit], bary[hit])]
        if unsure.any():
            if "vertex_faces" not in mesh._cache:
                mesh._cache["vertex_faces"] = _vertex_faces(mesh.geometric_faces)
            offsets, vfaces = mesh._cache["vertex_faces"]
            r2, f2 = _expand(ray[unsure], tri[unsure], mesh.geometric_faces, offsets, vfaces)
            t2 = proj.local[f2]
            ok = t2 >= 0
            r2, f2, t2 = r2[ok], f2[ok], t2[ok]
            h2, d2, b2, _ = proj.crossings(t2, r2 % nu, r2 // nu)
            parts.append(Hits(r2[h2], d2[h2], f2[h2], b2[h2]))
        hits = Hits.concatenate(parts)
        # A pair can be reported twice only on a ray that met an edge or
        # vertex (an unsure pair) or had a hit behind its restart point.
        recheck[ray[unsure]] = True
        sel = np.flatnonzero(recheck[hits.ray])
        if len(sel):
            key = hits.triangle[sel] * np.int64(columns.count) + hits.ray[sel]
            _, first = np.unique(key, return_index=True)
            keep = np.ones(len(hits), dtype=bool)
            keep[sel] = False
            keep[sel[first]] = True
            hits = hits.take(keep)
        return hits
