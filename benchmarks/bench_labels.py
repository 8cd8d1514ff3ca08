"""Labels: what labelling a 20-part assembly costs over occupancy alone.

The model: 20 overlapping spheres (icosphere(4), 5,120 triangles each,
102,400 in all) in a 5 x 4 array, each an OBJ object with its own material
(Kd), written to a temporary folder. Every figure is the whole process (a
fresh interpreter running ``python -m geovox convert``, start-up and
loading included), ``RUNS`` pairs after one warm-up pair:

* occupancy only vs ``--labels part`` at 256³ (to ``.h5``);
* exact colour (``--color``) vs ``--labels material`` at 256³ (to ``.h5``).

Each pair runs in turn (A B A B ...), and the ratio is the median of the pairs' ratios, wall
and CPU, so that a change of the machine's load during the run moves both sides alike.

Usage: python benchmarks/bench_labels.py [RUNS] [--json]   (--json: write
benchmarks/results/labels.json, then run benchmarks/tables.py)
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

RUNS = next((int(a) for a in sys.argv[1:] if a.isdigit()), 5)


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


def _one_run(cmd, root) -> tuple:
    """(wall s, CPU s) of one fresh ``cmd`` process (CPU: user + system of the child)."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, cwd=root, stdout=subprocess.DEVNULL)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def paired(args_a, args_b) -> dict:
    """``python -m geovox convert`` with ``args_a`` (A) and ``args_b`` (B) in turn, A B A B...,
    RUNS pairs after one warm-up pair: the median wall and CPU seconds of each, and the
    median of the pair-by-pair ratios A/B (pairing keeps a ratio when the load drifts)."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    base = [sys.executable, "-m", "geovox", "convert"]
    runs = []
    for n in range(RUNS + 1):
        a = _one_run(base + args_a + ["-q"], root)
        b = _one_run(base + args_b + ["-q"], root)
        if n:
            runs.append((a, b))
    med = statistics.median
    return {"a_wall": med(a[0] for a, _ in runs), "a_cpu": med(a[1] for a, _ in runs),
            "b_wall": med(b[0] for _, b in runs), "b_cpu": med(b[1] for _, b in runs),
            "wall_ratio": med(a[0] / b[0] for a, b in runs),
            "cpu_ratio": med(a[1] / b[1] for a, b in runs)}


def main():
    write = "--json" in sys.argv
    load0 = os.getloadavg()[0]
    start = datetime.datetime.now(datetime.timezone.utc)
    print(f"# bench_labels {start:%Y-%m-%d %H:%M} UTC, {RUNS} pairs of whole-process runs, "
          f"load average {load0:.1f}")
    with tempfile.TemporaryDirectory() as d:
        model = assembly(d)
        out = os.path.join(d, "out.h5")
        base = ["-r", "256", "-o", out, model]
        part = paired(base + ["--labels", "part"], base)
        material = paired(base + ["--labels", "material"], base + ["--color"])
    load1 = os.getloadavg()[0]
    rows = [
        ["--labels part (20 parts) vs occupancy only", "256³", f"{part['a_wall']:.2f}",
         f"{part['b_wall']:.2f}", f"{part['wall_ratio']:.2f}x", f"{part['a_cpu']:.2f}",
         f"{part['b_cpu']:.2f}", f"{part['cpu_ratio']:.2f}x", "<= 1.5x"],
        ["--labels material (20 materials) vs exact colour (--color)", "256³",
         f"{material['a_wall']:.2f}", f"{material['b_wall']:.2f}",
         f"{material['wall_ratio']:.2f}x", f"{material['a_cpu']:.2f}", f"{material['b_cpu']:.2f}",
         f"{material['cpu_ratio']:.2f}x", "<= 1x"],
    ]
    columns = ["A vs B", "grid", "A wall (s)", "B wall (s)", "wall A/B", "A CPU (s)",
               "B CPU (s)", "CPU A/B", "target"]
    print("| " + " | ".join(columns) + " |")
    print("|" + "---|" * len(columns))
    for r in rows:
        print("| " + " | ".join(r) + " |")
    if write:
        import json

        result = {
            "benchmark": "labels",
            "title": "Labels: what a labelled conversion costs",
            "script": "benchmarks/bench_labels.py",
            "command": f"python benchmarks/bench_labels.py {RUNS} --json",
            "date": f"{start:%Y-%m-%d, %H:%M} UTC",
            "machine": ("the project machine: 2 cores, 24 GiB, Python 3.11, no GPU; load average "
                        f"{load0:.1f} before, {load1:.1f} after (shared with other work: the "
                        "pair-by-pair ratios hold better than the absolute times)"),
            "models": ["20 overlapping spheres (icosphere(4), 5,120 triangles each, 102,400 in "
                       "all) in a 5 x 4 array, each an OBJ object with its own material (Kd)"],
            "notes": ("Whole process: a fresh `python -m geovox convert ... -o out.h5` each run "
                      "(start-up, loading and writing included), A and B in turn, one warm-up "
                      f"pair, then {RUNS} pairs; medians, and the median of the pairs' ratios."),
            "tables": [{"caption": "Whole-process cost of labels at 256³", "columns": columns,
                        "rows": rows}],
        }
        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "labels.json")
        with open(path, "w", encoding="utf-8") as f:
            json.dump(result, f, indent=1, ensure_ascii=False)
            f.write("\n")
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
