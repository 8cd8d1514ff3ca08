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
import numpy as np

from ..errors import OutputError, ParameterError


#: The parts of a format a :class:`Format` looks up in its module on first use.
_PARTS = ("writer", "reader", "check", "slab_writer")


class Format:
    """One output format of the registry (what ``geovox formats`` lists).

    The writer's module is imported on first use of ``writer``, ``reader``,
    ``check`` or ``slab_writer``, not with the registry: a ``.npy``
    conversion imports none of the other writers (nor h5py, zarr, ...).
    Each part is given as a callable or as ``"module:attribute"``, the module
    relative to :mod:`geovox.formats`; a name is looked up at every use, so a
    stand-in patched onto the module is the one called.

    Attributes
    ----------
    name : str
        The name ``fmt=`` and ``--format`` take (``"raw"``, ``"hdf5"``, ...).
    extensions : tuple of str
        Lower-case extensions with their dot, the first the default.
    writer : callable
        ``writer(volume, path, **options) -> list of str``: the files written.
    description : str
        One line: what the files hold.
    reader : callable or None
        ``reader(path, **options) -> Volume``, where the format can be read back.
    check : callable or None
        ``check(grid)``: raises ParameterError for a grid the format cannot hold, before any work.
    slab_writer : callable or None
        ``slab_writer(path, meta, jobs, *, thick=None, client=None)``: a
        :class:`SlabWriter` that takes the volume one z-slab at a time (None:
        the format is written whole).
    libraries : tuple of str
        The packages the writer imports when it runs (``h5py``, ``zarr``, ...):
        what :meth:`load` imports ahead of a first model.
    """

    __slots__ = ("name", "extensions", "description", "libraries", "_parts")

    def __init__(self, name, extensions, writer, description="", reader=None, check=None,
                 slab_writer=None, libraries=()):
        self.name = name
        self.extensions = tuple(e.lower() for e in extensions)
        self.description = description
        self.libraries = tuple(libraries)
        self._parts = dict(writer=writer, reader=reader, check=check, slab_writer=slab_writer)

    def _part(self, key):
        ref = self._parts[key]
        if not isinstance(ref, str):
            return ref
        import importlib

        module, attr = ref.split(":")
        return getattr(importlib.import_module("." + module, __name__), attr)

    writer = property(lambda self: self._part("writer"))
    reader = property(lambda self: self._part("reader"))
    check = property(lambda self: self._part("check"))
    slab_writer = property(lambda self: self._part("slab_writer"))

    def load(self) -> None:
        """Import the writer's module and the packages it uses (those installed).

        A batch's pool workers call it before their first model, so that the
        model's time is its own work, not the imports.
        """
        import importlib

        for key in _PARTS:
            self._part(key)
        for lib in self.libraries:
            try:
                importlib.import_module(lib)
            except ImportError:  # the writer says what to install when it runs
                pass

    def __eq__(self, other):
        return isinstance(other, Format) and (self.name, self.extensions) == (other.name,
                                                                              other.extensions)

    def __hash__(self):
        return hash((self.name, self.extensions))

    def __repr__(self):
        return f"Format(name={self.name!r}, extensions={self.extensions!r})"


_FORMATS: dict = {}


def register_format(name, extensions, writer, description="", reader=None, check=None,
                    slab_writer=None, libraries=()):
    """Register ``writer`` for the given extensions (with dot), with an optional ``reader``,
    grid ``check``, ``slab_writer`` (for slab-by-slab conversions) and the ``libraries``
    it imports; each part a callable or ``"module:attribute"`` (imported on first use)."""
    _FORMATS[name] = Format(name, extensions, writer, description, reader, check, slab_writer,
                            libraries)


def formats() -> list:
    """All registered formats.

    Returns
    -------
    list of Format
        In registration order, as ``geovox formats`` prints them.
    """
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
    if os.path.isdir(os.fspath(path)) and not (
            # A .zarr is a folder; an existing one is replaced only once the new one is whole.
            os.fspath(path).lower().endswith(".zarr")
            and os.path.isfile(os.path.join(os.fspath(path), "zarr.json"))):
        raise OutputError(f"output path is a folder: {os.fspath(path)}")


class _Group:
    """Temporary files of one output, renamed into place together."""

    def __init__(self):
        self.pending = []  # (temporary, target)

    def add(self, path) -> str:
        """A temporary path beside ``path`` to write instead of it."""
        path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(path))
        tmp = _new_file(folder, "." + os.path.basename(path) + ".", ".tmp")
        self.pending.append((tmp, path))
        return tmp


