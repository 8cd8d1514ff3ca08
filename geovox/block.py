"""One unit of work: a block of the plan's grid, voxelised with every stage.

:func:`voxelize_block` runs the stages (rays, fill, colour, density,
distance, labels) on one block of the plan's grid: the whole grid, or a
slab of it along z. :func:`geovox.voxelize` runs it once; the slab runners
(:mod:`geovox.runners`) once per slab, here or as cluster tasks. Rays always
start outside the whole mesh, never at the block's edge (:func:`ray_start`),
so a block's voxels are classified exactly as the full grid's would be.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from . import parity
from .errors import ParameterError
from .grid import Grid
from .kernels import follows_plan
from .memory import bytes_per_voxel, check_memory
from .options import Colour, Inside, Occupancy, sdf_of
from .planner import Plan, load
from .volume import Progress, Volume


@dataclass
class BlockBuffers:
    """Working arrays and hand-offs of a caller that makes many blocks.

    Every field is optional; a block made alone needs none.

    Attributes
    ----------
    out : (nx, ny, nz_block) bool, Fortran order, or None
        Array the parity fill writes the occupancy into (reused, so its
        memory is not faulted in afresh for every block).
    colour_out : (nz_block, ny, nx, 4) uint8, C order, or None
        The same for the colours (see :func:`geovox.colour.colour_volume`).
    sdf_out : (nx * ny * nz_block,) float32, or None
        The same for the distance (see :func:`geovox.density.signed_distance`).
    colour_sink : callable or None
        Fast colour: ``sink(z0, rgba)`` is handed the colours chunk by chunk
        (layers from the block's first) instead of the volume holding them
        (``colors`` is then None).
    crossings : dict or None
        ``axis -> f(block_grid) -> (Hits, Columns)``: the colour step's
        crossings along that axis, cast once for the whole grid by the
        caller instead of again for every block.
    slices : callable or None
        The 64-slice occupancy fill (:attr:`Route.FILL <geovox.planner.Route.FILL>`:
        parity, rays along z, occupancy alone): ``slices(z0, occ)`` is
        handed each 64-layer piece of the occupancy as it is filled, in
        order, in one of two buffers taken in turn (a piece's buffer is
        filled again only after the next call returns); ``occupancy`` is
        then None, and no block-sized array is ever allocated.
    progress : callable or None
        ``progress(Progress(stage))`` as each stage starts.
    surface_out : (nx, ny, nz_block) bool, Fortran order, or None
        Array the surface voxels are made in (reused, as ``out``).
    points : callable or None
        Surface voxels alone into a point cloud (:attr:`Plan.surface_points
        <geovox.planner.Plan.surface_points>`): ``points(ijk)`` is handed the
        block's voxels as (m, 3) int32 indices in the grid's memory order
        (:func:`geovox.surface.surface_points`); ``occupancy`` is then None.
    words : (w,) uint64 or None
        With ``points``: the bits the block's voxels are made in (reused).
    point_values : three 1-D arrays or None
        With ``points``: per axis, a value for each index (the writer's
        centre coordinates): the voxels are handed over as those values
        (:func:`geovox.surface.surface_points`' ``values``), not as indices.
    """

    out: np.ndarray | None = None
    colour_out: np.ndarray | None = None
    sdf_out: np.ndarray | None = None
    colour_sink: object = None
    crossings: dict | None = None
    slices: object = None
    progress: object = None
    surface_out: np.ndarray | None = None
    points: object = None
    words: np.ndarray | None = None
    point_values: list | None = None

    def step(self, stage: str) -> None:
        """Say that ``stage`` starts (to :attr:`progress`, where there is one)."""
        if self.progress:
            self.progress(Progress(stage))


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
def voxelize_block(mesh, plan: Plan, block=None, *, buffers: BlockBuffers | None = None) -> Volume:
    """Voxelise one block of the plan's grid -- the whole grid or a slab along z -- with every option.

    The one place the stages (rays, fill, colour, density, distance, labels)
    are run: :func:`geovox.voxelize` calls it once for the whole grid,
    slab-by-slab conversions once per slab, cluster tasks once per task. A
    block is classified exactly as the whole grid would be: its rays start
    outside the whole mesh (see :func:`ray_start`).

    Parameters
    ----------
    mesh : geovox.mesh.Mesh
        The loaded model (anything :func:`geovox.io.load.load_mesh` reads is
        loaded first, once per call).
    plan : Plan
        What to make (:func:`geovox.planner.plan`): the grid, backend, inside
        test, colour method, stages, ray axis, threads and every option.
    block : (z0, z1) int, optional
        Voxel layers ``z0 <= k < z1`` to make (see :func:`block_grid`);
        default the whole grid.
    buffers : BlockBuffers, optional
        Working arrays and hand-offs of a caller that makes many blocks.

    Returns
    -------
    Volume
        Over the block's sub-grid: ``occupancy`` (nx, ny, nz_block) bool,
        Fortran order, and ``colors`` / ``density`` / ``sdf`` / ``labels``
        as asked for. ``timings`` holds "rays", "fill", then "colour",
        "density", "sdf" as run (seconds); no "total". ``approximate``: the
        block's voxels left to an estimate of the winding number.

    Raises
    ------
    ParameterError
        A bad block.
    GridTooLargeError
        The block's arrays would not fit in the available memory.
    """
    t0 = time.perf_counter()
    buffers = buffers or BlockBuffers()
    m = load(mesh, plan.options)
    o = plan.options
    grid = block_grid(plan.grid, block)
    if buffers.slices is None and buffers.points is None:  # points: a bit a voxel, planned so
        check_memory(grid, bytes_per_voxel(o) + (0.0 if plan.labels is None
                                                 else plan.labels.working_bytes()))
    textures = None
    if plan.colour:
        from .colour import prefetch_textures

        textures = prefetch_textures(m)  # decoded while the rays and the fill run
    buffers.step("rays")
    crossings = {}
    classified = None
    method = None if plan.inside is None else plan.inside.value
    approximate = 0
    counts = None
    if buffers.slices is not None:
        occ, t_rays = _fill_in_slices(m, plan, grid, buffers.slices)
    elif plan.labels is not None and plan.labels.by_parts:
        # By parts: each part's own inside test (and surface voxels), overlaps settled by the rule.
        classified = plan.labels.classify(
            m, grid, axis=plan.axis, jobs=plan.jobs,
            cast_mesh=lambda mesh, ax, on=grid: _cast(mesh, plan, on, ax),
            within=None if block is None else (plan.grid, block),
            surface=None if plan.occupancy == Occupancy.SOLID else
            (plan.occupancy, lambda part: _surface(part, plan, block)))
        if classified.crossings is not None:
            crossings[plan.axis] = classified.crossings
        t_rays = time.perf_counter()
        occ = np.asfortranarray(classified.labels != 0)
        method = "+".join(sorted(set(classified.methods)))
        approximate = classified.approximate
    elif plan.inside is not None:
        occ, t_rays, approximate = _fill(m, plan, grid, crossings, buffers.out)
    else:
        occ, t_rays = None, time.perf_counter()  # surface voxels alone: no solid
    t_fill = time.perf_counter()
    # The checks and the inside test's choice count with the rays.
    timings = {"rays": t_rays - t0, "fill": t_fill - t_rays}
    colors = dens = dist = None
    if plan.occupancy != Occupancy.SOLID:
        if o.sdf:  # the distance describes the solid: signed by it, before the surface joins
            dist, timings["sdf"] = _sdf(m, plan, grid, occ, block, buffers.sdf_out)
        occ, method, counts = _with_surface(m, plan, block, occ, method, classified, timings,
                                            buffers)
    if plan.colour:
        buffers.step("colour")
        if textures is not None:
            textures()
        colors = _colour(m, plan, grid, block, occ, crossings, buffers)
        timings["colour"] = time.perf_counter() - t_fill
    if o.density == "coverage":
        buffers.step("density")
        t = time.perf_counter()
        dens = _density(m, plan, grid, winding=plan.density_inside == Inside.WINDING)
        timings["density"] = time.perf_counter() - t
    if o.sdf and dist is None:
        buffers.step("sdf")
        dist, timings["sdf"] = _sdf(m, plan, grid, occ, block, buffers.sdf_out)
    extra = {}
    if plan.labels is not None:
        extra = plan.labels.fields(m, grid, occ, classified, run=_label_run(m, plan, grid, block),
                                   timings=timings, step=buffers.step)
    return Volume(occupancy=occ, grid=grid, backend=plan.backend.name, source=m.source,
                  colors=colors, timings=timings, inside=method, density=dens, sdf=dist,
                  band=float(o.band) if o.sdf else None, unsigned=sdf_of(o.sdf) == "unsigned",
                  approximate=approximate, counts=counts, **extra)


def _sdf(m, plan: Plan, grid: Grid, solid, block=None, out=None):
    """``(distance, seconds)`` of the block, signed by the solid ``solid`` (unless unsigned)."""
    from .density import signed_distance

    t = time.perf_counter()
    z0 = 0 if block is None else int(block[0])
    dist = signed_distance(m, grid, solid, band=float(plan.options.band), jobs=plan.jobs,
                           frame=(plan.grid.lo, plan.grid.spacing, z0),
                           signed=sdf_of(plan.options.sdf) == "signed", out=out)
    return dist, time.perf_counter() - t


def _surface(mesh, plan: Plan, block, out=None):
    """The block's surface voxels of ``mesh`` (the whole model, or one part of it)."""
    from .surface import surface_voxels

    return surface_voxels(mesh.vertices, plan.grid, block, faces=mesh.faces, jobs=plan.jobs,
                          bits=plan.surface_bits, out=out)


def _with_surface(m, plan: Plan, block, solid, method, classified, timings, buffers):
    """``(occupancy, what ran, counts)`` with the surface voxels: alone, or joined to the solid.

    By parts the labels' classification has joined each part's already.
    Into a point cloud (``buffers.points``) the voxels go to the writer as
    points (indices, or the writer's values), and the occupancy is None.
    """
    t = time.perf_counter()
    if buffers.points is not None:
        from .surface import surface_points

        points = surface_points(m.vertices, plan.grid, block, faces=m.faces, jobs=plan.jobs,
                                bits=plan.surface_bits, words=buffers.words,
                                values=buffers.point_values)
        timings["surface"] = time.perf_counter() - t
        buffers.points(points)
        return None, "surface", {"surface": len(points)}
    if classified is not None:
        occ = solid  # the parts' solids and surfaces, joined by classify
        surface = occ if plan.occupancy == Occupancy.SURFACE else _surface(m, plan, block)
        counts = {"surface": int(np.count_nonzero(surface))}
        if classified.inside is not None:
            counts["inside"] = classified.inside
    else:
        surface = occ = _surface(m, plan, block, buffers.surface_out)
        counts = {"surface": int(np.count_nonzero(surface))}
        if plan.occupancy == Occupancy.BOTH:
            counts["inside"] = int(np.count_nonzero(solid))
            occ = np.logical_or(solid, surface, out=solid)  # the solid is done with
    timings["surface"] = time.perf_counter() - t
    what = "surface" if not method else f"{method}+surface"
    return occ, what, counts


def _label_run(m, plan: Plan, grid: Grid, block):
    """What the labels stage needs of this block (:class:`geovox.labels.BlockRun`)."""
    from .labels import BlockRun

    return BlockRun(engine=plan.backend, axis=plan.axis, jobs=plan.jobs,
                    frame=(plan.grid.lo, plan.grid.spacing, 0 if block is None else block[0]),
                    start=ray_start(m, plan.grid if plan.axis == 2 else grid, plan.axis),
                    within=None if block is None else (plan.grid, block))


@follows_plan  # also on the colour step's threads
def _cast(mesh, plan: Plan, grid: Grid, ax: int):
    """``(Hits, Columns)`` of the block ``grid``'s column rays along ``ax`` through ``mesh``."""
    columns = grid.columns(ax, start=ray_start(mesh, grid, ax))
    return plan.backend.cast(mesh, columns, jobs=plan.jobs), columns


def cast_block(mesh, plan: Plan, grid: Grid, ax: int):
    """``(Hits, Columns)`` of ``grid``'s column rays along ``ax``, as a block casts them.

    The runners cast the whole grid's rays along z once with it, so each
    slab's share is what its own cast would have given.
    """
    return _cast(mesh, plan, grid, ax)


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
    from .inside import winding_occupancy

    # The winding fill is counted with the rays.
    occ, hits, columns, approximate = winding_occupancy(
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


def _colour(m, plan: Plan, grid: Grid, block, occ, crossings: dict, buffers: BlockBuffers):
    """The block's colours (see :func:`geovox.colour.colour_volume`)."""
    from .colour import Shading, colour_volume

    for a, crossings_of in (buffers.crossings or {}).items():
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
    return colour_volume(m, grid, occ, crossings, shading=Shading.of(plan.options),
                         jobs=plan.jobs, exact=exact,
                         frame=(plan.grid.lo, plan.grid.spacing, 0 if block is None else block[0]),
                         out=buffers.colour_out, sink=None if exact else buffers.colour_sink)


def _density(m, plan: Plan, grid: Grid, winding: bool):
    """Coverage density of the block (see :mod:`geovox.density`)."""
    from .density import coverage, sub_columns
    from .inside import capped, crossing_signs, target

    o, axis = plan.options, plan.axis
    target_mesh = capped(target(m)[0])[0] if winding else m
    k = int(o.supersample)
    sub = sub_columns(grid.columns(axis, start=ray_start(target_mesh, grid, axis)), k)
    sub_hits = plan.backend.cast(target_mesh, sub, jobs=plan.jobs)
    # The occupancy's rule: the winding number's, not parity (crossing_signs).
    sign = crossing_signs(target_mesh, sub_hits, axis) if winding else None
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

    if not overlaps(m.bounds, grid) and grid.reference is not None:
        return (f"{m.source}: the mesh lies entirely outside the field of view of "
                f"{grid.reference.source}; the volume is empty (is the mesh in the image's "
                f"frame? see --mesh-space)")
    if not overlaps(m.bounds, grid):
        return (f"the region {fmt(grid.lo)}..{fmt(grid.hi)} misses the mesh "
                f"{fmt(m.bounds[0])}..{fmt(m.bounds[1])}; the volume is empty")
    extent = m.bounds[1] - m.bounds[0]
    flat = [ax for ax, e in zip("xyz", extent) if e <= 1e-9 * m.scale]
    if flat:
        return (f"{m.source}: the volume is empty: the mesh is flat (no thickness along "
                f"{' and '.join(flat)}), so it encloses no volume")
    return f"{m.source}: the volume is empty: {_why_empty(m, grid, method, extent)}"


def _why_empty(m, grid: Grid, method: str, extent) -> str:
    """:func:`empty_reason` for a mesh that meets the grid and is not flat."""
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
    if n_open and method != Inside.PARITY:
        return (f"the mesh is an open surface ({n_open:,} open edges) that encloses no volume "
                f"at any voxel centre{region}")
    if n_dup:
        return (f"no voxel centre{region} lies inside the mesh: {n_dup:,} of its {len(f):,} faces "
                f"repeat another face (a double-sided model), so each crossing counts twice and "
                f"cancels")
    if n_same and method != Inside.PARITY:
        return (f"no voxel centre{region} lies inside the mesh by its winding number: its faces "
                f"are wound against each other ({n_same:,} edges run the same way in two faces), "
                f"so their solid angles cancel; try inside='parity' (--inside parity)")
    if thin:
        return (f"no voxel centre{region} lies inside the mesh, which is thinner than a voxel "
                f"along {' and '.join(thin)}; try a finer grid")
    return (f"no voxel centre{region} lies inside the mesh with the {method} inside test "
            f"({'closed' if not n_open else f'{n_open:,} open edges'}); its solid parts may be "
            f"thinner than a voxel")


def overlaps(box, grid) -> bool:
    """Whether the (2, 3) box ``box`` (a mesh's bounds) meets the grid's region."""
    return bool(np.all(box[0] <= grid.hi) and np.all(box[1] >= grid.lo))


__all__ = ["BlockBuffers", "block_grid", "cast_block", "empty_reason", "overlaps", "ray_start",
           "voxelize_block"]
