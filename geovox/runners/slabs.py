"""Slabs here: each block voxelised, then written into its place; and the 64-slice fill."""

from __future__ import annotations

import time

import numpy as np

from ..block import BlockBuffers, voxelize_block
from ..errors import collect_warnings
from ..grid import Grid
from ..labels import LabelTally
from ..options import Colour, Occupancy
from ..planner import Plan
from ..volume import Progress, Volume


class SlabArrays:
    """The arrays every slab of a run reuses, handed out in turn (the plan says which exist).

    One occupancy (two where a slab is written while the next is made), one
    surface array (two where it is the occupancy so written), one colour
    array (two), one distance array (two), or with surface voxels written as points one buffer of
    bits, reused by every slab: faulting a slab's worth of fresh memory in
    for each one cost more system time than filling it (exact colour's
    arrays are 4 bytes a voxel: spot at 1024³ faulted 4 GiB in). A slab's
    write is finished before its arrays are handed out again.
    """

    def __init__(self, p: Plan):
        self.arrays = {}
        self.layer = int(p.grid.shape[0]) * int(p.grid.shape[1])
        if not p.reuse_buffers:
            return
        nx, ny, _ = p.grid.shape
        if p.surface_points:
            from ..surface import word_count

            # All zero, and left so by every slab (surface_points).
            self.arrays["words"] = [np.zeros(word_count((nx, ny, p.thick)), dtype=np.uint64)]
            return
        turns = 2 if p.write_behind else 1
        self.arrays["out"] = [np.empty((nx, ny, p.thick), dtype=bool, order="F")
                              for _ in range(turns)]
        if p.occupancy != Occupancy.SOLID and (p.labels is None or not p.labels.by_parts):
            # Surface alone is the occupancy written (behind, with exact colour); both, ORed in.
            surface_turns = turns if p.occupancy == Occupancy.SURFACE else 1
            self.arrays["surface_out"] = [np.empty((nx, ny, p.thick), dtype=bool, order="F")
                                          for _ in range(surface_turns)]
        if p.options.sdf:
            self.arrays["sdf_out"] = [np.empty(nx * ny * p.thick, dtype=np.float32)
                                      for _ in range(turns)]
        if p.colour == Colour.EXACT or (p.colour == Colour.FAST and not p.colour_sink):
            colour_turns = turns if p.colour == Colour.EXACT else 1
            self.arrays["colour_out"] = [np.empty((p.thick, ny, nx, 4), dtype=np.uint8)
                                         for _ in range(colour_turns)]

    def buffers(self, n: int, depth: int) -> BlockBuffers:
        """The arrays of the ``n``-th slab, ``depth`` layers thick."""
        b = BlockBuffers()
        for name in ("out", "surface_out"):
            if name in self.arrays:
                outs = self.arrays[name]
                setattr(b, name, outs[n % len(outs)][:, :, :depth])
        if "words" in self.arrays:
            b.words = self.arrays["words"][0]
        if "sdf_out" in self.arrays:
            outs = self.arrays["sdf_out"]
            b.sdf_out = outs[n % len(outs)][:self.layer * depth]
        if "colour_out" in self.arrays:
            cols = self.arrays["colour_out"]
            b.colour_out = cols[n % len(cols)][:depth]
        return b


def run_blocks(m, p: Plan, writer, reuse, timings, progress, tally) -> int:
    """The slab route here: each block voxelised, then written into its place."""
    arrays = SlabArrays(p)
    pool = pending = None
    inside = 0
    try:
        for n, (z0, z1) in enumerate(p.blocks):
            buffers = arrays.buffers(n, z1 - z0)
            if p.colour_sink:
                buffers.colour_sink = lambda z, rgba, z0=z0: writer.write_colours(z0 + z, rgba)
            if reuse:
                buffers.crossings = reuse
            if p.surface_points:
                buffers.points = _points_into(writer, z0, z1, timings)
                buffers.point_values = writer.centres
            with collect_warnings(drop=True):  # said once, by run_slabs
                vol = voxelize_block(m, p, (z0, z1), buffers=buffers)
            tb = time.perf_counter()
            if vol.occupancy is None:
                pass  # its points are written
            elif p.write_behind:
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
            inside += vol.counts["surface"] if vol.occupancy is None else vol.inside_count
            if p.occupancy != Occupancy.SOLID and p.labels is None:
                tally.inside = tally.inside or vol.inside  # what ran, for the summary
            tally.add(LabelTally.of(vol))
            tally.add_counts(vol.counts)
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


def _points_into(writer, z0, z1, timings):
    """The block's ``points`` hand-off: its voxels written as they come, timed as writing."""
    def points(ijk):
        t = time.perf_counter()
        writer.write_points(z0, z1 - z0, ijk)
        timings["write"] += time.perf_counter() - t

    return points


def run_fill(m, p: Plan, writer, timings, progress) -> int:
    """The 64-slice occupancy fill (:attr:`Route.FILL`): each piece written as the next is filled.

    Two buffers: a piece is written (compressed, on the pool's thread) while
    the next one is filled; one write in flight at a time, so a buffer is
    refilled only after its piece has been written (see
    :class:`geovox.block.BlockBuffers`' ``slices``).
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
            vol = voxelize_block(m, p, buffers=BlockBuffers(slices=piece))
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


def z_once(m, p: Plan, timings):
    """Fast colour over several slabs: the rays along z, cast once for the whole grid.

    Those rays run through every slab, so each slab takes them with depths
    measured from its own low face (its rays along x and y are its own).
    Returns ``({2: f(block_grid) -> (Hits, Columns)}, (z_hits, z_start))``.
    """
    from ..backends.base import Hits
    from ..block import ray_start

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


__all__ = ["SlabArrays", "run_blocks", "run_fill", "z_once"]
