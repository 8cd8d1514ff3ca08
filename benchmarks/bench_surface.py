"""Surface voxels: geovox's exact kernel against Open3D's, same run, same voxels.

``geovox.surface.surface_voxels`` (every voxel whose half-open box the
surface meets; issue 35) against Open3D's
``VoxelGrid.create_from_triangle_mesh_within_bounds`` on the same grid: a
cube of N³ cubic voxels over the model's longest side at its box's minimum
corner (``make_grid(..., fit="cube")``), Open3D given the same origin and
voxel size. Each measurement runs in a fresh interpreter, so peak memory is
its own; the mesh is loaded and handed over before the clock starts.

* ``first``: geovox's first call, which also pays for the output's pages
  (a fresh N³ bool array is calloc'd; its pages are faulted in as voxels are
  set); ``best``: the best of several calls on a reused output buffer
  (``out=``), the kernel alone.
* Open3D: the best of its calls (one at 1024³).
* ``agree``: voxels in one answer and not the other, as a share of geovox's
  count. Open3D tests closed boxes in floating point, so a surface lying on
  a voxel plane lights both voxels there (the rule lights one); the
  differing voxels are split by an exact rational test
  (tests/surface_reference.py) into ties (the surface meets the voxel's
  closed box but not its half-open one) and the rest.

Models: ``spot`` (data/spot), ``bunny105k`` (benchmarks/common.py),
``cadbox`` (a box with its faces on voxel planes, where the rules differ),
``dragon`` (the Stanford dragon, 100,000 triangles: ``--dragon PATH``, else
``$GEOVOX_DRAGON``, else ``../shared/corpus/dragon/dragon.ply``; bunny105k
stands in where it is missing, and the table says so), and ``bunny1.6m`` and
``dragon1.6m`` (subdivided twice with trimesh, 16x the triangles).

Usage: python benchmarks/bench_surface.py [--models dragon spot bunny105k bunny1.6m]
           [--res 256 1024] [--jobs 1 2] [--dragon PATH] [--no-open3d] [--agreement 128]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import CORPUS, ROOT, load_model, peak_rss, reset_peak, run_worker  # noqa: E402

DRAGON_DEFAULT = os.path.join(CORPUS, "dragon", "dragon.ply")


def dragon_path():
    path = os.environ.get("GEOVOX_DRAGON") or DRAGON_DEFAULT
    return path if os.path.exists(path) else None


def load(name):
    """(Mesh, what it is): a benchmark model; the dragon falls back to bunny105k."""
    import geovox

    # bunny1.6m is bunny105k subdivided twice, dragon1.6m the dragon.
    base = {"bunny1.6m": "bunny105k", "dragon1.6m": "dragon"}.get(name, name)
    what = base
    if base == "cadbox":
        # A box whose faces lie on voxel planes of the cube grids (1/128 of
        # its longest side and finer): the rules differ there, at ties.
        import trimesh

        box = trimesh.creation.box(bounds=[(0, 0, 0), (1, 0.5, 0.75)])
        v, f = box.vertices, box.faces
        for _ in range(5):
            v, f = trimesh.remesh.subdivide(v, f)
        return geovox.Mesh(v, f, source="cadbox"), "CAD box on voxel planes"
    if base == "dragon":
        path = dragon_path()
        if path is None:
            base, what = "bunny105k", "bunny105k (no dragon here)"
            mesh = load_model(base)
        else:
            mesh = geovox.load_mesh(path)
    else:
        mesh = load_model(base)
    if name.endswith("1.6m"):
        import trimesh

        v, f = mesh.vertices, mesh.faces
        for _ in range(2):
            v, f = trimesh.remesh.subdivide(v, f)
        mesh = geovox.Mesh(v, f, source=name)
        what += " ×16"
    return mesh, what


def grid_for(mesh, res):
    from geovox.grid import make_grid

    return make_grid(mesh.bounds, resolution=res, fit="cube")


def worker(engine, model, res, jobs):
    import numpy as np

    mesh, what = load(model)
    grid = grid_for(mesh, res)
    repeats = 5 if res <= 256 else 2
    if engine == "open3d":
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                      o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
        times, peak = [], 0
        for _ in range(repeats if res < 1024 else 1):
            reset_peak()
            base = peak_rss()
            t0 = time.perf_counter()
            vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(
                m, float(grid.spacing[0]), grid.lo, grid.hi)
            times.append(time.perf_counter() - t0)
            peak = max(peak, peak_rss() - base)
            count = len(vg.get_voxels()) if _ == 0 else count
            del vg
        return {"what": what, "tris": len(mesh.faces), "time": min(times), "peak": peak,
                "count": count}
    from geovox.surface import surface_voxels

    tris = np.ascontiguousarray(mesh.triangles)
    surface_voxels(tris[:1], grid_for(mesh, 4))  # imports, and the kernel's module
    reset_peak()
    base = peak_rss()
    t0 = time.perf_counter()
    out = surface_voxels(tris, grid, jobs=jobs)
    first = time.perf_counter() - t0
    peak = peak_rss() - base
    count = int(np.count_nonzero(out))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        surface_voxels(tris, grid, jobs=jobs, out=out)
        times.append(time.perf_counter() - t0)
    return {"what": what, "tris": len(tris), "first": first, "time": min(times), "peak": peak,
            "count": count}


def agreement(model, res):
    """geovox against Open3D on one grid: counts, differences, and how many are ties."""
    import numpy as np
    import open3d as o3d

    from geovox.surface import surface_voxels

    mesh, what = load(model)
    grid = grid_for(mesh, res)
    ours = surface_voxels(np.ascontiguousarray(mesh.triangles), grid)
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                  o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
    vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(
        m, float(grid.spacing[0]), grid.lo, grid.hi)
    idx = np.array([v.grid_index for v in vg.get_voxels()], dtype=np.int64).reshape(-1, 3)
    inside = ((idx >= 0) & (idx < np.asarray(grid.shape))).all(axis=1)
    theirs = np.zeros(grid.shape, dtype=bool)
    theirs[tuple(idx[inside].T)] = True
    only_ours = np.argwhere(ours & ~theirs)
    only_theirs = np.argwhere(theirs & ~ours)
    # The exact test is slow in Fractions: beyond 400 differing voxels, a
    # sample of 400 is classified and the count scaled (marked "~").
    differ = np.concatenate([only_ours, only_theirs])
    sample = differ
    if len(sample) > 400:
        sample = sample[np.random.default_rng(0).choice(len(sample), 400, replace=False)]
    ties = _ties(mesh.triangles, grid, sample) * len(differ) / max(len(sample), 1)
    return {"what": what, "ours": int(ours.sum()), "theirs": int(theirs.sum()),
            "outside": int((~inside).sum()), "only_ours": len(only_ours),
            "only_theirs": len(only_theirs), "ties": round(ties),
            "sampled": len(sample) < len(differ)}


def _ties(triangles, grid, voxels):
    """How many of ``voxels`` are ties: the surface meets their closed box, never their interior.

    There the two rules may differ (Open3D tests closed boxes in floating
    point, from the voxel holding each triangle's lowest corner); anywhere
    else, a differing voxel is one of them missing the surface, or lighting
    a voxel it does not reach.
    """
    import numpy as np

    sys.path.insert(0, os.path.join(ROOT, "tests"))
    from fractions import Fraction

    from surface_reference import clipped, touches_only

    lo, h = grid.lo, grid.spacing
    tmin, tmax = triangles.min(axis=1), triangles.max(axis=1)
    ties = 0
    for v in voxels:
        blo, bhi = lo + v * h, lo + (v + 1) * h
        near = np.flatnonzero((tmax >= blo).all(axis=1) & (tmin <= bhi).all(axis=1))
        box_lo = [Fraction(float(x)) for x in blo]
        box_hi = [Fraction(float(x)) for x in bhi]
        tris = [[[Fraction(float(x)) for x in p] for p in triangles[t]] for t in near]
        touching = [t for t in tris if clipped(t, box_lo, box_hi)]
        ties += bool(touching) and all(touches_only(t, box_lo, box_hi) for t in touching)
    return ties


def loadavg():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--worker", nargs=4)
    p.add_argument("--models", nargs="+", default=["dragon", "spot", "bunny105k", "bunny1.6m"])
    p.add_argument("--res", type=int, nargs="+", default=[256, 1024])
    p.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    p.add_argument("--dragon", default=None, help="the Stanford dragon (PLY/OBJ)")
    p.add_argument("--no-open3d", action="store_true")
    p.add_argument("--agreement", type=int, nargs="*", default=[128],
                   help="grids on which to compare the voxels with Open3D's (none: skip)")
    p.add_argument("--json", default=None, help="also write the results here")
    args = p.parse_args()
    if args.dragon:
        os.environ["GEOVOX_DRAGON"] = os.path.abspath(args.dragon)
    if args.worker:
        engine, model, res, jobs = args.worker
        print(json.dumps(worker(engine, model, int(res), int(jobs))))
        return
    try:
        import open3d  # noqa: F401

        have_o3d = not args.no_open3d
    except ImportError:
        have_o3d = False
    print(f"# bench_surface {datetime.date.today()}: load average {loadavg()} (before), "
          f"{os.cpu_count()} CPUs, Open3D {'yes' if have_o3d else 'no'}, "
          f"dragon {dragon_path() or 'missing: bunny105k stands in'}")
    print()
    print("| model | triangles | grid | engine | jobs | first (s) | best (s) | vs Open3D "
          "| peak rise (MiB) | output (MiB) | voxels |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for model in args.models:
        for res in args.res:
            if model.endswith("1.6m") and res > 256:
                continue  # the target for 1.6M triangles is at 256³
            o3d = run_worker(__file__, "open3d", model, res, 1) if have_o3d else {}
            results = [("geovox", j, run_worker(__file__, "geovox", model, res, j)) for j in args.jobs]
            if have_o3d:
                results.append(("open3d", 1, o3d))
            for engine, jobs, r in results:
                if "error" in r:
                    print(f"| {model} | | {res}³ | {engine} | {jobs} | error: {r['error']} "
                          "| | | | | |", flush=True)
                    continue
                ratio = (f"{o3d['time'] / r['time']:.1f}× faster"
                         if engine == "geovox" and "time" in o3d else "")
                first = f"{r['first']:.3f}" if "first" in r else ""
                print(f"| {r['what']} | {r['tris']:,} | {res}³ | {engine} | {jobs} | {first} | "
                      f"{r['time']:.3f} | {ratio} | {r['peak'] / 2**20:.0f} | {res**3 / 2**20:.0f} | "
                      f"{r['count']:,} |", flush=True)
                rows.append({"model": model, "res": res, "engine": engine, "jobs": jobs, **r})
    if have_o3d and args.agreement:
        print()
        print("| model | grid | geovox voxels | Open3D voxels (outside the grid) | only geovox "
              "| only Open3D | of which ties | differing, not ties |")
        print("|---|---|---|---|---|---|---|---|")
        for model in args.models:
            if model.endswith("1.6m"):
                continue
            for res in args.agreement:
                a = agreement(model, res)
                rest = a["only_ours"] + a["only_theirs"] - a["ties"]
                print(f"| {a['what']} | {res}³ | {a['ours']:,} | {a['theirs']:,} ({a['outside']:,}) | "
                      f"{a['only_ours']:,} | {a['only_theirs']:,} | {'~' * a['sampled']}{a['ties']:,} | "
                      f"{rest:,} "
                      f"({100 * rest / max(a['ours'], 1):.3f} %) |", flush=True)
                rows.append({"model": model, "res": res, "agreement": a})
    print()
    print(f"load average {loadavg()} (after)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
