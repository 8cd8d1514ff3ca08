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

from .base import FIELD_VALUES, SlabWriter, as_meta, atomic_outputs, label_table_json, table_from_json


def _dataset(f, name, shape, dtype, chunks):
    # Chunks arrive compressed (formats.chunks); the level given here only
    # labels the filter, which readers ignore when decompressing.
    from .chunks import LEVEL

    return f.create_dataset(name, shape=shape, dtype=dtype, chunks=chunks, compression="gzip",
                            compression_opts=LEVEL, fillvalue=0)


class HDF5Writer(SlabWriter):
    """Writes a volume into a new HDF5 file, whole or one z-slab at a time.

    ``meta`` is the :class:`~geovox.formats.base.Meta` of the whole volume
    (or the volume itself, written whole). Slabs must start on multiples of 64 voxels in z (the chunk size), and
    the file appears only on :meth:`close`.
    """

    def __init__(self, path, meta, jobs: int = 2):
        import h5py

        meta = as_meta(meta)
        self.path, self.meta, self.jobs = os.fspath(path), meta, jobs
        self._ctx = atomic_outputs()
        self.f = None
        try:
            self.f = h5py.File(self._ctx.__enter__().add(self.path), "w")
            self._layout(meta)
        except BaseException:
            self.abort()
            raise

    def _layout(self, meta) -> None:
        from .headers import frame_of

        nx, ny, nz = meta.shape
        self.chunks = tuple(min(64, n) for n in meta.shape)
        zyx = self.chunks[::-1]
        f = self.f
        self.sets = {"occupancy": _dataset(f, "occupancy", meta.shape, np.uint8, self.chunks)}
        g = f.create_group("VTKHDF")
        g.attrs["Version"] = np.array([1, 0], dtype=np.int64)  # what ParaView 5.10+ reads silently
        # VTK requires a fixed-length ASCII string here, not a variable-length one.
        g.attrs.create("Type", np.bytes_("ImageData"))
        g.attrs["WholeExtent"] = np.array([0, nx - 1, 0, ny - 1, 0, nz - 1], dtype=np.int64)
        origin, spacing, direction, space = frame_of(meta)
        g.attrs["Origin"] = np.asarray(origin, dtype=np.float64)
        g.attrs["Spacing"] = np.asarray(spacing, dtype=np.float64)
        g.attrs["Direction"] = (np.eye(3) if direction is None else direction).reshape(-1)
        pd = g.create_group("PointData")
        self.vtk = {"occupancy": _dataset(pd, "occupancy", (nz, ny, nx), np.uint8, zyx)}
        if meta.colors:
            c = _dataset(f, "color", meta.shape + (4,), np.uint8, self.chunks + (4,))
            c.attrs["components"] = "RGBA"
            c.attrs["axis_order"] = "xyzc"
            self.sets["color"] = c
            self.vtk["color"] = _dataset(pd, "color", (nz, ny, nx, 4), np.uint8, zyx + (4,))
        for name in ("density", "sdf", "labels"):
            dtype = meta.dtype(name)
            if dtype is not None:
                d = _dataset(f, name, meta.shape, dtype, self.chunks)
                d.attrs["values"] = FIELD_VALUES[name](dtype)
                d.attrs["axis_order"] = "xyz"
                self.sets[name] = d
                self.vtk[name] = _dataset(pd, name, (nz, ny, nx), dtype, zyx)
        self.fractions = None
        if meta.fractions is not None:
            # One 64³ chunk per label and block of voxels, so that a slab fills whole chunks.
            n, dtype = meta.fractions
            d = f.create_dataset("fractions", shape=meta.shape + (n,), dtype=dtype,
                                 chunks=self.chunks + (1,), compression="gzip",
                                 compression_opts=1, fillvalue=0)
            d.attrs["axis_order"] = "xyzl"
            d.attrs["values"] = ("fraction of the voxel per label (index k: label k + 1), "
                                 + ("x 255" if dtype == np.uint8 else "0 to 1"))
            self.fractions = d

    def write(self, z0: int, vol) -> None:
        """Write ``vol`` (a Volume covering z0 .. z0 + its depth) into place."""
        from .chunks import write_both

        arrays = {"occupancy": vol.occupancy.view(np.uint8), "color": vol.colors,
                  "density": vol.density, "sdf": vol.sdf, "labels": vol.labels}
        for name, dset in self.sets.items():
            arr = arrays[name]
            # VTK's (z, y, x) order is the arrays' memory order (x fastest).
            src = arr.transpose((2, 1, 0) + tuple(range(3, arr.ndim)))
            write_both(src, self.vtk[name], dset, z0=z0, jobs=self.jobs)
        if self.fractions is not None:
            fr = vol.fractions
            for k in range(fr.shape[3]):  # one label at a time: a slab's copy of one label
                self.fractions[:, :, z0:z0 + fr.shape[2], k] = fr[..., k]

    def _finish(self) -> list:
        meta = self.meta
        lo, hi = meta.bounds
        attrs = {"spacing": np.asarray(meta.spacing, dtype=np.float64),
                 "bounds": np.asarray([lo, hi], dtype=np.float64),
                 "shape": np.asarray(meta.shape, dtype=np.int64), "axis_order": "xyz",
                 "values": "0 outside, 1 inside", "backend": meta.backend, "source": str(meta.source)}
        from .headers import frame_metadata

        ref = frame_metadata(meta)
        if ref:  # a reference grid: index of a voxel centre -> world, in `space`
            attrs["affine"] = np.asarray(ref["affine"], dtype=np.float64)
            attrs["space"] = ref["space"]
        for key, value in attrs.items():
            self.sets["occupancy"].attrs[key] = value
            self.f.attrs[key] = value
        if "labels" in self.sets and meta.label_table:
            self.sets["labels"].attrs["label_table"] = label_table_json(meta)
            self.f.attrs["label_table"] = label_table_json(meta)
        self.f.close()
        self._ctx.__exit__(None, None, None)
        return [self.path]

    def _release(self) -> None:
        if self.f is not None:
            self.f.close()


