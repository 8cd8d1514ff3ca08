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
   faces, coincident faces of touching parts -- would hide each other from a
   restart that steps past the first: their crossings are found by the
   exact rasteriser instead of by Embree.
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


def coplanar_overlaps(mesh) -> np.ndarray:
    """(m,) bool: triangles that overlap another triangle lying in nearly the same plane.

    Planes are compared as points ``(n, d / size)`` (unit normal with a
    canonical sign, offset over the mesh size) in a k-d tree, so there are no
    bucket boundaries to miss a pair; pairs whose boxes are apart, or that
    share an edge with their third vertices on opposite sides of it (the two
    halves of one flat face), do not count.
    """
    if "coplanar" in mesh._cache:
        return mesh._cache["coplanar"]
    from scipy.spatial import cKDTree

    t = mesh.triangles
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    length = np.linalg.norm(n, axis=1)
    ok = length > 0
    n = n[ok] / length[ok, None]
    # Canonical sign: the largest component positive.
    big = np.argmax(np.abs(n), axis=1)
    n *= np.sign(n[np.arange(len(n)), big])[:, None]
    d = np.einsum("ij,ij->i", n, t[ok, 0]) / mesh.scale
    ids = np.flatnonzero(ok)
    flags = np.zeros(len(t), dtype=bool)
    pairs = cKDTree(np.column_stack([n, d])).query_pairs(r=1e-6, output_type="ndarray")
    if len(pairs):
        a, b = ids[pairs[:, 0]], ids[pairs[:, 1]]
        lo, hi = t.min(axis=1), t.max(axis=1)
        tol = 1e-9 * mesh.scale
        overlap = np.all((lo[a] <= hi[b] + tol) & (lo[b] <= hi[a] + tol), axis=1)
        a, b = a[overlap], b[overlap]
        # Two halves of one flat face: sharing an edge, third vertices apart.
        g = mesh.geometric_faces
        shared = (g[a][:, :, None] == g[b][:, None, :])
        n_shared = shared.any(axis=2).sum(axis=1)
        edge = n_shared == 2
        if edge.any():
            ae, be = a[edge], b[edge]
            sa = shared[edge].any(axis=2)  # which vertices of a are shared
            sb = shared[edge].any(axis=1)
            pa = t[ae][~sa].reshape(-1, 3)
            pb = t[be][~sb].reshape(-1, 3)
            e0 = t[ae][sa].reshape(-1, 2, 3)
            axis_e = e0[:, 1] - e0[:, 0]
            nrm = np.cross(t[ae, 1] - t[ae, 0], t[ae, 2] - t[ae, 0])
            side_a = np.einsum("ij,ij->i", np.cross(axis_e, pa - e0[:, 0]), nrm)
            side_b = np.einsum("ij,ij->i", np.cross(axis_e, pb - e0[:, 0]), nrm)
            apart = np.zeros(len(a), dtype=bool)
            apart[np.flatnonzero(edge)] = side_a * side_b < 0
            a, b = a[~apart], b[~apart]
        flags[a] = True
        flags[b] = True
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
            tris = (mesh.triangles - centre) * factor
            v0 = tris[:, 0]
            normal = np.cross(tris[:, 1] - v0, tris[:, 2] - v0)
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
