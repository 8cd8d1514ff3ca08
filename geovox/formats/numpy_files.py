"""``.npy`` (occupancy only) and ``.npz`` (occupancy, colour and the grid) for NumPy users."""

from __future__ import annotations

import os

import numpy as np


def write_npy(volume, path) -> list:
    """``[x, y, z]`` uint8 0/1 (stored Fortran-ordered, no copy)."""
    from .base import atomic_output

    path = os.fspath(path)
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            np.save(f, volume.occupancy.view(np.uint8))
    return [path]


def packbits_c(occupancy: np.ndarray) -> np.ndarray:
    """``np.packbits(occupancy.ravel(order="C"))``, a few x-planes at a time.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool, any memory order (geovox's is Fortran)

    Returns
    -------
    (ceil(nx * ny * nz / 8),) uint8

    The C order of a Fortran-ordered array is its transpose; copied whole
    that took twice as long as copying 32 x-planes at a time in tiles of 8
    y-rows that stay in cache (measured at 512³). 32 planes hold a whole
    number of bytes of bits, so the pieces concatenate to the same bytes.
    """
    nx, ny, nz = occupancy.shape
    planes, rows = 32, 8
    buf = np.empty((planes, ny, nz), dtype=np.uint8)
    out = []
    for x0 in range(0, nx, planes):
        part = occupancy[x0:x0 + planes].view(np.uint8)
        b = buf[:part.shape[0]]
        for y0 in range(0, ny, rows):
            b[:, y0:y0 + rows] = part[:, y0:y0 + rows]
        out.append(np.packbits(b.reshape(-1)))
    return np.concatenate(out) if out else np.zeros(0, np.uint8)


def write_npz(volume, path, pack_bits: bool = False, sparse: bool = False) -> list:
    """Compressed arrays ``occupancy``, ``colors`` (if any), ``spacing``, ``bounds``, ``origin``.

    With ``pack_bits``, ``occupancy_bits`` and ``shape`` replace ``occupancy``:
    ``np.packbits`` of the ``[x, y, z]`` array raveled in C order (z fastest),
    as Occupancy Networks' data sets store it, so
    ``np.unpackbits(d["occupancy_bits"])[:np.prod(d["shape"])].reshape(d["shape"])``
    is the volume again; one bit per voxel instead of a byte.

    With ``sparse``, the occupied voxels alone: ``coords`` (N, 3) int32, their
    ``[i, j, k]`` in the grid's memory order (x fastest), and beside them the
    per-voxel arrays aligned with it -- ``colors`` (N, 4) uint8, ``labels``
    (N,), ``density`` (N,), ``sdf`` (N,), ``fractions`` (N, L) where made --
    with ``shape``, ``spacing``, ``bounds`` and ``origin`` (the centre of
    voxel 0; on a reference grid ``affine`` maps ``coords`` to the world).
    With a distance, the voxels of its exact band too: ``occupied`` (N,)
    bool says which points are occupied, and ``sdf_background`` is the
    distance of every voxel left out (the band's, ``band * min(spacing)``).
    """
    from .base import atomic_output
    from .headers import origin_of

    if pack_bits and sparse:
        from ..errors import ParameterError

        raise ParameterError("`pack_bits` and `sparse` are two ways to write the occupancy; "
                             "give one")
    path = os.fspath(path)
    if sparse:
        arrays, per_voxel = _sparse(volume)
    else:
        arrays, per_voxel = {}, None
    if sparse:
        pass
    elif pack_bits:
        arrays["occupancy_bits"] = packbits_c(volume.occupancy)
        arrays["shape"] = np.asarray(volume.shape, dtype=np.int64)
    else:
        arrays["occupancy"] = volume.occupancy.view(np.uint8)
    arrays.update({
        "spacing": np.asarray(volume.spacing),
        "bounds": np.asarray(volume.bounds),
        "origin": origin_of(volume),
    })
    from .headers import frame_metadata

    ref = frame_metadata(volume)
    if ref:  # a reference grid: index of a voxel centre -> world, in `space`
        arrays.update(affine=np.asarray(ref["affine"]), space=np.asarray(ref["space"]),
                      origin=np.asarray(ref["affine"])[:3, 3])
    if volume.colors is not None:
        arrays["colors"] = volume.colors
    from .base import scalar_fields

    for name, arr, _, _ in scalar_fields(volume):
        arrays[name] = arr
    if getattr(volume, "fractions", None) is not None:
        arrays["fractions"] = volume.fractions
    if per_voxel is not None:  # sparse: each field at the occupied voxels alone
        for name in ("colors", "density", "sdf", "labels", "fractions"):
            if name in arrays:
                arrays[name] = per_voxel(arrays[name])
    if getattr(volume, "label_table", None):
        from .base import label_table_json

        arrays["label_table"] = np.array(label_table_json(volume))
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return [path]


