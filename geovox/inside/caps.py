"""Caps over an open mesh's holes, and the mesh closed by them.

An open target M has its holes filled with caps K: for each closed loop of
the boundary (the directed edges whose opposite edge is missing, see
:func:`geovox.inside.edges.boundary_edges`), a minimum-area triangulation of
the loop's vertices (:mod:`geovox.inside.bridge`; a fan from the centroid for
long loops and for pieces that are not loops), oriented so that M + K is
closed. The winding number of M does not depend on the caps
(``w_M = w_{M+K} - w_K``, :mod:`geovox.inside.winding`), the cost of summing
``w_K`` does (:mod:`geovox.inside.captree`).
"""

from __future__ import annotations

import numpy as np

from ..kernels import lattice
from ..mesh import Mesh
from .bridge import loop_caps
from .edges import boundary_edges, components


def caps(mesh: Mesh, edges: np.ndarray, small: bool = False) -> np.ndarray:
    """Cap triangles closing the boundary: a fan per connected boundary piece.

    ``small``: a minimum-area triangulation over each closed loop instead
    (:func:`geovox.inside.bridge.loop_caps`; the winding number's caps, see :func:`bridged`).

    Returns
    -------
    triangles : (k, 3, 3) float64
        One triangle ``(centroid, b, a)`` per boundary edge ``a -> b`` (with
        ``small``, ``n - 2`` per loop of ``n`` edges, oriented the same way).
    piece : (k,) int64
        The boundary piece each belongs to.
    """
    if len(edges) == 0:
        return np.zeros((0, 3, 3)), np.zeros(0, np.int64)
    pos = mesh.vertices
    vid = _position_ids(mesh, edges)
    nv = int(vid.max()) + 1
    kernel = lattice()
    found = None if kernel is None else kernel.boundary_loops(vid, nv)
    if found is None:  # NumPy, or a position where loops do not balance
        _, label, _ = components(nv, vid[:, 0], vid[:, 1])
        piece, rank = loops(vid, label[vid[:, 0]]), None
    else:
        piece, rank = found
    if small:
        return loop_caps(pos, edges, vid, piece, rank)
    npieces = int(piece.max()) + 1
    mid = (pos[edges[:, 0]] + pos[edges[:, 1]]) / 2
    centroid = np.stack([np.bincount(piece, weights=mid[:, k], minlength=npieces)
                         for k in range(3)], axis=1) / np.bincount(piece, minlength=npieces)[:, None]
    return np.stack([centroid[piece], pos[edges[:, 1]], pos[edges[:, 0]]], axis=1), piece


def _position_ids(mesh: Mesh, edges: np.ndarray) -> np.ndarray:
    """(k, 2) int64: the edges' ends numbered by position, in lexicographic order.

    Pieces are connected through shared positions, not vertex indices:
    ``np.unique`` of the ends' positions numbers them. Where the mesh knows
    its faces over positions in that order (:attr:`Mesh.geometric_faces`;
    the repaired copy's are its own faces), the ends' numbers there, made
    dense, are the same, without sorting coordinates.
    """
    if "geometric_faces" not in mesh._cache:
        _, vid = np.unique(mesh.vertices[edges.reshape(-1)], axis=0, return_inverse=True)
        return vid.reshape(-1, 2)
    geo = np.empty(len(mesh.vertices), np.int64)
    geo[mesh.faces.reshape(-1)] = mesh.geometric_faces.reshape(-1)
    at = geo[edges]
    used = np.zeros(int(at.max()) + 1, bool)
    used[at.reshape(-1)] = True
    return (np.cumsum(used) - 1)[at]


