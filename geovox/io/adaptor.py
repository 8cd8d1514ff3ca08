"""The trimesh adaptor: trimesh objects into a Mesh, and the long tail of formats through trimesh.

geovox reads OBJ, STL, PLY, glTF and GLB itself (:mod:`geovox.io.load`);
everything else -- OFF, 3MF, COLLADA, 3DXML, archives of these, ... -- is
read by trimesh here, imported only on these paths. trimesh objects given
in Python (a ``trimesh.Trimesh`` or ``Scene``) become a Mesh through
:func:`from_trimesh`, with their materials, UVs, vertex colours and parts.
"""

from __future__ import annotations

import os
import re
import threading
import warnings

import numpy as np

from ..errors import MeshError
from ..mesh import Material, Mesh, build_mesh, texels
from .gltf import colours_or_white, unit_colours
from .kinds import NOT_A_MESH, PIP_NAMES, kind, readable_extensions
from .off import read_off
from .references import Refused, resolver

__all__ = ["from_trimesh", "trimesh_load", "load_failure", "LOST_GEOMETRY", "SELF_CONTAINED",
           "TRIMESH_DEFAULT", "TRIMESH_PLACEHOLDER"]

#: The diffuse colour trimesh gives a material the file does not colour.
TRIMESH_DEFAULT = np.array([102, 102, 102, 255])
#: The texel of the 2 x 2 image trimesh makes up for UVs without a texture.
TRIMESH_PLACEHOLDER = np.array([100, 100, 100, 255])

#: Held while trimesh reads a file (see load_mesh).
TRIMESH_LOAD = threading.Lock()

# trimesh logs (and carries on) when it drops geometry it could not read; these
# messages mean the mesh it returns is missing parts, so geovox refuses it
# rather than voxelise placeholder zeros or half a model.
# Some are debug messages: a glTF triangle fan skipped, a broken file inside a
# zip left out of the scene, a glTF mesh dropped.
LOST_GEOMETRY = re.compile(
    r"didn't decode, values are placeholder zeros|failed to process extension "
    r"KHR_draco_mesh_compression|PLY failed to populate|unable to load Rep|"
    r"unsupported format|included but not defined|unable to get faces|"
    r"skipping primitive with mode 6|failed to load file in zip|failed to load mesh")


