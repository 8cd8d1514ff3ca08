"""Reading back any file geovox writes: a volume, or a header, sidecar or companion of one.

A RAW output is several files (``NAME.raw``, ``NAME.json``, ``NAME.mhd``,
``NAME.nhdr``, and ``NAME_rgba.raw`` / ``_density`` / ``_sdf`` with headers of
their own); an NRRD output is ``NAME.nrrd`` beside ``NAME_rgba.nrrd`` and the
like. Whichever of them is named, :func:`volume_source` finds the file the
volume is read from, so ``geovox preview spot.json`` draws what ``geovox
preview spot.raw`` does.
"""

from __future__ import annotations

import json
import os
import re

import numpy as np

#: Extensions of the headers and sidecars geovox writes beside RAW data.
HEADER_EXTENSIONS = (".json", ".mhd", ".nhdr")

#: Suffixes of the companion files of an extra field (``NAME_rgba.raw``, ...).
COMPANIONS = ("_rgba", "_density", "_sdf")

_MET_DTYPES = {"MET_UCHAR": "uint8", "MET_FLOAT": "float32", "MET_SHORT": "int16",
               "MET_USHORT": "uint16"}


def _sidecar(data_path: str):
    """``(sidecar path, its JSON)`` of the RAW output that ``data_path`` belongs to, or None.

    The data file may be the occupancy (``NAME.raw``, sidecar ``NAME.json``)
    or a companion (``NAME_rgba.raw``), which the sidecar names.
    """
    folder, name = os.path.split(data_path)
    root = os.path.splitext(name)[0]
    roots = [root] + [root[:-len(s)] for s in COMPANIONS if root.endswith(s) and len(root) > len(s)]
    for r in roots:
        path = os.path.join(folder, r + ".json")
        try:
            with open(path) as f:
                meta = json.load(f)
        except (OSError, ValueError):
            continue
        named = [meta.get("data_file")] + [
            (meta.get(k) or {}).get("data_file") for k in ("color", "density", "sdf")
            if isinstance(meta.get(k), dict)]
        if isinstance(meta, dict) and name in named:
            return path, meta
    return None


def _header_data_file(path: str) -> str:
    """The data file a ``.mhd`` (``ElementDataFile``) or ``.nhdr`` (``data file:``) names."""
    with open(path, encoding="latin-1") as f:
        text = f.read(65536)
    key = r"^\s*ElementDataFile\s*=\s*(.+?)\s*$" if path.lower().endswith(".mhd") else \
        r"^\s*data ?file\s*:\s*(.+?)\s*$"
    match = re.search(key, text, re.MULTILINE | re.IGNORECASE)
    if match is None:
        raise ValueError("the header names no data file")
    return os.path.join(os.path.dirname(path), match.group(1))


def volume_source(path):
    """Where the volume that ``path`` belongs to is read from.

    Parameters
    ----------
    path : str or os.PathLike
        Any file geovox writes: a volume (``.raw``, ``.h5``, ``.nrrd``, ...),
        a RAW output's ``.json`` sidecar or ``.mhd`` / ``.nhdr`` header, or
        the companion of an extra field (``NAME_rgba.raw``,
        ``NAME_sdf.nrrd``, ...).

    Returns
    -------
    (str, str)
        ``(file, how)``: ``how`` is a format name of the registry (the file
        is read by its reader), or ``"header"`` (a ``.mhd`` / ``.nhdr``
        without a geovox sidecar, read through the header alone).
    """
    path = os.fspath(path)
    lower = path.lower()
    if lower.endswith(".json"):
        with open(path) as f:
            meta = json.load(f)
        if not (isinstance(meta, dict) and "data_file" in meta and "shape" in meta):
            raise ValueError("not a geovox sidecar (no `data_file` and `shape`)")
        return os.path.join(os.path.dirname(path), meta["data_file"]), "raw"
    if lower.endswith((".mhd", ".nhdr")):
        data = _header_data_file(path)
        found = _sidecar(data)
        if found is None:
            return path, "header"
        return os.path.join(os.path.dirname(found[0]), found[1]["data_file"]), "raw"
    if lower.endswith(".raw"):
        found = _sidecar(path)
        if found is not None:
            return os.path.join(os.path.dirname(found[0]), found[1]["data_file"]), "raw"
        root = os.path.splitext(path)[0]
        for ext in (".mhd", ".nhdr"):
            if os.path.isfile(root + ext):
                return root + ext, "header"
        raise ValueError(f"no sidecar {os.path.basename(root)}.json or header beside it")
    if lower.endswith(".nrrd") and not lower.endswith(".seg.nrrd"):  # a segmentation is whole
        root = os.path.splitext(path)[0]
        for suffix in COMPANIONS:
            main = root[:-len(suffix)] + ".nrrd"
            if root.endswith(suffix) and os.path.isfile(main):
                return main, "nrrd"
        return path, "nrrd"
    from .registry import format_for

    return path, format_for(path).name


