"""The Volume a conversion makes: arrays and the grid they live on.

Its own module so that the writers in :mod:`geovox.formats` can build and
read volumes without importing the pipeline that makes them.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .grid import Grid


@dataclass
class Volume:
    """A voxelised mesh.

    Attributes
    ----------
    occupancy : (nx, ny, nz) bool, Fortran order
        True inside. Indexed ``[x, y, z]``; x is fastest in memory, so
        ``occupancy.T.tobytes()`` is the x-fastest byte order of RAW files.
    grid : Grid
        The grid the arrays live on: ``lo``, ``hi`` (3,) float64 and
        ``shape``.
    backend : str
        Name of the backend that ran.
    source : str
        Where the mesh came from (its path, or a description).
    colors : (nx, ny, nz, 4) uint8 or None
        RGBA colour per voxel, when colour was asked for.
    inside : str
        The inside/outside method that ran (``auto`` resolved).
    density : (nx, ny, nz) uint8 or float32, or None
        Coverage: the fraction of each voxel inside the mesh (0-255 as uint8).
    sdf : (nx, ny, nz) float32 or None
        Distance from each voxel centre to the surface (signed: negative
        inside; or unsigned), exact within ``band`` voxels and clamped to
        ``band`` voxels (``band * min(spacing)``) beyond.
    band : float or None
        With ``sdf``: the band's half-width in voxels (``inf``: every voxel exact).
    unsigned : bool
        With ``sdf``: the distance is unsigned (``sdf="unsigned"``), not
        negative inside.
    timings : dict
        Seconds per stage.
    mesh_space : (str, str) or None
        On a reference grid (``like=``): the mesh's frame ("LPS" or "RAS") and
        how it was decided (see :func:`geovox.reference.resolve_mesh_space`).
    labels : (nx, ny, nz) uint8 or uint16, or None
        Label value per voxel (0 the background), when labels were asked for
        (see :mod:`geovox.labels`).
    label_table : list of dict or None
        One entry per label value, the background (0) first: ``value``,
        ``name``, ``source``, ``color`` (RGBA 0-255), ``voxels``, ``volume``
        (model units cubed).
    contested : int
        Voxels inside more than one part (settled by the overlap rule).
    fractions : (nx, ny, nz, L) uint8 or float32, or None
        Each label's coverage fraction per voxel (index ``k`` for label
        value ``k + 1``), when asked for.
    approximate : int
        Voxels whose inside was left to an estimate of the winding number
        (its work budget ran out: ``Report.approximate``); 0 where every
        voxel is exact or proven.
    counts : dict or None
        With surface voxels (``occupancy="surface"`` or ``"both"``): how many
        the surface passes through (``"surface"``) and, with ``"both"``, how
        many are inside (``"inside"``); ``occupancy`` holds their union.
    """

    occupancy: np.ndarray
    grid: Grid
    backend: str
    source: str = "<mesh>"
    colors: np.ndarray | None = None
    timings: dict = field(default_factory=dict)
    inside: str = "parity"
    density: np.ndarray | None = None
    sdf: np.ndarray | None = None
    band: float | None = None
    unsigned: bool = False
    mesh_space: tuple | None = None
    labels: np.ndarray | None = None
    label_table: list | None = None
    contested: int = 0
    fractions: np.ndarray | None = None
    approximate: int = 0
    counts: dict | None = None

    @property
    def bounds(self) -> tuple:
        """``((xmin, ymin, zmin), (xmax, ymax, zmax))`` of the grid."""
        return (tuple(float(x) for x in self.grid.lo), tuple(float(x) for x in self.grid.hi))

    @property
    def spacing(self) -> tuple:
        """``(dx, dy, dz)``: the voxel dimensions."""
        return tuple(float(x) for x in self.grid.spacing)

    @property
    def shape(self) -> tuple:
        """``(nx, ny, nz)``."""
        return tuple(self.grid.shape)

    @property
    def inside_count(self) -> int:
        return int(np.count_nonzero(self.occupancy))

    @property
    def occupied_word(self) -> str:
        """What an occupied voxel is, as a summary says it: ``"inside"`` (the solid),
        ``"surface"`` (surface voxels alone) or ``"occupied"`` (both)."""
        if self.counts is None:
            return "inside"
        return "surface" if "inside" not in self.counts else "occupied"


@dataclass(frozen=True)
class Progress:
    """What a ``progress`` callback is handed, by every entry point.

    Attributes
    ----------
    stage : str
        ``"load"``, ``"rays"``, ``"colour"``, ``"density"``, ``"sdf"`` as a
        block's stage starts; ``"slab"`` after each slab of a streamed
        conversion; ``"model"`` after each model of a batch.
    done, total : int or None
        Slabs or models done, and how many in all (None for a stage).
    result : object
        ``"model"``: that model's :class:`geovox.batch.Result`.
    """

    stage: str
    done: int | None = None
    total: int | None = None
    result: object = None


@dataclass
class Report:
    """What one conversion did: the one result type of every entry point.

    :func:`geovox.voxelize` returns its ``volume``; :func:`geovox.convert_to`
    the Report itself (which also reads as the dict it used to return:
    ``report["files"]``); a batch's :class:`geovox.batch.Result` is made
    from one; the command line prints it (:meth:`summary`).

    Attributes
    ----------
    source : str
    grid : Grid
        The whole grid.
    backend : str
    inside_test : str
        The inside test that ran.
    inside : int
        Voxels inside.
    route : str
        How it ran (:class:`geovox.planner.Route`).
    slabs : int
        Blocks it ran in.
    volume : Volume or None
        The volume, where it was held in memory.
    files : list of str
        Every file written, the volume first.
    timings : dict
        Seconds per stage ("load", "rays", "fill", "colour", "density",
        "sdf", "write", "total" as run).
    warnings : list of str
        What was said (where the caller collected it).
    approximate : int
        Voxels whose inside was left to an estimate of the winding number
        because its work budget (``geovox.inside.winding.WORK_SECONDS`` of
        processor time) ran out, summed over the slabs (and over the parts,
        with labels by part); 0 where every voxel is exact or proven by its
        error bound. Only the winding number of an open model can leave any.
    """

    source: str
    grid: Grid
    backend: str
    inside_test: str
    inside: int
    route: str = "memory"
    slabs: int = 1
    volume: Volume | None = None
    files: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    mesh_space: tuple | None = None
    #: More lines for the summary, after the inside count (e.g. the labels made).
    lines: list = field(default_factory=list)
    #: With labels, where no volume is held (slab by slab): the whole grid's label table.
    label_table: list | None = None
    #: With labels: voxels inside more than one part (summed over the slabs).
    contested: int = 0
    approximate: int = 0
    #: With surface voxels: how many the surface passes through ("surface") and, with
    #: ``occupancy="both"``, how many are inside ("inside"); ``inside`` counts their union.
    counts: dict | None = None

    @property
    def shape(self) -> tuple:
        return tuple(self.grid.shape)

    @property
    def spacing(self) -> tuple:
        return tuple(float(x) for x in self.grid.spacing)

    @property
    def bounds(self) -> tuple:
        return (tuple(float(x) for x in self.grid.lo), tuple(float(x) for x in self.grid.hi))

    @property
    def filled_in_slabs(self) -> bool:
        """Whether a one-piece occupancy was filled and written 64 slices at a time."""
        return self.route == "64-slice fill"

    #: The keys of the dict convert_to returned before it returned a Report, and ``approximate``.
    KEYS = ("shape", "spacing", "bounds", "inside", "inside_test", "backend", "slabs", "files",
            "timings", "filled_in_slabs", "grid", "source", "mesh_space", "approximate")

    def __getitem__(self, key):
        if key in ("labels", "contested") and self.volume is not None \
                and self.volume.label_table is not None:
            v = self.volume
            return len(v.label_table) - 1 if key == "labels" else v.contested
        if key in ("labels", "contested") and self.label_table is not None:
            return len(self.label_table) - 1 if key == "labels" else self.contested
        if key not in self.KEYS:
            raise KeyError(key)
        return getattr(self, key)

    def get(self, key, default=None):
        try:
            return self[key]
        except KeyError:
            return default

    def keys(self):
        return self.KEYS

    def summary(self, wall: float, extra_load: float = 0.0) -> list:
        """The lines the command line prints after a conversion."""
        nx, ny, nz = self.shape
        dx, dy, dz = self.spacing
        lo, hi = self.bounds
        t = dict(self.timings)
        t["load"] = t.get("load", 0.0) + extra_load
        if self.route == "memory" and self.grid.reference is not None:
            where = " of the reference image"
        elif self.route == "memory":
            where = (f" over ({lo[0]:.6g}, {lo[1]:.6g}, {lo[2]:.6g})..({hi[0]:.6g}, {hi[1]:.6g}, "
                     f"{hi[2]:.6g})")
        else:
            where = (f" in {self.slabs} slabs" if self.slabs > 1 else
                     " in 64-slice slabs" if self.filled_in_slabs else "")
        n = nx * ny * nz
        stages = ", ".join(f"{k} {t[k]:.2f}" for k in ("load", "rays", "fill", "surface", "colour",
                                                        "density", "sdf", "write") if k in t)
        onto = [] if self.mesh_space is None else [reference_line(self.grid.reference,
                                                                   self.mesh_space)]
        return [f"{os.path.basename(self.source)}: grid {nx} x {ny} x {nz}{where}",
                f"voxel size {dx:.6g} x {dy:.6g} x {dz:.6g}, backend {self.backend}, "
                f"{self._test()}", *onto, self._count_line(n),
                *([approximate_line(self.approximate, n)] if self.approximate else []),
                *self.lines,
                f"time {wall:.2f} s ({stages})",
                "wrote " + ", ".join(self.files)]


    def _test(self) -> str:
        """What decided the voxels: the inside test, with the surface voxels where they are on."""
        if self.counts is None:
            return f"inside test {self.inside_test}"
        test = self.inside_test.removesuffix("+surface")
        if test == "surface":
            return "occupancy surface (the voxels the surface passes through)"
        return f"inside test {test}, occupancy both (inside or on the surface)"

    def _count_line(self, n: int) -> str:
        """The summary's count: inside voxels, surface voxels, or both and their union."""
        def share(k):
            return f"{k:,} of {n:,} voxels ({100.0 * k / n:.2f}%)"

        if self.counts is None:
            return f"inside {share(self.inside)}"
        if "inside" not in self.counts:
            return f"surface {share(self.counts['surface'])}"
        return (f"occupied {share(self.inside)}: inside {self.counts['inside']:,}, "
                f"surface {self.counts['surface']:,}")


def approximate_line(n: int, total: int) -> str:
    """The summary's line on the voxels an estimate of the winding number decided (``n`` of ``total``)."""
    share = 100.0 * n / total
    share = f"{share:.1f}" if share >= 1 else f"{share:.2g}"  # never "1e+02"
    return (f"approximate {n:,} voxels ({share}%): decided by an estimate of the winding number "
            f"(its work budget ran out)")


def reference_line(ref, decided) -> str:
    """The summary's line on a conversion onto a reference grid.

    ``decided``: the mesh's frame and how it was decided, ``(space, how)``
    (a Volume's or a Plan's ``mesh_space``).
    """
    space, how = decided
    return (f"onto {os.path.basename(ref.source)} ({ref.space}); mesh space {space} "
            f"({'--mesh-space' if how == 'given' else how})")
