"""HDF5: dataset ``occupancy`` ([x, y, z], uint8 0/1, chunked, gzip) plus attributes."""

from __future__ import annotations

import os

import numpy as np

#: Voxels converted per slab while writing.
SLAB_VOXELS = 1 << 24


def write_hdf5(volume, path) -> list:
    """Write the volume to an HDF5 file.

    The dataset ``occupancy`` has shape ``(nx, ny, nz)`` and is indexed
    ``[x, y, z]`` as in the library (h5py reads it back unchanged), with
    attributes ``spacing``, ``bounds`` (2 x 3), ``shape``, ``axis_order``,
    ``backend`` and ``source``.
    """
    import h5py

    from . import atomic_output

    path = os.fspath(path)
    occ = volume.occupancy
    nx, ny, nz = occ.shape
    chunks = tuple(min(64, n) for n in occ.shape)
    with atomic_output(path) as tmp:
        with h5py.File(tmp, "w") as f:
            d = f.create_dataset("occupancy", shape=occ.shape, dtype=np.uint8, chunks=chunks,
                                 compression="gzip", compression_opts=4, shuffle=False)
            per = max(1, SLAB_VOXELS // max(1, ny * nz))
            per = max(chunks[0], per // chunks[0] * chunks[0])
            for x0 in range(0, nx, per):
                d[x0:x0 + per] = occ[x0:x0 + per].view(np.uint8)
            if volume.colors is not None:
                c = f.create_dataset("color", shape=occ.shape + (4,), dtype=np.uint8,
                                     chunks=chunks + (4,), compression="gzip",
                                     compression_opts=4)
                for x0 in range(0, nx, per):
                    c[x0:x0 + per] = volume.colors[x0:x0 + per]
                c.attrs["components"] = "RGBA"
                c.attrs["axis_order"] = "xyzc"
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