def _new_file(folder: str, prefix: str, suffix: str) -> str:
    """A new empty file ``folder/prefix<random>suffix`` with a plain open()'s permissions.

    tempfile.mkstemp's way (an exclusive create under a random name, tried
    again where the name is taken) without importing tempfile, which cost a
    short conversion a few milliseconds; the mode is 0o666 less the umask,
    what ``open(path, "w")`` gives (mkstemp's 0o600 had to be changed back).
    """
    flags = (os.O_RDWR | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
             | getattr(os, "O_BINARY", 0))
    for _ in range(100):
        tmp = os.path.join(folder, prefix + os.urandom(6).hex() + suffix)
        try:
            os.close(os.open(tmp, flags, 0o666))
            return tmp
        except FileExistsError:
            continue
        except OSError as exc:
            raise OutputError(f"cannot write in {folder}: {exc.strerror or exc}") from exc
    raise OutputError(f"cannot write in {folder}: no free temporary name")


@contextlib.contextmanager
def atomic_outputs():
    """Yield a group; files added to it are renamed into place only when all are complete.

    Any exception (including KeyboardInterrupt) removes every temporary file
    and leaves the targets as they were. OS errors become :class:`OutputError`.
    """
    group = _Group()
    try:
        yield group
        for tmp, path in group.pending:
            os.replace(tmp, path)
    except BaseException as exc:
        for tmp, _ in group.pending:
            with contextlib.suppress(OSError):
                os.unlink(tmp)
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            target = group.pending[-1][1] if group.pending else "output"
            if exc.errno == errno.ENOSPC:
                raise OutputError(f"disk full while writing {target}; nothing was written") from exc
            raise OutputError(f"cannot write {target}: {exc.strerror or exc}") from exc
        raise


@contextlib.contextmanager
def atomic_output(path):
    """Yield a temporary path beside ``path``; rename it over ``path`` on success."""
    with atomic_outputs() as group:
        yield group.add(path)


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
    if not (os.path.isfile(path) or (f.name == "zarr" and os.path.isdir(path))):
        raise InputNotFoundError(f"volume file not found: {path}")
    try:
        return f.reader(path, **options)
    except Exception as exc:  # readers of several libraries raise their own types
        raise MeshError(f"{path}: cannot be read as a geovox {f.name} volume "
                        f"({type(exc).__name__}: {exc})") from exc


def is_volume_file(path) -> bool:
    """Whether ``path`` names a file geovox writes (a volume, or a RAW output's
    ``.json`` sidecar or ``.mhd`` / ``.nhdr`` header), judged by its name."""
    from .readback import HEADER_EXTENSIONS

    lower = os.fspath(path).lower().rstrip("/" + os.sep)
    return lower.endswith(HEADER_EXTENSIONS) or any(
        lower.endswith(e) for f in _FORMATS.values() for e in f.extensions)


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
    return read(source, how, **({"max_side": max_side} if how == "zarr" and max_side else {}))


#: What the values of each extra field mean, by its dtype.
FIELD_VALUES = {
    "density": lambda dtype: ("inside fraction x 255" if np.dtype(dtype) == np.uint8
                              else "inside fraction, 0 to 1"),
    "sdf": lambda dtype: "signed distance, negative inside, clamped beyond the exact band",
    "labels": lambda dtype: "label value, 0 the background (see label_table)",
}


def scalar_fields(volume) -> list:
    """The extra scalar volumes to write: ``[(name, [x, y, z] array, dtype name, values)]``."""
    out = []
    for name in ("density", "sdf", "labels"):
        arr = getattr(volume, name, None)
        if arr is not None:
            out.append((name, arr, str(arr.dtype), FIELD_VALUES[name](arr.dtype)))
    return out


class SlabWriter:
    """Base of the writers that take a volume whole or one z-slab at a time.

    Subclasses open their files in an :func:`atomic_outputs` group kept in
    ``self._ctx`` and define ``write(z0, vol)``, ``_finish() -> files`` and
    ``_release()`` (close open handles). ``close`` renames everything into
    place; any failure, there or before, leaves nothing behind.
    """

    def write_whole(self, volume) -> list:
        try:
            self.write(0, volume)
        except BaseException:
            self.abort()
            raise
        return self.close()

    def close(self) -> list:
        try:
            return self._finish()
        except BaseException:
            self.abort()
            raise

    def abort(self) -> None:
        """Drop everything written (call from an ``except`` block)."""
        import sys

        try:
            self._release()
        finally:
            self._ctx.__exit__(*sys.exc_info())


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


#: Formats with no way to say where a reference grid's voxels lie (oblique or not).
NO_FRAME = ("binvox", "vox", "vdb")


def check_frame(f: Format, grid) -> None:
    """ParameterError for a reference grid (``like``) in a format that cannot place it."""
    if getattr(grid, "reference", None) is not None and f.name in NO_FRAME:
        raise ParameterError(f"{f.name} cannot record the reference grid's placement (origin, "
                             f"spacing, direction); onto a reference write .nii.gz, .nrrd, .seg.nrrd, "
                             f".raw (.mhd/.nhdr), .h5, .vtkhdf, .npz or .zarr")


#: The formats that hold a label volume (and its table).
LABEL_FORMATS = ("seg_nrrd", "nrrd", "nifti", "hdf5", "vtkhdf", "npz", "raw", "vox", "zarr")


