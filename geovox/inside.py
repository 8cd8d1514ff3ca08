"""Inside/outside tests: parity, vote and winding, and the automatic choice.

``parity``  odd/even crossings along one axis: exact for closed meshes.
``vote``    parity along x, y and z; the majority decides.
``winding`` the generalised winding number, computed exactly and fast:

    Fill every hole of the mesh M with a cap K: for each connected piece of
    the boundary (the directed edges whose opposite edge is missing), a fan
    of triangles from the piece's centroid, oriented so that M + K is closed.
    For a closed surface the winding number is an integer that the column
    rays give exactly (signed crossings, by the same exact rules as parity),
    and by additivity ``w_M = w_{M+K} - w_K``, where ``w_K`` is the solid
    angle of the cap triangles over 4 pi. A point is inside when
    ``w_M > 1/2``. Since ``w_{M+K}`` is an integer, ``w_K`` only matters where
    ``|w_K| >= 1/2``, and ``|w_K| <= area(K) / (4 pi d^2)`` at distance ``d``
    from a cap, so ``w_K`` is summed exactly only for the voxels near the caps.
    Holes are bridged the way the surface around them suggests, and regions
    where parts of the mesh overlap (self-intersections) count as inside.

``auto`` uses parity when the mesh is closed (every edge, after merging
vertices by position, has a partner edge running the other way) and
``winding`` otherwise, with a warning that says why.
"""

from __future__ import annotations

import warnings

import numpy as np

from .backends.base import Hits
from .errors import GeovoxWarning, ParameterError
from .mesh import Mesh
from .parallel import for_blocks, scan_along

METHODS = ("auto", "parity", "vote", "winding")


def boundary_edges(mesh: Mesh) -> np.ndarray:
    """Directed edges without a partner running the other way (with multiplicity).

    Returns
    -------
    (k, 2) int64
        Vertex indices into ``mesh.vertices`` (merged by position), in the
        direction the faces traverse them. Empty for a closed mesh.
    """
    if "boundary" in mesh._cache:
        return mesh._cache["boundary"]
    f = mesh.geometric_faces
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    e = e[e[:, 0] != e[:, 1]]  # degenerate faces repeat a vertex
    n = int(f.max()) + 1 if len(f) else 1
    lo, hi = np.minimum(e[:, 0], e[:, 1]), np.maximum(e[:, 0], e[:, 1])
    # The common case first, with one sort: closed exactly when every
    # undirected edge is run as often one way as the other. Sorted by
    # (edge, direction), a running +-1 sum returns to 0 at the end of
    # every edge's run.
    forward = e[:, 0] < e[:, 1]
    order = np.sort(2 * (lo * n + hi) + forward)
    net = np.cumsum(np.where(order & 1, 1, -1))
    ends = np.flatnonzero(np.r_[order[1:] >> 1 != order[:-1] >> 1, len(order) > 0])
    if not net[ends].any():
        out = np.zeros((0, 2), dtype=np.int64)
        mesh._cache["boundary"] = out
        return out
    key = lo * n + hi
    sign = np.where(e[:, 0] < e[:, 1], 1, -1)
    uniq, inverse = np.unique(key, return_inverse=True)
    net = np.bincount(inverse.reshape(-1), weights=sign, minlength=len(uniq)).astype(np.int64)
    k = np.flatnonzero(net)
    a, b = uniq[k] // n, uniq[k] % n
    m = net[k]
    # net > 0: a -> b left over; net < 0: b -> a.
    src = np.where(m > 0, a, b)
    dst = np.where(m > 0, b, a)
    reps = np.abs(m)
    out = np.stack([np.repeat(src, reps), np.repeat(dst, reps)], axis=1)
    # Map merged vertex ids back to a representative original vertex.
    rep = np.zeros(n, dtype=np.int64)
    rep[mesh.geometric_faces.reshape(-1)] = mesh.faces.reshape(-1)
    out = rep[out]
    mesh._cache["boundary"] = out
    return out


def edge_counts(mesh: Mesh):
    """``(open, non_manifold)``: edges used by one face, and edges used by more than two."""
    f = mesh.geometric_faces
    e = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
    e = e[e[:, 0] != e[:, 1]]
    _, counts = np.unique(e, axis=0, return_counts=True)
    return int(np.count_nonzero(counts == 1)), int(np.count_nonzero(counts > 2))


