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
its headers and sidecar), 3D Slicer's ``.seg.nrrd`` and OME-Zarr; other
formats need the whole volume in memory.

Labels and fractions stream too (:class:`LabelTally` sums the label
table's counts and the contested voxels over the slabs; the writers put the
table into their metadata on close). With rays along z each slab takes the
whole grid's rays, so its labels and fractions are the whole grid's bit for
bit (see :func:`geovox.labels.classify` and :func:`geovox.density.coverage`).

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
from .kernels import follows_plan
from . import memory
from .memory import bytes_per_voxel
from .options import Colour, Inside, Options
from .pipeline import Plan, Route, _overlaps, empty_reason, load, plan, ray_start, voxelize_block
from .volume import Progress, Report, Volume

#: Memory a slab's arrays may take, by default: 2048³ occupancy goes in
#: 256-voxel slabs and stays under 3 GiB; occupancy up to 1024³ is one slab.
SLAB_BUDGET = 1 << 30
#: Thickest slab of a local .zarr conversion: at 1024³ four 256-layer slabs
#: took 5.2-6.8 s where one piece took 8.4 s (its 1 GiB array is touched
#: fresh), and 256 layers still write pyramid levels 0-2 in the slab.
LOCAL_ZARR_SLAB = 256
#: Voxels from which a one-piece occupancy is filled and written 64 slices at a
#: time anyway (512³; see :func:`streams_whole`).
WHOLE_STREAM_VOXELS = 1 << 27
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


def streams(grid: Grid, fmt, options: Options, extra=0.0) -> bool:
    """Whether a conversion into format ``fmt`` runs slab by slab (:func:`convert_to`).

    The one rule for the command line and batches (:func:`geovox.plan` with
    ``stream=None`` applies it): a format with a slab writer, and a grid
    that needs several slabs within :func:`slab_budget`, or whose occupancy
    is worth streaming in one piece (:func:`streams_whole`). Either way the
    file is the same as one written from memory.

    Parameters
    ----------
    fmt : geovox.formats.Format or str
        The format, or its name.
    options : Options
        What the conversion makes (its memory per voxel).
    extra : float
        More working bytes per voxel: labels and fractions
        (:func:`geovox.labels.working_bytes`); with them a one-piece grid is
        made in memory.
    """
    from .formats import format_for

    f = format_for("", fmt) if isinstance(fmt, str) else fmt
    if f.slab_writer is None:
        return False
    if f.name == "zarr":
        return True  # always slab by slab: each slab writes its own shards
    blocks = slab_plan(grid, bytes_per_voxel(options) + extra, slab_budget())
    return len(blocks) > 1 or (not extra and streams_whole(grid, options))


def streams_whole(grid: Grid, options: Options | None = None) -> bool:
    """Whether a one-piece conversion to .h5 / .raw is worth streaming anyway.

    Occupancy alone of a grid of 512³ voxels or more: filling and writing
    64 slices at a time skips allocating (and first touching) the whole
    array, which on a 1024³ grid costs 0.2-2.5 s by itself, depending on
    the machine's memory state. ``options``: what is made (default
    occupancy alone).
    """
    alone = options is None or bytes_per_voxel(options) == 1.0  # occupancy: 1 byte a voxel
    return alone and grid.size >= WHOLE_STREAM_VOXELS and grid.shape[2] > 64


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


@follows_plan
def _zarr_slab(m, p: Plan, block, layout, z_part=None, z_start=None):
    """One cluster task: voxelise slab ``block`` of plan ``p`` and write it into its own shards.

    Returns ``(inside count, timings, label counts, approximate voxels)`` (see
    :meth:`LabelTally.of`).
    """
    from .errors import OutputError
    from .formats.zarr import write_slab

    if not os.path.isdir(layout.root):
        # Shards written here would never reach the output.
        raise OutputError(f"a worker cannot see the output folder {layout.root}: put the .zarr on "
                          f"a file system that the client and every worker share")
    buffers = {}
    if z_part is not None:
        buffers["crossings"] = {2: lambda g: (z_part, g.columns(2, start=z_start))}
    t = time.perf_counter()
    shape = (p.grid.shape[0], p.grid.shape[1], block[1] - block[0])
    if p.inside == Inside.PARITY:
        # One occupancy buffer per worker thread, reused by its slabs:
        # faulting 1 GiB in afresh for every slab cost more system time
        # than the fill itself.
        me = threading.get_ident()
        out = _SLAB_BUFFERS.get(me)
        if out is None or out.shape != shape:
            _SLAB_BUFFERS.pop(me, None)
            out = _SLAB_BUFFERS[me] = np.empty(shape, dtype=bool, order="F")
        buffers["out"] = out
    with collect_warnings(drop=True):  # said once, on the client
        vol = voxelize_block(m, p, block, buffers=buffers)
    tb = time.perf_counter()
    write_slab(layout, block[0], vol, 1)
    timings = {k: v for k, v in vol.timings.items() if k != "total"}
    timings["write"] = time.perf_counter() - tb
    timings["task"] = time.perf_counter() - t
    return vol.inside_count, timings, LabelTally.of(vol), vol.approximate


