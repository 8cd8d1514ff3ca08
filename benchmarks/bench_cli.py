"""The user's path (issue 11): one `geovox convert`, a fresh process, end to end.

Every figure is the wall time (and the CPU time, user + system, which a
loaded machine inflates less) of a new interpreter running the console
script `geovox convert MODEL.obj -o OUT -r N [--color] [--backend B]` (Python
start, imports, reading the OBJ, rays, fill, colour, writing), median of
``--repeat`` runs, with that process's peak RSS (from ``os.wait4``) and the
time per stage that the CLI's summary prints. Output: ``.raw`` up to 512³,
``.h5`` at 1024³ (the cases the issue names). Beside it, in the same run,
Open3D end to end in a fresh process: read the OBJ
(``open3d.io.read_triangle_mesh``), ``RaycastingScene.compute_occupancy`` on
the same voxel centres, write the bytes as geovox's ``.raw`` (uint8 0/255,
x fastest); Open3D is skipped at 1024³ (about 4 minutes and 40 GiB of query
points there, by its 512³ figures).

Also: import times (``python -c "import geovox"``, ``geovox --help``), and
``--auto-rule``: every corpus model at 64³-1024³, first call of
``geovox.voxelize`` on a loaded mesh in a fresh process for each backend,
backend imports and set-up included (the measurement behind ``auto``); and
``--only setup``: the Embree backend's set-up for the lattice it casts (scene with its BVH,
coplanar check) against the NumPy backend's whole first call, in fresh
processes whose imports were warmed on spot, with both backends' warm calls
beside them.

Usage (each part prints a Markdown table; the load average is printed
before and after, as the machine is shared)::

    python benchmarks/bench_cli.py                    # everything but --auto-rule
    python benchmarks/bench_cli.py --models spot --res 256 --colour off --no-open3d
    python benchmarks/bench_cli.py --only imports
    python benchmarks/bench_cli.py --only auto-rule --res 64,256,1024
    python benchmarks/bench_cli.py --only setup --models bunny105k,spot --res 256 --repeat 5
    python benchmarks/bench_cli.py --only e2e --models spot --res 256,512 --colour on \
        --repeat 5 --vs /path/to/other/checkout     # A/B against another tree, pair by pair

The full default run (imports and e2e, 3 runs a cell) took about 20 minutes
under load average 8-10 on 2 cores; pick a subset with the options above.
(`/usr/bin/time -v geovox convert ...` gives the same wall time, CPU time and
peak memory for a single run by hand.)
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

from common import CORPUS, ROOT, SPOT  # noqa: E402

BACKENDS = ("default", "numpy", "embree")


def _env(root=ROOT) -> dict:
    return dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""))


def _geovox_cmd() -> list:
    script = os.path.join(os.path.dirname(sys.executable), "geovox")
    return [script] if os.path.exists(script) else [sys.executable, "-m", "geovox"]


def run_timed(cmd, cwd=None) -> dict:
    """Wall time and output of one fresh process."""
    t = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_env(), cwd=cwd,
                         text=True)
    out, err = p.communicate()
    wall = time.perf_counter() - t
    return {"wall": wall, "rc": p.returncode, "out": out, "err": err}


def run_rss(cmd, cwd=None, root=ROOT) -> dict:
    """Like :func:`run_timed`, with the child's own peak RSS and CPU time (``os.wait4``,
    which reports the one child reaped, unlike ``RUSAGE_CHILDREN``); ``root``: the
    geovox tree the child imports."""
    t = time.perf_counter()
    with tempfile.TemporaryFile("w+") as fo, tempfile.TemporaryFile("w+") as fe:
        p = subprocess.Popen(cmd, stdout=fo, stderr=fe, env=_env(root), cwd=cwd, text=True)
        _, status, usage = os.wait4(p.pid, 0)
        wall = time.perf_counter() - t
        p.returncode = os.waitstatus_to_exitcode(status)
        fo.seek(0)
        fe.seek(0)
        return {"wall": wall, "rc": p.returncode, "out": fo.read(), "err": fe.read(),
                "rss": usage.ru_maxrss * 1024, "cpu": usage.ru_utime + usage.ru_stime,
                "user": usage.ru_utime, "sys": usage.ru_stime}


STAGE_RE = re.compile(r"^time ([\d.]+) s \((.*)\)$", re.M)


def stages_of(out: str) -> dict:
    m = STAGE_RE.search(out)
    if not m:
        return {}
    parts = dict(p.strip().rsplit(" ", 1) for p in m.group(2).split(","))
    return {k: float(v) for k, v in parts.items()}


def model_paths(names, tmp) -> dict:
    """name -> OBJ path; bunny105k is written out as an OBJ first (trimesh)."""
    paths = {}
    for name in names:
        if name == "spot":
            paths[name] = SPOT
        elif name == "bunny105k":
            path = os.path.join(tmp, "bunny105k.obj")
            code = ("import sys; sys.path.insert(0, %r)\n"
                    "from common import load_model\nimport trimesh\n"
                    "m = load_model('bunny105k')\n"
                    "trimesh.Trimesh(m.vertices, m.faces, process=False).export(%r)\n") % (HERE, path)
            subprocess.run([sys.executable, "-c", code], check=True, env=_env())
            paths[name] = path
        else:
            paths[name] = name
    return paths


# --- Open3D, end to end, in its own process ---------------------------------------------

OPEN3D_WORKER = r"""
import sys, numpy as np, open3d as o3d
obj, n, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
mesh = o3d.io.read_triangle_mesh(obj)
v = np.asarray(mesh.vertices); f = np.asarray(mesh.triangles)
used = v[np.unique(f)]
lo, hi = used.min(axis=0), used.max(axis=0)
# geovox's grid for -r N: the mesh's bounding box, N voxels per axis, centres at (i + 0.5) * spacing.
h = (hi - lo) / n
axes = [(lo[a] + (np.arange(n) + 0.5) * h[a]).astype(np.float32) for a in range(3)]
scene = o3d.t.geometry.RaycastingScene()
scene.add_triangles(o3d.t.geometry.TriangleMesh.from_legacy(mesh))
# Query points z slowest, x fastest: the occupancy comes out in RAW order.
zz, yy, xx = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")
pts = np.stack([xx.ravel(), yy.ravel(), zz.ravel()], axis=1)
del xx, yy, zz
occ = scene.compute_occupancy(o3d.core.Tensor(pts)).numpy()
(occ.astype(np.uint8) * np.uint8(255)).tofile(out)
print(int(occ.sum()))
"""


def bench_vs(args, tmp) -> None:
    """``--vs TREE``: each e2e cell run by this tree (A) and by TREE (B) in turn, A B A B ...

    The ratio A/B is taken pair by pair (a loaded machine's speed drifts, and a
    pair shares it), and its median printed beside both medians.
    """
    paths = model_paths(args.models, tmp)
    colours = {"off": [False], "on": [True], "both": [False, True]}[args.colour]
    print(f"A = {ROOT}, B = {args.vs}; {args.repeat} pairs a cell after one warm-up pair")
    print("| model | grid | output | colour | A wall (s) | B wall (s) | A/B wall | A user / sys (s) "
          "| B user / sys (s) | A/B CPU | A peak (MiB) | B peak (MiB) | A stages (s), median run |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    med = statistics.median
    for name, path in paths.items():
        for res in args.res:
            ext = ".h5" if res >= 1024 else ".raw"
            for colour in colours:
                if colour and res > args.max_colour_res:
                    continue
                cmd = _geovox_cmd() + ["convert", path, "-o", os.path.join(tmp, f"out{ext}"),
                                       "-r", str(res)] + (["--color"] if colour else [])
                runs = {"A": [], "B": []}
                for n in range(args.repeat + 1):
                    for side, root in (("A", ROOT), ("B", args.vs)):
                        r = run_rss(cmd, cwd=tmp, root=root)
                        if r["rc"] != 0:
                            sys.exit(f"FAILED ({side}): {' '.join(cmd)}\n{r['err']}")
                        if n:  # the first pair warms the file cache
                            runs[side].append(r)
                a, b = runs["A"], runs["B"]
                wall = med(x["wall"] / y["wall"] for x, y in zip(a, b))
                cpu = med(x["cpu"] / y["cpu"] for x, y in zip(a, b))
                mid = min(a, key=lambda r: abs(r["wall"] - med(x["wall"] for x in a)))
                print(f"| {name} | {res}³ | {ext} | {'yes' if colour else 'no'} "
                      f"| {med(x['wall'] for x in a):.2f} | {med(x['wall'] for x in b):.2f} "
                      f"| {wall:.2f} | {med(x['user'] for x in a):.2f} / {med(x['sys'] for x in a):.2f} "
                      f"| {med(x['user'] for x in b):.2f} / {med(x['sys'] for x in b):.2f} "
                      f"| {cpu:.2f} | {max(x['rss'] for x in a) / 2**20:.0f} "
                      f"| {max(x['rss'] for x in b) / 2**20:.0f} | {_fmt_stages(stages_of(mid['out']))} |",
                      flush=True)


def bench_e2e(args, tmp) -> None:
    paths = model_paths(args.models, tmp)
    colours = {"off": [False], "on": [True], "both": [False, True]}[args.colour]
    rows = []
    for name, path in paths.items():
        for res in args.res:
            ext = ".h5" if res >= 1024 else ".raw"
            for colour in colours:
                if colour and res > args.max_colour_res:
                    continue
                cells = {}
                for backend in args.backends:
                    out = os.path.join(tmp, f"out{ext}")
                    cmd = _geovox_cmd() + ["convert", path, "-o", out, "-r", str(res)]
                    if colour:
                        cmd.append("--color")
                    if backend != "default":
                        cmd += ["--backend", backend]
                    runs = []
                    for _ in range(args.repeat):
                        r = run_rss(cmd, cwd=tmp)
                        if r["rc"] != 0:
                            print(f"FAILED: {' '.join(cmd)}\n{r['err']}", file=sys.stderr)
                            break
                        runs.append(r)
                    if not runs:
                        continue
                    walls = sorted(r["wall"] for r in runs)
                    med = statistics.median(walls)
                    mid = min(runs, key=lambda r: abs(r["wall"] - med))
                    backend_ran = re.search(r"backend (\w+)", mid["out"])
                    cells[backend] = {"wall": med, "lo": walls[0], "hi": walls[-1],
                                      "cpu": statistics.median(r["cpu"] for r in runs),
                                      "rss": max(r["rss"] for r in runs),
                                      "stages": stages_of(mid["out"]),
                                      "ran": backend_ran.group(1) if backend_ran else "?"}
                o3d = None
                if not colour and args.open3d and res <= args.max_open3d_res:
                    out = os.path.join(tmp, "o3d.raw")
                    r = run_rss([sys.executable, "-c", OPEN3D_WORKER, path, str(res), out])
                    if r["rc"] == 0:
                        o3d = {"wall": r["wall"], "rss": r["rss"], "cpu": r["cpu"]}
                    else:
                        print(f"Open3D failed: {r['err'][-300:]}", file=sys.stderr)
                rows.append((name, res, ext, colour, cells, o3d))
                _print_row(rows[-1])
    print()
    print_e2e_table(rows)


def _fmt_stages(st: dict) -> str:
    return ", ".join(f"{k} {v:.2f}" for k, v in st.items() if k != "time")


def _print_row(row) -> None:
    name, res, ext, colour, cells, o3d = row
    bits = [f"{b} {c['wall']:.2f}s" for b, c in cells.items()]
    if o3d:
        bits.append(f"open3d {o3d['wall']:.2f}s")
    print(f"# {name} {res}^3 {ext}{' --color' if colour else ''}: " + ", ".join(bits), flush=True)


def print_e2e_table(rows) -> None:
    print("| model | grid | output | colour | backend | wall (s), median | range (s) | CPU (s) "
          "| peak RSS (MiB) | Open3D end to end: wall / CPU (s) | Open3D / geovox (wall) "
          "| stages (s), median run |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, res, ext, colour, cells, o3d in rows:
        for backend, c in cells.items():
            label = backend if backend != "default" else f"default ({c['ran']})"
            ratio = f"{o3d['wall'] / c['wall']:.1f}×" if o3d else ""
            o3 = f"{o3d['wall']:.2f} / {o3d['cpu']:.2f}" if o3d else ("n/a" if colour else "not run")
            print(f"| {name} | {res}³ | {ext} | {'yes' if colour else 'no'} | {label} | "
                  f"{c['wall']:.2f} | {c['lo']:.2f}-{c['hi']:.2f} | {c['cpu']:.2f} | "
                  f"{c['rss'] / 2**20:.0f} | {o3} | "
                  f"{ratio} | {_fmt_stages(c['stages'])} |")


# --- import times ---------------------------------------------------------------------------

def bench_imports(args) -> None:
    cases = [
        ("python -c pass", [sys.executable, "-c", "pass"]),
        ('python -c "import numpy"', [sys.executable, "-c", "import numpy"]),
        ('python -c "import geovox"', [sys.executable, "-c", "import geovox"]),
        ("geovox --help", _geovox_cmd() + ["--help"]),
        ('python -c "import trimesh"', [sys.executable, "-c", "import trimesh"]),
        ('python -c "import trimesh.ray.ray_pyembree"',
         [sys.executable, "-c", "import trimesh.ray.ray_pyembree"]),
    ]
    print("| command | wall (s), median of %d | range (s) | CPU (s), median |" % args.import_repeat)
    print("|---|---|---|---|")
    for label, cmd in cases:
        runs = [run_rss(cmd) for _ in range(args.import_repeat)]
        walls = sorted(r["wall"] for r in runs)
        cpu = statistics.median(r["cpu"] for r in runs)
        print(f"| `{label}` | {statistics.median(walls):.3f} | {walls[0]:.3f}-{walls[-1]:.3f} | "
              f"{cpu:.3f} |", flush=True)


# --- auto rule: first call per backend, every corpus model -------------------------------

AUTO_WORKER = r"""
import sys, time, json
import geovox
from geovox.backends import get_backend
path, n, backend = sys.argv[1], int(sys.argv[2]), sys.argv[3]
mesh = geovox.load_mesh(path)
t = time.perf_counter()
# inside="parity": the same job for both backends on open models too (winding
# casts the same rays and adds caps that do not depend on the backend).
vol = geovox.voxelize(mesh, resolution=n, backend=backend, inside="parity")
print(json.dumps({"t": time.perf_counter() - t, "backend": vol.backend,
                  "auto": get_backend("auto").name,
                  "inside": vol.inside_count, "tri": len(mesh.faces)}))
