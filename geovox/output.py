"""Where a conversion's output goes, resolved once: a file, a folder of named files, or a URL.

``-o spot.h5`` is a file; ``-o out/`` (or an existing folder, or nothing: the
current folder) is a folder whose files are named after the model and the
grid (``spot_128x128x128_uint8.raw``); an fsspec URL (``s3://bucket/x.zarr``,
``gs://bucket/out/``) names either, written locally first and then copied up
complete (:func:`upload`). A folder format's output (``.zarr``) is a file
here, though it is a folder on disk. :func:`resolve_output` decides which,
once, for the command line, :func:`geovox.convert_many` and the plan
(:func:`geovox.planner.plan` takes a folder :class:`Target` and names the file
after the grid it makes).
"""

from __future__ import annotations

import enum
import os
from dataclasses import dataclass, replace

from .errors import OutputError, ParameterError


class Kind(enum.StrEnum):
    """What an output names."""

    FILE = "file"  #: one volume (its side files beside it)
    FOLDER = "folder"  #: a folder; each volume named after its model and grid


def is_url(path) -> bool:
    """Whether ``path`` names a place through fsspec (``s3://``, ``memory://``, ...)."""
    return isinstance(path, str) and "://" in path


@dataclass(frozen=True)
class Target:
    """One conversion's (or a batch's) output, resolved by :func:`resolve_output`.

    Attributes
    ----------
    kind : Kind
    path : str
        The file, or the folder, as given (a URL, or a local path).
    fmt : geovox.formats.Format
        The format written: the file's (its extension, or ``--format``), or
        a folder's files' (``--format``, default RAW).
    stem : str or None
        A folder's file name before the grid's size: the model's (see :meth:`named`).
    """

    kind: Kind
    path: str
    fmt: object
    stem: str | None = None

    @property
    def url(self) -> bool:
        """Whether the output is an fsspec URL (written locally first, then uploaded)."""
        return is_url(self.path)

    def named(self, stem: str) -> "Target":
        """This target with the file stem of a folder's output (the model's name)."""
        return replace(self, stem=stem)

    def file_for(self, shape) -> str:
        """The file a volume of grid ``shape`` goes to: the target's own, or named in the folder."""
        if self.kind == Kind.FILE:
            return self.path
        from .formats.headers import default_name

        name = default_name(self.stem or "volume", shape, "uint8", self.fmt.extensions[0])
        return (self.path.rstrip("/") + "/" + name if self.url
                else os.path.join(self.path, name))

    def check(self) -> None:
        """Fail before any work where the output cannot be written (local outputs)."""
        from . import formats

        if self.url:
            return
        if self.kind == Kind.FILE:
            formats.check_writable(self.path)
        elif not os.path.isdir(self.path):
            formats.check_writable(os.path.join(self.path, "x"))


def resolve_output(output=None, fmt=None, *, many: bool = False) -> Target:
    """What ``output`` (``-o``) names: a file or a folder, local or a URL, and its format.

    Parameters
    ----------
    output : str or os.PathLike, optional
        A file, a folder (an existing one, or one ending in ``/``), or an
        fsspec URL; None: the current folder.
    fmt : str, optional
        Format name (``--format``), overriding the extension.
    many : bool
        Several models: ``output`` is a folder whenever it can be (a URL, or
        a path without an extension that does not exist yet); a file is then
        refused.

    Raises
    ------
    ParameterError
        An output whose format cannot be told, or a file for many models.
    """
    from .formats import format_for, match

    if output is None:
        return Target(Kind.FOLDER, os.getcwd(), format_for("x.raw", fmt))
    out = os.fspath(output)
    if is_url(out):
        tail = out.rsplit("/", 1)[-1]
        file = not many and not out.endswith("/") and bool(os.path.splitext(tail)[1])
    else:
        named = match(out)
        folder_format = named is not None and named.can.folder
        file = not (out.endswith(("/", os.sep)) or (os.path.isdir(out) and not folder_format))
        if many and file and not os.path.splitext(out)[1]:
            file = False  # a folder to be made
    if file and many:
        raise ParameterError(f"with several inputs (or --manifest, --shard), -o must be a folder; "
                             f"got {out!r}")
    if file:
        return Target(Kind.FILE, out, format_for(out, fmt))
    return Target(Kind.FOLDER, out, format_for("x.raw", fmt))


