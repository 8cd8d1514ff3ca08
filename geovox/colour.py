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

The nearest surface point is exact by default (``color=True`` or
``"exact"``, :func:`exact_colours`): the triangle at the smallest Euclidean
distance from the voxel centre (ties within 1e-9 voxel sizes go to the
smallest triangle index) and the closest point on it, for every inside
voxel. The compiled kernel (``geovox/_nearest.pyx``, built by ``pip
install``) finds it and shades it; without it, :func:`geovox.nearest.nearest_inside`'s
NumPy search and :func:`shade` give the same colours, slower (a branch and
bound over voxel cells that drops a triangle only where a valid bound proves
it farther; where every triangle still in the running for a block of voxels
has the same constant colour, that colour is used without finding which of
them is nearest). It needs no rays.

With ``color="fast"`` (``--fast-color``) the nearest surface point is found
in columns, from the ray hits themselves (every hit already carries its
triangle and barycentric coordinates): rays are cast along all three axes,
and for each inside voxel the crossings just before and just after it in its
x, y and z columns are the candidates. The nearest of these six by distance
to the crossing triangle's plane (see :func:`nearest_crossings`) is taken,
and for voxels within ``REFINE`` voxels of the surface the exact closest
point on that crossing's triangle replaces the crossing. Deeper voxels take
the crossing's own colour. The result equals the brute-force nearest point
wherever the nearest triangle is one of the six candidates (nearly always
next to the surface; measured in tests/test_colour.py), and is otherwise a
nearby point of the surface.
"""

from __future__ import annotations


import numpy as np

from .errors import warn
from .parallel import for_blocks, scan_along

#: Voxels whose nearest axis crossing is closer than this many voxels get the
#: exact closest point on that crossing's triangle.
REFINE = 2.0
#: Inside voxels processed per block (small enough to stay in cache).
BLOCK = 1 << 19
#: Colour of faces without any material (and no vertex colours).
DEFAULT_GREY = 0.8


def load_textures(mesh) -> None:
    """Read each material's texture once; warn about what is missing or unreadable."""
    from PIL import Image

    from .surface import texels

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


def _texel_axis(t: np.ndarray, n: int, mode: str) -> tuple:
    """Texels ``i0``, ``i1`` (int64) and the weight of ``i1`` along one texture axis.

    ``t`` runs along the image's rows or columns (0 at the first texel's outer
    edge, 1 at the last's); wrap modes act on texel indices as OpenGL's do.
    """
    # Reduce t first (exact for each mode) so huge UVs keep their fraction.
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
        Wrap mode along u and along v: ``"repeat"``, ``"mirror"`` or
        ``"clamp"`` (see :attr:`geovox.surface.Material.wrap`).

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
            texel = sample_bilinear(m.image, uv[ok], m.wrap)
            # glTF's COLOR_0 multiplies the texture; OBJ's vertex colours give way to it.
            base[sel[ok]] = texel * base[sel[ok]] if m.vertex_tint else texel
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


def _unit_normals(mesh) -> np.ndarray:
    t = mesh.triangles
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(length > 0, n / length, 0.0)


def relevant_crossings(hits, k, n: int, rays: int):
    """The crossings a grid of ``n`` voxels along the rays can need.

    A voxel uses the deepest crossing at or before its centre and the one
    after it, so of the crossings before the first centre (``k == 0``) only
    the deepest on each ray matters, and of those past the last (``k == n``)
    only the shallowest. Dropping the rest before sorting matters when the
    grid is one slab of a long ray: most of its crossings lie outside.

    Parameters
    ----------
    hits : Hits
    k : (h,) int
        Index of the first voxel centre at or past each crossing.
    n : int
        Voxels along the rays.
    rays : int
        Number of rays.
    """
    inner = (k > 0) & (k < n)
    if inner.all():
        return hits
    if hits.ordered:
        # In ray-then-depth order the ones to keep are where k changes side.
        same_next = np.r_[hits.ray[1:] == hits.ray[:-1], False]
        same_prev = np.r_[False, same_next[:-1]]
        k_next = np.r_[k[1:], n + 1]
        k_prev = np.r_[-1, k[:-1]]
        keep = (inner | ((k == 0) & ~(same_next & (k_next == 0)))
                | ((k == n) & ~(same_prev & (k_prev == n))))
        out = hits.take(keep)
        out.ordered = True
        return out
    keep = [np.flatnonzero(inner)]
    for side, pick in ((0, np.maximum), (n, np.minimum)):
        sub = np.flatnonzero(k == side)
        if len(sub) == 0:
            continue
        ray, depth = hits.ray[sub], hits.depth[sub]
        # The extreme depth per ray, then among equal depths the extreme
        # triangle: the first or last of the ray in sorted (depth, triangle) order.
        ext = np.full(rays, np.inf if pick is np.minimum else -np.inf)
        pick.at(ext, ray, depth)
        sub = sub[depth == ext[ray]]
        tri = hits.triangle[sub]
        ray = hits.ray[sub]
        best = np.full(rays, np.iinfo(np.int64).max if pick is np.minimum else -1, dtype=np.int64)
        pick.at(best, ray, tri)
        keep.append(sub[tri == best[ray]])
    return hits.take(np.sort(np.concatenate(keep)))


