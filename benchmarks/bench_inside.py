"""Inside tests on models from the wild (issue 12): agreement and time.

Agreement: for every open model of the corpus and for synthetic broken
variants of closed ones, the share of voxels on which ``inside="auto"``
agrees with a brute-force generalised winding number of the *repaired* mesh
(``geovox.inside.repair``): the solid angle of every triangle summed exactly at the
voxel centres (float64, Van Oosterom and Strackee), inside where > 1/2. Every
voxel is checked where triangles x voxels <= 5e7, else a random sample of
voxels (the table says which). Flipped and doubled variants are also compared
voxel for voxel with the clean model under parity.

Time: each method on a fresh copy of the loaded mesh (so the first-call work,
Embree's scene and checks, and the repair, is counted; imports warm).

The speed targets (``--targets``): the user's path, ``geovox convert FILE -r N
-o out.npy`` with default options in a fresh process each run (the console
script; ``/usr/bin/time -v`` gives the same wall time), against ``--inside
parity`` on the same file, the runs taken in turn (auto, parity, auto, ...)
so that a drifting load hits both alike; medians. Beside it, warm in-process
``geovox.voxelize`` of a fresh copy of the loaded mesh (imports and first
allocations warm). Models: an icosphere of 20,480 faces with 10 and with 200
one-triangle holes at 256³ (issue 12: at most twice parity), and the 86-part
cracked assembly below at 128³ (at most 5 s).

Usage: python benchmarks/bench_inside.py [--res 64] [--samples 4000] [--times 64,128,256]
       [--skip-agreement] [--targets [--runs 5]]
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
from geovox import inside  # noqa: E402
from geovox.inside import boundary_edges, edge_counts  # noqa: E402

OPEN = ["suzanne/suzanne.obj", "stanford_bunny/bunny.obj", "cornell_box/cornell_box.obj",
        "trimesh_edge_cases/wallhole.obj", "trimesh_edge_cases/two_objects.obj",
        "trimesh_edge_cases/joined_tetrahedra.obj", "trimesh_edge_cases/polygonfaces.obj"]


def brute_inside(mesh, points, block=1 << 20):
    """(n,) bool: generalised winding number > 1/2, every triangle summed exactly."""
    tris = mesh.triangles
    out = np.zeros(len(points))
    per = max(1, block // max(1, len(tris)))
    for s in range(0, len(points), per):
        p = points[s:s + per]
        for t0 in range(0, len(tris), block):
            t = tris[t0:t0 + block]
            k = len(p)
            a = inside.captree.triangle_angles(np.tile(t, (k, 1, 1)), np.repeat(p, len(t), axis=0))
            out[s:s + per] += a.reshape(k, -1).sum(axis=1)
    return out > 0.5


def mesh_of(v, f, name):
    return geovox.Mesh(np.asarray(v, float), np.asarray(f, np.int64), source=name)


def flip(mesh, share=0.3, seed=0):
    rng = np.random.default_rng(seed)
    f = mesh.faces.copy()
    sel = rng.random(len(f)) < share
    f[sel] = f[sel][:, ::-1]
    return mesh_of(mesh.vertices, f, f"{mesh.source}, 30 % of faces flipped")


def doubled(mesh):
    return mesh_of(mesh.vertices, np.concatenate([mesh.faces, mesh.faces[:, ::-1]]),
                   f"{mesh.source}, every face also reversed")


def overlapping(mesh, shift=0.3):
    d = shift * (mesh.bounds[1] - mesh.bounds[0])
    v = np.concatenate([mesh.vertices, mesh.vertices + d * [1, 0.5, 0.2]])
    return mesh_of(v, np.concatenate([mesh.faces, mesh.faces + len(mesh.vertices)]),
                   f"two overlapping {mesh.source}")


def holes(mesh, n, seed=0):
    rng = np.random.default_rng(seed)
    keep = np.ones(len(mesh.faces), bool)
    keep[rng.choice(len(mesh.faces), n, replace=False)] = False
    return mesh_of(mesh.vertices, mesh.faces[keep], f"{mesh.source}, {n} one-triangle holes")


def open_boxes(n, seed=0, share=0.3, size=(0.02, 0.08)):
    """``n`` boxes without their top, at random places and angles, 30 % of faces flipped."""
    import trimesh

    rng = np.random.default_rng(seed)
    b = trimesh.creation.box((1, 1, 1))
    f0 = np.asarray(b.faces)[b.triangles_center[:, 2] < 0.49]
    V, F = [], []
    for i in range(n):
        R = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
        V.append(np.asarray(b.vertices) * rng.uniform(*size) @ R.T + rng.uniform(0, 1, 3))
        F.append(f0 + 8 * i)
    F = np.concatenate(F)
    sel = rng.random(len(F)) < share
    F[sel] = F[sel][:, ::-1]
    return mesh_of(np.concatenate(V), F, f"{n} open boxes")


def cracked_assembly(seed=0, holes_per_part=50):
    """About 110k triangles and 13k open edges, as a CAD assembly has them.

    86 closed parts (icospheres of 1,280 triangles, scaled and placed at
    random, overlapping) with an unwelded seam each (the faces on one side of
    a random plane use copies of the vertices moved by 1e-7: a crack), and
    ``holes_per_part`` faces missing from each; 30 % of faces are flipped.
    """
    import trimesh

    rng = np.random.default_rng(seed)
    ico = trimesh.creation.icosphere(subdivisions=3)
    v0, f0 = np.asarray(ico.vertices), np.asarray(ico.faces)
    V, F, off = [], [], 0
    for i in range(86):
        v = v0 * rng.uniform(0.05, 0.2, 3) + rng.uniform(0, 1, 3)
        # Faces with centroid above a random plane use their own copies of
        # the vertices: a seam of open edges around that cap.
        n = rng.normal(size=3)
        top = (v0[f0].mean(axis=1) @ n) > rng.uniform(-0.3, 0.3)
        f = f0.copy()
        f[top] += len(v0)
        f = f[np.sort(rng.choice(len(f), len(f) - holes_per_part, replace=False))]
        # Unwelded copies moved by a float32 rounding step: a crack, not a gap.
        V += [v, v + 1e-7]
        F.append(f + off)
        off += 2 * len(v0)
    F = np.concatenate(F)
    sel = rng.random(len(F)) < 0.3
    F[sel] = F[sel][:, ::-1]
    m = mesh_of(np.concatenate(V), F, f"86-part cracked assembly, {holes_per_part} holes a part")
    return m


def agreement(mesh, res, samples, rng):
    warnings.simplefilter("ignore")
    vol = geovox.voxelize(mesh, resolution=res)
    g = vol.grid
    ref_mesh = inside.target(mesh)[0]
    if len(ref_mesh.faces) * g.size <= 5e7:
        idx = np.argwhere(np.ones(g.shape, bool))
        how = "all"
    else:
        idx = np.stack([rng.integers(0, n, samples) for n in g.shape], axis=1)
        how = f"{samples:,} sampled"
    pts = np.stack([g.centres(a)[idx[:, a]] for a in range(3)], axis=1)
    ref = brute_inside(ref_mesh, pts)
    return vol, 100.0 * np.mean(vol.occupancy[tuple(idx.T)] == ref), how


def timed(mesh, res, method):
    warnings.simplefilter("ignore")
    fresh = mesh_of(mesh.vertices, mesh.faces, mesh.source)  # nothing cached
    t = time.perf_counter()
    vol = geovox.voxelize(fresh, resolution=res, inside=method)
    return time.perf_counter() - t, vol


def targets(runs):
    """The speed targets' rows: whole process and warm in-process (see the module notes)."""
    import statistics
    import subprocess
    import tempfile

    import trimesh

    tmp = tempfile.mkdtemp(prefix="bench_inside_")
    ico = trimesh.creation.icosphere(subdivisions=5)
    sphere = mesh_of(ico.vertices, ico.faces, "icosphere(5)")
    assembly = cracked_assembly()
    exe = os.path.join(os.path.dirname(sys.executable), "geovox")
    cmd = [exe] if os.path.exists(exe) else [sys.executable, "-m", "geovox"]
    env = dict(os.environ, PYTHONPATH=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    print(f"# bench_inside --targets {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC,"
          f" load average {os.getloadavg()[0]:.1f}, {runs} runs each")
    print("| model | grid | auto, whole process (s) | parity, whole process (s) | ratio | "
          "auto, warm in process (s) | parity, warm in process (s) | auto ran |")
    print("|---|---|---|---|---|---|---|---|")
    for name, m, res in [("icosphere(5), 10 one-triangle holes", holes(sphere, 10), 256),
                         ("icosphere(5), 200 one-triangle holes", holes(sphere, 200), 256),
                         ("86-part cracked assembly", assembly, 128)]:
        path = os.path.join(tmp, "model.obj")
        trimesh.Trimesh(m.vertices, m.faces, process=False).export(path)
        whole = {"auto": [], "parity": []}
        for _ in range(runs):
            for meth in whole:
                extra = [] if meth == "auto" else ["--inside", "parity"]
                t = time.perf_counter()
                subprocess.run(cmd + ["convert", path, "-r", str(res), "-o",
                                      os.path.join(tmp, "out.npy")] + extra,
                               env=env, check=True, capture_output=True)
                whole[meth].append(time.perf_counter() - t)
        warm, ran = {}, ""
        for meth in ("auto", "parity"):
            got = [timed(m, res, meth) for _ in range(runs + 1)][1:]  # the first warms up
            warm[meth] = statistics.median(g[0] for g in got)
            ran = ran or got[-1][1].inside
        a, b = statistics.median(whole["auto"]), statistics.median(whole["parity"])
        print(f"| {name} | {res}³ | {a:.2f} | {b:.2f} | {a / b:.2f} | {warm['auto']:.2f} | "
              f"{warm['parity']:.2f} | {ran} |", flush=True)
    print(f"# load average after: {os.getloadavg()[0]:.1f}")


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--res", type=int, default=64)
    p.add_argument("--samples", type=int, default=4000)
    p.add_argument("--times", default="64,128,256")
    p.add_argument("--skip-agreement", action="store_true", help="print the times only")
    p.add_argument("--targets", action="store_true",
                   help="only the speed targets: whole process and warm in process")
    p.add_argument("--runs", type=int, default=5)
    args = p.parse_args()
    if args.targets:
        warnings.simplefilter("ignore")
        targets(args.runs)
        return
    warnings.simplefilter("ignore")
    rng = np.random.default_rng(0)
    bunny = geovox.load_mesh(os.path.join(CORPUS, "bunny_watertight", "bunny_oded.obj"))
    bunny.source = "bunny_oded"
    big = load_model("bunny105k")
    models = [geovox.load_mesh(os.path.join(CORPUS, rel)) for rel in OPEN]
    for m, rel in zip(models, OPEN):
        m.source = rel.split("/")[-1]
    clean_variants = [(bunny, flip(bunny)), (bunny, doubled(bunny)), (big, flip(big)),
                      (big, doubled(big))]
    models += [v for _, v in clean_variants]
    models += [overlapping(bunny), holes(big, 1000), cracked_assembly(), open_boxes(300)]
    print(f"# bench_inside {datetime.date.today()}: agreement of auto at {args.res}³")
    print("| model | triangles | open / non-manifold / unpartnered edges | auto ran | agrees with "
          "brute force (voxels checked) | same voxels as the clean model |")
    print("|---|---|---|---|---|---|")
    clean_of = {id(v): c for c, v in clean_variants}
    for m in ([] if args.skip_agreement else models):
        n_open, n_nm = edge_counts(m)
        vol, agree, how = agreement(m, args.res, args.samples, rng)
        same = ""
        if id(m) in clean_of:
            c = geovox.voxelize(clean_of[id(m)], resolution=args.res, inside="parity",
                                bounds=np.r_[vol.grid.lo, vol.grid.hi])
            same = (f"yes ({c.inside_count:,})" if np.array_equal(c.occupancy, vol.occupancy)
                    else f"no ({vol.inside_count:,} vs {c.inside_count:,})")
        print(f"| {m.source} | {len(m.faces):,} | {n_open:,} / {n_nm:,} / "
              f"{len(boundary_edges(m)):,} | {vol.inside} | {agree:.2f} % ({how}) | {same} |",
              flush=True)
    print()
    print("| model | grid | parity (s) | vote (s) | winding (s) | auto (s) |")
    print("|---|---|---|---|---|---|")
    res_all = list(map(int, args.times.split(",")))
    # The many-large-caps models only where they finish in reasonable time.
    timing = [(models[1], res_all), (models[2], res_all), (clean_variants[2][1], res_all),
              (clean_variants[3][1], res_all), (models[-4], res_all), (models[-3], res_all),
              (models[-2], [r for r in res_all if r <= 128]), (models[-1], [64])]
    for m, resolutions in timing:
        for res in resolutions:
            row = [f"{timed(m, res, meth)[0]:.2f}" for meth in ("parity", "vote", "winding", "auto")]
            print(f"| {m.source} | {res}³ | " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
