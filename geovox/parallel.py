"""Splitting array work over threads.

NumPy releases the GIL inside its loops, so blocks of a large array can be
processed by several threads at once. Every block writes only its own slice
of the output, so the result never depends on the number of jobs.
"""

from __future__ import annotations

import os

from .errors import ParameterError


def resolve_jobs(jobs) -> int:
    """Number of threads: ``None`` or 0 means one per CPU core."""
    if jobs is None or jobs == 0:
        return max(1, os.cpu_count() or 1)
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 0:
        raise ParameterError(f"`jobs` must be a non-negative integer, got {jobs!r}")
    return jobs


def for_blocks(fn, n: int, block: int, jobs: int = 1) -> None:
    """Call ``fn(start, stop)`` for consecutive blocks covering ``range(n)``.

    With ``jobs > 1``, ``jobs`` threads take the blocks in turn; every block
    runs even where another raised, and the exception of the first block
    (in order) that raised is raised here once all have finished, as a
    ThreadPoolExecutor's results would give it. Plain threads: importing
    concurrent.futures (with logging) cost a short conversion as much as
    its whole fill.
    """
    import threading

    bounds = [(s, min(s + block, n)) for s in range(0, n, block)]
    if jobs <= 1 or len(bounds) <= 1:
        for s, e in bounds:
            fn(s, e)
        return
    errors = [None] * len(bounds)
    order = iter(range(len(bounds)))
    lock = threading.Lock()

    def work():
        while True:
            with lock:
                k = next(order, None)
            if k is None:
                return
            try:
                fn(*bounds[k])
            except BaseException as exc:  # raised in the calling thread below
                errors[k] = exc

    threads = [threading.Thread(target=work, daemon=True) for _ in range(min(jobs, len(bounds)))]
    for t in threads:
        t.start()
    try:
        for t in threads:
            t.join()
    finally:  # an interrupt while waiting still lets every block finish, as the pool's exit did
        for t in threads:
            t.join()
    for exc in errors:
        if exc is not None:
            raise exc


def scan_along(op, array, axis: int, jobs: int = 1) -> None:
    """In-place running ``op`` (e.g. ``np.logical_xor``, ``np.maximum``) along ``axis``.

    One slice at a time, so no temporary larger than a slice; the other axes
    are split into ``jobs`` parts scanned in parallel.
    """
    other = max((a for a in range(array.ndim) if a != axis), key=lambda a: array.shape[a])
    n = array.shape[other]
    parts = max(1, min(jobs, n))

    # Along the axis that is contiguous in memory, NumPy's own accumulate
    # runs along each row in cache; stepping slice by slice there would
    # stride through memory (several times slower).
    along_rows = array.strides[axis] == array.itemsize

    def scan(s, e):
        sub = [slice(None)] * array.ndim
        sub[other] = slice(s, e)
        view = array[tuple(sub)]
        if along_rows:
            op.accumulate(view, axis=axis, out=view)
            return
        prev = [slice(None)] * array.ndim
        cur = [slice(None)] * array.ndim
        for k in range(1, array.shape[axis]):
            prev[axis] = k - 1
            cur[axis] = k
            op(view[tuple(cur)], view[tuple(prev)], out=view[tuple(cur)])

    for_blocks(scan, n, -(-n // parts), jobs)
