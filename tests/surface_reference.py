"""An exact reference for surface voxels, in rational arithmetic, independent of geovox.surface.

Each triangle (a point, segment or triangle: any three vertices) is clipped
against each candidate voxel's *closed* box with Sutherland-Hodgman, in
:class:`fractions.Fraction` arithmetic; the clipped set ``K`` is the convex
hull of the output vertices (degenerate polygons included: the output of a
clipped segment is its clipped ends, repeated). Then the half-open rule:
the voxel is on iff ``K`` is non-empty and, for every axis on which the voxel
is not the grid's last, some vertex of ``K`` lies below the box's top (``K``
is convex and inside the closed box, so ``K`` misses the half-open box only
when it lies wholly in one of its open top faces).
"""

from __future__ import annotations

import math
from fractions import Fraction

import numpy as np


def _clip(poly, axis, value, keep_above):
    """Clip polygon ``poly`` (list of 3-tuples of Fraction) to the closed half-space."""
    out = []
    m = len(poly)
    for i in range(m):
        a, b = poly[i], poly[(i + 1) % m]
        ina = a[axis] >= value if keep_above else a[axis] <= value
        inb = b[axis] >= value if keep_above else b[axis] <= value
        if ina:
            out.append(a)
        if ina != inb:
            t = (value - a[axis]) / (b[axis] - a[axis])
            out.append(tuple(a[c] + t * (b[c] - a[c]) for c in range(3)))
    return out


def clipped(tri, box_lo, box_hi):
    """The vertices of the triangle clipped to the closed box (an empty list: they miss)."""
    poly = [tuple(p) for p in tri]
    for a in range(3):
        poly = _clip(poly, a, box_lo[a], True)
        if not poly:
            return []
        poly = _clip(poly, a, box_hi[a], False)
        if not poly:
            return []
    return poly


def touches_only(tri, box_lo, box_hi):
    """Whether the triangle meets the closed box but not its interior: a tie on its boundary.

    ``K`` (the clipped set) misses the open box iff it lies in one of the
    box's faces: every vertex of ``K`` at ``lo_a``, or every one at ``hi_a``.
    """
    poly = clipped(tri, box_lo, box_hi)
    return bool(poly) and any(all(p[a] == box_lo[a] for p in poly)
                              or all(p[a] == box_hi[a] for p in poly) for a in range(3))


def meets(tri, box_lo, box_hi, last):
    """Whether the triangle meets the box, half-open on the axes where ``last[a]`` is False.

    Parameters
    ----------
    tri : sequence of 3 points, each 3 Fractions
    box_lo, box_hi : 3 Fractions each
    last : 3 bools: the voxel is the grid's last along that axis (its box is closed there)
    """
    poly = clipped(tri, box_lo, box_hi)
    return bool(poly) and all(last[a] or any(p[a] < box_hi[a] for p in poly) for a in range(3))


def reference_voxels(triangles, lo, spacing, shape):
    """(nx, ny, nz) bool: the rule for the exact triangles (floats taken as exact rationals).

    Parameters
    ----------
    triangles : (n, 3, 3) float64
    lo, spacing : (3,) float64
        The grid's corner and voxel size; voxel ``i`` spans ``lo + i * spacing``
        to ``lo + (i + 1) * spacing`` exactly.
    shape : (3,) int
    """
    lo = [Fraction(float(x)) for x in lo]
    h = [Fraction(float(x)) for x in spacing]
    index = [[[(Fraction(float(p[a])) - lo[a]) / h[a] for a in range(3)] for p in t]
             for t in np.asarray(triangles, dtype=np.float64) if np.isfinite(t).all()]
    return reference_index_voxels(index, shape)


def reference_index_voxels(triangles, shape):
    """(nx, ny, nz) bool: the rule in index space, where voxel ``i`` spans ``[i, i + 1]``.

    Parameters
    ----------
    triangles : sequence of triangles, each 3 points of 3 Fractions (voxel units)
    shape : (3,) int
    """
    out = np.zeros(tuple(shape), dtype=bool)
    for tri in triangles:
        ranges = []
        for a in range(3):
            f = [p[a] for p in tri]
            i0 = max(math.floor(min(f)) - 1, 0)
            i1 = min(math.floor(max(f)) + 1, shape[a] - 1)
            ranges.append(range(i0, i1 + 1))
        for i in ranges[0]:
            for j in ranges[1]:
                for k in ranges[2]:
                    idx = (i, j, k)
                    if out[idx]:
                        continue
                    last = [idx[a] == shape[a] - 1 for a in range(3)]
                    if meets(tri, idx, [x + 1 for x in idx], last):
                        out[idx] = True
    return out
