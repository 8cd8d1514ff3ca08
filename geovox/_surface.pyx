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
* within one layer along an axis ``a``: a 2-D problem, for the layer holds
  every point of the triangle -- a voxel of the layer is on iff its cell
  meets the triangle's projection along ``a``, which the three edge x ``a``
  axes decide (no normal's test); cells found by rows as in the walk below;
* a segment (zero normal): walked layer by layer along its longest axis,
  at most 3 x 3 candidates a layer;
* a box of at most 64 voxels: the nine edge x axis tests are the 2-D tests
  of the three coordinate projections, so they are made once per projected
  cell (64-bit masks) and shared by the voxels over it, each voxel adding the
  normal's test; the voxels that pass are a 64-bit mask whose set bits are
  marked;
* a larger box: walked column by column along ``w``, the axis of the
  normal's largest component. Per ``(u, v)`` strip, the cells that the
  projected triangle can meet (float64, widened by ``MARGIN`` lattice steps);
  per cell, the three edge x ``w`` axes first (they do not depend on the
  layer), then the plane's ``w``-range over the cell (at most two voxels,
  widened), and only those voxels get the normal's test -- and, unless the
  cell lies inside the projected triangle (then the triangle over the cell
  *is* the plane), the six edge x ``u`` and edge x ``v`` axes.

Measured against testing every voxel of the box instead of the last two
(paired, one thread, a loaded 2-core machine): the dragon (100,000
triangles) 34 against 53 ms at 256^3 and 264 against 427 ms at 1024^3; one
tilted triangle across a 512^3 grid 7 against 525 ms. The tests are written
with ``&`` and ``|`` rather than ``and``/``or``: their outcomes are
data-dependent, and mispredicted branches cost more than the arithmetic.

The float64 ranges only choose candidates; every voxel marked has passed the
exact integer tests (int64, and ``__int128`` for the normal's degree-3
projections: GCC and Clang; elsewhere this module does not build and geovox
uses the NumPy twin).

Threads share the triangles (dynamic schedule) and write the one output
with relaxed atomic byte stores of 1, or bits with an atomic OR (a plain
load first: most voxels are met by several triangles): each voxel is the OR
of a pure function of (triangle, voxel), so the answer does not depend on
the threads, and atomic writes make the concurrent writes race-free with no
per-thread copy of the output. Every path returns the bits it newly set, so
the count of a block's voxels comes with them; :func:`points` and
:func:`values_at` read them back.

