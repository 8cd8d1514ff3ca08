"""Every file of a loader test suite through the CLI, as a new user would run it.

The yardstick of issue 12: trimesh's own ``models/`` folder (about 150 files of
every format, many broken on purpose). Get it with

    git clone --depth 1 https://github.com/mikedh/trimesh /tmp/trimesh
    python benchmarks/bench_wild.py /tmp/trimesh/models

(default folder: /work/wild/models when it exists). For every file, in a fresh
process each with a time-out:

* ``geovox convert FILE -r 64 --color -o TMP/out.npz`` and ``geovox info FILE``,
  sorted into: converted (exit 0), error (exit 2 with one ``geovox: error:`` line
  on stderr that names the file), and anything else: a traceback, a time-out,
  a file left behind by a failed run, an error line that does not name the file,
  or exit 0 with an empty volume and no warning.
* For every converted file, the IoU of the volume with a brute-force winding
  number at the same voxel centres: the exact solid-angle sum (Van Oosterom and
  Strackee) over every triangle of the *repaired* mesh, inside when > 1/2. The
  mesh is loaded by trimesh (``trimesh.load(..., force="mesh", process=False)``,
  independent of geovox's own readers) and repaired with trimesh's own tools:
  ``merge_vertices()`` (by position), ``update_faces(nondegenerate_faces())``,
  ``update_faces(unique_faces())`` (which also collapses the two sides of a
  double-sided face) and ``trimesh.repair.fix_normals(multibody=True)``
  (faces wound consistently across each body, each closed body turned
  outward); vertices are merged by position alone (``merge_tex=True,
  merge_norm=True``), and each open body is turned to the side that most
  rays from outside enter (:func:`orient_open_bodies`, the rule issue 12
  gives for open pieces; geovox uses its capped volume's sign instead). The
  repaired mesh is a *solid* when every connected piece of it is watertight
  and consistently wound (``mesh.split(only_watertight=False)``): closed
  parts may touch or overlap, as in CAD assemblies, and their union is the
  solid (the winding number counts an overlap as 2, inside). A voxel centre on the surface (in the plane of a triangle
  and inside it or on its edge) counts as agreeing either way: geovox decides
  those by its tie rule, and the solid angle jumps there.
  Meshes whose triangles x voxels exceed ``--budget`` are
  compared on a random sample of voxels, half inside and half outside geovox's
  volume, each half weighted by its share (the table gives the sample size).

Usage: python benchmarks/bench_wild.py [FOLDER] [--timeout 120] [--only SUBSTRING]
       [--budget 1e7] [--json ROWS.json]
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
DEFAULT = "/work/wild/models"


def geovox_cmd():
    """The installed console script beside this interpreter, else ``python -m geovox``."""
    exe = os.path.join(os.path.dirname(sys.executable), "geovox")
    return [exe] if os.path.exists(exe) else [sys.executable, "-m", "geovox"]


def run(cmd, cwd, timeout):
    """Run one command in a fresh process; (exit status or 'timeout', stdout, stderr, seconds)."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    t = time.perf_counter()
    try:
        out = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout,
                             env=env, check=False)
    except subprocess.TimeoutExpired:
        return "timeout", "", "", time.perf_counter() - t
    return out.returncode, out.stdout, out.stderr, time.perf_counter() - t


def classify(rc, stderr, name, leftovers):
    """'ok', 'error' (one clear line) or a short description of what went wrong."""
    if rc == "timeout":
        return "TIME-OUT"
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    if "Traceback" in stderr:
        return "TRACEBACK: " + (lines[-1][:80] if lines else "")
    if rc == 0:
        return "ok"
    if leftovers:
        return f"LEFTOVER {', '.join(leftovers)}"
    errors = [ln for ln in lines if ln.startswith("geovox: error:")]
    if rc == 2 and len(errors) == 1 and not [ln for ln in lines if not ln.startswith("geovox: ")]:
        if os.path.splitext(name)[0].lower() not in errors[0].lower():
            return "ERROR WITHOUT FILE NAME: " + errors[0]
        return "error"
    return f"EXIT {rc}: " + " / ".join(lines[-2:])[:100]


# --------------------------------------------------------------------------- reference


