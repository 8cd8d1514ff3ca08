"""Pure-NumPy backend: an exact, vectorised rasteriser of the column rays.

Each triangle's projection is scanned over the column centres inside its
bounding box; every (column, triangle) candidate is settled by the exact
integer edge functions of :mod:`geovox.exact`. No rtree, no Embree, no loop
per triangle or per voxel: candidates are generated and tested in blocks of
``block`` pairs, which bounds memory at a few hundred bytes per pair.

Where the compiled lattice search is built (``geovox/_lattice.pyx``, see
:mod:`geovox.kernels`), :func:`rasterise` runs that instead: the same scan
as one loop, with the same hits in the same order.
"""

from __future__ import annotations

import numpy as np

from ..exact import Projection
from ..grid import Columns
from ..kernels import lattice
from ..parallel import for_blocks
from .base import Backend, Hits

#: Candidate pairs tested per block (about 150 MB of temporaries).
BLOCK = 1 << 20


def rasterise(proj: Projection, column_mask: np.ndarray | None = None, block: int = BLOCK,
              triangle_mask: np.ndarray | None = None, jobs: int = 1) -> Hits:
    """Every crossing of the projection's column rays, found by scanning.

    Parameters
    ----------
    proj : Projection
    column_mask : (nu * nv,) bool, optional
        Only report crossings of the rays where this is True.
    block : int
        Candidate pairs per block.
    triangle_mask : (len(proj),) bool, optional
        Only scan these active triangles.
    jobs : int
        Threads scanning blocks at once (the hits are the same for any value;
        the compiled search runs on one).
    """
    nu = proj.columns.nu
    kernel = lattice()
    if kernel is not None:
        ray, depth, tri, bary = kernel.scan(
            proj.coef, proj.tie, proj.area, proj.z, proj.imin, proj.imax, proj.jmin, proj.jmax,
            proj.tri, nu, column_mask, triangle_mask)
        return Hits(ray=ray, depth=depth, triangle=tri, bary=bary)
    width = np.maximum(proj.imax - proj.imin + 1, 0)
    height = np.maximum(proj.jmax - proj.jmin + 1, 0)
    counts = width * height
    if triangle_mask is not None:
        counts = np.where(triangle_mask, counts, 0)
    ends = np.cumsum(counts)
    starts = ends - counts
    total = int(ends[-1]) if len(ends) else 0
    parts = [None] * (-(-total // block))

    def scan(a, b):
        # Triangles whose candidate ranges overlap [a, b).
        t0 = int(np.searchsorted(ends, a, side="right"))
        t1 = int(np.searchsorted(ends, b - 1, side="right"))
        tids = np.arange(t0, t1 + 1)
        seg = np.minimum(ends[tids], b) - np.maximum(starts[tids], a)
        seg = np.maximum(seg, 0)
        t = np.repeat(tids, seg)
        local = np.arange(a, b, dtype=np.int64) - np.repeat(starts[tids], seg)
        w = width[t]
        i = proj.imin[t] + local % w
        j = proj.jmin[t] + local // w
        if column_mask is not None:
            keep = column_mask[i + nu * j]
            t, i, j = t[keep], i[keep], j[keep]
        # The exact test first, then depths only for the pairs that cross
        # (about half of the candidates): the same values proj.crossings gives.
        w = proj.edge_values(t, i, j)
        hit = np.flatnonzero((w > 0).all(axis=1))
        t, i, j, w = t[hit], i[hit], j[hit], w[hit]
        depth, bary = proj.interpolate(t, w)
        parts[a // block] = Hits(ray=i + nu * j, depth=depth, triangle=proj.tri[t], bary=bary)

    for_blocks(scan, total, block, jobs)
    return Hits.concatenate(parts)


class NumpyBackend(Backend):
    """Exact scan-conversion in NumPy; runs everywhere NumPy does."""

    name = "numpy"

    def cast(self, mesh, columns: Columns, jobs: int = 1) -> Hits:
        return rasterise(Projection(mesh.vertices, columns, faces=mesh.faces), jobs=jobs)
