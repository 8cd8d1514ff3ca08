"""Single-file NRRD through pynrrd: occupancy as uint8 0/255, colour beside it."""

from __future__ import annotations

import os

import numpy as np


def _header(volume, components: int = 1) -> dict:
    from .headers import origin_of

    directions = np.diag(np.asarray(volume.spacing, dtype=np.float64))
    header = {
        "space dimension": 3,
        "space directions": directions,
        "space origin": origin_of(volume),
        "kinds": ["domain", "domain", "domain"],
        "encoding": "gzip",
    }
    if components > 1:
        header["space directions"] = np.vstack([np.full((1, 3), np.nan), directions])
        header["kinds"] = ["RGBA-color"] + header["kinds"]
    return header


def write_nrrd(volume, path) -> list:
    """``NAME.nrrd`` (uint8 0/255, x fastest) and, with colour, ``NAME_rgba.nrrd`` (RGBA)."""
    import nrrd

    from . import atomic_outputs
    from .raw import colour_path

    path = os.fspath(path)
    written = [path]
    with atomic_outputs() as group:
        # pynrrd's default index order 'F' takes an [x, y, z] array.
        nrrd.write(group.add(path), volume.occupancy.view(np.uint8) * np.uint8(255),
                   _header(volume))
        if volume.colors is not None:
            cpath = colour_path(path)
            nrrd.write(group.add(cpath), np.moveaxis(volume.colors, 3, 0),
                       _header(volume, components=4))
            written.append(cpath)
        from . import scalar_fields
        from .raw import field_path

        for name, arr, _, _ in scalar_fields(volume):
            fpath = field_path(path, name)
            nrrd.write(group.add(fpath), np.asfortranarray(arr), _header(volume))
            written.append(fpath)
    return written


def read_nrrd(path):
    """A Volume from a file written by :func:`write_nrrd`."""
    import nrrd

    from ..grid import Grid
    from ..pipeline import Volume
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
    return Volume(occupancy=occ, grid=Grid(lo, lo + spacing * np.asarray(occ.shape), occ.shape),
                  backend="?", source=os.fspath(path), colors=colors, **extra)
