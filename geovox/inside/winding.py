"""The winding number: exact for closed targets, with caps for open ones.

A closed target's winding number is an integer that the column rays give
exactly (signed crossings, by the same exact rules as parity,
:func:`signed_counts`); a voxel is inside where it is not 0, so the space two
overlapping parts share counts and a cavity inside an inward-facing shell
does not. An open target M is closed by caps K (:mod:`geovox.inside.caps`).
By additivity ``w_M = w_{M+K} - w_K``: the first term is the exact integer
from signed crossings, the second the caps' solid angle over 4 pi
(:mod:`geovox.inside.captree`), and a point is inside when ``w_M > 1/2``.
"""

from __future__ import annotations

import time

import numpy as np

from ..backends.base import Hits
from ..errors import warn
from ..memory import check_memory
from ..mesh import Mesh
from ..parallel import scan_along
from . import captree
from .caps import bridged
from .choice import target


def signed_counts(mesh: Mesh, hits: Hits, columns, grid, jobs: int = 1) -> np.ndarray:
    """Winding number of a closed mesh at every voxel centre, from signed crossings.

    Each crossing counts +1 where the surface faces along the ray (the ray
    leaves) and -1 where it faces against it; the winding number at a point
    is the sum over the crossings beyond it.

    Returns
    -------
    (nx, ny, nz) int16, Fortran order.
    """
    axis = columns.axis
    sigma = crossing_signs(mesh, hits, axis)
    total = np.bincount(hits.ray, weights=sigma, minlength=columns.count).astype(np.int64)
    centres = (np.arange(grid.shape[axis]) + 0.5) * grid.spacing[axis]  # from the low face
    k = np.searchsorted(centres, hits.depth, side="left")
    keep = k < len(centres)
    idx = [None, None, None]
    idx[columns.u_axis] = hits.ray[keep] % columns.nu
    idx[columns.v_axis] = hits.ray[keep] // columns.nu
    idx[axis] = k[keep]
    nx, ny, _ = grid.shape
    lin = idx[0] + nx * (idx[1] + ny * idx[2])
    order = np.argsort(lin, kind="stable")
    lin, s = lin[order], sigma[keep][order]
    w = np.zeros(grid.shape, dtype=np.int16, order="F")
    if len(lin):
        starts = np.flatnonzero(np.r_[True, lin[1:] != lin[:-1]])
        w.reshape(-1, order="F")[lin[starts]] = np.add.reduceat(s, starts)
    scan_along(np.add, w, axis, jobs)  # crossings at or before each centre
    # Beyond = total - before; total is 0 on every column of a closed mesh.
    shape = [1, 1, 1]
    shape[columns.u_axis], shape[columns.v_axis] = columns.nu, columns.nv
    tot = total.reshape(columns.nv, columns.nu).T  # [i, j]; u_axis < v_axis always
    np.subtract(tot.reshape(shape).astype(np.int16), w, out=w)
    return w


def crossing_signs(mesh: Mesh, hits: Hits, axis: int) -> np.ndarray:
    """(m,) int64: +1 where the crossed triangle faces along the ray (``axis``), -1 against it.

    Only the crossed triangles are gathered (``mesh.triangles`` of a capped
    scan is 120 MB a million and a half faces, for a few thousand crossings).
    """
    t = mesh.vertices[mesh.faces[hits.triangle]]
    n_axis = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[:, axis]
    return np.sign(n_axis).astype(np.int64)


def winding_occupancy(mesh: Mesh, grid, cast, axis: int, jobs: int = 1):
    """Occupancy by the generalised winding number (see the module notes).

    The winding number is taken of :func:`target`'s mesh: the mesh itself
    when it is closed and consistently wound, else its repaired copy. A
    closed target gives the integer winding number from signed crossings
    exactly, and a voxel is inside where it is not 0 (so overlapping parts
    count, and a cavity inside an inward-facing shell does not). An open
    target has its holes capped; inside is ``w_{M+K} - w_K > 1/2``.

    ``cast(mesh, axis)`` returns ``(Hits, Columns)`` for any mesh.

    Returns
    -------
    occupancy : (nx, ny, nz) bool, Fortran order
    hits, columns : the crossings of the original mesh's triangles
    approximate : int
        Voxels left to an estimate of the caps' winding number (the work
        budget ran out, see ``WORK_SECONDS``; said in a warning too); 0 where
        every voxel is proven or summed exactly.
    """
    tmesh, rep = target(mesh)
    if len(tmesh.faces) == 0:  # every face degenerate: nothing inside
        # The columns are the whole mesh's (its bounds); the rays are cast
        # through one of its faces, not every degenerate one (a file of 40
        # million zero-area triangles cast them all, for no crossing).
        stand_in = Mesh(mesh.vertices, mesh.faces[:1], source=mesh.source)
        stand_in._cache["bounds"] = mesh.bounds
        hits, columns = cast(stand_in, axis)
        return np.zeros(grid.shape, dtype=bool, order="F"), hits.take(hits.triangle < 0), columns, 0
    closed, cap_tris, _ = bridged(tmesh)
    nf = len(tmesh.faces)
    check_memory(grid, 1.0 + working_bytes(mesh, "winding"))
    hits, columns = cast(closed, axis)
    w = signed_counts(closed, hits, columns, grid, jobs)
    approximate = 0
    if len(cap_tris):
        occ = np.zeros(grid.shape, dtype=bool, order="F")
        left = captree.correct_caps(occ, w, grid, cap_tris, jobs)
        left = settle_ties(occ, w, grid, cap_tris, hits.take(hits.triangle >= nf), hits, columns,
                           left)
        if left is not None:
            approximate = _estimated(left, grid)
        hits = hits.take(hits.triangle < nf)
    else:
        occ = np.asfortranarray(w != 0)
    if rep is not None:
        hits = rep.original_hits(hits)
    return occ, hits, columns, approximate


