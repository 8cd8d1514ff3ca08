"""A whole data set through ``geovox convert``: models per second, the slowest models, the peers.

The data set is every file of trimesh's ``models/`` folder (``--models``, about 225 files of
every format, many broken on purpose, 2-D drawings among them) and of the shared corpus
(``--corpus``). Nothing is downloaded: point ``--models`` at your own copy, e.g.::

    git clone --depth 1 https://github.com/mikedh/trimesh ../trimesh
    python benchmarks/bench_dataset.py --models ../trimesh/models

(default: ``../trimesh/models`` beside this checkout), or ``--models-git GIT_DIR`` to take the
``models/`` folder of a clone's ``HEAD`` (bare clones too) into a temporary folder.

What it does:

1. **Which files are meshes.** Every file is loaded by geovox's own loader (in a separate
   process, each file with a time-out): a file it refuses with its one-line error (a material
   library, a texture, a glTF buffer, a point cloud, a 2-D drawing, an empty file, a format
   that needs a package not installed) is not part of the data set; the table counts them by
   reason. A loader failure that is not a geovox error (a traceback) is a bug and is listed.
2. **geovox, the user's command.** For each grid (``--res``, 64 and 128), format (``--formats``,
   ``binvox`` and ``npz``) and engine (``--engines``: ``j2`` = ``--jobs 2``, the local process
   pool; ``lc2`` = ``--local-cluster 2``, two Dask workers started by the command), one fresh
   ``geovox convert MESH ... -o OUT -r N --format F --manifest OUT.jsonl`` over every mesh,
   timed from outside: wall (``time.perf_counter``) and CPU (``os.wait4``'s usage: the CLI and
   every process it reaped). Models per second = converted models / wall. The per-model time
   and inside test come from the manifest (``seconds``: the model's own time where it ran;
   ``inside_test``). ``-r N`` is what the format makes of it: for ``.binvox`` binvox's ``-d N``
   cube, voxel edge = the bounding box's longest side / N (the peers' voxel size); for ``.npz``
   N voxels along each side of the bounding box.
3. **The peers, same models, same voxel size** (longest side of the bounding box of each tool's
   own loaded mesh / N), one process per tool and grid, each model under a time-out
   (``--timeout``, 60 s; a model over it is counted, the process restarted after it):
   Open3D ``o3d.io.read_triangle_mesh`` + ``VoxelGrid.create_from_triangle_mesh(mesh,
   voxel_size)`` (the surface voxels the TRELLIS data pipeline uses), trimesh
   ``trimesh.load(path, force="mesh")`` + ``mesh.voxelized(pitch).fill()``. A model the tool
   cannot load (nothing read, or an exception while loading) is counted, not timed. Time =
   the process's start and imports + the load and voxelisation of the models it converted
   (failures and time-outs excluded, so the figure flatters the peer where there are many);
   the peers run on one core, so compare CPU seconds as well as models/s.

The machine may be shared: the load average is sampled every 5 s and reported with the
figures. ``--results FILE`` writes the result file that ``benchmarks/tables.py`` renders.

Usage::

    python benchmarks/bench_dataset.py [--models DIR ...] [--models-git GIT_DIR]
        [--corpus DIR] [--res 64 128] [--formats binvox npz] [--engines j2 lc2]
        [--peers open3d trimesh] [--timeout 60] [--results benchmarks/results/dataset.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import selectors
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)

from benchmarks.common import CORPUS  # noqa: E402

DEFAULT_MODELS = os.path.join(ROOT, "..", "trimesh", "models")
#: --engines: name -> the CLI's options and the table's words
ENGINES = {"j2": (["--jobs", "2"], "--jobs 2"), "j1": (["--jobs", "1"], "--jobs 1"),
           "lc2": (["--local-cluster", "2"], "--local-cluster 2"),
           "lc1": (["--local-cluster", "1"], "--local-cluster 1")}
#: worker lines start with this (Open3D and trimesh print their own lines on stdout)
MARK = "@@bench "


def env():
    """This checkout's geovox first; no Dask scheduler from the caller's environment."""
    e = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    e.pop("DASK_SCHEDULER_ADDRESS", None)
    return e


# --------------------------------------------------------------------------- the files


def gather(folders) -> list:
    """Every file under ``folders`` (recursively, sorted), absolute paths."""
    found = []
    for folder in folders:
        for root, dirs, files in os.walk(folder):
            dirs.sort()
            found += [os.path.abspath(os.path.join(root, f)) for f in sorted(files)]
    return found


def extract_git(git_dir, into) -> tuple:
    """``HEAD:models/`` of a (bare) clone into the folder ``into``: (models folder, commit)."""
    commit = subprocess.run(["git", "--git-dir", git_dir, "rev-parse", "HEAD"], check=True,
                            capture_output=True, text=True).stdout.strip()
    archive = subprocess.run(["git", "--git-dir", git_dir, "archive", "HEAD", "models"],
                             check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", into], input=archive, check=True)
    return os.path.join(into, "models"), commit


def reason(error, path) -> str:
    """A loader error without its file name and counts: the table's reason."""
    text = error.replace(path, "FILE")
    text = text.split("FILE: ", 1)[-1].split("; ", 1)[0]
    return re.sub(r"\b\d[\d,.]*\b(?!-D)", "N", text)  # counts, not "2-D"


