"""What a file is by its extension: names for messages, what geovox reads itself, what is not a mesh."""

from __future__ import annotations

import os

__all__ = ["FORMAT_NAMES", "NOT_A_MESH", "PIP_NAMES", "NATIVE", "ARCHIVES", "kind",
           "readable_extensions"]

#: Extensions geovox reads itself, without trimesh.
NATIVE = (".obj", ".stl", ".ply", ".gltf", ".glb")
#: Compressed inputs (archives, and formats that are zip files): inflated under a limit.
ARCHIVES = (".zip", ".tar", ".gz", ".bz2", ".xz", ".tgz", ".zae", ".3dxml", ".3mf")

#: What a file type is, for messages ("cannot be read as glTF binary (.glb)").
FORMAT_NAMES = {
    ".glb": "glTF binary", ".gltf": "glTF", ".stl": "STL", ".ply": "PLY", ".off": "OFF",
    ".3mf": "3MF", ".dae": "COLLADA", ".zae": "COLLADA archive", ".3dxml": "3DXML",
    ".xaml": "XAML", ".xyz": "XYZ point", ".zip": "zip archive", ".gz": "compressed",
    ".bz2": "compressed", ".tar": "tar archive", ".obj": "OBJ", ".step": "STEP",
    ".stp": "STEP", ".ctm": "OpenCTM",
}

#: Files people try that are not meshes, with what to do instead.
NOT_A_MESH = {
    ".bin": "a glTF buffer, not a mesh; convert the .gltf file that refers to it",
    ".mtl": "an OBJ material library, not a mesh; convert the .obj file that uses it",
    ".binvox": "already a voxel grid (binvox), not a polygon mesh",
    ".png": "an image, not a mesh", ".jpg": "an image, not a mesh",
    ".jpeg": "an image, not a mesh", ".bmp": "an image, not a mesh",
    ".tga": "an image, not a mesh", ".dxf": "a 2-D drawing (DXF), not a 3-D mesh",
    ".svg": "a 2-D drawing (SVG), not a 3-D mesh",
}

#: The pip name of each optional module trimesh's readers import.
PIP_NAMES = {"collada": "pycollada", "cascadio": "cascadio",
             "networkx": "networkx", "lxml": "lxml", "DracoPy": "DracoPy",
             "ezdxf": "ezdxf", "shapely": "shapely", "meshio": "meshio", "rtree": "rtree"}


def kind(path: str) -> str:
    """``"glTF binary (.glb)"``: the format a file's extension claims, for messages."""
    ext = os.path.splitext(path)[1].lower()
    name = FORMAT_NAMES.get(ext)
    return f"{name} ({ext})" if name else (ext or "a file without an extension")


def readable_extensions() -> list:
    """Extensions geovox reads: :data:`NATIVE` itself, the rest through trimesh (``.zip`` etc. included)."""
    import trimesh

    exts = set(NATIVE) | {"." + e.lower() for e in trimesh.available_formats()}
    return sorted(exts - set(NOT_A_MESH) - {".json", ".dict", ".dict64", ".npz", ".stl_ascii"})
