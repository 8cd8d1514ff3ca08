"""A batch's local process pool: workers ready before their first model.

Each worker runs :func:`warm` before it takes a model: the conversion stack,
the compiled kernels, the backend, the loaders of the batch's file types and
the writer of its format are imported there, so a model's ``seconds`` in the
manifest is its own work and not the worker's start-up (which reached 12 s
under load for the first model of each worker).
"""

from __future__ import annotations

import os
import time

#: In a worker: ``time.perf_counter()`` when :func:`warm` had imported
#: everything (None before, and in the parent); a test's hook.
WARMED = None


# --- in a worker -------------------------------------------------------------

#: geovox modules every conversion may import on its way (loaders, inside
#: tests, slab streaming, the manifest's version check).
STACK = ("geovox.pipeline", "geovox.io.load", "geovox.io.obj", "geovox.io.references",
         "geovox.mesh", "geovox.inside", "geovox.inside.winding", "geovox.inside.repair",
         "geovox.inside.bridge", "geovox.exact", "geovox.parity", "geovox.stream",
         "geovox.formats.headers", "geovox.cluster", "geovox.batch")

#: Compiled kernels (each optional: the NumPy twins run where one is missing).
KERNELS = ("geovox._lattice", "geovox._winding", "geovox._objtext", "geovox._nearest",
           "geovox._forward")

#: Loaders by input extension; every file type but OBJ is read through trimesh.
LOADERS = {".ply": "geovox.io.ply", ".gltf": "geovox.io.gltf", ".glb": "geovox.io.gltf",
           ".3mf": "geovox.io.threemf", ".dae": "geovox.io.dae", ".zae": "geovox.io.dae"}


def warm(ext: str, extensions: tuple, options) -> None:
    """The pool's initializer: import what the batch's models will use, then set :data:`WARMED`.

    Parameters
    ----------
    ext : str
        The output extension (``".binvox"``): its writer and the packages it uses.
    extensions : tuple of str
        The lower-case extensions of the batch's inputs: their loaders (and
        trimesh for all but ``.obj``).
    options : Options
        The batch's options: the backend they name, colour's modules.
    """
    global WARMED
    import importlib

    wanted = list(STACK) + list(KERNELS)
    if options.color:
        wanted += ["geovox.colour.shading", "geovox.colour.nearest"]
    if options.labels is not None:
        wanted.append("geovox.labels")
    for e in extensions:
        wanted += [LOADERS[e]] if e in LOADERS else []
        wanted += ["trimesh"] if e != ".obj" else []
    for name in dict.fromkeys(wanted):
        try:
            importlib.import_module(name)
        except Exception:  # optional, or broken: the model says so where it matters
            pass
    from . import formats
    from .backends import get_backend

    try:
        formats.format_for("x" + ext).load()
        get_backend(options.backend)  # embree's first use imports trimesh and embreex
    except Exception:  # never the pool's failure: each model reports its own
        pass
    WARMED = time.perf_counter()


# --- in the parent -----------------------------------------------------------

def run(tasks, workers: int, on_result) -> None:
    """Convert ``tasks`` on ``workers`` processes; ``on_result(i, Result)`` as each arrives.

    Parameters
    ----------
    tasks : list of dict
        :func:`geovox.batch._convert_one`'s tasks, one output extension.
    workers : int
        Processes (at most one per task).
    on_result : callable
        Called in this process with the task's index and its Result.
    """
    from concurrent.futures import ProcessPoolExecutor, as_completed

    from .batch import _convert_one

    extensions = tuple(sorted({os.path.splitext(t["input"])[1].lower() for t in tasks}))

    with ProcessPoolExecutor(max_workers=min(workers, len(tasks)), initializer=warm,
                             initargs=(tasks[0]["ext"], extensions, tasks[0]["options"])) as pool:
        futures = {pool.submit(_convert_one, t): i for i, t in enumerate(tasks)}
        for f in as_completed(futures):
            on_result(futures[f], f.result())
