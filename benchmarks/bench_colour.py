"""Colour: accuracy against a brute-force nearest point, and end-to-end times.

Accuracy (``--accuracy``): for each corpus model with colour, every inside
voxel of a 64³ grid (the whole volume, not a sample) is coloured by both
methods -- ``color="fast"`` (the nearest of the six axis crossings, the
default until 2026-11-30) and ``color="exact"`` (the exact nearest surface
point, the default since) -- and
compared with a brute-force reference: the closest point over *every*
triangle (:func:`geovox.nearest.search.brute_force`, no pruning), its barycentrics,
UVs, bilinear texel x Kd. Per model: the share of inside voxels within 2
levels per channel, and the median and 90th percentile of the largest
per-channel error.

Times (``--times``): wall clock of a fresh interpreter running ``geovox
convert data/spot/spot.obj -o spot.raw -r N --color`` (or ``--fast-color``)
(imports, OBJ and texture loading, rays, fill, colour, writing the RAW + RGBA
RAW files; ``--h5 N`` writes ``spot.h5`` instead at those sizes, slab by
slab), best of ``--repeat`` runs; peak memory is the process's peak RSS
(VmHWM, what ``/usr/bin/time -v`` reports as maximum resident set size), and
CPU time the child's user + system seconds. ``--kernel numpy`` times exact
colour without the compiled kernel (``GEOVOX_KERNEL=numpy``, what an install
without a C compiler runs).

Paired (``--vs DIR [DIR ...]``): the same conversions by this checkout (A)
and by each other checkout's CLI (B, run from that folder), in turn A B A B
... ``--repeat`` times (at every size, 1024³ included); printed are each
side's median wall clock and the median of the pair-by-pair ratios A/B,
which stays meaningful on a machine whose speed drifts (a loaded one). The
runs write the same files; ``--keep DIR`` leaves the last run's outputs of
each side there (``a_*``, ``b<i>_*``), to compare them byte for byte.

Usage: python benchmarks/bench_colour.py [--accuracy] [--times] [--res 128 256]
       [--h5 1024] [--methods color fast-color] [--repeat 3] [--kernel auto|numpy]
       [--vs ../base ../prev] [--keep DIR]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import CORPUS, SPOT  # noqa: E402

#: Corpus models with colour: texture (spot, fuze), materials (cornell_box,
#: suzanne), a texture on a tetrahedron (trimesh's test file).
MODELS = {
    "spot": SPOT,
    "fuze": os.path.join(CORPUS, "fuze", "fuze.obj"),
    "suzanne": os.path.join(CORPUS, "suzanne", "suzanne.obj"),
    "cornell_box": os.path.join(CORPUS, "cornell_box", "cornell_box.obj"),
    "textured_tetrahedron": os.path.join(CORPUS, "trimesh_edge_cases", "textured_tetrahedron.obj"),
}

CHILD = """
import sys, json
from geovox.cli import main
rc = main(sys.argv[1:])
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]
print(json.dumps({"rc": rc, "peak_kib": int(hwm)}))
"""


def accuracy(path, res=64):
    """Errors of both methods against the brute-force reference, over every inside voxel."""
    import geovox
    from geovox.colour import load_textures, shade
    from geovox.nearest.search import brute_force, prepare

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        before = geovox.voxelize(path, resolution=res, color="fast")
        t0 = time.perf_counter()
        after = geovox.voxelize(path, resolution=res, color="exact")
        t_exact = time.perf_counter() - t0
    mesh = geovox.load_mesh(path)
    load_textures(mesh)
    g = after.grid
    idx = np.argwhere(after.occupancy)
    pts = (idx + 0.5) * g.spacing  # the frame nearest_inside uses: relative to grid.lo
    t0 = time.perf_counter()
    tri, uv = brute_force(pts, prepare(mesh.triangles, g.lo), float(g.spacing.min()))
    t_brute = time.perf_counter() - t0
    ref = np.rint(shade(mesh, tri, uv) * 255)
    out = {"inside": len(idx), "exact_s": t_exact, "brute_s": t_brute}
    for name, vol in (("before", before), ("after", after)):
        err = np.abs(vol.colors[tuple(idx.T)][:, :3].astype(int) - ref).max(axis=1)
        out[name] = (float(np.mean(err <= 2)), float(np.median(err)), float(np.percentile(err, 90)))
    return out


def run(res, flag, out_dir, ext="raw", kernel="auto", cwd=None, prefix=""):
    """One fresh interpreter converting spot (from ``cwd``: that checkout's geovox)."""
    out = os.path.join(out_dir, f"{prefix}spot_{res}.{ext}")
    args = ["convert", SPOT, "-o", out, "-r", str(res), f"--{flag}", "-q", "--overwrite"]
    env = dict(os.environ, GEOVOX_KERNEL=kernel)
    t0 = time.perf_counter()
    before = os.times()
    p = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True,
                       env=env, cwd=cwd)
    wall = time.perf_counter() - t0
    after = os.times()
    cpu = (after.children_user - before.children_user
           + after.children_system - before.children_system)
    if p.returncode != 0:
        return {"error": p.stderr.strip().splitlines()[-1]}
    info = json.loads(p.stdout.strip().splitlines()[-1])
    if not prefix:
        for f in os.listdir(out_dir):
            os.remove(os.path.join(out_dir, f))
    return {"wall": wall, "cpu": cpu, "peak": info["peak_kib"] * 1024}


