"""Sweep: geovox's own glTF/GLB/PLY readers against trimesh's, on every such file of public test sets.

For each ``.gltf``, ``.glb`` and ``.ply`` under trimesh's ``models/``,
assimp's ``test/models/{glTF2,PLY,OBJ}`` and tinygltf's ``models/`` (extracted
from git mirrors with ``git archive``), it loads the file twice:

* **geovox**: ``geovox.load_mesh(path)`` (:mod:`geovox.io.gltf`, :mod:`geovox.io.ply`);
* **trimesh**: ``trimesh.load(path, process=False)`` made into a Mesh by
  :func:`geovox.io.adaptor.from_trimesh` (what geovox read before);

and voxelises both on one grid (the geovox mesh's bounds, ``-r`` voxels
along its longest side, numpy backend, parity where closed), comparing the
occupancy. It prints one line per file and a summary; ``--json FILE``
writes the rows.

Each row's verdict: ``same`` (equal volumes), ``differs`` (counts of
voxels that differ, and the triangle counts), ``trimesh fails`` (trimesh
cannot read it or drops geometry, with its words) or ``both refuse``
(neither reads it: geovox's one line is printed), ``geovox refuses``.

    python benchmarks/sweep_readers.py --mirrors /work/.mirror -r 48 [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import subprocess
import sys
import time
import warnings

import numpy as np

SOURCES = [
    ("trimesh", "mikedh+trimesh", "models"),
    ("assimp", "assimp+assimp", "test/models/glTF2"),
    ("assimp", "assimp+assimp", "test/models/PLY"),
    ("assimp", "assimp+assimp", "test/models/OBJ"),
    ("tinygltf", "syoyo+tinygltf", "models"),
]
EXTS = (".gltf", ".glb", ".ply")


def extract(mirrors: str, out: str) -> tuple:
    """Extract each source's folder into ``out``: ``(model files, files the mirror lacks)``.

    File by file (``git cat-file``): a mirror may list a large file it does
    not hold.
    """
    files, absent = [], []
    for name, repo, folder in SOURCES:
        git = ["git", f"--git-dir={os.path.join(mirrors, repo, 'repo')}"]
        listing = subprocess.run(git + ["ls-tree", "-r", "HEAD", folder], check=True,
                                 capture_output=True, text=True).stdout.splitlines()
        for line in listing:
            meta, rel = line.split("\t", 1)
            blob = meta.split()[2]
            dest = os.path.join(out, name, rel)
            if not os.path.exists(dest):
                got = subprocess.run(git + ["cat-file", "blob", blob], capture_output=True)
                if got.returncode:
                    absent.append(os.path.join(name, rel))
                    continue
                os.makedirs(os.path.dirname(dest), exist_ok=True)
                with open(dest, "wb") as f:
                    f.write(got.stdout)
            if rel.lower().endswith(EXTS):
                files.append(dest)
    return files, absent


def trimesh_mesh(path: str):
    """trimesh's reading as a Mesh, or the reason it has none (a string)."""
    import trimesh

    from geovox.io.adaptor import LOST_GEOMETRY, from_trimesh

    records = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record.getMessage())

    logger = logging.getLogger("trimesh")
    handler = Keep(logging.DEBUG)
    logger.addHandler(handler)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            loaded = trimesh.load(path, process=False)
            lost = [m for m in records if LOST_GEOMETRY.search(m)]
            if lost:
                return "drops geometry: " + "; ".join(dict.fromkeys(lost))[:100]
            return from_trimesh(loaded, source=path)
    except Exception as exc:  # trimesh raises many types
        return f"{type(exc).__name__}: {str(exc).splitlines()[0][:100] if str(exc) else ''}"
    finally:
        logger.removeHandler(handler)


def compare(path: str, resolution: int) -> dict:
    import geovox
    from geovox.errors import GeovoxError

    row = {"file": path}
    t = time.perf_counter()
    try:
        ours = geovox.load_mesh(path)
    except GeovoxError as exc:
        ours = str(exc)
    row["geovox_s"] = time.perf_counter() - t
    t = time.perf_counter()
    theirs = trimesh_mesh(path)
    row["trimesh_s"] = time.perf_counter() - t
    if isinstance(ours, str) and isinstance(theirs, str):
        return row | {"verdict": "both refuse", "geovox": ours, "trimesh": theirs}
    if isinstance(ours, str):
        return row | {"verdict": "geovox refuses", "geovox": ours}
    if isinstance(theirs, str):
        return row | {"verdict": "trimesh fails", "trimesh": theirs,
                      "triangles": len(ours.faces)}
    row["triangles"] = [len(ours.faces), len(theirs.faces)]
    a, b = np.sort(ours.triangles.reshape(len(ours.faces), -1), axis=0), None
    if len(ours.faces) == len(theirs.faces):
        b = np.sort(theirs.triangles.reshape(len(theirs.faces), -1), axis=0)
        row["same_coordinates"] = bool(np.array_equal(a, b))
    lo, hi = ours.bounds
    span = float((hi - lo).max())
    if span <= 0:
        return row | {"verdict": "same" if row.get("same_coordinates") else "differs",
                      "note": "flat"}
    pad = 1e-3 * span
    bounds = tuple(np.r_[lo - pad, hi + pad])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        va = geovox.voxelize(ours, resolution=resolution, bounds=bounds, backend="numpy")
        vb = geovox.voxelize(theirs, resolution=resolution, bounds=bounds, backend="numpy",
                             inside=va.inside)
    diff = int(np.count_nonzero(va.occupancy != vb.occupancy))
    row.update(inside=[int(va.inside_count), int(vb.inside_count)], voxels_differ=diff,
               parts=[len(ours.parts), len(theirs.parts)])
    row["verdict"] = "same" if diff == 0 else "differs"
    return row


