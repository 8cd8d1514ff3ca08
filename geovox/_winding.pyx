# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False, nonecheck=False
"""Compiled caps' winding number: the occupancy ``w_{M+K} - w_K > 1/2`` of a capped mesh.

The dual-tree traversal of :func:`geovox.inside.cap_winding` (the same tree
of cap triangles over bricks of ``2^k`` voxels), written as a depth-first
loop over (brick, node) pairs per top brick, with OpenMP threads over the
top bricks; each top brick's sums live in per-thread buffers, so nothing
grows with the grid.

Each far pair is summed to second order, not as a bare dipole. With
``f(y) = n . y / |y|^3`` and ``y = x - p`` (x on the node, p a voxel
centre), expanding about ``y0 = c - p0`` (the node's centre, the brick's
centre) gives the dipole ``S . K(y0)``, the first moment's term
``J(y0) : Q`` (``Q = sum_t S_t (x) (centroid_t - c)``, ``J`` the Jacobian
of ``K(y) = y / |y|^3``, ``I / r^3 - 3 y y^T / r^5``) and a gradient in p,
``-J^T S``, so each brick carries a linear field. The remainder is at
most ``|grad^2 f| |y - y0|^2 / 2 <= 3 |y - y0|^2 / d^4`` (``grad^2 f`` is
the third derivative of ``1/|y|`` along ``n``, of norm ``6 / |y|^4``;
``d`` the gap between the node's box and the brick's ball, which every
point of the segment keeps by convexity), so per pair
``3 A (r + rb)^2 / (4 pi d^4)``: second order in the opening ratio where
the bare dipole's ``A (r + rb) / (2 pi d^3)`` is first order. That is what
lets the caps of messy models (fans over boundary loops with much more area
than net area vector: unsigned solid angles near 1 at most voxels) be
decided in bulk.

Two refinements of that bound (:func:`second_bound`), each a proof, not an
estimate. The displacement at a point x of the node is ``|x - c| + rb``, so
``A (r + rb)^2`` becomes ``int (|x - c| + rb)^2 dA <= (sqrt(M2) + rb sqrt(A))^2``
with ``M2`` the node's second moment about ``c`` (Cauchy-Schwarz). And the
distance along the segment from ``y0`` falls no faster than ``a - s rho``
(``a = |y0|``), so Taylor's remainder in integral form,
``int_0^1 (1 - s) f''(y0 + s h)[h, h] ds``, is at most
``6 rho^2 phi(rho / a) / a^4`` with
``phi(u) = int_0^1 (1 - s) (1 - u s)^-4 ds = (3 - 2 u) / (6 (1 - u)^2)``,
where the closest point alone gives ``3 rho^2 / d^4``, ``d >= a (1 - u)``
(at ``u = 1/3`` the first is 2.9 times smaller). The kernel takes the lesser.

A voxel and a single cap triangle are always summed exactly (as cheap as an
expansion and its bound), and a brick and a single triangle are judged by
the distance to the triangle itself (:func:`tri_distance`), not to its box:
the caps of slit-like holes are slivers across the axes, whose boxes are
many times their own neighbourhoods.

A brick and a single triangle are summed as the triangle's exact solid
angle and gradient at the brick's centre c, a linear field over the brick,
with the lesser of two bounds on its error (each a proof). The first
(:func:`single_bound`) is the remainder above per point of the triangle,
from the distance g0 to its face. It is loose over a big triangle's
interior, where the face is near and the edges far, and a soup of big
triangles (each its own cap) sits there everywhere. The second
(:func:`edge_bound`) uses the edges alone. Where the brick's ball (radius
rb) misses the triangle, Omega (the solid angle) is smooth in the ball and
its gradient is the Biot-Savart field of the edge loop,
``grad Omega(p) = int_dT dl x K(r)`` up to sign, ``r = y - p``, ``K(r) = r / |r|^3``,
whose Jacobian is ``J = I / r^3 - 3 r r^T / r^5``. So
``Omega''(p)[h, h] = -int_dT h . (dl x J h) = -int_dT dl . (J h x h)`` and
``J h x h = -3 (r . h) (r x h) / r^5``: with ``a`` the angle between r and h,
``|Omega''(p)[h, h]| <= 3 |h|^2 int_dT |dl| |cos a sin a| / r^3
<= (3 / 2) |h|^2 int_dT |dl| / |y - p|^3`` (the Jacobian's norm, ``2 / r^3``, alone
gives 2 for 3 / 2). Taylor's remainder in integral form along the segment
from c to a voxel (it never meets the face, where Omega jumps by 4 pi),
``int_0^1 (1 - s) Omega''(c + s h)[h, h] ds``, with ``|y - c - s h| >= rho - s rb``
(``rho = |y - c|``) and ``int_0^1 (1 - s) (1 - u s)^-3 ds = 1 / (2 (1 - u))``, is then
at most ``(3 / 4) rb^2 int_dT |dl| / (rho^2 (rho - rb))``; ``rho / (rho - rb)`` falls
with rho, so per edge e at distance ``d_e`` from c this is at most
``(3 / 4) rb^2 d_e / (d_e - rb) I_e`` with ``I_e = int_e dl / rho^3`` in closed form
(over 4 pi: the error of the winding number). Beside the middle of a long
edge the error reaches about two thirds of it (tests/test_winding_bounds.py).
Over a brick at height g0 above a big triangle's interior, with its edges D
away, that is of order ``(rb / D)^2`` where the face's is of order
``(rb / g0)^2``. It costs about
what the triangle's exact value and gradient cost, so it is worked out only
for a pair that the pass takes (by ``theta`` or the face's bound, the same
pairs as without it) and whose face's bound is above the pass's ``eps``:
the bounds shrink, the pairs do not change, so no voxel's sum of bounds
grows. (A voxel alone has no such use: a voxel and a triangle are summed
exactly.)

The passes: a loose one over every brick, then tighter ones over only the
bricks that hold voxels it left undecided (``bricks`` of them in all); a
voxel still undecided is then refined alone: a traversal per tighter pass,
then the exact sum over every cap triangle (Van Oosterom and Strackee).
Only the time budget (``seconds`` of processor time a thread, read every
``CLOCK_EVERY`` voxels refined) leaves a voxel to its estimate; such voxels
are marked. Every other decision is proven by a bound (a margin of 1e-4, far above the float64
rounding of these sums) or taken on the exact sum.
"""

import numpy as np

from cython.parallel cimport prange, parallel
from libc.stdlib cimport malloc, free
from libc.string cimport memset
from libc.math cimport sqrt, atan2, fabs, M_PI
from libc.stdint cimport int16_t, int64_t, uint8_t
from posix.time cimport clock_gettime, timespec, CLOCK_PROCESS_CPUTIME_ID