# --------------------------------------------------------------------------- workers


def work_probe(path):
    from geovox.errors import GeovoxError
    from geovox.io.load import load_mesh

    try:
        mesh = load_mesh(path)
    except GeovoxError as exc:
        return {"status": "not a mesh", "error": " ".join(str(exc).split())}
    except Exception as exc:  # not geovox's one line: a bug
        return {"status": "BUG", "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}"}
    return {"status": "ok", "triangles": int(len(mesh.faces))}


def work_open3d(path, res):
    import numpy as np
    import open3d as o3d

    t0 = time.perf_counter()
    try:
        mesh = o3d.io.read_triangle_mesh(path)
    except Exception as exc:
        return {"status": "cannot load", "error": f"{type(exc).__name__}: {exc}"}
    if len(mesh.triangles) == 0:
        return {"status": "cannot load", "error": "no triangles read"}
    size = float(np.max(mesh.get_max_bound() - mesh.get_min_bound())) / res
    grid = o3d.geometry.VoxelGrid.create_from_triangle_mesh(mesh, voxel_size=size)
    return {"status": "ok", "seconds": time.perf_counter() - t0, "voxels": len(grid.get_voxels()),
            "voxel_size": size}


def work_trimesh(path, res):
    import trimesh

    t0 = time.perf_counter()
    try:
        mesh = trimesh.load(path, force="mesh")
    except Exception as exc:
        return {"status": "cannot load", "error": f"{type(exc).__name__}: {exc}"}
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
        return {"status": "cannot load", "error": "no triangles read"}
    pitch = float(mesh.extents.max()) / res
    try:
        grid = mesh.voxelized(pitch).fill()
    except Exception as exc:
        return {"status": "failed", "error": f"{type(exc).__name__}: {exc}"[:200]}
    return {"status": "ok", "seconds": time.perf_counter() - t0, "voxels": int(grid.filled_count),
            "voxel_size": pitch}


def work_warm(path, res, fmt, out):
    """One model through the batch's own per-model code, in a process that has converted one."""
    import geovox

    [r] = geovox.convert_many([path], out, fmt=fmt, overwrite=True, resolution=res)
    return {"status": r.status, "seconds": r.seconds, "inside_test": r.inside_test,
            "error": r.error}


WORK = {"probe": work_probe, "open3d": work_open3d, "trimesh": work_trimesh, "warm": work_warm}