Measured after the walks (one thread, 2 shared cores): the six edge x u and
edge x v tests of a column's boundary cells precomputed as coefficients and
run branch-free instead of through ``edge_separates``, and ``box`` decoding
its bits through a table of offsets instead of three divisions a voxel: the
dragon at 256³ 27.2 -> 23.6 ms (median of 15, the same run), at 1024³ about
200 -> 166-170 ms (runs minutes apart).
"""

from cython.parallel cimport prange, parallel, threadid
from libc.math cimport rint, isfinite
from libc.stdint cimport int32_t, int64_t, uint8_t, uint64_t
from libc.stdlib cimport calloc, free
from libc.string cimport memset

cdef extern from *:
    """
    typedef __int128 geovox_i128;
    static inline void geovox_set_on(unsigned char *p) {
        __atomic_store_n(p, (unsigned char)1, __ATOMIC_RELAXED);
    }
    static inline unsigned long long geovox_fetch_or(unsigned long long *p,
                                                     unsigned long long bit) {
        /* A plain load first: most voxels are met by several triangles, and a
           bit already set needs no locked read-modify-write. */
        unsigned long long old = __atomic_load_n(p, __ATOMIC_RELAXED);
        if (old & bit)
            return old;
        return __atomic_fetch_or(p, bit, __ATOMIC_RELAXED);
    }
    """
    ctypedef long long i128 "geovox_i128"
    void set_on "geovox_set_on"(uint8_t *p) noexcept nogil
    uint64_t fetch_or "geovox_fetch_or"(uint64_t *p, uint64_t bit) noexcept nogil
    int ctz "__builtin_ctzll"(unsigned long long x) noexcept nogil
    int popcount "__builtin_popcountll"(unsigned long long x) noexcept nogil

#: A flat triangle's cells are all tested up to this many; above, only the
#: cells of each row that its projection may reach.
cdef int64_t SMALL = 8
#: Widening of the walks' float64 ranges, in lattice steps (their rounding
#: is below 2**-20 of a step: coordinates < 2**30).
cdef double MARGIN = 4.0


cdef struct Frame:
    const double *V      # vertices (v, 3)
    const int64_t *faces # (n, 3) indices into V; NULL: triangle t is V[3t .. 3t + 2]
    double lo[3]
    double h[3]
    double near[3]       # the reach test's low side: -1 (z: the block's z0 - 1)
    double reach[3]      # its far side: n_a + 1 (z: the block's z1 + 1)
    double scale         # 2**s
    int64_t n[3]
    int64_t s
    int64_t S
    int64_t z0
    int64_t z1
    int64_t nx
    int64_t nxy
    uint8_t *out         # bytes, Fortran order (or NULL)
    uint64_t *words      # or bits: voxel f = i + nx * (j + ny * (k - z0)), bit f % 64 of word f / 64
    bint shared          # several threads write the output


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


cdef inline int64_t ifloor(double x) noexcept nogil:
    # floor() for |x| < 2**62 without a call into libm (it was not inlined).
    cdef int64_t i = <int64_t>x
    return i - (x < i)


#: The axes after a: b = AFTER1[a], c = AFTER2[a] (no % in the inner loops).
cdef int AFTER1[3]
cdef int AFTER2[3]
AFTER1[:] = [1, 2, 0]
AFTER2[:] = [2, 0, 1]


cdef inline const double *vertex(const Frame *F, Py_ssize_t t, int v) noexcept nogil:
    if F.faces != NULL:
        return F.V + 3 * F.faces[3 * t + v]
    return F.V + 9 * t + 3 * v


cdef inline bint reach(const Frame *F, Py_ssize_t t, double *f) noexcept nogil:
    """Index-space coordinates of triangle t into f; whether it reaches the grid (_reaching).

    z first, against the block's layers widened by one: a triangle that
    misses them cannot meet the block once snapped (rint moves a coordinate
    by at most half a lattice step), and costs three divisions.
    """
    cdef int a, k, v
    cdef double lo, hi
    cdef const double *x[3]
    for v in range(3):
        x[v] = vertex(F, t, v)
    for k in range(3):
        a = (k + 2) % 3  # z, x, y
        for v in range(3):
            # (x - lo) / h: the NumPy twin's two roundings, no fused operations.
            f[3 * v + a] = (x[v][a] - F.lo[a]) / F.h[a]
            if not isfinite(f[3 * v + a]):
                return False
        lo = dmin(dmin(f[a], f[3 + a]), f[6 + a])
        hi = dmax(dmax(f[a], f[3 + a]), f[6 + a])
        if not (hi >= F.near[a] and lo <= F.reach[a]):
            return False
    return True


cdef inline double largest(const double *f) noexcept nogil:
    """The largest |index-space coordinate| of a triangle."""
    cdef double m = 0.0, a
    cdef int v
    for v in range(9):
        a = f[v] if f[v] >= 0 else -f[v]
        if a > m:
            m = a
    return m


cdef void set_frame(Frame *F, const double[:, ::1] V, const int64_t[:, ::1] faces,
                    const double[::1] lo, const double[::1] h, const int64_t[::1] n,
                    int64_t z0, int64_t z1) noexcept:
    cdef int a
    F.V = &V[0, 0] if V.shape[0] else NULL
    F.faces = NULL if faces is None or faces.shape[0] == 0 else &faces[0, 0]
    for a in range(3):
        F.lo[a], F.h[a], F.n[a] = lo[a], h[a], n[a]
        F.near[a], F.reach[a] = -1.0, n[a] + 1.0
    F.near[2], F.reach[2] = z0 - 1.0, z1 + 1.0
    F.z0, F.z1 = z0, z1
    F.nx = n[0]
    F.nxy = n[0] * n[1]
    F.out = NULL
    F.words = NULL
    F.shared = False


cdef double tri_extent(const Frame *F, Py_ssize_t t) noexcept nogil:
    """The largest |index-space coordinate| of triangle t if it reaches the grid, else -1."""
    cdef double f[9]
    if not reach(F, t, f):
        return -1.0
    return largest(f)


cdef inline Py_ssize_t count_of(const double[:, ::1] V, const int64_t[:, ::1] faces):
    return V.shape[0] // 3 if faces is None else faces.shape[0]


def extent(const double[:, ::1] V, const int64_t[:, ::1] faces, const double[::1] lo,
           const double[::1] h, const int64_t[::1] n, int jobs):
    """The largest ``|(x - lo) / h|`` over the triangles reaching the grid (0 if none).

    ``V`` (v, 3) vertices and ``faces`` (n, 3) indices into them, or None:
    ``V`` is then (3n, 3), triangle t its rows 3t .. 3t + 2.
    :func:`geovox.surface._extent`'s value, bit for bit (a maximum of the same doubles).
    """
    cdef Frame F
    cdef Py_ssize_t t, ntri = count_of(V, faces)
    cdef int a, nt = max(1, jobs), tid
    cdef double m, best = 0.0
    cdef double *part
    set_frame(&F, V, faces, lo, h, n, 0, n[2])
    if nt == 1 or ntri < 4096:
        with nogil:
            for t in range(ntri):
                m = tri_extent(&F, t)
                if m > best:
                    best = m
        return best
    part = <double *>calloc(nt, sizeof(double))
    if part == NULL:
        raise MemoryError()
    with nogil, parallel(num_threads=nt):
        for t in prange(ntri, schedule="static"):
            tid = threadid()
            m = tri_extent(&F, t)
            if m > part[tid]:
                part[tid] = m
    for a in range(nt):
        if part[a] > best:
            best = part[a]
    free(part)
    return best


def vertex_extent(const double[:, ::1] V, const double[::1] lo, const double[::1] h):
    """The largest ``|(x - lo) / h|`` over the finite vertices (0 if none): a bound of :func:`extent`.

    Every triangle that :func:`extent` looks at has its vertices among these,
    computed the same way, so this is never below its value.
    """
    cdef Py_ssize_t v, nv = V.shape[0]
    cdef int a
    cdef double f, best = 0.0
    with nogil:
        for v in range(nv):
            for a in range(3):
                f = (V[v, a] - lo[a]) / h[a]
                if isfinite(f):
                    f = f if f >= 0 else -f
                    if f > best:
                        best = f
    return best


cdef inline int64_t mark(const Frame *F, const int64_t *idx) noexcept nogil:
    """Turn voxel idx on; 1 if it was off (bits only: bytes count 0)."""
    return mark_at(F, idx[0] + F.nx * idx[1] + F.nxy * (idx[2] - F.z0))


cdef inline int64_t mark_at(const Frame *F, int64_t f) noexcept nogil:
    """Turn on the block's voxel ``f`` (Fortran order); 1 if it was off (bits only)."""
    cdef uint64_t bit, old
    if F.words != NULL:
        bit = (<uint64_t>1) << (f & 63)
        if F.shared:
            old = fetch_or(F.words + (f >> 6), bit)
        else:
            old = F.words[f >> 6]
            F.words[f >> 6] = old | bit
        return (old & bit) == 0
    if F.shared:
        set_on(F.out + f)
    else:
        F.out[f] = 1
    return 0


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
    cdef int b = AFTER1[a], c = AFTER2[a]
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


