# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False, nonecheck=False
"""Compiled surface voxels: :func:`geovox.surface.surface_voxels`'s exact rule, threaded.

The rule, the snapping and the bounds are :mod:`geovox.surface`'s (its
docstring is the contract); this is the same decision, voxel for voxel, as
its NumPy twin. Per triangle, in order of cost:

* not reaching the grid (the float index-space box misses ``[-1, n + 1]``,
  or a coordinate is not finite): skipped before snapping;
* snapped, and missing the grid or the block: skipped;
* in one voxel, or spanning voxels along one axis only (the other two
  axes each in one voxel's half-open interval): those voxels, no test;
* a segment (zero normal): walked layer by layer along its longest axis,
  at most 3 x 3 candidates a layer;
* a triangle whose box holds at most ``SMALL`` voxels: each tested;
* a larger one: walked column by column along ``w``, the axis of its
  normal's largest component. Per ``(u, v)`` strip, the cells that the
  projected triangle can meet (float64, widened by ``MARGIN`` lattice steps);
  per cell, the three edge x ``w`` axes first (they do not depend on the
  layer), then the plane's ``w``-range over the cell (at most two voxels,
  widened), and only those voxels get the normal's test -- and, unless the
  cell lies inside the projected triangle (then the triangle over the cell
  *is* the plane), the six edge x ``u`` and edge x ``v`` axes.

The float64 ranges only choose candidates; every voxel marked has passed the
exact integer tests (int64, and ``__int128`` for the normal's degree-3
projections: GCC and Clang; elsewhere this module does not build and geovox
uses the NumPy twin).

Threads share the triangles (dynamic schedule) and write the one output
with relaxed atomic byte stores of 1: each voxel is the OR of a pure
function of (triangle, voxel), so the answer does not depend on the threads,
and atomic stores make the concurrent writes race-free with no per-thread
copy of the output.
"""

from cython.parallel cimport prange, parallel, threadid
from libc.math cimport rint, floor, isfinite
from libc.stdint cimport int64_t, uint8_t
from libc.stdlib cimport calloc, free
from libc.string cimport memset

cdef extern from *:
    """
    typedef __int128 geovox_i128;
    static inline void geovox_set_on(unsigned char *p) {
        __atomic_store_n(p, (unsigned char)1, __ATOMIC_RELAXED);
    }
    """
    ctypedef long long i128 "geovox_i128"
    void set_on "geovox_set_on"(uint8_t *p) noexcept nogil

#: Candidates of a triangle's box tested one by one below this many voxels;
#: above it the column walk (measured on the dragon at 1024^3: see
#: benchmarks/bench_surface.py).
cdef int64_t SMALL = 8
#: Widening of the walks' float64 ranges, in lattice steps (their rounding
#: is below 2**-20 of a step: coordinates < 2**30).
cdef double MARGIN = 4.0


cdef struct Frame:
    double lo[3]
    double h[3]
    double reach[3]      # n_a + 1: the far side of the reach test
    double scale         # 2**s
    int64_t n[3]
    int64_t s
    int64_t S
    int64_t z0
    int64_t z1
    int64_t nx
    int64_t nxy
    uint8_t *out


cdef struct Tri:
    int64_t q[9]         # snapped vertices, q[3 * vertex + axis]
    int64_t lo[3]        # voxel range of the box, in the grid (z: in the block)
    int64_t hi[3]
    int64_t N[3]         # (q1 - q0) x (q2 - q0), < 2**61
    i128 d0              # N . q0, < 2**93
    i128 pmax            # S * sum(max(N_a, 0))
    i128 pmin            # S * sum(min(N_a, 0))
    # edge k x unit axis a, at [3 * k + a]: L_b = lb, L_c = lc (b, c the
    # axes after a), the triangle's projections [tmin, tmax] and the unit
    # box's [bmin, bmax] (all < 2**61)
    int64_t lb[9]
    int64_t lc[9]
    int64_t tmin[9]
    int64_t tmax[9]
    int64_t bmin[9]
    int64_t bmax[9]


