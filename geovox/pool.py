"""A local process pool: workers ready before their first task, and stopped with the run.

Generic: :func:`run` takes the work function and an initializer (a batch's
:func:`geovox.batch.warm` imports the conversion stack, the compiled kernels,
the backend, the loaders of the batch's file types and the writer of its
format, so a model's ``seconds`` in the manifest is its own work and not the
worker's start-up, which reached 12 s under load for the first model of
each worker).

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

#: In a worker: ``time.perf_counter()`` when its initializer had run
#: (None before, and in the parent); a test's hook.
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

def _start(initializer, initargs) -> None:
    """Every worker's start: its signals set, then the caller's ``initializer(*initargs)``
    (importing what the work will use), then :data:`WARMED`.

    SIGINT is ignored here: Ctrl-C reaches the whole process group, and the
    parent stops the workers itself (with SIGTERM, which unwinds the work).
    """
    global WARMED
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, _worker_stop)
    if initializer is not None:
        initializer(*initargs)
    WARMED = time.perf_counter()


def _worker_stop(signum, frame):
    """A worker's SIGTERM: unwind the work running (its atomic writes remove their
    temporary files; see :func:`_call`), or exit at once when idle."""
    if _RUNNING:
        raise Stopped(signum)
    os._exit(128 + signum)


def _call(work, task):
    """A worker's unit of work: ``work(task)``, stoppable.

    A :class:`Stopped` that unwound the work ends the worker; the parent is
    stopping the pool and waits for no result.
    """
    global _RUNNING
    try:
        _RUNNING = True
        return work(task)
    except Stopped as exc:
        os._exit(128 + exc.signum)
    finally:
        _RUNNING = False


# --- in the parent -----------------------------------------------------------

def run(work, tasks, workers: int, on_result, *, initializer=None, initargs=()) -> None:
    """Run ``work(task)`` for each of ``tasks`` on ``workers`` processes; ``on_result(i, result)``
    as each arrives.

    Parameters
    ----------
    work : callable
        A module-level function (the workers import it by name).
    tasks : list
        Its arguments, one per call.
    workers : int
        Processes (at most one per task).
    on_result : callable
        Called in this process with the task's index and its result.
    initializer : callable, optional
        Run once in each worker before its first task, with ``initargs``:
        the imports the work needs, so that a task's time is its own.

    Raises
    ------
    Stopped
        SIGTERM (where it had its default action) stopped the run; a
        KeyboardInterrupt (SIGINT) passes through. Either way the workers
        have ended and no partial file is left.
    """
    from concurrent.futures import ProcessPoolExecutor, as_completed

    pool = ProcessPoolExecutor(max_workers=min(workers, len(tasks)), initializer=_start,
                               initargs=(initializer, tuple(initargs)))
    with sigterm_raises():
        try:
            futures = {pool.submit(_call, work, t): i for i, t in enumerate(tasks)}
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
