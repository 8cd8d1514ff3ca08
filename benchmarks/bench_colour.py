"""Colour conversion, end to end: `geovox convert spot.obj --color` per grid size.

Each run is a fresh interpreter running the CLI in-process (imports, OBJ and
texture loading, rays along three axes, parity fill, colouring, writing the
RAW + RGBA RAW files), timed by wall clock from interpreter start to exit;
peak memory is the process's peak RSS (VmHWM).

Usage: python benchmarks/bench_colour.py [--res 64 128 256 512] [--backend auto]
"""

from __future__ import annotations

import argparse
import datetime
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import SPOT  # noqa: E402

CHILD = """
import sys, json
from geovox.cli import main
rc = main(sys.argv[1:])
hwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0].split()[1]
print(json.dumps({"rc": rc, "peak_kib": int(hwm)}))
"""


def run(res, backend, out_dir):
    out = os.path.join(out_dir, f"spot_{res}.raw")
    args = ["convert", SPOT, "-o", out, "-r", str(res), "--color", "--backend", backend, "-q"]
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        return {"error": p.stderr.strip().splitlines()[-1]}
    import json

    info = json.loads(p.stdout.strip().splitlines()[-1])
    for f in os.listdir(out_dir):
        os.remove(os.path.join(out_dir, f))
    return {"wall": wall, "peak": info["peak_kib"] * 1024}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--res", type=int, nargs="+", default=[64, 128, 256, 512])
    p.add_argument("--backend", default="auto")
    p.add_argument("--repeat", type=int, default=3)
    args = p.parse_args()
    print(f"# bench_colour {datetime.date.today()} backend={args.backend}")
    print("| model | grid | end to end (s), best of runs | peak RSS (MiB) |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for res in args.res:
            runs = [run(res, args.backend, tmp) for _ in range(args.repeat if res <= 256 else 1)]
            ok = [r for r in runs if "error" not in r]
            if not ok:
                print(f"| spot | {res}³ | error: {runs[0]['error']} | |")
                continue
            best = min(r["wall"] for r in ok)
            peak = max(r["peak"] for r in ok)
            print(f"| spot | {res}³ | {best:.2f} | {peak / 2**20:.0f} |", flush=True)


if __name__ == "__main__":
    main()