cdef inline int64_t imin(int64_t a, int64_t b) noexcept nogil:
    return a if a < b else b


cdef inline int64_t imax(int64_t a, int64_t b) noexcept nogil:
    return a if a > b else b


cdef inline double dmin(double a, double b) noexcept nogil:
    return a if a < b else b


cdef inline double dmax(double a, double b) noexcept nogil:
    return a if a > b else b


cdef inline bint reach(const double *x, const Frame *F, double *f) noexcept nogil:
    """Index-space coordinates into f; whether the triangle reaches the grid (surface._reaching)."""
    cdef int a, v
    cdef double lo, hi
    for a in range(3):
        for v in range(3):
            # (x - lo) / h: the NumPy twin's two roundings, no fused operations.
            f[3 * v + a] = (x[3 * v + a] - F.lo[a]) / F.h[a]
            if not isfinite(f[3 * v + a]):
                return False
        lo = dmin(dmin(f[a], f[3 + a]), f[6 + a])
        hi = dmax(dmax(f[a], f[3 + a]), f[6 + a])
        if not (hi >= -1.0 and lo <= F.reach[a]):
            return False
    return True


cdef double tri_extent(const double *x, const Frame *F) noexcept nogil:
    """The largest |index-space coordinate| of a triangle reaching the grid, else -1."""
    cdef double f[9]
    cdef double m = 0.0, a
    cdef int v
    if not reach(x, F, f):
        return -1.0
    for v in range(9):
        a = f[v] if f[v] >= 0 else -f[v]
        if a > m:
            m = a
    return m


def extent(const double[:, :, ::1] tri, const double[::1] lo, const double[::1] h,
           const int64_t[::1] n, int jobs):
    """The largest ``|(x - lo) / h|`` over the triangles reaching the grid (0 if none).

    :func:`geovox.surface._extent`'s value, bit for bit (a maximum of the same doubles).
    """
    cdef Frame F
    cdef Py_ssize_t t, ntri = tri.shape[0]
    cdef int a, nt = max(1, jobs), tid
    cdef double m, best = 0.0
    cdef double *part
    for a in range(3):
        F.lo[a], F.h[a], F.reach[a] = lo[a], h[a], n[a] + 1.0
    if nt == 1 or ntri < 4096:
        with nogil:
            for t in range(ntri):
                m = tri_extent(&tri[t, 0, 0], &F)
                if m > best:
                    best = m
        return best
    part = <double *>calloc(nt, sizeof(double))
    if part == NULL:
        raise MemoryError()
    with nogil, parallel(num_threads=nt):
        for t in prange(ntri, schedule="static"):
            tid = threadid()
            m = tri_extent(&tri[t, 0, 0], &F)
            if m > part[tid]:
                part[tid] = m
    for a in range(nt):
        if part[a] > best:
            best = part[a]
    free(part)
    return best


cdef inline void mark(const Frame *F, const int64_t *idx) noexcept nogil:
    set_on(F.out + idx[0] + F.nx * idx[1] + F.nxy * (idx[2] - F.z0))


