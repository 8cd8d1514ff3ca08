"""Surface voxels: every voxel the surface passes through.

The rule (part of geovox's numeric contract)
--------------------------------------------
Voxel ``(i, j, k)`` is on when the surface meets its box
``[x_i, x_{i+1}) × [y_j, y_{j+1}) × [z_k, z_{k+1})``, each interval closed at
the grid's far face, as :func:`numpy.histogram` closes its last bin. So:

* every point of the surface inside the grid lies in exactly one voxel;
* a face lying exactly on a voxel boundary plane gives one layer, the one
  above it (at the grid's far face, the last one): a CAD box whose faces sit
  on grid planes gets walls one voxel thick, not two;
* a vertex on a voxel corner lights one voxel, an edge along a voxel edge
  one row;
* degenerate triangles (segments, points) follow the same rule;
* a triangle with a non-finite coordinate is skipped.

Ties are decided exactly, on snapped coordinates, the same way by the
compiled kernel (``geovox/_surface.pyx``) and its NumPy twin here, for every
block and every number of threads:

* **Snapping**, as the parity rule snaps (:mod:`geovox.exact`), in 3-D:
  every coordinate goes to index space and onto an integer lattice of
  ``2**-s`` of a voxel, ``q = rint((x - lo_a) / h_a * 2**s)`` (int64, per
  axis ``a``, ``h = grid.spacing``), so voxel boundary planes are the exact
  integers ``m * 2**s``. Snapping is a function of the vertex alone: shared
  vertices stay shared. ``s`` (:func:`snap_bits`) is one per call, chosen from
  the grid and the triangles that reach it -- never from the block or the
  threads: with ``M`` the largest ``|(x - lo_a) / h_a|`` over those
  triangles' vertices and the grid's sides, ``s = min(20, 29 - e)`` where
  ``M + 1 < 2**e``, so every ``|q| < 2**29``. A triangle *reaches* the grid
  when its index-space box meets ``[-1, n_a + 1]`` on every axis; one that
  does not cannot meet the grid once snapped (rint moves a coordinate by at
  most half a lattice step), and does not shrink ``s``. ``s < 1`` (a vertex
  of such a triangle some ``2**28`` voxels from the grid) is refused, as the
  parity rule refuses it. On a dyadic grid (``lo`` and ``h`` powers of two
  times integers) with vertices on a ``2**-s``-voxel lattice, the snap is
  exact and the answer is the rule's for the real triangles; elsewhere a
  vertex moves by at most ``2**-(s+1)`` of a voxel (under 2e-6 of a voxel up
  to 1024 voxels a side), which changes only near-ties.
* **Decision.** ``T`` meets the half-open box ``H`` exactly when it meets
  the closed box ``[lo, hi - eps * m]`` for every small ``eps > 0``, where
  ``m_a = 1`` on the axes where the voxel is not the grid's last and ``0``
  where it is (if ``T ∩ H`` holds a point, that point is in those boxes for
  small ``eps``; a point of one of them is in ``H``). That is decided by the
  separating-axis theorem (the 3 box axes, the triangle's normal and the 9
  edge × axis cross products; zero axes never separate, and the same axes
  serve segments and points) with ``eps`` symbolic: an axis ``L`` with the
  triangle's projection ``[tmin, tmax]`` and the box's ``[bmin0, bmax0]`` at
  ``eps = 0`` separates when ``tmin + dmax > bmax0`` or ``tmax - dmin <
  bmin0``, where ``dmax = 1`` if some axis ``a`` with ``m_a = 1`` has ``L_a >
  0`` (the box's top then moves down with ``eps``) and ``dmin = 1`` if some
  has ``L_a < 0``: with integer projections, a tie at the moving side is a
  separation. Every projection is an integer polynomial of the snapped
  coordinates, so every decision is exact.
* **Bounds.** With ``|q| < 2**29``: differences ``< 2**30``; edge × axis
  projections (degree 2) ``< 2**61``; normal components ``< 2**61`` (int64);
  the normal's projections (degree 3) ``< 2**93``: ``__int128`` in the
  kernel, two 31-bit limbs and Python integers per triangle here.

Speed
-----
Most triangles of a fine mesh lie in one voxel (all three snapped vertices
in the same half-open box: that voxel, no test, for the box is convex), or
span voxels along one axis only (every voxel of that run, no test). A
larger triangle is walked column by column along the axis ``w`` of its
normal's largest component: over one ``(u, v)`` cell the plane's ``w`` spans
at most two voxels, so each cell of the projected footprint has a few
candidate voxels (found in float64 with a margin of 4 lattice steps, far
above its rounding; the exact test decides), and a cell inside the
projected triangle needs only the plane's test. A segment is walked layer
by layer along its longest axis. So a triangle costs its footprint in
cells, not its bounding box in voxels: one tilted triangle across a 512³
grid takes 7 ms where testing every voxel of its box took 525 ms, and the
dragon (100,000 triangles) 264 ms instead of 427 at 1024³ (one thread).
The compiled kernel has two more exact shortcuts (see
``geovox/_surface.pyx``): a triangle within one layer is a 2-D problem, and
a small box shares its edge tests among voxels as bit masks.

A mesh comes as its vertices and faces (``faces=``) or as triangles; a
block's pass skips, after three divisions, the triangles whose z-range
misses its layers. The snapping scale needs no pass over the triangles
where no vertex lies farther from the grid than its own side does.

Sparse outputs (:func:`surface_points`)
---------------------------------------
A point cloud needs the voxels on, not a byte per voxel: the compiled
kernel sets them as bits of uint64 words (1024³ is 128 MiB of bits against
1 GiB of bytes), counts them as it sets them, and reads the set bits back
word by word in the grid's memory order, clearing each word as it goes (so
one buffer serves every slab), with rows followed as the bits are (no
division per voxel), handing back indices or per-axis values (a ``.ply``'s
centre coordinates). The dragon at 1024³ into ``.ply`` took 0.70-1.15 s
whole process with a byte volume (its pages, its count and the scans of
it) and 0.28-0.30 s with bits (paired runs, two shared cores).

Threads (compiled kernel)
-------------------------
Triangles are shared among OpenMP threads (dynamic schedule); every thread
writes the shared output with relaxed atomic byte stores of 1, or bits with
an atomic OR (after a plain load: a bit already set needs no locked
instruction). A voxel's value is the OR over triangles of a pure function
of the triangle and the voxel, so the result is the same for every thread
count and schedule, and atomic writes make the concurrent writes race-free;
this needs no per-thread copy of the output and no partition of the mesh.
Threads are used where the work pays for them (``_THREADS_TRIANGLES``,
``_THREADS_SIDE``): a parallel region is cheap on idle cores but can wait a
scheduler slice for its last thread on busy ones. The NumPy twin runs on
one thread.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import MeshError, ParameterError
from .grid import Grid
from .kernels import compiled, openmp_threads
from .parallel import resolve_jobs

__all__ = ["COORD_BITS", "MAX_SUB_BITS", "snap_bits", "surface_points", "surface_voxels",
           "word_count"]

#: Every snapped coordinate (and every grid side, ``n_a * 2**s``) is below ``2**COORD_BITS``.
COORD_BITS = 29
#: Finest snapping used: ``2**-20`` of a voxel.
MAX_SUB_BITS = 20

# Triangles per batch of the NumPy twin, and candidate voxels per exact
# test: the twin's memory is bounded by these, not by the mesh or the grid.
_BATCH = 1 << 15
_CANDIDATES = 1 << 18
# The walks' float64 ranges are widened by this many lattice steps; their
# rounding error is below 2**-20 of a step (coordinates < 2**30).
_MARGIN = 4.0
# Limbs of the normal's exact test (see _normal_meets).
_LIMB = 31
_LIMB_MASK = (1 << _LIMB) - 1
# Threads (compiled kernel) only where the work is worth them. A parallel
# region costs ~0.1 ms on idle cores, but on busy ones it can wait a
# scheduler slice (~10 ms) for its last thread: measured on two shared
# cores, the dragon (100,000 triangles) at 256^3 took 25 ms on one thread
# and 14 on two when the other core was free, 25-45 when it was not; the
# snapping scale's pass (1 ms per 100,000 triangles) never gains.
_THREADS_TRIANGLES = 1 << 16
_THREADS_SIDE = 512
_EXTENT_THREADS_TRIANGLES = 1 << 21


# ---- the public functions --------------------------------------------------

def snap_bits(triangles, grid: Grid, *, faces=None, jobs: int = 1) -> int:
    """The snapping scale ``s`` of :func:`surface_voxels`: coordinates snap to ``2**-s`` of a voxel.

    Parameters
    ----------
    triangles : (n, 3, 3) float64, or (v, 3) float64 with ``faces``
        Triangle vertex coordinates in the frame of ``grid``; with
        ``faces``, the vertices they index.
    grid : Grid
        The whole grid (never a block of it).
    faces : (n, 3) int, optional
        The triangles as indices into ``triangles`` (a mesh's vertices):
        the same answer as ``triangles[faces]``, without making that array.
    jobs : int
        Threads for the compiled kernel's pass over the triangles (used
        from some two million triangles up).

    Returns
    -------
    int
        ``s`` in ``[1, MAX_SUB_BITS]``: ``min(20, 29 - e)`` with ``M + 1 <
        2**e``, ``M`` the largest ``|(x - lo) / h|`` over the vertices of the
        finite triangles whose index-space box meets ``[-1, n + 1]`` on
        every axis, and the grid's sides.

    Raises
    ------
    ParameterError
        ``s`` would be below 1: a triangle reaching the grid has a vertex
        some ``2**28`` voxels away.
    """
    verts, faces, count = _as_mesh(triangles, faces)
    _check_grid(grid)
    kernel = compiled("_surface", "surface-voxel")
    threads = resolve_jobs(jobs) if count >= _EXTENT_THREADS_TRIANGLES else 1
    return _snap(verts, faces, grid, kernel, openmp_threads(threads))


def surface_voxels(triangles, grid: Grid, block=None, *, faces=None, jobs: int = 1, out=None,
                   bits=None) -> np.ndarray:
    """The voxels of ``grid`` that the triangles pass through (the rule in :mod:`geovox.surface`).

    Parameters
    ----------
    triangles : (n, 3, 3) float64, or (v, 3) float64 with ``faces``
        Triangle vertex coordinates in the frame of ``grid``; with
        ``faces``, the vertices they index. Triangles with a non-finite
        coordinate are skipped; triangles outside the grid (or the block)
        cost one pass over their coordinates.
    grid : Grid
        The whole axis-aligned grid; the snapping scale comes from it and
        the mesh (:func:`snap_bits`), never from ``block``.
    block : (int, int), optional
        ``(z0, z1)``: make only voxel layers ``z0 <= k < z1`` of the whole
        grid. The answer is that slice of the whole grid's, bit for bit.
        Default: the whole grid.
    faces : (n, 3) int, optional
        The triangles as indices into ``triangles`` (a mesh's vertices):
        the same voxels as ``triangles[faces]``, without making that array.
    jobs : int
        Threads (compiled kernel; None or 0: one per core), used where the
        work is large enough to gain from them. The answer does not depend
        on it.
    out : (nx, ny, z1 - z0) bool array, Fortran order, optional
        A buffer to fill (its contents are overwritten), e.g. reused across
        slabs.
    bits : int, optional
        The snapping scale, :func:`snap_bits` of the whole mesh: given, a
        slab may be made from only the triangles that reach it and still be
        the whole mesh's slice. It may not exceed ``snap_bits`` of the
        triangles given that reach the block (their coordinates would not
        fit the integer bounds; ``out`` is then left undefined). Default:
        ``snap_bits(triangles, grid)``.

    Returns
    -------
    (nx, ny, z1 - z0) bool, Fortran order
        ``out`` if given. Voxel ``[i, j, k]`` is layer ``z0 + k`` of the grid.

    Raises
    ------
    MeshError
        ``triangles`` (or ``faces``) is not an array of the shapes above.
    ParameterError
        A bad ``grid``, ``block``, ``jobs``, ``out`` or ``bits``, or a
        triangle too far from the grid to snap (see :func:`snap_bits`).
    """
    verts, faces, count = _as_mesh(triangles, faces)
    _check_grid(grid)
    z0, z1 = _check_block(block, grid)
    shape = (int(grid.shape[0]), int(grid.shape[1]), z1 - z0)
    fresh = out is None
    if fresh:
        # calloc'd: pages the surface never reaches are never touched (np.empty and a
        # clear, huge pages and all, was no faster: 256³ 0.209 s against 0.210 whole
        # process, 512³ 0.380 against 0.340, and a higher peak).
        out = np.zeros(shape, dtype=bool, order="F")
    else:
        _check_out(out, shape)
    run = _Run(verts, faces, count, grid, (z0, z1), jobs, bits)
    if run.kernel is not None:
        run.compiled(out=out.view(np.uint8), zero=not fresh)
    else:
        out[...] = False
        _numpy_surface(verts, faces, run, z0, z1, out)
    return out


def surface_points(triangles, grid: Grid, block=None, *, faces=None, jobs: int = 1, bits=None,
                   words=None, values=None) -> np.ndarray:
    """The indices of :func:`surface_voxels`' voxels, in the grid's memory order.

    The same voxels, for a sparse output: no byte per voxel is made or
    scanned. The compiled kernel sets them as bits (a 512th of the bytes,
    with atomic OR where threads share a word) and reads the set bits back
    word by word; the NumPy twin takes them from :func:`surface_voxels`.

    Parameters
    ----------
    triangles, grid, block, faces, jobs, bits
        As :func:`surface_voxels`.
    words : (w,) uint64 array, optional
        A buffer for the block's bits, at least :func:`word_count` of the
        block's shape, all zero; it is left all zero (the bits are cleared
        as they are read back), so one buffer serves every slab with no
        clearing pass. Default: a fresh one.
    values : three 1-D arrays, optional
        Per axis, a value for each index of the whole grid (``nx``, ``ny``
        and ``nz`` of them), one dtype, float32 or float64: e.g. the voxel
        centres' coordinates. Given, each voxel comes back as ``(values[0][i],
        values[1][j], values[2][k])``, looked up as its bit is read: a point
        cloud with no pass over the indices.

    Returns
    -------
    (m, 3) int32, or (m, 3) of the values' dtype
        ``[i, j, k]`` of each voxel on (``k`` a layer of the whole grid,
        ``z0 <= k < z1``), or its values, x fastest, then y, then z: the
        order of ``np.argwhere`` on the Fortran-ordered volume's transpose,
        as the ``.ply`` and sparse ``.npz`` list them.

    Raises
    ------
    MeshError, ParameterError
        As :func:`surface_voxels`, and a ``words`` that is not a writeable
        contiguous uint64 array of at least that many words.
    """
    verts, faces, count = _as_mesh(triangles, faces)
    _check_grid(grid)
    z0, z1 = _check_block(block, grid)
    nx, ny = int(grid.shape[0]), int(grid.shape[1])
    need = word_count((nx, ny, z1 - z0))
    if words is None:
        words = np.zeros(need, dtype=np.uint64)  # calloc'd, as surface_voxels' out
    elif (not isinstance(words, np.ndarray) or words.dtype != np.uint64 or words.ndim != 1
          or not words.flags.c_contiguous or not words.flags.writeable or len(words) < need):
        got = (f"{words.dtype} {words.shape}" if isinstance(words, np.ndarray)
               else type(words).__name__)
        raise ParameterError(f"`words` must be a writeable contiguous uint64 array of at least "
                             f"{need} words, got {got}")
    if values is not None:
        values = _check_values(values, grid.shape)
    run = _Run(verts, faces, count, grid, (z0, z1), jobs, bits)
    if run.kernel is None:
        occ = np.zeros((nx, ny, z1 - z0), dtype=bool, order="F")
        _numpy_surface(verts, faces, run, z0, z1, occ)
        flat = np.flatnonzero(occ.reshape(-1, order="F"))
        ijk = np.stack([flat % nx, (flat // nx) % ny, flat // (nx * ny) + z0], axis=1)
        if values is not None:
            return np.stack([v[ijk[:, a]] for a, v in enumerate(values)], axis=1)
        return ijk.astype(np.int32)
    try:
        on = run.compiled(words=words)
    except ParameterError:
        words[:need] = 0  # left all zero, as promised
        raise
    if values is not None:
        out = np.empty((on, 3), dtype=values[0].dtype)
        run.kernel.values_at(words, nx, ny, z1 - z0, z0, *values, out)
        return out
    ijk = np.empty((on, 3), dtype=np.int32)
    run.kernel.points(words, nx, ny, z1 - z0, z0, ijk)
    return ijk


def _check_values(values, shape):
    """The per-axis values of :func:`surface_points`, checked: three contiguous 1-D arrays."""
    try:
        vals = [np.ascontiguousarray(v) for v in values]
    except TypeError:
        vals = []
    if (len(vals) != 3 or any(v.ndim != 1 or len(v) != n for v, n in zip(vals, shape))
            or vals[0].dtype not in (np.float32, np.float64)
            or any(v.dtype != vals[0].dtype for v in vals)):
        raise ParameterError(f"`values` must be three 1-D float32 or float64 arrays of one dtype "
                             f"and lengths {tuple(int(n) for n in shape)}, got {values!r:.80}")
    return vals


def word_count(shape) -> int:
    """uint64 words that hold a block of ``shape`` ``(nx, ny, nz)`` as bits (surface_points)."""
    nx, ny, nz = (int(n) for n in shape)
    return -(-nx * ny * nz // 64)


class _Run:
    """One call's frame, snapping scale and threads; runs the compiled kernel."""

    def __init__(self, verts, faces, count, grid, block, jobs, bits):
        z0, z1 = block
        threads = resolve_jobs(jobs)
        # Threads only where the work is worth them (_THREADS_TRIANGLES).
        if count < _THREADS_TRIANGLES and max(grid.shape) < _THREADS_SIDE:
            threads = 1
        self.threads = openmp_threads(threads)
        self.kernel = compiled("_surface", "surface-voxel")
        self.verts, self.faces, self.grid, self.block = verts, faces, grid, (z0, z1)
        self.lo, self.h, self.n = _frame(grid)
        self.given = bits is not None
        if self.given:
            if isinstance(bits, bool) or not isinstance(bits, (int, np.integer)) \
                    or not 1 <= bits <= MAX_SUB_BITS:
                raise ParameterError(f"`bits` must be an integer from 1 to {MAX_SUB_BITS}, "
                                     f"got {bits!r}")
            self.s = int(bits)
            if self.kernel is None:  # the twin checks first (the kernel checks as it runs)
                self._check(_extent(verts, faces, grid, None, 1, (z0, z1)))
        else:
            self.s = _snap(verts, faces, grid, self.kernel, self.threads)

    def compiled(self, *, out=None, words=None, zero=True) -> int:
        """Run the compiled kernel into ``out`` (bytes) or ``words`` (bits); voxels on (bits)."""
        z0, z1 = self.block
        on, m = self.kernel.surface(self.verts, self.faces, self.lo, self.h, self.n, self.s, z0,
                                    z1, out, words, zero, self.threads)
        if self.given:
            self._check(m)
        return on

    def _check(self, m):
        s = _bits(m, self.grid)
        if self.s > s:
            raise ParameterError(f"`bits` must be an integer from 1 to {s} (snap_bits of these "
                                 f"triangles), got {self.s}")


