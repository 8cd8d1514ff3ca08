"""Connecting to a Dask cluster and checking that its workers can run geovox.

Only this module and the distributed branch of :mod:`geovox.batch` import
Dask, and only when a cluster is asked for: a plain ``geovox convert`` never
pays for it. Every bad set-up becomes one :class:`~geovox.errors.GeovoxError`
whose message the CLI prints as one line (exit status 2), within seconds:

* no scheduler answers at the address (:class:`~geovox.errors.ClusterError`,
  naming the address; the connection gives up after ``CONNECT_TIMEOUT``);
* the scheduler file does not exist (:class:`~geovox.errors.InputNotFoundError`);
* Dask is not installed (:class:`~geovox.errors.BackendUnavailableError`,
  saying ``pip install 'geovox[distributed]'``);
* a worker has another geovox or NumPy version than this process, or cannot
  import geovox at all (:class:`~geovox.errors.ClusterError`).
"""

from __future__ import annotations

import contextlib
import json
import logging
import os

from .errors import BackendUnavailableError, ClusterError, InputNotFoundError, ParameterError

#: Seconds to wait for a scheduler to answer. A live scheduler answers in
#: milliseconds, even a loaded one across a data centre; the issue's promise
#: is one line within 10 s, and importing Dask takes about 1 s of that.
CONNECT_TIMEOUT = 5.0

#: What to install when Dask is missing.
EXTRA_HINT = "pip install 'geovox[distributed]'"

#: Dask settings for a cluster geovox starts itself (``local_cluster``):
#: a dead worker fails its task at once (geovox's own ``retries`` then
#: decide, so they count exactly); a worker holds only the tasks it is
#: running, so a worker that dies takes no queued model down with it; and
#: workers start without Dask's ``MALLOC_TRIM_THRESHOLD_=65536``, which
#: returns freed memory to the system so eagerly that the corpus's slow
#: models took twice the wall time (5.7 s of system time instead of 1.2 s,
#: measured; see benchmarks/results/history.md). A model that has waited
#: 120 s with no worker alive fails (then geovox's ``retries`` decide): a
#: local worker whose restart failed (its nanny gives up) never comes back,
#: and the batch would otherwise wait for it for ever.
LOCAL_CLUSTER_CONFIG = {
    "distributed.scheduler.allowed-failures": 0,
    "distributed.scheduler.worker-saturation": 1.0,
    "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
    "distributed.scheduler.no-workers-timeout": "120s",
}


def import_distributed():
    """``dask.distributed``, or the error that says which extra to install."""
    try:
        import distributed
    except ImportError as exc:
        raise BackendUnavailableError(
            f"a Dask cluster needs dask.distributed, which is not installed here ({exc}); "
            f"{EXTRA_HINT}") from None
    return distributed


