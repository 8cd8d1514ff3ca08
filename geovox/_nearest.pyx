# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False, nonecheck=False
"""Compiled exact nearest triangle (and colour) of every inside voxel.

The same search as :mod:`geovox.nearest.search` -- a branch and bound over an
octree of voxel cells, a triangle leaving a cell's list only when a surface
point provably dominates it over the whole cell -- written as a depth-first
recursion per top cell, with OpenMP threads over the top cells. Every
distance is :func:`geovox.nearest.search.closest`'s float64 formula operation for
operation (built with ``-ffp-contract=off``, no fast-math), and the tie rule
is :func:`geovox.nearest.search.pick`'s, so the answer is the brute-force one bit
for bit. :meth:`Kernel.run` optionally shades each voxel too, with
:func:`geovox.colour.shade`'s arithmetic (see ``shade_one``).

Per cell (see ``solve``): the top cells' lists come from triangle boxes
within reach (``top_list``); a cell measures its candidates at its centre,
drops those a plane bound or a Lipschitz bound already rules out, measures
the rest at its 8 corners and drops those dominated by one of nine surface
points (the nearest to the centre and to each corner). Cells of 4 voxels a
side measure their candidates at the centre only and finish their voxels
with each candidate's tangent plane there as a lower bound (``leaf_planes``:
the least bound measured first, then those within reach of the nearest),
so a voxel measures about 1.7 triangles exactly (spot 256³) and no corner
is measured below cells of 8. (``leaf4``, bounds interpolated from 8
measured corners, is kept for tests: ``Kernel.planes_at(0)``.)

Why a recursion: the NumPy search holds (cell, triangle) pairs level by
level in arrays; here each top cell's lists live in per-thread buffers (a
child's list is a subset of its parent's), so nothing grows with the grid.

Bounds only ever drop a triangle that is farther than the nearest by more
than the margin (1e-6 voxel sizes, far above float64 rounding here) at
every point of a cell, so every triangle within the tie distance of a
voxel's nearest is measured exactly, with the reference formula.
"""

from cython.parallel cimport prange, parallel, threadid
from libc.stdlib cimport malloc, calloc, free
from libc.math cimport sqrt, fmod, fabs, isfinite, floor, ceil, INFINITY
from libc.stdint cimport int32_t, int64_t, uint8_t, uint32_t


cdef struct Ctx:
    const double *T        # (t, 21) rows of prepare()["crow"], one triangle a row
    const uint8_t *flat    # (t,) zero-area triangles: no face region
    const uint8_t *occ     # (nx, ny, nz) F-order inside flags
    int64_t nx, ny, nz, z0
    double h0, h1, h2
    double m               # MARGIN in length units
    double tieh            # TIE in length units
    # Output: RGBA colours, or the raw triangle and barycentrics.
    uint32_t *rgba         # (nx*ny*nz,) F-order, or NULL
    int32_t *tri_out       # (nx*ny*nz,) or NULL
    double *uv_out         # (nx*ny*nz, 2) or NULL
    float *dist_out        # (nx*ny*nz,) distance to the closest point, or NULL
    # Shading (see shade_one).
    const int32_t *fmat    # (t,) material row of each face
    const double *vc       # (t, 3, 3) corner colours, or NULL
    const double *cuv      # (t, 3, 2) corner UVs, or NULL
    const double *factor   # (k, 3)
    const double *add      # (k, 3)
    const int32_t *mint    # (k, 7): textured, tint, h, w, wrap u, wrap v (0 repeat,
                           # 1 mirror, 2 clamp, 3 border), unused
    const int64_t *moff    # (k,) offset of each texture in tex
    const uint8_t *tex     # all textures, (h, w, 3) each
    # Constant colours (see Kernel.same_colours): NULL, or each face's key
    # (-1: its colour varies over it) and each key's packed colour.
    const int64_t *same
    const uint32_t *same_rgba
    # The top cells' first lists (see top_list).
    const double *tlo      # (t, 3) triangle boxes
    const double *thi
    const double *clo      # (g, 3) cluster boxes
    const double *chi
    const int64_t *members # (t,) triangles by cluster
    const int64_t *cstart  # (g + 1,)
    int64_t ncl
    const double *rep      # (r, 3) surface points
    int64_t nrep
    int64_t leaf_max       # leaf4 takes lists up to this long (LEAF_MAX)
    int64_t plane_level    # cells of 2**plane_level voxels finish by leaf_planes (0: none)
    int64_t fail_cell      # tests: the top cell whose lists count as not allocated (-1: none)


cdef inline double closest(const double *R, uint8_t flat, double x0, double x1, double x2,
                           double *u, double *v) noexcept nogil:
    """geovox.nearest.search.closest for one point and triangle, the same operations in order."""
    cdef double ap0 = x0 - R[0]
    cdef double ap1 = x1 - R[1]
    cdef double ap2 = x2 - R[2]
    cdef double s = ap0 * R[9] + ap1 * R[10] + ap2 * R[11]
    cdef double r = ap0 * R[12] + ap1 * R[13] + ap2 * R[14]
    cdef double hh, w, d0, d1, d2, best, dd, st0, st1, st2, e0, e1, e2
    if s >= 0 and r >= 0 and s + r <= 1 and not flat:
        hh = ap0 * R[15] + ap1 * R[16] + ap2 * R[17]
        u[0] = s
        v[0] = r
        return hh * hh
    # Edge ab.
    w = (ap0 * R[3] + ap1 * R[4] + ap2 * R[5]) * R[18]
    w = clip01(w)
    d0 = ap0 - w * R[3]
    d1 = ap1 - w * R[4]
    d2 = ap2 - w * R[5]
    best = d0 * d0 + d1 * d1 + d2 * d2
    u[0] = w
    v[0] = 0.0
    # Edge ac.
    w = (ap0 * R[6] + ap1 * R[7] + ap2 * R[8]) * R[19]
    w = clip01(w)
    d0 = ap0 - w * R[6]
    d1 = ap1 - w * R[7]
    d2 = ap2 - w * R[8]
    dd = d0 * d0 + d1 * d1 + d2 * d2
    if dd < best:
        best = dd
        u[0] = 0.0
        v[0] = w
    # Edge bc, as b + w (ac - ab).
    st0 = ap0 - R[3]
    st1 = ap1 - R[4]
    st2 = ap2 - R[5]
    e0 = R[6] - R[3]
    e1 = R[7] - R[4]
    e2 = R[8] - R[5]
    w = (st0 * e0 + st1 * e1 + st2 * e2) * R[20]
    w = clip01(w)
    d0 = st0 - w * e0
    d1 = st1 - w * e1
    d2 = st2 - w * e2
    dd = d0 * d0 + d1 * d1 + d2 * d2
    if dd < best:
        best = dd
        u[0] = 1.0 - w
        v[0] = w
    return best


cdef inline double clip01(double w) noexcept nogil:
    # np.clip(w, 0, 1): NaN stays NaN.
    if w < 0.0:
        return 0.0
    if w > 1.0:
        return 1.0
    return w


cdef inline double pymod(double a, double b) noexcept nogil:
    """np.mod for floats and b > 0: the result has the sign of b."""
    cdef double r
    if 0.0 <= a < b:  # fmod's own answer, without the libm call
        return a
    r = fmod(a, b)
    if r != 0.0:
        if r < 0.0:
            r += b
    else:
        r = 0.0
    return r


cdef inline int64_t imod(int64_t a, int64_t b) noexcept nogil:
    """a mod b in [0, b), as np.mod; the texel indices here are nearly always
    within one period, where no (slow) integer division is needed."""
    cdef int64_t r
    if 0 <= a < b:
        return a
    if -b <= a < 0:
        return a + b
    if b <= a < 2 * b:
        return a - b
    r = a % b
    if r < 0:
        r += b
    return r


