"""Issues 27 and 37: the ray stage on meshes of millions of triangles, closed and open (scans).

Whole-process ``python -m geovox convert MODEL -o OUT.npy -r N`` with default
options, this checkout (A) against another (B, ``--vs PATH``, e.g. a checkout
of main with its own build), run in turn A B A B ... so that the ratio A/B is
taken pair by pair on a loaded machine; prints the median wall time of each
side, the median of the pairwise ratios, each side's peak resident memory
(the child's own ``ru_maxrss``, from ``os.wait4``), and whether both sides
wrote the same bytes. CPU is the child's user + system time. Each tree caches
its bytecode in a folder of its own outside both (an installed package has
its ``.pyc``; with ``PYTHONDONTWRITEBYTECODE`` set, both sides would compile
their sources in every run).

Models (written into ``--folder`` first, default a temporary one; made once,
kept where the folder is given), all from the benchmarks' 105,568-triangle
closed bunny (``common.load_model("bunny105k")``) subdivided by
``trimesh.remesh.subdivide``:

* ``bunny105k``: as it is, an OBJ (as ``bench_cli.py`` writes it);
* ``bunny1m6``: subdivided twice more (1,689,088 triangles, closed): the
  "1.6M-triangle" case of issue 27;
* ``open1m6``, ``open6m4``, ``open25m``: subdivided twice, three and four
  times (1.69, 6.76 and 27.0 million triangles), then 5 % of the faces
  removed at random (seed 37): scans with many small holes (issue 37's
  "1.6M" with 229k... here 242,133 open edges, its "6.4M" and a 25-million
  one); ``closed6m4`` is the 6.76-million one before the removal;
* the models are binary STL (``--format stl``, as a scanner writes them: three
  vertices a triangle, merged by position when read) or binary PLY
  (``--format ply``, shared vertices, as issue 27's and 37's figures were
  measured).

``--check`` adds, for every open model at its grid:

* the voxels where A and B differ, each decided again by the brute-force
  winding number of the repaired mesh (every triangle's solid angle summed
  exactly at the voxel centre, geovox.inside.captree.triangle_angles): how
  many A has right;
* the voxels where the open model differs from the closed one at the same
  grid (A), as a share of the closed model's inside count, and the largest
  distance of such a voxel's centre from a removed face, in voxels;
* whether either side said that voxels were approximate (an estimate).

Usage::

    python benchmarks/bench_triangles.py --vs /path/to/main [--repeat 3] [--format stl]
        [--cases open1m6:64,open1m6:256,open6m4:128,bunny1m6:64] [--check]
        [--folder /tmp/geovox-scans] [--huge]   # --huge: open25m:128 too (a 1.3 GB STL)

(`/usr/bin/time -v python -m geovox convert ...` gives the same wall time
for one run by hand.)
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from common import BUNNY, ROOT  # noqa: E402

#: Subdivisions of bunny105k and whether 5 % of the faces are removed, per model.
MODELS = {"bunny1m6": (2, False), "open1m6": (2, True), "closed6m4": (3, False),
          "open6m4": (3, True), "open25m": (4, True)}
#: The share of faces removed from the open models, and the seed that draws them.
REMOVED, SEED = 0.05, 37

MAKE = r"""
import sys
import numpy as np
sys.path.insert(0, {here!r})
import trimesh
import common
common.BUNNY = {bunny!r}
m = common.load_model("bunny105k")
if {obj!r}:
    trimesh.Trimesh(m.vertices, m.faces, process=False).export({obj!r})
v, f = m.vertices, m.faces
for _ in range({levels}):
    v, f = trimesh.remesh.subdivide(v, f)
removed = np.zeros(len(f), bool)
if {open_}:
    removed = np.random.default_rng({seed}).random(len(f)) < {share}
    np.save({removed_path!r}, v[f[removed]])  # the removed triangles, for --check
