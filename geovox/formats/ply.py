"""``.ply``: the occupied voxels' centres as a binary point cloud (sparse output).

What Open3D, trimesh, MeshLab and CloudCompare open as a point cloud, and
what the TRELLIS data pipeline stores its 64³ surface voxels as: one vertex
per occupied voxel, at its centre in model units (on a reference grid, in
the mesh's own frame through the reference's affine), in the grid's memory
order (x fastest, then y, then z). ``x``, ``y``, ``z`` are ``float`` (float32)
where that places every centre to better than 1/16 of a voxel, else
``double``. With colour, ``red``, ``green``, ``blue`` (``uchar``, what every
one of those tools reads as colour) and ``alpha``; with labels an ``int``
``label`` (0 never appears: only occupied voxels are written); with density
or distance, ``density`` (``uchar`` or ``float``) and ``sdf`` (``float``). With a
distance the voxels of its exact band are points too (``|sdf|`` below the
band's ``band * min(spacing)``, ``comment geovox sdf_background``), each
with ``occupied`` (``uchar`` 0 or 1).

The header's comments hold the grid (``comment geovox grid NX NY NZ``,
``comment geovox bounds ...``, ``comment geovox affine ...`` on a reference
grid), so :func:`read_ply` reads the volume back whole; the label table is
one more comment line of JSON. A PLY without ``comment geovox`` is a mesh,
not a volume (:func:`is_geovox_ply`): ``geovox preview model.ply``
voxelises it.

Written whole or slab by slab (:class:`PlyWriter`): the count of vertices
heads the file but is known only at the end, so the points go to a
temporary file beside the target and follow the header when it is closed.
"""

from __future__ import annotations

import json
import os

import numpy as np

from .base import SlabWriter, as_meta, atomic_outputs

#: What marks a PLY as geovox's volume (the first comment of its header).
MARK = "comment geovox voxel centres"

#: Points converted and written at a time (bounds the extra memory of a write).
CHUNK_POINTS = 1 << 20

#: Records held in memory before they spill to a temporary file (the count
#: that heads the file is known only at the end): 1024³'s dragon, 2.7M
#: points, is 32 MB.
HOLD_BYTES = 1 << 26


def is_geovox_ply(path) -> bool:
    """Whether ``path`` is a PLY geovox wrote (its header carries :data:`MARK`)."""
    try:
        with open(path, "rb") as f:
            head = f.read(512)
    except OSError:
        return False
    return head.startswith(b"ply") and MARK.encode() in head


def _frame(meta):
    """``(origin, axes)``: voxel index ``(i, j, k)`` has its centre at ``origin + axes @ (i, j, k)``.

    In the mesh's own frame: on a reference grid its affine in the mesh's
    space (:attr:`Meta.mesh_space`), else the grid's voxel centres.
    """
    ref = meta.grid.reference
    if ref is None:
        spacing = np.asarray(meta.grid.spacing, dtype=np.float64)
        return np.asarray(meta.grid.lo, dtype=np.float64) + 0.5 * spacing, np.diag(spacing)
    space = meta.mesh_space[0] if meta.mesh_space else ref.space
    a = ref.affine_in(space)
    return a[:3, 3].copy(), a[:3, :3].copy()


def _coordinate_type(meta, origin, axes) -> str:
    """``"float"`` where float32 places every centre to 1/16 voxel, else ``"double"``."""
    nx, ny, nz = meta.shape
    far = np.abs(origin) + np.abs(axes) @ np.asarray([nx, ny, nz], dtype=np.float64)
    step = float(np.min(np.linalg.norm(axes, axis=0)))
    # float32 rounds a coordinate c to within c * 2**-24.
    return "float" if float(far.max()) * 2.0 ** -24 <= step / 16 else "double"