def nearest_crossings(mesh, grid, occupancy, cast, jobs=1):
    """For every inside voxel, the nearest crossing among its six axis neighbours.

    Parameters
    ----------
    grid : Grid
    occupancy : (nx, ny, nz) bool, Fortran order
    cast : dict axis -> (Hits, Columns)
        Crossings of the grid's column rays along each axis.

    Returns
    -------
    inside : (k,) int64
        F-order linear indices of the inside voxels.
    hits : Hits
        The crossings of all axes, concatenated (each axis sorted by ray,
        then depth).
    best : (k,) int64
        Index into ``hits`` of each inside voxel's nearest crossing.
    dist : (k,) float32
        Estimated distance from the voxel centre to the surface there, in
        voxels.

    Notes
    -----
    A crossing at axis distance ``d`` on a triangle with unit normal ``n``
    is ranked by ``d * max(|n_axis|, 1/sqrt(3))``: the distance to the
    triangle's plane where that plane faces the axis, which is the true
    distance for the axis that sees the nearest surface best (some axis has
    ``|n_axis| >= 1/sqrt(3)``), while a crossing far along the axis cannot win
    just because its plane happens to pass close by.
    """
    from .backends.base import Hits

    nx, ny, nz = grid.shape
    inside = np.flatnonzero(occupancy.reshape(-1, order="F"))
    strides = (1, nx, nx * ny)

    def coord(axis, vox):  # voxel coordinate along `axis` of F-order indices
        c = vox // strides[axis] if axis else vox
        return c % grid.shape[axis] if axis < 2 else c
    best_d = np.full(len(inside), np.inf, dtype=np.float32)
    best = np.zeros(len(inside), np.int64)
    scale = grid.spacing.min()
    normals = _unit_normals(mesh)
    parts, offset = [], 0
    g = None  # one int32 volume, refilled for each axis (its pages are touched once)
    for axis in (2, 1, 0):  # ties go to z, then y, then x
        if axis not in cast:
            continue
        hits, cols = cast[axis]
        n_axis = grid.shape[axis]
        centres = (np.arange(n_axis) + 0.5) * grid.spacing[axis]  # from the low face, like depths
        hits = relevant_crossings(hits, np.searchsorted(centres, hits.depth, side="left"),
                                  n_axis, cols.count).sorted()
        parts.append(hits)
        k = np.searchsorted(centres, hits.depth, side="left")
        centres32 = centres.astype(np.float32)
        idx = [None, None, None]
        idx[cols.u_axis] = hits.ray % cols.nu
        idx[cols.v_axis] = hits.ray // cols.nu
        idx[axis] = k
        # The deepest crossing at or before each voxel: a running maximum of
        # hit numbers (sorted by ray, then depth, so deeper means larger).
        if g is None:
            g = np.full(grid.shape, -1, dtype=np.int32, order="F")
        else:
            g.fill(-1)
        keep = k < n_axis
        lin = (idx[0] + nx * (idx[1] + ny * idx[2]))[keep]
        h = np.flatnonzero(keep).astype(np.int32)
        if len(lin):
            last = np.r_[lin[1:] != lin[:-1], True]
            g.reshape(-1, order="F")[lin[last]] = h[last]
        scan_along(np.maximum, g, axis, jobs)
        # Depth of the crossing after each one on the same ray (inf if none),
        # and a sentinel at index -1 for voxels before any crossing.
        # Per crossing, one row gathered per voxel: its depth and facing, and
        # the depth and facing of the next crossing on the same ray (inf if
        # none); row -1 is a sentinel for voxels before any crossing. float32
        # is plenty to choose the nearer crossing and halves the traffic.
        same = np.r_[hits.ray[1:] == hits.ray[:-1], False]
        facing = np.maximum(np.abs(normals[hits.triangle, axis]), 1 / np.sqrt(3))
        table = np.empty((len(hits) + 1, 4), dtype=np.float32)
        table[:-1, 0] = hits.depth
        table[:-1, 1] = facing
        table[:-1, 2] = np.where(same, np.r_[hits.depth[1:], 0.0], np.inf)
        table[:-1, 3] = np.r_[facing[1:], 1.0]
        table[-1] = (-np.inf, 1.0, np.inf, 1.0)
        first = first_hit = None
        if len(hits):
            first = np.full(cols.count, np.inf)
            starts = np.r_[True, ~same[:-1]]
            first[hits.ray[starts]] = hits.depth[starts]
            first_hit = np.full(cols.count, -1, dtype=np.int64)
            first_hit[hits.ray[starts]] = np.flatnonzero(starts)
        gflat = g.reshape(-1, order="F")
        # Gathering whole 16-byte rows as one complex128 is several times
        # faster than fancy-indexing rows of a (n, 4) float32 array.
        rows = table.view(np.complex128).reshape(-1)
        def block(s, e, axis=axis, cols=cols, hits=hits, rows=rows, table=table,
                  gflat=gflat, centres32=centres32, offset=offset):
            vox = inside[s:e]
            prev = gflat[vox]
            c = centres32[coord(axis, vox)]
            row = rows[prev].view(np.float32).reshape(-1, 4)
            d_prev = (c - row[:, 0]) * row[:, 1]
            d_next = (row[:, 2] - c) * row[:, 3]
            pick = prev + np.int32(1)
            if len(hits) and prev.min(initial=0) < 0:
                # Inside yet before every crossing of its column: only
                # possible with inside tests other than this axis's parity.
                before = np.flatnonzero(prev < 0)
                ray = (coord(cols.u_axis, vox[before])
                       + cols.nu * coord(cols.v_axis, vox[before]))
                pick[before] = first_hit[ray]
                d_next[before] = (first[ray] - c[before]) * table[pick[before], 1]
            use_next = d_next < d_prev
            d = np.where(use_next, d_next, d_prev)
            d *= np.float32(1.0 / scale)
            chosen = np.where(use_next, pick, prev).astype(np.int64)
            chosen += offset
            # Masked copies: much cheaper than gathering and scattering the winners.
            better = d < best_d[s:e]
            np.copyto(best_d[s:e], d, where=better)
            np.copyto(best[s:e], chosen, where=better)

        if len(hits):
            for_blocks(block, len(inside), BLOCK, jobs)
        offset += len(hits)
        del gflat
    return inside, Hits.concatenate(parts), best, best_d


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


