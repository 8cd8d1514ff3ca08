"""The pipeline: load -> grid -> rays -> parity fill, and the Volume it makes."""

from __future__ import annotations

import time
import numpy as np

from . import parity
from .backends import get_backend
from .errors import GridTooLargeError, ParameterError
from .grid import Grid, make_grid
from .mesh import load_mesh
from .volume import Volume

#: Refuse grids whose occupancy array alone would exceed this fraction of RAM.
MEMORY_FRACTION = 0.8


def _available_memory() -> int | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return None


def check_memory(grid: Grid, bytes_per_voxel: float = 1.0) -> None:
    """Refuse, before allocating, a grid that cannot fit in memory."""
    need = grid.size * bytes_per_voxel
    avail = _available_memory()
    if avail is not None and need > MEMORY_FRACTION * avail:
        nx, ny, nz = grid.shape
        raise GridTooLargeError(
            f"a {nx} x {ny} x {nz} grid needs {need / 2**30:.1f} GiB but only "
            f"{avail / 2**30:.1f} GiB of memory is available; use a smaller resolution, or "
            f"write it slab by slab to .h5 or .raw (geovox convert does; in Python, "
            f"geovox.convert_to)"
        )


def voxelize(
    mesh,
    resolution=None,
    bounds=None,
    backend="auto",
    *,
    shape=None,
    voxel_size=None,
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
    _reuse=None,
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
    backend : {"auto", "embree", "numpy"}
        Ray-casting engine; ``"auto"`` is NumPy, measured the faster one for
        column rays (see :mod:`geovox.backends`); both give the same volume.
    shape : (3,) int, optional
        Voxels along x, y, z (instead of ``resolution``).
    voxel_size : float, optional
        Cubic voxel edge (instead of ``resolution``); the region grows
        symmetrically to a whole number of voxels.
    axis : {0, 1, 2}
        Direction of the column rays (default z; slab-by-slab conversions
        use y, see :mod:`geovox.stream`). Occupancy is the same up to ties on
        the surface; coverage density, sampled across the rays, can differ
        by a step or so where the surface is steep.
    color : bool
        Also fill ``Volume.colors`` from the model's materials, textures or
        vertex colours (see :mod:`geovox.colour` for the exact rule).
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
    _reuse : dict, optional
        Internal (slab streaming): ``axis -> f(grid)`` giving the colour
        step's crossings along that axis, ``(Hits, Columns)``, cast once for
        the whole grid instead of again for every slab.

    Returns
    -------
    Volume
    """
    t0 = time.perf_counter()
    if axis not in (0, 1, 2):
        raise ParameterError(f"`axis` must be 0, 1 or 2, got {axis!r}")
    from .parallel import resolve_jobs

    jobs = resolve_jobs(jobs)
    step = progress or (lambda stage: None)
    step("load")
    engine = get_backend(backend)
    m = load_mesh(mesh)
    t_load = time.perf_counter()
    grid = make_grid(m.bounds, bounds=bounds, resolution=resolution, shape=shape,
                     voxel_size=voxel_size)
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
    # Occupancy is 1 byte a voxel; colour adds 4 for RGBA and about 16 of
    # working arrays while nearest crossings are found; density and distance
    # 4 each plus a float32 working copy.
    from .stream import bytes_per_voxel

    check_memory(grid, bytes_per_voxel(color, density, sdf))

    from . import inside as inside_tests

    method = inside_tests.choose(m, inside)

    def cast_mesh(mesh, ax):
        # Rays start outside the whole mesh, not at the region's edge.
        start = min(float(mesh.bounds[0, ax]), float(grid.lo[ax])) - 1e-3 * mesh.scale
        columns = grid.columns(ax, start=start)
        return engine.cast(mesh, columns, jobs=jobs), columns

    def cast(ax):
        return cast_mesh(m, ax)

    crossings = {}
    step("rays")
    if method == "parity":
        crossings[axis] = cast(axis)
        t_rays = time.perf_counter()
        occ = parity.fill(*crossings[axis], grid, jobs=jobs)
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
    timings = {"load": t_load - t0, "rays": t_rays - t_load, "fill": t_fill - t_rays}
    if not occ.any():
        import warnings

        from .errors import GeovoxWarning

        warnings.warn(empty_reason(m, grid, method), GeovoxWarning, stacklevel=2)
    colors = None
    if color:
        from .colour import colour_volume

        step("colour")
        for a, crossings_of in (_reuse or {}).items():
            if a not in crossings:
                crossings[a] = crossings_of(grid)
        others = [a for a in range(3) if a not in crossings]
        if jobs > 1 and len(others) > 1:
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=2) as pool:
                for a, result in zip(others, pool.map(cast, others)):
                    crossings[a] = result
        else:
            for a in others:
                crossings[a] = cast(a)
        colors = colour_volume(m, grid, occ, crossings, diffuse=diffuse, ambient=ambient,
                               jobs=jobs)
        timings["colour"] = time.perf_counter() - t_fill
    dens = None
    if density == "coverage":
        from .density import coverage, sub_columns

        step("density")
        t = time.perf_counter()
        target = m
        if method == "winding":
            target = inside_tests.capped(inside_tests.target(m)[0])[0]
        start = min(float(target.bounds[0, axis]), float(grid.lo[axis])) - 1e-3 * target.scale
        sub = sub_columns(grid.columns(axis, start=start), supersample)
        frac = coverage(engine.cast(target, sub, jobs=jobs), sub, grid, supersample, jobs)
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
    timings["total"] = time.perf_counter() - t0
    return Volume(
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
