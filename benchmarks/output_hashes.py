"""SHA-256 of every output of the CLI conversions the tests and benchmarks use.

A refactoring check, not a benchmark: run it on one tree, change the code,
run it again and compare. Every case is ``geovox convert ...`` in a fresh
process (``python -m geovox`` from the tree given with ``--root``), on copies
of the bundled and test models in a fixed scratch folder, so that the paths
written into the files (a volume's ``source``) are the same for every tree.

What is hashed, per file:

* HDF5 (``.h5``, ``.hdf5``, ``.vtkhdf``, ``.hdf``): every dataset (dtype,
  shape, bytes) and every attribute, in name order. The container's bytes
  hold object timestamps (HDF5 tracks them by default), so they differ from
  one run to the next.
* ``.zarr``: every array (dtype, shape, decoded values) and every group's and
  array's attributes, through zarr; plus, separately (``bytes:`` entries),
  the bytes of every file of the folder, which are deterministic too and
  also catch a change of codec or chunking.
* ``.npz``: every member array by name (a zip stores member timestamps).
* ``.nrrd``: the header and the gunzipped data (gzip may store a time).
* ``.vdb``: its bytes but the 36-byte UUID that every write draws afresh
  (bytes 21-56, after the magic number and the versions).
* manifests (``.jsonl``): the records without ``time`` and ``seconds``, by
  input (models finish in any order).
* ``.gz`` (``.nii.gz``): the gunzipped bytes (gzip stores a time).
* anything else: its bytes.

Usage::

    python benchmarks/output_hashes.py --root ../old-checkout --out before.json
    python benchmarks/output_hashes.py --root . --compare before.json
    python benchmarks/output_hashes.py --only occ_raw,zarr_colour   # a few cases

Cases whose command fails are recorded with their exit status and stderr's
last line, and count as a difference when compared.
"""

from __future__ import annotations

import argparse
import fcntl
import gzip
import hashlib
import json
import os
import shutil
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)

#: A slab budget small enough that the 192³ cases below run in several slabs.
SMALL_BUDGET = 1 << 22

#: Where models and outputs live while the cases run (the same for every tree).
SCRATCH = "/tmp/geovox-output-hashes"

MODELS = {
    "spot.obj": "data/spot/spot.obj",
    "spot.mtl": "data/spot/spot.mtl",
    "spot_texture.png": "data/spot/spot_texture.png",
    "cornell_box.obj": "tests/data/cornell_box/cornell_box.obj",
    "cornell_box.mtl": "tests/data/cornell_box/cornell_box.mtl",
    "fuze.obj": "tests/data/fuze/fuze.obj",
    "fuze.obj.mtl": "tests/data/fuze/fuze.obj.mtl",
    "fuze uv.jpg": "tests/data/fuze/fuze uv.jpg",
    "bunny_oded.obj": "tests/data/bunny_watertight/bunny_oded.obj",
    "suzanne.obj": "tests/data/suzanne/suzanne.obj",
    "suzanne.mtl": "tests/data/suzanne/suzanne.mtl",
    "wallhole.obj": "tests/data/trimesh_edge_cases/wallhole.obj",
    "rabbit.obj": "tests/data/trimesh_edge_cases/rabbit.obj",
    "rabbit.mtl": "tests/data/trimesh_edge_cases/rabbit.mtl",
    "pyramids.3mf": "tests/data/wild/pyramids.3mf",
}

