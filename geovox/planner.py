"""The plan: every decision of one conversion, taken once from its Options.

Every conversion is a plan and then a run. :func:`plan` takes every
decision once -- the grid, the backend, the inside test, the colour method,
the stages (labels), the memory budget and the slab sizing, the route (in
memory, slabs, the 64-slice occupancy fill, cluster tasks), how the slabs
are written, and the writer from the format registry -- and the block
function (:func:`geovox.block.voxelize_block`) and the runners
(:mod:`geovox.runners`) do what it says, deciding nothing again.

Slab sizing lives here too: a grid is cut into slabs along z (64 voxels
thick, or a multiple, to match the 64³ HDF5 and Zarr chunks) within a
memory budget (:func:`slab_plan`), and whether a conversion streams at all
is one rule (:func:`streams`).
"""

from __future__ import annotations

import dataclasses
import enum
import math
import os
from dataclasses import dataclass, fields

from .errors import GridTooLargeError, ParameterError
from .grid import Grid, make_grid
from .kernels import chosen
from . import memory
from .memory import bytes_per_voxel, check_memory
from .options import Colour, Inside, LabelSource, Occupancy, Options, colour_of, sdf_of
from .output import Target

#: Memory a slab's arrays may take, by default: 2048³ occupancy goes in
#: 256-voxel slabs and stays under 3 GiB; occupancy up to 1024³ is one slab.
SLAB_BUDGET = 1 << 30
#: Thickest slab of a local chunked (.zarr) conversion: at 1024³ four 256-layer
#: slabs took 5.2-6.8 s where one piece took 8.4 s (its 1 GiB array is touched
#: fresh), and 256 layers still write pyramid levels 0-2 in the slab.
LOCAL_ZARR_SLAB = 256
#: Voxels from which a one-piece occupancy is filled and written 64 slices at a
#: time anyway (512³; see :func:`streams_whole`).
WHOLE_STREAM_VOXELS = 1 << 27
#: Memory one slab task may take on a cluster worker (its occupancy and working arrays).
WORKER_SLAB_BUDGET = 1 << 30
#: Bits one slab of surface voxels written as points may take (:attr:`Plan.surface_points`),
#: reused from slab to slab: 1024³ is one slab, 2048³ eight of 256 layers. Fewer slabs,
#: fewer passes over the triangles and fewer parallel regions: on two busy cores each
#: region can wait a scheduler slice for its second thread (the dragon at 1024³ in four
#: 256-layer slabs took 260 ms on two threads, 170 on one).
POINTS_SLAB_BUDGET = 1 << 27


class Route(enum.StrEnum):
    """How a plan's blocks are run and written."""

    MEMORY = "memory"  #: one block, the whole grid, held in memory (then written whole)
    SLABS = "slabs"  #: blocks along z, each written into the file before the next is made
    FILL = "64-slice fill"  #: occupancy alone: rays once, parity filled and written 64 slices at a time
    CLUSTER = "cluster"  #: chunked (.zarr) slabs as tasks on a Dask cluster's workers


