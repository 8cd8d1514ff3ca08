"""Reading meshes: the loader's entry points and the format readers it calls.

``load_mesh``, ``readable_extensions`` and ``from_trimesh`` live in
:mod:`geovox.io.load` and are re-exported here on first use (PEP 562): the
loader imports this package's readers, so an eager import would be a cycle,
and a program that reads no file should not pay for the loader.

| module | reads |
|---|---|
| :mod:`geovox.io.load` | ``load_mesh``: every format, by the readers below or trimesh; OFF, PLY colours, the trimesh adaptor ``from_trimesh``, glTF materials |
| :mod:`geovox.io.obj` | Wavefront OBJ and MTL, without trimesh |
| :mod:`geovox.io.ply` | plain binary triangle PLY, without trimesh |
| :mod:`geovox.io.stl` | binary and ASCII STL, without trimesh |
| :mod:`geovox.io.gltf` | glTF primitive modes (strips and fans) |
| :mod:`geovox.io.threemf` | 3MF build items and components |
| :mod:`geovox.io.references` | the rule for files a model names (textures, MTL) |
"""

_LOADER = ("load_mesh", "readable_extensions", "from_trimesh")

__all__ = list(_LOADER)


def __getattr__(name):
    if name in _LOADER:
        from . import load

        value = getattr(load, name)
        globals()[name] = value  # later look-ups skip this function
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LOADER))