class PlyWriter(SlabWriter):
    """Writes the occupied voxels' centres as a binary PLY, whole or one z-slab at a time, in order.

    ``meta`` is the :class:`~geovox.formats.base.Meta` of the whole volume
    (or the volume itself, written whole). A slab comes as a volume
    (:meth:`write`) or, surface voxels alone, as the indices of its voxels
    (:meth:`write_points`). The records are held in memory up to
    :data:`HOLD_BYTES` and spill to a temporary file beside the target
    beyond it.

    Attributes
    ----------
    centres : list of three 1-D arrays, or None
        Per axis, the centre coordinate of each of the grid's indices in the
        file's type (float32 or float64); None on an oblique (reference)
        grid, whose centres mix the axes.
    """

    def __init__(self, path, meta, jobs: int = 1):
        meta = as_meta(meta)
        self.path, self.meta = os.fspath(path), meta
        self.origin, self.axes = _frame(meta)
        self.xyz = _coordinate_type(meta, self.origin, self.axes)
        self.dtype = self._record(meta)
        self.centres = self._centres_per_axis(meta)
        self.count = 0
        self.next = 0
        self.held, self.held_bytes = [], 0
        self.body = None
        self._ctx = atomic_outputs()
        try:
            self.target = self._ctx.__enter__().add(self.path)
        except BaseException:
            self.abort()
            raise

    def _record(self, meta) -> np.dtype:
        """One vertex: its coordinates and the fields the conversion makes."""
        xyz = "<f4" if self.xyz == "float" else "<f8"
        fields = [("x", xyz), ("y", xyz), ("z", xyz)]
        if meta.colors:
            fields += [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
        if meta.dtype("labels") is not None:
            fields.append(("label", "<i4"))
        if meta.dtype("density") is not None:
            fields.append(("density", "u1" if meta.dtype("density") == np.uint8 else "<f4"))
        if meta.dtype("sdf") is not None:
            # With a distance the band's voxels are points too: which are occupied.
            fields += [("sdf", "<f4"), ("occupied", "u1")]
        return np.dtype(fields)

    def _centres_per_axis(self, meta):
        """:attr:`centres`: per axis, every index's centre coordinate; None on an oblique grid.

        On an axis-aligned grid a centre's coordinate along an axis depends on
        that axis's index alone: ``origin + i * spacing`` in float64, then the
        file's type -- the numbers the general ``origin + axes @ (i, j, k)``
        gives (the other terms are exact zeros), looked up instead of computed
        per voxel.
        """
        if np.count_nonzero(self.axes - np.diag(np.diag(self.axes))):
            return None
        kind = self.dtype["x"]
        return [(self.origin[a] + np.arange(n, dtype=np.float64) * self.axes[a, a]).astype(kind)
                for a, n in enumerate(meta.shape)]

    def write(self, z0: int, vol) -> None:
        """Append the occupied voxels of ``vol`` (the next slab in z: layers z0 .. z0 + its depth)."""
        self._in_order(z0)
        from .base import point_voxels

        nx, ny, nz = vol.occupancy.shape
        # x fastest: the file's order; with a distance, the band's voxels too.
        flat = point_voxels(vol) if "sdf" in self.dtype.names else \
            vol.occupancy.reshape(-1, order="F")
        for start in range(0, flat.size, CHUNK_POINTS * 8):
            idx = np.flatnonzero(flat[start:start + CHUNK_POINTS * 8]) + start
            if len(idx):
                self._append(self._points(vol, idx, nx, ny, z0))
        self.next = z0 + nz

    def write_points(self, z0: int, nz: int, points) -> None:
        """Append the voxels of the next slab, layers ``z0 .. z0 + nz - 1``, as points.

        ``points``: (m, 3) in the grid's memory order
        (:func:`geovox.surface.surface_points`), either int indices ``(i, j,
        k)`` (``k`` a layer of the whole grid) or already the voxels' centres
        looked up in :attr:`centres` (``surface_points(values=writer.centres)``),
        which are the records as they are. Coordinates only: the surface
        voxels alone carry no other field.
        """
        self._in_order(z0)
        if self.dtype.names != ("x", "y", "z"):
            raise ValueError("write_points takes coordinates alone; this .ply carries "
                             + ", ".join(self.dtype.names[3:]))
        if points.dtype.kind == "f":
            if points.dtype != self.dtype["x"]:
                raise ValueError(f"points must be {self.dtype['x']} centres, got {points.dtype}")
            self._append(np.ascontiguousarray(points).view(self.dtype).reshape(-1))
        else:
            for start in range(0, len(points), CHUNK_POINTS):
                part = points[start:start + CHUNK_POINTS]
                out = np.empty(len(part), dtype=self.dtype)
                self._coordinates(out, part[:, 0], part[:, 1], part[:, 2])
                self._append(out)
        self.next = z0 + nz

    def _in_order(self, z0):
        if z0 != self.next:
            raise ValueError(f"a .ply takes its slabs in order: layer {self.next} next, got {z0}")

    def _points(self, vol, idx, nx, ny, z0) -> np.ndarray:
        """The records of the voxels ``idx`` (F-order indices in ``vol``, layers from ``z0``)."""
        i = idx % nx
        j = (idx // nx) % ny
        k = idx // (nx * ny)
        out = np.empty(len(idx), dtype=self.dtype)
        self._coordinates(out, i, j, k + z0)
        if "red" in self.dtype.names:
            rgba = vol.colors.reshape(-1, 4, order="F")[idx] if vol.colors.flags.f_contiguous \
                else vol.colors[i, j, k]
            out["red"], out["green"], out["blue"], out["alpha"] = rgba.T
        for name, field in (("labels", "label"), ("density", "density"), ("sdf", "sdf"),
                            ("occupancy", "occupied")):
            if field in self.dtype.names:
                out[field] = getattr(vol, name).reshape(-1, order="F")[idx]
        return out

    def _coordinates(self, out, i, j, k) -> None:
        """``out``'s x, y, z: the centres of voxels ``(i, j, k)`` (indices in the whole grid)."""
        if self.centres is not None:
            for name, lut, index in zip("xyz", self.centres, (i, j, k)):
                out[name] = lut[index]
            return
        ijk = np.stack([i, j, k], axis=1).astype(np.float64)
        centres = self.origin + ijk @ self.axes.T
        out["x"], out["y"], out["z"] = centres[:, 0], centres[:, 1], centres[:, 2]

    def _append(self, records) -> None:
        """Hold ``records``, or spill them (and all held) to a temporary body past HOLD_BYTES."""
        self.count += len(records)
        if self.body is None and self.held_bytes + records.nbytes <= HOLD_BYTES:
            self.held.append(records)
            self.held_bytes += records.nbytes
            return
        if self.body is None:
            import tempfile

            self.body = tempfile.TemporaryFile(dir=os.path.dirname(os.path.abspath(self.path)))
            for held in self.held:
                self.body.write(memoryview(held).cast("B"))
            self.held, self.held_bytes = [], 0
        self.body.write(memoryview(records).cast("B"))

    def _header(self) -> bytes:
        meta = self.meta
        lo, hi = meta.bounds
        lines = ["ply", "format binary_little_endian 1.0", MARK,
                 f"comment geovox grid {' '.join(str(n) for n in meta.shape)}",
                 f"comment geovox bounds {' '.join(repr(float(v)) for v in (*lo, *hi))}",
                 f"comment geovox source {_one_line(meta.source)}"]
        if meta.grid.reference is not None:
            a = np.eye(4)
            a[:3, :3], a[:3, 3] = self.axes, self.origin
            lines.append(f"comment geovox affine {' '.join(repr(float(v)) for v in a.reshape(-1))}")
        if meta.label_table:
            lines.append(f"comment geovox label_table {json.dumps(meta.label_table)}")
        if meta.dtype("sdf") is not None:
            from .base import level_set_background

            if meta.band is not None and np.isfinite(meta.band):
                lines.append(f"comment geovox sdf_background "
                             f"{float(level_set_background(meta))!r}")
        lines.append(f"element vertex {self.count}")
        names = {"<f4": "float", "<f8": "double", "u1": "uchar", "<i4": "int"}
        for name in self.dtype.names:
            lines.append(f"property {names[self.dtype[name].str.replace('|', '')]} {name}")
        lines.append("end_header")
        return ("\n".join(lines) + "\n").encode("utf-8")

    def _finish(self) -> list:
        with open(self.target, "wb") as f:
            f.write(self._header())
            for held in self.held:
                f.write(memoryview(held).cast("B"))
            if self.body is not None:
                f.flush()
                _copy_body(self.body, f)
        self.held = []
        self._release()
        self._ctx.__exit__(None, None, None)
        return [self.path]

    def _release(self) -> None:
        self.held = []
        if self.body is not None:
            self.body.close()
            self.body = None


def _copy_body(body, f) -> None:
    """Append the temporary ``body`` to ``f`` (flushed): in the kernel where the OS can."""
    body.flush()
    if hasattr(os, "sendfile"):
        offset, size = 0, os.fstat(body.fileno()).st_size
        while offset < size:
            sent = os.sendfile(f.fileno(), body.fileno(), offset, size - offset)
            if not sent:
                raise OSError(f"could not copy the points into {f.name}")
            offset += sent
        return
    import shutil

    body.seek(0)
    shutil.copyfileobj(body, f, 1 << 24)


def _one_line(text) -> str:
    return " ".join(str(text).split()) or "-"


def write_ply(volume, path) -> list:
    """The occupied voxels' centres of ``volume`` as a binary PLY point cloud (see the module notes).

    Returns
    -------
    list of str
        ``[path]``.
    """
    return PlyWriter(path, volume).write_whole(volume)


def read_ply(path):
    """A Volume from a PLY geovox wrote: its grid from the header, its voxels from the points."""
    from ..grid import Grid
    from ..volume import Volume

    path = os.fspath(path)
    with open(path, "rb") as f:
        head = b""
        while not head.endswith(b"end_header\n"):
            line = f.readline()
            if not line:
                raise ValueError("no end_header")
            head += line
        text = head.decode("utf-8").splitlines()
        info = {}
        props, count = [], 0
        for line in text:
            if line.startswith("comment geovox "):
                key, _, value = line[len("comment geovox "):].partition(" ")
                info[key] = value
            elif line.startswith("element vertex"):
                count = int(line.split()[2])
            elif line.startswith("property"):
                _, kind, name = line.split()
                props.append((name, {"float": "<f4", "double": "<f8", "uchar": "u1",
                                     "int": "<i4"}[kind]))
        if "grid" not in info:
            raise ValueError("not a PLY geovox wrote (no grid comment)")
        dtype = np.dtype(props)
        data = np.frombuffer(f.read(count * dtype.itemsize), dtype=dtype, count=count)
    shape = tuple(int(n) for n in info["grid"].split())
    b = np.array([float(v) for v in info["bounds"].split()])
    grid = Grid(b[:3], b[3:], shape)
    if "affine" in info:
        a = np.array([float(v) for v in info["affine"].split()]).reshape(4, 4)
        origin, axes = a[:3, 3], a[:3, :3]
    else:
        spacing = grid.spacing
        origin, axes = grid.lo + 0.5 * spacing, np.diag(spacing)
    xyz = np.stack([data["x"], data["y"], data["z"]], axis=1).astype(np.float64)
    ijk = np.rint(np.linalg.solve(axes, (xyz - origin).T).T).astype(np.int64)
    occ = np.zeros(shape, dtype=bool, order="F")
    i, j, k = ijk.T
    occ[i, j, k] = data["occupied"] != 0 if "occupied" in dtype.names else True
    extra = {}
    if "red" in dtype.names:
        colors = np.zeros((shape[2], shape[1], shape[0], 4), np.uint8).transpose(2, 1, 0, 3)
        colors[i, j, k] = np.stack([data[c] for c in ("red", "green", "blue", "alpha")], axis=1)
        extra["colors"] = colors
    for name, field in (("labels", "label"), ("density", "density"), ("sdf", "sdf")):
        if field in dtype.names:
            # Voxels left out of a distance are beyond its band: the background.
            fill = float(info["sdf_background"]) if field == "sdf" and "sdf_background" in info \
                else 0
            arr = np.full(shape, fill, dtype=np.uint16 if field == "label" else data[field].dtype,
                          order="F")
            arr[i, j, k] = data[field]
            extra[name] = arr
    if "label_table" in info:
        extra["label_table"] = json.loads(info["label_table"])
        if "labels" in extra and max(e["value"] for e in extra["label_table"]) <= 255:
            extra["labels"] = np.asfortranarray(extra["labels"].astype(np.uint8))
    return Volume(occupancy=occ, grid=grid, backend="?", source=info.get("source", path), **extra)


__all__ = ["MARK", "PlyWriter", "is_geovox_ply", "read_ply", "write_ply"]
