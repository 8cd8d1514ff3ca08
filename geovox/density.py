"""Beyond on/off voxels: anti-aliased coverage density and signed distance.

Coverage
--------
Each voxel's value is the fraction of its volume inside the mesh. ``K x K``
rays per voxel column (a lattice ``K`` times finer across the rays, decided
by the same exact rules as occupancy) give the inside intervals along each
ray exactly, so no sampling is needed along the ray: a crossing at depth
``d`` in voxel ``k`` (``z_k <= d < z_k+1``) adds ``s * (z_k+1 - d) / h`` to
voxel ``k`` and ``s`` to every voxel past it (``s = +1`` entering, ``-1``
leaving, by the parity of the crossing along its ray). Two scatter-adds and a
running sum along the axis evaluate that for every ray at once. Inside is the
parity rule along the ray axis; when the inside test is ``winding``, it is
the winding number's rule on the mesh (repaired, its holes capped: see
:mod:`geovox.inside`) instead, counted from the crossings' signs: inside
where the winding number is not 0, so space that closed parts share counts,
as it does in the occupancy.

Signed distance
---------------
Negative inside. Within ``band`` voxels of the surface the distance is exact:
each triangle is measured at every voxel centre that can be within the band of
it, and each voxel keeps the smallest distance (the nearest-point stage's band
engine, :func:`geovox.nearest.band_distances`). Beyond the band the value is
clamped to ``+-band`` voxels (a truncated signed distance, as OpenVDB level
sets have): there the true distance is at least that much. ``band = inf``
gives every voxel the distance of its exact nearest surface point, from the
search exact colour uses (:func:`geovox.nearest.nearest_distances`). The
sign comes from the occupancy of the chosen inside test (parity, or the
winding number of a messy model); the unsigned distance needs none.
"""

from __future__ import annotations

import math

import numpy as np

from .grid import Columns
from .parallel import scan_along

#: Default half-width of the exact band of the signed distance, in voxels.
BAND = 3.0


def sub_columns(columns: Columns, k: int) -> Columns:
    """The lattice of ``k x k`` rays per column of ``columns``."""
    return Columns(axis=columns.axis, u_axis=columns.u_axis, v_axis=columns.v_axis,
                   u0=columns.u0, v0=columns.v0, du=columns.du / k, dv=columns.dv / k,
                   nu=columns.nu * k, nv=columns.nv * k, start=columns.start, w0=columns.w0)


def coverage(hits, sub: Columns, grid, k: int, jobs: int = 1, sign=None,
             layers=None) -> np.ndarray:
    """Inside fraction of every voxel from the crossings of ``k x k`` rays per column.

    Parameters
    ----------
    hits : Hits
        Crossings of the ``sub`` lattice.
    sub : Columns
        ``sub_columns(grid.columns(axis), k)``.
    sign : (m,) int, optional
        Per crossing, +1 where the surface faces along the ray and -1 where
        it faces against it: inside is then where the winding number (0
        before a ray's first crossing) is not 0. Without it, parity.
    layers : (z0, z1), optional
        Rays along z (``sub.axis == 2``) only: make layers ``z0 <= k < z1``
        of ``grid`` alone, equal bit for bit to those layers of the whole
        grid's coverage (the running sum is carried in from below in the
        same float32 order), in ``(nx, ny, z1 - z0)`` voxels.

    Returns
    -------
    (nx, ny, nz) float32 in [0, 1], Fortran order (nz: ``z1 - z0`` with ``layers``).
    """
    axis = sub.axis
    n = grid.shape[axis]
    z0, z1 = (0, n) if layers is None else layers
    shape = tuple(z1 - z0 if a == axis else grid.shape[a] for a in range(3))
    acc = np.zeros(shape, dtype=np.float32, order="F")
    if len(hits):
        col, kd, frac, s = _steps(hits, sub, grid, k, sign)
        nx, ny, _ = shape
        strides = [1, nx, nx * ny]
        flat = acc.reshape(-1, order="F")
        steps = ((kd, s * frac), (kd + 1, s * (1.0 - frac)))
        for kk, w in steps:
            ok = (kk >= z0) & (kk < z1)
            np.add.at(flat, col[ok] + (kk[ok] - z0) * strides[axis], w[ok].astype(np.float32))
        if z0 > 0:
            cols, carry = _carry_below(steps, col, z0)
            # The whole grid's running sum at layer z0 - 1, added as its scan would add it.
            flat[cols] = carry + flat[cols]
    scan_along(np.add, acc, axis, jobs)
    acc *= np.float32(1.0 / (k * k))
    np.clip(acc, 0.0, 1.0, out=acc)
    return acc