def folder_files(folder, last=None) -> list:
    """The files under ``folder`` (relative paths, ``/``-separated), its root file ``last`` last."""
    out = []
    for here, _, names in os.walk(folder):
        rel = os.path.relpath(here, folder)
        out += [n if rel == "." else rel.replace(os.sep, "/") + "/" + n for n in sorted(names)]
    return sorted(out, key=lambda r: r == last)


def output_exists(target: str) -> bool:
    """Whether the volume ``target`` (a local path or a URL) is there, whole."""
    from .formats import match

    fmt = match(target.rstrip("/"))
    if fmt is not None and fmt.can.folder:
        # A folder output's root file is uploaded last (see upload): on an object
        # store, some of its chunks may be there before it is whole.
        target = target.rstrip("/") + "/" + fmt.can.root_file
    if is_url(target):
        import fsspec

        fs, p = fsspec.core.url_to_fs(target)
        return fs.exists(p)
    return os.path.exists(target)


def check_url(url: str) -> None:
    """ParameterError where ``url`` cannot be written: no fsspec, or its filesystem is missing."""
    try:
        import fsspec

        fsspec.core.url_to_fs(url)  # an unknown protocol or a missing filesystem package
    except ImportError:
        raise ParameterError(f"an output URL needs fsspec (pip install 'geovox[cloud]'): {url}") \
            from None
    except ValueError as exc:
        raise ParameterError(f"cannot write to {url}: {exc}") from None


def make_folder(out: str) -> None:
    """Create the output folder (or the URL's), or say why not."""
    if is_url(out):
        try:
            import fsspec

            fs, base = fsspec.core.url_to_fs(out)
            fs.makedirs(base, exist_ok=True)
        except ImportError as exc:
            raise OutputError(f"cannot write to {out}: {exc} (pip install 'geovox[cloud]')") \
                from None
        except (OSError, ValueError) as exc:
            raise OutputError(f"cannot write to {out}: {type(exc).__name__}: {exc}") from None
    else:
        try:
            os.makedirs(out, exist_ok=True)
        except OSError as exc:
            raise OutputError(f"cannot create output folder {out}: {exc.strerror or exc}") \
                from None


def upload(local_files, main, folder) -> list:
    """Copy files (or a folder output) written locally into the URL ``folder``; ``main`` last.

    An object store shows an object only once its upload is complete; on a
    plain file system each file goes to a temporary name first and is then
    renamed. The volume is copied last, so its presence (what skipping and
    resuming look at) means its side files are there too.

    Returns
    -------
    list of str
        The URLs of ``local_files``, in their order, as the user spelt the folder.
    """
    import fsspec

    from .formats import match

    fs, base = fsspec.core.url_to_fs(folder)
    order = [f for f in local_files if f != main] + [main]
    atomic_rename = "file" in (fs.protocol if isinstance(fs.protocol, tuple) else (fs.protocol,))
    urls = {}
    for f in order:
        name = os.path.basename(f.rstrip(os.sep))
        target = base.rstrip("/") + "/" + name
        dest = base.rstrip("/") + f"/.{name}.{os.getpid()}.part" if atomic_rename else target
        if os.path.isdir(f):  # a folder output: every file, its root file last
            if atomic_rename and fs.exists(target):
                fs.rm(target, recursive=True)  # mv would nest the folder inside the old one
            fmt = match(f.rstrip(os.sep))
            for rel in folder_files(f, fmt.can.root_file if fmt is not None else None):
                fs.makedirs((dest + "/" + rel).rsplit("/", 1)[0], exist_ok=True)
                fs.put_file(os.path.join(f, *rel.split("/")), dest + "/" + rel)
        else:
            fs.put_file(f, dest)
        if atomic_rename:
            fs.mv(dest, target, recursive=os.path.isdir(f))
        urls[f] = folder.rstrip("/") + "/" + name
    return [urls[f] for f in local_files]


__all__ = ["Kind", "Target", "check_url", "folder_files", "is_url", "make_folder",
           "output_exists", "resolve_output", "upload"]