def caps(mesh: Mesh, edges: np.ndarray) -> np.ndarray:
    """Cap triangles closing the boundary: a fan per connected boundary piece.

    Returns
    -------
    triangles : (k, 3, 3) float64
        One triangle ``(centroid, b, a)`` per boundary edge ``a -> b``.
    piece : (k,) int64
        The boundary piece each belongs to.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    if len(edges) == 0:
        return np.zeros((0, 3, 3)), np.zeros(0, np.int64)
    pos = mesh.vertices
    # Pieces are connected through shared positions, not vertex indices.
    _, vid = np.unique(pos[edges.reshape(-1)], axis=0, return_inverse=True)
    vid = vid.reshape(-1, 2)
    nv = int(vid.max()) + 1
    graph = coo_matrix((np.ones(len(vid)), (vid[:, 0], vid[:, 1])), shape=(nv, nv))
    _, label = connected_components(graph, directed=False)
    piece = label[vid[:, 0]]
    npieces = int(piece.max()) + 1
    mid = (pos[edges[:, 0]] + pos[edges[:, 1]]) / 2
    centroid = np.stack([np.bincount(piece, weights=mid[:, k], minlength=npieces)
                         for k in range(3)], axis=1) / np.bincount(piece, minlength=npieces)[:, None]
    return np.stack([centroid[piece], pos[edges[:, 1]], pos[edges[:, 0]]], axis=1), piece


def solid_angles(tris: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Sum over ``tris`` of the signed solid angle at each point, over 4 pi.

    Van Oosterom & Strackee's formula. ``tris`` (k, 3, 3), ``points`` (n, 3).
    """
    out = np.zeros(len(points))
    for t in tris:
        A, B, C = t[0] - points, t[1] - points, t[2] - points
        la, lb, lc = (np.sqrt(np.einsum("ij,ij->i", x, x)) for x in (A, B, C))
        num = np.einsum("ij,ij->i", A, np.cross(B, C))
        den = (la * lb * lc + np.einsum("ij,ij->i", A, B) * lc
               + np.einsum("ij,ij->i", A, C) * lb + np.einsum("ij,ij->i", B, C) * la)
        out += 2.0 * np.arctan2(num, den)
    return out / (4.0 * np.pi)


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
    t = mesh.triangles[hits.triangle]
    n_axis = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])[:, axis]
    sigma = np.sign(n_axis).astype(np.int64)
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


def capped(mesh: Mesh):
    """The mesh with every hole closed by a cap (see :func:`caps`).

    Returns
    -------
    closed : Mesh
        ``mesh`` itself when it has no boundary; else its faces followed by
        the cap triangles.
    cap_tris : (k, 3, 3) float64
    piece : (k,) int64
    """
    if "capped" in mesh._cache:
        return mesh._cache["capped"]
    cap_tris, piece = caps(mesh, boundary_edges(mesh))
    closed = mesh
    if len(cap_tris):
        verts = np.concatenate([mesh.vertices, cap_tris.reshape(-1, 3)])
        cap_faces = len(mesh.vertices) + np.arange(3 * len(cap_tris)).reshape(-1, 3)
        closed = Mesh(verts, np.concatenate([mesh.faces, cap_faces]), source=mesh.source)
    mesh._cache["capped"] = (closed, cap_tris, piece)
    return mesh._cache["capped"]


def winding_occupancy(mesh: Mesh, grid, cast, axis: int, jobs: int = 1):
    """Occupancy by the generalised winding number (see the module notes).

    ``cast(mesh, axis)`` returns ``(Hits, Columns)`` for any mesh.

    Returns
    -------
    occupancy : (nx, ny, nz) bool, Fortran order
    hits, columns : the crossings of the original mesh's triangles
    """
    closed, cap_tris, piece = capped(mesh)
    nf = len(mesh.faces)
    hits, columns = cast(closed, axis)
    w = signed_counts(closed, hits, columns, grid, jobs)
    occ = np.asfortranarray(w >= 1)
    if len(cap_tris):
        _correct_near_caps(occ, w, grid, cap_tris, piece)
        hits = hits.take(hits.triangle < nf)
    return occ, hits, columns


#: Bricks of BRICK³ voxels organise the cap correction.
BRICK = 8