def _scheduler_file_address(path) -> str:
    """The address a ``dask scheduler --scheduler-file`` wrote into ``path``."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputNotFoundError(f"scheduler file not found: {path}")
    try:
        with open(path, encoding="utf-8") as f:
            address = json.load(f)["address"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ClusterError(f"cannot read a scheduler address from {path}: "
                           f"{type(exc).__name__}: {exc}") from None
    if not isinstance(address, str) or not address:
        raise ClusterError(f"cannot read a scheduler address from {path}: address is {address!r}")
    return address


def _probe(distributed, address: str, where: str) -> None:
    """Ask ``address`` who it is, within ``CONNECT_TIMEOUT``; a ClusterError unless a scheduler.

    Done before making a Client: a Client whose connection failed still
    tries to close itself when collected, and waits twice its timeout to do
    so; and a port that answers with something other than Dask (a proxy, a
    web server) would otherwise fail deep inside the protocol.
    """
    import asyncio

    async def ask():
        comm = await distributed.comm.connect(address, timeout=CONNECT_TIMEOUT)
        try:
            await comm.write({"op": "identity", "n_workers": 0, "reply": True})
            return await comm.read()
        finally:
            comm.abort()

    import socket

    try:
        scheme, location = distributed.comm.parse_address(address)
        if scheme == "tcp":
            host, port = distributed.comm.parse_host_port(location)
    except ValueError as exc:
        raise ClusterError(f"not a scheduler address: {where} ({exc})") from None
    if scheme == "tcp":
        # A refused port or an unknown host is known at once; Dask's own
        # connect would retry both until its timeout.
        try:
            socket.create_connection((host, port), timeout=CONNECT_TIMEOUT).close()
        except socket.gaierror as exc:
            raise ClusterError(f"no Dask scheduler answered at {where} (unknown host {host!r}: "
                               f"{exc.strerror or exc})") from None
        except socket.timeout:
            raise ClusterError(f"no Dask scheduler answered at {where} (no answer in "
                               f"{CONNECT_TIMEOUT:g} s)") from None
        except OSError as exc:
            raise ClusterError(f"no Dask scheduler answered at {where} "
                               f"({exc.strerror or exc})") from None
    from concurrent.futures import ThreadPoolExecutor

    try:
        # In a thread of its own: the caller may be running an event loop
        # (Jupyter), where asyncio.run cannot start another.
        with ThreadPoolExecutor(1) as pool:
            reply = pool.submit(asyncio.run, asyncio.wait_for(ask(), CONNECT_TIMEOUT)).result()
    except (OSError, asyncio.TimeoutError) as exc:
        why = f"no answer in {CONNECT_TIMEOUT:g} s" if isinstance(exc, asyncio.TimeoutError) \
            else one_line(exc)
        raise ClusterError(f"no Dask scheduler answered at {where} ({why})") from None
    except Exception:  # e.g. a web server's reply read as a Dask frame length
        reply = None
    if not (isinstance(reply, dict) and reply.get("type") == "Scheduler"):
        raise ClusterError(f"{where} answered, but not as a Dask scheduler")


def versions() -> dict:
    """Run on each worker (and here): the versions that must agree."""
    import numpy

    from .version import __version__

    return {"geovox": __version__, "numpy": numpy.__version__}


def one_line(exc) -> str:
    """An exception as one line: its type and the first line of its message."""
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


#: Seconds the workers get to report their versions (see check_versions).
VERSION_TIMEOUT = 5.0


def check_versions(client) -> None:
    """Refuse workers whose geovox or NumPy version differs from this process's.

    A different NumPy or geovox can change a voxel (a rounding, a fixed
    bug), so a cluster run would no longer give the files a local run gives.
    Workers that join later are checked by each task instead (see
    :func:`geovox.batch.convert_one`).

    Raises
    ------
    ClusterError
        A worker differs or cannot import geovox.
    """
    mine = versions()
    try:
        # With a bound: a worker that hangs must not hang the set-up (errors
        # within 10 s); client.run itself waits for ever.
        theirs = client.sync(client._run, versions, on_error="return",
                             callback_timeout=VERSION_TIMEOUT)
    except TimeoutError:
        raise ClusterError(f"the cluster's workers did not say their versions within "
                           f"{VERSION_TIMEOUT:g} s; is every worker alive?") from None
    bad = []
    for address, v in sorted(theirs.items()):
        if isinstance(v, BaseException):
            raise ClusterError(f"worker {address} cannot run geovox ({one_line(v)}); install "
                               f"geovox {mine['geovox']} and NumPy {mine['numpy']} on every worker")
        if v != mine:
            bad.append((address, v))
    if bad:
        address, v = bad[0]
        raise ClusterError(
            f"{len(bad)} of {len(theirs)} workers differ from this client: {address} has geovox "
            f"{v['geovox']} and NumPy {v['numpy']}, this client geovox {mine['geovox']} and NumPy "
            f"{mine['numpy']}; install the same versions on every worker")


@contextlib.contextmanager
def _quiet_dask_logs():
    """Hold back Dask's own log lines while the client is open.

    Each failure (a refused connection, a worker that died) is reported once
    by geovox, in its error line or its model's row; Dask would otherwise
    print its own multi-line account of the same event on stderr.
    """
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    before = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, before):
            lg.setLevel(level)


@contextlib.contextmanager
def client_from_options(scheduler=None, scheduler_file=None, local_cluster=None):
    """A ``dask.distributed.Client`` for the options given, or ``None``.

    Parameters
    ----------
    scheduler : str, optional
        Address of a running scheduler, e.g. ``"tcp://10.0.0.5:8786"``.
    scheduler_file : path, optional
        JSON file written by ``dask scheduler --scheduler-file`` (or
        dask-jobqueue, dask-mpi): the usual way on a shared file system.
    local_cluster : int, optional
        Start a cluster of this many single-threaded worker processes on
        this machine, for trying things out; closed on exit.

    With none of these, the ``DASK_SCHEDULER_ADDRESS`` environment variable
    is used when set; otherwise the context yields ``None`` (no cluster, and
    Dask is not imported).

    Yields
    ------
    distributed.Client or None
        Connected, with every worker checked (:func:`check_versions`);
        closed on exit.

    Raises
    ------
    ParameterError
        More than one of the options, or a bad ``local_cluster``.
    InputNotFoundError, ClusterError, BackendUnavailableError
        See the module's docstring.
    """
    given = [n for n, v in (("scheduler", scheduler), ("scheduler_file", scheduler_file),
                            ("local_cluster", local_cluster)) if v is not None and v != ""]
    if len(given) > 1:
        raise ParameterError(f"give one of scheduler, scheduler_file and local_cluster, "
                             f"not {' and '.join(given)}")
    if not given:
        scheduler = os.environ.get("DASK_SCHEDULER_ADDRESS", "").strip() or None
        if scheduler is None:
            yield None
            return
    if local_cluster is not None and (isinstance(local_cluster, bool)
                                      or not isinstance(local_cluster, int) or local_cluster < 1):
        raise ParameterError(f"`local_cluster` must be a positive number of workers, "
                             f"got {local_cluster!r}")
    if scheduler_file is not None:
        scheduler = _scheduler_file_address(scheduler_file)
    distributed = import_distributed()
    import dask

    with _quiet_dask_logs(), contextlib.ExitStack() as stack:
        if local_cluster is not None:
            try:
                with dask.config.set(LOCAL_CLUSTER_CONFIG):
                    cluster = stack.enter_context(distributed.LocalCluster(
                        n_workers=local_cluster, threads_per_worker=1, processes=True,
                        dashboard_address=":0", silence_logs=logging.CRITICAL))
            except Exception as exc:  # e.g. a script without `if __name__ == "__main__":`
                raise ClusterError(f"cannot start a local Dask cluster of {local_cluster} "
                                   f"workers ({one_line(exc)})") from None
            client = stack.enter_context(distributed.Client(cluster))
        else:
            where = scheduler + (f" (from {os.fspath(scheduler_file)})" if scheduler_file else "")
            _probe(distributed, scheduler, where)
            try:
                client = distributed.Client(scheduler, timeout=CONNECT_TIMEOUT)
            except Exception as exc:  # it answered a moment ago; say what went wrong
                raise ClusterError(f"cannot open a client of the Dask scheduler at {where} "
                                   f"({one_line(exc)})") from None
            stack.enter_context(client)
        check_versions(client)
        yield client
