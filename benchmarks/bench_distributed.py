"""Many models on a Dask cluster against today's local pool (issue 14).

What it measures, on the corpus (every mesh in ``--corpus``, default
../shared/corpus: 16 models) at ``--res`` (128³), output ``.raw``:

1. The user's path: a fresh process of ``geovox convert CORPUS -o OUT -r 128
   -q --overwrite`` with ``-j 1``, ``-j 2`` (today's process pool),
   ``--local-cluster 1`` and ``--local-cluster 2`` (Dask workers started by
   the command, start-up and shut-down included). Wall time, median of
   ``--repeat``.
2. Warm, in one process: ``geovox.convert_many`` with the local pool (``jobs``
   = 1, 2) and with a client of an already running LocalCluster of 1 and 2
   single-threaded worker processes (geovox's settings:
   ``cluster.LOCAL_CLUSTER_CONFIG``). From each: wall time, models/s, the sum
   of the models' own times (``Result.seconds``, measured where each model
   ran) and the *per-model overhead* ``(wall * workers - sum) / models``:
   worker time not spent converting (scheduling, sending the task and its
   result, imports in fresh pool processes, idle workers at the tail).
3. Scheduler throughput: ``client.map`` of a no-op over 2000 items, 1 and 2
   workers: tasks/s, i.e. the cost ``c`` of one task with nothing in it.
4. Bad set-ups, fresh process each: seconds to the one-line error for a
   refused port, an unknown host, a missing scheduler file.
5. A model of N workers from 2 and 3 (printed as a table): with mean model
   time ``t``, per-task overhead ``o`` on a worker, scheduler time per task
   ``c`` (taken as 1 / no-op tasks/s with one worker: the scheduler and the
   worker shared the machine, so it is an upper bound) and start-up ``S``,
   ``n`` models on ``N`` workers in tasks of ``B`` models take about
   ``S + max(n (t + o/B) / N, n c / B) + B t_max`` -- the workers' share, or
   the scheduler's, whichever is larger, plus the last task's tail. Scaling
   stops near ``N* = B (t + o/B) / c``; batching B models per task divides
   the scheduler's load and the per-task overhead by B and adds up to
   ``B t_max`` of tail.

The machine is shared (2 cores, other jobs running): the load average is
printed before and after, and figures under load are pessimistic.
``/usr/bin/time -v geovox convert ...`` gives one fresh-process figure by hand.

Usage::

    python benchmarks/bench_distributed.py                 # about 2 minutes
    python benchmarks/bench_distributed.py --repeat 3 --res 64
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, ROOT)

from benchmarks.common import CORPUS  # noqa: E402


def load() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg())


def fresh(args, repeat) -> tuple:
    """Median wall seconds of a fresh ``geovox`` process, and its exit status."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    times, cpus, rc = [], [], None
    for _ in range(repeat):
        t0 = time.perf_counter()
        p = subprocess.Popen([sys.executable, "-m", "geovox", *args], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        err = p.stderr.read()
        _, status, ru = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
        times.append(time.perf_counter() - t0)
        # CPU time of the process and every process it waited for (Dask's
        # workers are reaped by their nanny, which runs in the CLI process).
        cpus.append(ru.ru_utime + ru.ru_stime)
        rc = p.returncode
        if rc not in (0, 2):
            raise RuntimeError(err)
    return statistics.median(times), rc, err.strip().splitlines(), statistics.median(cpus)


def warm_rows(corpus, res, out, n_tiny, tiny_only=False):
    import dask
    import distributed

    import geovox
    from geovox.cluster import LOCAL_CLUSTER_CONFIG

    rows = []

    def cpu(client=None):
        """CPU seconds so far of this process, its reaped children, and the client's workers."""
        import resource

        own = resource.getrusage(resource.RUSAGE_SELF)
        kids = resource.getrusage(resource.RUSAGE_CHILDREN)
        total = own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime
        if client is not None:
            total += sum(client.run(_cpu_seconds).values())
        return total

    def row(label, workers, fn, client=None):
        c0 = cpu(client)
        t0 = time.perf_counter()
        results = fn()
        wall = time.perf_counter() - t0
        cpu_s = cpu(client) - c0
        own = sum(r.seconds for r in results)
        n = len(results)
        rows.append(dict(label=label, workers=workers, n=n, wall=wall, rate=n / wall, own=own,
                         cpu=cpu_s,
                         longest=max(r.seconds for r in results),
                         overhead=(wall * workers - own) / n,
                         ok=sum(r.status == "ok" for r in results)))
        return results

    tiny = [os.path.join(corpus, "trimesh_edge_cases", "box.obj")] * n_tiny
    for jobs in (1, 2):
        if not tiny_only:
            row(f"local pool, jobs={jobs}", jobs,
                lambda: geovox.convert_many([corpus], out, overwrite=True, jobs=jobs,
                                            resolution=res))
        row(f"tiny: local pool, jobs={jobs}", jobs,
            lambda: geovox.convert_many(tiny, out, overwrite=True, jobs=jobs, resolution=8))
    noop = {}
    for workers in (1, 2):
        with dask.config.set(LOCAL_CLUSTER_CONFIG), \
                distributed.LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                                         dashboard_address=":0", silence_logs=50) as cl, \
                distributed.Client(cl) as client:
            client.run(_warm)  # imports paid once, as on a cluster that is already up
            label = f"{workers} worker{'s' if workers > 1 else ''}"
            if not tiny_only:
                row(f"Dask LocalCluster, {label}", workers,
                    lambda: geovox.convert_many([corpus], out, client=client, overwrite=True,
                                                resolution=res), client)
            row(f"tiny: Dask LocalCluster, {label}", workers,
                lambda: geovox.convert_many(tiny, out, client=client, overwrite=True,
                                            resolution=8), client)
            client.gather(client.map(_noop, range(50), pure=False))  # warm-up
            t0 = time.perf_counter()
            client.gather(client.map(_noop, range(2000), pure=False))
            noop[workers] = 2000 / (time.perf_counter() - t0)
    return rows, noop