cdef struct Tree:
    const double *T      # (k, 9) sorted cap triangles
    const double *S      # (n, 3) area vectors
    const double *Q      # (n, 9) first moments: sum of S_t (x) (centroid_t - c), row-major
    const double *A      # (n,) areas
    const double *C      # (n, 3) box centres
    const double *H      # (n, 3) box half sizes
    const double *R      # (n,) radii
    const double *M      # (n,) root of the second moment: sqrt(sum_t int_t |x - c|^2 dA)
    const double *RA     # (n,) root of the area
    const int64_t *off   # first node of each tree level
    const int64_t *size  # nodes per tree level
    int64_t top          # the root's tree level
    int64_t ntri


cdef struct Grid:
    int64_t n[3]
    double lo[3]
    double d[3]
    double dnorm
    int64_t T            # brick level of the top bricks


#: Voxels refined alone between two readings of the clock (see brick_run).
cdef int64_t CLOCK_EVERY = 64


cdef inline double now() noexcept nogil:
    # The process's processor time, all threads: a loaded machine's waiting
    # does not spend the budget, so what is proven does not depend on the load.
    cdef timespec ts
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &ts)
    return ts.tv_sec + 1e-9 * ts.tv_nsec


cdef inline double tri_angle(const double *t, double px, double py, double pz) noexcept nogil:
    """Signed solid angle over 4 pi of one triangle at p (geovox.inside._triangle_angles)."""
    cdef double ax = t[0] - px, ay = t[1] - py, az = t[2] - pz
    cdef double bx = t[3] - px, by = t[4] - py, bz = t[5] - pz
    cdef double cx = t[6] - px, cy = t[7] - py, cz = t[8] - pz
    cdef double la = sqrt(ax * ax + ay * ay + az * az)
    cdef double lb = sqrt(bx * bx + by * by + bz * bz)
    cdef double lc = sqrt(cx * cx + cy * cy + cz * cz)
    cdef double num = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    cdef double den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
                       + (ax * cx + ay * cy + az * cz) * lb + (bx * cx + by * cy + bz * cz) * la)
    return atan2(num, den) / (2.0 * M_PI)


cdef inline double node_gap(const Tree *tr, int64_t node, double px, double py, double pz,
                            double *vec) noexcept nogil:
    """Distance from p to the node's box (vec: the node's centre minus p)."""
    cdef double o, g = 0
    cdef int a
    vec[0] = tr.C[3 * node] - px
    vec[1] = tr.C[3 * node + 1] - py
    vec[2] = tr.C[3 * node + 2] - pz
    for a in range(3):
        o = fabs(vec[a]) - tr.H[3 * node + a]
        if o > 0:
            g += o * o
    return sqrt(g)


cdef inline double tri_distance(const double *t, double px, double py, double pz) noexcept nogil:
    """Distance from p to the triangle ``t`` (9 doubles): its closest point by Voronoi region.

    Ericson, Real-Time Collision Detection, 5.1.5. A degenerate triangle
    may give NaN; the caller then keeps the box's distance.
    """
    cdef double abx = t[3] - t[0], aby = t[4] - t[1], abz = t[5] - t[2]
    cdef double acx = t[6] - t[0], acy = t[7] - t[1], acz = t[8] - t[2]
    cdef double apx = px - t[0], apy = py - t[1], apz = pz - t[2]
    cdef double d1 = abx * apx + aby * apy + abz * apz, d2 = acx * apx + acy * apy + acz * apz
    cdef double bpx, bpy, bpz, cpx, cpy, cpz, d3, d4, d5, d6, va, vb, vc, v, w, qx, qy, qz
    if d1 <= 0 and d2 <= 0:
        return sqrt(apx * apx + apy * apy + apz * apz)
    bpx = px - t[3]; bpy = py - t[4]; bpz = pz - t[5]
    d3 = abx * bpx + aby * bpy + abz * bpz; d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0 and d4 <= d3:
        return sqrt(bpx * bpx + bpy * bpy + bpz * bpz)
    vc = d1 * d4 - d3 * d2
    if vc <= 0 and d1 >= 0 and d3 <= 0:
        v = d1 / (d1 - d3)
        qx = apx - v * abx; qy = apy - v * aby; qz = apz - v * abz
        return sqrt(qx * qx + qy * qy + qz * qz)
    cpx = px - t[6]; cpy = py - t[7]; cpz = pz - t[8]
    d5 = abx * cpx + aby * cpy + abz * cpz; d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0 and d5 <= d6:
        return sqrt(cpx * cpx + cpy * cpy + cpz * cpz)
    vb = d5 * d2 - d1 * d6
    if vb <= 0 and d2 >= 0 and d6 <= 0:
        w = d2 / (d2 - d6)
        qx = apx - w * acx; qy = apy - w * acy; qz = apz - w * acz
        return sqrt(qx * qx + qy * qy + qz * qz)
    va = d3 * d6 - d5 * d4
    if va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        qx = bpx - w * (t[6] - t[3]); qy = bpy - w * (t[7] - t[4]); qz = bpz - w * (t[8] - t[5])
        return sqrt(qx * qx + qy * qy + qz * qz)
    w = 1.0 / (va + vb + vc)
    v = vb * w
    w = vc * w
    qx = apx - v * abx - w * acx; qy = apy - v * aby - w * acy; qz = apz - v * abz - w * acz
    return sqrt(qx * qx + qy * qy + qz * qz)


cdef inline double expansion(const Tree *tr, int64_t node, const double *y, double *grad) noexcept nogil:
    """The node's solid angle over 4 pi at ``p``, to first order in the node's and p's displacement.

    ``y = c - p0`` (node centre minus expansion point). Returns the value at
    ``p0`` (dipole plus the first moment's term); ``grad`` (3) is its
    gradient in ``p`` (see the module notes of geovox.inside._compiled_caps).
    """
    cdef double r2 = y[0] * y[0] + y[1] * y[1] + y[2] * y[2]
    cdef double r = sqrt(r2)
    cdef double i3 = 1.0 / (r2 * r), i5 = i3 / r2
    cdef const double *S = tr.S + 3 * node
    cdef const double *Q = tr.Q + 9 * node
    cdef double ys = y[0] * S[0] + y[1] * S[1] + y[2] * S[2]
    cdef double yqy = 0, tr_q = Q[0] + Q[4] + Q[8]
    cdef int a, b
    for a in range(3):
        for b in range(3):
            yqy += y[a] * Q[3 * a + b] * y[b]
    cdef double f = 1.0 / (4 * M_PI)
    for a in range(3):  # -J^T S, J = I / r^3 - 3 y y^T / r^5
        grad[a] = -f * (S[a] * i3 - 3 * y[a] * ys * i5)
    return f * (ys * i3 + tr_q * i3 - 3 * yqy * i5)