def worker(mode, items_file):
    """Run ``WORK[mode]`` on each item, one marked JSON line each (CPU seconds added)."""
    import resource

    t0 = time.perf_counter()
    if mode == "open3d":
        import open3d as o3d

        o3d.utility.set_verbosity_level(o3d.utility.VerbosityLevel.Error)
    elif mode == "trimesh":
        import trimesh  # noqa: F401

        # A fill of a big model can take all the memory of a shared machine: a MemoryError
        # is a failed model instead.
        resource.setrlimit(resource.RLIMIT_AS, (8 << 30, resource.RLIM_INFINITY))
    elif mode == "warm":
        import geovox

        # Imports and first-call costs paid before the clock of any model starts.
        with tempfile.TemporaryDirectory() as warm_out:
            opened = os.path.join(warm_out, "open_box.obj")  # the winding number's path
            with open(opened, "w") as f:
                f.write("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\n"
                        "v 0 1 1\nf 1 3 2\nf 1 4 3\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\n"
                        "f 3 4 8\nf 3 8 7\n")
            stl = os.path.join(warm_out, "tetrahedron.stl")  # read by trimesh
            with open(stl, "w") as f:
                f.write("solid t\n" + "".join(
                    f"facet normal 0 0 0\nouter loop\n{a}{b}{c}endloop\nendfacet\n"
                    for a, b, c in [("vertex 0 0 0\n", "vertex 0 1 0\n", "vertex 1 0 0\n"),
                                    ("vertex 0 0 0\n", "vertex 1 0 0\n", "vertex 0 0 1\n"),
                                    ("vertex 0 0 0\n", "vertex 0 0 1\n", "vertex 0 1 0\n"),
                                    ("vertex 1 0 0\n", "vertex 0 1 0\n", "vertex 0 0 1\n")])
                        + "endsolid t\n")
            spot = os.path.join(ROOT, "data", "spot", "spot.obj")  # parity's, and OBJ's
            for fmt in ("binvox", "npz"):
                geovox.convert_many([spot, opened, stl], warm_out, fmt=fmt, resolution=16)
    else:
        import geovox.mesh  # noqa: F401
    print(MARK + json.dumps({"ready": time.perf_counter() - t0}), flush=True)
    with open(items_file, encoding="utf-8") as f:
        items = json.load(f)
    # A file STOP-MODE beside the items ends a long peer run early (the run's own time limit is
    # --timeout per model only): the models left are recorded "not run".
    stop = os.path.join(os.path.dirname(items_file), f"STOP-{mode}")
    for i, item in enumerate(items):
        if os.path.exists(stop):
            print(MARK + json.dumps({"i": i, "status": "not run"}), flush=True)
            continue
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        rec = WORK[mode](*item)
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        rec["cpu"] = r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime
        print(MARK + json.dumps({"i": i, **rec}), flush=True)


def _spawn(mode, items, tmp):
    """A worker process on ``items``, its stderr into a file (a full pipe would stall it)."""
    stem = os.path.join(tmp, f"{mode}-{time.monotonic_ns()}")
    with open(stem + ".json", "w", encoding="utf-8") as f:
        json.dump(items, f)
    err = open(stem + ".stderr", "w+")
    proc = subprocess.Popen([sys.executable, os.path.abspath(__file__), "--worker", mode,
                             stem + ".json"], stdout=subprocess.PIPE, stderr=err, env=env(),
                            cwd=ROOT, start_new_session=True)
    return proc, err


def _lines(proc, deadline):
    """The worker's marked lines as they come: a dict each, or None once ``deadline[0]``
    (``time.monotonic``, which the caller moves on) has passed with no line."""
    fd, buf = proc.stdout.fileno(), b""
    sel = selectors.DefaultSelector()
    sel.register(fd, selectors.EVENT_READ)
    try:
        while True:
            while b"\n" not in buf:
                if not sel.select(max(0.0, deadline[0] - time.monotonic())):
                    yield None
                    continue
                chunk = os.read(fd, 1 << 16)
                if not chunk:
                    return
                buf += chunk
            line, buf = buf.split(b"\n", 1)
            text = line.decode("utf-8", "replace")
            if text.startswith(MARK):
                yield json.loads(text[len(MARK):])
    finally:
        sel.close()


def run_items(mode, items, tmp, timeout, startup_timeout=300.0) -> tuple:
    """Every item through a ``--worker mode`` process, each item under ``timeout`` seconds.

    A worker past its time-out (or one that dies) is killed and a new one carries on after that
    item, which is recorded ``"timeout"`` (or ``"crashed"``).

    Returns
    -------
    records : list of dict
        One per item, in order, each with ``status``.
    startup : float
        Seconds from the first worker's start to its first line (interpreter and imports).
    restarts : int
    """
    records, startup, restarts, start = [None] * len(items), None, -1, 0
    while start < len(items):
        restarts += 1
        t_spawn = time.perf_counter()
        proc, err = _spawn(mode, items[start:], tmp)
        deadline = [time.monotonic() + startup_timeout]
        ready, nxt, status = False, start, "crashed"
        for rec in _lines(proc, deadline):
            if rec is None:
                status = "timeout"
                break
            if "ready" in rec:
                ready = True
                startup = time.perf_counter() - t_spawn if startup is None else startup
            else:
                records[start + rec.pop("i")] = rec
                nxt += 1
            deadline[0] = time.monotonic() + timeout
            if nxt == len(items):
                status = None
                break
        _kill(proc)
        proc.stdout.close()
        err.seek(0)
        tail = [ln for ln in err.read().splitlines() if ln.strip()][-1:]
        err.close()
        if status is not None:
            if not ready:
                raise RuntimeError(f"the {mode} worker did not start: {(tail or [status])[0]}")
            records[nxt] = {"status": status, "error": tail[0] if tail and status == "crashed"
                            else f"over {timeout:g} s"}
            nxt += 1
        start = nxt
    return records, startup or 0.0, max(restarts, 0)


