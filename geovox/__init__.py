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
    OutputError,
    ParameterError,
)

__version__ = "0.1.0"

#: public name -> submodule that defines it
_LAZY = {
    "voxelize": "pipeline",
    "plan": "pipeline",
    "Plan": "pipeline",
    "Route": "pipeline",
    "voxelize_block": "pipeline",
    "Options": "options",
    "Inside": "options",
    "Report": "volume",
    "Progress": "volume",
    "Volume": "volume",
    "convert_to": "stream",
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
]


#: old module path -> the module's path since the sub-packages (issue 21): both names
#: are one module object, so `geovox.obj is geovox.io.obj` and a patch on either is seen by
#: both. (`geovox.inside`, `geovox.colour` and `geovox.cli` are now the packages themselves,
#: which show their modules' names, live: geovox/_forward.py; `geovox.mesh`, once the loader
#: and now the data model, shows the loader's names the same way.)
_MOVED = {
    "geovox.obj": "geovox.io.obj",
    "geovox.gltf": "geovox.io.gltf",
    "geovox.ply": "geovox.io.ply",
    "geovox.threemf": "geovox.io.threemf",
    "geovox.references": "geovox.io.references",
    "geovox.repair": "geovox.inside.repair",
    "geovox.nearest": "geovox.colour.nearest",
}


class _MovedFinder:
    """Imports an old module path (:data:`_MOVED`) as the module at its new one.

    First on ``sys.meta_path``: an editable install's finder would otherwise answer an old
    path from the checkout it was installed from. It answers nothing but :data:`_MOVED`'s
    names, and nothing is imported until an old path is. The import system then keeps the
    module under both names.
    """

    @staticmethod
    def find_spec(name, path=None, target=None):
        if name not in _MOVED:
            return None
        from importlib.machinery import ModuleSpec

        return ModuleSpec(name, _MovedFinder)

    @staticmethod
    def create_module(spec):
        import importlib

        module = importlib.import_module(_MOVED[spec.name])
        spec.loader_state = module.__spec__  # the import system overwrites __spec__
        return module

    @staticmethod
    def exec_module(module):
        module.__spec__ = module.__spec__.loader_state  # already run, under its own name


def _install_finder():
    import sys

    if not any(f is _MovedFinder for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder)


_install_finder()


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
