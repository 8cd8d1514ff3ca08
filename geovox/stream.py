"""Big grids in bounded memory: convert slab by slab, streaming into the file.

The grid is cut into slabs along z (64 voxels thick, or a multiple, to match
the 64³ HDF5 chunks), each slab is voxelised as a block of the grid
(:func:`geovox.pipeline.voxelize_block`, as the in-memory path is) -- the
rays still start outside the whole mesh, so a slab is classified exactly as
the full grid would be -- and written into its place in the output before
the next one is made. Peak memory is one slab's arrays, whatever the grid.
Colour, density and distance work per slab too: every candidate crossing of
a slab's voxels lies on a ray through that slab.

Streaming writes HDF5 (plain datasets and the VTK-HDF group), RAW (with
its headers and sidecar) and OME-Zarr; other formats need the whole volume
in memory.

``.zarr`` output is always written slab by slab, each slab into its own
shards (:mod:`geovox.formats.zarr`), so the slabs may also be voxelised on
the workers of a Dask cluster (``client=``): one task per slab, the mesh
sent to each worker once, each task writing its own shards, the coarser
pyramid levels made afterwards from the finer ones. Colour takes the
crossings just before and after each voxel along x, y and z
(:mod:`geovox.colour`). A slab casts its own rays along x and y, which lie
wholly within its z range, so those are complete; along z the nearest
crossings of a slab's voxels can lie far above or below it, so the rays
along z are cast once for the whole grid (here, or on the client) and each
slab gets, per column, the crossings inside its z range plus the last one
below and the first one above it (:func:`geovox.colour.relevant_crossings`):
exactly the candidates the whole grid's colour step would use.
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np

from .errors import ParameterError, collect_warnings, warn
from .grid import Grid
from . import memory
from .memory import bytes_per_voxel
from .mesh import load_mesh
from .pipeline import empty_reason, ray_start, voxelize_block

#: Memory a slab's arrays may take, by default: 2048³ occupancy goes in
#: 256-voxel slabs and stays under 3 GiB; occupancy up to 1024³ is one slab.
SLAB_BUDGET = 1 << 30
STREAMABLE = ("hdf5", "raw", "vtkhdf", "zarr")
#: Thickest slab of a local .zarr conversion: at 1024³ four 256-layer slabs
#: took 5.2-6.8 s where one piece took 8.4 s (its 1 GiB array is touched
#: fresh), and 256 layers still write pyramid levels 0-2 in the slab.
LOCAL_ZARR_SLAB = 256
#: Memory one slab task may take on a cluster worker (its occupancy and working arrays).
WORKER_SLAB_BUDGET = 1 << 30


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
    if fmt == "zarr":
        return True  # always slab by slab: each slab writes its own shards
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


def cluster_thick(grid: Grid, per_voxel: float, budget: float = WORKER_SLAB_BUDGET) -> int:
    """Slab thickness for cluster tasks: 64 x a power of two within ``budget``, four slabs at least.

    A power of two lets each slab write its own shards of the first pyramid
    levels too (see :func:`geovox.formats.zarr.in_slab_levels`); four slabs
    or more keep two workers busy.
    """
    nx, ny, nz = grid.shape
    thick = 64
    while (thick * 2 * nx * ny * per_voxel <= budget and thick * 2 * 4 <= nz):
        thick *= 2
    return thick


def z_crossings_of_slab(z_hits, grid: Grid, block, z_start: float):
    """The crossings along z that the colour step of slab ``block`` needs, depths from its low face.

    Parameters
    ----------
    z_hits : Hits
        Crossings of the whole grid's rays along z, sorted (ray, then depth).
    grid : Grid
        The whole grid.
    block : (z0, z1)
    z_start : float
        Where the rays along z start (:func:`geovox.pipeline.ray_start`).

    Returns
    -------
    Hits
        Per column, the crossings inside the slab plus the last one below and
        the first one above it (:func:`geovox.colour.relevant_crossings`),
        ordered.
    """
    from .backends.base import Hits
    from .colour import relevant_crossings
    from .pipeline import block_grid

    g = block_grid(grid, block)
    shift = g.columns(2, start=z_start).w0 - float(grid.lo[2])
    hits = Hits(z_hits.ray, z_hits.depth - shift, z_hits.triangle, z_hits.bary, ordered=True)
    centres = (np.arange(g.shape[2]) + 0.5) * g.spacing[2]
    k = np.searchsorted(centres, hits.depth, side="left")
    return relevant_crossings(hits, k, g.shape[2], g.shape[0] * g.shape[1])


#: The occupancy buffer of each thread's slab tasks, by thread id (see :func:`_zarr_slab`).
_SLAB_BUFFERS: dict = {}


def _release_slab_buffers() -> None:
    """Drop this process's slab buffers (run on each worker when a conversion ends)."""
    _SLAB_BUFFERS.clear()


