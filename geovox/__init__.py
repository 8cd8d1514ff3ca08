"""geovox: polygon meshes to voxel volumes by ray casting.

>>> import geovox
>>> vol = geovox.voxelize("model.obj", resolution=128)   # doctest: +SKIP
>>> vol.occupancy.shape, vol.spacing, vol.backend          # doctest: +SKIP
"""

from .backends import available_backends
from .errors import (
    BackendUnavailableError,
    GeovoxError,
    GridTooLargeError,
    InputNotFoundError,
    MeshError,
    OutputError,
    ParameterError,
)
from .grid import Grid
from .mesh import Mesh, load_mesh
from .pipeline import Volume, voxelize
from .stream import convert_to

__version__ = "0.1.0"

__all__ = [
    "voxelize",
    "convert_to",
    "Volume",
    "Grid",
    "Mesh",
    "load_mesh",
    "available_backends",
    "GeovoxError",
    "InputNotFoundError",
    "MeshError",
    "ParameterError",
    "BackendUnavailableError",
    "OutputError",
    "GridTooLargeError",
]