def check_labels(volume, f) -> None:
    """ParameterError where ``volume`` has labels and format ``f`` would drop them.

    ``volume`` may be ``True`` for a conversion that will make labels.
    """
    labelled = volume is True or getattr(volume, "labels", None) is not None
    if labelled and f.name not in LABEL_FORMATS:
        raise ParameterError(
            f"{f.name} output does not hold labels; write them to .seg.nrrd (3D Slicer), .nrrd, "
            f".nii.gz, .h5, .vtkhdf, .npz, .raw, .vox or .zarr")


def _slabs(ref: str):
    """The slab writer of a format whose writer class (``"module:Class"``) takes
    ``(path, meta, jobs)``; the class is looked up when a slab writer is made."""
    module, cls = ref.split(":")

    def make(path, meta, jobs, *, thick=None, client=None):
        import importlib

        return getattr(importlib.import_module("." + module, __name__), cls)(path, meta, jobs)

    make.__name__ = make.__qualname__ = f"slab_writer_{cls}"
    return make


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

register_format("raw", (".raw",), "raw:write_raw",
                "headerless uint8 (0/255), x fastest; .json sidecar, .mhd and .nhdr headers",
                reader="raw:read_raw_volume", slab_writer=_slabs("raw:RawWriter"))
register_format("hdf5", (".h5", ".hdf5"), "hdf5:write_hdf5",
                "HDF5: `occupancy`/`color` [x, y, z] datasets plus a VTK-HDF ImageData group",
                reader="hdf5:read_hdf5", slab_writer=_slabs("hdf5:HDF5Writer"),
                libraries=("h5py",))
register_format("vtkhdf", (".vtkhdf", ".hdf"), "vtkhdf:write_vtkhdf",
                "VTK-HDF 1.0 ImageData for ParaView (opens by name): occupancy, color, density, sdf",
                reader="vtkhdf:read_vtkhdf", slab_writer=_slabs("vtkhdf:VTKHDFWriter"),
                libraries=("h5py",))
register_format("seg_nrrd", (".seg.nrrd",), "seg_nrrd:write_seg_nrrd",
                "3D Slicer segmentation: the labels (--labels) as named, coloured segments",
                reader="seg_nrrd:read_seg_nrrd", slab_writer=_slabs("seg_nrrd:SegNrrdWriter"),
                libraries=("scipy.ndimage",))
register_format("nrrd", (".nrrd",), "nrrd:write_nrrd",
                "single-file NRRD (gzip), uint8 0/255; colour in NAME_rgba.nrrd",
                reader="nrrd:read_nrrd")
register_format("npy", (".npy",), "numpy_files:write_npy", "NumPy array [x, y, z], uint8 0/1",
                reader="numpy_files:read_npy")
register_format("npz", (".npz",), "numpy_files:write_npz",
                "NumPy archive: occupancy (bits with --pack-bits), colors, spacing, bounds, origin",
                reader="numpy_files:read_npz")
register_format("binvox", (".binvox",), "binvox:write_binvox",
                "binvox (ShapeNet, 3D-R2N2, ONet): -r N is binvox -d N (N³ cube over the longest "
                "side; --cube-center: -cb); --voxel-size grids padded to a cube",
                reader="binvox:read_binvox", check="binvox:check_grid")
register_format("vdb", (".vdb",), "vdb:write_vdb",
                "OpenVDB for Blender/Houdini: density (fog), color (vec3s), sdf (level set) grids",
                reader="vdb:read_vdb")
register_format("vox", (".vox",), "vox:write_vox",
                "MagicaVoxel: 256³ models in a scene graph, 255 quantised colours",
                reader="vox:read_vox", libraries=("PIL.Image",))
register_format("zarr", (".zarr",), "zarr:write_zarr",
                "OME-Zarr 0.5 (Zarr v3) multiscale image for napari, neuroglancer, Fiji, WEBKNOSSOS: "
                "occupancy, color, density, sdf; written slab by slab, or on a Dask cluster",
                reader="zarr:read_zarr", slab_writer="zarr:ZarrWriter", libraries=("zarr",))
register_format("nifti", (".nii.gz", ".nii"), "nifti:write_nifti",
                "NIfTI-1 for 3D Slicer, ITK-SNAP, FSL, nibabel: uint8 mask, sform = qform = the "
                "grid's RAS affine (needs nibabel: the nifti extra)",
                reader="nifti:read_nifti", libraries=("nibabel",))

__all__ = ["register_format", "formats", "format_for", "write", "read", "read_volume",
           "is_volume_file", "atomic_output", "check_frame",
           "atomic_outputs",
           "check_writable"]


def label_table_json(volume) -> str:
    """The volume's label table as JSON text (``"[]"`` without labels)."""
    import json

    return json.dumps(getattr(volume, "label_table", None) or [])


def table_from_json(text):
    """A label table from :func:`label_table_json`'s text; None when it is empty."""
    import json

    if isinstance(text, bytes):
        text = text.decode("utf-8")
    table = json.loads(str(text))
    return table or None
