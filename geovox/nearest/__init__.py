"""The nearest-point stage: each asked-for voxel's exact nearest surface point.

One search answers every stage that needs a voxel's nearest surface point:
exact colour asks it for the inside voxels (and shades in the compiled
kernel), labels by nearest part for theirs, and the distance field for the
voxels of its band (or for every voxel). For each voxel centre ``x`` of a
mask the answer is the triangle ``T`` at the smallest Euclidean distance
``d(x, T)`` (ties within ``TIE`` voxel sizes go to the smallest index), the
barycentrics of the closest point on it, and that distance; nothing is
estimated (see :mod:`geovox.nearest.search` for the branch and bound and
its bounds).

| module | holds |
|---|---|
| :mod:`geovox.nearest.search` | the search: NumPy, the compiled kernel's driver, the brute-force reference |

:func:`nearest_distances` is the distance's question for any set of voxels
(``band = inf``: all of them); :func:`point_distances` turns a triangle and
barycentrics into the distance, with the compiled kernel's operations in
order, so both searches give the same float32 bits. A narrow band has an
engine of its own, :func:`band_distances`: each triangle measured at the
voxel centres that can be within the band of it (a few hundred a triangle),
which costs less than a search per voxel where the voxels are only a thin
shell around the surface; its distances are the same minimum, exactly.

The masks are voxels of a block of the whole grid; coordinates are taken
relative to the whole grid's low corner (``frame``), so a slab's answers are
the whole grid's bit for bit.
"""

from __future__ import annotations

import numpy as np

from .search import (CHUNK, MARGIN, TIE, band_tables, brute_force, closest, kernel_module,
                     nearest_inside, prepare, run_kernel)

__all__ = ["CHUNK", "MARGIN", "TIE", "band_distances", "brute_force", "closest", "kernel_module",
           "nearest_distances", "nearest_inside", "point_distances", "prepare", "run_kernel"]

#: (voxel, triangle) pairs per block of the NumPy band engine.
PAIR_BLOCK = 1 << 20