def loops(vid: np.ndarray, piece: np.ndarray) -> np.ndarray:
    """Each boundary piece split into closed loops of edges, where it can be: (k,) int64 labels.

    Holes that touch at a vertex form one connected piece, and one fan from
    the piece's centroid then reaches across the model from hole to hole
    (the truck of libigl's tutorial: a piece of 139 edges, 15 vertices
    where loops meet, whose fan has 60 times the area of its net area
    vector). A fan over each closed loop spans the same boundary, so the
    winding number of the mesh is the same, but the caps are small: the
    far-field sums of :func:`cap_winding` then decide far more voxels.

    At each position the k-th edge arriving is continued by the k-th edge
    leaving, and the loops are the cycles of that successor map (labelled
    by pointer jumping, in whole arrays). A piece with a position where as
    many edges do not arrive as leave has no such loops: it keeps one fan.

    Parameters
    ----------
    vid : (k, 2) int64
        Each boundary edge's start and end, as position ids.
    piece : (k,) int64
        Each edge's connected piece.
    """
    k = len(vid)
    out_order = np.argsort(vid[:, 0], kind="stable")
    in_order = np.argsort(vid[:, 1], kind="stable")
    balanced = np.array_equal(vid[out_order, 0], vid[in_order, 1])
    nxt = np.empty(k, np.int64)
    if balanced:
        nxt[in_order] = out_order
    else:  # per piece: balanced pieces still split, where every position balances
        nv = int(vid.max()) + 1
        d = np.bincount(vid[:, 0], minlength=nv) - np.bincount(vid[:, 1], minlength=nv)
        bad = np.zeros(int(piece.max()) + 1, bool)
        bad[piece[(d[vid[:, 0]] != 0) | (d[vid[:, 1]] != 0)]] = True
        ok = ~bad[piece]
        if not ok.any():
            return piece
        sub = np.flatnonzero(ok)
        lab = loops(vid[sub], piece[sub])
        out = piece.copy()
        out[sub] = int(piece.max()) + 1 + lab
        return np.unique(out, return_inverse=True)[1].astype(np.int64)
    label = np.arange(k, dtype=np.int64)
    for _ in range(max(1, int(np.ceil(np.log2(max(k, 2)))) + 1)):
        label = np.minimum(label, label[nxt])
        nxt = nxt[nxt]
    return np.unique(label, return_inverse=True)[1].astype(np.int64)


def capped(mesh: Mesh, small: bool = False):
    """The mesh with every hole closed by a cap (see :func:`caps`; ``small`` as there).

    Returns
    -------
    closed : Mesh
        ``mesh`` itself when it has no boundary; else its faces followed by
        the cap triangles (for a repaired copy, in the room its arrays have
        after them: the first closed mesh made of it shares them).
    cap_tris : (k, 3, 3) float64
    piece : (k,) int64
    """
    key = "bridged" if small else "capped"
    if key in mesh._cache:
        return mesh._cache[key]
    cap_tris, piece = caps(mesh, boundary_edges(mesh), small)
    closed = mesh
    if len(cap_tris):
        nv, nf, k = len(mesh.vertices), len(mesh.faces), len(cap_tris)
        cap_faces = nv + np.arange(3 * k).reshape(-1, 3)
        room = mesh._cache.pop("room", None)  # a repaired copy's (see geovox.inside.repair)
        if room is not None and mesh.vertices.base is room[0] and mesh.faces.base is room[1] \
                and len(room[0]) >= nv + 3 * k and len(room[1]) >= nf + k:
            room[0][nv:nv + 3 * k], room[1][nf:nf + k] = cap_tris.reshape(-1, 3), cap_faces
            verts, faces = room[0][:nv + 3 * k], room[1][:nf + k]
        else:
            verts = np.concatenate([mesh.vertices, cap_tris.reshape(-1, 3)])
            faces = np.concatenate([mesh.faces, cap_faces])
        closed = Mesh(verts, faces, source=mesh.source)
    mesh._cache[key] = (closed, cap_tris, piece)
    return mesh._cache[key]


def bridged(mesh: Mesh):
    """The mesh closed by the winding number's caps: :func:`capped` with ``small`` caps.

    Any caps give the same winding number of the mesh; small ones make it
    cheaper to sum (see :mod:`geovox.inside.bridge`). The coverage density keeps
    the fans of :func:`capped` (its solid is the capped mesh's, so its
    fractions are those of the fans).
    """
    return capped(mesh, small=True)
