"""The winding number's work budget on every model we have (issue 27, item 1's budget).

Every mesh file of the corpus (``/work/shared/corpus`` or ``--corpus``), of
``tests/data/wild`` and of trimesh's ``models/`` folder (``--trimesh``: a
folder, or a bare git mirror whose ``HEAD:models`` is read with ``git
archive``), with default options at 64³, 128³ and 256³ (``--res``). For each
model, in a fresh process with a time-out: ``geovox.plan`` says its inside
test; a model whose test is the winding number of an open (repaired, capped)
copy is voxelised (in memory, no file), and the report's ``approximate``
count (voxels left to an estimate of the caps' winding number because the
work budget, ``WORK_SECONDS`` of processor time, ran out) is recorded with the
compiled kernel's counts (voxels refined alone, summed exactly) and the
processor time of the conversion. Only such a model can have approximate
voxels: parity, vote and the winding number of a closed copy are exact
integers from the rays, so those are listed with their test and not run.

Usage: python benchmarks/bench_budget.py [--res 64,128,256] [--timeout 900]
       [--only SUBSTRING] [--write benchmarks/results/budget.json]
       [--from-log RUN.log --date ... --machine ...]   # the tables again from a run's output
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import platform
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
MESH_EXT = (".obj", ".off", ".ply", ".stl", ".glb", ".gltf", ".3mf", ".dae")
TRIMESH_MIRROR = "/work/.mirror/mikedh+trimesh/repo"

# Runs in the child: one model, every resolution; prints one JSON line.
CHILD = r"""
import json, sys, time, warnings
import geovox
from geovox.errors import GeovoxError, GeovoxWarning
from geovox.inside import captree, winding
from geovox.planner import as_options, load, plan  # noqa: E402
from geovox.runners import run  # noqa: E402

path, res = sys.argv[1], [int(r) for r in sys.argv[2].split(",")]
out = {"rows": []}
warnings.simplefilter("ignore")
try:
    mesh = load(path, as_options())
except (GeovoxError, ValueError, OSError) as exc:
    print(json.dumps({"error": str(exc).splitlines()[0][:120]}))
    sys.exit(0)
for n in res:
    row = {"res": n}
    try:
        p = plan(mesh, as_options(resolution=n))
        row["inside"] = str(p.inside)
        capped = (row["inside"] == "winding" and len(winding.target(mesh)[0].faces)
                  and len(winding.bridged(winding.target(mesh)[0])[1]) > 0)
        row["caps"] = int(len(winding.bridged(winding.target(mesh)[0])[1])) if capped else 0
        if capped:
            captree.STATS.clear()
            t, c = time.perf_counter(), time.process_time()
            report = run(mesh, p)
            row.update(wall=time.perf_counter() - t, cpu=time.process_time() - c,
                       approximate=report.approximate, voxels=int(report.grid.size),
                       refined=captree.STATS.get("refined"), exact=captree.STATS.get("exact"))
    except GeovoxError as exc:
        row["error"] = str(exc).splitlines()[0][:120]
    out["rows"].append(row)
print(json.dumps(out))
"""


def models(corpus, trimesh_models):
    """Every mesh file: (label, path), sorted within each source."""
    found = []
    for label, folder in (("corpus", corpus), ("wild", os.path.join(ROOT, "tests", "data", "wild")),
                          ("trimesh", trimesh_models)):
        if not folder or not os.path.isdir(folder):
            continue
        for base, dirs, files in os.walk(folder):
            dirs.sort()
            for f in sorted(files):
                if f.lower().endswith(MESH_EXT):
                    p = os.path.join(base, f)
                    found.append((f"{label}/{os.path.relpath(p, folder)}", p))
    return found


def trimesh_folder(spec, tmp):
    """trimesh's models folder: ``spec`` itself, or extracted from a bare mirror into ``tmp``."""
    if spec and os.path.isdir(os.path.join(spec, "models")) and not spec.endswith("repo"):
        return os.path.join(spec, "models")
    if spec and os.path.isdir(spec) and os.path.exists(os.path.join(spec, "HEAD")):
        archive = subprocess.run(["git", f"--git-dir={spec}", "archive", "HEAD", "models"],
                                 capture_output=True, check=True).stdout
        subprocess.run(["tar", "-x", "-C", tmp], input=archive, check=True)
        return os.path.join(tmp, "models")
    return spec if spec and os.path.isdir(spec) else None