def _zarr_slab(m, grid, block, layout, options, z_part=None, z_start=None):
    """One cluster task: voxelise slab ``block`` and write it into its own shards.

    Returns ``(inside count, timings)``.
    """
    import os

    from .errors import OutputError
    from .formats.zarr import write_slab

    if not os.path.isdir(layout.root):
        # Shards written here would never reach the output.
        raise OutputError(f"a worker cannot see the output folder {layout.root}: put the .zarr on "
                          f"a file system that the client and every worker share")
    shared = None
    if z_part is not None:
        shared = {2: lambda g: (z_part, g.columns(2, start=z_start))}
    t = time.perf_counter()
    shape = (grid.shape[0], grid.shape[1], block[1] - block[0])
    out = None
    if options.get("inside") == "parity":
        # One occupancy buffer per worker thread, reused by its slabs:
        # faulting 1 GiB in afresh for every slab cost more system time
        # than the fill itself.
        me = threading.get_ident()
        out = _SLAB_BUFFERS.get(me)
        if out is None or out.shape != shape:
            _SLAB_BUFFERS.pop(me, None)
            out = _SLAB_BUFFERS[me] = np.empty(shape, dtype=bool, order="F")
    with collect_warnings(drop=True):  # said once, on the client
        vol = voxelize_block(m, grid, block, jobs=1, shared_crossings=shared, out=out, **options)
    tb = time.perf_counter()
    write_slab(layout, block[0], vol, 1)
    timings = {k: v for k, v in vol.timings.items() if k != "total"}
    timings["write"] = time.perf_counter() - tb
    timings["task"] = time.perf_counter() - t
    return vol.inside_count, timings


def _run_on_cluster(client, m, grid, plan, layout, options, reuse_z, progress, timings) -> int:
    """Submit one :func:`_zarr_slab` task per slab; their inside counts summed, timings added up."""
    from dask.distributed import as_completed

    if options.get("color"):
        from .colour import load_textures

        # Read here, once: the tasks of one worker share its copy of the
        # mesh, and reading textures in each would race on it.
        load_textures(m)
    mesh = client.scatter(m, broadcast=True, hash=False)
    futures = []
    for z0, z1 in plan:
        extra = {}
        if reuse_z is not None:
            z_hits, z_start = reuse_z
            extra = {"z_part": z_crossings_of_slab(z_hits, grid, (z0, z1), z_start),
                     "z_start": z_start}
        futures.append(client.submit(_zarr_slab, mesh, grid, (z0, z1), layout, options,
                                     pure=False, **extra))
    inside = 0
    try:
        for n, future in enumerate(as_completed(futures)):
            count, t = future.result()
            inside += count
            for key, value in t.items():
                timings[key] = timings.get(key, 0.0) + value
            if progress:
                progress(n + 1, len(plan))
    except BaseException:
        client.cancel(futures)
        raise
    finally:
        # A long-lived cluster keeps no slab-sized buffers after the conversion
        # (best effort: a cluster that is failing must not hide the first error).
        try:
            client.run(_release_slab_buffers)
        except Exception:  # noqa: BLE001 - whatever the cluster raises here
            pass
    return inside


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


def _labelled_to(mesh, path, f, jobs, t0, options) -> dict:
    """:func:`convert_to` with labels: made in memory (labels do not stream yet) and written."""
    from . import formats
    from .pipeline import voxelize

    formats.check_labels(True, f)
    formats.check_writable(path)
    vol = voxelize(mesh, jobs=jobs, **options)
    files = formats.write(vol, path, fmt=f.name)
    timings = dict(vol.timings, total=time.perf_counter() - t0)
    return {"shape": vol.shape, "spacing": vol.spacing, "bounds": vol.bounds,
            "inside": vol.inside_count, "inside_test": vol.inside, "backend": vol.backend,
            "slabs": 1, "files": files, "timings": timings, "filled_in_slabs": False,
            "grid": vol.grid, "source": vol.source, "labels": len(vol.label_table) - 1,
            "contested": vol.contested}


