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

The nearest surface point is exact: the triangle at the smallest Euclidean
distance from the voxel centre (ties within 1e-9 voxel sizes go to the
smallest triangle index) and the closest point on it, found for every inside
voxel by :func:`geovox.nearest.nearest_inside` (a branch and bound over
voxel cells that drops a triangle only where a valid bound proves it
farther). Where every triangle still in the running for a block of voxels
has the same constant colour (no texture, no vertex colours), that colour is
used without finding which of them is nearest.
"""

from __future__ import annotations

import warnings

import numpy as np

from .errors import GeovoxWarning

#: Inside voxels processed per block (small enough to stay in cache).
BLOCK = 1 << 19
#: Colour of faces without any material (and no vertex colours).
DEFAULT_GREY = 0.8


def load_textures(mesh) -> None:
    """Read each material's texture once; warn about what is missing or unreadable."""
    from PIL import Image

    for m in mesh.materials:
        if m.image is not None or not m.texture_file or getattr(m, "_tried", False):
            continue
        m._tried = True
        try:
            with Image.open(m.texture_file) as im:
                m.image = np.asarray(im.convert("RGB"))
        except Exception as exc:  # Pillow raises several types for bad files
            warnings.warn(f"cannot read texture {m.texture_file} (material {m.name!r}): "
                          f"{exc}; using its Kd colour", GeovoxWarning, stacklevel=3)


def sample_bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Bilinear texture lookup with wrapping; OBJ's V points up, image rows down.

    Parameters
    ----------
    image : (h, w, 3) uint8
    uv : (n, 2) float64

    Returns
    -------
    (n, 3) float64 in [0, 1]
    """
    h, w = image.shape[:2]
    flat = image.reshape(h * w, -1)
    x = np.mod(uv[:, 0], 1.0) * w - 0.5
    y = (1.0 - np.mod(uv[:, 1], 1.0)) * h - 0.5
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = (x - x0)[:, None]
    fy = (y - y0)[:, None]
    x0 = x0.astype(np.int64) % w
    y0 = y0.astype(np.int64) % h
    x1 = (x0 + 1) % w
    r0 = y0 * w
    r1 = ((y0 + 1) % h) * w
    top = flat[r0 + x0] * (1 - fx) + flat[r0 + x1] * fx
    bottom = flat[r1 + x0] * (1 - fx) + flat[r1 + x1] * fx
    return (top * (1 - fy) + bottom * fy) / 255.0


def shade(mesh, tri: np.ndarray, bary: np.ndarray, *, diffuse=True, ambient=False) -> np.ndarray:
    """Colour of surface points given by triangle and barycentric ``(u, v)``.

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
    if no_material.any() and diffuse and mesh.vertex_colors is None:
        factor[no_material] = DEFAULT_GREY
    for k, m in enumerate(mesh.materials):
        sel = np.flatnonzero(fm == k)
        if len(sel) == 0 or not m.defined:
            continue
        if m.image is not None and mesh.corner_uv is not None:
            uv = np.einsum("nk,nkc->nc", w[sel], mesh.corner_uv[tri[sel]])
            ok = np.isfinite(uv).all(axis=1)
            base[sel[ok]] = sample_bilinear(m.image, uv[ok])
        if diffuse:
            factor[sel] = m.diffuse()
        if ambient:
            add[sel] = m.ka
    return np.clip(base * factor + add, 0.0, 1.0)


