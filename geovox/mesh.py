"""Loading polygon models into one plain triangle structure."""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .errors import InputNotFoundError, MeshError


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
    """

    vertices: np.ndarray
    faces: np.ndarray
    source: str = "<mesh>"
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
            used = self.vertices[np.unique(self.faces)]
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
            _, inverse = np.unique(self.vertices, axis=0, return_inverse=True)
            self._cache["geometric_faces"] = inverse.reshape(-1)[self.faces]
        return self._cache["geometric_faces"]


def _check(vertices, faces, source) -> Mesh:
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
    used = vertices[np.unique(faces)]
    if not np.all(np.isfinite(used)):
        bad = int((~np.isfinite(used)).any(axis=1).sum())
        raise MeshError(f"{source}: {bad} vertices have NaN or infinite coordinates")
    return Mesh(vertices=vertices, faces=faces, source=source)


def from_trimesh(obj, source: str = "<trimesh>") -> Mesh:
    """Convert a ``trimesh.Trimesh`` or ``trimesh.Scene`` (transforms applied)."""
    import trimesh

    if isinstance(obj, trimesh.Scene):
        parts = [g for g in obj.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
        if not parts:
            raise MeshError(f"{source}: contains no triangle mesh")
        verts, faces, offset = [], [], 0
        for g in parts:
            verts.append(np.asarray(g.vertices, dtype=np.float64))
            faces.append(np.asarray(g.faces, dtype=np.int64) + offset)
            offset += len(g.vertices)
        return _check(np.concatenate(verts), np.concatenate(faces), source)
    if isinstance(obj, trimesh.Trimesh):
        return _check(obj.vertices, obj.faces, source)
    raise MeshError(f"{source}: contains no triangle mesh (got {type(obj).__name__})")


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
