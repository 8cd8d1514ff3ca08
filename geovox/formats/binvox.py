"""binvox: the run-length voxel format of ShapeNet, 3D-R2N2 and Occupancy Networks.

The format, as binvox itself defines it (Patrick Min's binvox page)::

    #binvox 1
    dim D D D
    translate tx ty tz      <- the minimum corner of the cube
    scale s                 <- the cube's edge length
    data
    (value, count) byte pairs, count 1..255, over the D³ voxels with y
    fastest, then z, then x

so voxel ``(i, j, k)`` covers ``translate + s * [i, i + 1] / D`` (and so on)
and its centre is ``translate + s * (i + 0.5) / D``. binvox is cubic: the
grid must have cubic voxels. A resolution gives binvox's own ``-d D`` cube
(``geovox.grid.cube_region``: edge = the bounding box's longest side,
``translate`` its minimum corner, or the box centred with ``fit="cube-center"``,
binvox's ``-cb``); a ``voxel_size`` grid with unequal sides is padded with
empty voxels on the high side of the short axes (with a warning).

trimesh's own writer (``trimesh.exchange.binvox.export_binvox``) and loader
read ``translate`` as the centre of voxel 0 and ``scale`` as the pitch ×
(D − 1); files geovox writes follow binvox's definition instead, so trimesh
places them half a voxel off and slightly scaled (the occupancy is the same).
"""

from __future__ import annotations

import os

import numpy as np

#: Voxels run-length encoded per step (whole x-planes), which bounds the extra memory.
SLAB_VOXELS = 1 << 24


def header(dim: int, translate, scale: float) -> bytes:
    """The text header, up to and including the ``data`` line."""
    tx, ty, tz = (repr(float(v)) for v in translate)
    return (f"#binvox 1\ndim {dim} {dim} {dim}\ntranslate {tx} {ty} {tz}\n"
            f"scale {float(scale)!r}\ndata\n").encode()


def run_lengths(flat: np.ndarray) -> np.ndarray:
    """binvox's (value, count) byte pairs for a flat uint8 0/1 array.

    Parameters
    ----------
    flat : (n,) uint8

    Returns
    -------
    (2 * runs,) uint8: value, count, value, count, ... with every count 1..255.
    """
    n = flat.size
    if n == 0:
        return np.zeros(0, np.uint8)
    starts = np.concatenate(([0], np.flatnonzero(flat[1:] != flat[:-1]) + 1))
    lengths = np.diff(np.append(starts, n))
    # A run longer than 255 becomes several pairs: 255, 255, ..., the rest.
    pieces = -(-lengths // 255)
    last = np.cumsum(pieces) - 1
    counts = np.full(int(pieces.sum()), 255, dtype=np.int64)
    counts[last] = lengths - 255 * (pieces - 1)
    out = np.empty((counts.size, 2), dtype=np.uint8)
    out[:, 0] = np.repeat(flat[starts], pieces)
    out[:, 1] = counts
    return out.reshape(-1)


def check_grid(grid) -> None:
    """Refuse, before any work, a grid whose voxels are not cubic (binvox has one scale).

    ``grid`` is anything with ``spacing`` (a Grid or a Volume).

    Raises
    ------
    ParameterError
    """
    from ..errors import ParameterError

    spacing = np.asarray(grid.spacing, dtype=np.float64)
    if not np.allclose(spacing, spacing[0], rtol=1e-6, atol=0.0):
        dx, dy, dz = spacing
        raise ParameterError(
            f"binvox needs cubic voxels, got {dx:.6g} x {dy:.6g} x {dz:.6g}: use -r N for "
            f"binvox's -d N cube (fit=\"cube\") or --voxel-size (voxel_size=), not --shape")


def cube_of(volume):
    """``(dim, translate, scale)`` of the binvox cube holding ``volume``.

    The voxels must be cubic (see :func:`check_grid`).
    """
    check_grid(volume)
    spacing = np.asarray(volume.spacing, dtype=np.float64)
    dim = int(max(volume.shape))
    return dim, np.asarray(volume.bounds[0], dtype=np.float64), float(spacing[0]) * dim


def write_binvox(volume, path) -> list:
    """Write the occupancy as a ``.binvox`` file (see the module docstring)."""
    from ..errors import warn
    from .base import atomic_output

    path = os.fspath(path)
    dim, translate, scale = cube_of(volume)
    nx, ny, nz = volume.shape
    if (nx, ny, nz) != (dim, dim, dim):
        warn(f"binvox is cubic: the {nx} x {ny} x {nz} grid is padded with empty voxels "
             f"to {dim}³ on the high side of each shorter axis", stacklevel=3)
    occ = volume.occupancy.view(np.uint8)
    per = max(1, SLAB_VOXELS // (dim * dim))
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(header(dim, translate, scale))
            for x0 in range(0, dim, per):
                # A block of x-planes, laid out [x, z, y] in C order (y fastest),
                # padded with zeros beyond the grid. Runs are not merged across
                # blocks: a run split in two pairs reads back the same.
                block = np.zeros((min(per, dim - x0), dim, dim), dtype=np.uint8)
                part = occ[x0:x0 + per]
                block[:part.shape[0], :nz, :ny] = part.transpose(0, 2, 1)
                f.write(run_lengths(block.reshape(-1)).tobytes())
    return [path]


def parse(data: bytes):
    """``(occupancy [x, y, z] bool, translate (3,), scale)`` of a binvox file's bytes."""
    end = data.index(b"data\n") + len(b"data\n")
    fields = {}
    for line in data[:end].decode("ascii").splitlines():
        key, _, rest = line.partition(" ")
        fields[key] = rest.split()
    if "#binvox" not in fields:
        raise ValueError("not a binvox file (no '#binvox' line)")
    dims = [int(v) for v in fields["dim"]]
    translate = np.array([float(v) for v in fields.get("translate", [0, 0, 0])])
    scale = float(fields.get("scale", [1])[0])
    pairs = np.frombuffer(data, dtype=np.uint8, offset=end)
    if pairs.size % 2:
        raise ValueError("odd number of bytes in the run-length data")
    flat = np.repeat(pairs[0::2], pairs[1::2])
    if flat.size != np.prod(dims):
        raise ValueError(f"the runs hold {flat.size} voxels, not {np.prod(dims)}")
    # Stored [x, z, y] with y fastest.
    occ = flat.reshape(dims[0], dims[2], dims[1]).transpose(0, 2, 1) > 0
    return occ, translate, scale


def read_binvox(path):
    """A Volume from a binvox file: the whole cube (padding included)."""
    from ..grid import Grid
    from ..volume import Volume

    with open(path, "rb") as f:
        occ, translate, scale = parse(f.read())
    occ = np.asfortranarray(occ)
    hi = translate + scale * np.asarray(occ.shape, dtype=np.float64) / max(occ.shape)
    return Volume(occupancy=occ, grid=Grid(translate, hi, occ.shape), backend="?",
                  source=os.fspath(path))
