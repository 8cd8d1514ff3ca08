"""STL read without trimesh (issue 27): whole-process conversions, this checkout against a baseline.

Each case is ``geovox convert MODEL -r N -o out.npy -q`` in a fresh
interpreter, run from this checkout (A) and from a baseline checkout (B,
``--baseline DIR``: today's main, built), in turn (A B A B ...) after one
warm-up run each, so that a drifting load hits both alike; the ratio A/B is
taken pair by pair and the medians are quoted. Wall seconds from a monotonic
clock around each child, processor seconds (user + system) from the
operating system's accounting of the finished child and what it reaped
(``resource.getrusage(RUSAGE_CHILDREN)`` before and after). Both sides run
with Python's bytecode cache (``PYTHONDONTWRITEBYTECODE`` removed from the
environment), as on a user's machine. ``--batch`` adds one command over every
STL mesh of the folder (``--format npz``, ``--jobs 2`` and ``--jobs 1``): the
data set's STL part. Every output of A is compared with B's, byte for byte.

The models are trimesh's ``models/`` folder: ``--models DIR`` (a clone's
folder) or ``--models-git GIT_DIR`` (its ``HEAD``, bare clones too).

Usage: python benchmarks/bench_stl.py --baseline /path/to/main --models-git GIT_DIR
       [--runs 5] [--cases featuretype.STL,...] [--batch] [--write benchmarks/results/stl.json]
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

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
CASES = ["unit_sphere.STL", "featuretype.STL", "counter.unitsmm.STL", "ADIS16480.STL",
         "multibody.stl"]
ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def timed(cmd, cwd):
    """(wall s, cpu s) of one child run to completion."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    p = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, env=ENV)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode:
        raise RuntimeError(f"{' '.join(cmd)} failed: {p.stderr.strip()}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def paired(args_of, baseline, runs, outs):
    """Medians of A and B and of the pair-by-pair ratios; ``args_of(out)`` is the CLI's arguments."""
    sides = (("a", ROOT, outs[0]), ("b", baseline, outs[1]))
    got = {k: [] for k in ("a", "b")}
    for i in range(runs + 1):
        for k, cwd, out in sides:
            w, c = timed([sys.executable, "-m", "geovox", *args_of(out)], cwd)
            if i:  # the first pair is the warm-up (it writes the bytecode caches)
                got[k].append((w, c))
    med = {k: [statistics.median(x[j] for x in got[k]) for j in (0, 1)] for k in got}
    ratio = [statistics.median(a[j] / b[j] for a, b in zip(got["a"], got["b"])) for j in (0, 1)]
    return med, ratio


def same_bytes(a, b):
    """Whether two files, or two folders' files, hold the same bytes."""
    if os.path.isdir(a):
        names = sorted(os.listdir(a))
        return names == sorted(os.listdir(b)) and all(
            same_bytes(os.path.join(a, n), os.path.join(b, n)) for n in names)
    with open(a, "rb") as fa, open(b, "rb") as fb:
        return fa.read() == fb.read()


def describe(path):
    """(kind, triangles) of an STL as this checkout reads it."""
    sys.path.insert(0, ROOT)
    import geovox

    mesh = geovox.load_mesh(path)
    with open(path, "rb") as f:
        data = f.read()
    binary = len(data) >= 84 and int.from_bytes(data[80:84], "little") * 50 == len(data) - 84
    kind = "binary" if binary else (f"ASCII, {len(mesh.parts)} solids (parts)" if mesh.parts
                                    else "ASCII, one solid")
    return kind, len(mesh.faces)


def models_folder(args, tmp):
    if args.models:
        return args.models
    names = subprocess.run(["git", f"--git-dir={args.models_git}", "ls-tree", "--name-only",
                            "HEAD", "models/"], capture_output=True, text=True, check=True)
    folder = os.path.join(tmp, "models")
    os.makedirs(folder)
    for name in names.stdout.split():
        if name.lower().endswith(".stl"):
            blob = subprocess.run(["git", f"--git-dir={args.models_git}", "show", f"HEAD:{name}"],
                                  capture_output=True, check=True).stdout
            with open(os.path.join(folder, os.path.basename(name)), "wb") as f:
                f.write(blob)
    return folder


def batch_files(folder):
    """The folder's STL files that this checkout reads as meshes."""
    sys.path.insert(0, ROOT)
    import geovox
    from geovox.errors import MeshError

    files = []
    for name in sorted(os.listdir(folder)):
        try:
            geovox.load_mesh(os.path.join(folder, name))
            files.append(os.path.join(folder, name))
        except MeshError:
            pass
    return files


def pair_cells(med, ratio):
    return [f"{med['b'][0]:.2f} / {med['b'][1]:.2f}", f"{med['a'][0]:.2f} / {med['a'][1]:.2f}",
            f"{ratio[0]:.2f}, {ratio[1]:.2f}"]


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--baseline", required=True, help="a built checkout of the baseline (B)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--models", help="trimesh's models/ folder")
    src.add_argument("--models-git", help="a clone of trimesh (its HEAD's models/)")
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--cases", default=",".join(CASES))
    p.add_argument("--batch", action="store_true", help="also the folder's STL meshes in one command")
    p.add_argument("--write", help="write the result file here")
    args = p.parse_args(argv)
    baseline, res = os.path.abspath(args.baseline), str(args.res)
    load = [os.getloadavg()[0]]
    start = datetime.datetime.now(datetime.timezone.utc)
    one, many = [], []
    with tempfile.TemporaryDirectory() as tmp:
        folder = models_folder(args, tmp)
        outs = (os.path.join(tmp, "a.npy"), os.path.join(tmp, "b.npy"))
        for name in args.cases.split(","):
            path = os.path.join(folder, name)
            med, ratio = paired(lambda out: ["convert", path, "-r", res, "-o", out, "-q"],
                                baseline, args.runs, outs)
            load.append(os.getloadavg()[0])
            kind, n = describe(path)
            one.append([f"`{name}`", kind, f"{n:,}", f"{os.path.getsize(path) / 1e3:,.0f} KB",
                        *pair_cells(med, ratio), "identical" if same_bytes(*outs) else "DIFFERENT"])
            print(" | ".join(one[-1]), flush=True)
        files = batch_files(folder) if args.batch else []
        for jobs in (["2", "1"] if files else []):
            dirs = (os.path.join(tmp, "a" + jobs), os.path.join(tmp, "b" + jobs))
            med, ratio = paired(lambda out: ["convert", *files, "-o", out, "-r", res, "--format",
                                             "npz", "--jobs", jobs, "-q"], baseline, args.runs, dirs)
            load.append(os.getloadavg()[0])
            rate = f"{len(files) / med['b'][0]:.1f} / {len(files) / med['a'][0]:.1f}"
            many.append([f"`--jobs {jobs}`", *pair_cells(med, ratio), rate,
                         f"{len(files)} identical" if same_bytes(*dirs) else "DIFFERENT"])
            print(" | ".join(many[-1]), flush=True)
    end = datetime.datetime.now(datetime.timezone.utc)
    result = {
        "benchmark": "stl",
        "title": "STL read without trimesh: whole process (issue 27, sections 4-5)",
        "script": "benchmarks/bench_stl.py",
        "command": f"python benchmarks/bench_stl.py --baseline MAIN --models-git TRIMESH "
                   f"--runs {args.runs} --res {res}{' --batch' if args.batch else ''}",
        "date": f"{start:%Y-%m-%d, %H:%M}-{end:%H:%M} UTC",
        "machine": f"{os.cpu_count()} cores, {platform.machine()}, Python "
                   f"{platform.python_version()}; load average {min(load):.1f}-{max(load):.1f}",
        "tables": [{"caption": f"One model per process, {res}³ to .npy",
                    "columns": ["model", "kind", "triangles", "file", "main wall / CPU (s)",
                                "branch wall / CPU (s)", "ratio (wall, CPU)", "output"],
                    "rows": one}],
    }
    if many:
        result["tables"].append({
            "caption": f"The folder's STL meshes ({len(files)}) in one command, {res}³ to .npz",
            "columns": ["engine", "main wall / CPU (s)", "branch wall / CPU (s)",
                        "ratio (wall, CPU)", "models per second, main / branch (wall)", "outputs"],
            "rows": many})
    if args.write:
        with open(args.write, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1, ensure_ascii=False)
            f.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