# ---- checks ------------------------------------------------------------------

def _as_mesh(triangles, faces):
    """``(vertices (v, 3) float64, faces (n, 3) int64 or None, n)``: the kernels' input.

    Without ``faces``, triangle ``t`` is rows ``3t .. 3t + 2`` of the vertices
    (a view of ``triangles``, no copy).
    """
    what = "(n, 3, 3)" if faces is None else "(v, 3) (the vertices `faces` index)"
    try:
        verts = np.ascontiguousarray(triangles, dtype=np.float64)
    except (TypeError, ValueError):
        raise MeshError(f"`triangles` must be an {what} array of numbers, "
                        f"got {type(triangles).__name__}") from None
    if faces is None:
        if verts.ndim != 3 or verts.shape[1:] != (3, 3):
            raise MeshError(f"`triangles` must be an (n, 3, 3) array, got shape {verts.shape}")
        return verts.reshape(-1, 3), None, len(verts)
    if verts.ndim != 2 or verts.shape[1] != 3:
        raise MeshError(f"`triangles` must be a {what} array with `faces`, got shape {verts.shape}")
    try:
        idx = np.ascontiguousarray(faces, dtype=np.int64)
    except (TypeError, ValueError):
        raise MeshError(f"`faces` must be an (n, 3) array of indices, "
                        f"got {type(faces).__name__}") from None
    if idx.ndim != 2 or idx.shape[1] != 3:
        raise MeshError(f"`faces` must be an (n, 3) array, got shape {idx.shape}")
    if idx.size and (idx.min() < 0 or idx.max() >= len(verts)):
        raise MeshError(f"`faces` must index the {len(verts)} vertices, got indices "
                        f"{idx.min()}..{idx.max()}")
    return verts, idx, len(idx)