def colour_method(color):
    """Which colour method ``color`` asks for: None (no colour), ``"exact"`` or ``"fast"``.

    True means the default, ``"exact"`` (every voxel from its exact nearest
    surface point); ``"fast"`` is the nearest of the six axis crossings
    around each voxel (:func:`nearest_crossings`).

    Raises
    ------
    ParameterError
        Anything else.
    """
    from .errors import ParameterError

    if color is None or isinstance(color, (bool, np.bool_, int)) and not isinstance(color, str):
        return "exact" if color else None
    if color in ("exact", "fast"):
        return color
    raise ParameterError(f"`color` must be True, False, 'exact' or 'fast', got {color!r}")


def exact_colours(mesh, grid, occupancy, *, diffuse=True, ambient=False, jobs=1,
                  frame=None, kernel=None) -> np.ndarray:
    """RGBA colours of the inside voxels from their exact nearest surface points; alpha 0 outside.

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
    kernel : {None, "auto", "compiled", "numpy"}
        The compiled search and shading, or the NumPy ones (the same
        colours); None reads ``GEOVOX_KERNEL`` (see
        :func:`geovox.nearest.kernel_module`).

    Returns
    -------
    colors : (nx, ny, nz, 4) uint8
        Indexed ``[x, y, z, channel]``; in memory RGBA-interleaved with x
        fastest (``colors.transpose(2, 1, 0, 3)`` is C-contiguous).
    """
    from .nearest import kernel_module, nearest_inside, run_kernel

    nx, ny, nz = grid.shape
    base = np.zeros((nz, ny, nx, 4), dtype=np.uint8)
    colors = base.transpose(2, 1, 0, 3)
    lo, spacing, z0 = frame if frame is not None else (grid.lo, grid.spacing, 0)
    # One uint32 per voxel: RGBA bytes in memory order (index = F-order voxel index).
    flat = base.reshape(-1, 4).view(np.uint32).reshape(-1)
    module = kernel_module(kernel)
    tables = None
    if module is not None:
        tables = shading_tables(mesh, diffuse=diffuse, ambient=ambient)
    if tables is not None:
        # The compiled kernel finds the nearest point and shades it in one go
        # (shading 4.4 M voxels in NumPy alone took 1.6 s, spot 256³).
        run_kernel(module, mesh.triangles, occupancy, spacing, origin=lo, z0=z0, jobs=jobs,
                   output=lambda k: k.colour_output(flat, *tables))
        return colors
    key, key_rgba = constant_colours(mesh, diffuse=diffuse, ambient=ambient)

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
                   same=key, kernel="numpy")
    return colors