cdef inline void texel_axis(double t, int64_t n, int mode, int64_t *i0, int64_t *i1,
                            double *f) noexcept nogil:
    """geovox.colour._texel_axis for one coordinate (mode 0 repeat, 1 mirror, 2 clamp,
    3 border, sampled as clamp)."""
    cdef double x, x0
    cdef int64_t a, b
    if mode == 3:
        mode = 2
    if mode == 2:
        t = clip01(t)
    elif mode == 1:
        t = pymod(t, 2.0)
    else:
        t = pymod(t, 1.0)
    x = t * <double>n - 0.5
    # floor(x) without a libm call (x86-64's baseline has no rounding
    # instruction); x is within a few texture sizes of 0 here.
    x0 = <double>(<int64_t>x)
    if x0 > x:
        x0 -= 1.0
    f[0] = x - x0
    a = <int64_t>x0
    b = a + 1
    if mode == 2:
        a = 0 if a < 0 else (n - 1 if a > n - 1 else a)
        b = 0 if b < 0 else (n - 1 if b > n - 1 else b)
    elif mode == 1:
        a = imod(a, 2 * n)
        b = imod(b, 2 * n)
        if a >= n:
            a = 2 * n - 1 - a
        if b >= n:
            b = 2 * n - 1 - b
    else:
        a = imod(a, n)
        b = imod(b, n)
    i0[0] = a
    i1[0] = b


cdef inline uint32_t shade_one(const Ctx *c, int64_t t, double u, double v) noexcept nogil:
    """geovox.colour.shade and _pack for one surface point, the same operations in order."""
    cdef double w0 = 1.0 - u - v
    cdef double base[3]
    cdef double out[3]
    cdef double tu, tv, fx, fy, top, bottom
    cdef int64_t x0, x1, y0, y1, r0, r1, h, wd
    cdef int ch
    cdef int32_t mi = c.fmat[t]
    cdef const double *q
    cdef const uint8_t *img
    cdef const int32_t *mt = c.mint + 7 * mi
    cdef uint32_t rgba = 0
    if c.vc != NULL:
        q = c.vc + 9 * t
        for ch in range(3):
            base[ch] = w0 * q[ch] + u * q[3 + ch] + v * q[6 + ch]
    else:
        base[0] = 1.0
        base[1] = 1.0
        base[2] = 1.0
    if mt[0]:
        q = c.cuv + 6 * t
        tu = w0 * q[0] + u * q[2] + v * q[4]
        tv = w0 * q[1] + u * q[3] + v * q[5]
        # geovox.colour.on_texture: finite, and within [0, 1] (a margin of
        # 1e-9) along a "border" axis; elsewhere the face is as if untextured.
        if isfinite(tu) and isfinite(tv) and (
                mt[4] != 3 or (tu >= -1e-9 and tu <= 1.0 + 1e-9)) and (
                mt[5] != 3 or (tv >= -1e-9 and tv <= 1.0 + 1e-9)):
            h = mt[2]
            wd = mt[3]
            img = c.tex + c.moff[mi]
            texel_axis(tu, wd, mt[4], &x0, &x1, &fx)
            # Rows run down the image: row coordinate 1 - v.
            texel_axis(1.0 - tv, h, mt[5], &y0, &y1, &fy)
            r0 = y0 * wd
            r1 = y1 * wd
            for ch in range(3):
                top = img[3 * (r0 + x0) + ch] * (1 - fx) + img[3 * (r0 + x1) + ch] * fx
                bottom = img[3 * (r1 + x0) + ch] * (1 - fx) + img[3 * (r1 + x1) + ch] * fx
                top = (top * (1 - fy) + bottom * fy) / 255.0
                base[ch] = top * base[ch] if mt[1] else top
    for ch in range(3):
        out[ch] = clip01(base[ch] * c.factor[3 * mi + ch] + c.add[3 * mi + ch])
        # rint for 0 <= x <= 255 without a libm call: adding and taking
        # away 2**52 rounds to the nearest integer, ties to even, as rint.
        rgba |= (<uint32_t>((out[ch] * 255.0 + 4503599627370496.0) - 4503599627370496.0)
                 ) << (8 * ch)
    return rgba | (<uint32_t>255 << 24)


cdef inline void emit(const Ctx *c, int64_t i, int64_t j, int64_t k, int64_t t, double u,
                      double v) noexcept nogil:
    cdef int64_t idx = i + c.nx * (j + c.ny * k)
    cdef const double *R
    cdef double d0, d1, d2
    if c.rgba != NULL:
        c.rgba[idx] = shade_one(c, t, u, v)
    elif c.tri_out != NULL:
        c.tri_out[idx] = <int32_t>t
        c.uv_out[2 * idx] = u
        c.uv_out[2 * idx + 1] = v
    if c.dist_out != NULL:
        # |x - (a + u ab + v ac)| in float64, as geovox.nearest.point_distances
        # computes it (same operations in order), then rounded to float32.
        R = c.T + 21 * t
        d0 = ((<double>i + 0.5) * c.h0 - R[0]) - (u * R[3] + v * R[6])
        d1 = ((<double>j + 0.5) * c.h1 - R[1]) - (u * R[4] + v * R[7])
        d2 = ((<double>(k + c.z0) + 0.5) * c.h2 - R[2]) - (u * R[5] + v * R[8])
        c.dist_out[idx] = <float>sqrt(d0 * d0 + d1 * d1 + d2 * d2)


cdef inline int64_t common_key(const Ctx *c, const int32_t *cand, int64_t n) noexcept nogil:
    """The constant-colour key every candidate shares, or -1 (none, or not all the same)."""
    cdef int64_t q, key
    if c.same == NULL or n == 0:
        return -1
    key = c.same[cand[0]]
    if key < 0:
        return -1
    for q in range(1, n):
        if c.same[cand[q]] != key:
            return -1
    return key


cdef void fill_cell(const Ctx *c, int64_t i0, int64_t i1, int64_t j0, int64_t j1, int64_t k0,
                    int64_t k1, uint32_t rgba) noexcept nogil:
    """Every inside voxel of the box takes the colour ``rgba``."""
    cdef int64_t i, j, k, row
    for k in range(k0, k1):
        for j in range(j0, j1):
            row = c.nx * (j + c.ny * k)
            for i in range(i0, i1):
                if c.occ[row + i]:
                    c.rgba[row + i] = rgba


cdef inline bint any_inside(const Ctx *c, int64_t i0, int64_t i1, int64_t j0, int64_t j1,
                            int64_t k0, int64_t k1) noexcept nogil:
    cdef int64_t i, j, k, row
    for k in range(k0, k1):
        for j in range(j0, j1):
            row = c.nx * (j + c.ny * k)
            for i in range(i0, i1):
                if c.occ[row + i]:
                    return True
    return False


cdef void leaf(const Ctx *c, int64_t i0, int64_t i1, int64_t j0, int64_t j1, int64_t k0,
               int64_t k1, const int32_t *cand, int64_t n, double *dbuf) noexcept nogil:
    """Every inside voxel of the box: its candidates measured exactly, then the tie rule."""
    cdef int64_t i, j, k, q, t, row, win
    cdef double x0, x1, x2, u, v, d, low, far
    for k in range(k0, k1):
        x2 = (<double>(k + c.z0) + 0.5) * c.h2
        for j in range(j0, j1):
            x1 = (<double>j + 0.5) * c.h1
            row = c.nx * (j + c.ny * k)
            for i in range(i0, i1):
                if not c.occ[row + i]:
                    continue
                x0 = (<double>i + 0.5) * c.h0

                if n == 1:
                    t = cand[0]
                    closest(c.T + 21 * t, c.flat[t], x0, x1, x2, &u, &v)
                    emit(c, i, j, k, t, u, v)
                    continue
                low = INFINITY
                for q in range(n):
                    t = cand[q]
                    d = closest(c.T + 21 * t, c.flat[t], x0, x1, x2,
                                &dbuf[3 * q + 1], &dbuf[3 * q + 2])
                    dbuf[3 * q] = d
                    if d < low:
                        low = d
                # pick(): of those within TIE of the smallest distance, the
                # smallest index. Distances are compared as pick() does, after
                # sqrt; the squares only skip those clearly beyond the tie.
                low = sqrt(low) + c.tieh
                far = low * low * (1.0 + 1e-9) + c.tieh * c.tieh
                win = -1
                for q in range(n):
                    if dbuf[3 * q] <= far and sqrt(dbuf[3 * q]) <= low and (
                            win < 0 or cand[q] < cand[win]):
                        win = q
                if win < 0:  # every distance NaN: never index cand[-1]
                    win = 0
                emit(c, i, j, k, cand[win], dbuf[3 * win + 1], dbuf[3 * win + 2])


