"""Fast colour: the nearest of the six axis crossings around each voxel (``color="fast"``).

With ``color="fast"`` (``--fast-color``) the nearest surface point is found
in columns, from the ray hits themselves (every hit already carries its
triangle and barycentric coordinates): rays are cast along all three axes,
and for each inside voxel the crossings just before and just after it in its
x, y and z columns are the candidates. The nearest of these six by distance
to the crossing triangle's plane (see :func:`nearest_crossings`) is taken,
and for voxels within ``REFINE`` voxels of the surface the exact closest
point on that crossing's triangle replaces the crossing. Deeper voxels take
the crossing's own colour. The result equals the brute-force nearest point
wherever the nearest triangle is one of the six candidates (nearly always
next to the surface; measured in tests/test_colour.py), and is otherwise a
nearby point of the surface.

The fast method's work goes through the block in chunks of z layers (``CHUNK_VOXELS``):
per chunk and axis, an int32 volume of "the last crossing on this voxel's
ray at or before it" (a running maximum of crossing numbers), then the six
candidates of each inside voxel in cache-sized blocks. Nothing the size of
the grid is made but the colours themselves, which a caller may also take
chunk by chunk (``sink``) or give a reused array for (``out``). Chunks run in
tasks on the threads; no result depends on the chunking or on ``jobs``.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from ..backends.base import Hits
from ..geometry import closest_on_triangles
from .shading import Shading, pack, shade, unit_normals

#: Voxels whose nearest axis crossing is closer than this many voxels get the
#: exact closest point on that crossing's triangle.
REFINE = 2.0


#: Inside voxels processed per block (small enough to stay in cache).
BLOCK = 1 << 16


#: Voxels in one chunk of z layers: the six-crossing colour works a chunk at
#: a time, so its index volume (int32) stays in cache and nothing
#: grid-sized but the colours themselves is made.
CHUNK_VOXELS = 1 << 21


#: Voxels in one task of consecutive chunks (the unit given to a thread).
TASK_VOXELS = 1 << 23


def relevant_crossings(hits, k, n: int, rays: int):
    """The crossings a grid of ``n`` voxels along the rays can need.

    A voxel uses the deepest crossing at or before its centre and the one
    after it, so of the crossings before the first centre (``k == 0``) only
    the deepest on each ray matters, and of those past the last (``k == n``)
    only the shallowest. Dropping the rest before sorting matters when the
    grid is one slab of a long ray: most of its crossings lie outside.

    Parameters
    ----------
    hits : Hits
    k : (h,) int
        Index of the first voxel centre at or past each crossing.
    n : int
        Voxels along the rays.
    rays : int
        Number of rays.
    """
    inner = (k > 0) & (k < n)
    if inner.all():
        return hits
    if hits.ordered:
        # In ray-then-depth order the ones to keep are where k changes side.
        same_next = np.r_[hits.ray[1:] == hits.ray[:-1], False]
        same_prev = np.r_[False, same_next[:-1]]
        k_next = np.r_[k[1:], n + 1]
        k_prev = np.r_[-1, k[:-1]]
        keep = (inner | ((k == 0) & ~(same_next & (k_next == 0)))
                | ((k == n) & ~(same_prev & (k_prev == n))))
        out = hits.take(keep)
        out.ordered = True
        return out
    keep = [np.flatnonzero(inner)]
    for side, pick in ((0, np.maximum), (n, np.minimum)):
        sub = np.flatnonzero(k == side)
        if len(sub) == 0:
            continue
        ray, depth = hits.ray[sub], hits.depth[sub]
        # The extreme depth per ray, then among equal depths the extreme
        # triangle: the first or last of the ray in sorted (depth, triangle) order.
        ext = np.full(rays, np.inf if pick is np.minimum else -np.inf)
        pick.at(ext, ray, depth)
        sub = sub[depth == ext[ray]]
        tri = hits.triangle[sub]
        ray = hits.ray[sub]
        best = np.full(rays, np.iinfo(np.int64).max if pick is np.minimum else -1, dtype=np.int64)
        pick.at(best, ray, tri)
        keep.append(sub[tri == best[ray]])
    return hits.take(np.sort(np.concatenate(keep)))


class _Axis(NamedTuple):
    """The crossings along one axis, as the chunks read them (see :func:`_prepare`)."""

    axis: int
    #: (n_axis,) float32: voxel centres along the axis, from the low face.
    centres: np.ndarray
    #: (rays,) float64 and int32: each ray's first crossing depth (inf if
    #: none) and its index in :attr:`_Crossings.rows` (-1 if none).
    first: np.ndarray
    first_hit: np.ndarray
    #: One entry per (ray, voxel) where a crossing is the last one on its ray
    #: at or before that voxel's centre: ``layer`` (e,) int64, sorted, the
    #: voxel's z (for rays along z, its ``k``), so that a chunk of layers is
    #: one run of entries; ``u`` (e,) int64 the ray's place in the layer (y
    #: for rays along x, x for rays along y, ``x + nx * y`` for rays along
    #: z); ``k`` (e,) int64 the voxel's coordinate along the axis; ``value``
    #: (e,) int32 the crossing's index in :attr:`_Crossings.rows`.
    layer: np.ndarray
    u: np.ndarray
    k: np.ndarray
    value: np.ndarray


class _Crossings(NamedTuple):
    """Every candidate crossing of a block, all axes concatenated (z, then y, then x)."""

    #: (m,) int64 and (m, 2) float64: each crossing's triangle and barycentrics.
    triangle: np.ndarray
    bary: np.ndarray
    #: (m + 1,) complex128: per crossing, four float32 (its depth and
    #: facing, and the depth and facing of the next crossing on its ray, inf
    #: and 1 if none), gathered as one 16-byte item (several times faster
    #: than fancy-indexing rows of an (m, 4) float32 array); the last row
    #: (-inf, 1, inf, 1) stands for "no crossing yet".
    rows: np.ndarray
    axes: list


def _prepare(mesh, grid, cast, jobs: int = 1) -> _Crossings:
    """Sort each axis's crossings and build the tables that every chunk reads.

    Parameters
    ----------
    cast : dict axis -> (Hits, Columns)
        Crossings of the grid's column rays along each axis.
    jobs : int
        Threads (the axes are prepared side by side).
    """
    normals = unit_normals(mesh)
    order = [a for a in (2, 1, 0) if a in cast]  # ties go to z, then y, then x
    if jobs > 1 and len(order) > 1:
        with ThreadPoolExecutor(max_workers=min(jobs, len(order))) as pool:
            done = list(pool.map(lambda a: _prepare_axis(*cast[a], grid, a, normals), order))
    else:
        done = [_prepare_axis(*cast[a], grid, a, normals) for a in order]
    parts, tables, axes = [], [], []
    offset = 0
    for hits, table, ax in done:
        if len(hits) == 0:
            continue
        # Crossing numbers count through the axes concatenated.
        ax.first_hit[ax.first_hit >= 0] += offset
        ax.value[:] += offset
        parts.append(hits)
        tables.append(table)
        axes.append(ax)
        offset += len(hits)
    tables.append(np.array([[-np.inf, 1.0, np.inf, 1.0]], dtype=np.float32))
    rows = np.concatenate(tables).view(np.complex128).reshape(-1)
    hits = Hits.concatenate(parts)
    return _Crossings(hits.triangle, hits.bary, rows, axes)


def _prepare_axis(hits, cols, grid, axis: int, normals):
    """One axis of :func:`_prepare`: its sorted crossings, their table rows and an _Axis.

    Crossing numbers in the _Axis count from 0 on this axis.
    """
    n_axis = grid.shape[axis]
    centres = (np.arange(n_axis) + 0.5) * grid.spacing[axis]  # from the low face, like depths
    hits = relevant_crossings(hits, np.searchsorted(centres, hits.depth, side="left"),
                              n_axis, cols.count).sorted()
    k = np.searchsorted(centres, hits.depth, side="left")
    # float32 is plenty to choose the nearer crossing and halves the traffic.
    same = np.r_[hits.ray[1:] == hits.ray[:-1], False]
    facing = np.maximum(np.abs(normals[hits.triangle, axis]), 1 / np.sqrt(3))
    table = np.empty((len(hits), 4), dtype=np.float32)
    table[:, 0] = hits.depth
    table[:, 1] = facing
    table[:, 2] = np.where(same, np.r_[hits.depth[1:], 0.0], np.inf)
    table[:, 3] = np.r_[facing[1:], 1.0]
    first = np.full(cols.count, np.inf)
    first_hit = np.full(cols.count, -1, dtype=np.int32)
    if len(hits):
        starts = np.r_[True, ~same[:-1]]
        first[hits.ray[starts]] = hits.depth[starts]
        first_hit[hits.ray[starts]] = np.flatnonzero(starts)
    # The deepest crossing at or before each voxel centre is a running
    # maximum of crossing numbers (sorted by ray, then depth, so deeper means
    # larger) from the first voxel past each crossing: one entry per (ray,
    # voxel), the last crossing there.
    keep = np.flatnonzero(k < n_axis)
    ray, kk = hits.ray[keep], k[keep]
    last = np.r_[(ray[1:] != ray[:-1]) | (kk[1:] != kk[:-1]), True][:len(keep)]
    ray, kk, value = ray[last], kk[last], keep[last].astype(np.int32)
    if axis == 2:
        # In ray order; chunks of z layers want them by layer.
        order = np.argsort(kk, kind="stable")
        layer, u, kk, value = kk[order], ray[order], kk[order], value[order]
    else:
        layer, u = ray // cols.nu, ray % cols.nu
    ax = _Axis(axis, centres.astype(np.float32), first, first_hit, layer, u, kk, value)
    return hits, table, ax


def _z_carry(ax: _Axis, nxy: int, z0: int) -> np.ndarray:
    """Per column (``x + nx * y``), the deepest crossing along z before layer ``z0`` (-1: none)."""
    carry = np.full(nxy, -1, dtype=np.int32)
    e = np.searchsorted(ax.layer, z0, side="left")
    np.maximum.at(carry, ax.u[:e], ax.value[:e])
    return carry


def _index_volumes(crossings, shape, z0: int, t: int, volumes, carry) -> None:
    """Per axis, the deepest crossing at or before each voxel of layers ``z0 .. z0 + t``.

    Parameters
    ----------
    volumes : list of (>= nx * ny * t,) int32
        One per axis of ``crossings.axes``, filled in place: along y and z
        indexed as the chunk's F order, ``x + nx * (y + ny * z)``, along x
        ``y + ny * (x + nx * z)`` (``z`` counted from ``z0``); -1 where the
        ray has no crossing yet. The running maximum along the axis then
        steps through whole planes of contiguous rows, vectorised (a scan
        along the contiguous axis goes element by element, several times
        slower).
    carry : (nx * ny,) int32 or None
        Along z: the index before layer ``z0`` (see :func:`_z_carry`),
        advanced to the chunk's last layer.
    """
    nx, ny, _ = shape
    nxy = nx * ny
    for ax, g in zip(crossings.axes, volumes):
        g = g[:nxy * t]
        lo, hi = np.searchsorted(ax.layer, [z0, z0 + t], side="left")
        if ax.axis == 2:
            planes = g.reshape((nxy, t), order="F")
            planes[:, 0] = carry
            planes[:, 1:] = -1
            g[ax.u[lo:hi] + nxy * (ax.k[lo:hi] - z0)] = ax.value[lo:hi]
            for i in range(1, t):
                np.maximum(planes[:, i], planes[:, i - 1], out=planes[:, i])
            carry[:] = planes[:, t - 1]
        else:
            # Along y the F order itself; along x, x in the middle (y, x, z).
            # Either way each step of the scan is one plane of contiguous rows.
            n_u, n_a = (nx, ny) if ax.axis == 1 else (ny, nx)
            g.fill(-1)
            g[ax.u[lo:hi] + n_u * (ax.k[lo:hi] + n_a * (ax.layer[lo:hi] - z0))] = ax.value[lo:hi]
            cube = g.reshape((n_u, n_a, t), order="F")
            for i in range(1, n_a):
                np.maximum(cube[:, i], cube[:, i - 1], out=cube[:, i])


def _nearest(crossings, shape, z0: int, t: int, volumes, vox, x, y, z, inv_scale):
    """For some inside voxels of a chunk, the nearest of their six axis crossings.

    Parameters
    ----------
    volumes : list of int32 arrays
        The chunk's index volumes (:func:`_index_volumes`).
    vox : (k,) intp
        The voxels' F-order indices within the chunk.
    x, y, z : (k,) intp
        Their coordinates (``z`` counted from ``z0``).
    inv_scale : float32
        One over the smallest voxel edge.

    Returns
    -------
    best : (k,) int32
        Index of each voxel's nearest crossing (0 where none was found).
    dist : (k,) float32
        Estimated distance from the voxel centre to the surface there, in
        voxels (inf where none).

    Notes
    -----
    A crossing at axis distance ``d`` on a triangle with unit normal ``n``
    is ranked by ``d * max(|n_axis|, 1/sqrt(3))``: the distance to the
    triangle's plane where that plane faces the axis, which is the true
    distance for the axis that sees the nearest surface best (some axis has
    ``|n_axis| >= 1/sqrt(3)``), while a crossing far along the axis cannot win
    just because its plane happens to pass close by.
    """
    nx, ny, _ = shape
    best = best_d = None
    for ax, g in zip(crossings.axes, volumes):
        # np.take: several times faster than fancy indexing for these gathers.
        if ax.axis == 2:
            prev = np.take(g, vox)
            c = np.take(ax.centres, z + z0)
        elif ax.axis == 1:
            prev = np.take(g, vox)
            c = np.take(ax.centres, y)
        else:
            prev = np.take(g, y + ny * (x + nx * z))
            c = np.take(ax.centres, x)
        row = np.take(crossings.rows, prev).view(np.float32).reshape(-1, 4)
        d_prev = (c - row[:, 0]) * row[:, 1]
        d_next = (row[:, 2] - c) * row[:, 3]
        before = None
        if prev.min(initial=0) < 0:
            # Inside yet before every crossing of its column: only possible
            # with inside tests other than this axis's parity.
            before = np.flatnonzero(prev < 0)
            zb = z[before] + z0
            ray = (x[before] + nx * y[before] if ax.axis == 2 else
                   x[before] + nx * zb if ax.axis == 1 else y[before] + ny * zb)
            pick = ax.first_hit[ray]
            facing = crossings.rows[pick].view(np.float32).reshape(-1, 4)[:, 1]
            d_next[before] = (ax.first[ray] - c[before]) * facing
        use_next = d_next < d_prev
        d = np.minimum(d_next, d_prev, out=d_prev)  # no NaN: the same as picking by use_next
        d *= inv_scale
        chosen = prev + use_next
        if before is not None:
            chosen[before] = np.where(use_next[before], pick, prev[before])
        if best is None:
            # The first axis sets the running best (0 where it found nothing).
            np.copyto(chosen, 0, where=np.isinf(d))
            best_d, best = d, chosen
            continue
        # Masked copies: much cheaper than gathering and scattering the winners.
        better = d < best_d
        np.copyto(best_d, d, where=better)
        np.copyto(best, chosen, where=better)
    if best is None:
        return np.zeros(len(vox), np.int32), np.full(len(vox), np.inf, dtype=np.float32)
    return best, best_d


def _work_space(crossings, voxels: int) -> dict:
    """Arrays one thread reuses from chunk to chunk: index volumes and the shading cache."""
    m = len(crossings.triangle)
    return {"volumes": [np.empty(voxels, dtype=np.int32) for _ in crossings.axes],
            "rgba": np.empty(m, dtype=np.uint32), "shaded": np.zeros(m, dtype=bool),
            "pending": np.zeros(m, dtype=bool), "chunk": np.empty(voxels, dtype=np.uint32)}


def _colour_chunks(mesh, grid, occupancy, crossings, chunks, base, space, *, shading,
                   sink=None):
    """Colour the inside voxels of consecutive chunks of z layers, in place.

    Parameters
    ----------
    crossings : _Crossings
    chunks : list of (z0, t)
        ``t`` layers from ``z0``, each chunk following the one before.
    base : (nz, ny, nx, 4) uint8 or None
        The block's colours, C order (x fastest); the chunks' voxels are
        written.
    space : dict
        Work space (:func:`_work_space`).
    sink : callable, optional
        Instead of ``base``: given each chunk's colours (see
        :func:`colour_volume`).
    """
    nx, ny, nz = grid.shape
    nxy = nx * ny
    inv_scale = np.float32(1.0 / grid.spacing.min())
    centres = [grid.centres(a) for a in range(3)]
    along_z = next((ax for ax in crossings.axes if ax.axis == 2), None)
    carry = _z_carry(along_z, nxy, chunks[0][0]) if along_z is not None else None
    volumes = space["volumes"]
    # The colour of each crossing a deep voxel takes, shaded once per thread
    # (shading is row by row, so which batch a crossing falls in is immaterial).
    hit_rgba, shaded, pending = space["rgba"], space["shaded"], space["pending"]
    for z0, t in chunks:
        # One uint32 per voxel: RGBA bytes in memory order, index = F-order voxel index.
        flat = (space["chunk"][:nxy * t] if sink else
                base[z0:z0 + t].reshape(-1, 4).view(np.uint32).reshape(-1))
        flat.fill(0)
        vox = np.flatnonzero(occupancy[:, :, z0:z0 + t].reshape(-1, order="F"))
        if len(vox) == 0:
            if carry is not None:
                carry = _z_carry(along_z, nxy, z0 + t)
            if sink:
                sink(z0, flat.view(np.uint8).reshape(t, ny, nx, 4))
            continue
        _index_volumes(crossings, grid.shape, z0, t, volumes, carry)
        best = np.empty(len(vox), dtype=np.int32)
        dist = np.empty(len(vox), dtype=np.float32)
        # In blocks small enough for the temporaries to stay in cache.
        for s in range(0, len(vox), BLOCK):
            v = vox[s:s + BLOCK]
            q = v // nx
            z = q // ny
            best[s:s + BLOCK], dist[s:s + BLOCK] = _nearest(
                crossings, grid.shape, z0, t, volumes, v, v - q * nx, q - z * ny, z, inv_scale)
        # Deeper voxels take their crossing's own colour (every crossing is a
        # surface point with a known triangle and barycentrics), each crossing
        # shaded once; near voxels' entries are replaced below.
        new = np.compress(~np.take(shaded, best), best)
        if len(new):
            # Each new crossing once: marked, then read back in order.
            lo, hi = new.min(), new.max() + 1
            pending[new] = True
            new = np.flatnonzero(pending[lo:hi]) + lo
            pending[new] = False
            hit_rgba[new] = pack(shade(mesh, np.take(crossings.triangle, new),
                                        np.take(crossings.bary, new, axis=0), shading))
            shaded[new] = True
        rgba = np.take(hit_rgba, best)
        near = np.flatnonzero(dist < REFINE)
        if len(near):
            # Near the surface, the exact closest point on the crossing's triangle.
            v = vox[near]
            q = v // nx
            z = q // ny
            p = np.stack([centres[0][v - q * nx], centres[1][q - z * ny], centres[2][z + z0]],
                         axis=1)
            tri = np.take(crossings.triangle, np.take(best, near))
            b = closest_on_triangles(p, np.take(mesh.triangles, tri, axis=0))
            rgba[near] = pack(shade(mesh, tri, b, shading))
        flat[vox] = rgba
        if sink:
            sink(z0, flat.view(np.uint8).reshape(t, ny, nx, 4))


def fast_colours(mesh, grid, occupancy, cast, *, shading: Shading = Shading(), jobs=1, out=None,
                 sink=None):
    """RGBA colours of the inside voxels from their six axis crossings; alpha 0 outside.

    Parameters
    ----------
    mesh : Mesh
    grid : Grid
    occupancy : (nx, ny, nz) bool
    cast : dict axis -> (Hits, Columns)
        Crossings along each axis (see :func:`_prepare`).
    shading : Shading
        The options ``diffuse`` and ``ambient`` (:meth:`Shading.of`).
    out : (nz, ny, nx, 4) uint8, C order, optional
        The array to write every voxel's colour into (reused by a caller
        making many blocks, so that its memory is not faulted in afresh each
        time); ``colors`` is its transpose.
    sink : callable, optional
        Instead of making the array, hand over each chunk
        of layers as soon as it is coloured, ``sink(z0, rgba)`` with
        ``rgba`` (t, ny, nx, 4) uint8 C order, layers ``z0 .. z0 + t``;
        called from the worker threads, in no particular order, with a
        buffer that is reused once it returns.

    Returns
    -------
    colors : (nx, ny, nz, 4) uint8, or None with ``sink``
        Indexed ``[x, y, z, channel]``; in memory RGBA-interleaved with x
        fastest (``colors.transpose(2, 1, 0, 3)`` is C-contiguous).
    """
    nx, ny, nz = grid.shape
    # Each chunk clears its own layers just before filling them (in cache).
    base = None if sink else np.empty((nz, ny, nx, 4), dtype=np.uint8) if out is None else out
    colors = None if sink else base.transpose(2, 1, 0, 3)
    crossings = _prepare(mesh, grid, cast, jobs)
    if not crossings.axes:
        if sink:
            for z0 in range(nz):
                sink(z0, np.zeros((1, ny, nx, 4), dtype=np.uint8))
        else:
            base.fill(0)
        return colors
    # Chunks of z layers, in tasks of consecutive chunks handed to the threads
    # as they come free (each task carries the z axis's index from chunk to
    # chunk; the chunks' results do not depend on which thread ran them).
    t = max(1, min(nz, CHUNK_VOXELS // (nx * ny)))
    chunks = [(z0, min(t, nz - z0)) for z0 in range(0, nz, t)]
    per_task = max(1, TASK_VOXELS // (t * nx * ny))
    tasks = [chunks[s:s + per_task] for s in range(0, len(chunks), per_task)]
    lock = threading.Lock()
    todo = iter(tasks)
    failed = threading.Event()  # one thread's error stops the others' next tasks

    def worker():
        # Work space made once per thread, reused by each of its tasks.
        space = _work_space(crossings, nx * ny * t)
        while not failed.is_set():
            with lock:
                task = next(todo, None)
            if task is None:
                return
            try:
                _colour_chunks(mesh, grid, occupancy, crossings, task, base, space,
                               shading=shading, sink=sink)
            except BaseException:
                failed.set()
                raise

    n = min(jobs, len(tasks))
    if n <= 1:
        worker()
    else:
        with ThreadPoolExecutor(max_workers=n) as pool:
            for f in [pool.submit(worker) for _ in range(n)]:
                f.result()
    return colors
