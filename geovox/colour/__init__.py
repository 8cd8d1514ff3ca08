"""Colour: every voxel takes the colour of its nearest surface point.

| module | holds |
|---|---|
| :mod:`geovox.colour.shading` | the colour of a surface point: materials, textures, vertex colours |
| :mod:`geovox.colour.exact` | exact colour: each voxel's exact nearest surface point (the default) |
| :mod:`geovox.colour.fast` | fast colour: the nearest of the six axis crossings around each voxel |

:func:`colour_volume` is the stage: the block function calls it once per block. Exact
colour asks the nearest-point stage (:mod:`geovox.nearest`) for its inside voxels.
"""

from __future__ import annotations

from ..errors import warn
from .exact import exact_colours
from .fast import fast_colours, relevant_crossings
from .shading import Shading, load_textures, prefetch_textures, shade

__all__ = ["Shading", "colour_volume", "exact_colours", "fast_colours", "load_textures",
           "prefetch_textures", "relevant_crossings", "shade"]


def colour_volume(mesh, grid, occupancy, cast=None, *, shading: Shading = Shading(), jobs=1,
                  exact=False, frame=None, out=None, sink=None):
    """RGBA colours of the inside voxels; alpha 0 outside.

    Parameters
    ----------
    mesh : Mesh
    grid : Grid
    occupancy : (nx, ny, nz) bool
    cast : dict axis -> (Hits, Columns)
        Crossings along each axis (see :func:`geovox.colour.fast.fast_colours`);
        not needed with ``exact``.
    shading : Shading
        The options ``diffuse`` and ``ambient`` (:meth:`Shading.of`).
    exact : bool
        Colour every voxel from its exact nearest surface point
        (:func:`~geovox.colour.exact.exact_colours`) instead of the nearest of
        its six axis crossings (:func:`~geovox.colour.fast.fast_colours`).
    frame : (lo, spacing, z0), optional
        With ``exact``: see :func:`~geovox.colour.exact.exact_colours`.
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
    return fast_colours(mesh, grid, occupancy, cast, shading=shading, jobs=jobs, out=out,
                        sink=sink)