def _signal_group(pid):
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


def _kill(proc):
    """The process and everything it started (its own session)."""
    _signal_group(proc.pid)
    if proc.poll() is None:
        proc.wait()


# --------------------------------------------------------------------------- geovox


def geovox_batch(files, res, fmt, engine, out, limit) -> dict:
    """One fresh ``geovox convert`` over ``files``; wall, CPU, exit status, manifest records."""
    manifest = out + ".jsonl"
    cmd = [sys.executable, "-m", "geovox", "convert", *files, "-o", out, "-r", str(res),
           "--format", fmt, "--manifest", manifest, *ENGINES[engine][0]]
    load0 = os.getloadavg()[0]
    with open(out + ".stdout", "w") as so, open(out + ".stderr", "w") as se:
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=so, stderr=se, env=env(), cwd=ROOT,
                                start_new_session=True)
        timer = threading.Timer(limit, _signal_group, [proc.pid])
        timer.start()
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t0
        timer.cancel()
    rc = os.waitstatus_to_exitcode(status)
    with open(out + ".stderr") as f:
        stderr = f.read()
    records = []
    if os.path.exists(manifest):
        with open(manifest, encoding="utf-8") as f:
            records = [json.loads(line) for line in f if line.strip()]
    return {"res": res, "format": fmt, "engine": engine, "wall": wall, "load": load0,
            "cpu": usage.ru_utime + usage.ru_stime, "rc": rc, "records": records,
            "traceback": "Traceback" in stderr,
            "stderr_tail": [ln for ln in stderr.splitlines() if ln.strip()][-3:]}


# --------------------------------------------------------------------------- load


class LoadSampler:
    """The 1-minute load average every ``every`` seconds, in a thread."""

    def __init__(self, every=5.0):
        self.samples, self._stop, self.every = [os.getloadavg()[0]], threading.Event(), every
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.wait(self.every):
            self.samples.append(os.getloadavg()[0])

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def words(self) -> str:
        s = self.samples
        return f"{min(s):.1f}-{max(s):.1f} (median {sorted(s)[len(s) // 2]:.1f})"


# --------------------------------------------------------------------------- tables


def short(path, roots) -> str:
    """``path`` shown under the name of the data set it came from."""
    for label, root in roots:
        if path.startswith(root.rstrip("/") + "/"):
            return f"{label}/{os.path.relpath(path, root)}"
    return path


def config_table(runs, n_models) -> dict:
    rows = []
    for r in runs:
        ok = sum(x["status"] == "ok" for x in r["records"])
        failed = sum(x["status"] == "failed" for x in r["records"])
        exit_word = str(r["rc"]) + (" (traceback)" if r["traceback"] else "")
        rows.append([f"`-r {r['res']} --format {r['format']} {ENGINES[r['engine']][1]}`",
                     f"{r['res']}³", f".{r['format']}", str(n_models), str(ok), str(failed),
                     exit_word, f"{r['wall']:.1f}", f"{r['cpu']:.1f}",
                     f"{ok / r['wall']:.2f}",
                     f"{sum(x['seconds'] for x in r['records']):.1f}", f"{r['load']:.1f}"])
    return {"caption": "geovox: one fresh `geovox convert MESHES -o OUT --manifest M` per row, "
                       "timed from outside",
            "columns": ["options", "grid", "format", "models", "converted", "failed", "exit",
                        "wall s", "CPU s", "models/s", "sum of per-model s (manifest)",
                        "load at start"],
            "rows": rows}


def slowest_table(runs, warm, triangles, roots, top=10) -> dict:
    """The ``top`` slowest models, warm (:func:`warm_times`), with their manifest times."""
    firsts = {}
    for r in runs:
        firsts.setdefault(r["res"], r)  # each grid's first configuration
    grids = sorted(firsts)
    by = {res: {x["input"]: x for x in r["records"]} for res, r in firsts.items()}
    paths = sorted({p for p, _ in warm}, key=lambda p: -warm[(p, grids[-1])].get("seconds", 0))
    rows = []
    for path in paths[:top]:
        rec = warm[(path, grids[-1])]
        row = [f"`{short(path, roots)}`", f"{triangles.get(path, 0):,}",
               rec.get("inside_test") or rec["status"]]
        row += [f"{warm[(path, g)]['seconds']:.2f}" if "seconds" in warm[(path, g)] else
                warm[(path, g)]["status"] for g in grids]
        row += [f"{by[g][path]['seconds']:.2f}" if path in by[g] else "-" for g in grids]
        rows.append(row)
    r = firsts[grids[-1]]
    return {"caption": f"The {top} slowest models: each alone in one warm process (the batch's "
                       f"own per-model code, `convert_many` of one model, after a warm-up), and "
                       f"the per-model seconds of the `--format {r['format']} "
                       f"{ENGINES[r['engine']][1]}` runs' manifests (a worker's first model "
                       f"there includes its imports)",
            "columns": ["model", "triangles", "inside test"]
                       + [f"warm s at {g}³" for g in grids]
                       + [f"manifest s at {g}³" for g in grids],
            "rows": rows}