#: Texture wrap modes as the compiled kernel numbers them.
_WRAP_CODE = {"repeat": 0, "mirror": 1, "clamp": 2, "border": 3}


def shading_tables(mesh, *, diffuse=True, ambient=False) -> tuple:
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


def colour_volume(mesh, grid, occupancy, cast=None, *, diffuse=True, ambient=False, jobs=1,
                  exact=False, frame=None) -> np.ndarray:
    """RGBA colours of the inside voxels; alpha 0 outside.

    Parameters
    ----------
    mesh : Mesh
    grid : Grid
    occupancy : (nx, ny, nz) bool
    cast : dict axis -> (Hits, Columns)
        Crossings along each axis (see :func:`nearest_crossings`); not
        needed with ``exact``.
    exact : bool
        Colour every voxel from its exact nearest surface point
        (:func:`exact_colours`) instead of the nearest of its six axis
        crossings.
    frame : (lo, spacing, z0), optional
        With ``exact``: see :func:`exact_colours`.

    Returns
    -------
    colors : (nx, ny, nz, 4) uint8
        Indexed ``[x, y, z, channel]``; in memory RGBA-interleaved with x
        fastest (``colors.transpose(2, 1, 0, 3)`` is C-contiguous).
    """
    for problem in mesh.problems:
        warn(problem, stacklevel=3)
    load_textures(mesh)
    if exact:
        return exact_colours(mesh, grid, occupancy, diffuse=diffuse, ambient=ambient, jobs=jobs,
                             frame=frame)
    nx, ny, nz = grid.shape
    base = np.zeros((nz, ny, nx, 4), dtype=np.uint8)
    colors = base.transpose(2, 1, 0, 3)
    inside, hits, best, dist = nearest_crossings(mesh, grid, occupancy, cast, jobs=jobs)
    if len(inside) == 0:
        return colors
    # Every crossing is a surface point with a known triangle and
    # barycentrics: shade each chosen one once (in a slab of a long grid, many
    # crossings on the rays along z go unused); deep voxels take their
    # crossing's colour.
    hit_rgba = np.zeros(len(hits), dtype=np.uint32)
    used = np.zeros(len(hits), dtype=bool)
    used[best] = True
    used = np.flatnonzero(used)

    def shade_hits(s, e):
        h = used[s:e]
        rgb = shade(mesh, hits.triangle[h], hits.bary[h], diffuse=diffuse, ambient=ambient)
        hit_rgba[h] = _pack(rgb)

    for_blocks(shade_hits, len(used), BLOCK, jobs)
    # One uint32 per voxel: RGBA bytes in memory order, scattered in one go.
    flat = base.reshape(-1, 4).view(np.uint32).reshape(-1)  # index = F-order voxel index
    centres = [grid.centres(a) for a in range(3)]

    def colour_block(s, e):
        vox = inside[s:e]
        h = best[s:e]
        rgba = hit_rgba[h]
        # Near the surface, the exact closest point on the crossing's triangle.
        near = np.flatnonzero(dist[s:e] < REFINE)
        if len(near):
            v = vox[near]
            p = np.stack([centres[0][v % nx], centres[1][(v // nx) % ny],
                          centres[2][v // (nx * ny)]], axis=1)
            t = hits.triangle[h[near]]
            b = closest_on_triangles(p, mesh.triangles[t])
            rgba[near] = _pack(shade(mesh, t, b, diffuse=diffuse, ambient=ambient))
        flat[vox] = rgba

    for_blocks(colour_block, len(inside), BLOCK, jobs)
    return colors


def _pack(rgb: np.ndarray) -> np.ndarray:
    """(n, 3) floats in [0, 1] -> (n,) uint32 holding bytes R, G, B, 255 in memory order."""
    out = np.empty((len(rgb), 4), dtype=np.uint8)
    out[:, :3] = np.rint(rgb * 255.0)
    out[:, 3] = 255
    return out.view(np.uint32).reshape(-1)
