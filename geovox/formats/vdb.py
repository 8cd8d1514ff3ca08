"""OpenVDB (``.vdb``) for Blender, Houdini, Unreal and ParaView, written with NumPy.

No maintained Python package writes VDB, so this module writes the file
format itself (file version 224, the version OpenVDB 10 writes; a reader
takes every version up to its own), from the layout of OpenVDB's
``io::Archive`` and tree nodes:

* header: int64 magic ``0x56444220``, uint32 file version, uint32 library
  major and minor, uint8 "has grid offsets", the 36-character UUID; the
  file's metadata; int32 grid count.
* per grid: a descriptor (name, type ``Tree_float_5_4_3`` or
  ``Tree_vec3s_5_4_3``, instance parent, then int64 offsets of the grid, its
  data blocks and its end), uint32 compression flags, the grid's metadata
  (``class``, ``name``, bounding box and voxel count), the transform
  (``ScaleTranslateMap``: index (0, 0, 0) is voxel 0's centre), the topology
  and the leaf buffers.
* topology: int32 buffer count 1, the background value, the root's tiles
  and children; a 32³ internal node writes its child mask, value mask and
  its 32768 tile values, then its 16³ children the same way; a leaf (8³
  voxels) writes its value mask. The buffers then give each leaf's value
  mask and 512 values, in the same order.
* values: a byte saying which inactive values are left out (all background,
  all minus background, a mask between the two, or none), then the values
  as zlib streams (int64 size, negative for bytes stored as they are).

Only leaves that are not uniform are stored; a uniform 8³ block is a tile of
its 16³ node and a uniform 128³ block a tile of the 32³ node, so a solid
takes space for its surface only (a box filling most of a 1024³ grid, its
faces cutting the leaves: 10.8 MB). ``density`` (fog volume: the coverage density, or
occupancy 0/1), ``color`` (RGB 0..1, vec3s, active where inside) and ``sdf``
(level set, background = the clamped distance, narrow band active) are the
grids; Blender's volume objects read ``density`` and ``color`` by name.
"""

from __future__ import annotations

import os
import struct
import zlib

import numpy as np

from ..errors import ParameterError
from .base import SlabWriter, level_set_background

MAGIC = 0x56444220
FILE_VERSION = 224
#: The library whose reader the files are checked against (OpenVDB 10.0, Debian's).
LIBRARY_VERSION = (10, 0)
COMPRESS_ZIP, COMPRESS_ACTIVE_MASK = 0x1, 0x2
#: What the reader is told to expect per node: zlib, and inactive values left out. A level
#: set's grid leaves zlib out (COMPRESS_ACTIVE_MASK alone): exact float32 distances deflate
#: by 2.6 % (spot at 200 voxels, zlib's level 6), not worth 2.7 s of a 1024-voxel grid.
COMPRESSION = COMPRESS_ZIP | COMPRESS_ACTIVE_MASK
#: zlib level: zlib's default, which OpenVDB's own zipToStream uses.
ZIP_LEVEL = 6
#: Leaves gathered per batch (bounds the memory of the values being encoded).
BATCH = 8192

# Log2 of the node sizes: leaf 8³, internal 16³ of leaves, internal 32³ of those.
LEAF, N16, N32 = 3, 4, 5

# Which inactive values a node leaves out (io::writeCompressedValues' metadata byte).
NO_MASK_OR_INACTIVE_VALS, NO_MASK_AND_MINUS_BG, MASK_AND_NO_INACTIVE_VALS, NO_MASK_AND_ALL_VALS = 0, 1, 3, 6


def _string(s: str) -> bytes:
    b = s.encode()
    return struct.pack("<I", len(b)) + b


def _metadata(items) -> bytes:
    """A MetaMap: count, then name, type name, size and value of each (sorted, as std::map)."""
    out = [struct.pack("<I", len(items))]
    for name, (type_name, value) in sorted(items.items()):
        out += [_string(name), _string(type_name), struct.pack("<I", len(value)), value]
    return b"".join(out)


def _mask(bits: np.ndarray) -> bytes:
    """A NodeMask: bit n of the node's slots (z fastest) in little-endian 64-bit words."""
    return np.packbits(bits.reshape(-1), bitorder="little").tobytes()


def _zip(data: bytes) -> bytes:
    """io::zipToStream: int64 size and the zlib stream, or minus the size and the bytes.

    zlib, not ISA-L: with ISA-L's fastest level a slab file's bytes were seen to differ
    from a whole write's of the same values (4 bytes, 3 runs of the suite in about 15; its
    hash table is likely not cleared between calls); a file's bytes should depend on its
    values alone, and zlib's do.
    """
    packed = zlib.compress(data, ZIP_LEVEL)
    if len(packed) < len(data):
        return struct.pack("<q", len(packed)) + packed
    return struct.pack("<q", -len(data)) + data


