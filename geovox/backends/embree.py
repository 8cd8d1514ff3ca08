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
   vertices and edges are left to step 2.
4. A ray with an odd number of exact crossings (impossible on a closed mesh
   when no crossing was lost), or one that ran out of restarts, is redone by
   the exact NumPy rasteriser.

The result equals the NumPy backend's whenever step 1 meets each crossing or
one of its vertex neighbours; the remaining exception would need two
crossings of unrelated, non-coplanar triangles closer together than the
restart step (1e-6 of the mesh size) on the same ray, twice.
"""

from __future__ import annotations

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


#: A fixed direction in the 4-D plane space of :func:`_plane_neighbours`
#: (normal, offset), generic enough not to be near many real planes' points.
PLANE_SIDE = np.array([0.38, 0.55, 0.71, 0.23]) / np.linalg.norm([0.38, 0.55, 0.71, 0.23])


#: Share of a sample of triangles with a plane neighbour above which the
#: plane filter passes every triangle without searching for the rest.
PASS_ALL = 0.9


def _plane_neighbours(t, unit, length, mesh, plane) -> np.ndarray:
    """(n,) bool: triangles with some other triangle in nearly the same plane.

    A cheap filter before pairing boxes, looser than the test that follows.
    If every vertex of triangle x lies within ``plane`` of y's plane, the
    edges of x rise by at most ``2 plane`` along y's normal, so the angle
    between the normals has ``sin(theta) <= 2 plane / h`` (``h``: x's least
    height, its narrowest width in any direction). The normals then differ
    by at most ``theta`` and the planes' offsets from the mesh centre, over
    the mesh size, by at most ``theta / 2`` plus ``plane``: within
    ``1.12 theta`` in the 4-D points ``p = (normal, offset)``. Each triangle
    looks for such a neighbour within its own radius (``1.5 theta``). Slivers
    and tiny triangles, whose normal says little (``2 plane / h >= 0.5``),
    always pass.

    A plane has two such points, ``p`` and ``-p``. Each triangle is entered
    once, by the one on the positive side of the fixed direction
    ``PLANE_SIDE``: ``q = +-p`` with ``PLANE_SIDE . q >= 0``. Two triangles
    whose planes are within ``r`` (``|p_x -+ p_y| <= r``, ``r`` the smaller
    radius) either have their ``q`` within ``r`` of each other, or have
    ``|q_x + q_y| <= r``; then ``PLANE_SIDE . q_x + PLANE_SIDE . q_y <= r``
    with both terms >= 0, so each lies within its own radius of the split.
    Such triangles are also entered as ``-q``, and each is then within ``r``
    of the other's mirror: one search finds every neighbour.
    """
    from scipy.spatial import cKDTree

    if len(t) < 2:
        return np.zeros(len(t), dtype=bool)
    longest = np.zeros(len(t))
    for i in range(3):
        e = t[:, (i + 1) % 3] - t[:, i]
        np.maximum(longest, np.einsum("ij,ij->i", e, e), out=longest)
    height = length / np.sqrt(longest)  # twice the area over the longest edge
    ratio = 2.0 * plane / height
    wild = ratio >= 0.5
    radius = 1.5 * np.arcsin(np.minimum(ratio, 1.0)) + 1e-5
    offset = np.einsum("ij,ij->i", unit, t[:, 0] - mesh.bounds.mean(axis=0)) / mesh.scale
    points = np.column_stack([unit, offset])
    side = points @ PLANE_SIDE
    points[side < 0] *= -1.0
    mirror = (np.abs(side) <= radius) & ~wild
    # Sliding-midpoint splits: half the build time, the same answers.
    tree = cKDTree(np.concatenate([points, -points[mirror]]), balanced_tree=False)
    # The nearest other point (the first found is itself; its mirror is
    # 2 away), searched only as far as the largest radius: a search that
    # may give up early is much faster.
    bound = float(radius[~wild].max()) if (~wild).any() else 0.0

    def search(sel):
        return tree.query(points[sel], k=[2], distance_upper_bound=bound, workers=-1)[0][:, 0]

    # A mesh of flat patches (a subdivided one: every triangle has coplanar
    # siblings) passes nearly whole, and then the search only costs time: a
    # sample of 512 decides whether to pass every triangle instead (more
    # than the filter's answer is always safe, as the exact tests follow).
    sample = np.arange(0, len(t), max(1, len(t) // 512))
    if len(t) > 4096 and np.mean(wild[sample] | (search(sample) <= radius[sample])) >= PASS_ALL:
        return np.ones(len(t), dtype=bool)
    return wild | (search(slice(None)) <= radius)


def _clean_vertices(t, unit, g) -> np.ndarray:
    """(v,) bool: vertices whose incident faces' wedges do not overlap.

    Each vertex's fan is projected along the axis its mean face normal
    is largest along; each incident face covers a wedge of directions there.
    Two faces that share a vertex and lie in one plane overlap exactly when
    their wedges at that vertex do (the projection maps their common plane
    onto the projection plane one to one, so it keeps overlaps and gaps). A
    vertex is clean when, sorted by their first direction, every wedge ends
    where or before the next begins; a pair of faces sharing a clean vertex
    then cannot overlap, and need not be paired. A vertex with a face
    steeper than 84 degrees to its projection plane is never clean (its
    wedge would be a needle, badly conditioned).

    ``t``: (m, 3, 3) float, ``unit``: (m, 3) unit normals, ``g``: (m, 3) int
    geometric faces. Faces whose normal is zero must be left out by the caller.
    """
    nv = int(g.max()) + 1 if g.size else 0
    vert = g.reshape(-1)
    face = np.repeat(np.arange(len(g)), 3)
    # Any normal will do to pick the axis: a face steep to it is caught below.
    normal = np.column_stack([np.bincount(vert, np.repeat(unit[:, i], 3), minlength=nv)
                              for i in range(3)])
    drop = np.argmax(np.abs(normal), axis=1)[vert]  # per incidence
    # Incidence 3 f + c: corner c of face f; its coordinates along the two
    # kept axes, and those of the next two corners (1-D gathers: fast).
    flat = t.reshape(-1)
    # Offsets within a face's 9 coordinates, by (corner, dropped axis), of
    # the kept x and y of this corner and of the next two.
    c = np.arange(3)[:, None]
    d = np.arange(3)[None, :]
    table = np.stack([(c + k) % 3 * 3 + (d + j) % 3 for k in range(3) for j in (1, 2)])
    base = face * 9
    sel = np.tile(np.arange(3), len(g)) * 3 + drop  # (corner, dropped axis) as one index
    x0, y0 = flat[base + table[0].reshape(-1)[sel]], flat[base + table[1].reshape(-1)[sel]]
    x1, y1 = flat[base + table[2].reshape(-1)[sel]] - x0, flat[base + table[3].reshape(-1)[sel]] - y0
    x2, y2 = flat[base + table[4].reshape(-1)[sel]] - x0, flat[base + table[5].reshape(-1)[sel]] - y0
    a1, a2 = np.arctan2(y1, x1), np.arctan2(y2, x2)
    ccw = x1 * y2 - y1 * x2 > 0
    start, end = np.where(ccw, a1, a2), np.where(ccw, a2, a1)
    bad = np.abs(unit.reshape(-1)[face * 3 + drop]) < 0.1
    # By vertex, then by first direction: one sort of a float key (not a
    # stable one: faster, and ties need no order). Ties within its rounding
    # may come out of order; an out-of-order pair only ever fails the test
    # below (never passes it wrongly).
    order = np.argsort(vert * 8.0 + (start + np.pi))
    v, s, e = vert[order], start[order], end[order]
    w = np.mod(e - s, 2 * np.pi)  # = width[order], without a fourth gather
    # Next wedge round the same vertex (the first one again after the last).
    first = np.r_[True, v[1:] != v[:-1]]
    head = np.maximum.accumulate(np.where(first, np.arange(len(v)), 0))
    last = np.r_[v[1:] != v[:-1], True]
    nxt = np.where(last, head, np.arange(len(v)) + 1)
    s_next = s[nxt] + np.where(last, 2 * np.pi, 0.0)
    # A shared edge gives the very same angle on both sides; otherwise a
    # gap. A triangle's wedge is under a half turn (one that rounding made
    # wider is not trusted), so the wedges, each ending before the next
    # begins, go round at most once.
    fine = ((e == s[nxt]) | (s + w <= s_next)) & (w < np.pi)
    dirty = np.zeros(nv, dtype=bool)
    dirty[v[~fine]] = True
    dirty[vert[bad]] = True
    return ~dirty


def _normals(mesh) -> np.ndarray:
    """(m, 3) float64: ``(v1 - v0) x (v2 - v0)`` per face, kept with the mesh."""
    if "normals" not in mesh._cache:
        t = mesh.triangles
        mesh._cache["normals"] = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    return mesh._cache["normals"]


def coplanar_overlaps(mesh) -> np.ndarray:
    """(m,) bool: triangles that a restart past another, coplanar one could hide.

    Two triangles count when they lie in (nearly) the same plane -- every
    vertex of each within ``2 STEP`` of the mesh size of the other's plane -- and
    either their interiors overlap (duplicated faces, coincident faces of
    touching parts, folds) or they touch without sharing a vertex (a
    T-junction). Triangles that only meet at shared vertices or edges, as the
    pieces of any flat region do, do not count: a ray through a shared point
    has its hit's vertex neighbours tested anyway.

    Pairs sharing a vertex whose fan is clean (see :func:`_clean_vertices`)
    are dropped before any geometry: in a mesh of flat groups they are most
    of the pairs, and settling them was most of the cost.
    """
    if "coplanar" in mesh._cache:
        return mesh._cache["coplanar"]
    t = mesh.triangles
    n = _normals(mesh)
    length = np.sqrt(np.einsum("ij,ij->i", n, n))
    unit = n / np.where(length > 0, length, 1.0)[:, None]
    flags = np.zeros(len(t), dtype=bool)
    tol = 1e-9 * mesh.scale
    plane = 2 * STEP * mesh.scale
    ok = np.flatnonzero(length > 0)
    ok = ok[_plane_neighbours(t[ok], unit[ok], length[ok], mesh, plane)]
    g = mesh.geometric_faces
    clean = _clean_vertices(t[ok], unit[ok], g[ok]) if len(ok) else np.zeros(0, dtype=bool)
    g_cols = [np.ascontiguousarray(g[:, i]) for i in range(3)]
    # Each face's clean vertices, -1 in place of the others (no vertex's
    # number): a pair shares a clean vertex when one of a's equals one of b's.
    is_clean = np.zeros(int(g.max()) + 1 if g.size else 0, dtype=bool)
    is_clean[:len(clean)] = clean
    clean_cols = [np.where(is_clean[gc], gc, -1) for gc in g_cols]

    def near(x, y):  # every vertex of x within `plane` of y's plane
        u, o = unit[y], t[y, 0]
        return np.logical_and.reduce([np.abs(((t[x, v] - o) * u).sum(axis=1)) <= plane
                                      for v in range(3)])

    # Boxes padded by `plane`: two faces that pass `near` may lie up to that
    # far apart across their planes (stacked parts with a hairline gap).
    # Triangles crowding one cell (the hub of a fan of thousands) are flagged
    # without pairing them: the exact rasteriser then finds their crossings,
    # which is always right and cheaper than settling millions of pairs.
    crowded: list = []
    for pairs in box_pair_chunks(t[ok].min(axis=1), t[ok].max(axis=1), plane, crowded=crowded):
        a, b = ok[pairs[:, 0]], ok[pairs[:, 1]]
        # Faces sharing a clean vertex cannot overlap (their wedges there
        # are apart), nor hide each other: drop them before any geometry.
        gb = [gc[b] for gc in g_cols]
        apart = np.zeros(len(a), dtype=bool)
        for cc in clean_cols:
            vi = cc[a]
            apart |= (vi == gb[0]) | (vi == gb[1]) | (vi == gb[2])
        a, b = a[~apart], b[~apart]
        same = near(a, b)
        same[same] = near(b[same], a[same])
        a, b = a[same], b[same]
        match = g[a][:, :, None] == g[b][:, None, :]  # (k, 3, 3): vertex i of a is vertex j of b
        in_b = match.any(axis=2)
        n_shared = in_b.sum(axis=1)
        hide = n_shared == 3  # the same triangle twice
        # Sharing an edge: the interiors overlap exactly when the third
        # vertices lie on the same side of it.
        edge = np.flatnonzero(n_shared == 2)
        if len(edge):
            ta, tb = t[a[edge]], t[b[edge]]
            e = ta[in_b[edge]].reshape(-1, 2, 3)
            pa = ta[~in_b[edge]]
            pb = tb[~match[edge].any(axis=1)]
            axis_e = e[:, 1] - e[:, 0]
            side_a = np.einsum("ij,ij->i", np.cross(axis_e, pa - e[:, 0]), unit[a[edge]])
            side_b = np.einsum("ij,ij->i", np.cross(axis_e, pb - e[:, 0]), unit[a[edge]])
            hide[edge] = side_a * side_b > 0
        # Otherwise, in a's plane (dropping the coordinate a's normal is
        # largest along): overlapping interiors, or touching with no vertex
        # in common.
        rest = np.flatnonzero(n_shared < 2)
        if len(rest):
            ar, br = a[rest], b[rest]
            drop = np.argmax(np.abs(unit[ar]), axis=1)
            keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]
            rows = np.arange(len(ar))[:, None, None]
            cols = np.arange(3)[None, :, None]
            sep = _separation(t[ar][rows, cols, keep[:, None, :]], t[br][rows, cols, keep[:, None, :]])
            hide[rest] = (sep < -tol) | ((sep <= tol) & (n_shared[rest] == 0))
        flags[a[hide]] = True
        flags[b[hide]] = True
    for boxes in crowded:
        flags[ok[boxes]] = True
    mesh._cache["coplanar"] = flags
    return flags


class EmbreeBackend(Backend):
    """Embree (embreex, via trimesh.ray.ray_pyembree) with exact verification."""

    name = "embree"

    def __init__(self):
        # Importing here keeps `import geovox` working where embreex is absent.
        import importlib

        # Raises ImportError where embreex is missing or has no working build.
        self._ray_pyembree = importlib.import_module("trimesh.ray.ray_pyembree")

    def _intersector(self, mesh):
        cache = mesh._cache
        if "embree" not in cache:
            import trimesh

            centre = mesh.bounds.mean(axis=0)
            factor = 100.0 / mesh.scale
            local = trimesh.Trimesh(
                (mesh.vertices - centre) * factor, mesh.faces, process=False, validate=False
            )
            v0 = (mesh.triangles[:, 0] - centre) * factor
            # Depths along a ray use only ratios of the normal's components,
            # so the unscaled normal (shared with the coplanar check) serves.
            normal = _normals(mesh)
            cache["embree"] = (self._ray_pyembree.RayMeshIntersector(local, scale_to_box=False),
                               centre, factor, v0, normal)
        return cache["embree"]

    def cast(self, mesh, columns: Columns, jobs: int = 1) -> Hits:
        proj = Projection(mesh.triangles, columns)
        if len(proj) == 0:
            return Hits.empty()
        intersector, centre, factor, v0, normal = self._intersector(mesh)
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
            return self._trace(intersector, origin[sel], direction[sel], rays[sel], lo, step,
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
        flagged = coplanar_overlaps(mesh)
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
    def _trace(intersector, origin, direction, rays, lo, step, v0, normal, ax, ua, va):
        """Multi-hit restart loop for a set of rays.

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