f = f[~removed]
if {fmt!r} == "ply":
    trimesh.Trimesh(v, f, process=False).export({path!r})
else:  # binary STL, written directly (trimesh's writer keeps a second copy of everything)
    t = v[f].astype(np.float32)
    rec = np.zeros(len(f), np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]))
    rec["n"], rec["v"] = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), t
    with open({path!r}, "wb") as out:
        out.write(b"geovox bench_triangles".ljust(80, b" "))
        out.write(np.uint32(len(f)).tobytes())
        rec.tofile(out)
"""


def make_model(folder, name, fmt, bunny) -> str:
    """The model's path, written first where it is not in ``folder`` yet."""
    if name == "bunny105k":
        path = os.path.join(folder, "bunny105k.obj")
        levels, open_, fmt_ = 0, False, "none"
    else:
        (levels, open_), fmt_ = MODELS[name], fmt
        path = os.path.join(folder, f"{name}.{fmt}")
    if not os.path.exists(path):
        code = MAKE.format(here=HERE, bunny=bunny, obj=path if name == "bunny105k" else "",
                           levels=levels, open_=open_, seed=SEED, share=REMOVED,
                           removed_path=os.path.join(folder, f"{name}.removed.npy"),
                           fmt=fmt_, path=path if name != "bunny105k" else os.devnull)
        subprocess.run([sys.executable, "-c", code], check=True)
    return path