def _triangles(verts, faces, start, stop):
    """(m, 3, 3) float64: triangles ``start .. stop - 1``."""
    if faces is None:
        return verts[3 * start:3 * stop].reshape(-1, 3, 3)
    return verts[faces[start:stop]]


def _check_grid(grid) -> None:
    if not isinstance(grid, Grid):
        raise ParameterError(f"`grid` must be a geovox Grid, got {type(grid).__name__}")


def _check_block(block, grid: Grid):
    nz = int(grid.shape[2])
    if block is None:
        return 0, nz
    try:
        z0, z1 = (int(b) for b in block)
    except (TypeError, ValueError):
        raise ParameterError(f"`block` must be (z0, z1) voxel layers, got {block!r}") from None
    if not 0 <= z0 < z1 <= nz:
        raise ParameterError(f"`block` must satisfy 0 <= z0 < z1 <= {nz}, got {block!r}")
    return z0, z1


def _check_out(out, shape) -> None:
    if (not isinstance(out, np.ndarray) or out.dtype != np.bool_ or out.shape != shape
            or not out.flags.f_contiguous or not out.flags.writeable):
        got = (f"{out.dtype} {out.shape} {'F' if out.flags.f_contiguous else 'not F'}-ordered"
               if isinstance(out, np.ndarray) else type(out).__name__)
        raise ParameterError(f"`out` must be a writeable Fortran-ordered bool array of shape "
                             f"{shape}, got {got}")