#: name -> (argv after ``geovox``, environment additions, force a small slab budget)
CASES = {
    # in memory, one format each
    "occ_raw": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "64"], {}, False),
    "occ_raw_embree": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "64",
                        "--backend", "embree"], {}, False),
    "occ_h5": (["convert", "M/bunny_oded.obj", "-o", "O/bunny.h5", "-r", "80"], {}, False),
    "occ_npy_shape": (["convert", "M/spot.obj", "-o", "O/spot.npy", "--shape", "40", "50", "30"],
                      {}, False),
    "occ_npz_bits": (["convert", "M/spot.obj", "-o", "O/spot.npz", "-r", "40", "--pack-bits"],
                     {}, False),
    "occ_binvox": (["convert", "M/bunny_oded.obj", "-o", "O/bunny.binvox", "--voxel-size", "0.02"],
                   {}, False),
    "occ_nrrd_bounds": (["convert", "M/spot.obj", "-o", "O/spot.nrrd", "-r", "48", "--bounds",
                         "-0.3", "-0.5", "-0.5", "0.4", "0.8", "0.6"], {}, False),
    "occ_voxel_size_vdb": (["convert", "M/bunny_oded.obj", "-o", "O/bunny.vdb",
                            "--voxel-size", "0.01"], {}, False),
    "occ_default_name": (["convert", "M/spot.obj", "-o", "O/", "-r", "32", "--format", "raw"],
                         {}, False),
    "inside_vote": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "64", "--inside", "vote"],
                    {}, False),
    "inside_winding_open": (["convert", "M/wallhole.obj", "-o", "O/wallhole.raw", "-r", "48"],
                            {}, False),
    "inside_winding_3mf": (["convert", "M/pyramids.3mf", "-o", "O/pyr.h5", "-r", "48"], {}, False),
    "colour_exact_h5": (["convert", "M/spot.obj", "-o", "O/spot.h5", "-r", "96", "--color"],
                        {}, False),
    "colour_exact_numpy_kernel": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "48",
                                   "--color"], {"GEOVOX_KERNEL": "numpy"}, False),
    "colour_fast_raw": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "96",
                         "--fast-color"], {}, False),
    "colour_ambient_nodiffuse": (["convert", "M/cornell_box.obj", "-o", "O/cb.h5", "-r", "48",
                                  "--color", "--ambient", "--no-diffuse"], {}, False),
    "colour_fuze_vtkhdf": (["convert", "M/fuze.obj", "-o", "O/fuze.vtkhdf", "-r", "64",
                            "--fast-color"], {}, False),
    "colour_rabbit_npz": (["convert", "M/rabbit.obj", "-o", "O/rabbit.npz", "-r", "48",
                           "--color"], {}, False),
    "density_vtkhdf": (["convert", "M/spot.obj", "-o", "O/spot.vtkhdf", "-r", "64",
                        "--density", "coverage"], {}, False),
    "density_float_npz": (["convert", "M/bunny_oded.obj", "-o", "O/bunny.npz", "-r", "48",
                           "--density", "coverage", "--density-float", "--supersample", "3"],
                          {}, False),
    "density_winding": (["convert", "M/wallhole.obj", "-o", "O/wallhole.h5", "-r", "40",
                         "--density", "coverage"], {}, False),
    "sdf_nrrd": (["convert", "M/spot.obj", "-o", "O/spot.nrrd", "-r", "64", "--sdf"], {}, False),
    "sdf_vdb": (["convert", "M/bunny_oded.obj", "-o", "O/bunny.vdb", "-r", "48", "--sdf",
                 "--band", "2", "--density", "coverage"], {}, False),
    "vox_colour": (["convert", "M/spot.obj", "-o", "O/spot.vox", "-r", "64", "--color"], {}, False),
    "vox_shell": (["convert", "M/suzanne.obj", "-o", "O/suz.vox", "-r", "64", "--shell"], {},
                  False),
    "preview": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "48", "--color",
                 "--preview", "O/spot.png"], {}, False),
    "preview_command": (["preview", "M/spot.obj", "-o", "O/p.png", "-r", "48"], {}, False),
    # .zarr (always slab by slab)
    "zarr_occ": (["convert", "M/spot.obj", "-o", "O/spot.zarr", "-r", "96"], {}, False),
    "zarr_colour": (["convert", "M/spot.obj", "-o", "O/spot.zarr", "-r", "96", "--fast-color"],
                    {}, False),
    "zarr_exact_density_sdf": (["convert", "M/bunny_oded.obj", "-o", "O/bunny.zarr", "-r", "80",
                                "--color", "--density", "coverage", "--sdf"], {}, False),
    "zarr_slabs": (["convert", "M/spot.obj", "-o", "O/spot.zarr", "-r", "192", "--fast-color"],
                   {}, True),
    # streamed: the 64-slice occupancy fill (512³ occupancy), and several slabs
    "stream_occ_fill_raw": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "512"], {},
                            False),
    "stream_occ_slabs_h5": (["convert", "M/spot.obj", "-o", "O/spot.h5", "-r", "192"], {}, True),
    "stream_exact_raw": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "192", "--color"],
                         {}, True),
    "stream_fast_raw": (["convert", "M/spot.obj", "-o", "O/spot.raw", "-r", "192",
                         "--fast-color"], {}, True),
    "stream_fast_h5": (["convert", "M/spot.obj", "-o", "O/spot.h5", "-r", "192", "--fast-color"],
                       {}, True),
    "stream_vote_fast_h5": (["convert", "M/spot.obj", "-o", "O/spot.h5", "-r", "160",
                             "--fast-color", "--inside", "vote"], {}, True),
    "stream_density_sdf_vtkhdf": (["convert", "M/bunny_oded.obj", "-o", "O/bunny.vtkhdf", "-r",
                                   "160", "--density", "coverage", "--sdf"], {}, True),
    "stream_winding_raw": (["convert", "M/wallhole.obj", "-o", "O/wallhole.raw", "-r", "160"], {},
                           True),
    # many models
    "batch": (["convert", "M/spot.obj", "M/bunny_oded.obj", "M/wallhole.obj", "-o", "O/batch",
               "-r", "48", "--manifest", "O/manifest.jsonl", "-q"], {}, False),
    "batch_colour_h5_jobs": (["convert", "M/spot.obj", "M/fuze.obj", "-o", "O/batch", "-r", "48",
                              "--color", "--format", "hdf5", "-j", "2", "-q"], {}, False),
    "batch_streamed": (["convert", "M/spot.obj", "M/bunny_oded.obj", "-o", "O/batch", "-r", "160",
                        "--format", "hdf5", "-q"], {}, True),
    "batch_url": (["convert", "M/spot.obj", "M/bunny_oded.obj", "-o", "file://O/remote/", "-r",
                   "32", "-q"], {}, False),
    "cluster_batch": (["convert", "M/spot.obj", "M/bunny_oded.obj", "-o", "O/batch", "-r", "48",
                       "--local-cluster", "2", "-q"], {}, False),
    "cluster_zarr": (["convert", "M/spot.obj", "-o", "O/spot.zarr", "-r", "192", "--fast-color",
                      "--local-cluster", "2"], {}, False),
    # labels: by part, material, component and file, fractions, streamed, with colour
    "labels_part_segnrrd": (["convert", "M/cornell_box.obj", "-o", "O/cb.seg.nrrd", "-r", "48",
                             "--labels", "part"], {}, False),
    "labels_material_h5": (["convert", "M/cornell_box.obj", "-o", "O/cb.h5", "-r", "48",
                            "--labels", "material"], {}, False),
    "labels_component_npz": (["convert", "M/pyramids.3mf", "-o", "O/pyr.npz", "-r", "40",
                              "--labels", "component"], {}, False),
    "labels_file_nifti": (["convert", "M/spot.obj", "M/bunny_oded.obj", "-o", "O/two.nii.gz",
                           "-r", "48", "--labels", "file"], {}, False),
    "labels_fractions_vtkhdf": (["convert", "M/cornell_box.obj", "-o", "O/cb.vtkhdf", "-r", "40",
                                 "--labels", "part", "--fractions", "--overlap", "smallest"],
                                {}, False),
    "labels_stream_h5": (["convert", "M/cornell_box.obj", "-o", "O/cb.h5", "-r", "160",
                          "--labels", "part", "--color"], {}, True),
    "labels_colour_zarr": (["convert", "M/cornell_box.obj", "-o", "O/cb.zarr", "-r", "64",
                            "--labels", "material", "--color"], {}, False),
    "labels_density_raw": (["convert", "M/cornell_box.obj", "-o", "O/cb.raw", "-r", "48",
                            "--labels", "part", "--density", "coverage"], {}, False),
    # onto an oblique, anisotropic reference grid (written by reference_image below)
    "like_nrrd_colour": (["convert", "M/spot.obj", "--like", "M/ref.mhd", "-o", "O/spot.nrrd",
                          "--color"], {}, False),
    "like_nifti_sdf": (["convert", "M/spot.obj", "--like", "M/ref.mhd", "-o", "O/spot.nii.gz",
                        "--sdf", "--density", "coverage"], {}, False),
    "like_stream_raw": (["convert", "M/bunny_oded.obj", "--like", "M/ref_big.mhd", "-o",
                         "O/bunny.raw", "--fast-color"], {}, True),
    # surface voxels (issue 35): alone and with the solid, dense and sparse, streamed
    "surface_raw": (["convert", "M/bunny_oded.obj", "-o", "O/b.raw", "-r", "96",
                     "--occupancy", "surface"], {}, False),
    "surface_cube_raw_j1": (["convert", "M/bunny_oded.obj", "-o", "O/b.raw", "-r", "96", "--cube",
                             "-j", "1", "--occupancy", "surface"], {}, False),
    "surface_ply": (["convert", "M/bunny_oded.obj", "-o", "O/b.ply", "-r", "128",
                     "--occupancy", "surface"], {}, False),
    "surface_h5_stream": (["convert", "M/bunny_oded.obj", "-o", "O/b.h5", "-r", "192",
                           "--occupancy", "surface"], {}, True),
    "surface_ply_stream": (["convert", "M/bunny_oded.obj", "-o", "O/b.ply", "-r", "192",
                            "--occupancy", "surface"], {}, True),
    "surface_npz_sparse_colour": (["convert", "M/spot.obj", "-o", "O/s.npz", "-r", "96",
                                   "--occupancy", "surface", "--sparse", "--color"], {}, False),
    "surface_ply_colour_stream": (["convert", "M/spot.obj", "-o", "O/s.ply", "-r", "192",
                                   "--occupancy", "surface", "--color"], {}, True),
    "both_raw_colour": (["convert", "M/spot.obj", "-o", "O/s.raw", "-r", "96",
                         "--occupancy", "both", "--fast-color"], {}, False),
    "both_ply_stream": (["convert", "M/spot.obj", "-o", "O/s.ply", "-r", "192",
                         "--occupancy", "both"], {}, True),
    "surface_labels_ply": (["convert", "M/cornell_box.obj", "-o", "O/c.ply", "-r", "64",
                            "--occupancy", "surface", "--labels", "part"], {}, False),
    "both_labels_material_colour": (["convert", "M/cornell_box.obj", "-o", "O/c.h5", "-r", "64",
                                     "--occupancy", "both", "--labels", "material", "--color"],
                                    {}, False),
    "surface_numpy_kernel": (["convert", "M/wallhole.obj", "-o", "O/w.ply", "-r", "48",
                              "--occupancy", "surface"], {"GEOVOX_KERNEL": "numpy"}, False),
    "surface_like_ply": (["convert", "M/spot.obj", "--like", "M/ref.mhd", "-o", "O/s.ply",
                          "--occupancy", "surface"], {}, False),
    "surface_sdf_ply": (["convert", "M/spot.obj", "-o", "O/s.ply", "-r", "64",
                         "--occupancy", "surface", "--sdf"], {}, False),
    "surface_zarr": (["convert", "M/bunny_oded.obj", "-o", "O/b.zarr", "-r", "128",
                      "--occupancy", "surface"], {}, False),
    "surface_info": (["info", "M/bunny_oded.obj", "-r", "128", "--occupancy", "surface"], {},
                     False),
    # what geovox info says (its plan and route)
    "info": (["info", "M/cornell_box.obj", "-r", "96"], {}, False),
    "info_like": (["info", "M/spot.obj", "--like", "M/ref.mhd"], {}, False),
}


