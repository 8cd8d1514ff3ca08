"""Big grids in bounded memory: convert slab by slab, streaming into the file.

The grid is cut into slabs along z (64 voxels thick, or a multiple, to match
the 64³ HDF5 chunks), each slab is voxelised as a sub-grid of its own -- the
rays still start outside the whole mesh, so a slab is classified exactly as
the full grid would be -- and written into its place in the output before
the next one is made. Peak memory is one slab's arrays, whatever the grid.
Colour, density and distance work per slab too: every candidate crossing of
a slab's voxels lies on a ray through that slab.

Streaming writes HDF5 (plain datasets and the VTK-HDF group) and RAW (with
its headers and sidecar); other formats need the whole volume in memory.
"""

from __future__ import annotations

import json
import os
import time
import warnings

import numpy as np

from .errors import GeovoxWarning, ParameterError
from .grid import Grid, make_grid
from .mesh import load_mesh

#: Memory a slab's arrays may take, by default: 2048³ occupancy goes in
#: 256-voxel slabs and stays under 3 GiB; occupancy up to 1024³ is one slab.
SLAB_BUDGET = 1 << 30
STREAMABLE = ("hdf5", "raw")


def bytes_per_voxel(color=False, density=None, sdf=False) -> float:
    """Working memory per voxel of one conversion (occupancy and what is asked for)."""
    return 1.0 + (20.0 if color else 0.0) + (8.0 if density else 0.0) + (8.0 if sdf else 0.0)