cdef inline double tri_angle_gradient(const double *t, double px, double py, double pz,
                                     double *grad) noexcept nogil:
    """:func:`tri_angle` at p, and its gradient in p into ``grad``: the Biot-Savart sum over the
    triangle's edges, over 4 pi.

    Each edge's term uses the lengths of the vectors to its two ends, the
    same three that the solid angle uses: three square roots, not nine.
    """
    cdef double v[9]
    cdef double l[3]
    cdef double f
    cdef int i, q, a, b
    for i in range(3):
        v[3 * i] = t[3 * i] - px; v[3 * i + 1] = t[3 * i + 1] - py; v[3 * i + 2] = t[3 * i + 2] - pz
        l[i] = sqrt(v[3 * i] * v[3 * i] + v[3 * i + 1] * v[3 * i + 1] + v[3 * i + 2] * v[3 * i + 2])
    cdef double ax = v[0], ay = v[1], az = v[2], bx = v[3], by = v[4], bz = v[5]
    cdef double cx = v[6], cy = v[7], cz = v[8]
    cdef double num = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
    cdef double den = (l[0] * l[1] * l[2] + (ax * bx + ay * by + az * bz) * l[2]
                       + (ax * cx + ay * cy + az * cz) * l[1] + (bx * cx + by * cy + bz * cz) * l[0])
    grad[0] = 0; grad[1] = 0; grad[2] = 0
    for i in range(3):
        q = (i + 1) % 3
        a = 3 * i; b = 3 * q
        f = (l[i] + l[q]) / (l[i] * l[q] * (l[i] * l[q] + v[a] * v[b] + v[a + 1] * v[b + 1]
                                            + v[a + 2] * v[b + 2]) * 4 * M_PI)
        grad[0] += (v[a + 1] * v[b + 2] - v[a + 2] * v[b + 1]) * f
        grad[1] += (v[a + 2] * v[b] - v[a] * v[b + 2]) * f
        grad[2] += (v[a] * v[b + 1] - v[a + 1] * v[b]) * f
    return atan2(num, den) / (2.0 * M_PI)


#: 1 / (4 pi), rounded once: a bound multiplied by it moves by an ulp, far
#: below the decisions' margin of 1e-4.
cdef double INV_4PI = 1.0 / (4 * M_PI)


cdef inline double single_bound(double area, double rb, double g0) noexcept nogil:
    """Error bound of one triangle's exact value and gradient at a brick's centre, within ``rb``.

    ``g0 > rb`` is the distance from the brick's centre to the triangle (or
    its box). At each point x of the triangle the linear expansion in the
    voxel's offset h (``|h| <= rb``) errs by at most
    ``6 rb^2 phi(rb / |x - p0|) / |x - p0|^4`` (``phi`` of the module notes), over 4 pi;
    ``|x - p0| >= g0``, and summed over the triangle that is at most
    ``6 A rb^2 phi(u) / g0^4`` or, over a whole plane of points at least
    ``g0`` away (``int 6 / |y|^4 dA <= 6 pi / g0^2``), ``6 pi rb^2 phi(u) / g0^2``.
    """
    # 6 phi(u) / g0^2 = (3 g0 - 2 rb) / (g0 (g0 - rb)^2): one division.
    cdef double f = rb * rb * (3 * g0 - 2 * rb) * INV_4PI
    cdef double g2 = g0 * g0
    if area < M_PI * g2:
        return f * area / (g0 * g2 * (g0 - rb) * (g0 - rb))
    return f * M_PI / (g0 * (g0 - rb) * (g0 - rb))


cdef inline double edge_bound(const double *t, double px, double py, double pz,
                             double rb) noexcept nogil:
    """Error bound of one triangle's exact value and gradient at a brick's centre p, within ``rb``,
    from its edges alone: ``(3 / 4) rb^2 sum_e d_e / (d_e - rb) I_e`` over 4 pi (module notes).

    Valid where the ball of radius ``rb`` about p misses the triangle (the
    caller's ``gap > 0``). ``d_e`` is p's distance to edge ``e`` and
    ``I_e = int_e dl / |y - p|^3`` in closed form: along the edge's line at
    distance ``D`` from p, with ``tau`` the offset from the foot of the
    perpendicular and ``rho`` the distance, ``int dtau / rho^3 = [tau / (D^2 rho)]``;
    where both ends lie on one side of the foot that difference is taken as
    ``L |tau0 + tau1| / (rho0 rho1 |tau1 rho0 + tau0 rho1|)``, without
    cancelling. Returns 1e300 where an edge is within ``rb`` (never the
    lesser bound).
    """
    cdef double v[9]
    cdef double l[3]
    cdef double ex, ey, ez, L, si, sq, d, cx, cy, cz, total = 0
    cdef int i, q, a, b
    for i in range(3):
        v[3 * i] = t[3 * i] - px; v[3 * i + 1] = t[3 * i + 1] - py; v[3 * i + 2] = t[3 * i + 2] - pz
        l[i] = sqrt(v[3 * i] * v[3 * i] + v[3 * i + 1] * v[3 * i + 1] + v[3 * i + 2] * v[3 * i + 2])
    for i in range(3):
        q = (i + 1) % 3
        a = 3 * i; b = 3 * q
        ex = v[b] - v[a]; ey = v[b + 1] - v[a + 1]; ez = v[b + 2] - v[a + 2]
        L = sqrt(ex * ex + ey * ey + ez * ez)
        if not L > 0:  # a point: no line integral (NaN: no bound)
            if L == 0:
                continue
            return 1e300
        # tau0 = si / L, tau1 = sq / L: the terms below are those of the
        # docstring with L multiplied out, one division an edge.
        si = v[a] * ex + v[a + 1] * ey + v[a + 2] * ez
        sq = v[b] * ex + v[b + 1] * ey + v[b + 2] * ez
        if si >= 0 or sq <= 0:  # the foot off the edge: the nearer end is nearest
            d = l[i] if l[i] < l[q] else l[q]
            if not d > rb:
                return 1e300
            total += d * L * fabs(si + sq) / ((d - rb) * l[i] * l[q] * fabs(sq * l[i] + si * l[q]))
        else:  # the foot on the edge, at D = |v_i x v_q| / L
            cx = v[a + 1] * v[b + 2] - v[a + 2] * v[b + 1]
            cy = v[a + 2] * v[b] - v[a] * v[b + 2]
            cz = v[a] * v[b + 1] - v[a + 1] * v[b]
            d = sqrt(cx * cx + cy * cy + cz * cz)  # D L
            if not d > rb * L:
                return 1e300
            total += (sq * l[i] - si * l[q]) * L / (l[i] * l[q] * d * (d - rb * L))
    return 0.75 * rb * rb * total * INV_4PI


