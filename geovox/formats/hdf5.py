"""HDF5: plain datasets for NumPy users plus a VTK-HDF ImageData group for ParaView.

``/occupancy`` ([x, y, z], uint8 0/1) and ``/color`` ([x, y, z, c], RGBA) are
what h5py users read. ``/VTKHDF`` holds the same data as VTK expects it
(``Type = "ImageData"``, ``Version``, ``WholeExtent``, ``Origin`` = centre of
voxel 0, ``Spacing``, ``Direction``; point data shaped ``(nz, ny, nx[, 4])``,
x fastest), so ParaView 5.11+ opens the file itself and volume-renders the
4-component uint8 colour directly. Both are gzip-compressed; the binary
occupancy compresses to a small fraction, so keeping two layouts costs little.
"""

from __future__ import annotations

import os

import numpy as np

#: gzip level of every dataset.
LEVEL = 4


def _dataset(f, name, shape, dtype, chunks):
    return f.create_dataset(name, shape=shape, dtype=dtype, chunks=chunks, compression="gzip",
                            compression_opts=LEVEL, fillvalue=0)


def _fill(dset, array, transpose=False, jobs=2):
    """Write ``array`` ([x, y, z(, c)]) into ``dset`` chunk by chunk (see chunks.py).

    With ``transpose`` the dataset is (z, y, x(, c)): VTK's order.
    """
    from .chunks import write_blocks

    chunks = dset.chunks
    if transpose:
        src = array.transpose((2, 1, 0) + tuple(range(3, array.ndim)))
    else:
        src = array

    def block(index):
        return src[tuple(slice(i * c, (i + 1) * c) for i, c in zip(index, chunks))]

    write_blocks(dset, block, level=LEVEL, jobs=jobs)


def write_hdf5(volume, path, jobs: int = 2) -> list:
    """Write the volume to an HDF5 file.

    The dataset ``occupancy`` has shape ``(nx, ny, nz)`` and is indexed
    ``[x, y, z]`` as in the library (h5py reads it back unchanged), with
    attributes ``spacing``, ``bounds`` (2 x 3), ``shape``, ``axis_order``,
    ``backend`` and ``source``.
    """
    import h5py

    from . import atomic_output, scalar_fields

    path = os.fspath(path)
    occ = volume.occupancy.view(np.uint8)
    chunks = tuple(min(64, n) for n in occ.shape)
    with atomic_output(path) as tmp:
        with h5py.File(tmp, "w") as f:
            d = _dataset(f, "occupancy", occ.shape, np.uint8, chunks)
            _fill(d, occ, jobs=jobs)
            if volume.colors is not None:
                c = _dataset(f, "color", occ.shape + (4,), np.uint8, chunks + (4,))
                _fill(c, volume.colors, jobs=jobs)
                c.attrs["components"] = "RGBA"
                c.attrs["axis_order"] = "xyzc"
            for name, arr, dtype, values in scalar_fields(volume):
                field = _dataset(f, name, occ.shape, dtype, chunks)
                _fill(field, arr, jobs=jobs)
                field.attrs["values"] = values
                field.attrs["axis_order"] = "xyz"
            _write_vtkhdf(f, volume, chunks, jobs)
            lo, hi = volume.bounds
            attrs = {
                "spacing": np.asarray(volume.spacing, dtype=np.float64),
                "bounds": np.asarray([lo, hi], dtype=np.float64),
                "shape": np.asarray(volume.shape, dtype=np.int64),
                "axis_order": "xyz",
                "values": "0 outside, 1 inside",
                "backend": volume.backend,
                "source": str(volume.source),
            }
            for key, value in attrs.items():
                d.attrs[key] = value
                f.attrs[key] = value
    return [path]


def _write_vtkhdf(f, volume, chunks, jobs=2) -> None:
    """The VTK-HDF ImageData group (point data at voxel centres)."""
    from . import scalar_fields
    from .headers import origin_of

    nx, ny, nz = volume.shape
    g = f.create_group("VTKHDF")
    g.attrs["Version"] = np.array([2, 1], dtype=np.int64)
    # VTK requires a fixed-length ASCII string here, not a variable-length one.
    g.attrs.create("Type", np.bytes_("ImageData"))
    g.attrs["WholeExtent"] = np.array([0, nx - 1, 0, ny - 1, 0, nz - 1], dtype=np.int64)
    g.attrs["Origin"] = origin_of(volume).astype(np.float64)
    g.attrs["Spacing"] = np.asarray(volume.spacing, dtype=np.float64)
    g.attrs["Direction"] = np.eye(3).reshape(-1)
    pd = g.create_group("PointData")
    zyx = chunks[::-1]
    shape = (nz, ny, nx)
    _fill(_dataset(pd, "occupancy", shape, np.uint8, zyx), volume.occupancy.view(np.uint8),
          transpose=True, jobs=jobs)
    if volume.colors is not None:
        _fill(_dataset(pd, "color", shape + (4,), np.uint8, zyx + (4,)), volume.colors,
              transpose=True, jobs=jobs)
    for name, arr, dtype, _ in scalar_fields(volume):
        _fill(_dataset(pd, name, shape, dtype, zyx), arr, transpose=True, jobs=jobs)


def read_hdf5(path):
    """A Volume from a file written by :func:`write_hdf5`."""
    import h5py

    from ..grid import Grid
    from ..pipeline import Volume

    with h5py.File(path, "r") as f:
        d = f["occupancy"]
        occ = np.asfortranarray(d[...] > 0)
        bounds = np.asarray(d.attrs["bounds"], dtype=np.float64)
        colors = None
        if "color" in f:
            base = np.zeros((occ.shape[2], occ.shape[1], occ.shape[0], 4), dtype=np.uint8)
            base[...] = f["color"][...].transpose(2, 1, 0, 3)
            colors = base.transpose(2, 1, 0, 3)
        extra = {name: np.asfortranarray(f[name][...]) for name in ("density", "sdf") if name in f}
        return Volume(occupancy=occ, grid=Grid(bounds[0], bounds[1], occ.shape),
                      backend=str(d.attrs.get("backend", "?")),
                      source=str(d.attrs.get("source", path)), colors=colors, **extra)
