"""The pipeline: options -> plan -> blocks, and the Volume a block makes.

Every conversion is a plan and then a run. :func:`plan` takes every
decision once -- the grid, the backend, the inside test, the colour method,
the memory budget, the route (in memory, slabs, the 64-slice occupancy fill,
cluster tasks) and the writer from the format registry -- and
:func:`voxelize_block` runs the stages (rays, fill, colour, density,
distance) on one block of the plan's grid: the whole grid, or a slab of it
along z. :func:`voxelize` is load + plan + one block; the slab streamer
(:mod:`geovox.stream`) runs one block per slab, here or as cluster tasks.
Rays always start outside the whole mesh, never at the block's edge, so a
block's voxels are classified exactly as the full grid's would be.
"""

from __future__ import annotations

import dataclasses
import enum
import time
from dataclasses import dataclass, fields

import numpy as np

from . import parity
from .errors import ParameterError, warn
from .grid import Grid, make_grid
from .kernels import chosen, follows_plan
from .memory import bytes_per_voxel, check_memory
from .options import Colour, Inside, Options, colour_of
from .volume import Progress, Report, Volume


class Route(enum.StrEnum):
    """How a plan's blocks are run and written."""

    MEMORY = "memory"  #: one block, the whole grid, held in memory (then written whole)
    SLABS = "slabs"  #: blocks along z, each written into the file before the next is made
    FILL = "64-slice fill"  #: occupancy alone: rays once, parity filled and written 64 slices at a time
    CLUSTER = "cluster"  #: ``.zarr`` slabs as tasks on a Dask cluster's workers


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
    inside : Inside
        The inside test that runs (``auto`` resolved).
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
        Output file or folder.
    reuse_z : bool
        Fast colour over several slabs: the rays along z are cast once for
        the whole grid and each slab takes its part (see :mod:`geovox.stream`).
    chunk_slab : int or None
        ``.zarr``: the slab thickness its shards are laid out for (a
        multiple of 64; the last block may be thinner).
    mesh_space : (str, str) or None
        With ``like``: the mesh's frame and how it was decided (see
        :func:`geovox.reference.resolve_mesh_space`).
    labels : geovox.labels.LabelSet or None
        With ``labels``: what each label is (by parts, ``inside`` is the
        test asked for, which each part resolves for itself).
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
        from dataclasses import replace

        return replace(self, jobs=1, format=None, path=None)

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
        lines = [f"plan: backend {self.backend.name}, inside test {self.inside}, "
                 f"colour {self.colour or 'none'}"
                 + (f", density {o.density} ({o.density_dtype})" if o.density else "")
                 + (f", sdf (band {float(o.band):g} voxels)" if o.sdf else "")
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
        return loader.load_mesh(mesh, references=options.references)


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


def plan(mesh, options=None, path=None, *, fmt=None, stream=None, cluster=False, budget=None,
         slab=None, grid=None) -> Plan:
    """Take every decision of one conversion once.

    Parameters
    ----------
    mesh : geovox.mesh.Mesh
        The loaded model (anything :func:`geovox.io.load.load_mesh` reads is loaded first).
    options : Options or dict, optional
        What to make (a dict is checked by :meth:`Options.from_kwargs`).
    path : str, optional
        The output: its format comes from the extension (or ``fmt``).
        Without it the plan is in memory.
    fmt : str, optional
        Format name, overriding the extension.
    stream : bool, optional
        True: slab by slab whatever the size (:func:`geovox.convert_to`);
        False: in memory; None: the rule of :func:`geovox.stream.streams`
        (the command line and batches).
    cluster : bool
        The slabs run as tasks on a cluster (``.zarr`` only).
    budget : float, optional
        Bytes one slab's arrays may take (default: :func:`geovox.stream.slab_budget`).
    slab : int, optional
        ``.zarr`` only: slab thickness, a multiple of 64.
    grid : Grid, optional
        The grid :func:`grid_of` already made for this mesh, options and
        format (a batch names its file after the grid's shape before it
        plans); without it, or with ``like``, the plan makes its own.

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
        return _plan(mesh, o, path, fmt, stream, cluster, budget, slab, grid)


def _plan(mesh, o: Options, path, fmt, stream, cluster, budget, slab, grid=None) -> Plan:
    """:func:`plan`, with ``o`` validated."""
    from . import inside as inside_tests
    from .backends import get_backend
    from .parallel import resolve_jobs

    engine = get_backend(o.backend) if isinstance(o.backend, str) else o.backend
    m = load(mesh, o)
    f = None
    if path is not None:
        from . import formats

        f = formats.format_for(path, fmt)
    m, grid, used = _mesh_and_grid(m, o, f, grid)
    colour = colour_of(o.color)
    base = dict(options=o, grid=grid, backend=engine, colour=colour, jobs=resolve_jobs(o.jobs),
                format=f, path=None if path is None else str(path), mesh_space=used)
    lset = _label_set(m, o, f)
    extra = 0.0  # the labels' and fractions' bytes per voxel
    if lset is not None:
        from .labels import working_bytes

        base["labels"] = lset
        extra = working_bytes(lset, o)
        if f is None or f.slab_writer is None:
            stream = False  # the format is written whole
    if stream is None:
        from .stream import streams

        stream = f is not None and streams(grid, f, o, extra=extra)
    if not stream or f is None:
        # By parts, each part takes its own inside test (geovox.labels.classify).
        method = (Inside(o.inside) if lset is not None and lset.source != "material"
                  else Inside(inside_tests.choose(m, o.inside)))
        p = Plan(inside=method, axis=o.axis, route=Route.MEMORY, blocks=((0, grid.shape[2]),),
                 per_voxel=bytes_per_voxel(o) + extra, **base)
    else:
        p = _streamed_plan(m, base, cluster=cluster, budget=budget, slab=slab, extra=extra)
    # With `like`, the mesh the blocks run on is the moved one (see Plan.mesh_for).
    object.__setattr__(p, "_mesh", m if used is not None else None)
    return p


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


def _label_set(m, o: Options, f):
    """The labels ``o.labels`` asks for (None without), checked against the format."""
    if o.labels is None:
        return None
    from . import labels as label_mod

    if f is not None:
        from . import formats

        formats.check_labels(True, f)
    # The overlap rule travels with the labels (geovox.labels.paint_order reads it).
    lset = dataclasses.replace(label_mod.label_set(m, o.labels), overlap=o.overlap)
    if lset.source == "material":
        return lset
    import warnings

    from . import inside as inside_tests

    methods = []
    for part in label_mod.part_meshes(m, lset):
        with warnings.catch_warnings():
            # A part's repair is its own business; the whole mesh's is said once.
            warnings.simplefilter("ignore")
            methods.append("parity" if part is None else inside_tests.choose(part, o.inside))
    return dataclasses.replace(lset, methods=tuple(methods))


def _streamed_plan(m, base: dict, *, cluster, budget, slab, extra=0.0) -> Plan:
    """The slab routes' part of :func:`plan`: blocks within the budget, the route, the axis.

    ``extra``: the labels' and fractions' bytes per voxel, counted in the budget.
    """
    from . import inside as inside_tests
    from .memory import check_memory as fits
    from .stream import LOCAL_ZARR_SLAB, cluster_thick, slab_budget, slab_plan

    o, grid, colour, f = base["options"], base["grid"], base["colour"], base["format"]
    lset = base.get("labels")
    by_parts = lset is not None and lset.source != "material"
    if by_parts:
        # Each part takes its own inside test (as in memory); the budget counts
        # the winding number's arrays wherever a part may need them.
        method = Inside(o.inside)
        working = 15.0 if len(inside_tests.boundary_edges(m)) else 2.0
    else:
        method = Inside(inside_tests.choose(m, o.inside))
        working = inside_tests.working_bytes(m, method)
    per = bytes_per_voxel(o) + working + extra
    budget = slab_budget() if budget is None else budget
    blocks = slab_plan(grid, per, budget)
    nx, ny, nz = grid.shape
    thick = None
    if f.name == "zarr":
        from .formats.zarr import check_thick

        if slab is None:
            # Here: the budget's slabs in whole chunks, at most LOCAL_ZARR_SLAB;
            # on a cluster: cluster_thick.
            slab = cluster_thick(grid, per) if cluster else \
                min(LOCAL_ZARR_SLAB, -(-(blocks[0][1] - blocks[0][0]) // 64) * 64)
        thick = check_thick(slab)
        blocks = [(z, min(z + thick, nz)) for z in range(0, nz, thick)]
    z0, z1 = blocks[0]
    try:
        fits(Grid(grid.lo, grid.hi, (nx, ny, z1 - z0)), per)
    except MemoryError:
        from .errors import GridTooLargeError

        raise GridTooLargeError(
            f"a {nx} x {ny} x {nz} grid does not fit in memory even slab by slab "
            f"({z1 - z0}-voxel slabs need {nx * ny * (z1 - z0) * per / 2**30:.1f} GiB); "
            f"use a smaller resolution") from None
    if cluster:
        route = Route.CLUSTER
    elif (f.name != "zarr" and len(blocks) == 1 and method == Inside.PARITY
          and not (colour or o.density or o.sdf or lset is not None)):
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
    axis = o.axis if lset is not None else 1 if len(blocks) > 1 else 2
    # Vote casts z itself; exact colour needs no rays.
    reuse_z = (colour == Colour.FAST and len(blocks) > 1 and method != Inside.VOTE
               and axis != 2)
    return Plan(inside=method, axis=axis, route=route, blocks=tuple(blocks), per_voxel=per,
                budget=budget, reuse_z=reuse_z, chunk_slab=thick, **base)


@follows_plan
def run(mesh, p: Plan, *, progress=None, client=None, write_options=None) -> Report:
    """Run plan ``p`` on ``mesh`` (the loaded Mesh it was made for): one Report.

    In memory: one block, written whole where the plan has a path; any other
    route runs slab by slab (:func:`geovox.stream.run_slabs`).
    """
    mesh = p.mesh_for(mesh)
    if p.route != Route.MEMORY:
        from .stream import run_slabs

        return run_slabs(mesh, p, progress=progress, client=client)
    vol = voxelize_block(mesh, p, buffers={"progress": progress})
    vol.mesh_space = p.mesh_space
    if not vol.occupancy.any():
        warn(empty_reason(mesh, p.grid, vol.inside), stacklevel=3)
    files, t = [], vol.timings
    if p.path is not None:
        from . import formats

        tw = time.perf_counter()
        files = formats.write(vol, p.path, fmt=p.format.name, **(write_options or {}))
        t["write"] = time.perf_counter() - tw
    lines = [] if vol.label_table is None else label_lines(p, vol.label_table, vol.contested)
    return Report(source=mesh.source, grid=p.grid, backend=p.backend.name,
                  inside_test=vol.inside, inside=vol.inside_count, route=str(p.route),
                  slabs=1, volume=vol, files=files, timings=t, mesh_space=p.mesh_space,
                  lines=lines, approximate=vol.approximate)


def label_lines(p: Plan, table: list, contested: int) -> list:
    """The summary's line on the labels made (the table, the contested voxels)."""
    return [f"labels {p.options.labels}: {len(table) - 1:,} "
            f"({', '.join(e['name'] for e in table[1:][:6])}"
            f"{', ...' if len(table) > 7 else ''}), "
            f"{contested:,} contested voxels (overlap rule {p.options.overlap})"]


def voxelize(
    mesh,
    resolution=None,
    bounds=None,
    backend="auto",
    *,
    shape=None,
    voxel_size=None,
    fit=None,
    axis=2,
    color=False,
    diffuse=True,
    ambient=False,
    jobs=None,
    inside="auto",
    density=None,
    supersample=4,
    density_dtype="uint8",
    sdf=False,
    band=3.0,
    kernel=None,
    references="anywhere",
    labels=None,
    overlap="last",
    fractions=False,
    like=None,
    mesh_space=None,
    progress=None,
) -> Volume:
    """Turn a closed triangle mesh into a solid voxel volume.

    Each voxel centre is classified by casting one ray per voxel column
    along ``axis`` from outside the whole mesh and counting crossings
    (odd = inside). Every option is a field of :class:`geovox.Options` (a
    test checks that this signature matches it).

    Parameters
    ----------
    mesh : str, os.PathLike, trimesh.Trimesh, trimesh.Scene or geovox.mesh.Mesh
        The model; files are read with trimesh (OBJ, STL, PLY, GLB, ...).
    resolution : int, optional
        Voxels on every axis (default 128 when neither ``shape`` nor
        ``voxel_size`` is given).
    bounds : sequence of 6 float, optional
        Region ``(xmin, ymin, zmin, xmax, ymax, zmax)``; default: the mesh's
        bounding box. The region may cut through the mesh.
    backend : {"auto", "numpy", "embree", "webgpu"}
        Ray-casting engine; ``"auto"`` is NumPy, measured the faster one for
        column rays (see :mod:`geovox.backends`); all give the same volume.
        ``"webgpu"`` (the ``gpu`` extra) is used only when named.
    shape : (3,) int, optional
        Voxels along x, y, z (instead of ``resolution``).
    voxel_size : float, optional
        Cubic voxel edge (instead of ``resolution``); the region grows
        symmetrically to a whole number of voxels.
    fit : {None, "box", "cube", "cube-center"}
        How ``resolution`` covers the region: ``"box"`` (the default, also
        for None) N voxels on each axis of the box; ``"cube"`` an N³ cube of
        cubic voxels whose edge is the box's longest side, at its minimum
        corner (binvox's ``-d N``); ``"cube-center"`` that cube centred on the
        box (binvox's ``-cb``).
    axis : {0, 1, 2}
        Direction of the column rays (default z; slab-by-slab conversions
        use y, see :mod:`geovox.stream`). Occupancy is the same up to ties on
        the surface; coverage density, sampled across the rays, can differ
        by a step or so where the surface is steep.
    color : bool, "exact" or "fast"
        Also fill ``Volume.colors`` from the model's materials, textures or
        vertex colours (see :mod:`geovox.colour` for the exact rule): True
        or ``"exact"`` takes every voxel's colour from its exact nearest
        surface point; ``"fast"`` from the nearest of the six axis
        crossings around it (a nearby surface point, not always the
        nearest).
    diffuse : bool
        Multiply by the material's ``Kd`` (MTL semantics for ``map_Kd``).
    ambient : bool
        Add the material's ``Ka``.
    jobs : int, optional
        Threads for the array work (default: one per core). The result is
        the same for any number of jobs.
    inside : {"auto", "parity", "vote", "winding"}
        Inside/outside test (see :mod:`geovox.inside`): ``auto`` is parity
        for closed meshes and the winding number otherwise, with a warning.
    density : {None, "coverage"}
        Also fill ``Volume.density`` with each voxel's inside fraction, from
        ``supersample`` x ``supersample`` rays per column (see
        :mod:`geovox.density`).
    supersample : int
        Rays per voxel column across the ray direction, per axis.
    density_dtype : {"uint8", "float32"}
        uint8 stores ``round(255 * fraction)``.
    sdf : bool
        Also fill ``Volume.sdf`` (float32, negative inside).
    band : float
        Half-width in voxels of the exact band of the signed distance.
    kernel : {None, "auto", "compiled", "numpy"}
        Exact colour's nearest-surface search; None reads ``GEOVOX_KERNEL``
        (default ``auto``: the compiled kernel where it was built).
    references : {"anywhere", "folder"}
        Where the files a model file names (materials, textures, buffers)
        may be read from: anywhere (``../textures/x.png`` included), or only
        under the model's own folder, for files you did not make (see
        :mod:`geovox.io.references`). URLs are never fetched.
    labels : {None, "part", "component", "material", "file"}
        Also fill ``Volume.labels`` and ``Volume.label_table`` (see
        :mod:`geovox.labels`): the model's own parts (OBJ objects or groups,
        scene nodes), its connected components, the material of each
        voxel's exact nearest surface point, or the file each part came
        from (``mesh`` a list of files, one scene on one grid). With parts,
        ``occupancy`` is the union of the parts, each by its own inside test.
    overlap : {"last", "first", "smallest"}
        Which part a voxel inside several takes: the later in file order,
        the earlier, or the one with the smaller enclosed volume.
    fractions : bool
        Also fill ``Volume.fractions`` (nx, ny, nz, L): each label's coverage
        fraction per voxel from ``supersample`` x ``supersample`` rays per
        column, overlaps settled by ``overlap`` (see
        :func:`geovox.labels.label_fractions`); uint8 0-255, or float32
        with ``density_dtype="float32"``. Not with ``labels="material"``.
    like : path, geovox.reference.Reference or (affine, shape), optional
        Voxelise onto this reference grid (a NIfTI, NRRD or MetaImage scan,
        a volume geovox wrote, or a 4 x 4 index-to-world affine and a shape),
        oblique or not, instead of a grid over the mesh; excludes
        ``resolution``, ``bounds``, ``shape`` and ``voxel_size``. See
        :mod:`geovox.reference`.
    mesh_space : {"lps", "ras"}, optional
        With ``like``: the mesh's frame, overriding its file's 3D Slicer
        ``SPACE=`` mark (LPS where there is none).
    progress : callable, optional
        ``progress(event)`` with a :class:`geovox.volume.Progress` as each
        stage starts (``event.stage``: "load", "rays", "colour", "density",
        "sdf").

    Returns
    -------
    Volume
        ``occupancy`` an ``(nx, ny, nz)`` bool array indexed ``[x, y, z]``
        (Fortran order); ``colors`` ``(nx, ny, nz, 4)`` uint8 RGBA (alpha 255
        inside, 0 outside), ``density`` ``(nx, ny, nz)`` uint8 or float32 and
        ``sdf`` ``(nx, ny, nz)`` float32 where asked for, else None; the
        ``grid``, the ``backend`` and ``inside`` test that ran,
        ``timings`` in seconds per stage, and ``approximate``, the voxels
        left to an estimate of the winding number (its work budget ran
        out; 0 nearly always).

    Raises
    ------
    InputNotFoundError
        ``mesh`` is a path that does not exist.
    MeshError
        The file cannot be read as a triangle mesh (the message says why).
    ParameterError
        A bad value: ``resolution``, ``shape`` or ``voxel_size`` not
        positive (or more than one given), ``bounds`` with min >= max,
        ``axis``, ``backend``, ``inside``, ``color``, ``density``,
        ``supersample``, ``density_dtype``, ``band`` or ``kernel``.
    BackendUnavailableError
        The named backend cannot run here (its package or a driver is
        missing); the message says what to install.
    GridTooLargeError
        The arrays would not fit in the available memory (raised before
        anything is allocated, with the size needed).
    """
    t0 = time.perf_counter()
    given = dict(locals())
    options = Options.from_kwargs(**{k: given[k] for k in Options.names()
                                     if k in given and not (k == "kernel" and kernel is None)})
    if progress:
        progress(Progress("load"))
    m = load(mesh, options)
    t_load = time.perf_counter()
    vol = run(m, plan(m, options), progress=progress).volume
    vol.timings = {"load": t_load - t0, **vol.timings, "total": time.perf_counter() - t0}
    return vol


def block_grid(grid: Grid, block=None) -> Grid:
    """The sub-grid of ``grid`` that a block covers.

    Parameters
    ----------
    grid : Grid
        The whole grid.
    block : (z0, z1) int, optional
        Voxel layers ``z0 <= k < z1`` along z; None for the whole grid.

    Returns
    -------
    Grid
        ``(nx, ny, z1 - z0)`` voxels with the whole grid's spacing, its last
        block ending exactly at ``grid.hi``.
    """
    if block is None:
        return grid
    z0, z1 = (int(z) for z in block)
    nx, ny, nz = grid.shape
    if not 0 <= z0 < z1 <= nz:
        raise ParameterError(f"a block must be layers z0..z1 with 0 <= z0 < z1 <= {nz}, "
                             f"got {block!r}")
    if (z0, z1) == (0, nz):
        return grid
    h = grid.spacing
    lo = grid.lo.copy()
    lo[2] = grid.lo[2] + z0 * h[2]
    hi = grid.hi.copy()
    hi[2] = grid.lo[2] + z1 * h[2] if z1 < nz else grid.hi[2]
    return Grid(lo=lo, hi=hi, shape=(nx, ny, z1 - z0), reference=grid.reference)


def ray_start(mesh, grid: Grid, axis: int) -> float:
    """Where the column rays along ``axis`` start: outside the whole mesh and the grid.

    A block's rays start where the whole grid's would (not at the block's
    low face), so every crossing below the block is counted and the block's
    parity is the full grid's.
    """
    return min(float(mesh.bounds[0, axis]), float(grid.lo[axis])) - 1e-3 * mesh.scale


@follows_plan
def voxelize_block(mesh, plan: Plan, block=None, *, buffers=None) -> Volume:
    """Voxelise one block of the plan's grid -- the whole grid or a slab along z -- with every option.

    The one place the stages (rays, fill, colour, density, distance) are
    run: :func:`voxelize` calls it once for the whole grid, slab-by-slab
    conversions once per slab, cluster tasks once per task. A block is
    classified exactly as the whole grid would be: its rays start outside
    the whole mesh (see :func:`ray_start`).

    Parameters
    ----------
    mesh : geovox.mesh.Mesh
        The loaded model (anything :func:`geovox.io.load.load_mesh` reads is
        loaded first, once per call).
    plan : Plan
        What to make (:func:`plan`): the grid, backend, inside test, colour
        method, ray axis, threads and every option.
    block : (z0, z1) int, optional
        Voxel layers ``z0 <= k < z1`` to make (see :func:`block_grid`);
        default the whole grid.
    buffers : dict, optional
        Working arrays and hand-offs of a caller that makes many blocks:

        ``out`` : (nx, ny, nz_block) bool, Fortran order
            Array the parity fill writes the occupancy into (reused, so its
            memory is not faulted in afresh for every block).
        ``colour_out`` : (nz_block, ny, nx, 4) uint8, C order
            The same for fast colour (see :func:`geovox.colour.colour_volume`).
        ``colour_sink`` : callable
            Fast colour: ``sink(z0, rgba)`` is handed the colours chunk by
            chunk (layers from the block's first) instead of the volume
            holding them (``colors`` is then None).
        ``crossings`` : dict
            ``axis -> f(block_grid) -> (Hits, Columns)``: the colour step's
            crossings along that axis, cast once for the whole grid by the
            caller instead of again for every block.
        ``slices`` : callable
            The 64-slice occupancy fill (:attr:`Route.FILL`: parity, rays
            along z, occupancy alone): ``slices(z0, occ)`` is handed each
            64-layer piece of the occupancy as it is filled, in order, in
            one of two buffers taken in turn (a piece's buffer is filled
            again only after the next call returns); ``occupancy`` is then
            None, and no block-sized array is ever allocated.
        ``progress`` : callable
            ``progress(Progress(stage))`` as each stage starts.

    Returns
    -------
    Volume
        Over the block's sub-grid: ``occupancy`` (nx, ny, nz_block) bool,
        Fortran order, and ``colors`` / ``density`` / ``sdf`` as asked for.
        ``timings`` holds "rays", "fill", then "colour", "density", "sdf" as
        run (seconds); no "total". ``approximate``: the block's voxels left to
        an estimate of the winding number.

    Raises
    ------
    ParameterError
        A bad block.
    GridTooLargeError
        The block's arrays would not fit in the available memory.
    """
    t0 = time.perf_counter()
    buffers = buffers or {}
    m = load(mesh, plan.options)
    o = plan.options
    progress = buffers.get("progress")

    def step(stage):
        if progress:
            progress(Progress(stage))

    grid = block_grid(plan.grid, block)
    if "slices" not in buffers:
        extra = 0.0
        if plan.labels is not None:
            from .labels import working_bytes

            extra = working_bytes(plan.labels, o)
        check_memory(grid, bytes_per_voxel(o) + extra)
    textures = None
    if plan.colour:
        from .colour import prefetch_textures

        textures = prefetch_textures(m)  # decoded while the rays and the fill run
    step("rays")
    crossings = {}
    classified = None
    method = plan.inside.value
    approximate = 0
    if "slices" in buffers:
        occ, t_rays = _fill_in_slices(m, plan, grid, buffers["slices"])
    elif plan.labels is not None and plan.labels.source != "material":
        from .labels import classify

        # By parts: each part's own inside test, overlaps settled by the rule.
        classified = classify(m, grid, plan.labels, axis=plan.axis, jobs=plan.jobs,
                              cast_mesh=lambda mesh, ax, on=grid: _cast(mesh, plan, on, ax),
                              within=None if block is None else (plan.grid, block))
        if classified.crossings is not None:
            crossings[plan.axis] = classified.crossings
        t_rays = time.perf_counter()
        occ = np.asfortranarray(classified.labels != 0)
        method = "+".join(sorted(set(classified.methods)))
        approximate = classified.approximate
    else:
        occ, t_rays, approximate = _fill(m, plan, grid, crossings, buffers.get("out"))
    t_fill = time.perf_counter()
    # The checks and the inside test's choice count with the rays.
    timings = {"rays": t_rays - t0, "fill": t_fill - t_rays}
    colors = dens = dist = None
    if plan.colour:
        step("colour")
        if textures is not None:
            textures()
        colors = _colour(m, plan, grid, block, occ, crossings, buffers)
        timings["colour"] = time.perf_counter() - t_fill
    if o.density == "coverage":
        step("density")
        t = time.perf_counter()
        dens = _density(m, plan, grid, winding=_density_method(m, o, method, classified)
                        == "winding")
        timings["density"] = time.perf_counter() - t
    if o.sdf:
        from .density import signed_distance

        step("sdf")
        t = time.perf_counter()
        dist = signed_distance(m, grid, occ, band=float(o.band), jobs=plan.jobs)
        timings["sdf"] = time.perf_counter() - t
    extra = {} if plan.labels is None else _labels(m, plan, grid, block, occ, classified, step,
                                                   timings)
    return Volume(occupancy=occ, grid=grid, backend=plan.backend.name, source=m.source,
                  colors=colors, timings=timings, inside=method, density=dens, sdf=dist,
                  approximate=approximate, **extra)


@follows_plan  # also on the colour step's threads
def _cast(mesh, plan: Plan, grid: Grid, ax: int):
    """``(Hits, Columns)`` of the block ``grid``'s column rays along ``ax`` through ``mesh``."""
    columns = grid.columns(ax, start=ray_start(mesh, grid, ax))
    return plan.backend.cast(mesh, columns, jobs=plan.jobs), columns


def _fill(m, plan: Plan, grid: Grid, crossings: dict, out=None):
    """``(occupancy, time the rays ended, approximate voxels)`` by the plan's inside test; fills ``crossings``."""
    axis, jobs = plan.axis, plan.jobs
    if plan.inside == Inside.PARITY:
        crossings[axis] = _cast(m, plan, grid, axis)
        t_rays = time.perf_counter()
        return parity.fill(*crossings[axis], grid, out=out, jobs=jobs), t_rays, 0
    if plan.inside == Inside.VOTE:
        votes = None
        for ax in (axis,) + tuple(a for a in range(3) if a != axis):
            crossings[ax] = _cast(m, plan, grid, ax)
            one = parity.fill(*crossings[ax], grid, jobs=jobs).view(np.uint8)
            votes = one if votes is None else np.add(votes, one, out=votes)
        t_rays = time.perf_counter()  # the three fills are counted with the rays
        return np.asfortranarray(votes >= 2), t_rays, 0
    from . import inside as inside_tests

    # The winding fill is counted with the rays.
    occ, hits, columns, approximate = inside_tests.winding_occupancy(
        m, grid, lambda mesh, ax: _cast(mesh, plan, grid, ax), axis, jobs)
    crossings[axis] = (hits, columns)
    return occ, time.perf_counter(), approximate


def _fill_in_slices(m, plan: Plan, grid: Grid, sink):
    """The 64-slice occupancy fill: rays along z once, each piece handed to ``sink(z0, occ)``."""
    hits, columns = _cast(m, plan, grid, 2)
    t_rays = time.perf_counter()
    for z0, occ in parity.fill_slabs(hits, columns, grid, thick=64, buffers=2):
        sink(z0, occ)
    return None, t_rays


def _colour(m, plan: Plan, grid: Grid, block, occ, crossings: dict, buffers: dict):
    """The block's colours (see :func:`geovox.colour.colour_volume`)."""
    from .colour import Shading, colour_volume

    o = plan.options
    for a, crossings_of in (buffers.get("crossings") or {}).items():
        if a not in crossings:
            crossings[a] = crossings_of(grid)
    exact = plan.colour == Colour.EXACT
    # Exact colour needs no crossings at all.
    others = [a for a in range(3) if a not in crossings and not exact]
    if plan.jobs > 1 and len(others) > 1:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=2) as pool:
            for a, result in zip(others, pool.map(lambda a: _cast(m, plan, grid, a), others)):
                crossings[a] = result
    else:
        for a in others:
            crossings[a] = _cast(m, plan, grid, a)
    return colour_volume(m, grid, occ, crossings, shading=Shading.of(o), jobs=plan.jobs,
                         exact=exact,
                         frame=(plan.grid.lo, plan.grid.spacing, 0 if block is None else block[0]),
                         out=buffers.get("colour_out"),
                         sink=None if exact else buffers.get("colour_sink"))