cdef inline double second_bound(const Tree *tr, int64_t node, double rb, double gap,
                                double a) noexcept nogil:
    """Error bound of :func:`expansion` of ``node`` anywhere within ``rb`` of a brick's centre.

    ``gap`` (> 0) separates the node's box from the brick's ball; ``a`` is
    the distance of the two centres. At a point x of the node and a voxel
    offset h the segment's displacement is ``rho(x) = |x - c| + rb`` at most
    and its distance never below ``gap`` (convexity) nor below
    ``a - s rho``; so the error is at most ``(3 / gap^4) int rho^2 dA`` and,
    where ``r + rb < a``, ``(6 phi(u) / a^4) int rho^2 dA`` (``u = (r + rb) / a``,
    ``phi`` of the module notes, increasing), over 4 pi. ``int rho^2 dA = M2 + 2 rb M1 + rb^2 A
    <= (sqrt(M2) + rb sqrt(A))^2`` (``M1 <= sqrt(A M2)``, Cauchy-Schwarz), with
    ``M2`` the node's second moment about its centre.
    """
    cdef double wq = tr.M[node] + rb * tr.RA[node]
    cdef double reach = tr.R[node] + rb, g2 = gap * gap, d1 = g2 * g2, d2
    wq = wq * wq * INV_4PI
    if reach < a:
        # 6 phi(u) / a^4 = (3 a - 2 reach) / ((a - reach)^2 a^3); the lesser
        # of the two bounds chosen without dividing (d1, d2 > 0).
        d2 = (a - reach) * (a - reach) * a * a * a
        if (3 * a - 2 * reach) * d1 < 3 * d2:
            return wq * (3 * a - 2 * reach) / d2
    return 3 * wq / d1


cdef void brick_pass(const Tree *tr, const Grid *g, const int64_t *tb, double *sums,
                     const int64_t *lev_off, int64_t *stack, double theta, double eps,
                     const uint8_t *act) noexcept nogil:
    """Pass one over top brick ``tb``: every (brick, node) pair, sums per brick into ``sums``.

    ``sums`` holds five doubles per brick of every level ``0 .. g.T`` of this
    top brick (level ``k``: ``2^(T-k)`` a side, from ``lev_off[k]``): the
    value at the brick's centre, its gradient (3) and the error bound. A
    pair is far where ``r + rb <= theta * gap`` or its bound is below ``eps``;
    else the larger side splits; a voxel and a triangle are summed exactly.
    ``act`` (one flag a brick, laid out as ``sums``; NULL: all): only the
    flagged bricks are entered, and only their sums are meaningful.
    """
    cdef int64_t sp, k, ix, iy, iz, l, j, node, nk, slot, o, cx, cy, cz, a
    cdef double side, px, py, pz, rb, gap, reach, bound, val
    cdef double vec[3]
    cdef double grad[3]
    cdef bint ok
    stack[0] = g.T; stack[1] = 0; stack[2] = 0; stack[3] = 0; stack[4] = tr.top; stack[5] = 0
    sp = 1
    while sp > 0:
        sp -= 1
        k = stack[6 * sp]; ix = stack[6 * sp + 1]; iy = stack[6 * sp + 2]; iz = stack[6 * sp + 3]
        l = stack[6 * sp + 4]; j = stack[6 * sp + 5]
        nk = (<int64_t>1) << (g.T - k)
        side = <double>((<int64_t>1) << k)
        px = g.lo[0] + ((tb[0] * nk + ix) * side + (side - 1) / 2 + 0.5) * g.d[0]
        py = g.lo[1] + ((tb[1] * nk + iy) * side + (side - 1) / 2 + 0.5) * g.d[1]
        pz = g.lo[2] + ((tb[2] * nk + iz) * side + (side - 1) / 2 + 0.5) * g.d[2]
        rb = 0.5 * (side - 1) * g.dnorm
        node = tr.off[l] + j
        slot = 5 * (lev_off[k] + (ix * nk + iy) * nk + iz)
        if k == 0 and l == 0:
            # A voxel and one triangle: exact, for about what its expansion
            # and bound would cost.
            sums[slot] += tri_angle(tr.T + 9 * j, px, py, pz)
            continue
        gap = node_gap(tr, node, px, py, pz, vec) - rb
        reach = tr.R[node] + rb
        if l == 0 and k > 0:
            # One triangle: exact at the brick's centre, with its gradient;
            # the bound does not grow with the triangle (a long sliver of a
            # fan is taken per brick, not per voxel), and it takes the
            # distance to the triangle itself, not to its box: a sliver
            # across the axes has a box many times its own neighbourhood.
            val = tri_distance(tr.T + 9 * j, px, py, pz) - rb
            if val > gap:  # not NaN, and no nearer than the box by rounding
                gap = val
        if gap > 0 and l == 0 and k > 0:
            bound = single_bound(tr.A[node], rb, gap + rb)
            if rb <= theta * gap or bound <= eps:
                if bound > eps:
                    # Over a big triangle the edges are far where the face
                    # is near: their bound is the lesser. Only the bound
                    # shrinks, not the pairs taken (each voxel's sum of
                    # bounds is at most what it was).
                    val = edge_bound(tr.T + 9 * j, px, py, pz, rb)
                    if val < bound:
                        bound = val
                sums[slot] += tri_angle_gradient(tr.T + 9 * j, px, py, pz, grad)
                sums[slot + 1] += grad[0]; sums[slot + 2] += grad[1]
                sums[slot + 3] += grad[2]; sums[slot + 4] += bound
                continue
        elif gap > 0:
            bound = second_bound(tr, node, rb, gap, sqrt(vec[0] * vec[0] + vec[1] * vec[1]
                                                         + vec[2] * vec[2]))
            if reach <= theta * gap or bound <= eps:
                val = expansion(tr, node, vec, grad)
                sums[slot] += val; sums[slot + 1] += grad[0]; sums[slot + 2] += grad[1]
                sums[slot + 3] += grad[2]; sums[slot + 4] += bound
                continue
        if k > 0 and (l == 0 or rb > tr.R[node]):  # eight sub-bricks (those inside the grid)
            for o in range(8):
                cx = 2 * ix + (o & 1); cy = 2 * iy + ((o >> 1) & 1); cz = 2 * iz + ((o >> 2) & 1)
                ok = ((tb[0] * 2 * nk + cx) << (k - 1) < g.n[0]
                      and (tb[1] * 2 * nk + cy) << (k - 1) < g.n[1]
                      and (tb[2] * 2 * nk + cz) << (k - 1) < g.n[2])
                if ok and act != NULL:
                    ok = act[lev_off[k - 1] + (cx * 2 * nk + cy) * 2 * nk + cz]
                if ok:
                    a = 6 * sp
                    stack[a] = k - 1; stack[a + 1] = cx; stack[a + 2] = cy; stack[a + 3] = cz
                    stack[a + 4] = l; stack[a + 5] = j
                    sp += 1
        else:  # the node's two children (the second may not exist)
            for o in range(2):
                if 2 * j + o < tr.size[l - 1]:
                    a = 6 * sp
                    stack[a] = k; stack[a + 1] = ix; stack[a + 2] = iy; stack[a + 3] = iz
                    stack[a + 4] = l - 1; stack[a + 5] = 2 * j + o
                    sp += 1