cdef int64_t run(const Tri *t, const Frame *F) noexcept nogil:
    """At most one axis spans several voxels: every voxel of the run (no test)."""
    cdef int64_t idx[3]
    cdef int a, along = 0
    cdef int64_t i, count = 0
    for a in range(3):
        idx[a] = t.lo[a]
        if t.hi[a] > t.lo[a]:
            along = a
    for i in range(t.lo[along], t.hi[along] + 1):
        idx[along] = i
        count += mark(F, idx)
    return count


cdef uint64_t plane_mask(const Tri *t, const Frame *F, int a, int64_t ib0, int64_t nb,
                         int64_t ic0, int64_t nc) noexcept nogil:
    """Bit ``(ib - ib0) * nc + (ic - ic0)`` set where no edge x ``a`` axis separates cell ``(ib, ic)``.

    The cells are those of the plane across ``a`` (``b, c`` the axes after
    ``a``), ``nb * nc <= 64``. These axes are the 2-D separating axes of the
    triangle's projection along ``a`` and a cell: its edge normals in that
    plane. Written with ``&`` and ``|``: the outcomes are data-dependent, and
    mispredicted branches cost more than the tests.
    """
    cdef int b = AFTER1[a], c = AFTER2[a], k, e
    cdef int64_t sb[3]
    cdef int64_t sc[3]
    cdef int64_t low[3]
    cdef int64_t high[3]
    cdef int64_t upb[3]
    cdef int64_t upc[3]
    cdef int64_t dnb[3]
    cdef int64_t dnc[3]
    cdef int64_t ib, ic, inb, inc, corner, row
    cdef uint64_t bits = 0, ok
    for k in range(3):
        e = 3 * k + a
        sb[k], sc[k] = F.S * t.lb[e], F.S * t.lc[e]
        # Not separated: tmin - corner + up <= bmax and tmax - corner - down >= bmin.
        low[k], high[k] = t.tmin[e] - t.bmax[e], t.tmax[e] - t.bmin[e]
        upb[k], upc[k] = t.lb[e] > 0, t.lc[e] > 0
        dnb[k], dnc[k] = t.lb[e] < 0, t.lc[e] < 0
    for ib in range(nb):
        inb = ib0 + ib < F.n[b] - 1
        for ic in range(nc):
            inc = ic0 + ic < F.n[c] - 1
            ok = 1
            for k in range(3):
                corner = sb[k] * (ib0 + ib) + sc[k] * (ic0 + ic)
                ok &= ((corner >= low[k] + ((upb[k] & inb) | (upc[k] & inc)))
                       & (corner <= high[k] - ((dnb[k] & inb) | (dnc[k] & inc))))
            bits |= ok << (ib * nc + ic)
    return bits