cdef void prepare(Tri *t, const Frame *F) noexcept nogil:
    """The normal's and the edge x axis tests' per-triangle terms."""
    cdef int64_t d1[3]
    cdef int64_t d2[3]
    cdef int64_t e[3]
    cdef int64_t p, lb, lc, S = F.S
    cdef int k, a, b, c, v
    for a in range(3):
        d1[a] = t.q[3 + a] - t.q[a]
        d2[a] = t.q[6 + a] - t.q[a]
    t.N[0] = d1[1] * d2[2] - d1[2] * d2[1]
    t.N[1] = d1[2] * d2[0] - d1[0] * d2[2]
    t.N[2] = d1[0] * d2[1] - d1[1] * d2[0]
    t.d0 = <i128>t.N[0] * t.q[0] + <i128>t.N[1] * t.q[1] + <i128>t.N[2] * t.q[2]
    t.pmax = 0
    t.pmin = 0
    for a in range(3):
        if t.N[a] > 0:
            t.pmax += <i128>t.N[a] * S
        else:
            t.pmin += <i128>t.N[a] * S
    for k in range(3):
        for a in range(3):
            e[a] = t.q[3 * ((k + 1) % 3) + a] - t.q[3 * k + a]
        for a in range(3):
            b, c = (a + 1) % 3, (a + 2) % 3
            # L = e x unit_a: L_a = 0, L_b = e_c, L_c = -e_b.
            lb, lc = e[c], -e[b]
            t.lb[3 * k + a], t.lc[3 * k + a] = lb, lc
            t.tmin[3 * k + a] = lb * t.q[b] + lc * t.q[c]
            t.tmax[3 * k + a] = t.tmin[3 * k + a]
            for v in range(1, 3):
                p = lb * t.q[3 * v + b] + lc * t.q[3 * v + c]
                t.tmin[3 * k + a] = imin(t.tmin[3 * k + a], p)
                t.tmax[3 * k + a] = imax(t.tmax[3 * k + a], p)
            t.bmax[3 * k + a] = S * (imax(lb, 0) + imax(lc, 0))
            t.bmin[3 * k + a] = S * (imin(lb, 0) + imin(lc, 0))


cdef inline bint edge_separates(const Tri *t, const Frame *F, int e, const int64_t *idx,
                                const bint *inner) noexcept nogil:
    """Whether edge x axis ``e`` separates the triangle from voxel ``idx`` (eps symbolic)."""
    cdef int a = e % 3
    cdef int b = (a + 1) % 3, c = (a + 2) % 3
    cdef int64_t lb = t.lb[e], lc = t.lc[e]
    cdef int64_t corner = F.S * (lb * idx[b] + lc * idx[c])
    # The box's top moves down with eps on the axes where the voxel is not
    # the last: a tie on that side separates.
    cdef int64_t up = (lb > 0 and inner[b]) or (lc > 0 and inner[c])
    cdef int64_t down = (lb < 0 and inner[b]) or (lc < 0 and inner[c])
    return (t.tmin[e] - corner + up > t.bmax[e]) or (t.tmax[e] - corner - down < t.bmin[e])


cdef inline bint normal_separates(const Tri *t, const Frame *F, const int64_t *idx,
                                  const bint *inner) noexcept nogil:
    cdef i128 r = t.d0 - <i128>F.S * (<i128>t.N[0] * idx[0] + <i128>t.N[1] * idx[1]
                                      + <i128>t.N[2] * idx[2])
    cdef int up = ((t.N[0] > 0 and inner[0]) or (t.N[1] > 0 and inner[1])
                   or (t.N[2] > 0 and inner[2]))
    cdef int down = ((t.N[0] < 0 and inner[0]) or (t.N[1] < 0 and inner[1])
                     or (t.N[2] < 0 and inner[2]))
    return r + up > t.pmax or r - down < t.pmin


cdef inline void inner_of(const Frame *F, const int64_t *idx, bint *inner) noexcept nogil:
    inner[0] = idx[0] < F.n[0] - 1
    inner[1] = idx[1] < F.n[1] - 1
    inner[2] = idx[2] < F.n[2] - 1


cdef bint meets(const Tri *t, const Frame *F, const int64_t *idx, int skip) noexcept nogil:
    """The rule for voxel ``idx``, the edge x ``skip`` axes already passed (-1: none)."""
    cdef bint inner[3]
    cdef int e
    inner_of(F, idx, inner)
    if normal_separates(t, F, idx, inner):
        return False
    for e in range(9):
        if e % 3 != skip and edge_separates(t, F, e, idx, inner):
            return False
    return True