def reference_image(folder, name="ref", shape=(40, 36, 24), scale=1.0) -> None:
    """An oblique, anisotropic MetaImage reference (``ref.mhd`` + ``ref.raw``) around spot.

    Written by hand, with no library, so that it is the same bytes for every tree.
    """
    import numpy as np

    spacing = np.array([0.03, 0.035, 0.06]) * scale
    c, s = np.cos(0.4), np.sin(0.4)
    rx = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    c, s = np.cos(0.7), np.sin(0.7)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    direction = rx @ rz
    offset = -(direction * spacing) @ ((np.asarray(shape) - 1) / 2) + [0.0, 0.1, 0.2]
    tm = " ".join(repr(float(v)) for v in direction.T.reshape(-1))
    with open(os.path.join(folder, name + ".mhd"), "w") as f:
        f.write("ObjectType = Image\nNDims = 3\nBinaryData = True\n"
                "BinaryDataByteOrderMSB = False\n"
                f"TransformMatrix = {tm}\nOffset = {' '.join(repr(float(v)) for v in offset)}\n"
                "AnatomicalOrientation = RAI\n"
                f"ElementSpacing = {' '.join(repr(float(v)) for v in spacing)}\n"
                f"DimSize = {' '.join(map(str, shape))}\nElementType = MET_UCHAR\n"
                f"ElementDataFile = {name}.raw\n")
    np.zeros(int(np.prod(shape)), np.uint8).tofile(os.path.join(folder, name + ".raw"))