def _values(vals: np.ndarray, active: np.ndarray, background, ignore=None,
            zipped: bool = True) -> bytes:
    """io::writeCompressedValues with active-mask compression.

    Parameters
    ----------
    vals : (n,) or (n, 3) float32
        Every slot's value, in the node's slot order.
    active : (n,) bool
    background : float32 scalar or (3,) float32
    ignore : (n,) bool, optional
        Slots holding children, whose values the reader never uses.
    zipped : bool
        The grid's values are zlib streams (:data:`COMPRESS_ZIP`), else as they are.
    """
    pack = _zip if zipped else bytes
    inactive = ~active if ignore is None else ~active & ~ignore
    eq = vals == background
    neg = vals == -background
    if vals.ndim > 1:
        eq, neg = eq.all(axis=1), neg.all(axis=1)
    out = []
    if np.all(eq[inactive]):
        out.append(bytes([NO_MASK_OR_INACTIVE_VALS]))
    elif np.all(neg[inactive]):
        out.append(bytes([NO_MASK_AND_MINUS_BG]))
    elif np.all((eq | neg)[inactive]):
        # The reader restores a set bit as +background, a clear one as -background.
        out += [bytes([MASK_AND_NO_INACTIVE_VALS]), _mask(inactive & eq)]
    else:
        return bytes([NO_MASK_AND_ALL_VALS]) + pack(np.ascontiguousarray(vals).tobytes())
    out.append(pack(np.ascontiguousarray(vals[active]).tobytes()))
    return b"".join(out)


def _leaf_values(vals: np.ndarray, act: np.ndarray, background, zipped: bool = True) -> list:
    """:func:`_values` of many leaves at once: the same bytes, leaf by leaf.

    ``vals`` (k, 512[, 3]) and ``act`` (k, 512): each leaf's values and active
    mask. Which inactive values a leaf leaves out is decided for all of them
    in whole arrays; the zlib streams are made on two threads (zlib lets go
    of the GIL), a leaf's one at a time as before.
    """
    from concurrent.futures import ThreadPoolExecutor

    eq = vals == background
    neg = vals == -background
    if vals.ndim > 2:
        eq, neg = eq.all(axis=2), neg.all(axis=2)
    all_eq = (eq | act).all(axis=1)
    all_neg = (neg | act).all(axis=1)
    either = (eq | neg | act).all(axis=1)
    masks = np.packbits(~act & eq, axis=1, bitorder="little")
    heads, payloads = [], []
    for k in range(len(vals)):
        if all_eq[k]:
            heads.append(bytes([NO_MASK_OR_INACTIVE_VALS]))
        elif all_neg[k]:
            heads.append(bytes([NO_MASK_AND_MINUS_BG]))
        elif either[k]:
            heads.append(bytes([MASK_AND_NO_INACTIVE_VALS]) + masks[k].tobytes())
        else:
            heads.append(bytes([NO_MASK_AND_ALL_VALS]))
            payloads.append(np.ascontiguousarray(vals[k]).tobytes())
            continue
        payloads.append(np.ascontiguousarray(vals[k][act[k]]).tobytes())
    if not zipped:
        return [h + p for h, p in zip(heads, payloads)]
    half = (len(payloads) + 1) // 2
    with ThreadPoolExecutor(2) as pool:
        parts = pool.map(lambda chunk: [_zip(p) for p in chunk],
                         (payloads[:half], payloads[half:]))
        zipped = [z for part in parts for z in part]
    return [h + z for h, z in zip(heads, zipped)]