#: Cells of 4 voxels a side with at most this many candidates are finished
#: by leaf4 (bounds interpolated from the corners); bigger lists go down to
#: cells of 2 (a fixed per-thread buffer of 68 doubles a candidate).
cdef enum:
    LEAF_MAX = 256


cdef inline int64_t pick_measured(const Ctx *c, const double *E, int64_t cnt,
                                  double low) noexcept nogil:
    """pick() over ``cnt`` measured candidates ``E`` (cnt, 4: squared distance, u, v,
    triangle), ``low`` the smallest squared distance; returns the winner's row.

    As in leaf(): of those within TIE of the smallest distance, the smallest
    triangle index, compared after sqrt; every distance NaN gives row 0.
    """
    cdef double far
    cdef int64_t q, win = -1
    low = sqrt(low) + c.tieh
    far = low * low * (1.0 + 1e-9) + c.tieh * c.tieh
    for q in range(cnt):
        if E[4 * q] <= far and sqrt(E[4 * q]) <= low and (
                win < 0 or E[4 * q + 3] < E[4 * win + 3]):
            win = q
    if win < 0:
        win = 0
    return win


cdef inline bint plane_drops(const double *R, double u, double v, double dc, double m0,
                             double m1, double m2, double X[8][3], const double *r2,
                             double th0, double *e0, double *e1, double *e2) noexcept nogil:
    """Whether the plane bound alone drops triangle ``R`` at every corner ``X``.

    ``(u, v)`` is its closest point to the cell centre ``m``, ``dc > 0`` that
    distance; ``e`` gets the unit normal from that point to ``m``. T lies
    behind the plane through the point, facing the centre (T is convex), so
    ``dc + (X - m) . e`` bounds ``d(X, T)`` from below; where its square beats
    ``r2[k] = |X[k] - p|**2`` by ``th0`` at all 8 corners, the centre's point
    ``p`` dominates T over the cell.
    """
    cdef double d2
    cdef int k
    e0[0] = (m0 - (R[0] + u * R[3] + v * R[6])) / dc
    e1[0] = (m1 - (R[1] + u * R[4] + v * R[7])) / dc
    e2[0] = (m2 - (R[2] + u * R[5] + v * R[8])) / dc
    for k in range(8):
        d2 = dc + (X[k][0] - m0) * e0[0] + (X[k][1] - m1) * e1[0] + (X[k][2] - m2) * e2[0]
        d2 = d2 * d2 if d2 > 0 else 0.0
        if not (d2 - r2[k] > th0):
            return False
    return True


cdef void leaf4(const Ctx *c, int64_t i0, int64_t i1, int64_t j0, int64_t j1, int64_t k0,
                int64_t k1, const int32_t *cand, int64_t n, const double *D,
                double *wbuf) noexcept nogil:
    """A cell of up to 4 voxels a side whose candidates' squared distances at the 8
    corner voxels ``D`` (n, 8) are known: each voxel measures only the candidates
    that bounds interpolated from the corners cannot rule out.

    ``d(x, T)**2`` is convex, so at most its multilinear interpolation from
    the box's corners ``I(x)``; ``d(x, T)**2 - |x|**2`` is concave, so at
    least ``I(x) - q(x)`` with ``q(x) = sum over axes of (x - lo) (hi - x)``
    (the same interpolation of ``|x|**2``, less ``|x|**2``). The nearest
    distance is at most ``U = min over T of I_T(x)``; a triangle within the
    margin of it has ``I_T(x) - q(x) <= U + 2 m sqrt(U) + m**2``, so only
    those are measured exactly (q <= 6 voxels^2 here, 0 at the corners).
    """
    cdef int64_t lx = i1 - i0, ly = j1 - j0, lz = k1 - k0
    cdef int64_t i, j, k, q, t, row, vi, cnt, win, qb
    cdef double *I = wbuf               # (n, 64) interpolated bounds
    cdef double *E = wbuf + 64 * n      # (n, 4) exact distance, u, v, candidate
    cdef double wx, wy, wz, a, b, U, lim, qx, x0, x1, x2, d, low, u, v
    cdef double fx = 1.0 / (lx - 1) if lx > 1 else 0.0
    cdef double fy = 1.0 / (ly - 1) if ly > 1 else 0.0
    cdef double fz = 1.0 / (lz - 1) if lz > 1 else 0.0
    cdef const double *Dq
    for q in range(n):
        Dq = D + 8 * q
        for k in range(lz):
            wz = k * fz
            for j in range(ly):
                wy = j * fy
                a = ((Dq[0] * (1 - wy) + Dq[2] * wy) * (1 - wz)
                     + (Dq[4] * (1 - wy) + Dq[6] * wy) * wz)
                b = ((Dq[1] * (1 - wy) + Dq[3] * wy) * (1 - wz)
                     + (Dq[5] * (1 - wy) + Dq[7] * wy) * wz)
                for i in range(lx):
                    wx = i * fx
                    I[64 * q + 16 * k + 4 * j + i] = a * (1 - wx) + b * wx
    for k in range(k0, k1):
        x2 = (<double>(k + c.z0) + 0.5) * c.h2
        for j in range(j0, j1):
            x1 = (<double>j + 0.5) * c.h1
            row = c.nx * (j + c.ny * k)
            for i in range(i0, i1):
                if not c.occ[row + i]:
                    continue
                x0 = (<double>i + 0.5) * c.h0
                vi = 16 * (k - k0) + 4 * (j - j0) + (i - i0)
                U = INFINITY
                qb = 0
                for q in range(n):
                    if I[64 * q + vi] < U:
                        U = I[64 * q + vi]
                        qb = q
                # The candidate that looks nearest, measured first: its
                # distance is a tighter U (at most its I, by convexity).
                t = cand[qb]
                d = closest(c.T + 21 * t, c.flat[t], x0, x1, x2, &u, &v)
                E[0] = d
                E[1] = u
                E[2] = v
                E[3] = <double>t
                cnt = 1
                low = d
                if d < U:
                    U = d
                qx = (c.h0 * c.h0 * ((i - i0) * (i1 - 1 - i))
                      + c.h1 * c.h1 * ((j - j0) * (j1 - 1 - j))
                      + c.h2 * c.h2 * ((k - k0) * (k1 - 1 - k)))
                # Rounding of I (about 1e-16 of it) is far inside the margin.
                lim = U + qx + 2.0 * c.m * sqrt(U) + c.m * c.m
                for q in range(n):
                    if q == qb or I[64 * q + vi] > lim:  # NaN keeps the candidate
                        continue
                    t = cand[q]
                    d = closest(c.T + 21 * t, c.flat[t], x0, x1, x2, &u, &v)
                    E[4 * cnt] = d
                    E[4 * cnt + 1] = u
                    E[4 * cnt + 2] = v
                    E[4 * cnt + 3] = <double>t
                    cnt += 1
                    if d < low:
                        low = d
                if cnt == 1:  # pick() of one: it (NaN or not), without the square roots
                    emit(c, i, j, k, <int64_t>E[3], E[1], E[2])
                    continue
                # pick(), as in leaf().
                win = pick_measured(c, E, cnt, low)
                emit(c, i, j, k, <int64_t>E[4 * win + 3], E[4 * win + 1], E[4 * win + 2])