cdef void run(const Tri *t, const Frame *F) noexcept nogil:
    """At most one axis spans several voxels: every voxel of the run (no test)."""
    cdef int64_t idx[3]
    cdef int a, along = 0
    cdef int64_t i
    for a in range(3):
        idx[a] = t.lo[a]
        if t.hi[a] > t.lo[a]:
            along = a
    for i in range(t.lo[along], t.hi[along] + 1):
        idx[along] = i
        mark(F, idx)


cdef void each(const Tri *t, const Frame *F) noexcept nogil:
    cdef int64_t idx[3]
    cdef int64_t i, j, k
    for k in range(t.lo[2], t.hi[2] + 1):
        idx[2] = k
        for j in range(t.lo[1], t.hi[1] + 1):
            idx[1] = j
            for i in range(t.lo[0], t.hi[0] + 1):
                idx[0] = i
                if meets(t, F, idx, -1):
                    mark(F, idx)


cdef void strip_range(const double *pu, const double *pv, double ul, double uh,
                      double *vmin, double *vmax) noexcept nogil:
    """The v-range of the 2-D triangle within ``ul <= u <= uh`` (surface._strip_range)."""
    cdef int e, f
    cdef double du, ta, tb, t0, t1, va, vb
    vmin[0] = 1e300
    vmax[0] = -1e300
    for e in range(3):
        f = (e + 1) % 3
        du = pu[f] - pu[e]
        if du != 0:
            ta = (ul - pu[e]) / du
            tb = (uh - pu[e]) / du
            t0 = dmax(dmin(ta, tb), 0.0)
            t1 = dmin(dmax(ta, tb), 1.0)
            if t0 > t1:
                continue
        elif pu[e] >= ul and pu[e] <= uh:
            t0, t1 = 0.0, 1.0
        else:
            continue
        va = pv[e] + t0 * (pv[f] - pv[e])
        vb = pv[e] + t1 * (pv[f] - pv[e])
        vmin[0] = dmin(vmin[0], dmin(va, vb))
        vmax[0] = dmax(vmax[0], dmax(va, vb))


cdef void columns(const Tri *t, const Frame *F) noexcept nogil:
    """Walk a triangle column by column along its normal's dominant axis."""
    cdef int w = 0, u, v, k, e
    cdef int64_t idx[3]
    cdef bint inner[3]
    cdef double pu[3]
    cdef double pv[3]
    cdef double Sd = <double>F.S, gu, gv, vmin, vmax, wc, wlo, whi
    cdef int64_t i, j, layer, jlo, jhi, klo, khi, corner, up, down, lb, lc
    cdef bint separated, interior
    cdef int64_t an[3]
    for k in range(3):
        an[k] = t.N[k] if t.N[k] >= 0 else -t.N[k]
    if an[1] > an[w]:
        w = 1
    if an[2] > an[w]:
        w = 2
    u, v = (w + 1) % 3, (w + 2) % 3
    gu = <double>t.N[u] / <double>t.N[w]
    gv = <double>t.N[v] / <double>t.N[w]
    for k in range(3):
        pu[k] = <double>t.q[3 * k + u]
        pv[k] = <double>t.q[3 * k + v]
    for i in range(t.lo[u], t.hi[u] + 1):
        strip_range(pu, pv, i * Sd - MARGIN, (i + 1) * Sd + MARGIN, &vmin, &vmax)
        if vmin > vmax:
            continue
        jlo = imax(t.lo[v], <int64_t>floor((vmin - MARGIN) / Sd))
        jhi = imin(t.hi[v], <int64_t>floor((vmax + MARGIN) / Sd))
        idx[u] = i
        for j in range(jlo, jhi + 1):
            idx[v] = j
            idx[w] = t.lo[w]
            inner_of(F, idx, inner)
            # The edge x w axes: in the (u, v) plane, the same for the whole column.
            separated = False
            interior = True
            for k in range(3):
                e = 3 * k + w
                lb, lc = t.lb[e], t.lc[e]
                corner = F.S * (lb * idx[u] + lc * idx[v])
                up = (lb > 0 and inner[u]) or (lc > 0 and inner[v])
                down = (lb < 0 and inner[u]) or (lc < 0 and inner[v])
                if (t.tmin[e] - corner + up > t.bmax[e]) or (t.tmax[e] - corner - down < t.bmin[e]):
                    separated = True
                    break
                if corner + t.bmin[e] < t.tmin[e] or corner + t.bmax[e] > t.tmax[e]:
                    interior = False
            if separated:
                continue
            # The plane's w over the cell [iS, (i+1)S] x [jS, (j+1)S].
            wc = t.q[w] - gu * (i * Sd - pu[0]) - gv * (j * Sd - pv[0])
            wlo = wc - Sd * (dmax(gu, 0.0) + dmax(gv, 0.0)) - MARGIN
            whi = wc - Sd * (dmin(gu, 0.0) + dmin(gv, 0.0)) + MARGIN
            klo = imax(t.lo[w], <int64_t>floor(wlo / Sd))
            khi = imin(t.hi[w], <int64_t>floor(whi / Sd))
            for layer in range(klo, khi + 1):
                idx[w] = layer
                inner[w] = layer < F.n[w] - 1
                if normal_separates(t, F, idx, inner):
                    continue
                # Inside the projected triangle, the triangle over the cell
                # is the plane: the normal's test was the whole test.
                if not interior:
                    separated = False
                    for e in range(9):
                        if e % 3 != w and edge_separates(t, F, e, idx, inner):
                            separated = True
                            break
                    if separated:
                        continue
                mark(F, idx)


