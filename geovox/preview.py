"""Headless PNG previews made with NumPy and Pillow alone.

Top row: the volume composited along x, y and z (front to back, each inside
voxel partly opaque, shaded by depth; colour where the volume has colour;
with a coverage density, the density is the opacity). Bottom row: the middle
slice across each axis (the signed distance, blue inside and red outside,
when the volume has one). A footer gives the grid size,
the voxel dimensions and the inside count. Panels keep the physical aspect
ratio of anisotropic voxels.
"""

from __future__ import annotations

import numpy as np

#: Opacity of one inside voxel in the composites.
ALPHA = 0.35
BACKGROUND = (24, 24, 28)
GREY = np.array([225.0, 225.0, 225.0])
PANEL = 300
#: A ``.zarr`` is previewed from its finest pyramid level with every side at
#: most this (the composites walk every slice: 512³ takes a few seconds).
LARGEST = 512

# view axis -> (horizontal axis, vertical axis, front is the high end of the view axis);
# horizontal < vertical always, so a slice indexed [h, v] needs one transpose.
VIEWS = {0: (1, 2, True), 1: (0, 2, False), 2: (0, 1, True)}
AXIS = "xyz"


def composite(volume, axis: int) -> np.ndarray:
    """Front-to-back composite along ``axis``.

    Returns
    -------
    (n_vertical, n_horizontal, 3) float64 in [0, 255], row 0 at the top
    (high end of the vertical axis), background where nothing is hit.
    """
    h, v, front_high = VIEWS[axis]
    occ = volume.occupancy
    n = occ.shape[axis]
    order = range(n - 1, -1, -1) if front_high else range(n)
    out = np.zeros((occ.shape[h], occ.shape[v], 3))
    trans = np.ones((occ.shape[h], occ.shape[v]))
    idx = [slice(None)] * 3
    density = getattr(volume, "density", None)
    for depth, k in enumerate(order):
        idx[axis] = k
        o = occ[tuple(idx)]
        if density is not None:
            o = density[tuple(idx)].astype(np.float64)
            o = o / 255.0 if density.dtype == np.uint8 else o
        if not o.any():
            continue
        shade = 0.55 + 0.45 * (1.0 - depth / max(1, n - 1))
        if volume.colors is not None:
            c = volume.colors[tuple(idx)][..., :3].astype(np.float64)
        else:
            c = GREY
        a = ALPHA * o
        out += (trans * a)[..., None] * c * shade
        trans *= 1.0 - a
    out += trans[..., None] * np.asarray(BACKGROUND, dtype=np.float64)
    return np.flipud(out.transpose(1, 0, 2))


def middle_slice(volume, axis: int) -> np.ndarray:
    """The slice across ``axis`` through the middle; same orientation as :func:`composite`."""
    h, v, _ = VIEWS[axis]
    idx = [slice(None)] * 3
    idx[axis] = volume.occupancy.shape[axis] // 2
    o = volume.occupancy[tuple(idx)]
    sdf = getattr(volume, "sdf", None)
    if sdf is not None:
        s = sdf[tuple(idx)].astype(np.float64)
        t = np.clip(np.abs(s) / max(float(np.abs(sdf).max()), 1e-30), 0.0, 1.0)[..., None]
        inside_col, outside_col, zero = np.array([40, 90, 255.0]), np.array([255, 80, 40.0]), 255.0
        c = np.where((s < 0)[..., None], zero * (1 - t) + inside_col * t, zero * (1 - t) + outside_col * t)
        return np.flipud(c.transpose(1, 0, 2))
    if volume.colors is not None:
        c = volume.colors[tuple(idx)][..., :3].astype(np.float64)
    else:
        c = np.where(o[..., None], 255.0, 0.0) * np.ones(3)
    c = np.where(o[..., None], c, np.asarray(BACKGROUND, dtype=np.float64))
    return np.flipud(c.transpose(1, 0, 2))