_BUDGET_CODE = (
    "import sys\n"
    "try:\n    import geovox.planner as s\nexcept ImportError:  # a tree before geovox.planner\n"
    "    import geovox.stream as s\n"
    "s.SLAB_BUDGET = {budget}\n"
    "from geovox.cli import main\n"
    "sys.exit(main(sys.argv[1:]))\n"
)


def _sha(*parts) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(p if isinstance(p, bytes) else str(p).encode())
    return h.hexdigest()


def _attrs(attrs) -> list:
    out = []
    for k in sorted(attrs):
        v = attrs[k]
        v = v.tolist() if hasattr(v, "tolist") else v
        v = v.decode() if isinstance(v, bytes) else v
        out.append((k, repr(v)))
    return out


def hash_hdf5(path) -> dict:
    import h5py

    out = {}
    with h5py.File(path, "r") as f:
        out["/ attrs"] = _sha(repr(_attrs(f.attrs)))

        def visit(name, obj):
            if isinstance(obj, h5py.Dataset):
                a = obj[()]
                import numpy as np

                a = np.asarray(a)
                data = a.tobytes() if a.dtype.kind != "O" else repr(a.tolist()).encode()
                out[name] = _sha(a.dtype.str, a.shape, data, repr(_attrs(obj.attrs)))
            else:
                out[name + " attrs"] = _sha(repr(_attrs(obj.attrs)))

        f.visititems(visit)
    return out


