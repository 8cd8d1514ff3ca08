"""The Volume a conversion makes: arrays and the grid they live on.

Its own module so that the writers in :mod:`geovox.formats` can build and
read volumes without importing the pipeline that makes them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .grid import Grid


@dataclass
class Volume:
    """A voxelised mesh.

    Attributes
    ----------
    occupancy : (nx, ny, nz) bool, Fortran order
        True inside. Indexed ``[x, y, z]``; x is fastest in memory, so
        ``occupancy.T.tobytes()`` is the x-fastest byte order of RAW files.
    grid : Grid
        The grid the arrays live on: ``lo``, ``hi`` (3,) float64 and
        ``shape``.
    backend : str
        Name of the backend that ran.
    source : str
        Where the mesh came from (its path, or a description).
    colors : (nx, ny, nz, 4) uint8 or None
        RGBA colour per voxel, when colour was asked for.
    inside : str
        The inside/outside method that ran (``auto`` resolved).
    density : (nx, ny, nz) uint8 or float32, or None
        Coverage: the fraction of each voxel inside the mesh (0-255 as uint8).
    sdf : (nx, ny, nz) float32 or None
        Signed distance from each voxel centre to the surface, negative inside,
        exact within ``band`` voxels and clamped to ``+-band`` voxels beyond.
    timings : dict
        Seconds per stage.
    mesh_space : (str, str) or None
        On a reference grid (``like=``): the mesh's frame ("LPS" or "RAS") and
        how it was decided (see :func:`geovox.reference.resolve_mesh_space`).
    labels : (nx, ny, nz) uint8 or uint16, or None
        Label value per voxel (0 the background), when labels were asked for
        (see :mod:`geovox.labels`).
    label_table : list of dict or None
        One entry per label value, the background (0) first: ``value``,
        ``name``, ``source``, ``color`` (RGBA 0-255), ``voxels``, ``volume``
        (model units cubed).
    contested : int
        Voxels inside more than one part (settled by the overlap rule).
    fractions : (nx, ny, nz, L) uint8 or float32, or None
        Each label's coverage fraction per voxel (index ``k`` for label
        value ``k + 1``), when asked for.
    """

    occupancy: np.ndarray
    grid: Grid
    backend: str
    source: str = "<mesh>"
    colors: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    inside: str = "parity"
    density: np.ndarray | None = None
    sdf: np.ndarray | None = None
    mesh_space: tuple | None = None
    labels: np.ndarray | None = None
    label_table: list | None = None
    contested: int = 0
    fractions: np.ndarray | None = None

    @property
    def bounds(self) -> tuple:
        """``((xmin, ymin, zmin), (xmax, ymax, zmax))`` of the grid."""
        return (tuple(float(x) for x in self.grid.lo), tuple(float(x) for x in self.grid.hi))

    @property
    def spacing(self) -> tuple:
        """``(dx, dy, dz)``: the voxel dimensions."""
        return tuple(float(x) for x in self.grid.spacing)

    @property
    def shape(self) -> tuple:
        """``(nx, ny, nz)``."""
        return tuple(self.grid.shape)

    @property
    def inside_count(self) -> int:
        return int(np.count_nonzero(self.occupancy))
