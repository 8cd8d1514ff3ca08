"""Small pure functions that build the text headers pointing at RAW data.

The origin written everywhere is the centre of voxel 0 (``lo + spacing/2``):
MetaImage, NRRD and VTK image data place samples at points, and geovox
classifies voxel centres.
"""

from __future__ import annotations

import numpy as np

_MET_TYPES = {"uint8": "MET_UCHAR", "float32": "MET_FLOAT", "int16": "MET_SHORT",
              "uint16": "MET_USHORT"}
_NRRD_TYPES = {"uint8": "uint8", "float32": "float", "int16": "int16", "uint16": "uint16"}


def _num(x) -> str:
    return repr(float(x))


def origin_of(volume) -> np.ndarray:
    """(3,) float64: centre of voxel (0, 0, 0)."""
    return np.asarray(volume.bounds[0]) + 0.5 * np.asarray(volume.spacing)


#: NRRD ``space`` names of the two patient frames.
NRRD_SPACES = {"LPS": "left-posterior-superior", "RAS": "right-anterior-superior"}


def frame_of(volume, space=None) -> tuple:
    """``(origin, spacing, direction, space)`` that place ``volume``'s voxels in the world.

    For a grid over the mesh: the centre of voxel 0, the voxel size, None
    (axes aligned) and None (no patient frame). On a reference grid
    (``like=``): the reference's, its direction cosines (3, 3, columns = index
    axes) in ``space`` ("LPS" or "RAS"; default the reference's own).
    """
    ref = getattr(getattr(volume, "grid", None), "reference", None)
    if ref is None:
        return origin_of(volume), np.asarray(volume.spacing, dtype=np.float64), None, None
    space = space or ref.space
    a = ref.affine_in(space)
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    return a[:3, 3].copy(), spacing, a[:3, :3] / spacing, space


def frame_metadata(volume) -> dict:
    """JSON-ready ``affine`` (index of a voxel centre -> world) and ``space`` on a reference grid, else {}."""
    ref = getattr(getattr(volume, "grid", None), "reference", None)
    if ref is None:
        return {}
    return {"affine": ref.affine.tolist(), "space": ref.space}


def mhd_header(shape, spacing, origin, dtype: str, data_file: str, components: int = 1,
               direction=None) -> str:
    """MetaImage (.mhd) header for an x-fastest RAW file.

    Parameters
    ----------
    shape : (3,) int
        ``(nx, ny, nz)``.
    spacing, origin : (3,) float
    dtype : {"uint8", "float32", "int16", "uint16"}
    data_file : str
        RAW file name, relative to the header.
    components : int
        Values per voxel (4 for RGBA).
    direction : (3, 3) float, optional
        Direction cosines, LPS (columns: the index axes); written as
        ``TransformMatrix`` one axis after another, as ITK reads it.
    """
    matrix = "1 0 0 0 1 0 0 0 1" if direction is None else " ".join(
        _num(v) for v in np.asarray(direction, dtype=np.float64).T.reshape(-1))
    lines = [
        "ObjectType = Image",
        "NDims = 3",
        "BinaryData = True",
        "BinaryDataByteOrderMSB = False",
        "CompressedData = False",
        "TransformMatrix = " + matrix,
        "Offset = " + " ".join(_num(v) for v in origin),
        "CenterOfRotation = 0 0 0",
        "ElementSpacing = " + " ".join(_num(v) for v in spacing),
        "DimSize = " + " ".join(str(int(n)) for n in shape),
    ]
    if components > 1:
        lines.append(f"ElementNumberOfChannels = {components}")
    lines += [f"ElementType = {_MET_TYPES[dtype]}", f"ElementDataFile = {data_file}"]
    return "\n".join(lines) + "\n"


def nhdr_header(shape, spacing, origin, dtype: str, data_file, components: int = 1,
                encoding: str = "raw", direction=None, space=None) -> str:
    """NRRD header for x-fastest data (same parameters as :func:`mhd_header`).

    With ``direction`` (3, 3; columns the index axes) and ``space`` ("LPS"
    or "RAS"), the header says ``space:`` and each axis's direction
    scaled by its spacing (a reference grid); otherwise axis-aligned, with
    no ``space`` line, as before.

    With ``data_file=None`` the header is that of a single-file NRRD (the
    data follows it); ``encoding`` is ``"raw"`` or ``"gzip"``.

    ``sizes`` comes before ``space dimension``: VTK's NRRD reader (through
    9.7 at least) sizes its axis list by the last ``dimension`` or ``space
    dimension`` it has read, so a 4-D colour file whose ``sizes`` follow
    ``space dimension: 3`` loses its z axis there (it opens as one slice).
    NRRD itself allows the fields in any order after ``dimension``.
    """
    if direction is None:
        sx, sy, sz = (_num(v) for v in spacing)
        dirs = f"({sx},0,0) (0,{sy},0) (0,0,{sz})"
    else:
        cols = np.asarray(direction, dtype=np.float64) * np.asarray(spacing, dtype=np.float64)
        dirs = " ".join("(" + ",".join(_num(v) for v in cols[:, a]) + ")" for a in range(3))
    sizes = " ".join(str(int(n)) for n in shape)
    kinds = "domain domain domain"
    dimension = 3
    if components > 1:
        dirs = "none " + dirs
        sizes = f"{components} {sizes}"
        kinds = ("RGBA-color " if components == 4 else "vector ") + kinds
        dimension = 4
    return (
        "NRRD0004\n"
        "# written by geovox\n"
        f"type: {_NRRD_TYPES[dtype]}\n"
        f"dimension: {dimension}\n"
        f"sizes: {sizes}\n"
        + ("space dimension: 3\n" if space is None else f"space: {NRRD_SPACES[space]}\n")
        + f"space directions: {dirs}\n"
        f"kinds: {kinds}\n"
        "endian: little\n"
        f"encoding: {encoding}\n"
        "space origin: (" + ",".join(_num(v) for v in origin) + ")\n"
        + (f"data file: {data_file}\n" if data_file is not None else "\n")
    )


def default_name(stem: str, shape, dtype: str = "uint8", ext: str = ".raw") -> str:
    """File name that carries the dimensions and type: ``spot_128x128x128_uint8.raw``."""
    nx, ny, nz = (int(n) for n in shape)
    return f"{stem}_{nx}x{ny}x{nz}_{dtype}{ext}"
