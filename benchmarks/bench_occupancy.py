"""Occupancy speed and memory: geovox's backends against Open3D, same run.

Each measurement runs in a fresh interpreter so peak memory is its own.
Times are the best of several runs of ``geovox.voxelize`` on an already
loaded mesh (rays + parity fill; mesh loading excluded, identical for all),
and the first of them on its own: the first call on a mesh also builds what
geovox keeps for the mesh (the Embree scene, the coplanar-triangle check).
Open3D's ``RaycastingScene.compute_occupancy`` gets the same voxel centres
(building the (N^3, 3) float32 query array is not timed; its own BVH is
built inside the timed call, so the fair ratio is against geovox's first
call).
Peak memory is the rise of the process's peak RSS during the call, next to
the size of the uint8 output (N^3 bytes).

Usage: python benchmarks/bench_occupancy.py [--res 128 256 512] [--models spot bunny105k]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import load_model, peak_rss, reset_peak, run_worker  # noqa: E402


def worker(engine, model, res):
    import numpy as np

    import geovox

    mesh = load_model(model)
    repeats = 5 if res <= 256 else 2
    if engine == "open3d":
        import open3d as o3d

        grid = geovox.grid.make_grid(mesh.bounds, resolution=res)
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                            o3d.core.Tensor(mesh.faces.astype(np.uint32)))
        c = [grid.centres(a).astype(np.float32) for a in range(3)]
        pts = np.empty((res, res, res, 3), np.float32)
        pts[..., 0] = c[0][:, None, None]
        pts[..., 1] = c[1][None, :, None]
        pts[..., 2] = c[2][None, None, :]
        pts = o3d.core.Tensor(pts.reshape(-1, 3))
        reset_peak()
        base = peak_rss()
        t0 = time.perf_counter()
        occ = scene.compute_occupancy(pts)
        dt = time.perf_counter() - t0
        inside = int(occ.numpy().sum())
        return {"time": dt, "peak": peak_rss() - base, "inside": inside}
    # Warm up the imports on another mesh, so the first timed call pays only
    # for this mesh.
    geovox.voxelize(load_model("ico1"), resolution=16, backend=engine)
    times = []
    peak = 0
    for _ in range(repeats if res < 1024 else 1):
        reset_peak()
        base = peak_rss()
        t0 = time.perf_counter()
        vol = geovox.voxelize(mesh, resolution=res, backend=engine)
        times.append(time.perf_counter() - t0)
        peak = max(peak, peak_rss() - base)
        inside = vol.inside_count
        del vol
    return {"time": min(times), "first": times[0], "peak": peak, "inside": inside}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--worker", nargs=3)
    p.add_argument("--res", type=int, nargs="+", default=[128, 256, 512])
    p.add_argument("--models", nargs="+", default=["spot", "bunny105k"])
    p.add_argument("--no-open3d", action="store_true")
    p.add_argument("--json", default=None, help="also write the results here")
    args = p.parse_args()
    if args.worker:
        engine, model, res = args.worker
        print(json.dumps(worker(engine, model, int(res))))
        return
    import geovox

    engines = geovox.available_backends()
    try:
        import open3d  # noqa: F401

        if not args.no_open3d:
            engines = engines + ["open3d"]
    except Exception:
        pass
    rows = []
    print(f"# bench_occupancy {datetime.date.today()} engines={engines}")
    print("| model | grid | engine | first call (s) | vs Open3D | best (s) | vs Open3D | peak rise (MiB) "
          "| peak / output | inside |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for model in args.models:
        for res in args.res:
            results = {e: run_worker(__file__, e, model, res) for e in engines}
            o3d = results.get("open3d", {}).get("time")
            out_mib = res**3 / 2**20
            for e, r in results.items():
                if "error" in r:
                    print(f"| {model} | {res}³ | {e} | error: {r['error']} | | | | | | | |")
                    continue
                first = r.get("first", r["time"])
                ours = e != "open3d" and o3d
                r1 = f"{o3d / first:.1f}× faster" if ours else ""
                r2 = f"{o3d / r['time']:.1f}× faster" if ours else ""
                best = f"{r['time']:.3f}" if e != "open3d" else ""
                print(f"| {model} | {res}³ | {e} | {first:.3f} | {r1} | {best} | {r2} | "
                      f"{r['peak'] / 2**20:.0f} | {r['peak'] / 2**20 / out_mib:.2f} | {r['inside']:,} |",
                      flush=True)
                rows.append({"model": model, "res": res, "engine": e, **r})
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