def inside_table(runs) -> dict:
    """How many models each inside test took, and their time, per grid."""
    rows = []
    seen = set()
    for r in runs:
        if r["res"] in seen:
            continue
        seen.add(r["res"])
        groups = {}
        for x in r["records"]:
            if x["status"] == "ok":
                g = groups.setdefault(x.get("inside_test") or "?", [0, 0.0])
                g[0] += 1
                g[1] += x["seconds"]
        total = sum(g[1] for g in groups.values()) or 1.0
        for test, (n, s) in sorted(groups.items()):
            rows.append([f"{r['res']}³", test, str(n), f"{s:.1f}", f"{100 * s / total:.0f} %"])
    return {"caption": "Time by inside test (the same runs as the slowest models)",
            "columns": ["grid", "inside test", "models", "sum of per-model s", "share of time"],
            "rows": rows}


def peer_table(peers, n_models, runs=()) -> dict:
    """The peers' rows, with geovox's own per-model seconds over the models each converted."""
    rows = []
    for p in peers:
        recs = p["records"]
        count = {s: sum(r["status"] == s for r in recs)
                 for s in ("ok", "cannot load", "failed", "timeout", "crashed", "not run")}
        timed = p["startup"] + sum(r["seconds"] for r in recs if r["status"] == "ok")
        cpu = sum(r.get("cpu", 0.0) for r in recs if r["status"] == "ok")
        done = {f for f, r in zip(p["files"], recs) if r["status"] == "ok"}
        same = [r for r in runs if r["res"] == p["res"]][:1]  # that grid's first run
        ours = (f"{sum(x['seconds'] for x in same[0]['records'] if x['input'] in done):.1f}"
                if same else "-")
        tried = n_models - count["not run"]
        rows.append([p["label"], f"{p['res']}³",
                     str(tried) + (f" (first {tried}; stopped)" if count["not run"] else ""),
                     str(count["ok"]),
                     str(count["cannot load"]), str(count["failed"] + count["crashed"]),
                     str(count["timeout"]), f"{p['startup']:.1f}", f"{timed:.1f}",
                     f"{cpu:.1f}", f"{count['ok'] / timed:.2f}", ours, f"{p['load']:.1f}"])
    return {"caption": "The peers, the same models at the same voxel size (one process per row, "
                       "each model under a time-out)",
            "columns": ["tool", "grid", "models", "converted", "cannot load", "failed",
                        "time-outs", "start + imports s", "s (start + converted models)",
                        "CPU s (converted models)", "models/s",
                        "geovox on those models: sum of manifest s", "load at start"],
            "rows": rows}


def skipped_table(probe, files) -> dict:
    groups = {}
    for path, rec in zip(files, probe):
        if rec["status"] != "ok":
            g = groups.setdefault((rec["status"], reason(rec["error"], path)), [])
            g.append(os.path.basename(path))
    rows = [[status, why, str(len(names)), ", ".join(f"`{n}`" for n in names[:3])
             + (", ..." if len(names) > 3 else "")]
            for (status, why), names in sorted(groups.items(), key=lambda kv: -len(kv[1]))]
    return {"caption": "Files that are not meshes, by geovox's one-line error (not in the "
                       "data set)",
            "columns": ["status", "geovox says", "files", "for example"], "rows": rows}


def failure_table(runs, peers, roots) -> dict:
    rows = []
    for r in runs:
        for x in r["records"]:
            if x["status"] == "failed":
                rows.append([f"geovox -r {r['res']} .{r['format']} {ENGINES[r['engine']][1]}",
                             f"`{short(x['input'], roots)}`", x["error"][:160]])
        if r["rc"] not in (0, 2) or r["traceback"]:
            rows.append([f"geovox -r {r['res']} .{r['format']} {ENGINES[r['engine']][1]}",
                         "(the command)", f"exit {r['rc']}: " + " / ".join(r["stderr_tail"])])
    for p in peers:
        for path, x in zip(p["files"], p["records"]):
            if x["status"] not in ("ok", "cannot load", "not run"):
                rows.append([f"{p['label']} {p['res']}³ ({x['status']})",
                             f"`{short(path, roots)}`", str(x.get("error", ""))[:160]])
    return {"caption": "Failures, time-outs and models a tool cannot load",
            "columns": ["run", "model", "error"], "rows": rows}


