"""Headerless RAW (x fastest) with a JSON sidecar that says how to read it."""

from __future__ import annotations

import json
import os

import numpy as np

from .base import FIELD_VALUES, SlabWriter, as_meta, atomic_outputs

#: Voxels converted per slab, which bounds the extra memory of writing: 1 MB
#: of 0/255 bytes at a time (1 << 24 made a 256³ volume's whole second copy,
#: the peak of a short conversion; the pieces give the same bytes).
SLAB_VOXELS = 1 << 20


def metadata(volume, data_file: str, dtype: str = "uint8", values: str = "0 outside, 255 inside") -> dict:
    """Everything a reader needs to interpret the RAW file, as plain JSON types."""
    nx, ny, nz = volume.shape
    lo, hi = volume.bounds
    return {
        "data_file": os.path.basename(data_file),
        "shape": [nx, ny, nz],
        "dtype": dtype,
        "byte_order": "little" if np.dtype(dtype).itemsize > 1 else "n/a",
        "axis_order": "x fastest, then y, then z (Fortran order of a [x, y, z] array)",
        "values": values,
        "spacing": list(volume.spacing),
        "bounds": [list(lo), list(hi)],
        "origin_of_first_voxel_centre": [lo[a] + 0.5 * volume.spacing[a] for a in range(3)],
        "backend": volume.backend,
        "source": volume.source,
        "numpy": (f"np.fromfile({os.path.basename(data_file)!r}, dtype=np.{dtype})"
                  f".reshape(({nx}, {ny}, {nz}), order='F')"),
        **_reference_metadata(volume),
    }


def _reference_metadata(volume) -> dict:
    """On a reference grid: the world placement (``affine``, ``space``, its origin; bounds of
    the voxels' corners, axis-aligned in that space), replacing the local frame's."""
    from .headers import frame_metadata

    extra = frame_metadata(volume)
    if extra:
        a = np.asarray(extra["affine"])
        corners = np.array([[i, j, k, 1.0] for i in (-0.5, volume.shape[0] - 0.5)
                            for j in (-0.5, volume.shape[1] - 0.5)
                            for k in (-0.5, volume.shape[2] - 0.5)]) @ a.T
        extra["origin_of_first_voxel_centre"] = a[:3, 3].tolist()
        extra["bounds"] = [corners[:, :3].min(axis=0).tolist(), corners[:, :3].max(axis=0).tolist()]
    return extra


def colour_path(path: str) -> str:
    """Where the RGBA file goes beside an occupancy RAW file."""
    return field_path(path, "rgba")


def field_path(path: str, name: str) -> str:
    """Where the file of an extra field (``rgba``, ``density``, ``sdf``) goes."""
    root, ext = os.path.splitext(path)
    return f"{root}_{name}{ext}"


def _write_text(group, path: str, text: str) -> None:
    with open(group.add(path), "w") as f:
        f.write(text)


def _write_headers(group, volume, path: str, dtype: str, components: int = 1) -> list:
    """.mhd and .nhdr headers beside a RAW file, pointing at it."""
    from .headers import frame_of, mhd_header, nhdr_header

    root = os.path.splitext(path)[0]
    name = os.path.basename(path)
    origin, spacing, direction, space = frame_of(volume, "LPS")  # ITK's frame is LPS
    _write_text(group, root + ".mhd", mhd_header(volume.shape, spacing, origin, dtype, name,
                                                 components, direction=direction))
    origin, spacing, direction, space = frame_of(volume)
    _write_text(group, root + ".nhdr", nhdr_header(volume.shape, spacing, origin, dtype, name,
                                                   components, direction=direction, space=space))
    return [root + ".mhd", root + ".nhdr"]


