"""Big grids in bounded memory: convert slab by slab, streaming into the file.

The grid is cut into slabs along z (64 voxels thick, or a multiple, to match
the 64³ HDF5 chunks), each slab is voxelised as a block of the grid
(:func:`geovox.pipeline.voxelize_block`, as the in-memory path is) -- the
rays still start outside the whole mesh, so a slab is classified exactly as
the full grid would be -- and written into its place in the output before
the next one is made. Peak memory is one slab's arrays, whatever the grid.
Colour, density and distance work per slab too: every candidate crossing of
a slab's voxels lies on a ray through that slab.

Streaming writes HDF5 (plain datasets and the VTK-HDF group) and RAW (with
its headers and sidecar); other formats need the whole volume in memory.
"""

from __future__ import annotations

import time
import warnings

import numpy as np

from .errors import GeovoxWarning, ParameterError
from .grid import Grid, make_grid
from . import memory
from .memory import bytes_per_voxel
from .mesh import load_mesh
from .pipeline import empty_reason, ray_start, voxelize_block

#: Memory a slab's arrays may take, by default: 2048³ occupancy goes in
#: 256-voxel slabs and stays under 3 GiB; occupancy up to 1024³ is one slab.
SLAB_BUDGET = 1 << 30
STREAMABLE = ("hdf5", "raw", "vtkhdf")


