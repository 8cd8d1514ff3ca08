"""Reference grids: voxelise onto the user's own (often oblique) grid, such as a CT or MR scan.

A reference is an index-to-world affine ``A`` (4 x 4, float64) plus a shape:
voxel ``(i, j, k)``'s centre is at ``A @ (i, j, k, 1)`` in patient
coordinates, LPS (DICOM's, NRRD's and ITK's usual frame) or RAS (NIfTI's).

The pipeline keeps its axis-aligned grid and its exact rules: the mesh is
moved, once, in float64, into the reference's *local frame*

    local = D . L^-1 . (p - t),   L = A[:3, :3], t = A[:3, 3], D = diag(spacing)

(spacing = the lengths of L's columns), where voxel ``(i, j, k)``'s centre is
at ``(i dx, j dy, k dz)``: the index space, scaled per axis. Where the
direction cosines are orthonormal (every scanner grid, rotated or not) this
map is a rotation plus a translation, so distances there are world
distances: the exact nearest-surface colour and the signed distance (in
world units) are unchanged by the move. A sheared grid (direction cosines
not orthogonal, e.g. a tilted CT gantry) keeps occupancy and coverage exact
(both are invariant under any affine map), but its local distances are not
world distances: ``sdf`` is refused there and colour warns.

Mesh coordinates follow 3D Slicer's convention: a ``SPACE=LPS`` or
``SPACE=RAS`` mark in the file's header (STL's 80-byte header or ASCII
``solid`` line, a leading ``#`` comment of OBJ, a PLY ``comment``, a legacy
VTK file's title line), LPS where there is none, ``mesh_space`` overriding
both. Only a conversion onto a reference looks at it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
from dataclasses import dataclass

import numpy as np

from .errors import InputNotFoundError, MeshError, ParameterError, warn

#: Sign of each world axis relative to LPS, by NRRD ``space`` name (or its short form).
_SPACE_SIGNS = {
    "left-posterior-superior": (1, 1, 1), "lps": (1, 1, 1),
    "right-anterior-superior": (-1, -1, 1), "ras": (-1, -1, 1),
    "left-anterior-superior": (1, -1, 1), "las": (1, -1, 1),
}
#: Largest departure of the direction cosines from orthonormal still taken as a rotation.
ORTHOGONAL_TOLERANCE = 1e-4
#: Reference images geovox reads, by extension (lower case).
IMAGE_EXTENSIONS = (".nii", ".nii.gz", ".nrrd", ".nhdr", ".seg.nrrd", ".mhd", ".mha")
#: Volumes geovox writes whose header or sidecar carries the grid.
VOLUME_EXTENSIONS = (".json", ".raw", ".h5", ".hdf5", ".vtkhdf", ".hdf", ".npz", ".zarr")
RAS_FROM_LPS = np.diag([-1.0, -1.0, 1.0, 1.0])


@dataclass(frozen=True)
class Reference:
    """A grid given by an index-to-world affine and a shape.

    Attributes
    ----------
    affine : (4, 4) float64
        Index ``(i, j, k, 1)`` of a voxel centre -> world, in ``space``.
    shape : (3,) tuple of int
    space : {"LPS", "RAS"}
        The world frame of ``affine``; outputs are written in it where the
        format names its frame (NRRD), and converted where the format fixes
        one (NIfTI: RAS; MetaImage and VTK-HDF: LPS).
    source : str
        Where the grid came from (a file, or ``"<affine>"``).
    """

    affine: np.ndarray
    shape: tuple
    space: str = "LPS"
    source: str = "<affine>"

    @property
    def spacing(self) -> np.ndarray:
        """(3,) float64: voxel edge lengths (the columns' norms)."""
        return np.linalg.norm(self.affine[:3, :3], axis=0)

    @property
    def direction(self) -> np.ndarray:
        """(3, 3) float64: unit direction of each index axis (columns), in ``space``."""
        return self.affine[:3, :3] / self.spacing

    @property
    def origin(self) -> np.ndarray:
        """(3,) float64: centre of voxel (0, 0, 0), in ``space``."""
        return self.affine[:3, 3].copy()

    @property
    def orthogonal(self) -> bool:
        """Whether the direction cosines are orthonormal (within ORTHOGONAL_TOLERANCE)."""
        d = self.direction
        return bool(np.abs(d.T @ d - np.eye(3)).max() <= ORTHOGONAL_TOLERANCE)

    def affine_in(self, space: str) -> np.ndarray:
        """(4, 4) float64: the index-to-world affine in ``space`` ("LPS" or "RAS")."""
        return self.affine.copy() if space == self.space else RAS_FROM_LPS @ self.affine

    def local_grid(self):
        """The axis-aligned Grid of the local frame: voxel (i, j, k)'s centre at (i, j, k) x spacing."""
        from .grid import Grid

        s = self.spacing
        n = np.asarray(self.shape, dtype=np.float64)
        return Grid(lo=-0.5 * s, hi=(n - 0.5) * s, shape=tuple(self.shape), reference=self)

    def world_to_local(self, mesh_space: str) -> np.ndarray:
        """(4, 4) float64: mesh coordinates (in ``mesh_space``) -> the local frame."""
        flip = np.eye(4) if mesh_space == self.space else RAS_FROM_LPS
        lin = self.affine[:3, :3]
        m = np.eye(4)
        m[:3, :3] = np.diag(self.spacing) @ np.linalg.inv(lin)
        m[:3, 3] = -m[:3, :3] @ self.affine[:3, 3]
        return m @ flip


def reference_grid(affine, shape, space: str = "LPS", source: str = "<affine>") -> Reference:
    """A :class:`Reference` from any index-to-world affine and a shape, checked.

    Parameters
    ----------
    affine : (4, 4) array_like
        Voxel centre index ``(i, j, k, 1)`` -> world; the last row must be
        ``0 0 0 1``.
    shape : (3,) int
    space : {"LPS", "RAS"}
        The world frame of ``affine`` (the mesh's frame is LPS unless its file
        is marked ``SPACE=RAS`` or ``mesh_space`` says so).

    Raises
    ------
    ParameterError
        Not 4 x 4, not finite, not affine, singular, or a bad shape or space.
    """
    from .grid import check_positive_int

    try:
        a = np.array(affine, dtype=np.float64)
    except (TypeError, ValueError):
        raise ParameterError(f"`like` affine must be a 4 x 4 array of numbers, got {affine!r}") from None
    if a.shape != (4, 4):
        raise ParameterError(f"`like` affine must be 4 x 4, got shape {a.shape} ({source})")
    if not np.all(np.isfinite(a)):
        raise ParameterError(f"`like` affine has NaN or infinite entries ({source})")
    if not np.allclose(a[3], [0, 0, 0, 1], rtol=0, atol=1e-12):
        raise ParameterError(f"`like` affine's last row must be 0 0 0 1, got {a[3].tolist()} ({source})")
    a[3] = (0, 0, 0, 1)
    lin = a[:3, :3]
    norms = np.linalg.norm(lin, axis=0)
    if np.any(norms == 0) or abs(np.linalg.det(lin / norms)) < 1e-9:
        raise ParameterError(f"{source}: the image's affine is singular (its direction columns "
                             f"do not span 3-D space): {lin.tolist()}")
    try:
        items = [int(x) for x in shape] if len(shape) == 3 else None
    except (TypeError, ValueError):
        items = None
    if items is None:
        raise ParameterError(f"`like` shape must be three positive integers, got {shape!r}")
    n = tuple(check_positive_int("shape", x) for x in items)
    space = str(space).upper()
    if space not in ("LPS", "RAS"):
        raise ParameterError(f"`space` must be 'LPS' or 'RAS', got {space!r}")
    return Reference(affine=a, shape=n, space=space, source=source)


def load_reference(like, *, with_data: bool = False):
    """The reference grid ``like`` names.

    Parameters
    ----------
    like : str, os.PathLike, Reference or (affine, shape)
        An image (NIfTI ``.nii``/``.nii.gz``, NRRD ``.nrrd``/``.nhdr``/
        ``.seg.nrrd``, MetaImage ``.mhd``/``.mha``), a volume geovox wrote
        (``.json`` sidecar, ``.raw`` beside one, ``.h5``, ``.vtkhdf``,
        ``.npz``, ``.zarr``), a Reference, or a 4 x 4 affine and a shape
        (LPS).
    with_data : bool
        Also return the image's voxels (for ``preview --like``).

    Returns
    -------
    Reference, or (Reference, (nx, ny, nz) array or None) with ``with_data``.

    Raises
    ------
    InputNotFoundError, ParameterError
        A missing file; not an image; a singular affine; a 4-D image.
    """
    if isinstance(like, Reference):
        return (like, None) if with_data else like
    if isinstance(like, (tuple, list)) and len(like) == 2 and not isinstance(like[0], str):
        ref = reference_grid(like[0], like[1])
        return (ref, None) if with_data else ref
    path = os.fspath(like)
    if not os.path.exists(path):
        raise InputNotFoundError(f"reference image not found: {path}")
    lower = path.lower().rstrip("/")
    readers = [(".nii", _read_nifti), (".nii.gz", _read_nifti), (".nrrd", _read_nrrd),
               (".nhdr", _read_nrrd), (".mhd", _read_mhd), (".mha", _read_mhd)]
    for ext, reader in readers:
        if lower.endswith(ext):
            break
    else:
        if lower.endswith(VOLUME_EXTENSIONS):
            ref = _read_geovox(path)
            return (ref, None) if with_data else ref
        raise ParameterError(f"--like {path}: not a reference image geovox reads (use one of "
                             f"{', '.join(IMAGE_EXTENSIONS + VOLUME_EXTENSIONS)})")
    try:
        ref, data = reader(path, with_data)
    except (ParameterError, InputNotFoundError):
        raise
    except Exception as exc:  # the image libraries raise many types for a damaged file
        raise ParameterError(f"--like {path}: cannot be read as an image "
                             f"({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from exc
    return (ref, data) if with_data else ref


def _refuse_4d(path, shape):
    raise ParameterError(
        f"--like {path}: a 4-D image ({' x '.join(str(int(n)) for n in shape)}); geovox needs one "
        f"3-D volume as the grid: save the volume you mean as its own file (e.g. with nibabel: "
        f"img.slicer[..., 0])")


def _read_nifti(path, with_data):
    """NIfTI-1/2 via nibabel: the sform where its code is set, else the qform (RAS)."""
    try:
        import nibabel
    except ImportError:
        from .errors import BackendUnavailableError

        raise BackendUnavailableError("reading NIfTI needs nibabel: pip install 'geovox[nifti]'") from None
    img = nibabel.load(path)
    shape = tuple(int(n) for n in img.shape)
    if len(shape) > 3 and int(np.prod(shape[3:])) > 1:
        _refuse_4d(path, shape)
    shape = (shape + (1, 1, 1))[:3]
    hdr = img.header
    sform, scode = hdr.get_sform(coded=True)
    qform, qcode = hdr.get_qform(coded=True)
    affine = sform if scode else qform if qcode else hdr.get_base_affine()
    ref = reference_grid(affine, shape, "RAS", source=path)
    data = None
    if with_data:
        data = np.asarray(img.dataobj).reshape(shape)
    return ref, data


def _read_nrrd(path, with_data):
    """NRRD / .seg.nrrd via pynrrd: ``space``, ``space directions``, ``space origin``.

    Axes without a space direction (a segmentation's layers, colour
    components) are not part of the grid.
    """
    import nrrd

    if with_data:
        data, header = nrrd.read(path)
    else:
        header, data = nrrd.read_header(path), None
    space_name = str(header.get("space", "left-posterior-superior")).lower()
    if space_name not in _SPACE_SIGNS:
        raise ParameterError(f"--like {path}: NRRD space {space_name!r} is not a patient space "
                             f"(LPS, RAS or LAS)")
    dirs = header.get("space directions")
    if dirs is None:
        raise ParameterError(f"--like {path}: the NRRD has no `space directions`; it is not "
                             f"placed in patient space")
    dirs = np.asarray(dirs, dtype=np.float64)
    sizes = [int(n) for n in header["sizes"]]
    spatial = [a for a in range(len(sizes)) if np.all(np.isfinite(dirs[a]))]
    if len(spatial) != 3:
        raise ParameterError(f"--like {path}: {len(spatial)} spatial axes; a reference needs 3")
    kinds = [str(k).lower() for k in header.get("kinds", ["domain"] * len(sizes))]
    others = [a for a in range(len(sizes)) if a not in spatial]
    if any(kinds[a] in ("time", "space", "domain") and sizes[a] > 1 for a in others):
        _refuse_4d(path, sizes)
    affine = np.eye(4)
    affine[:3, :3] = dirs[spatial].T
    affine[:3, 3] = np.asarray(header.get("space origin", np.zeros(3)), dtype=np.float64)
    signs = np.diag(list(_SPACE_SIGNS[space_name]) + [1.0])
    space = "RAS" if space_name in ("right-anterior-superior", "ras") else "LPS"
    if space == "LPS":
        affine = signs @ affine  # LAS -> LPS
    ref = reference_grid(affine, [sizes[a] for a in spatial], space, source=path)
    if data is not None:
        if others:  # a segmentation's layers: any layer's label marks the voxel
            data = np.moveaxis(data, others, list(range(-len(others), 0)))
            data = data.reshape(data.shape[:3] + (-1,)).max(axis=3)
        data = np.asarray(data)
    return ref, data


def parse_mhd(text: str) -> dict:
    """MetaImage header fields: ``{key: value string}`` (keys as written; parsing stops at the data file)."""
    fields = {}
    for line in text.splitlines():
        if "=" not in line:
            continue
        key, value = (s.strip() for s in line.split("=", 1))
        fields[key] = value
        if key == "ElementDataFile":
            break
    return fields


def mhd_affine(fields: dict, path: str = "<mhd>") -> tuple:
    """``(affine (4, 4) LPS, shape)`` from MetaImage fields (see :func:`parse_mhd`).

    ``TransformMatrix`` lists the direction of each index axis in turn (as
    ITK writes and reads it); ``Offset`` (or ``Position``/``Origin``) is voxel
    0's centre; world coordinates are LPS, as in ITK, whatever
    ``AnatomicalOrientation`` says (it describes the axes, and is read only
    to check it names three axes).
    """
    def numbers(key, n, default=None):
        for k in (key,) if isinstance(key, str) else key:
            if k in fields:
                vals = [float(v) for v in fields[k].split()]
                if len(vals) != n:
                    raise ParameterError(f"--like {path}: `{k}` needs {n} numbers, got {fields[k]!r}")
                return np.asarray(vals)
        if default is None:
            raise ParameterError(f"--like {path}: MetaImage header has no `{key}`")
        return np.asarray(default, dtype=np.float64)

    if fields.get("ObjectType", "Image") != "Image":
        raise ParameterError(f"--like {path}: MetaImage ObjectType {fields['ObjectType']!r} is "
                             f"not an image")
    ndims = int(fields.get("NDims", 3))
    dims = [int(v) for v in fields.get("DimSize", "").split()]
    if ndims == 4 and len(dims) == 4 and dims[3] > 1:
        _refuse_4d(path, dims)
    if ndims != 3 or len(dims) != 3:
        raise ParameterError(f"--like {path}: a {ndims}-D MetaImage (DimSize {fields.get('DimSize')!r});"
                             f" a reference needs a 3-D image")
    spacing = numbers(("ElementSpacing", "ElementSize"), 3, [1, 1, 1])
    offset = numbers(("Offset", "Position", "Origin"), 3, [0, 0, 0])
    matrix = numbers(("TransformMatrix", "Rotation", "Orientation"), 9, np.eye(3).ravel())
    affine = np.eye(4)
    affine[:3, :3] = matrix.reshape(3, 3).T * spacing
    affine[:3, 3] = offset
    return affine, dims


def _read_mhd(path, with_data):
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    text = head.decode("latin-1")
    fields = parse_mhd(text)
    if "ElementDataFile" not in fields or "DimSize" not in fields:
        raise ParameterError(f"--like {path}: not a MetaImage header (no DimSize or ElementDataFile)")
    affine, dims = mhd_affine(fields, path)
    ref = reference_grid(affine, dims, "LPS", source=path)
    data = None
    if with_data:
        data = _mhd_data(path, fields, text, dims)
    return ref, data


_MET_DTYPES = {"MET_UCHAR": "u1", "MET_CHAR": "i1", "MET_USHORT": "u2", "MET_SHORT": "i2",
               "MET_UINT": "u4", "MET_INT": "i4", "MET_FLOAT": "f4", "MET_DOUBLE": "f8"}


def _mhd_data(path, fields, text, dims):
    """(nx, ny, nz) array of a MetaImage's first channel (raw or zlib), or None if unreadable."""
    import zlib

    kind = _MET_DTYPES.get(fields.get("ElementType", ""))
    if kind is None:
        return None
    big = fields.get("BinaryDataByteOrderMSB", fields.get("ElementByteOrderMSB", "False")) == "True"
    dtype = np.dtype(("> " if big else "<").strip() + kind)
    channels = int(fields.get("ElementNumberOfChannels", 1))
    name = fields["ElementDataFile"]
    if name == "LOCAL":
        with open(path, "rb") as f:
            raw = f.read()
        raw = raw[raw.index(b"ElementDataFile"):]
        raw = raw[raw.index(b"\n") + 1:]
    else:
        with open(os.path.join(os.path.dirname(path), name), "rb") as f:
            raw = f.read()
    if fields.get("CompressedData", "False") == "True":
        raw = zlib.decompress(raw)
    n = int(np.prod(dims)) * channels
    arr = np.frombuffer(raw, dtype=dtype, count=n).reshape(dims[2], dims[1], dims[0], channels)
    return np.ascontiguousarray(arr[..., 0].transpose(2, 1, 0))


def _read_geovox(path) -> Reference:
    """The grid of a volume geovox wrote, from its header or sidecar (no voxels read)."""
    lower = path.lower().rstrip("/")
    if lower.endswith(".raw"):
        path = os.path.splitext(path)[0] + ".json"
        lower = path.lower()
    try:
        if lower.endswith(".json"):
            with open(path, encoding="utf-8") as f:
                info = json.load(f)
            shape, spacing = info["shape"], info["spacing"]
            origin, affine = info["origin_of_first_voxel_centre"], info.get("affine")
            space = info.get("space", "LPS")
        elif lower.endswith((".h5", ".hdf5", ".vtkhdf", ".hdf")):
            import h5py

            with h5py.File(path, "r") as f:
                g = f["VTKHDF"]
                ext = np.asarray(g.attrs["WholeExtent"])
                shape = [int(ext[1] - ext[0] + 1), int(ext[3] - ext[2] + 1), int(ext[5] - ext[4] + 1)]
                spacing, origin = np.asarray(g.attrs["Spacing"]), np.asarray(g.attrs["Origin"])
                direction = np.asarray(g.attrs.get("Direction", np.eye(3).ravel()), dtype=np.float64)
                affine = np.eye(4)
                affine[:3, :3] = direction.reshape(3, 3) * spacing
                affine[:3, 3] = origin
                space = str(g.attrs.get("space", f.attrs.get("space", "LPS")))
                exact = g.attrs.get("affine", f.attrs.get("affine"))
                if exact is not None:  # written onto a reference: its affine as it was
                    affine = np.asarray(exact, dtype=np.float64)
        elif lower.endswith(".npz"):
            with np.load(path) as d:
                shape = d["shape"] if "shape" in d else d["occupancy"].shape
                spacing, origin = d["spacing"], d["origin"]
                affine = d["affine"] if "affine" in d else None
                space = str(d["space"]) if "space" in d else "LPS"
        else:  # .zarr
            with open(os.path.join(path, "zarr.json"), encoding="utf-8") as f:
                info = json.load(f)["attributes"]["geovox"]
            shape, spacing = info["shape"], info["spacing"]
            origin = np.asarray(info["bounds"][0]) + 0.5 * np.asarray(info["spacing"])
            affine, space = info.get("affine"), info.get("space", "LPS")
    except (OSError, KeyError, ValueError, TypeError) as exc:
        raise ParameterError(f"--like {path}: no grid found in this geovox volume "
                             f"({type(exc).__name__}: {exc})") from None
    if affine is None:
        affine = np.eye(4)
        affine[:3, :3] = np.diag(np.asarray(spacing, dtype=np.float64))
        affine[:3, 3] = np.asarray(origin, dtype=np.float64)
    return reference_grid(affine, shape, space, source=path)


# ---------------------------------------------------------------------------
# The mesh's space: 3D Slicer's SPACE= mark.

_MARK = re.compile(rb"SPACE=(RAS|LPS)")


def mesh_space_mark(path) -> str | None:
    """"RAS" or "LPS" from a 3D Slicer ``SPACE=`` mark in a mesh file's header, else None.

    Where Slicer writes it (``vtkMRMLModelStorageNode``): STL's header (the
    80 bytes of a binary STL, the ``solid`` line of an ASCII one), an OBJ's
    leading comment, a PLY ``comment``, a legacy VTK file's title; the text
    is ``3D Slicer output. SPACE=LPS``. Like Slicer, RAS is looked for first.
    Only the header is read: the first 80 bytes of a binary STL, the lines
    before the first vertex of an OBJ, up to ``end_header`` of a PLY, the
    second line of a VTK file.
    """
    if not isinstance(path, (str, os.PathLike)) or not os.path.isfile(path):
        return None
    lower = os.fspath(path).lower()
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return None
    if lower.endswith(".stl"):
        text = head[:80] if not head[:5].lower() == b"solid" else head.split(b"\n", 1)[0]
    elif lower.endswith(".obj"):
        lines = []
        for line in head.splitlines():
            if line.strip() and not line.lstrip().startswith(b"#"):
                break
            lines.append(line)
        text = b"\n".join(lines)
    elif lower.endswith(".ply"):
        end = head.find(b"end_header")
        text = b"\n".join(line for line in head[:end if end >= 0 else None].splitlines()
                          if line.strip().startswith(b"comment"))
    elif lower.endswith(".vtk"):
        parts = head.split(b"\n", 2)
        text = parts[1] if len(parts) > 1 else b""
    else:
        return None
    if b"SPACE=RAS" in text:
        return "RAS"
    return "LPS" if b"SPACE=LPS" in text else None


def resolve_mesh_space(mesh, mesh_space=None) -> tuple:
    """``(space, how)``: the mesh's frame and how it was decided.

    ``how`` is ``"--mesh-space"`` (given), ``"SPACE=... mark"`` (the file's),
    or ``"assumed (no SPACE= mark)"``.
    """
    if mesh_space is not None:
        space = str(mesh_space).upper()
        if space not in ("LPS", "RAS"):
            raise ParameterError(f"`mesh_space` must be 'lps' or 'ras', got {mesh_space!r}")
        return space, "given"
    source = getattr(mesh, "source", None)
    mark = mesh_space_mark(source)
    if mark is not None:
        return mark, f"the file's SPACE={mark} mark"
    if isinstance(source, (str, os.PathLike)) and os.path.isfile(source):
        return "LPS", "assumed: the file has no SPACE= mark"
    return "LPS", "assumed: no file to read a SPACE= mark from"


def to_local(mesh, ref: Reference, space: str):
    """``mesh`` in ref's local frame, from its frame ``space`` (``"LPS"`` or ``"RAS"``).

    The vertices are moved once, in float64. Everything else (faces,
    materials, UVs, colours) is shared with ``mesh``: an affine map keeps
    barycentric coordinates, so colours are unchanged.
    """
    m = ref.world_to_local(space)
    v = mesh.vertices @ m[:3, :3].T + m[:3, 3]
    return dataclasses.replace(mesh, vertices=np.ascontiguousarray(v), _cache={})


def check_reference_options(ref: Reference, options) -> None:
    """Refuse or warn about options a sheared (non-orthogonal) reference cannot give exactly."""
    if ref.orthogonal:
        return
    if options.sdf:
        raise ParameterError(f"--like {ref.source}: the grid's direction cosines are not orthogonal "
                             f"(a sheared grid), so a signed distance in world units cannot be "
                             f"computed on it exactly; drop --sdf")
    if options.color:
        warn(f"{ref.source}: the grid is sheared (direction cosines not orthogonal): colours come "
             f"from the nearest surface point measured in the grid's scaled index space, which "
             f"is not the nearest in world space", stacklevel=3)


def reject_grid_options(**given) -> None:
    """`like` fixes the grid: any of bounds, resolution, shape, voxel_size as well is an error."""
    # fit="box" is the default fit, not a choice; "cube"/"cube-center" are --cube/--cube-center.
    named = [("cube" if given[k] == "cube" else "cube-center") if k == "fit" else k
             for k, v in given.items() if v is not None and not (k == "fit" and v == "box")]
    if named:
        flags = ", ".join("--" + k.replace("_", "-") for k in named)
        raise ParameterError(f"`like` (--like) sets the grid; it cannot be combined with {flags}")


def prepare(mesh, options):
    """``(local mesh, Grid, (space, how))`` for a conversion onto reference ``options.like``.

    The one entry the pipeline, the streamer and the CLI use.
    """
    reject_grid_options(**options.grid_options())
    ref = load_reference(options.like)
    check_reference_options(ref, options)
    used = resolve_mesh_space(mesh, options.mesh_space)
    return to_local(mesh, ref, used[0]), ref.local_grid(), used


def field_of_view(mesh, ref: Reference, options) -> dict:
    """How much of ``mesh`` lies in ``ref``'s field of view (the voxels' extent).

    Returns
    -------
    dict with ``space``, ``how``, ``vertices_inside`` (fraction of the used
    vertices), ``area_inside`` (fraction of the surface area, by each
    triangle's centroid), ``inside`` ("all", "part", "around": no surface inside but
    the boxes meet, or "none") and the mesh's
    extent in index coordinates ``index_lo``, ``index_hi``; the mesh's frame
    is ``options.mesh_space``'s (see :func:`resolve_mesh_space`).
    """
    space, how = resolve_mesh_space(mesh, options.mesh_space)
    moved = to_local(mesh, ref, space)
    s = ref.spacing
    lo, hi = -0.5 * s, (np.asarray(ref.shape) - 0.5) * s
    t = moved.triangles
    used = np.unique(moved.faces)
    v = moved.vertices[used]
    vin = np.all((v >= lo) & (v <= hi), axis=1)
    c = t.mean(axis=1)
    cin = np.all((c >= lo) & (c <= hi), axis=1)
    area = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    total = float(area.sum()) or 1.0
    frac_v = float(vin.mean())
    inside = ("all" if vin.all() else "part" if vin.any() or cin.any()
              else "around" if _boxes_meet(v, lo, hi) else "none")
    return {"space": space, "how": how, "vertices_inside": frac_v,
            "area_inside": float(area[cin].sum()) / total, "inside": inside,
            "index_lo": (v.min(axis=0) / s).tolist(), "index_hi": (v.max(axis=0) / s).tolist()}


def _boxes_meet(v, lo, hi) -> bool:
    return bool(np.all(v.min(axis=0) <= hi) and np.all(v.max(axis=0) >= lo))


def format_field_of_view(ref: Reference, fov: dict) -> str:
    """The lines ``geovox info --like`` prints."""
    nx, ny, nz = ref.shape
    dx, dy, dz = ref.spacing
    lines = [f"reference {os.path.basename(ref.source)}: grid {nx} x {ny} x {nz}, voxel "
             f"{dx:.6g} x {dy:.6g} x {dz:.6g}, {ref.space}"
             f"{'' if ref.orthogonal else ', sheared (direction cosines not orthogonal)'}",
             f"mesh space {fov['space']} ({fov['how']})"]
    if fov["inside"] == "all":
        lines.append("field of view: the whole mesh lies inside the image")
    elif fov["inside"] == "none":
        lines.append("field of view: the mesh lies entirely outside the image; the volume "
                     "would be empty (check --mesh-space)")
    elif fov["inside"] == "around":
        lines.append("field of view: no part of the mesh's surface lies inside the image, but its "
                     "bounding box meets the image (the image may lie inside the mesh)")
    else:
        lines.append(f"field of view: part of the mesh lies inside the image: "
                     f"{100 * fov['vertices_inside']:.1f}% of its vertices, "
                     f"{100 * fov['area_inside']:.1f}% of its surface area")
    lines.append("mesh in voxel indices (" + ", ".join(f"{x:.1f}" for x in fov["index_lo"])
                 + ") .. (" + ", ".join(f"{x:.1f}" for x in fov["index_hi"]) + ")")
    return "\n".join(lines)