cdef void voxel_pass(const Tree *tr, double theta, double eps, double px, double py, double pz,
                     int64_t *stack, double *out) noexcept nogil:
    """One voxel alone, at opening ratio ``theta``: out = (value, bound)."""
    cdef int64_t sp = 1, l, j, node, o
    cdef double gap, bound
    cdef double vec[3]
    cdef double grad[3]
    out[0] = 0; out[1] = 0
    stack[0] = tr.top; stack[1] = 0
    while sp > 0:
        sp -= 1
        l = stack[2 * sp]; j = stack[2 * sp + 1]
        if l == 0:  # one triangle: exact (see brick_pass)
            out[0] += tri_angle(tr.T + 9 * j, px, py, pz)
            continue
        node = tr.off[l] + j
        gap = node_gap(tr, node, px, py, pz, vec)
        if gap > 0:
            bound = second_bound(tr, node, 0, gap, sqrt(vec[0] * vec[0] + vec[1] * vec[1]
                                                        + vec[2] * vec[2]))
            if tr.R[node] <= theta * gap or bound <= eps:
                out[0] += expansion(tr, node, vec, grad)
                out[1] += bound
                continue
        for o in range(2):
            if 2 * j + o < tr.size[l - 1]:
                stack[2 * sp] = l - 1; stack[2 * sp + 1] = 2 * j + o
                sp += 1


cdef inline int unsure_of(double v, double bound) noexcept nogil:
    # w_K in [est - bound, est + bound]: w_{M+K} - w_K in [v - bound, v + bound].
    return (v - bound <= 0.5 + 1e-4) and (v + bound >= 0.5 - 1e-4)


cdef inline void voxel_field(const Grid *g, const double *sums, const int64_t *lev_off,
                             int64_t vx, int64_t vy, int64_t vz, int64_t gx, int64_t gy, int64_t gz,
                             double *out) noexcept nogil:
    """A voxel's estimate and bound (``out``, 2): its bricks' linear fields summed over the levels."""
    cdef int64_t k, nk, slot
    cdef double s, h
    cdef double px = g.lo[0] + (gx + 0.5) * g.d[0]
    cdef double py = g.lo[1] + (gy + 0.5) * g.d[1]
    cdef double pz = g.lo[2] + (gz + 0.5) * g.d[2]
    out[0] = 0; out[1] = 0
    for k in range(g.T + 1):
        nk = (<int64_t>1) << (g.T - k)
        slot = 5 * (lev_off[k] + ((vx >> k) * nk + (vy >> k)) * nk + (vz >> k))
        # The brick's linear field at the voxel: offsets from its centre.
        s = <double>((<int64_t>1) << k)
        h = (s - 1) / 2 + 0.5
        out[0] += (sums[slot] + sums[slot + 1] * (px - (g.lo[0] + ((gx >> k) * s + h) * g.d[0]))
                   + sums[slot + 2] * (py - (g.lo[1] + ((gy >> k) * s + h) * g.d[1]))
                   + sums[slot + 3] * (pz - (g.lo[2] + ((gz >> k) * s + h) * g.d[2])))
        out[1] += sums[slot + 4]


cdef int64_t brick_decide(const Grid *g, const int64_t *tb, const double *sums,
                          const int64_t *lev_off, const int16_t *w, uint8_t *occ,
                          uint8_t *act, bint every) noexcept nogil:
    """Decide the top brick's voxels from a brick pass's ``sums``; the undecided stay flagged.

    ``act`` level 0 (one flag a voxel of the top brick): on entry the voxels
    to decide (``every``: all those inside the grid); on return those still
    undecided. Returns how many they are.
    """
    cdef int64_t side = (<int64_t>1) << g.T, vx, vy, vz, gx, gy, gz, lin, f, left = 0
    cdef double v
    cdef double out[2]
    for vx in range(side):
        gx = tb[0] * side + vx
        if gx >= g.n[0]:
            break
        for vy in range(side):
            gy = tb[1] * side + vy
            if gy >= g.n[1]:
                break
            for vz in range(side):
                gz = tb[2] * side + vz
                if gz >= g.n[2]:
                    break
                f = (vx * side + vy) * side + vz
                if not every and not act[f]:
                    continue
                voxel_field(g, sums, lev_off, vx, vy, vz, gx, gy, gz, out)
                lin = gx + g.n[0] * (gy + g.n[1] * gz)
                v = w[lin] - out[0]
                occ[lin] = v > 0.5
                act[f] = unsure_of(v, out[1])
                left += act[f]
    return left


cdef void flag_bricks(const Grid *g, const int64_t *lev_off, uint8_t *act) noexcept nogil:
    """Levels 1 .. T of ``act`` from level 0: a brick is flagged where a voxel in it is."""
    cdef int64_t k, nk, x, y, z, o
    memset(act + lev_off[1], 0, lev_off[g.T + 1] - lev_off[1])
    for k in range(1, g.T + 1):
        nk = (<int64_t>1) << (g.T - k)
        for x in range(2 * nk):
            for y in range(2 * nk):
                for z in range(2 * nk):
                    if act[lev_off[k - 1] + (x * 2 * nk + y) * 2 * nk + z]:
                        o = lev_off[k] + ((x >> 1) * nk + (y >> 1)) * nk + (z >> 1)
                        act[o] = 1


