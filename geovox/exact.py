"""The numeric contract: exact inside-triangle decisions for column rays.

Every backend finds *candidate* (column, triangle) pairs its own way; the
decision whether a column ray crosses a triangle, and where, is made here,
once, the same way for all of them. That is what makes the backends agree
voxel for voxel, including rays through edges and vertices.

The rules
---------
* The triangles are projected onto the plane across the rays and their 2-D
  vertex coordinates are snapped to an integer lattice in which every column
  centre is an integer point: ``q = rint((x - u0) / du * 2**s)``, column ``i``
  at ``i * 2**s + 2**(s - 1)``. ``s`` is chosen per call so that every
  coordinate stays below ``2**MAX_BITS``; with ``s`` capped at ``MAX_SUB_BITS``
  the snapping moves a vertex by at most ``2**-(s+1)`` of a column (under 1e-5
  of a voxel at 1024 voxels across the mesh). Snapping is a function of the vertex
  value alone, so shared vertices stay shared and a closed mesh stays closed.
* Edge functions (2-D orientation determinants) are then exact ``int64``
  arithmetic: ``|q| < 2**28`` keeps every product below ``2**59``.
* A column centre lying exactly on an edge is decided by symbolic
  perturbation: the point is treated as ``p + eps * (1, delta)`` with
  ``0 < delta << eps << 1`` (the "top-left" rule of rasterisers). The
  perturbed point is in general position, so a ray through an edge shared by
  two triangles crosses exactly one of them when the surface passes through,
  and both or neither where it only touches; a ray through a vertex crosses
  exactly one triangle of the fan. Parity is therefore exact on closed meshes.
* Triangles with zero projected area (parallel to the rays) are never crossed.
* Depth along the ray is interpolated in float64 from the exact barycentric
  weights, based at the vertex of largest weight, so a vertex gets exactly
  its own coordinate from every triangle around it and a face parallel to
  the grid gets exactly its vertices' coordinate.
* Along the ray a voxel centre exactly at a crossing's depth counts as past
  it (see :mod:`geovox.parity`), so inside is the half-open interval
  ``[enter, leave)`` on every axis. A ray that only touches the surface
  (two crossings at one depth) changes nothing, even for a centre exactly at
  the touching point: that is the perturbation with the offset along the ray
  much larger than the one across it.
"""

from __future__ import annotations

import numpy as np

from .errors import ParameterError
from .grid import Columns
from .kernels import lattice

#: Bound on the magnitude of the snapped integer coordinates (bits).
MAX_BITS = 28
#: Finest snapping used: 2**-20 of a column.
MAX_SUB_BITS = 20


def _column_boxes(tris, columns, limits):
    """The triangles whose box in column units reaches a column centre, and those boxes.

    Returns ``(idx, lo_u, hi_u, lo_v, hi_v)``: (k,) int64 triangle indices and
    (k,) float64 box bounds (``(x - u0) / du`` and the same along ``v``).
    """
    a, b = columns.u_axis, columns.v_axis
    with np.errstate(invalid="ignore", over="ignore"):
        fu = [(tris[:, k, a] - columns.u0) / columns.du for k in range(3)]  # column units
        fv = [(tris[:, k, b] - columns.v0) / columns.dv for k in range(3)]
    lo_u = np.minimum(np.minimum(fu[0], fu[1]), fu[2])
    hi_u = np.maximum(np.maximum(fu[0], fu[1]), fu[2])
    lo_v = np.minimum(np.minimum(fv[0], fv[1]), fv[2])
    hi_v = np.maximum(np.maximum(fv[0], fv[1]), fv[2])
    low, top_u, top_v = limits
    keep = (hi_u >= low) & (lo_u <= top_u) & (hi_v >= low) & (lo_v <= top_v)
    idx = np.flatnonzero(keep)
    return idx, lo_u[idx], hi_u[idx], lo_v[idx], hi_v[idx]