def convert_to(mesh, path, fmt=None, *, budget=None, jobs=None, progress=None, client=None,
               slab=None, **options):
    """Voxelise ``mesh`` into ``path`` slab by slab (HDF5, RAW or OME-Zarr).

    Parameters
    ----------
    mesh : str, os.PathLike, trimesh.Trimesh, trimesh.Scene or geovox.mesh.Mesh
        The model, as for :func:`geovox.voxelize`.
    path : str or os.PathLike
        Output file (``.h5`` / ``.hdf5`` / ``.vtkhdf`` / ``.hdf`` / ``.raw``)
        or folder (``.zarr``).
    fmt : str, optional
        Format name instead of the extension (``"hdf5"``, ``"vtkhdf"``,
        ``"raw"``, ``"zarr"``).
    budget : float, optional
        Bytes one slab's arrays may take (default ``SLAB_BUDGET``).
    jobs : int, optional
        Threads (default: one per core); the file is the same for any value.
    progress : callable, optional
        Called with ``(slabs_done, n_slabs)`` after each slab.
    client : dask.distributed.Client, optional
        ``.zarr`` only: voxelise and write each slab as a task on the
        cluster's workers (which must reach ``path``, e.g. a shared file
        system). The result is the same as without.
    slab : int, optional
        ``.zarr`` only: slab thickness in voxels, a multiple of 64 (default:
        from ``budget`` here, :func:`cluster_thick` on a cluster).
    **options
        As for :func:`geovox.voxelize` (resolution, shape, voxel_size, fit,
        bounds, backend, inside, color, diffuse, ambient, density,
        supersample, density_dtype, sdf, band, labels, overlap, fractions,
        references).
        With ``labels`` the volume is made in memory (labels do not stream
        yet) and written to any format that holds labels; the result also
        gives ``labels`` (how many) and ``contested``.

    Returns
    -------
    dict with ``shape``, ``spacing``, ``bounds``, ``inside`` (count),
    ``inside_test``, ``backend``, ``slabs``, ``files`` and ``timings``;
    ``filled_in_slabs`` is True where a one-piece occupancy was filled and
    written 64 slices at a time (see :func:`geovox.parity.fill_slabs`).
    ``shape`` is a tuple of 3 int, ``spacing`` of 3 float, ``bounds`` two
    tuples of 3 float (low and high corners), ``files`` a list of str and
    ``timings`` seconds per stage.

    Raises
    ------
    ParameterError
        A format that cannot be written slab by slab, ``client`` or ``slab``
        without ``.zarr``, a ``slab`` that is not a multiple of 64, or a bad
        option as for :func:`geovox.voxelize`.
    InputNotFoundError, MeshError, BackendUnavailableError
        As for :func:`geovox.voxelize`.
    OutputError
        The output cannot be written (missing folder, no permission, disk
        full; nothing is left behind), or the cluster's workers cannot see
        the output folder.
    GridTooLargeError
        Even one slab would not fit in the available memory.
    """
    from . import formats
    from . import inside as inside_tests
    from .backends import get_backend
    from .parallel import resolve_jobs
    from .volume import Volume

    t0 = time.perf_counter()
    f = formats.format_for(path, fmt)
    if options.get("labels") is not None or options.get("fractions"):
        return _labelled_to(mesh, path, f, jobs, t0, options)
    if f.name not in STREAMABLE:
        raise ParameterError(f"slab-by-slab output needs .h5, .vtkhdf/.hdf, .raw or .zarr, "
                             f"not {f.name}")
    if f.name != "zarr" and (client is not None or slab is not None):
        raise ParameterError(f"`client` and `slab` are for .zarr output, not {f.name}")
    formats.check_writable(path)
    jobs = resolve_jobs(jobs)
    m = load_mesh(mesh, references=options.pop("references", "anywhere"))
    engine = get_backend(options.pop("backend", "auto"))
    t_load = time.perf_counter()
    from .reference import grid_for

    m, grid, used = grid_for(m, options)  # pops the grid options (and like, mesh_space)
    method = inside_tests.choose(m, options.pop("inside", "auto"))
    # Said once here; the slabs below are silenced.
    if options.get("color"):
        for problem in m.problems:
            warn(problem, stacklevel=2)
    if not (np.all(m.bounds[0] <= grid.hi) and np.all(m.bounds[1] >= grid.lo)):
        warn(empty_reason(m, grid, method) if grid.reference is not None else
             "the region misses the mesh; the volume is empty", stacklevel=2)
    per = bytes_per_voxel(options.get("color"), options.get("density"), options.get("sdf"))
    per += inside_tests.working_bytes(m, method)
    if budget is None:
        budget = slab_budget()
    plan = slab_plan(grid, per, budget)
    if f.name == "zarr":
        from .formats.zarr import check_thick

        if slab is None:
            # Here: the budget's slabs in whole chunks, at most LOCAL_ZARR_SLAB;
            # on a cluster: cluster_thick.
            slab = cluster_thick(grid, per) if client is not None else \
                min(LOCAL_ZARR_SLAB, -(-(plan[0][1] - plan[0][0]) // 64) * 64)
        thick = check_thick(slab)
        plan = [(z, min(z + thick, grid.shape[2])) for z in range(0, grid.shape[2], thick)]
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

    if f.name == "zarr":
        from .formats.zarr import ZarrWriter

        writer = ZarrWriter(path, meta, thick, jobs)
    else:
        writer = {"hdf5": HDF5Writer, "raw": RawWriter, "vtkhdf": VTKHDFWriter}[f.name](path, meta,
                                                                                      jobs)
    inside = 0
    timings = {"load": 0.0, "rays": 0.0, "fill": 0.0, "write": 0.0}
    h = grid.spacing
    reuse = None
    pool = pending = None  # exact colour's slab writes on a thread (see below)
    try:
        from .colour import colour_method

        if (colour_method(options.get("color")) == "fast" and len(plan) > 1
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
        axis = 1 if len(plan) > 1 else 2
        if client is not None:
            # The same blocks as below, as tasks; z crossings for colour as above.
            block_options = dict(options, engine=engine.name, inside=method, axis=axis)
            inside = _run_on_cluster(client, m, grid, plan, writer.layout, block_options,
                                     (z_hits, z_start) if reuse else None, progress, timings)
            plan_left, streamed = [], False
        elif f.name != "zarr" and len(plan) == 1 and method == "parity" and not any(
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
        # RAW colours go into their file chunk by chunk as they are made (from
        # the colour step's threads): no slab of colours is held or copied.
        # Not where the OS has no positional write (os.pwrite: Windows).
        to_file = (f.name == "raw" and colour_method(options.get("color")) == "fast"
                   and len(plan_left) > 1 and hasattr(os, "pwrite"))
        buffers = {}
        # Exact colour: a slab is written on a thread while the next one is
        # computed (the kernel runs without the GIL), as the fast colour's
        # chunks are; two occupancy buffers take turns, and a slab's write
        # is finished before its buffer is filled again.
        overlap = (len(plan_left) > 1 and f.name != "zarr"
                   and colour_method(options.get("color")) == "exact")
        if len(plan_left) > 1 and f.name != "zarr":
            # One occupancy and one colour array, reused by every slab:
            # faulting a slab's worth of fresh memory in for each one cost
            # more system time than filling it (the writers are done with
            # a slab when write returns).
            nx, ny, _ = grid.shape
            thick = plan_left[0][1] - plan_left[0][0]
            buffers["out"] = np.empty((nx, ny, thick), dtype=bool, order="F")
            if overlap:
                buffers["out2"] = np.empty((nx, ny, thick), dtype=bool, order="F")
            if colour_method(options.get("color")) == "fast" and not to_file:
                buffers["colour_out"] = np.empty((thick, ny, nx, 4), dtype=np.uint8)
        for n, (z0, z1) in enumerate(plan_left):
            turn = "out2" if overlap and n % 2 else "out"
            slab_arrays = {"out": buffers[turn][:, :, :z1 - z0]} if buffers else {}
            if "colour_out" in buffers:
                slab_arrays["colour_out"] = buffers["colour_out"][:z1 - z0]
            if to_file:
                slab_arrays["colour_sink"] = (
                    lambda z, rgba, z0=z0: writer.write_colours(z0 + z, rgba))
            with collect_warnings(drop=True):  # said once, above
                # Several slabs: rays along y, so a slab's columns are its own
                # (x, z) pairs and no ray is cast twice. One piece: voxelize's
                # default axis, so the file equals the in-memory volume.
                vol = voxelize_block(m, grid, (z0, z1), engine=engine, inside=method, jobs=jobs,
                                     axis=axis, shared_crossings=reuse, **slab_arrays,
                                     **options)
            tb = time.perf_counter()
            if overlap:
                if pending is not None:
                    pending.result()  # the slab before: done (and its error raised)
                if pool is None:
                    from concurrent.futures import ThreadPoolExecutor

                    pool = ThreadPoolExecutor(1)
                pending = pool.submit(writer.write, z0, vol)
            else:
                writer.write(z0, vol)
            for key, value in vol.timings.items():
                if key != "total":
                    timings[key] = timings.get(key, 0.0) + value
            timings["write"] += time.perf_counter() - tb
            inside += vol.inside_count
            del vol
            if progress:
                progress(n + 1, len(plan))
        if pending is not None:
            tb = time.perf_counter()
            pending.result()
            timings["write"] += time.perf_counter() - tb
        files = writer.close(client) if f.name == "zarr" else writer.close()
        if inside == 0 and np.all(m.bounds[0] <= grid.hi) and np.all(m.bounds[1] >= grid.lo):
            warn(empty_reason(m, grid, method), stacklevel=2)
    except BaseException:
        if pool is not None:
            pool.shutdown(wait=True)  # no write may still run into the files abort removes
        writer.abort()
        raise
    finally:
        if pool is not None:
            pool.shutdown(wait=True)
    timings["load"] += t_load - t0
    timings["total"] = time.perf_counter() - t0
    return {"shape": tuple(grid.shape), "spacing": tuple(float(x) for x in h),
            "bounds": meta.bounds, "inside": inside, "inside_test": method,
            "backend": engine.name, "slabs": len(plan), "files": files, "timings": timings,
            "filled_in_slabs": streamed,
            "grid": grid, "source": m.source, "mesh_space": used}
