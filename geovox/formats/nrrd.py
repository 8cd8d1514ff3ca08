"""Single-file NRRD: occupancy as uint8 0/255 (gzip), colour (raw) and fields (gzip) beside it.

The header comes from :func:`geovox.formats.headers.nhdr_header` (the same
one the detached ``.nhdr`` files use), in the field order VTK's reader
needs for the 4-D colour file; pynrrd reads them back.
"""

from __future__ import annotations

import os
import zlib

import numpy as np

#: Voxels compressed per step, which bounds the extra memory of writing.
SLAB_VOXELS = 1 << 24


def _write_one(path, arr, volume, components: int = 1, times: int = 1, keys=None) -> None:
    """One attached NRRD: header, then ``arr`` x fastest.

    ``arr`` is ``(nx, ny, nz)`` or ``(nx, ny, nz, components)``, indexed
    ``[x, y, z]``; its dtype is what is stored, each value multiplied by
    ``times`` slab by slab (occupancy 0/1 is stored 0/255 without a whole
    copy). Single values are gzip-encoded;
    several components per voxel are stored raw, because VTK's NRRD reader
    (ParaView's; through VTK 9.7 at least) inflates only one value per voxel
    of a gzip-encoded file, so a gzip RGBA file opens with three quarters of
    its voxels black.
    """
    from .headers import frame_of, nhdr_header

    encoding = "gzip" if components == 1 else "raw"
    origin, spacing, direction, space = frame_of(volume)
    header = nhdr_header(volume.shape, spacing, origin, str(arr.dtype), None,
                         components=components, encoding=encoding, direction=direction, space=space)
    if keys:  # NRRD key/value pairs ("key:=value"), before the blank line that ends the header
        header = header[:-1] + "".join(f"{k}:={v}\n" for k, v in keys.items()) + "\n"
    nx, ny, nz = volume.shape
    per = max(1, SLAB_VOXELS // max(1, nx * ny))
    # wbits 31: the gzip container, which NRRD's "gzip" encoding names; level 1
    # because binary volumes compress nearly as well at 1 as at 9, many times faster.
    z = zlib.compressobj(1, zlib.DEFLATED, 31) if encoding == "gzip" else None
    with open(path, "wb") as f:
        f.write(header.encode("ascii"))
        for a in range(0, nz, per):
            part = arr[:, :, a:a + per]
            if times != 1:
                part = part * arr.dtype.type(times)
            # x fastest (then components first): the C order of the (z, y, x[, c]) transpose.
            zyx = np.ascontiguousarray(part.transpose((2, 1, 0) + tuple(range(3, arr.ndim))),
                                       dtype=arr.dtype.newbyteorder("<"))
            f.write(z.compress(zyx.data) if z is not None else zyx.data)
        if z is not None:
            f.write(z.flush())


def write_nrrd(volume, path) -> list:
    """``NAME.nrrd`` (uint8 0/255, x fastest) and, with colour, ``NAME_rgba.nrrd`` (RGBA);
    density and distance in ``NAME_density.nrrd`` and ``NAME_sdf.nrrd``."""
    from .base import atomic_outputs, scalar_fields
    from .raw import colour_path, field_path

    path = os.fspath(path)
    written = [path]
    with atomic_outputs() as group:
        _write_one(group.add(path), volume.occupancy.view(np.uint8), volume, times=255)
        if volume.colors is not None:
            cpath = colour_path(path)
            _write_one(group.add(cpath), volume.colors, volume, components=4)
            written.append(cpath)
        for name, arr, _, _ in scalar_fields(volume):
            fpath = field_path(path, name)
            _write_one(group.add(fpath), arr, volume,
                       keys=_label_keys(volume) if name == "labels" else None)
            written.append(fpath)
    return written


def _label_keys(volume) -> dict:
    """The label table as NRRD key/value pairs: one per label, and the whole as JSON."""
    from .base import label_table_json

    keys = {}
    for e in volume.label_table or []:
        name = str(e["name"]).replace("\n", " ")
        keys[f"label{e['value']}"] = f"{name}|{' '.join(str(c) for c in e['color'])}"
    keys["geovox_label_table"] = label_table_json(volume)
    return keys


def read_nrrd(path):
    """A Volume from a file written by :func:`write_nrrd`."""
    import nrrd

    from ..grid import Grid
    from ..volume import Volume
    from .raw import colour_path

    data, header = nrrd.read(os.fspath(path))
    spacing = np.abs(np.diag(np.asarray(header["space directions"], dtype=np.float64)))
    lo = np.asarray(header["space origin"], dtype=np.float64) - 0.5 * spacing
    occ = np.asfortranarray(data > 0)
    colors = None
    cpath = colour_path(os.fspath(path))
    if os.path.exists(cpath):
        c, _ = nrrd.read(cpath)
        colors = np.ascontiguousarray(np.moveaxis(c, 0, 3).transpose(2, 1, 0, 3)).transpose(2, 1, 0, 3)
    from .raw import field_path

    extra = {}
    for name in ("density", "sdf"):
        fpath = field_path(os.fspath(path), name)
        if os.path.exists(fpath):
            extra[name] = np.asfortranarray(nrrd.read(fpath)[0])
    grid = Grid(lo, lo + spacing * np.asarray(occ.shape), occ.shape)
    if "space" in header:  # written onto a reference grid (like=): oblique, perhaps
        from ..reference import load_reference

        grid = load_reference(os.fspath(path)).local_grid()
    lpath = field_path(os.fspath(path), "labels")
    if os.path.exists(lpath):
        from .base import table_from_json

        lab, lheader = nrrd.read(lpath)
        extra["labels"] = np.asfortranarray(lab)
        extra["label_table"] = table_from_json(lheader.get("geovox_label_table", "[]"))
    return Volume(occupancy=occ, grid=grid, backend="?", source=os.fspath(path), colors=colors,
                  **extra)