cdef void segment(const Tri *t, const Frame *F) noexcept nogil:
    """Walk a degenerate triangle (a segment) layer by layer along its longest axis."""
    cdef int a, b, c, d = 0, best = 0, k, pa, pb
    cdef int64_t idx[3]
    cdef int64_t length, longest = -1, layer, i, j, lo1, hi1, lo2, hi2
    cdef double p0[3]
    cdef double delta[3]
    cdef double Sd = <double>F.S, ta, tb, t0, t1, va, vb
    # A degenerate triangle is the segment between its farthest pair of vertices.
    for k in range(3):
        length = 0
        for a in range(3):
            length = imax(length, imax(t.q[3 * ((k + 1) % 3) + a] - t.q[3 * k + a],
                                       t.q[3 * k + a] - t.q[3 * ((k + 1) % 3) + a]))
        if length > longest:
            longest, best = length, k
    pa, pb = best, (best + 1) % 3
    for a in range(3):
        p0[a] = <double>t.q[3 * pa + a]
        delta[a] = <double>t.q[3 * pb + a] - p0[a]
        if (delta[a] if delta[a] >= 0 else -delta[a]) > (delta[d] if delta[d] >= 0 else -delta[d]):
            d = a
    b, c = (d + 1) % 3, (d + 2) % 3
    for layer in range(t.lo[d], t.hi[d] + 1):
        ta = (layer * Sd - MARGIN - p0[d]) / delta[d]
        tb = ((layer + 1) * Sd + MARGIN - p0[d]) / delta[d]
        t0 = dmax(dmin(ta, tb), 0.0)
        t1 = dmin(dmax(ta, tb), 1.0)
        if t0 > t1:
            continue
        va, vb = p0[b] + t0 * delta[b], p0[b] + t1 * delta[b]
        lo1 = imax(t.lo[b], <int64_t>floor((dmin(va, vb) - MARGIN) / Sd))
        hi1 = imin(t.hi[b], <int64_t>floor((dmax(va, vb) + MARGIN) / Sd))
        va, vb = p0[c] + t0 * delta[c], p0[c] + t1 * delta[c]
        lo2 = imax(t.lo[c], <int64_t>floor((dmin(va, vb) - MARGIN) / Sd))
        hi2 = imin(t.hi[c], <int64_t>floor((dmax(va, vb) + MARGIN) / Sd))
        idx[d] = layer
        for i in range(lo1, hi1 + 1):
            idx[b] = i
            for j in range(lo2, hi2 + 1):
                idx[c] = j
                if meets(t, F, idx, -1):
                    mark(F, idx)