def _visual_parts(g, nfaces, materials, original=None):
    """Per-face material, corner UVs and vertex colours of one trimesh geometry.

    ``original`` is the scene's geometry ``g`` was copied from: trimesh's
    copies of textured visuals drop their vertex colours (glTF ``COLOR_0``).
    """
    visual = getattr(g, "visual", None)
    shown = getattr(visual, "kind", None)
    fm = np.full(nfaces, -1, dtype=np.int64)
    uv = vc = None
    source = g if original is None else original
    mat = getattr(visual, "material", None) if shown == "texture" else None
    if shown == "texture":
        m = Material(name=getattr(mat, "name", None) or "material")
        image = getattr(mat, "image", None) or getattr(mat, "baseColorTexture", None)
        if image is not None and image.size == (2, 2) and np.all(
                np.asarray(image.convert("RGBA")) == TRIMESH_PLACEHOLDER):
            # trimesh.visual.material.empty_material's stand-in for a
            # texture the file does not have (a PLY with UVs only)
            image = None
        if image is not None:
            m.image = texels(image)
        if hasattr(mat, "baseColorFactor"):
            # A trimesh PBR material (glTF's model) made in Python: base colour
            # = factor x texture x vertex colour; the factor's default in the
            # glTF specification is white.
            factor = mat.baseColorFactor
            m.kd = (np.ones(3) if factor is None
                    else np.asarray(factor, dtype=np.float64)[:3] / 255.0)
            m.vertex_tint = True
            vc = unit_colours(_vertex_attribute(source, "color"), len(g.vertices))
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
    elif shown == "vertex":
        vc = np.asarray(visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
    elif shown == "face" and len(visual.face_colors) == nfaces:
        # Face colours become flat per-face materials. (A PLY's colours of
        # polygons trimesh cut into triangles do not match its faces.)
        fc = np.asarray(visual.face_colors, dtype=np.float64)[:, :3] / 255.0
        uniq, inverse = np.unique(fc, axis=0, return_inverse=True)
        for colour in uniq:
            materials.append(Material(name="face colour", kd=colour))
        fm[:] = len(materials) - len(uniq) + inverse.reshape(-1)
    return fm, uv, vc


def _vertex_attribute(g, key: str):
    """A geometry's textured-visual vertex attribute, or None."""
    store = getattr(getattr(g, "visual", None), "vertex_attributes", None)
    return store.get(key) if store is not None else None


def load_failure(path: str, exc: Exception) -> str:
    """One line saying, in words, why trimesh could not read ``path``."""
    ext = os.path.splitext(path)[1].lower()
    text = str(exc).strip().splitlines()[0].strip() if str(exc).strip() else ""
    missing = re.search(r"No module named '([\w.]+)'", text)
    if isinstance(exc, ImportError) and (getattr(exc, "name", None) or missing):
        # trimesh re-raises a stored ImportError for readers whose module is
        # missing, without its `name`; the text still names it.
        module = (exc.name or missing.group(1)).split(".")[0]
        pip = PIP_NAMES.get(module, module)
        return (f"{path}: reading {kind(path)} files needs the Python package {pip!r}, which is "
                f"not installed (pip install {pip})")
    if isinstance(exc, Refused):
        return f"{path}: refers to a file that is not read: {exc}"
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
    return (f"{path}: cannot be read as {kind(path)}; the file is damaged or not what its "
            f"extension says (trimesh's reader stopped with {detail})")


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
        originals = [obj.geometry.get(g.metadata.get("name")) for g in parts]
        # A scene's nodes are its parts (labels="part"): named after node and
        # mesh, so a mesh two nodes use gives two parts.
        part_names = [_part_name(g, k) for k, g in enumerate(parts)]
    elif isinstance(obj, trimesh.Trimesh):
        parts, originals, part_names = [obj], [obj], None
    elif isinstance(obj, trimesh.parent.Geometry):
        raise MeshError(_no_faces(source, [obj]))
    else:
        raise MeshError(f"{source}: contains no triangle mesh (got {type(obj).__name__})")
    verts, faces, fms, uvs, vcs, materials, offset = [], [], [], [], [], [], 0
    have_uv = False
    for g, original in zip(parts, originals):
        f = np.asarray(g.faces, dtype=np.int64).reshape(-1, 3)
        verts.append(np.asarray(g.vertices, dtype=np.float64).reshape(-1, 3))
        faces.append(f + offset)
        offset += len(g.vertices)
        fm, uv, vc = _visual_parts(g, len(f), materials, original)
        fms.append(fm)
        uvs.append(uv if uv is not None else np.full((len(f), 3, 2), np.nan))
        vcs.append(vc)
        have_uv |= uv is not None
    made = []  # the plain material's index, once one is needed

    def plain() -> int:
        if not made:
            made.append(len(materials))
            materials.append(Material(name="default"))
        return made[0]

    vertex_colors = colours_or_white(vcs, [len(v) for v in verts], fms, plain)
    mesh = build_mesh(
        np.concatenate(verts), np.concatenate(faces), source,
        face_material=np.concatenate(fms),
        materials=materials,
        corner_uv=np.concatenate(uvs) if have_uv else None,
        vertex_colors=vertex_colors,
        face_part=None if part_names is None else
        np.repeat(np.arange(len(faces), dtype=np.int64), [len(f) for f in faces]),
        parts=part_names or [],
    )
    return mesh


def _part_name(g, k: int) -> str:
    """A scene geometry's part name: ``node (mesh)``, or whichever of them it has."""
    node, name = g.metadata.get("node"), g.metadata.get("name")
    if node and name and node != name:
        return f"{node} ({name})"
    return str(node or name or f"part {k + 1}")


#: Formats whose files trimesh reads from inside an archive of their own, not beside the model.
SELF_CONTAINED = {".zip", ".tar", ".gz", ".bz2", ".zae", ".3dxml", ".3mf", ".xz", ".tgz"}


def trimesh_load(path: str, rule: str = "anywhere") -> Mesh:
    """Read a file of the long tail with trimesh; every failure becomes one MeshError line.

    The files the model names (glTF buffers and images, COLLADA and PLY
    textures) are read by geovox's resolver under ``rule``.
    """
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
        # The lock: catch_warnings swaps process-wide filters, so two threads
        # of one Dask worker loading side by side would restore each other's.
        with TRIMESH_LOAD, warnings.catch_warnings():
            warnings.simplefilter("ignore")  # NumPy noise from trimesh's parsers
            said: list = []
            flat = None
            if ext == ".3mf":
                from . import threemf  # xml and zipfile: not imported for other files

                flat = threemf.flatten(path)
            if flat is not None:
                import io

                loaded = trimesh.load(io.BytesIO(flat), file_type="3mf", process=False)
            elif ext in SELF_CONTAINED:
                loaded = trimesh.load(path, process=False)
            else:
                loaded = trimesh.load(path, process=False, resolver=resolver(path, rule, said))
    except MeshError:
        raise  # geovox's own line (a 3MF beam lattice, a part it does not have)
    except Exception as exc:  # trimesh raises many types for unreadable files
        own = read_off(path, None) if ext == ".off" else None
        if own is not None:
            return own  # e.g. polygons of five corners or more, which trimesh cannot fan
        raise MeshError(load_failure(path, exc)) from exc
    finally:
        logger.removeHandler(collect)
        logger.setLevel(saved[0])
        logger.propagate = saved[1]
    lost = [m for _, m in collect.records if LOST_GEOMETRY.search(m)]
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
        if ext == ".off":
            mesh = read_off(path, mesh)
        elif ext == ".dae":
            from .dae import regroup

            regroup(mesh, path)  # COLLADA nodes as parts (trimesh names its geometries)
    except MeshError:
        raise
    except Exception as exc:  # odd visuals or arrays trimesh accepted
        text = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else ""
        raise MeshError(
            f"{path}: trimesh read the file, but its geometry or materials could not be "
            f"taken over ({type(exc).__name__}{': ' + text if text else ''})") from exc
    logged = [m for level, m in collect.records if level >= logging.WARNING
              and not (said and m == "unable to load image!")]  # said below, in words
    mesh.problems.extend(f"{path}: {m}" for m in dict.fromkeys(logged))
    # References refused or read from beside the model that no material's
    # line has said (a COLLADA or PLY texture; a glTF's are said per material).
    mesh.problems.extend(f"{path}: {line}" for line in dict.fromkeys(x[1] for x in said))
    return mesh
