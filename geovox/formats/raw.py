"""Headerless RAW (x fastest) with a JSON sidecar that says how to read it."""

from __future__ import annotations

import json
import os

import numpy as np

#: Voxels converted per slab, which bounds the extra memory of writing.
SLAB_VOXELS = 1 << 24


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
    }


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
    from .headers import mhd_header, nhdr_header, origin_of

    root = os.path.splitext(path)[0]
    name = os.path.basename(path)
    args = (volume.shape, volume.spacing, origin_of(volume), dtype, name, components)
    _write_text(group, root + ".mhd", mhd_header(*args))
    _write_text(group, root + ".nhdr", nhdr_header(*args))
    return [root + ".mhd", root + ".nhdr"]


def write_raw(volume, path) -> list:
    """Write occupancy as uint8 0/255, x fastest, and ``<path minus .raw>.json``.

    With colour, ``<name>_rgba.raw`` beside it holds uint8 RGBA interleaved
    per voxel, x fastest (the sidecar names it and says so). Every RAW file
    gets a MetaImage ``.mhd`` and a detached NRRD ``.nhdr`` header beside it,
    so ParaView, 3D Slicer and ITK open it with no questions.

    Parameters
    ----------
    volume : Volume
    path : str
        Target ``.raw`` file.

    Returns
    -------
    list of str
        The RAW file and its sidecar.
    """
    from . import atomic_outputs

    path = os.fspath(path)
    occ = volume.occupancy
    nx, ny, nz = occ.shape
    per = max(1, SLAB_VOXELS // max(1, nx * ny))
    # All files appear together or not at all.
    with atomic_outputs() as group:
        with open(group.add(path), "wb") as f:
            for z0 in range(0, nz, per):
                slab = occ[:, :, z0:z0 + per]
                # Transposed, the Fortran-ordered slab is C-contiguous in
                # (z, y, x): its bytes are already x fastest.
                f.write((slab.T.view(np.uint8) * np.uint8(255)).data)
        written = [path] + _write_headers(group, volume, path, "uint8")
        meta = metadata(volume, path)
        if volume.colors is not None:
            cpath = colour_path(path)
            # colors is a [x, y, z, c] view of a C-ordered (z, y, x, c) array:
            # its transpose's bytes are RGBA interleaved with x fastest.
            base = volume.colors.transpose(2, 1, 0, 3)
            with open(group.add(cpath), "wb") as f:
                for z0 in range(0, nz, per):
                    f.write(np.ascontiguousarray(base[z0:z0 + per]).data)
            written += [cpath] + _write_headers(group, volume, cpath, "uint8", components=4)
            meta["color"] = {
                "data_file": os.path.basename(cpath),
                "dtype": "uint8",
                "components": 4,
                "layout": "RGBA interleaved per voxel, x fastest, then y, then z",
                "values": "alpha 255 inside, 0 outside",
                "numpy": (f"np.fromfile({os.path.basename(cpath)!r}, dtype=np.uint8)"
                          f".reshape(({nz}, {ny}, {nx}, 4)).transpose(2, 1, 0, 3)"),
            }
        from . import scalar_fields

        for name, arr, dtype, values in scalar_fields(volume):
            fpath = field_path(path, name)
            with open(group.add(fpath), "wb") as f:
                for z0 in range(0, nz, per):
                    # Little-endian, x fastest (the transposed Fortran slab is C order).
                    f.write(np.ascontiguousarray(arr[:, :, z0:z0 + per].T, dtype=f"<{np.dtype(dtype).str[1:]}").data)
            written += [fpath] + _write_headers(group, volume, fpath, dtype)
            meta[name] = {"data_file": os.path.basename(fpath), "dtype": dtype,
                          "byte_order": "little", "values": values,
                          "numpy": (f"np.fromfile({os.path.basename(fpath)!r}, dtype=np.{dtype})"
                                    f".reshape(({nx}, {ny}, {nz}), order='F')")}
        sidecar = os.path.splitext(path)[0] + ".json"
        with open(group.add(sidecar), "w") as f:
            json.dump(meta, f, indent=2)
            f.write("\n")
    return written + [sidecar]


def read_raw(path) -> np.ndarray:
    """Read a RAW file written by :func:`write_raw` back as a [x, y, z] array."""
    sidecar = os.path.splitext(os.fspath(path))[0] + ".json"
    with open(sidecar) as f:
        meta = json.load(f)
    return np.fromfile(path, dtype=meta["dtype"]).reshape(meta["shape"], order="F")


def read_raw_volume(path):
    """A Volume from a RAW file and its JSON sidecar (colour too when present)."""
    from ..grid import Grid
    from ..pipeline import Volume

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
    for name in ("density", "sdf"):
        if name in meta:
            fpath = os.path.join(os.path.dirname(path), meta[name]["data_file"])
            extra[name] = np.fromfile(fpath, dtype=meta[name]["dtype"]).reshape((nx, ny, nz), order="F")
    return Volume(occupancy=np.asfortranarray(occ), grid=Grid(lo, hi, (nx, ny, nz)),
                  backend=meta.get("backend", "?"), source=meta.get("source", path),
                  colors=colors, **extra)
