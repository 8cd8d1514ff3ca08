"""Slabs as tasks on a Dask cluster: one task per slab, each writing its own shards.

Imported only on the cluster route (it imports Dask).
"""

from __future__ import annotations

import os
import threading
import time

import numpy as np
from distributed import WorkerPlugin, as_completed, get_worker

from ..backends.base import Hits
from ..block import BlockBuffers, block_grid, voxelize_block
from ..colour import relevant_crossings
from ..errors import OutputError, collect_warnings
from ..grid import Grid
from ..kernels import follows_plan
from ..labels import LabelTally
from ..options import Inside
from ..planner import Plan
from ..volume import Progress


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
        Where the rays along z start (:func:`geovox.block.ray_start`).

    Returns
    -------
    Hits
        Per column, the crossings inside the slab plus the last one below and
        the first one above it (:func:`geovox.colour.relevant_crossings`),
        ordered.
    """

    g = block_grid(grid, block)
    shift = g.columns(2, start=z_start).w0 - float(grid.lo[2])
    hits = Hits(z_hits.ray, z_hits.depth - shift, z_hits.triangle, z_hits.bary, ordered=True)
    centres = (np.arange(g.shape[2]) + 0.5) * g.spacing[2]
    k = np.searchsorted(centres, hits.depth, side="left")
    return relevant_crossings(hits, k, g.shape[2], g.shape[0] * g.shape[1])


#: The name of the worker plugin that holds the slab tasks' buffers (:class:`SlabBuffers`).
PLUGIN = "geovox-slab-buffers"


class SlabBuffers(WorkerPlugin):
    """A Dask worker plugin: each worker thread's occupancy buffer, reused by its slab tasks.

    Faulting a slab's 1 GiB in afresh for every slab cost more system time
    than the fill itself. The buffers are the worker's, not a module's: the
    run registers the plugin on the cluster when it starts and unregisters
    it when it ends, which drops them (a long-lived cluster keeps nothing).
    """

    name = PLUGIN

    def __init__(self):
        self.by_thread = {}

    def setup(self, worker):
        self.by_thread = {}

    def teardown(self, worker):
        self.by_thread.clear()

    def out(self, shape) -> np.ndarray:
        """This thread's (nx, ny, depth) bool Fortran-ordered buffer, made or remade for ``shape``."""
        me = threading.get_ident()
        out = self.by_thread.get(me)
        if out is None or out.shape != shape:
            self.by_thread.pop(me, None)
            out = self.by_thread[me] = np.empty(shape, dtype=bool, order="F")
        return out


def _worker_buffers():
    """This Dask worker's :class:`SlabBuffers`, or None (not on a worker, or not registered)."""
    try:
        return get_worker().plugins.get(PLUGIN)
    except ValueError:  # not on a worker
        return None


@follows_plan
def slab_task(m, p: Plan, block, layout, z_part=None, z_start=None):
    """One cluster task: voxelise slab ``block`` of plan ``p`` and write it into its own shards.

    Returns ``(inside count, timings, label counts, approximate voxels, surface counts)``
    (see :meth:`LabelTally.of`, :attr:`geovox.volume.Volume.counts`).
    """
    from ..formats.zarr import write_slab

    if not os.path.isdir(layout.root):
        # Shards written here would never reach the output.
        raise OutputError(f"a worker cannot see the output folder {layout.root}: put the .zarr on "
                          f"a file system that the client and every worker share")
    buffers = BlockBuffers()
    if z_part is not None:
        buffers.crossings = {2: lambda g: (z_part, g.columns(2, start=z_start))}
    t = time.perf_counter()
    shape = (p.grid.shape[0], p.grid.shape[1], block[1] - block[0])
    own = _worker_buffers()
    if p.inside == Inside.PARITY and own is not None:
        buffers.out = own.out(shape)
    with collect_warnings(drop=True):  # said once, on the client
        vol = voxelize_block(m, p, block, buffers=buffers)
    tb = time.perf_counter()
    write_slab(layout, block[0], vol, 1)
    timings = {k: v for k, v in vol.timings.items() if k != "total"}
    timings["write"] = time.perf_counter() - tb
    timings["task"] = time.perf_counter() - t
    return vol.inside_count, timings, LabelTally.of(vol), vol.approximate, vol.counts


def run_on_cluster(client, m, p: Plan, layout, reuse_z, progress, timings, tally) -> int:
    """Submit one :func:`slab_task` per slab; their inside counts summed, timings added up,
    their label counts into ``tally``."""
    if p.colour:
        from ..colour import load_textures

        # Read here, once: the tasks of one worker share its copy of the
        # mesh, and reading textures in each would race on it.
        load_textures(m)
    client.register_plugin(SlabBuffers(), name=PLUGIN)
    mesh = client.scatter(m, broadcast=True, hash=False)
    task = p.for_task()
    futures = []
    for z0, z1 in p.blocks:
        extra = {}
        if reuse_z is not None:
            z_hits, z_start = reuse_z
            extra = {"z_part": z_crossings_of_slab(z_hits, p.grid, (z0, z1), z_start),
                     "z_start": z_start}
        futures.append(client.submit(slab_task, mesh, task, (z0, z1), layout, pure=False,
                                     **extra))
    inside = 0
    try:
        for n, future in enumerate(as_completed(futures)):
            count, t, labelled, approximate, counts = future.result()
            inside += count
            tally.add(labelled)
            tally.add_counts(counts)
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
            client.unregister_worker_plugin(PLUGIN)
        except Exception:  # noqa: BLE001 - whatever the cluster raises here
            pass
    return inside


__all__ = ["PLUGIN", "SlabBuffers", "run_on_cluster", "slab_task", "z_crossings_of_slab"]
