# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True
# cython: initializedcheck=False, nonecheck=False
"""Compiled per-block minimum and maximum of a voxel array (the .vdb writer's blocks).

:func:`geovox.formats.vdb._block_extrema` for the scalar grids (float32 and
uint8, a bool occupancy viewed as uint8): one pass over the array, each
``size³`` block's minimum and maximum, the part of a block beyond the array
taken as ``pad``, with threads over the layers of blocks. Its NumPy twin is
that function; the answers are the same (a minimum and a maximum are exact).
"""

from cython.parallel cimport prange
from libc.stdint cimport int64_t, uint8_t

ctypedef fused scalar:
    float
    uint8_t


def block_extrema(const scalar[::1] raw, shape, int64_t size, double pad, scalar[:, :, ::1] lo,
                  scalar[:, :, ::1] hi, int jobs):
    """Per ``size³`` block of the (nx, ny, nz) F-order ``raw``: its minimum into ``lo`` and
    maximum into ``hi`` (bx, by, bz), C order; voxels beyond the array count as ``pad``."""
    cdef int64_t nx, ny, nz
    nx, ny, nz = shape
    cdef int64_t bx = lo.shape[0], by = lo.shape[1], bz = lo.shape[2]
    if raw.shape[0] != nx * ny * nz:
        raise ValueError("raw must hold nx * ny * nz voxels")
    if (bx != (nx + size - 1) // size or by != (ny + size - 1) // size
            or bz != (nz + size - 1) // size or hi.shape[0] != bx or hi.shape[1] != by
            or hi.shape[2] != bz):
        raise ValueError("lo and hi must have one entry per block")
    cdef scalar p = <scalar>pad
    cdef int64_t c, i, j, k, a, b, i1, j1, k1, row
    cdef scalar vlo, vhi, v
    cdef bint partial
    with nogil:
        for c in prange(bz, num_threads=max(1, jobs), schedule="static"):
            k1 = min(c * size + size, nz)
            for b in range(by):
                j1 = min(b * size + size, ny)
                for a in range(bx):
                    i1 = min(a * size + size, nx)
                    partial = i1 - a * size < size or j1 - b * size < size or \
                        k1 - c * size < size
                    vlo = raw[a * size + nx * (b * size + ny * c * size)]
                    vhi = vlo
                    if partial:
                        if p < vlo:
                            vlo = p
                        if p > vhi:
                            vhi = p
                    for k in range(c * size, k1):
                        for j in range(b * size, j1):
                            row = nx * (j + ny * k)
                            for i in range(a * size, i1):
                                v = raw[row + i]
                                if v < vlo:
                                    vlo = v
                                elif v > vhi:
                                    vhi = v
                    lo[a, b, c] = vlo
                    hi[a, b, c] = vhi
