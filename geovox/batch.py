"""Converting many models in one command: folders searched, jobs in parallel,
existing outputs skipped, failures reported without stopping the rest."""

from __future__ import annotations

import os
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from .errors import GeovoxError, InputNotFoundError, OutputError

#: File types searched for in folders. Archives (.zip, .tar.gz) are read when
#: named, but not searched for: a downloaded zip often holds several models or
#: none, and would be voxelised as one scene.
MESH_EXTENSIONS = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf", ".3mf", ".dae", ".zae")


@dataclass
class Result:
    input: str
    output: str | None
    status: str  # "converted", "skipped", "failed"
    message: str = ""
    seconds: float = 0.0


def find_inputs(paths) -> list:
    """Mesh files named directly or found (recursively, sorted) in the folders given.

    Raises
    ------
    InputNotFoundError
        A path does not exist, or a folder holds no file with a mesh extension.
    """
    found = []
    for p in paths:
        if os.path.isdir(p):
            before = len(found)
            for root, dirs, files in os.walk(p):
                dirs.sort()
                for name in sorted(files):
                    if name.lower().endswith(MESH_EXTENSIONS):
                        found.append(os.path.join(root, name))
            if len(found) == before:
                raise InputNotFoundError(f"no meshes found in {p} (looked for "
                                         f"{' '.join(MESH_EXTENSIONS)}, in every subfolder)")
        elif os.path.exists(p):
            found.append(p)
        else:
            raise InputNotFoundError(f"input file not found: {p}")
    return found


def _convert_one(task):
    """Run in a worker process: returns a Result (never raises for bad models)."""
    path, stem, out_dir, options, ext, overwrite, write_options = task
    from .formats import write
    from .formats.headers import default_name
    from .grid import make_grid
    from .mesh import load_mesh
    from .pipeline import voxelize

    t0 = time.perf_counter()
    import warnings

    from .errors import GeovoxWarning
    from .stream import convert_to, streams

    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", GeovoxWarning)
            mesh = load_mesh(path)
            grid = make_grid(mesh.bounds, bounds=options.get("bounds"),
                             resolution=options.get("resolution"), shape=options.get("shape"),
                             voxel_size=options.get("voxel_size"))
            out = os.path.join(out_dir, default_name(stem, grid.shape, "uint8", ext))
            if os.path.exists(out) and not overwrite:
                return Result(path, out, "skipped", "output exists (use --overwrite)",
                              time.perf_counter() - t0)
            from .formats import format_for

            if streams(grid, format_for(out).name, options.get("color"), options.get("density"),
                       options.get("sdf")):
                opts = {k: v for k, v in options.items() if k not in ("resolution", "shape",
                                                                       "voxel_size", "bounds")}
                info = convert_to(mesh, out, shape=grid.shape, bounds=np.r_[grid.lo, grid.hi], **opts)
                inside = info["inside"]
            else:
                vol = voxelize(mesh, **options)
                write(vol, out, **write_options)
                inside = vol.inside_count
        said = [str(w.message) for w in caught if issubclass(w.category, GeovoxWarning)]
        note = f"{inside:,} inside" + (f"; warning: {'; '.join(said)}" if said else "")
        return Result(path, out, "converted", note, time.perf_counter() - t0)
    except (GeovoxError, MemoryError) as exc:
        return Result(path, None, "failed", str(exc), time.perf_counter() - t0)
    except Exception as exc:  # a model must not stop the batch; say what happened
        return Result(path, None, "failed", f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)


def convert_many(paths, out_dir, options: dict, ext: str = ".raw", overwrite: bool = False,
                 jobs: int = 1, progress=None, write_options=None) -> list:
    """Convert every model into ``out_dir``; returns one Result per model, in input order.

    Models run in ``jobs`` processes, each single-threaded, so the outputs are
    the same whatever ``jobs`` is.
    """
    inputs = find_inputs(paths)
    try:
        os.makedirs(out_dir, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"cannot create output folder {out_dir}: {exc.strerror or exc}") from None
    options = dict(options, jobs=1)
    # Models with the same file name get _2, _3, ... in input order.
    stems, seen = [], {}
    for p in inputs:
        stem = os.path.splitext(os.path.basename(p))[0]
        seen[stem] = seen.get(stem, 0) + 1
        stems.append(stem if seen[stem] == 1 else f"{stem}_{seen[stem]}")
    tasks = [(p, s, out_dir, options, ext, overwrite, write_options or {})
             for p, s in zip(inputs, stems)]
    results = []
    if jobs > 1 and len(tasks) > 1:
        with ProcessPoolExecutor(max_workers=jobs) as pool:
            for r in pool.map(_convert_one, tasks):
                results.append(r)
                if progress:
                    progress(r)
    else:
        for t in tasks:
            r = _convert_one(t)
            results.append(r)
            if progress:
                progress(r)
    return results


def summary_table(results) -> str:
    width = max([len(os.path.basename(r.input)) for r in results] + [5])
    lines = [f"{'model':<{width}}  {'status':<9}  {'time':>7}  details"]
    for r in results:
        detail = r.message if r.status != "converted" else f"{r.output} ({r.message})"
        lines.append(f"{os.path.basename(r.input):<{width}}  {r.status:<9}  {r.seconds:6.2f}s  {detail}")
    n = {s: sum(r.status == s for r in results) for s in ("converted", "skipped", "failed")}
    lines.append(f"{n['converted']} converted, {n['skipped']} skipped, {n['failed']} failed")
    return "\n".join(lines)
