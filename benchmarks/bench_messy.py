"""Messy models, whole process (issue 27): this checkout against a baseline checkout and libigl.

Each case is ``geovox convert MODEL -r N -o out.npy`` with default options in
a fresh interpreter, run from this checkout (A) and from a baseline checkout
(B, ``--baseline DIR``: today's main, built), in turn (A B A B ...), so that a
drifting load hits both alike; the ratio A/B is taken pair by pair. Wall
seconds from a monotonic clock around each child, processor seconds (user +
system) from the operating system's accounting of the finished child
(``resource.getrusage(RUSAGE_CHILDREN)`` before and after). Medians are
quoted. After the pairs, libigl's ``fast_winding_number``
(``benchmarks/libigl_winding.py``: the mesh as read, not repaired) on the
same grid, the same number of runs.

Beside the times: the voxels on which A and B differ, and whether either
warned that voxels were approximate (left to an estimate of the winding
number). Where they differ, the brute-force winding number of the repaired
mesh (every triangle's solid angle summed exactly at the voxel centre)
says which is right.

``--hashes`` (issue 37): instead, every messy model of the corpus and the
tests (``HASH_MODELS``: open, double-sided, non-manifold, inner walls, the
truck) at every grid of ``--grids`` (64, 128, 256), converted once by each
side, and the SHA-256 of the two outputs compared; where they differ, the
differing voxels are counted and decided by the brute force as above.

Usage: python benchmarks/bench_messy.py --baseline /path/to/main [--runs 3]
       [--cases truck.obj:64,truck.obj:128,...] [--write benchmarks/results/messy.json]
       [--igl-max 128]  (libigl only up to 128³: at 256³ it takes minutes a run)
       python benchmarks/bench_messy.py --baseline /path/to/main --hashes [--grids 64,128,256]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DATA = os.path.join(ROOT, "tests", "data")
CASES = ["wild/truck.obj:64", "wild/truck.obj:128", "suzanne/suzanne.obj:128",
         "cornell_box/cornell_box.obj:128"]
#: The shared corpus (stanford_bunny/bunny.obj, the open scan, is there only).
CORPUS = os.path.join(ROOT, "..", "shared", "corpus")
#: --hashes: messy models (under tests/data, or the corpus where marked), each
#: decided by the winding number of a repaired copy (or, the cornell box, of
#: overlapping closed parts).
HASH_MODELS = ["suzanne/suzanne.obj", "corpus:stanford_bunny/bunny.obj",
               "trimesh_edge_cases/wallhole.obj", "cornell_box/cornell_box.obj",
               "trimesh_edge_cases/rabbit.obj", "wild/truck.obj", "wild/pyramids.3mf",
               "trimesh_edge_cases/quadknot.obj", "trimesh_edge_cases/joined_tetrahedra.obj",
               "trimesh_edge_cases/two_objects.obj", "trimesh_edge_cases/box.obj"]


def timed(cmd, cwd):
    """(wall s, cpu s, stderr) of one child run to completion."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed: {p.stderr.strip()}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, p.stderr


def brute_force(path, res, idx):
    """The repaired mesh's winding number > 1/2 at the voxels ``idx`` ((k, 3)) of the N³ grid."""
    sys.path.insert(0, ROOT)
    import geovox
    from geovox import inside

    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        m = geovox.load_mesh(path)
        grid = geovox.voxelize(m, resolution=res, inside="parity").grid
        tris = inside.target(m)[0].triangles
    p = np.stack([grid.centres(a)[idx[:, a]] for a in range(3)], axis=1)
    return np.array([inside.captree.triangle_angles(tris, np.repeat(q[None], len(tris), 0)).sum() > 0.5
                     for q in p], bool)