cdef int64_t flat(const Tri *t, const Frame *F, int a) noexcept nogil:
    """Every point of the triangle is in one layer ``t.lo[a]`` along ``a``: a 2-D problem.

    Voxel ``(cell, layer)`` meets the triangle iff the cell meets its
    projection along ``a``, so the edge x ``a`` axes decide alone.
    """
    cdef int b = (a + 1) % 3, c = (a + 2) % 3, k
    cdef int64_t idx[3]
    cdef int64_t ib, ic, clo, chi, nc, count = 0
    cdef uint64_t bits
    cdef double pb[3]
    cdef double pc[3]
    cdef double Sd = <double>F.S, vmin, vmax
    cdef bint walk = (t.hi[b] - t.lo[b] + 1) * (t.hi[c] - t.lo[c] + 1) > SMALL
    for k in range(3):
        pb[k] = <double>t.q[3 * k + b]
        pc[k] = <double>t.q[3 * k + c]
    idx[a] = t.lo[a]
    for ib in range(t.lo[b], t.hi[b] + 1):
        clo, chi = t.lo[c], t.hi[c]
        if walk:
            # Only the cells of the strip that the projected triangle may reach.
            strip_range(pb, pc, ib * Sd - MARGIN, (ib + 1) * Sd + MARGIN, &vmin, &vmax)
            if vmin > vmax:
                continue
            clo = imax(clo, ifloor((vmin - MARGIN) / Sd))
            chi = imin(chi, ifloor((vmax + MARGIN) / Sd))
        idx[b] = ib
        while clo <= chi:
            # 64 cells at a time as bits, then only the set ones visited.
            nc = imin(chi - clo + 1, 64)
            bits = plane_mask(t, F, a, ib, 1, clo, nc)
            while bits:
                idx[c] = clo + ctz(bits)
                count += mark(F, idx)
                bits &= bits - 1
            clo += nc
    return count