def unloadable_table(peers) -> dict:
    """The models each peer cannot load, by file type (the first grid's run)."""
    rows, seen = [], set()
    for p in peers:
        if p["tool"] in seen:
            continue
        seen.add(p["tool"])
        kinds = {}
        for path, x in zip(p["files"], p["records"]):
            if x["status"] == "cannot load":
                ext = os.path.basename(path).lower().split(".", 1)[-1]
                kinds.setdefault(ext, []).append(x.get("error", ""))
        for ext, errors in sorted(kinds.items()):
            rows.append([p["label"], f".{ext}", str(len(errors)), errors[0][:120]])
    return {"caption": "Models a peer cannot load, by file type",
            "columns": ["tool", "file type", "models", "what happened (the first)"],
            "rows": rows}


def markdown(table) -> str:
    lines = [f"**{table['caption']}**", "", "| " + " | ".join(table["columns"]) + " |",
             "|" + "---|" * len(table["columns"])]
    lines += ["| " + " | ".join(str(c).replace("|", "\\|") for c in row) + " |"
              for row in table["rows"]]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- main


def versions() -> str:
    from importlib import metadata

    names = ("numpy", "trimesh", "embreex", "scipy", "open3d", "distributed")
    out = []
    for n in names:
        try:
            out.append(f"{n} {metadata.version(n)}")
        except metadata.PackageNotFoundError:
            out.append(f"no {n}")
    return ", ".join(out)


def machine(load) -> str:
    with open("/proc/meminfo") as f:
        mem = int(f.readline().split()[1]) / 2 ** 20
    return (f"{os.cpu_count()} cores, {mem:.0f} GiB, Python {sys.version.split()[0]}, "
            f"{versions()}; shared with other jobs: load average {load} during the run")


def parse(argv):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", action="append", nargs="+", metavar="DIR",
                    help=f"trimesh's models/ folder(s) (default {DEFAULT_MODELS})")
    ap.add_argument("--models-git", metavar="GIT_DIR",
                    help="take HEAD:models/ of this git clone (bare too) instead")
    ap.add_argument("--corpus", default=CORPUS, help="another folder of models ('' for none)")
    ap.add_argument("--res", type=int, nargs="+", default=[64, 128])
    ap.add_argument("--formats", nargs="+", default=["binvox", "npz"])
    ap.add_argument("--engines", nargs="+", default=["j2", "lc2"], choices=sorted(ENGINES))
    ap.add_argument("--only", nargs="+", metavar="CONFIG",
                    help="run only these configurations, as RES:FORMAT:ENGINE (64:binvox:j2)")
    ap.add_argument("--peers", nargs="*", default=["open3d", "trimesh"],
                    choices=["open3d", "trimesh"])
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds per model, peers")
    ap.add_argument("--batch-timeout", type=float, default=3600.0,
                    help="seconds per geovox command")
    ap.add_argument("--limit", type=int, help="only the first N meshes (a quick try)")
    ap.add_argument("--results", metavar="FILE", help="write the result file here")
    ap.add_argument("--raw", metavar="FILE",
                    help="also keep every measurement here (JSON), to re-make the tables")
    ap.add_argument("--from-raw", metavar="FILE",
                    help="measure nothing: make the tables and result file from a --raw file")
    ap.add_argument("--worker", nargs=2, help=argparse.SUPPRESS)
    return ap.parse_args(argv)


def inputs(a, tmp) -> tuple:
    """(files, roots, words about the sources)."""
    roots, words = [], []
    if a.models_git:
        folder, commit = extract_git(a.models_git, tmp)
        roots.append(("trimesh/models", folder))
        words.append(f"trimesh's `models/` at commit {commit[:10]} (taken from a clone's HEAD)")
    else:
        for folder in [d for group in (a.models or [[DEFAULT_MODELS]]) for d in group]:
            if not os.path.isdir(folder):
                sys.exit(f"bench_dataset: no folder {folder}: clone trimesh "
                         "(git clone --depth 1 https://github.com/mikedh/trimesh) and pass "
                         "--models TRIMESH/models, or --models-git")
            roots.append(("trimesh/models" if len(roots) == 0 else os.path.basename(folder),
                          os.path.abspath(folder)))
            words.append(f"`{folder}`")
    if a.corpus:
        if not os.path.isdir(a.corpus):
            sys.exit(f"bench_dataset: no folder {a.corpus} (--corpus; '' for none)")
        roots.append(("corpus", os.path.abspath(a.corpus)))
        words.append(f"the shared corpus (`{a.corpus}`)")
    return gather([r for _, r in roots]), roots, words


