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
it farther). Both search less where every triangle still in the running for
a block of voxels has the same constant colour: that colour is used without
finding which of them is nearest. It needs no rays.

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

The fast method's work goes through the block in chunks of z layers (``CHUNK_VOXELS``):
per chunk and axis, an int32 volume of "the last crossing on this voxel's
ray at or before it" (a running maximum of crossing numbers), then the six
candidates of each inside voxel in cache-sized blocks. Nothing the size of
the grid is made but the colours themselves, which a caller may also take
chunk by chunk (``sink``) or give a reused array for (``out``). Chunks run in
tasks on the threads; no result depends on the chunking or on ``jobs``.
"""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from ..errors import ParameterError, warn
from ..geometry import closest_on_triangles

#: Voxels whose nearest axis crossing is closer than this many voxels get the
#: exact closest point on that crossing's triangle.
REFINE = 2.0
#: Inside voxels processed per block (small enough to stay in cache).
BLOCK = 1 << 16
#: Voxels in one chunk of z layers: the six-crossing colour works a chunk at
#: a time, so its index volume (int32) stays in cache and nothing
#: grid-sized but the colours themselves is made.
CHUNK_VOXELS = 1 << 21
#: Voxels in one task of consecutive chunks (the unit given to a thread).
TASK_VOXELS = 1 << 23
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


class _Axis(NamedTuple):
    """The crossings along one axis, as the chunks read them (see :func:`_prepare`)."""

    axis: int
    #: (n_axis,) float32: voxel centres along the axis, from the low face.
    centres: np.ndarray
    #: (rays,) float64 and int32: each ray's first crossing depth (inf if
    #: none) and its index in :attr:`_Crossings.rows` (-1 if none).
    first: np.ndarray
    first_hit: np.ndarray
    #: One entry per (ray, voxel) where a crossing is the last one on its ray
    #: at or before that voxel's centre: ``layer`` (e,) int64, sorted, the
    #: voxel's z (for rays along z, its ``k``), so that a chunk of layers is
    #: one run of entries; ``u`` (e,) int64 the ray's place in the layer (y
    #: for rays along x, x for rays along y, ``x + nx * y`` for rays along
    #: z); ``k`` (e,) int64 the voxel's coordinate along the axis; ``value``
    #: (e,) int32 the crossing's index in :attr:`_Crossings.rows`.
    layer: np.ndarray
    u: np.ndarray
    k: np.ndarray
    value: np.ndarray


class _Crossings(NamedTuple):
    """Every candidate crossing of a block, all axes concatenated (z, then y, then x)."""

    #: (m,) int64 and (m, 2) float64: each crossing's triangle and barycentrics.
    triangle: np.ndarray
    bary: np.ndarray
    #: (m + 1,) complex128: per crossing, four float32 (its depth and
    #: facing, and the depth and facing of the next crossing on its ray, inf
    #: and 1 if none), gathered as one 16-byte item (several times faster
    #: than fancy-indexing rows of an (m, 4) float32 array); the last row
    #: (-inf, 1, inf, 1) stands for "no crossing yet".
    rows: np.ndarray
    axes: list


def _prepare(mesh, grid, cast, jobs: int = 1) -> _Crossings:
    """Sort each axis's crossings and build the tables that every chunk reads.

    Parameters
    ----------
    cast : dict axis -> (Hits, Columns)
        Crossings of the grid's column rays along each axis.
    jobs : int
        Threads (the axes are prepared side by side).
    """
    from ..backends.base import Hits

    normals = _unit_normals(mesh)
    order = [a for a in (2, 1, 0) if a in cast]  # ties go to z, then y, then x
    if jobs > 1 and len(order) > 1:
        with ThreadPoolExecutor(max_workers=min(jobs, len(order))) as pool:
            done = list(pool.map(lambda a: _prepare_axis(*cast[a], grid, a, normals), order))
    else:
        done = [_prepare_axis(*cast[a], grid, a, normals) for a in order]
    parts, tables, axes = [], [], []
    offset = 0
    for hits, table, ax in done:
        if len(hits) == 0:
            continue
        # Crossing numbers count through the axes concatenated.
        ax.first_hit[ax.first_hit >= 0] += offset
        ax.value[:] += offset
        parts.append(hits)
        tables.append(table)
        axes.append(ax)
        offset += len(hits)
    tables.append(np.array([[-np.inf, 1.0, np.inf, 1.0]], dtype=np.float32))
    rows = np.concatenate(tables).view(np.complex128).reshape(-1)
    hits = Hits.concatenate(parts)
    return _Crossings(hits.triangle, hits.bary, rows, axes)


def _prepare_axis(hits, cols, grid, axis: int, normals):
    """One axis of :func:`_prepare`: its sorted crossings, their table rows and an _Axis.

    Crossing numbers in the _Axis count from 0 on this axis.
    """
    n_axis = grid.shape[axis]
    centres = (np.arange(n_axis) + 0.5) * grid.spacing[axis]  # from the low face, like depths
    hits = relevant_crossings(hits, np.searchsorted(centres, hits.depth, side="left"),
                              n_axis, cols.count).sorted()
    k = np.searchsorted(centres, hits.depth, side="left")
    # float32 is plenty to choose the nearer crossing and halves the traffic.
    same = np.r_[hits.ray[1:] == hits.ray[:-1], False]
    facing = np.maximum(np.abs(normals[hits.triangle, axis]), 1 / np.sqrt(3))
    table = np.empty((len(hits), 4), dtype=np.float32)
    table[:, 0] = hits.depth
    table[:, 1] = facing
    table[:, 2] = np.where(same, np.r_[hits.depth[1:], 0.0], np.inf)
    table[:, 3] = np.r_[facing[1:], 1.0]
    first = np.full(cols.count, np.inf)
    first_hit = np.full(cols.count, -1, dtype=np.int32)
    if len(hits):
        starts = np.r_[True, ~same[:-1]]
        first[hits.ray[starts]] = hits.depth[starts]
        first_hit[hits.ray[starts]] = np.flatnonzero(starts)
    # The deepest crossing at or before each voxel centre is a running
    # maximum of crossing numbers (sorted by ray, then depth, so deeper means
    # larger) from the first voxel past each crossing: one entry per (ray,
    # voxel), the last crossing there.
    keep = np.flatnonzero(k < n_axis)
    ray, kk = hits.ray[keep], k[keep]
    last = np.r_[(ray[1:] != ray[:-1]) | (kk[1:] != kk[:-1]), True][:len(keep)]
    ray, kk, value = ray[last], kk[last], keep[last].astype(np.int32)
    if axis == 2:
        # In ray order; chunks of z layers want them by layer.
        order = np.argsort(kk, kind="stable")
        layer, u, kk, value = kk[order], ray[order], kk[order], value[order]
    else:
        layer, u = ray // cols.nu, ray % cols.nu
    ax = _Axis(axis, centres.astype(np.float32), first, first_hit, layer, u, kk, value)
    return hits, table, ax


def _z_carry(ax: _Axis, nxy: int, z0: int) -> np.ndarray:
    """Per column (``x + nx * y``), the deepest crossing along z before layer ``z0`` (-1: none)."""
    carry = np.full(nxy, -1, dtype=np.int32)
    e = np.searchsorted(ax.layer, z0, side="left")
    np.maximum.at(carry, ax.u[:e], ax.value[:e])
    return carry


def _index_volumes(crossings, shape, z0: int, t: int, volumes, carry) -> None:
    """Per axis, the deepest crossing at or before each voxel of layers ``z0 .. z0 + t``.

    Parameters
    ----------
    volumes : list of (>= nx * ny * t,) int32
        One per axis of ``crossings.axes``, filled in place: along y and z
        indexed as the chunk's F order, ``x + nx * (y + ny * z)``, along x
        ``y + ny * (x + nx * z)`` (``z`` counted from ``z0``); -1 where the
        ray has no crossing yet. The running maximum along the axis then
        steps through whole planes of contiguous rows, vectorised (a scan
        along the contiguous axis goes element by element, several times
        slower).
    carry : (nx * ny,) int32 or None
        Along z: the index before layer ``z0`` (see :func:`_z_carry`),
        advanced to the chunk's last layer.
    """
    nx, ny, _ = shape
    nxy = nx * ny
    for ax, g in zip(crossings.axes, volumes):
        g = g[:nxy * t]
        lo, hi = np.searchsorted(ax.layer, [z0, z0 + t], side="left")
        if ax.axis == 2:
            planes = g.reshape((nxy, t), order="F")
            planes[:, 0] = carry
            planes[:, 1:] = -1
            g[ax.u[lo:hi] + nxy * (ax.k[lo:hi] - z0)] = ax.value[lo:hi]
            for i in range(1, t):
                np.maximum(planes[:, i], planes[:, i - 1], out=planes[:, i])
            carry[:] = planes[:, t - 1]
        else:
            # Along y the F order itself; along x, x in the middle (y, x, z).
            # Either way each step of the scan is one plane of contiguous rows.
            n_u, n_a = (nx, ny) if ax.axis == 1 else (ny, nx)
            g.fill(-1)
            g[ax.u[lo:hi] + n_u * (ax.k[lo:hi] + n_a * (ax.layer[lo:hi] - z0))] = ax.value[lo:hi]
            cube = g.reshape((n_u, n_a, t), order="F")
            for i in range(1, n_a):
                np.maximum(cube[:, i], cube[:, i - 1], out=cube[:, i])


def _nearest(crossings, shape, z0: int, t: int, volumes, vox, x, y, z, inv_scale):
    """For some inside voxels of a chunk, the nearest of their six axis crossings.

    Parameters
    ----------
    volumes : list of int32 arrays
        The chunk's index volumes (:func:`_index_volumes`).
    vox : (k,) intp
        The voxels' F-order indices within the chunk.
    x, y, z : (k,) intp
        Their coordinates (``z`` counted from ``z0``).
    inv_scale : float32
        One over the smallest voxel edge.

    Returns
    -------
    best : (k,) int32
        Index of each voxel's nearest crossing (0 where none was found).
    dist : (k,) float32
        Estimated distance from the voxel centre to the surface there, in
        voxels (inf where none).

    Notes
    -----
    A crossing at axis distance ``d`` on a triangle with unit normal ``n``
    is ranked by ``d * max(|n_axis|, 1/sqrt(3))``: the distance to the
    triangle's plane where that plane faces the axis, which is the true
    distance for the axis that sees the nearest surface best (some axis has
    ``|n_axis| >= 1/sqrt(3)``), while a crossing far along the axis cannot win
    just because its plane happens to pass close by.
    """
    nx, ny, _ = shape
    best = best_d = None
    for ax, g in zip(crossings.axes, volumes):
        # np.take: several times faster than fancy indexing for these gathers.
        if ax.axis == 2:
            prev = np.take(g, vox)
            c = np.take(ax.centres, z + z0)
        elif ax.axis == 1:
            prev = np.take(g, vox)
            c = np.take(ax.centres, y)
        else:
            prev = np.take(g, y + ny * (x + nx * z))
            c = np.take(ax.centres, x)
        row = np.take(crossings.rows, prev).view(np.float32).reshape(-1, 4)
        d_prev = (c - row[:, 0]) * row[:, 1]
        d_next = (row[:, 2] - c) * row[:, 3]
        before = None
        if prev.min(initial=0) < 0:
            # Inside yet before every crossing of its column: only possible
            # with inside tests other than this axis's parity.
            before = np.flatnonzero(prev < 0)
            zb = z[before] + z0
            ray = (x[before] + nx * y[before] if ax.axis == 2 else
                   x[before] + nx * zb if ax.axis == 1 else y[before] + ny * zb)
            pick = ax.first_hit[ray]
            facing = crossings.rows[pick].view(np.float32).reshape(-1, 4)[:, 1]
            d_next[before] = (ax.first[ray] - c[before]) * facing
        use_next = d_next < d_prev
        d = np.minimum(d_next, d_prev, out=d_prev)  # no NaN: the same as picking by use_next
        d *= inv_scale
        chosen = prev + use_next
        if before is not None:
            chosen[before] = np.where(use_next[before], pick, prev[before])
        if best is None:
            # The first axis sets the running best (0 where it found nothing).
            np.copyto(chosen, 0, where=np.isinf(d))
            best_d, best = d, chosen
            continue
        # Masked copies: much cheaper than gathering and scattering the winners.
        better = d < best_d
        np.copyto(best_d, d, where=better)
        np.copyto(best, chosen, where=better)
    if best is None:
        return np.zeros(len(vox), np.int32), np.full(len(vox), np.inf, dtype=np.float32)
    return best, best_d


def constant_colours(mesh, shading: Shading = Shading()):
    """Triangles whose whole face has one colour (lit by ``shading``), keyed by that colour.

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
    rgba = _pack(shade(mesh, sel, np.full((len(sel), 2), 1 / 3), shading))
    values, inverse = np.unique(rgba, return_inverse=True)
    key[sel] = inverse.reshape(-1)
    return key, values


