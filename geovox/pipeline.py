"""The pipeline: load -> grid -> rays -> parity fill, and the Volume it makes.

:func:`voxelize_block` runs the stages on one block of a grid (the whole grid,
or a slab of it along z) with every option; :func:`voxelize` is load + grid +
one block, and the slab streamer (:mod:`geovox.stream`) runs one block per
slab. Rays always start outside the whole mesh, never at the block's edge, so
a block's voxels are classified exactly as the full grid's would be.
"""

from __future__ import annotations

import time

import numpy as np

from . import parity
from .backends import get_backend
from .errors import ParameterError, warn
from .grid import Grid, make_grid
from .memory import bytes_per_voxel, check_memory
from .mesh import load_mesh
from .volume import Volume


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
    progress=None,
    like=None,
    mesh_space=None,
    labels=None,
    overlap="last",
    fractions=False,
    references="anywhere",
) -> Volume:
    """Turn a closed triangle mesh into a solid voxel volume.

    Each voxel centre is classified by casting one ray per voxel column
    along ``axis`` from outside the whole mesh and counting crossings
    (odd = inside).

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
    progress : callable, optional
        Called with the name of each stage as it starts ("load", "rays",
        "colour", "density", "sdf").
    like : path, geovox.reference.Reference or (affine, shape), optional
        Voxelise onto this reference grid (a NIfTI, NRRD or MetaImage scan,
        a volume geovox wrote, or a 4 x 4 index-to-world affine and a shape),
        oblique or not, instead of a grid over the mesh; excludes
        ``resolution``, ``bounds``, ``shape`` and ``voxel_size``. See
        :mod:`geovox.reference`.
    mesh_space : {"lps", "ras"}, optional
        With ``like``: the mesh's frame, overriding its file's 3D Slicer
        ``SPACE=`` mark (LPS where there is none).
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
    references : {"anywhere", "folder"}
        Where the files a model file names (materials, textures, buffers)
        may be read from: anywhere (``../textures/x.png`` included), or only
        under the model's own folder, for files you did not make (see
        :mod:`geovox.references`). URLs are never fetched.

    Returns
    -------
    Volume
        ``occupancy`` an ``(nx, ny, nz)`` bool array indexed ``[x, y, z]``
        (Fortran order); ``colors`` ``(nx, ny, nz, 4)`` uint8 RGBA (alpha 255
        inside, 0 outside), ``density`` ``(nx, ny, nz)`` uint8 or float32 and
        ``sdf`` ``(nx, ny, nz)`` float32 where asked for, else None; the
        ``grid``, the ``backend`` and ``inside`` test that ran, and
        ``timings`` in seconds per stage.

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
        ``supersample``, ``density_dtype`` or ``band``.
    BackendUnavailableError
        The named backend cannot run here (its package or a driver is
        missing); the message says what to install.
    GridTooLargeError
        The arrays would not fit in the available memory (raised before
        anything is allocated, with the size needed).
    """
    t0 = time.perf_counter()
    if axis not in (0, 1, 2):
        raise ParameterError(f"`axis` must be 0, 1 or 2, got {axis!r}")
    from .parallel import resolve_jobs

    jobs = resolve_jobs(jobs)
    from . import labels as label_mod

    label_mod.check(labels, overlap, fractions)
    (progress or (lambda stage: None))("load")
    engine = get_backend(backend)
    if isinstance(mesh, (list, tuple)):
        if labels is None:
            raise ParameterError("several meshes make one scene only with `labels` (e.g. "
                                 "labels='file'); convert them one by one otherwise")
        m = label_mod.scene(mesh, references=references)
    else:
        m = load_mesh(mesh, references=references)
    t_load = time.perf_counter()
    used = None
    if like is not None:
        from .reference import prepare

        m, grid, used = prepare(m, like, mesh_space, sdf=sdf, color=color, bounds=bounds,
                                resolution=resolution, shape=shape, voxel_size=voxel_size,
                                fit=fit)
    else:
        if mesh_space is not None:
            raise ParameterError("`mesh_space` (--mesh-space) applies only onto a reference grid "
                                 "(`like`, --like)")
        grid = make_grid(m.bounds, bounds=bounds, resolution=resolution, shape=shape,
                         voxel_size=voxel_size, fit="box" if fit is None else fit)
    lset = None if labels is None else label_mod.label_set(m, labels)
    vol = voxelize_block(m, grid, engine=engine, inside=inside, axis=axis, jobs=jobs, color=color,
                         diffuse=diffuse, ambient=ambient, density=density,
                         supersample=supersample, density_dtype=density_dtype, sdf=sdf,
                         band=band, progress=progress, labels=lset, overlap=overlap,
                         fractions=fractions, _stacklevel=3)
    vol.timings = {"load": t_load - t0, **vol.timings, "total": time.perf_counter() - t0}
    vol.mesh_space = used
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