cdef void voxel_refine(const Tree *tr, const Grid *g, int64_t lin, double px, double py,
                       double pz, const int16_t *w, uint8_t *occ, const double *passes,
                       int64_t npasses, int64_t *stack, int64_t *counts) noexcept nogil:
    """One voxel alone: each pass in turn until one decides it, else the exact sum."""
    cdef int64_t q, i
    cdef double v, est
    cdef double out[2]
    for q in range(npasses):
        voxel_pass(tr, passes[2 * q], passes[2 * q + 1], px, py, pz, stack, out)
        v = w[lin] - out[0]
        occ[lin] = v > 0.5
        if not unsure_of(v, out[1]):
            return
    counts[1] += 1  # the exact sum over every cap triangle
    est = 0
    for i in range(tr.ntri):
        est += tri_angle(tr.T + 9 * i, px, py, pz)
    occ[lin] = (w[lin] - est) > 0.5


cdef void brick_run(const Tree *tr, const Grid *g, int64_t t, const int64_t *nt,
                    const int16_t *w, uint8_t *occ, uint8_t *est_out, const double *passes,
                    int64_t nbricks, int64_t npasses, int64_t few, double deadline,
                    double *sums, uint8_t *act, const int64_t *lev_off, int64_t *stack,
                    int64_t *counts) noexcept nogil:
    """Decide every voxel of top brick ``t``; counts += (refined, summed exactly, estimated).

    The first ``nbricks`` passes run over bricks (the later ones only over
    the bricks that hold voxels still undecided, and only while at least
    1 / ``few`` of the top brick's voxels are), the rest over single voxels.
    """
    cdef int64_t tb[3]
    cdef int64_t side = (<int64_t>1) << g.T, vx, vy, vz, gx, gy, gz, lin, q, left
    cdef bint late = False
    cdef int64_t seen = 0
    tb[0] = t // (nt[1] * nt[2]); tb[1] = (t // nt[2]) % nt[1]; tb[2] = t % nt[2]
    memset(act, 0, lev_off[1])
    for q in range(nbricks):
        if q and now() > deadline:
            late = True
            break
        if q:
            flag_bricks(g, lev_off, act)
        memset(sums, 0, 5 * lev_off[g.T + 1] * sizeof(double))
        brick_pass(tr, g, tb, sums, lev_off, stack, passes[2 * q], passes[2 * q + 1],
                   NULL if q == 0 else act)
        left = brick_decide(g, tb, sums, lev_off, w, occ, act, q == 0)
        if q == 0:
            counts[0] += left
        if left == 0:
            return
        if left * few < side * side * side:
            # Under 1 / few of the top brick's voxels left: refining them
            # alone costs less than another pass over their bricks (each
            # from the root of the caps' tree).
            break
    for vx in range(side):
        gx = tb[0] * side + vx
        for vy in range(side):
            gy = tb[1] * side + vy
            for vz in range(side):
                gz = tb[2] * side + vz
                if not act[(vx * side + vy) * side + vz] or gx >= g.n[0] or gy >= g.n[1] \
                        or gz >= g.n[2]:
                    continue
                lin = gx + g.n[0] * (gy + g.n[1] * gz)
                # The process's processor clock is a system call that takes
                # a lock over every thread (about as long as a voxel's exact
                # sum over a hundred triangles): read once every CLOCK_EVERY
                # voxels refined, not before each.
                if not late and seen % CLOCK_EVERY == 0:
                    late = now() > deadline
                seen += 1
                if late:
                    est_out[lin] = 1
                    counts[2] += 1
                    continue
                voxel_refine(tr, g, lin, g.lo[0] + (gx + 0.5) * g.d[0],
                             g.lo[1] + (gy + 0.5) * g.d[1], g.lo[2] + (gz + 0.5) * g.d[2], w, occ,
                             passes + 2 * nbricks, npasses - nbricks, stack, counts)


def cap_occupancy(const double[:, ::1] T, const double[:, ::1] S, const double[:, ::1] Q,
                  const double[::1] A,
                  const double[:, ::1] C, const double[:, ::1] H, const double[::1] R,
                  const double[::1] M, const int64_t[::1] offset, const int64_t[::1] size,
                  const int16_t[::1] w, uint8_t[::1] occ, uint8_t[::1] estimated,
                  shape, lo, spacing, int top, const double[:, ::1] passes, int bricks,
                  int few, double seconds, int jobs):
    """Decide ``occ = w - w_K > 1/2`` at every voxel (see the module notes).

    Parameters
    ----------
    T : (k, 9) float64
        The cap triangles in the tree's order (geovox.inside._cap_tree).
    S, Q, A, C, H, R, M, offset, size
        The tree's nodes and levels (geovox.inside._cap_tree; Q and M from
        geovox.inside._first_moments and geovox.inside._second_moments).
    w : (nx * ny * nz,) int16
        ``w_{M+K}`` per voxel, flat in Fortran order.
    occ, estimated : (nx * ny * nz,) uint8, written
        The decision, and 1 where it is the estimate's (the time ran out).
    shape, lo, spacing : the grid (3 ints, 3 floats, 3 floats).
    top : int
        Brick level of the top bricks (``2^top`` voxels a side).
    passes : (p, 2) float64
        Every pass's (theta, eps): the first over every brick, then each in
        turn on what the ones before left undecided, before the exact sum.
    bricks : int
        How many of the passes (at least 1) run over bricks; the rest refine
        single voxels.
    few : int
        A top brick with under 1 / ``few`` of its voxels undecided after a
        brick pass goes on to the single voxels' passes at once.
    seconds : float
        Processor time per thread (the process's, from this call) after
        which an undecided voxel keeps its estimate.
    jobs : int
        Threads; the answer does not depend on them (only where the time runs out).

    Returns
    -------
    (refined, exact, estimated) : voxels the first pass left undecided, of them summed
    exactly, left to the estimate.
    """
    cdef Tree tr
    cdef Grid g
    cdef int64_t nt[3]
    cdef int64_t a, t, ntop, nlev = len(size), stack_len, nsums
    cdef int64_t[::1] lev_off = __import__("numpy").zeros(top + 2, dtype="int64")
    cdef int64_t[:, ::1] counts
    cdef double *sums = NULL
    cdef uint8_t *act = NULL
    cdef int64_t *stack = NULL
    cdef double deadline
    cdef int64_t npasses = passes.shape[0]
    if not 1 <= bricks <= npasses:
        raise ValueError(f"cap_occupancy: {bricks} brick passes of {npasses}")
    cdef const double *pp = &passes[0, 0]
    cdef double[::1] RA = __import__("numpy").sqrt(A)
    tr.T = &T[0, 0]; tr.S = &S[0, 0]; tr.Q = &Q[0, 0]; tr.A = &A[0]; tr.C = &C[0, 0]; tr.H = &H[0, 0]
    tr.R = &R[0]; tr.M = &M[0]; tr.RA = &RA[0]; tr.off = &offset[0]; tr.size = &size[0]; tr.top = nlev - 1
    tr.ntri = T.shape[0]
    for a in range(3):
        g.n[a] = shape[a]; g.lo[a] = lo[a]; g.d[a] = spacing[a]
        # (n + side - 1) // side: with cdivision, // of a negative number truncates.
        nt[a] = (g.n[a] + ((<int64_t>1) << top) - 1) // ((<int64_t>1) << top)
    g.dnorm = sqrt(g.d[0] * g.d[0] + g.d[1] * g.d[1] + g.d[2] * g.d[2])
    g.T = top
    for a in range(top + 1):
        lev_off[a + 1] = lev_off[a] + ((<int64_t>1) << (3 * (top - a)))
    nsums = 5 * lev_off[top + 1]
    # Depth-first: each pop pushes at most 8, and each push goes one level
    # down the bricks or the tree.
    stack_len = 6 * (8 * (top + nlev + 2) + 8)
    ntop = nt[0] * nt[1] * nt[2]
    counts = __import__("numpy").zeros((ntop, 3), dtype="int64")
    deadline = now() + seconds * jobs
    with nogil, parallel(num_threads=jobs):
        sums = <double *>malloc(nsums * sizeof(double))
        act = <uint8_t *>malloc(lev_off[top + 1] * sizeof(uint8_t))
        stack = <int64_t *>malloc(stack_len * sizeof(int64_t))
        for t in prange(ntop, schedule="dynamic"):
            brick_run(&tr, &g, t, nt, &w[0], &occ[0], &estimated[0], pp, bricks, npasses, few,
                      deadline, sums, act, &lev_off[0], stack, &counts[t, 0])
        free(sums)
        free(act)
        free(stack)
    tot = __import__("numpy").asarray(counts).sum(axis=0)
    return int(tot[0]), int(tot[1]), int(tot[2])


