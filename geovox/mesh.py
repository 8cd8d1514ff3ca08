"""Mesh and Material: the plain structure every reader fills (the data model).

The OBJ reader (:mod:`geovox.io.obj`) and the loader of every other format
(:mod:`geovox.io.load`) both build these; keeping them here, with no I/O, lets
the two readers import this module instead of each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .errors import MeshError


#: Texture wrap modes, by glTF sampler code (OBJ textures always repeat).
WRAP_MODES = {10497: "repeat", 33648: "mirror", 33071: "clamp"}


@dataclass
class Material:
    """A material: the parts that colour a voxel.

    An MTL material, or a glTF one (``kd`` is then ``baseColorFactor``, or
    the specular-glossiness ``diffuseFactor``, and ``image`` its texture).

    Attributes
    ----------
    name : str
    kd : (3,) float64 or None
        Diffuse colour ``Kd``; None when the file gives none.
    ka : (3,) float64
        Ambient colour ``Ka`` (black when absent).
    texture_file : str or None
        Resolved path of ``map_Kd``, or of a glTF material's external image.
    defined : bool
        False for a ``usemtl`` name no material file defines.
    image : (h, w, 3) uint8 or None
        The texture's texels as stored (sRGB), once read.
    wrap : (str, str)
        How UVs outside [0, 1] wrap along u and v: ``"repeat"``, ``"mirror"``
        (glTF MIRRORED_REPEAT), ``"clamp"`` (CLAMP_TO_EDGE: the edge texels
        beyond) or ``"border"`` (MTL ``-clamp on``: one copy of the texture;
        beyond it the face is coloured as if it had no texture).
    uv_transform : (3, 3) float64 or None
        Affine map applied to the texture coordinates before sampling (MTL
        ``-o``/``-s``); the OBJ reader has already applied it to
        :attr:`Mesh.corner_uv`, so it is informational.
    ignored_options : list of (str, list of str, str)
        ``map_Kd`` options that are not applied: option, values, what it does.
    ambient_map : str or None
        The ``map_Ka`` statement's argument, which is not read (said with
        ``ambient``).
    vertex_tint : bool
        Whether vertex colours multiply the texture (glTF's ``COLOR_0``) rather
        than being replaced by it (OBJ's ``v x y z r g b``).
    """

    name: str = "default"
    kd: np.ndarray | None = None
    ka: np.ndarray = field(default_factory=lambda: np.zeros(3))
    texture_file: str | None = None
    defined: bool = True
    image: np.ndarray | None = field(default=None, repr=False)
    wrap: tuple = ("repeat", "repeat")
    vertex_tint: bool = False
    uv_transform: np.ndarray | None = field(default=None, repr=False)
    ignored_options: list = field(default_factory=list, repr=False)
    ambient_map: str | None = None

    def diffuse(self) -> np.ndarray:
        """``Kd``, or the default: 1 under a texture (so it shows as painted), else 0.8 grey."""
        if self.kd is not None:
            return self.kd
        return np.ones(3) if self.texture_file or self.image is not None else np.full(3, 0.8)


def transform_uv(uv: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``t`` (3, 3) applied to texture coordinates ``uv`` (..., 2) as points; NaN stays NaN.

    Affine, so transforming a face's corner UVs is the same as transforming
    the UVs interpolated between them.
    """
    u, v = uv[..., 0], uv[..., 1]
    return np.stack([t[0, 0] * u + t[0, 1] * v + t[0, 2],
                     t[1, 0] * u + t[1, 1] * v + t[1, 2]], axis=-1)


def texels(image) -> np.ndarray:
    """(h, w, 3) uint8: a Pillow image's colours as stored, alpha dropped.

    No colour-space conversion: an sRGB texture keeps its sRGB values.
    Alpha is not applied: an RGBA, LA or PA texel gives its colour channels
    as stored (straight, not multiplied by alpha; a premultiplied ``RGBa`` or
    ``La`` image is divided back). Grey images (L, LA, 1) give the grey in
    all three channels, palette images (P, PA) their palette's colours.
    Pillow opens 16-bit grey PNGs as mode ``I;16`` (or ``I``), whose RGB
    conversion clips them at 255 (nearly everything white), so those are
    scaled by 1/257; a float image (``F``) is taken as 0-1, or 0-255 when a
    value exceeds 1.
    """
    mode = image.mode
    if mode == "I" or mode.startswith("I;16") or mode == "F":
        grey = np.asarray(image, dtype=np.float64)
        if mode == "F":
            finite = grey[np.isfinite(grey)]
            grey = np.nan_to_num(grey, nan=0.0) * (255.0 if finite.size == 0 or finite.max() <= 1.0
                                                   else 1.0)
        else:
            grey = np.clip(grey, 0, 65535) / 257.0
        grey = np.rint(np.clip(grey, 0, 255)).astype(np.uint8)
        return np.repeat(grey[..., None], 3, axis=2)
    if mode == "La":
        image = image.convert("LA")  # Pillow converts La to nothing else
    return np.asarray(image.convert("RGB"))


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
    face_part : (m,) int64 or None
        Index into ``parts`` per face: the file's own parts (OBJ ``o``
        objects, or ``g`` groups where there are none; a scene's nodes).
        None when the file names no parts.
    parts : list of str
        The parts' names, in file order.
    face_feature : (m,) int64 or None
        Each face's feature ID (glTF ``EXT_mesh_features``: its first vertex's
        ID in the primitive's first feature ID set); -1 for faces without one.
        None when the file has no feature IDs.
    """

    vertices: np.ndarray
    faces: np.ndarray
    source: str = "<mesh>"
    face_material: np.ndarray | None = None
    materials: list = field(default_factory=list)
    corner_uv: np.ndarray | None = None
    vertex_colors: np.ndarray | None = None
    problems: list = field(default_factory=list)
    face_part: np.ndarray | None = None
    parts: list = field(default_factory=list)
    face_feature: np.ndarray | None = None
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
            # Column by column: NumPy reduces a long (n, 3) array along axis 0
            # ten times slower (1 s for the min and max of 19M vertices).
            self._cache["bounds"] = np.array([[used[:, k].min() for k in range(3)],
                                              [used[:, k].max() for k in range(3)]])
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


def build_mesh(vertices, faces, source, **extra) -> Mesh:
    """A :class:`Mesh` of these arrays once they are checked (shapes, indices, finite).

    Raises
    ------
    MeshError
        Naming ``source`` and what is wrong.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"{source}: vertices must have shape (n, 3), got {vertices.shape}")
    if faces.size == 0:
        raise MeshError(f"{source}: has no faces, only {len(vertices):,} "
                        f"{'vertex' if len(vertices) == 1 else 'vertices'}; geovox voxelises "
                        f"the inside of a triangle surface")
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
             ("face_material", "materials", "corner_uv", "vertex_colors", "problems",
              "face_part", "parts", "face_feature")}
    return build_mesh(mesh.vertices, mesh.faces, mesh.source, **extra)