def solid_angle_sum(triangles, points, chunk=1 << 20):
    """Generalised winding number at each point, by brute force over every triangle.

    Parameters
    ----------
    triangles : (m, 3, 3) float64
    points : (p, 3) float64

    Returns
    -------
    winding : (p,) float64
        The sum of the triangles' signed solid angles / (4 pi).
    on_surface : (p,) bool
        The point lies on a triangle (in its plane, inside it or on its edge),
        where the solid angle jumps by 4 pi and the sum means nothing.
    """
    out = np.zeros(len(points))
    tie = np.zeros(len(points), dtype=bool)
    if len(triangles) == 0:
        return out, tie
    # One coordinate per array, (points, triangles): plain element-wise passes.
    v = [[np.ascontiguousarray(triangles[:, k, d]) for d in range(3)] for k in range(3)]
    step = max(1, chunk // len(triangles))
    for s in range(0, len(points), step):
        p = points[s:s + step]
        (ax, ay, az), (bx, by, bz), (cx, cy, cz) = (
            [v[k][d][None, :] - p[:, d, None] for d in range(3)] for k in range(3))
        la = np.sqrt(ax * ax + ay * ay + az * az)
        lb = np.sqrt(bx * bx + by * by + bz * bz)
        lc = np.sqrt(cx * cx + cy * cy + cz * cz)
        det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
        den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
               + (bx * cx + by * cy + bz * cz) * la + (cx * ax + cy * ay + cz * az) * lb)
        out[s:s + step] = np.arctan2(det, den).sum(axis=1)
        scale = la * lb * lc
        tie[s:s + step] = ((np.abs(det) <= 1e-9 * scale) & (den <= 1e-9 * scale)).any(axis=1)
    return out / (2.0 * np.pi), tie


def repaired(path):
    """trimesh's own load and repair of a file (see the module docstring), or None."""
    import logging

    import trimesh

    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    try:
        m = trimesh.load(path, force="mesh", process=False)
    except Exception:
        return None
    if not isinstance(m, trimesh.Trimesh) or len(m.faces) == 0:
        return None
    m = trimesh.Trimesh(m.vertices, m.faces, process=False)
    # By position only: vertices that differ in normal or texture coordinate
    # are one vertex of the shape (else the two sides of a double-sided face
    # are not seen as duplicates, and they cancel in the winding number).
    m.merge_vertices(merge_tex=True, merge_norm=True)
    m.update_faces(m.nondegenerate_faces())
    m.update_faces(m.unique_faces())
    m.remove_unreferenced_vertices()
    if len(m.faces):
        trimesh.repair.fix_normals(m, multibody=True)
        orient_open_bodies(m)
    return m


