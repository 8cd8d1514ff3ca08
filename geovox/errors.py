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


class GeovoxWarning(UserWarning):
    """Something was missing or had to be guessed; the conversion went on."""
