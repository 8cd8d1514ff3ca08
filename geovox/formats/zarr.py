"""OME-Zarr 0.5 on Zarr v3: a chunked, sharded multiscale image, written slab by slab.

Layout of ``NAME.zarr`` (a folder)::

    zarr.json            group; attributes "ome" (OME-Zarr 0.5 multiscales) and "geovox"
    0/ 1/ 2/ ...         occupancy, uint8 0 outside / 255 inside, axes (z, y, x)
    color/0/ ...         RGBA, uint8, axes (c, z, y, x)         with colour
    density/0/ ...       coverage, uint8 or float32             with density
    sdf/0/ ...           signed distance, float32               with distance
    labels/labels/0/ ... label values, uint8 or uint16 (OME-Zarr image-label)  with labels
    fractions/0/ ...     per-label fractions, axes (c, z, y, x), one channel a label  with fractions

Each multiscale level halves the previous one (sides rounded up) until every
side is at most :data:`TOP`; ``scale`` is the level's voxel size and
``translation`` the centre of its voxel 0 (``lo + scale / 2``), so the levels
overlay each other in a viewer. The pyramid keeps thin parts: a coarse
occupancy voxel is inside when any of its 8 children is (the maximum), a
coarse colour is that of an inside child (the child with the highest alpha,
ties to the lowest corner), density is the mean of the children, and the
signed distance is their minimum -- the rule that keeps ``sdf < 0`` exactly
where occupancy says inside at every level, and is within half a voxel
diagonal of the true distance at the coarse centre (as the mean is).

Chunks are 64³ (``4 x 64³`` for colour), gzip level 1; shards are
``thick x 512 x 512``, where ``thick`` is the z-thickness of the slabs the
writer takes: level 0 has one shard row per slab, and level ``L`` has
``thick / 2**L`` rows per slab while that is a whole number of chunks, so a
slab writes its own shards of those levels too and no shard has two writers.
Coarser levels have 64-voxel shard rows and are made afterwards from the
level above them (:func:`build_levels`), one task per output shard.

Writing: zarr-python spends about 0.35 ms a chunk in its codec pipeline
(1.5 s for one 128 x 2048² slab, measured), more than the voxelisation of
it, so shards are assembled here as the Zarr v3 sharding codec defines them
(inner chunks gzip-compressed, then the index of ``(offset, nbytes)``
``uint64`` pairs with its CRC-32C, at the end), with the trick of
:mod:`geovox.formats.chunks`: chunks of zeros (the fill value) are not stored,
chunks of one value are compressed once. zarr-python writes the metadata and
:func:`read_zarr` reads with it; the levels above the slabs are made from
shards read back by :func:`read_block` (the tests check it against
zarr-python, and every level against the pyramid's rules).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from dataclasses import dataclass

import numpy as np

from ..errors import OutputError, ParameterError
from .base import FIELD_VALUES, as_meta

#: Chunk side; shard z-thickness must be a multiple of it.
CHUNK = 64
#: Shard side across y and x.
SHARD_XY = 512
#: The coarsest level has every side at most this.
TOP = 256
_EMPTY = np.uint64(2**64 - 1)

def _deflate():
    """ISA-L's zlib module (the same streams, much faster), or zlib where isal is missing.

    Imported here, not with the package: only .zarr output needs it.
    """
    try:
        from isal import isal_zlib
    except ImportError:  # pragma: no cover - isal has wheels for the common platforms
        import zlib as isal_zlib
    return isal_zlib


def _gzip(data) -> bytes:
    return _deflate().compress(data, 1, 31)  # wbits 31: the gzip container


@dataclass(frozen=True)
class Level:
    """One array of the pyramid: where it is, its shape and shard (z, y, x; colour adds c first)."""

    path: str
    shape: tuple
    shard: tuple


@dataclass(frozen=True)
class Field:
    """One multiscale image: occupancy (the root), color, density or sdf."""

    name: str
    dtype: str
    channels: int  # 0 for a scalar field, 4 for RGBA
    levels: tuple


@dataclass(frozen=True)
class Layout:
    """What a writer (on any machine) needs to put a slab in place; small and picklable.

    ``root`` is the folder being written (the temporary name until it is
    renamed), ``thick`` the slab thickness in z at level 0, and ``in_slab``
    the number of levels each slab writes itself (level 0 and the next
    ``in_slab - 1``); the rest are made by :func:`build_levels`.
    """

    root: str
    shape: tuple  # (nx, ny, nz) of level 0
    thick: int
    in_slab: int
    fields: tuple


def level_shapes(shape) -> list:
    """``[(nz, ny, nx), ...]``: level 0 and each half of it (sides rounded up) down to <= TOP."""
    zyx = tuple(int(n) for n in shape[::-1])
    out = [zyx]
    while max(out[-1]) > TOP:
        out.append(tuple(-(-n // 2) for n in out[-1]))
    return out


def in_slab_levels(thick: int, n_levels: int) -> int:
    """How many levels a slab of ``thick`` layers writes itself: while its part is whole chunks."""
    k = 1
    while k < n_levels and (thick >> k) % CHUNK == 0 and (thick >> k) << k == thick:
        k += 1
    return k


def check_thick(thick) -> int:
    """``thick`` as an int, or ParameterError: slabs must be a whole number of 64-voxel chunks."""
    if isinstance(thick, bool) or not isinstance(thick, (int, np.integer)) or thick < CHUNK \
            or thick % CHUNK:
        raise ParameterError(f"`slab` must be a positive multiple of {CHUNK} voxels (the Zarr chunk "
                             f"side), got {thick!r}")
    return int(thick)


def make_layout(root, meta, thick: int) -> Layout:
    """The arrays of a ``.zarr`` output of ``meta``'s grid and fields, for slabs of ``thick`` layers."""
    thick = check_thick(thick)
    shapes = level_shapes(meta.shape)
    in_slab = in_slab_levels(thick, len(shapes))

    def levels(prefix, channels):
        out = []
        for k, s in enumerate(shapes):
            z = thick >> k if k < in_slab else CHUNK
            shard = (z,) + tuple(min(SHARD_XY, -(-n // CHUNK) * CHUNK) for n in s[1:])
            if channels:
                s, shard = (channels,) + s, (channels,) + shard
            out.append(Level(prefix + str(k), s, shard))
        return tuple(out)

    meta = as_meta(meta)
    fields = [Field("occupancy", "uint8", 0, levels("", 0))]
    if meta.colors:
        fields.append(Field("color", "uint8", 4, levels("color/", 4)))
    for name in ("density", "sdf"):
        if meta.dtype(name) is not None:
            fields.append(Field(name, str(meta.dtype(name)), 0, levels(name + "/", 0)))
    if meta.dtype("labels") is not None:
        # OME-Zarr's labels/ group: one label image, "labels/labels".
        fields.append(Field("labels", str(meta.dtype("labels")), 0, levels("labels/labels/", 0)))
    if meta.fractions is not None:
        # One channel per label (index k: label k + 1), as colour has one per component.
        n, dtype = meta.fractions
        fields.append(Field("fractions", str(dtype), int(n), levels("fractions/", int(n))))
    return Layout(os.fspath(root), tuple(int(n) for n in meta.shape), thick, in_slab, tuple(fields))


def multiscales(meta, field: Field, unit=None) -> dict:
    """The OME-Zarr 0.5 ``multiscales`` entry of one field (scale and translation per level)."""
    h = np.asarray(meta.spacing, dtype=np.float64)[::-1]  # (dz, dy, dx)
    lo = np.asarray(meta.bounds[0], dtype=np.float64)[::-1]
    axes = [{"name": a, "type": "space", **({"unit": unit} if unit else {})} for a in "zyx"]
    datasets = []
    for k, level in enumerate(field.levels):
        s = h * 2**k
        scale, shift = [float(x) for x in s], [float(x) for x in lo + 0.5 * s]
        if field.channels:
            scale, shift = [1.0] + scale, [0.0] + shift
        datasets.append({"path": level.path.rsplit("/", 1)[-1], "coordinateTransformations": [
            {"type": "scale", "scale": scale}, {"type": "translation", "translation": shift}]})
    if field.channels:
        axes = [{"name": "c", "type": "channel"}] + axes
    name = os.path.splitext(os.path.basename(str(meta.source)))[0] or "volume"
    return {"name": name if field.name == "occupancy" else f"{name} {field.name}",
            "axes": axes, "datasets": datasets}


def _zarr():
    """The zarr module, or a ParameterError that says what to install."""
    try:
        import zarr
    except ImportError:
        raise ParameterError("writing or reading .zarr needs zarr-python 3: "
                             "pip install 'geovox[distributed]'") from None
    return zarr


def create(layout: Layout, meta, unit=None) -> None:
    """Write every group's and array's metadata under ``layout.root`` (no data yet)."""
    zarr = _zarr()
    from zarr.codecs import BytesCodec, GzipCodec

    from .headers import frame_metadata

    root = zarr.open_group(layout.root, mode="w", zarr_format=3)
    lo, hi = meta.bounds
    root.attrs["geovox"] = {
        "shape": list(meta.shape), "bounds": [list(lo), list(hi)],
        "spacing": list(meta.spacing), "axis_order": "zyx", "source": str(meta.source),
        "backend": meta.backend, "values": "0 outside, 255 inside",
        **{f.name + "_values": FIELD_VALUES[f.name](f.dtype) for f in layout.fields
           if f.name in FIELD_VALUES}, **frame_metadata(meta)}
    for field in layout.fields:
        if field.name == "labels":
            group = _label_group(root, meta, field, unit)
        else:
            group = root if field.name == "occupancy" else root.create_group(field.name)
            group.attrs["ome"] = {"version": "0.5", "multiscales": [multiscales(meta, field, unit)]}
        names = (["c"] if field.channels else []) + ["z", "y", "x"]
        chunk = ((field.channels,) if field.channels else ()) + (CHUNK,) * 3
        for level in field.levels:
            root.create_array(level.path, shape=level.shape, dtype=field.dtype, chunks=chunk,
                              shards=level.shard, compressors=GzipCodec(level=1),
                              serializer=BytesCodec(endian="little"), fill_value=0,
                              dimension_names=names)
    # What _shard_bytes writes must be what the metadata says.
    codecs = root[layout.fields[0].levels[0].path].metadata.to_dict()["codecs"]
    inner = codecs[0]["configuration"]
    assert [c["name"] for c in inner["codecs"]] == ["bytes", "gzip"], inner
    assert [c["name"] for c in inner["index_codecs"]] == ["bytes", "crc32c"], inner
    assert inner.get("index_location", "end") == "end", inner


def _label_group(root, meta, field, unit=None):
    """``labels/`` (listing one label image) and ``labels/labels`` with its ``image-label``
    metadata: a colour and properties (name, source, voxels, volume) per label value, and
    the image it labels (``source``: the root, two levels up)."""
    lg = root.create_group("labels")
    lg.attrs["ome"] = {"version": "0.5", "labels": ["labels"]}
    group = lg.create_group("labels")
    group.attrs["ome"] = label_attributes(meta, field, unit)
    return group


def label_attributes(meta, field, unit=None) -> dict:
    """The ``ome`` attributes of ``labels/labels``: its multiscales and ``image-label``."""
    table = [e for e in (meta.label_table or []) if e["value"] != 0]
    return {
        "version": "0.5", "multiscales": [multiscales(meta, field, unit)],
        "image-label": {
            "version": "0.5",
            "colors": [{"label-value": int(e["value"]), "rgba": [int(c) for c in e["color"]]}
                       for e in table],
            "properties": [{"label-value": int(e["value"]), "name": str(e["name"]),
                            "source": str(e.get("source", "")), "voxels": int(e.get("voxels", 0)),
                            "volume": float(e.get("volume", 0.0))} for e in table],
            "source": {"image": "../../"}}}


# --- writing shards -------------------------------------------------------

def _extrema(block: np.ndarray, jobs: int):
    """Per-chunk minimum and maximum of ``(z, y, x)`` or ``(c, z, y, x)`` (channels stacked last)."""
    from .chunks import chunk_extrema

    if block.ndim == 3:
        return chunk_extrema(np.ascontiguousarray(block), (CHUNK,) * 3, jobs)
    parts = [chunk_extrema(np.ascontiguousarray(b), (CHUNK,) * 3, jobs) for b in block]
    return np.stack([p[0] for p in parts], -1), np.stack([p[1] for p in parts], -1)


def _crc32c(data: bytes) -> bytes:
    import google_crc32c  # zarr's own dependency for the sharding index

    return np.uint32(google_crc32c.value(data)).astype("<u4").tobytes()


def write_block(root: str, level: Level, block: np.ndarray, origin=(0, 0, 0), *,
                scale: int = 1, jobs: int = 1) -> None:
    """Write ``block`` -- whole shards of one array -- into its shard files.

    Parameters
    ----------
    root : str
        The ``.zarr`` folder.
    level : Level
    block : (sz, sy, sx) or (c, sz, sy, sx) ndarray
        The voxels from ``origin`` on: a multiple of the shard shape on every
        axis, or up to the array's end.
    origin : (z0, y0, x0) int
        First voxel; multiples of the shard shape.
    scale : int
        Multiplier of the stored values (255 for occupancy given as 0/1).
    jobs : int
        Threads compressing chunks.

    Raises
    ------
    ParameterError
        The block does not cover whole shards (a shard would have two writers).
    """
    lead = block.ndim - 3
    shard = level.shard[lead:]
    shape = level.shape[lead:]
    extent = block.shape[lead:]
    for o, e, s, n in zip(origin, extent, shard, shape):
        if o % s or o + e > n or (e % s and o + e != n) or e == 0:
            raise ParameterError(
                f"a block must cover whole shards: {tuple(extent)} voxels at {tuple(origin)} of "
                f"{level.path or '0'} ({tuple(shape)} in shards of {tuple(shard)})")
    lo, hi = _extrema(block, jobs)
    if lead:
        uniform = (lo == hi).all(axis=-1)
        zero = uniform & (hi == 0).all(axis=-1)
    else:
        uniform, zero = lo == hi, (lo == hi) & (hi == 0)
    # A uniform chunk cut short by the block's edge is padded with zeros.
    full = np.zeros(uniform.shape, dtype=bool)
    full[:extent[0] // CHUNK, :extent[1] // CHUNK, :extent[2] // CHUNK] = True
    chunk = block.shape[:lead] + (CHUNK,) * 3
    stored = np.dtype(block.dtype).newbyteorder("<")
    cache: dict = {}

    def repeated(value) -> bytes:
        value = np.asarray(value).astype(stored)
        value = value.reshape((-1, 1, 1, 1)) if lead else value * stored.type(scale)
        key = value.tobytes()
        if key not in cache:
            cache[key] = _gzip(np.broadcast_to(value, chunk).tobytes())
        return cache[key]

    def encode(index):
        if zero[index]:
            return None
        if uniform[index] and full[index]:
            return repeated(lo[index])
        kz, ky, kx = index
        part = block[(slice(None),) * lead + (slice(kz * CHUNK, (kz + 1) * CHUNK),
                                              slice(ky * CHUNK, (ky + 1) * CHUNK),
                                              slice(kx * CHUNK, (kx + 1) * CHUNK))]
        data = np.zeros(chunk, dtype=stored)
        data[tuple(slice(0, n) for n in part.shape)] = part
        if scale != 1:
            data *= stored.type(scale)
        return _gzip(data.tobytes())

    per = tuple(s // CHUNK for s in shard)
    n_chunks = tuple(-(-e // CHUNK) for e in extent)
    first = tuple(o // s for o, s in zip(origin, shard))
    tiles = [(tz, ty, tx) for tz in range(-(-extent[0] // shard[0]))
             for ty in range(-(-extent[1] // shard[1])) for tx in range(-(-extent[2] // shard[2]))]

    def write_shard(tile):
        parts, offset = [], 0
        index = np.full(per + (2,), _EMPTY, dtype="<u8")
        start = tuple(t * p for t, p in zip(tile, per))
        for kz in range(start[0], min(start[0] + per[0], n_chunks[0])):
            for ky in range(start[1], min(start[1] + per[1], n_chunks[1])):
                for kx in range(start[2], min(start[2] + per[2], n_chunks[2])):
                    data = encode((kz, ky, kx))
                    if data is None:
                        continue
                    index[kz - start[0], ky - start[1], kx - start[2]] = (offset, len(data))
                    parts.append(data)
                    offset += len(data)
        key = os.path.join(root, level.path, "c", *(["0"] if lead else []),
                           *(str(f + t) for f, t in zip(first, tile)))
        if not parts:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(key)  # a shard of zeros is absent, as zarr leaves it
            return
        raw = index.tobytes()
        os.makedirs(os.path.dirname(key), exist_ok=True)
        with open(key, "wb") as f:
            f.writelines(parts)
            f.write(raw)
            f.write(_crc32c(raw))

    from concurrent.futures import ThreadPoolExecutor  # not imported with the format registry

    with ThreadPoolExecutor(max_workers=max(1, jobs)) as pool:
        list(pool.map(write_shard, tiles))


# --- the pyramid ----------------------------------------------------------

def _halve(a: np.ndarray, axis: int, pick, pad):
    """Pairs along ``axis`` combined by ``pick(first, second)``; an odd end is padded with ``pad``."""
    if a.shape[axis] % 2:
        shape = list(a.shape)
        shape[axis] = 1
        a = np.concatenate([a, np.full(shape, pad, dtype=a.dtype)], axis=axis)
    idx = [slice(None)] * a.ndim
    idx[axis] = slice(0, None, 2)
    first = a[tuple(idx)]
    idx[axis] = slice(1, None, 2)
    return pick(first, a[tuple(idx)])


def _halve_occupancy(a: np.ndarray) -> np.ndarray:
    """The maximum over 2 x 2 x 2 children of 0/v bytes ``(z, y, x)``, as 0/1.

    OR is the maximum of 0/v values, and the last step compares byte pairs
    as one uint16 (a byte-strided maximum along x took 4x as long). Eight
    layers at a time, in buffers that stay in cache: a whole 128 x 2048²
    slab at once spent most of its 0.9 s touching fresh temporary memory.
    """
    if any(n % 2 for n in a.shape):
        a = np.pad(a, [(0, n % 2) for n in a.shape])
    nz, ny, nx = a.shape
    out = np.empty((nz // 2, ny // 2, nx // 2), dtype=np.uint8)
    step = 4
    b = np.empty((step, ny, nx), dtype=np.uint8)
    c = np.empty((step, ny // 2, nx), dtype=np.uint8)
    for z in range(0, nz // 2, step):
        k = min(step, nz // 2 - z)
        np.bitwise_or(a[2 * z:2 * (z + k):2], a[2 * z + 1:2 * (z + k):2], out=b[:k])
        np.bitwise_or(b[:k, 0::2], b[:k, 1::2], out=c[:k])
        np.not_equal(c[:k].view(np.uint16), 0, out=out[z:z + k].view(bool))
    return out


def downsample(a: np.ndarray, name: str) -> np.ndarray:
    """One pyramid step of a field: ``(.., z, y, x)`` -> halves (sides rounded up).

    ``occupancy`` (0/v, any v): the maximum, as 0/1; ``color`` ``(4, z, y, x)``: the
    child with the highest alpha (ties to the lowest corner); ``density``:
    the mean of the children that exist (rounded for uint8); ``sdf``: the
    minimum.
    """
    axes = (a.ndim - 3, a.ndim - 2, a.ndim - 1)
    if name == "occupancy":
        return _halve_occupancy(a)
    if name == "sdf":
        for ax in axes:
            a = _halve(a, ax, np.minimum, np.inf)
        return a
    if name == "labels":
        # The largest child value: a coarse voxel with a labelled child stays labelled.
        for ax in axes:
            a = _halve(a, ax, np.maximum, 0)
        return a
    if name == "fractions":
        # Each label's channel by the density rule (the mean of the children).
        return np.stack([downsample(c, "density") for c in a])
    if name == "color":
        def pick(p, q):
            return np.where(q[3:4] > p[3:4], q, p)
        for ax in axes:
            a = _halve(a, ax, pick, 0)
        return a
    # density: sums and how many children each coarse voxel has
    total = a.astype(np.float64 if a.dtype == np.float32 else np.uint32)
    count = np.ones((1, 1, 1), dtype=np.uint32)
    for ax in axes:
        total = _halve(total, ax, np.add, 0)
        c = np.full(a.shape[ax], 1, dtype=np.uint32)
        c = _halve(c, 0, np.add, 0)
        count = count * c.reshape([-1 if i == ax else 1 for i in range(3)])
    if a.dtype == np.uint8:
        # Round half up, in integers: floor((2 * total + count) / (2 * count)).
        return ((2 * total + count) // (2 * count)).astype(np.uint8)
    return (total / count).astype(a.dtype)


def slab_fields(vol) -> dict:
    """The arrays of a slab Volume in Zarr order: name -> ``(.., z, y, x)`` view (no copy)."""
    out = {"occupancy": vol.occupancy.view(np.uint8).T}
    if vol.colors is not None:
        out["color"] = vol.colors.transpose(3, 2, 1, 0)
    for name in ("density", "sdf", "labels"):
        arr = getattr(vol, name, None)
        if arr is not None:
            out[name] = arr.T
    if getattr(vol, "fractions", None) is not None:
        out["fractions"] = vol.fractions.transpose(3, 2, 1, 0)
    return out


def write_slab(layout: Layout, z0: int, vol, jobs: int = 1) -> None:
    """Write slab ``z0 ..`` (a Volume over the whole x-y extent) at level 0 and its in-slab levels.

    Raises
    ------
    ParameterError
        The slab does not start on a shard boundary or does not fill its
        shards (see :func:`write_block`): two writers would share a shard.
    """
    z0 = int(z0)
    depth = vol.shape[2]
    nz = layout.shape[2]
    if z0 % layout.thick or depth != min(layout.thick, nz - z0) or tuple(vol.shape[:2]) != \
            tuple(layout.shape[:2]):
        raise ParameterError(
            f"a slab must be layers z0..z0+{layout.thick} with z0 a multiple of {layout.thick} "
            f"(the shard rows of this .zarr), over the whole x-y extent {layout.shape[:2]}; got "
            f"z {z0}..{z0 + depth}, {tuple(vol.shape[:2])} across")
    arrays = slab_fields(vol)
    for field in layout.fields:
        a = arrays[field.name]
        for k in range(layout.in_slab):
            if k:
                a = downsample(a, field.name)
            write_block(layout.root, field.levels[k], a, (z0 >> k, 0, 0),
                        scale=255 if field.name == "occupancy" else 1, jobs=jobs)


def level_tasks(layout: Layout, k: int) -> list:
    """``[(field, z0, y0, x0), ...]``: the output shards of after-level ``k``, one task each."""
    out = []
    for field in layout.fields:
        level = field.levels[k]
        lead = 1 if field.channels else 0
        nz, ny, nx = level.shape[lead:]
        sz, sy, sx = level.shard[lead:]
        out += [(field.name, z, y, x) for z in range(0, nz, sz) for y in range(0, ny, sy)
                for x in range(0, nx, sx)]
    return out


def _chunks(root: str, level: Level, origin, stop):
    """Yield ``(start, raw)`` for each stored chunk of ``level`` meeting ``origin .. stop`` (z, y, x).

    ``start`` is the chunk's first voxel and ``raw`` its compressed bytes;
    absent chunks (zeros) are skipped. Shards are read as :func:`write_block`
    wrote them, without zarr-python (its codec pipeline cost about 0.16 ms a
    chunk, most of the time of making a level).
    """
    lead = len(level.shape) - 3
    shard = level.shard[lead:]
    per = tuple(s // CHUNK for s in shard)
    n = int(np.prod(per))
    ranges = [range(o // s, -(-b // s)) for o, b, s in zip(origin, stop, shard)]
    for key in ((a, b, c) for a in ranges[0] for b in ranges[1] for c in ranges[2]):
        path = os.path.join(root, level.path, "c", *(["0"] if lead else []), *map(str, key))
        try:
            with open(path, "rb") as f:
                data = f.read()
        except FileNotFoundError:
            continue  # a shard of zeros
        index = np.frombuffer(data, "<u8", count=2 * n, offset=len(data) - 4 - 16 * n)
        index = index.reshape(per + (2,))
        for k in np.ndindex(per):
            offset, nbytes = (int(v) for v in index[k])
            if offset == int(_EMPTY):
                continue
            start = tuple(sk * s + kk * CHUNK for sk, s, kk in zip(key, shard, k))
            if all(a < b and a + CHUNK > o for a, o, b in zip(start, origin, stop)):
                yield start, data[offset:offset + nbytes]


def read_block(root: str, level: Level, dtype, origin, extent) -> np.ndarray:
    """Voxels ``origin .. origin + extent`` (z, y, x; clipped to the array) of one array."""
    lead = len(level.shape) - 3
    stop = [min(o + e, n) for o, e, n in zip(origin, extent, level.shape[lead:])]
    dtype = np.dtype(dtype)
    out = np.zeros(level.shape[:lead] + tuple(b - a for a, b in zip(origin, stop)), dtype=dtype)
    chunk = level.shape[:lead] + (CHUNK,) * 3
    inflate = _deflate().decompress
    for start, raw in _chunks(root, level, origin, stop):
        src = tuple(slice(max(a, o) - a, min(a + CHUNK, b) - a) for a, o, b in zip(start, origin, stop))
        dst = tuple(slice(max(a, o) - o, min(a + CHUNK, b) - o) for a, o, b in zip(start, origin, stop))
        values = np.frombuffer(inflate(raw, 31), dtype=dtype.newbyteorder("<")).reshape(chunk)
        out[(...,) + dst] = values[(...,) + src]
    return out


def make_level_tile(layout: Layout, k: int, task, jobs: int = 1) -> None:
    """Make one output shard of level ``k`` from level ``k - 1`` (already complete) and write it.

    Chunk by chunk: a chunk starts on an even voxel, so its children never
    straddle two chunks and its own half is the level's there; an absent
    chunk halves to zeros (under every rule) and a full chunk of 255 to ones,
    neither decompressed, and the fine level is never held whole.
    """
    name, z0, y0, x0 = task
    field = next(f for f in layout.fields if f.name == name)
    level, fine = field.levels[k], field.levels[k - 1]
    lead = 1 if field.channels else 0
    origin = (z0, y0, x0)
    stop = [min(o + s, n) for o, s, n in zip(origin, level.shard[lead:], level.shape[lead:])]
    fine_stop = [min(2 * b, n) for b, n in zip(stop, fine.shape[lead:])]
    dtype = np.dtype(field.dtype)
    out_dtype = np.uint8 if name == "occupancy" else dtype
    out = np.zeros(level.shape[:lead] + tuple(b - a for a, b in zip(origin, stop)), dtype=out_dtype)
    chunk = level.shape[:lead] + (CHUNK,) * 3
    full = _gzip(np.full(chunk, 255, np.uint8).tobytes()) if name == "occupancy" else None
    inflate = _deflate().decompress
    for start, raw in _chunks(layout.root, fine, tuple(2 * o for o in origin), fine_stop):
        valid = tuple(min(CHUNK, n - a) for a, n in zip(start, fine.shape[lead:]))
        dst = tuple(slice(a // 2 - o, (a + v + 1) // 2 - o) for a, v, o in zip(start, valid, origin))
        if raw == full:
            out[dst] = 1
            continue
        values = np.frombuffer(inflate(raw, 31), dtype=dtype.newbyteorder("<")).reshape(chunk)
        out[(...,) + dst] = downsample(values[(...,) + tuple(slice(0, v) for v in valid)], name)
    write_block(layout.root, level, out, origin, scale=255 if name == "occupancy" else 1, jobs=jobs)


def build_levels(layout: Layout, client=None, jobs: int = 1) -> None:
    """Make the levels no slab wrote, each from the one above it.

    With a ``dask.distributed`` client each output shard is a task on a
    worker (a level waits for the one above it); without one they run here.
    """
    for k in range(layout.in_slab, len(layout.fields[0].levels)):
        tasks = level_tasks(layout, k)
        if client is None:
            for t in tasks:
                make_level_tile(layout, k, t, jobs)
        else:
            futures = client.map(make_level_tile, [layout] * len(tasks), [k] * len(tasks), tasks,
                                 pure=False)
            client.gather(futures)


# --- the writer and the reader --------------------------------------------

class ZarrWriter:
    """Writes a ``.zarr`` folder slab by slab under a temporary name, renamed into place on close.

    ``meta`` is the :class:`~geovox.formats.base.Meta` of the whole volume
    (or the volume itself, written whole). Slabs are ``thick`` layers (a multiple of 64; default the whole depth,
    :func:`whole_thick`) starting on multiples of ``thick``; any process that
    can reach the folder may write them (see :attr:`layout` and
    :func:`write_slab`). The first three parameters are every slab writer's
    (see :class:`geovox.formats.Format`); ``client``, a Dask client, makes
    the coarser pyramid levels on its workers when the writer is closed.
    """

    def __init__(self, path, meta, jobs: int = 2, *, thick=None, client=None, unit=None):
        import tempfile

        meta = as_meta(meta)
        self.path, self.jobs, self.client = os.fspath(path), jobs, client
        self.meta, self.unit = meta, unit
        thick = check_thick(whole_thick(meta.shape) if thick is None else thick)
        folder = os.path.dirname(os.path.abspath(self.path))
        try:
            tmp = tempfile.mkdtemp(prefix="." + os.path.basename(self.path) + ".", suffix=".tmp",
                                   dir=folder)
        except OSError as exc:
            raise OutputError(f"cannot write in {folder}: {exc.strerror or exc}") from exc
        os.chmod(tmp, 0o777 & ~_umask())
        self.layout = make_layout(tmp, meta, thick)
        try:
            create(self.layout, meta, unit)
        except BaseException as exc:
            self._fail(exc)

    def write(self, z0: int, vol) -> None:
        """Write ``vol`` (a Volume covering layers z0 .. z0 + its depth) into place."""
        try:
            write_slab(self.layout, z0, vol, self.jobs)
        except OSError as exc:
            self._fail(exc)

    def write_whole(self, volume) -> list:
        try:
            for z0 in range(0, volume.shape[2], self.layout.thick):
                self.write(z0, _slab_of(volume, z0, min(z0 + self.layout.thick, volume.shape[2])))
        except BaseException as exc:
            self._fail(exc)
        return self.close()

    def close(self) -> list:
        """Make the remaining levels (on the client's workers if there is one) and rename into place."""
        try:
            self._label_table()
            build_levels(self.layout, self.client, self.jobs)
            _replace_folder(self.layout.root, self.path)
        except BaseException as exc:
            self._fail(exc)
        return [self.path]

    def _label_table(self) -> None:
        """The labels' ``image-label`` again, from ``meta.label_table`` as it is now.

        Streamed, the counts (``voxels``, ``volume``) are known only once
        every slab is made (:func:`geovox.runners.run_slabs` sets them).
        """
        field = next((f for f in self.layout.fields if f.name == "labels"), None)
        if field is None:
            return
        group = _zarr().open_group(self.layout.root, mode="r+", zarr_format=3)
        group["labels/labels"].attrs["ome"] = label_attributes(self.meta, field, self.unit)

    def _fail(self, exc):
        """Drop everything and raise ``exc`` (an OS error as an OutputError)."""
        self.abort()
        if isinstance(exc, OSError) and not isinstance(exc, OutputError):
            import errno

            if exc.errno == errno.ENOSPC:
                raise OutputError(f"disk full while writing {self.path}; nothing was written") \
                    from exc
            raise OutputError(f"cannot write {self.path}: {exc.strerror or exc}") from exc
        raise exc

    def abort(self) -> None:
        """Drop everything written (call from an ``except`` block)."""
        shutil.rmtree(self.layout.root if hasattr(self, "layout") else "", ignore_errors=True)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _replace_folder(tmp: str, path: str) -> None:
    """Rename ``tmp`` to ``path``; an existing ``.zarr`` there is replaced only once ``tmp`` is whole."""
    if not os.path.lexists(path):
        os.replace(tmp, path)
        return
    old = tmp + ".old"
    os.replace(path, old)
    try:
        os.replace(tmp, path)
    except BaseException:
        os.replace(old, path)
        raise
    if os.path.isdir(old) and not os.path.islink(old):
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.unlink(old)


def _slab_of(volume, z0: int, z1: int):
    """Layers z0..z1 of an in-memory Volume, as a Volume (views, no copies)."""
    from ..grid import Grid
    from ..volume import Volume

    cut = slice(z0, z1)
    return Volume(occupancy=volume.occupancy[:, :, cut],
                  grid=Grid(volume.grid.lo, volume.grid.hi, volume.occupancy[:, :, cut].shape),
                  backend=volume.backend,
                  colors=None if volume.colors is None else volume.colors[:, :, cut],
                  density=None if volume.density is None else volume.density[:, :, cut],
                  sdf=None if volume.sdf is None else volume.sdf[:, :, cut],
                  labels=None if volume.labels is None else volume.labels[:, :, cut],
                  label_table=volume.label_table,
                  fractions=None if volume.fractions is None else volume.fractions[:, :, cut])


def whole_thick(shape) -> int:
    """Slab thickness for writing a volume held in memory: the whole depth, in whole chunks."""
    return max(CHUNK, -(-int(shape[2]) // CHUNK) * CHUNK)


def write_zarr(volume, path, jobs: int = 2) -> list:
    """Write the volume as an OME-Zarr 0.5 image (see the module's docstring for the layout)."""
    return ZarrWriter(path, volume, jobs).write_whole(volume)


def pick_level(shapes, max_side=None) -> int:
    """The finest level whose sides are all at most ``max_side`` (the coarsest if none is)."""
    if max_side is None:
        return 0
    for k, s in enumerate(shapes):
        if max(s) <= max_side:
            return k
    return len(shapes) - 1


def read_zarr(path, max_side=None, level=None):
    """A Volume from a ``.zarr`` written by geovox.

    Parameters
    ----------
    path : str
    max_side : int, optional
        Read the finest level whose sides are all at most this (a viewer
        opening a 4096³ volume asks for what fits); default level 0.
    level : int, optional
        Read this level instead.
    """
    zarr = _zarr()

    from ..grid import Grid
    from ..volume import Volume

    g = zarr.open_group(os.fspath(path), mode="r")
    info = g.attrs["geovox"]
    paths = [d["path"] for d in g.attrs["ome"]["multiscales"][0]["datasets"]]
    if level is None:
        level = pick_level([g[p].shape for p in paths], max_side)
    a = g[paths[level]]
    occ = np.asfortranarray(a[...].T > 0)
    lo, hi = (np.asarray(b, dtype=np.float64) for b in info["bounds"])
    if level:
        h = np.asarray(info["spacing"], dtype=np.float64) * 2**level
        hi = lo + h * np.asarray(occ.shape)
    colors = None
    if "color" in g:
        c = g["color"][paths[level]][...]
        base = np.empty(c.shape[1:] + (4,), dtype=np.uint8)
        base[...] = c.transpose(1, 2, 3, 0)
        colors = base.transpose(2, 1, 0, 3)
    extra = {name: np.asfortranarray(g[name][paths[level]][...].T) for name in ("density", "sdf")
             if name in g}
    if "labels" in g and "labels" in g["labels"]:
        extra.update(_read_labels(g["labels/labels"], paths[level]))
    if "fractions" in g:
        extra["fractions"] = g["fractions"][paths[level]][...].transpose(3, 2, 1, 0)
    return Volume(occupancy=occ, grid=Grid(lo, hi, occ.shape), backend=str(info.get("backend", "?")),
                  source=str(info.get("source", path)), colors=colors, **extra)


def _read_labels(group, path) -> dict:
    """``labels`` and ``label_table`` from the ``labels/labels`` image (its ``image-label``)."""
    meta = group.attrs["ome"]["image-label"]
    colour = {c["label-value"]: list(c["rgba"]) for c in meta.get("colors", [])}
    table = [{"value": 0, "name": "background", "color": [0, 0, 0, 0]}]
    for q in meta.get("properties", []):
        v = int(q["label-value"])
        table.append({"value": v, "name": q.get("name", str(v)), "source": q.get("source", ""),
                      "color": colour.get(v, [0, 0, 0, 255]), "voxels": q.get("voxels"),
                      "volume": q.get("volume")})
    return {"labels": np.asfortranarray(group[path][...].T), "label_table": table}