def slab_plan(grid: Grid, per_voxel: float, budget: float = SLAB_BUDGET) -> list:
    """``[(z0, z1), ...]``: slabs along z, a multiple of 64 thick, within ``budget``."""
    nx, ny, nz = grid.shape
    fit = int(budget // max(1.0, nx * ny * per_voxel))
    thick = nz if fit >= nz else max(64, fit // 64 * 64)
    return [(z, min(z + thick, nz)) for z in range(0, nz, thick)]


class _Volume:
    """The facts of the whole grid that headers and attributes need."""

    def __init__(self, grid, backend, source, colors, density, sdf):
        from .pipeline import Volume

        self.grid = grid
        self.backend = backend
        self.source = source
        self.colors = colors
        self.density = density
        self.sdf = sdf
        self.bounds = Volume.bounds.fget(self)
        self.spacing = Volume.spacing.fget(self)
        self.shape = tuple(grid.shape)


def convert_to(mesh, path, fmt=None, *, budget=None, jobs=None, progress=None, **options):
    """Voxelise ``mesh`` into ``path`` slab by slab (HDF5 or RAW).

    Parameters
    ----------
    mesh : path, trimesh object or Mesh
    path : str
        Output file (``.h5`` / ``.hdf5`` / ``.raw``).
    budget : float, optional
        Bytes one slab's arrays may take (default ``SLAB_BUDGET``).
    progress : callable, optional
        Called with ``(slab_index, n_slabs)`` after each slab.
    **options
        As for :func:`geovox.voxelize` (resolution, shape, voxel_size,
        bounds, backend, inside, color, diffuse, ambient, density,
        supersample, density_dtype, sdf, band).

    Returns
    -------
    dict with ``shape``, ``spacing``, ``bounds``, ``inside`` (count),
    ``inside_test``, ``backend``, ``slabs``, ``files`` and ``timings``.
    """
    from . import formats
    from . import inside as inside_tests
    from .backends import get_backend
    from .parallel import resolve_jobs
    from .pipeline import voxelize

    t0 = time.perf_counter()
    f = formats.format_for(path, fmt)
    if f.name not in STREAMABLE:
        raise ParameterError(f"slab-by-slab output needs .h5 or .raw, not {f.name}")
    formats.check_writable(path)
    jobs = resolve_jobs(jobs)
    m = load_mesh(mesh)
    engine = get_backend(options.pop("backend", "auto"))
    t_load = time.perf_counter()
    grid = make_grid(m.bounds, bounds=options.pop("bounds", None),
                     resolution=options.pop("resolution", None), shape=options.pop("shape", None),
                     voxel_size=options.pop("voxel_size", None))
    method = inside_tests.choose(m, options.pop("inside", "auto"))
    per = bytes_per_voxel(options.get("color"), options.get("density"), options.get("sdf"))
    from .pipeline import _available_memory, check_memory

    if budget is None:
        avail = _available_memory()
        budget = SLAB_BUDGET if avail is None else min(SLAB_BUDGET, 0.5 * avail)
    plan = slab_plan(grid, per, budget)
    try:
        z0, z1 = plan[0]
        check_memory(Grid(grid.lo, grid.hi, (grid.shape[0], grid.shape[1], z1 - z0)), per)
    except MemoryError:
        nx, ny, nz = grid.shape
        from .errors import GridTooLargeError

        raise GridTooLargeError(
            f"a {nx} x {ny} x {nz} grid does not fit in memory even slab by slab "
            f"({z1 - z0}-voxel slabs need {nx * ny * (z1 - z0) * per / 2**30:.1f} GiB); "
            f"use a smaller resolution") from None
    dens_dtype = options.get("density_dtype", "uint8")
    meta = _Volume(grid, engine.name, m.source,
                   colors=True if options.get("color") else None,
                   density=np.zeros(0, dens_dtype) if options.get("density") else None,
                   sdf=np.zeros(0, np.float32) if options.get("sdf") else None)
    writer = (_HDF5Writer if f.name == "hdf5" else _RawWriter)(path, meta, jobs)
    inside = 0
    timings = {"load": 0.0, "rays": 0.0, "fill": 0.0, "write": 0.0}
    nx, ny, _ = grid.shape
    h = grid.spacing
    try:
        for n, (z0, z1) in enumerate(plan):
            lo = grid.lo.copy()
            lo[2] = grid.lo[2] + z0 * h[2]
            hi = grid.hi.copy()
            hi[2] = grid.lo[2] + z1 * h[2] if z1 < grid.shape[2] else grid.hi[2]
            ta = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", GeovoxWarning)  # said once, not per slab
                # Rays along y: a slab's columns are its own (x, z) pairs, so
                # no ray is cast twice across slabs.
                vol = voxelize(m, shape=(nx, ny, z1 - z0), bounds=np.r_[lo, hi], backend=engine.name,
                               inside=method, jobs=jobs, axis=1, **options)
            tb = time.perf_counter()
            writer.write(z0, vol)
            for key, value in vol.timings.items():
                if key != "total":
                    timings[key] = timings.get(key, 0.0) + value
            timings["write"] += time.perf_counter() - tb
            inside += vol.inside_count
            del vol
            if progress:
                progress(n + 1, len(plan))
        files = writer.close()
    except BaseException:
        writer.abort()
        raise
    timings["load"] += t_load - t0
    timings["total"] = time.perf_counter() - t0
    return {"shape": tuple(grid.shape), "spacing": tuple(float(x) for x in h),
            "bounds": meta.bounds, "inside": inside, "inside_test": method,
            "backend": engine.name, "slabs": len(plan), "files": files, "timings": timings,
            "grid": grid, "source": m.source}


class _HDF5Writer:
    def __init__(self, path, meta, jobs):
        import h5py

        from . import formats
        from .formats.hdf5 import _dataset
        from .formats.headers import origin_of

        self.path, self.meta, self.jobs = os.fspath(path), meta, jobs
        self._ctx = formats.atomic_outputs()
        group = self._ctx.__enter__()
        self.tmp = group.add(self.path)
        self.f = h5py.File(self.tmp, "w")
        nx, ny, nz = meta.shape
        self.chunks = tuple(min(64, n) for n in meta.shape)
        zyx = self.chunks[::-1]
        f = self.f
        self.sets = {"occupancy": (_dataset(f, "occupancy", meta.shape, np.uint8, self.chunks), False)}
        g = f.create_group("VTKHDF")
        g.attrs["Version"] = np.array([2, 1], dtype=np.int64)
        g.attrs.create("Type", np.bytes_("ImageData"))
        g.attrs["WholeExtent"] = np.array([0, nx - 1, 0, ny - 1, 0, nz - 1], dtype=np.int64)
        g.attrs["Origin"] = origin_of(meta).astype(np.float64)
        g.attrs["Spacing"] = np.asarray(meta.spacing, dtype=np.float64)
        g.attrs["Direction"] = np.eye(3).reshape(-1)
        pd = g.create_group("PointData")
        self.vtk = {"occupancy": _dataset(pd, "occupancy", (nz, ny, nx), np.uint8, zyx)}
        if meta.colors is not None:
            self.sets["color"] = (_dataset(f, "color", meta.shape + (4,), np.uint8, self.chunks + (4,)), True)
            self.sets["color"][0].attrs["components"] = "RGBA"
            self.sets["color"][0].attrs["axis_order"] = "xyzc"
            self.vtk["color"] = _dataset(pd, "color", (nz, ny, nx, 4), np.uint8, zyx + (4,))
        for name, arr in (("density", meta.density), ("sdf", meta.sdf)):
            if arr is not None:
                self.sets[name] = (_dataset(f, name, meta.shape, arr.dtype, self.chunks), False)
                self.vtk[name] = _dataset(pd, name, (nz, ny, nx), arr.dtype, zyx)

    def write(self, z0, vol):
        from .formats.chunks import write_blocks

        arrays = {"occupancy": vol.occupancy.view(np.uint8), "color": vol.colors,
                  "density": vol.density, "sdf": vol.sdf}
        c = self.chunks
        k0 = z0 // c[2]
        nz = vol.shape[2]
        zr = range(k0, k0 + -(-nz // c[2]))
        for name, (dset, _) in self.sets.items():
            arr = arrays[name]

            def block(index, arr=arr):
                sl = tuple(slice(i * n, (i + 1) * n) for i, n in zip(index[:2], c[:2]))
                zs = slice((index[2] - k0) * c[2], (index[2] - k0 + 1) * c[2])
                return arr[sl + (zs,)]

            ranges = [range(-(-s // n)) for s, n in zip(dset.shape[:2], c[:2])] + [zr]
            if arr.ndim == 4:
                ranges.append(range(1))
            write_blocks(dset, block, jobs=self.jobs, ranges=ranges)
            vdset = self.vtk[name]
            src = arr.transpose((2, 1, 0) + tuple(range(3, arr.ndim)))

            def vblock(index, src=src):
                zs = slice((index[0] - k0) * c[2], (index[0] - k0 + 1) * c[2])
                sl = tuple(slice(i * n, (i + 1) * n) for i, n in zip(index[1:3], (c[1], c[0])))
                return src[(zs,) + sl]

            vranges = [zr] + [range(-(-s // n)) for s, n in zip(vdset.shape[1:3], (c[1], c[0]))]
            if arr.ndim == 4:
                vranges.append(range(1))
            write_blocks(vdset, vblock, jobs=self.jobs, ranges=vranges)

    def close(self):
        meta = self.meta
        lo, hi = meta.bounds
        attrs = {"spacing": np.asarray(meta.spacing, dtype=np.float64),
                 "bounds": np.asarray([lo, hi], dtype=np.float64),
                 "shape": np.asarray(meta.shape, dtype=np.int64), "axis_order": "xyz",
                 "values": "0 outside, 1 inside", "backend": meta.backend, "source": str(meta.source)}
        d = self.sets["occupancy"][0]
        for key, value in attrs.items():
            d.attrs[key] = value
            self.f.attrs[key] = value
        self.f.close()
        self._ctx.__exit__(None, None, None)
        return [self.path]

    def abort(self):
        import sys

        try:
            self.f.close()
        finally:
            self._ctx.__exit__(*sys.exc_info())


class _RawWriter:
    def __init__(self, path, meta, jobs):
        from . import formats
        from .formats.raw import field_path

        self.path, self.meta = os.fspath(path), meta
        self._ctx = formats.atomic_outputs()
        self.group = self._ctx.__enter__()
        self.names = {"occupancy": self.path}
        if meta.colors is not None:
            self.names["color"] = field_path(self.path, "rgba")
        for name in ("density", "sdf"):
            if getattr(meta, name) is not None:
                self.names[name] = field_path(self.path, name)
        self.files = {k: open(self.group.add(p), "wb") for k, p in self.names.items()}

    def write(self, z0, vol):
        occ = vol.occupancy
        self.files["occupancy"].write((occ.T.view(np.uint8) * np.uint8(255)).tobytes())
        if "color" in self.files:
            self.files["color"].write(np.ascontiguousarray(vol.colors.transpose(2, 1, 0, 3)).tobytes())
        for name in ("density", "sdf"):
            if name in self.files:
                arr = getattr(vol, name)
                self.files[name].write(np.ascontiguousarray(arr.T, dtype=arr.dtype.newbyteorder("<")).tobytes())

    def close(self):
        from .formats.raw import _write_headers, metadata

        for fh in self.files.values():
            fh.close()
        meta = self.meta
        nx, ny, nz = meta.shape
        info = metadata(meta, self.path)
        written = [self.path] + _write_headers(self.group, meta, self.path, "uint8")
        if "color" in self.names:
            cpath = self.names["color"]
            written += [cpath] + _write_headers(self.group, meta, cpath, "uint8", components=4)
            info["color"] = {"data_file": os.path.basename(cpath), "dtype": "uint8", "components": 4,
                             "layout": "RGBA interleaved per voxel, x fastest, then y, then z",
                             "values": "alpha 255 inside, 0 outside"}
        for name in ("density", "sdf"):
            if name in self.names:
                dtype = str(getattr(meta, name).dtype)
                fpath = self.names[name]
                written += [fpath] + _write_headers(self.group, meta, fpath, dtype)
                info[name] = {"data_file": os.path.basename(fpath), "dtype": dtype,
                              "byte_order": "little"}
        sidecar = os.path.splitext(self.path)[0] + ".json"
        with open(self.group.add(sidecar), "w") as fh:
            json.dump(info, fh, indent=2)
            fh.write("\n")
        self._ctx.__exit__(None, None, None)
        return written + [sidecar]

    def abort(self):
        import sys

        for fh in self.files.values():
            fh.close()
        self._ctx.__exit__(*sys.exc_info())