cdef void min_area_one(const double *p, int64_t n, double *cost, int64_t *arg, int64_t *cur,
                       int64_t *nxt, int64_t *out) noexcept nogil:
    """One polygon of :func:`min_area_triangles`: the same sums in the same order, the same ties.

    ``cost``, ``arg`` (n * n) are the programme's tables; ``cur``, ``nxt``
    (2 n) the unfolding's intervals; ``out`` (3 (n - 2)) the triangles.
    """
    cdef int64_t d, i, j, k, best, m, q, nc, nn, lk
    cdef double ax, ay, az, bx, by, bz, cx, cy, cz, total, low
    cdef bint nan
    for i in range(n * n):
        cost[i] = 0
    for d in range(2, n):
        for i in range(n - d):
            j = i + d
            bx = p[3 * j] - p[3 * i]; by = p[3 * j + 1] - p[3 * i + 1]; bz = p[3 * j + 2] - p[3 * i + 2]
            best = i + 1
            low = 0
            nan = False
            for k in range(i + 1, j):
                ax = p[3 * k] - p[3 * i]; ay = p[3 * k + 1] - p[3 * i + 1]; az = p[3 * k + 2] - p[3 * i + 2]
                cx = ay * bz - az * by
                cy = az * bx - ax * bz
                cz = ax * by - ay * bx
                total = cost[i * n + k] + cost[k * n + j] + 0.5 * sqrt(cx * cx + cy * cy + cz * cz)
                # NumPy's argmin and min: the first least value, a NaN before all.
                if k == i + 1 or (not nan and (total != total or total < low)):
                    if total != total:
                        nan = True
                    best = k
                    low = total
            cost[i * n + j] = low
            arg[i * n + j] = best
    # Unfolded as the NumPy twin does: a level's intervals, then the left
    # halves of the next level in order, then the right halves.
    cur[0] = 0; cur[1] = n - 1
    nc = 1
    m = 0
    while nc:
        nn = 0
        for q in range(nc):
            i = cur[2 * q]; j = cur[2 * q + 1]
            lk = arg[i * n + j]
            out[3 * m] = i; out[3 * m + 1] = lk; out[3 * m + 2] = j
            m += 1
            if lk - i >= 2:
                nxt[2 * nn] = i; nxt[2 * nn + 1] = lk
                nn += 1
        for q in range(nc):
            i = cur[2 * q]; j = cur[2 * q + 1]
            lk = arg[i * n + j]
            if j - lk >= 2:
                nxt[2 * nn] = lk; nxt[2 * nn + 1] = j
                nn += 1
        for q in range(2 * nn):
            cur[q] = nxt[q]
        nc = nn


def min_area_triangles(const double[:, :, ::1] poly):
    """:func:`geovox.inside.bridge.min_area_triangles`, compiled: the same triangles in the same order.

    Parameters
    ----------
    poly : (m, n, 3) float64, n >= 3

    Returns
    -------
    (m, n - 2, 3) int64
    """
    np = __import__("numpy")
    cdef int64_t m = poly.shape[0], n = poly.shape[1], s
    out_arr = np.zeros((m, max(n - 2, 0), 3), dtype=np.int64)
    cdef int64_t[:, :, ::1] out = out_arr
    if m == 0 or n < 3:
        return out_arr
    cdef double *cost = <double *>malloc(n * n * sizeof(double))
    cdef int64_t *arg = <int64_t *>malloc(n * n * sizeof(int64_t))
    cdef int64_t *cur = <int64_t *>malloc(2 * n * sizeof(int64_t))
    cdef int64_t *nxt = <int64_t *>malloc(2 * n * sizeof(int64_t))
    if cost == NULL or arg == NULL or cur == NULL or nxt == NULL:
        free(cost); free(arg); free(cur); free(nxt)
        raise MemoryError("min_area_triangles: no memory for the tables")
    with nogil:
        for s in range(m):
            min_area_one(&poly[s, 0, 0], n, cost, arg, cur, nxt, &out[s, 0, 0])
    free(cost); free(arg); free(cur); free(nxt)
    return out_arr


