"""What every writer shares: atomic outputs, the slab writer's base, and the layout it writes.

Every file goes through :func:`atomic_output`: written to a temporary file in
the target folder and renamed into place only when complete, so an
interrupted or failed write leaves no partial file and an existing file is
replaced only by a complete one.
"""

from __future__ import annotations

import contextlib
import errno
import os
from dataclasses import dataclass, field

import numpy as np

from ..errors import OutputError
from ..grid import Grid
from .registry import match


@dataclass
class Meta:
    """What a writer lays its files out for: the whole grid and the fields a conversion makes.

    A slab writer is made from one before any slab exists; a volume written
    whole gives its own (:meth:`of`). Writers read the fields' presence and
    dtypes here, and the data from each slab's :class:`~geovox.volume.Volume`.

    Attributes
    ----------
    grid : Grid
        The whole grid (its ``reference`` places the voxels of ``like=``).
    backend : str
    source : str
    colors : bool
        RGBA colour is made.
    fields : dict of str -> numpy.dtype
        The scalar fields made (``"density"``, ``"sdf"``, ``"labels"``) and their dtypes.
    fractions : (int, numpy.dtype) or None
        The labels' coverage fractions: how many labels, and the dtype.
    label_table : list of dict or None
        With labels: one entry per label value (see :func:`geovox.labels.table`);
        a slab run fills its counts in before the writer closes.
    mesh_space : (str, str) or None
        On a reference grid: the mesh's frame (``"LPS"`` or ``"RAS"``) and how
        it was decided; a point cloud's coordinates are in it.
    band : float or None
        With a distance: its band's half-width in voxels (``inf``: exact everywhere).
    unsigned : bool
        With a distance: it is unsigned (not negative inside).
    """

    grid: Grid
    backend: str = ""
    source: str = "<mesh>"
    colors: bool = False
    fields: dict = field(default_factory=dict)
    fractions: tuple | None = None
    label_table: list | None = None
    mesh_space: tuple | None = None
    band: float | None = None
    unsigned: bool = False

    @classmethod
    def of(cls, volume) -> "Meta":
        """The layout of a whole :class:`~geovox.volume.Volume`."""
        fields = {name: getattr(volume, name).dtype for name in ("density", "sdf", "labels")
                  if getattr(volume, name, None) is not None}
        fr = getattr(volume, "fractions", None)
        return cls(grid=volume.grid, backend=volume.backend, source=volume.source,
                   colors=volume.colors is not None, fields=fields,
                   fractions=None if fr is None else (fr.shape[3], fr.dtype),
                   label_table=getattr(volume, "label_table", None),
                   mesh_space=getattr(volume, "mesh_space", None),
                   band=getattr(volume, "band", None) if fields.get("sdf") is not None else None,
                   unsigned=bool(getattr(volume, "unsigned", False)))

    def dtype(self, name):
        """The dtype of scalar field ``name`` (``"density"``, ``"sdf"``, ``"labels"``), or None."""
        return self.fields.get(name)

    @property
    def shape(self) -> tuple:
        """``(nx, ny, nz)``."""
        return tuple(self.grid.shape)

    @property
    def spacing(self) -> tuple:
        """``(dx, dy, dz)``."""
        return tuple(float(x) for x in self.grid.spacing)

    @property
    def bounds(self) -> tuple:
        """``((xmin, ymin, zmin), (xmax, ymax, zmax))``."""
        return (tuple(float(x) for x in self.grid.lo), tuple(float(x) for x in self.grid.hi))


def as_meta(meta_or_volume) -> Meta:
    """A :class:`Meta`, or the one of a whole volume (what a slab writer is made from)."""
    return meta_or_volume if isinstance(meta_or_volume, Meta) else Meta.of(meta_or_volume)


def check_writable(path) -> None:
    """Fail early, before any work, if ``path``'s folder cannot take the file."""
    folder = os.path.dirname(os.path.abspath(os.fspath(path)))
    if not os.path.isdir(folder):
        raise OutputError(f"output folder does not exist: {folder}")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError(f"output folder is not writable: {folder}")
    fmt = match(path)
    if os.path.isdir(os.fspath(path)) and not (
            # A folder format's output: an existing one is replaced only once the new one is whole.
            fmt is not None and fmt.can.folder
            and os.path.isfile(os.path.join(os.fspath(path), fmt.can.root_file))):
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


def level_set_background(meta, sdf=None):
    """The level set's background: the band's clamped distance, ``band * min(spacing)``.

    Known before any voxel is made (so a slab writer pads with it) where the
    band is finite; otherwise (``band = inf``, or a volume that does not say)
    the largest distance of ``sdf``, 1 for an empty one.
    """
    band = getattr(meta, "band", None)
    if band is not None and np.isfinite(band):
        return np.float32(band * float(np.min(meta.spacing)))
    return np.float32(np.abs(sdf).max()) if sdf is not None and sdf.size else np.float32(1.0)


def point_voxels(volume) -> np.ndarray:
    """(nx * ny * nz,) bool, F order: the voxels a point format writes.

    The occupied voxels; with a distance also those of its exact band
    (``|sdf|`` below the background of :func:`level_set_background`), so a
    sparse file carries every exact distance, each point flagged
    ``occupied`` or not.
    """
    occ = volume.occupancy.reshape(-1, order="F")
    sdf = getattr(volume, "sdf", None)
    if sdf is None:
        return occ
    bg = level_set_background(as_meta(volume) if not isinstance(volume, Meta) else volume, sdf)
    return occ | (np.abs(sdf.reshape(-1, order="F")) < bg)


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


__all__ = ["FIELD_VALUES", "Meta", "as_meta", "SlabWriter", "atomic_output", "atomic_outputs",
           "check_writable", "label_table_json", "scalar_fields", "table_from_json"]