def _correct_near_caps(occ, w, grid, cap_tris, piece) -> None:
    """Decide ``w_M = w_{M+K} - w_K > 1/2`` exactly where ``w_K`` can change the answer.

    The grid is cut into bricks of BRICK³ voxels. A cap piece next to a
    brick (closer than the brick's diagonal) is summed exactly at every voxel
    of it; a farther piece ``c`` (area ``A_c``) is summed at the brick's centre
    only, and differs from that inside the brick by at most
    ``rho * A_c / (pi d^3)`` (``rho`` the brick's half-diagonal, ``d`` the
    distance), because the solid-angle kernel's gradient is at most
    ``4 / r^3``. Voxels whose estimate is further than that bound from 1/2
    are decided; the few others get the exact sum over every cap triangle.
    """
    npieces = int(piece.max()) + 1
    order = np.argsort(piece, kind="stable")
    counts = np.bincount(piece, minlength=npieces)
    starts = np.r_[0, np.cumsum(counts)[:-1]]
    tri_sorted = cap_tris[order]
    lo = np.minimum.reduceat(tri_sorted.min(axis=1), starts, axis=0)
    hi = np.maximum.reduceat(tri_sorted.max(axis=1), starts, axis=0)
    area = 0.5 * np.linalg.norm(np.cross(tri_sorted[:, 1] - tri_sorted[:, 0],
                                         tri_sorted[:, 2] - tri_sorted[:, 0]), axis=1)
    piece_area = np.add.reduceat(area, starts)

    shape = np.asarray(grid.shape)
    nb = -(-shape // BRICK)
    centres = [grid.centres(a) for a in range(3)]
    first = np.stack(np.meshgrid(*[np.arange(n) for n in nb], indexing="ij"), -1) * BRICK
    last = np.minimum(first + BRICK, shape) - 1
    b_lo = np.stack([centres[a][first[..., a]] for a in range(3)], -1)
    b_hi = np.stack([centres[a][last[..., a]] for a in range(3)], -1)
    mid = (b_lo + b_hi) / 2
    rho = np.linalg.norm(b_hi - b_lo, axis=-1) / 2
    reach = 2.0 * rho.max() + 1e-12
    far_mid = solid_angles(cap_tris, mid.reshape(-1, 3)).reshape(tuple(nb))
    deviation = np.zeros(tuple(nb))
    near_sum = np.zeros(grid.shape, dtype=np.float32, order="F")
    for c in range(npieces):
        tris = tri_sorted[starts[c]:starts[c] + counts[c]]
        gap = np.maximum(0.0, np.maximum(lo[c] - b_hi, b_lo - hi[c]))
        d = np.sqrt((gap ** 2).sum(-1))
        near = d <= reach
        with np.errstate(divide="ignore", invalid="ignore"):
            deviation += np.where(near, 0.0, rho * piece_area[c] / (np.pi * d ** 3))
        bricks = np.argwhere(near)
        if len(bricks) == 0:
            continue
        far_mid[near] -= solid_angles(tris, mid[near])
        pts = []
        for b in bricks:
            pts.append(np.stack(np.meshgrid(*[np.arange(first[tuple(b)][a], last[tuple(b)][a] + 1)
                                              for a in range(3)], indexing="ij"), -1).reshape(-1, 3))
        vox = np.concatenate(pts)
        p = np.stack([centres[a][vox[:, a]] for a in range(3)], axis=1)
        near_sum[tuple(vox.T)] += solid_angles(tris, p).astype(np.float32)
    expand = [np.repeat(np.arange(nb[a]), BRICK)[: shape[a]] for a in range(3)]
    estimate = w - far_mid[np.ix_(*expand)] - near_sum
    occ[...] = estimate > 0.5
    # float32 rounding of the near sums is far below this margin.
    unsure = np.abs(estimate - 0.5) <= deviation[np.ix_(*expand)] + 1e-4
    idx = np.argwhere(unsure)
    for s in range(0, len(idx), 1 << 16):
        block = idx[s:s + (1 << 16)]
        p = np.stack([centres[a][block[:, a]] for a in range(3)], axis=1)
        ii = tuple(block.T)
        occ[ii] = (w[ii] - solid_angles(cap_tris, p)) > 0.5


def choose(mesh: Mesh, method: str) -> str:
    """The method to run for ``method`` (resolving ``auto``), warning when it had to guess."""
    if method not in METHODS:
        raise ParameterError(f"`inside` must be one of {', '.join(METHODS)}; got {method!r}")
    if method != "auto":
        return method
    edges = boundary_edges(mesh)
    if len(edges) == 0:
        return "parity"
    n_open, n_nonmanifold = edge_counts(mesh)
    warnings.warn(
        f"{mesh.source}: the mesh is not closed ({n_open} open edges, {n_nonmanifold} "
        f"non-manifold, {len(edges)} without a partner edge running the other way, after "
        f"merging vertices by position); using the winding-number inside test, which bridges "
        f"holes (pass inside='parity' or --inside parity to override)",
        GeovoxWarning, stacklevel=3)
    return "winding"