def run(root, model, res, out, cache) -> tuple:
    """``(wall, cpu, peak bytes, stderr)`` of one whole-process conversion from the tree ``root``.

    Bytecode is cached in ``cache`` (one folder per tree, outside both), as
    an installed package's is: with PYTHONDONTWRITEBYTECODE set every run
    would compile its sources again. The peak is the child's own (``os.wait4``).
    """
    env = dict(os.environ, PYTHONPATH=root, PYTHONPYCACHEPREFIX=cache)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    t = time.perf_counter()
    with tempfile.TemporaryFile("w+") as err:
        p = subprocess.Popen([sys.executable, "-m", "geovox", "convert", model, "-o", out, "-r",
                              str(res)], cwd=root, env=env, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t
        err.seek(0)
        said = err.read()
    if p.returncode:
        raise RuntimeError(f"{root}: geovox convert {model} -r {res} failed: {said.strip()}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss * 1024, said


def sha(path) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


CHECK = r"""
import json, sys, warnings
import numpy as np
sys.path.insert(0, {root!r})
import geovox
from geovox.inside import captree, choice
warnings.simplefilter("ignore")
a, b = np.load({a!r}), np.load({b!r})
m = geovox.load_mesh({model!r})
grid = geovox.plan(m, dict(resolution={res})).grid
out = {{}}
idx = np.argwhere(a != b)
if len(idx):
    tris = choice.target(m)[0].triangles
    p = np.stack([grid.centres(k)[idx[:, k]] for k in range(3)], axis=1)
    w = np.array([sum(captree.triangle_angles(tris[s:s + 1 << 20], np.repeat(q[None], len(tris[s:s + 1 << 20]), 0)).sum()
                      for s in range(0, len(tris), 1 << 20)) for q in p])
    out["a_right"] = int(np.count_nonzero((w > 0.5) == a[tuple(idx.T)].astype(bool)))
out["a_vs_b"] = int(len(idx))
if {closed!r}:
    c = np.load({closed!r})
    moved = np.argwhere(a != c)
    out["vs_closed"] = int(len(moved))
    out["closed_inside"] = int(np.count_nonzero(c))
    if len(moved):
        gone = np.load({removed!r})  # (k, 3, 3) removed triangles
        q = np.stack([grid.centres(k)[moved[:, k]] for k in range(3)], axis=1)
        from geovox.geometry import closest_on_triangles
        far = 0.0
        cen = gone.mean(axis=1)
        for x in q:
            t = gone[np.argsort(np.linalg.norm(cen - x, axis=1))[:64]]
            uv = closest_on_triangles(np.repeat(x[None], len(t), 0), t)
            pt = t[:, 0] + uv[:, :1] * (t[:, 1] - t[:, 0]) + uv[:, 1:] * (t[:, 2] - t[:, 0])
            far = max(far, float(np.linalg.norm(pt - x, axis=1).min()))
        out["farthest_voxels"] = far / float(np.linalg.norm(grid.spacing))
print(json.dumps(out))
"""


def check(model, res, a, b, closed, removed) -> dict:
    """The --check figures of one open model (see the module notes), in a fresh interpreter."""
    code = CHECK.format(root=ROOT, a=a, b=b, model=model, res=res, closed=closed or "",
                        removed=removed)
    import json

    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--vs", required=True, help="the other checkout (B)")
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--cases", default="open1m6:64,open1m6:256,open6m4:128,bunny1m6:64")
    p.add_argument("--format", choices=("stl", "ply"), default="stl")
    p.add_argument("--folder", help="where the models are written and kept (default: a temporary one)")
    p.add_argument("--check", action="store_true", help="voxels against the brute force and the closed model")
    p.add_argument("--huge", action="store_true", help="also open25m:128 (a 1.3 GB STL, minutes)")
    p.add_argument("--bunny", default=BUNNY,
                   help="upsampled_bunny_oded.obj of the corpus (default: common.BUNNY)")
    args = p.parse_args(argv)
    cases = args.cases.split(",") + (["open25m:128"] if args.huge else [])
    print(f"load average before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = args.folder or tmp
        os.makedirs(folder, exist_ok=True)
        print("| case | A wall median (min-max) | B wall median (min-max) | A/B wall | A/B CPU "
              "| A peak MB | B peak MB | same bytes | approximate (A, B) |")
        print("|---|---|---|---|---|---|---|---|---|")
        ca, cb = os.path.join(tmp, "pyc-a"), os.path.join(tmp, "pyc-b")
        notes = []
        for case in cases:
            name, res = case.split(":")
            model = make_model(folder, name, args.format, args.bunny)
            oa, ob = os.path.join(tmp, f"{name}-{res}-a.npy"), os.path.join(tmp, f"{name}-{res}-b.npy")
            run(ROOT, model, res, oa, ca)  # warm-up (file cache, bytecode)
            run(args.vs, model, res, ob, cb)
            a, b = [], []
            for _ in range(args.repeat):
                a.append(run(ROOT, model, res, oa, ca))
                b.append(run(args.vs, model, res, ob, cb))
            wall = statistics.median(x[0] / y[0] for x, y in zip(a, b))
            cpu = statistics.median(x[1] / y[1] for x, y in zip(a, b))
            spread = [f"{statistics.median(w):.2f} ({min(w):.2f}-{max(w):.2f})"
                      for w in ([x[0] for x in a], [y[0] for y in b])]
            peaks = [max(x[2] for x in side) / 1e6 for side in (a, b)]
            approx = ["approximate" in side[-1][3] for side in (a, b)]
            print(f"| {name} {res}³ | {spread[0]} | {spread[1]} | {wall:.2f} | {cpu:.2f} | "
                  f"{peaks[0]:.0f} | {peaks[1]:.0f} | {sha(oa) == sha(ob)} | {approx} |", flush=True)
            if args.check and MODELS.get(name, (0, False))[1]:
                closed = {"open1m6": "bunny1m6", "open6m4": "closed6m4"}.get(name)
                oc = None
                if closed is not None:
                    oc = os.path.join(tmp, f"{closed}-{res}-a.npy")
                    run(ROOT, make_model(folder, closed, args.format, args.bunny), res, oc, ca)
                got = check(model, res, oa, ob, oc, os.path.join(folder, f"{name}.removed.npy"))
                notes.append(f"{name} {res}³: {got}")
        for n in notes:
            print(n)
    print(f"load average after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