def _frame(grid: Grid):
    lo = np.ascontiguousarray(grid.lo, dtype=np.float64)
    h = np.ascontiguousarray(grid.spacing, dtype=np.float64)
    n = np.asarray(grid.shape, dtype=np.int64)
    return lo, h, n


# ---- the snapping scale ------------------------------------------------------

def _extent(verts, faces, grid, module, threads, block=None) -> float:
    """The largest ``|(x - lo) / h|`` over the vertices of the triangles that reach the grid.

    With ``block`` (the NumPy twin's check of a given scale), of those that
    reach its layers, as the compiled kernel's pass reports it.
    """
    lo, h, n = _frame(grid)
    if module is not None:
        return module.extent(verts, faces, lo, h, n, threads)
    count = len(verts) // 3 if faces is None else len(faces)
    m = 0.0
    for start in range(0, count, _BATCH):
        f = _index_space(_triangles(verts, faces, start, start + _BATCH), lo, h)
        near = f[_reaching(f, n, block)]
        if len(near):
            m = max(m, float(np.abs(near).max()))
    return m


def _snap(verts, faces, grid, module, threads) -> int:
    """:func:`snap_bits`' scale: at once where no vertex at all lowers it below the grid's own.

    ``M`` lies between the grid's largest side and the largest ``|(x - lo) /
    h|`` of every finite vertex, and ``s`` only falls as ``M`` grows: where
    both ends give the same ``s``, so does ``M``, and the pass over the
    triangles that reach the grid is not needed (a mesh within its grid:
    1.6M triangles took 22 ms for that pass, their vertices 2).
    """
    grid_s = _bits(0.0, grid)
    if _scale(_vertex_extent(verts, grid, module), grid) == grid_s:
        return grid_s
    return _bits(_extent(verts, faces, grid, module, threads), grid)