def configurations(a) -> list:
    # Engine by engine: a run cut short still has every grid and format of the first one.
    configs = [(res, fmt, eng) for eng in a.engines for res in a.res for fmt in a.formats]
    if a.only:
        wanted = {tuple(c.split(":")) for c in a.only}
        configs = [c for c in configs if (str(c[0]), c[1], c[2]) in wanted]
    return configs


def measure(a, tmp, files, sampler):
    """The probe, every geovox configuration, the peers; printed as they finish."""
    probe, _, _ = run_items("probe", [[f] for f in files], tmp, a.timeout)
    bugs = [(f, r) for f, r in zip(files, probe) if r["status"] not in ("ok", "not a mesh")]
    for f, r in bugs:
        print(f"LOADER BUG: {f}: {r['status']}: {r.get('error', '')}", flush=True)
    meshes = [f for f, r in zip(files, probe) if r["status"] == "ok"][:a.limit]
    triangles = {f: r["triangles"] for f, r in zip(files, probe) if r["status"] == "ok"}
    print(f"{len(files)} files, {len(meshes)} meshes; load {sampler.samples[-1]:.1f}", flush=True)
    runs = []
    for res, fmt, eng in configurations(a):
        out = os.path.join(tmp, f"out-{res}-{fmt}-{eng}")
        r = geovox_batch(meshes, res, fmt, eng, out, a.batch_timeout)
        runs.append(r)
        shutil.rmtree(out, ignore_errors=True)
        ok = sum(x["status"] == "ok" for x in r["records"])
        print(f"geovox -r {res} .{fmt} {eng}: {ok}/{len(meshes)} in {r['wall']:.1f} s "
              f"(CPU {r['cpu']:.1f} s, exit {r['rc']}), load {r['load']:.1f}", flush=True)
    warm = warm_times(a, tmp, runs)
    peers = []
    for tool in a.peers:
        for res in a.res:
            load0 = os.getloadavg()[0]
            recs, startup, restarts = run_items(tool, [[f, res] for f in meshes], tmp, a.timeout)
            label = {"open3d": "Open3D `VoxelGrid.create_from_triangle_mesh` (surface)",
                     "trimesh": "trimesh `voxelized(pitch).fill()`"}[tool]
            peers.append({"label": label, "tool": tool, "res": res, "records": recs,
                          "startup": startup, "restarts": restarts, "files": meshes,
                          "load": load0})
            ok = sum(x["status"] == "ok" for x in recs)
            print(f"{tool} {res}³: {ok}/{len(meshes)}, load {load0:.1f}", flush=True)
    return probe, meshes, triangles, runs, peers, bugs, warm


def warm_times(a, tmp, runs, top=10) -> dict:
    """The slowest models again, one by one in one warm process: {(path, res): record}.

    A pool process or a Dask worker imports geovox, trimesh, SciPy and the kernels in its first
    model, whose manifest time then includes them (several seconds on a loaded machine); the
    candidates are the ``top + 6`` slowest by the manifests of each grid's first run.
    """
    firsts = {}
    for r in runs:
        firsts.setdefault(r["res"], r)
    if not firsts:
        return {}
    key = max(firsts)
    ranked = sorted(firsts[key]["records"], key=lambda x: -x["seconds"])[:top + 6]
    out = os.path.join(tmp, "warm")
    items = [[x["input"], res, firsts[res]["format"], out]
             for x in ranked for res in sorted(firsts)]
    recs, _, _ = run_items("warm", items, tmp, max(a.timeout, 300.0))
    shutil.rmtree(out, ignore_errors=True)
    print(f"warm re-timing of {len(ranked)} models done, load {os.getloadavg()[0]:.1f}", flush=True)
    return {(item[0], item[1]): rec for item, rec in zip(items, recs)}