def closest_on_triangles(p: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """Barycentric ``(u, v)`` of the closest point on each triangle to each point.

    Parameters
    ----------
    p : (n, 3) float64
    tris : (n, 3, 3) float64

    Returns
    -------
    (n, 2) float64: weights of vertices 1 and 2.

    Notes
    -----
    The Voronoi-region test of Ericson, *Real-Time Collision Detection*, 5.1.5.
    """
    a, b, c = tris[:, 0], tris[:, 1], tris[:, 2]
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = va + vb + vc
        u = np.where(denom != 0, vb / denom, 0.0)
        v = np.where(denom != 0, vc / denom, 0.0)
        # Edges and vertices, lowest priority first so the checks of
        # Ericson's order win where regions touch.
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        m = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        u = np.where(m, 1 - t, u)
        v = np.where(m, t, v)
        t = d2 / (d2 - d6)
        m = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        u = np.where(m, 0.0, u)
        v = np.where(m, t, v)
        m = (d6 >= 0) & (d5 <= d6)
        u = np.where(m, 0.0, u)
        v = np.where(m, 1.0, v)
        t = d1 / (d1 - d3)
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        u = np.where(m, t, u)
        v = np.where(m, 0.0, v)
        m = (d3 >= 0) & (d4 <= d3)
        u = np.where(m, 1.0, u)
        v = np.where(m, 0.0, v)
        m = (d1 <= 0) & (d2 <= 0)
        u = np.where(m, 0.0, u)
        v = np.where(m, 0.0, v)
    bad = ~(np.isfinite(u) & np.isfinite(v))
    u[bad] = 0.0
    v[bad] = 0.0
    return np.stack([u, v], axis=1)


def constant_colours(mesh, *, diffuse=True, ambient=False):
    """Triangles whose whole face has one colour, keyed by that colour.

    Returns
    -------
    key : (t,) int64
        Equal keys >= 0 for triangles of the same constant colour (no
        texture sampled and no vertex colours); -1 where the colour varies
        over the face.
    rgba : (k,) uint32
        The packed colour of each key (see :func:`_pack`).
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
    rgba = _pack(shade(mesh, sel, np.full((len(sel), 2), 1 / 3), diffuse=diffuse,
                       ambient=ambient))
    values, inverse = np.unique(rgba, return_inverse=True)
    key[sel] = inverse.reshape(-1)
    return key, values


def colour_volume(mesh, grid, occupancy, *, diffuse=True, ambient=False, jobs=1,
                  frame=None) -> np.ndarray:
    """RGBA colours of the inside voxels, from their exact nearest surface points; alpha 0 outside.

    Parameters
    ----------
    mesh : Mesh
    grid : Grid
        The block's grid.
    occupancy : (nx, ny, nz) bool
    frame : (lo, spacing, z0), optional
        The whole grid's low corner and voxel size, and the block's first
        layer in it (default: this grid, layer 0). Voxel centres are
        computed from these, so a slab's colours are the whole grid's bit
        for bit.

    Returns
    -------
    colors : (nx, ny, nz, 4) uint8
        Indexed ``[x, y, z, channel]``; in memory RGBA-interleaved with x
        fastest (``colors.transpose(2, 1, 0, 3)`` is C-contiguous).
    """
    from .nearest import nearest_inside

    for problem in mesh.problems:
        warnings.warn(problem, GeovoxWarning, stacklevel=3)
    load_textures(mesh)
    nx, ny, nz = grid.shape
    base = np.zeros((nz, ny, nx, 4), dtype=np.uint8)
    colors = base.transpose(2, 1, 0, 3)
    lo, spacing, z0 = frame if frame is not None else (grid.lo, grid.spacing, 0)
    key, key_rgba = constant_colours(mesh, diffuse=diffuse, ambient=ambient)
    # One uint32 per voxel: RGBA bytes in memory order (index = F-order voxel index).
    flat = base.reshape(-1, 4).view(np.uint32).reshape(-1)

    def emit(vox, tri, uv):
        k = key[tri]
        rgba = np.zeros(len(tri), np.uint32)
        const = k >= 0
        rgba[const] = key_rgba[k[const]]
        vary = np.flatnonzero(~const)
        if len(vary):
            rgba[vary] = _pack(shade(mesh, tri[vary], uv[vary], diffuse=diffuse, ambient=ambient))
        flat[vox[:, 0] + nx * (vox[:, 1] + ny * vox[:, 2])] = rgba

    nearest_inside(mesh.triangles, occupancy, spacing, origin=lo, z0=z0, jobs=jobs, emit=emit,
                   same=key)
    return colors


def _pack(rgb: np.ndarray) -> np.ndarray:
    """(n, 3) floats in [0, 1] -> (n,) uint32 holding bytes R, G, B, 255 in memory order."""
    out = np.empty((len(rgb), 4), dtype=np.uint8)
    out[:, :3] = np.rint(rgb * 255.0)
    out[:, 3] = 255
    return out.view(np.uint32).reshape(-1)
