"""Surface voxels: geovox's exact kernel against Open3D's, same run, same voxels.

``geovox.surface.surface_voxels`` (every voxel whose half-open box the
surface meets; issue 35) against Open3D's
``VoxelGrid.create_from_triangle_mesh_within_bounds`` on the same grid: a
cube of N³ cubic voxels over the model's longest side at its box's minimum
corner (``make_grid(..., fit="cube")``), Open3D given the same origin and
voxel size. Each measurement runs in a fresh interpreter, so peak memory is
its own; the mesh is loaded and handed over before the clock starts.

* ``first``: geovox's first call, which also pays for the output's pages
  (a fresh N³ bool array is calloc'd; its pages are faulted in as voxels are
  set); ``best``: the best of several calls on a reused output buffer
  (``out=``), the kernel alone.
* Open3D: the best of its calls (one at 1024³).
* ``agree``: voxels in one answer and not the other, as a share of geovox's
  count. Open3D tests closed boxes in floating point, so a surface lying on
  a voxel plane lights both voxels there (the rule lights one); the
  differing voxels are split by an exact rational test
  (tests/surface_reference.py) into ties (the surface meets the voxel's
  closed box but not its half-open one) and the rest.

Models: ``spot`` (data/spot), ``bunny105k`` (benchmarks/common.py),
``cadbox`` (a box with its faces on voxel planes, where the rules differ),
``dragon`` (the Stanford dragon, 100,000 triangles: ``--dragon PATH``, else
``$GEOVOX_DRAGON``, else ``../shared/corpus/dragon/dragon.ply``; bunny105k
stands in where it is missing, and the table says so), and ``bunny1.6m`` and
``dragon1.6m`` (subdivided twice with trimesh, 16x the triangles).

Whole process (``--whole``): the user's command, ``geovox convert MODEL -o OUT -r N --cube
--occupancy surface`` with default options (its threads included), in a fresh process each time,
against a fresh process that imports Open3D, reads the same file and calls
``create_from_triangle_mesh_within_bounds`` on the same grid (it writes nothing); the two run in
turn, A B A B ..., ``--rounds`` times, and the table gives medians and the median of the pairs'
ratios. Peak memory is the process's own (``wait4``'s ``ru_maxrss``). Start-up floors are timed
the same way: ``python -c pass``, ``python -c "import numpy"`` (and with
``OPENBLAS_NUM_THREADS=1``: OpenBLAS starts its threads at import) and a 16³ conversion of spot.
The 1.6M-triangle dragon is written to a temporary binary PLY first (trimesh, subdivided twice).

In process (``--inprocess``): ``geovox.convert_to`` of the dragon into ``.ply`` (plan, surface
voxels, writing) in a process that has converted once already, against Open3D's
``create_from_triangle_mesh_within_bounds`` alone, on the same grid.

A data set (``--dataset DIR`` or ``--dataset-git GIT_DIR``, e.g. trimesh's ``models/``): the
files geovox loads (probed in separate processes, as ``bench_dataset.py`` does) through one
fresh ``geovox convert MESHES -o OUT -r N --cube --occupancy surface --format ply`` (default
options: a pool of one process per core), against Open3D's ``create_from_triangle_mesh`` with
voxel size = the longest side of its own loaded mesh / N, one process, each model under a
time-out (``bench_dataset.py``'s worker: its time is its start and imports plus the models it
converted). Models per second = models converted / time.

``--results FILE`` writes what ran as a result file for ``benchmarks/tables.py``.

Usage: python benchmarks/bench_surface.py [--models dragon spot bunny105k bunny1.6m]
           [--res 256 1024] [--jobs 1 2] [--dragon PATH] [--no-open3d] [--agreement 128]
           [--whole] [--rounds 7] [--inprocess] [--dataset DIR | --dataset-git GIT_DIR]
           [--dataset-res 64] [--no-kernel] [--results benchmarks/results/surface.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import CORPUS, ROOT, load_model, peak_rss, reset_peak, run_worker  # noqa: E402

DRAGON_DEFAULT = os.path.join(CORPUS, "dragon", "dragon.ply")


def dragon_path():
    path = os.environ.get("GEOVOX_DRAGON") or DRAGON_DEFAULT
    return path if os.path.exists(path) else None


def load(name):
    """(Mesh, what it is): a benchmark model; the dragon falls back to bunny105k."""
    import geovox

    # bunny1.6m is bunny105k subdivided twice, dragon1.6m the dragon.
    base = {"bunny1.6m": "bunny105k", "dragon1.6m": "dragon"}.get(name, name)
    what = base
    if base == "cadbox":
        # A box whose faces lie on voxel planes of the cube grids (1/128 of
        # its longest side and finer): the rules differ there, at ties.
        import trimesh

        box = trimesh.creation.box(bounds=[(0, 0, 0), (1, 0.5, 0.75)])
        v, f = box.vertices, box.faces
        for _ in range(5):
            v, f = trimesh.remesh.subdivide(v, f)
        return geovox.Mesh(v, f, source="cadbox"), "CAD box on voxel planes"
    if base == "dragon":
        path = dragon_path()
        if path is None:
            base, what = "bunny105k", "bunny105k (no dragon here)"
            mesh = load_model(base)
        else:
            mesh = geovox.load_mesh(path)
    else:
        mesh = load_model(base)
    if name.endswith("1.6m"):
        import trimesh

        v, f = mesh.vertices, mesh.faces
        for _ in range(2):
            v, f = trimesh.remesh.subdivide(v, f)
        mesh = geovox.Mesh(v, f, source=name)
        what += " ×16"
    return mesh, what


def grid_for(mesh, res):
    from geovox.grid import make_grid

    return make_grid(mesh.bounds, resolution=res, fit="cube")


def worker(engine, model, res, jobs):
    import numpy as np

    mesh, what = load(model)
    grid = grid_for(mesh, res)
    repeats = 5 if res <= 256 else 2
    if engine == "open3d":
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                      o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
        times, peak = [], 0
        for _ in range(repeats if res < 1024 else 1):
            reset_peak()
            base = peak_rss()
            t0 = time.perf_counter()
            vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(
                m, float(grid.spacing[0]), grid.lo, grid.hi)
            times.append(time.perf_counter() - t0)
            peak = max(peak, peak_rss() - base)
            count = len(vg.get_voxels()) if _ == 0 else count
            del vg
        return {"what": what, "tris": len(mesh.faces), "time": min(times), "peak": peak,
                "count": count}
    from geovox.surface import surface_voxels

    tris = np.ascontiguousarray(mesh.triangles)
    surface_voxels(tris[:1], grid_for(mesh, 4))  # imports, and the kernel's module
    reset_peak()
    base = peak_rss()
    t0 = time.perf_counter()
    out = surface_voxels(tris, grid, jobs=jobs)
    first = time.perf_counter() - t0
    peak = peak_rss() - base
    count = int(np.count_nonzero(out))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        surface_voxels(tris, grid, jobs=jobs, out=out)
        times.append(time.perf_counter() - t0)
    return {"what": what, "tris": len(tris), "first": first, "time": min(times), "peak": peak,
            "count": count}


def agreement(model, res):
    """geovox against Open3D on one grid: counts, differences, and how many are ties."""
    import numpy as np
    import open3d as o3d

    from geovox.surface import surface_voxels

    mesh, what = load(model)
    grid = grid_for(mesh, res)
    ours = surface_voxels(np.ascontiguousarray(mesh.triangles), grid)
    m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                  o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
    vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(
        m, float(grid.spacing[0]), grid.lo, grid.hi)
    idx = np.array([v.grid_index for v in vg.get_voxels()], dtype=np.int64).reshape(-1, 3)
    inside = ((idx >= 0) & (idx < np.asarray(grid.shape))).all(axis=1)
    theirs = np.zeros(grid.shape, dtype=bool)
    theirs[tuple(idx[inside].T)] = True
    only_ours = np.argwhere(ours & ~theirs)
    only_theirs = np.argwhere(theirs & ~ours)
    # The exact test is slow in Fractions: beyond 400 differing voxels, a
    # sample of 400 is classified and the count scaled (marked "~").
    differ = np.concatenate([only_ours, only_theirs])
    sample = differ
    if len(sample) > 400:
        sample = sample[np.random.default_rng(0).choice(len(sample), 400, replace=False)]
    ties = _ties(mesh.triangles, grid, sample) * len(differ) / max(len(sample), 1)
    return {"what": what, "ours": int(ours.sum()), "theirs": int(theirs.sum()),
            "outside": int((~inside).sum()), "only_ours": len(only_ours),
            "only_theirs": len(only_theirs), "ties": round(ties),
            "sampled": len(sample) < len(differ)}


def _ties(triangles, grid, voxels):
    """How many of ``voxels`` are ties: the surface meets their closed box, never their interior.

    There the two rules may differ (Open3D tests closed boxes in floating
    point, from the voxel holding each triangle's lowest corner); anywhere
    else, a differing voxel is one of them missing the surface, or lighting
    a voxel it does not reach.
    """
    import numpy as np

    sys.path.insert(0, os.path.join(ROOT, "tests"))
    from fractions import Fraction

    from surface_reference import clipped, touches_only

    lo, h = grid.lo, grid.spacing
    tmin, tmax = triangles.min(axis=1), triangles.max(axis=1)
    ties = 0
    for v in voxels:
        blo, bhi = lo + v * h, lo + (v + 1) * h
        near = np.flatnonzero((tmax >= blo).all(axis=1) & (tmin <= bhi).all(axis=1))
        box_lo = [Fraction(float(x)) for x in blo]
        box_hi = [Fraction(float(x)) for x in bhi]
        tris = [[[Fraction(float(x)) for x in p] for p in triangles[t]] for t in near]
        touching = [t for t in tris if clipped(t, box_lo, box_hi)]
        ties += bool(touching) and all(touches_only(t, box_lo, box_hi) for t in touching)
    return ties


def loadavg():
    with open("/proc/loadavg") as f:
        return " ".join(f.read().split()[:3])


# ---- whole process ---------------------------------------------------------------

OPEN3D_SCRIPT = """
import sys
import numpy as np
import open3d as o3d
o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
path, h = sys.argv[1], float(sys.argv[2])
lo, hi = np.array(sys.argv[3:6], float), np.array(sys.argv[6:9], float)
mesh = o3d.io.read_triangle_mesh(path)
vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(mesh, h, lo, hi)
print(len(vg.get_voxels()))
"""


def timed(cmd, env=None):
    """``(wall seconds, peak MiB)`` of one fresh process (its output dropped).

    The peak is GNU time's (``%M``): a child's own ``ru_maxrss`` counts this process's memory
    too, for Linux keeps the high-water mark of the forked copy across ``exec``.
    """
    import tempfile

    with tempfile.NamedTemporaryFile("r", suffix=".time") as peak:
        t0 = time.perf_counter()
        proc = subprocess.run(["/usr/bin/time", "-f", "%M", "-o", peak.name, *cmd],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env,
                              cwd=ROOT, check=False)
        wall = time.perf_counter() - t0
        if proc.returncode:
            tail = proc.stderr.decode(errors="replace").strip().splitlines()[-1:]
            raise RuntimeError(f"{' '.join(cmd[:6])} ... exited {proc.returncode}: {tail}")
        return wall, int(peak.read().split()[-1]) / 1024


def median(values):
    v = sorted(values)
    return v[len(v) // 2] if len(v) % 2 else 0.5 * (v[len(v) // 2 - 1] + v[len(v) // 2])


def dragon_file(name, tmp):
    """A model file for the command line: the dragon, or it subdivided twice (1.6M triangles)."""
    if name == "dragon":
        path = dragon_path()
        if path is None:
            raise SystemExit("--whole needs the dragon (--dragon PATH or $GEOVOX_DRAGON)")
        return path
    import trimesh

    mesh, _ = load(name)
    path = os.path.join(tmp, f"{name}.ply")
    trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(path)
    return path


def whole_process(rounds, have_o3d, tmp):
    """The whole-process rows: geovox's command against an Open3D process, in turn."""
    import geovox
    from geovox.grid import make_grid

    py = sys.executable
    gv = [py, "-m", "geovox", "convert"]
    rows, floors = [], []
    base = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    for label, cmd, env in (("`python -c pass`", [py, "-c", "pass"], None),
                            ("`python -c \"import numpy\"`", [py, "-c", "import numpy"], None),
                            ("the same, `OPENBLAS_NUM_THREADS=1`", [py, "-c", "import numpy"],
                             dict(os.environ, OPENBLAS_NUM_THREADS="1")),
                            ("`geovox convert spot.obj -r 16 --occupancy surface -o s.ply`",
                             gv + [os.path.join(ROOT, "data", "spot", "spot.obj"), "-r", "16",
                                   "--occupancy", "surface", "-o", os.path.join(tmp, "s.ply"),
                                   "-q"], base)):
            walls = [timed(cmd, env)[0] for _ in range(rounds)]
            floors.append([label, f"{median(walls):.3f}", f"{min(walls):.3f}-{max(walls):.3f}"])
            print(f"| {' | '.join(floors[-1])} |", flush=True)
    cases = [("dragon", 256, "raw", True), ("dragon", 256, "ply", True),
             ("dragon", 1024, "ply", True), ("dragon1.6m", 256, "ply", True),
             ("dragon", 2048, "ply", False), ("dragon", 2048, "h5", False)]
    files = {}
    for model, res, ext, with_o3d in cases:
        if model not in files:
            files[model] = dragon_file(model, tmp)
        path = files[model]
        mesh = geovox.load_mesh(path)
        grid = make_grid(mesh.bounds, resolution=res, fit="cube")
        out = os.path.join(tmp, f"out.{ext}")
        ours = gv + [path, "-o", out, "-r", str(res), "--cube", "--occupancy", "surface", "-q"]
        theirs = [py, "-c", OPEN3D_SCRIPT, path, repr(float(grid.spacing[0])),
                  *map(repr, map(float, grid.lo)), *map(repr, map(float, grid.hi))]
        peer = have_o3d and with_o3d
        n = rounds if res < 2048 else max(1, rounds // 3)
        a, b = [], []
        for _ in range(n):
            a.append(timed(ours, base))
            if peer:
                b.append(timed(theirs))
        wall, peak = median([x[0] for x in a]), max(x[1] for x in a)
        row = [f"{model} ({len(mesh.faces):,} triangles)", f"{res}³", f".{ext}", f"{wall:.3f}",
               f"{min(x[0] for x in a):.3f}-{max(x[0] for x in a):.3f}", f"{peak:.0f}"]
        if peer:
            ratio = median([y[0] / x[0] for x, y in zip(a, b)])
            row += [f"{median([y[0] for y in b]):.3f}", f"{max(y[1] for y in b):.0f}",
                    f"{ratio:.1f}×"]
        else:
            row += ["", "", ""]
        rows.append(row)
        print(f"| {' | '.join(row)} |", flush=True)
    return [
        {"caption": f"Start-up floors: fresh processes, median of {rounds}",
         "columns": ["command", "wall (s)", "range (s)"], "rows": floors},
        {"caption": f"Whole process, geovox's command (default options, `--cube --occupancy "
                    f"surface`) and an Open3D process on the same grid run in turn, median of "
                    f"{rounds} (2048³: {max(1, rounds // 3)})",
         "columns": ["model", "grid", "output", "geovox wall (s)", "range (s)",
                     "geovox peak (MiB)", "Open3D wall (s)", "Open3D peak (MiB)",
                     "Open3D / geovox (median of pairs)"],
         "rows": rows},
    ]


def inprocess_worker(engine, res):
    """One engine's in-process time on the dragon (a fresh process, warmed up first)."""
    import tempfile

    import numpy as np

    import geovox

    mesh, _ = load("dragon")
    grid = grid_for(mesh, res)
    if engine == "open3d":
        import open3d as o3d

        m = o3d.geometry.TriangleMesh(o3d.utility.Vector3dVector(mesh.vertices),
                                      o3d.utility.Vector3iVector(mesh.faces.astype(np.int32)))
        t0 = time.perf_counter()
        vg = o3d.geometry.VoxelGrid.create_from_triangle_mesh_within_bounds(
            m, float(grid.spacing[0]), grid.lo, grid.hi)
        return {"time": time.perf_counter() - t0, "count": len(vg.get_voxels())}
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "d.ply")
        geovox.convert_to(mesh, out, resolution=64, fit="cube", occupancy="surface")  # warm
        times = []
        for _ in range(3):
            t0 = time.perf_counter()
            info = geovox.convert_to(mesh, out, resolution=res, fit="cube", occupancy="surface")
            times.append(time.perf_counter() - t0)
        return {"time": median(times), "count": info.counts["surface"]}


def in_process(res=1024):
    ours = run_worker(__file__, "geovox", "inprocess", res, 0)
    theirs = run_worker(__file__, "open3d", "inprocess", res, 0)
    row = [f"dragon, {res}³", f"{ours['time']:.3f}", f"{theirs['time']:.3f}",
           f"{theirs['time'] / ours['time']:.1f}×", f"{ours['count']:,}", f"{theirs['count']:,}"]
    print(f"| {' | '.join(row)} |", flush=True)
    return {"caption": "In process: `geovox.convert_to(mesh, 'd.ply', occupancy='surface')` "
                       "(plan, surface voxels and writing; median of 3 after a warm-up) against "
                       "Open3D's `create_from_triangle_mesh_within_bounds` alone, same grid",
            "columns": ["model, grid", "geovox (s)", "Open3D (s)", "Open3D / geovox",
                        "geovox voxels", "Open3D voxels"],
            "rows": [row]}


# ---- a data set ------------------------------------------------------------------

def dataset(folder, res, timeout, have_o3d, tmp):
    """The data-set row: every mesh of ``folder`` through geovox's command and through Open3D."""
    import bench_dataset as bd

    files = bd.gather([folder])
    probed, _, _ = bd.run_items("probe", [(f,) for f in files], tmp, timeout)
    meshes = [f for f, r in zip(files, probed) if r["status"] == "ok"]
    out = os.path.join(tmp, "dataset-out")
    os.makedirs(out, exist_ok=True)
    manifest = os.path.join(tmp, "dataset.jsonl")
    cmd = [sys.executable, "-m", "geovox", "convert", *meshes, "-o", out, "-r", str(res),
           "--cube", "--occupancy", "surface", "--format", "ply", "--manifest", manifest, "-q"]
    load0 = loadavg()
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=bd.env(), cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    with open(manifest, encoding="utf-8") as f:
        records = [json.loads(line) for line in f if line.strip()]
    ok = sum(r["status"] == "ok" for r in records)
    rows = [[f"geovox `convert MESHES -r {res} --cube --occupancy surface --format ply` "
             f"(default: a process per core)", str(len(meshes)), str(ok),
             str(len(meshes) - ok), f"{wall:.1f}", f"{ok / wall:.1f}", load0]]
    print(f"| {' | '.join(rows[-1])} | exit {proc.returncode}", flush=True)
    if have_o3d:
        load0 = loadavg()
        t0 = time.perf_counter()
        recs, startup, _ = bd.run_items("open3d", [(f, res) for f in meshes], tmp, timeout)
        run_wall = time.perf_counter() - t0
        done = [r for r in recs if r["status"] == "ok"]
        spent = startup + sum(r["seconds"] for r in done)
        rows.append([f"Open3D `create_from_triangle_mesh` (one process; its start and imports "
                     f"+ the models it converted; whole run {run_wall:.1f} s)", str(len(meshes)),
                     str(len(done)), str(len(meshes) - len(done)), f"{spent:.1f}",
                     f"{len(done) / spent:.1f}", load0])
        print(f"| {' | '.join(rows[-1])} |", flush=True)
    return {"caption": f"A data set: {len(meshes)} meshes geovox loads of {len(files)} files in "
                       f"{os.path.basename(folder.rstrip('/'))}/, {res}³ surface voxels, "
                       f"models per second",
            "columns": ["tool", "meshes", "converted", "not converted", "time (s)", "models/s",
                        "load before"],
            "rows": rows}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--worker", nargs=4)
    p.add_argument("--models", nargs="+", default=["dragon", "spot", "bunny105k", "bunny1.6m"])
    p.add_argument("--res", type=int, nargs="+", default=[256, 1024])
    p.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    p.add_argument("--dragon", default=None, help="the Stanford dragon (PLY/OBJ)")
    p.add_argument("--no-open3d", action="store_true")
    p.add_argument("--agreement", type=int, nargs="*", default=[128],
                   help="grids on which to compare the voxels with Open3D's (none: skip)")
    p.add_argument("--no-kernel", action="store_true", help="skip the kernel table")
    p.add_argument("--whole", action="store_true", help="whole-process timings")
    p.add_argument("--rounds", type=int, default=7)
    p.add_argument("--inprocess", action="store_true", help="convert_to against Open3D, 1024³")
    p.add_argument("--dataset", default=None, help="a folder of models (trimesh's models/)")
    p.add_argument("--dataset-git", default=None, help="models/ of a clone's HEAD")
    p.add_argument("--dataset-res", type=int, default=64)
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--results", default=None, help="write a result file for tables.py")
    args = p.parse_args()
    if args.dragon:
        os.environ["GEOVOX_DRAGON"] = os.path.abspath(args.dragon)
    if args.worker:
        engine, model, res, jobs = args.worker
        if model == "inprocess":
            print(json.dumps(inprocess_worker(engine, int(res))))
            return
        print(json.dumps(worker(engine, model, int(res), int(jobs))))
        return
    try:
        import open3d  # noqa: F401

        have_o3d = not args.no_open3d
    except ImportError:
        have_o3d = False
    start, load_before = datetime.datetime.now(datetime.UTC), loadavg()
    print(f"# bench_surface {start:%Y-%m-%d %H:%M} UTC: load average {load_before} (before), "
          f"{os.cpu_count()} CPUs, Open3D {'yes' if have_o3d else 'no'}, "
          f"dragon {dragon_path() or 'missing: bunny105k stands in'}")
    print()
    tables, models = [], []
    if not args.no_kernel:
        tables += kernel_tables(args, have_o3d)
        models += [f"{m}" for m in args.models]
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        if args.whole:
            tables += whole_process(args.rounds, have_o3d, tmp)
        if args.inprocess and have_o3d:
            tables.append(in_process())
        folder = args.dataset
        if args.dataset_git:
            import bench_dataset as bd

            folder, commit = bd.extract_git(args.dataset_git, tmp)
            models.append(f"the data set: trimesh's models/ at {commit[:12]}")
        if folder:
            tables.append(dataset(folder, args.dataset_res, args.timeout, have_o3d, tmp))
    print()
    print(f"load average {loadavg()} (after)")
    if args.results:
        write_results(args, tables, models, start, load_before, have_o3d)


def kernel_tables(args, have_o3d):
    """The kernel against Open3D in process, and where their voxels differ."""
    print("| model | triangles | grid | engine | jobs | first (s) | best (s) | vs Open3D "
          "| peak rise (MiB) | output (MiB) | voxels |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    rows = []
    for model in args.models:
        for res in args.res:
            if model.endswith("1.6m") and res > 256:
                continue  # the target for 1.6M triangles is at 256³
            o3d = run_worker(__file__, "open3d", model, res, 1) if have_o3d else {}
            results = [("geovox", j, run_worker(__file__, "geovox", model, res, j))
                       for j in args.jobs]
            if have_o3d:
                results.append(("open3d", 1, o3d))
            for engine, jobs, r in results:
                if "error" in r:
                    print(f"| {model} | | {res}³ | {engine} | {jobs} | error: {r['error']} "
                          "| | | | | |", flush=True)
                    continue
                ratio = (f"{o3d['time'] / r['time']:.1f}× faster"
                         if engine == "geovox" and "time" in o3d else "")
                first = f"{r['first']:.3f}" if "first" in r else ""
                row = [r["what"], f"{r['tris']:,}", f"{res}³", engine, str(jobs), first,
                       f"{r['time']:.3f}", ratio, f"{r['peak'] / 2**20:.0f}",
                       f"{res**3 / 2**20:.0f}", f"{r['count']:,}"]
                print(f"| {' | '.join(row)} |", flush=True)
                rows.append(row)
    tables = [{"caption": "The kernel in process (`surface_voxels`, the mesh loaded before the "
                          "clock): first call (a fresh output) and best of several on a reused "
                          "one, against Open3D's `create_from_triangle_mesh_within_bounds`",
               "columns": ["model", "triangles", "grid", "engine", "jobs", "first (s)",
                           "best (s)", "vs Open3D", "peak rise (MiB)", "output (MiB)", "voxels"],
               "rows": rows}]
    if have_o3d and args.agreement:
        print()
        print("| model | grid | geovox voxels | Open3D voxels (outside the grid) | only geovox "
              "| only Open3D | of which ties | differing, not ties |")
        print("|---|---|---|---|---|---|---|---|")
        agree = []
        for model in args.models:
            if model.endswith("1.6m"):
                continue
            for res in args.agreement:
                a = agreement(model, res)
                rest = a["only_ours"] + a["only_theirs"] - a["ties"]
                row = [a["what"], f"{res}³", f"{a['ours']:,}",
                       f"{a['theirs']:,} ({a['outside']:,})", f"{a['only_ours']:,}",
                       f"{a['only_theirs']:,}", f"{'~' * a['sampled']}{a['ties']:,}",
                       f"{rest:,} ({100 * rest / max(a['ours'], 1):.3f} %)"]
                print(f"| {' | '.join(row)} |", flush=True)
                agree.append(row)
        tables.append({"caption": "The same voxels as Open3D's, inside the grid, but at ties",
                       "columns": ["model", "grid", "geovox voxels",
                                   "Open3D voxels (outside the grid)", "only geovox",
                                   "only Open3D", "of which ties", "differing, not ties"],
                       "rows": agree})
    return tables


def write_results(args, tables, models, start, load_before, have_o3d):
    """The result file ``benchmarks/tables.py`` renders (the figures of this run)."""
    import numpy

    argv = " ".join(a if " " not in a else repr(a) for a in sys.argv[1:])
    versions = f"numpy {numpy.__version__}"
    if have_o3d:
        import open3d

        versions += f", Open3D {open3d.__version__}"
    result = {
        "benchmark": "surface",
        "title": "Surface voxels against Open3D",
        "script": "benchmarks/bench_surface.py",
        "command": f"python benchmarks/bench_surface.py {argv}",
        "date": f"{start:%Y-%m-%d, %H:%M}-{datetime.datetime.now(datetime.UTC):%H:%M} UTC",
        "machine": f"the project machine: {os.cpu_count()} cores shared with other users, "
                   f"Python {sys.version_info.major}.{sys.version_info.minor}, {versions}; load "
                   f"average {load_before} before, {loadavg()} after",
        "models": models,
        "notes": NOTES,
        "tables": tables,
    }
    with open(args.results, "w", encoding="utf-8") as f:
        json.dump(result, f, indent=1, ensure_ascii=False)
        f.write("\n")


#: What every result file of this script says about its figures.
NOTES = ("geovox's surface voxels (every voxel whose half-open box the surface meets, issue 35) "
         "and Open3D's on the same grid: a cube of N³ cubic voxels over the model's longest side "
         "(`-r N --cube`), Open3D given the same voxel size and bounds. Whole-process figures "
         "start the interpreter; Python and NumPy's start alone is the first table. The machine "
         "is shared: compare within a table, and pairs within a row.")


if __name__ == "__main__":
    main()
