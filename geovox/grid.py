"""The voxel grid and its column rays.

Voxel ``(i, j, k)`` covers ``lo + (i, j, k) * spacing`` to
``lo + (i + 1, j + 1, k + 1) * spacing``; its centre is what gets classified.
Arrays over the grid are indexed ``[x, y, z]``.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

import numpy as np

from .errors import ParameterError

#: Resolution used when the caller gives none of resolution, shape, voxel_size.
DEFAULT_RESOLUTION = 128

#: How ``resolution`` lays its N³ voxels over the region (``fit=``, ``--cube``):
#: ``"box"``: N per axis over the box, so voxels are as unequal as its sides;
#: ``"cube"``: binvox's ``-d N``, an N³ cube of cubic voxels whose edge is the
#: box's longest side, at the box's minimum corner; ``"cube-center"``: the same
#: cube centred on the box, as binvox's ``-cb``.
FITS = ("box", "cube", "cube-center")


@dataclass(frozen=True)
class Grid:
    """A regular grid over an axis-aligned region.

    Attributes
    ----------
    lo, hi : (3,) float64
        Corners of the region covered by the grid.
    shape : (3,) tuple of int
        Number of voxels along x, y, z.
    reference : geovox.reference.Reference or None
        The user's grid this one stands for (``like=``): the region is then
        its local frame (see :mod:`geovox.reference`) and writers place the
        voxels with the reference's affine.
    """

    lo: np.ndarray
    hi: np.ndarray
    shape: tuple
    reference: object = field(default=None, compare=False)

    @property
    def spacing(self) -> np.ndarray:
        """(3,) float64: the voxel dimensions ``(dx, dy, dz)``."""
        return (self.hi - self.lo) / np.asarray(self.shape, dtype=np.float64)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape, dtype=np.int64))

    def centres(self, axis: int) -> np.ndarray:
        """(n,) float64: voxel-centre coordinates along ``axis``.

        Every stage that compares a position with a voxel centre uses these
        values, so decisions at exact ties are made once, the same way.
        """
        n = self.shape[axis]
        return self.lo[axis] + (np.arange(n) + 0.5) * self.spacing[axis]

    def columns(self, axis: int = 2, start: float | None = None) -> "Columns":
        """The column rays of this grid travelling along ``+axis``.

        Parameters
        ----------
        axis : int
            Ray direction (0, 1 or 2).
        start : float, optional
            Coordinate along ``axis`` where the rays begin; it must lie outside
            the whole mesh (not merely outside the grid) so that a grid that
            cuts through the mesh is still classified correctly. Default: the
            grid's low face.

        Returns
        -------
        Columns
            ``shape[u] * shape[v]`` rays, one per voxel column.
        """
        u, v = (a for a in range(3) if a != axis)
        return Columns(
            axis=axis,
            u_axis=u,
            v_axis=v,
            u0=float(self.lo[u]),
            v0=float(self.lo[v]),
            du=float(self.spacing[u]),
            dv=float(self.spacing[v]),
            nu=int(self.shape[u]),
            nv=int(self.shape[v]),
            start=float(self.lo[axis] if start is None else start),
            w0=float(self.lo[axis]),
        )


@dataclass(frozen=True)
class Columns:
    """A regular lattice of axis-parallel rays, one per voxel column.

    Ray ``r = i + nu * j`` passes through ``(u, v) = (u0 + (i + 0.5) * du,
    v0 + (j + 0.5) * dv)`` and travels along ``+axis`` from ``start``.
    ``u_axis < v_axis`` are the two axes other than ``axis``. Depths of
    crossings are measured along the ray from the plane ``axis = w0`` (the
    grid's low face), so that they, like the lattice, move with the grid:
    translating mesh and grid together by whole voxels changes nothing.

    Attributes
    ----------
    axis : int
        Direction of the rays (0, 1 or 2).
    u_axis, v_axis : int
        The other two axes, ``u_axis < v_axis``.
    u0, v0 : float
        Low corner of the lattice across the rays.
    du, dv : float
        Spacing of the rays along ``u_axis`` and ``v_axis`` (the voxel size).
    nu, nv : int
        Rays along ``u_axis`` and ``v_axis``; ray ``i + nu * j``.
    start : float
        Coordinate along ``axis`` where every ray starts, outside the mesh.
    w0 : float
        The plane depths are measured from (the grid's low face).
    """

    axis: int
    u_axis: int
    v_axis: int
    u0: float
    v0: float
    du: float
    dv: float
    nu: int
    nv: int
    start: float
    w0: float = 0.0

    @property
    def count(self) -> int:
        return self.nu * self.nv

    def centres_u(self) -> np.ndarray:
        return self.u0 + (np.arange(self.nu) + 0.5) * self.du

    def centres_v(self) -> np.ndarray:
        return self.v0 + (np.arange(self.nv) + 0.5) * self.dv


def check_positive_int(name, value):
    if isinstance(value, bool):
        raise ParameterError(f"`{name}` must be a positive integer, got {value!r}")
    if not isinstance(value, numbers.Integral):
        if isinstance(value, numbers.Real) and float(value).is_integer():
            value = int(value)
        else:
            raise ParameterError(f"`{name}` must be a positive integer, got {value!r}")
    if value < 1:
        raise ParameterError(f"`{name}` must be a positive integer, got {value!r}")
    return int(value)


def check_bounds(bounds):
    try:
        b = np.asarray(bounds, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise ParameterError(
            f"`bounds` must be 6 numbers (xmin ymin zmin xmax ymax zmax), got {bounds!r}"
        ) from None
    if b.size != 6:
        raise ParameterError(
            f"`bounds` must be 6 numbers (xmin ymin zmin xmax ymax zmax), got {bounds!r}"
        )
    if not np.all(np.isfinite(b)):
        raise ParameterError(f"`bounds` must be finite, got {tuple(b.tolist())}")
    lo, hi = b[:3], b[3:]
    bad = [("xyz"[a]) for a in range(3) if not lo[a] < hi[a]]
    if bad:
        raise ParameterError(
            f"`bounds` needs min < max on every axis; not so on {', '.join(bad)}: "
            f"{tuple(b.tolist())}"
        )
    return lo, hi


def make_grid(
    mesh_bounds,
    *,
    bounds=None,
    resolution=None,
    shape=None,
    voxel_size=None,
    fit="box",
) -> Grid:
    """Build the grid from the user's region and resolution choice.

    Parameters
    ----------
    mesh_bounds : (2, 3) float64
        Bounding box of the mesh: the default region.
    bounds : sequence of 6 float, optional
        ``(xmin, ymin, zmin, xmax, ymax, zmax)`` of the region of interest.
    resolution : int, optional
        Voxels on every axis.
    shape : (3,) int, optional
        Voxels along x, y and z.
    voxel_size : float, optional
        Edge of a cubic voxel; the region grows symmetrically to a whole
        number of voxels (``shape = ceil(extent / voxel_size)``).
    fit : {"box", "cube", "cube-center"}
        With ``resolution`` (see :data:`FITS`): ``"cube"`` and
        ``"cube-center"`` give the N³ cube of binvox's ``-d N`` (and ``-cb``)
        over the region's longest side; they refuse ``shape`` and
        ``voxel_size``.

    At most one of ``resolution``, ``shape`` and ``voxel_size`` may be given;
    with none, ``resolution=DEFAULT_RESOLUTION``.
    """
    if fit not in FITS:
        raise ParameterError(f"`fit` must be one of {', '.join(map(repr, FITS))}, got {fit!r}")
    given = [n for n, v in (("resolution", resolution), ("shape", shape),
                            ("voxel_size", voxel_size)) if v is not None]
    if len(given) > 1:
        raise ParameterError(
            f"give only one of `resolution`, `shape`, `voxel_size`; got {', '.join(given)}"
        )
    if fit != "box" and given and given[0] != "resolution":
        raise ParameterError(f"`fit={fit!r}` (--cube) makes an N³ cube from `resolution`; it "
                             f"cannot take `{given[0]}`")
    if bounds is None:
        mb = np.asarray(mesh_bounds, dtype=np.float64)
        lo, hi = mb[0].copy(), mb[1].copy()
        # A flat mesh has zero extent on an axis; give that axis a thin slab
        # so spacing stays positive (the volume is empty there anyway).
        flat = (hi - lo) <= 0
        pad = ((hi - lo).max() or 1.0) * 1e-3
        lo[flat] -= pad
        hi[flat] += pad
    else:
        lo, hi = check_bounds(bounds)

    if voxel_size is not None:
        try:
            s = float(voxel_size)
        except (TypeError, ValueError):
            raise ParameterError(f"`voxel_size` must be a positive number, got {voxel_size!r}") from None
        if not (math.isfinite(s) and s > 0):
            raise ParameterError(f"`voxel_size` must be a positive number, got {voxel_size!r}")
        extent = hi - lo
        counts = np.ceil(extent / s - 1e-9)
        if not np.all(counts < 2**31):
            raise ParameterError(f"`voxel_size` {voxel_size!r} gives a grid of "
                                 f"{' x '.join(f'{c:.3g}' for c in counts)} voxels; use a larger voxel size")
        n = np.maximum(1, counts).astype(np.int64)
        grow = (n * s - extent) / 2.0
        lo, hi = lo - grow, lo - grow + n * s
        return Grid(lo=lo, hi=hi, shape=tuple(int(x) for x in n))

    if shape is not None:
        try:
            items = list(shape)
        except TypeError:
            raise ParameterError(f"`shape` must be three positive integers, got {shape!r}") from None
        if len(items) != 3:
            raise ParameterError(f"`shape` must be three positive integers, got {shape!r}")
        n = tuple(check_positive_int("shape", x) for x in items)
        return Grid(lo=lo, hi=hi, shape=n)

    r = DEFAULT_RESOLUTION if resolution is None else check_positive_int("resolution", resolution)
    if fit != "box":
        lo, hi = cube_region(lo, hi, centre=fit == "cube-center")
    return Grid(lo=lo, hi=hi, shape=(r, r, r))


def cube_region(lo, hi, centre=False):
    """The cube binvox's ``-d`` voxelises: edge = the box's longest side.

    binvox normalises a model by translating its bounding box's minimum
    corner to the origin and scaling by 1 / (longest side), then voxelises
    the unit cube; its header's ``translate`` is that corner and ``scale``
    that side. With ``-cb`` ("center model inside unit cube") the box is
    centred in the cube instead, on every axis.

    Parameters
    ----------
    lo, hi : (3,) float64
        The box.
    centre : bool
        Centre the box in the cube (``-cb``) rather than start both at ``lo``.

    Returns
    -------
    lo, hi : (3,) float64
        The cube's corners.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    edge = float(np.max(hi - lo))
    if centre:
        # Centred in float64 as (lo + hi) / 2 - edge / 2; on the longest axis
        # this is lo up to rounding, so that axis's corner is kept exactly.
        start = np.where(hi - lo == edge, lo, (lo + hi) / 2.0 - edge / 2.0)
    else:
        start = lo.copy()
    return start, start + edge


def fit_for(fit, fmt_name=None, *, shape=None, voxel_size=None) -> str:
    """The fit a conversion into format ``fmt_name`` uses.

    ``fit`` when given; otherwise ``"cube"`` for ``.binvox`` with a resolution
    (given or the default), because binvox's ``-d N`` means that cube and
    every pipeline that reads binvox asks for it so; ``"box"`` elsewhere.
    """
    if fit is not None:
        return fit
    return "cube" if fmt_name == "binvox" and shape is None and voxel_size is None else "box"