def _check_options(density, density_dtype, supersample, sdf, band):
    """Validated ``(supersample, band)``; ParameterError for a bad option."""
    if density not in (None, "coverage"):
        raise ParameterError(f"`density` must be None or 'coverage', got {density!r}")
    if density_dtype not in ("uint8", "float32"):
        raise ParameterError(f"`density_dtype` must be 'uint8' or 'float32', got {density_dtype!r}")
    if density is not None:
        from .grid import _check_positive_int

        supersample = _check_positive_int("supersample", supersample)
    if sdf:
        try:
            band = float(band)
        except (TypeError, ValueError):
            raise ParameterError(f"`band` must be a positive number of voxels, got {band!r}") from None
        if not band > 0:
            raise ParameterError(f"`band` must be a positive number of voxels, got {band!r}")
    return supersample, band


def voxelize_block(
    mesh,
    grid: Grid,
    block=None,
    *,
    engine="auto",
    inside="auto",
    axis=2,
    jobs=1,
    color=False,
    diffuse=True,
    ambient=False,
    density=None,
    supersample=4,
    density_dtype="uint8",
    sdf=False,
    band=3.0,
    progress=None,
    labels=None,
    overlap="last",
    fractions=False,
    shared_crossings=None,
    out=None,
    colour_out=None,
    colour_sink=None,
    _stacklevel=2,
) -> Volume:
    """Voxelise one block of a grid -- the whole grid or a slab along z -- with every option.

    The one place the stages (rays, fill, colour, density, distance) are
    run: :func:`voxelize` calls it once for the whole grid, and slab-by-slab
    conversions once per slab. A block is classified exactly as the whole
    grid would be: its rays start outside the whole mesh (see
    :func:`ray_start`).

    Parameters
    ----------
    mesh : geovox.mesh.Mesh
        The loaded model (anything :func:`geovox.mesh.load_mesh` reads is
        loaded first, once per call).
    grid : Grid
        The whole grid.
    block : (z0, z1) int, optional
        Voxel layers ``z0 <= k < z1`` to make (see :func:`block_grid`);
        default the whole grid.
    engine : str or geovox.backends.Backend
        Ray-casting backend, or its name.
    inside : {"auto", "parity", "vote", "winding"}
        Inside test, resolved by :func:`geovox.inside.choose` (a resolved
        name is kept as it is).
    axis, jobs, color, diffuse, ambient, density, supersample, density_dtype, sdf, band, progress
        As for :func:`voxelize` (``jobs`` already resolved: an int >= 1;
        ``progress`` is not told "load").
    labels : str or geovox.labels.LabelSet, optional
        A label source, or the labels :func:`geovox.labels.label_set` made.
    overlap, fractions
        As for :func:`voxelize`.
    shared_crossings : dict, optional
        ``axis -> f(block_grid) -> (Hits, Columns)``: the colour step's
        crossings along that axis, cast once for the whole grid by the
        caller instead of again for every block.
    out : (nx, ny, nz_block) bool, Fortran order, optional
        Array the parity fill writes the occupancy into (reused by a caller
        making many blocks, so its memory is not faulted in afresh each time).
    colour_out : (nz_block, ny, nx, 4) uint8, C order, optional
        The same for the colours (``color=True``; see
        :func:`geovox.colour.colour_volume`).
    colour_sink : callable, optional
        With ``color=True``: ``sink(z0, rgba)`` is handed the colours chunk by
        chunk (layers from the block's first) instead of the volume holding
        them (``colors`` is then None; see
        :func:`geovox.colour.colour_volume`).

    Returns
    -------
    Volume
        Over the block's sub-grid: ``occupancy`` (nx, ny, nz_block) bool,
        Fortran order, and ``colors`` / ``density`` / ``sdf`` as asked for.
        ``timings`` holds "rays", "fill", then "colour",
        "density", "sdf" as run (seconds); no "total".

    Raises
    ------
    ParameterError
        A bad option or block.
    GridTooLargeError
        The block's arrays would not fit in the available memory.
    """
    t0 = time.perf_counter()
    if axis not in (0, 1, 2):
        raise ParameterError(f"`axis` must be 0, 1 or 2, got {axis!r}")
    if isinstance(engine, str):
        engine = get_backend(engine)
    m = load_mesh(mesh)
    step = progress or (lambda stage: None)
    whole, grid = grid, block_grid(grid, block)
    supersample, band = _check_options(density, density_dtype, supersample, sdf, band)
    from .colour import colour_method

    color = colour_method(color)  # None, "exact" (True) or "fast"
    check_memory(grid, bytes_per_voxel(color, density, sdf))

    from . import inside as inside_tests

    from . import labels as label_mod

    lset = label_mod.resolve(m, labels, overlap, fractions)
    by_parts = lset is not None and lset.source != "material"
    method = None if by_parts else inside_tests.choose(m, inside)

    def cast_mesh(mesh, ax):
        columns = grid.columns(ax, start=ray_start(mesh, grid, ax))
        return engine.cast(mesh, columns, jobs=jobs), columns

    def cast(ax):
        return cast_mesh(m, ax)

    crossings = {}
    step("rays")
    if by_parts:
        classified = label_mod.classify(m, grid, lset, cast_mesh=cast_mesh, axis=axis, jobs=jobs,
                                        inside=inside, overlap=overlap)
        crossings[axis] = classified.crossings
        t_rays = time.perf_counter()
        occ = np.asfortranarray(classified.labels != 0)
        method = "+".join(sorted(set(classified.methods)))
    elif method == "parity":
        crossings[axis] = cast(axis)
        t_rays = time.perf_counter()
        occ = parity.fill(*crossings[axis], grid, out=out, jobs=jobs)
    elif method == "vote":
        votes = None
        for ax in (axis,) + tuple(a for a in range(3) if a != axis):
            crossings[ax] = cast(ax)
            one = parity.fill(*crossings[ax], grid, jobs=jobs).view(np.uint8)
            votes = one if votes is None else np.add(votes, one, out=votes)
        t_rays = time.perf_counter()  # the three fills are counted with the rays
        occ = np.asfortranarray(votes >= 2)
        del votes
    else:
        # The winding fill is counted with the rays.
        occ, hits, columns = inside_tests.winding_occupancy(m, grid, cast_mesh, axis, jobs)
        crossings[axis] = (hits, columns)
        t_rays = time.perf_counter()
    t_fill = time.perf_counter()
    # The checks and the inside test's choice count with the rays.
    timings = {"rays": t_rays - t0, "fill": t_fill - t_rays}
    if not occ.any():
        warn(empty_reason(m, grid, method), stacklevel=_stacklevel)
    colors = None
    if color:
        from .colour import colour_volume

        step("colour")
        for a, crossings_of in (shared_crossings or {}).items():
            if a not in crossings:
                crossings[a] = crossings_of(grid)
        # Exact colour needs no crossings at all.
        others = [a for a in range(3) if a not in crossings and color != "exact"]
        if jobs > 1 and len(others) > 1:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=2) as pool:
                for a, result in zip(others, pool.map(cast, others)):
                    crossings[a] = result
        else:
            for a in others:
                crossings[a] = cast(a)
        colors = colour_volume(m, grid, occ, crossings, diffuse=diffuse, ambient=ambient,
                               jobs=jobs, exact=color == "exact",
                               frame=(whole.lo, whole.spacing, 0 if block is None else block[0]),
                               out=None if color == "exact" else colour_out,
                               sink=None if color == "exact" else colour_sink)
        timings["colour"] = time.perf_counter() - t_fill
    dens = None
    if density == "coverage":
        from .density import coverage, sub_columns

        step("density")
        t = time.perf_counter()
        target = m
        if method == "winding":
            target = inside_tests.capped(inside_tests.target(m)[0])[0]
        sub = sub_columns(grid.columns(axis, start=ray_start(target, grid, axis)), supersample)
        sub_hits = engine.cast(target, sub, jobs=jobs)
        # The occupancy's rule: the winding number's, not parity (inside_tests.crossing_signs).
        sign = inside_tests.crossing_signs(target, sub_hits, axis) if method == "winding" else None
        frac = coverage(sub_hits, sub, grid, supersample, jobs, sign=sign)
        if density_dtype == "uint8":
            dens = np.asfortranarray(np.rint(frac * np.float32(255.0)).astype(np.uint8))
        else:
            dens = frac
        timings["density"] = time.perf_counter() - t
    dist = None
    if sdf:
        from .density import signed_distance

        step("sdf")
        t = time.perf_counter()
        dist = signed_distance(m, grid, occ, band=band, jobs=jobs)
        timings["sdf"] = time.perf_counter() - t
    extra = {}
    if lset is not None:
        extra = label_mod.label_results(
            m, grid, occ, lset, classified if by_parts else None, engine=engine, axis=axis,
            jobs=jobs, overlap=overlap, fractions=fractions, density_dtype=density_dtype,
            supersample=supersample if density is not None else
            _check_options("coverage", density_dtype, supersample, False, band)[0],
            frame=(whole.lo, whole.spacing, 0 if block is None else block[0]),
            start=ray_start(m, grid, axis), timings=timings, step=step)
    return Volume(
        **extra,
        occupancy=occ,
        grid=grid,
        backend=engine.name,
        source=m.source,
        colors=colors,
        timings=timings,
        inside=method,
        density=dens,
        sdf=dist,
    )


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


def _overlaps(bounds, grid) -> bool:
    return bool(np.all(bounds[0] <= grid.hi) and np.all(bounds[1] >= grid.lo))