def measure(path, res, timeout):
    """The child's JSON for one model (or an error / time-out)."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    try:
        p = subprocess.run([sys.executable, "-c", CHILD, path, ",".join(map(str, res))],
                           capture_output=True, text=True, timeout=timeout, env=env, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"error": f"time-out ({timeout} s)"}
    lines = [x for x in p.stdout.splitlines() if x.startswith("{")]
    if p.returncode or not lines:
        return {"error": (p.stderr.strip().splitlines() or ["exit %d" % p.returncode])[-1][:120]}
    return json.loads(lines[-1])


def cell(row):
    """``approximate`` cell of one (model, resolution)."""
    if "error" in row:
        return "error: " + row["error"]
    if row.get("inside") != "winding" or not row.get("caps"):
        return "–"
    return f"{row['approximate']:,}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", default="/work/shared/corpus")
    ap.add_argument("--trimesh", default=TRIMESH_MIRROR)
    ap.add_argument("--res", default="64,128,256")
    ap.add_argument("--timeout", type=float, default=900)
    ap.add_argument("--only", default="")
    ap.add_argument("--write", default=None)
    ap.add_argument("--from-log", default=None, help="remake the tables from a run's printed lines")
    ap.add_argument("--date", default=None, help="with --from-log: the run's date")
    ap.add_argument("--machine", default=None, help="with --from-log: the run's machine line")
    args = ap.parse_args(argv)
    res = [int(r) for r in args.res.split(",")]
    load0 = os.getloadavg()[0]
    started = datetime.datetime.now(datetime.timezone.utc)
    if args.from_log:  # the tables again from a run's printed lines
        results = []
        with open(args.from_log, encoding="utf-8") as f:
            for line in f:
                label, sep, rest = line.partition(": {")
                if sep and not line.startswith(" "):
                    results.append((label, json.loads("{" + rest.rsplit(" (", 1)[0])))
        todo = results
    else:
        with tempfile.TemporaryDirectory() as tmp:
            todo = [m for m in models(args.corpus, trimesh_folder(args.trimesh, tmp))
                    if args.only in m[0]]
            results = []
            for label, path in todo:
                t = time.perf_counter()
                got = measure(path, res, args.timeout)
                results.append((label, got))
                print(f"{label}: {json.dumps(got)} ({time.perf_counter() - t:.1f} s)", flush=True)
    capped_rows, others = [], {}
    for label, got in results:
        if "error" in got:
            why = got["error"].split(": ", 1)[-1].split(" (")[0].split(";")[0]
            others.setdefault("not read: " + why[:50], []).append(label)
            continue
        rows = got["rows"]
        if any(r.get("caps") for r in rows):
            by = {r["res"]: r for r in rows}
            capped_rows.append([label, f"{max(r.get('caps', 0) for r in rows):,}"]
                               + [cell(by[n]) for n in res]
                               + [" / ".join(f"{by[n]['cpu']:.1f}" if "cpu" in by[n] else "–"
                                             for n in res),
                                  " / ".join(f"{by[n].get('refined') or 0:,}/{by[n].get('exact') or 0:,}"
                                             if "cpu" in by[n] else "–" for n in res)])
        else:
            tests = sorted({"winding (of a closed copy: exact)" if r.get("inside") == "winding"
                            else r.get("inside", "error") for r in rows})
            others.setdefault("+".join(tests), []).append(label)
    total = sum(1 for _, g in results if "error" not in g)
    approx = sum(1 for r in capped_rows if any(c not in ("0", "–") for c in r[2:2 + len(res)]))
    out = {
        "benchmark": "budget",
        "title": "The winding number's work budget on every model (issue 27)",
        "script": "benchmarks/bench_budget.py",
        "command": "python benchmarks/bench_budget.py" + (f" --res {args.res}" if args.res != "64,128,256" else ""),
        "date": args.date or started.strftime("%Y-%m-%d %H:%M UTC"),
        "machine": args.machine or (
            f"{os.cpu_count()} cores, {platform.machine()}, Python {platform.python_version()}; "
            f"shared: load average {load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end"),
        "notes": (f"{len(todo)} mesh files (the corpus, tests/data/wild, trimesh's models/), "
                  f"{total} read; default options (compiled kernels), at "
                  f"{', '.join(f'{n}³' for n in res)}. Only the winding number of an open, "
                  f"capped copy can leave a voxel to an estimate (parity, vote and a closed copy's "
                  f"winding number are exact integers from the rays): those "
                  f"{len(capped_rows)} models were voxelised and every one is listed; the rest are "
                  f"counted by inside test below. Approximate: voxels left to the estimate because "
                  f"the work budget (WORK_SECONDS, 10 s of processor time) ran out "
                  f"(Report.approximate); {approx} of the {len(capped_rows)} models had any. "
                  f"Processor seconds of the conversion in the child (load and plan excluded); "
                  f"refined/exact: voxels the compiled kernel's first pass left undecided and refined "
                  f"alone, and of them summed exactly over every cap triangle."),
        "tables": [
            {"caption": "Models voxelised by the winding number of a capped copy",
             "columns": ["model", "cap triangles"] + [f"approximate at {n}³" for n in res]
                        + ["cpu s (" + " / ".join(f"{n}³" for n in res) + ")",
                           "refined/exact (" + " / ".join(f"{n}³" for n in res) + ")"],
             "rows": capped_rows},
            {"caption": "The other models: none can have approximate voxels",
             "columns": ["inside test (at every grid)", "models", "files"],
             "rows": [[k, str(len(v)), ", ".join(sorted(os.path.basename(x) for x in v))[:400]
                       + ("…" if len(", ".join(v)) > 400 else "")]
                      for k, v in sorted(others.items())]},
        ],
    }
    if args.write:
        with open(args.write, "w", encoding="utf-8") as f:
            json.dump(out, f, indent=1, ensure_ascii=False)
            f.write("\n")
    print(json.dumps(out["tables"], indent=1, ensure_ascii=False))
    return 0


if __name__ == "__main__":
    sys.exit(main())