def _noop(x):
    return x


def _cpu_seconds():
    import resource

    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _warm():
    import geovox.planner  # noqa: F401
    import geovox.runners  # noqa: F401


def bad_setups(tmp):
    import socket

    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    spot = os.path.join(ROOT, "data", "spot", "spot.obj")
    cases = {"refused port": ["--scheduler", f"tcp://127.0.0.1:{port}"],
             "unknown host": ["--scheduler", "tcp://no-such-host.invalid:8786"],
             "missing scheduler file": ["--scheduler-file", os.path.join(tmp, "nope.json")]}
    out = {}
    for name, extra in cases.items():
        t, rc, err, _ = fresh(["convert", spot, spot, "-o", os.path.join(tmp, "bad"), "-r", "8",
                               *extra], 1)
        out[name] = (t, rc, err[0] if len(err) == 1 else f"{len(err)} lines")
    s.close()
    return out


def model_table(t_mean, t_max, o, c, startup, n=100_000):
    """Predicted wall time and speed-up for N workers, batches of B models."""
    lines = ["| workers N | B = 1: time | speed-up | B = 16: time | speed-up |",
             "|---:|---:|---:|---:|---:|"]
    serial = n * (t_mean + o)
    for N in (1, 2, 8, 32, 128, 512, 2048):
        cells = []
        for B in (1, 16):
            t = startup + max(n * (t_mean + o / B) / N, n * c / B) + B * t_max
            cells += [f"{t / 60:.1f} min", f"{serial / t:.0f}x"]
        lines.append(f"| {N} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--corpus", default=CORPUS)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--skip-fresh", action="store_true")
    ap.add_argument("--tiny", type=int, default=300,
                    help="copies of box.obj (12 triangles) at 8³ for the overhead rows")
    ap.add_argument("--tiny-only", action="store_true",
                    help="only the overhead rows (tiny models) and the no-op tasks")
    a = ap.parse_args()
    print(f"load average before: {load()}  ({time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())})")
    with tempfile.TemporaryDirectory() as tmp:
        out = os.path.join(tmp, "out")
        fresh_times = {}
        if not a.skip_fresh:
            print("\n| command (fresh process, corpus at %d³) | wall s | CPU s |" % a.res)
            print("|---|---:|---:|")
            for extra in (["-j", "1"], ["-j", "2"], ["--local-cluster", "1"],
                          ["--local-cluster", "2"]):
                t, rc, _, c = fresh(["convert", a.corpus, "-o", out, "-r", str(a.res), "-q",
                                     "--overwrite", *extra], a.repeat)
                fresh_times[" ".join(extra)] = t
                print(f"| `geovox convert CORPUS -o OUT -r {a.res} {' '.join(extra)}` | {t:.2f} | "
                      f"{c:.2f} |"
                      + ("" if rc == 0 else f" (exit {rc})"))
        rows, noop = warm_rows(a.corpus, a.res, out, a.tiny, a.tiny_only)
        print(f"\n| warm, in one process (corpus at {a.res}³; tiny: box.obj x {a.tiny} at 8³) | models | wall s | models/s | "
              "sum of model times s | per-model overhead ms | CPU s |")
        print("|---|---:|---:|---:|---:|---:|---:|")
        for r in rows:
            print(f"| {r['label']} | {r['n']} ({r['ok']} ok) | {r['wall']:.2f} | {r['rate']:.2f} | "
                  f"{r['own']:.2f} | {1000 * r['overhead']:.0f} | {r['cpu']:.2f} |")
        print("\n| no-op tasks (client.map over 2000) | tasks/s |\n|---|---:|")
        for w, rate in noop.items():
            print(f"| {w} worker{'s' if w > 1 else ''} | {rate:.0f} |")
        bad = bad_setups(tmp)
        print("\n| bad set-up (fresh process) | seconds to the error | exit | stderr |\n|---|---:|---:|---|")
        for name, (t, rc, line) in bad.items():
            print(f"| {name} | {t:.2f} | {rc} | `{line}` |")
    if a.tiny_only:
        print(f"\nload average after: {load()}")
        return
    one = [r for r in rows if r["label"].startswith("Dask") and r["workers"] == 1][0]
    o_tiny = [r for r in rows if r["label"].startswith("tiny: Dask") and r["workers"] == 1][0]
    t_mean = one["own"] / one["n"]
    o = max(0.0, o_tiny["overhead"])  # tiny models: the overhead with no tail to hide in
    c = 1 / noop[1]
    print(f"\nmodel inputs: t = {t_mean * 1000:.0f} ms a model (mean), o = {o * 1000:.1f} ms, "
          f"c = {c * 1000:.2f} ms a task; N* = (t + o) / c = {(t_mean + o) / c:.0f} workers "
          f"(B = 1), {16 * (t_mean + o / 16) / c:.0f} (B = 16)")
    two = [r for r in rows if r["label"].startswith("Dask") and r["workers"] == 2][0]
    startup = max(0.0, fresh_times.get("--local-cluster 2", two["wall"]) - two["wall"])
    t_max = max(r["longest"] for r in rows)
    print(f"\npredicted, 100,000 models like these (t_max = {t_max:.1f} s, the slowest model; "
          f"start-up S = {startup:.1f} s, fresh --local-cluster 2 minus its warm run):")
    print(model_table(t_mean, t_max, o, c, startup))
    print(f"\nload average after: {load()}")


if __name__ == "__main__":
    main()
