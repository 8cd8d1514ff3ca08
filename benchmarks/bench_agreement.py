"""Voxel-for-voxel agreement on closed meshes: geovox's two backends, Open3D,
and a parity fill over trimesh's own multi-hit Embree loop (what a naive
Embree backend would inherit).

Usage: python benchmarks/bench_agreement.py [--res 256 512]
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import load_model  # noqa: E402

import geovox  # noqa: E402
from geovox import parity  # noqa: E402
from geovox.backends import Hits  # noqa: E402


def trimesh_multihit(mesh, grid):
    """Occupancy from trimesh's RayMeshIntersector.intersects_location (all hits)."""
    import trimesh
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    tm = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
    cols = grid.columns(2, start=mesh.bounds[0, 2] - 1e-3 * mesh.scale)
    u, v = np.meshgrid(cols.centres_u(), cols.centres_v(), indexing="ij")
    origins = np.stack([u.ravel(order="F"), v.ravel(order="F"),
                        np.full(u.size, cols.start)], axis=1)
    dirs = np.tile([0.0, 0.0, 1.0], (len(origins), 1))
    loc, ray, tri = RayMeshIntersector(tm).intersects_location(origins, dirs, multiple_hits=True)
    hits = Hits(ray.astype(np.int64), loc[:, 2] - cols.w0, tri.astype(np.int64), np.zeros((len(ray), 2)))
    return parity.fill(hits, cols, grid)


def open3d_occupancy(mesh, grid):
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices.astype(np.float32)),
                        o3d.core.Tensor(mesh.faces.astype(np.uint32)))
    c = [grid.centres(a).astype(np.float32) for a in range(3)]
    pts = np.stack(np.meshgrid(*c, indexing="ij"), axis=-1).reshape(-1, 3)
    return scene.compute_occupancy(o3d.core.Tensor(pts)).numpy().reshape(grid.shape).astype(bool)


def winding_inside(mesh, points):
    """Generalised winding number > 1/2 in float64 (slow; for a few points)."""
    T = mesh.triangles
    out = np.zeros(len(points), bool)
    for n, p in enumerate(points):
        A, B, C = T[:, 0] - p, T[:, 1] - p, T[:, 2] - p
        a, b, c = (np.linalg.norm(x, axis=1) for x in (A, B, C))
        num = np.einsum("ij,ij->i", A, np.cross(B, C))
        den = (a * b * c + np.einsum("ij,ij->i", A, B) * c + np.einsum("ij,ij->i", B, C) * a
               + np.einsum("ij,ij->i", C, A) * b)
        out[n] = np.arctan2(num, den).sum() / (2 * np.pi) > 0.5
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--res", type=int, nargs="+", default=[256, 512])
    p.add_argument("--models", nargs="+", default=["spot", "bunny105k"])
    args = p.parse_args()
    print(f"# bench_agreement {datetime.date.today()}")
    print("| model | grid | geovox inside | numpy vs embree | vs Open3D (float32) | vs trimesh multi-hit parity |")
    print("|---|---|---|---|---|---|")
    for model in args.models:
        mesh = load_model(model)
        for res in args.res:
            a = geovox.voxelize(mesh, resolution=res, backend="numpy")
            b = geovox.voxelize(mesh, resolution=res, backend="embree")
            d_be = np.count_nonzero(a.occupancy != b.occupancy)
            try:
                idx = np.argwhere(open3d_occupancy(mesh, a.grid) != a.occupancy)
                pts = np.stack([a.grid.centres(k)[idx[:, k]] for k in range(3)], axis=1)
                right = np.count_nonzero(winding_inside(mesh, pts) == a.occupancy[tuple(idx.T)])
                d_o3 = f"{len(idx)} (geovox matches the float64 winding number on {right})"
            except ImportError:
                d_o3 = "n/a"
            d_tm = np.count_nonzero(trimesh_multihit(mesh, a.grid) != a.occupancy)
            print(f"| {model} | {res}³ | {a.inside_count:,} | {d_be} | {d_o3} | {d_tm} |", flush=True)


if __name__ == "__main__":
    main()