def main(argv=None):
    a = parse(argv)
    if a.worker:
        return worker(*a.worker)
    if a.from_raw:
        with open(a.from_raw, encoding="utf-8") as f:
            raw = json.load(f)
    else:
        raw = {"started": datetime.datetime.now(datetime.timezone.utc).isoformat()}
        with tempfile.TemporaryDirectory(prefix="bench-dataset-") as tmp, \
                LoadSampler() as sampler:
            files, roots, words = inputs(a, tmp)
            probe, meshes, triangles, runs, peers, bugs, warm = measure(a, tmp, files, sampler)
        raw.update(ended=datetime.datetime.now(datetime.timezone.utc).isoformat(),
                   load=sampler.words(), files=files, roots=roots, words=words, probe=probe,
                   meshes=meshes, triangles=triangles, runs=runs, peers=peers, bugs=bugs,
                   warm=[[p, res, rec] for (p, res), rec in warm.items()],
                   argv=list(argv if argv is not None else sys.argv[1:]), timeout=a.timeout)
        if a.raw:
            with open(a.raw, "w", encoding="utf-8") as f:
                json.dump(raw, f)
    result = result_file(a, raw)
    for t in result["tables"]:
        print("\n" + markdown(t))
    print(f"load average during the run: {raw['load']}")
    if a.results:
        with open(a.results, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1, ensure_ascii=False)
            f.write("\n")
        print(f"wrote {a.results}")
    return 0


def all_tables(raw) -> list:
    runs, peers, roots = raw["runs"], raw["peers"], raw["roots"]
    n = len(raw["meshes"])
    warm = {(p, res): rec for p, res, rec in raw["warm"]}
    tables = []
    if runs:
        tables += [config_table(runs, n), slowest_table(runs, warm, raw["triangles"], roots),
                   inside_table(runs)]
    if peers:
        tables += [peer_table(peers, n, runs), unloadable_table(peers)]
    tables += [skipped_table(raw["probe"], raw["files"]), failure_table(runs, peers, roots)]
    return [t for t in tables if t["rows"]]  # no failures: no table (the notes say so)


def result_file(a, raw) -> dict:
    """The result file's dict (the shape ``benchmarks/tables.py`` reads)."""
    started, ended = (datetime.datetime.fromisoformat(raw[k]) for k in ("started", "ended"))
    shown = " ".join(raw["argv"]).replace(ROOT + "/", "")
    runs = raw["runs"]
    notes = (f"{len(raw['files'])} files, of which {len(raw['meshes'])} are meshes geovox loads "
             "(the others: the last table but one). Configurations run: "
             + ", ".join(f"{r['res']}³ .{r['format']} {ENGINES[r['engine']][1]}" for r in runs)
             + ". models/s = converted models / wall time of the whole command (a fresh "
             "process: start, imports, the pool or the Dask cluster's start and stop, every "
             "model). Per-model seconds are the manifest's (each model's own time where it "
             "ran; a worker's first model includes the worker's imports). "
             "Grid: `.binvox`'s `-r N` is binvox's N³ cube, voxel edge = the longest side of "
             "the bounding box / N, the voxel size the peers were given (their own loaded "
             "mesh's longest side / N); `.npz`'s is N voxels along each side of the box. "
             "The peers run one process per tool and grid, on one core; their time excludes "
             "the models they cannot load and those over the "
             f"{raw.get('timeout', a.timeout):g} s time-out. "
             "Open3D makes surface voxels only (no inside); trimesh's fill fills the inside "
             "of each voxelised surface with SciPy's hole filling.")
    failed = sum(x["status"] == "failed" for r in runs for x in r["records"])
    odd = sum(r["rc"] not in (0, 2) or r["traceback"] for r in runs)
    for p in raw["peers"]:
        left = sum(x["status"] == "not run" for x in p["records"])
        if left:
            notes += (f" {p['tool']} at {p['res']}³ was stopped (a STOP-{p['tool']} file) after "
                      f"{len(p['records']) - left} of the {len(p['records'])} models, for time: "
                      "its row is those models only, in file order.")
    notes += (f" geovox: {failed} failed models, {odd} commands with a traceback or an exit "
              f"status other than 0 and 2, {len(raw['bugs'])} loader tracebacks.")
    return {"benchmark": "dataset",
            "title": "A data set: every mesh of trimesh's models/ and the corpus",
            "script": "benchmarks/bench_dataset.py",
            "command": f"python benchmarks/bench_dataset.py {shown}".strip(),
            "date": f"{started:%Y-%m-%d, %H:%M}-{ended:%H:%M} UTC",
            "machine": machine(raw["load"]),
            "models": raw["words"], "notes": notes, "tables": all_tables(raw)}


if __name__ == "__main__":
    sys.exit(main())