def _edges(t, columns, S):
    """The exact edge functions of triangles ``t`` ((k, 3, 3) float64) snapped with scale ``S``.

    Returns ``(sel, coef, tie, area, edge_len, z)``: (m,) int64 indices of the
    triangles of non-zero projected area, and :class:`Projection`'s arrays
    of the same names for them.
    """
    a, b, c = columns.u_axis, columns.v_axis, columns.axis
    half = S // 2
    # Written with one 1-D array per vertex: reductions over a length-3
    # axis and fancy indexing on (n, 3) arrays cost several times more.
    with np.errstate(invalid="ignore", over="ignore"):
        qu = [np.rint((t[:, k, a] - columns.u0) / columns.du * float(S)).astype(np.int64)
              for k in range(3)]
        qv = [np.rint((t[:, k, b] - columns.v0) / columns.dv * float(S)).astype(np.int64)
              for k in range(3)]

    # Edge k runs from vertex k+1 to vertex k+2 (opposite vertex k):
    # orient(A, B, P) = ex * (Py - Ay) - ey * (Px - Ax), which for
    # P = (i*S + half, j*S + half) is K0 + Ki*i + Kj*j.
    ex = [qu[(k + 2) % 3] - qu[(k + 1) % 3] for k in range(3)]
    ey = [qv[(k + 2) % 3] - qv[(k + 1) % 3] for k in range(3)]
    area2 = ex[0] * (qv[0] - qv[1]) - ey[0] * (qu[0] - qu[1])
    sign = np.sign(area2)
    sel = np.flatnonzero(sign)  # zero projected area: never crossed
    sign = sign[sel]
    coef = np.empty((len(sel), 3, 3), dtype=np.int64)
    tie = np.empty((len(sel), 3), dtype=np.int64)
    edge_len = np.empty((len(sel), 3), dtype=np.float64)
    for k in range(3):
        exk, eyk = ex[k][sel], ey[k][sel]
        A = (k + 1) % 3
        const = eyk * qu[A][sel] - exk * qv[A][sel]
        # Tie rule: d/dP of orient(A, B, P) along (1, delta) is -ey, or ex
        # when ey == 0. A tie counts as inside when that sign matches the
        # winding. Orient every triangle positively, then fold the tie
        # into K0: w > 0 or (w == 0 and tie) <=> w + tie > 0 for integer w.
        tie_sign = np.where(eyk != 0, -np.sign(eyk), np.sign(exk))
        tie[:, k] = tie_sign == sign
        coef[:, k, 0] = (const + (exk - eyk) * half) * sign + tie[:, k]
        coef[:, k, 1] = -eyk * S * sign
        coef[:, k, 2] = exk * S * sign
        edge_len[:, k] = np.hypot(exk, eyk)
    area = np.abs(area2[sel]).astype(np.float64)
    # Depths are measured from the grid's low face (see Columns).
    z = t[sel, :, c] - columns.w0
    return sel, coef, tie, area, edge_len, z