cdef int64_t box(const Tri *t, const Frame *F) noexcept nogil:
    """A triangle whose box holds at most 64 voxels: every voxel tested, as bits.

    The nine edge x axis tests are the 2-D tests of the triangle's three
    coordinate projections, so they are made once per projected cell (bit
    masks) and shared by the voxels over it; each voxel adds the normal's
    test. The voxels that pass are a 64-bit mask whose set bits are marked.
    """
    cdef uint64_t mask[3]
    cdef uint64_t on = 0, ok
    cdef int64_t span[3]
    cdef int64_t at[64]  # each bit's voxel in the block (no division to decode a bit)
    cdef int64_t i, j, k, ib, ic, inx, iny, inz, up, down, bit, count = 0, fk, fj
    cdef i128 rk, rj, r, sx, sy, sz
    cdef int a, b, c
    for a in range(3):
        span[a] = t.hi[a] - t.lo[a] + 1
    for a in range(3):
        b, c = AFTER1[a], AFTER2[a]
        mask[a] = plane_mask(t, F, a, t.lo[b], span[b], t.lo[c], span[c])
        if mask[a] == 0:
            return 0
    # The normal's projection of each voxel's corner, stepped along the axes.
    sx, sy, sz = <i128>F.S * t.N[0], <i128>F.S * t.N[1], <i128>F.S * t.N[2]
    rk = t.d0 - sx * t.lo[0] - sy * t.lo[1] - sz * t.lo[2]
    fk = t.lo[0] + F.nx * t.lo[1] + F.nxy * (t.lo[2] - F.z0)
    for k in range(span[2]):
        inz = t.lo[2] + k < F.n[2] - 1
        rj = rk
        fj = fk
        for j in range(span[1]):
            iny = t.lo[1] + j < F.n[1] - 1
            r = rj
            for i in range(span[0]):
                at[(k * span[1] + j) * span[0] + i] = fj + i
                inx = t.lo[0] + i < F.n[0] - 1
                up = ((t.N[0] > 0) & inx) | ((t.N[1] > 0) & iny) | ((t.N[2] > 0) & inz)
                down = ((t.N[0] < 0) & inx) | ((t.N[1] < 0) & iny) | ((t.N[2] < 0) & inz)
                ok = ((mask[0] >> (j * span[2] + k)) & (mask[1] >> (k * span[0] + i))
                      & (mask[2] >> (i * span[1] + j)) & 1)
                ok &= (r + up <= t.pmax) & (r - down >= t.pmin)
                on |= ok << ((k * span[1] + j) * span[0] + i)
                r -= sx
            rj -= sy
            fj += F.nx
        rk -= sz
        fk += F.nxy
    while on:
        count += mark_at(F, at[ctz(on)])
        on &= on - 1
    return count


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


