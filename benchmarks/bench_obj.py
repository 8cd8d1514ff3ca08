"""OBJ reading speed (issues 11 and 12): MB/s of three readers, per file, each read in a fresh process.

Readers:

* ``before``: geovox 0.1's reader, one Python loop per line (a copy is kept below, as it was);
* ``geovox``: ``geovox.io.obj.read_obj``, the reader on whole arrays;
* ``load``: ``geovox.load_mesh``, the user's path (read + the mesh checks);
* ``trimesh``: ``trimesh.load(path, process=False)``, trimesh's own OBJ loader (it also decodes
  textures, which the others leave to the colour stage).

Each (file, reader) pair runs ``--runs`` times, every run in a new interpreter that imports the
reader's modules first and then times one read, its first (wall clock and CPU time); the table
gives medians. MB/s is
the file's size over the wall time. With ``--convert TREE ...`` it also times ``geovox convert`` of
the 100k-triangle OBJ at 256³ with ``--backend numpy`` as a whole process, once per source tree
(for before/after, check the older commit out in a second worktree).

Files: ``bunny105k.obj`` (the benchmarks' bunny105k written out by trimesh into a temporary
folder, about 4 MB), ``bunny105k_repr.obj`` (the same written with Python's repr, 17 significant
digits), spot, every OBJ of the shared corpus (not with ``--no-corpus``), and any files or folders
given.

Usage: python benchmarks/bench_obj.py [--runs 3] [--readers before geovox load trimesh]
                                      [--no-corpus] [--convert TREE ...] [EXTRA_OBJ_OR_FOLDER ...]
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import BUNNY, CORPUS, ROOT, SPOT  # noqa: E402


def worker(reader, path):
    """Import the reader, then time one read of ``path``; print a JSON line."""
    import numpy as np  # noqa: F401  (imported before timing, as the CLI would)

    if reader != "trimesh":
        import geovox.io.obj  # noqa: F401  (load_mesh imports it lazily; not part of a read)

    if reader == "trimesh":
        import trimesh

        def read(p):
            return trimesh.load(p, process=False)
    elif reader == "before":
        # geovox 0.1's OBJ reader (commit c6f2705), kept once, in the tests,
        # as the reference the new reader must match; imported before timing.
        sys.path.insert(0, os.path.join(ROOT, "tests"))
        from test_obj import reference_read_obj as read
    elif reader == "load":
        from geovox.io.load import load_mesh as read
    else:
        from geovox.io.obj import read_obj as read
    wall, cpu = time.perf_counter(), time.process_time()
    try:
        out = read(path)
        faces = len(out.faces) if hasattr(out, "faces") else sum(
            len(g.faces) for g in out.geometry.values())
        error = None
    except Exception as exc:  # a reader refusing a file is a result here
        faces, error = None, f"{type(exc).__name__}: {str(exc).splitlines()[0][:80]}"
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    print(json.dumps({"wall": wall, "cpu": cpu, "faces": faces, "error": error}))


def run_worker(reader, path):
    out = subprocess.run([sys.executable, __file__, "--worker", reader, path],
                         capture_output=True, text=True, cwd=ROOT,
                         env=dict(os.environ, PYTHONPATH=ROOT))
    if out.returncode != 0:
        return {"error": (out.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(out.stdout.strip().splitlines()[-1])


def write_bunny105k(folder):
    """bunny105k (see common.py) written as OBJ by trimesh, and as a Python
    script would write it (repr: up to 17 significant digits)."""
    import trimesh

    m = trimesh.load(BUNNY, force="mesh", process=False)
    v, f = trimesh.remesh.subdivide(m.vertices, m.faces)
    path = os.path.join(folder, "bunny105k.obj")
    with open(path, "w") as fh:
        fh.write(trimesh.exchange.obj.export_obj(trimesh.Trimesh(v, f, process=False)))
    path_repr = os.path.join(folder, "bunny105k_repr.obj")
    with open(path_repr, "w") as fh:
        fh.writelines(f"v {float(a)!r} {float(b)!r} {float(c)!r}\n" for a, b, c in v)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f)
    return [path, path_repr]


def time_convert(tree, obj, runs):
    """Median whole-process wall time of `geovox convert OBJ -r 256 --backend numpy`."""
    times = []
    with tempfile.TemporaryDirectory() as out:
        for _ in range(runs):
            t = time.perf_counter()
            p = subprocess.run([sys.executable, "-m", "geovox", "convert", obj, "-o",
                                os.path.join(out, "v.raw"), "-r", "256", "--backend", "numpy",
                                "-q"], capture_output=True, text=True, cwd=tree,
                               env=dict(os.environ, PYTHONPATH=tree))
            times.append(time.perf_counter() - t)
            if p.returncode != 0:
                return f"failed: {p.stderr.strip()[-200:]}"
    return f"{statistics.median(times):.2f} s (runs {', '.join(f'{t:.2f}' for t in times)})"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--readers", nargs="+", default=["before", "geovox", "load", "trimesh"])
    ap.add_argument("--convert", nargs="*", default=None, metavar="TREE")
    ap.add_argument("--no-corpus", action="store_true", help="only the generated files and spot")
    ap.add_argument("extra", nargs="*", help="more OBJ files or folders of them")
    args = ap.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    tmp = tempfile.mkdtemp(prefix="bench_obj_")
    files = write_bunny105k(tmp) + [SPOT]
    if not args.no_corpus:
        files += sorted(glob.glob(os.path.join(CORPUS, "**", "*.obj"), recursive=True))
    for e in args.extra:
        files += sorted(glob.glob(os.path.join(e, "*.obj"))) if os.path.isdir(e) else [e]
    print(f"python {sys.version.split()[0]}, {os.cpu_count()} cores, load average "
          f"{os.getloadavg()[0]:.1f}; {args.runs} fresh processes per cell, medians: wall time, "
          f"MB/s over wall (and over CPU time); 'x' = the 'before' wall time over this one")
    print()
    names = {"geovox": "read_obj", "load": "load_mesh"}
    head = "| file | MB | triangles | " + " | ".join(names.get(r, r) for r in args.readers) + " |"
    print(head)
    print("|" + "---|" * (3 + len(args.readers)))
    for path in files:
        size = os.path.getsize(path) / 1e6
        cells, tris, base = [], "", None
        for reader in args.readers:
            res = [run_worker(reader, path) for _ in range(args.runs)]
            err = next((r["error"] for r in res if r.get("error")), None)
            if err:
                cells.append(f"error ({err[:60]})")
                continue
            wall = statistics.median(r["wall"] for r in res)
            cpu = statistics.median(r["cpu"] for r in res)
            if reader == "before":
                base = wall
            if reader in ("geovox", "before") and res[0]["faces"] is not None:
                tris = f"{res[0]['faces']:,}"
            ratio = f", {base / wall:.1f}x" if base and reader != "before" else ""
            cells.append(f"{wall:.3f} s, {size / wall:.1f} MB/s (CPU {size / max(cpu, 1e-9):.0f}){ratio}")
        name = os.path.relpath(path, CORPUS) if path.startswith(CORPUS) else os.path.basename(path)
        print(f"| {name} | {size:.2f} | {tris} | " + " | ".join(cells) + " |", flush=True)
    if args.convert is not None:
        print()
        for tree in args.convert or [ROOT]:
            print(f"geovox convert bunny105k.obj -r 256 --backend numpy, whole process, tree "
                  f"{tree}: {time_convert(tree, files[0], max(args.runs, 5))}", flush=True)


if __name__ == "__main__":
    main()
