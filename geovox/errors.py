"""The one error hierarchy of geovox.

Every exception raised on purpose by the library derives from
:class:`GeovoxError` *and* from the built-in exception a caller would expect,
so ``except ValueError`` and ``except FileNotFoundError`` keep working.
Messages name the parameter or file and show the offending value; the CLI
prints them as one line and exits with status 2.
"""

from __future__ import annotations


class GeovoxError(Exception):
    """Base class of every error geovox raises on purpose."""


class InputNotFoundError(GeovoxError, FileNotFoundError):
    """The input path does not exist (or is a folder where a file is needed)."""


class MeshError(GeovoxError, ValueError):
    """The input exists but is not a usable triangle mesh."""


class ParameterError(GeovoxError, ValueError):
    """A parameter (resolution, bounds, backend, ...) has a bad value."""


class BackendUnavailableError(GeovoxError, ImportError):
    """An explicitly requested backend cannot run here (its package is missing)."""


class OutputError(GeovoxError, OSError):
    """The output cannot be written (missing folder, no permission, disk full)."""


class ClusterError(GeovoxError, ConnectionError):
    """A Dask cluster cannot be used: nobody answers, or its workers differ from the client."""


class GridTooLargeError(GeovoxError, MemoryError):
    """The requested grid would not fit in memory; raised before allocating."""


class MeshTooLargeError(GridTooLargeError):
    """The mesh's inside test (the repair of an open mesh) would not fit in memory; raised before it."""


class GeovoxWarning(UserWarning):
    """Something was missing or had to be guessed; the conversion went on."""


# --- warnings --------------------------------------------------------------
# geovox says what it had to guess through warn() below, not warnings.warn
# directly: warnings.catch_warnings() swaps process-wide state, so two
# conversions on threads of one Dask worker that each record their warnings
# would take (or lose) each other's, and one leaving its block restores the
# filters under the other's feet. A context variable is per thread and per task.
import contextlib as _contextlib
import contextvars as _contextvars

_SINK = _contextvars.ContextVar("geovox_warning_sink", default=None)
_DROP = object()


def warn(message: str, stacklevel: int = 2) -> None:
    """Say ``message`` as a :class:`GeovoxWarning`, or hand it to :func:`collect_warnings`.

    Parameters
    ----------
    message : str
        One line, naming the file or parameter where it can.
    stacklevel : int
        As for :func:`warnings.warn`, counted from the caller of this function.
    """
    sink = _SINK.get()
    if sink is None:
        import warnings

        warnings.warn(message, GeovoxWarning, stacklevel=stacklevel + 1)
    elif sink is not _DROP:
        sink.append(message)


@_contextlib.contextmanager
def collect_warnings(drop: bool = False):
    """Gather the warnings geovox says in this thread (or task) in a list, or drop them.

    Unlike :func:`warnings.catch_warnings`, this touches no process-wide state,
    so conversions running side by side on threads each get their own.

    Parameters
    ----------
    drop : bool
        Forget them (they were said once elsewhere) instead of gathering them.

    Yields
    ------
    list of str
        The messages, in the order they were said (empty when ``drop``).
    """
    said: list = []
    token = _SINK.set(_DROP if drop else said)
    try:
        yield said
    finally:
        _SINK.reset(token)