def hash_zarr(path) -> dict:
    import numpy as np
    import zarr

    out = {}
    root = zarr.open_group(path, mode="r")

    def walk(g, prefix):
        out[(prefix or "/") + " attrs"] = _sha(json.dumps(dict(g.attrs), sort_keys=True))
        for name, a in sorted(g.arrays()):
            v = np.asarray(a[...])
            out[prefix + "/" + name] = _sha(v.dtype.str, v.shape, v.tobytes(),
                                            json.dumps(dict(a.attrs), sort_keys=True))
        for name, sub in sorted(g.groups()):
            walk(sub, prefix + "/" + name)

    walk(root, "")
    for here, dirs, files in os.walk(path):
        dirs.sort()
        for n in sorted(files):
            p = os.path.join(here, n)
            with open(p, "rb") as f:
                out["bytes:" + os.path.relpath(p, path)] = _sha(f.read())
    return out


def hash_npz(path) -> dict:
    import numpy as np

    with np.load(path, allow_pickle=False) as z:
        return {k: _sha(z[k].dtype.str, z[k].shape, z[k].tobytes()) for k in sorted(z.files)}


def hash_nrrd(path) -> dict:
    with open(path, "rb") as f:
        data = f.read()
    head, _, body = data.partition(b"\n\n")
    if b"encoding: gzip" in head:
        body = gzip.decompress(body)
    return {"header": _sha(head), "data": _sha(body)}


def hash_manifest(path) -> dict:
    """Each record by its input (models finish in any order on a process pool)."""
    out = {}
    with open(path, encoding="utf-8") as f:
        for line in f:
            if line.strip():
                rec = json.loads(line)
                rec.pop("time", None)
                rec.pop("seconds", None)
                out[os.path.basename(rec["input"])] = _sha(json.dumps(rec, sort_keys=True))
    return out


def hash_file(path) -> dict:
    lower = path.lower()
    if lower.endswith((".h5", ".hdf5", ".vtkhdf", ".hdf")):
        return hash_hdf5(path)
    if lower.endswith(".ply"):
        # A PLY's header names the source path; the rest is its bytes.
        with open(path, "rb") as f:
            data = f.read()
        head, sep, body = data.partition(b"end_header\n")
        return {"header": _sha(head), "data": _sha(body)}
    if lower.endswith(".npz"):
        return hash_npz(path)
    if lower.endswith(".nrrd"):
        return hash_nrrd(path)
    if lower.endswith(".gz"):
        # gzip stores a time in its header: the inflated bytes.
        with gzip.open(path, "rb") as f:
            return {"gunzipped": _sha(f.read())}
    if lower.endswith(".jsonl"):
        return hash_manifest(path)
    if lower.endswith(".vdb"):
        with open(path, "rb") as f:
            data = f.read()
        return {"bytes less the uuid": _sha(data[:21], data[57:])}
    with open(path, "rb") as f:
        return {"bytes": _sha(f.read())}


def outputs(folder) -> dict:
    """Every output under ``folder``: relative name -> {part: sha256}."""
    out = {}
    for here, dirs, files in os.walk(folder):
        dirs.sort()
        zarrs = [d for d in dirs if d.lower().endswith(".zarr")]
        for d in zarrs:
            p = os.path.join(here, d)
            out[os.path.relpath(p, folder)] = hash_zarr(p)
        dirs[:] = [d for d in dirs if d not in zarrs]
        for n in sorted(files):
            p = os.path.join(here, n)
            out[os.path.relpath(p, folder)] = hash_file(p)
    return out


