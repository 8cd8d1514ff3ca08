"""Exact colour's kernel split in two: the nearest-point search alone, and search plus shading.

Issue 27, section 2 asks for spot with exact colour at 256³ in 0.45 s and at
1024³ (to ``.h5``) in 6 s, whole process, on a 2-core machine. This script
measures how much of that the compiled kernel (``geovox/_nearest.pyx``) needs
per inside voxel, in-process, so that the targets can be set against a
floor:

* **search**: the kernel with ``Kernel.raw_output`` (each inside voxel's
  nearest triangle and barycentrics, no colour; it stores 20 bytes a voxel
  where colour stores 4, so the difference below is a lower bound on the
  shading's cost);
* **search + shading**: ``Kernel.colour_output`` (with the constant colours'
  shortcut where a model has them), set as ``--color`` sets it.

The occupancy comes from :func:`geovox.voxelize` first (not timed). The
kernel runs over the whole grid up to 512³ (as a one-piece conversion
does) and above that slab by slab of ``--slab`` layers, as the streamed
conversions run it (the per-triangle tables made once, as there). Reported per size:
inside voxels, wall seconds of each side (best of ``--repeat``), and
nanoseconds of processor time per inside voxel (``time.process_time``, every
thread of this process). The search's answers are the same in both (the
colour is shaded from them).

Usage: python benchmarks/bench_colour_split.py [--res 256 512 1024] [--jobs 2]
       [--repeat 3] [--slab 64]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import SPOT  # noqa: E402


def _timed(fn, repeat):
    """Best wall seconds and the processor seconds of that run."""
    best = None
    for _ in range(repeat):
        w, c = time.perf_counter(), time.process_time()
        fn()
        run = (time.perf_counter() - w, time.process_time() - c)
        if best is None or run[0] < best[0]:
            best = run
    return best


def split(res: int, jobs: int, repeat: int, slab: int) -> dict:
    import geovox
    from geovox.nearest.search import kernel_module, run_kernel
    from geovox.colour.exact import kernel_output
    from geovox.colour.shading import Shading, constant_colours, load_textures, shading_tables

    module = kernel_module()
    if module is None:
        raise SystemExit("the compiled kernel is not built (python setup.py build_ext --inplace)")
    mesh = geovox.load_mesh(SPOT)
    vol = geovox.voxelize(mesh, resolution=res)
    occ = vol.occupancy
    nx, ny, nz = occ.shape
    grid = vol.grid
    load_textures(mesh)
    tables = shading_tables(mesh, Shading())
    key, key_rgba = constant_colours(mesh, Shading())
    cache: dict = {}
    slab = nz if res <= 512 else slab
    blocks = [(z, min(nz, z + slab)) for z in range(0, nz, slab)]
    thick = blocks[0][1] - blocks[0][0]
    tri = np.empty(nx * ny * thick, np.int32)
    uv = np.empty((nx * ny * thick, 2), np.float64)
    rgba = np.empty(nx * ny * thick, np.uint32)

    def run(kind):
        for z0, z1 in blocks:
            n = nx * ny * (z1 - z0)
            if kind == "raw":
                def out(k, n=n):
                    k.raw_output(tri[:n], uv[:n])
            else:
                def out(k, n=n):  # as --color sets it; only inside voxels are written
                    kernel_output(k, rgba[:n], tables, key, key_rgba)
            run_kernel(module, mesh.triangles, occ[:, :, z0:z1], grid.spacing, origin=grid.lo,
                       z0=z0, jobs=jobs, output=out, cache=cache)

    run("raw")  # the tables, the pages of the buffers
    inside = int(occ.sum())
    search = _timed(lambda: run("raw"), repeat)
    colour = _timed(lambda: run("colour"), repeat)
    row = {"res": res, "inside": inside, "jobs": jobs,
           "search_wall_s": round(search[0], 3), "colour_wall_s": round(colour[0], 3),
           "search_cpu_ns_per_voxel": round(1e9 * search[1] / inside, 1),
           "colour_cpu_ns_per_voxel": round(1e9 * colour[1] / inside, 1)}
    row["shading_cpu_ns_per_voxel_at_least"] = round(
        row["colour_cpu_ns_per_voxel"] - row["search_cpu_ns_per_voxel"], 1)
    return row


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--res", type=int, nargs="+", default=[256, 512, 1024])
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--slab", type=int, default=64, help="layers a slab, above 512³")
    args = p.parse_args(argv)
    print(f"load average before: {os.getloadavg()}")
    print("| grid | inside voxels | search wall s | search + shading wall s "
          "| search CPU ns/voxel | search + shading CPU ns/voxel | shading, at least |")
    print("|---|---|---|---|---|---|---|")
    for res in args.res:
        r = split(res, args.jobs, args.repeat, args.slab)
        print(f"| {res}³ | {r['inside']:,} | {r['search_wall_s']:.3f} | {r['colour_wall_s']:.3f} "
              f"| {r['search_cpu_ns_per_voxel']:.0f} | {r['colour_cpu_ns_per_voxel']:.0f} "
              f"| {r['shading_cpu_ns_per_voxel_at_least']:.0f} |", flush=True)
    print(f"load average after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
