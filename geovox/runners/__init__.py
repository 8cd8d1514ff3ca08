"""The runners: a plan's route carried out, block by block, into its file.

| module | runs |
|---|---|
| :mod:`geovox.runners` | :func:`run`: the in-memory route, and the slab routes' frame (:func:`run_slabs`) |
| :mod:`geovox.runners.slabs` | slabs here, and the 64-slice fill |
| :mod:`geovox.runners.on_cluster` | slabs as tasks on a Dask cluster (imported only there) |


:func:`run` takes a :class:`~geovox.planner.Plan` and runs its route:

* in memory: one block, the whole grid, written whole where there is a path;
* slabs: the grid cut into slabs along z, each voxelised as a block of the
  grid (:func:`geovox.block.voxelize_block`, as the in-memory path is) and
  written into its place in the output before the next one is made. Peak
  memory is one slab's arrays, whatever the grid. Colour, density, distance
  and labels work per slab too: every candidate crossing of a slab's voxels
  lies on a ray through that slab;
* the 64-slice fill: occupancy alone in one piece, its rays cast once and
  its parity filled and written 64 slices at a time in two reused buffers;
* cluster tasks: the slabs of a chunked format (``.zarr``) voxelised on the
  workers of a Dask cluster, one task per slab, the mesh sent to each worker
  once, each task writing its own shards, the coarser pyramid levels made
  afterwards from the finer ones.

Fast colour takes the crossings just before and after each voxel along x, y
and z (:mod:`geovox.colour.fast`). A slab casts its own rays along x and y,
which lie wholly within its z range, so those are complete; along z the
nearest crossings of a slab's voxels can lie far above or below it, so the
rays along z are cast once for the whole grid (here, or on the client) and
each slab gets, per column, the crossings inside its z range plus the last
one below and the first one above it
(:func:`geovox.colour.relevant_crossings`): exactly the candidates the whole
grid's colour step would use.

Every decision (the route, the slab sizes, whether colours go to the file
chunk by chunk, whether a slab is written while the next is made, which
arrays are reused) is the plan's; the runners only carry them out.
"""

from __future__ import annotations

import time

import numpy as np

from ..block import BlockBuffers, empty_reason, overlaps, voxelize_block
from ..errors import warn
from ..kernels import follows_plan
from ..labels import LabelTally
from ..options import Occupancy, sdf_of
from ..planner import Plan, Route
from ..volume import Report
from .slabs import run_blocks, run_fill, z_once


@follows_plan
def run(mesh, p: Plan, *, progress=None, client=None, write_options=None) -> Report:
    """Run plan ``p`` on ``mesh`` (the loaded Mesh it was made for): one Report.

    In memory: one block, written whole where the plan has a path; any other
    route runs slab by slab (:func:`run_slabs`).

    Parameters
    ----------
    mesh : geovox.mesh.Mesh
        The loaded mesh the plan was made for.
    p : Plan
    progress : callable, optional
        ``progress(Progress(...))`` as stages start, and after each slab.
    client : dask.distributed.Client, optional
        For :attr:`Route.CLUSTER`.
    write_options : dict, optional
        The writer's own keywords (``shell`` for ``.vox``, ``pack_bits`` for ``.npz``).
    """
    mesh = p.mesh_for(mesh)
    if p.route != Route.MEMORY:
        return run_slabs(mesh, p, progress=progress, client=client)
    vol = voxelize_block(mesh, p, buffers=BlockBuffers(progress=progress))
    vol.mesh_space = p.mesh_space
    if not vol.occupancy.any():
        warn(empty_reason(mesh, p.grid, vol.inside), stacklevel=3)
    files, t = [], vol.timings
    if p.path is not None:
        from .. import formats

        tw = time.perf_counter()
        files = formats.write(vol, p.path, fmt=p.format.name, **(write_options or {}))
        t["write"] = time.perf_counter() - tw
    lines = [] if vol.label_table is None else p.labels.lines(vol.label_table, vol.contested)
    return Report(source=mesh.source, grid=p.grid, backend=p.backend.name,
                  inside_test=vol.inside, inside=vol.inside_count, route=str(p.route),
                  slabs=1, volume=vol, files=files, timings=t, mesh_space=p.mesh_space,
                  lines=lines, approximate=vol.approximate, counts=vol.counts)


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
    if not overlaps(m.bounds, grid):
        warn("the region misses the mesh; the volume is empty", stacklevel=3)
    meta = _meta(m, p)
    writer = p.writer(meta, client=client)
    timings = {"load": 0.0, "rays": 0.0, "fill": 0.0, "write": 0.0}
    tally = LabelTally(p.labels)
    try:
        reuse, reuse_z = z_once(m, p, timings) if p.reuse_z else (None, None)
        if p.route == Route.CLUSTER:
            from .on_cluster import run_on_cluster  # imports Dask

            inside = run_on_cluster(client, m, p, writer.layout, reuse_z, progress, timings,
                                    tally)
        elif p.route == Route.FILL:
            inside = run_fill(m, p, writer, timings, progress)
        else:
            inside = run_blocks(m, p, writer, reuse, timings, progress, tally)
        if p.labels is not None:
            # The writers hold `meta`: its table, with the summed counts, goes
            # into the files' metadata as they are closed.
            meta.label_table = tally.table(grid.spacing)
        files = writer.close()
        if inside == 0 and overlaps(m.bounds, grid):
            warn(empty_reason(m, grid, p.inside), stacklevel=3)
        if tally.approximate:  # the slabs were silenced: said once, for the whole grid
            from ..inside import approximate_warning

            warn(approximate_warning(tally.approximate, grid.size), stacklevel=3)
    except BaseException:
        writer.abort()
        raise
    timings["total"] = time.perf_counter() - t0
    labelled = {}
    if p.labels is not None:
        labelled = dict(label_table=meta.label_table, contested=tally.contested,
                        lines=p.labels.lines(meta.label_table, tally.contested))
    return Report(source=m.source, grid=grid, backend=p.backend.name,
                  inside_test=tally.inside or _what_ran(p), inside=inside, route=str(p.route),
                  slabs=len(p.blocks), files=files, timings=timings, mesh_space=p.mesh_space,
                  approximate=tally.approximate, counts=tally.counts_of_surface, **labelled)


def _what_ran(p: Plan) -> str:
    """The inside test (and the surface voxels) the plan's blocks run, as a Report says it."""
    if p.inside is None:
        return "surface"
    return f"{p.inside}+surface" if p.occupancy == Occupancy.BOTH else str(p.inside)


def _meta(m, p: Plan):
    """The whole grid's layout for the writers (:class:`geovox.formats.base.Meta`).

    With labels, ``label_table`` holds the names and colours, its counts 0
    until every block is made (:func:`run_slabs` sets it then).
    """
    from ..formats.base import Meta

    o = p.options
    fields = {}
    if o.density:
        fields["density"] = np.dtype(o.density_dtype)
    if o.sdf:
        fields["sdf"] = np.dtype(np.float32)
    fractions = label_table = None
    if p.labels is not None:
        labelled = p.labels.meta(p.grid)
        fields["labels"] = labelled["labels"]
        label_table, fractions = labelled["label_table"], labelled["fractions"]
    return Meta(grid=p.grid, backend=p.backend.name, source=m.source, colors=bool(p.colour),
                fields=fields, fractions=fractions, label_table=label_table,
                mesh_space=p.mesh_space, band=float(o.band) if o.sdf else None,
                unsigned=sdf_of(o.sdf) == "unsigned")




__all__ = ["run", "run_slabs"]
