"""Loading polygon models into one plain triangle structure."""

from __future__ import annotations

import os
import re
import warnings

import numpy as np

from .errors import InputNotFoundError, MeshError
# Mesh, Material and check_mesh are also public here, where they used to live.
from .surface import Material, Mesh, build_mesh, check_mesh  # noqa: F401


#: The diffuse colour trimesh gives a material the file does not colour.
TRIMESH_DEFAULT = np.array([102, 102, 102, 255])
#: The texel of the 2 x 2 image trimesh makes up for UVs without a texture.
TRIMESH_PLACEHOLDER = np.array([100, 100, 100, 255])


def _visual_parts(g, nfaces, materials):
    """Per-face material, corner UVs and vertex colours of one trimesh geometry."""
    visual = getattr(g, "visual", None)
    kind = getattr(visual, "kind", None)
    fm = np.full(nfaces, -1, dtype=np.int64)
    uv = vc = None
    if kind == "texture":
        mat = getattr(visual, "material", None)
        m = Material(name=getattr(mat, "name", None) or "material")
        image = getattr(mat, "image", None) or getattr(mat, "baseColorTexture", None)
        if image is not None and image.size == (2, 2) and np.all(
                np.asarray(image.convert("RGBA")) == TRIMESH_PLACEHOLDER):
            # trimesh.visual.material.empty_material's stand-in for a
            # texture the file does not have (a PLY with UVs only)
            image = None
        if image is not None:
            # sRGB texels as stored (no linearisation), alpha dropped
            m.image = np.asarray(image.convert("RGB"))
        if hasattr(mat, "baseColorFactor"):
            # glTF (metallic-roughness, or specular-glossiness converted by
            # trimesh): base colour = factor x texture; the factor's default
            # in the glTF specification is white.
            factor = mat.baseColorFactor
            m.kd = (np.ones(3) if factor is None
                    else np.asarray(factor, dtype=np.float64)[:3] / 255.0)
        else:
            colour = getattr(mat, "diffuse", None)
            # trimesh gives materials it makes up (a PLY's texture, UVs
            # without any) its default 0.4 grey: not the file's colour.
            if colour is not None and not np.array_equal(np.asarray(colour), TRIMESH_DEFAULT):
                m.kd = np.asarray(colour, dtype=np.float64)[:3] / 255.0
        fm[:] = len(materials)
        materials.append(m)
        if visual.uv is not None and len(visual.uv) == len(g.vertices):
            uv = np.asarray(visual.uv, dtype=np.float64)[g.faces]
    elif kind == "vertex":
        vc = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
    elif kind == "face":
        # Face colours become flat per-face materials.
        fc = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0
        uniq, inverse = np.unique(fc, axis=0, return_inverse=True)
        for colour in uniq:
            materials.append(Material(name="face colour", kd=colour))
        fm[:] = len(materials) - len(uniq) + inverse.reshape(-1)
    return fm, uv, vc


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

# trimesh logs (and carries on) when it drops geometry it could not read; these
# messages mean the mesh it returns is missing parts, so geovox refuses it
# rather than voxelise placeholder zeros or half a model.
# Some are debug messages: a glTF triangle fan skipped, a broken file inside a
# zip left out of the scene, a glTF mesh dropped.
_LOST_GEOMETRY = re.compile(
    r"didn't decode, values are placeholder zeros|failed to process extension "
    r"KHR_draco_mesh_compression|PLY failed to populate|unable to load Rep|"
    r"unsupported format|included but not defined|unable to get faces|"
    r"skipping primitive with mode 6|failed to load file in zip|failed to load mesh")


def _kind(path: str) -> str:
    """``"glTF binary (.glb)"``: the format a file's extension claims, for messages."""
    ext = os.path.splitext(path)[1].lower()
    name = FORMAT_NAMES.get(ext)
    return f"{name} ({ext})" if name else (ext or "a file without an extension")