def case(path, res, baseline, runs, tmp, igl_max=None):
    """One row: medians for A, B and libigl, the pair ratios, and the voxel comparison.

    libigl runs only up to ``igl_max`` voxels a side (None: always): at 256³ it takes minutes a run.
    """
    py = sys.executable
    outs = {k: os.path.join(tmp, f"{k}.npy") for k in ("a", "b", "igl")}
    a_cmd = [py, "-m", "geovox", "convert", path, "-r", str(res), "-o", outs["a"]]
    b_cmd = [py, "-m", "geovox", "convert", path, "-r", str(res), "-o", outs["b"]]
    got = {"a": [], "b": [], "igl": []}
    err = {}
    for _ in range(runs):
        for k, cmd, cwd in (("a", a_cmd, ROOT), ("b", b_cmd, baseline)):
            wall, cpu, err[k] = timed(cmd, cwd)
            got[k].append((wall, cpu))
    igl_cmd = [py, os.path.join(HERE, "libigl_winding.py"), path, str(res), outs["igl"]]
    igl = igl_max is None or res <= igl_max
    for _ in range(runs if igl else 0):
        got["igl"].append(timed(igl_cmd, ROOT)[:2])
    a, b = np.load(outs["a"]), np.load(outs["b"])
    row = {"model": os.path.relpath(path, ROOT), "grid": res, "runs": runs}
    for k in got:
        if got[k]:
            row[f"{k}_wall"] = statistics.median(w for w, _ in got[k])
            row[f"{k}_cpu"] = statistics.median(c for _, c in got[k])
    row["ratio_wall"] = statistics.median(x[0] / y[0] for x, y in zip(got["a"], got["b"]))
    row["ratio_cpu"] = statistics.median(x[1] / y[1] for x, y in zip(got["a"], got["b"]))
    row["approximate_a"] = "approximate" in err["a"]
    row["approximate_b"] = "approximate" in err["b"]
    idx = np.argwhere(a != b)
    row["differ"] = len(idx)
    if len(idx):
        bf = brute_force(path, res, idx)
        row["a_agrees"] = int(np.sum(a[tuple(idx.T)] == bf))
        row["b_agrees"] = int(np.sum(b[tuple(idx.T)] == bf))
    row["inside_a"] = int(a.sum())
    if igl:
        row["inside_igl"] = int(np.load(outs["igl"]).sum())
    return row


def hashes(baseline, grids, tmp):
    """``--hashes``: every HASH_MODELS model at every grid, once by each side; rows of the comparison."""
    import hashlib

    rows = []
    py = sys.executable
    for rel in HASH_MODELS:
        path = os.path.join(CORPUS, rel[7:]) if rel.startswith("corpus:") else os.path.join(DATA, rel)
        for res in grids:
            outs = {k: os.path.join(tmp, f"{k}.npy") for k in ("a", "b")}
            said = {}
            for k, cwd in (("a", ROOT), ("b", baseline)):
                said[k] = timed([py, "-m", "geovox", "convert", path, "-r", str(res), "-o", outs[k]],
                                cwd)[2]
            digest = {k: hashlib.sha256(open(outs[k], "rb").read()).hexdigest() for k in outs}
            a, b = np.load(outs["a"]), np.load(outs["b"])
            row = {"model": rel, "grid": res, "same": digest["a"] == digest["b"],
                   "inside": int(a.sum()), "approximate": ["approximate" in said[k] for k in "ab"]}
            idx = np.argwhere(a != b)
            if len(idx):
                bf = brute_force(path, res, idx)
                row.update(differ=len(idx), a_agrees=int(np.sum(a[tuple(idx.T)] == bf)),
                           b_agrees=int(np.sum(b[tuple(idx.T)] == bf)))
            rows.append(row)
            print(json.dumps(row), flush=True)
    return rows