class RawWriter(SlabWriter):
    """Writes a volume as RAW files, whole or one z-slab at a time (z slabs are
    contiguous in x-fastest files, so each is appended). Headers and the
    sidecar are written on :meth:`close`, when every file appears at once.

    ``meta`` is as for :class:`geovox.formats.hdf5.HDF5Writer`.
    """

    def __init__(self, path, meta, jobs: int = 1):
        meta = as_meta(meta)
        self.path, self.meta = os.fspath(path), meta
        self._ctx = atomic_outputs()
        self.group = self._ctx.__enter__()
        self.names = {"occupancy": self.path}
        if meta.colors:
            self.names["color"] = colour_path(self.path)
        for name in ("density", "sdf", "labels"):
            if meta.dtype(name) is not None:
                self.names[name] = field_path(self.path, name)
        if meta.fractions is not None:
            self.names["fractions"] = field_path(self.path, "fractions")
        self.files = {k: open(self.group.add(p), "wb") for k, p in self.names.items()}

    def write(self, z0: int, vol) -> None:
        """Append ``vol`` (the next slab in z), a bounded number of voxels at a time."""
        nx, ny, nz = vol.shape
        per = max(1, SLAB_VOXELS // max(1, nx * ny))
        for a in range(0, nz, per):
            sl = slice(a, a + per)
            # Transposed, a Fortran-ordered [x, y, z] slab is C-ordered (z, y, x):
            # its bytes are x fastest.
            occ = vol.occupancy[:, :, sl]
            self.files["occupancy"].write((occ.T.view(np.uint8) * np.uint8(255)).data)
            if "color" in self.files and vol.colors is not None:
                self.files["color"].write(
                    np.ascontiguousarray(vol.colors[:, :, sl].transpose(2, 1, 0, 3)).data)
            for name in ("density", "sdf", "labels"):
                if name in self.files:
                    arr = getattr(vol, name)[:, :, sl]
                    self.files[name].write(
                        np.ascontiguousarray(arr.T, dtype=arr.dtype.newbyteorder("<")).data)
            if "fractions" in self.files:
                # The labels' fractions interleaved per voxel (as RGBA is), x fastest.
                arr = vol.fractions[:, :, sl]
                self.files["fractions"].write(np.ascontiguousarray(
                    arr.transpose(2, 1, 0, 3), dtype=arr.dtype.newbyteorder("<")).data)

    def write_colours(self, z: int, rgba: np.ndarray) -> None:
        """Put layers ``z ..`` of the colours in place, from any thread.

        For a slab whose ``colors`` is None in :meth:`write` (handed over
        chunk by chunk instead; see :func:`geovox.colour.colour_volume`).

        Parameters
        ----------
        z : int
            The first layer, in the whole grid.
        rgba : (t, ny, nx, 4) uint8, C order
        """
        nx, ny, _ = self.meta.shape
        fd = self.files["color"].fileno()
        data = memoryview(rgba).cast("B")
        offset = z * nx * ny * 4
        while len(data):  # a regular file takes it whole; loop in case it does not
            n = os.pwrite(fd, data, offset)
            data, offset = data[n:], offset + n

    def _finish(self) -> list:
        for fh in self.files.values():
            fh.close()
        meta = self.meta
        nx, ny, nz = meta.shape
        info = metadata(meta, self.path)
        written = [self.path] + _write_headers(self.group, meta, self.path, "uint8")
        if "color" in self.names:
            cpath = self.names["color"]
            written += [cpath] + _write_headers(self.group, meta, cpath, "uint8", components=4)
            info["color"] = {
                "data_file": os.path.basename(cpath),
                "dtype": "uint8",
                "components": 4,
                "layout": "RGBA interleaved per voxel, x fastest, then y, then z",
                "values": "alpha 255 inside, 0 outside",
                "numpy": (f"np.fromfile({os.path.basename(cpath)!r}, dtype=np.uint8)"
                          f".reshape(({nz}, {ny}, {nx}, 4)).transpose(2, 1, 0, 3)"),
            }
        for name in ("density", "sdf", "labels"):
            if name in self.names:
                dtype = str(meta.dtype(name))
                fpath = self.names[name]
                written += [fpath] + _write_headers(self.group, meta, fpath, dtype)
                info[name] = {"data_file": os.path.basename(fpath), "dtype": dtype,
                              "byte_order": "little", "values": FIELD_VALUES[name](dtype),
                              "numpy": (f"np.fromfile({os.path.basename(fpath)!r}, dtype=np.{dtype})"
                                        f".reshape(({nx}, {ny}, {nz}), order='F')")}
        if "fractions" in self.names:
            written += self._fractions_info(info)
        if "labels" in info and meta.label_table:
            info["labels"]["label_table"] = meta.label_table
        sidecar = os.path.splitext(self.path)[0] + ".json"
        with open(self.group.add(sidecar), "w") as fh:
            json.dump(info, fh, indent=2)
            fh.write("\n")
        self._ctx.__exit__(None, None, None)
        return written + [sidecar]

    def _fractions_info(self, info: dict) -> list:
        """The fractions file's headers and its entry in the sidecar; the files written."""
        meta = self.meta
        nx, ny, nz = meta.shape
        n, dtype = meta.fractions
        dtype = str(dtype)
        fpath = self.names["fractions"]
        info["fractions"] = {
            "data_file": os.path.basename(fpath), "dtype": dtype, "components": n,
            "byte_order": "little" if dtype != "uint8" else "n/a",
            "layout": "one value per label interleaved per voxel (index k: label k + 1), "
                      "x fastest, then y, then z",
            "values": "fraction of the voxel per label" + (", x 255" if dtype == "uint8" else
                                                           ", 0 to 1"),
            "numpy": (f"np.fromfile({os.path.basename(fpath)!r}, dtype=np.{dtype})"
                      f".reshape(({nz}, {ny}, {nx}, {n})).transpose(2, 1, 0, 3)")}
        return [fpath] + _write_headers(self.group, meta, fpath, dtype, components=n)

    def _release(self) -> None:
        import contextlib

        for fh in self.files.values():
            with contextlib.suppress(Exception):
                fh.close()


def write_raw(volume, path) -> list:
    """Write occupancy as uint8 0/255, x fastest, and ``<path minus .raw>.json``.

    With colour, ``<name>_rgba.raw`` beside it holds uint8 RGBA interleaved
    per voxel, x fastest (the sidecar names it and says so); density and
    distance go to ``<name>_density.raw`` and ``<name>_sdf.raw``. Every RAW
    file gets a MetaImage ``.mhd`` and a detached NRRD ``.nhdr`` header beside
    it, so ParaView, 3D Slicer and ITK open it with no questions.

    Returns
    -------
    list of str
        Every file written.
    """
    return RawWriter(path, volume).write_whole(volume)


def read_raw_volume(path):
    """A Volume from a RAW file and its JSON sidecar (colour too when present)."""
    from ..grid import Grid
    from ..volume import Volume

    path = os.fspath(path)
    sidecar = os.path.splitext(path)[0] + ".json"
    with open(sidecar) as f:
        meta = json.load(f)
    nx, ny, nz = meta["shape"]
    occ = np.fromfile(path, dtype=np.uint8).reshape((nx, ny, nz), order="F") > 0
    colors = None
    if "color" in meta:
        cfile = os.path.join(os.path.dirname(path), meta["color"]["data_file"])
        colors = np.fromfile(cfile, dtype=np.uint8).reshape(nz, ny, nx, 4).transpose(2, 1, 0, 3)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in meta["bounds"])
    extra = {}
    for name in ("density", "sdf", "labels"):
        if name in meta:
            fpath = os.path.join(os.path.dirname(path), meta[name]["data_file"])
            extra[name] = np.fromfile(fpath, dtype=meta[name]["dtype"]).reshape((nx, ny, nz), order="F")
    if "labels" in meta:
        extra["label_table"] = meta["labels"].get("label_table")
    if "fractions" in meta:
        f = meta["fractions"]
        fpath = os.path.join(os.path.dirname(path), f["data_file"])
        extra["fractions"] = np.fromfile(fpath, dtype=np.dtype(f["dtype"]).newbyteorder("<")) \
            .reshape(nz, ny, nx, f["components"]).transpose(2, 1, 0, 3)
    return Volume(occupancy=np.asfortranarray(occ), grid=Grid(lo, hi, (nx, ny, nz)),
                  backend=meta.get("backend", "?"), source=meta.get("source", path),
                  colors=colors, **extra)
