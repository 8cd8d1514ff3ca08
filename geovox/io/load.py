"""``load_mesh``: any model file (or trimesh object) into one plain triangle structure.

| extension | read by |
|---|---|
| ``.obj`` | :mod:`geovox.io.obj` (with :mod:`geovox.io.mtl`) |
| ``.stl`` | :mod:`geovox.io.stl` (trimesh for the odd ASCII file it leaves) |
| ``.ply`` | :mod:`geovox.io.ply` |
| ``.gltf``, ``.glb`` | :mod:`geovox.io.gltf` (with :mod:`geovox.io.gltf_materials`) |
| anything else | trimesh, through :mod:`geovox.io.adaptor` (OFF, 3MF, COLLADA, 3DXML, archives, ...) |

trimesh is imported only on the last row. Compressed inputs are checked
against the size limit before anything inflates them (:mod:`geovox.io.archive`).
"""

from __future__ import annotations

import os

from ..errors import InputNotFoundError, MeshError, ParameterError
from ..mesh import Mesh, check_mesh
from . import limits
from .kinds import ARCHIVES, readable_extensions
from .references import check_rule

__all__ = ["load_mesh", "readable_extensions", "check_max_input_size"]


def check_max_input_size(value):
    """``max_input_size`` validated: None, or a positive number of bytes (an int)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise ParameterError(f"`max_input_size` must be a positive number of bytes, "
                             f"got {value!r}")
    return value


def load_mesh(source, *, references: str = "anywhere", max_input_size: int | None = None) -> Mesh:
    """Load a mesh from a path, a trimesh object, or pass a :class:`Mesh` through.

    OBJ, STL, PLY, glTF and GLB files are read by geovox itself (see the
    table in this module's docstring); everything else by trimesh (OFF, 3MF,
    COLLADA, 3DXML, zip and tar archives of these, ...).

    Parameters
    ----------
    source : str, os.PathLike, Mesh, trimesh.Trimesh or trimesh.Scene
        A file, a trimesh object (a scene's transforms are applied), or a
        Mesh, returned as it is.
    references : {"anywhere", "folder"}
        Where the files a model names (OBJ materials and textures, glTF
        buffers and images, COLLADA textures) may be read from: anywhere, or
        only under the model's own folder (see :mod:`geovox.io.references`).
        URLs are never fetched.
    max_input_size : int, optional
        The most bytes a file may hold once read or inflated: an archive's
        members together, a glTF's decoded buffers, the file itself, a glTF's
        instanced copies. Default: 100 times the file's size (at least 64
        MiB), at most half the available memory; for instanced copies, half
        the available memory (see :mod:`geovox.io.limits`).

    Returns
    -------
    Mesh
        ``vertices`` (n, 3) float64, ``faces`` (m, 3) int64, and the
        materials, UVs and colours the file states.

    Raises
    ------
    InputNotFoundError
        The path does not exist or is a folder.
    MeshError
        The file cannot be read as a mesh, has no faces (a point cloud, lines),
        would grow past ``max_input_size``, or trimesh dropped part of its
        geometry while reading it. The message names the file and says what
        is wrong in words, in one line.
    """
    rule = check_rule(references)
    limit = limits.Limit(check_max_input_size(max_input_size))
    if isinstance(source, Mesh):
        return source
    if isinstance(source, (str, os.PathLike)):
        return _load_file(os.fspath(source), rule, limit)
    from .adaptor import from_trimesh

    try:
        return from_trimesh(source, source=f"<{type(source).__name__}>")
    except MeshError:
        if type(source).__module__.startswith("trimesh"):
            raise  # a trimesh point cloud, lines or empty scene: the message says which
        raise MeshError(
            f"`mesh` must be a file path, a trimesh.Trimesh or a trimesh.Scene, "
            f"got {type(source).__name__}"
        ) from None


def _load_file(path: str, rule: str, limit: limits.Limit) -> Mesh:
    if not os.path.exists(path):
        raise InputNotFoundError(f"input file not found: {path}")
    if os.path.isdir(path):
        raise InputNotFoundError(f"input is a folder, not a mesh file: {path}")
    size = os.path.getsize(path)
    if size == 0:
        raise MeshError(f"{path}: the file is empty")
    if limit.most is not None and size > limit.most:
        raise limit.refuse(path, "the file", size, limit.most)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".obj":
        from .obj import read_obj

        return check_mesh(read_obj(path, rule=rule))
    if ext == ".ply":
        from .ply import read_ply

        return read_ply(path, rule=rule)
    if ext in (".gltf", ".glb"):
        from .gltf import read_gltf

        return read_gltf(path, rule=rule, limit=limit)
    if ext == ".stl":
        from .stl import read_stl

        mesh = read_stl(path)
        if mesh is not None:
            return mesh
    if ext in ARCHIVES:
        from .archive import check_archive

        check_archive(path, limit)
    from .adaptor import trimesh_load

    return trimesh_load(path, rule)