def triangle_bounds(const double[::1] t, const double[::1] p, double rb):
    """Test-only entry: one triangle's linear field at a brick's centre and its two error bounds.

    What :func:`brick_pass` computes for a (brick, triangle) pair, exposed so
    that the tests can hold the bounds to sampled points of the ball (not
    used by the conversion).

    Parameters
    ----------
    t : (9,) float64
        The triangle's corners.
    p : (3,) float64
        The brick's centre.
    rb : float
        The brick's radius; the ball must miss the triangle.

    Returns
    -------
    (value, gradient, face, edges) : the solid angle over 4 pi at ``p``, its
    gradient (a tuple of 3), :func:`single_bound` at p's distance to the
    triangle and :func:`edge_bound` (1e300 where an edge is within ``rb``).
    """
    cdef double grad[3]
    cdef double g0 = tri_distance(&t[0], p[0], p[1], p[2])
    cdef double area
    cdef double ux = t[3] - t[0], uy = t[4] - t[1], uz = t[5] - t[2]
    cdef double wx = t[6] - t[0], wy = t[7] - t[1], wz = t[8] - t[2]
    if not g0 > rb:
        raise ValueError(f"triangle_bounds: the ball of radius {rb} meets the triangle ({g0})")
    area = 0.5 * sqrt((uy * wz - uz * wy) ** 2 + (uz * wx - ux * wz) ** 2
                      + (ux * wy - uy * wx) ** 2)
    val = tri_angle_gradient(&t[0], p[0], p[1], p[2], grad)
    return (val, (grad[0], grad[1], grad[2]), single_bound(area, rb, g0),
            edge_bound(&t[0], p[0], p[1], p[2], rb))


def cap_tree(const double[:, ::1] T):
    """The nodes of the caps' tree over triangles ``T`` in their tree order, in one pass a level.

    What geovox.inside.captree's ``_cap_tree`` (after its Morton sort),
    ``_first_moments`` and ``_second_moments`` compute with NumPy, level by
    level in loops: node ``j`` of level ``l + 1`` sums nodes ``2j`` and
    ``2j + 1`` of level ``l`` (area vector ``S``, area ``A``, box ``lo``/``hi``,
    the first moment's sum of ``S_t (x) centroid_t``); the box gives the centre
    ``c``, half sizes ``h`` and radius ``r``; the first moment is taken about
    ``c``, and the second moment's root ``M`` sums each node's triangles
    directly (never a difference, which could round below the truth).

    Parameters
    ----------
    T : (k, 9) float64, k >= 1

    Returns
    -------
    S (n, 3), A (n,), C (n, 3), H (n, 3), R (n,), Q (n, 9), M (n,) : float64
    offset, size : (levels,) int64
    """
    cdef Py_ssize_t k = T.shape[0], n = 0, i, j, l, nl, a, b, first, c0
    cdef int x
    sizes = [k]
    while sizes[len(sizes) - 1] > 1:
        sizes.append((sizes[len(sizes) - 1] + 1) // 2)
    for s_ in sizes:
        n += s_
    size_a = np.asarray(sizes, np.int64)
    offset_a = np.zeros(len(sizes), np.int64)
    offset_a[1:] = np.cumsum(size_a)[:-1]
    S_a = np.empty((n, 3)); A_a = np.empty(n); lo_a = np.empty((n, 3)); hi_a = np.empty((n, 3))
    C_a = np.empty((n, 3)); H_a = np.empty((n, 3)); R_a = np.empty(n); Q_a = np.empty((n, 9))
    M_a = np.zeros(n); g_a = np.empty((k, 3)); own_a = np.empty(k)
    cdef double[:, ::1] S = S_a, lo = lo_a, hi = hi_a, C = C_a, H = H_a, Q = Q_a, g = g_a
    cdef double[::1] A = A_a, R = R_a, M = M_a, own = own_a
    cdef int64_t[::1] offset = offset_a, size = size_a
    cdef double ux, uy, uz, wx, wy, wz, d, e
    cdef int nlev = len(sizes)
    with nogil:
        for i in range(k):
            ux, uy, uz = T[i, 3] - T[i, 0], T[i, 4] - T[i, 1], T[i, 5] - T[i, 2]
            wx, wy, wz = T[i, 6] - T[i, 0], T[i, 7] - T[i, 1], T[i, 8] - T[i, 2]
            S[i, 0] = 0.5 * (uy * wz - uz * wy)
            S[i, 1] = 0.5 * (uz * wx - ux * wz)
            S[i, 2] = 0.5 * (ux * wy - uy * wx)
            A[i] = sqrt(S[i, 0] * S[i, 0] + S[i, 1] * S[i, 1] + S[i, 2] * S[i, 2])
            for x in range(3):
                lo[i, x] = min(min(T[i, x], T[i, 3 + x]), T[i, 6 + x])
                hi[i, x] = max(max(T[i, x], T[i, 3 + x]), T[i, 6 + x])
                g[i, x] = (T[i, x] + T[i, 3 + x] + T[i, 6 + x]) / 3
            e = 0
            for j in range(3):
                for x in range(3):
                    d = T[i, 3 * j + x] - g[i, x]
                    e += d * d
            own[i] = e / 12
            for a in range(3):
                for b in range(3):
                    Q[i, 3 * a + b] = S[i, a] * g[i, b]
        for l in range(1, nlev):
            first, nl = offset[l], size[l]
            c0 = offset[l - 1]
            for j in range(nl):
                a = c0 + 2 * j
                b = a + 1 if 2 * j + 1 < size[l - 1] else -1
                A[first + j] = A[a] + (A[b] if b >= 0 else 0.0)
                for x in range(3):
                    S[first + j, x] = S[a, x] + (S[b, x] if b >= 0 else 0.0)
                    lo[first + j, x] = min(lo[a, x], lo[b, x]) if b >= 0 else lo[a, x]
                    hi[first + j, x] = max(hi[a, x], hi[b, x]) if b >= 0 else hi[a, x]
                for x in range(9):
                    Q[first + j, x] = Q[a, x] + (Q[b, x] if b >= 0 else 0.0)
        for i in range(n):
            e = 0
            for x in range(3):
                C[i, x] = (lo[i, x] + hi[i, x]) / 2
                H[i, x] = (hi[i, x] - lo[i, x]) / 2
                d = hi[i, x] - lo[i, x]
                e += d * d
            R[i] = sqrt(e) / 2
            for a in range(3):
                for b in range(3):
                    Q[i, 3 * a + b] -= S[i, a] * C[i, b]
        for l in range(nlev):
            first = offset[l]
            for i in range(k):
                j = first + (i >> l)
                e = 0
                for x in range(3):
                    d = g[i, x] - C[j, x]
                    e += d * d
                M[j] += A[i] * (e + own[i])
        for i in range(n):
            M[i] = sqrt(M[i])
    return S_a, A_a, C_a, H_a, R_a, Q_a, M_a, offset_a, size_a