def _run_on_cluster(client, m, p: Plan, layout, reuse_z, progress, timings, tally) -> int:
    """Submit one :func:`_zarr_slab` task per slab; their inside counts summed, timings added up,
    their label counts into ``tally``."""
    from dask.distributed import as_completed

    if p.colour:
        from .colour import load_textures

        # Read here, once: the tasks of one worker share its copy of the
        # mesh, and reading textures in each would race on it.
        load_textures(m)
    mesh = client.scatter(m, broadcast=True, hash=False)
    task = p.for_task()
    futures = []
    for z0, z1 in p.blocks:
        extra = {}
        if reuse_z is not None:
            z_hits, z_start = reuse_z
            extra = {"z_part": z_crossings_of_slab(z_hits, p.grid, (z0, z1), z_start),
                     "z_start": z_start}
        futures.append(client.submit(_zarr_slab, mesh, task, (z0, z1), layout, pure=False,
                                     **extra))
    inside = 0
    try:
        for n, future in enumerate(as_completed(futures)):
            count, t, labelled, approximate = future.result()
            inside += count
            tally.add(labelled)
            tally.approximate += approximate
            for key, value in t.items():
                timings[key] = timings.get(key, 0.0) + value
            if progress:
                progress(Progress("slab", n + 1, len(p.blocks)))
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


