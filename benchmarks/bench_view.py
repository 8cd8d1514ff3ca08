"""The HTML viewer: page size and whole-process time of ``geovox view VOLUME --html OUT.html``.

Converts spot with colour at each resolution (the README's first command), then times fresh
processes of ``geovox view NAME.json --html page.html`` and prints a Markdown table: the page's
size, the median wall and CPU seconds of the runs, and the peak memory of the largest run.

    python benchmarks/bench_view.py [--res 128,256] [--repeat 5]
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPOT = os.path.join(ROOT, "data", "spot", "spot.obj")


def _run(args, cwd):
    """Run ``python -m geovox ARGS`` once; return (wall s, CPU s, peak KiB of that process)."""
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "geovox", *args], cwd=cwd,
                            stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(proc.pid, 0)  # this child's own rusage, not all children's
    wall = time.perf_counter() - t0
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode:
        raise SystemExit(f"geovox {' '.join(args)} failed with status {proc.returncode}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--res", default="128,256")
    p.add_argument("--repeat", type=int, default=5)
    a = p.parse_args(argv)
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print("| volume (colour) | page size (B) | wall (s), median | CPU (s), median | peak (MiB) |")
    print("|---|---:|---:|---:|---:|")
    with tempfile.TemporaryDirectory() as tmp:
        for n in (int(r) for r in a.res.split(",")):
            raw = f"spot_{n}x{n}x{n}_uint8.raw"
            subprocess.run([sys.executable, "-m", "geovox", "convert", SPOT, "-o", raw,
                            "--resolution", str(n), "--color", "-q"], cwd=tmp, check=True)
            view = ["view", raw.replace(".raw", ".json"), "--html", "page.html"]
            _run(view, tmp)  # warm-up: the bytecode cache, the page cache
            runs = [_run(view, tmp) for _ in range(a.repeat)]
            size = os.path.getsize(os.path.join(tmp, "page.html"))
            wall = statistics.median(r[0] for r in runs)
            cpu = statistics.median(r[1] for r in runs)
            peak = max(r[2] for r in runs) / 1024
            print(f"| spot {n}³ | {size:,} | {wall:.2f} | {cpu:.2f} | {peak:.0f} |")
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
