"""Labels: what labelling a 20-part assembly costs over occupancy alone.

The model: 20 overlapping spheres (icosphere(4), 5,120 triangles each,
102,400 in all) in a 5 x 4 array, each an OBJ object with its own material
(Kd), written to a temporary folder. Every figure is the whole process (a
fresh interpreter running ``python -m geovox convert``, start-up and
loading included), the median of ``RUNS`` runs after one warm-up:

* occupancy only vs ``--labels part`` at 256³ (to ``.h5``);
* exact colour (``--color``) vs ``--labels material`` at 256³ (to ``.h5``).

Usage: python benchmarks/bench_labels.py [RUNS]
"""

from __future__ import annotations

import datetime
import os
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

RUNS = int(sys.argv[1]) if len(sys.argv) > 1 else 5


def assembly(folder: str) -> str:
    """Write the 20-part OBJ (and its MTL) into ``folder``; returns its path."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.62)
    lines, mtl, off = ["mtllib parts.mtl"], [], 0
    rng = np.random.default_rng(0)
    for k in range(20):
        x, y = k % 5, k // 5
        v = np.asarray(sphere.vertices) + (x, y, 0.15 * (k % 3))
        lines += [f"o part{k + 1:02d}", f"usemtl m{k + 1:02d}"]
        lines += [f"v {a:.6f} {b:.6f} {c:.6f}" for a, b, c in v]
        lines += [f"f {a + off + 1} {b + off + 1} {c + off + 1}" for a, b, c in sphere.faces]
        off += len(v)
        r, g, b = rng.uniform(0.1, 1.0, 3)
        mtl += [f"newmtl m{k + 1:02d}", f"Kd {r:.3f} {g:.3f} {b:.3f}"]
    with open(os.path.join(folder, "parts.mtl"), "w") as f:
        f.write("\n".join(mtl) + "\n")
    path = os.path.join(folder, "assembly.obj")
    with open(path, "w") as f:
        f.write("\n".join(lines) + "\n")
    return path


def whole_process(args) -> float:
    """Median wall seconds of ``python -m geovox convert ARGS`` over RUNS runs (one warm-up)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    cmd = [sys.executable, "-m", "geovox", "convert", *args, "-q"]
    times = []
    for n in range(RUNS + 1):
        t0 = time.perf_counter()
        subprocess.run(cmd, check=True, cwd=root, stdout=subprocess.DEVNULL)
        if n:
            times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main():
    print(f"# bench_labels {datetime.date.today()}, median of {RUNS} whole-process runs")
    print("| what | grid | time (s) | vs |")
    print("|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        model = assembly(d)
        out = os.path.join(d, "out.h5")
        base = ["-r", "256", "-o", out, model]
        occ = whole_process(base)
        part = whole_process(base + ["--labels", "part"])
        print(f"| occupancy only | 256³ | {occ:.2f} | |")
        print(f"| --labels part (20 parts) | 256³ | {part:.2f} | {part / occ:.2f}x occupancy |",
              flush=True)
        colour = whole_process(base + ["--color"])
        material = whole_process(base + ["--labels", "material"])
        print(f"| exact colour (--color) | 256³ | {colour:.2f} | |")
        print(f"| --labels material (20 materials) | 256³ | {material:.2f} | "
              f"{material / colour:.2f}x exact colour |", flush=True)


if __name__ == "__main__":
    main()
