"""``.npy`` (occupancy only) and ``.npz`` (occupancy, colour and the grid) for NumPy users."""

from __future__ import annotations

import os

import numpy as np


def write_npy(volume, path) -> list:
    """``[x, y, z]`` uint8 0/1 (stored Fortran-ordered, no copy)."""
    from . import atomic_output

    path = os.fspath(path)
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, volume.occupancy.view(np.uint8))
    return [path]


def write_npz(volume, path) -> list:
    """Compressed arrays ``occupancy``, ``colors`` (if any), ``spacing``, ``bounds``, ``origin``."""
    from . import atomic_output
    from .headers import origin_of

    path = os.fspath(path)
    arrays = {
        "occupancy": volume.occupancy.view(np.uint8),
        "spacing": np.asarray(volume.spacing),
        "bounds": np.asarray(volume.bounds),
        "origin": origin_of(volume),
    }
    if volume.colors is not None:
        arrays["colors"] = volume.colors
    from . import scalar_fields

    for name, arr, _, _ in scalar_fields(volume):
        arrays[name] = arr
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return [path]


def read_npz(path):
    from ..grid import Grid
    from ..pipeline import Volume

    with np.load(path) as z:
        occ = np.asfortranarray(z["occupancy"] > 0)
        bounds = z["bounds"]
        colors = None
        if "colors" in z:
            c = z["colors"]
            colors = np.ascontiguousarray(c.transpose(2, 1, 0, 3)).transpose(2, 1, 0, 3)
        extra = {name: np.asfortranarray(z[name]) for name in ("density", "sdf") if name in z}
    return Volume(occupancy=occ, grid=Grid(bounds[0], bounds[1], occ.shape), backend="?",
                  source=os.fspath(path), colors=colors, **extra)


def read_npy(path):
    from ..grid import Grid
    from ..pipeline import Volume

    occ = np.asfortranarray(np.load(path) > 0)
    return Volume(occupancy=occ, grid=Grid(np.zeros(3), np.asarray(occ.shape, float), occ.shape),
                  backend="?", source=os.fspath(path))