def _labels(m, plan: Plan, grid: Grid, block, occ, classified, step, timings) -> dict:
    """``labels``, ``label_table``, ``contested`` and ``fractions`` of the block (geovox.labels)."""
    from .labels import label_results

    o = plan.options
    return label_results(
        m, grid, occ, plan.labels, classified, engine=plan.backend, axis=plan.axis,
        jobs=plan.jobs, fractions=o.fractions, density_dtype=o.density_dtype,
        supersample=int(o.supersample),
        frame=(plan.grid.lo, plan.grid.spacing, 0 if block is None else block[0]),
        start=ray_start(m, plan.grid if plan.axis == 2 else grid, plan.axis), timings=timings,
        step=step, within=None if block is None else (plan.grid, block))


def _density_method(m, o: Options, method: str, classified) -> str:
    """The inside test density's coverage follows: the occupancy's, or with labels by part
    the whole mesh's own (what it is without labels), so density is the same bytes with
    and without labels; the per-part shares are ``fractions``."""
    if classified is None:
        return method
    from . import inside as inside_tests
    from .errors import collect_warnings

    with collect_warnings(drop=True):  # the parts' inside tests said what they repaired
        return inside_tests.choose(m, o.inside)


def _density(m, plan: Plan, grid: Grid, winding: bool):
    """Coverage density of the block (see :mod:`geovox.density`)."""
    from . import inside as inside_tests
    from .density import coverage, sub_columns

    o, axis = plan.options, plan.axis
    target = inside_tests.capped(inside_tests.target(m)[0])[0] if winding else m
    k = int(o.supersample)
    sub = sub_columns(grid.columns(axis, start=ray_start(target, grid, axis)), k)
    sub_hits = plan.backend.cast(target, sub, jobs=plan.jobs)
    # The occupancy's rule: the winding number's, not parity (inside_tests.crossing_signs).
    sign = inside_tests.crossing_signs(target, sub_hits, axis) if winding else None
    frac = coverage(sub_hits, sub, grid, k, plan.jobs, sign=sign)
    if o.density_dtype == "uint8":
        return np.asfortranarray(np.rint(frac * np.float32(255.0)).astype(np.uint8))
    return frac


