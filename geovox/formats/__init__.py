"""Output formats: a small registry keyed by file extension, and reading volumes back.

A writer is ``writer(volume, path, **options) -> list[str]`` (the files it
wrote); every file goes through :func:`atomic_output` (:mod:`geovox.formats.base`),
so an interrupted or failed write leaves no partial file. The registry
(:mod:`geovox.formats.registry`) holds each format's parts and abilities; the
writers' modules (``formats.raw``, ``formats.zarr``, ...) are imported only
when their format is used.

| module | holds |
|---|---|
| :mod:`geovox.formats.registry` | ``Format``, its ``Abilities``, ``format_for``, the formats themselves |
| :mod:`geovox.formats.base` | atomic outputs, ``SlabWriter``, ``Meta`` (what a writer lays out) |
| :mod:`geovox.formats.readback` | any file geovox wrote (header, sidecar, companion) back to its volume |
| one module per format | its writer, reader and slab writer |
"""

from __future__ import annotations

import os

from ..errors import ParameterError
from .base import Meta, SlabWriter, atomic_output, atomic_outputs, check_writable
from .readback import HEADER_EXTENSIONS
from .registry import Abilities, Format, format_for, formats, match, register_format


def read(path, fmt=None, **options):
    """Read a volume written by geovox back (occupancy, grid, colour when present).

    Parameters
    ----------
    path : str or os.PathLike
        A file (or a ``.zarr`` folder) that geovox wrote; for ``.raw``, the
        ``.raw`` beside its ``.json`` sidecar.
    fmt : str, optional
        Format name instead of the extension.
    **options
        For the reader: ``max_side`` (int) for ``.zarr``, the finest level
        of the pyramid with every side at most that.

    Returns
    -------
    Volume
        ``occupancy`` (nx, ny, nz) bool indexed ``[x, y, z]``, the grid, and
        ``colors`` (nx, ny, nz, 4) uint8 where the file holds colour. A
        ``.binvox`` comes back as its whole padded cube; a ``.vdb``'s
        occupancy is its ``density`` grid where that holds 0/1, else
        ``sdf < 0``, else coverage >= 0.5.

    Raises
    ------
    InputNotFoundError
        No such file.
    ParameterError
        The format cannot be told from the extension, or ``fmt`` is unknown.
    MeshError
        The file cannot be read as a geovox volume of that format (the
        message names the reader's own error).
    """
    from ..errors import InputNotFoundError, MeshError

    path = os.fspath(path)
    f = format_for(path, fmt)
    if not (os.path.isfile(path) or (f.can.folder and os.path.isdir(path))):
        raise InputNotFoundError(f"volume file not found: {path}")
    try:
        return f.reader(path, **options)
    except Exception as exc:  # readers of several libraries raise their own types
        raise MeshError(f"{path}: cannot be read as a geovox {f.name} volume "
                        f"({type(exc).__name__}: {exc})") from exc


def is_volume_file(path) -> bool:
    """Whether ``path`` names a file geovox writes (a volume, or a RAW output's
    ``.json`` sidecar or ``.mhd`` / ``.nhdr`` header), judged by its name."""
    lower = os.fspath(path).lower().rstrip("/" + os.sep)
    if lower.endswith(HEADER_EXTENSIONS):
        return True
    f = match(lower)
    # An extension that is also a mesh's (.ply): the file's own header says which.
    return f is not None and (f.sniff is None or f.sniff(os.fspath(path)))


def read_volume(path, *, max_side=None):
    """Read back any file geovox writes, data or header, as a Volume.

    The one reader behind ``geovox preview`` and ``geovox view``.

    Parameters
    ----------
    path : str or os.PathLike
        A volume in any format of :func:`formats` (``.raw``, ``.h5``,
        ``.vtkhdf``, ``.nrrd``, ``.npz``, ``.npy``, ``.binvox``, ``.vox``,
        ``.vdb``, ``.zarr``); a RAW output's ``NAME.json`` sidecar or
        ``NAME.mhd`` / ``NAME.nhdr`` header; or the file of one of its extra
        fields (``NAME_rgba.raw``, ``NAME_sdf.nrrd``, their headers), which
        reads the whole output it belongs to. A ``.mhd`` / ``.nhdr`` without
        geovox's sidecar is read through the header alone.
    max_side : int, optional
        ``.zarr`` only: read the finest pyramid level with every side at most
        this; other formats are read whole.

    Returns
    -------
    Volume
        ``occupancy`` (nx, ny, nz) bool and the grid, with ``colors``,
        ``density`` and ``sdf`` where the output holds them.

    Raises
    ------
    InputNotFoundError
        ``path``, or the data file it names, does not exist.
    MeshError
        The file is not one geovox wrote, or is damaged (the message says how).
    """
    from ..errors import GeovoxError, InputNotFoundError, MeshError
    from . import readback

    path = os.fspath(path)
    if not os.path.exists(path):
        raise InputNotFoundError(f"volume file not found: {path}")
    if os.path.isdir(path):  # a .zarr, perhaps named with a trailing slash
        path = path.rstrip("/" + os.sep) or path
    try:
        source, how = readback.volume_source(path)
        if how == "header":
            return readback.read_header_volume(source)
    except GeovoxError:
        raise
    except FileNotFoundError as exc:
        raise InputNotFoundError(f"{path}: refers to a file that is missing: "
                                 f"{exc.filename or exc}") from exc
    except Exception as exc:  # JSON, pynrrd and NumPy raise their own types
        raise MeshError(f"{path}: cannot be read as a geovox volume "
                        f"({type(exc).__name__}: {exc})") from exc
    folder = format_for("", how).can.folder
    return read(source, how, **({"max_side": max_side} if folder and max_side else {}))


