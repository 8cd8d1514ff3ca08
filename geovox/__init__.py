"""geovox: polygon meshes to voxel volumes by ray casting.

>>> import geovox
>>> vol = geovox.voxelize("model.obj", resolution=128)   # doctest: +SKIP
>>> vol.occupancy.shape, vol.spacing, vol.backend          # doctest: +SKIP

The public names are imported on first use (PEP 562), so ``import geovox``
and ``geovox --help`` do not pay for NumPy and the pipeline's modules until
something needs them.
"""

from .errors import (
    BackendUnavailableError,
    ClusterError,
    GeovoxError,
    GridTooLargeError,
    InputNotFoundError,
    MeshError,
    MeshTooLargeError,
    OutputError,
    ParameterError,
)

from .version import __version__

#: public name -> submodule that defines it
_LAZY = {
    "voxelize": "api",
    "plan": "planner",
    "Plan": "planner",
    "Route": "planner",
    "voxelize_block": "block",
    "Options": "options",
    "Inside": "options",
    "Report": "volume",
    "Progress": "volume",
    "Volume": "volume",
    "convert_to": "api",
    "convert_many": "batch",
    "Grid": "grid",
    "Mesh": "mesh",
    "load_mesh": "io.load",
    "available_backends": "backends",
    "usable_backends": "backends",
}

__all__ = [
    "voxelize",
    "plan",
    "Plan",
    "Options",
    "Report",
    "Progress",
    "convert_to",
    "convert_many",
    "Volume",
    "Grid",
    "Mesh",
    "load_mesh",
    "available_backends",
    "usable_backends",
    "GeovoxError",
    "InputNotFoundError",
    "MeshError",
    "ParameterError",
    "BackendUnavailableError",
    "ClusterError",
    "OutputError",
    "GridTooLargeError",
    "MeshTooLargeError",
]


def __getattr__(name):
    import importlib

    if name in _LAZY:
        value = getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    try:  # `geovox.grid` and the like, as when this file imported them all
        return importlib.import_module(f".{name}", __name__)
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise
    raise AttributeError(f"module 'geovox' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
