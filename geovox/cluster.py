"""Connecting to a Dask cluster from the command line's options.

A minimal version for the ``.zarr`` branch (issue 14); the many-models work
brings the full one with the same :func:`client_from_options`.
"""

from __future__ import annotations

import contextlib
import os

from .errors import InputNotFoundError, ParameterError

#: Seconds to wait for a scheduler before saying it does not answer.
CONNECT_TIMEOUT = 10


@contextlib.contextmanager
def client_from_options(scheduler=None, scheduler_file=None, local_cluster=None):
    """Yield a ``dask.distributed.Client`` for the options given, or None when none is.

    Parameters
    ----------
    scheduler : str, optional
        Scheduler address (``tcp://host:8786``); default the
        ``DASK_SCHEDULER_ADDRESS`` environment variable when no other option
        is given.
    scheduler_file : str, optional
        A scheduler's JSON file (``dask scheduler --scheduler-file``).
    local_cluster : int, optional
        Start a local cluster of this many worker processes (one thread each).

    Raises
    ------
    ParameterError
        The ``distributed`` extra is missing, or a scheduler does not answer.
    InputNotFoundError
        The scheduler file does not exist.
    """
    if scheduler is None and scheduler_file is None and local_cluster is None:
        scheduler = os.environ.get("DASK_SCHEDULER_ADDRESS") or None
    if scheduler is None and scheduler_file is None and local_cluster is None:
        yield None
        return
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        raise ParameterError("running on a Dask cluster needs the distributed extra: "
                             "pip install 'geovox[distributed]'") from None
    cluster = None
    if scheduler_file is not None and not os.path.isfile(scheduler_file):
        raise InputNotFoundError(f"scheduler file not found: {scheduler_file}")
    try:
        if local_cluster is not None:
            import dask

            # Dask sets MALLOC_TRIM_THRESHOLD_ for its workers, which also
            # fixes glibc's mmap threshold at 128 KiB: every array over that
            # is then mapped, faulted in and unmapped again, slab after slab
            # (the 2048³ bunny's workers took 29 s of CPU with it, 22 s
            # without, on a loaded machine: benchmarks/README.md).
            with dask.config.set({"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_":
                                  None}):
                cluster = LocalCluster(n_workers=int(local_cluster), threads_per_worker=1,
                                       dashboard_address=":0")
            client = Client(cluster)
        elif scheduler_file is not None:
            client = Client(scheduler_file=scheduler_file, timeout=CONNECT_TIMEOUT)
        else:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT)
    except (OSError, TimeoutError) as exc:
        if cluster is not None:
            cluster.close()
        where = scheduler or scheduler_file or "the local cluster"
        raise ParameterError(f"no Dask scheduler answers at {where} ({exc})") from None
    try:
        yield client
    finally:
        client.close()
        if cluster is not None:
            cluster.close()
