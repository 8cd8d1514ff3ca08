"""The registry of output formats: each :class:`Format` with its parts and its abilities.

A format is found by name (``--format``) or by the output's extension. Its
writer, reader and slab writer live in their own modules, imported on first
use; what the format can hold and how it is written (:class:`Abilities`) is
data here, so the plan and the command line ask ``fmt.can.cluster``, never
``fmt.name == "zarr"``.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..errors import ParameterError


@dataclass(frozen=True)
class Abilities:
    """What a format can hold and how it is written (``Format.can``).

    Attributes
    ----------
    labels : bool
        It holds a label volume and its table (``--labels``).
    frame : bool
        It records where a reference grid's voxels lie (``--like``): origin,
        spacing and direction.
    folder : bool
        The output is a folder, complete once ``root_file`` is in it (which
        is written, and uploaded, last).
    root_file : str or None
        With ``folder``: the file whose presence means the output is whole.
    chunk : int or None
        Slabs are laid out in chunks of this many layers: a slab's
        thickness is a multiple of it (and the 64-slice fill, which writes
        its own pieces, does not apply).
    always_streams : bool
        Written slab by slab whatever the grid's size.
    cluster : bool
        Its slabs may run as tasks on a Dask cluster, each writing its own part.
    colour_chunks : bool
        Its slab writer takes fast colour chunk by chunk, from the colour
        step's threads (``write_colours``), so no slab of colours is held.
    points : bool
        It lists the occupied voxels (a point cloud), and its slab writer
        takes a slab as their indices (``write_points``): surface voxels
        alone are then made as bits, never as a byte per voxel.
    """

    labels: bool = True
    frame: bool = True
    folder: bool = False
    root_file: str | None = None
    chunk: int | None = None
    always_streams: bool = False
    cluster: bool = False
    colour_chunks: bool = False
    points: bool = False


#: The parts of a format a :class:`Format` looks up in its module on first use.
_PARTS = ("writer", "reader", "check", "slab_writer", "sniff")


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
    sniff : callable or None
        ``sniff(path) -> bool``: whether a file of this extension is geovox's
        volume, where the extension is also a mesh's (``.ply``); None: the
        extension says.
    can : Abilities
        What the format can hold and how it is written: what the plan and
        the command line read, never the format's name.
    """

    __slots__ = ("name", "extensions", "description", "libraries", "can", "_parts")

    def __init__(self, name, extensions, writer, description="", *, libraries=(), can=None,
                 **parts):
        unknown = set(parts) - set(_PARTS)
        if unknown:
            raise TypeError(f"unknown part of a format: {', '.join(sorted(unknown))}")
        self.name = name
        self.extensions = tuple(e.lower() for e in extensions)
        self.description = description
        self.libraries = tuple(libraries)
        self.can = can if can is not None else Abilities()
        self._parts = {key: parts.get(key) for key in _PARTS}
        self._parts["writer"] = writer

    def _part(self, key):
        ref = self._parts[key]
        if not isinstance(ref, str):
            return ref
        import importlib

        module, attr = ref.split(":")
        return getattr(importlib.import_module("geovox.formats." + module), attr)

    writer = property(lambda self: self._part("writer"))
    reader = property(lambda self: self._part("reader"))
    check = property(lambda self: self._part("check"))
    slab_writer = property(lambda self: self._part("slab_writer"))
    sniff = property(lambda self: self._part("sniff"))

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


def register_format(name, extensions, writer, description="", **parts) -> Format:
    """Register ``writer`` for the given extensions (with dot).

    ``parts`` are :class:`Format`'s keywords: an optional ``reader``, grid
    ``check``, ``slab_writer`` (for slab-by-slab conversions), the
    ``libraries`` it imports (each part a callable or ``"module:attribute"``,
    imported on first use) and what it ``can`` do (:class:`Abilities`).
    """
    _FORMATS[name] = Format(name, extensions, writer, description, **parts)
    return _FORMATS[name]


def formats() -> list:
    """All registered formats.

    Returns
    -------
    list of Format
        In registration order, as ``geovox formats`` prints them.
    """
    return list(_FORMATS.values())