@dataclass(frozen=True)
class Plan:
    """Every decision of one conversion, taken once by :func:`plan`.

    Attributes
    ----------
    options : Options
        What was asked for.
    grid : Grid
        The whole grid.
    backend : geovox.backends.Backend
        The ray-casting engine (shipped to cluster tasks by name).
    inside : Inside or None
        The inside test that runs (``auto`` resolved); None where no solid
        is made (``occupancy="surface"`` alone: no inside test runs).
    colour : Colour or None
        The colour method, None without colour.
    jobs : int
        Threads (>= 1).
    axis : int
        Direction of the blocks' column rays.
    route : Route
    blocks : tuple of (z0, z1)
        Layers of each block; one block ``(0, nz)`` in memory.
    per_voxel : float
        Working bytes per voxel of a block (the memory budget's unit).
    budget : float or None
        Bytes one slab may take (streamed routes).
    format : geovox.formats.Format or None
        Output format (None: no file).
    path : str or None
        Output file.
    reuse_z : bool
        Fast colour over several slabs: the rays along z are cast once for
        the whole grid and each slab takes its part (see :mod:`geovox.runners`).
    chunk_slab : int or None
        A chunked format (``.zarr``): the slab thickness its shards are laid
        out for (a multiple of its chunk; the last block may be thinner).
    mesh_space : (str, str) or None
        With ``like``: the mesh's frame and how it was decided (see
        :func:`geovox.reference.resolve_mesh_space`).
    labels : geovox.labels.LabelStage or None
        With ``labels``: the labels stage (what each label is, each part's
        inside test, fractions), run per block like colour.
    density_inside : Inside or None
        With ``density``: the inside test the coverage follows (the whole
        mesh's own, also where labels by part give the occupancy).
    colour_sink : bool
        Fast colour over several slabs into a format whose writer takes
        colours chunk by chunk (RAW): no slab of colours is held.
    write_behind : bool
        Exact colour over several slabs: a slab is written on a thread while
        the next one is made (two sets of buffers take turns).
    reuse_buffers : bool
        Several slabs, not chunked: one set of slab arrays is reused by
        every slab instead of faulting fresh memory in for each.
    occupancy : Occupancy
        Which voxels are on: the solid, the surface voxels, or both.
    surface_bits : int or None
        With surface voxels: the whole mesh's snapping scale
        (:func:`geovox.surface.snap_bits`), the same for every block.
    surface_points : bool
        Surface voxels alone, slab by slab into a point cloud (a format
        that ``can.points``): each block's voxels are made as bits and
        handed to the writer as indices (:func:`geovox.surface.surface_points`);
        no byte per voxel is made, filled or scanned.
    """

    options: Options
    grid: Grid
    backend: object
    inside: Inside
    colour: Colour | None
    jobs: int
    axis: int
    route: Route = Route.MEMORY
    blocks: tuple = ()
    per_voxel: float = 1.0
    budget: float | None = None
    format: object = None
    path: str | None = None
    reuse_z: bool = False
    chunk_slab: int | None = None
    mesh_space: tuple | None = None
    labels: object = None
    density_inside: Inside | None = None
    colour_sink: bool = False
    write_behind: bool = False
    reuse_buffers: bool = False
    occupancy: Occupancy = Occupancy.SOLID
    surface_bits: int | None = None
    surface_points: bool = False

    def mesh_for(self, mesh):
        """The mesh the blocks run on: ``mesh``, or with ``like`` the copy moved into the
        reference's frame that :func:`plan` made from it."""
        moved = self.__dict__.get("_mesh")
        return mesh if moved is None else moved

    @property
    def thick(self) -> int:
        """Layers of the first block (slab thickness)."""
        z0, z1 = self.blocks[0]
        return z1 - z0

    def writer(self, meta, client=None):
        """A slab writer for this plan's output (the format's, from the registry)."""
        return self.format.slab_writer(self.path, meta, self.jobs, thick=self.chunk_slab,
                                       client=client)

    def for_task(self) -> "Plan":
        """The plan a cluster task runs a slab with: single-threaded, no writer (it writes shards)."""
        return dataclasses.replace(self, jobs=1, format=None, path=None)

    def __getstate__(self):
        # The backend travels by name: a worker uses its own instance.
        # (The moved mesh of `like` stays here: a task is handed its mesh.)
        state = {f.name: getattr(self, f.name) for f in fields(self)}
        from .backends import REGISTRY

        if getattr(self.backend, "name", None) in REGISTRY:
            state["backend"] = self.backend.name
        return state

    def __setstate__(self, state):
        if isinstance(state["backend"], str):
            from .backends import get_backend

            state = dict(state, backend=get_backend(state["backend"]))
        for k, v in state.items():
            object.__setattr__(self, k, v)

    def describe(self) -> list:
        """Lines for ``geovox info``: what this plan will do."""
        nx, ny, nz = self.grid.shape
        o = self.options
        lines = [f"plan: backend {self.backend.name}, inside test {self.inside or 'none'}, "
                 + (f"occupancy {self.occupancy}, " if self.occupancy != Occupancy.SOLID else "")
                 + f"colour {self.colour or 'none'}"
                 + (f", density {o.density} ({o.density_dtype})" if o.density else "")
                 + (f", sdf {sdf_of(o.sdf)} (band {float(o.band):g} voxels)" if o.sdf else "")
                 + f", {self.jobs} thread{'s' if self.jobs > 1 else ''}"]
        if self.route == Route.MEMORY:
            where = "in memory, one block"
        else:
            where = (f"{self.route}, {len(self.blocks)} block{'s' if len(self.blocks) > 1 else ''}"
                     f" of {self.thick} layers")
        need = self.per_voxel * nx * ny * (self.thick if self.blocks else nz)
        lines.append(f"route: {where}; rays along {'xyz'[self.axis]}; about "
                     f"{_size(need)} of working memory"
                     + (f" (slab budget {_size(self.budget)})" if self.budget else ""))
        if self.format is not None:
            lines.append(f"writer: {self.format.name} -> {self.path}")
        return lines