def _load_failure(path: str, exc: Exception) -> str:
    """One line saying, in words, why trimesh could not read ``path``."""
    ext = os.path.splitext(path)[1].lower()
    text = str(exc).strip().splitlines()[0].strip() if str(exc).strip() else ""
    missing = re.search(r"No module named '([\w.]+)'", text)
    if isinstance(exc, ImportError) and (getattr(exc, "name", None) or missing):
        # trimesh re-raises a stored ImportError for readers whose module is
        # missing, without its `name`; the text still names it.
        module = (exc.name or missing.group(1)).split(".")[0]
        pip = PIP_NAMES.get(module, module)
        return (f"{path}: reading {_kind(path)} files needs the Python package {pip!r}, which is "
                f"not installed (pip install {pip})")
    if isinstance(exc, FileNotFoundError):
        missing = exc.filename or text.strip("'\"") or "a file"
        return f"{path}: refers to a file that is missing: {missing}"
    if ext in NOT_A_MESH:
        return f"{path}: this is {NOT_A_MESH[ext]}"
    if isinstance(exc, (NotImplementedError, KeyError)) and "not supported" in text:
        return (f"{path}: cannot be read as a mesh: geovox does not read "
                f"{ext + ' files' if ext else 'files without an extension'}; it reads "
                f"{' '.join(readable_extensions())}")
    detail = type(exc).__name__ + (f": {text[:120]}" if text else "")
    return (f"{path}: cannot be read as {_kind(path)}; the file is damaged or not what its "
            f"extension says (trimesh's reader stopped with {detail})")


def readable_extensions() -> list:
    """Extensions geovox reads: OBJ itself, the rest through trimesh (``.zip`` etc. included)."""
    import trimesh

    exts = {".obj"} | {"." + e.lower() for e in trimesh.available_formats()}
    return sorted(exts - set(NOT_A_MESH) - {".json", ".dict", ".dict64", ".npz", ".stl_ascii"})


def _no_faces(source: str, parts) -> str:
    """Why a file with no triangles cannot be voxelised, naming what it holds instead."""
    counts = {}
    for g in parts:
        kind = type(g).__name__
        if kind == "PointCloud":
            what = f"a point cloud ({len(g.vertices):,} points)"
        elif kind in ("Path2D", "Path3D"):
            n = len(g.entities)
            what = f"lines ({n:,} line {'piece' if n == 1 else 'pieces'})"
        elif kind == "Trimesh":
            what = f"a mesh with no faces ({len(g.vertices):,} vertices)"
        else:
            what = f"a {kind}"
        counts[what] = counts.get(what, 0) + 1
    if not counts:
        return f"{source}: contains no geometry (no vertices or faces could be read from it)"
    held = ", ".join(k if n == 1 else f"{n} x {k}" for k, n in counts.items())
    return (f"{source}: has no faces, only {held}; geovox voxelises the inside of a "
            f"triangle surface")


