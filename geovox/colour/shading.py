"""Colour: every inside voxel takes the colour of its nearest surface point.

The colour of a surface point on triangle ``t`` with barycentric weights
``(1-u-v, u, v)`` is, per channel and clipped to [0, 1]::

    colour = base * D + A
    base   = map_Kd texture at the interpolated UV (bilinear, UVs wrap, V up)
             if the face's material has a readable texture and the face UVs;
             else the interpolated vertex colour if the mesh has them;
             else 1
    D      = the material's Kd if `diffuse` else 1   (Kd defaults to 1 under a
             texture and to 0.8 grey without; faces with no material at all
             use D = 0.8 grey, or 1 when the mesh has vertex colours)
    A      = the material's Ka if `ambient` else 0

Here: the shading itself (:func:`shade`, its compiled tables :func:`shading_tables`), the
textures (loaded while the rays run, :func:`prefetch_textures`) and the constant colours that
let both colour methods skip their search (:func:`constant_colours`). The two methods that find
each voxel's surface point are :mod:`geovox.colour.exact` and :mod:`geovox.colour.fast`.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..errors import warn


#: Colour of faces without any material (and no vertex colours).
DEFAULT_GREY = 0.8


class Shading(NamedTuple):
    """How a surface point's colour is lit: the ``D`` and ``A`` of the formula above.

    The colour stage's record of the options ``diffuse`` and ``ambient``
    (:meth:`of`), handed down instead of the two keywords.
    """

    diffuse: bool = True  #: multiply by the material's Kd
    ambient: bool = False  #: add the material's Ka

    @classmethod
    def of(cls, options) -> "Shading":
        """The shading an :class:`~geovox.Options` asks for."""
        return cls(bool(options.diffuse), bool(options.ambient))


def load_textures(mesh, shading: Shading = Shading()) -> None:
    """Read each material's texture once; warn about what is missing or unreadable.

    With ``shading.ambient``, also say which materials have an ambient
    texture (``map_Ka``), which is not read: their ``A`` is ``Ka`` alone.
    """
    from PIL import Image

    from ..mesh import texels

    if shading.ambient:
        named = [m.name for m in mesh.materials if getattr(m, "ambient_map", None)]
        if named:
            shown = ", ".join(repr(n) for n in named[:3]) + (", ..." if len(named) > 3 else "")
            warn(f"{mesh.source}: the ambient textures (map_Ka) of material"
                 f"{'s' if len(named) > 1 else ''} {shown} are not read; the ambient colour "
                 f"added is their Ka alone", stacklevel=3)
    for m in mesh.materials:
        if m.image is not None or not m.texture_file or getattr(m, "_tried", False):
            continue
        m._tried = True
        try:
            with Image.open(m.texture_file) as im:
                m.image = texels(im)
        except Exception as exc:  # Pillow raises several types for bad files
            warn(f"cannot read texture {m.texture_file} (material {m.name!r}): "
                 f"{exc}; using its Kd colour", stacklevel=3)


def prefetch_textures(mesh):
    """Start decoding the textures :func:`load_textures` will read, on a thread.

    The colour step needs them only after the rays and the fill, and
    decoding one takes a while (spot's 1024² PNG: about 0.05 s, a tenth of
    its 256³ run), so the pipeline starts it as soon as the mesh is loaded.
    Only plain PNG and JPEG files whose header opens without a warning are
    read ahead (their decoding warns about nothing, so no warning is raised
    on the thread); any other file, and any failure, is left to
    :func:`load_textures`, which reads and reports it as before.

    Returns
    -------
    callable or None
        ``finish()`` waits for the thread and puts the textures it decoded in
        place (``Material.image``); None where there is nothing to read ahead.
    """
    import threading
    import warnings

    todo = []
    for m in mesh.materials:
        if m.image is not None or not m.texture_file or getattr(m, "_tried", False):
            continue
        from PIL import Image

        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")
                with Image.open(m.texture_file) as im:
                    plain = (im.format in ("PNG", "JPEG") and im.mode in ("RGB", "RGBA", "L", "LA")
                             and getattr(im, "n_frames", 1) == 1)
        except Exception:  # Pillow raises several types for bad files; load_textures says which
            plain = False
        if plain:
            todo.append(m)
    if not todo:
        return None
    images = {}

    def read():
        from PIL import Image

        from ..mesh import texels

        for m in todo:
            try:
                with Image.open(m.texture_file) as im:
                    images[id(m)] = texels(im)
            except Exception:  # left to load_textures, which warns
                pass

    thread = threading.Thread(target=read, name="geovox-textures", daemon=True)
    thread.start()

    def finish():
        thread.join()
        for m in todo:
            if m.image is None and id(m) in images:
                m.image = images[id(m)]
                m._tried = True

    return finish


def _texel_axis(t: np.ndarray, n: int, mode: str) -> tuple:
    """Texels ``i0``, ``i1`` (int64) and the weight of ``i1`` along one texture axis.

    ``t`` runs along the image's rows or columns (0 at the first texel's outer
    edge, 1 at the last's); wrap modes act on texel indices as OpenGL's do.
    """
    # Reduce t first (exact for each mode) so huge UVs keep their fraction.
    # "border" samples like "clamp" (the caller leaves out UVs beyond the texture).
    if mode == "border":
        mode = "clamp"
    t = np.clip(t, 0.0, 1.0) if mode == "clamp" else np.mod(t, 2.0 if mode == "mirror" else 1.0)
    x = t * n - 0.5
    x0 = np.floor(x)
    f = x - x0
    i0 = x0.astype(np.int64)
    i1 = i0 + 1
    if mode == "clamp":
        return np.clip(i0, 0, n - 1), np.clip(i1, 0, n - 1), f
    if mode == "mirror":
        i0, i1 = np.mod(i0, 2 * n), np.mod(i1, 2 * n)
        return np.where(i0 >= n, 2 * n - 1 - i0, i0), np.where(i1 >= n, 2 * n - 1 - i1, i1), f
    return np.mod(i0, n), np.mod(i1, n), f


def sample_bilinear(image: np.ndarray, uv: np.ndarray, wrap=("repeat", "repeat")) -> np.ndarray:
    """Bilinear texture lookup; V points up (OBJ, and glTF's as trimesh flips it), rows down.

    Parameters
    ----------
    image : (h, w, 3) uint8
    uv : (n, 2) float64
    wrap : (str, str)
        Wrap mode along u and along v: ``"repeat"``, ``"mirror"``,
        ``"clamp"`` or ``"border"`` (sampled as ``"clamp"``; see
        :func:`on_texture` and :attr:`geovox.mesh.Material.wrap`).

    Returns
    -------
    (n, 3) float64 in [0, 1]
    """
    h, w = image.shape[:2]
    flat = image.reshape(h * w, -1)
    x0, x1, fx = _texel_axis(uv[:, 0], w, wrap[0])
    # Rows run down the image: row coordinate 1 - v (glTF's own V).
    y0, y1, fy = _texel_axis(1.0 - uv[:, 1], h, wrap[1])
    fx = fx[:, None]
    fy = fy[:, None]
    r0 = y0 * w
    r1 = y1 * w

    def texel(i):  # np.take: several times faster than fancy-indexing rows
        return np.take(flat, i, axis=0)

    top = texel(r0 + x0) * (1 - fx) + texel(r0 + x1) * fx
    bottom = texel(r1 + x0) * (1 - fx) + texel(r1 + x1) * fx
    return (top * (1 - fy) + bottom * fy) / 255.0


def on_texture(uv: np.ndarray, wrap) -> np.ndarray:
    """(n,) bool: finite UVs that fall on the texture (within [0, 1] along each ``"border"`` axis).

    The bounds have a margin of 1e-9: UVs interpolated between corners at
    exactly 0 or 1 (a UV island on the texture's edge) round a little past it.
    """
    ok = np.isfinite(uv).all(axis=1)
    for axis, mode in enumerate(wrap):
        if mode == "border":
            ok &= (uv[:, axis] >= -1e-9) & (uv[:, axis] <= 1.0 + 1e-9)
    return ok


def shade(mesh, tri: np.ndarray, bary: np.ndarray, shading: Shading = Shading()) -> np.ndarray:
    """Colour of surface points given by triangle and barycentric ``(u, v)``, lit by ``shading``.

    Returns
    -------
    (n, 3) float64 in [0, 1]
    """
    n = len(tri)
    w = np.empty((n, 3))
    w[:, 1:] = bary
    w[:, 0] = 1.0 - bary[:, 0] - bary[:, 1]
    if mesh.vertex_colors is not None:
        base = np.einsum("nk,nkc->nc", w, mesh.vertex_colors[mesh.faces[tri]])
    else:
        base = np.ones((n, 3))
    fm = mesh.face_material[tri] if mesh.face_material is not None else np.full(n, -1)
    factor = np.ones((n, 3))
    add = np.zeros((n, 3))
    # A `usemtl` name that no material file defines counts as no material.
    undefined = np.array([not m.defined for m in mesh.materials] + [True])
    no_material = undefined[fm]  # fm == -1 picks the final True
    diffuse, ambient = shading
    if no_material.any() and diffuse and mesh.vertex_colors is None:
        factor[no_material] = DEFAULT_GREY
    for k, m in enumerate(mesh.materials):
        sel = np.flatnonzero(fm == k)
        if len(sel) == 0 or not m.defined:
            continue
        if m.image is not None and mesh.corner_uv is not None:
            uv = np.einsum("nk,nkc->nc", w[sel], np.take(mesh.corner_uv, tri[sel], axis=0))
            ok = on_texture(uv, m.wrap)
            texel = sample_bilinear(m.image, uv[ok], m.wrap)
            # glTF's COLOR_0 multiplies the texture; OBJ's vertex colours give way to it.
            base[sel[ok]] = texel * base[sel[ok]] if m.vertex_tint else texel
        if diffuse:
            factor[sel] = m.diffuse()
        if ambient:
            add[sel] = m.ka
    return np.clip(base * factor + add, 0.0, 1.0)


def unit_normals(mesh) -> np.ndarray:
    t = mesh.triangles
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(length > 0, n / length, 0.0)


def constant_colours(mesh, shading: Shading = Shading()):
    """Triangles whose whole face has one colour (lit by ``shading``), keyed by that colour.

    Returns
    -------
    key : (t,) int64
        Equal keys >= 0 for triangles of the same constant colour (no
        texture sampled and no vertex colours); -1 where the colour varies
        over the face.
    rgba : (k,) uint32
        The packed colour of each key (see :func:`pack`).
    """
    n = len(mesh.faces)
    key = np.full(n, -1, np.int64)
    if mesh.vertex_colors is not None or n == 0:
        return key, np.zeros(0, np.uint32)
    flat = np.ones(n, bool)
    if mesh.face_material is not None and mesh.corner_uv is not None:
        textured = np.array([m.defined and m.image is not None for m in mesh.materials] + [False])
        fm = mesh.face_material
        uv_ok = np.isfinite(mesh.corner_uv).all(axis=(1, 2))
        flat = ~(textured[fm] & uv_ok)
    sel = np.flatnonzero(flat)
    if len(sel) == 0:
        return key, np.zeros(0, np.uint32)
    rgba = pack(shade(mesh, sel, np.full((len(sel), 2), 1 / 3), shading))
    values, inverse = np.unique(rgba, return_inverse=True)
    key[sel] = inverse.reshape(-1)
    return key, values


#: Texture wrap modes as the compiled kernel numbers them.
_WRAP_CODE = {"repeat": 0, "mirror": 1, "clamp": 2, "border": 3}


def shading_tables(mesh, shading: Shading = Shading()) -> tuple:
    """What the compiled kernel needs to do :func:`shade`'s arithmetic, as flat arrays.

    One row per material plus a last one for faces without a (defined)
    material, holding exactly the factors :func:`shade` applies.

    Returns
    -------
    None, where a material has something the kernel does not do (a wrap
    mode it does not know, a texture not (h, w, 3) uint8): :func:`shade` then
    colours the voxels. Otherwise:

    fmat : (t,) int32
        Each face's row.
    vc : (9 t,) float64 or None
        Corner colours ``vertex_colors[faces]`` (t, 3, 3), flattened.
    cuv : (6 t,) float64 or None
        Corner UVs (t, 3, 2), flattened, where some row is textured.
    factor, add : (k, 3) float64
        Multiplied (Kd, or the default grey) and added (Ka).
    mint : (k, 7) int32
        Textured, vertex tint, texture height, width, wrap along u, along v, 0.
    moff : (k,) int64
        Offset of each row's texture in ``tex``.
    tex : (n,) uint8
        The textures' (h, w, 3) texels, one after another.
    """
    n = len(mesh.faces)
    nm = len(mesh.materials)
    fm = mesh.face_material if mesh.face_material is not None else np.full(n, -1)
    rows = np.where(fm < 0, nm, fm).astype(np.int32)
    factor = np.ones((nm + 1, 3))
    add = np.zeros((nm + 1, 3))
    mint = np.zeros((nm + 1, 7), np.int32)
    moff = np.zeros(nm + 1, np.int64)
    images, offset = [], 0
    vc = None
    if mesh.vertex_colors is not None:
        vc = np.ascontiguousarray(mesh.vertex_colors[mesh.faces], dtype=np.float64).reshape(-1)
    diffuse, ambient = shading
    if diffuse and mesh.vertex_colors is None:
        factor[nm] = DEFAULT_GREY  # no material at all
    for k, m in enumerate(mesh.materials):
        if not m.defined:  # a `usemtl` name no material file defines counts as no material
            factor[k] = factor[nm]
            continue
        if m.image is not None and mesh.corner_uv is not None:
            img = np.ascontiguousarray(m.image)
            if (img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3
                    or any(w not in _WRAP_CODE for w in m.wrap)):
                return None
            mint[k, :6] = (1, bool(m.vertex_tint), img.shape[0], img.shape[1],
                           _WRAP_CODE[m.wrap[0]], _WRAP_CODE[m.wrap[1]])
            moff[k] = offset
            images.append(img.reshape(-1))
            offset += img.size
        if diffuse:
            factor[k] = m.diffuse()
        if ambient:
            add[k] = m.ka
    cuv = None
    if mint[:, 0].any():
        cuv = np.ascontiguousarray(mesh.corner_uv, dtype=np.float64).reshape(-1)
    tex = np.concatenate(images) if images else np.zeros(1, np.uint8)
    return rows, vc, cuv, factor, add, mint, moff, tex


def pack(rgb: np.ndarray) -> np.ndarray:
    """(n, 3) floats in [0, 1] -> (n,) uint32 holding bytes R, G, B, 255 in memory order."""
    out = np.empty((len(rgb), 4), dtype=np.uint8)
    out[:, :3] = np.rint(rgb * 255.0)
    out[:, 3] = 255
    return out.view(np.uint32).reshape(-1)