cdef int64_t columns(const Tri *t, const Frame *F) noexcept nogil:
    """Walk a triangle column by column along its normal's dominant axis ``w``."""
    cdef int w = 0, u, v, k, e
    cdef int64_t idx[3]
    cdef bint inner[3]
    cdef double pu[3]
    cdef double pv[3]
    cdef int64_t an[3]
    # The edge x w axes, as in plane_mask, and the cell-inside-triangle bounds.
    cdef int64_t su[3]
    cdef int64_t sv[3]
    cdef int64_t low[3]
    cdef int64_t high[3]
    cdef int64_t inlow[3]
    cdef int64_t inhigh[3]
    cdef int64_t upu[3]
    cdef int64_t upv[3]
    cdef int64_t dnu[3]
    cdef int64_t dnv[3]
    cdef double Sd = <double>F.S, inv = 1.0 / Sd, gu, gv, vmin, vmax, wc, below, above
    cdef int64_t i, j, layer, jlo, jhi, klo, khi, corner, inu, inv_, inw, up, down, ok, inside
    cdef int64_t nu_up, nv_up, nw_up, nu_dn, nv_dn, nw_dn, count = 0
    cdef i128 r, rrow, snu, snv, snw
    # The six edge x u and edge x v axes (needed off the inside cells), as
    # coefficients along u, v, w and the bounds of the box's test.
    cdef int64_t cu[6]
    cdef int64_t cv[6]
    cdef int64_t cw[6]
    cdef int64_t slow[6]
    cdef int64_t shigh[6]
    cdef int64_t sup[18]    # [3 * m + axis]: the box's top moves down along that axis (u, v, w)
    cdef int64_t sdown[18]
    cdef int64_t base[6]
    cdef int64_t coef[3]
    cdef int m, a, b, c, side
    for k in range(3):
        an[k] = t.N[k] if t.N[k] >= 0 else -t.N[k]
    if an[1] > an[w]:
        w = 1
    if an[2] > an[w]:
        w = 2
    u, v = AFTER1[w], AFTER2[w]
    for k in range(3):
        e = 3 * k + w
        su[k], sv[k] = F.S * t.lb[e], F.S * t.lc[e]
        low[k], high[k] = t.tmin[e] - t.bmax[e], t.tmax[e] - t.bmin[e]
        inlow[k], inhigh[k] = t.tmin[e] - t.bmin[e], t.tmax[e] - t.bmax[e]
        upu[k], upv[k] = t.lb[e] > 0, t.lc[e] > 0
        dnu[k], dnv[k] = t.lb[e] < 0, t.lc[e] < 0
        pu[k] = <double>t.q[3 * k + u]
        pv[k] = <double>t.q[3 * k + v]
    m = 0
    for k in range(3):
        for side in range(2):
            a = u if side == 0 else v
            e = 3 * k + a
            b, c = AFTER1[a], AFTER2[a]
            coef[0] = coef[1] = coef[2] = 0
            sup[3 * m] = sup[3 * m + 1] = sup[3 * m + 2] = 0
            sdown[3 * m] = sdown[3 * m + 1] = sdown[3 * m + 2] = 0
            # Axes in (u, v, w) order: u -> 0, v -> 1, w -> 2.
            coef[(b - w + 2) % 3] = F.S * t.lb[e]
            coef[(c - w + 2) % 3] = F.S * t.lc[e]
            sup[3 * m + (b - w + 2) % 3] = t.lb[e] > 0
            sup[3 * m + (c - w + 2) % 3] = t.lc[e] > 0
            sdown[3 * m + (b - w + 2) % 3] = t.lb[e] < 0
            sdown[3 * m + (c - w + 2) % 3] = t.lc[e] < 0
            cu[m], cv[m], cw[m] = coef[0], coef[1], coef[2]
            slow[m], shigh[m] = t.tmin[e] - t.bmax[e], t.tmax[e] - t.bmin[e]
            m += 1
    nu_up, nv_up, nw_up = t.N[u] > 0, t.N[v] > 0, t.N[w] > 0
    nu_dn, nv_dn, nw_dn = t.N[u] < 0, t.N[v] < 0, t.N[w] < 0
    snu, snv, snw = <i128>F.S * t.N[u], <i128>F.S * t.N[v], <i128>F.S * t.N[w]
    gu = <double>t.N[u] / <double>t.N[w]
    gv = <double>t.N[v] / <double>t.N[w]
    # The plane's w over a cell is wc (at its low corner) minus these, widened.
    below = Sd * (dmax(gu, 0.0) + dmax(gv, 0.0)) + MARGIN
    above = -Sd * (dmin(gu, 0.0) + dmin(gv, 0.0)) + MARGIN
    for i in range(t.lo[u], t.hi[u] + 1):
        strip_range(pu, pv, i * Sd - MARGIN, (i + 1) * Sd + MARGIN, &vmin, &vmax)
        if vmin > vmax:
            continue
        jlo = imax(t.lo[v], ifloor((vmin - MARGIN) * inv))
        jhi = imin(t.hi[v], ifloor((vmax + MARGIN) * inv))
        inu = i < F.n[u] - 1
        idx[u] = i
        rrow = t.d0 - snu * i
        for j in range(jlo, jhi + 1):
            inv_ = j < F.n[v] - 1
            ok = 1
            inside = 1
            for k in range(3):
                corner = su[k] * i + sv[k] * j
                ok &= ((corner >= low[k] + ((upu[k] & inu) | (upv[k] & inv_)))
                       & (corner <= high[k] - ((dnu[k] & inu) | (dnv[k] & inv_))))
                inside &= (corner >= inlow[k]) & (corner <= inhigh[k])
            if not ok:
                continue
            idx[v] = j
            if not inside:
                for m in range(6):
                    base[m] = cu[m] * i + cv[m] * j
            # The plane's w-range over the cell [iS, (i+1)S] x [jS, (j+1)S].
            wc = t.q[w] - gu * (i * Sd - pu[0]) - gv * (j * Sd - pv[0])
            klo = imax(t.lo[w], ifloor((wc - below) * inv))
            khi = imin(t.hi[w], ifloor((wc + above) * inv))
            r = rrow - snv * j - snw * klo
            for layer in range(klo, khi + 1):
                inw = layer < F.n[w] - 1
                up = (nu_up & inu) | (nv_up & inv_) | (nw_up & inw)
                down = (nu_dn & inu) | (nv_dn & inv_) | (nw_dn & inw)
                if (r + up <= t.pmax) & (r - down >= t.pmin):
                    idx[w] = layer
                    # Inside the projected triangle, the triangle over the
                    # cell is the plane: the normal's test was the whole test.
                    ok = 1
                    if not inside:
                        for m in range(6):
                            corner = base[m] + cw[m] * layer
                            up = ((sup[3 * m] & inu) | (sup[3 * m + 1] & inv_)
                                  | (sup[3 * m + 2] & inw))
                            down = ((sdown[3 * m] & inu) | (sdown[3 * m + 1] & inv_)
                                    | (sdown[3 * m + 2] & inw))
                            ok &= (corner >= slow[m] + up) & (corner <= shigh[m] - down)
                    if ok:
                        count += mark(F, idx)
                r -= snw
    return count


