"""Coverage density and signed distance: speed and accuracy.

In-process times are the best of 3 runs of ``geovox.voxelize`` on a loaded
mesh (after a warm-up); end to end is a fresh interpreter running
``geovox convert spot.obj --density coverage --supersample 4`` to a RAW file.

Usage: python benchmarks/bench_density.py
"""

from __future__ import annotations

import datetime
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import SPOT, load_model  # noqa: E402

import geovox  # noqa: E402


def best(fn, n=3):
    fn()
    t = []
    for _ in range(n):
        t0 = time.perf_counter()
        out = fn()
        t.append(time.perf_counter() - t0)
    return min(t), out


def main():
    print(f"# bench_density {datetime.date.today()}")
    print("| what | model | grid | backend | time (s) | result |")
    print("|---|---|---|---|---|---|")
    spot = load_model("spot")
    import trimesh

    sphere = geovox.Mesh(*(np.asarray(a) for a in (trimesh.creation.icosphere(5).vertices,
                                                   trimesh.creation.icosphere(5).faces)))
    for backend in geovox.available_backends():
        t, v = best(lambda: geovox.voxelize(spot, resolution=256, density="coverage",
                                            supersample=4, backend=backend))
        print(f"| coverage K=4, in process | spot | 256³ | {backend} | {t:.2f} | "
              f"{np.count_nonzero((v.density > 0) & (v.density < 255)):,} partial voxels |", flush=True)
        t, v = best(lambda: geovox.voxelize(sphere, resolution=128, density="coverage",
                                            supersample=4, density_dtype="float32", backend=backend))
        vol = float(v.density.astype(np.float64).sum() * np.prod(v.spacing))
        err = (vol - 4 / 3 * math.pi) / (4 / 3 * math.pi)
        print(f"| coverage K=4 volume vs 4/3 π r³ | icosphere(5), 20,480 tri | 128³ | {backend} | "
              f"{t:.2f} | {100 * err:+.3f} % |", flush=True)
        t, v = best(lambda: geovox.voxelize(spot, resolution=128, sdf=True, backend=backend), n=1)
        print(f"| signed distance, band 3 | spot | 128³ | {backend} | {t:.2f} | "
              f"range {v.sdf.min():.4f} .. {v.sdf.max():.4f} |", flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            runs = []
            for _ in range(3):
                t0 = time.perf_counter()
                subprocess.run([sys.executable, "-m", "geovox", "convert", SPOT, "-o",
                                os.path.join(tmp, "s.raw"), "-r", "256", "--density", "coverage",
                                "--supersample", "4", "--backend", backend, "-q"], check=True)
                runs.append(time.perf_counter() - t0)
        print(f"| coverage K=4, end to end (CLI) | spot | 256³ | {backend} | {min(runs):.2f} | |",
              flush=True)


if __name__ == "__main__":
    main()
