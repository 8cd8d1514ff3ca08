"""The caps' winding number ``w_K``, summed over a tree of the cap triangles.

``w_K`` is summed hierarchically (:func:`cap_winding`: a dual tree over
bricks of voxels and cap triangles, far-field dipoles with a proven error
bound), in passes that tighten only where the bound leaves the answer open,
and exactly over every cap triangle for the last few voxels
(:func:`correct_caps`). The compiled kernel (``geovox/_winding.pyx``,
:func:`winding_kernel`) runs the same traversal to second order, per voxel.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

import numpy as np

from ..kernels import compiled, openmp_threads


#: Opening ratio of the caps' far field: a group of cap triangles within
#: radius ``r`` of its centre is summed as one dipole at a brick of radius
#: ``rb`` when ``r + rb <= THETA * d`` (``d`` the gap between their balls).
THETA = 0.5
#: A single cap triangle is summed once for a whole brick only where its
#: bound there is below THETA times this.
SINGLE = 0.05
#: A far-field term whose error bound is below this is accepted whatever THETA says.
EPS = 1e-4
#: The traversal's passes: (THETA, EPS) of each, tighter each time, over the
#: voxels the one before left undecided; then the exact sum.
PASSES = ((1.0, 1e-3), (0.3, 1e-5), (0.1, 1e-6))
#: The last compiled run's counts: voxels refined alone, of them summed
#: exactly, left to the estimate; and the cap triangles.
STATS: dict = {}
#: The compiled kernel's passes (second order, see geovox/_winding.pyx): the
#: first ``COMPILED_BRICKS`` over bricks (the first over all, each next one
#: over the bricks that hold voxels left undecided), the others over single
#: voxels the one before left undecided. A loose first pass and tighter ones
#: over what it leaves cost about half of one tight pass over everything. The
#: fourth brick pass (0.05) pays on soups of big cap triangles (trimesh's
#: soup.stl at 256³: 5.4 s of processor time, not 6.9 s; the truck the same).
COMPILED_PASSES = ((0.4, 1e-4), (0.2, 1e-4), (0.1, 1e-5), (0.05, 1e-5), (0.25, 1e-6),
                   (0.1, 1e-7))
COMPILED_BRICKS = 4
#: A looser brick pass run first where the caps are small: a scan's holes
#: (thousands of caps, each a few triangles) leave nearly every voxel decided
#: by it, with a third of the (brick, node) pairs of COMPILED_PASSES' first
#: (4.3 million, not 14.0, on a 1.6-million-triangle bunny with 5 % of its
#: faces removed, at 64³; twice as fast in all). Over big caps it decides
#: too little to pay: a soup of 40 triangles of 8 to 24 voxels took 8-15 %
#: longer with it, the truck (caps of 0.3-0.6 voxels) 6-30 % less.
SCAN_PASS = (0.7, 1e-3)
#: ... run where the caps' median size (the root of the area) is under this
#: many voxel diagonals (suzanne's 35 caps: 3.9 at 128³, 8 % faster).
SCAN_CAPS = 6.0
#: A top brick whose undecided voxels are under 1 / COMPILED_FEW of its own
#: after a brick pass has them refined alone instead (another pass over their
#: bricks would cost more: the truck's fourth pass cost 3 % of its 128³ kernel).
COMPILED_FEW = 64
#: The compiled kernel's top bricks are about the grid's largest side over
#: this, voxels a side (a power of two; each top brick starts from the root of the caps' tree).
TOP_VOXELS = 8
#: The work budget of the caps' winding number, in processor seconds per
#: thread (the process's processor time, so a loaded machine's waiting does
#: not spend it), counted from the start of a block's caps. Past it, the
#: voxels the first pass left undecided keep their estimates: they are
#: counted (``Report.approximate``) and said in a warning. The first pass
#: always runs to its end; until the budget runs out nothing depends on time.
#: The compiled kernel checks it before every 64th voxel it refines alone
#: (the process's processor clock is a system call); the NumPy
#: traversal (one thread) between chunks of pairs, before a pass it cannot
#: finish in time (its sure work, see :func:`_sure_work`, at the rate of the
#: pass before), and between blocks of the exact sums.
WORK_SECONDS = 10.0
#: A voxel centre within this share of a voxel of a cap crossing along its
#: column is a tie (see :func:`settle_ties`).
TIE = 1e-4
#: (brick, cap group) pairs handled at once: bounds the traversal's memory.
PAIR_CHUNK = 1 << 17
#: Undecided voxels times cap triangles up to which they are summed exactly
#: straight away, without another pass.
DIRECT = 1 << 22
#: Voxel-level sums kept as separate parts until this many, then summed per voxel.
MERGE_AT = 1 << 20


def winding_kernel():
    """The compiled caps' winding number (``geovox._winding``), or None for the NumPy one.

    As the running conversion's kernel choice says (see
    :func:`geovox.kernels.compiled`): ``numpy`` forces the NumPy traversal,
    ``compiled`` insists on the kernel, ``auto`` (the default) uses it where
    it was built.
    """
    return compiled("_winding", "winding-number")


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


def triangle_angles(tris: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Signed solid angle over 4 pi of triangle ``i`` at point ``i`` (both ``(n, 3[, 3])``)."""
    # Component by component: about 2.5 times faster than einsum and
    # np.cross on (n, 3) rows, which copy and stride; the same formula.
    t = tris.reshape(len(tris), 9)
    px, py, pz = points[:, 0], points[:, 1], points[:, 2]
    ax, ay, az = t[:, 0] - px, t[:, 1] - py, t[:, 2] - pz
    bx, by, bz = t[:, 3] - px, t[:, 4] - py, t[:, 5] - pz
    cx, cy, cz = t[:, 6] - px, t[:, 7] - py, t[:, 8] - pz
    la = np.sqrt(ax * ax + ay * ay + az * az)
    lb = np.sqrt(bx * bx + by * by + bz * bz)
    lc = np.sqrt(cx * cx + cy * cy + cz * cz)
    num = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
           + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la)
    return np.arctan2(num, den) / (2.0 * np.pi)


