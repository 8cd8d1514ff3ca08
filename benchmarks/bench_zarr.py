"""One big volume into OME-Zarr: on a 2-worker local Dask cluster, and here, against today's .h5.

Cases (bunny105k, the 105,568-triangle watertight bunny of common.py, occupancy only):

- ``cli``: fresh processes of ``python -m geovox convert bunny105k.ply -r N -o v.EXT -q``
  for ``.h5`` and ``.zarr`` (each slab by slab here), and ``.zarr --local-cluster 2`` (the user's
  path on a cluster: starting it included); wall time, CPU time (user + system of the command
  and every process it reaped) and the peak RSS of the largest process (``RUSAGE_CHILDREN``; for
  the cluster run, the largest of the client and its workers).
- ``cluster``: a warm 2-worker ``LocalCluster`` (processes, one thread each) in this process;
  ``geovox.convert_to(mesh, "v.zarr", resolution=N, client=client)``: wall time, and each
  worker's own peak RSS (``VmHWM``, reset before the run, read with ``client.run``).

Usage: ``python benchmarks/bench_zarr.py {cli,cluster} N [--out DIR] [--repeat K]``.
Prints one JSON line per measurement.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time

from common import ROOT, load_model, peak_rss, reset_peak


def model_file(folder) -> str:
    """bunny105k written as PLY (the CLI reads files)."""
    import trimesh

    path = os.path.join(folder, "bunny105k.ply")
    if not os.path.exists(path):
        m = load_model("bunny105k")
        trimesh.Trimesh(m.vertices, m.faces, process=False).export(path)
    return path


def cli(n, folder, repeat):
    model = model_file(folder)
    env = dict(os.environ, PYTHONPATH=ROOT)
    for ext, extra in [(".h5", []), (".zarr", []), (".zarr", ["--local-cluster", "2"])]:
        for _ in range(repeat):
            out = os.path.join(folder, "v" + ext)
            usage = resource.getrusage(resource.RUSAGE_CHILDREN)
            before, cpu0 = usage.ru_maxrss, usage.ru_utime + usage.ru_stime
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "geovox", "convert", model, "-r", str(n), "-o", out,
                            "-q", *extra], check=True, env=env)
            wall = time.perf_counter() - t
            # ru_maxrss of children is a running maximum: only a new high is this run's.
            usage = resource.getrusage(resource.RUSAGE_CHILDREN)
            peak, cpu = usage.ru_maxrss, usage.ru_utime + usage.ru_stime - cpu0
            size = sum(os.path.getsize(os.path.join(d, f)) for d, _, fs in os.walk(out) for f in fs) \
                if os.path.isdir(out) else os.path.getsize(out)
            print(json.dumps({"case": "cli", "grid": n, "out": ext, "extra": " ".join(extra),
                              "seconds": round(wall, 2), "cpu_s": round(cpu, 2),
                              "peak_rss_gib": round(peak / 2**20, 2) if peak > before else "<= earlier",
                              "mib": round(size / 2**20, 1), "load": os.getloadavg()[0]}), flush=True)
            shutil.rmtree(out, ignore_errors=True) if os.path.isdir(out) else os.unlink(out)


def cpu_seconds() -> float:
    """User + system seconds of this process so far."""
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def cluster(n, folder, repeat):
    from dask.distributed import Client, LocalCluster

    from geovox.api import convert_to

    import dask

    m = load_model("bunny105k")
    # As geovox's --local-cluster starts it (see geovox/cluster.py).
    with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None}), \
            LocalCluster(n_workers=2, threads_per_worker=1, dashboard_address=":0") as lc, \
            Client(lc) as client:
        client.run(lambda: __import__("geovox.planner"))  # imports are not the conversion
        for _ in range(repeat):
            client.run(reset_peak)
            reset_peak()
            out = os.path.join(folder, "v.zarr")
            cpu0 = client.run(cpu_seconds)
            c = cpu_seconds()
            t = time.perf_counter()
            info = convert_to(m, out, resolution=n, client=client)
            wall = time.perf_counter() - t
            c = cpu_seconds() - c
            cpu = {k: v - cpu0[k] for k, v in client.run(cpu_seconds).items()}
            workers = client.run(peak_rss)
            print(json.dumps({"case": "cluster", "grid": n, "seconds": round(wall, 2),
                              "slabs": info["slabs"], "inside": info["inside"],
                              "worker_peak_gib": [round(v / 2**30, 2) for v in workers.values()],
                              "client_peak_gib": round(peak_rss() / 2**30, 2),
                              "worker_cpu_s": [round(v, 1) for v in cpu.values()],
                              "client_cpu_s": round(c, 1),
                              "task_seconds": {k: round(v, 1) for k, v in info["timings"].items()},
                              "load": os.getloadavg()[0]}), flush=True)
            shutil.rmtree(out)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("case", choices=["cli", "cluster"])
    p.add_argument("n", type=int)
    p.add_argument("--out", default=None, help="folder for the outputs (default: a temporary one)")
    p.add_argument("--repeat", type=int, default=1)
    a = p.parse_args()
    folder = a.out or tempfile.mkdtemp(prefix="bench_zarr.")
    os.makedirs(folder, exist_ok=True)
    {"cli": cli, "cluster": cluster}[a.case](a.n, folder, a.repeat)


if __name__ == "__main__":
    main()