def table(rows):
    """The result file's table: one row per case."""
    out = []
    for r in rows:
        diff = f"{r['differ']:,}"
        if r["differ"]:
            diff += f" (brute force agrees with this branch on {r['a_agrees']:,}, main on {r['b_agrees']:,})"
        approx = f"{'yes' if r['approximate_b'] else 'no'} / {'yes' if r['approximate_a'] else 'no'}"
        out.append([r["model"].split("/")[-1], f"{r['grid']}³",
                    f"{r['b_wall']:.2f} / {r['b_cpu']:.2f}", f"{r['a_wall']:.2f} / {r['a_cpu']:.2f}",
                    f"{r['ratio_wall']:.2f}, {r['ratio_cpu']:.2f}",
                    f"{r['igl_wall']:.2f} / {r['igl_cpu']:.2f}" if "igl_wall" in r else "not run",
                    diff, approx])
    return out


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--baseline", required=True, help="a built checkout of the baseline (B)")
    p.add_argument("--runs", type=int, default=3)
    p.add_argument("--cases", default=",".join(CASES), help="MODEL:N,... (MODEL under tests/data)")
    p.add_argument("--write", help="write the result file here")
    p.add_argument("--igl-max", type=int, help="run libigl only up to this grid (default: every grid)")
    p.add_argument("--hashes", action="store_true",
                   help="compare the outputs' SHA-256 over HASH_MODELS at --grids instead")
    p.add_argument("--grids", default="64,128,256")
    args = p.parse_args(argv)
    if args.hashes:
        print(f"load average before: {os.getloadavg()}")
        with tempfile.TemporaryDirectory(prefix="bench_messy_") as tmp:
            rows = hashes(os.path.abspath(args.baseline), [int(g) for g in args.grids.split(",")],
                          tmp)
        same = sum(r["same"] for r in rows)
        print(f"{same} of {len(rows)} outputs byte-identical to the baseline's; "
              f"approximate voxels in {sum(any(r['approximate']) for r in rows)}")
        return
    rows = []
    load0 = os.getloadavg()[0]
    started = datetime.datetime.now(datetime.timezone.utc)
    with tempfile.TemporaryDirectory(prefix="bench_messy_") as tmp:
        for c in args.cases.split(","):
            rel, res = c.rsplit(":", 1)
            rows.append(case(os.path.join(DATA, rel), int(res), os.path.abspath(args.baseline),
                             args.runs, tmp, args.igl_max))
            print(json.dumps(rows[-1]), flush=True)
    load1 = os.getloadavg()[0]
    result = {
        "benchmark": "messy",
        "title": "Messy models, whole process (issue 27)",
        "script": "benchmarks/bench_messy.py",
        "command": f"python benchmarks/bench_messy.py --baseline MAIN --runs {args.runs} "
                   f"--cases {args.cases}" + (f" --igl-max {args.igl_max}" if args.igl_max else ""),
        "date": f"{started:%Y-%m-%d %H:%M} UTC",
        "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}; "
                   f"shared: load average {load0:.1f} at the start, {load1:.1f} at the end",
        "notes": "geovox convert MODEL -r N -o out.npy, default options, a fresh process each run; this "
                 "branch and main in turn, ratios pair by pair, medians. libigl: fast_winding_number on "
                 "the same grid, the mesh as read (not repaired). Wall and processor (user + system) "
                 "seconds; on a loaded machine the processor time is the better guide. "
                 + ("PYTHONDONTWRITEBYTECODE set: both sides compile their sources each run."
                    if os.environ.get("PYTHONDONTWRITEBYTECODE") else
                    "PYTHONDONTWRITEBYTECODE unset: both sides run from their .pyc files."),
        "tables": [{"caption": "Whole process: main, this branch, libigl",
                    "columns": ["model", "grid", "main wall / cpu (s)", "branch wall / cpu (s)",
                                "ratio (wall, cpu)", "libigl wall / cpu (s)",
                                "voxels that differ from main", "approximate voxels, main / branch"],
                    "rows": table(rows)}],
        "raw": rows,
    }
    if args.write:
        with open(args.write, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1, ensure_ascii=False)
            f.write("\n")
    print(json.dumps(result["tables"], ensure_ascii=False))


if __name__ == "__main__":
    main()
