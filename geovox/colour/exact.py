"""Exact colour: every inside voxel from its exact nearest surface point (``color=True``).

The nearest surface point is exact by default (``color=True`` or
``"exact"``, here): the triangle at the smallest Euclidean
distance from the voxel centre (ties within 1e-9 voxel sizes go to the
smallest triangle index) and the closest point on it, for every inside
voxel. The compiled kernel (``geovox/_nearest.pyx``, built by ``pip
install``) finds it and shades it; without it, :func:`geovox.nearest.search.nearest_inside`'s
NumPy search and :func:`shade` give the same colours, slower (a branch and
bound over voxel cells that drops a triangle only where a valid bound proves
it farther). Both search less where every triangle still in the running for
a block of voxels has the same constant colour: that colour is used without
finding which of them is nearest. It needs no rays.
"""

from __future__ import annotations

import numpy as np

from ..errors import ParameterError
from ..kernels import chosen
from ..nearest.search import kernel_module, nearest_inside, run_kernel
from .shading import Shading, constant_colours, pack, shade, shading_tables

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
    :func:`geovox.nearest.search.kernel_module`).

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
                   output=lambda k: kernel_output(k, flat, tables, key, key_rgba),
                   cache=getattr(mesh, "_cache", None))
        return colors

    def emit(vox, tri, uv):
        k = key[tri]
        rgba = np.zeros(len(tri), np.uint32)
        const = k >= 0
        rgba[const] = key_rgba[k[const]]
        vary = np.flatnonzero(~const)
        if len(vary):
            rgba[vary] = pack(shade(mesh, tri[vary], uv[vary], shading))
        flat[vox[:, 0] + nx * (vox[:, 1] + ny * vox[:, 2])] = rgba

    with chosen("numpy"):  # shade() colours what the tables cannot
        nearest_inside(mesh.triangles, occupancy, spacing, origin=lo, z0=z0, jobs=jobs,
                       emit=emit, same=key)
    return colors


def kernel_output(search, flat, tables, key, key_rgba) -> None:
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