COLOUR_PROBE = """
import sys, warnings, numpy as np, geovox
out = sys.argv[1]
for k, path in enumerate(sys.argv[2:]):
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = geovox.voxelize(path, resolution=int(out.split(":")[1]), color=True,
                                backend="numpy")
        np.savez(f"{out.split(':')[0]}/{k}.npz", occ=v.occupancy, col=v.colors)
    except Exception as exc:
        print(k, type(exc).__name__, str(exc).splitlines()[0][:100] if str(exc) else "")
"""


def colours(files: list, old_root: str, out: str, resolution: int) -> list:
    """Colours (``--color``, exact) of each file here and under the tree ``old_root``.

    Each tree runs in its own process (``PYTHONPATH``); the rows say how many
    inside voxels each has and how many of the shared ones differ in colour,
    by at most how much.
    """
    here = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    rows = []
    for tag, root in (("new", here), ("old", old_root)):
        folder = os.path.join(out, "colours", tag)
        os.makedirs(folder, exist_ok=True)
        env = dict(os.environ, PYTHONPATH=root)
        subprocess.run([sys.executable, "-c", COLOUR_PROBE, f"{folder}:{resolution}", *files],
                       env=env, cwd="/", check=True)
    for k, path in enumerate(files):
        got = {}
        for tag in ("new", "old"):
            f = os.path.join(out, "colours", tag, f"{k}.npz")
            got[tag] = np.load(f) if os.path.exists(f) else None
        row = {"file": path}
        if got["new"] is None or got["old"] is None:
            row["verdict"] = "not both"
        elif got["new"]["occ"].shape != got["old"]["occ"].shape:
            row["verdict"] = "grids differ"
        else:
            both = got["new"]["occ"] & got["old"]["occ"]
            a = got["new"]["col"][both].astype(int)
            b = got["old"]["col"][both].astype(int)
            diff = np.any(a != b, axis=1)
            row.update(inside=int(both.sum()), colours_differ=int(diff.sum()),
                       most=int(np.abs(a - b).max()) if diff.any() else 0,
                       occupancy_differ=int((got["new"]["occ"] != got["old"]["occ"]).sum()))
            row["verdict"] = "same colours" if not diff.any() else "colours differ"
        rows.append(row)
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mirrors", default="/work/.mirror")
    ap.add_argument("--out", default="/tmp/geovox_sweep")
    ap.add_argument("-r", "--resolution", type=int, default=48)
    ap.add_argument("--json")
    ap.add_argument("--colours-against", metavar="TREE",
                    help="also compare --color volumes with geovox as it is in TREE (a "
                         "checkout of main: `git archive main geovox | tar -x -C TREE`)")
    ap.add_argument("--extra", nargs="*", default=[],
                    help="more model files to sweep (the corpus's textured ones)")
    args = ap.parse_args(argv)
    files, absent = extract(args.mirrors, args.out)
    files += args.extra
    lacking = [a for a in absent if a.lower().endswith(EXTS)]
    print(f"{len(absent)} files the mirrors lack ({len(lacking)} models: {', '.join(lacking) or 'none'})")
    rows = []
    for path in files:
        row = compare(path, args.resolution)
        rows.append(row)
        shown = os.path.relpath(path, args.out)
        extra = {k: v for k, v in row.items() if k not in ("file", "verdict", "geovox_s",
                                                           "trimesh_s")}
        print(f"{row['verdict']:>15}  {shown}  {json.dumps(extra)[:300]}", flush=True)
    counts = {}
    for row in rows:
        counts[row["verdict"]] = counts.get(row["verdict"], 0) + 1
    print(f"{len(rows)} files: " + ", ".join(f"{n} {k}" for k, n in sorted(counts.items())))
    if args.colours_against:
        read = [r["file"] for r in rows if r["verdict"] in ("same", "differs", "trimesh fails")]
        crows = colours(read, args.colours_against, args.out, max(16, args.resolution // 2))
        for row in crows:
            extra = {k: v for k, v in row.items() if k not in ("file", "verdict")}
            print(f"{row['verdict']:>15}  {os.path.relpath(row['file'], args.out)}  "
                  f"{json.dumps(extra)}")
        tally = {}
        for row in crows:
            tally[row["verdict"]] = tally.get(row["verdict"], 0) + 1
        print(f"colours: {len(crows)} files: "
              + ", ".join(f"{n} {k}" for k, n in sorted(tally.items())))
        rows += [dict(r, colours=True) for r in crows]
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
