"""A volume as one self-contained HTML page: a WebGL2 ray-marching viewer.

The page needs no network and no install: the viewer's JavaScript, GLSL and
CSS (``geovox/view/static/``) are inlined when the page is written, and the
volume is embedded in ``<script type="application/octet-stream">`` blocks,
each the base64 of one zlib (RFC 1950 "deflate") stream, which the browser
inflates with ``DecompressionStream("deflate")``.

The embedded data (what :func:`page_fields` returns, and what a test can
decode back without a browser):

=============  =========================================  ======================
block id       bytes after inflating                      array
=============  =========================================  ======================
``occupancy``  ``np.packbits(occ, bitorder="little")``    (mx, my, mz) bool
``colors``     RGBA, 4 bytes a voxel                      (mx, my, mz, 4) uint8
``labels``     uint8 or little-endian uint16              (mx, my, mz)
``density``    uint8, or little-endian float32            (mx, my, mz)
``sdf``        little-endian float32                      (mx, my, mz)
=============  =========================================  ======================

Every array is laid out x fastest, then y, then z (``arr.ravel(order="F")``).
The ``geovox-meta`` JSON block says which blocks there are, the grid shown and
the grid converted, and the downsampling factor.

A volume with a side above ``max_side`` (256 by default: 16 M voxels, what a
browser holds comfortably in GPU textures) is shown downsampled by the
smallest integer factor ``f`` that brings every side within it: occupancy by
the maximum over each ``f³`` block (a voxel is inside when any voxel of its
block is, so thin parts stay), colour by the alpha-weighted mean, labels,
distance and density by the nearest voxel (the block's centre voxel,
``f // 2`` from its low corner, clipped to the grid).
"""

from __future__ import annotations

import base64
import html
import json
import math
import os
import re
import zlib
from importlib import resources

import numpy as np

from ..errors import ParameterError

#: Sides above this are downsampled (see the module docstring).
MAX_SIDE = 256
#: What the page says for each rule, keyed by field.
RULES = {"occupancy": "max", "colors": "alpha-weighted mean", "labels": "nearest",
         "density": "nearest", "sdf": "nearest"}
_STATIC = ("viewer.css", "viewer.js", "raymarch.vert", "raymarch.frag", "viewer.html")


def _static(name: str) -> str:
    return resources.files(__package__).joinpath("static", name).read_text(encoding="utf-8")


def factor_for(shape, max_side: int = MAX_SIDE) -> int:
    """The smallest integer ``f`` with every ``ceil(n / f) <= max_side``."""
    return max(1, max(math.ceil(int(n) / max_side) for n in shape))


