"""Writing each output format: the CLI end to end, in a fresh process per run.

For every format, ``python -m geovox convert spot.obj -o v.EXT -r N -q`` runs
in its own interpreter (binvox: ``--voxel-size`` giving N voxels on the
longest axis, since binvox needs cubic voxels); the table gives its wall
time, its peak RSS (from ``wait4``) and the size of what it wrote. One run
per row: on a shared machine compare rows, not absolute times.

    .venv/bin/python benchmarks/bench_formats.py [N ...]   # default: 256 1024
"""

from __future__ import annotations

import glob
import os
import subprocess
import sys
import tempfile
import time

from common import ROOT, SPOT

FORMATS = [".h5", ".vtkhdf", ".nrrd", ".npz", ".npz --pack-bits", ".binvox", ".vdb"]


def run(args, folder):
    """Wall seconds and peak RSS (bytes) of one CLI run in a fresh interpreter."""
    env = dict(os.environ, PYTHONPATH=ROOT)
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "geovox", "convert", *args], cwd=folder, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode()
    if os.waitstatus_to_exitcode(status) != 0:
        raise RuntimeError(err)
    return wall, usage.ru_maxrss * 1024


def main(sizes):
    import geovox

    extent = geovox.load_mesh(SPOT).bounds
    longest = float((extent[1] - extent[0]).max())
    print("| grid | format | CLI end to end (s) | peak RSS (GiB) | written (MiB) |")
    print("|---|---|---|---|---|")
    for n in sizes:
        for spec in FORMATS:
            ext, *flags = spec.split()
            with tempfile.TemporaryDirectory() as folder:
                out = os.path.join(folder, "v" + ext)
                grid = (["--voxel-size", repr(longest / n)] if ext == ".binvox" else ["-r", str(n)])
                wall, rss = run([SPOT, "-o", out, *grid, "-q", *flags], folder)
                size = sum(os.path.getsize(p) for p in glob.glob(os.path.join(folder, "*")))
            print(f"| spot {n}³ | `{spec}` | {wall:.2f} | {rss / 2**30:.2f} | {size / 2**20:.1f} |",
                  flush=True)


if __name__ == "__main__":
    main([int(a) for a in sys.argv[1:]] or [256, 1024])