def _fit(img: np.ndarray, width_len: float, height_len: float, box: int):
    """Nearest-neighbour resize to the physical aspect ratio, fitting ``box``."""
    from PIL import Image

    scale = box / max(width_len, height_len)
    w = max(1, int(round(width_len * scale)))
    h = max(1, int(round(height_len * scale)))
    pil = Image.fromarray(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return pil.resize((w, h), Image.NEAREST)


def _panel(canvas, draw, font, img, corner, panel: int, title: int, caption: str) -> None:
    """One picture of a preview: its caption at ``corner``, the image centred in the square below."""
    x0, y0 = corner
    draw.text((x0, y0), caption, fill=(230, 230, 230), font=font)
    canvas.paste(img, (x0 + (panel - img.width) // 2, y0 + title + (panel - img.height) // 2))


def render(volume, panel: int = PANEL):
    """The preview as a ``PIL.Image``."""
    from PIL import Image, ImageDraw, ImageFont

    try:
        font = ImageFont.load_default(size=14)
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    table = getattr(volume, "label_table", None)
    if getattr(volume, "labels", None) is not None and table:
        import dataclasses

        from .labels import label_colours

        # Labels are drawn in the table's colours (over any --color), with a legend.
        volume = dataclasses.replace(volume, colors=label_colours(volume.labels, table),
                                     density=None)
    extent = np.asarray(volume.bounds[1]) - np.asarray(volume.bounds[0])
    pad, title, footer = 10, 20, 44
    legend_table = table if getattr(volume, "labels", None) is not None else None
    legend = _legend_rows(legend_table) if legend_table else []
    footer += 20 * len(legend)
    width = 3 * panel + 4 * pad
    height = 2 * (panel + title) + 3 * pad + footer
    canvas = Image.new("RGB", (width, height), (12, 12, 14))
    draw = ImageDraw.Draw(canvas)
    slice_label = "signed distance across" if getattr(volume, "sdf", None) is not None else "middle slice across"
    comp_label = "density along" if getattr(volume, "density", None) is not None else "composite along"
    for row, (make, label) in enumerate(((composite, comp_label), (middle_slice, slice_label))):
        for col, axis in enumerate((0, 1, 2)):
            h, v, _ = VIEWS[axis]
            img = _fit(make(volume, axis), extent[h], extent[v], panel)
            x0 = pad + col * (panel + pad)
            y0 = pad + row * (panel + title + pad)
            _panel(canvas, draw, font, img, (x0, y0), panel, title,
                   f"{label} {AXIS[axis]}  ({AXIS[h]} right, {AXIS[v]} up)")
    nx, ny, nz = volume.shape
    dx, dy, dz = volume.spacing
    inside = int(np.count_nonzero(volume.occupancy))
    total = nx * ny * nz
    text = (f"grid {nx} x {ny} x {nz}   voxel {dx:.4g} x {dy:.4g} x {dz:.4g}   "
            f"{getattr(volume, 'occupied_word', 'inside')} {inside:,} "
            f"({100.0 * inside / total:.1f}%)"
            + (f"   {len(legend_table) - 1:,} labels" if legend_table
               else "   colour" if volume.colors is not None else ""))
    draw.text((pad, height - footer + 6), text, fill=(255, 255, 255), font=font)
    draw.text((pad, height - footer + 24), f"{volume.source}", fill=(160, 160, 160), font=font)
    for r, row in enumerate(legend):
        x, y = pad, height - footer + 44 + 20 * r
        for value, name, color in row:
            draw.rectangle((x, y + 2, x + 12, y + 14), fill=tuple(int(c) for c in color[:3]))
            draw.text((x + 18, y), f"{value} {name}", fill=(230, 230, 230), font=font)
            x += 18 + int(draw.textlength(f"{value} {name}", font=font)) + 16
    return canvas


def _legend_rows(table, per_row: int = 6, most: int = 30) -> list:
    """The label legend, ``per_row`` entries a row: ``[(value, name, color)]`` rows."""
    entries = [(e["value"], str(e["name"])[:24], e["color"]) for e in (table or [])[1:most + 1]]
    if table and len(table) - 1 > most:
        entries.append(("", f"... {len(table) - 1 - most:,} more", (12, 12, 14)))
    return [entries[i:i + per_row] for i in range(0, len(entries), per_row)]


def write_preview(volume, path, panel: int = PANEL) -> str:
    """Render and write the preview PNG atomically."""
    import os

    from .formats import atomic_output, check_writable

    path = os.fspath(path)
    check_writable(path)
    with atomic_output(path) as tmp:
        render(volume, panel).save(tmp, format="PNG")
    return path


# --- preview --like: the mask over the reference image -------------------

#: Colour and opacity of the mask drawn over the reference image.
MASK_RGB = np.array([255.0, 60.0, 40.0])
MASK_ALPHA = 0.45


def _window(image: np.ndarray) -> tuple:
    """(low, high): the 1st and 99th percentiles of the image, the grey ramp's ends."""
    finite = np.asarray(image, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    if finite.size == 0:
        return 0.0, 1.0
    lo, hi = np.percentile(finite, [1, 99])
    return float(lo), float(hi if hi > lo else lo + 1.0)


def overlay_slice(volume, image: np.ndarray, axis: int, window: tuple) -> np.ndarray:
    """The middle slice across index ``axis``: the image in grey, the mask in red over it.

    Parameters
    ----------
    volume : Volume
        On the image's grid (same shape).
    image : (nx, ny, nz) array
        The reference image's voxels.

    Returns
    -------
    (n_vertical, n_horizontal, 3) float64 in [0, 255], oriented as :func:`composite`;
    the mask's edge is drawn opaque so the boundary shows over bright tissue.
    """
    h, v, _ = VIEWS[axis]
    idx = [slice(None)] * 3
    idx[axis] = volume.occupancy.shape[axis] // 2
    lo, hi = window
    g = np.clip((np.asarray(image[tuple(idx)], dtype=np.float64) - lo) / (hi - lo), 0.0, 1.0)
    grey = (255.0 * g)[..., None] * np.ones(3)
    o = volume.occupancy[tuple(idx)]
    edge = o & ~(np.roll(o, 1, 0) & np.roll(o, -1, 0) & np.roll(o, 1, 1) & np.roll(o, -1, 1))
    out = np.where(o[..., None], (1 - MASK_ALPHA) * grey + MASK_ALPHA * MASK_RGB, grey)
    out = np.where(edge[..., None], MASK_RGB, out)
    return np.flipud(out.transpose(1, 0, 2))


def render_like(volume, image: np.ndarray, reference, note: str = "", panel: int = PANEL):
    """``preview --like``: the mask over the reference image's three middle slices (a PIL image).

    Slices are across the image's own index axes (i, j, k), drawn with the
    voxels' physical aspect ratio (``spacing``).
    """
    from PIL import Image, ImageDraw, ImageFont

    try:
        font = ImageFont.load_default(size=14)
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    extent = np.asarray(volume.shape, dtype=np.float64) * np.asarray(reference.spacing)
    pad, title, footer = 10, 20, 44
    width = 3 * panel + 4 * pad
    height = panel + title + 2 * pad + footer
    canvas = Image.new("RGB", (width, height), (12, 12, 14))
    draw = ImageDraw.Draw(canvas)
    window = _window(image)
    for col, axis in enumerate((0, 1, 2)):
        h, v, _ = VIEWS[axis]
        img = _fit(overlay_slice(volume, image, axis, window), extent[h], extent[v], panel)
        x0 = pad + col * (panel + pad)
        _panel(canvas, draw, font, img, (x0, pad), panel, title,
               f"middle slice across {'ijk'[axis]}  ({'ijk'[h]} right, {'ijk'[v]} up)")
    nx, ny, nz = volume.shape
    dx, dy, dz = reference.spacing
    inside = int(np.count_nonzero(volume.occupancy))
    draw.text((pad, height - footer + 6),
              f"mask (red) over {reference.source.split('/')[-1]}: grid {nx} x {ny} x {nz}, voxel "
              f"{dx:.4g} x {dy:.4g} x {dz:.4g}, inside {inside:,}", fill=(255, 255, 255), font=font)
    draw.text((pad, height - footer + 24), f"{volume.source}" + (f"; {note}" if note else ""),
              fill=(160, 160, 160), font=font)
    return canvas


def write_preview_like(volume, image, reference, path, note: str = "", panel: int = PANEL) -> str:
    """Render :func:`render_like` and write the PNG atomically."""
    import os

    from .errors import ParameterError
    from .formats import atomic_output, check_writable

    if image is None:
        raise ParameterError(f"--like {reference.source}: its voxels cannot be read for the "
                             f"preview (only the grid)")
    if tuple(image.shape[:3]) != tuple(volume.shape):
        raise ParameterError(f"the volume's grid {tuple(volume.shape)} is not the reference's "
                             f"{tuple(image.shape[:3])}")
    path = os.fspath(path)
    check_writable(path)
    with atomic_output(path) as tmp:
        render_like(volume, image, reference, note, panel).save(tmp, format="PNG")
    return path