def _size(b) -> str:
    return f"{b / 2**20:,.1f} MiB" if b < 2**30 else f"{b / 2**30:,.2f} GiB"


# --- slab sizing ---------------------------------------------------------------

def slab_plan(grid: Grid, per_voxel: float, budget: float = SLAB_BUDGET) -> list:
    """``[(z0, z1), ...]``: slabs along z, a multiple of 64 thick, within ``budget``."""
    nx, ny, nz = grid.shape
    fit = int(budget // max(1.0, nx * ny * per_voxel))
    thick = nz if fit >= nz else max(64, fit // 64 * 64)
    return [(z, min(z + thick, nz)) for z in range(0, nz, thick)]


def slab_budget() -> float:
    """Bytes one slab's arrays may take: ``SLAB_BUDGET``, or half the available memory if less."""
    avail = memory.available_memory()  # looked up at call time (a test's stand-in)
    return SLAB_BUDGET if avail is None else min(SLAB_BUDGET, 0.5 * avail)


def streams(grid: Grid, fmt, options: Options, extra=0.0) -> bool:
    """Whether a conversion into format ``fmt`` runs slab by slab (:func:`geovox.convert_to`).

    The one rule for the command line and batches (:func:`plan` with
    ``stream=None`` applies it): a format with a slab writer, and a grid
    that needs several slabs within :func:`slab_budget`, or whose occupancy
    is worth streaming in one piece (:func:`streams_whole`). Either way the
    file is the same as one written from memory.

    Parameters
    ----------
    fmt : geovox.formats.Format or str
        The format, or its name.
    options : Options
        What the conversion makes (its memory per voxel).
    extra : float
        More working bytes per voxel: labels and fractions
        (:meth:`geovox.labels.LabelStage.working_bytes`); with them a
        one-piece grid is made in memory.
    """
    from .formats import format_for

    f = format_for("", fmt) if isinstance(fmt, str) else fmt
    if f.slab_writer is None:
        return False
    if f.name == "vdb" and sdf_of(options.sdf) and math.isinf(float(options.band)):
        return False  # a level set's slabs are padded with its background, the band's distance
    if f.can.always_streams:
        return True  # each slab writes its own chunks
    blocks = slab_plan(grid, bytes_per_voxel(options) + extra, slab_budget())
    return len(blocks) > 1 or (not extra and streams_whole(grid, options))


def streams_whole(grid: Grid, options: Options | None = None) -> bool:
    """Whether a one-piece conversion to .h5 / .raw is worth streaming anyway.

    Occupancy alone of a grid of 512³ voxels or more: filling and writing
    64 slices at a time skips allocating (and first touching) the whole
    array, which on a 1024³ grid costs 0.2-2.5 s by itself, depending on
    the machine's memory state. ``options``: what is made (default
    occupancy alone).
    """
    alone = options is None or bytes_per_voxel(options) == 1.0  # occupancy: 1 byte a voxel
    return alone and grid.size >= WHOLE_STREAM_VOXELS and grid.shape[2] > 64


def cluster_thick(grid: Grid, per_voxel: float, budget: float = WORKER_SLAB_BUDGET) -> int:
    """Slab thickness for cluster tasks: 64 x a power of two within ``budget``, four slabs at least.

    A power of two lets each slab write its own shards of the first pyramid
    levels too (see :func:`geovox.formats.zarr.in_slab_levels`); four slabs
    or more keep two workers busy.
    """
    nx, ny, nz = grid.shape
    thick = 64
    while (thick * 2 * nx * ny * per_voxel <= budget and thick * 2 * 4 <= nz):
        thick *= 2
    return thick


# --- the plan --------------------------------------------------------------------

def load(mesh, options: Options):
    """``mesh`` loaded as ``options`` say (a loaded Mesh passes through): the load stage."""
    from .io import load as loader  # looked up at call time (a test's stand-in, a worker's plugin)

    if isinstance(mesh, (list, tuple)):
        if options.labels is None:
            raise ParameterError("several meshes make one scene only with `labels` (e.g. "
                                 "labels='file'); convert them one by one otherwise")
        from .labels import scene

        with chosen(options.kernel):  # the OBJ reader's compiled loop follows the option too
            return scene(mesh, options)
    with chosen(options.kernel):
        return loader.load_mesh(mesh, references=options.references,
                                max_input_size=options.max_input_size)


def grid_of(mesh, options: Options, fmt=None) -> Grid:
    """The grid ``options`` ask for over ``mesh`` (a loaded Mesh): the one place grids are made.

    ``fmt`` (a Format or its name) is the output's: a ``.binvox`` resolution is binvox's cube.
    """
    name = getattr(fmt, "name", fmt)
    if options.like is not None:  # the reference's grid, in its local frame
        from .reference import load_reference, reject_grid_options

        reject_grid_options(**options.grid_options())  # --cube as given, not a format's default
        return load_reference(options.like).local_grid()
    return make_grid(mesh.bounds, **options.grid_options(name))


def as_options(options=None, **kw) -> Options:
    """``options`` (an Options, a dict or None) with keywords ``kw`` on top, validated."""
    if options is None:
        return Options.from_kwargs(**kw)
    if isinstance(options, dict):
        return Options.from_kwargs(**{**options, **kw})
    return options.replace(**kw) if kw else options


@dataclass(frozen=True)
class _Request:
    """How :func:`plan` was asked to run: its keywords that are not Options."""

    stream: bool | None = None
    cluster: bool = False
    budget: float | None = None
    slab: int | None = None


def plan(mesh, options=None, path=None, *, fmt=None, stream=None, cluster=False, budget=None,
         slab=None, grid=None) -> Plan:
    """Take every decision of one conversion once.

    Parameters
    ----------
    mesh : geovox.mesh.Mesh
        The loaded model (anything :func:`geovox.io.load.load_mesh` reads is loaded first).
    options : Options or dict, optional
        What to make (a dict is checked by :meth:`Options.from_kwargs`).
    path : str or geovox.output.Target, optional
        The output file: its format comes from the extension (or ``fmt``);
        or a resolved output (:func:`geovox.output.resolve_output`), whose
        folder's file is named after the grid the plan makes. Without it
        the plan is in memory.
    fmt : str, optional
        Format name, overriding the extension.
    stream : bool, optional
        True: slab by slab whatever the size (:func:`geovox.convert_to`);
        False: in memory; None: the rule of :func:`streams` (the command
        line and batches).
    cluster : bool
        The slabs run as tasks on a cluster (a format that ``can.cluster``: ``.zarr``).
    budget : float, optional
        Bytes one slab's arrays may take (default: :func:`slab_budget`).
    slab : int, optional
        A chunked format only (``.zarr``): slab thickness, a multiple of its chunk.
    grid : Grid, optional
        The grid :func:`grid_of` already made for this mesh, options and
        format (the output's default name carries its shape); without it,
        or with ``like``, the plan makes its own.

    Returns
    -------
    Plan

    Raises
    ------
    ParameterError
        An option, format or combination that cannot be made.
    GridTooLargeError
        The grid does not fit in memory, even slab by slab.
    BackendUnavailableError
        The backend named cannot run here.
    """
    o = as_options(options)
    with chosen(o.kernel):  # the inside test's mesh checks run compiled or not, as asked
        return _plan(mesh, o, path, fmt, _Request(stream, cluster, budget, slab), grid)


def _plan(mesh, o: Options, path, fmt, how: _Request, grid=None) -> Plan:
    """:func:`plan`, with ``o`` validated."""
    from .backends import get_backend
    from .parallel import resolve_jobs

    engine = get_backend(o.backend) if isinstance(o.backend, str) else o.backend
    m = load(mesh, o)
    f = target = None
    if isinstance(path, Target):
        target, f = path, path.fmt
    elif path is not None:
        from . import formats

        f = formats.format_for(path, fmt)
    m, grid, used = _mesh_and_grid(m, o, f, grid)
    if target is not None:  # a folder's file is named after the grid
        path = target.file_for(grid.shape)
    colour = colour_of(o.color)
    occupancy = Occupancy(o.occupancy)
    base = dict(options=o, grid=grid, backend=engine, colour=colour, jobs=resolve_jobs(o.jobs),
                format=f, path=None if path is None else str(path), mesh_space=used,
                occupancy=occupancy)
    if occupancy != Occupancy.SOLID:
        from .surface import snap_bits

        # One snapping scale for the whole mesh: every block's surface voxels are the whole grid's.
        base["surface_bits"] = snap_bits(m.vertices, grid, faces=m.faces, jobs=base["jobs"])
    stage = _label_stage(m, o, f)
    stream = how.stream
    extra = 0.0  # the labels' and fractions' bytes per voxel
    if stage is not None:
        base["labels"] = stage
        extra = stage.working_bytes()
        if f is None or f.slab_writer is None:
            stream = False  # the format is written whole
    solid = _makes_solid(o, occupancy, stage)
    if o.density is not None:
        # Coverage follows the whole mesh's own inside test, also where labels by
        # part give the occupancy (so density is the same bytes with and without labels),
        # and describes the solid whatever the occupancy.
        base["density_inside"] = _chosen_quietly(_inside_tests(), m, o.inside) \
            if stage is not None and stage.by_parts else \
            None if solid else Inside(_inside_tests().choose(m, o.inside))
    # Surface voxels alone into a point cloud: slabs of bits, written as points, at any size.
    points = (f is not None and f.can.points and occupancy == Occupancy.SURFACE
              and stage is None and not (colour or o.density or o.sdf) and stream is not False)
    if stream is None:
        stream = f is not None and (points or streams(grid, f, o, extra=extra))
    base["surface_points"] = points and bool(stream) and not how.cluster
    if not stream or f is None:
        # By parts, each part takes its own inside test (geovox.labels.classify).
        method = (Inside(o.inside) if stage is not None and stage.by_parts
                  else Inside(_inside_tests().choose(m, o.inside)) if solid else None)
        p = Plan(inside=method, axis=o.axis, route=Route.MEMORY, blocks=((0, grid.shape[2]),),
                 per_voxel=bytes_per_voxel(o) + extra, **base)
    else:
        p = _streamed_plan(m, base, how, extra=extra)
    if p.options.density is not None and p.density_inside is None:
        object.__setattr__(p, "density_inside", p.inside)
    # With `like`, the mesh the blocks run on is the moved one (see Plan.mesh_for).
    object.__setattr__(p, "_mesh", m if used is not None else None)
    return p


def _makes_solid(o: Options, occupancy: Occupancy, stage) -> bool:
    """Whether the blocks make the solid: its voxels are on, or the signed distance's sign
    needs it (the distance, like density, describes the solid whatever the occupancy)."""
    if stage is not None and stage.by_parts:
        return occupancy != Occupancy.SURFACE  # each part's own solid (geovox.labels.classify)
    return occupancy != Occupancy.SURFACE or sdf_of(o.sdf) == "signed"


def _inside_tests():
    """:mod:`geovox.inside`, imported where a solid is made (surface voxels alone need none)."""
    from . import inside

    return inside


def _chosen_quietly(inside_tests, m, method) -> Inside:
    """The whole mesh's inside test, its repair not said again (the parts said theirs)."""
    from .errors import collect_warnings

    with collect_warnings(drop=True):
        return Inside(inside_tests.choose(m, method))


def _mesh_and_grid(m, o: Options, f, made=None):
    """``(mesh, grid, mesh space)``: with ``like`` the mesh moved into the reference's frame.

    ``made``: the grid :func:`grid_of` gave already (not used with ``like``,
    whose grid comes with the moved mesh).
    """
    used = None
    if o.like is not None:
        from .reference import prepare

        # The mesh moved into the reference's local frame, where its grid is axis-aligned.
        m, grid, used = prepare(m, o)
    else:
        grid = made if made is not None else grid_of(m, o, f)
    if f is not None:
        from . import formats

        formats.check_frame(f, grid)
        if f.check is not None:
            f.check(grid)  # e.g. binvox needs cubic voxels
    return m, grid, used


def _label_stage(m, o: Options, f):
    """The labels stage ``o.labels`` asks for (None without), checked against the format."""
    if o.labels is None:
        return None
    from .errors import collect_warnings, warn
    from .inside import choose
    from .labels import LabelStage, label_set, part_meshes

    if f is not None:
        from . import formats

        formats.check_labels(True, f)
    methods = []
    lset = label_set(m, o.labels, stacklevel=4)
    # Surface voxels alone need no part's inside test (nor its repair).
    if lset.source != LabelSource.MATERIAL and o.occupancy != Occupancy.SURFACE:
        repaired = 0
        for part in part_meshes(m, lset):
            # Each part's own warning would be one line a part (a Cornell box: eight); they
            # are said as one below.
            with collect_warnings() as said:
                methods.append(Inside.PARITY if part is None else Inside(choose(part, o.inside)))
            repaired += bool(said)
        if repaired:
            name = os.path.basename(str(m.source)) or "the mesh"
            warn(f"{name}: {repaired:,} of {len(methods):,} {lset.source} labels are not closed or "
                 f"not consistently wound; each is inside by the winding number of its repaired "
                 f"copy (geovox info lists them)", stacklevel=4)
    return LabelStage.build(m, o, methods)


def _streamed_plan(m, base: dict, how: _Request, *, extra=0.0) -> Plan:
    """The slab routes' part of :func:`plan`: blocks within the budget, the route, the axis,
    and how the slabs are written.

    ``extra``: the labels' and fractions' bytes per voxel, counted in the budget.
    """
    o, grid, colour, f = base["options"], base["grid"], base["colour"], base["format"]
    stage = base.get("labels")
    occupancy = base["occupancy"]
    if stage is not None and stage.by_parts:
        # Each part takes its own inside test (as in memory); the budget counts
        # the winding number's arrays wherever a part may need them.
        method = Inside(o.inside)
        working = 15.0 if len(_inside_tests().boundary_edges(m)) else 2.0
    elif _makes_solid(o, occupancy, stage):
        method = Inside(_inside_tests().choose(m, o.inside))
        working = _inside_tests().working_bytes(m, method)
    else:
        method, working = None, 0.0  # surface voxels alone: no inside test
    per = bytes_per_voxel(o) + working + extra
    budget = slab_budget() if how.budget is None else how.budget
    if base["surface_points"]:
        per, budget = 1 / 8, min(budget, POINTS_SLAB_BUDGET)  # a bit a voxel
    blocks = slab_plan(grid, per, budget)
    nx, ny, nz = grid.shape
    thick = None
    if f.can.chunk:
        thick = _chunk_thick(f, grid, per, blocks, how)
        blocks = [(z, min(z + thick, nz)) for z in range(0, nz, thick)]
    z0, z1 = blocks[0]
    try:
        check_memory(Grid(grid.lo, grid.hi, (nx, ny, z1 - z0)), per)
    except MemoryError:
        raise GridTooLargeError(
            f"a {nx} x {ny} x {nz} grid does not fit in memory even slab by slab "
            f"({z1 - z0}-voxel slabs need {nx * ny * (z1 - z0) * per / 2**30:.1f} GiB); "
            f"use a smaller resolution") from None
    several = len(blocks) > 1
    if how.cluster:
        route = Route.CLUSTER
    elif (not f.can.chunk and not several and method == Inside.PARITY
          and occupancy == Occupancy.SOLID
          and not (colour or o.density or o.sdf or stage is not None)):
        # Occupancy alone, one piece: the rays along z are cast once for the
        # whole grid (as voxelize casts them, so the file is the same) and the
        # fill runs 64 slices at a time in two reused buffers, each piece
        # written as the next is made (see parity.fill_slabs): no grid-sized
        # array is ever allocated.
        route = Route.FILL
    else:
        route = Route.SLABS
    # Several slabs: rays along y, so a slab's columns are its own (x, z)
    # pairs and no ray is cast twice. One piece: voxelize's default axis, so
    # the file equals the in-memory volume.
    # With labels: the axis asked for, so the labels and fractions are the
    # in-memory ones byte for byte (fractions are sampled across the rays).
    axis = o.axis if stage is not None else 1 if several else 2
    # Vote casts z itself; exact colour needs no rays.
    reuse_z = colour == Colour.FAST and several and method != Inside.VOTE and axis != 2
    # RAW colours go into their file chunk by chunk as they are made (from the
    # colour step's threads): no slab of colours is held or copied. Not where
    # the OS has no positional write (os.pwrite: Windows).
    colour_sink = (f.can.colour_chunks and colour == Colour.FAST and several
                   and hasattr(os, "pwrite") and route == Route.SLABS)
    # Exact colour: a slab is written on a thread while the next one is
    # computed (the kernel runs without the GIL), as the fast colour's chunks
    # are; two occupancy buffers take turns.
    write_behind = several and not f.can.chunk and colour == Colour.EXACT and route == Route.SLABS
    reuse_buffers = several and not f.can.chunk and route == Route.SLABS
    return Plan(inside=method, axis=axis, route=route, blocks=tuple(blocks), per_voxel=per,
                budget=budget, reuse_z=reuse_z, chunk_slab=thick, colour_sink=colour_sink,
                write_behind=write_behind, reuse_buffers=reuse_buffers, **base)


def _chunk_thick(f, grid: Grid, per: float, blocks: list, how: _Request) -> int:
    """A chunked format's slab thickness: asked for, a cluster's, or the budget's in whole chunks."""
    from .formats.zarr import check_thick

    slab = how.slab
    if slab is None:
        # Here: the budget's slabs in whole chunks, at most LOCAL_ZARR_SLAB;
        # on a cluster: cluster_thick.
        chunk = f.can.chunk
        slab = cluster_thick(grid, per) if how.cluster else \
            min(LOCAL_ZARR_SLAB, -(-(blocks[0][1] - blocks[0][0]) // chunk) * chunk)
    return check_thick(slab)


__all__ = ["LOCAL_ZARR_SLAB", "POINTS_SLAB_BUDGET", "Plan", "Route", "SLAB_BUDGET",
           "WHOLE_STREAM_VOXELS", "WORKER_SLAB_BUDGET", "as_options", "cluster_thick", "grid_of",
           "load", "plan", "slab_budget", "slab_plan", "streams", "streams_whole"]
