"""The public functions: a mesh to a Volume in memory, or into a file slab by slab.

Each is a load, a plan (:func:`geovox.planner.plan`) and a run
(:func:`geovox.runners.run`); many models at once are :func:`geovox.convert_many`.
"""

from __future__ import annotations

import time

from . import formats
from .errors import ParameterError
from .options import Options
from .planner import load, plan
from .runners import run
from .volume import Progress, Volume


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
    occupancy="solid",
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
    max_input_size=None,
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
        use y, see :mod:`geovox.runners`). Occupancy is the same up to ties on
        the surface; coverage density, sampled across the rays, can differ
        by a step or so where the surface is steep.
    occupancy : {"solid", "surface", "both"}
        Which voxels are on: ``"solid"`` those whose centre is inside the
        closed surface (by ``inside``); ``"surface"`` every voxel the surface
        passes through, exactly, each surface point in one voxel (see
        :mod:`geovox.surface`); ``"both"`` either, which keeps open sheets and
        thin parts. ``density`` and ``sdf`` describe the solid whatever it is.
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
    sdf : {False, True, "signed", "unsigned"}
        Also fill ``Volume.sdf`` (float32, in the mesh's units) with each voxel
        centre's distance to the surface: signed (True, ``"signed"``: negative
        inside, by the plan's inside test) or ``"unsigned"`` (no inside test:
        open sheets and scans, ``occupancy="surface"`` too). See
        :mod:`geovox.density`.
    band : float
        Half-width in voxels (of the smallest voxel edge) of the distance's
        exact band, positive; ``math.inf``: every voxel exact. Beyond the band
        the value is ``band * min(spacing)`` (negated inside).
    kernel : {None, "auto", "compiled", "numpy"}
        Exact colour's nearest-surface search; None reads ``GEOVOX_KERNEL``
        (default ``auto``: the compiled kernel where it was built).
    references : {"anywhere", "folder"}
        Where the files a model file names (materials, textures, buffers)
        may be read from: anywhere (``../textures/x.png`` included), or only
        under the model's own folder, for files you did not make (see
        :mod:`geovox.io.references`). URLs are never fetched.
    labels : {None, "part", "component", "material", "file", "feature"}
        Also fill ``Volume.labels`` and ``Volume.label_table`` (see
        :mod:`geovox.labels`): the model's own parts (OBJ objects or groups,
        scene nodes), its connected components, the material of each
        voxel's exact nearest surface point, the file each part came
        from (``mesh`` a list of files, one scene on one grid), or the
        feature ID of glTF's ``EXT_mesh_features`` (3D Tiles, BIM). With parts,
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
    max_input_size : int, optional
        The most bytes the model file may hold once read or inflated (an
        archive's members together, a glTF's decoded buffers, the file
        itself, a glTF's instanced copies); default 100 times the file's size
        (at least 64 MiB), at most half the available memory, and for
        instanced copies half the available memory. A file past it is refused
        in one line before the memory is spent (see :mod:`geovox.io.limits`).
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


def convert_to(mesh, path, fmt=None, *, budget=None, jobs=None, progress=None, client=None,
               slab=None, **options):
    """Voxelise ``mesh`` into ``path`` slab by slab (HDF5, VTK-HDF, RAW or OME-Zarr).

    A plan (:func:`geovox.plan` with ``stream=True``) and its run.

    Parameters
    ----------
    mesh : str, os.PathLike, trimesh.Trimesh, trimesh.Scene or geovox.mesh.Mesh
        The model, as for :func:`geovox.voxelize`.
    path : str or os.PathLike
        Output file (``.h5`` / ``.hdf5`` / ``.vtkhdf`` / ``.hdf`` / ``.raw``)
        or folder (``.zarr``).
    fmt : str, optional
        Format name instead of the extension (``"hdf5"``, ``"vtkhdf"``,
        ``"raw"``, ``"zarr"``).
    budget : float, optional
        Bytes one slab's arrays may take (default :data:`geovox.planner.SLAB_BUDGET`).
    jobs : int, optional
        Threads (default: one per core); the files do not depend on it.
    progress : callable, optional
        ``progress(Progress("slab", done, total))`` after each slab.
    client : dask.distributed.Client, optional
        ``.zarr`` only: voxelise and write each slab as a task on the
        cluster's workers (which must reach ``path``, e.g. a shared file
        system). The result is the same as without.
    slab : int, optional
        ``.zarr`` only: slab thickness in voxels, a multiple of 64 (default:
        from ``budget`` here, :func:`geovox.planner.cluster_thick` on a cluster).
    **options
        Any field of :class:`geovox.Options` (resolution, shape, voxel_size,
        fit, bounds, backend, inside, color, diffuse, ambient, density,
        supersample, density_dtype, sdf, band, kernel, references); a misspelt one is a
        ParameterError naming the closest.

    Returns
    -------
    Report
        Also read as the dict this returned before: ``shape``, ``spacing``,
        ``bounds``, ``inside`` (count), ``inside_test``, ``backend``,
        ``slabs``, ``files``, ``timings``, ``filled_in_slabs`` (True where a
        one-piece occupancy was filled and written 64 slices at a time, see
        :func:`geovox.parity.fill_slabs`), ``grid``, ``source``, ``mesh_space``,
        ``approximate`` (voxels left to an estimate of the winding number,
        summed over the slabs: see :class:`geovox.volume.Report`);
        with labels also ``labels`` (how many) and ``contested`` (summed over
        the slabs, as is the table's ``label_table``). Labels and fractions
        stream slab by slab like the rest, into .h5, .vtkhdf, .raw,
        .seg.nrrd and .zarr; into the other label formats they are made in
        memory and written whole.

    Raises
    ------
    ParameterError
        A format that cannot be written slab by slab, ``client`` or ``slab``
        without ``.zarr``, a ``slab`` that is not a multiple of 64, or a bad
        option as for :func:`geovox.voxelize` (a misspelt one names the closest).
    InputNotFoundError, MeshError, BackendUnavailableError
        As for :func:`geovox.voxelize`.
    OutputError
        The output cannot be written (missing folder, no permission, disk
        full; nothing is left behind), or the cluster's workers cannot see
        the output folder.
    GridTooLargeError
        Even one slab would not fit in the available memory.
    """
    t0 = time.perf_counter()
    f = formats.format_for(path, fmt)
    labelled = options.get("labels") is not None or options.get("fractions")
    if labelled:
        formats.check_labels(True, f)
    # Labels into a format written whole (.nrrd, NIfTI, .npz, .vox): made in memory.
    if f.slab_writer is None and not labelled:
        raise ParameterError(f"slab-by-slab output needs .h5, .vtkhdf/.hdf, .raw, .seg.nrrd or "
                             f".zarr, not {f.name}")
    if not f.can.chunk and (client is not None or slab is not None):
        raise ParameterError(f"`client` and `slab` are for .zarr output, not {f.name}")
    o = Options.from_kwargs(jobs=jobs, **options)
    formats.check_writable(path)
    m = load(mesh, o)
    t_load = time.perf_counter()
    p = plan(m, o, path, fmt=fmt, stream=f.slab_writer is not None, cluster=client is not None,
             budget=budget, slab=slab)
    report = run(m, p, progress=progress, client=client)
    report.timings["load"] = report.timings.get("load", 0.0) + t_load - t0
    report.timings["total"] = time.perf_counter() - t0
    return report


__all__ = ["convert_to", "voxelize"]
