"""Inside/outside methods on models that are not closed, against a trusted reference.

Reference: the generalised winding number summed by brute force over every
triangle (float64) at a random sample of voxel centres; inside when > 1/2.
Also times `winding` at 128³ on a 105k-triangle mesh with 200 holes punched
in it, against parity on the same mesh closed.

Usage: python benchmarks/bench_inside.py [--res 64] [--samples 4000]
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import CORPUS, load_model  # noqa: E402

import geovox  # noqa: E402
from geovox.inside import boundary_edges, edge_counts, solid_angles  # noqa: E402

MODELS = ["suzanne/suzanne.obj", "stanford_bunny/bunny.obj", "cornell_box/cornell_box.obj",
          "trimesh_edge_cases/wallhole.obj", "trimesh_edge_cases/two_objects.obj",
          "trimesh_edge_cases/joined_tetrahedra.obj", "trimesh_edge_cases/polygonfaces.obj"]


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--samples", type=int, default=4000)
    args = p.parse_args()
    warnings.simplefilter("ignore")
    print(f"# bench_inside {datetime.date.today()} grid {args.res}³, {args.samples} sampled voxels")
    print("| model | triangles | open / non-manifold edges | auto picks | parity | vote | winding | "
          "time parity / vote / winding (s) |")
    print("|---|---|---|---|---|---|---|---|")
    for rel in MODELS:
        mesh = geovox.load_mesh(os.path.join(CORPUS, rel))
        n_open, n_nm = edge_counts(mesh)
        auto = "parity" if len(boundary_edges(mesh)) == 0 else "winding"
        vols, times = {}, {}
        for method in ("parity", "vote", "winding"):
            t = time.perf_counter()
            vols[method] = geovox.voxelize(mesh, resolution=args.res, inside=method)
            times[method] = time.perf_counter() - t
        g = vols["parity"].grid
        rng = np.random.default_rng(0)
        idx = np.stack([rng.integers(0, n, args.samples) for n in g.shape], axis=1)
        pts = np.stack([g.centres(a)[idx[:, a]] for a in range(3)], axis=1)
        ref = solid_angles(mesh.triangles, pts) > 0.5
        agree = {m: 100.0 * np.mean(v.occupancy[tuple(idx.T)] == ref) for m, v in vols.items()}
        print(f"| {rel.split('/')[-1]} | {len(mesh.faces):,} | {n_open} / {n_nm} | {auto} | "
              f"{agree['parity']:.2f} % | {agree['vote']:.2f} % | {agree['winding']:.2f} % | "
              f"{times['parity']:.2f} / {times['vote']:.2f} / {times['winding']:.2f} |", flush=True)

    closed = load_model("bunny105k")
    rng = np.random.default_rng(0)
    keep = np.ones(len(closed.faces), bool)
    keep[rng.choice(len(closed.faces), 200, replace=False)] = False
    holed = geovox.Mesh(closed.vertices, closed.faces[keep], source="bunny105k with 200 holes")
    print()
    print("| mesh | grid | winding (s) | parity on the closed mesh (s) | voxels that differ |")
    print("|---|---|---|---|---|")
    for res in (128, 256):
        t = time.perf_counter()
        w = geovox.voxelize(holed, resolution=res, inside="winding")
        tw = time.perf_counter() - t
        t = time.perf_counter()
        c = geovox.voxelize(closed, resolution=res, inside="parity")
        tc = time.perf_counter() - t
        print(f"| bunny105k, 200 one-triangle holes ({len(boundary_edges(holed))} open edges) | "
              f"{res}³ | {tw:.2f} | {tc:.2f} | {np.count_nonzero(w.occupancy != c.occupancy)} |",
              flush=True)


if __name__ == "__main__":
    main()