def _vertex_extent(verts, grid, module) -> float:
    """The largest ``|(x - lo) / h|`` over every finite vertex (each triangle's, used or not)."""
    lo, h, _ = _frame(grid)
    if module is not None:
        return module.vertex_extent(verts, lo, h)
    f = np.abs(_index_space(verts, lo, h))
    f = f[np.isfinite(f)]
    return float(f.max()) if len(f) else 0.0


def _scale(m: float, grid: Grid) -> int:
    """``s`` for ``M = max(m, the largest side)`` (below 1 where it cannot snap)."""
    _, e = math.frexp(max(m, float(max(grid.shape))) + 1.0)
    return min(MAX_SUB_BITS, COORD_BITS - e)


def _bits(m: float, grid: Grid) -> int:
    # frexp: m + 1 < 2**e exactly, so every |q| <= (m + 1) * 2**s < 2**COORD_BITS.
    s = _scale(m, grid)
    if s < 1:
        raise ParameterError(
            "the grid is too small next to the triangles that reach it for exact surface "
            f"tests (a vertex {m:.3g} voxels from its corner); use larger `bounds` or a "
            "coarser grid")
    return s


def _index_space(t, lo, h):
    # The compiled kernel computes (x - lo) / h with the same two roundings.
    with np.errstate(invalid="ignore", over="ignore"):
        return (t - lo) / h


def _reaching(f, n, block=None):
    """(m,) bool: finite triangles whose index-space box meets ``[-1, n + 1]`` on every axis.

    The others cannot meet the grid once snapped: ``f < -1`` gives ``q <=
    -2**s < 0`` and ``f > n + 1`` gives ``q > n * 2**s``. With ``block``
    ``(z0, z1)``, along z ``[z0 - 1, z1 + 1]``: the others cannot meet its
    layers (the compiled kernel skips them before snapping).
    """
    low = np.full(3, -1.0)
    high = n + 1.0
    if block is not None:
        low[2], high[2] = block[0] - 1.0, block[1] + 1.0
    finite = np.isfinite(f).all(axis=(1, 2))
    with np.errstate(invalid="ignore"):
        near = ((f.max(axis=1) >= low) & (f.min(axis=1) <= high)).all(axis=1)
    return finite & near