def _steps(hits, sub: Columns, grid, k: int, sign):
    """Per crossing that reaches the grid: its column's flat index in ``grid`` (x fastest,
    the ray axis left out), its layer ``kd`` (-1 before the grid), the part of that layer
    past it ``frac``, and ``s``, the change of "inside" there (see :func:`coverage`)."""
    axis = sub.axis
    n = grid.shape[axis]
    h = grid.spacing[axis]
    lo = 0.0  # depths are measured from the grid's low face
    # Rank of each crossing along its ray: one argsort of a combined key
    # (ray + depth scaled into [0, 1)). Crossings closer than ~1e-10 of the
    # depth range may swap, which changes a zero-length interval only.
    span = float(np.ptp(hits.depth)) or 1.0
    key = hits.ray + (hits.depth - hits.depth.min()) * (0.999 / span)
    order = np.argsort(key, kind="stable")
    ray = hits.ray[order]
    depth = hits.depth[order]
    first = np.r_[True, ray[1:] != ray[:-1]]
    start = np.maximum.accumulate(np.where(first, np.arange(len(ray)), 0))
    if sign is None:
        s = np.where((np.arange(len(ray)) - start) % 2 == 0, 1.0, -1.0)
    else:
        # Passing a crossing that faces along the ray lowers the winding
        # number by one; s is the change of "inside" (w != 0) there.
        step = -np.asarray(sign, dtype=np.int64)[order]
        run = np.cumsum(step)
        after = run - (run[start] - step[start])
        s = (after != 0).astype(np.float64) - ((after - step) != 0)
    kd = np.floor((depth - lo) / h).astype(np.int64)
    frac = (lo + (kd + 1) * h - depth) / h
    before = kd < 0
    kd[before] = -1
    frac[before] = 0.0
    keep = kd < n
    ray, kd, frac, s = ray[keep], kd[keep], frac[keep], s[keep]
    nx, ny, _ = grid.shape
    strides = [1, nx, nx * ny]
    col = ((ray % sub.nu) // k) * strides[sub.u_axis] + ((ray // sub.nu) // k) * strides[sub.v_axis]
    return col, kd, frac, s


def _carry_below(steps, col, z0: int):
    """The whole grid's float32 running sum at layer ``z0 - 1`` of each column that has one.

    Each voxel's scattered sum is made as :func:`coverage`'s ``np.add.at``
    makes it (the same additions in the same order), then each column's are
    added up layer by layer in float32, as the scan along the whole column
    adds them (the layers between add zeros, which change nothing).

    Returns
    -------
    cols : (c,) int64
        Flat column indices (x + nx * y).
    carry : (c,) float32
    """
    keys, weights = [], []
    for kk, w in steps:
        ok = (kk >= 0) & (kk < z0)
        keys.append(kk[ok] + z0 * col[ok])  # column-major: a column's layers together, in order
        weights.append(w[ok].astype(np.float32))
    keys, weights = np.concatenate(keys), np.concatenate(weights)
    if not len(keys):
        return np.zeros(0, np.int64), np.zeros(0, np.float32)
    uniq, inverse = np.unique(keys, return_inverse=True)
    voxel = np.zeros(len(uniq), np.float32)
    np.add.at(voxel, inverse.reshape(-1), weights)  # the order of coverage's two passes
    cols = uniq // z0
    first = np.r_[True, cols[1:] != cols[:-1]]
    starts = np.flatnonzero(first)
    rank = np.arange(len(uniq)) - np.repeat(starts, np.diff(np.r_[starts, len(uniq)]))
    table = np.zeros((len(starts), int(rank.max()) + 1), np.float32)
    table[np.cumsum(first) - 1, rank] = voxel
    np.add.accumulate(table, axis=1, out=table)  # sequential, in float32
    return cols[starts], table[:, -1].copy()


def signed_distance(mesh, grid, occupancy, band: float = BAND, jobs: int = 1, *, frame=None,
                    signed: bool = True, out=None) -> np.ndarray:
    """Distance from every voxel centre to the surface, exact within ``band`` voxels.

    Every voxel centre within ``band * min(spacing)`` of the surface gets its
    exact distance (the nearest-point stage: :func:`geovox.nearest.band_distances`);
    the others ``band * min(spacing)``, which the true distance is at least.
    With ``band=math.inf`` every voxel is exact, from its exact nearest
    surface point (:func:`geovox.nearest.nearest_distances`).

    Parameters
    ----------
    mesh : Mesh
    grid : Grid
        The block's grid.
    occupancy : (nx, ny, nz) bool or None
        The solid: negative there (``signed``). Not needed unsigned.
    band : float
        Half-width of the exact band in voxels, positive, or ``math.inf``.
    jobs : int
        Threads; the result does not depend on it.
    frame : (lo, spacing, z0), optional
        The whole grid's low corner and voxel size, and the block's first
        layer in it (default: this grid, layer 0), so a slab's distances
        are the whole grid's bit for bit.
    signed : bool
        Negative where ``occupancy`` is set (``-0.0`` on a surface voxel
        centre inside); else the unsigned distance.
    out : (nx * ny * nz,) float32, optional
        The array to make it in (its contents are overwritten), e.g. reused
        across slabs; the result is a view of it.

    Returns
    -------
    (nx, ny, nz) float32, Fortran order, in the mesh's units; values beyond
    the band are clamped to ``band * min(spacing)`` (negated inside).
    """
    from .nearest import band_distances, nearest_distances

    lo, spacing, z0 = frame if frame is not None else (grid.lo, grid.spacing, 0)
    limit = band * float(np.min(spacing))
    cache = getattr(mesh, "_cache", None)
    # Every voxel starts at the band's limit, which only a nearer triangle lowers: the
    # clamped distance with no pass of its own.
    if out is None:
        flat = np.full(grid.size, np.float32(limit), np.float32)
    else:
        flat = out[:grid.size]
        flat.fill(np.float32(limit))
    if math.isinf(band):
        nearest_distances(mesh.triangles, np.ones(grid.shape, bool, order="F"), spacing,
                          origin=lo, z0=z0, jobs=jobs, cache=cache, out=flat)
    else:
        band_distances(mesh.triangles, grid.shape, spacing, origin=lo, z0=z0, limit=limit,
                       jobs=jobs, cache=cache, out=flat)
    dist = flat.reshape(grid.shape, order="F")
    if signed:
        # In place and in memory order (a boolean index of an F-order array took 0.5 s
        # a 64-layer slab at 1024 voxels a side).
        flat_occ = np.asarray(occupancy, bool).reshape(-1, order="F")
        np.negative(flat, out=flat, where=flat_occ)
    return dist
