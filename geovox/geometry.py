"""Geometry the stages share: the closest point of a triangle to a point.

Colour (:mod:`geovox.colour`) shades a voxel from its nearest surface point,
density (:mod:`geovox.density`) measures the distance to it, labels take
its material: one routine serves them all, below every stage.
"""

from __future__ import annotations

import numpy as np

__all__ = ["closest_on_triangles"]


def closest_on_triangles(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Barycentric ``(u, v)`` of the closest point on each triangle to each point.

    Parameters
    ----------
    p : (n, 3) float64
    tris : (n, 3, 3) float64

    Returns
    -------
    (n, 2) float64: weights of vertices 1 and 2.

    Notes
    -----
    The Voronoi-region test of Ericson, *Real-Time Collision Detection*, 5.1.5.
    """
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        u = np.where(denom != 0, vb / denom, 0.0)
        v = np.where(denom != 0, vc / denom, 0.0)
        # Edges and vertices, lowest priority first so the checks of
        # Ericson's order win where regions touch.
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        u = np.where(m, 1 - t, u)
        v = np.where(m, t, v)
        t = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        u = np.where(m, 0.0, u)
        v = np.where(m, t, v)
        m = (d6 >= 0) & (d5 <= d6)
        u = np.where(m, 0.0, u)
        v = np.where(m, 1.0, v)
        t = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        u = np.where(m, t, u)
        v = np.where(m, 0.0, v)
        m = (d3 >= 0) & (d4 <= d3)
        u = np.where(m, 1.0, u)
        v = np.where(m, 0.0, v)
        m = (d1 <= 0) & (d2 <= 0)
        u = np.where(m, 0.0, u)
        v = np.where(m, 0.0, v)
    bad = ~(np.isfinite(u) & np.isfinite(v))
    u[bad] = 0.0
    v[bad] = 0.0
    return np.stack([u, v], axis=1)