def empty_reason(m, grid: Grid, method: str) -> str:
    """Why no voxel came out inside, for the warning that an empty volume always carries.

    Parameters
    ----------
    m : geovox.mesh.Mesh
    grid : Grid
    method : str
        The inside test that ran.
    """
    def fmt(v):
        return "(" + ", ".join(f"{x:.6g}" for x in v) + ")"

    if not _overlaps(m.bounds, grid) and grid.reference is not None:
        return (f"{m.source}: the mesh lies entirely outside the field of view of "
                f"{grid.reference.source}; the volume is empty (is the mesh in the image's "
                f"frame? see --mesh-space)")
    if not _overlaps(m.bounds, grid):
        return (f"the region {fmt(grid.lo)}..{fmt(grid.hi)} misses the mesh "
                f"{fmt(m.bounds[0])}..{fmt(m.bounds[1])}; the volume is empty")
    extent = m.bounds[1] - m.bounds[0]
    flat = [ax for ax, e in zip("xyz", extent) if e <= 1e-9 * m.scale]
    if flat:
        return (f"{m.source}: the volume is empty: the mesh is flat (no thickness along "
                f"{' and '.join(flat)}), so it encloses no volume")
    f = m.geometric_faces
    directed = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    directed = directed[directed[:, 0] != directed[:, 1]]
    edges = np.sort(directed, axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    n_open = int(np.count_nonzero(counts == 1))
    n_dup = len(f) - len(np.unique(np.sort(f, axis=1), axis=0))
    # Edges two faces run the same way: faces wound against their neighbours.
    _, same = np.unique(directed, axis=0, return_counts=True)
    n_same = int(np.count_nonzero(same > 1))
    region = ("" if np.all(grid.lo <= m.bounds[0]) and np.all(grid.hi >= m.bounds[1])
              else " of the region")
    thin = [ax for ax, e, h in zip("xyz", extent, grid.spacing) if e < h]
    if n_open and method != "parity":
        why = (f"the mesh is an open surface ({n_open:,} open edges) that encloses no volume "
               f"at any voxel centre{region}")
    elif n_dup:
        why = (f"no voxel centre{region} lies inside the mesh: {n_dup:,} of its {len(f):,} faces "
               f"repeat another face (a double-sided model), so each crossing counts twice and "
               f"cancels")
    elif n_same and method != "parity":
        why = (f"no voxel centre{region} lies inside the mesh by its winding number: its faces "
               f"are wound against each other ({n_same:,} edges run the same way in two faces), "
               f"so their solid angles cancel; try inside='parity' (--inside parity)")
    elif thin:
        why = (f"no voxel centre{region} lies inside the mesh, which is thinner than a voxel "
               f"along {' and '.join(thin)}; try a finer grid")
    else:
        why = (f"no voxel centre{region} lies inside the mesh with the {method} inside test "
               f"({'closed' if not n_open else f'{n_open:,} open edges'}); its solid parts may be "
               f"thinner than a voxel")
    return f"{m.source}: the volume is empty: {why}"


def _overlaps(box, grid) -> bool:
    """Whether the (2, 3) box ``box`` (a mesh's bounds) meets the grid's region."""
    return bool(np.all(box[0] <= grid.hi) and np.all(box[1] >= grid.lo))