"""


def corpus_models() -> list:
    return sorted(glob.glob(os.path.join(CORPUS, "**", "*.obj"), recursive=True))


def bench_auto_rule(args, tmp) -> None:
    """First call of each backend per model and grid; ``auto`` runs the NumPy
    code itself (it resolves to it), so ``auto / fastest`` is
    ``numpy / min(numpy, embree)``: timing ``auto`` separately would only
    time NumPy twice and add the machine's noise."""
    models = corpus_models() + [model_paths(["bunny105k"], tmp)["bunny105k"]]
    print(f"| model | triangles | grid | numpy first call (s), best of {args.auto_repeat} | "
          f"embree first call (s), best of {args.auto_repeat} | embree / numpy | auto runs | "
          f"auto / fastest | inside voxels equal |")
    print("|---|---|---|---|---|---|---|---|---|")
    worst = 0.0
    for path in models:
        for res in args.res:
            got = {}
            # Interleaved repeats, best of each: on a shared machine a single
            # run of either can be slowed by another job.
            for _ in range(args.auto_repeat):
                for backend in ("numpy", "embree"):
                    r = run_timed([sys.executable, "-c", AUTO_WORKER, path, str(res), backend])
                    if r["rc"] != 0:
                        print(f"FAILED {path} {res} {backend}: {r['err'][-300:]}", file=sys.stderr)
                        continue
                    one = json.loads(r["out"].strip().splitlines()[-1])
                    if got.get(backend) is None or one["t"] < got[backend]["t"]:
                        got[backend] = one
            if not (got.get("numpy") and got.get("embree")):
                continue
            auto = got["numpy"]["auto"]
            ratio = got[auto]["t"] / min(got["numpy"]["t"], got["embree"]["t"])
            worst = max(worst, ratio)
            same = got["numpy"]["inside"] == got["embree"]["inside"]
            rel = os.path.relpath(path, CORPUS) if path.startswith(CORPUS) else os.path.basename(path)
            print(f"| {rel} | {got['numpy']['tri']:,} | {res}³ | {got['numpy']['t']:.3f} | "
                  f"{got['embree']['t']:.3f} | {got['embree']['t'] / got['numpy']['t']:.1f} | "
                  f"{auto} | {ratio:.2f} | {'yes' if same else 'NO'} |", flush=True)
    print(f"\nworst auto / fastest: {worst:.2f}")