def orient_open_bodies(m, rays=20000, seed=0):
    """Turn each open body of ``m`` (in place) to the side that most rays from outside enter.

    trimesh's ``fix_normals`` turns only closed bodies outward. For an open
    one, issue 12's rule: cast ``rays`` rays from outside (directions uniform
    on the sphere, origins uniform on a disk that covers the bounding sphere),
    take each ray's first hit on the whole model, and count, per body, the hits
    that enter the outward side (the face's normal against the ray); a body
    that most of its hits leave is turned over. A body no ray hits, or one with
    as many of each, stays as it is. Independent of geovox, which orients open
    pieces by the sign of their capped volume instead: this checks that rule.
    """
    import trimesh

    label = trimesh.graph.connected_component_labels(m.face_adjacency, node_count=len(m.faces))
    edges = m.edges_sorted
    key = edges[:, 0].astype(np.int64) * (len(m.vertices) + 1) + edges[:, 1]
    _, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    open_face = np.zeros(len(m.faces), bool)
    open_face[m.edges_face[count[inv.reshape(-1)] == 1]] = True
    open_body = np.unique(label[open_face])
    if len(open_body) == 0:
        return
    rng = np.random.default_rng(seed)
    centre = m.bounds.mean(axis=0)
    radius = max(float(np.linalg.norm(m.extents)) / 2, 1e-12) * 1.01
    d = rng.normal(size=(rays, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    u = np.cross(d, rng.normal(size=(rays, 3)))
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(d, u)
    r = radius * np.sqrt(rng.random(rays))
    a = 2 * np.pi * rng.random(rays)
    origin = centre - 2 * radius * d + (r * np.cos(a))[:, None] * u + (r * np.sin(a))[:, None] * v
    tri = m.ray.intersects_first(origin, d)
    hit = tri >= 0
    vote = np.where((m.face_normals[tri[hit]] * d[hit]).sum(axis=1) < 0, 1, -1)
    total = np.bincount(label[tri[hit]], weights=vote, minlength=int(label.max()) + 1)
    turn = np.zeros(len(total), bool)
    turn[open_body] = total[open_body] < 0
    if turn.any():
        f = m.faces.copy()
        sel = turn[label]
        f[sel] = f[sel][:, ::-1]
        m.faces = f


def iou(path, npz, budget, seed=0):
    """(IoU %, voxels compared, solid?) of a converted volume against the reference.

    The whole grid when triangles x voxels fits ``budget``; otherwise a sample
    drawn half from the voxels geovox calls inside and half from the rest,
    each half weighted by its share of the grid, so a small object is still
    measured on its own voxels.
    """
    ref_mesh = repaired(path)
    if ref_mesh is None or len(ref_mesh.faces) == 0:
        return None, 0, False
    with np.load(npz) as z:
        occ = z["occupancy"].astype(bool)
        lo = np.asarray(z["bounds"], float).reshape(2, 3)[0]
        spacing = np.asarray(z["spacing"], float)
    tri = np.asarray(ref_mesh.triangles, float)
    strata = [np.flatnonzero(occ.ravel(order="C")), np.flatnonzero(~occ.ravel(order="C"))]
    n = max(4000, int(budget // len(tri)))
    rng = np.random.default_rng(seed)
    inter = union = 0.0
    compared = 0
    for k, cells in enumerate(strata):
        if len(cells) == 0:
            continue
        take = cells if occ.size <= n else rng.choice(cells, min(len(cells), n // 2), replace=False)
        weight = len(cells) / len(take)
        idx = np.stack(np.unravel_index(take, occ.shape), axis=1)
        w, on_surface = solid_angle_sum(tri, lo + (idx + 0.5) * spacing)
        # A centre on the surface is inside or out by a tie rule, not by the
        # shape: it counts as agreeing.
        ref = np.where(on_surface | (np.abs(w - 0.5) < 1e-6), k == 0, w > 0.5)
        compared += len(take)
        if k == 0:  # geovox inside: in the union; in the intersection where ref agrees
            inter += weight * np.count_nonzero(ref)
            union += len(cells)
        else:
            union += weight * np.count_nonzero(ref)
    value = 100.0 if union == 0 else 100.0 * inter / union
    return value, compared, is_solid(ref_mesh)


def is_solid(mesh):
    """Every connected piece closed and consistently wound (pieces may overlap or touch)."""
    pieces = mesh.split(only_watertight=False)
    return bool(len(pieces)) and all(p.is_watertight and p.is_winding_consistent for p in pieces)


def trimesh_faces(path):
    """Triangles trimesh itself loads from the file (0 for point clouds, lines, failures)."""
    import logging

    import trimesh

    logging.getLogger("trimesh").setLevel(logging.CRITICAL)
    try:
        m = trimesh.load(path, process=False)
    except Exception:
        return 0
    parts = m.dump(concatenate=False) if isinstance(m, trimesh.Scene) else [m]
    return sum(len(g.faces) for g in parts if isinstance(g, trimesh.Trimesh))


# --------------------------------------------------------------------------- main


def one(path, args, work):
    name = os.path.basename(path)
    tmp = tempfile.mkdtemp(dir=work)
    out = os.path.join(tmp, "out.npz")
    rc, so, se, secs = run(geovox_cmd() + ["convert", path, "-r", "64", "--color", "-o", out],
                           tmp, args.timeout)
    left = sorted(f for f in os.listdir(tmp) if not (rc == 0 and f in ("out.npz",)))
    conv = classify(rc, se, name, left if rc != 0 else [])
    if rc == 0 and left:
        conv = f"LEFTOVER {', '.join(left)}"
    warn = [ln[len("geovox: warning: "):] for ln in se.splitlines()
            if ln.startswith("geovox: warning:")]
    inside = None
    for ln in so.splitlines():
        if ln.startswith("inside "):
            inside = int(ln.split()[1].replace(",", ""))
    if conv == "ok" and inside == 0 and not any("empty" in w for w in warn):
        conv = "EMPTY, NO WARNING"
    rci, _, sei, secs_info = run(geovox_cmd() + ["info", path], tmp, args.timeout)
    info = classify(rci, sei, name, [])
    faces = trimesh_faces(path)
    score = (None, 0, False)
    if rc == 0 and os.path.exists(out):
        score = iou(path, out, args.budget)
    shutil.rmtree(tmp, ignore_errors=True)
    errline = next((ln for ln in se.splitlines() if ln.startswith("geovox: error:")), "")
    return dict(name=name, path=path, conv=conv, secs=secs, info=info, secs_info=secs_info, faces=faces,
                inside=inside, warn=warn, error=errline[len("geovox: error: "):],
                iou=score[0], compared=score[1], solid=score[2])


def _short(text, path):
    """A message without the file's path, the open-mesh warning cut to its numbers."""
    text = text.replace(path + ": ", "").replace(path, "FILE")
    m = re.match(r"the mesh is not closed \((\d+) open edges, (\d+) non-manifold", text)
    if m:
        return f"not closed ({m.group(1)} open, {m.group(2)} non-manifold edges)"
    return text if len(text) <= 160 else text[:157] + "..."


def fmt_row(r):
    iou_s = "" if r["iou"] is None else f"{r['iou']:.1f}"
    if r["iou"] is not None and r["compared"] < 64 ** 3:
        iou_s += f" ({r['compared']:,})"
    status = r["conv"] if r["conv"] != "ok" else f"converted, {r['inside']:,} inside"
    note = (_short(r["error"], r["path"]) if r["conv"] == "error"
            else "; ".join(_short(w, r["path"]) for w in r["warn"]))
    note = note.replace("|", "/")
    return (f"| {r['name']} | {r['faces']:,} | {status} | {r['secs']:.1f} | "
            f"{'ok' if r['info'] == 'ok' else r['info']} | {iou_s} | "
            f"{'yes' if r['solid'] else ('no' if r['iou'] is not None else '')} | {note} |")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("folder", nargs="?", default=DEFAULT,
                   help="trimesh's models/ folder (git clone https://github.com/mikedh/trimesh)")
    p.add_argument("--timeout", type=float, default=120.0, help="seconds per command")
    p.add_argument("--only", default=None,
                   help="only files whose name contains one of these (comma-separated)")
    p.add_argument("--budget", type=float, default=1e7,
                   help="triangle-voxel pairs summed per file; beyond it voxels are sampled "
                        "(1e12: the whole grid)")
    p.add_argument("--json", default=None, help="also write every row to this JSON file")
    args = p.parse_args(argv)
    if not os.path.isdir(args.folder):
        sys.exit(f"no folder {args.folder}: clone https://github.com/mikedh/trimesh and pass "
                 f"its models/ folder")
    files = sorted(f for f in os.listdir(args.folder)
                   if os.path.isfile(os.path.join(args.folder, f))
                   and (args.only is None or any(o in f for o in args.only.split(","))))
    work = tempfile.mkdtemp(prefix="bench_wild_")
    print(f"# bench_wild {datetime.date.today()}: {len(files)} files of {args.folder}, "
          f"`geovox convert FILE -r 64 --color` and `geovox info FILE`, time-out {args.timeout:g} s")
    print("| file | trimesh triangles | convert | s | info | IoU % (voxels) | solid | "
          "error or warnings |")
    print("|---|---|---|---|---|---|---|---|")
    rows = []
    try:
        for f in files:
            r = one(os.path.join(args.folder, f), args, work)
            rows.append(r)
            print(fmt_row(r), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(rows, f, indent=1)
    bad = [r for r in rows if r["conv"] not in ("ok", "error") or r["info"] not in ("ok", "error")]
    missed = [r for r in rows if r["faces"] > 0 and r["conv"] != "ok"]
    low = [r for r in rows if r["solid"] and r["iou"] is not None and r["iou"] < 99.0]
    slow = [r for r in rows if r["secs"] > 10]
    print()
    print(f"converted {sum(r['conv'] == 'ok' for r in rows)}, one-line error "
          f"{sum(r['conv'] == 'error' for r in rows)}, anything else {len(bad)}"
          + (f" ({', '.join(r['name'] for r in bad)})" if bad else ""))
    print(f"trimesh loads triangles but geovox does not convert: {len(missed)}"
          + (f" ({', '.join(r['name'] for r in missed)})" if missed else ""))
    print(f"solid after repair with IoU < 99 %: {len(low)}"
          + (f" ({', '.join(r['name'] + ' %.1f' % r['iou'] for r in low)})" if low else ""))
    print(f"over 10 s: {len(slow)}"
          + (f" ({', '.join(r['name'] + ' %.1f s' % r['secs'] for r in slow)})" if slow else ""))


if __name__ == "__main__":
    main()