def _nearest(arr: np.ndarray, f: int) -> np.ndarray:
    """Every ``f``-th voxel from the ``f // 2``-th (clipped to the grid), along x, y, z."""
    idx = [np.minimum(np.arange(math.ceil(n / f)) * f + f // 2, n - 1) for n in arr.shape[:3]]
    return np.asfortranarray(arr[np.ix_(*idx)])


def _blocks(arr: np.ndarray, f: int, fill) -> np.ndarray:
    """``arr`` padded with ``fill`` to whole blocks, viewed as (mx, f, my, f, mz, f, ...)."""
    m = [math.ceil(n / f) for n in arr.shape[:3]]
    pad = [(0, mi * f - n) for mi, n in zip(m, arr.shape[:3])] + [(0, 0)] * (arr.ndim - 3)
    padded = np.pad(arr, pad, constant_values=fill)
    return padded.reshape(m[0], f, m[1], f, m[2], f, *arr.shape[3:])


def downsample(name: str, arr: np.ndarray, f: int) -> np.ndarray:
    """One field of a volume reduced by the integer factor ``f`` with its rule (``RULES``).

    Parameters
    ----------
    name : {"occupancy", "colors", "labels", "density", "sdf"}
    arr : (nx, ny, nz) or (nx, ny, nz, 4) array
    f : int

    Returns
    -------
    (ceil(nx / f), ceil(ny / f), ceil(nz / f)[, 4]) array of ``arr``'s dtype, Fortran order.
    """
    if f == 1:
        return arr
    if name == "occupancy":
        return np.asfortranarray(_blocks(arr, f, False).any(axis=(1, 3, 5)))
    if name == "colors":
        b = _blocks(arr, f, 0).astype(np.float64)
        w = b[..., 3:4]
        wsum = w.sum(axis=(1, 3, 5))
        rgb = (b[..., :3] * w).sum(axis=(1, 3, 5)) / np.maximum(wsum, 1)
        # Alpha: the mean over the voxels of the block that lie in the grid.
        count = _blocks(np.ones(arr.shape[:3], np.float64), f, 0).sum(axis=(1, 3, 5))
        alpha = wsum[..., 0] / count
        out = np.concatenate([rgb, alpha[..., None]], axis=-1)
        return np.asfortranarray(np.clip(np.rint(out), 0, 255).astype(np.uint8))
    return _nearest(arr, f)


def _labels(volume):
    """``(labels, table)`` of a volume that carries them, else ``(None, None)``; validated."""
    labels = getattr(volume, "labels", None)
    if labels is None:
        return None, None
    labels = np.asarray(labels)
    if labels.shape != tuple(volume.shape) or labels.dtype not in (np.uint8, np.uint16):
        raise ParameterError(f"`labels` must be a {tuple(volume.shape)} uint8 or uint16 array, "
                             f"got {labels.shape} {labels.dtype}")
    table = []
    for i, entry in enumerate(getattr(volume, "label_table", None) or []):
        try:
            value, color = int(entry["value"]), [int(c) for c in entry["color"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise ParameterError(f"`label_table[{i}]` needs `value` and `color` (RGBA 0-255), "
                                 f"got {entry!r}") from exc
        if len(color) == 3:
            color.append(255)
        if value == 0:
            continue  # the background entry geovox's own tables start with: never drawn
        if len(color) != 4 or not all(0 <= c <= 255 for c in color) or value < 0:
            raise ParameterError(f"`label_table[{i}]` needs a value >= 0 and an RGBA colour of "
                                 f"0-255 integers, got {entry!r}")
        table.append({"value": value, "name": str(entry.get("name", f"label {value}")),
                      "color": color})
    return labels, table


def page_fields(volume, max_side: int = MAX_SIDE) -> tuple:
    """The arrays a page of ``volume`` embeds, and the downsampling factor.

    Returns
    -------
    fields : dict
        ``name -> array`` over the shown grid, for each of ``occupancy``,
        ``colors``, ``labels``, ``density``, ``sdf`` the volume has.
    f : int
        1 when the volume is shown whole.
    """
    if not (isinstance(max_side, (int, np.integer)) and max_side >= 1):
        raise ParameterError(f"`max_side` must be a positive integer, got {max_side!r}")
    f = factor_for(volume.shape, int(max_side))
    labels, _ = _labels(volume)
    fields = {"occupancy": np.asarray(volume.occupancy, dtype=bool)}
    for name, arr in (("colors", volume.colors), ("labels", labels),
                      ("density", getattr(volume, "density", None)),
                      ("sdf", getattr(volume, "sdf", None))):
        if arr is not None:
            fields[name] = np.asarray(arr)
    return {name: downsample(name, arr, f) for name, arr in fields.items()}, f


def _deflate(raw: bytes) -> bytes:
    """A zlib stream of ``raw``: ISA-L's level 1 where installed (spot 256³'s colour in 0.12 s
    instead of zlib's 2.1 s at level 6, 1.31 MB instead of 1.15), else zlib's level 6."""
    try:
        from isal import isal_zlib
    except ImportError:  # pragma: no cover - isal has wheels for the common platforms
        return zlib.compress(raw, 6)
    return isal_zlib.compress(raw, 1)


def _encode(name: str, arr: np.ndarray) -> tuple:
    """``(dtype name, base64 text)`` of one field, as the module docstring lays it out."""
    if name == "occupancy":
        raw, dtype = np.packbits(arr.ravel(order="F"), bitorder="little").tobytes(), "bits"
    else:
        dtype = arr.dtype.newbyteorder("<") if arr.dtype.itemsize > 1 else arr.dtype
        flat = arr.reshape(-1, 4, order="F") if name == "colors" else arr.ravel(order="F")
        raw, dtype = flat.astype(dtype, copy=False).tobytes(), np.dtype(dtype).name
    return dtype, base64.b64encode(_deflate(raw)).decode("ascii")


def _script_json(obj) -> str:
    """JSON safe inside a ``<script>`` element (no ``</script>``, no ``<!--``)."""
    text = json.dumps(obj, ensure_ascii=True, separators=(",", ":"))
    return text.replace("<", "\\u003c").replace(">", "\\u003e").replace("&", "\\u0026")


def _meta(volume, fields, f, source, labels_table) -> dict:
    shape = tuple(int(n) for n in volume.shape)
    shown = tuple(int(n) for n in fields["occupancy"].shape)
    lo = [float(x) for x in volume.bounds[0]]
    spacing = [float(s) for s in volume.spacing]
    meta = {
        "format": "geovox-view-1",
        "source": os.path.basename(str(source)) if source else "",
        "source_path": str(source or ""),
        "shape": list(shown),
        "original_shape": list(shape),
        "factor": f,
        "rules": {k: RULES[k] for k in fields} if f > 1 else {},
        "bounds": [lo, [float(x) for x in volume.bounds[1]]],
        "spacing": spacing,
        "shown_spacing": [s * f for s in spacing],
        "inside_count": int(np.count_nonzero(volume.occupancy)),
        "shown_inside_count": int(np.count_nonzero(fields["occupancy"])),
        "fields": {},
        "label_table": labels_table or [],
    }
    return meta


def render_page(volume, *, max_side: int = MAX_SIDE, title: str | None = None,
                source: str | None = None) -> str:
    """The HTML text of the page :func:`to_html` writes (see it for the parameters)."""
    fields, f = page_fields(volume, max_side)
    _, table = _labels(volume)
    source = source or getattr(volume, "source", "") or ""
    meta = _meta(volume, fields, f, source, table)
    blocks = []
    for name, arr in fields.items():
        dtype, text = _encode(name, arr)
        meta["fields"][name] = {"dtype": dtype, "encoding": "deflate-base64",
                                "order": "x fastest, then y, then z"}
        blocks.append(f'<script type="application/octet-stream" id="geovox-field-{name}">'
                      f"{text}</script>")
    if "sdf" in fields:
        sdf = fields["sdf"]
        meta["fields"]["sdf"]["range"] = [float(np.min(sdf)), float(np.max(sdf))]
    if "density" in fields:
        meta["fields"]["density"]["max"] = float(np.max(fields["density"]))
    name = title or (meta["source"] or "volume")
    js = _static("viewer.js")
    shaders = "".join(
        f'<script type="x-shader/x-{kind}" id="geovox-{kind}">\n{_static(fname)}</script>\n'
        for kind, fname in (("vertex", "raymarch.vert"), ("fragment", "raymarch.frag")))
    parts = {"@@TITLE@@": html.escape(f"{name} - geovox"),
             "/*@@CSS@@*/": _static("viewer.css"),
             "<!--@@SHADERS@@-->": shaders,
             "/*@@JS@@*/": js,
             "@@META@@": _script_json(meta),
             "<!--@@DATA@@-->": "\n".join(blocks)}
    # One pass over the template: a marker inside what is put in (a title, say) stays text.
    pattern = "|".join(re.escape(m) for m in parts)
    return re.sub(pattern, lambda m: parts[m.group(0)], _static("viewer.html"))


def to_html(volume, path, *, max_side: int = MAX_SIDE, title: str | None = None,
            source: str | None = None) -> str:
    """Write ``volume`` as one self-contained HTML page that shows it in 3D.

    The page opens from ``file://`` in any browser with WebGL2: a lit
    iso-surface in the voxels' colours (labels in their table colours, with a
    legend and toggles; density as fog; distance with an iso-level slider),
    orbit/zoom/pan camera, a clipping box that prints itself as ``--bounds``,
    three slices, and the grid's facts with a scale bar.

    Parameters
    ----------
    volume : Volume
        Also shown when present: ``colors`` (nx, ny, nz, 4) uint8, ``density``
        (nx, ny, nz) uint8 or float32, ``sdf`` (nx, ny, nz) float32, and
        ``labels`` (nx, ny, nz) uint8 or uint16 (0 = background) with
        ``label_table``, a list of ``{"value": int, "name": str, "color":
        [r, g, b, a]}`` (0-255); values missing from the table get a colour of
        their own.
    path : str or os.PathLike
        The page to write (replaced only by a complete page).
    max_side : int
        Sides above this are downsampled (see the module docstring).
    title : str, optional
        The page's title (default: the source file's name).
    source : str, optional
        The source file named in the page (default: ``volume.source``).

    Returns
    -------
    str
        ``path``.
    """
    from ..formats import atomic_output, check_writable

    path = os.fspath(path)
    check_writable(path)
    page = render_page(volume, max_side=max_side, title=title, source=source)
    with atomic_output(path) as tmp, open(tmp, "w", encoding="utf-8") as fh:
        fh.write(page)
    return path