def write_hdf5(volume, path, jobs: int = 2) -> list:
    """Write the volume to an HDF5 file.

    The dataset ``occupancy`` has shape ``(nx, ny, nz)`` and is indexed
    ``[x, y, z]`` as in the library (h5py reads it back unchanged), with
    attributes ``spacing``, ``bounds`` (2 x 3), ``shape``, ``axis_order``,
    ``backend`` and ``source``; ``color``, ``density`` and ``sdf`` likewise
    when the volume has them, and the ``/VTKHDF`` group.
    """
    return HDF5Writer(path, volume, jobs).write_whole(volume)


def read_hdf5(path):
    """A Volume from a file written by :func:`write_hdf5`."""
    import h5py

    from ..grid import Grid
    from ..volume import Volume

    with h5py.File(path, "r") as f:
        d = f["occupancy"]
        occ = np.asfortranarray(d[...] > 0)
        bounds = np.asarray(d.attrs["bounds"], dtype=np.float64)
        colors = None
        if "color" in f:
            base = np.zeros((occ.shape[2], occ.shape[1], occ.shape[0], 4), dtype=np.uint8)
            base[...] = f["color"][...].transpose(2, 1, 0, 3)
            colors = base.transpose(2, 1, 0, 3)
        extra = {name: np.asfortranarray(f[name][...])
                 for name in ("density", "sdf", "labels", "fractions") if name in f}
        if "labels" in f and "label_table" in f["labels"].attrs:
            extra["label_table"] = table_from_json(f["labels"].attrs["label_table"])
        return Volume(occupancy=occ, grid=Grid(bounds[0], bounds[1], occ.shape),
                      backend=str(d.attrs.get("backend", "?")),
                      source=str(d.attrs.get("source", path)), colors=colors, **extra)