#: leaf_planes takes lists up to this long (its buffer: 10 doubles a candidate).
cdef enum:
    PLANE_MAX = (64 + 4) * LEAF_MAX // 10


cdef void leaf_planes(const Ctx *c, int64_t i0, int64_t i1, int64_t j0, int64_t j1,
                      int64_t k0, int64_t k1, double X[8][3], const double *r2c,
                      const int32_t *cand, int64_t n, const double *dbuf, double rh,
                      double lim, double th0, double *wbuf) noexcept nogil:
    """A cell whose candidates' squared distances and barycentrics at its centre are in
    ``dbuf`` (9 a candidate): each voxel measures its candidates in the order of
    a lower bound, until the bound of the next exceeds the nearest measured.

    The bound: ``T`` lies behind the plane through its closest point ``p`` to
    the centre ``m``, facing ``m`` (``T`` is convex), so ``d(x, T) >= dc +
    (x - m) . e`` with ``dc = |m - p|`` and ``e = (m - p) / dc``: exact where
    ``x``'s nearest point on ``T`` is on its face, below by about ``r**2 / (2
    dc)`` (``r`` the sideways offset of ``x``) elsewhere. A candidate whose
    bound exceeds ``sqrt(U) + m`` (``U`` the least squared distance measured)
    is farther than the nearest by more than the margin: never within the
    tie distance. The cell first drops what the centre's point dominates at
    every corner (as ``solve``: ``X`` the corners, ``r2c`` their squared
    distances to that point, ``rh``, ``lim``, ``th0`` its thresholds).
    """
    # By component (contiguous rows: the bounds' loop is vectorised): dc,
    # e0, e1, e2 and the triangle of each survivor, then its bound at one voxel.
    cdef double *Pd = wbuf
    cdef double *P0 = wbuf + n
    cdef double *P1 = wbuf + 2 * n
    cdef double *P2 = wbuf + 3 * n
    cdef double *Pt = wbuf + 4 * n
    cdef double *L = wbuf + 5 * n
    cdef double *E = wbuf + 6 * n     # (ns, 4) measured: squared distance, u, v, triangle
    cdef double m0 = 0.5 * (X[0][0] + X[7][0])
    cdef double m1 = 0.5 * (X[0][1] + X[7][1])
    cdef double m2 = 0.5 * (X[0][2] + X[7][2])
    cdef double dc, d2, u, v, e0, e1, e2, x0, x1, x2, y0, y1, y2, best, reach, lq, low
    cdef const double *R
    cdef int64_t q, t, ns = 0, i, j, k, row, cnt, qb, win, same = -1
    cdef int a
    cdef bint drop
    # Below this a centre's closest point gives no trustworthy direction (the
    # rounding of m - p over dc): such a candidate has bound 0, always measured.
    cdef double guard = 1e-3 * c.h0
    if c.h1 < c.h0:
        guard = 1e-3 * c.h1
    if c.h2 * 1e-3 < guard:
        guard = 1e-3 * c.h2
    for q in range(n):
        t = cand[q]
        dc = sqrt(dbuf[9 * q])
        d2 = dc - rh
        if d2 > 0 and d2 * d2 > lim:
            continue
        e0 = e1 = e2 = 0.0
        if dc > guard:
            R = c.T + 21 * t
            if plane_drops(R, dbuf[9 * q + 1], dbuf[9 * q + 2], dc, m0, m1, m2, X, r2c, th0,
                           &e0, &e1, &e2):
                continue
        if not (dc > guard and isfinite(e0) and isfinite(e1) and isfinite(e2)):
            dc = e0 = e1 = e2 = 0.0
        Pd[ns] = dc
        P0[ns] = e0
        P1[ns] = e1
        P2[ns] = e2
        Pt[ns] = <double>t
        ns += 1
        if c.same != NULL and ns > 1 and c.same[t] != same:
            same = -1
        elif ns == 1:
            same = c.same[t] if c.same != NULL else -1
    if same >= 0:  # every survivor has one constant colour (see common_key)
        fill_cell(c, i0, i1, j0, j1, k0, k1, c.same_rgba[same])
        return
    if ns == 0:  # not for a finite nearest (it is never dropped); measure all
        leaf(c, i0, i1, j0, j1, k0, k1, cand, n, wbuf)
        return
    for k in range(k0, k1):
        x2 = (<double>(k + c.z0) + 0.5) * c.h2
        y2 = x2 - m2
        for j in range(j0, j1):
            x1 = (<double>j + 0.5) * c.h1
            y1 = x1 - m1
            row = c.nx * (j + c.ny * k)
            for i in range(i0, i1):
                if not c.occ[row + i]:
                    continue
                x0 = (<double>i + 0.5) * c.h0
                y0 = x0 - m0
                # The least bound first: where it is exact (x over the face
                # of its triangle) its distance is the nearest, and the
                # others' bounds are measured against it.
                for q in range(ns):
                    L[q] = Pd[q] + y0 * P0[q] + y1 * P1[q] + y2 * P2[q]
                qb = 0
                lq = L[0]
                for q in range(1, ns):
                    if L[q] < lq:
                        lq = L[q]
                        qb = q
                t = <int64_t>Pt[qb]
                best = closest(c.T + 21 * t, c.flat[t], x0, x1, x2, &u, &v)
                E[0] = best
                E[1] = u
                E[2] = v
                E[3] = <double>t
                cnt = 1
                # A NaN distance: every candidate is measured ("not >").
                reach = sqrt(best) + c.m
                for q in range(ns):
                    if q == qb or L[q] > reach:
                        continue
                    t = <int64_t>Pt[q]
                    d2 = closest(c.T + 21 * t, c.flat[t], x0, x1, x2, &u, &v)
                    E[4 * cnt] = d2
                    E[4 * cnt + 1] = u
                    E[4 * cnt + 2] = v
                    E[4 * cnt + 3] = <double>t
                    cnt += 1
                    if d2 < best:  # a lower reach only skips more that are beyond it
                        best = d2
                        reach = sqrt(d2) + c.m
                if cnt == 1:  # pick() of one: it (NaN or not), without the square roots
                    emit(c, i, j, k, <int64_t>E[3], E[1], E[2])
                    continue
                # pick(), as in leaf().
                low = INFINITY
                for q in range(cnt):
                    if E[4 * q] < low:
                        low = E[4 * q]
                win = pick_measured(c, E, cnt, low)
                emit(c, i, j, k, <int64_t>E[4 * win + 3], E[4 * win + 1], E[4 * win + 2])


