"""Distance fields: geovox's whole process against OpenVDB, libigl and a previous tree.

Every row is one model at cubic voxels of its longest side / N (``--voxel-size``):

* ``geovox``: a fresh ``python -m geovox convert MODEL -o OUT --voxel-size H --sdf`` (default
  options: band 3, the plan's inside test, threads one per core), end to end, its wall time and
  peak memory (``/usr/bin/time``);
* ``baseline``: the same command run from another tree (``--baseline PATH``, e.g. the previous
  main), in turn with the first, so the pair shares the machine's state;
* ``openvdb``: ``pyopenvdb.FloatGrid.createLevelSetFromPolygons`` (half-width 3, the same voxel
  size) in process, the call alone (no file read or written), in the system Python that has
  Debian's ``python3-openvdb``;
* ``libigl`` (``--band inf`` rows): ``igl.signed_distance`` of 100,000 random points in the grid's
  box, scaled to the grid's voxel count (what a dense grid costs it).

Medians of ``--rounds`` runs (default 3), with the ratios. The machine is shared: compare within a
row.

Models: ``bunny105k`` (closed; see common.load_model), ``spot``, and any mesh file given with
``--model NAME=PATH`` (the 38k-triangle dragon from the wild, say).

Usage::

    python benchmarks/bench_sdf.py --res 256 1024 --baseline ../old-main \\
        --results benchmarks/results/sdf.json
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import ROOT, load_model  # noqa: E402

OPENVDB_PYTHON = os.environ.get("GEOVOX_OPENVDB_PYTHON", "/usr/bin/python3")

OPENVDB_SCRIPT = r"""
import sys, time, json, numpy as np
import pyopenvdb as vdb
z = np.load(sys.argv[1]); h = float(sys.argv[2]); rounds = int(sys.argv[3])
pts = np.asarray(z["v"], np.float32); tri = np.asarray(z["f"], np.int32)
times = []
for _ in range(rounds):
    t = time.perf_counter()
    g = vdb.FloatGrid.createLevelSetFromPolygons(
        pts, triangles=tri, transform=vdb.createLinearTransform(voxelSize=h), halfWidth=3.0)
    times.append(time.perf_counter() - t)
print(json.dumps({"times": times, "active": int(g.activeVoxelCount())}))
"""


def mesh_file(name, path, folder):
    """``(path to convert, (vertices, faces) .npz for OpenVDB, longest side)``."""
    import geovox

    if path is None:
        m = load_model(name)
        import trimesh

        path = os.path.join(folder, name + ".ply")
        trimesh.Trimesh(m.vertices, m.faces, process=False).export(path)
    m = geovox.load_mesh(path)
    npz = os.path.join(folder, name + "_mesh.npz")
    np.savez(npz, v=m.vertices, f=m.faces)
    return path, npz, float(np.ptp(m.vertices, axis=0).max())


def run_cli(root, model, out, h, band):
    """``(seconds, peak MiB, stderr tail)`` of one fresh geovox convert from tree ``root``."""
    env = dict(os.environ, PYTHONPATH=root)
    cmd = ["/usr/bin/time", "-f", "TIME %e %M", sys.executable, "-m", "geovox", "convert",
           model, "-o", out, "--voxel-size", repr(h), "--sdf", "--overwrite", "-q"]
    if band != "3":
        cmd += ["--band", band]
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=root)
    line = [x for x in p.stderr.splitlines() if x.startswith("TIME ")]
    if p.returncode != 0 or not line:
        return None, None, p.stderr.strip().splitlines()[-1:] if p.stderr.strip() else ["failed"]
    _, sec, kb = line[-1].split()
    return float(sec), int(kb) / 1024, []


def openvdb(npz, h, rounds):
    p = subprocess.run([OPENVDB_PYTHON, "-c", OPENVDB_SCRIPT, npz, repr(h), str(rounds)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        return None
    return json.loads(p.stdout.strip().splitlines()[-1])


def libigl_per_point(path, n=100_000, seed=0):
    """Seconds a point of ``igl.signed_distance`` on the mesh, over ``n`` random points in its box."""
    import igl

    import geovox

    m = geovox.load_mesh(path)
    v = np.asarray(m.vertices, float)
    f = np.asarray(m.faces, np.int64)
    rng = np.random.default_rng(seed)
    p = v.min(0) + rng.random((n, 3)) * np.ptp(v, axis=0)
    t = time.perf_counter()
    igl.signed_distance(p, v, f)
    return (time.perf_counter() - t) / n


def voxels(path, h):
    import geovox

    return geovox.plan(geovox.load_mesh(path), dict(voxel_size=h, sdf=True)).grid.size


COLUMNS = ["model", "N", "band", "grid voxels", "geovox (s)", "peak MiB", "previous main (s)",
           "geovox vs previous", "OpenVDB in process (s)", "geovox vs OpenVDB",
           "libigl, estimated (s)", "geovox vs libigl"]


def table_row(row) -> list:
    """One result row as the page's cells (ratios: how many times faster geovox is)."""
    def num(key):
        return f"{row[key]:.2f}" if key in row else ""

    def ratio(key):
        return f"{row[key] / row['geovox_s']:.2f}×" if key in row else ""

    return [row["model"], str(row["N"]), row["band"], f"{row['voxels']:,}", num("geovox_s"),
            f"{row['geovox_peak_mib']:.0f}", num("baseline_s"), ratio("baseline_s"),
            num("openvdb_s"), ratio("openvdb_s"), num("libigl_s_estimate"),
            ratio("libigl_s_estimate")]