# --- Embree set-up against NumPy's whole first call (issue 11) ----------------------------

SETUP_WORKER = r"""
import sys, time, json
import numpy as np
import geovox
path, n, mode, warm = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
backend = "numpy" if mode == "numpy" else "embree"
# Imports warmed on another mesh, so the timed calls pay only for this one;
# that mesh is kept, and with it its Embree scene, so that Embree's thread
# pool stays up (freeing a process's last scene tears it down, and the
# next scene's first query then starts it again, about 2 ms).
warmed = geovox.load_mesh(warm)
geovox.voxelize(warmed, resolution=16, backend=backend)
mesh = geovox.load_mesh(path)
out = {"scene": 0.0, "scene_cpu": 0.0, "coplanar": 0.0, "coplanar_cpu": 0.0}
first = [True]


def clock():
    # Wall and CPU (all threads of the process: user + system).
    return time.perf_counter(), time.process_time()


if backend == "embree":
    # The set-up is timed inside the first call, for the lattice it casts:
    # the coplanar check, and the rest of the set-up (the scene, with the
    # BVH that Embree builds on the first query) as "scene".
    from geovox.backends import embree as E, get_backend

    engine = get_backend("embree")
    setup, check = engine.setup, E._check

    def timed_check(*a):
        t, c = clock()
        r = check(*a)
        if first[0]:
            out["coplanar"] += time.perf_counter() - t
            out["coplanar_cpu"] += time.process_time() - c
        return r

    def timed_setup(m, columns):
        t, c = clock()
        before = out["coplanar"], out["coplanar_cpu"]
        r = setup(m, columns)
        if r[0] is not None:
            r[0].intersects_first(np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
        if first[0]:
            out["scene"] += time.perf_counter() - t - (out["coplanar"] - before[0])
            out["scene_cpu"] += time.process_time() - c - (out["coplanar_cpu"] - before[1])
        return r

    E._check, engine.setup = timed_check, timed_setup


def timed(name, f):
    t, c = clock()
    f()
    out[name], out[name + "_cpu"] = time.perf_counter() - t, time.process_time() - c


timed("first", lambda: geovox.voxelize(mesh, resolution=n, backend=backend))
first[0] = False
timed("warm", lambda: geovox.voxelize(mesh, resolution=n, backend=backend))
print(json.dumps(out))
"""