cdef void solve(const Ctx *c, int level, int64_t ci, int64_t cj, int64_t ck,
                const int32_t *cand, int64_t n, int32_t *buf, double *dbuf,
                double *wbuf) noexcept nogil:
    """The cell of ``2**level`` voxels at (ci, cj, ck): prune its list, then its children.

    A triangle ``T`` is dropped when some surface point ``p`` dominates it
    over the cell's box: ``d(x, T)**2 - |x - p|**2`` is concave in ``x``, so
    if it exceeds ``2 m r + m**2`` (``r`` the largest ``|corner - p|``) at
    the 8 corners it does everywhere in the box, and then ``d(x, T) > d(x,
    surface) + m`` there (see geovox.nearest.search). Nine points are tried: the
    nearest surface point to the centre and to each corner (among the
    candidates); a point near one corner drops what lies beyond that corner.
    """
    cdef int64_t s = (<int64_t>1) << level
    cdef int64_t i0 = ci * s, j0 = cj * s, k0 = ck * s
    cdef int64_t i1 = min(i0 + s, c.nx), j1 = min(j0 + s, c.ny), k1 = min(k0 + s, c.nz)
    cdef double lo0, lo1, lo2, hi0, hi1, hi2, m0, m1, m2, d2, u, v, lim, rh
    cdef double x0, x1, x2, e0, e1, e2, r2max, dc, th0
    cdef double X[8][3]            # the corners
    cdef double P[9][3]            # the dominating points: centre's, then each corner's
    cdef double best[9]
    cdef double pu[9]
    cdef double pv[9]
    cdef int64_t bt[9]
    cdef double r2[9][8]           # |corner - point|^2
    cdef double thresh[9]
    cdef const double *R
    cdef const double *D
    cdef int64_t q, t, nn, ns, a, b, g
    cdef int k, j
    cdef bint drop
    if n == 0:
        return
    # Every triangle still in the running has the same constant colour: so
    # has every voxel's nearest point, whichever triangle it is on.
    q = common_key(c, cand, n)
    if q >= 0:
        fill_cell(c, i0, i1, j0, j1, k0, k1, c.same_rgba[q])
        return
    if level <= 1 or n == 1:
        leaf(c, i0, i1, j0, j1, k0, k1, cand, n, dbuf)
        return
    # The box of the cell's voxel centres (clipped to the block).
    lo0 = (<double>i0 + 0.5) * c.h0
    hi0 = (<double>(i1 - 1) + 0.5) * c.h0
    lo1 = (<double>j0 + 0.5) * c.h1
    hi1 = (<double>(j1 - 1) + 0.5) * c.h1
    lo2 = (<double>(k0 + c.z0) + 0.5) * c.h2
    hi2 = (<double>(k1 - 1 + c.z0) + 0.5) * c.h2
    m0 = 0.5 * (lo0 + hi0)
    m1 = 0.5 * (lo1 + hi1)
    m2 = 0.5 * (lo2 + hi2)
    for k in range(8):
        X[k][0] = hi0 if k & 1 else lo0
        X[k][1] = hi1 if k & 2 else lo1
        X[k][2] = hi2 if k & 4 else lo2
    for j in range(9):
        best[j] = INFINITY
        bt[j] = -1
        pu[j] = pv[j] = 0.0
    # The surface point nearest the centre among the candidates.
    for q in range(n):
        t = cand[q]
        d2 = closest(c.T + 21 * t, c.flat[t], m0, m1, m2, &u, &v)
        dbuf[9 * q] = d2
        dbuf[9 * q + 1] = u
        dbuf[9 * q + 2] = v
        if d2 < best[0] or bt[0] < 0:
            best[0] = d2
            bt[0] = t
            pu[0] = u
            pv[0] = v
    surface_point(c, bt[0], pu[0], pv[0], P[0])
    r2max = corner_r2(X, P[0], r2[0])
    # Every corner is rh from the centre, so d(corner, T) >= d(centre, T) - rh:
    # where that alone beats every corner's |corner - p|, no corner is measured.
    e0 = 0.5 * (hi0 - lo0)
    e1 = 0.5 * (hi1 - lo1)
    e2 = 0.5 * (hi2 - lo2)
    rh = sqrt(e0 * e0 + e1 * e1 + e2 * e2)
    lim = r2max + 2.0 * c.m * sqrt(r2max) + c.m * c.m
    th0 = 2.0 * c.m * sqrt(r2max) + c.m * c.m
    if level == c.plane_level and n <= PLANE_MAX:
        leaf_planes(c, i0, i1, j0, j1, k0, k1, X, r2[0], cand, n, dbuf, rh, lim, th0, wbuf)
        return
    # The others: squared distances at the 8 corners (8 per survivor, in dbuf).
    ns = 0
    for q in range(n):
        t = cand[q]
        dc = sqrt(dbuf[9 * q])
        d2 = dc - rh
        if d2 > 0 and d2 * d2 > lim:
            continue
        R = c.T + 21 * t
        if dc > 0:
            # T lies behind the plane through its closest point to the
            # centre, facing the centre (T is convex): the distance to that
            # plane bounds d(corner, T) from below; if it alone lets the
            # centre's point dominate T at every corner, T is dropped unmeasured.
            if plane_drops(R, dbuf[9 * q + 1], dbuf[9 * q + 2], dc, m0, m1, m2, X, r2[0], th0,
                           &e0, &e1, &e2):
                continue
        buf[ns] = <int32_t>t
        for k in range(8):
            d2 = closest(R, c.flat[t], X[k][0], X[k][1], X[k][2], &u, &v)
            dbuf[8 * ns + k] = d2
            if d2 < best[1 + k] or bt[1 + k] < 0:
                best[1 + k] = d2
                bt[1 + k] = t
                pu[1 + k] = u
                pv[1 + k] = v
        ns += 1
    for j in range(9):
        if j:
            surface_point(c, bt[j], pu[j], pv[j], P[j])
            r2max = corner_r2(X, P[j], r2[j])
        else:
            r2max = 0.0
            for k in range(8):
                if r2[0][k] > r2max:
                    r2max = r2[0][k]
        thresh[j] = 2.0 * c.m * sqrt(r2max) + c.m * c.m
    nn = 0
    for q in range(ns):
        D = dbuf + 8 * q
        drop = False
        for j in range(9):
            drop = True
            for k in range(8):
                if not (D[k] - r2[j][k] > thresh[j]):  # NaN keeps the triangle
                    drop = False
                    break
            if drop:
                break
        if not drop:
            buf[nn] = buf[q]
            for k in range(8):
                dbuf[8 * nn + k] = D[k]
            nn += 1
    q = common_key(c, buf, nn)
    if q >= 0:
        fill_cell(c, i0, i1, j0, j1, k0, k1, c.same_rgba[q])
        return
    if level == 2 and nn <= c.leaf_max and nn > 1:
        leaf4(c, i0, i1, j0, j1, k0, k1, buf, nn, dbuf, wbuf)
        return
    for g in range(8):
        a = 2 * ci + (g & 1)
        b = 2 * cj + ((g >> 1) & 1)
        q = 2 * ck + ((g >> 2) & 1)
        s = (<int64_t>1) << (level - 1)
        if a * s >= c.nx or b * s >= c.ny or q * s >= c.nz:
            continue
        if not any_inside(c, a * s, min(a * s + s, c.nx), b * s, min(b * s + s, c.ny),
                          q * s, min(q * s + s, c.nz)):
            continue
        solve(c, level - 1, a, b, q, buf, nn, buf + nn, dbuf, wbuf)


cdef inline void surface_point(const Ctx *c, int64_t t, double u, double v,
                               double *p) noexcept nogil:
    cdef const double *R = c.T + 21 * t
    p[0] = R[0] + u * R[3] + v * R[6]
    p[1] = R[1] + u * R[4] + v * R[7]
    p[2] = R[2] + u * R[5] + v * R[8]


cdef inline double corner_r2(double X[8][3], const double *p, double *r2) noexcept nogil:
    """``r2[k] = |X[k] - p|**2``; returns the largest."""
    cdef double e0, e1, e2, top = 0.0
    cdef int k
    for k in range(8):
        e0 = X[k][0] - p[0]
        e1 = X[k][1] - p[1]
        e2 = X[k][2] - p[2]
        r2[k] = e0 * e0 + e1 * e1 + e2 * e2
        if r2[k] > top:
            top = r2[k]
    return top


