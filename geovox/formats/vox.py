"""MagicaVoxel ``.vox`` (format version 150) for coloured voxels.

A model holds at most 256 voxels per axis and colours are indices into a
palette of 255 entries, so: colours are quantised with Pillow's median cut
(built from a sample of up to a million voxels, every distinct colour then
mapped to its nearest palette entry), and a grid larger than 256 on an axis
is split into tiles of at most 256³, one model each, placed by a scene graph
(``nTRN`` -> ``nGRP`` -> ``nTRN`` + ``nSHP`` per model) so MagicaVoxel shows
them assembled. ``shell=True`` keeps only the voxels with a face on the
outside, which is all a voxel editor shows and keeps files small.
Coordinates: MagicaVoxel's z is up, like geovox's z; a model's translation
``_t`` is its centre, ``offset + size // 2``, relative to the whole grid's
``shape // 2``.
"""

from __future__ import annotations

import os
import struct

import numpy as np

from ..errors import ParameterError

MAX_SIZE = 256
DEFAULT_RGB = (200, 200, 200)


def shell_mask(occ: np.ndarray) -> np.ndarray:
    """Inside voxels with at least one of their 6 neighbours outside (or off the grid)."""
    interior = occ.copy()
    for axis in range(3):
        lo = [slice(None)] * 3
        hi = [slice(None)] * 3
        lo[axis], hi[axis] = slice(1, None), slice(None, -1)
        interior[tuple(lo)] &= occ[tuple(hi)]
        interior[tuple(hi)] &= occ[tuple(lo)]
        edge = [slice(None)] * 3
        edge[axis] = 0
        interior[tuple(edge)] = False
        edge[axis] = -1
        interior[tuple(edge)] = False
    return occ & ~interior