def bench_setup(args, tmp) -> None:
    """Embree's set-up (scene with its BVH, coplanar check, for the lattice
    the call casts; timed inside the Embree first call) against the NumPy
    backend's whole first call, each in its own fresh process with the
    imports warmed on spot first; default options (``inside="auto"``).
    Medians (range) of wall and of CPU time (user + system, all threads),
    which a loaded machine inflates far less."""
    paths = model_paths(args.models, tmp)
    modes = ("numpy", "embree")
    print("| model | triangles | grid | time | NumPy first call (s) | NumPy warm (s) "
          "| Embree scene + BVH (s) | Embree coplanar check (s) | Embree set-up (s) "
          "| set-up / NumPy first call | Embree first call (s) | Embree warm (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, path in paths.items():
        tri = None
        for res in args.res:
            got = {m: [] for m in modes}
            for _ in range(args.repeat):  # interleaved, so load hits all alike
                for mode in modes:
                    r = run_timed([sys.executable, "-c", SETUP_WORKER, path, str(res), mode, SPOT])
                    if r["rc"] != 0:
                        print(f"FAILED {name} {res} {mode}: {r['err'][-300:]}", file=sys.stderr)
                        continue
                    got[mode].append(json.loads(r["out"].strip().splitlines()[-1]))
            if not all(got.values()):
                continue
            if tri is None:
                code = "import geovox, sys; print(len(geovox.load_mesh(sys.argv[1]).faces))"
                tri = int(run_timed([sys.executable, "-c", code, path])["out"])

            def cell(mode, key):
                v = sorted(x[key] for x in got[mode])
                return statistics.median(v), f"{statistics.median(v):.3f} ({v[0]:.3f}-{v[-1]:.3f})"

            for x in got["embree"]:
                x["setup"] = x["scene"] + x["coplanar"]
                x["setup_cpu"] = x["scene_cpu"] + x["coplanar_cpu"]
            corpus = os.path.realpath(CORPUS) + os.sep
            real = os.path.realpath(path)
            label = os.path.relpath(real, corpus) if real.startswith(corpus) else name
            for unit in ("", "_cpu"):
                print(f"| {label} | {tri:,} | {res}³ | {'CPU' if unit else 'wall'} | "
                      f"{cell('numpy', 'first' + unit)[1]} | {cell('numpy', 'warm' + unit)[1]} | "
                      f"{cell('embree', 'scene' + unit)[1]} | "
                      f"{cell('embree', 'coplanar' + unit)[1]} | "
                      f"{cell('embree', 'setup' + unit)[1]} | "
                      f"{cell('embree', 'setup' + unit)[0] / cell('numpy', 'first' + unit)[0]:.2f} | "
                      f"{cell('embree', 'first' + unit)[1]} | {cell('embree', 'warm' + unit)[1]} |",
                      flush=True)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--only", choices=["e2e", "imports", "auto-rule", "setup"], action="append",
                   help="run only these parts (repeatable); default: e2e and imports")
    p.add_argument("--models", default="spot,bunny105k", type=lambda s: s.split(","))
    p.add_argument("--res", default=None, type=lambda s: [int(x) for x in s.split(",")],
                   help="default 128,256,512,1024 (auto-rule: 64,128,256,512,1024)")
    p.add_argument("--colour", default="both", choices=["off", "on", "both"])
    p.add_argument("--max-colour-res", type=int, default=512,
                   help="largest grid run with --color (default 512)")
    p.add_argument("--backends", default=",".join(BACKENDS), type=lambda s: s.split(","))
    p.add_argument("--repeat", type=int, default=3, help="runs per cell (median)")
    p.add_argument("--import-repeat", type=int, default=7)
    p.add_argument("--auto-repeat", type=int, default=2, help="auto-rule: runs per cell (best)")
    p.add_argument("--no-open3d", dest="open3d", action="store_false")
    p.add_argument("--max-open3d-res", type=int, default=512)
    p.add_argument("--vs", metavar="TREE",
                   help="e2e: run each cell (default backend) by this tree and by the geovox "
                        "source tree TREE in turn, with pair-by-pair ratios")
    args = p.parse_args()
    parts = args.only or ["imports", "e2e"]
    print(f"load average before: {os.getloadavg()}, {os.cpu_count()} cores, "
          f"{time.strftime('%Y-%m-%d %H:%M %Z')}", flush=True)
    tmp = tempfile.mkdtemp(prefix="bench_cli_")
    try:
        if "imports" in parts:
            bench_imports(args)
            print()
        if "e2e" in parts:
            if args.res is None:
                args.res = [128, 256, 512, 1024]
            (bench_vs if args.vs else bench_e2e)(args, tmp)
            print()
        if "setup" in parts:
            if args.res is None:
                args.res = [256]
            bench_setup(args, tmp)
            print()
        if "auto-rule" in parts:
            if args.res is None or ("e2e" in parts and args.res == [128, 256, 512, 1024]):
                args.res = [64, 128, 256, 512, 1024]
            bench_auto_rule(args, tmp)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    print(f"load average after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