cdef class Kernel:
    """One block's search: triangle rows, inside flags, frame, and where answers go."""

    cdef Ctx c
    cdef object keep  # the arrays the pointers point into

    def __init__(self, const double[:, ::1] rows, const uint8_t[::1] flat,
                 const uint8_t[::1] occ, shape, int64_t z0, spacing, double margin,
                 double tie):
        self.keep = [rows, flat, occ]
        self.c.T = &rows[0, 0]
        self.c.flat = &flat[0]
        self.c.occ = &occ[0]
        self.c.nx, self.c.ny, self.c.nz = shape
        self.c.z0 = z0
        self.c.h0, self.c.h1, self.c.h2 = spacing
        self.c.m = margin
        self.c.tieh = tie
        self.c.rgba = NULL
        self.c.tri_out = NULL
        self.c.uv_out = NULL
        self.c.dist_out = NULL
        self.c.vc = NULL
        self.c.cuv = NULL
        self.c.same = NULL
        self.c.same_rgba = NULL
        self.c.ncl = 0
        self.c.nrep = 0
        self.c.leaf_max = LEAF_MAX
        self.c.plane_level = 2
        self.c.fail_cell = -1
        if rows.shape[1] != 21 or flat.shape[0] != rows.shape[0]:
            raise ValueError("rows must be (t, 21) and flat (t,)")
        if occ.shape[0] != self.c.nx * self.c.ny * self.c.nz:
            raise ValueError("occupancy size does not match the shape")

    def raw_output(self, int32_t[::1] tri, double[:, ::1] uv):
        """Write each inside voxel's triangle and barycentrics (F-order voxel index)."""
        if tri.shape[0] != self.c.nx * self.c.ny * self.c.nz or uv.shape[0] != tri.shape[0]:
            raise ValueError("outputs must have one row per voxel")
        self.keep += [tri, uv]
        self.c.tri_out = &tri[0]
        self.c.uv_out = &uv[0, 0]
        self.c.rgba = NULL
        self.c.same = NULL  # the raw answers are the nearest triangles themselves

    def dist_output(self, float[::1] dist):
        """Also write each voxel's distance to its nearest surface point (float32, F order).

        With no other output, the answers are the distances alone; with
        :meth:`raw_output` the triangles and barycentrics too.
        """
        if dist.shape[0] != self.c.nx * self.c.ny * self.c.nz:
            raise ValueError("dist must have one entry per voxel")
        if self.c.rgba != NULL:
            raise ValueError("distances are not written with the colour output")
        self.keep += [dist]
        self.c.dist_out = &dist[0]
        self.c.same = NULL  # every voxel's own nearest point is needed

    def colour_output(self, uint32_t[::1] rgba, const int32_t[::1] fmat, vc, cuv,
                      const double[:, ::1] factor, const double[:, ::1] add,
                      const int32_t[:, ::1] mint, const int64_t[::1] moff,
                      const uint8_t[::1] tex):
        """Shade each inside voxel into ``rgba`` (see geovox.colour._shading_tables)."""
        cdef const double[::1] vcv
        cdef const double[::1] cuvv
        if rgba.shape[0] != self.c.nx * self.c.ny * self.c.nz:
            raise ValueError("rgba must have one entry per voxel")
        if fmat.shape[0] != self.keep[1].shape[0] or mint.shape[1] != 7:
            raise ValueError("bad shading tables")
        self.keep += [rgba, fmat, vc, cuv, factor, add, mint, moff, tex]
        self.c.rgba = &rgba[0]
        self.c.fmat = &fmat[0]
        self.c.factor = &factor[0, 0]
        self.c.add = &add[0, 0]
        self.c.mint = &mint[0, 0]
        self.c.moff = &moff[0]
        self.c.tex = &tex[0]
        self.c.vc = NULL
        self.c.cuv = NULL
        if vc is not None:
            vcv = vc
            if vcv.shape[0] != 9 * fmat.shape[0]:
                raise ValueError("vertex colours must be (t, 3, 3)")
            self.c.vc = &vcv[0]
        if cuv is not None:
            cuvv = cuv
            if cuvv.shape[0] != 6 * fmat.shape[0]:
                raise ValueError("corner UVs must be (t, 3, 2)")
            self.c.cuv = &cuvv[0]

    def same_colours(self, const int64_t[::1] key, const uint32_t[::1] rgba):
        """With colour output: faces of the same key >= 0 have the same constant
        colour ``rgba[key]`` (see geovox.colour.constant_colours). Where every
        candidate left in a cell shares a key, its voxels take that colour
        without the search going on (the NumPy search's ``same``)."""
        cdef int64_t t = self.keep[1].shape[0], q
        if self.c.rgba == NULL:
            raise ValueError("constant colours need the colour output")
        if key.shape[0] != t:
            raise ValueError("key must have one entry per face")
        for q in range(t):
            if key[q] >= rgba.shape[0]:
                raise ValueError("a key beyond the colours")
        self.keep += [key, rgba]
        self.c.same = &key[0]
        self.c.same_rgba = &rgba[0] if rgba.shape[0] else NULL

    def limit_leaf4(self, int64_t n):
        """Let cells of 4 voxels finish by interpolated bounds only with at most
        ``n`` candidates (0: never; the others go down to cells of 2). For tests."""
        self.c.leaf_max = max(0, min(n, LEAF_MAX))

    def planes_at(self, int64_t level):
        """Let cells of ``2**level`` voxels finish by tangent-plane bounds (0: none). For tests."""
        self.c.plane_level = level

    def fail_allocation_at(self, int64_t cell):
        """Let top cell number ``cell`` (a row of :meth:`run`'s ``cells``) find its
        lists not allocated, as when malloc fails (-1: none). For tests."""
        self.c.fail_cell = cell

    def clusters(self, const double[:, ::1] tlo, const double[:, ::1] thi,
                 const double[:, ::1] clo, const double[:, ::1] chi,
                 const int64_t[::1] members, const int64_t[::1] cstart,
                 const double[:, ::1] rep):
        """Triangle boxes ``tlo, thi`` (t, 3); clusters of triangles: boxes (g, 3),
        ``members[cstart[i]:cstart[i + 1]]``; ``rep`` (r, 3) surface points
        (see geovox.nearest.search._Search._clusters)."""
        cdef int64_t t = self.keep[1].shape[0]
        if (tlo.shape[0] != t or thi.shape[0] != t or members.shape[0] != t
                or cstart.shape[0] != clo.shape[0] + 1 or chi.shape[0] != clo.shape[0]
                or rep.shape[0] == 0 or tlo.shape[1] != 3 or clo.shape[1] != 3
                or rep.shape[1] != 3):
            raise ValueError("bad clusters")
        self.keep += [tlo, thi, clo, chi, members, cstart, rep]
        self.c.tlo = &tlo[0, 0]
        self.c.thi = &thi[0, 0]
        self.c.clo = &clo[0, 0]
        self.c.chi = &chi[0, 0]
        self.c.members = &members[0]
        self.c.cstart = &cstart[0]
        self.c.ncl = clo.shape[0]
        self.c.rep = &rep[0, 0]
        self.c.nrep = rep.shape[0]

    def run(self, const int64_t[:, ::1] cells, int level, int jobs):
        """Solve the top cells ``cells`` (m, 3) of ``2**level`` voxels.

        Threads take cells one at a time; each voxel's answer depends only on
        its own cell's lists, so the result does not depend on ``jobs``.
        """
        cdef int64_t ncell = cells.shape[0]
        cdef int64_t i, n, need
        cdef int nt = max(1, jobs), tid
        cdef int failed = 0
        cdef const Ctx *c = &self.c
        cdef int32_t **bufs
        cdef double **dbufs
        cdef double **wbufs
        cdef int64_t *caps
        if self.c.rgba == NULL and self.c.tri_out == NULL and self.c.dist_out == NULL:
            raise ValueError("no output set")
        if self.c.ncl == 0:
            raise ValueError("no clusters set")
        if ncell == 0:
            return
        # Per thread: a list per level (each a subset of its parent's) and per
        # candidate distances and barycentrics, grown to the longest top list
        # the thread meets (not the mesh's size: many threads, big meshes).
        bufs = <int32_t **> calloc(nt, sizeof(int32_t *))
        dbufs = <double **> calloc(nt, sizeof(double *))
        wbufs = <double **> calloc(nt, sizeof(double *))
        caps = <int64_t *> calloc(nt, sizeof(int64_t))
        try:
            if bufs == NULL or dbufs == NULL or wbufs == NULL or caps == NULL:
                raise MemoryError("the nearest-surface kernel could not allocate its lists")
            for tid in range(nt):
                wbufs[tid] = <double *> malloc(sizeof(double) * (64 + 4) * LEAF_MAX)
                if wbufs[tid] == NULL:
                    raise MemoryError("the nearest-surface kernel could not allocate its lists")
            for i in prange(ncell, nogil=True, num_threads=nt, schedule="dynamic", chunksize=1):
                tid = threadid()
                # Into the thread's list where it fits (nearly always, once
                # grown), else counted, grown and made again.
                n = top_list(c, level, cells[i, 0], cells[i, 1], cells[i, 2], bufs[tid],
                             caps[tid])
                if n > caps[tid]:
                    need = n + n // 2 + 16
                    free(bufs[tid])
                    free(dbufs[tid])
                    bufs[tid] = <int32_t *> malloc(sizeof(int32_t) * (need * (level + 2) + 1))
                    dbufs[tid] = <double *> malloc(sizeof(double) * (9 * need + 9))
                    caps[tid] = need
                    if bufs[tid] == NULL or dbufs[tid] == NULL:
                        caps[tid] = 0
                    else:
                        n = top_list(c, level, cells[i, 0], cells[i, 1], cells[i, 2],
                                     bufs[tid], caps[tid])
                if caps[tid] == 0 or i == c.fail_cell:
                    # A reduction (+=): a plain assignment in a prange is
                    # lastprivate, so a failure on any thread but the one
                    # that ran the last cell would be lost, its voxels left
                    # unanswered without an error.
                    failed += 1
                else:
                    solve(c, level, cells[i, 0], cells[i, 1], cells[i, 2], bufs[tid], n,
                          bufs[tid] + n, dbufs[tid], wbufs[tid])
        finally:
            for tid in range(nt):
                if bufs != NULL:
                    free(bufs[tid])
                if dbufs != NULL:
                    free(dbufs[tid])
                if wbufs != NULL:
                    free(wbufs[tid])
            free(bufs)
            free(dbufs)
            free(wbufs)
            free(caps)
        if failed:
            raise MemoryError("the nearest-surface kernel could not allocate its lists")


