"""Issue 27, sections 3 and 4: the ray stage and meshes of millions of triangles.

Whole-process `python -m geovox convert MODEL -o OUT.raw -r N` with default
options, this checkout (A) against another (B, ``--vs PATH``, e.g. a clone
of main), run in turn A B A B ... so that the ratio A/B is taken pair by pair
on a loaded machine; prints the median wall time of each side, the median
of the pairwise ratios, and whether both sides wrote the same bytes (sha256
of the ``.raw``); CPU is the children's user + system time. Each tree
caches its bytecode in a folder of its own outside both (an installed
package has its ``.pyc``; with ``PYTHONDONTWRITEBYTECODE`` set, both sides
would compile their sources in every run).

Models (written into a temporary folder first, with trimesh):

* ``bunny105k``: the benchmarks' 105,568-triangle closed bunny
  (``common.load_model``) as an OBJ, as ``bench_cli.py`` writes it;
* ``bunny1m6``: the same subdivided twice more by
  ``trimesh.remesh.subdivide`` (1,689,088 triangles, closed), written as a
  binary PLY by ``trimesh.Trimesh(v, f, process=False).export(path)``
  (32 MB): the "1.6M-triangle" case of the issue.

Usage::

    python benchmarks/bench_triangles.py --vs /path/to/main [--repeat 5]
        [--cases bunny105k:256,bunny1m6:64,bunny1m6:256] [--bunny CORPUS/bunny_watertight/upsampled_bunny_oded.obj]

(`/usr/bin/time -v python -m geovox convert ...` gives the same wall time
for one run by hand.)
"""

from __future__ import annotations

import argparse
import hashlib
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from common import BUNNY, ROOT  # noqa: E402

MAKE = r"""
import sys
sys.path.insert(0, {here!r})
import trimesh
import common
common.BUNNY = {bunny!r}
m = common.load_model("bunny105k")
trimesh.Trimesh(m.vertices, m.faces, process=False).export({obj!r})
v, f = trimesh.remesh.subdivide(m.vertices, m.faces)
v, f = trimesh.remesh.subdivide(v, f)
trimesh.Trimesh(v, f, process=False).export({ply!r})
"""


def make_models(folder, bunny) -> dict:
    obj, ply = os.path.join(folder, "bunny105k.obj"), os.path.join(folder, "bunny1m6.ply")
    subprocess.run([sys.executable, "-c", MAKE.format(here=HERE, bunny=bunny, obj=obj, ply=ply)],
                   check=True)
    return {"bunny105k": obj, "bunny1m6": ply}


def run(root, model, res, out, cache) -> tuple:
    """``(wall, cpu)`` seconds of one whole-process conversion from the tree ``root``.

    Bytecode is cached in ``cache`` (one folder per tree, outside both), as
    an installed package's is: with PYTHONDONTWRITEBYTECODE set every run
    would compile its sources again.
    """
    env = dict(os.environ, PYTHONPATH=root, PYTHONPYCACHEPREFIX=cache)
    env.pop("PYTHONDONTWRITEBYTECODE", None)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "geovox", "convert", model, "-o", out, "-r", str(res)],
                   cwd=root, env=env, check=True, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def sha(path) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--vs", required=True, help="the other checkout (B)")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--cases", default="bunny105k:256,bunny1m6:64,bunny1m6:256")
    p.add_argument("--bunny", default=BUNNY,
                   help="upsampled_bunny_oded.obj of the corpus (default: common.BUNNY)")
    args = p.parse_args(argv)
    print(f"load average before: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        models = make_models(tmp, args.bunny)
        print("| case | A wall median (min-max) | B wall median (min-max) | A/B wall | A/B CPU "
              "| same bytes |")
        print("|---|---|---|---|---|---|")
        ca, cb = os.path.join(tmp, "pyc-a"), os.path.join(tmp, "pyc-b")
        for case in args.cases.split(","):
            name, res = case.split(":")
            oa, ob = os.path.join(tmp, "a.raw"), os.path.join(tmp, "b.raw")
            run(ROOT, models[name], res, oa, ca)  # warm-up (file cache, bytecode)
            run(args.vs, models[name], res, ob, cb)
            a, b = [], []
            for _ in range(args.repeat):
                a.append(run(ROOT, models[name], res, oa, ca))
                b.append(run(args.vs, models[name], res, ob, cb))
            wall = statistics.median(x[0] / y[0] for x, y in zip(a, b))
            cpu = statistics.median(x[1] / y[1] for x, y in zip(a, b))
            spread = [f"{statistics.median(w):.2f} ({min(w):.2f}-{max(w):.2f})"
                      for w in ([x[0] for x in a], [y[0] for y in b])]
            print(f"| {name} {res}³ | {spread[0]} | {spread[1]} | {wall:.2f} | {cpu:.2f} | "
                  f"{sha(oa) == sha(ob)} |", flush=True)
    print(f"load average after: {os.getloadavg()}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