def _sparse(volume):
    """``({"coords", "shape"}, take)``: the occupied voxels' indices, and a function that
    gives any ``[x, y, z, ...]`` array's values there, in the same order."""
    from .base import as_meta, level_set_background, point_voxels

    occ = volume.occupancy
    nx, ny, _ = occ.shape
    # x fastest: the volume's memory order; with a distance, its band's voxels too.
    idx = np.flatnonzero(point_voxels(volume))
    coords = np.stack([idx % nx, (idx // nx) % ny, idx // (nx * ny)], axis=1).astype(np.int32)

    def take(arr):
        if arr.ndim == 3:
            return arr.reshape(-1, order="F")[idx]
        return arr.reshape(-1, arr.shape[3], order="F")[idx]

    arrays = {"coords": coords, "shape": np.asarray(occ.shape, dtype=np.int64)}
    sdf = getattr(volume, "sdf", None)
    if sdf is not None:
        # Which points are occupied, and the distance of every voxel left out (beyond the band).
        arrays["occupied"] = take(occ)
        arrays["sdf_background"] = np.float32(level_set_background(as_meta(volume), sdf))
    return arrays, take


def read_npz(path):
    from ..grid import Grid
    from ..volume import Volume

    with np.load(path) as z:
        if "coords" in z:
            return _read_sparse(z, os.fspath(path))
        if "occupancy_bits" in z:
            shape = tuple(int(n) for n in z["shape"])
            bits = np.unpackbits(z["occupancy_bits"], count=int(np.prod(shape)))
            occ = np.asfortranarray(bits.reshape(shape) > 0)
        else:
            occ = np.asfortranarray(z["occupancy"] > 0)
        bounds = z["bounds"]
        colors = None
        if "colors" in z:
            c = z["colors"]
            colors = np.ascontiguousarray(c.transpose(2, 1, 0, 3)).transpose(2, 1, 0, 3)
        extra = {name: np.asfortranarray(z[name]) for name in ("density", "sdf", "labels")
                 if name in z}
        if "label_table" in z:
            from .base import table_from_json

            extra["label_table"] = table_from_json(z["label_table"][()])
    return Volume(occupancy=occ, grid=Grid(bounds[0], bounds[1], occ.shape), backend="?",
                  source=os.fspath(path), colors=colors, **extra)


def _read_sparse(z, path):
    """A Volume from a sparse ``.npz`` (:func:`write_npz` with ``sparse``)."""
    from ..grid import Grid
    from ..volume import Volume

    shape = tuple(int(n) for n in z["shape"])
    i, j, k = z["coords"].astype(np.int64).T
    occ = np.zeros(shape, dtype=bool, order="F")
    occ[i, j, k] = z["occupied"] if "occupied" in z else True
    extra = {}
    if "colors" in z:
        colors = np.zeros((shape[2], shape[1], shape[0], 4), np.uint8).transpose(2, 1, 0, 3)
        colors[i, j, k] = z["colors"]
        extra["colors"] = colors
    for name in ("density", "sdf", "labels"):
        if name in z:
            fill = z["sdf_background"] if name == "sdf" and "sdf_background" in z else 0
            arr = np.full(shape, fill, dtype=z[name].dtype, order="F")
            arr[i, j, k] = z[name]
            extra[name] = arr
    if "fractions" in z:
        fr = z["fractions"]
        arr = np.zeros(shape + (fr.shape[1],), dtype=fr.dtype, order="F")
        arr[i, j, k] = fr
        extra["fractions"] = arr
    if "label_table" in z:
        from .base import table_from_json

        extra["label_table"] = table_from_json(z["label_table"][()])
    bounds = z["bounds"]
    return Volume(occupancy=occ, grid=Grid(bounds[0], bounds[1], shape), backend="?",
                  source=path, **extra)


def read_npy(path):
    from ..grid import Grid
    from ..volume import Volume

    occ = np.asfortranarray(np.load(path) > 0)
    return Volume(occupancy=occ, grid=Grid(np.zeros(3), np.asarray(occ.shape, float), occ.shape),
                  backend="?", source=os.fspath(path))
