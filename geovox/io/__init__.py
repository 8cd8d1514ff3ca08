"""Reading meshes: ``load_mesh`` and the format readers it calls.

``load_mesh``, ``readable_extensions`` and ``from_trimesh`` are re-exported
here on first use (PEP 562), so that a program that reads no file pays for
no reader.

| module | reads |
|---|---|
| :mod:`geovox.io.load` | ``load_mesh``: every format, by the readers below or trimesh |
| :mod:`geovox.io.obj`, :mod:`geovox.io.mtl` | Wavefront OBJ and its MTL material libraries |
| :mod:`geovox.io.stl` | binary and ASCII STL |
| :mod:`geovox.io.ply` | PLY: ASCII and binary, colours, texture coordinates |
| :mod:`geovox.io.gltf`, :mod:`geovox.io.gltf_materials` | glTF 2.0 and GLB, with Draco, meshopt, instancing, materials |
| :mod:`geovox.io.adaptor` | trimesh objects, and the formats read through trimesh (OFF, 3MF, COLLADA, archives, ...) |
| :mod:`geovox.io.off` | OFF colours and polygons (beside trimesh) |
| :mod:`geovox.io.threemf`, :mod:`geovox.io.dae` | 3MF build items and components; COLLADA nodes as parts |
| :mod:`geovox.io.archive`, :mod:`geovox.io.limits` | the size limit for compressed inputs and decoded data |
| :mod:`geovox.io.references`, :mod:`geovox.io.kinds` | the rule for files a model names; extensions and their names |
"""

_LAZY = {"load_mesh": "load", "readable_extensions": "kinds", "from_trimesh": "adaptor"}

__all__ = list(_LAZY)


def __getattr__(name):
    if name in _LAZY:
        import importlib

        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