def exact_colours(mesh, grid, occupancy, *, shading: Shading = Shading(), jobs=1,
                  frame=None, out=None) -> np.ndarray:
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
    shading : Shading
    out : (nz, ny, nx, 4) uint8, C order, optional
        The array to write the colours into (cleared first; see
        :func:`colour_volume`).

    The compiled search and shading run, or the NumPy ones (the same
    colours), as the conversion's kernel choice says (see
    :func:`geovox.nearest.kernel_module`).

    Returns
    -------
    colors : (nx, ny, nz, 4) uint8
        Indexed ``[x, y, z, channel]``; in memory RGBA-interleaved with x
        fastest (``colors.transpose(2, 1, 0, 3)`` is C-contiguous).

    Raises
    ------
    ParameterError
        Lengths outside ``1 / EXACT_RANGE .. EXACT_RANGE`` (see there), for
        a mesh of more than one colour.
    """
    from ..kernels import chosen
    from .nearest import kernel_module, nearest_inside, run_kernel

    nx, ny, nz = grid.shape
    if out is None:
        base = np.zeros((nz, ny, nx, 4), dtype=np.uint8)
    else:
        base = out
        base.fill(0)  # only the inside voxels are written below
    colors = base.transpose(2, 1, 0, 3)
    lo, spacing, z0 = frame if frame is not None else (grid.lo, grid.spacing, 0)
    # One uint32 per voxel: RGBA bytes in memory order (index = F-order voxel index).
    flat = base.reshape(-1, 4).view(np.uint32).reshape(-1)
    key, key_rgba = constant_colours(mesh, shading)
    if len(key) and len(key_rgba) == 1 and (key >= 0).all():
        # One colour over the whole surface (an STL, an uncoloured scan, a
        # single untextured material): every nearest point has it, so no
        # search is needed (bunny105k at 256³: 3.4 s of search for one grey).
        np.copyto(flat.reshape((nx, ny, nz), order="F"), key_rgba[0], where=occupancy)
        return colors
    # The search's float64 formulas take fourth powers of lengths (the
    # triangles' Gram determinants): beyond about 1e77 they overflow, below
    # about 1e-77 they underflow, and the nearest points come out wrong (from
    # 1e150, NaN: inside voxels left uncoloured). 1e60 leaves a wide margin.
    span = max(float(np.abs(mesh.triangles - np.asarray(lo, float)).max(initial=0.0)),
               float(np.abs(np.asarray(grid.hi, float) - np.asarray(lo, float)).max()))
    hmin = float(np.min(spacing))
    if not (span <= EXACT_RANGE and hmin >= 1.0 / EXACT_RANGE):
        raise ParameterError(
            f"exact colour needs lengths between {1 / EXACT_RANGE:g} and {EXACT_RANGE:g} "
            f"(this mesh and grid span {span:.3g} in voxels of {hmin:.3g}); scale the mesh, "
            f"or use fast colour (--fast-color, color='fast')")
    module = kernel_module()
    tables = None
    if module is not None:
        tables = shading_tables(mesh, shading)
    if tables is not None:
        # The compiled kernel finds the nearest point and shades it in one go
        # (shading 4.4 M voxels in NumPy alone took 1.6 s, spot 256³).
        run_kernel(module, mesh.triangles, occupancy, spacing, origin=lo, z0=z0, jobs=jobs,
                   output=lambda k: _kernel_output(k, flat, tables, key, key_rgba),
                   cache=getattr(mesh, "_cache", None))
        return colors

    def emit(vox, tri, uv):
        k = key[tri]
        rgba = np.zeros(len(tri), np.uint32)
        const = k >= 0
        rgba[const] = key_rgba[k[const]]
        vary = np.flatnonzero(~const)
        if len(vary):
            rgba[vary] = _pack(shade(mesh, tri[vary], uv[vary], shading))
        flat[vox[:, 0] + nx * (vox[:, 1] + ny * vox[:, 2])] = rgba

    with chosen("numpy"):  # shade() colours what the tables cannot
        nearest_inside(mesh.triangles, occupancy, spacing, origin=lo, z0=z0, jobs=jobs,
                       emit=emit, same=key)
    return colors


def _kernel_output(search, flat, tables, key, key_rgba) -> None:
    """Let the compiled kernel shade into ``flat``, and skip the search where colours are constant.

    Where every triangle still in the running for a cell of voxels has the
    same constant colour (``key``, see :func:`constant_colours`), the kernel
    gives the cell that colour without finding which of them is nearest, as
    the NumPy search does (cornell_box at 256³: most of the volume).
    """
    search.colour_output(flat, *tables)
    if (key >= 0).any():
        search.same_colours(key, key_rgba)


#: Exact colour works with lengths (the mesh's extent and the voxel size,
#: relative to the grid's corner) within 1 / EXACT_RANGE .. EXACT_RANGE.
EXACT_RANGE = 1e60

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


def colour_volume(mesh, grid, occupancy, cast=None, *, shading: Shading = Shading(), jobs=1,
                  exact=False, frame=None, out=None, sink=None):
    """RGBA colours of the inside voxels; alpha 0 outside.

    Parameters
    ----------
    mesh : Mesh
    grid : Grid
    occupancy : (nx, ny, nz) bool
    cast : dict axis -> (Hits, Columns)
        Crossings along each axis (see :func:`_prepare`); not needed with
        ``exact``.
    shading : Shading
        The options ``diffuse`` and ``ambient`` (:meth:`Shading.of`).
    exact : bool
        Colour every voxel from its exact nearest surface point
        (:func:`exact_colours`) instead of the nearest of its six axis
        crossings.
    frame : (lo, spacing, z0), optional
        With ``exact``: see :func:`exact_colours`.
    out : (nz, ny, nx, 4) uint8, C order, optional
        The array to write every voxel's colour into (reused by a caller
        making many blocks, so that its memory is not faulted in afresh each
        time); ``colors`` is its transpose.
    sink : callable, optional
        Without ``exact``: instead of making the array, hand over each chunk
        of layers as soon as it is coloured, ``sink(z0, rgba)`` with
        ``rgba`` (t, ny, nx, 4) uint8 C order, layers ``z0 .. z0 + t``;
        called from the worker threads, in no particular order, with a
        buffer that is reused once it returns.

    Returns
    -------
    colors : (nx, ny, nz, 4) uint8, or None with ``sink``
        Indexed ``[x, y, z, channel]``; in memory RGBA-interleaved with x
        fastest (``colors.transpose(2, 1, 0, 3)`` is C-contiguous).
    """
    for problem in mesh.problems:
        warn(problem, stacklevel=3)
    load_textures(mesh, shading)
    if exact:
        return exact_colours(mesh, grid, occupancy, shading=shading, jobs=jobs, frame=frame,
                             out=out)
    nx, ny, nz = grid.shape
    # Each chunk clears its own layers just before filling them (in cache).
    base = None if sink else np.empty((nz, ny, nx, 4), dtype=np.uint8) if out is None else out
    colors = None if sink else base.transpose(2, 1, 0, 3)
    crossings = _prepare(mesh, grid, cast, jobs)
    if not crossings.axes:
        if sink:
            for z0 in range(nz):
                sink(z0, np.zeros((1, ny, nx, 4), dtype=np.uint8))
        else:
            base.fill(0)
        return colors
    # Chunks of z layers, in tasks of consecutive chunks handed to the threads
    # as they come free (each task carries the z axis's index from chunk to
    # chunk; the chunks' results do not depend on which thread ran them).
    t = max(1, min(nz, CHUNK_VOXELS // (nx * ny)))
    chunks = [(z0, min(t, nz - z0)) for z0 in range(0, nz, t)]
    per_task = max(1, TASK_VOXELS // (t * nx * ny))
    tasks = [chunks[s:s + per_task] for s in range(0, len(chunks), per_task)]
    lock = threading.Lock()
    todo = iter(tasks)
    failed = threading.Event()  # one thread's error stops the others' next tasks

    def worker():
        # Work space made once per thread, reused by each of its tasks.
        space = _work_space(crossings, nx * ny * t)
        while not failed.is_set():
            with lock:
                task = next(todo, None)
            if task is None:
                return
            try:
                _colour_chunks(mesh, grid, occupancy, crossings, task, base, space,
                               shading=shading, sink=sink)
            except BaseException:
                failed.set()
                raise

    n = min(jobs, len(tasks))
    if n <= 1:
        worker()
    else:
        with ThreadPoolExecutor(max_workers=n) as pool:
            for f in [pool.submit(worker) for _ in range(n)]:
                f.result()
    return colors


def _work_space(crossings, voxels: int) -> dict:
    """Arrays one thread reuses from chunk to chunk: index volumes and the shading cache."""
    m = len(crossings.triangle)
    return {"volumes": [np.empty(voxels, dtype=np.int32) for _ in crossings.axes],
            "rgba": np.empty(m, dtype=np.uint32), "shaded": np.zeros(m, dtype=bool),
            "pending": np.zeros(m, dtype=bool), "chunk": np.empty(voxels, dtype=np.uint32)}


def _colour_chunks(mesh, grid, occupancy, crossings, chunks, base, space, *, shading,
                   sink=None):
    """Colour the inside voxels of consecutive chunks of z layers, in place.

    Parameters
    ----------
    crossings : _Crossings
    chunks : list of (z0, t)
        ``t`` layers from ``z0``, each chunk following the one before.
    base : (nz, ny, nx, 4) uint8 or None
        The block's colours, C order (x fastest); the chunks' voxels are
        written.
    space : dict
        Work space (:func:`_work_space`).
    sink : callable, optional
        Instead of ``base``: given each chunk's colours (see
        :func:`colour_volume`).
    """
    nx, ny, nz = grid.shape
    nxy = nx * ny
    inv_scale = np.float32(1.0 / grid.spacing.min())
    centres = [grid.centres(a) for a in range(3)]
    along_z = next((ax for ax in crossings.axes if ax.axis == 2), None)
    carry = _z_carry(along_z, nxy, chunks[0][0]) if along_z is not None else None
    volumes = space["volumes"]
    # The colour of each crossing a deep voxel takes, shaded once per thread
    # (shading is row by row, so which batch a crossing falls in is immaterial).
    hit_rgba, shaded, pending = space["rgba"], space["shaded"], space["pending"]
    for z0, t in chunks:
        # One uint32 per voxel: RGBA bytes in memory order, index = F-order voxel index.
        flat = (space["chunk"][:nxy * t] if sink else
                base[z0:z0 + t].reshape(-1, 4).view(np.uint32).reshape(-1))
        flat.fill(0)
        vox = np.flatnonzero(occupancy[:, :, z0:z0 + t].reshape(-1, order="F"))
        if len(vox) == 0:
            if carry is not None:
                carry = _z_carry(along_z, nxy, z0 + t)
            if sink:
                sink(z0, flat.view(np.uint8).reshape(t, ny, nx, 4))
            continue
        _index_volumes(crossings, grid.shape, z0, t, volumes, carry)
        best = np.empty(len(vox), dtype=np.int32)
        dist = np.empty(len(vox), dtype=np.float32)
        # In blocks small enough for the temporaries to stay in cache.
        for s in range(0, len(vox), BLOCK):
            v = vox[s:s + BLOCK]
            q = v // nx
            z = q // ny
            best[s:s + BLOCK], dist[s:s + BLOCK] = _nearest(
                crossings, grid.shape, z0, t, volumes, v, v - q * nx, q - z * ny, z, inv_scale)
        # Deeper voxels take their crossing's own colour (every crossing is a
        # surface point with a known triangle and barycentrics), each crossing
        # shaded once; near voxels' entries are replaced below.
        new = np.compress(~np.take(shaded, best), best)
        if len(new):
            # Each new crossing once: marked, then read back in order.
            lo, hi = new.min(), new.max() + 1
            pending[new] = True
            new = np.flatnonzero(pending[lo:hi]) + lo
            pending[new] = False
            hit_rgba[new] = _pack(shade(mesh, np.take(crossings.triangle, new),
                                        np.take(crossings.bary, new, axis=0), shading))
            shaded[new] = True
        rgba = np.take(hit_rgba, best)
        near = np.flatnonzero(dist < REFINE)
        if len(near):
            # Near the surface, the exact closest point on the crossing's triangle.
            v = vox[near]
            q = v // nx
            z = q // ny
            p = np.stack([centres[0][v - q * nx], centres[1][q - z * ny], centres[2][z + z0]],
                         axis=1)
            tri = np.take(crossings.triangle, np.take(best, near))
            b = closest_on_triangles(p, np.take(mesh.triangles, tri, axis=0))
            rgba[near] = _pack(shade(mesh, tri, b, shading))
        flat[vox] = rgba
        if sink:
            sink(z0, flat.view(np.uint8).reshape(t, ny, nx, 4))


def _pack(rgb: np.ndarray) -> np.ndarray:
    """(n, 3) floats in [0, 1] -> (n,) uint32 holding bytes R, G, B, 255 in memory order."""
    out = np.empty((len(rgb), 4), dtype=np.uint8)
    out[:, :3] = np.rint(rgb * 255.0)
    out[:, 3] = 255
    return out.view(np.uint32).reshape(-1)