cdef int64_t segment(const Tri *t, const Frame *F) noexcept nogil:
    """Walk a degenerate triangle (a segment) layer by layer along its longest axis."""
    cdef int a, b, c, d = 0, best = 0, k, pa, pb
    cdef int64_t idx[3]
    cdef int64_t length, longest = -1, layer, i, j, lo1, hi1, lo2, hi2, count = 0
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
        lo1 = imax(t.lo[b], ifloor((dmin(va, vb) - MARGIN) / Sd))
        hi1 = imin(t.hi[b], ifloor((dmax(va, vb) + MARGIN) / Sd))
        va, vb = p0[c] + t0 * delta[c], p0[c] + t1 * delta[c]
        lo2 = imax(t.lo[c], ifloor((dmin(va, vb) - MARGIN) / Sd))
        hi2 = imin(t.hi[c], ifloor((dmax(va, vb) + MARGIN) / Sd))
        idx[d] = layer
        for i in range(lo1, hi1 + 1):
            idx[b] = i
            for j in range(lo2, hi2 + 1):
                idx[c] = j
                if meets(t, F, idx, -1):
                    count += mark(F, idx)
    return count


cdef int64_t triangle(const Frame *F, Py_ssize_t t, double *m) noexcept nogil:
    """Mark triangle t's voxels; the voxels newly on (bits; bytes: 0).

    ``m``: raised to the triangle's largest |index-space coordinate| if it
    reaches the block (the check of the snapping scale given).
    """
    cdef double f[9]
    cdef Tri tr
    cdef int a, v, single = 0
    cdef bint flat_axis[3]
    cdef int64_t mn, mx, side, count
    if not reach(F, t, f):
        return 0
    m[0] = dmax(m[0], largest(f))
    for v in range(9):
        tr.q[v] = <int64_t>rint(f[v] * F.scale)
    for a in range(3):
        mn = imin(imin(tr.q[a], tr.q[3 + a]), tr.q[6 + a])
        mx = imax(imax(tr.q[a], tr.q[3 + a]), tr.q[6 + a])
        side = F.n[a] * F.S
        if mx < 0 or mn > side:
            return 0
        # mn, mx >= 0 where shifted: the shift is floor division by 2**s.
        tr.lo[a] = 0 if mn < 0 else imin(mn >> F.s, F.n[a] - 1)
        tr.hi[a] = imin(mx >> F.s, F.n[a] - 1)
        # Every point of the triangle in one voxel's half-open interval along a.
        flat_axis[a] = tr.lo[a] == tr.hi[a] and mn >= 0 and mx <= side
        single += flat_axis[a]
    tr.lo[2] = imax(tr.lo[2], F.z0)
    tr.hi[2] = imin(tr.hi[2], F.z1 - 1)
    if tr.lo[2] > tr.hi[2]:
        return 0
    if single >= 2:
        return run(&tr, F)
    prepare(&tr, F)
    if single == 1:
        for a in range(3):
            if flat_axis[a]:
                return flat(&tr, F, a)
    if tr.N[0] == 0 and tr.N[1] == 0 and tr.N[2] == 0:
        return segment(&tr, F)
    count = (tr.hi[0] - tr.lo[0] + 1) * (tr.hi[1] - tr.lo[1] + 1) * (tr.hi[2] - tr.lo[2] + 1)
    if count <= 64:
        return box(&tr, F)
    return columns(&tr, F)