class Projection:
    """Triangles prepared for exact tests against one lattice of column rays.

    Only triangles whose snapped bounding box contains a column centre and
    that are not parallel to the rays are kept ("active"); ``local[t]`` maps a mesh
    triangle index to its active index or -1.

    Parameters
    ----------
    triangles : (n, 3, 3) float64
        Triangle vertex coordinates; with ``faces``, (v, 3) float64 vertex
        positions instead, the triangles being ``triangles[faces]`` (never
        gathered whole: most of a fine mesh's triangles enclose no column
        centre and are dropped first).
    columns : Columns
        The ray lattice.
    faces : (n, 3) int64, optional

    Attributes
    ----------
    tri : (m,) int64
        Mesh triangle index of each active triangle.
    imin, imax, jmin, jmax : (m,) int64
        Inclusive range of column indices in each active triangle's bounding box.
    coef : (m, 3, 3) int64
        For edge ``k`` (opposite vertex ``k``): ``K0, Ki, Kj`` such that
        ``K0 + Ki * i + Kj * j > 0`` exactly when column ``(i, j)`` is on the
        inner side of that edge, ties already resolved by the perturbation.
    tie : (m, 3) int64
        The 0/1 tie term folded into ``K0`` (subtract it to get the true
        edge function).
    area : (m,) float64
        Twice the projected area in lattice units (positive).
    z : (m, 3) float64
        Vertex coordinates along the ray axis.
    """

    def __init__(self, triangles: np.ndarray, columns: Columns, *, faces: np.ndarray | None = None):
        self.columns = columns
        if faces is None:
            vertices = np.asarray(triangles, dtype=np.float64).reshape(-1, 3)
            faces = np.arange(len(vertices), dtype=np.int64).reshape(-1, 3)
        else:
            vertices = np.asarray(triangles, dtype=np.float64)
            faces = np.asarray(faces, dtype=np.int64)
        n_all = len(faces)
        a, b, c = columns.u_axis, columns.v_axis, columns.axis
        # Column i's centre sits at i + 0.5 in column units: keep triangles
        # whose bounding box reaches a centre.
        limits = (0.5 - 1e-9, columns.nu - 0.5 + 1e-9, columns.nv - 0.5 + 1e-9)
        kernel = lattice()
        if kernel is not None:  # the same arithmetic in one pass (geovox/_lattice.pyx)
            idx, lo_u, hi_u, lo_v, hi_v = kernel.column_boxes(
                np.ascontiguousarray(vertices), np.ascontiguousarray(faces), a, b, columns.u0,
                columns.du, columns.v0, columns.dv, *limits)
        else:
            idx, lo_u, hi_u, lo_v, hi_v = _column_boxes(vertices[faces], columns, limits)
        # The largest |coordinate| of these triangles' vertices (the extremes
        # of their boxes) sets the snapping.
        m = max(max(np.abs(x).max(initial=1.0) for x in (lo_u, hi_u, lo_v, hi_v)),
                float(columns.nu), float(columns.nv))
        s = int(min(MAX_SUB_BITS, np.floor(MAX_BITS - 1 - np.log2(m + 1.0))))
        if s < 1:
            raise ParameterError(
                "the region is too small next to the mesh's triangles for exact "
                f"ray tests (a triangle spans {m:.3g} columns); use larger `bounds` "
                "or a coarser grid"
            )
        self.sub_bits = s
        S = np.int64(1) << np.int64(s)
        half = S // 2
        # The exact range of column centres in each snapped box first: rint
        # is monotonic, so rint(min) is the min of the snapped vertices.
        # Most triangles of a fine mesh on a coarse grid enclose no centre;
        # they are dropped here, before the per-vertex work (they could
        # never be crossed: a crossed centre lies in the closed box).
        if kernel is not None:
            seen, imin, imax, jmin, jmax = kernel.column_ranges(lo_u, hi_u, lo_v, hi_v, s,
                                                                columns.nu, columns.nv)
        else:
            lu, hu, lv, hv = (np.rint(x * float(S)).astype(np.int64)
                              for x in (lo_u, hi_u, lo_v, hi_v))
            imin = np.maximum(-((half - lu) // S), 0)
            imax = np.minimum((hu - half) // S, columns.nu - 1)
            jmin = np.maximum(-((half - lv) // S), 0)
            jmax = np.minimum((hv - half) // S, columns.nv - 1)
            seen = np.flatnonzero((imin <= imax) & (jmin <= jmax))
            imin, imax, jmin, jmax = imin[seen], imax[seen], jmin[seen], jmax[seen]
        idx = idx[seen]
        if kernel is not None:
            sel, coef, tie, area, edge_len, z = kernel.edges(
                np.ascontiguousarray(vertices), np.ascontiguousarray(faces), idx, a, b, c, columns.u0, columns.du,
                columns.v0, columns.dv, columns.w0, s)
        else:
            sel, coef, tie, area, edge_len, z = _edges(vertices[faces[idx]], columns, S)
        self.tri = idx[sel]
        self.coef = coef
        self.tie = tie
        self.area = area
        self.edge_len = edge_len
        self.z = z
        # Column i is in range when lu <= i*S + half <= hu.
        self.imin, self.imax, self.jmin, self.jmax = imin[sel], imax[sel], jmin[sel], jmax[sel]
        self.local = np.full(n_all, -1, dtype=np.int64)
        self.local[self.tri] = np.arange(len(self.tri))
        self.scale = int(S)

    def __len__(self) -> int:
        return len(self.tri)

    def edge_values(self, t: np.ndarray, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Tie-resolved edge functions; all three > 0 means inside.

        Parameters
        ----------
        t : (n,) int64
            Active triangle indices.
        i, j : (n,) int64
            Column indices.

        Returns
        -------
        w : (n, 3) int64
        """
        cf = self.coef[t]  # (n, 3, 3)
        return cf[:, :, 0] + cf[:, :, 1] * i[:, None] + cf[:, :, 2] * j[:, None]

    def crossings(self, t, i, j):
        """Exact test of candidate pairs.

        Parameters
        ----------
        t : (n,) int64
            Active triangle indices.
        i, j : (n,) int64
            Column indices.

        Returns
        -------
        hit : (n,) bool
            Whether ray ``(i, j)`` crosses triangle ``t``.
        depth : (n,) float64
            Distance of the crossing from the plane ``axis = columns.w0``
            (plane extrapolated where ``hit`` is False).
        bary : (n, 2) float64
            Weights ``(u, v)`` of vertices 1 and 2 (vertex 0 gets ``1-u-v``).
        w : (n, 3) int64
            The tie-resolved edge functions.
        """
        w = self.edge_values(t, i, j)
        hit = (w > 0).all(axis=1)
        depth, bary = self.interpolate(t, w)
        return hit, depth, bary, w

    def interpolate(self, t, w):
        """Depth and barycentric weights from tie-resolved edge functions.

        The depth is interpolated from the vertex with the largest weight,
        ``z_k + sum_i l_i (z_i - z_k)``: exact at a vertex (so every triangle
        of a fan reports the vertex's own coordinate, and a ray that touches
        the surface at a vertex gets two crossings at one depth) and exact on
        faces parallel to the grid.
        """
        lam = (w - self.tie[t]).astype(np.float64) / self.area[t][:, None]  # (n, 3)
        z = self.z[t]
        k = np.argmax(lam, axis=1)[:, None]
        zk = np.take_along_axis(z, k, axis=1)
        dz = z - zk
        np.put_along_axis(dz, k, 0.0, axis=1)
        depth = zk[:, 0] + (lam * dz).sum(axis=1)
        return depth, lam[:, 1:]

    def edge_distance(self, t, w):
        """(n,) float64: distance in columns from the ray to the nearest edge line."""
        ww = np.abs(w - self.tie[t]).astype(np.float64)
        return (ww / self.edge_len[t]).min(axis=1) / self.scale