def quantise(rgb: np.ndarray, colours: int = 255, seed: int = 0):
    """Palette of at most ``colours`` entries and each colour's index into it.

    Parameters
    ----------
    rgb : (n, 3) uint8

    Returns
    -------
    palette : (k, 3) uint8, k <= colours
    index : (n,) int64
    """
    from PIL import Image

    if len(rgb) == 0:
        return np.array([DEFAULT_RGB], np.uint8), np.zeros(0, np.int64)
    packed = rgb[:, 0].astype(np.uint32) << 16 | rgb[:, 1].astype(np.uint32) << 8 | rgb[:, 2]
    uniq, inverse = np.unique(packed, return_inverse=True)
    urgb = np.stack([(uniq >> 16) & 255, (uniq >> 8) & 255, uniq & 255], axis=1).astype(np.uint8)
    if len(uniq) <= colours:
        return urgb, inverse.reshape(-1)
    rng = np.random.default_rng(seed)
    sample = rgb[rng.choice(len(rgb), min(len(rgb), 1 << 20), replace=False)]
    pimg = Image.fromarray(sample.reshape(1, -1, 3)).quantize(
        colors=colours, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    mapped = Image.fromarray(urgb.reshape(1, -1, 3)).quantize(palette=pimg, dither=Image.Dither.NONE)
    palette = np.asarray(pimg.getpalette()[: 3 * colours], dtype=np.uint8).reshape(-1, 3)
    return palette, np.asarray(mapped).reshape(-1)[inverse.reshape(-1)].astype(np.int64)


def _chunk(cid: bytes, content: bytes, children: bytes = b"") -> bytes:
    return cid + struct.pack("<ii", len(content), len(children)) + content + children


def _string(s: str) -> bytes:
    b = s.encode()
    return struct.pack("<i", len(b)) + b


def _dict(d: dict) -> bytes:
    return struct.pack("<i", len(d)) + b"".join(_string(k) + _string(v) for k, v in d.items())


def encode(occ: np.ndarray, colors: np.ndarray | None, shell: bool = False,
           labels: np.ndarray | None = None, label_rgb: np.ndarray | None = None) -> bytes:
    """The bytes of a .vox file for an occupancy grid and optional RGBA colours.

    With ``labels`` (values 1..255 inside) and ``label_rgb`` (L, 3) uint8,
    label ``v`` is palette entry ``v`` in colour ``label_rgb[v - 1]``, instead
    of quantised colours.
    """
    keep = shell_mask(occ) if shell else occ
    idx = np.argwhere(keep)
    if colors is not None:
        rgb = colors[keep][:, :3]
    else:
        rgb = np.tile(np.array(DEFAULT_RGB, np.uint8), (len(idx), 1))
    if labels is not None:
        palette, pal_index = label_rgb, labels[keep].astype(np.int64) - 1
    else:
        palette, pal_index = quantise(rgb)
    shape = np.array(occ.shape)
    tiles = [range(0, n, MAX_SIZE) for n in shape]
    models, graph = [], []
    tile_of = idx // MAX_SIZE
    ntile = -(-shape // MAX_SIZE)
    tile_id = (tile_of[:, 0] * ntile[1] + tile_of[:, 1]) * ntile[2] + tile_of[:, 2]
    order = np.argsort(tile_id, kind="stable")
    bounds = np.searchsorted(tile_id[order], np.arange(int(np.prod(ntile)) + 1))
    placed = []
    for tx in tiles[0]:
        for ty in tiles[1]:
            for tz in tiles[2]:
                off = np.array([tx, ty, tz])
                size = np.minimum(shape - off, MAX_SIZE)
                t = ((tx // MAX_SIZE) * ntile[1] + ty // MAX_SIZE) * ntile[2] + tz // MAX_SIZE
                sel = order[bounds[t]:bounds[t + 1]]
                xyzi = np.empty((len(sel), 4), np.uint8)
                xyzi[:, :3] = idx[sel] - off
                xyzi[:, 3] = pal_index[sel] + 1
                models.append(_chunk(b"SIZE", struct.pack("<iii", *size))
                              + _chunk(b"XYZI", struct.pack("<i", len(sel)) + xyzi.tobytes()))
                placed.append(off + size // 2 - shape // 2)
    # Scene graph: root transform 0 -> group 1 -> (transform, shape) per model.
    n = len(models)
    child_ids = [2 + 2 * k for k in range(n)]
    graph.append(_chunk(b"nTRN", struct.pack("<i", 0) + _dict({}) + struct.pack("<iiii", 1, -1, -1, 1)
                        + _dict({})))
    graph.append(_chunk(b"nGRP", struct.pack("<i", 1) + _dict({}) + struct.pack("<i", n)
                        + struct.pack(f"<{n}i", *child_ids)))
    for k, t in enumerate(placed):
        graph.append(_chunk(b"nTRN", struct.pack("<i", 2 + 2 * k) + _dict({})
                            + struct.pack("<iiii", 3 + 2 * k, -1, 0, 1)
                            + _dict({"_t": f"{int(t[0])} {int(t[1])} {int(t[2])}"})))
        graph.append(_chunk(b"nSHP", struct.pack("<i", 3 + 2 * k) + _dict({})
                            + struct.pack("<ii", 1, k) + _dict({})))
    rgba = np.zeros((256, 4), np.uint8)
    rgba[: len(palette), :3] = palette
    rgba[:, 3] = 255
    body = b"".join(models) + b"".join(graph) + _chunk(b"RGBA", rgba.tobytes())
    return b"VOX " + struct.pack("<i", 150) + _chunk(b"MAIN", b"", body)


def write_vox(volume, path, shell: bool = False) -> list:
    from .base import atomic_output

    path = os.fspath(path)
    if getattr(volume, "labels", None) is not None:
        table = volume.label_table or []
        if len(table) - 1 > 255:
            from ..errors import ParameterError

            raise ParameterError(f".vox holds at most 255 labels (one palette entry each), "
                                 f"not {len(table) - 1:,}")
        rgb = np.zeros((len(table) - 1, 3), np.uint8)
        for e in table[1:]:
            rgb[e["value"] - 1] = e["color"][:3]
        data = encode(volume.labels != 0, None, shell=shell, labels=volume.labels,
                      label_rgb=rgb)
    else:
        data = encode(volume.occupancy, volume.colors, shell=shell)
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
    return [path]


def decode(data: bytes):
    """Parse .vox bytes: ``(models, transforms, palette)``.

    ``models`` is a list of ``(size (3,), xyzi (n, 4) uint8)``; ``transforms``
    maps model index to its ``_t`` translation; ``palette`` is (256, 4) uint8.
    """
    if data[:4] != b"VOX ":
        raise ParameterError("not a MagicaVoxel file (no 'VOX ' magic)")
    pos = 8
    cid, nc, nch = data[pos:pos + 4], *struct.unpack_from("<ii", data, pos + 4)
    if cid != b"MAIN":
        raise ParameterError("not a MagicaVoxel file (no MAIN chunk)")
    pos += 12 + nc
    end = pos + nch
    models, palette, size = [], None, None
    trn, shp = {}, {}

    def read_dict(p):
        (count,) = struct.unpack_from("<i", data, p)
        p += 4
        out = {}
        for _ in range(count):
            (n,) = struct.unpack_from("<i", data, p)
            key = data[p + 4:p + 4 + n].decode()
            p += 4 + n
            (n,) = struct.unpack_from("<i", data, p)
            out[key] = data[p + 4:p + 4 + n].decode()
            p += 4 + n
        return out, p

    while pos < end:
        cid = data[pos:pos + 4]
        nc, nch = struct.unpack_from("<ii", data, pos + 4)
        body = pos + 12
        if cid == b"SIZE":
            size = np.array(struct.unpack_from("<iii", data, body))
        elif cid == b"XYZI":
            (n,) = struct.unpack_from("<i", data, body)
            xyzi = np.frombuffer(data, np.uint8, 4 * n, body + 4).reshape(n, 4)
            models.append((size, xyzi))
        elif cid == b"RGBA":
            palette = np.frombuffer(data, np.uint8, 1024, body).reshape(256, 4)
        elif cid == b"nTRN":
            (node,) = struct.unpack_from("<i", data, body)
            _, p = read_dict(body + 4)
            child, _, _, frames = struct.unpack_from("<iiii", data, p)
            frame, _ = read_dict(p + 16)
            trn[child] = frame.get("_t", "0 0 0")
        elif cid == b"nSHP":
            (node,) = struct.unpack_from("<i", data, body)
            _, p = read_dict(body + 4)
            (model,) = struct.unpack_from("<i", data, p + 4)
            shp[node] = model
        pos = body + nc + nch
    transforms = {model: np.array([int(v) for v in trn.get(node, "0 0 0").split()])
                  for node, model in shp.items()}
    if palette is None:
        # Files may leave the palette out; show their voxels in neutral grey.
        palette = np.tile(np.array([*DEFAULT_RGB, 255], np.uint8), (256, 1))
    return models, transforms, palette


def read_vox(path):
    """A Volume (unit voxels, origin at 0) assembled from a .vox file's models."""
    from ..grid import Grid
    from ..volume import Volume

    with open(path, "rb") as f:
        models, transforms, palette = decode(f.read())
    lows, pts = [], []
    for k, (size, xyzi) in enumerate(models):
        low = transforms.get(k, np.zeros(3, int)) - size // 2
        lows.append(low)
        pts.append((xyzi[:, :3].astype(np.int64) + low, xyzi[:, 3]))
    lo = np.min([lw for lw in lows], axis=0) if lows else np.zeros(3, int)
    hi = np.max([lw + s for lw, (s, _) in zip(lows, models)], axis=0) if lows else np.ones(3, int)
    shape = tuple(int(v) for v in hi - lo)
    occ = np.zeros(shape, bool, order="F")
    base = np.zeros(shape[::-1] + (4,), np.uint8)
    colors = base.transpose(2, 1, 0, 3)
    for p, ci in pts:
        q = p - lo
        occ[q[:, 0], q[:, 1], q[:, 2]] = True
        colors[q[:, 0], q[:, 1], q[:, 2]] = palette[ci.astype(np.int64) - 1]
    return Volume(occupancy=occ, grid=Grid(np.zeros(3), np.asarray(shape, float), shape),
                  backend="?", source=os.fspath(path), colors=colors)