def surface(const double[:, ::1] V, const int64_t[:, ::1] faces, const double[::1] lo,
            const double[::1] h, const int64_t[::1] n, int s, int64_t z0, int64_t z1,
            uint8_t[::1, :, :] out, uint64_t[::1] words, bint zero, int jobs):
    """Mark the surface voxels of layers z0..z1-1 in ``out`` or ``words``.

    ``V``, ``faces``: the triangles, as :func:`extent` takes them. ``out``:
    (nx, ny, z1 - z0) uint8, Fortran order, or None; else ``words``: the
    block's voxels as bits, voxel ``f = i + nx * (j + ny * (k - z0))`` bit
    ``f % 64`` of word ``f // 64`` (at least ``ceil(nx * ny * (z1 - z0) / 64)``
    words, all zero: :func:`points` clears them as it reads them). ``s`` is
    :func:`geovox.surface.snap_bits`'s; ``zero``: clear ``out`` first;
    ``jobs``: OpenMP threads (already through
    :func:`geovox.kernels.openmp_threads`).

    Returns ``(on, m)``: with ``words`` the number of voxels on (0 with
    ``out``), and the largest |index-space coordinate| of the triangles that
    reach the block (so the caller can check ``s`` against them).
    """
    cdef Frame F
    cdef Py_ssize_t t, ntri = count_of(V, faces)
    cdef int64_t k, nz = z1 - z0, total = 0, size, chunk
    cdef int a, nt = max(1, jobs), tid
    cdef double m = 0.0
    cdef double *part
    set_frame(&F, V, faces, lo, h, n, z0, z1)
    F.s = s
    F.S = (<int64_t>1) << s
    F.scale = <double>F.S
    F.shared = nt > 1
    if out is not None:
        F.out = &out[0, 0, 0]
        size, chunk = F.nxy * nz, F.nxy
    else:
        F.words = &words[0]
        zero = False
    if nt == 1:
        with nogil:
            if zero:
                memset(F.out, 0, size)
            for t in range(ntri):
                total += triangle(&F, t, &m)
        return total, m
    # One cache line per thread: raised for every triangle, shared lines would ping-pong.
    part = <double *>calloc(8 * nt, sizeof(double))
    if part == NULL:
        raise MemoryError()
    with nogil:
        if zero:
            for k in prange(nz, num_threads=nt, schedule="static"):
                memset(F.out + chunk * k, 0, chunk)
        for t in prange(ntri, num_threads=nt, schedule="dynamic", chunksize=256):
            tid = threadid()
            total += triangle(&F, t, &part[8 * tid])
    for a in range(nt):
        m = dmax(m, part[8 * a])
    free(part)
    return total, m


ctypedef fused real:
    float
    double


def values_at(uint64_t[::1] words, int64_t nx, int64_t ny, int64_t nz, int64_t z0,
              const real[::1] vx, const real[::1] vy, const real[::1] vz, real[:, ::1] out):
    """:func:`points`, each voxel given as ``(vx[i], vy[j], vz[k])`` instead of ``(i, j, k)``.

    Per-axis values of the whole grid's indices (a point cloud's centre
    coordinates, say), looked up as the bits are read: no pass over indices.
    """
    cdef Py_ssize_t w, nw = (nx * ny * nz + 63) // 64, found = 0, cap = out.shape[0]
    cdef int64_t f, row = 0, j = 0, k = z0
    cdef uint64_t bits
    cdef real y = vy[0], z = vz[z0]
    with nogil:
        for w in range(nw):
            bits = words[w]
            if bits:
                words[w] = 0
            while bits:
                f = 64 * w + ctz(bits)
                bits &= bits - 1
                if f >= row + nx:
                    while f >= row + nx:
                        row += nx
                        j += 1
                        if j == ny:
                            j = 0
                            k += 1
                    y, z = vy[j], vz[k]
                if found < cap:
                    out[found, 0] = vx[f - row]
                    out[found, 1] = y
                    out[found, 2] = z
                found += 1
    return found


def points(uint64_t[::1] words, int64_t nx, int64_t ny, int64_t nz, int64_t z0,
           int32_t[:, ::1] ijk):
    """The voxels on in ``words`` (:func:`surface`'s bits of layers z0 .. z0 + nz - 1), in order.

    Fills ``ijk`` ((count, 3) int32: ``i, j, k``, ``k`` counted in the
    whole grid) in the grid's memory order, x fastest; returns how many it
    found (at most ``ijk``'s rows). Rows are followed as the bits are: no
    division per voxel. Every word read is cleared, so the buffer is all
    zero again for the next block (no clearing pass over it).
    """
    cdef Py_ssize_t w, nw = (nx * ny * nz + 63) // 64, found = 0, cap = ijk.shape[0]
    cdef int64_t f, row = 0, j = 0, k = z0
    cdef uint64_t bits
    with nogil:
        for w in range(nw):
            bits = words[w]
            if bits:
                words[w] = 0
            while bits:
                f = 64 * w + ctz(bits)
                bits &= bits - 1
                while f >= row + nx:
                    row += nx
                    j += 1
                    if j == ny:
                        j = 0
                        k += 1
                if found < cap:
                    ijk[found, 0] = <int32_t>(f - row)
                    ijk[found, 1] = <int32_t>j
                    ijk[found, 2] = <int32_t>k
                found += 1
    return found