def write(volume, path, fmt=None, **options) -> list:
    """Write ``volume`` to ``path`` in the format its extension (or ``fmt``) names.

    Every file goes to a temporary name beside its target and is renamed
    when complete; the files of one output appear together or not at all.

    Parameters
    ----------
    volume : Volume
        ``occupancy`` (nx, ny, nz) bool, and ``colors`` (nx, ny, nz, 4)
        uint8, ``density`` (nx, ny, nz) uint8 or float32 and ``sdf``
        (nx, ny, nz) float32 where set: every format but ``.npy`` and
        ``.vox`` writes them too.
    path : str or os.PathLike
        The main output file (``.raw``, ``.h5``, ``.vtkhdf``, ``.nrrd``,
        ``.npy``, ``.npz``, ``.binvox``, ``.vdb``, ``.vox``) or ``.zarr``
        folder; the other files of a format are named after it
        (``NAME_rgba.raw``, ``NAME.json``, ...).
    fmt : str, optional
        Format name (see :func:`formats`) instead of the extension.
    **options
        For the writer: ``pack_bits`` (bool) for ``.npz``, ``shell`` (bool)
        for ``.vox``.

    Returns
    -------
    list of str
        Every file written, the main one first.

    Raises
    ------
    ParameterError
        The format cannot be told from the extension, ``fmt`` is unknown,
        or the format cannot hold the grid (binvox needs cubic voxels).
    OutputError
        The folder does not exist or is not writable, the path is a folder,
        or the disk filled up (nothing is left behind).
    """
    check_writable(path)
    f = format_for(path, fmt)
    check_frame(f, getattr(volume, "grid", None))
    check_labels(volume, f)
    return f.writer(volume, path, **options)


def check_frame(f: Format, grid) -> None:
    """ParameterError for a reference grid (``like``) in a format that cannot place it."""
    if getattr(grid, "reference", None) is not None and not f.can.frame:
        raise ParameterError(f"{f.name} cannot record the reference grid's placement (origin, "
                             f"spacing, direction); onto a reference write .nii.gz, .nrrd, .seg.nrrd, "
                             f".raw (.mhd/.nhdr), .h5, .vtkhdf, .npz or .zarr")


def check_labels(volume, f) -> None:
    """ParameterError where ``volume`` has labels and format ``f`` would drop them.

    ``volume`` may be ``True`` for a conversion that will make labels.
    """
    labelled = volume is True or getattr(volume, "labels", None) is not None
    if labelled and not f.can.labels:
        raise ParameterError(
            f"{f.name} output does not hold labels; write them to .seg.nrrd (3D Slicer), .nrrd, "
            f".nii.gz, .h5, .vtkhdf, .npz, .raw, .vox or .zarr")


def __getattr__(name):
    """The writer modules as attributes (``formats.raw``), imported on first use."""
    import importlib

    if name == "zarr_format":
        return importlib.import_module(".zarr", __name__)
    if name in _MODULES:
        return importlib.import_module("." + name, __name__)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


#: The writers' modules, imported only when their format is used.
_MODULES = ("binvox", "hdf5", "nifti", "nrrd", "numpy_files", "raw", "seg_nrrd", "vdb", "vox",
            "vtkhdf", "zarr")

__all__ = ["Abilities", "Format", "Meta", "SlabWriter", "atomic_output", "atomic_outputs",
           "check_frame", "check_labels", "check_writable", "format_for", "formats",
           "is_volume_file", "read", "read_volume", "register_format", "write"]
