"""WebGPU backend against the NumPy backend: stage times per lattice (issue 16).

For every WebGPU adapter found (Vulkan, Metal or DX12; lavapipe on a machine
without a GPU) and every lattice N³, in one process, warm (one untimed call
per lattice first), runs paired rounds, NumPy then WebGPU, and reports the
median of the rounds:

* pairs: the exact pair search. WebGPU: projection, tiles and the device
  search, crossings and their edge values read back. NumPy: its whole cast
  (the scan computes depths for every candidate, so its pairs and depth are
  one step).
* depth: WebGPU only, depth and barycentrics of the crossings on the host
  (``Projection.interpolate``, float64).
* fill: the parity fill (shared code; same hits, so the same work).
* end to end: ``geovox.voxelize(mesh, resolution=N, backend=...)`` with
  default options (one thread per core), loading excluded.

Also reports the cold start (import of wgpu, adapter, device, pipeline, first
dispatch) once, checks that the two backends' volumes are equal, and times the
user's path with the default adapter: paired fresh processes of ``geovox
convert MODEL.obj -o v.h5 -r N -q --backend B`` (the model written to an OBJ
first), wall clock.

Usage: python benchmarks/bench_gpu.py [--model bunny105k] [--sizes 256 512 1024] [--rounds 3]
       [--cli-sizes 512 1024]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from common import load_model  # noqa: E402


def stages_numpy(mesh, columns, grid):
    from geovox import parity
    from geovox.backends import get_backend

    t = time.perf_counter()
    hits = get_backend("numpy").cast(mesh, columns, jobs=2)
    t_cast = time.perf_counter() - t
    t = time.perf_counter()
    parity.fill(hits, columns, grid, jobs=2)
    return {"pairs": t_cast, "depth": None, "fill": time.perf_counter() - t}


def stages_webgpu(mesh, columns, grid):
    from geovox import parity
    from geovox.backends import webgpu
    from geovox.exact import Projection

    t = time.perf_counter()
    proj = Projection(mesh.triangles, columns)
    records = webgpu.search(proj)
    t_pairs = time.perf_counter() - t
    t = time.perf_counter()
    hits = webgpu.to_hits(proj, records, jobs=2)
    t_depth = time.perf_counter() - t
    t = time.perf_counter()
    parity.fill(hits, columns, grid, jobs=2)
    return {"pairs": t_pairs, "depth": t_depth, "fill": time.perf_counter() - t}


def end_to_end(mesh, n, backend):
    import geovox

    t = time.perf_counter()
    vol = geovox.voxelize(mesh, resolution=n, backend=backend)
    return time.perf_counter() - t, vol


def adapter_table(mesh, info, args):
    """The per-stage table on one adapter (already opened in geovox.backends.webgpu)."""
    import geovox  # noqa: F401
    from geovox.grid import make_grid

    print()
    print(f"adapter: {info['device']} ({info['adapter_type']}, {info['backend_type']})")
    print()
    print("| grid | backend | pairs (s) | depth (s) | fill (s) | end to end (s) | crossings | end to end, NumPy / WebGPU |")
    print("|---|---|---|---|---|---|---|---|")
    for n in args.sizes:
        grid = make_grid(mesh.bounds, resolution=n)
        columns = grid.columns(2, start=float(mesh.bounds[0, 2]) - 1e-3 * mesh.scale)
        # Warm-up (allocations, buffer growth), untimed.
        stages_webgpu(mesh, columns, grid)
        stages_numpy(mesh, columns, grid)
        rows = {"numpy": [], "webgpu": []}
        ratios = []
        for _ in range(args.rounds):
            pair = {}
            for backend, fn in (("numpy", stages_numpy), ("webgpu", stages_webgpu)):
                s = fn(mesh, columns, grid)
                s["total"], vol = end_to_end(mesh, n, backend)
                rows[backend].append(s)
                pair[backend] = vol
            a, b = pair["numpy"], pair["webgpu"]
            assert np.array_equal(a.occupancy, b.occupancy), "volumes differ"
            ratios.append(rows["numpy"][-1]["total"] / rows["webgpu"][-1]["total"])
            del pair, a, b, vol
        from geovox.backends import get_backend

        crossings = len(get_backend("webgpu").cast(mesh, columns))
        for backend in ("numpy", "webgpu"):
            med = {k: (None if rows[backend][0][k] is None
                       else statistics.median(r[k] for r in rows[backend]))
                   for k in rows[backend][0]}
            depth = "" if med["depth"] is None else f"{med['depth']:.3f}"
            ratio = f"{statistics.median(ratios):.2f}× (rounds: {', '.join(f'{r:.2f}' for r in ratios)})" \
                if backend == "webgpu" else ""
            print(f"| {n}³ | {backend} | {med['pairs']:.3f} | {depth} | {med['fill']:.3f} | "
                  f"{med['total']:.3f} | {crossings:,} | {ratio} |", flush=True)


def cli_rows(mesh, sizes, rounds):
    """Fresh processes of the CLI, paired: the user's path, cold start included."""
    import subprocess
    import tempfile

    import trimesh

    print()
    print("Fresh CLI processes (the default adapter):")
    print()
    print("| grid | NumPy, CLI end to end (s) | WebGPU, CLI end to end (s) | NumPy / WebGPU |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        obj = os.path.join(tmp, "model.obj")
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(obj)
        for n in sizes:
            times = {"numpy": [], "webgpu": []}
            for _ in range(rounds):
                for backend in times:
                    out = os.path.join(tmp, f"{backend}.h5")
                    t = time.perf_counter()
                    subprocess.run([sys.executable, "-m", "geovox", "convert", obj, "-o", out,
                                    "-r", str(n), "-q", "--overwrite", "--backend", backend],
                                   check=True, stderr=subprocess.DEVNULL)
                    times[backend].append(time.perf_counter() - t)
            ratios = [a / b for a, b in zip(times["numpy"], times["webgpu"])]
            print(f"| {n}³ | {statistics.median(times['numpy']):.2f} | "
                  f"{statistics.median(times['webgpu']):.2f} | {statistics.median(ratios):.2f}× "
                  f"(rounds: {', '.join(f'{r:.2f}' for r in ratios)}) |", flush=True)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--model", default="bunny105k")
    p.add_argument("--sizes", type=int, nargs="+", default=[256, 512, 1024])
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--cli-sizes", type=int, nargs="*", default=[512, 1024],
                   help="lattices for the fresh-process CLI rows (none: skip them)")
    args = p.parse_args(argv)

    t0 = time.perf_counter()
    import wgpu

    from geovox.backends import webgpu

    webgpu.adapter()
    webgpu._device()
    t_cold = time.perf_counter() - t0

    import geovox

    mesh = load_model(args.model)
    # First dispatch, on a small lattice.
    t = time.perf_counter()
    geovox.voxelize(mesh, resolution=16, backend="webgpu")
    t_cold += time.perf_counter() - t
    print(f"model {args.model}, {len(mesh.faces):,} triangles; cold start with the default adapter "
          f"(import wgpu, adapter, device, pipeline, first dispatch): {t_cold:.2f} s")
    # Every adapter but OpenGL ones (the backend never uses those unless told to).
    adapters = [a for a in wgpu.gpu.enumerate_adapters_sync()
                if a.info["backend_type"] != "OpenGL"]
    for a in adapters:
        webgpu._state.clear()
        webgpu._state["adapter"] = a
        webgpu._device()
        geovox.voxelize(mesh, resolution=16, backend="webgpu")
        adapter_table(mesh, a.info, args)
    if args.cli_sizes:
        cli_rows(mesh, args.cli_sizes, args.rounds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
