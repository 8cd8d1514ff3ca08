"""Crossings -> inside intervals -> occupancy, shared by every backend.

Along each column the rays start outside the whole mesh, so after an odd
number of crossings a point is inside. A voxel is inside when an odd number
of crossings lie at or before its centre: the interval ``[enter, leave)``
(a centre exactly on a crossing counts as past it, matching the tie rule
across the rays in :mod:`geovox.exact`).

The fill never materialises per-voxel intermediates: each crossing toggles
the first voxel at or past it, toggles that land on the same voxel cancel,
and a running XOR along the ray axis, one slice at a time and in place,
turns toggles into occupancy. Peak memory is the output plus the hits.
"""

from __future__ import annotations

import numpy as np

from .backends.base import Hits
from .grid import Columns, Grid
from .parallel import scan_along


def toggle_indices(hits: Hits, columns: Columns, grid: Grid) -> np.ndarray:
    """F-order linear indices of the voxels where parity flips an odd number of times.

    Returns
    -------
    (k,) int64, sorted, unique.
    """
    axis = columns.axis
    # Centres measured from the grid's low face, like the depths.
    centres = (np.arange(grid.shape[axis]) + 0.5) * grid.spacing[axis]
    # First voxel whose centre is at or past the crossing.
    k = np.searchsorted(centres, hits.depth, side="left")
    keep = k < len(centres)
    k = k[keep].astype(np.int64)
    ray = hits.ray[keep]
    idx = [None, None, None]
    idx[columns.u_axis] = ray % columns.nu
    idx[columns.v_axis] = ray // columns.nu
    idx[axis] = k
    nx, ny, _ = grid.shape
    lin = idx[0] + nx * (idx[1] + ny * idx[2])
    lin.sort()
    if len(lin) == 0:
        return lin
    # Keep the indices that occur an odd number of times.
    starts = np.flatnonzero(np.r_[True, lin[1:] != lin[:-1]])
    counts = np.diff(np.r_[starts, len(lin)])
    return lin[starts[counts % 2 == 1]]


def fill(hits: Hits, columns: Columns, grid: Grid, out: np.ndarray | None = None,
         jobs: int = 1) -> np.ndarray:
    """Occupancy of ``grid`` from the crossings of its column rays.

    Parameters
    ----------
    hits : Hits
        Crossings of ``columns`` (any order).
    columns : Columns
        The rays, one per voxel column of ``grid``.
    grid : Grid
    out : (nx, ny, nz) bool, Fortran order, optional
        Array to fill (zeroed first).
    jobs : int
        Threads for the running XOR.

    Returns
    -------
    occupancy : (nx, ny, nz) bool, Fortran order (x fastest in memory).
    """
    if out is None:
        out = np.zeros(grid.shape, dtype=bool, order="F")
    else:
        out[...] = False
    flat = out.reshape(-1, order="F")  # a view: `out` is Fortran-ordered
    flat[toggle_indices(hits, columns, grid)] = True
    running_xor(out, columns.axis, jobs)
    return out


def running_xor(out: np.ndarray, axis: int, jobs: int) -> None:
    """Toggles -> occupancy in place: a running XOR along ``axis``."""
    if axis != 0 and out.shape[0] % 8 == 0:
        # Eight voxels per XOR: bytes holding 0 or 1 stay 0 or 1, and with
        # rays along y or z the eight x-neighbours in a word are eight
        # separate columns, scanned side by side.
        words = out.T.view(np.uint64)
        scan_along(np.bitwise_xor, words, 2 - axis, jobs)
    else:
        scan_along(np.logical_xor, out, axis, jobs)


def fill_slabs(hits: Hits, columns: Columns, grid: Grid, thick: int = 64, buffers: int = 1):
    """The occupancy :func:`fill` gives, made ``thick`` z-slices at a time in one buffer.

    For rays along z: the toggles are found once for the whole grid; then
    each z-slice is the one before it (copied) with its own toggles flipped.
    That writes every voxel once -- no zeroing, no separate scan -- in one
    thread (a memory-bound copy of each slice), and peak
    memory is one slab (and the hits), not the grid. The buffer, touched
    once, stays mapped: on a large grid the first touch of fresh memory is
    the slowest part of :func:`fill`.

    Yields
    ------
    z0 : int
        The slab's first z index.
    occupancy : (nx, ny, z1 - z0) bool, Fortran order
        The slab. With ``buffers=1`` the same buffer is refilled on the next
        step, so use it (write it) before asking for the next one; with
        ``buffers=2`` a slab stays intact until two steps later, so it can
        be written while the next one is made.
    """
    if columns.axis != 2:
        raise ValueError("fill_slabs needs rays along z")
    lin = toggle_indices(hits, columns, grid)
    nx, ny, nz = grid.shape
    plane = nx * ny
    # Where each z-slice's toggles start in the sorted indices.
    bounds = np.searchsorted(lin, np.arange(nz + 1, dtype=np.int64) * plane)
    bufs = [np.empty((nx, ny, min(thick, nz)), dtype=bool, order="F")
            for _ in range(max(1, min(buffers, -(-nz // thick))))]
    prev = np.zeros(plane, dtype=bool)
    for n, z0 in enumerate(range(0, nz, thick)):
        z1 = min(z0 + thick, nz)
        buf = bufs[n % len(bufs)]
        flat = buf.reshape(-1, order="F")  # a view: `buf` is Fortran-ordered
        for k in range(z0, z1):
            cur = flat[(k - z0) * plane:(k - z0 + 1) * plane]
            cur[...] = prev
            idx = lin[bounds[k]:bounds[k + 1]] - k * plane
            cur[idx] = ~cur[idx]  # unique indices: each flips once
            prev = cur
        prev = prev.copy()  # the buffer is reused for the next slab
        yield z0, buf[:, :, :z1 - z0]
