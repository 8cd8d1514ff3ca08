"""Output formats: a small registry keyed by file extension.

A writer is ``writer(volume, path, **options) -> list[str]`` (the files it
wrote). Every file goes through :func:`atomic_output`: written to a temporary
file in the target folder and renamed into place only when complete, so an
interrupted or failed write leaves no partial file and an existing file is
replaced only by a complete one.
"""

from __future__ import annotations

import contextlib
import errno
import os
import tempfile
from dataclasses import dataclass

from ..errors import OutputError, ParameterError


@dataclass(frozen=True)
class Format:
    name: str
    extensions: tuple
    writer: object
    description: str


_FORMATS: dict = {}


def register_format(name, extensions, writer, description=""):
    """Register ``writer`` for the given extensions (with leading dot)."""
    _FORMATS[name] = Format(name, tuple(e.lower() for e in extensions), writer, description)


def formats() -> list:
    """All registered formats."""
    return list(_FORMATS.values())


def format_for(path, fmt=None) -> Format:
    """The format named ``fmt``, or the one the extension of ``path`` implies."""
    if fmt is not None:
        if fmt not in _FORMATS:
            raise ParameterError(f"`format` must be one of {', '.join(_FORMATS)}; got {fmt!r}")
        return _FORMATS[fmt]
    lower = os.fspath(path).lower()
    for f in _FORMATS.values():
        if any(lower.endswith(ext) for ext in f.extensions):
            return f
    known = ", ".join(e for f in _FORMATS.values() for e in f.extensions)
    raise ParameterError(
        f"cannot tell the output format from {os.fspath(path)!r}: use one of {known}"
    )


def check_writable(path) -> None:
    """Fail early, before any work, if ``path``'s folder cannot take the file."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path)))
    if not os.path.isdir(folder):
        raise OutputError(f"output folder does not exist: {folder}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"output folder is not writable: {folder}")
    if os.path.isdir(os.fspath(path)):
        raise OutputError(f"output path is a folder: {os.fspath(path)}")


@contextlib.contextmanager
def atomic_output(path):
    """Yield a temporary path beside ``path``; rename it over ``path`` on success.

    Any exception (including KeyboardInterrupt) removes the temporary file
    and leaves ``path`` as it was. OS errors become :class:`OutputError`.
    """
    path = os.fspath(path)
    folder = os.path.dirname(os.path.abspath(path))
    try:
        fd, tmp = tempfile.mkstemp(prefix="." + os.path.basename(path) + ".", suffix=".tmp",
                                   dir=folder)
    except OSError as exc:
        raise OutputError(f"cannot write in {folder}: {exc.strerror or exc}") from exc
    os.close(fd)
    try:
        # mkstemp creates 0600; give the file the permissions a plain open() would.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        yield tmp
        os.replace(tmp, path)
    except BaseException as exc:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            if exc.errno == errno.ENOSPC:
                raise OutputError(f"disk full while writing {path}; nothing was written") from exc
            raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from exc
        raise


def write(volume, path, fmt=None, **options) -> list:
    """Write ``volume`` to ``path`` in the format its extension (or ``fmt``) names.

    Returns
    -------
    list of str
        Every file written.
    """
    check_writable(path)
    return format_for(path, fmt).writer(volume, path, **options)


from . import hdf5, raw  # noqa: E402  (registration)

register_format("raw", (".raw",), raw.write_raw,
                "headerless uint8 (0/255), x fastest, with a .json sidecar")
register_format("hdf5", (".h5", ".hdf5"), hdf5.write_hdf5,
                "HDF5 dataset `occupancy` (uint8 0/1, gzip) with grid attributes")

__all__ = ["register_format", "formats", "format_for", "write", "atomic_output", "check_writable"]
