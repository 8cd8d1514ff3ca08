"""A batch's local process pool: workers ready before their first model, and
stopped with the batch.

Each worker runs :func:`warm` before it takes a model: the conversion stack,
the compiled kernels, the backend, the loaders of the batch's file types and
the writer of its format are imported there, so a model's ``seconds`` in the
manifest is its own work and not the worker's start-up (which reached 12 s
under load for the first model of each worker).

SIGTERM or SIGINT to the batch stops it: the models running are abandoned
(their workers unwind them, so every temporary file of an atomic write is
removed, and exit), the models not started are not, the workers are gone
when :func:`run` returns, and a :class:`Stopped` says how far the batch got.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
import time

#: Seconds a worker has to unwind its model after SIGTERM before it is
#: killed (a long compiled call must return before Python code runs).
GRACE = 10.0

#: In a worker: ``time.perf_counter()`` when :func:`warm` had imported
#: everything (None before, and in the parent); a test's hook.
WARMED = None

#: In a worker: whether a model is being converted (SIGTERM then unwinds it).
_RUNNING = False


class Stopped(KeyboardInterrupt):
    """A signal stopped the work; the command line exits with ``128 + signum``.

    A KeyboardInterrupt, so that everything that already cleans up after
    Ctrl-C (atomic writes, the Dask client) does so for SIGTERM too.

    Attributes
    ----------
    signum : int
        The signal (``signal.SIGTERM``, ``signal.SIGINT``).
    message : str
        One line for the user (empty: the command line says its own).
    """

    def __init__(self, signum: int, message: str = ""):
        super().__init__(message)
        self.signum = int(signum)
        self.message = message


def signal_name(signum: int) -> str:
    """``"SIGTERM"`` for ``signal.SIGTERM``, and so on."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def _raise_stopped(signum, frame):
    raise Stopped(signum)


@contextlib.contextmanager
def sigterm_raises():
    """Within the block, SIGTERM raises :class:`Stopped` in the main thread.

    Only where SIGTERM has its default action (which would end the process
    at once, leaving the pool's workers running and temporary files behind)
    and in the main thread (the only one that may set handlers); a handler
    of the caller's is left alone, and the old one comes back afterwards.
    """
    if (threading.current_thread() is not threading.main_thread()
            or signal.getsignal(signal.SIGTERM) is not signal.SIG_DFL):
        yield
        return
    old = signal.signal(signal.SIGTERM, _raise_stopped)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


# --- in a worker -------------------------------------------------------------

#: geovox modules every conversion may import on its way (loaders, inside
#: tests, slab streaming, the manifest's version check).
STACK = ("geovox.pipeline", "geovox.io.load", "geovox.io.obj", "geovox.io.references",
         "geovox.mesh", "geovox.inside", "geovox.inside.winding", "geovox.inside.repair",
         "geovox.inside.bridge", "geovox.exact", "geovox.parity", "geovox.stream",
         "geovox.formats.headers", "geovox.cluster", "geovox.batch")

#: Compiled kernels (each optional: the NumPy twins run where one is missing).
KERNELS = ("geovox._lattice", "geovox._winding", "geovox._objtext", "geovox._nearest")

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

    SIGINT is ignored here: Ctrl-C reaches the whole process group, and the
    parent stops the workers itself (with SIGTERM, which unwinds a model).
    """
    global WARMED
    import importlib

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_stop)
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


def _worker_stop(signum, frame):
    """A worker's SIGTERM: unwind the model being converted (its atomic writes
    remove their temporary files; see :func:`convert`), or exit at once when idle."""
    if _RUNNING:
        raise Stopped(signum)
    os._exit(128 + signum)


def convert(task):
    """A pool worker's unit of work: :func:`geovox.batch._convert_one` (a model), stoppable.

    A :class:`Stopped` that unwound the model ends the worker; the parent is
    stopping the pool and waits for no result.
    """
    global _RUNNING
    from .batch import _convert_one

    try:
        _RUNNING = True
        return _convert_one(task)
    except Stopped as exc:
        os._exit(128 + exc.signum)
    finally:
        _RUNNING = False


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

    Raises
    ------
    Stopped
        SIGTERM (where it had its default action) stopped the batch; a
        KeyboardInterrupt (SIGINT) passes through. Either way the workers
        have ended and no partial file is left.
    """
    from concurrent.futures import ProcessPoolExecutor, as_completed

    extensions = tuple(sorted({os.path.splitext(t["input"])[1].lower() for t in tasks}))

    pool = ProcessPoolExecutor(max_workers=min(workers, len(tasks)), initializer=warm,
                               initargs=(tasks[0]["ext"], extensions, tasks[0]["options"]))
    with sigterm_raises():
        try:
            futures = {pool.submit(convert, t): i for i, t in enumerate(tasks)}
            for f in as_completed(futures):
                on_result(futures[f], f.result())
        except BaseException:
            _stop(pool)
            raise
    pool.shutdown()


def _stop(pool) -> None:
    """End every worker: SIGTERM (each unwinds its model), SIGKILL after :data:`GRACE` s."""
    # A second Ctrl-C or SIGTERM must not cut the clean-up short.
    with _ignoring(signal.SIGINT, signal.SIGTERM):
        _end(pool)


@contextlib.contextmanager
def _ignoring(*signums):
    """The signals ignored within the block (in the main thread; elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = {s: signal.signal(s, signal.SIG_IGN) for s in signums}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


def _end(pool) -> None:
    # The executor keeps its processes in a private dict; nothing public lists them.
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        with contextlib.suppress(OSError, ValueError):
            p.terminate()
    deadline = time.monotonic() + GRACE
    for p in processes:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            p.join(max(0.0, deadline - time.monotonic()))
    for p in processes:
        with contextlib.suppress(OSError, ValueError, AssertionError):
            if p.is_alive():
                p.kill()
                p.join(5.0)
