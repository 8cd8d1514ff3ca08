"""VTK-HDF ImageData (``.vtkhdf``, ``.hdf``): the file ParaView opens by name.

ParaView picks its VTK-HDF reader by extension only: ``.hdf`` (5.10 on) and
``.vtkhdf`` (5.12 on), never ``.h5``. The reader of ParaView 5.10 and 5.11
supports format version 1.0 and warns on anything newer, and static image
data needs nothing later, so the file says ``Version = [1, 0]``.

Layout (the whole file is the ``/VTKHDF`` group): attributes ``Version``,
``Type = "ImageData"`` (fixed-length ASCII: VTK rejects a variable-length
string), ``WholeExtent`` ``[0, nx-1, 0, ny-1, 0, nz-1]``, ``Origin`` (the
centre of voxel 0: VTK image data samples at points), ``Spacing`` and
``Direction``; ``PointData/occupancy`` (uint8 0/1), ``color`` (RGBA uint8,
4 components), ``density`` and ``sdf`` shaped ``(nz, ny, nx[, 4])``, x
fastest, gzip-compressed in 64³ chunks.
"""

from __future__ import annotations

import os

import numpy as np

from .base import SlabWriter, as_meta, atomic_outputs

#: The oldest VTK-HDF version with image data: what ParaView 5.10+ reads silently.
VERSION = (1, 0)


def image_attributes(shape, spacing, origin, direction=None) -> dict:
    """The ``/VTKHDF`` attributes of an ImageData file.

    Parameters
    ----------
    shape : (3,) int
        ``(nx, ny, nz)``.
    spacing, origin : (3,) float
        Voxel size and the centre of voxel 0.
    direction : (3, 3) float, optional
        Direction cosines (columns: the index axes), stored row by row as
        VTK's ``vtkImageData::DirectionMatrix``; identity by default.

    Returns
    -------
    dict of name -> NumPy value, in the dtypes VTK's reader expects.
    """
    nx, ny, nz = (int(n) for n in shape)
    return {
        "Version": np.array(VERSION, dtype=np.int64),
        "Type": np.bytes_("ImageData"),
        "WholeExtent": np.array([0, nx - 1, 0, ny - 1, 0, nz - 1], dtype=np.int64),
        "Origin": np.asarray(origin, dtype=np.float64),
        "Spacing": np.asarray(spacing, dtype=np.float64),
        "Direction": (np.eye(3) if direction is None
                      else np.asarray(direction, dtype=np.float64)).reshape(-1),
    }


class VTKHDFWriter(SlabWriter):
    """Writes a volume as VTK-HDF image data, whole or one z-slab at a time.

    ``meta`` is as for :class:`geovox.formats.hdf5.HDF5Writer`; slabs start
    on multiples of 64 voxels in z, and the file appears on :meth:`close`.
    """

    def __init__(self, path, meta, jobs: int = 2):
        import h5py

        from .chunks import LEVEL
        from .headers import frame_of

        meta = as_meta(meta)
        self.path, self.jobs = os.fspath(path), jobs
        self._ctx = atomic_outputs()
        self.f = None
        try:
            self.f = h5py.File(self._ctx.__enter__().add(self.path), "w")
            g = self.f.create_group("VTKHDF")
            origin, spacing, direction, space = frame_of(meta)
            for key, value in image_attributes(meta.shape, spacing, origin, direction).items():
                g.attrs[key] = value
            if space is not None:  # a reference grid: its frame, and the affine whole
                g.attrs["space"] = space
                g.attrs["affine"] = meta.grid.reference.affine
            pd = g.create_group("PointData")
            zyx = tuple(min(64, n) for n in meta.shape[::-1])
            fields = {"occupancy": (np.uint8, ())}
            if meta.colors:
                fields["color"] = (np.uint8, (4,))
            for name in ("density", "sdf", "labels"):
                if meta.dtype(name) is not None:
                    fields[name] = (meta.dtype(name), ())
            # Chunks arrive compressed (formats.chunks); the level only labels the filter.
            self.sets = {
                name: pd.create_dataset(name, shape=tuple(meta.shape[::-1]) + tail, dtype=dtype,
                                        chunks=zyx + tail, compression="gzip",
                                        compression_opts=LEVEL, fillvalue=0)
                for name, (dtype, tail) in fields.items()}
            if meta.label_table:
                _label_field_data(g, meta.label_table)
        except BaseException:
            self.abort()
            raise

    def write(self, z0: int, vol) -> None:
        """Write ``vol`` (a Volume covering z0 .. z0 + its depth) into place."""
        from .chunks import write_both

        arrays = {"occupancy": vol.occupancy.view(np.uint8), "color": vol.colors,
                  "density": vol.density, "sdf": vol.sdf, "labels": vol.labels}
        for name, dset in self.sets.items():
            arr = arrays[name]
            # VTK's (z, y, x) order is the arrays' memory order (x fastest): no copy.
            write_both(arr.transpose((2, 1, 0) + tuple(range(3, arr.ndim))), dset, None,
                       z0=z0, jobs=self.jobs)

    def _finish(self) -> list:
        self.f.close()
        self._ctx.__exit__(None, None, None)
        return [self.path]

    def _release(self) -> None:
        if self.f is not None:
            self.f.close()