cdef int64_t top_list(const Ctx *c, int level, int64_t ci, int64_t cj, int64_t ck,
                      int32_t *out, int64_t cap) noexcept nogil:
    """The triangles whose boxes are within reach of a top cell, into ``out`` as far
    as ``cap`` of them fit; returns how many there are.

    Reach: the largest distance from the cell's corners to one surface point
    (the nearest of ``rep`` to the centre) bounds the distance to the
    surface everywhere in the cell (convexity), so a triangle whose box is
    farther from the cell's box than that (plus the margin) is never the
    nearest.
    """
    cdef int64_t s = (<int64_t>1) << level
    cdef int64_t i0 = ci * s, j0 = cj * s, k0 = ck * s
    cdef int64_t i1 = min(i0 + s, c.nx), j1 = min(j0 + s, c.ny), k1 = min(k0 + s, c.nz)
    cdef double lo[3]
    cdef double hi[3]
    cdef double m[3]
    cdef double best = INFINITY, d, e, reach2, g, gap
    cdef int64_t r, bv = 0, q, t, n = 0
    cdef int a, k
    lo[0] = (<double>i0 + 0.5) * c.h0
    hi[0] = (<double>(i1 - 1) + 0.5) * c.h0
    lo[1] = (<double>j0 + 0.5) * c.h1
    hi[1] = (<double>(j1 - 1) + 0.5) * c.h1
    lo[2] = (<double>(k0 + c.z0) + 0.5) * c.h2
    hi[2] = (<double>(k1 - 1 + c.z0) + 0.5) * c.h2
    for a in range(3):
        m[a] = 0.5 * (lo[a] + hi[a])
    for r in range(c.nrep):
        d = 0.0
        for a in range(3):
            e = m[a] - c.rep[3 * r + a]
            d = d + e * e
        if d < best:
            best = d
            bv = r
    reach2 = 0.0
    for k in range(8):
        d = 0.0
        for a in range(3):
            e = (hi[a] if (k >> a) & 1 else lo[a]) - c.rep[3 * bv + a]
            d = d + e * e
        if d > reach2:
            reach2 = d
    reach2 = sqrt(reach2) + c.m
    reach2 = reach2 * reach2
    for q in range(c.ncl):
        g = 0.0
        for a in range(3):
            gap = c.clo[3 * q + a] - hi[a]
            e = lo[a] - c.chi[3 * q + a]
            if e > gap:
                gap = e
            if gap > 0:
                g = g + gap * gap
        if g > reach2:
            continue
        for r in range(c.cstart[q], c.cstart[q + 1]):
            t = c.members[r]
            g = 0.0
            for a in range(3):
                gap = c.tlo[3 * t + a] - hi[a]
                e = lo[a] - c.thi[3 * t + a]
                if e > gap:
                    gap = e
                if gap > 0:
                    g = g + gap * gap
            if g <= reach2:
                if n < cap:  # beyond: counted only
                    out[n] = <int32_t>t
                n += 1
    return n


def top_cells(const uint8_t[::1] occ, shape, int level, int jobs):
    """(cx, cy, cz) uint8 flags: the top cells of ``2**level`` voxels holding an inside voxel.

    ``occ`` is the block's (nx, ny, nz) F-order inside flags.
    """
    cdef int64_t nx, ny, nz
    nx, ny, nz = shape
    cdef int64_t s = (<int64_t>1) << level
    cdef int64_t cx = (nx + s - 1) // s, cy = (ny + s - 1) // s, cz = (nz + s - 1) // s
    import numpy as np
    out = np.zeros((cx, cy, cz), np.uint8)
    cdef uint8_t[:, :, ::1] o = out
    cdef int64_t a, i, j, k, row, cj
    with nogil:
        for a in prange(cz, num_threads=max(1, jobs), schedule="dynamic"):
            for k in range(a * s, min(a * s + s, nz)):
                for j in range(ny):
                    row = nx * (j + ny * k)
                    cj = j >> level
                    i = 0
                    while i < nx:
                        if occ[row + i]:
                            # Shifts, not divisions (an integer division per
                            # inside voxel was most of this scan), and the
                            # rest of this cell's run skipped once it is marked.
                            o[i >> level, cj, a] = 1
                            i = ((i >> level) + 1) << level
                        else:
                            i = i + 1
    return out


cdef inline int64_t first_index(double x, int64_t lo, int64_t hi) noexcept nogil:
    """``ceil(x)`` less a hair for rounding, clipped into ``[lo, hi]`` (NaN: ``lo``)."""
    x = ceil(x - 1e-6)
    if not (x > <double>lo):
        return lo
    if x > <double>hi:
        return hi
    return <int64_t>x


cdef inline int64_t end_index(double x, int64_t lo, int64_t hi) noexcept nogil:
    """``floor(x) + 1`` and a hair for rounding, clipped into ``[lo, hi]`` (NaN: ``hi``)."""
    x = floor(x + 1e-6) + 1.0
    if not (x < <double>hi):
        return hi
    if x < <double>lo:
        return lo
    return <int64_t>x


cdef struct Band:
    const double *rows     # (t, 21)
    const uint8_t *flat
    const double *tlo      # (t, 3)
    const double *thi
    float *out
    int64_t n[3]
    int64_t stride[3]
    double h[3]
    double off[3]
    double limit