def working_bytes(mesh: Mesh, method: str) -> float:
    """Bytes a voxel that ``method`` needs beside the occupancy, at its peak.

    ``winding`` holds the integer winding number (int16) and, where there
    are caps, a float32 estimate and bound per voxel and a float32 working
    copy and the pushed-down level; ``vote`` one uint8 count. Slab streaming
    plans with this.
    """
    if method == "winding":
        tmesh = target(mesh)[0]
        return 15.0 if len(tmesh.faces) and len(bridged(tmesh)[1]) else 2.0
    return 1.0 if method == "vote" else 0.0


def settle_ties(occ, w, grid, cap_tris, cap_hits, hits, columns, left=None):
    """Decide again the voxels whose centre lies on a cap, on the side the rays counted it.

    ``w_{M+K}`` counts a crossing at a voxel centre as passed (see
    :mod:`geovox.exact`), with the exact decisions of a mesh snapped to a
    lattice; the caps' solid angle at a point on a cap triangle jumps by 1
    there (and is ``atan2(0, 0)`` on its edges), so the two terms of
    ``w_M = w_{M+K} - w_K`` could take the point on different sides of the
    cap, and ``w_M`` be off by 1/2 or 1. ``w_M`` itself is continuous there
    (the caps are not part of M): where a cap crossing on a voxel's column
    lies within ``captree.TIE`` of a voxel of its centre, ``w_K`` is summed exactly
    at a point moved along the column to the middle of the gap between the
    crossings the rays counted before the centre and after it (no further
    than ``4 captree.TIE`` voxels), so both terms see the same side of every
    crossing. The same for either kernel; the moved point shifts ``w_M`` by
    about ``captree.TIE`` voxels times its gradient.

    Parameters
    ----------
    occ : (nx, ny, nz) bool, Fortran order, written
    w : (nx, ny, nz) int16
        ``w_{M+K}`` per voxel (:func:`signed_counts`).
    cap_tris : (k, 3, 3) float64
    cap_hits, hits : Hits
        The crossings of cap triangles, and every crossing of the capped
        mesh, along ``columns``.
    left : (nx, ny, nz) bool or None
        The voxels left to their estimates: the settled ones are no longer.

    The exact sums stop at the work budget (``WORK_SECONDS`` from here); the
    ties not summed by then keep their decisions and join ``left``.

    Returns
    -------
    (nx, ny, nz) bool or None
        ``left`` without the settled voxels (with those the budget left).
    """
    axis, h, n = columns.axis, float(grid.spacing[columns.axis]), grid.shape[columns.axis]
    centres = (np.arange(n) + 0.5) * h  # as signed_counts compares them
    reach = 4 * captree.TIE * h

    def nearest(depth):  # each depth's nearest centre, and how far from it
        k = np.clip(np.rint(depth / h - 0.5).astype(np.int64), 0, n - 1)
        return k, np.abs(depth - centres[k])

    k, off = nearest(cap_hits.depth)
    near = off <= captree.TIE * h
    if not near.any():
        return left
    # One entry per (column, centre); then every crossing within ``reach`` of it.
    key = np.unique(cap_hits.ray[near] * n + k[near])
    ray, k = key // n, key % n
    c = centres[k]
    kh, off = nearest(hits.depth)
    close = np.flatnonzero(off <= reach)  # few: no search over every crossing
    hkey = hits.ray[close] * n + kh[close]
    close = close[np.isin(hkey, key)]
    tie = np.searchsorted(key, hits.ray[close] * n + kh[close])
    d = hits.depth[close]
    lo, hi = c - reach, c + reach
    before = d <= c[tie]
    np.maximum.at(lo, tie[before], d[before])
    np.minimum.at(hi, tie[~before], d[~before])
    idx = [None, None, None]
    idx[columns.u_axis], idx[columns.v_axis], idx[axis] = ray % columns.nu, ray // columns.nu, k
    p = np.stack([grid.centres(a)[idx[a]] for a in range(3)], axis=1)
    p[:, axis] = grid.lo[axis] + (lo + hi) / 2
    ii = tuple(idx)
    if left is not None:
        left[ii] = False
    # A planar cap along a layer of centres makes a whole layer of ties: the
    # work budget holds here too, and what it leaves is counted.
    deadline = time.process_time() + captree.WORK_SECONDS
    block = max(1, (1 << 16) // len(cap_tris))
    for s in range(0, len(p), block):
        sub = tuple(x[s:s + block] for x in ii)
        if time.process_time() >= deadline:
            if left is None:
                left = np.zeros(grid.shape, dtype=bool)
            left[tuple(x[s:] for x in ii)] = True
            break
        occ[sub] = (w[sub] - captree.exact_sums(cap_tris, p[s:s + block])) > 0.5
    if left is not None and not left.any():
        left = None
    return left


def _estimated(unsure, grid) -> int:
    """Say how many voxels of ``grid`` (the True ones of ``unsure``) are approximate; return that count."""
    n = int(np.count_nonzero(unsure))
    if n:
        warn(approximate_warning(n, grid.size), stacklevel=3)
    return n


def approximate_warning(n: int, total: int) -> str:
    """The second of the two short lines a messy model gets (see :func:`repair_warning`).

    How many of the ``total`` voxels the estimate of the winding number
    decided (``n``, the Report's ``approximate``).
    """
    share = 100.0 * n / total
    # "99.6 %" or "0.0031 %", never "1e+02 %"
    share = f"{share:.1f}" if share >= 1 else f"{share:.2g}"
    return (f"{n:,} of {total:,} voxels ({share} %) are approximate; the holes' caps passed "
            f"the work budget (--inside vote is faster)")