def run_case(name, root, python) -> dict:
    argv, env_add, small = CASES[name]
    models, out = os.path.join(SCRATCH, "models"), os.path.join(SCRATCH, "out")
    shutil.rmtree(out, ignore_errors=True)
    os.makedirs(out)
    args = [a.replace("M/", models + "/").replace("O/", out + "/") for a in argv]
    env = dict(os.environ, **env_add)
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    env["PYTHONPATH"] = root
    if small:
        cmd = [python, "-c", _BUDGET_CODE.format(budget=SMALL_BUDGET)] + args
    else:
        cmd = [python, "-m", "geovox"] + args
    t = time.perf_counter()
    p = subprocess.run(cmd, cwd=root, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    rec = {"rc": p.returncode, "seconds": round(wall, 2), "files": outputs(out)}
    if p.returncode:
        rec["stderr"] = (p.stderr.strip().splitlines() or [""])[-1]
    # What the user reads, less the wall times.
    rec["stdout"] = [line for line in p.stdout.splitlines() if not line.startswith("time ")]
    rec["warnings"] = sorted(line for line in p.stderr.splitlines()
                             if line.startswith("geovox: warning"))
    return rec


def compare(before: dict, after: dict) -> list:
    """Lines naming every case, file or part that differs."""
    diff = []
    for case in sorted(set(before) | set(after)):
        b, a = before.get(case), after.get(case)
        if b is None or a is None:
            diff.append(f"{case}: only {'after' if b is None else 'before'}")
            continue
        if b["rc"] != a["rc"]:
            diff.append(f"{case}: exit status {b['rc']} -> {a['rc']} {a.get('stderr', '')}")
        if b.get("stdout") != a.get("stdout"):
            diff.append(f"{case}: stdout {b.get('stdout')} -> {a.get('stdout')}")
        if b.get("warnings") != a.get("warnings"):
            diff.append(f"{case}: warnings {b.get('warnings')} -> {a.get('warnings')}")
        for f in sorted(set(b["files"]) | set(a["files"])):
            fb, fa = b["files"].get(f), a["files"].get(f)
            if fb != fa:
                parts = sorted(k for k in set(fb or {}) | set(fa or {})
                               if (fb or {}).get(k) != (fa or {}).get(k))
                diff.append(f"{case}: {f} differs ({', '.join(parts[:6])})")
    return diff


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--root", default=ROOT, help="tree whose geovox runs (default: this one)")
    ap.add_argument("--python", default=sys.executable)
    ap.add_argument("--only", help="comma-separated case names")
    ap.add_argument("--out", help="write the hashes to this JSON file")
    ap.add_argument("--compare", help="JSON file of earlier hashes to compare with")
    args = ap.parse_args(argv)
    # Outputs (sidecars, manifests) name the scratch folder, so it cannot differ between runs:
    # two runs at once wait for each other instead of sharing it.
    os.makedirs(SCRATCH, exist_ok=True)
    lock = open(SCRATCH + ".lock", "w")
    fcntl.flock(lock, fcntl.LOCK_EX)
    root = os.path.abspath(args.root)
    names = args.only.split(",") if args.only else list(CASES)
    models = os.path.join(SCRATCH, "models")
    os.makedirs(models, exist_ok=True)
    for name, rel in MODELS.items():
        shutil.copyfile(os.path.join(ROOT, rel), os.path.join(models, name))
    reference_image(models)
    reference_image(models, "ref_big", (200, 180, 120), 0.2)
    result = {}
    for name in names:
        result[name] = run_case(name, root, args.python)
        r = result[name]
        print(f"{name:28s} rc {r['rc']} {r['seconds']:6.1f} s {len(r['files'])} files"
              + (f"  {r['stderr']}" if r["rc"] else ""), flush=True)
    if args.out:
        with open(args.out, "w") as f:
            json.dump(result, f, indent=1, sort_keys=True)
    if args.compare:
        with open(args.compare) as f:
            before = json.load(f)
        before = {k: v for k, v in before.items() if k in result}
        new = sorted(set(result) - set(before))  # cases the earlier tree's file did not have
        diff = compare(before, {k: v for k, v in result.items() if k in before})
        print("\n".join(diff) if diff else f"all {len(before)} cases match"
              + (f" ({len(new)} new, not in {os.path.basename(args.compare)})" if new else ""))
        return 1 if diff else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