def exact_sums(tris, points):
    """(n,) float64: the solid angle over 4 pi of every triangle of ``tris`` (k, 3, 3) summed at each point (n, 3)."""
    k = len(points)
    wk = triangle_angles(np.tile(tris, (k, 1, 1)), np.repeat(points, len(tris), axis=0))
    return wk.reshape(k, -1).sum(axis=1)


def _morton_sorted(tris):
    """(k, 3, 3) float64: the cap triangles in Morton order of their centroids (10 bits an axis), stably."""
    cen = tris.mean(axis=1)
    lo, hi = cen.min(axis=0), cen.max(axis=0)
    q = ((cen - lo) / max(float((hi - lo).max()), 1e-300) * 1023).astype(np.int64)
    code = np.zeros(len(tris), dtype=np.int64)
    for bit in range(10):
        for k in range(3):
            code |= ((q[:, k] >> bit) & 1) << (3 * bit + k)
    return tris[np.argsort(code, kind="stable")]


def _cap_tree(tris):
    """A binary tree over the cap triangles, in Morton order, as flat arrays.

    Level 0 holds the triangles; node ``j`` of level ``l`` covers the sorted
    triangles ``j 2^l .. (j + 1) 2^l - 1``. Per node: area vector ``S`` (the
    sum of the triangles' area-weighted normals, the dipole moment of their
    solid angle), total area ``A``, box centre ``c`` and radius ``r`` (every
    point of every triangle is within ``r`` of ``c``).

    Returns
    -------
    tris : (k, 3, 3) float64, sorted
    nodes : dict of flat arrays ``S (n, 3)``, ``A (n,)``, ``c (n, 3)``, ``r (n,)``
    offset : list of int
        Index of each level's first node in the flat arrays; ``size`` per level.
    """
    tris = _morton_sorted(tris)
    S = 0.5 * np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    A = np.linalg.norm(S, axis=1)
    blo, bhi = tris.min(axis=1), tris.max(axis=1)
    levels = [(S, A, blo, bhi)]
    while len(levels[-1][0]) > 1:
        S, A, blo, bhi = levels[-1]
        starts = np.arange(0, len(S), 2)
        levels.append((np.add.reduceat(S, starts, axis=0), np.add.reduceat(A, starts),
                       np.minimum.reduceat(blo, starts, axis=0),
                       np.maximum.reduceat(bhi, starts, axis=0)))
    size = [len(lv[0]) for lv in levels]
    offset = np.r_[0, np.cumsum(size)[:-1]].astype(np.int64)
    S = np.concatenate([lv[0] for lv in levels])
    A = np.concatenate([lv[1] for lv in levels])
    blo = np.concatenate([lv[2] for lv in levels])
    bhi = np.concatenate([lv[3] for lv in levels])
    nodes = {"S": S, "A": A, "c": (blo + bhi) / 2, "r": np.linalg.norm(bhi - blo, axis=1) / 2,
             "h": (bhi - blo) / 2}
    return tris, nodes, offset, np.asarray(size, dtype=np.int64)