def _read_mhd(path: str):
    """``(data, spacing, origin)`` of a MetaImage header and its data, x fastest."""
    fields = {}
    with open(path, encoding="latin-1") as f:
        for line in f:
            key, sep, value = line.partition("=")
            if sep:
                fields[key.strip()] = value.strip()
    shape = [int(v) for v in fields["DimSize"].split()]
    channels = int(fields.get("ElementNumberOfChannels", 1))
    dtype = np.dtype(_MET_DTYPES[fields["ElementType"]]).newbyteorder(
        ">" if fields.get("BinaryDataByteOrderMSB", "False") == "True" else "<")
    if fields.get("CompressedData", "False") == "True":
        raise ValueError("compressed MetaImage data is not read")
    flat = np.fromfile(os.path.join(os.path.dirname(path), fields["ElementDataFile"]), dtype=dtype)
    data = flat.reshape(shape[::-1] + ([channels] if channels > 1 else []))
    data = np.moveaxis(data, [0, 1, 2], [2, 1, 0])  # (z, y, x[, c]) -> (x, y, z[, c])
    spacing = np.array([float(v) for v in fields["ElementSpacing"].split()])
    origin = np.array([float(v) for v in fields["Offset"].split()])
    return data, spacing, origin


def _read_nhdr(path: str):
    """``(data, spacing, origin)`` of a detached NRRD header (pynrrd), x fastest."""
    import nrrd

    data, header = nrrd.read(path)
    if data.ndim == 4:  # (c, x, y, z) -> (x, y, z, c)
        data = np.moveaxis(data, 0, 3)
    # A colour file's first axis has direction "none" (a row of NaN): the last three are space.
    rows = np.asarray(header["space directions"], dtype=np.float64)[-3:]
    spacing = np.abs(np.diag(rows))
    origin = np.asarray(header["space origin"], dtype=np.float64)
    return data, spacing, origin


def read_header_volume(path):
    """A Volume from a ``.mhd`` or ``.nhdr`` header and its RAW data, without a sidecar.

    Four channels are RGBA colours (occupancy from alpha > 0). One channel
    is named by geovox's file names: ``NAME_density`` a coverage density
    (inside where at least half covered), ``NAME_sdf`` a signed distance
    (inside where < 0), anything else occupancy (> 0).
    """
    from ..grid import Grid
    from ..volume import Volume

    path = os.fspath(path)
    data, spacing, origin = (_read_mhd if path.lower().endswith(".mhd") else _read_nhdr)(path)
    root = os.path.splitext(os.path.basename(path))[0]
    extra, colors = {}, None
    if data.ndim == 4:
        colors = np.ascontiguousarray(data.astype(np.uint8))
        occ = colors[..., 3] > 0
    elif root.endswith(("_density", "_sdf")):
        name = root.rsplit("_", 1)[1]
        field = np.asfortranarray(data.astype(data.dtype.newbyteorder("=")))
        extra[name] = field
        half = 0.5 if np.issubdtype(field.dtype, np.floating) else 128  # uint8: fraction x 255
        occ = field < 0 if name == "sdf" else field >= half
    else:
        occ = data > 0
    lo = origin - 0.5 * spacing
    shape = occ.shape
    return Volume(occupancy=np.asfortranarray(occ),
                  grid=Grid(lo, lo + spacing * np.asarray(shape, dtype=np.float64), shape),
                  backend="?", source=path, colors=colors, **extra)