cdef void band_triangle(const Band *b, int64_t t, int64_t c0, int64_t c1) noexcept nogil:
    """One triangle into layers ``c0 <= k < c1`` of the band (see band_distances)."""
    cdef const double *R = b.rows + 21 * t
    cdef const double *lo = b.tlo + 3 * t
    cdef const double *hi = b.thi + 3 * t
    cdef double limit = b.limit, lim2 = b.limit * b.limit
    cdef int64_t iq, ip, ir, qa, qb, pa, pb, ra, rb, base, idx
    cdef double xq, xp, dq, dp, r2, rest, u, v, d2, pl, nr, wx, a0, b0
    cdef double x[3]
    cdef int ar, ap, aq
    cdef float d
    cdef uint8_t fl = b.flat[t]
    # Layers (block indices) whose centres are within limit of the box along z.
    if end_index((hi[2] + limit) / b.h[2] - 0.5 - b.off[2], c0, c1) <= \
            first_index((lo[2] - limit) / b.h[2] - 0.5 - b.off[2], c0, c1):
        return
    # Rows along the axis the normal points most along (x for a zero-area one).
    ar = 0
    if not fl:
        if fabs(R[16]) > fabs(R[15]) and fabs(R[16]) >= fabs(R[17]):
            ar = 1
        elif fabs(R[17]) > fabs(R[15]) and fabs(R[17]) > fabs(R[16]):
            ar = 2
    ap = 1 if ar == 0 else 0
    aq = 2 if ar != 2 else 1
    qa = first_index((lo[aq] - limit) / b.h[aq] - 0.5 - b.off[aq], 0, b.n[aq])
    qb = end_index((hi[aq] + limit) / b.h[aq] - 0.5 - b.off[aq], 0, b.n[aq])
    pa = first_index((lo[ap] - limit) / b.h[ap] - 0.5 - b.off[ap], 0, b.n[ap])
    pb = end_index((hi[ap] + limit) / b.h[ap] - 0.5 - b.off[ap], 0, b.n[ap])
    if aq == 2:
        qa = max(qa, c0)
        qb = min(qb, c1)
    elif ap == 2:
        pa = max(pa, c0)
        pb = min(pb, c1)
    wx = limit * (1.0 + 1e-9)
    nr = 0.0
    pl = 0.0
    for iq in range(qa, qb):
        xq = (<double>iq + b.off[aq] + 0.5) * b.h[aq]
        x[aq] = xq
        dq = max(max(lo[aq] - xq, xq - hi[aq]), 0.0)
        for ip in range(pa, pb):
            xp = (<double>ip + b.off[ap] + 0.5) * b.h[ap]
            x[ap] = xp
            dp = max(max(lo[ap] - xp, xp - hi[ap]), 0.0)
            r2 = dp * dp + dq * dq
            if r2 > lim2 * (1.0 + 1e-9):
                continue
            # Along the row: within the box grown by what is left of limit ...
            rest = sqrt(max(lim2 - r2, 0.0)) * (1.0 + 1e-9)
            a0 = (lo[ar] - rest) / b.h[ar] - 0.5 - b.off[ar]
            b0 = (hi[ar] + rest) / b.h[ar] - 0.5 - b.off[ar]
            if not fl:
                # ... and within limit of the plane: n . (x - a) is linear in the
                # row's index, with slope n_r h_r, |n_r| >= 1/sqrt(3).
                nr = R[15 + ar] * b.h[ar]
                pl = ((xp - R[ap]) * R[15 + ap] + (xq - R[aq]) * R[15 + aq]
                      + ((b.off[ar] + 0.5) * b.h[ar] - R[ar]) * R[15 + ar])
                if nr > 0:
                    a0 = max(a0, (-wx - pl) / nr)
                    b0 = min(b0, (wx - pl) / nr)
                else:
                    a0 = max(a0, (wx - pl) / nr)
                    b0 = min(b0, (-wx - pl) / nr)
            ra = first_index(a0, 0, b.n[ar])
            rb = end_index(b0, 0, b.n[ar])
            if ar == 2:
                ra = max(ra, c0)
                rb = min(rb, c1)
            base = ip * b.stride[ap] + iq * b.stride[aq]
            for ir in range(ra, rb):
                idx = base + ir * b.stride[ar]
                x[ar] = (<double>ir + b.off[ar] + 0.5) * b.h[ar]
                d2 = closest(R, fl, x[0], x[1], x[2], &u, &v)
                d = <float>sqrt(d2)
                if d < b.out[idx]:
                    b.out[idx] = d


def band_distances(const double[:, ::1] rows, const uint8_t[::1] flat,
                   const double[:, ::1] tlo, const double[:, ::1] thi, shape, int64_t z0,
                   spacing, double limit, float[::1] out, int jobs,
                   const int64_t[::1] order=None):
    """Every voxel within ``limit`` of a triangle: the smallest distance to the triangles.

    The narrow band's exact engine (see geovox.nearest.band_distances): each
    triangle is measured (``closest``, the reference formula) at every voxel
    centre whose distance to it can be at most ``limit``, and each voxel keeps
    the smallest, as float32 (rounding is monotonic, so the smallest float32
    is the smallest distance rounded). Voxel centres are ``((i, j, k + z0) +
    0.5) * spacing`` in the frame of ``rows`` (the whole grid's low corner);
    ``out`` is the block's (nx * ny * nz) F-order array, lowered where a
    triangle is nearer (values elsewhere are left as they are).

    Which centres: those in the triangle's box grown by ``limit``, row by row
    along the axis its normal points most along, each row cut to the part
    within ``limit`` of the box across it and of the triangle's plane (both
    lower bounds of the distance; so a row holds at most about ``2 limit
    sqrt(3)`` of centres; a zero-area triangle has no plane and is cut by its
    box alone), the index bounds widened by 1e-6 voxel so that rounding never
    drops a centre. Threads take chunks of layers (each voxel is written by
    one thread), so the result does not depend on ``jobs``. ``order``: the
    triangles in the order to measure them (a spatial one keeps the values a
    chunk writes in cache; the result does not depend on it).
    """
    cdef int64_t nx, ny, nz
    nx, ny, nz = shape
    cdef double h[3]
    h[0], h[1], h[2] = spacing
    cdef int64_t nt = rows.shape[0]
    if rows.shape[1] != 21 or flat.shape[0] != nt or tlo.shape[0] != nt or thi.shape[0] != nt:
        raise ValueError("rows (t, 21), flat (t,) and boxes (t, 3) must agree")
    if out.shape[0] != nx * ny * nz:
        raise ValueError("out must have one entry per voxel")
    if nt == 0 or nx * ny * nz == 0:
        return
    cdef Band b
    b.rows = &rows[0, 0]
    b.flat = &flat[0]
    b.tlo = &tlo[0, 0]
    b.thi = &thi[0, 0]
    b.out = &out[0]
    b.n[0], b.n[1], b.n[2] = nx, ny, nz
    b.stride[0], b.stride[1], b.stride[2] = 1, nx, nx * ny
    b.h[0], b.h[1], b.h[2] = h[0], h[1], h[2]
    b.off[0], b.off[1], b.off[2] = 0.0, 0.0, <double>z0
    b.limit = limit
    cdef int64_t step = 4  # layers a chunk
    cdef int64_t nchunk = (nz + step - 1) // step
    cdef int64_t ch, q
    cdef const int64_t *perm = NULL
    if order is not None:
        if order.shape[0] != nt:
            raise ValueError("order must list every triangle")
        for q in range(nt):
            if order[q] < 0 or order[q] >= nt:
                raise ValueError("order must list every triangle")
        perm = &order[0]
    with nogil:
        for ch in prange(nchunk, num_threads=max(1, jobs), schedule="dynamic", chunksize=1):
            for q in range(nt):
                band_triangle(&b, perm[q] if perm != NULL else q, ch * step,
                              min(ch * step + step, nz))