def from_trimesh(obj, source: str = "<trimesh>") -> Mesh:
    """Convert a ``trimesh.Trimesh`` or ``trimesh.Scene`` (transforms applied),
    keeping each geometry's material, UVs and vertex colours.

    Point clouds and lines in a scene are skipped; a scene with no faces at
    all is a :class:`MeshError` that says what it holds instead.
    """
    import trimesh

    if isinstance(obj, trimesh.Scene):
        every = list(obj.dump(concatenate=False))
        parts = [g for g in every if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not parts:
            raise MeshError(_no_faces(source, every))
    elif isinstance(obj, trimesh.Trimesh):
        parts = [obj]
    elif isinstance(obj, trimesh.parent.Geometry):
        raise MeshError(_no_faces(source, [obj]))
    else:
        raise MeshError(f"{source}: contains no triangle mesh (got {type(obj).__name__})")
    verts, faces, fms, uvs, vcs, materials, offset = [], [], [], [], [], [], 0
    have_uv, have_vc = False, False
    for g in parts:
        f = np.asarray(g.faces, dtype=np.int64).reshape(-1, 3)
        verts.append(np.asarray(g.vertices, dtype=np.float64).reshape(-1, 3))
        faces.append(f + offset)
        offset += len(g.vertices)
        fm, uv, vc = _visual_parts(g, len(f), materials)
        fms.append(fm)
        uvs.append(uv if uv is not None else np.full((len(f), 3, 2), np.nan))
        vcs.append(vc if vc is not None else np.ones((len(verts[-1]), 3)))
        have_uv |= uv is not None
        have_vc |= vc is not None
    return build_mesh(
        np.concatenate(verts), np.concatenate(faces), source,
        face_material=np.concatenate(fms),
        materials=materials,
        corner_uv=np.concatenate(uvs) if have_uv else None,
        vertex_colors=np.concatenate(vcs) if have_vc else None,
    )


def _trimesh_load(path: str) -> Mesh:
    """Read any non-OBJ file with trimesh; every failure becomes one MeshError line."""
    import logging

    import trimesh

    class _Collect(logging.Handler):
        """Keeps trimesh's log records while a file loads: ``(level, message)``."""

        def __init__(self):
            super().__init__(logging.DEBUG)
            self.records = []

        def emit(self, record):
            try:
                self.records.append((record.levelno, record.getMessage()))
            except Exception:  # a malformed record must not break loading
                self.records.append((record.levelno, str(record.msg)))

    ext = os.path.splitext(path)[1].lower()
    if ext in NOT_A_MESH:
        raise MeshError(f"{path}: this is {NOT_A_MESH[ext]}")
    # trimesh reports what it skipped through `logging` (some of it only at
    # debug level); without a handler Python prints its warnings on stderr.
    # While the file loads every record comes here instead, to be judged below.
    collect = _Collect()
    logger = logging.getLogger("trimesh")
    saved = logger.level, logger.propagate
    logger.addHandler(collect)
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NumPy noise from trimesh's parsers
            loaded = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many types for unreadable files
        raise MeshError(_load_failure(path, exc)) from exc
    finally:
        logger.removeHandler(collect)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]
    lost = [m for _, m in collect.records if _LOST_GEOMETRY.search(m)]
    if any("draco" in m.lower() for m in lost):
        why = ("the DracoPy package is not installed (pip install DracoPy)"
               if any("No module named" in m or "import of DracoPy" in m for m in lost)
               else "DracoPy could not decode it (trimesh: " + "; ".join(lost) + ")")
        raise MeshError(f"{path}: its geometry is Draco-compressed (glTF extension "
                        f"KHR_draco_mesh_compression) and was not decoded: {why}")
    if lost:
        raise MeshError(f"{path}: part of the geometry could not be read, so the volume would "
                        f"be incomplete (trimesh: {'; '.join(dict.fromkeys(lost))})")
    try:
        mesh = from_trimesh(loaded, source=path)
    except MeshError:
        raise
    except Exception as exc:  # odd visuals or arrays trimesh accepted
        text = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else ""
        raise MeshError(
            f"{path}: trimesh read the file, but its geometry or materials could not be "
            f"taken over ({type(exc).__name__}{': ' + text if text else ''})") from exc
    said = [m for level, m in collect.records if level >= logging.WARNING]
    mesh.problems.extend(f"{path}: {m}" for m in dict.fromkeys(said))
    return mesh


def load_mesh(source) -> Mesh:
    """Load a mesh from a path, a trimesh object, or pass a :class:`Mesh` through.

    OBJ files are read by :mod:`geovox.obj`; everything else by trimesh
    (STL, PLY, OFF, glTF/GLB with Draco compression, 3MF, COLLADA, 3DXML,
    zip and tar archives of these, ...).

    Parameters
    ----------
    source : str, os.PathLike, Mesh, trimesh.Trimesh or trimesh.Scene

    Raises
    ------
    InputNotFoundError
        The path does not exist or is a folder.
    MeshError
        The file cannot be read as a mesh, has no faces (a point cloud, lines),
        or trimesh dropped part of its geometry while reading it. The message
        names the file and says what is wrong in words.
    """
    if isinstance(source, Mesh):
        return source
    if isinstance(source, (str, os.PathLike)):
        path = os.fspath(source)
        if not os.path.exists(path):
            raise InputNotFoundError(f"input file not found: {path}")
        if os.path.isdir(path):
            raise InputNotFoundError(f"input is a folder, not a mesh file: {path}")
        if os.path.getsize(path) == 0:
            raise MeshError(f"{path}: the file is empty")
        if path.lower().endswith(".obj"):
            from .obj import read_obj

            return check_mesh(read_obj(path))
        return _trimesh_load(path)
    try:
        return from_trimesh(source, source=f"<{type(source).__name__}>")
    except MeshError:
        if type(source).__module__.startswith("trimesh"):
            raise  # a trimesh point cloud, lines or empty scene: the message says which
        raise MeshError(
            f"`mesh` must be a file path, a trimesh.Trimesh or a trimesh.Scene, "
            f"got {type(source).__name__}"
        ) from None