def point_distances(points: np.ndarray, triangles: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Distance from each point to the point of its triangle at barycentrics ``uv``.

    Parameters
    ----------
    points : (n, 3) float64
        In the frame of ``triangles``.
    triangles : (n, 3, 3) float64
        Each point's triangle.
    uv : (n, 2) float64
        Weights of vertices 1 and 2 (vertex 0 has ``1 - u - v``).

    Returns
    -------
    (n,) float32
        ``|x - (a + u (b - a) + v (c - a))|``, each difference and sum taken in
        the compiled kernel's order (``geovox/_nearest.pyx``, ``emit``).
    """
    a = triangles[:, 0]
    ab = triangles[:, 1] - a
    ac = triangles[:, 2] - a
    d = (points - a) - (uv[:, :1] * ab + uv[:, 1:] * ac)
    return np.sqrt(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]).astype(np.float32)


def nearest_distances(triangles, mask, spacing, *, origin, z0=0, jobs=1, cache=None,
                      out=None) -> np.ndarray:
    """Exact distance from every voxel centre of ``mask`` to the surface.

    Parameters
    ----------
    triangles : (t, 3, 3) float64
    mask : (nx, ny, nz) bool
        The block's voxels to answer.
    spacing : (3,) float64
        The whole grid's voxel size.
    origin : (3,) float64
        The whole grid's low corner; voxel ``(i, j, k)`` of the block has its
        centre at ``origin + ((i, j, k + z0) + 0.5) * spacing``.
    z0 : int
        The block's first layer in the whole grid.
    jobs : int
        Threads; the result does not depend on it.
    cache : dict, optional
        The mesh's cache for the compiled kernel's per-triangle tables.
    out : (nx * ny * nz,) float32, optional
        Where to write (F-order voxel index); its values outside ``mask``
        are left as they are.

    Returns
    -------
    (nx * ny * nz,) float32
        ``out`` (or a new array, ``inf`` outside ``mask``): the distance of
        each voxel of ``mask`` in the mesh's units, F-order voxel index. The
        compiled search and the NumPy one (as the conversion's kernel choice
        says, :func:`kernel_module`) give the same bits.
    """
    mask = np.asarray(mask, bool)
    if out is None:
        out = np.full(mask.size, np.inf, np.float32)
    if not mask.any() or len(triangles) == 0:
        return out
    triangles = np.asarray(triangles, float)
    origin = np.asarray(origin, float)
    spacing = np.asarray(spacing, float)
    module = kernel_module()
    if module is not None:
        run_kernel(module, triangles, mask, spacing, origin=origin, z0=z0, jobs=jobs,
                   output=lambda k: k.dist_output(out), cache=cache)
        return out
    nx, ny, _ = mask.shape
    rel = triangles - origin

    def emit(vox, tri, uv):
        centres = (vox + np.array([0, 0, z0])) + 0.5
        x = centres * spacing
        out[vox[:, 0] + nx * (vox[:, 1] + ny * vox[:, 2])] = point_distances(x, rel[tri], uv)

    nearest_inside(triangles, mask, spacing, origin=origin, z0=z0, jobs=jobs, emit=emit)
    return out


def band_distances(triangles, shape, spacing, *, origin, limit, z0=0, jobs=1, cache=None,
                   out=None) -> np.ndarray:
    """Exact distance to the surface of every voxel centre within ``limit`` of it.

    Each triangle is measured (:func:`~geovox.nearest.search.closest`, the
    search's float64 formula) at every voxel centre that can be within
    ``limit`` of it, and each voxel keeps the smallest distance: for a
    centre within ``limit`` of the surface that is its exact distance,
    since its nearest triangle is among those measured. Other centres are
    left ``inf`` or get the distance of some triangle, more than ``limit``
    (what a caller clamps to the band).

    Parameters
    ----------
    triangles : (t, 3, 3) float64
    shape : (nx, ny, nz) int
        The block's voxels.
    spacing, origin, z0, jobs, cache
        As for :func:`nearest_distances`.
    limit : float
        The band's half-width in the mesh's units, finite.
    out : (nx * ny * nz,) float32, optional
        Lowered where a triangle is nearer (default: a new array of ``inf``).

    Returns
    -------
    (nx * ny * nz,) float32, F-order voxel index
        The compiled engine (``geovox/_nearest.pyx``, ``band_distances``) and
        the NumPy one give the same values wherever they are within ``limit``.
    """
    nx, ny, nz = (int(n) for n in shape)
    if out is None:
        out = np.full(nx * ny * nz, np.inf, np.float32)
    if len(triangles) == 0 or out.size == 0:
        return out
    triangles = np.asarray(triangles, float)
    origin = np.asarray(origin, float)
    spacing = np.asarray(spacing, float)
    module = kernel_module()
    if module is not None:
        from ..kernels import openmp_threads

        rows, flat, lo, hi = band_tables(triangles, origin, cache)
        module.band_distances(rows, flat, lo, hi, (nx, ny, nz), int(z0),
                              tuple(float(h) for h in spacing), float(limit), out,
                              openmp_threads(jobs), spatial_order(lo, spacing))
        return out
    _numpy_band(triangles, (nx, ny, nz), spacing, origin, float(limit), int(z0), jobs, out)
    return out


def spatial_order(lo: np.ndarray, spacing) -> np.ndarray:
    """(t,) int64: triangles ordered by the 4-voxel cell of their box's low corner, z, y, x.

    The band engine measures them so: neighbours one after another, so the
    values it writes stay in cache.
    """
    cell = np.floor(lo / (4.0 * np.asarray(spacing, float))).astype(np.int64)
    return np.lexsort((cell[:, 0], cell[:, 1], cell[:, 2])).astype(np.int64)


def _numpy_band(triangles, shape, spacing, origin, limit, z0, jobs, out) -> None:
    """:func:`band_distances` in NumPy: every centre in each triangle's box grown by ``limit``."""
    from concurrent.futures import ThreadPoolExecutor

    tris = prepare(triangles, origin, closest_only=True)
    nx, ny, nz = shape
    lo = tris["lo"] - limit
    hi = tris["hi"] + limit
    # Block index ranges of the centres (i + 0.5) h (+ z0 along z) inside each grown box.
    offset = np.array([0, 0, z0])
    first = np.maximum(np.ceil(lo / spacing - 0.5) - offset, 0).astype(np.int64)
    last = np.minimum(np.floor(hi / spacing - 0.5) - offset + 1, shape).astype(np.int64)
    size = np.maximum(last - first, 0)
    counts = size.prod(axis=1)
    ends = np.cumsum(counts)
    starts = ends - counts
    total = int(ends[-1]) if len(ends) else 0

    def block(a, b):
        t0 = int(np.searchsorted(ends, a, side="right"))
        t1 = int(np.searchsorted(ends, b - 1, side="right"))
        tids = np.arange(t0, t1 + 1)
        seg = np.maximum(np.minimum(ends[tids], b) - np.maximum(starts[tids], a), 0)
        t = np.repeat(tids, seg)
        local = np.arange(a, b, dtype=np.int64) - np.repeat(starts[tids], seg)
        sx, sy = size[t, 0], size[t, 1]
        ix = first[t, 0] + local % sx
        iy = first[t, 1] + (local // sx) % sy
        iz = first[t, 2] + local // (sx * sy)
        x = (np.stack([ix, iy, iz + z0], axis=1) + 0.5) * spacing
        d2, _ = closest(x, t, tris)
        return ix + nx * (iy + ny * iz), np.sqrt(d2).astype(np.float32)

    # Threads measure; the minimum is taken in this thread (ufunc.at on a
    # shared array is not safe to run concurrently).
    bounds = [(s, min(s + PAIR_BLOCK, total)) for s in range(0, total, PAIR_BLOCK)]
    with ThreadPoolExecutor(max_workers=max(1, jobs or 1)) as pool:
        for lin, d in pool.map(lambda ab: block(*ab), bounds):
            np.minimum.at(out, lin, d)
