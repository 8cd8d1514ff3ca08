"""Interactive 3D view of a volume (and its source mesh), through PyVista, or in a browser.

PyVista (and VTK) is an optional extra: ``pip install -e '.[view]'``. With a
screenshot path the view renders off-screen, which works without a display.
:func:`to_html` (from :mod:`geovox.view.html`) needs neither: it writes one
self-contained page that shows the volume in any browser with WebGL2.
"""

from __future__ import annotations

import os

import numpy as np

from ..errors import GeovoxError, OutputError

#: Above this many inside voxels only the visible shell is drawn.
SHELL_ABOVE = 200_000
#: A ``.zarr`` is shown from its finest pyramid level with every side at most
#: this (each voxel is a hexahedron; 256³ is what a desktop GPU turns smoothly).
LARGEST = 256


__all__ = ["LARGEST", "SHELL_ABOVE", "ViewerUnavailableError", "render_page", "show", "to_html",
           "voxel_cells"]


def __getattr__(name):
    # geovox.view.to_html without importing the page writer with the PyVista viewer.
    if name in ("to_html", "render_page"):
        from . import html

        return getattr(html, name)
    raise AttributeError(f"module 'geovox.view' has no attribute {name!r}")


class ViewerUnavailableError(GeovoxError, ImportError):
    """PyVista is not installed."""


def _pyvista():
    try:
        import pyvista
    except ImportError as exc:
        raise ViewerUnavailableError(
            "the 3D viewer needs PyVista: pip install -e '.[view]' (or pip install pyvista)"
        ) from exc
    return pyvista


def voxel_cells(volume):
    """The inside voxels as a PyVista UnstructuredGrid of hexahedra (shell only when large)."""
    pv = _pyvista()
    from ..formats.vox import shell_mask

    occ = volume.occupancy
    keep = shell_mask(occ) if np.count_nonzero(occ) > SHELL_ABOVE else occ
    grid = pv.ImageData(dimensions=np.asarray(volume.shape) + 1, spacing=volume.spacing,
                        origin=volume.bounds[0])
    # VTK orders cells x fastest: the Fortran order of the [x, y, z] arrays.
    grid.cell_data["inside"] = keep.reshape(-1, order="F").view(np.uint8)
    if volume.colors is not None:
        grid.cell_data["rgba"] = volume.colors.transpose(2, 1, 0, 3).reshape(-1, 4)
    return grid.threshold(0.5, scalars="inside")


#: The legend lists at most this many labels (then one "... N more" line).
LEGEND_MOST = 20


def _labelled(volume):
    """``(volume, legend)``: a labelled volume in its table's colours, and its legend.

    As in the preview, labels are drawn over any ``colors`` and in place of
    density and distance; ``legend`` is ``[[name, (r, g, b)]]`` (0-1 floats), one
    entry per label value of the table (at most :data:`LEGEND_MOST`), empty for a
    volume without labels.
    """
    table = getattr(volume, "label_table", None)
    if getattr(volume, "labels", None) is None or not table:
        return volume, []
    import dataclasses

    from ..labels import label_colours

    volume = dataclasses.replace(volume, colors=label_colours(volume.labels, table),
                                 density=None, sdf=None)
    entries = [e for e in table if int(e["value"]) > 0]
    legend = [[f"{int(e['value'])} {e['name']}"[:32], tuple(int(c) / 255 for c in e["color"][:3])]
              for e in entries[:LEGEND_MOST]]
    if len(entries) > LEGEND_MOST:
        legend.append([f"... {len(entries) - LEGEND_MOST:,} more", (0.5, 0.5, 0.5)])
    return volume, legend


def show(volume, mesh=None, screenshot=None, window_size=(1200, 600)):
    """Show the volume, and the mesh beside it when given.

    A volume with ``labels`` and a ``label_table`` is drawn in the table's
    colours, with a legend of the labels' values, names and colours.

    Parameters
    ----------
    volume : Volume
    mesh : geovox.mesh.Mesh, optional
    screenshot : str, optional
        Render off-screen into this PNG instead of opening a window.
    """
    pv = _pyvista()
    volume, legend = _labelled(volume)
    if screenshot is None and os.name == "posix" and not os.environ.get("DISPLAY") \
            and not os.environ.get("WAYLAND_DISPLAY") and os.uname().sysname == "Linux":
        raise OutputError("no display to open a window on: use --screenshot PNG to render off-screen")
    cells = voxel_cells(volume)
    shape = (1, 2) if mesh is not None else (1, 1)
    size = window_size if mesh is not None else (window_size[1], window_size[1])
    plotter = pv.Plotter(shape=shape, off_screen=screenshot is not None, window_size=size)
    plotter.subplot(0, 0)
    plotter.add_text(f"voxels {volume.shape[0]} x {volume.shape[1]} x {volume.shape[2]}", font_size=10)
    density = getattr(volume, "density", None)
    sdf = getattr(volume, "sdf", None)
    if density is not None or sdf is not None:
        # Point data at the voxel centres.
        img = pv.ImageData(dimensions=volume.shape, spacing=volume.spacing,
                           origin=np.asarray(volume.bounds[0]) + 0.5 * np.asarray(volume.spacing))
        if density is not None:
            d = density.astype(np.float32) / (255.0 if density.dtype == np.uint8 else 1.0)
            img.point_data["density"] = d.reshape(-1, order="F")
            plotter.add_volume(img, scalars="density", opacity="linear", cmap="bone",
                               show_scalar_bar=False)
        if sdf is not None:
            img.point_data["sdf"] = sdf.reshape(-1, order="F")
            surface = img.contour([0.0], scalars="sdf")
            if surface.n_points:
                plotter.add_mesh(surface, color="lightgrey", smooth_shading=True)
    elif cells.n_cells:
        if volume.colors is not None:
            plotter.add_mesh(cells, scalars="rgba", rgb=True, show_edges=False)
        else:
            plotter.add_mesh(cells, color="lightgrey", show_edges=False)
    if legend:
        plotter.add_legend(legend, bcolor=(0.1, 0.1, 0.12), face="rectangle",
                           size=(0.3, min(0.05 * len(legend), 0.6)), loc="lower right")
    if mesh is not None:
        plotter.subplot(0, 1)
        plotter.add_text("mesh", font_size=10)
        faces = np.hstack([np.full((len(mesh.faces), 1), 3), mesh.faces]).reshape(-1)
        plotter.add_mesh(pv.PolyData(mesh.vertices, faces), color="tan")
        plotter.link_views()
    plotter.view_isometric()
    if screenshot is not None:
        from ..formats import atomic_outputs, check_writable

        check_writable(screenshot)
        png = None
        try:
            with atomic_outputs() as group:
                tmp = group.add(screenshot)
                png = tmp + ".png"  # VTK picks the image format from the extension
                plotter.screenshot(png)
                os.replace(png, tmp)
        finally:
            plotter.close()
            if png is not None and os.path.exists(png):
                os.unlink(png)
        return screenshot
    plotter.show()
    return None