def paired(args, jobs):
    """A (this checkout) against each ``--vs`` checkout, in turn: medians and pair ratios."""
    import statistics

    here = os.path.dirname(HERE)
    print(f"# bench_colour --vs {date_and_load()}")
    print("| grid | output | option | checkout | median wall (s) | median CPU (s) "
          "| median of the pair ratios A/B | pairs |")
    print("|---|---|---|---|---|---|---|---|")
    keep = args.keep or tempfile.mkdtemp()
    os.makedirs(keep, exist_ok=True)
    for res, ext in jobs:
        for flag in args.methods:
            for i, other in enumerate(args.vs):
                a, b = [], []
                for _ in range(args.repeat):
                    a.append(run(res, flag, keep, ext, args.kernel, here, "a_"))
                    b.append(run(res, flag, keep, ext, args.kernel, os.path.abspath(other),
                                 f"b{i}_"))
                bad = [r["error"] for r in a + b if "error" in r]
                if bad:
                    print(f"| {res}³ | .{ext} | --{flag} | {other} | error: {bad[0]} | | | |")
                    continue
                ratio = statistics.median(x["wall"] / y["wall"] for x, y in zip(a, b))
                for name, rs in (("A (this)", a), (other, b)):
                    print(f"| {res}³ | .{ext} | --{flag} | {name} "
                          f"| {statistics.median(r['wall'] for r in rs):.2f} "
                          f"| {statistics.median(r['cpu'] for r in rs):.2f} "
                          f"| {ratio:.3f} | {len(a)} |", flush=True)
    print(f"# end: {date_and_load()}")


def date_and_load():
    return (f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, load average "
            f"{os.getloadavg()[0]:.1f}")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--accuracy", action="store_true")
    p.add_argument("--times", action="store_true")
    p.add_argument("--models", nargs="+", default=list(MODELS))
    p.add_argument("--grid", type=int, default=64, help="accuracy grid (default 64)")
    p.add_argument("--res", type=int, nargs="*", default=[128, 256])
    p.add_argument("--h5", type=int, nargs="*", default=[], help="sizes written to .h5")
    p.add_argument("--methods", nargs="+", default=["color", "fast-color"])
    p.add_argument("--kernel", default="auto", choices=["auto", "numpy"])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--vs", nargs="+", default=[], metavar="DIR",
                   help="paired runs against these checkouts' CLIs")
    p.add_argument("--keep", help="with --vs: folder keeping the last outputs of each side")
    args = p.parse_args()
    if args.vs:
        paired(args, [(r, "raw") for r in args.res] + [(r, "h5") for r in args.h5])
        return
    if not (args.accuracy or args.times):
        args.times = True
    today = datetime.date.today()
    if args.accuracy:
        print(f"# bench_colour --accuracy {today}: every inside voxel at {args.grid}³")
        print("| model | inside voxels | within 2 levels, before | after | median error, before "
              "| after | 90th percentile, before | after | exact colour step (s) | brute force (s) |")
        print("|---|---|---|---|---|---|---|---|---|---|")
        for name in args.models:
            r = accuracy(MODELS[name], args.grid)
            b, a = r["before"], r["after"]
            print(f"| {name} | {r['inside']:,} | {100 * b[0]:.2f} % | {100 * a[0]:.2f} % "
                  f"| {b[1]:.0f} | {a[1]:.0f} | {b[2]:.0f} | {a[2]:.0f} | {r['exact_s']:.2f} "
                  f"| {r['brute_s']:.1f} |", flush=True)
    if args.times:
        print(f"# bench_colour --times {today}, kernel {args.kernel}, load average "
              f"{os.getloadavg()[0]:.1f} at the start")
        print("| model | grid | output | option | end to end (s), best of runs "
              "| CPU (s), that run | peak RSS (MiB) |")
        print("|---|---|---|---|---|---|---|")
        jobs = [(r, "raw") for r in args.res] + [(r, "h5") for r in args.h5]
        with tempfile.TemporaryDirectory() as tmp:
            for res, ext in jobs:
                for flag in args.methods:
                    n = args.repeat if res <= 256 else 1
                    runs = [run(res, flag, tmp, ext, args.kernel) for _ in range(n)]
                    ok = [r for r in runs if "error" not in r]
                    if not ok:
                        print(f"| spot | {res}³ | .{ext} | --{flag} | error: {runs[0]['error']} "
                              f"| | |")
                        continue
                    best = min(ok, key=lambda r: r["wall"])
                    peak = max(r["peak"] for r in ok)
                    print(f"| spot | {res}³ | .{ext} | --{flag} | {best['wall']:.2f} "
                          f"| {best['cpu']:.2f} | {peak / 2**20:.0f} |", flush=True)


if __name__ == "__main__":
    main()