# ---- the NumPy twin ------------------------------------------------------------

def _numpy_surface(verts, faces, run: "_Run", z0: int, z1: int, out):
    """The compiled kernel's voxels, by the same exact tests (one thread), layers ``z0 .. z1``."""
    lo, h, n, S = run.lo, run.h, run.n, 1 << run.s
    count = len(verts) // 3 if faces is None else len(faces)
    for start in range(0, count, _BATCH):
        f = _index_space(_triangles(verts, faces, start, start + _BATCH), lo, h)
        f = f[_reaching(f, n)]
        q = np.rint(f * float(S)).astype(np.int64)  # (m, vertex, axis)
        _mark_batch(q, n, S, z0, z1, out)


def _mark_batch(q, n, S, z0, z1, out):
    side = n * S
    mn, mx = q.min(axis=1), q.max(axis=1)
    keep = ((mx >= 0) & (mn <= side)).all(axis=1)  # exactly: the others miss the grid
    q, mn, mx = q[keep], mn[keep], mx[keep]
    lo_i = np.minimum(np.maximum(mn // S, 0), n - 1)
    hi_i = np.minimum(mx // S, n - 1)
    # An axis is "single" when every point of the triangle is in one voxel's
    # half-open interval (closed at the grid's far face) along it.
    single = (lo_i == hi_i) & (mn >= 0) & (mx <= side)
    # The block: candidates and runs are clipped to its layers.
    lo_i[:, 2] = np.maximum(lo_i[:, 2], z0)
    hi_i[:, 2] = np.minimum(hi_i[:, 2], z1 - 1)
    keep = lo_i[:, 2] <= hi_i[:, 2]
    q, lo_i, hi_i, single = q[keep], lo_i[keep], hi_i[keep], single[keep]

    # At most one axis spans several voxels: the triangle's projection on it
    # is an interval, so it lights every voxel of that run, no test needed.
    run = single.sum(axis=1) >= 2
    if run.any():
        _mark_runs(lo_i[run], hi_i[run], z0, out)
    q, lo_i, hi_i = q[~run], lo_i[~run], hi_i[~run]
    if not len(q):
        return
    d1, d2 = q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]
    normal = np.cross(d1, d2)  # < 2**61: exact in int64
    flat = ~normal.any(axis=1)
    tests = _Tests(q, normal, n, S)
    for tri, idx in _column_candidates(q, normal, lo_i, hi_i, np.flatnonzero(~flat), S):
        _mark_tested(tests, tri, idx, z0, out)
    for tri, idx in _segment_candidates(q, lo_i, hi_i, np.flatnonzero(flat), S):
        _mark_tested(tests, tri, idx, z0, out)


def _mark_runs(lo_i, hi_i, z0, out):
    counts = (hi_i - lo_i + 1).prod(axis=1)
    owner, offset = _ragged(counts)
    # Only one axis spans more than one voxel, so the offset is along it.
    axis = np.argmax(hi_i - lo_i, axis=1)[owner]
    idx = lo_i[owner]
    idx[np.arange(len(owner)), axis] += offset
    out[idx[:, 0], idx[:, 1], idx[:, 2] - z0] = True


def _mark_tested(tests, tri, idx, z0, out):
    on = tests.meets(tri, idx)
    idx = idx[on]
    out[idx[:, 0], idx[:, 1], idx[:, 2] - z0] = True


def _ragged(counts):
    """(owner, offset): ``counts[o]`` entries for each ``o``, numbered from 0 within each."""
    counts = np.maximum(counts, 0)
    owner = np.repeat(np.arange(len(counts)), counts)
    starts = np.cumsum(counts) - counts
    return owner, np.arange(len(owner)) - starts[owner]


def _chunks(counts, limit):
    """Consecutive ranges of owners whose counts sum to about ``limit`` (at least one owner each)."""
    total = np.cumsum(counts)
    start = 0
    while start < len(counts):
        base = total[start - 1] if start else 0
        stop = int(np.searchsorted(total, base + limit, side="right"))
        stop = max(stop, start + 1)
        yield start, stop
        start = stop


def _column_candidates(q, normal, lo_i, hi_i, which, S):
    """Candidate voxels of non-degenerate triangles, walked column by column.

    Yields ``(tri, idx)``: (c,) int64 rows of ``q`` and (c, 3) int64 voxel
    indices, for about ``_CANDIDATES / 4`` cells at a time (a cell has at most
    four candidates: the plane's two voxels and the margins).
    """
    if not len(which):
        return
    Sd = float(S)
    nrm = normal[which]
    w = np.argmax(np.abs(nrm), axis=1)
    u, v = (w + 1) % 3, (w + 2) % 3
    r = np.arange(len(which))
    qt = q[which].astype(np.float64)
    pu, pv, pw = qt[r, :, u], qt[r, :, v], qt[r, :, w]  # (m, 3): 2-D vertices, depths
    gu = nrm[r, u] / nrm[r, w].astype(np.float64)
    gv = nrm[r, v] / nrm[r, w].astype(np.float64)
    lo, hi = lo_i[which], hi_i[which]
    # Rows: u-strips of cells, one triangle's at a time; at most n_v cells each.
    row_tri, row_off = _ragged(hi[r, u] - lo[r, u] + 1)
    row_i = lo[row_tri, u[row_tri]] + row_off
    row_cells = hi[row_tri, v[row_tri]] - lo[row_tri, v[row_tri]] + 1
    for a, b in _chunks(row_cells, _CANDIDATES // 4):
        owner, i = row_tri[a:b], row_i[a:b]
        # The v-range of the projected triangle within the strip, widened.
        vmin, vmax = _strip_range(pu[owner], pv[owner], i * Sd - _MARGIN, (i + 1) * Sd + _MARGIN)
        ok = vmin <= vmax
        owner, i, vmin, vmax = owner[ok], i[ok], vmin[ok], vmax[ok]
        jlo = np.maximum(lo[owner, v[owner]], np.floor((vmin - _MARGIN) / Sd).astype(np.int64))
        jhi = np.minimum(hi[owner, v[owner]], np.floor((vmax + _MARGIN) / Sd).astype(np.int64))
        cell, joff = _ragged(jhi - jlo + 1)
        tri, i, j = owner[cell], i[cell], jlo[cell] + joff
        # The plane's w-range over the cell [iS, (i+1)S] x [jS, (j+1)S].
        g1, g2 = gu[tri], gv[tri]
        wc = pw[tri, 0] - g1 * (i * Sd - pu[tri, 0]) - g2 * (j * Sd - pv[tri, 0])
        wlo = wc - Sd * (np.maximum(g1, 0) + np.maximum(g2, 0)) - _MARGIN
        whi = wc - Sd * (np.minimum(g1, 0) + np.minimum(g2, 0)) + _MARGIN
        ww = w[tri]
        klo = np.maximum(lo[tri, ww], np.floor(wlo / Sd).astype(np.int64))
        khi = np.minimum(hi[tri, ww], np.floor(whi / Sd).astype(np.int64))
        cand, koff = _ragged(khi - klo + 1)
        tri, i, j, k = tri[cand], i[cand], j[cand], klo[cand] + koff
        idx = np.empty((len(tri), 3), dtype=np.int64)
        rr = np.arange(len(tri))
        idx[rr, u[tri]] = i
        idx[rr, v[tri]] = j
        idx[rr, w[tri]] = k
        yield which[tri], idx


def _strip_range(pu, pv, ul, uh):
    """The v-range of 2-D triangles ``(pu, pv)`` ((m, 3) float64) within ``ul <= u <= uh``.

    (m,) float64 each; ``vmin > vmax`` where the strip misses the triangle.
    The extremes of a convex polygon cut by a strip lie on its edges' pieces
    within the strip.
    """
    vmin = np.full(len(pu), np.inf)
    vmax = np.full(len(pu), -np.inf)
    for e in range(3):
        au, av = pu[:, e], pv[:, e]
        bu, bv = pu[:, (e + 1) % 3], pv[:, (e + 1) % 3]
        du = bu - au
        with np.errstate(divide="ignore", invalid="ignore"):
            ta, tb = (ul - au) / du, (uh - au) / du
        t0 = np.where(du != 0, np.maximum(np.minimum(ta, tb), 0.0), 0.0)
        t1 = np.where(du != 0, np.minimum(np.maximum(ta, tb), 1.0), 1.0)
        hit = np.where(du != 0, t0 <= t1, (au >= ul) & (au <= uh))
        for t in (t0, t1):
            val = av + t * (bv - av)
            vmin = np.where(hit, np.minimum(vmin, val), vmin)
            vmax = np.where(hit, np.maximum(vmax, val), vmax)
    return vmin, vmax


def _segment_candidates(q, lo_i, hi_i, which, S):
    """Candidate voxels of degenerate triangles (segments, points), walked layer by layer.

    Yields ``(tri, idx)`` as :func:`_column_candidates`.
    """
    if not len(which):
        return
    Sd = float(S)
    qs = q[which]
    # A degenerate triangle is the segment between its farthest pair of vertices.
    ends = np.array([(0, 1), (1, 2), (2, 0)])
    length = np.stack([np.abs(qs[:, b] - qs[:, a]).max(axis=1) for a, b in ends], axis=1)
    pick = ends[np.argmax(length, axis=1)]
    r = np.arange(len(which))
    p0 = qs[r, pick[:, 0]].astype(np.float64)
    delta = qs[r, pick[:, 1]].astype(np.float64) - p0
    d = np.argmax(np.abs(delta), axis=1)  # its longest axis (delta[d] != 0: not a point)
    lo, hi = lo_i[which], hi_i[which]
    lay_tri, lay_off = _ragged(hi[r, d] - lo[r, d] + 1)
    # Over one layer the other coordinates move by at most a voxel: with the
    # margins, at most 3 x 3 candidates.
    for a, b in _chunks(np.full(len(lay_tri), 9), _CANDIDATES):
        owner = lay_tri[a:b]
        dd = d[owner]
        t = lo[owner, dd] + lay_off[a:b]
        base, step = p0[owner, dd], delta[owner, dd]
        ta = (t * Sd - _MARGIN - base) / step
        tb = ((t + 1) * Sd + _MARGIN - base) / step
        t0 = np.maximum(np.minimum(ta, tb), 0.0)
        t1 = np.minimum(np.maximum(ta, tb), 1.0)
        ranges = []
        for shift in (1, 2):
            ax = (dd + shift) % 3
            va = p0[owner, ax] + t0 * delta[owner, ax]
            vb = p0[owner, ax] + t1 * delta[owner, ax]
            low = np.floor((np.minimum(va, vb) - _MARGIN) / Sd).astype(np.int64)
            high = np.floor((np.maximum(va, vb) + _MARGIN) / Sd).astype(np.int64)
            rlo = np.maximum(lo[owner, ax], low)
            rhi = np.minimum(hi[owner, ax], high)
            ranges.append((ax, rlo, np.maximum(rhi - rlo + 1, 0)))
        (ax1, lo1, n1), (ax2, lo2, n2) = ranges
        cand, off = _ragged(np.where(t0 <= t1, n1 * n2, 0))
        idx = np.empty((len(cand), 3), dtype=np.int64)
        cc = np.arange(len(cand))
        idx[cc, dd[cand]] = t[cand]
        idx[cc, ax1[cand]] = lo1[cand] + off // n2[cand]
        idx[cc, ax2[cand]] = lo2[cand] + off % n2[cand]
        yield which[owner[cand]], idx


class _Tests:
    """The exact separating-axis tests of snapped triangles against voxels.

    Parameters
    ----------
    q : (m, 3, 3) int64
        Snapped vertices ``[triangle, vertex, axis]``.
    normal : (m, 3) int64
        ``(q1 - q0) x (q2 - q0)``.
    n : (3,) int64
        The grid's shape.
    S : int
        ``2**s``.
    """

    def __init__(self, q, normal, n, S):
        self.n, self.S = n, S
        self.edges = []
        for k in range(3):
            e = q[:, (k + 1) % 3] - q[:, k]
            for a in range(3):
                b, c = (a + 1) % 3, (a + 2) % 3
                # L = e x unit_a: L_a = 0, L_b = e_c, L_c = -e_b.
                lb, lc = e[:, c], -e[:, b]
                p = lb[:, None] * q[:, :, b] + lc[:, None] * q[:, :, c]  # < 2**60
                self.edges.append((b, c, lb, lc, p.min(axis=1), p.max(axis=1)))
        self.normal = normal
        # The normal's test compares X = N . idx with per-triangle thresholds
        # of up to 2**93 / S: N . idx in two 31-bit limbs (each sum < 2**62),
        # the thresholds from exact Python integers (one per triangle).
        self.nh, self.nl = normal >> _LIMB, normal & _LIMB_MASK
        N = normal.astype(object)
        d0 = (N * q[:, 0].astype(object)).sum(axis=1)
        pmax = (np.maximum(normal, 0).astype(object)).sum(axis=1) * S
        pmin = (np.minimum(normal, 0).astype(object)).sum(axis=1) * S
        # Separated on the top side iff X <= floor((d0 - Pmax + dmax - 1) / S);
        # on the bottom side iff X > floor((d0 - Pmin - dmin) / S).
        self.top = [_limbs((d0 - pmax + dmax - 1) // S) for dmax in (0, 1)]
        self.bottom = [_limbs((d0 - pmin - dmin) // S) for dmin in (0, 1)]

    def meets(self, tri, idx):
        """(c,) bool: whether triangle ``tri[c]`` meets voxel ``idx[c]`` (the rule)."""
        S = self.S
        inner = idx < self.n - 1  # m_a: the voxel is not the grid's last along a
        on = self._normal_meets(tri, idx, inner)
        for b, c, lb, lc, tmin, tmax in self.edges:
            if not on.any():
                break
            lb, lc = lb[tri], lc[tri]
            corner = S * (lb * idx[:, b] + lc * idx[:, c])
            bmax = S * (np.maximum(lb, 0) + np.maximum(lc, 0))
            bmin = S * (np.minimum(lb, 0) + np.minimum(lc, 0))
            dmax = ((lb > 0) & inner[:, b]) | ((lc > 0) & inner[:, c])
            dmin = ((lb < 0) & inner[:, b]) | ((lc < 0) & inner[:, c])
            on &= ~((tmin[tri] - corner + dmax > bmax) | (tmax[tri] - corner - dmin < bmin))
        return on

    def _normal_meets(self, tri, idx, inner):
        N = self.normal[tri]
        dmax = ((N > 0) & inner).any(axis=1).astype(np.int64)
        dmin = ((N < 0) & inner).any(axis=1).astype(np.int64)
        xh = (self.nh[tri] * idx).sum(axis=1)
        xl = (self.nl[tri] * idx).sum(axis=1)
        xh += xl >> _LIMB
        xl &= _LIMB_MASK
        th = np.where(dmax == 1, self.top[1][0][tri], self.top[0][0][tri])
        tl = np.where(dmax == 1, self.top[1][1][tri], self.top[0][1][tri])
        bh = np.where(dmin == 1, self.bottom[1][0][tri], self.bottom[0][0][tri])
        bl = np.where(dmin == 1, self.bottom[1][1][tri], self.bottom[0][1][tri])
        above_top = (xh > th) | ((xh == th) & (xl > tl))  # X > top
        within_bottom = (xh < bh) | ((xh == bh) & (xl <= bl))  # X <= bottom
        return above_top & within_bottom


def _limbs(values):
    """(hi, lo) int64 arrays of Python integers: ``v = hi * 2**31 + lo``, ``0 <= lo < 2**31``."""
    hi = np.array([v >> _LIMB for v in values], dtype=np.int64).reshape(-1)
    lo = np.array([v & _LIMB_MASK for v in values], dtype=np.int64).reshape(-1)
    return hi, lo