def cap_winding(grid, tris, active, theta=THETA, eps=EPS, budget=None, then=None, deadline=None):
    """The caps' winding number ``w_K`` over bricks of voxels, hierarchically, with a bound.

    A dual-tree traversal in whole arrays. Voxels are grouped in cubic
    bricks of ``2^k`` voxels a side (a brick of level 0 is one voxel centre),
    cap triangles in the tree of :func:`_cap_tree`. Starting from the given
    bricks paired with the root, each (brick, node) pair whose balls are far
    apart is summed as the node's dipole ``S . (c - p) / (4 pi |c - p|^3)`` at
    the brick's centre ``p``. Its error anywhere in the brick is at most
    ``A (r + rb) / (2 pi d^3)``: the solid-angle kernel ``n.(x-p)/|x-p|^3`` has
    gradient at most ``2 / |x-p|^3``, the triangles' points and the brick's
    voxel centres move at most ``r + rb`` from the two centres, and stay at
    least ``d`` (the gap between the balls) apart. Pairs that are not far
    split their larger side (8 sub-bricks, or 2 child nodes); a voxel and a
    single triangle are summed exactly (Van Oosterom and Strackee).

    Parameters
    ----------
    grid : Grid
    tris : (k, 3, 3) float64
        Cap triangles.
    active : list of bool arrays, one per brick level (shape ``ceil(shape / 2^l)``)
        The bricks that hold voxels to evaluate (see :func:`_pyramid`); the
        traversal starts at the top level and never enters an inactive brick.

    budget : int, optional
        Give up (return None) once more than this many pairs have been
        handled (a count that does not depend on time: for tests of
        :func:`_sure_work`).
    then : (theta, eps), optional
        The next pass's opening ratio and tolerance: count, per brick, the
        pairs the next pass is sure to visit (see ``work``).
    deadline : float, optional
        Give up (return None) once :func:`time.process_time` reaches it,
        checked before each chunk of ``PAIR_CHUNK`` pairs (the work budget,
        see ``WORK_SECONDS``).

    Returns
    -------
    est : list, one entry per brick level ``l``
        Sums to add up, each voxel taking its bricks' values on every level:
        on levels ``l >= 1`` float64 arrays of shape ``ceil(shape / 2^l)``; on
        level 0 (single voxels) the voxels that got a value of their own,
        sparse: ``(lin, value, below, above, count)``, the flat (C-order)
        index of each such voxel (int64, sorted, unique), its sum and its
        bounds' sums (float64), and how many pairs ended at it (int64).
        (The arrays may extend past ``ceil(shape / 2^l)``, with zeros.)
    err : list: the bounds of levels ``l >= 1``, added the same way (None on level 0):
        float64 ``(..., 2)``, how far below and above the sum the true value
        may lie (the bounds need not be symmetric: see :func:`_clamp`).
    work : list of int32 arrays ``(..., 2)``, one per brick level (None on level 0)
        Per brick of level >= 1: ``[..., 0]`` (visits), the pairs with it
        that this pass visited, plus the node's children for each of them
        that was far here but that the next pass (``then``) splits by its
        node; ``[..., 1]`` (splits), those the next pass splits by the brick
        instead. A
        tighter pass visits every pair a looser one visited on the bricks it
        enters (what was not far here is not far there), and the children of
        each such split, so these give a lower bound on its work (see
        :func:`_sure_work`). None without ``then``.
    pairs : int
        The pairs handled.
    """
    tris, nodes, offset, size = _cap_tree(tris)
    top = len(size) - 1
    shape = np.asarray(grid.shape, dtype=np.int64)
    level0 = len(active) - 1
    start = _argwhere(active[level0])
    # Levels where every brick is active need no look-up (the whole first pass).
    full = [bool(a.all()) for a in active]
    d = grid.spacing
    lo = grid.lo
    # Level 0 is kept sparse: dense, its two grid-sized arrays were most of
    # this step's memory, and first touching fresh pages costs more than the
    # sums (0.14 s for 64 MB in a fresh process here).
    # Each level exactly twice the next one up (bricks past the grid stay 0),
    # so sums push down in place (see _push_down).
    top_shape = -(-shape // (1 << level0))
    est = [[]] + [np.zeros(tuple(top_shape << (level0 - k))) for k in range(1, level0 + 1)]
    err = [None] + [np.zeros(e.shape + (2,)) for e in est[1:]]
    # Per brick: [visits, splits] (see ``work``), one array so one scatter.
    work = [None] + [np.zeros(e.shape + (2,), np.int32) if then is not None else None
                     for e in est[1:]]
    S, A, R = nodes["S"], nodes["A"], nodes["r"]
    stack = [(np.full(len(start), level0, np.int64), start.astype(np.int64),
              np.full(len(start), top, np.int64), np.zeros(len(start), np.int64))]
    handled = 0
    while stack:
        kb, b, ln, nj = stack.pop()
        handled += min(len(kb), PAIR_CHUNK)
        if (budget is not None and handled > budget) or (
                deadline is not None and time.process_time() >= deadline):
            return None
        if len(kb) > PAIR_CHUNK:
            stack.append((kb[PAIR_CHUNK:], b[PAIR_CHUNK:], ln[PAIR_CHUNK:], nj[PAIR_CHUNK:]))
            kb, b, ln, nj = kb[:PAIR_CHUNK], b[:PAIR_CHUNK], ln[:PAIR_CHUNK], nj[:PAIR_CHUNK]
        pr = _pairs(lo, d, nodes, offset, kb, b, ln, nj, theta, eps)
        node, vec, bound, gap, single, far, leaf = (pr.node, pr.vec, pr.bound, pr.gap, pr.single,
                                                     pr.far, pr.leaf)
        if then is not None:
            _count_next(work, nodes, size, kb, b, ln, nj, pr, then)
        far &= ~single
        if far.any():
            f = np.flatnonzero(far)
            val = np.einsum("ij,ij->i", S[node[f]], vec[f]) / (4 * np.pi * pr.dist[f] ** 3)
            _scatter(est, err, kb[f], b[f], val, *_clamp(val, bound[f], A[node[f]], gap[f]),
                     grid.shape)
        if leaf.any():
            f = np.flatnonzero(leaf)
            val = triangle_angles(tris[nj[f]], pr.p[f])
            brick = kb[f] > 0
            below, above = np.zeros(len(f)), np.zeros(len(f))
            if brick.any():
                g = f[brick]
                below[brick], above[brick] = _clamp(val[brick], bound[g], A[node[g]], gap[g])
            _scatter(est, err, kb[f], b[f], val, below, above, grid.shape)
        split = np.flatnonzero(~far & ~leaf)
        if len(split):
            handled += _split(stack, est, err, tris, grid, active, full, size,
                              kb[split], b[split], ln[split], nj[split], pr.rb[split],
                              R[node[split]])
    # Pairs summed straight away (_exact_leaves) after the last check count too:
    # a pass gives up exactly when it handles more than the budget.
    if budget is not None and handled > budget:
        return None
    est[0] = _merge(est[0])
    return est, err, work, handled


def _pairs(lo, d, nodes, offset, kb, b, ln, nj, theta, eps):
    """Measure each (brick, node) pair of :func:`cap_winding` and take its test.

    Returns a namespace with, per pair: ``p`` the brick's centre (n, 3), ``rb``
    its radius, ``node`` the flat node index, ``vec`` node centre minus ``p``,
    ``dist`` its length, ``gap`` between the brick's ball and the node's box,
    ``reach`` (r + rb), ``single`` (the node is one triangle), ``bound`` (the
    error bound of the pair's far-field term), ``far`` and ``leaf``.
    """
    C, H, R, A = nodes["c"], nodes["h"], nodes["r"], nodes["A"]
    side = (1 << kb).astype(np.float64)
    p = lo + (b * side[:, None] + (side[:, None] - 1) / 2 + 0.5) * d
    rb = 0.5 * (side - 1) * np.linalg.norm(d)
    node = offset[ln] + nj
    vec = C[node] - p
    dist = np.sqrt(np.einsum("ij,ij->i", vec, vec))
    # The gap between the brick's ball and the node's box.
    out = np.maximum(np.abs(vec) - H[node], 0.0)
    gap = np.sqrt(np.einsum("ij,ij->i", out, out)) - rb
    reach = R[node] + rb
    single = ln == 0
    with np.errstate(divide="ignore", invalid="ignore"):
        g3 = 2 * np.pi * gap * gap * gap
        # A group's dipole at the brick's centre, or one triangle's exact
        # value there: the first errs by moving both ends (r + rb), the
        # second by moving the brick's end only (rb; and the kernel's
        # integral over a triangle at least g away is at most 2 pi / g).
        bound = np.where(single,
                         np.minimum(A[node] * rb / g3, rb / gap),
                         A[node] * reach / g3)
    # A single triangle's bound at a brick (up to rb / g) shrinks only
    # linearly with the brick: it must also be small in absolute terms,
    # or large triangles next to many voxels leave them all undecided.
    far = _far(gap, reach, rb, bound, single, theta, eps)
    leaf = single & (far | (kb == 0))
    return SimpleNamespace(p=p, rb=rb, node=node, vec=vec, dist=dist, gap=gap, reach=reach,
                      single=single, bound=bound, far=far, leaf=leaf)


def _far(gap, reach, rb, bound, single, theta, eps):
    """cap_winding's test: the pair's far-field term is taken (bool per pair)."""
    return (gap > 0) & (((reach <= theta * gap) & ~single)
                        | ((rb <= theta * gap) & (bound <= theta * SINGLE)) | (bound <= eps))


def _count_next(work, nodes, size, kb, b, ln, nj, pr, then) -> None:
    """Count, per brick, the pairs the next pass (``then``) is sure to visit (cap_winding's ``work``)."""
    t2, e2 = then
    far2 = _far(pr.gap, pr.reach, pr.rb, pr.bound, pr.single, t2, e2)
    # Split next time: a far pair the next pass does not take as far
    # (a voxel and one triangle is always a leaf). Its children there
    # are the node's (1 or 2) or the brick's active sub-bricks (known
    # only after this pass: counted per brick in ``splits``).
    again = pr.far & ~far2 & ~(pr.single & (kb == 0))
    by_brick = again & (kb > 0) & (pr.single | (pr.rb > nodes["r"][pr.node]))
    kids = 1 + (2 * nj + 1 < size[np.maximum(ln - 1, 0)])
    _count(work, kb, b, 1 + np.where(again & ~by_brick, kids, 0), by_brick)


def _split(stack, est, err, tris, grid, active, full, size, kb, b, ln, nj, rb, r) -> int:
    """Push the children of the pairs that are neither far nor leaves; return the pairs summed at once.

    A pair splits its larger side: the brick into its 8 sub-bricks (those
    inside the grid and active), or the node into its 1 or 2 children.
    Children that are one voxel and one triangle are summed straight away
    (:func:`_exact_leaves`), the rest go on ``stack``.
    """
    shape = np.asarray(grid.shape, dtype=np.int64)
    handled = 0
    brick = (kb > 0) & ((ln == 0) | (rb > r))
    if (~brick).any():  # two children of the node (the second may not exist)
        s = np.flatnonzero(~brick)
        c_ln = np.repeat(ln[s] - 1, 2)
        c_nj = ((2 * nj[s])[:, None] + np.arange(2)).reshape(-1)
        ok = c_nj < size[c_ln]
        c_kb, c_b, c_ln, c_nj = np.repeat(kb[s], 2)[ok], np.repeat(b[s], 2, axis=0)[ok], c_ln[ok], c_nj[ok]
        handled += _exact_leaves(est, err, tris, grid, c_kb, c_b, c_ln, c_nj)
        keep = (c_kb > 0) | (c_ln > 0)
        stack.append((c_kb[keep], c_b[keep], c_ln[keep], c_nj[keep]))
    if brick.any():  # eight sub-bricks (those inside the grid)
        s = np.flatnonzero(brick)
        child = ((2 * b[s])[:, None, :] + _OCTANTS[None]).reshape(-1, 3)
        c_kb = np.repeat(kb[s] - 1, 8)
        ok = np.all(child * (1 << c_kb)[:, None] < shape, axis=1)
        ok[ok] = _lookup(active, full, c_kb[ok], child[ok])
        c_kb, child, c_ln, c_nj = c_kb[ok], child[ok], np.repeat(ln[s], 8)[ok], np.repeat(nj[s], 8)[ok]
        handled += _exact_leaves(est, err, tris, grid, c_kb, child, c_ln, c_nj)
        keep = (c_kb > 0) | (c_ln > 0)
        stack.append((c_kb[keep], child[keep], c_ln[keep], c_nj[keep]))
    return handled


def _clamp(val, bound, area, gap):
    """Narrow ``val`` +- ``bound`` to where the true value must also lie: within +- area / (4 pi gap²).

    A surface of area ``A`` whose every point is at least ``g`` from ``p``
    has a winding number at ``p`` of at most ``A / (4 pi g²)`` in size (the
    kernel ``n.(x - p) / |x - p|³`` is at most ``1 / g²``). Where the
    dipole's error bound is first order in the opening ratio, this one can be
    tighter (by up to 3 times at an opening ratio of 1). The value stays the
    estimate (the best guess where the bounds decide nothing and the work
    budget runs out); the bounds become the overlap of the two intervals,
    measured from it (``above`` may be negative, where the estimate lies
    beyond what is possible).

    Returns
    -------
    below, above : (n,) float64
        The true value lies in ``[val - below, val + above]``.
    """
    m = area / (4 * np.pi * gap * gap)
    return val - np.maximum(val - bound, -m), np.minimum(val + bound, m) - val


def _sure_work(unsure, level0, work, active) -> float:
    """A lower bound on the pairs the next pass will handle over the ``unsure`` voxels.

    The pairs this pass ended at on unsure voxels (level 0, ``level0``: see
    :func:`cap_winding`'s ``est[0]``),
    and on every brick of a coarser level that holds an unsure voxel
    (``active``, the next pass's pyramid) the pairs of :func:`cap_winding`'s
    ``work``: the visits and node children counted there, and for each pair
    the next pass splits by its brick, the active sub-bricks it splits into.
    """
    lin, _, _, _, count = level0
    n = float(count[unsure.reshape(-1)[lin]].sum())
    for k in range(1, len(active)):
        n0, n1, n2 = active[k].shape
        visits, splits = work[k][:n0, :n1, :n2, 0], work[k][:n0, :n1, :n2, 1]
        n += float(np.sum(visits, where=active[k], dtype=np.int64))
        idx = np.flatnonzero(splits)
        if len(idx) == 0:
            continue
        idx = np.stack(np.unravel_index(idx, splits.shape), axis=1)
        kids = np.zeros(len(idx), np.int64)
        fine = active[k - 1]
        for o in _OCTANTS:
            c = 2 * idx + o
            ok = np.all(c < fine.shape, axis=1)
            kids[ok] += fine[tuple(c[ok].T)]
        n += float(np.dot(splits[tuple(idx.T)].astype(np.int64), kids))
    return n


def _count(work, kb, b, visits, splits) -> None:
    """Add each pair's ``visits`` and ``splits`` to its brick's counts (levels >= 1)."""
    for k in np.flatnonzero(np.bincount(kb)):
        if k == 0:
            continue
        sel = kb == k
        lin = 2 * np.ravel_multi_index(tuple(b[sel].T), work[k].shape[:3])
        s = splits[sel]
        np.add.at(work[k].reshape(-1), np.r_[lin, lin[s] + 1],
                  np.r_[visits[sel], np.ones(np.count_nonzero(s), np.int64)].astype(np.int32))


def _exact_leaves(est, err, tris, grid, kb, b, ln, nj) -> int:
    """Sum the pairs of one voxel and one triangle exactly, at once; return how many.

    Such a pair is always a leaf of :func:`cap_winding` (exact, no error), so
    it skips the traversal's tests: most pairs are of this kind where large
    cap triangles pass near many voxels.
    """
    sel = np.flatnonzero((kb == 0) & (ln == 0))
    for s in range(0, len(sel), PAIR_CHUNK):
        f = sel[s:s + PAIR_CHUNK]
        p = grid.lo + (b[f] + 0.5) * grid.spacing
        _scatter(est, err, kb[f], b[f], triangle_angles(tris[nj[f]], p), np.zeros(len(f)),
                 np.zeros(len(f)), grid.shape)
    return len(sel)


def _argwhere(mask: np.ndarray) -> np.ndarray:
    """``np.argwhere(mask)`` (same rows, same order) for a 3-D bool array, faster.

    np.argwhere of a large, sparse 3-D array costs about 25 times as much as
    a flat search and an unravel (0.28 s against 0.011 s at 256³).
    """
    return np.stack(np.unravel_index(np.flatnonzero(mask), mask.shape), axis=1).astype(np.int64)


_OCTANTS = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], dtype=np.int64)