def _label_field_data(g, table) -> None:
    """The label table as field data: ``label_values``, ``label_names``, ``label_colors``."""
    fd = g.create_group("FieldData")
    fd.create_dataset("label_values", data=np.asarray([e["value"] for e in table], np.int64))
    # VTK's HDF reader (9.x) reads no string datasets: the names are one
    # UTF-8 byte array, each ended by a newline (numeric, so ParaView shows it).
    text = "".join(str(e["name"]).replace("\n", " ") + "\n" for e in table).encode("utf-8")
    fd.create_dataset("label_names", data=np.frombuffer(text, dtype=np.uint8))
    fd.create_dataset("label_colors", data=np.asarray([e["color"] for e in table], np.uint8))


def write_vtkhdf(volume, path, jobs: int = 2) -> list:
    """Write ``volume`` as a VTK-HDF ImageData file (see the module docstring)."""
    return VTKHDFWriter(path, volume, jobs).write_whole(volume)


def read_vtkhdf(path):
    """A Volume from a VTK-HDF ImageData file (geovox's, or any with an ``occupancy`` array)."""
    import h5py

    from ..grid import Grid
    from ..volume import Volume

    with h5py.File(path, "r") as f:
        g = f["VTKHDF"]
        e = np.asarray(g.attrs["WholeExtent"], dtype=np.int64)
        shape = tuple(int(e[2 * a + 1] - e[2 * a] + 1) for a in range(3))
        spacing = np.asarray(g.attrs["Spacing"], dtype=np.float64)
        lo = np.asarray(g.attrs["Origin"], dtype=np.float64) - 0.5 * spacing
        pd = g["PointData"]
        # (z, y, x) C order read back is the [x, y, z] Fortran-ordered array, transposed.
        occ = pd["occupancy"][...].transpose(2, 1, 0) > 0
        colors = pd["color"][...].transpose(2, 1, 0, 3) if "color" in pd else None
        extra = {n: pd[n][...].transpose(2, 1, 0) for n in ("density", "sdf", "labels") if n in pd}
        if "FieldData" in g and "label_names" in g["FieldData"]:
            fd = g["FieldData"]
            names = bytes(fd["label_names"][...]).decode("utf-8").split("\n")[:-1]
            extra["label_table"] = [
                {"value": int(v), "name": n, "color": [int(c) for c in rgba]}
                for v, n, rgba in zip(fd["label_values"][...], names, fd["label_colors"][...])]
    return Volume(occupancy=occ, grid=Grid(lo, lo + spacing * np.asarray(shape), shape),
                  backend="?", source=os.fspath(path), colors=colors, **extra)