def _run_fill(m, p: Plan, writer, timings, progress) -> int:
    """The 64-slice occupancy fill (:attr:`Route.FILL`): each piece written as the next is filled.

    Two buffers: a piece is written (compressed, on the pool's thread) while
    the next one is filled; one write in flight at a time, so a buffer is
    refilled only after its piece has been written (see
    :func:`geovox.pipeline.voxelize_block`'s ``slices``).
    """
    from concurrent.futures import ThreadPoolExecutor

    grid = p.grid
    n_slabs = -(-grid.shape[2] // 64)
    state = {"inside": 0, "n": 0, "pending": None, "wait": 0.0}

    def write(z0, occ):
        t = time.perf_counter()
        # Only the slab's shape and arrays are read by the writers.
        writer.write(z0, Volume(occupancy=occ, grid=Grid(grid.lo, grid.hi, occ.shape),
                                backend=p.backend.name))
        return time.perf_counter() - t

    with ThreadPoolExecutor(max_workers=1) as pool:

        def piece(z0, occ):
            state["inside"] += int(np.count_nonzero(occ))
            if state["pending"] is not None:
                t = time.perf_counter()
                # "write": time spent writing, partly overlapping "fill".
                timings["write"] += state["pending"].result()
                state["wait"] += time.perf_counter() - t
                if progress:
                    progress(Progress("slab", state["n"], n_slabs))
            state["pending"] = pool.submit(write, z0, occ)
            state["n"] += 1

        try:
            vol = voxelize_block(m, p, buffers={"slices": piece})
            timings["write"] += state["pending"].result()
        except BaseException:
            pending = state["pending"]
            if pending is not None:
                pending.cancel()
                try:
                    pending.result()
                except BaseException:
                    pass
            raise
    timings["rays"] += vol.timings["rays"]
    timings["fill"] += vol.timings["fill"] - state["wait"]
    if progress:
        progress(Progress("slab", n_slabs, n_slabs))
    return state["inside"]


def _slab_buffers(p: Plan, two: bool, to_file: bool) -> dict:
    """One occupancy (two where writes overlap) and one colour array (two), reused by every slab.

    Faulting a slab's worth of fresh memory in for each one cost more system
    time than filling it (the writers are done with a slab when write returns;
    where writes overlap, the buffers take turns, see _run_blocks). Exact
    colour's arrays are 4 bytes a voxel: spot at 1024³ faulted 4 GiB in.
    """
    if len(p.blocks) < 2 or p.format.name == "zarr":
        return {}
    nx, ny, _ = p.grid.shape
    out = {"out": np.empty((nx, ny, p.thick), dtype=bool, order="F")}
    if two:
        out["out2"] = np.empty((nx, ny, p.thick), dtype=bool, order="F")
    if p.colour == Colour.FAST and not to_file:
        out["colour_out"] = np.empty((p.thick, ny, nx, 4), dtype=np.uint8)
    elif p.colour == Colour.EXACT:
        for name in ("colour_out", "colour_out2") if two else ("colour_out",):
            out[name] = np.empty((p.thick, ny, nx, 4), dtype=np.uint8)
    return out


def _run_blocks(m, p: Plan, writer, reuse, timings, progress, tally) -> int:
    """The slab route here: each block voxelised, then written into its place."""
    # RAW colours go into their file chunk by chunk as they are made (from
    # the colour step's threads): no slab of colours is held or copied.
    # Not where the OS has no positional write (os.pwrite: Windows).
    several = len(p.blocks) > 1
    to_file = (p.format.name == "raw" and p.colour == Colour.FAST and several
               and hasattr(os, "pwrite"))
    # Exact colour: a slab is written on a thread while the next one is
    # computed (the kernel runs without the GIL), as the fast colour's
    # chunks are; two occupancy buffers take turns, and a slab's write
    # is finished before its buffer is filled again.
    overlap = several and p.format.name != "zarr" and p.colour == Colour.EXACT
    arrays = _slab_buffers(p, overlap, to_file)
    pool = pending = None
    inside = 0
    try:
        for n, (z0, z1) in enumerate(p.blocks):
            turn = "out2" if overlap and n % 2 else "out"
            buffers = {"out": arrays[turn][:, :, :z1 - z0]} if arrays else {}
            if "colour_out" in arrays:
                colour_turn = "colour_out2" if "colour_out2" in arrays and n % 2 else "colour_out"
                buffers["colour_out"] = arrays[colour_turn][:z1 - z0]
            if to_file:
                buffers["colour_sink"] = lambda z, rgba, z0=z0: writer.write_colours(z0 + z, rgba)
            if reuse:
                buffers["crossings"] = reuse
            with collect_warnings(drop=True):  # said once, by run_slabs
                # Several slabs: rays along y, so a slab's columns are its own
                # (x, z) pairs and no ray is cast twice. One piece: voxelize's
                # default axis, so the file equals the in-memory volume.
                vol = voxelize_block(m, p, (z0, z1), buffers=buffers)
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
                timings[key] = timings.get(key, 0.0) + value
            timings["write"] += time.perf_counter() - tb
            inside += vol.inside_count
            tally.add(LabelTally.of(vol))
            tally.approximate += vol.approximate
            del vol
            if progress:
                progress(Progress("slab", n + 1, len(p.blocks)))
        if pending is not None:
            tb = time.perf_counter()
            pending.result()
            timings["write"] += time.perf_counter() - tb
    finally:
        if pool is not None:
            pool.shutdown(wait=True)  # no write may still run into the files abort removes
    return inside


def _z_once(m, p: Plan, timings):
    """Fast colour over several slabs: the rays along z, cast once for the whole grid.

    Those rays run through every slab, so each slab takes them with depths
    measured from its own low face (its rays along x and y are its own).
    Returns ``({2: f(block_grid) -> (Hits, Columns)}, (z_hits, z_start))``.
    """
    from .backends.base import Hits

    grid = p.grid
    tz = time.perf_counter()
    z_start = ray_start(m, grid, 2)
    # Sorted once here, so each slab only picks its part.
    z_hits = p.backend.cast(m, grid.columns(2, start=z_start), jobs=p.jobs).sorted()
    timings["colour"] = time.perf_counter() - tz

    def along_z(g):
        cols = g.columns(2, start=z_start)
        shift = cols.w0 - float(grid.lo[2])
        # A constant shift keeps the order.
        return Hits(z_hits.ray, z_hits.depth - shift, z_hits.triangle, z_hits.bary,
                    ordered=True), cols

    return {2: along_z}, (z_hits, z_start)


class LabelTally:
    """The label table's voxel counts and the contested voxels, summed over the blocks.

    A block equals that part of the whole grid, so the whole grid's counts
    are the sums of the blocks' (and a voxel is contested in one block only).
    ``approximate`` sums the blocks' approximate voxels (with or without labels).
    """

    def __init__(self, p: Plan):
        self.lset = p.labels
        self.counts = None if p.labels is None else np.zeros(len(p.labels.names) + 1, np.int64)
        self.contested = 0
        self.approximate = 0
        self.inside = None  # the inside tests the parts ran (the same in every block)

    @staticmethod
    def of(vol):
        """``(counts, contested, inside)`` of a block's Volume, or None without labels."""
        if vol.label_table is None:
            return None
        return (np.array([e["voxels"] for e in vol.label_table], np.int64), int(vol.contested),
                vol.inside)

    def add(self, labelled) -> None:
        """Count one block's ``of(vol)``."""
        if labelled is None:
            return
        counts, contested, inside = labelled
        self.counts += counts
        self.contested += contested
        self.inside = self.inside or inside

    def table(self, spacing) -> list:
        """The whole grid's label table (:func:`geovox.labels.table`)."""
        from .labels import table

        return table(self.lset, None, spacing, counts=self.counts)


def _meta(m, p: Plan) -> Volume:
    """The whole grid's facts for headers and attributes.

    The arrays stand only for presence and dtype (the data comes slab by
    slab); with labels, ``label_table`` holds the names and colours, its
    counts 0 until every block is made (:func:`run_slabs` sets it then).
    """
    o = p.options
    extra = {}
    if p.labels is not None:
        from .labels import table

        n = len(p.labels.names)
        extra = {"labels": np.zeros((0, 0, 0), p.labels.dtype),
                 "label_table": table(p.labels, None, p.grid.spacing,
                                      counts=np.zeros(n + 1, np.int64))}
        if o.fractions:
            extra["fractions"] = np.zeros((0, 0, 0, n), np.float32 if o.density_dtype ==
                                          "float32" else np.uint8)
    return Volume(occupancy=None, grid=p.grid, backend=p.backend.name, source=m.source,
                  colors=np.zeros(0, np.uint8) if p.colour else None,
                  density=np.zeros(0, o.density_dtype) if o.density else None,
                  sdf=np.zeros(0, np.float32) if o.sdf else None, **extra)


@follows_plan
def run_slabs(m, p: Plan, *, progress=None, client=None) -> Report:
    """Run a streamed plan (slabs, the 64-slice fill or cluster tasks) into its file.

    Parameters
    ----------
    m : geovox.mesh.Mesh
        The loaded mesh the plan was made for.
    p : Plan
        Its route one of :attr:`Route.SLABS`, :attr:`Route.FILL`, :attr:`Route.CLUSTER`.
    progress : callable, optional
        ``progress(Progress("slab", done, total))`` after each slab.
    client : dask.distributed.Client, optional
        For :attr:`Route.CLUSTER`.

    Returns
    -------
    Report
        Without a volume; nothing is left behind on failure.
    """
    t0 = time.perf_counter()
    grid = p.grid
    # Said once here; the slabs are silenced.
    if p.colour:
        for problem in m.problems:
            warn(problem, stacklevel=3)
    if not _overlaps(m.bounds, grid):
        warn("the region misses the mesh; the volume is empty", stacklevel=3)
    meta = _meta(m, p)
    writer = p.writer(meta, client=client)
    timings = {"load": 0.0, "rays": 0.0, "fill": 0.0, "write": 0.0}
    tally = LabelTally(p)
    try:
        reuse, reuse_z = _z_once(m, p, timings) if p.reuse_z else (None, None)
        if p.route == Route.CLUSTER:
            inside = _run_on_cluster(client, m, p, writer.layout, reuse_z, progress, timings,
                                     tally)
        elif p.route == Route.FILL:
            inside = _run_fill(m, p, writer, timings, progress)
        else:
            inside = _run_blocks(m, p, writer, reuse, timings, progress, tally)
        if p.labels is not None:
            # The writers hold `meta`: its table, with the summed counts, goes
            # into the files' metadata as they are closed.
            meta.label_table = tally.table(grid.spacing)
        files = writer.close()
        if inside == 0 and _overlaps(m.bounds, grid):
            warn(empty_reason(m, grid, p.inside), stacklevel=3)
        if tally.approximate:  # the slabs were silenced: said once, for the whole grid
            from .inside.winding import approximate_warning

            warn(approximate_warning(tally.approximate, grid.size), stacklevel=3)
    except BaseException:
        writer.abort()
        raise
    timings["total"] = time.perf_counter() - t0
    labelled = {}
    if p.labels is not None:
        from .pipeline import label_lines

        labelled = dict(label_table=meta.label_table, contested=tally.contested,
                        lines=label_lines(p, meta.label_table, tally.contested))
    return Report(source=m.source, grid=grid, backend=p.backend.name,
                  inside_test=tally.inside or str(p.inside), inside=inside, route=str(p.route),
                  slabs=len(p.blocks), files=files, timings=timings, mesh_space=p.mesh_space,
                  approximate=tally.approximate, **labelled)


def convert_to(mesh, path, fmt=None, *, budget=None, jobs=None, progress=None, client=None,
               slab=None, **options):
    """Voxelise ``mesh`` into ``path`` slab by slab (HDF5, VTK-HDF, RAW or OME-Zarr).

    A plan (:func:`geovox.plan` with ``stream=True``) and its run.

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
        Threads (default: one per core); the files do not depend on it.
    progress : callable, optional
        ``progress(Progress("slab", done, total))`` after each slab.
    client : dask.distributed.Client, optional
        ``.zarr`` only: voxelise and write each slab as a task on the
        cluster's workers (which must reach ``path``, e.g. a shared file
        system). The result is the same as without.
    slab : int, optional
        ``.zarr`` only: slab thickness in voxels, a multiple of 64 (default:
        from ``budget`` here, :func:`cluster_thick` on a cluster).
    **options
        Any field of :class:`geovox.Options` (resolution, shape, voxel_size,
        fit, bounds, backend, inside, color, diffuse, ambient, density,
        supersample, density_dtype, sdf, band, kernel, references); a misspelt one is a
        ParameterError naming the closest.

    Returns
    -------
    Report
        Also read as the dict this returned before: ``shape``, ``spacing``,
        ``bounds``, ``inside`` (count), ``inside_test``, ``backend``,
        ``slabs``, ``files``, ``timings``, ``filled_in_slabs`` (True where a
        one-piece occupancy was filled and written 64 slices at a time, see
        :func:`geovox.parity.fill_slabs`), ``grid``, ``source``, ``mesh_space``,
        ``approximate`` (voxels left to an estimate of the winding number,
        summed over the slabs: see :class:`geovox.volume.Report`);
        with labels also ``labels`` (how many) and ``contested`` (summed over
        the slabs, as is the table's ``label_table``). Labels and fractions
        stream slab by slab like the rest, into .h5, .vtkhdf, .raw,
        .seg.nrrd and .zarr; into the other label formats they are made in
        memory and written whole.

    Raises
    ------
    ParameterError
        A format that cannot be written slab by slab, ``client`` or ``slab``
        without ``.zarr``, a ``slab`` that is not a multiple of 64, or a bad
        option as for :func:`geovox.voxelize` (a misspelt one names the closest).
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

    t0 = time.perf_counter()
    f = formats.format_for(path, fmt)
    labelled = options.get("labels") is not None or options.get("fractions")
    if labelled:
        formats.check_labels(True, f)
    # Labels into a format written whole (.nrrd, NIfTI, .npz, .vox): made in memory.
    if f.slab_writer is None and not labelled:
        raise ParameterError(f"slab-by-slab output needs .h5, .vtkhdf/.hdf, .raw, .seg.nrrd or "
                             f".zarr, not {f.name}")
    if f.name != "zarr" and (client is not None or slab is not None):
        raise ParameterError(f"`client` and `slab` are for .zarr output, not {f.name}")
    o = Options.from_kwargs(jobs=jobs, **options)
    formats.check_writable(path)
    m = load(mesh, o)
    t_load = time.perf_counter()
    p = plan(m, o, path, fmt=fmt, stream=f.slab_writer is not None, cluster=client is not None,
             budget=budget, slab=slab)
    from .pipeline import run

    report = run(m, p, progress=progress, client=client)
    report.timings["load"] = report.timings.get("load", 0.0) + t_load - t0
    report.timings["total"] = time.perf_counter() - t0
    return report