def _lookup(active, full, kb, b):
    """Whether brick ``b[i]`` of level ``kb[i]`` is active; ``full[k]``: all of level ``k`` are."""
    out = np.ones(len(kb), dtype=bool)
    for k in np.flatnonzero(np.bincount(kb)):
        if full[k]:
            continue
        sel = kb == k
        a = active[k]
        bs = b[sel]
        # One flat index, not three index arrays: fancy indexing by a tuple is slower.
        out[sel] = a.reshape(-1)[(bs[:, 0] * a.shape[1] + bs[:, 1]) * a.shape[2] + bs[:, 2]]
    return out


def _push_down(fine, coarse) -> None:
    """Add each brick's value to its 2³ sub-bricks, in place (``fine`` twice ``coarse`` a side).

    ``fine`` (2a, 2b, 2c, ...), ``coarse`` (a, b, c, ...): no temporary of ``fine``'s size.
    """
    a, b, c = coarse.shape[:3]
    rest = coarse.shape[3:]
    view = fine.reshape((a, 2, b, 2, c, 2) + rest)
    view += coarse.reshape((a, 1, b, 1, c, 1) + rest)


def _pyramid(mask, levels):
    """``[mask, any over 2³ blocks of it, ...]``: ``levels + 1`` arrays.

    ``mask`` is a bool array, or a shape for an all-True one. Built from the
    True voxels' indices: the masks after the first pass are sparse.
    """
    if not isinstance(mask, np.ndarray):
        # Read-only views of one True: nothing allocated or touched.
        shape = np.asarray(mask)
        return [np.broadcast_to(np.True_, tuple(-(-shape // (1 << k)))) for k in range(levels + 1)]
    shape = np.asarray(mask.shape)
    if np.count_nonzero(mask) > mask.size // 64:
        # Dense: any over 2³ blocks, level by level, costs less than indices.
        out = [mask]
        for _ in range(levels):
            m = out[-1]
            a, b, c = (-(-n // 2) for n in m.shape)
            pad = np.zeros((2 * a, 2 * b, 2 * c), dtype=bool)
            pad[: m.shape[0], : m.shape[1], : m.shape[2]] = m
            out.append(pad.reshape(a, 2, b, 2, c, 2).any(axis=(1, 3, 5)))
        return out
    idx = _argwhere(mask)
    out = [mask]
    for k in range(1, levels + 1):
        m = np.zeros(tuple(-(-shape // (1 << k))), dtype=bool)
        m[tuple((idx >> k).T)] = True
        out.append(m)
    return out


def _scatter(est, err, kb, b, val, below, above, shape):
    """Add each pair's value and bounds to its brick, level by level (level 0: sparse)."""
    for k in np.flatnonzero(np.bincount(kb)):
        sel = kb == k
        if k == 0:
            lin = np.ravel_multi_index(tuple(b[sel].T), shape)
            est[0].append((lin, val[sel], below[sel], above[sel], None))
            if sum(len(e[0]) for e in est[0]) > MERGE_AT:
                est[0][:] = [_merge(est[0])]
            continue
        lin = np.ravel_multi_index(tuple(b[sel].T), est[k].shape)
        np.add.at(est[k].reshape(-1), lin, val[sel])
        np.add.at(err[k].reshape(-1), np.r_[2 * lin, 2 * lin + 1], np.r_[below[sel], above[sel]])


def _merge(parts):
    """``(lin, value, below, above, count)`` parts (count None: 1 each) summed per voxel, ``lin`` sorted."""
    if not parts:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0, np.int64)
    lin = np.concatenate([p[0] for p in parts])
    order = np.argsort(lin, kind="stable")
    lin = lin[order]
    starts = np.flatnonzero(np.r_[True, lin[1:] != lin[:-1]])
    val, below, above = (np.add.reduceat(np.concatenate([p[i] for p in parts])[order], starts)
                         for i in (1, 2, 3))
    count = np.concatenate([np.ones(len(p[0]), np.int64) if p[4] is None else p[4] for p in parts])
    return lin[starts], val, below, above, np.add.reduceat(count[order], starts)


def correct_caps(occ, w, grid, cap_tris, jobs: int = 1):
    """Decide ``w_M = w_{M+K} - w_K > 1/2`` with the caps' winding number from :func:`cap_winding`.

    A first pass gives every voxel an estimate of ``w_K`` and a proven bound
    on its error; the voxels whose estimate is not decisive (within the bound
    of 1/2) get a second pass with a tighter opening ratio, over only the
    bricks that hold them, and any still undecided are summed exactly over
    every cap triangle (straight away, once they are few: see ``DIRECT``).
    The compiled kernel, where it is built, does the same per voxel (see
    :func:`_compiled_caps`).

    The passes after the first and the exact sums stop at the work budget
    (``WORK_SECONDS`` of processor time from here; the NumPy traversal runs
    in one thread): a pass is given up when it reaches it, or not started
    when its sure work (:func:`_sure_work`) at the rate of the pass before
    would pass it. Until then nothing depends on time.

    Returns
    -------
    (nx, ny, nz) bool or None
        The voxels left to their estimates (the budget ran out), or None.
    """
    module = winding_kernel()
    if module is not None:
        return _compiled_caps(module, occ, w, grid, cap_tris, jobs)
    deadline = time.process_time() + WORK_SECONDS
    shape = np.asarray(grid.shape)
    top = max(0, int(np.ceil(np.log2(max(1, int(shape.max()) / 16)))))
    active = _pyramid(grid.shape, top)
    first = True
    for i, (theta, eps) in enumerate(PASSES):
        started = time.process_time()
        got = cap_winding(grid, cap_tris, active, theta=theta, eps=eps,
                          deadline=None if first else deadline,
                          then=PASSES[i + 1] if i + 1 < len(PASSES) else None)
        if got is None:
            return active[0]
        est, err, work, pairs = got
        rate = (time.process_time() - started) / max(pairs, 1)  # seconds a pair
        level0 = est[0]
        lin0, val0, below0, above0, _ = level0
        # Every coarse level's sums, pushed down to bricks of 2³ voxels.
        for k in range(len(est) - 1, 1, -1):
            for arrays in (est, err):
                _push_down(arrays[k - 1], arrays[k])
                arrays[k] = None
        if first:
            np.greater_equal(w, 1, out=occ)
        # A brick of 2³ whose voxels got nothing of their own and whose
        # estimate and bound keep |w_K| below 1/2 leaves every integer
        # w_{M+K} decided as it is (w >= 1, set above); only the other
        # bricks' voxels are looked at one by one.
        if len(est) > 1:
            # |w_K| may reach 1/2 - margin on either side.
            n1 = tuple(-(-shape // 2))
            loose = np.empty(n1, dtype=bool)
            for z in range(0, n1[0], 8):  # in slabs: no grid-sized temporaries
                z1 = min(z + 8, n1[0])  # est[1] may extend past n1 (zeros)
                e1, r1 = est[1][z:z1, : n1[1], : n1[2]], err[1][z:z1, : n1[1], : n1[2]]
                loose[z:z1] = np.maximum(e1 + r1[..., 1], r1[..., 0] - e1) >= 0.5 - 1e-4
            loose[tuple((np.stack(np.unravel_index(lin0, grid.shape), axis=1) >> 1).T)] = True
            if not first:
                loose &= active[1]
            bricks = _argwhere(loose)
            vox = ((2 * bricks)[:, None, :] + _OCTANTS[None]).reshape(-1, 3)
            vox = vox[np.all(vox < shape, axis=1)]
        else:
            vox = _argwhere(active[0])
        if not first:
            vox = vox[active[0][tuple(vox.T)]]
        ii = tuple(vox.T)
        # Each voxel's own sums, where it has any (lin0 is sorted).
        vlin = np.ravel_multi_index(ii, grid.shape)
        at = np.minimum(np.searchsorted(lin0, vlin), max(len(lin0) - 1, 0))
        own = (lin0[at] == vlin) if len(lin0) else np.zeros(len(vlin), bool)
        wk, below, above = ((np.where(own, a[at], 0.0) if len(lin0) else np.zeros(len(vlin)))
                            for a in (val0, below0, above0))
        if len(est) > 1:
            jj = tuple((vox >> 1).T)
            wk += est[1][jj]
            below += err[1][jj + (0,)]
            above += err[1][jj + (1,)]
        del est, err
        v = w[ii] - wk
        occ[ii] = v > 0.5
        # w_K in [wk - below, wk + above]: w_{M+K} - w_K in [v - above, v + below].
        # Rounding of the float64 sums is far below this margin.
        unsure = np.zeros(grid.shape, dtype=bool)
        unsure[ii] = (v - above <= 0.5 + 1e-4) & (v + below >= 0.5 - 1e-4)
        first = False
        n_unsure = int(np.count_nonzero(unsure))
        if n_unsure == 0:
            return None
        if n_unsure * len(cap_tris) <= DIRECT:
            # So few left that summing every cap triangle at each costs less
            # than a pass's set-up over the whole grid.
            active = [unsure]
            break
        # The next pass, with a tighter opening ratio over the bricks that
        # hold unsure voxels, visits every pair this pass visited on such a
        # brick (a pair that was split here is split there too), and at least
        # one child of each pair that was far here but not there: a lower
        # bound on its work (see cap_winding's ``work``). Where that work,
        # at this pass's rate, would pass the budget, that pass would give
        # up anyway: give up now, without spending the budget first.
        active = _pyramid(unsure, top)
        if i + 1 < len(PASSES) and (_sure_work(unsure, level0, work, active) * rate
                                    > deadline - time.process_time()):
            return unsure
        del work, level0, lin0, val0, below0, above0
    # The last few: the exact sum over every cap triangle.
    return _exact_caps(occ, w, grid, cap_tris, _argwhere(active[0]), deadline)


def _exact_caps(occ, w, grid, cap_tris, idx, deadline=None):
    """Decide voxels ``idx`` ((n, 3) int64) on the exact sum of ``w_K`` over every cap triangle.

    In blocks of about 65,536 (voxel, triangle) pairs; once
    :func:`time.process_time` reaches ``deadline``, the voxels not yet summed
    keep the decisions they have.

    Returns
    -------
    (nx, ny, nz) bool or None
        Those voxels, or None where every one was summed.
    """
    centres = [grid.centres(a) for a in range(3)]
    block = max(1, (1 << 16) // len(cap_tris))
    for s in range(0, len(idx), block):
        if deadline is not None and time.process_time() >= deadline:
            left = np.zeros(grid.shape, dtype=bool)
            left[tuple(idx[s:].T)] = True
            return left
        ii = tuple(idx[s:s + block].T)
        p = np.stack([centres[a][ii[a]] for a in range(3)], axis=1)
        occ[ii] = (w[ii] - exact_sums(cap_tris, p)) > 0.5
    return None


def _compiled_caps(module, occ, w, grid, cap_tris, jobs) -> None:
    """:func:`correct_caps` in the compiled kernel (``geovox/_winding.pyx``).

    The first pass over bricks, as :func:`cap_winding`'s but to second order
    (``COMPILED_PASSES[0]``, after ``SCAN_PASS`` where the caps are small),
    then tighter ones over the bricks that hold the voxels left undecided (``COMPILED_BRICKS`` in all); each voxel still
    undecided is refined alone at once by the voxels' passes, then summed
    exactly over every cap triangle. Only past ``WORK_SECONDS`` of processor
    time per thread is an undecided voxel left to its estimate.

    Returns
    -------
    (nx, ny, nz) bool or None
        The voxels left to their estimates, or None.
    """
    # The tree of _cap_tree with the moments of the second-order expansion, in loops.
    tris = np.ascontiguousarray(_morton_sorted(cap_tris).reshape(-1, 9))
    S, A, C, H, R, Q, M, offset, size = module.cap_tree(tris)
    shape = np.asarray(grid.shape)
    top = max(0, int(np.ceil(np.log2(max(1, int(shape.max()) / TOP_VOXELS)))))
    passes, bricks = COMPILED_PASSES, COMPILED_BRICKS
    if np.sqrt(np.median(A[:len(tris)])) < SCAN_CAPS * np.linalg.norm(grid.spacing):
        passes, bricks = (SCAN_PASS,) + tuple(passes), bricks + 1
    jobs = openmp_threads(jobs)  # GNU OpenMP is not fork-safe (see geovox.kernels)
    flat = occ.reshape(-1, order="F").view(np.uint8)  # a view: occ is Fortran-ordered
    estimated = np.zeros(grid.size, np.uint8)
    counts = module.cap_occupancy(
        tris, S, Q, A, C, H, R, M, offset, size, w.reshape(-1, order="F"), flat, estimated,
        tuple(int(n) for n in grid.shape), tuple(float(x) for x in grid.lo),
        tuple(float(x) for x in grid.spacing), top,
        np.ascontiguousarray(np.asarray(passes, float).reshape(-1, 2)), bricks, COMPILED_FEW,
        WORK_SECONDS, max(1, int(jobs)))
    STATS.update(zip(("refined", "exact", "estimated"), counts), caps=len(tris))
    if estimated.any():
        return estimated.view(bool).reshape(grid.shape, order="F")
    return None