cdef void triangle(const double *x, const Frame *F) noexcept nogil:
    cdef double f[9]
    cdef Tri t
    cdef int a, v, single = 0
    cdef int64_t mn, mx, side, count
    if not reach(x, F, f):
        return
    for v in range(9):
        t.q[v] = <int64_t>rint(f[v] * F.scale)
    for a in range(3):
        mn = imin(imin(t.q[a], t.q[3 + a]), t.q[6 + a])
        mx = imax(imax(t.q[a], t.q[3 + a]), t.q[6 + a])
        side = F.n[a] * F.S
        if mx < 0 or mn > side:
            return
        # mn, mx >= 0 where shifted: the shift is floor division by 2**s.
        t.lo[a] = 0 if mn < 0 else imin(mn >> F.s, F.n[a] - 1)
        t.hi[a] = imin(mx >> F.s, F.n[a] - 1)
        # Every point of the triangle in one voxel's half-open interval along a.
        if t.lo[a] == t.hi[a] and mn >= 0 and mx <= side:
            single += 1
    t.lo[2] = imax(t.lo[2], F.z0)
    t.hi[2] = imin(t.hi[2], F.z1 - 1)
    if t.lo[2] > t.hi[2]:
        return
    if single >= 2:
        run(&t, F)
        return
    prepare(&t, F)
    if t.N[0] == 0 and t.N[1] == 0 and t.N[2] == 0:
        segment(&t, F)
        return
    count = (t.hi[0] - t.lo[0] + 1) * (t.hi[1] - t.lo[1] + 1) * (t.hi[2] - t.lo[2] + 1)
    if count <= SMALL:
        each(&t, F)
    else:
        columns(&t, F)


def surface(const double[:, :, ::1] tri, const double[::1] lo, const double[::1] h,
            const int64_t[::1] n, int s, int64_t z0, int64_t z1, uint8_t[::1, :, :] out,
            bint zero, int jobs):
    """Fill ``out`` ((nx, ny, z1 - z0) uint8, Fortran order) with the surface voxels of layers z0..z1-1.

    ``s`` is :func:`geovox.surface.snap_bits`'s; ``zero``: clear ``out`` first
    (a fresh calloc'd buffer need not be); ``jobs``: OpenMP threads (already
    through :func:`geovox.kernels.openmp_threads`).
    """
    cdef Frame F
    cdef Py_ssize_t t, ntri = tri.shape[0]
    cdef int64_t k, nz = z1 - z0
    cdef int a, nt = max(1, jobs)
    for a in range(3):
        F.lo[a], F.h[a], F.reach[a], F.n[a] = lo[a], h[a], n[a] + 1.0, n[a]
    F.s = s
    F.S = (<int64_t>1) << s
    F.scale = <double>F.S
    F.z0, F.z1 = z0, z1
    F.nx = n[0]
    F.nxy = n[0] * n[1]
    F.out = &out[0, 0, 0]
    if nt == 1:
        with nogil:
            if zero:
                memset(F.out, 0, F.nxy * nz)
            for t in range(ntri):
                triangle(&tri[t, 0, 0], &F)
        return
    with nogil:
        if zero:
            for k in prange(nz, num_threads=nt, schedule="static"):
                memset(F.out + F.nxy * k, 0, F.nxy)
        for t in prange(ntri, num_threads=nt, schedule="dynamic", chunksize=256):
            triangle(&tri[t, 0, 0], &F)
