"""OBJ reading speed (issues 11 and 12): MB/s of three readers, per file, each read in a fresh process.

Readers:

* ``before``: geovox 0.1's reader, one Python loop per line (a copy is kept below, as it was);
* ``geovox``: ``geovox.obj.read_obj``, the reader on whole arrays;
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


def before_read_obj(path):
    """geovox 0.1's OBJ reader (commit c6f2705), the "before" of this table (messages shortened)."""
    import numpy as np

    from geovox.errors import MeshError
    from geovox.mesh import Material, Mesh
    from geovox.obj import _rest, read_mtl, resolve_path

    with open(path, "rb") as f:
        data = f.read()
    if b"\0" in data[:4096]:
        raise MeshError(f"{path}: is a binary file, not a text OBJ mesh")
    text = data.decode("utf-8", errors="replace")
    text = text.replace("\\\r\n", " ").replace("\\\n", " ")
    folder = os.path.dirname(os.path.abspath(path))
    v, vc, vt = [], [], []
    tri_v, tri_t, tri_m = [], [], []
    mat_index, mat_names, libs = {}, [], []
    current = -1
    has_vc = False
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line or line[0] == "#":
            continue
        parts = line.split()
        if not parts:
            continue
        key = parts[0]
        try:
            if key == "v":
                v.append((float(parts[1]), float(parts[2]), float(parts[3])))
                if len(parts) >= 7:
                    vc.append((float(parts[4]), float(parts[5]), float(parts[6])))
                    has_vc = True
                else:
                    vc.append((1.0, 1.0, 1.0))
            elif key == "vt":
                vt.append((float(parts[1]), float(parts[2]) if len(parts) > 2 else 0.0))
            elif key == "f":
                nv, nt = len(v), len(vt)
                corners_v, corners_t = [], []
                for tok in parts[1:]:
                    s = tok.split("/")
                    i = int(s[0])
                    corners_v.append(i - 1 if i > 0 else nv + i)
                    if len(s) > 1 and s[1]:
                        j = int(s[1])
                        corners_t.append(j - 1 if j > 0 else nt + j)
                    else:
                        corners_t.append(-1)
                if len(corners_v) < 3:
                    continue
                for k in range(1, len(corners_v) - 1):
                    tri_v.append((corners_v[0], corners_v[k], corners_v[k + 1]))
                    tri_t.append((corners_t[0], corners_t[k], corners_t[k + 1]))
                    tri_m.append(current)
            elif key == "usemtl":
                name = _rest(line, "usemtl")
                if name not in mat_index:
                    mat_index[name] = len(mat_names)
                    mat_names.append(name)
                current = mat_index[name]
            elif key == "mtllib":
                libs.append(_rest(line, "mtllib"))
        except (ValueError, IndexError):
            raise MeshError(f"{path}: line {lineno} is not valid OBJ") from None
    if not v and not tri_v:
        raise MeshError(f"{path}: cannot be read as a mesh (no OBJ vertices or faces)")
    faces = np.array(tri_v, dtype=np.int64).reshape(-1, 3)
    tex = np.array(tri_t, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(v)):
        raise MeshError(f"{path}: faces index vertices that do not exist")
    if tex.size and tex.max() >= len(vt):
        raise MeshError(f"{path}: faces index texture coordinates that do not exist")
    problems, library, missing_lib = [], {}, False
    for lib in libs:
        found = resolve_path(lib, folder)
        if found is None:
            problems.append(f"material file not found: {lib!r}")
            missing_lib = True
            continue
        library.update(read_mtl(found, problems))
    materials = []
    for name in mat_names:
        if name in library:
            materials.append(library[name])
        else:
            if libs and not missing_lib:
                problems.append(f"material {name!r} is not defined")
            materials.append(Material(name=name, defined=False))
    uv = None
    if vt and (tex >= 0).any():
        vt_arr = np.array(vt, dtype=np.float64)
        uv = np.where((tex >= 0)[..., None], vt_arr[np.maximum(tex, 0)], np.nan)
    return Mesh(vertices=np.array(v, dtype=np.float64).reshape(-1, 3), faces=faces, source=path,
                face_material=np.array(tri_m, dtype=np.int64), materials=materials,
                corner_uv=uv, vertex_colors=np.array(vc, dtype=np.float64) if has_vc else None,
                problems=problems)


def worker(reader, path):
    """Import the reader, then time one read of ``path``; print a JSON line."""
    import numpy as np  # noqa: F401  (imported before timing, as the CLI would)

    if reader != "trimesh":
        import geovox.obj  # noqa: F401  (load_mesh imports it lazily; not part of a read)

    if reader == "trimesh":
        import trimesh

        def read(p):
            return trimesh.load(p, process=False)
    elif reader == "before":
        read = before_read_obj
    elif reader == "load":
        from geovox.mesh import load_mesh as read
    else:
        from geovox.obj import read_obj as read
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
