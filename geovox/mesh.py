"""Loading polygon models into one plain triangle structure."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .errors import InputNotFoundError, MeshError


@dataclass
class Material:
    """An MTL material: the parts that colour a voxel.

    Attributes
    ----------
    name : str
    kd : (3,) float64 or None
        Diffuse colour ``Kd``; None when the file gives none.
    ka : (3,) float64
        Ambient colour ``Ka`` (black when absent).
    texture_file : str or None
        Resolved path of ``map_Kd``.
    defined : bool
        False for a ``usemtl`` name no material file defines.
    """

    name: str = "default"
    kd: np.ndarray | None = None
    ka: np.ndarray = field(default_factory=lambda: np.zeros(3))
    texture_file: str | None = None
    defined: bool = True
    image: np.ndarray | None = field(default=None, repr=False)

    def diffuse(self) -> np.ndarray:
        """``Kd``, or the default: 1 under a texture (so it shows as painted), else 0.8 grey."""
        if self.kd is not None:
            return self.kd
        return np.ones(3) if self.texture_file or self.image is not None else np.full(3, 0.8)


@dataclass
class Mesh:
    """A triangle soup with the facts the pipeline needs.

    Attributes
    ----------
    vertices : (n, 3) float64
    faces : (m, 3) int64
        Indices into ``vertices``. Vertices may be split along UV seams, as
        OBJ files have them; :attr:`geometric_faces` merges them by position.
    source : str
        Where the mesh came from (file path or a description).
    face_material : (m,) int64 or None
        Index into ``materials`` per face; -1 for faces without a material.
    materials : list of Material
    corner_uv : (m, 3, 2) float64 or None
        Texture coordinates of each face corner (NaN where a face has none).
    vertex_colors : (n, 3) float64 or None
        Per-vertex RGB in [0, 1] (OBJ ``v x y z r g b``, or trimesh colours).
    problems : list of str
        Missing or unreadable material files and textures found while
        loading; reported as warnings when colour is asked for.
    """

    vertices: np.ndarray
    faces: np.ndarray
    source: str = "<mesh>"
    face_material: np.ndarray | None = None
    materials: list = field(default_factory=list)
    corner_uv: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None
    problems: list = field(default_factory=list)
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    @property
    def triangles(self) -> np.ndarray:
        """(m, 3, 3) float64: vertex coordinates per face."""
        if "triangles" not in self._cache:
            self._cache["triangles"] = self.vertices[self.faces]
        return self._cache["triangles"]

    @property
    def bounds(self) -> np.ndarray:
        """(2, 3) float64: the bounding box of the faces' vertices."""
        if "bounds" not in self._cache:
            used = _used_vertices(self.vertices, self.faces)
            self._cache["bounds"] = np.stack([used.min(axis=0), used.max(axis=0)])
        return self._cache["bounds"]

    @property
    def scale(self) -> float:
        """Length of the bounding box diagonal (1.0 for a point-like mesh)."""
        d = float(np.linalg.norm(self.bounds[1] - self.bounds[0]))
        return d if d > 0 else 1.0

    @property
    def geometric_faces(self) -> np.ndarray:
        """(m, 3) int64: faces over vertices merged by exact position.

        UV seams split an OBJ vertex into several with the same position;
        ray parity only sees positions, so adjacency is taken from these.
        """
        if "geometric_faces" not in self._cache:
            # np.unique(axis=0)'s numbering (lexicographic by x, y, z), by
            # one lexsort of the columns: several times faster.
            v = self.vertices
            order = np.lexsort((v[:, 2], v[:, 1], v[:, 0]))
            sv = v[order]
            new = np.empty(len(v), dtype=bool)
            new[:1] = True
            np.any(sv[1:] != sv[:-1], axis=1, out=new[1:])
            inverse = np.empty(len(v), dtype=np.int64)
            inverse[order] = np.cumsum(new) - 1
            self._cache["geometric_faces"] = inverse[self.faces]
        return self._cache["geometric_faces"]


def _used_vertices(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(k, 3): the vertices some face uses (all of them, usually, without a copy).

    A mask filled by indexing, not ``np.unique(faces)``: no sort.
    """
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.reshape(-1)] = True
    return vertices if used.all() else vertices[used]


def _check(vertices, faces, source, **extra) -> Mesh:
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"{source}: vertices must have shape (n, 3), got {vertices.shape}")
    if faces.size == 0:
        raise MeshError(f"{source}: the mesh has no faces ({len(vertices)} vertices)")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise MeshError(f"{source}: faces must be triangles with shape (m, 3), got {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(
            f"{source}: faces index vertices that do not exist "
            f"(indices {faces.min()}..{faces.max()}, {len(vertices)} vertices)"
        )
    used = _used_vertices(vertices, faces)
    if not np.all(np.isfinite(used)):
        bad = int((~np.isfinite(used)).any(axis=1).sum())
        raise MeshError(f"{source}: {bad} vertices have NaN or infinite coordinates")
    return Mesh(vertices=vertices, faces=faces, source=source, **extra)


def check_mesh(mesh: Mesh) -> Mesh:
    """Validate a Mesh built elsewhere (shapes, indices, finite coordinates)."""
    extra = {k: getattr(mesh, k) for k in
             ("face_material", "materials", "corner_uv", "vertex_colors", "problems")}
    return _check(mesh.vertices, mesh.faces, mesh.source, **extra)


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
        if image is not None:
            m.image = np.asarray(image.convert("RGB"))
        colour = getattr(mat, "diffuse", None)
        if colour is None:
            colour = getattr(mat, "baseColorFactor", None)
        if colour is not None:
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


def from_trimesh(obj, source: str = "<trimesh>") -> Mesh:
    """Convert a ``trimesh.Trimesh`` or ``trimesh.Scene`` (transforms applied),
    keeping each geometry's material, UVs and vertex colours."""
    import trimesh

    if isinstance(obj, trimesh.Scene):
        parts = [g for g in obj.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
        if not parts:
            raise MeshError(f"{source}: contains no triangle mesh")
    elif isinstance(obj, trimesh.Trimesh):
        parts = [obj]
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
    return _check(
        np.concatenate(verts), np.concatenate(faces), source,
        face_material=np.concatenate(fms),
        materials=materials,
        corner_uv=np.concatenate(uvs) if have_uv else None,
        vertex_colors=np.concatenate(vcs) if have_vc else None,
    )


def load_mesh(source) -> Mesh:
    """Load a mesh from a path, a trimesh object, or pass a :class:`Mesh` through.

    Parameters
    ----------
    source : str, os.PathLike, Mesh, trimesh.Trimesh or trimesh.Scene

    Raises
    ------
    InputNotFoundError
        The path does not exist or is a folder.
    MeshError
        The file cannot be read as a mesh, or the mesh has no usable faces.
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
        import trimesh

        try:
            loaded = trimesh.load(path, process=False)
        except Exception as exc:  # trimesh raises many types for unreadable files
            reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            raise MeshError(f"{path}: cannot be read as a mesh ({reason})") from exc
        return from_trimesh(loaded, source=path)
    try:
        return from_trimesh(source, source=f"<{type(source).__name__}>")
    except MeshError:
        raise MeshError(
            f"`mesh` must be a file path, a trimesh.Trimesh or a trimesh.Scene, "
            f"got {type(source).__name__}"
        ) from None