def result_file(rows, argv: str, started, load_after) -> dict:
    """The result in the Benchmarks page's form (benchmarks/tables.py)."""
    import platform

    import numpy

    when, load_before = started
    return {
        "benchmark": "sdf",
        "title": "Distance fields against OpenVDB, libigl and the previous main (issue 42)",
        "script": "benchmarks/bench_sdf.py",
        "command": f"python benchmarks/bench_sdf.py {argv}",
        "date": when,
        "machine": (f"the project machine: 2 shared cores, 24 GiB, {platform.machine()}, no GPU; "
                    f"Python {platform.python_version()}, numpy {numpy.__version__}; OpenVDB 10 "
                    f"(Debian's python3-openvdb) in the system Python; load average "
                    f"{load_before:.1f} before, {load_after:.1f} after"),
        "models": ["bunny105k = the corpus's upsampled_bunny_oded.obj midpoint-subdivided once "
                   "(105,568 triangles, closed; benchmarks/common.py)",
                   "spot = data/spot/spot.obj (5,856 triangles, closed)",
                   "dragon38k = models/dragon.ply of github.com/Byleon2361/bsp-tree (37,986 "
                   "triangles, Blender export, 778 open edges: inside by the winding number)"],
        "notes": ("Cubic voxels of the model's longest side / N (--voxel-size), to .vdb. geovox: "
                  "a fresh `python -m geovox convert MODEL -o OUT.vdb --voxel-size H --sdf` "
                  "(band 3 unless inf), whole process, default options; the previous main "
                  "(09a59a2, its NumPy band search) the same command in turn with it. OpenVDB: "
                  "`FloatGrid.createLevelSetFromPolygons` (half-width 3) in process, the call "
                  "alone (no file). libigl: `igl.signed_distance` of 100,000 random points in "
                  "the box, scaled to the grid's voxels. Medians of 3 runs; ratios are how many "
                  "times faster geovox is (below 1: slower). geovox's values are exact "
                  "(tests/test_distance.py); OpenVDB's are not beyond the first voxels."),
        "tables": [{"caption": "Whole process to .vdb, medians", "columns": COLUMNS,
                    "rows": [table_row(r) for r in rows]}],
        "raw": rows,
    }


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--res", type=int, nargs="+", default=[256, 1024])
    ap.add_argument("--models", nargs="+", default=["bunny105k", "spot"])
    ap.add_argument("--model", action="append", default=[], metavar="NAME=PATH")
    ap.add_argument("--baseline", help="another tree to run the same commands from")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--inf", type=int, nargs="*", default=[256],
                    help="resolutions with a --band inf row (and libigl's estimate)")
    ap.add_argument("--results")
    args = ap.parse_args()
    rows = []
    started = (f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d, %H:%M} UTC",
               os.getloadavg()[0])
    folder = tempfile.mkdtemp(prefix="bench_sdf_")
    models = [(n, None) for n in args.models] + [tuple(s.split("=", 1)) for s in args.model]
    print(f"# bench_sdf {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, "
          f"load {os.getloadavg()[0]:.1f}")
    print("| model | N | band | grid voxels | geovox (s) | peak MiB | baseline (s) | "
          "vs baseline | OpenVDB (s) | geovox faster than OpenVDB | libigl est. (s) | "
          "geovox faster than libigl |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, path in models:
        src, npz, longest = mesh_file(name, path, folder)
        for n in args.res:
            h = longest / n
            bands = ["3"] + (["inf"] if n in args.inf else [])
            for band in bands:
                ours, base, peaks = [], [], []
                for _ in range(args.rounds):
                    t, mib, err = run_cli(ROOT, src, os.path.join(folder, "o.vdb"), h, band)
                    if t is None:
                        print(f"| {name} | {n} | {band} | geovox failed: {err} |")
                        break
                    ours.append(t)
                    peaks.append(mib)
                    if args.baseline and band == "3":  # a finite band: the old code has no other
                        t, _, _ = run_cli(os.path.abspath(args.baseline), src,
                                          os.path.join(folder, "b.vdb"), h, band)
                        if t is not None:
                            base.append(t)
                if not ours:
                    continue
                row = {"model": name, "N": n, "band": band, "voxels": voxels(src, h),
                       "geovox_s": statistics.median(ours), "geovox_peak_mib": max(peaks),
                       "geovox_runs": ours}
                if base:
                    row["baseline_s"] = statistics.median(base)
                    row["baseline_runs"] = base
                if band == "3":
                    ov = openvdb(npz, h, args.rounds)
                    if ov is not None:
                        row["openvdb_s"] = statistics.median(ov["times"])
                        row["openvdb_active"] = ov["active"]
                else:
                    row["libigl_s_estimate"] = libigl_per_point(src) * row["voxels"]
                rows.append(row)
                fmt = lambda k: f"{row[k]:.2f}" if k in row else ""  # noqa: E731
                ratio = lambda a, b: (f"{row[b] / row[a]:.2f}x" if a in row and b in row  # noqa
                                      else "")
                print(f"| {name} | {n} | {band} | {row['voxels']:,} | {fmt('geovox_s')} | "
                      f"{row['geovox_peak_mib']:.0f} | {fmt('baseline_s')} | "
                      f"{ratio('geovox_s', 'baseline_s')} | {fmt('openvdb_s')} | "
                      f"{ratio('geovox_s', 'openvdb_s')} | {fmt('libigl_s_estimate')} | "
                      f"{ratio('geovox_s', 'libigl_s_estimate')} |", flush=True)
    if args.results:
        with open(args.results, "w") as f:
            json.dump(result_file(rows, " ".join(sys.argv[1:]), started, os.getloadavg()[0]),
                      f, indent=1, ensure_ascii=False)
            f.write("\n")


if __name__ == "__main__":
    main()