def match(path) -> Format | None:
    """The format whose extension ends ``path``, or None."""
    lower = os.fspath(path).lower()
    for f in _FORMATS.values():
        if any(lower.endswith(ext) for ext in f.extensions):
            return f
    return None


def format_for(path, fmt=None) -> Format:
    """The format named ``fmt``, or the one the extension of ``path`` implies."""
    if fmt is not None:
        if fmt not in _FORMATS:
            raise ParameterError(f"`format` must be one of {', '.join(_FORMATS)}; got {fmt!r}")
        return _FORMATS[fmt]
    found = match(path)
    if found is not None:
        return found
    known = ", ".join(e for f in _FORMATS.values() for e in f.extensions)
    raise ParameterError(
        f"cannot tell the output format from {os.fspath(path)!r}: use one of {known}"
    )


def _slabs(ref: str):
    """The slab writer of a format whose writer class (``"module:Class"``) takes
    ``(path, meta, jobs)``; the class is looked up when a slab writer is made."""
    module, cls = ref.split(":")

    def make(path, meta, jobs, *, thick=None, client=None):
        import importlib

        return getattr(importlib.import_module("geovox.formats." + module), cls)(path, meta, jobs)

    make.__name__ = make.__qualname__ = f"slab_writer_{cls}"
    return make


#: Neither labels nor a reference grid's placement.
_PLAIN = Abilities(labels=False, frame=False)

register_format("raw", (".raw",), "raw:write_raw",
                "headerless uint8 (0/255), x fastest; .json sidecar, .mhd and .nhdr headers",
                reader="raw:read_raw_volume", slab_writer=_slabs("raw:RawWriter"),
                can=Abilities(colour_chunks=True))
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
                reader="numpy_files:read_npy", can=Abilities(labels=False))
register_format("npz", (".npz",), "numpy_files:write_npz",
                "NumPy archive: occupancy (bits with --pack-bits), colors, spacing, bounds, origin",
                reader="numpy_files:read_npz")
register_format("binvox", (".binvox",), "binvox:write_binvox",
                "binvox (ShapeNet, 3D-R2N2, ONet): -r N is binvox -d N (N³ cube over the longest "
                "side; --cube-center: -cb); --voxel-size grids padded to a cube",
                reader="binvox:read_binvox", check="binvox:check_grid", can=_PLAIN)
register_format("vdb", (".vdb",), "vdb:write_vdb",
                "OpenVDB for Blender/Houdini: density (fog), color (vec3s), sdf (level set) "
                "grids; written slab by slab, holding only the trees' leaves",
                reader="vdb:read_vdb", slab_writer=_slabs("vdb:VDBWriter"), can=_PLAIN)
register_format("vox", (".vox",), "vox:write_vox",
                "MagicaVoxel: 256³ models in a scene graph, 255 quantised colours",
                reader="vox:read_vox", libraries=("PIL.Image",), can=Abilities(frame=False))
register_format("zarr", (".zarr",), "zarr:write_zarr",
                "OME-Zarr 0.5 (Zarr v3) multiscale image for napari, neuroglancer, Fiji, WEBKNOSSOS: "
                "occupancy, color, density, sdf; written slab by slab, or on a Dask cluster",
                reader="zarr:read_zarr", slab_writer="zarr:ZarrWriter", libraries=("zarr",),
                can=Abilities(folder=True, root_file="zarr.json", chunk=64, always_streams=True,
                              cluster=True))
register_format("ply", (".ply",), "ply:write_ply",
                "binary PLY point cloud: each occupied voxel's centre in model units, with "
                "red/green/blue and label (Open3D, trimesh, MeshLab, CloudCompare)",
                reader="ply:read_ply", slab_writer=_slabs("ply:PlyWriter"),
                sniff="ply:is_geovox_ply", can=Abilities(points=True))
register_format("nifti", (".nii.gz", ".nii"), "nifti:write_nifti",
                "NIfTI-1 for 3D Slicer, ITK-SNAP, FSL, nibabel: uint8 mask, sform = qform = the "
                "grid's RAS affine (needs nibabel: the nifti extra)",
                reader="nifti:read_nifti", libraries=("nibabel",))

__all__ = ["Abilities", "Format", "format_for", "formats", "match", "register_format"]