def _pad_to(a: np.ndarray, multiple: int, value) -> np.ndarray:
    """``a`` (first three axes ``[x, y, z]``) padded on the high side to multiples of ``multiple``."""
    shape = tuple(-(-n // multiple) * multiple for n in a.shape[:3])
    if shape == a.shape[:3]:
        return a
    out = np.empty(shape + a.shape[3:], dtype=a.dtype)
    out[...] = value
    out[tuple(slice(0, n) for n in a.shape[:3])] = a
    return out


def _block_extrema(raw: np.ndarray, size: int, pad):
    """Per ``size³`` block minimum and maximum of ``raw`` (``[x, y, z, ...]``).

    The grid is padded on the high side with ``pad`` to whole blocks, one
    slab of z-planes at a time (never a copy of the whole array). Each slab is
    reduced one axis at a time, slowest first: each step runs over contiguous
    memory and shrinks the data by ``size`` (several times faster than one
    reduction over three strided axes).

    Returns
    -------
    lo, hi : (bx, by, bz[, c]) arrays of ``raw``'s dtype

    The compiled kernel (``geovox/_blocks.pyx``) does the scalar float32 and
    uint8 (bool) grids in one threaded pass, where it is built and the
    conversion's kernel choice allows (:func:`geovox.kernels.compiled`); the
    answers are the same.
    """
    from ..kernels import compiled, openmp_threads
    from ..parallel import resolve_jobs

    nx, ny, nz = raw.shape[:3]
    module = compiled("_blocks", "block extrema")
    if module is not None and raw.ndim == 3 and raw.dtype in (np.float32, np.uint8, np.bool_) \
            and (raw.flags.f_contiguous or raw.size == 0):
        flat = raw.reshape(-1, order="F")
        if flat.dtype == np.bool_:
            flat = flat.view(np.uint8)
        shape = tuple(-(-n // size) for n in (nx, ny, nz))
        lo = np.empty(shape, flat.dtype)
        hi = np.empty(shape, flat.dtype)
        if raw.size:
            module.block_extrema(flat, (nx, ny, nz), size, float(pad), lo, hi,
                                 openmp_threads(resolve_jobs(None)))
        else:
            lo.fill(pad)
            hi.fill(pad)
        return (lo.view(np.bool_), hi.view(np.bool_)) if raw.dtype == np.bool_ else (lo, hi)
    tail = raw.shape[3:]
    bx, by = -(-nx // size), -(-ny // size)
    # The z, y, x transpose of an x-fastest array is C-contiguous: no copy.
    zyx = np.ascontiguousarray(raw.transpose((2, 1, 0) + tuple(range(3, raw.ndim))))
    step = size * max(1, (1 << 24) // max(1, nx * ny * size))  # ~16 M voxels a slab
    parts = ([], [])
    for z0 in range(0, nz, step):
        slab = zyx[z0:z0 + step]
        bz = -(-slab.shape[0] // size)
        if slab.shape[:3] != (bz * size, by * size, bx * size):
            padded = np.empty((bz * size, by * size, bx * size) + tail, dtype=raw.dtype)
            padded[...] = pad
            padded[:slab.shape[0], :ny, :nx] = slab
            slab = padded
        for reduce, out in zip((np.min, np.max), parts):
            a = reduce(slab.reshape((bz, size, by * size, bx * size) + tail), axis=1)
            a = reduce(a.reshape((bz, by, size, bx * size) + tail), axis=2)
            a = reduce(a.reshape((bz, by, bx, size) + tail), axis=3)
            out.append(a)
    back = (2, 1, 0) + tuple(range(3, 3 + len(tail)))
    return tuple(np.concatenate(p).transpose(back) for p in parts)


def _coarser(uniform, lo, hi, factor: int, pad):
    """Uniformity and extrema of blocks of ``factor³`` cells of the finer level."""
    def up(a, value, reduce):
        a = _pad_to(a, factor, value)
        nx, ny, nz = (n // factor for n in a.shape[:3])
        v = a.reshape((nx, factor, ny, factor, nz, factor) + a.shape[3:])
        return reduce(v, axis=(1, 3, 5))

    return (up(uniform, True, np.all), up(lo, pad, np.min), up(hi, pad, np.max))


class _Grid:
    """One grid's dense source and how its voxels become OpenVDB values.

    ``raw`` is ``[x, y, z]`` or ``[x, y, z, c]`` in its own dtype; ``value``
    maps raw cells to float32 values, ``active`` to the active mask;
    ``pad`` is the raw value beyond the grid (which must map to the
    background, inactive).
    """

    def __init__(self, name, raw, value, active, background, pad, grid_class, vector=False,
                 zipped=True):
        self.name, self.raw, self.value, self.active = name, raw, value, active
        self.zipped = zipped  # its values are zlib streams (COMPRESS_ZIP)
        self.background = np.asarray(background, dtype=np.float32)
        self.pad, self.grid_class, self.vector = pad, grid_class, vector
        self.stored = None

    def is_background(self, raw_value) -> np.ndarray:
        v = self.value(raw_value)
        eq = v == self.background
        if self.vector:
            eq = eq.all(axis=-1)
        return eq & ~self.active(raw_value)


class _Stats:
    """Active voxel count and index-space bounding box, gathered while the tree is built."""

    def __init__(self, shape):
        self.shape = np.asarray(shape)
        self.count = 0
        self.lo = np.full(3, np.iinfo(np.int64).max)
        self.hi = np.full(3, -1)

    def boxes(self, corners: np.ndarray, size: int) -> None:
        """Add active cubes of edge ``size`` at ``corners`` ((n, 3) int), clipped to the grid."""
        if len(corners) == 0:
            return
        lo = np.minimum(corners, self.shape)
        hi = np.minimum(corners + size, self.shape)
        self.count += int(np.prod(np.maximum(hi - lo, 0), axis=1).sum())
        self.lo = np.minimum(self.lo, lo.min(axis=0))
        self.hi = np.maximum(self.hi, hi.max(axis=0) - 1)

    def leaves(self, index: np.ndarray, active: np.ndarray) -> None:
        """Add the active voxels of leaves ``index`` ((k, 3) leaf coordinates), ``active`` (k, 8, 8, 8)."""
        self.count += int(np.count_nonzero(active))
        n8 = active.shape[1]
        for a in range(3):
            along = active.any(axis=tuple(b for b in (1, 2, 3) if b != a + 1))  # (k, 8)
            has = along.any(axis=1)
            if not has.any():
                return
            first = along.argmax(axis=1)
            last = n8 - 1 - along[:, ::-1].argmax(axis=1)
            base = index[has, a] * n8
            self.lo[a] = min(self.lo[a], int((base + first[has]).min()))
            self.hi[a] = max(self.hi[a], int((base + last[has]).max()))


def _node_values(g: _Grid, uniform: np.ndarray, lo: np.ndarray, corner, size: int, stats: _Stats):
    """Child mask, value mask and the compressed tile values of one internal node.

    ``uniform`` and ``lo`` are the node's slots (``[x, y, z]``, z fastest
    as OpenVDB numbers them): whether each is one value, and that raw value;
    a slot covers ``size³`` voxels from ``corner + slot * size``.
    """
    child = ~uniform.reshape(-1)
    vals = g.value(lo).reshape((child.size,) + g.background.shape)
    vals[child] = 0  # what OpenVDB stores in a child's slot
    act = uniform & g.active(lo)
    stats.boxes(np.argwhere(act) * size + np.asarray(corner), size)
    act = act.reshape(-1)
    return _mask(child) + _mask(act) + _values(vals, act, g.background, ignore=child,
                                               zipped=g.zipped)


def _same(a, b) -> np.ndarray:
    """Per block: its minimum equals its maximum (every component)."""
    eq = a == b
    return eq.reshape(eq.shape[:3] + (-1,)).all(axis=3)


def _dense_leaves(raw: np.ndarray, pad):
    """Leaf blocks gathered from a dense ``raw`` (see :func:`_tree`'s ``leaf_blocks``)."""
    off = np.arange(1 << LEAF)
    nx, ny, nz = raw.shape[:3]

    def blocks(idx):
        xs, ys, zs = (idx[:, a, None] * (1 << LEAF) + off for a in range(3))
        # (leaves, x, y, z[, c]) raw blocks; a leaf at the grid's high edge reads its
        # last voxel and gets the pad beyond.
        xi, yi, zi = xs[:, :, None, None], ys[:, None, :, None], zs[:, None, None, :]
        block = raw[np.minimum(xi, nx - 1), np.minimum(yi, ny - 1), np.minimum(zi, nz - 1)]
        beyond = (xi >= nx) | (yi >= ny) | (zi >= nz)
        if beyond.any():
            block[beyond] = pad
        return block

    return blocks


def _tree(g: _Grid, summary=None, leaf_blocks=None, shape=None):
    """``(topology, buffers, stats)``: the bytes of one grid's tree, its active voxels.

    Uniform blocks are found level by level from per-block extrema: 8³
    leaves, then 16³ of those, then 32³ of those; a uniform block is a tile
    of its parent, and a uniform background block is left out.

    ``summary`` ``(uni8, lo8)``: per 8³ block, whether it is uniform and its
    minimum raw value; ``leaf_blocks(idx)``: the raw blocks ``(k, 8, 8, 8[, c])``
    of leaves ``idx`` ``(k, 3)`` (the pad beyond the grid); ``shape`` the
    grid's. Default: all three from ``g.raw`` (a slab writer gives its own,
    gathered slab by slab: :class:`VDBWriter`).
    """
    if summary is None:
        lo, hi = _block_extrema(g.raw, 1 << LEAF, g.pad)
        summary = (_same(lo, hi), lo)
        leaf_blocks = _dense_leaves(g.raw, g.pad)
        shape = g.raw.shape[:3]
    uni8, lo = summary
    hi = lo  # where a block is uniform its maximum is its minimum; elsewhere unused
    same = _same
    uni16, lo16, hi16 = _coarser(uni8, lo, hi, 1 << N16, g.pad)
    uni16 &= same(lo16, hi16)
    uni32, lo32, hi32 = _coarser(uni16, lo16, hi16, 1 << N32, g.pad)
    uni32 &= same(lo32, hi32)
    lo8 = lo

    def window(a, corner, size, fill):
        """``a[corner : corner + size]`` on every axis, padded beyond ``a`` with ``fill``."""
        part = a[tuple(slice(int(c), int(c) + size) for c in corner)]
        if part.shape[:3] == (size,) * 3:
            return part
        out = np.empty((size,) * 3 + a.shape[3:], dtype=a.dtype)
        out[...] = fill
        out[tuple(slice(0, n) for n in part.shape[:3])] = part
        return out

    stats = _Stats(shape)
    tiles, nodes = [], []  # nodes: (origin, header, [(header16, leaf indices)])
    for i32 in np.ndindex(*uni32.shape):  # C order: the root map's (x, y, z) order
        corner = np.asarray(i32) << (LEAF + N16 + N32)
        origin = struct.pack("<3i", *(int(c) for c in corner))
        if uni32[i32]:
            if not g.is_background(lo32[i32]):
                on = bool(g.active(lo32[i32]))
                tiles.append(origin + g.value(lo32[i32]).tobytes() + struct.pack("<?", on))
                if on:
                    stats.boxes(corner[None], 1 << (LEAF + N16 + N32))
            continue
        c16 = np.asarray(i32) << N32
        u16, v16 = window(uni16, c16, 1 << N32, True), window(lo16, c16, 1 << N32, g.pad)
        subs = []
        for j16 in np.argwhere(~u16):  # slot order, z fastest
            c8 = (c16 + j16) << N16
            u8, v8 = window(uni8, c8, 1 << N16, True), window(lo8, c8, 1 << N16, g.pad)
            subs.append((_node_values(g, u8, v8, c8 << LEAF, 1 << LEAF, stats),
                         np.argwhere(~u8) + c8))
        nodes.append((origin, _node_values(g, u16, v16, corner, 1 << (LEAF + N16), stats), subs))

    # The leaves, in the order the topology and the buffers list them.
    index = [leaves for _, _, subs in nodes for _, leaves in subs]
    index = np.concatenate(index) if index else np.zeros((0, 3), dtype=np.int64)
    masks, buffers = [], []
    for s in range(0, len(index), BATCH):
        idx = index[s:s + BATCH]
        block = leaf_blocks(idx)
        # Raveled z fastest, as OpenVDB numbers a leaf's voxels.
        flat = block.reshape((len(idx), 1 << 3 * LEAF) + block.shape[4:])
        vals, act = g.value(flat), g.active(flat)
        stats.leaves(idx, act.reshape((len(idx),) + (1 << LEAF,) * 3))
        leaf_masks = np.packbits(act, axis=1, bitorder="little")  # each leaf's _mask
        for m, v in zip(leaf_masks, _leaf_values(vals, act, g.background, g.zipped)):
            m = m.tobytes()
            masks.append(m)
            buffers.append(m + v)

    topology = [struct.pack("<i", 1), g.background.tobytes(),
                struct.pack("<II", len(tiles), len(nodes))] + tiles
    at = 0
    for origin, header32, subs in nodes:
        topology += [origin, header32]
        for header16, leaves in subs:
            topology += [header16] + masks[at:at + len(leaves)]
            at += len(leaves)
    return b"".join(topology), b"".join(buffers), stats


def _specs(meta, sdf_background=1.0) -> list:
    """``[(grid, field), ...]``: the grids to write, ``density`` (fog), ``color`` (vec3s) and
    ``sdf`` (level set), each with the :class:`~geovox.volume.Volume` field it is made of.

    ``meta``: the whole volume's :class:`~geovox.formats.base.Meta`;
    ``sdf_background``: the level set's background, the largest distance
    (the clamped distance beyond the exact band: those voxels are inactive,
    the narrow band is active).
    """
    density = meta.dtype("density")
    if density is None:
        field, scale = "occupancy", 1.0
    else:
        field, scale = "density", (255.0 if density == np.uint8 else 1.0)
    fog = _Grid("density", None, value=lambda r: r.astype(np.float32) / np.float32(scale),
                active=lambda r: r != 0, background=0.0, pad=0, grid_class="fog volume")
    # How the reader gets the volume's own arrays back.
    fog.stored = "occupancy" if density is None else str(np.dtype(density))
    specs = [(fog, field)]
    if meta.colors:
        def colour(r):
            rgb = r[..., :3].astype(np.float32) / np.float32(255.0)
            return np.where(r[..., 3:] > 0, rgb, np.float32(0.0))

        specs.append((_Grid("color", None, value=colour, active=lambda r: r[..., 3] > 0,
                            background=np.zeros(3), pad=0, grid_class="unknown", vector=True),
                      "colors"))
    if meta.dtype("sdf") is not None:
        bg = np.float32(sdf_background)
        # An unsigned distance is no level set (no zero crossing to take as the surface):
        # Houdini and Blender would read one as an SDF.
        specs.append((_Grid("sdf", None, value=lambda r: np.asarray(r, dtype=np.float32),
                            active=lambda r, bg=bg: np.abs(r) < bg, background=bg, pad=bg,
                            grid_class="unknown" if getattr(meta, "unsigned", False)
                            else "level set", zipped=False), "sdf"))
    return specs


def _grids(volume) -> list:
    """The grids of a whole volume (see :func:`_specs`), each with its dense array."""
    from .base import as_meta

    meta = as_meta(volume)
    grids = []
    for g, field in _specs(meta, level_set_background(meta, getattr(volume, "sdf", None))):
        g.raw = getattr(volume, field)
        grids.append(g)
    return grids


def _transform(volume) -> bytes:
    """ScaleTranslateMap: index (i, j, k) -> voxel 0's centre + (i, j, k) * spacing."""
    from .headers import origin_of

    scale = np.asarray(volume.spacing, dtype=np.float64)
    name = "UniformScaleTranslateMap" if np.all(scale == scale[0]) else "ScaleTranslateMap"
    # Translation and scale, then the derived terms OpenVDB stores beside them.
    fields = (origin_of(volume), scale, np.abs(scale), 1.0 / scale, 1.0 / scale ** 2, 0.5 / scale)
    return _string(name) + b"".join(np.asarray(f, dtype="<f8").tobytes() for f in fields)


def _grid_metadata(g: _Grid, shape, stats: _Stats) -> bytes:
    items = {
        "class": ("string", g.grid_class.encode()),
        "name": ("string", g.name.encode()),
        "is_saved_as_half_float": ("bool", b"\0"),
        "file_voxel_count": ("int64", struct.pack("<q", stats.count)),
        # geovox's own: the dense grid's shape, for reading the volume back whole.
        "geovox_shape": ("vec3i", struct.pack("<3i", *shape)),
    }
    if g.vector:
        items["vector_type"] = ("string", b"invariant")
    if g.stored:
        items["geovox_values"] = ("string", g.stored.encode())
    if stats.count:
        # Index-space bounding box of the active voxels (Houdini shows it before loading).
        items["file_bbox_min"] = ("vec3i", struct.pack("<3i", *(int(v) for v in stats.lo)))
        items["file_bbox_max"] = ("vec3i", struct.pack("<3i", *(int(v) for v in stats.hi)))
    return _metadata(items)


def write_vdb(volume, path) -> list:
    """Write ``volume`` as an OpenVDB file (see the module docstring)."""
    from .base import as_meta, atomic_output

    path = os.fspath(path)
    with atomic_output(path) as tmp:
        _write_file(tmp, as_meta(volume), [(g, _tree(g)) for g in _grids(volume)])
    return [path]


def _write_file(path, meta, trees) -> None:
    """The file: header, then each grid of ``trees`` (``(grid, lazy tree)`` pairs, the tree
    ``(topology, buffers, stats)`` made as the grid is written); ``meta`` places the voxels."""
    import uuid  # (not imported with the format registry)

    from ..version import __version__

    header = (struct.pack("<qIIIB", MAGIC, FILE_VERSION, *LIBRARY_VERSION, 1)
              + str(uuid.uuid4()).encode()
              + _metadata({"creator": ("string", f"geovox {__version__}".encode())}))
    with open(path, "wb") as f:
        f.write(header + struct.pack("<i", len(trees)))
        pos = len(header) + 4
        for g, tree in trees:
            type_name = "Tree_vec3s_5_4_3" if g.vector else "Tree_float_5_4_3"
            descriptor = _string(g.name) + _string(type_name) + _string("")
            topology, buffers, stats = tree() if callable(tree) else tree
            flags = COMPRESSION if g.zipped else COMPRESS_ACTIVE_MASK
            head = (struct.pack("<I", flags) + _grid_metadata(g, meta.shape, stats)
                    + _transform(meta))
            # The descriptor's offsets: the grid, its leaf buffers, its end.
            grid_pos = pos + len(descriptor) + 24
            block_pos = grid_pos + len(head) + len(topology)
            end = block_pos + len(buffers)
            f.write(descriptor + struct.pack("<3q", grid_pos, block_pos, end))
            f.write(head)
            f.write(topology)
            f.write(buffers)
            pos = end


class VDBWriter(SlabWriter):
    """Writes a ``.vdb`` one z-slab at a time, holding only what the file keeps.

    Each slab is reduced as it comes to what its grids' trees need: per 8³
    block whether it is one value (and which), and the raw values of the
    blocks that are not -- the leaves, which a level set has only along its
    narrow band and a fog volume only along the surface. The file is written
    on :meth:`close` from those, with the trees :func:`write_vdb` makes of
    the whole volume (tests/test_distance.py). Slabs must start on multiples of 8 voxels in z (a
    leaf's side); a level set needs a finite band (its background pads the
    slabs: :func:`level_set_background`).

    Memory: the blocks' summary (about 9 bytes per 512 voxels a grid) and the
    leaves (512 values each), not the grid.
    """

    def __init__(self, path, meta, jobs: int = 1):
        from .base import as_meta, atomic_outputs

        self.path, self.meta = os.fspath(path), as_meta(meta)
        if self.meta.dtype("sdf") is not None and not (
                self.meta.band is not None and np.isfinite(self.meta.band)):
            # The background (the largest distance) pads every slab: it must be known first.
            raise ParameterError("a .vdb level set is written slab by slab only with a finite "
                                 "band (its background); with --band inf it is written whole")
        self._ctx = atomic_outputs()
        self.group = self._ctx.__enter__()
        self.tmp = self.group.add(self.path)
        self.specs = _specs(self.meta, level_set_background(self.meta))
        self.parts = [[] for _ in self.specs]  # per grid, per slab: (uni8, lo8, leaves, blocks)

    def write(self, z0: int, vol) -> None:
        """Take the slab ``vol`` whose first layer is ``z0`` (the next one in z)."""
        if z0 % (1 << LEAF):
            raise ValueError(f"a .vdb slab must start on a multiple of {1 << LEAF} layers, got {z0}")
        for (g, field), parts in zip(self.specs, self.parts):
            raw = getattr(vol, field)
            lo, hi = _block_extrema(raw, 1 << LEAF, g.pad)
            uni = _same(lo, hi)
            local = np.argwhere(~uni)
            blocks = _dense_leaves(raw, g.pad)(local) if len(local) else None
            local[:, 2] += z0 >> LEAF
            parts.append((uni, lo, local, blocks))

    def _finish(self) -> list:
        trees = [(g, self._tree(g, parts)) for (g, _), parts in zip(self.specs, self.parts)]
        _write_file(self.tmp, self.meta, trees)
        self.parts = None
        self._ctx.__exit__(None, None, None)
        return [self.path]

    def _release(self) -> None:
        self.parts = None  # no file is open between slabs

    def _tree(self, g, parts):
        """The grid's tree, made when the file reaches it, from the slabs' parts."""
        def make():
            uni8 = np.concatenate([p[0] for p in parts], axis=2)
            lo8 = np.concatenate([p[1] for p in parts], axis=2)
            leaves = np.concatenate([p[2] for p in parts])
            stored = [p[3] for p in parts if p[3] is not None]
            blocks = np.concatenate(stored) if stored else None
            # Where each leaf's block is among those stored.
            where = np.full(uni8.shape, -1, np.int64)
            where[tuple(leaves.T)] = np.arange(len(leaves))
            parts.clear()  # the slabs' arrays are in the concatenated ones now

            def leaf_blocks(idx):
                return blocks[where[tuple(np.asarray(idx).T)]]

            return _tree(g, (uni8, lo8), leaf_blocks, self.meta.shape)

        return make


# --- reading back (the subset geovox writes: float and vec3s trees, zlib or no compression) ---

class _Reader:
    def __init__(self, data: bytes):
        self.data, self.pos = data, 0

    def take(self, n: int) -> bytes:
        if self.pos + n > len(self.data):
            raise ValueError("the file ends early")
        b = self.data[self.pos:self.pos + n]
        self.pos += n
        return b

    def unpack(self, fmt: str):
        return struct.unpack("<" + fmt, self.take(struct.calcsize("<" + fmt)))

    def string(self) -> str:
        (n,) = self.unpack("I")
        return self.take(n).decode()

    def metadata(self) -> dict:
        (count,) = self.unpack("I")
        out = {}
        for _ in range(count):
            name, type_name = self.string(), self.string()
            (size,) = self.unpack("I")
            value = self.take(size)
            out[name] = {"string": lambda v: v.decode(), "vec3i": lambda v: struct.unpack("<3i", v),
                         "int64": lambda v: struct.unpack("<q", v)[0],
                         "bool": lambda v: v != b"\0"}.get(type_name, lambda v: v)(value)
        return out

    def mask(self, log2: int) -> np.ndarray:
        n = 1 << 3 * log2
        return np.unpackbits(np.frombuffer(self.take(n // 8), np.uint8), bitorder="little").astype(bool)

    def values(self, n, valmask, compression, background, log2):
        dtype, width = np.dtype("<f4"), background.size
        meta = self.take(1)[0]
        inactive = [background if meta == NO_MASK_OR_INACTIVE_VALS else -background, background]
        if meta in (2, 4, 5):
            inactive[0] = np.frombuffer(self.take(4 * width), dtype).copy()
            if meta == 5:
                inactive[1] = np.frombuffer(self.take(4 * width), dtype).copy()
        select = self.mask(log2) if meta in (3, 4, 5) else np.zeros(n, bool)
        count = int(valmask.sum()) if compression & COMPRESS_ACTIVE_MASK and meta != 6 else n
        nbytes = 4 * width * count
        if compression & 0x4:
            raise ValueError("Blosc-compressed VDB files are not supported; geovox writes zlib")
        if compression & COMPRESS_ZIP:
            (size,) = self.unpack("q")
            raw = self.take(-size) if size <= 0 else zlib.decompress(self.take(size))
        else:
            raw = self.take(nbytes)
        if len(raw) != nbytes:
            raise ValueError(f"a node holds {len(raw)} bytes of values, not {nbytes}")
        got = np.frombuffer(raw, dtype).reshape((count,) + background.shape)
        if count == n:
            return got.copy()
        out = np.where(select.reshape((n,) + (1,) * (background.ndim)), inactive[1], inactive[0])
        out = out.reshape((n,) + background.shape).astype(np.float32)
        out[valmask] = got
        return out


def _read_grid(r: _Reader, shape, vector: bool):
    """Dense values and active mask of the grid at ``r.pos`` (after its descriptor)."""
    (compression,) = r.unpack("I")
    meta = r.metadata()
    map_type = r.string()
    if map_type not in ("ScaleTranslateMap", "UniformScaleTranslateMap"):
        raise ValueError(f"unsupported transform {map_type}")
    translate, scale = np.array(r.unpack("3d")), np.array(r.unpack("3d"))
    r.take(4 * 24)  # the derived terms
    shape = tuple(meta.get("geovox_shape", shape))
    (buffers,) = r.unpack("i")
    width = 3 if vector else 1
    background = np.frombuffer(r.take(4 * width), "<f4").copy()
    background = background if vector else background.reshape(())
    tail = (3,) if vector else ()
    # x fastest, as geovox's arrays are (colour: components fastest, then x).
    dense = np.empty(tuple(shape[::-1]) + tail, np.float32)
    dense = dense.transpose((2, 1, 0) + tuple(range(3, 3 + len(tail))))
    dense[...] = background
    active = np.zeros(shape, bool, order="F")

    def put(origin, size, value, on):
        sl = tuple(slice(max(o, 0), max(min(o + size, n), 0)) for o, n in zip(origin, shape))
        dense[sl] = value
        active[sl] = on

    ntiles, nchildren = r.unpack("II")
    for _ in range(ntiles):
        origin = r.unpack("3i")
        value = np.frombuffer(r.take(4 * width), "<f4")
        (on,) = r.unpack("?")
        put(origin, 1 << (LEAF + N16 + N32), value if vector else value[0], on)
    leaves = []

    def node(origin, log2, child_log2):
        child_mask, value_mask = r.mask(log2), r.mask(log2)
        vals = r.values(1 << 3 * log2, value_mask, compression, background, log2)
        size, n = 1 << child_log2, 1 << log2
        slots = np.arange(n ** 3)
        coords = np.stack([slots >> 2 * log2, (slots >> log2) & (n - 1), slots & (n - 1)],
                          axis=1) * size + np.asarray(origin)
        tile = ~child_mask & (value_mask | np.any((vals != background).reshape(len(slots), -1), axis=1))
        if log2 == N16 and tile.any():
            # Leaf-sized tiles: expand the node's 16³ slots to its 128³ voxels at once.
            sl = tuple(slice(o, min(o + n * size, m)) for o, m in zip(origin, shape))
            cut = tuple(slice(0, q.stop - q.start) for q in sl)
            if all(q.stop > q.start for q in sl):
                def expand(a):
                    a = a.reshape((n, n, n) + a.shape[1:])
                    for axis in range(3):
                        a = np.repeat(a, size, axis=axis)
                    return a[cut]
                where = expand(tile)
                np.copyto(dense[sl], expand(vals), where=where[(...,) + (None,) * (vals.ndim - 1)])
                np.copyto(active[sl], expand(value_mask), where=where)
        else:
            for k in np.flatnonzero(tile):
                put(tuple(coords[k]), size, vals[k], value_mask[k])
        for k in np.flatnonzero(child_mask):
            if log2 == N32:
                node(tuple(coords[k]), N16, LEAF)
            else:
                leaves.append((tuple(coords[k]), r.mask(LEAF)))

    for _ in range(nchildren):
        node(r.unpack("3i"), N32, N16 + LEAF)
    for origin, _ in leaves:
        mask = r.mask(LEAF)
        vals = r.values(1 << 3 * LEAF, mask, compression, background, LEAF)
        n8 = 1 << LEAF
        block = vals.reshape((n8, n8, n8) + tail)
        sl = tuple(slice(o, min(o + n8, n)) for o, n in zip(origin, shape))
        cut = tuple(slice(0, s.stop - s.start) for s in sl)
        dense[sl] = block[cut]
        active[sl] = mask.reshape(n8, n8, n8)[cut]
    return dense, active, meta, translate, scale


def read_vdb(path):
    """A Volume from a ``.vdb`` file geovox wrote (grids ``density``, ``color``, ``sdf``).

    Occupancy is the density grid's (0/1) when no coverage was stored, else
    ``sdf < 0`` when there is a distance grid, else coverage ≥ 0.5.
    """
    from ..grid import Grid
    from ..volume import Volume

    with open(path, "rb") as f:
        r = _Reader(f.read())
    magic, version, _, _, offsets = r.unpack("qIIIB")
    if magic != MAGIC:
        raise ValueError("not an OpenVDB file")
    if not 222 <= version <= FILE_VERSION:
        raise ValueError(f"file version {version}: geovox reads versions 222 to {FILE_VERSION}")
    r.take(36)
    r.metadata()
    (count,) = r.unpack("i")
    grids = {}
    for _ in range(count):
        name, type_name, _ = r.string(), r.string(), r.string()
        _, _, end = r.unpack("3q")
        if type_name in ("Tree_float_5_4_3", "Tree_vec3s_5_4_3"):
            grids[name] = _read_grid(r, None, type_name == "Tree_vec3s_5_4_3")
        r.pos = end
    if "density" not in grids:
        raise ValueError("no `density` grid")
    dense, _, meta, translate, scale = grids["density"]
    stored = meta.get("geovox_values", "occupancy")
    extra = {}
    if stored == "uint8":
        extra["density"] = np.asfortranarray(np.rint(dense * 255).astype(np.uint8))
    elif stored != "occupancy":
        extra["density"] = np.asfortranarray(dense)
    if "sdf" in grids:
        extra["sdf"] = np.asfortranarray(grids["sdf"][0])
    if stored == "occupancy":
        occ = dense > 0
    elif "sdf" in grids:
        occ = grids["sdf"][0] < 0
    else:
        occ = dense >= 0.5
    colors = None
    if "color" in grids:
        rgb, on = grids["color"][0], grids["color"][1]
        colors = np.zeros(rgb.shape[:3] + (4,), np.uint8)
        colors[..., :3] = np.rint(np.clip(rgb, 0, 1) * 255)
        colors[..., 3] = np.where(on, 255, 0)
    lo = translate - 0.5 * scale
    shape = occ.shape
    return Volume(occupancy=np.asfortranarray(occ), grid=Grid(lo, lo + scale * np.asarray(shape), shape),
                  backend="?", source=os.fspath(path), colors=colors, **extra)