def slab_plan(grid: Grid, per_voxel: float, budget: float = SLAB_BUDGET) -> list:
    """``[(z0, z1), ...]``: slabs along z, a multiple of 64 thick, within ``budget``."""
    nx, ny, nz = grid.shape
    fit = int(budget // max(1.0, nx * ny * per_voxel))
    thick = nz if fit >= nz else max(64, fit // 64 * 64)
    return [(z, min(z + thick, nz)) for z in range(0, nz, thick)]


def slab_budget() -> float:
    """Bytes one slab's arrays may take: ``SLAB_BUDGET``, or half the available memory if less."""
    avail = memory._available_memory()
    return SLAB_BUDGET if avail is None else min(SLAB_BUDGET, 0.5 * avail)


def streams(grid: Grid, fmt: str, color=False, density=None, sdf=False) -> bool:
    """Whether a conversion into format ``fmt`` runs slab by slab (:func:`convert_to`).

    The one rule for the command line and batches: a streamable format, and
    a grid that needs several slabs within :func:`slab_budget`, or whose
    occupancy is worth streaming in one piece (:func:`streams_whole`).
    Either way the file is the same as one written from memory.
    """
    if fmt not in STREAMABLE:
        return False
    plan = slab_plan(grid, bytes_per_voxel(color, density, sdf), slab_budget())
    return len(plan) > 1 or streams_whole(grid, color, density, sdf)


def streams_whole(grid: Grid, color=False, density=None, sdf=False) -> bool:
    """Whether a one-piece conversion to .h5 / .raw is worth streaming anyway.

    Occupancy alone of a grid of 512³ voxels or more: filling and writing
    64 slices at a time skips allocating (and first touching) the whole
    array, which on a 1024³ grid costs 0.2-2.5 s by itself, depending on
    the machine's memory state.
    """
    return not (color or density or sdf) and grid.size >= 1 << 27 and grid.shape[2] > 64


def _stream_occupancy(m, grid, engine, writer, jobs, timings, progress) -> int:
    """Occupancy of the whole grid by rays along z, filled and written slab by slab."""
    from . import parity
    from .volume import Volume

    t = time.perf_counter()
    columns = grid.columns(2, start=ray_start(m, grid, 2))
    hits = engine.cast(m, columns, jobs=jobs)
    timings["rays"] += time.perf_counter() - t
    inside = 0
    nx, ny, nz = grid.shape
    n_slabs = -(-nz // 64)
    # Two buffers: a slab is written (compressed, on the pool's threads)
    # while the next one is filled; one write in flight at a time, so a
    # buffer is refilled only after its slab has been written.
    slabs = parity.fill_slabs(hits, columns, grid, thick=64, buffers=2)
    from concurrent.futures import ThreadPoolExecutor

    def write(z0, occ):
        t = time.perf_counter()
        # Only the slab's shape and arrays are read by the writers.
        writer.write(z0, Volume(occupancy=occ, grid=Grid(grid.lo, grid.hi, occ.shape),
                                backend=engine.name))
        return time.perf_counter() - t

    pending = None
    with ThreadPoolExecutor(max_workers=1) as pool:
        try:
            for n in range(n_slabs):
                t = time.perf_counter()
                z0, occ = next(slabs)
                inside += int(np.count_nonzero(occ))
                timings["fill"] += time.perf_counter() - t
                if pending is not None:
                    # "write": time spent writing, partly overlapping "fill".
                    timings["write"] += pending.result()
                    if progress:
                        progress(n, n_slabs)
                pending = pool.submit(write, z0, occ)
            timings["write"] += pending.result()
        except BaseException:
            if pending is not None:
                pending.cancel()
                try:
                    pending.result()
                except BaseException:
                    pass
            raise
    if progress:
        progress(n_slabs, n_slabs)
    return inside


def convert_to(mesh, path, fmt=None, *, budget=None, jobs=None, progress=None, **options):
    """Voxelise ``mesh`` into ``path`` slab by slab (HDF5 or RAW).

    Parameters
    ----------
    mesh : path, trimesh object or Mesh
    path : str
        Output file (``.h5`` / ``.hdf5`` / ``.raw``).
    budget : float, optional
        Bytes one slab's arrays may take (default ``SLAB_BUDGET``).
    progress : callable, optional
        Called with ``(slab_index, n_slabs)`` after each slab.
    **options
        As for :func:`geovox.voxelize` (resolution, shape, voxel_size,
        bounds, backend, inside, color, diffuse, ambient, density,
        supersample, density_dtype, sdf, band).

    Returns
    -------
    dict with ``shape``, ``spacing``, ``bounds``, ``inside`` (count),
    ``inside_test``, ``backend``, ``slabs``, ``files`` and ``timings``;
    ``filled_in_slabs`` is True where a one-piece occupancy was filled and
    written 64 slices at a time (see :func:`geovox.parity.fill_slabs`).
    """
    from . import formats
    from . import inside as inside_tests
    from .backends import get_backend
    from .parallel import resolve_jobs
    from .volume import Volume

    t0 = time.perf_counter()
    f = formats.format_for(path, fmt)
    if f.name not in STREAMABLE:
        raise ParameterError(f"slab-by-slab output needs .h5, .vtkhdf/.hdf or .raw, not {f.name}")
    formats.check_writable(path)
    jobs = resolve_jobs(jobs)
    m = load_mesh(mesh)
    engine = get_backend(options.pop("backend", "auto"))
    t_load = time.perf_counter()
    grid = make_grid(m.bounds, bounds=options.pop("bounds", None),
                     resolution=options.pop("resolution", None), shape=options.pop("shape", None),
                     voxel_size=options.pop("voxel_size", None))
    method = inside_tests.choose(m, options.pop("inside", "auto"))
    # Said once here; the slabs below are silenced.
    if options.get("color"):
        for problem in m.problems:
            warnings.warn(problem, GeovoxWarning, stacklevel=2)
    if not (np.all(m.bounds[0] <= grid.hi) and np.all(m.bounds[1] >= grid.lo)):
        warnings.warn("the region misses the mesh; the volume is empty", GeovoxWarning, stacklevel=2)
    per = bytes_per_voxel(options.get("color"), options.get("density"), options.get("sdf"))
    per += inside_tests.working_bytes(m, method)
    if budget is None:
        budget = slab_budget()
    plan = slab_plan(grid, per, budget)
    try:
        z0, z1 = plan[0]
        memory.check_memory(Grid(grid.lo, grid.hi, (grid.shape[0], grid.shape[1], z1 - z0)), per)
    except MemoryError:
        nx, ny, nz = grid.shape
        from .errors import GridTooLargeError

        raise GridTooLargeError(
            f"a {nx} x {ny} x {nz} grid does not fit in memory even slab by slab "
            f"({z1 - z0}-voxel slabs need {nx * ny * (z1 - z0) * per / 2**30:.1f} GiB); "
            f"use a smaller resolution") from None
    dens_dtype = options.get("density_dtype", "uint8")
    # The whole grid's facts for headers and attributes; the arrays stand
    # only for presence and dtype (the data comes slab by slab).
    meta = Volume(occupancy=None, grid=grid, backend=engine.name, source=m.source,
                  colors=np.zeros(0, np.uint8) if options.get("color") else None,
                  density=np.zeros(0, dens_dtype) if options.get("density") else None,
                  sdf=np.zeros(0, np.float32) if options.get("sdf") else None)
    from .formats.hdf5 import HDF5Writer
    from .formats.raw import RawWriter

    from .formats.vtkhdf import VTKHDFWriter

    writer = {"hdf5": HDF5Writer, "raw": RawWriter, "vtkhdf": VTKHDFWriter}[f.name](path, meta, jobs)
    inside = 0
    timings = {"load": 0.0, "rays": 0.0, "fill": 0.0, "write": 0.0}
    h = grid.spacing
    reuse = None
    try:
        if (options.get("color") and options.get("color") != "exact" and len(plan) > 1
                and method != "vote"):  # vote casts z itself; exact colour needs no rays
            # Colour wants the crossings along z as well; those rays run
            # through every slab, so they are cast once, for the whole grid,
            # and each slab takes them with depths measured from its own
            # low face (the slab's rays along x and y are its own).
            tz = time.perf_counter()
            z_start = ray_start(m, grid, 2)
            # Sorted once here, so each slab only picks its part.
            z_hits = engine.cast(m, grid.columns(2, start=z_start), jobs=jobs).sorted()
            timings["colour"] = time.perf_counter() - tz

            from .backends.base import Hits

            def along_z(g):
                cols = g.columns(2, start=z_start)
                shift = cols.w0 - float(grid.lo[2])
                # A constant shift keeps the order.
                return Hits(z_hits.ray, z_hits.depth - shift, z_hits.triangle, z_hits.bary,
                            ordered=True), cols

            reuse = {2: along_z}
        if len(plan) == 1 and method == "parity" and not any(
                options.get(k) for k in ("color", "density", "sdf")):
            # Occupancy alone, one piece: the rays along z are cast once for
            # the whole grid (as voxelize casts them, so the file is the same)
            # and the fill runs 64 slices at a time in one reused buffer,
            # each slab written before the next is made (see
            # parity.fill_slabs): no grid-sized array is ever allocated.
            inside = _stream_occupancy(m, grid, engine, writer, jobs, timings, progress)
            plan_left, streamed = [], True
        else:
            plan_left, streamed = plan, False
        for n, (z0, z1) in enumerate(plan_left):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", GeovoxWarning)  # said once, above
                # Several slabs: rays along y, so a slab's columns are its own
                # (x, z) pairs and no ray is cast twice. One piece: voxelize's
                # default axis, so the file equals the in-memory volume.
                vol = voxelize_block(m, grid, (z0, z1), engine=engine, inside=method, jobs=jobs,
                                     axis=1 if len(plan) > 1 else 2, shared_crossings=reuse,
                                     **options)
            tb = time.perf_counter()
            writer.write(z0, vol)
            for key, value in vol.timings.items():
                if key != "total":
                    timings[key] = timings.get(key, 0.0) + value
            timings["write"] += time.perf_counter() - tb
            inside += vol.inside_count
            del vol
            if progress:
                progress(n + 1, len(plan))
        files = writer.close()
        if inside == 0 and np.all(m.bounds[0] <= grid.hi) and np.all(m.bounds[1] >= grid.lo):
            warnings.warn(empty_reason(m, grid, method), GeovoxWarning, stacklevel=2)
    except BaseException:
        writer.abort()
        raise
    timings["load"] += t_load - t0
    timings["total"] = time.perf_counter() - t0
    return {"shape": tuple(grid.shape), "spacing": tuple(float(x) for x in h),
            "bounds": meta.bounds, "inside": inside, "inside_test": method,
            "backend": engine.name, "slabs": len(plan), "files": files, "timings": timings,
            "filled_in_slabs": streamed,
            "grid": grid, "source": m.source}
