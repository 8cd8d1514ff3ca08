"""Labelled volumes: which part, component, material, file or feature is in each voxel.

A label source gives every face a label (:func:`label_set`); then each
part is classified by its own inside test on the shared grid
(:func:`classify`): parity where the part is closed and its pieces do not
overlap, the winding number otherwise, as ``inside="auto"`` chooses for a
whole mesh. For the parity parts the rays are cast once, for the whole
mesh, and the crossings are split by the part of the triangle they cross;
each part is filled only over the box of voxels its crossings reach, so a
small part costs little however large the grid.

Where parts overlap, the ``overlap`` rule decides: ``"last"`` (later parts
in file order paint over earlier ones), ``"first"``, or ``"smallest"`` (the
part with the smaller enclosed volume wins; equal volumes: the later part).
A voxel has label ``k`` exactly where part ``k`` is inside and no part that
wins over it is. Label 0 is the background.

``"material"`` is different: the inside is the whole mesh's, and each
inside voxel takes the material of the face holding its exact nearest
surface point (the search exact colour uses, :mod:`geovox.nearest.search`).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from . import parity
from .errors import MeshError, ParameterError, collect_warnings, warn
from .mesh import Mesh
from .options import Inside, LabelSource, Occupancy, Overlap

#: Label sources, in the order the CLI lists them.
SOURCES = tuple(LabelSource)
#: Overlap rules.
OVERLAPS = tuple(Overlap)
#: The most labels a volume can hold (uint16, 0 the background).
MAX_LABELS = 65535

# Distinct colours for parts, components and files (the "tab20" palette's
# first ten, then its light variants); beyond them, hues by the golden ratio.
_PALETTE = np.array([
    (31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
    (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207),
    (174, 199, 232), (255, 187, 120), (152, 223, 138), (255, 152, 150), (197, 176, 213),
    (196, 156, 148), (247, 182, 210), (199, 199, 199), (219, 219, 141), (158, 218, 229),
], dtype=np.uint8)


@dataclass
class LabelSet:
    """What a label source makes of a mesh.

    Attributes
    ----------
    source : str
        One of :data:`SOURCES`.
    names : list of str
        One per label, label value ``k + 1`` for ``names[k]``.
    face_label : (m,) int64
        Each face's label index ``0 .. len(names) - 1``.
    colors : (L, 4) uint8
        RGBA per label.
    overlap : str
        Which part a voxel inside several takes (:data:`OVERLAPS`; the
        option ``overlap``, which the plan sets here).
    methods : tuple of str
        Each part's inside test (``"parity"``, ``"vote"``, ``"winding"``),
        chosen once by the plan (:func:`geovox.plan`) on the part alone;
        empty for ``"material"``.
    """

    source: str
    names: list
    face_label: np.ndarray
    colors: np.ndarray
    overlap: str = "last"
    methods: tuple = ()

    @property
    def dtype(self):
        """uint8 for up to 255 labels, else uint16."""
        return np.dtype(np.uint8 if len(self.names) <= 255 else np.uint16)


def palette(n: int) -> np.ndarray:
    """(n, 4) uint8: distinct opaque colours, the same for the same ``n``."""
    out = np.empty((n, 4), dtype=np.uint8)
    out[:, 3] = 255
    k = min(n, len(_PALETTE))
    out[:k, :3] = _PALETTE[:k]
    if n > k:
        import colorsys

        for i in range(k, n):
            h = (i * 0.618033988749895) % 1.0
            out[i, :3] = np.rint(np.array(colorsys.hsv_to_rgb(h, 0.65, 0.9)) * 255)
    return out


def components(mesh: Mesh) -> np.ndarray:
    """(m,) int64: each face's connected component, after merging vertices by position.

    Faces sharing a vertex position are connected; components are numbered
    by their first face. (NumPy's union-find of :func:`geovox.inside.repair.components`,
    not scipy's csgraph, whose import alone cost 0.2-2 s of a labelled conversion.)
    """
    from .inside.repair import components as graph_components

    f = mesh.geometric_faces
    n = int(f.max()) + 1
    _, vertex_comp, _ = graph_components(n, np.concatenate([f[:, 0], f[:, 1]]),
                                         np.concatenate([f[:, 1], f[:, 2]]))
    raw = vertex_comp[f[:, 0]]
    # Renumbered in order of first face.
    _, first, inverse = np.unique(raw, return_index=True, return_inverse=True)
    rank = np.empty(len(first), dtype=np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return rank[inverse.reshape(-1)]


def label_set(mesh: Mesh, source: str, *, stacklevel: int = 3) -> LabelSet:
    """The labels ``source`` gives ``mesh`` (see the module notes).

    ``"part"`` on a mesh whose file names no parts warns and falls back to
    ``"component"``, as does ``"feature"`` on a mesh without feature IDs
    (:attr:`Mesh.face_feature`; see :func:`feature_labels`). ``"file"`` on a
    mesh that is not a scene of files (:func:`scene`) gives one label, named
    after the file's stem.

    Raises
    ------
    ParameterError
        More than :data:`MAX_LABELS` labels.
    """
    key = ("labels", source)
    if key in mesh._cache:
        return mesh._cache[key]
    if source == "part" and mesh.face_part is None:
        warn(f"{mesh.source}: the file names no parts (OBJ objects or groups, scene nodes); "
             f"labelling its connected components instead", stacklevel=stacklevel)
        source = "component"
    if source == "feature" and mesh.face_feature is None:
        warn(f"{mesh.source}: the file has no feature IDs (glTF EXT_mesh_features); "
             f"labelling its connected components instead", stacklevel=stacklevel)
        source = "component"
    if source == "feature":
        face_label, names = feature_labels(mesh.face_feature)
        colors = palette(len(names))
        # What the reader could not read of them (IDs in textures), which the
        # mesh's problems otherwise say only with colour.
        for problem in mesh.problems:
            if "feature IDs" in problem:
                warn(problem, stacklevel=stacklevel)
    elif source == "component":
        face_label = components(mesh)
        names = [f"component {k + 1}" for k in range(int(face_label.max()) + 1)]
        colors = palette(len(names))
    elif source in ("part", "file"):
        if source == "file" and "files" in mesh._cache:
            face_label, names = mesh._cache["files"]
        elif source == "file":
            face_label, names = np.zeros(len(mesh.faces), np.int64), [_stem(mesh.source)]
        else:
            face_label, names = mesh.face_part, list(mesh.parts)
        colors = palette(len(names))
    else:  # material
        fm = mesh.face_material if mesh.face_material is not None else \
            np.full(len(mesh.faces), -1, np.int64)
        names = [m.name for m in mesh.materials]
        face_label = fm.astype(np.int64)
        colors = np.empty((len(names), 4), dtype=np.uint8)
        colors[:, 3] = 255
        for k, m in enumerate(mesh.materials):
            colors[k, :3] = np.rint(np.clip(m.diffuse(), 0, 1) * 255)
        if np.any(face_label < 0):
            face_label = np.where(face_label < 0, len(names), face_label)
            names.append("(no material)")
            colors = np.vstack([colors, [[204, 204, 204, 255]]]).astype(np.uint8)
    if len(names) > MAX_LABELS:
        raise ParameterError(f"`labels={source!r}` gives {len(names):,} labels; a label volume "
                             f"holds at most {MAX_LABELS:,}")
    out = LabelSet(source=source, names=names, face_label=np.asarray(face_label, np.int64),
                   colors=colors)
    mesh._cache[key] = out
    return out


def feature_labels(face_feature: np.ndarray):
    """``(face_label, names)`` of faces' feature IDs: one label per distinct ID, in ID order.

    Parameters
    ----------
    face_feature : (m,) int64
        Each face's feature ID; -1 for none.

    Returns
    -------
    face_label : (m,) int64
        Index into ``names``; faces without a feature take the last label,
        ``"(no feature)"``, which is there only when some face has none.
    names : list of str
        ``"feature 7"`` for ID 7.
    """
    ids = np.unique(face_feature[face_feature >= 0])
    names = [f"feature {int(i)}" for i in ids]
    face_label = np.searchsorted(ids, face_feature).astype(np.int64)
    if np.any(face_feature < 0):
        face_label[face_feature < 0] = len(names)
        names.append("(no feature)")
    return face_label, names


def _stem(path: str) -> str:
    base = os.path.basename(str(path))
    for ext in (".gz", ".zip"):
        if base.lower().endswith(ext):
            base = base[:-len(ext)]
    return os.path.splitext(base)[0] or base


def scene(sources, options=None) -> Mesh:
    """One mesh of several files (or meshes), each file's faces a label for ``"file"``.

    Each file is read by :func:`geovox.io.load.load_mesh` as ``options`` (an
    :class:`~geovox.Options`; default its defaults) say: the rule
    ``references``.

    The files' parts are kept as ``"stem: part"`` for ``labels="part"``, and
    their materials for ``"material"``.

    Raises
    ------
    MeshError
        A file in the scene is not a mesh (the message names it).
    InputNotFoundError
        A file does not exist.
    """
    from .io.load import load_mesh

    rule = "anywhere" if options is None else options.references
    most = None if options is None else options.max_input_size
    meshes = []
    for s in sources:
        try:
            meshes.append(load_mesh(s, references=rule, max_input_size=most))
        except MeshError as exc:
            raise MeshError(f"in the scene: {exc}") from exc
    if not meshes:
        raise ParameterError("a scene needs at least one mesh")
    if len(meshes) == 1:
        return meshes[0]
    verts, faces, fm, mats, fp, parts, uvs, vcs = [], [], [], [], [], [], [], []
    offset = 0
    any_feature = any(m.face_feature is not None for m in meshes)
    ff = [m.face_feature if m.face_feature is not None else np.full(len(m.faces), -1, np.int64)
          for m in meshes] if any_feature else []
    stems = [_stem(m.source) for m in meshes]
    any_uv = any(m.corner_uv is not None for m in meshes)
    any_vc = any(m.vertex_colors is not None for m in meshes)
    for m, stem in zip(meshes, stems):
        verts.append(m.vertices)
        faces.append(m.faces + offset)
        offset += len(m.vertices)
        own = m.face_material if m.face_material is not None else np.full(len(m.faces), -1)
        fm.append(np.where(own >= 0, own + len(mats), -1))
        mats.extend(m.materials)
        if m.face_part is None:
            fp.append(np.full(len(m.faces), len(parts), np.int64))
            parts.append(stem)
        else:
            fp.append(m.face_part + len(parts))
            parts.extend(f"{stem}: {p}" for p in m.parts)
        if any_uv:
            uvs.append(m.corner_uv if m.corner_uv is not None else
                       np.full((len(m.faces), 3, 2), np.nan))
        if any_vc:
            vcs.append(m.vertex_colors if m.vertex_colors is not None else
                       np.ones((len(m.vertices), 3)))
    out = Mesh(vertices=np.concatenate(verts), faces=np.concatenate(faces),
               source=" + ".join(os.path.basename(str(m.source)) for m in meshes),
               face_material=np.concatenate(fm).astype(np.int64), materials=mats,
               corner_uv=np.concatenate(uvs) if any_uv else None,
               vertex_colors=np.concatenate(vcs) if any_vc else None,
               problems=[p for m in meshes for p in m.problems],
               face_part=np.concatenate(fp), parts=parts,
               face_feature=np.concatenate(ff) if any_feature else None)
    out._cache["files"] = (np.repeat(np.arange(len(meshes), dtype=np.int64),
                                     [len(m.faces) for m in meshes]), stems)
    return out


def part_mesh(mesh: Mesh, faces: np.ndarray, name: str) -> Mesh:
    """The sub-mesh of ``mesh`` made of the faces ``faces`` (indices), with its own vertices.

    Its vertices are the ones its faces use, so the per-part checks cost the
    part's size, not the whole mesh's; its merge by position is the whole
    mesh's, renumbered in the same (lexicographic) order.
    """
    f = mesh.faces[faces]
    used, inverse = np.unique(f, return_inverse=True)
    fm = None if mesh.face_material is None else mesh.face_material[faces]
    uv = None if mesh.corner_uv is None else mesh.corner_uv[faces]
    vc = None if mesh.vertex_colors is None else mesh.vertex_colors[used]
    part = Mesh(vertices=mesh.vertices[used], faces=inverse.reshape(f.shape).astype(np.int64),
                source=f"{mesh.source} [{name}]", face_material=fm, materials=mesh.materials,
                corner_uv=uv, vertex_colors=vc)
    _, merged = np.unique(mesh.geometric_faces[faces], return_inverse=True)
    part._cache["geometric_faces"] = merged.reshape(f.shape).astype(np.int64)
    return part


def enclosed_volume(mesh: Mesh) -> float:
    """|signed volume| of the triangles (the enclosed volume of a closed, wound part)."""
    t = mesh.triangles
    return abs(float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum()) / 6.0)


def paint_order(lset: LabelSet, parts: list) -> list:
    """Label indices in the order they are painted: ``lset.overlap``'s winner last."""
    n = len(lset.names)
    if lset.overlap == "last":
        return list(range(n))
    if lset.overlap == "first":
        return list(range(n))[::-1]
    vols = [enclosed_volume(p) if p is not None else 0.0 for p in parts]
    # Largest first, so the smallest paints last; equal volumes: the later part wins.
    return sorted(range(n), key=lambda k: (-vols[k], k))


def _box_fill(hits, columns, grid, lo_ray, z0: int = 0, jobs=1):
    """A part's parity occupancy over the box of voxels its crossings reach.

    The toggles are those of :func:`geovox.parity.toggle_indices` (the same
    ``searchsorted`` rule on the same depths), so the box's voxels equal the
    whole grid's fill of these crossings; voxels outside the box are outside
    (no crossing reaches their columns, or their ray has passed an even
    number of crossings beyond the box).

    ``z0``: ``grid`` is a z-block from layer ``z0`` of the whole grid whose
    rays (along z) and voxel centres ``lo_ray`` these are: a crossing's
    layer is found in the whole grid, then moved into the block (the layers
    below it toggle its first layer), an exact integer step.

    Returns
    -------
    (slices, occupancy) : tuple of 3 slice, (bx, by, bz) bool, or None where
    no crossing lands in the grid.
    """
    axis = columns.axis
    n = grid.shape[axis]
    k = np.searchsorted(lo_ray, hits.depth, side="left")
    if z0:
        k = np.maximum(k - z0, 0)
    keep = k < n
    k = k[keep].astype(np.int64)
    ray = hits.ray[keep]
    if len(k) == 0:
        return None
    idx = [None, None, None]
    idx[columns.u_axis] = ray % columns.nu
    idx[columns.v_axis] = ray // columns.nu
    idx[axis] = k
    lo = [int(i.min()) for i in idx]
    hi = [int(i.max()) + 1 for i in idx]
    # A ray with an odd count stays inside to the grid's end, as in the full fill.
    odd = np.bincount(ray, minlength=columns.nu * columns.nv) & 1
    if odd.any():
        hi[axis] = n
    shape = tuple(h - l for l, h in zip(lo, hi))
    # x padded to whole 8-byte words: the running XOR then takes eight columns a word
    # (parity's own fill, 3-4 times faster than a byte-wise accumulate).
    nx = -(-shape[0] // 8) * 8
    lin = (idx[0] - lo[0]) + nx * ((idx[1] - lo[1]) + shape[1] * (idx[2] - lo[2]))
    lin.sort()
    starts = np.flatnonzero(np.r_[True, lin[1:] != lin[:-1]])
    odd_voxel = lin[starts[np.diff(np.r_[starts, len(lin)]) % 2 == 1]]
    t = np.zeros((nx,) + shape[1:], dtype=bool, order="F")
    t.reshape(-1, order="F")[odd_voxel] = True
    parity.running_xor(t, axis, jobs)
    return tuple(slice(l, h) for l, h in zip(lo, hi)), t[:shape[0]]


@dataclass
class Classified:
    """One block's labels.

    Attributes
    ----------
    labels : (nx, ny, nz) uint8 or uint16, Fortran order
    contested : int
        Voxels inside more than one part.
    methods : list of str
        The inside test each label's part ran (``"parity"``, ``"winding"``).
    crossings : (Hits, Columns) or None
        The whole mesh's crossings along the ray axis on the block (for
        colour); None where they were the whole grid's (``within``).
    approximate : int
        Voxels the parts' winding numbers left to an estimate (the work
        budget ran out), summed over the parts.
    inside : int or None
        With surface voxels joined to the parts' solids: the voxels inside
        some part (None otherwise).
    """

    labels: np.ndarray
    contested: int
    methods: list
    crossings: tuple
    approximate: int = 0
    inside: int | None = None


def part_meshes(mesh: Mesh, lset: LabelSet) -> list:
    """Each label's part of ``mesh`` (a Mesh of its faces), None for a label without faces.

    By components, each part is one whole connected component: a single
    piece, whose boxes cannot overlap, which its cache says (known without a
    search). Other parts' pieces are found by ``inside.choose`` on the part
    alone (linear in the part), cheaper than searching the whole mesh's
    components first.
    """
    from .inside import non_manifold

    n = len(lset.names)
    by_face = np.argsort(lset.face_label, kind="stable")
    cuts = np.searchsorted(lset.face_label[by_face], np.arange(n + 1))
    comp = lset.face_label if lset.source == "component" else None
    comp_size = None if comp is None else np.bincount(comp)
    parts = []
    for k in range(n):
        faces = by_face[cuts[k]:cuts[k + 1]]
        part = part_mesh(mesh, faces, lset.names[k]) if len(faces) else None
        if part is not None and comp is not None and comp_size[comp[faces[0]]] == len(faces) \
                and not non_manifold(part):
            part._cache["overlap"] = False
        parts.append(part)
    return parts


def classify(mesh: Mesh, grid, lset: LabelSet, *, cast_mesh, axis: int, jobs: int = 1,
             within=None, surface=None) -> Classified:
    """Each part by its own inside test (``lset.methods``, the plan's), overlaps by ``lset.overlap``.

    Parameters
    ----------
    mesh : Mesh
        The whole model.
    grid : Grid
        The block's grid.
    lset : LabelSet
        Its ``face_label`` gives the parts (not ``"material"``).
    cast_mesh : callable
        ``cast_mesh(mesh, axis, on=grid) -> (Hits, Columns)`` on grid ``on``
        (rays from outside the mesh, see :func:`geovox.block.ray_start`).
    axis, jobs
        As for :func:`geovox.voxelize`.
    within : (Grid, (z0, z1)), optional
        The whole grid, where ``grid`` is its block ``z0 .. z1``. With rays
        along z the parity parts take the whole grid's rays and crossings
        (its depths, its voxel centres) and move them into the block by
        whole layers (:func:`_box_fill`), so a block's labels are the whole
        grid's exactly, ties on the surface included.
    surface : (Occupancy, callable) or None
        With surface voxels (``occupancy="surface"`` or ``"both"``):
        ``surface_of(part) -> (nx, ny, nz) bool``, each part's surface voxels
        on the block, which are the part's own (``"surface"``) or join its
        solid (``"both"``) before the overlap rule settles shared voxels.
    """
    from . import inside as inside_tests

    n = len(lset.names)
    kind, surface_of = surface if surface is not None else (None, None)
    parts, methods = part_meshes(mesh, lset), list(lset.methods)
    if len(methods) != n and kind != Occupancy.SURFACE:
        raise ValueError("classify needs the parts' inside tests the plan chooses "
                         "(LabelSet.methods)")
    z0, frame = 0, grid
    if within is not None and axis == 2 and tuple(within[1]) != (0, within[0].shape[2]):
        frame, z0 = within[0], int(within[1][0])
    hits = columns = None
    if kind != Occupancy.SURFACE:  # surface voxels alone cast no ray
        hits, columns = cast_mesh(mesh, axis, frame)
        part_of_hit = lset.face_label[hits.triangle]
        by_part = np.argsort(part_of_hit, kind="stable")
        hcuts = np.searchsorted(part_of_hit[by_part], np.arange(n + 1))
    lo_ray = (np.arange(frame.shape[axis]) + 0.5) * frame.spacing[axis]
    labels = np.zeros(grid.shape, dtype=lset.dtype, order="F")
    # Parts inside each voxel (it cannot wrap: a uint8 count for at most 255 parts).
    inside_count = np.zeros(grid.shape, dtype=lset.dtype, order="F")
    approximate = 0
    solid_union = None
    if kind == Occupancy.BOTH:
        solid_union = np.zeros(grid.shape, dtype=bool, order="F")
    for k in paint_order(lset, parts):
        if parts[k] is None:
            continue
        if kind == Occupancy.SURFACE:
            box, occ = (slice(None),) * 3, surface_of(parts[k])
        elif methods[k] == Inside.PARITY:
            got = _box_fill(hits.take(by_part[hcuts[k]:hcuts[k + 1]]), columns, grid, lo_ray,
                            z0, jobs)
            if got is None:
                continue
            box, occ = got
        elif methods[k] == Inside.VOTE:
            votes = sum(parity.fill(*cast_mesh(parts[k], a), grid, jobs=jobs).view(np.uint8)
                        for a in range(3))
            box, occ = (slice(None),) * 3, votes >= 2
        else:
            with collect_warnings(drop=True):
                occ, _, _, guessed = inside_tests.winding_occupancy(parts[k], grid, cast_mesh,
                                                                    axis, jobs)
            approximate += guessed
            box = (slice(None),) * 3
        if kind == Occupancy.BOTH:
            # The part's solid joins its surface voxels: the whole grid's box.
            whole = surface_of(parts[k])
            np.logical_or(solid_union[box], occ, out=solid_union[box])
            np.logical_or(whole[box], occ, out=whole[box])
            box, occ = (slice(None),) * 3, whole
        # One add and one masked copy per part (a mask index is slower).
        np.add(inside_count[box], occ, out=inside_count[box])
        np.copyto(labels[box], lset.dtype.type(k + 1), where=occ)
    contested = int(np.count_nonzero(inside_count >= 2))
    if approximate:  # the parts' own warnings were silenced: this one is said
        from .inside.winding import approximate_warning

        warn(approximate_warning(approximate, grid.size), stacklevel=3)
    return Classified(labels=labels, contested=contested, methods=methods,
                      crossings=(hits, columns) if frame is grid and hits is not None else None,
                      approximate=approximate,
                      inside=None if solid_union is None else int(np.count_nonzero(solid_union)))


def table(lset: LabelSet, labels: np.ndarray, spacing, counts=None) -> list:
    """The label table: one dict per value, the background (0) first.

    Each entry: ``value`` int, ``name`` str, ``source`` str, ``color``
    [r, g, b, a] int 0-255, ``voxels`` int, ``volume`` float (model units³).
    ``counts`` (L + 1,) int64 replaces the count of ``labels``' values.
    """
    if counts is None:
        counts = label_counts(labels, len(lset.names))
    cell = float(np.prod(np.asarray(spacing, dtype=np.float64)))
    out = [{"value": 0, "name": "background", "source": lset.source, "color": [0, 0, 0, 0],
            "voxels": int(counts[0]), "volume": float(counts[0]) * cell}]
    for k, name in enumerate(lset.names):
        out.append({"value": k + 1, "name": str(name), "source": lset.source,
                    "color": [int(c) for c in lset.colors[k]], "voxels": int(counts[k + 1]),
                    "volume": float(counts[k + 1]) * cell})
    return out


def label_counts(labels: np.ndarray, n: int) -> np.ndarray:
    """(n + 1,) int64: voxels per label value."""
    flat = labels.ravel(order="K")
    counts = np.zeros(n + 1, dtype=np.int64)
    # In pieces: bincount widens its input to intp, a grid-sized copy at once.
    for s in range(0, len(flat), 1 << 20):
        counts += np.bincount(flat[s:s + (1 << 20)], minlength=n + 1)[:n + 1]
    return counts


def _label_output(search, rgba: np.ndarray, lset: LabelSet) -> None:
    """Let the compiled search write each voxel's label (its nearest face's) into ``rgba``.

    Label value ``v`` is the constant colour with red byte ``v & 255`` and
    green byte ``v >> 8`` (``add`` rows of exactly ``byte / 255``, no factor,
    no texture: the kernel's rounding gives the bytes back), and the faces of
    one label share one key, so the kernel's constant-colour cells apply.
    """
    n = len(lset.names)
    values = np.arange(1, n + 1, dtype=np.int64)
    add = np.zeros((n, 3))
    add[:, 0], add[:, 1] = (values & 255) / 255.0, (values >> 8) / 255.0
    search.colour_output(rgba, lset.face_label.astype(np.int32), None, None, np.zeros((n, 3)),
                         add, np.zeros((n, 7), np.int32), np.zeros(n, np.int64),
                         np.zeros(1, np.uint8))
    search.same_colours(np.ascontiguousarray(lset.face_label, dtype=np.int64),
                        values.astype(np.uint32) | np.uint32(255 << 24))


def material_labels(mesh: Mesh, grid, occupancy: np.ndarray, lset: LabelSet, *, frame,
                    jobs: int = 1) -> np.ndarray:
    """Each inside voxel's label: the material of its exact nearest surface point.

    The search is exact colour's (:func:`geovox.nearest.search.nearest_inside`, with
    its tie rule between faces); faces of one material are interchangeable,
    so the NumPy search need not tell them apart.

    Parameters
    ----------
    occupancy : (nx, ny, nz) bool
        The block's inside voxels.
    frame : (lo, spacing, z0)
        The whole grid's low corner and voxel size, and the block's first layer.

    Returns
    -------
    labels : (nx, ny, nz) uint8 or uint16, Fortran order; 0 outside.
    """
    from .nearest.search import kernel_module, nearest_inside, run_kernel

    nx, ny, _ = grid.shape
    labels = np.zeros(grid.shape, dtype=lset.dtype, order="F")
    flat = labels.reshape(-1, order="F")  # a view: Fortran order
    value = (lset.face_label + 1).astype(lset.dtype)
    if len(lset.names) == 1:
        flat[occupancy.reshape(-1, order="F")] = 1
        return labels

    lo, spacing, z0 = frame
    module = kernel_module()
    if module is not None:
        # The compiled search "shades" each voxel with its nearest face's label: every
        # material is a constant colour whose red and green bytes are the label value,
        # so cells whose candidates are all of one material take it without finishing
        # the search (Kernel.same_colours, as exact colour does for constant colours),
        # and the answer is 4 bytes a voxel, not the raw output's 20.
        rgba = np.zeros(occupancy.size, np.uint32)
        run_kernel(module, mesh.triangles, occupancy, spacing, origin=lo, z0=z0, jobs=jobs,
                   output=lambda k: _label_output(k, rgba, lset))
        inside = np.asarray(occupancy, bool).reshape(-1, order="F")
        flat[inside] = (rgba[inside] & np.uint32(0xFFFF)).astype(lset.dtype)
        return labels

    def emit(vox, tri, uv):
        flat[vox[:, 0] + nx * (vox[:, 1] + ny * vox[:, 2])] = value[tri]

    nearest_inside(mesh.triangles, occupancy, spacing, origin=lo, z0=z0, jobs=jobs, emit=emit,
                   same=lset.face_label)
    return labels


def _signed_volume(mesh: Mesh) -> float:
    t = mesh.triangles
    return float(np.einsum("ij,ij->i", t[:, 0], np.cross(t[:, 1], t[:, 2])).sum())


def _open_crossings(part: Mesh, engine, sub, axis: int, jobs: int):
    """``(hits, sign)`` of an open (or inconsistently wound) part's own inside test: the
    crossings of its repaired, capped copy (what its labels' winding number and its own
    ``density="coverage"`` are taken from), each signed +1 where it enters the copy."""
    from .inside import capped, crossing_signs, target

    closed = capped(target(part)[0])[0]
    hits = engine.cast(closed, sub, jobs=jobs)
    flip = -1 if _signed_volume(closed) < 0 else 1
    return hits, crossing_signs(closed, hits, axis) * flip


def label_fractions(mesh: Mesh, grid, lset: LabelSet, run, *, supersample: int = 4,
                    dtype: str = "uint8") -> np.ndarray:
    """Each label's coverage fraction per voxel, overlaps settled by ``lset.overlap``.

    From ``supersample`` x ``supersample`` rays per column (as
    ``density="coverage"``), cast once for the whole mesh. The parts are
    taken winners first: ``U_j`` is the coverage of the union of the ``j``
    strongest parts (inside where their summed winding number, each part's
    crossings signed so that it counts +1 inside itself, is not 0), and the
    ``j``-th part's fraction is ``U_j - U_{j-1}``. So a voxel's fractions sum
    to its union coverage (at most 1), and where only one part is near, its
    fraction is its own ``density="coverage"``. uint8 fractions are
    differences of the rounded ``255 * U_j``, so they too sum to the rounded
    union.

    Each part counts by the inside test its label uses: a closed,
    consistently wound part by its crossings in the whole mesh's cast; an
    open one by those of its repaired, capped copy (cast once more, for that
    part alone), so its fraction is the coverage of the voxels its label
    calls inside.

    ``run`` (:class:`BlockRun`) gives the engine, the ray axis, the threads,
    where the rays start and ``within`` = ``(whole grid, (z0, z1))``: ``grid``
    is that z-block of the whole grid. With rays along z the block's rays are the whole grid's
    (the same crossings, depths from the whole grid's low face) and its
    coverage is carried in from below (``coverage(layers=...)``), so the
    block's fractions are the whole grid's, bit for bit; along x or y a
    block's rays are its own.

    Returns
    -------
    (nx, ny, nz, L) uint8 (0-255) or float32 (0-1); index ``k`` is label ``k + 1``.
    """
    from .backends.base import Hits
    from .density import coverage, sub_columns
    from .inside import consistent, crossing_signs

    engine, axis, start, jobs, within = run.engine, run.axis, run.start, run.jobs, run.within
    n = len(lset.names)
    by_face = np.argsort(lset.face_label, kind="stable")
    cuts = np.searchsorted(lset.face_label[by_face], np.arange(n + 1))
    parts = [part_mesh(mesh, by_face[cuts[k]:cuts[k + 1]], lset.names[k])
             if cuts[k + 1] > cuts[k] else None for k in range(n)]
    flip = np.array([-1 if p is not None and _signed_volume(p) < 0 else 1 for p in parts],
                    dtype=np.int64)
    layers = None
    if within is not None and axis == 2 and tuple(within[1]) != (0, within[0].shape[2]):
        grid, layers = within[0], tuple(within[1])
    sub = sub_columns(grid.columns(axis, start=start), supersample)
    own = {k: _open_crossings(p, engine, sub, axis, jobs) for k, p in enumerate(parts)
           if p is not None and not consistent(p)}
    hits = engine.cast(mesh, sub, jobs=jobs)
    part_of = lset.face_label[hits.triangle]
    sign = crossing_signs(mesh, hits, axis) * flip[part_of]
    shape = grid.shape if layers is None else grid.shape[:2] + (layers[1] - layers[0],)
    out = np.zeros(tuple(shape) + (n,), dtype=np.float32 if dtype == "float32" else np.uint8,
                   order="F")
    included = np.zeros(n, dtype=bool)
    from_whole = np.array([k not in own for k in range(n)], dtype=bool)
    prev = None
    for k in reversed(paint_order(lset, parts)):
        if parts[k] is None:
            continue
        included[k] = True
        sel = (included & from_whole)[part_of]
        mine = [own[j] for j in sorted(own) if included[j]]
        if mine:
            union = Hits.concatenate([hits.take(sel)] + [h for h, _ in mine])
            signs = np.concatenate([sign[sel]] + [g for _, g in mine])
        else:
            union, signs = hits.take(sel), sign[sel]
        cov = coverage(union, sub, grid, supersample, jobs, sign=signs, layers=layers)
        if dtype != "float32":
            cov = np.rint(cov * np.float32(255.0)).astype(np.int16)
        out[..., k] = cov if prev is None else np.maximum(cov - prev, 0)
        prev = cov
    return out


def label_colours(labels: np.ndarray, table: list) -> np.ndarray:
    """(nx, ny, nz, 4) uint8: each voxel in its label's table colour (alpha 0 outside)."""
    n = max(int(e["value"]) for e in table) + 1
    lut = np.zeros((n, 4), dtype=np.uint8)
    for e in table:
        lut[int(e["value"])] = e["color"]
    lut[0] = 0
    return lut[labels]


def parts_report(mesh: Mesh, sources=("part", "component", "material", "feature"),
                 most: int = 12) -> str:
    """What each label source would give ``mesh``: per label its name, triangles,
    whether it is closed, and its materials (the first ``most`` labels of each)."""
    from .inside import boundary_edges

    lines = []
    for source in sources:
        if source == "part" and mesh.face_part is None:
            lines.append("labels part: the file names no parts (falls back to component)")
            continue
        if source == "feature" and mesh.face_feature is None:
            continue  # said only for a file that has feature IDs
        with collect_warnings(drop=True):
            lset = label_set(mesh, source)
        lines.append(f"labels {source}: {len(lset.names):,}")
        for k, name in enumerate(lset.names[:most]):
            faces = np.flatnonzero(lset.face_label == k)
            part = part_mesh(mesh, faces, name)
            closed = "closed" if len(boundary_edges(part)) == 0 else "open"
            mats = ""
            if source != "material" and mesh.face_material is not None and mesh.materials:
                used = np.unique(mesh.face_material[faces])
                names = [mesh.materials[i].name for i in used if i >= 0]
                mats = f", materials {', '.join(names[:4])}{', ...' if len(names) > 4 else ''}" \
                    if names else ""
            lines.append(f"  {k + 1:>5}  {name}: {len(faces):,} triangles, {closed}{mats}")
        if len(lset.names) > most:
            lines.append(f"  ... and {len(lset.names) - most:,} more")
    return "\n".join(lines)


@dataclass(frozen=True)
class LabelStage:
    """Labels as one stage of a conversion: built once by the plan, run per block like colour.

    Attributes
    ----------
    set : LabelSet
        What each label is; by parts, each part's inside test (``methods``),
        chosen once here on the part alone; the overlap rule.
    fractions : bool
        Also each label's coverage fraction per voxel (:func:`label_fractions`).
    dtype : str
        The fractions' dtype: ``"uint8"`` (255 x fraction) or ``"float32"``.
    supersample : int
        The fractions' rays per voxel column, per axis.
    option : str
        The label source asked for (``Options.labels``; ``set.source`` may
        differ where ``"part"`` fell back to components), as the summary says it.
    """

    set: LabelSet
    fractions: bool = False
    dtype: str = "uint8"
    supersample: int = 4
    option: str = ""

    @classmethod
    def build(cls, mesh: Mesh, options, methods=()) -> "LabelStage":
        """The stage ``options`` (an :class:`~geovox.Options` with ``labels``) make of ``mesh``.

        ``methods``: by parts, each part's inside test (the plan's choice, see
        :func:`part_meshes`); empty for materials.
        """
        import dataclasses

        # The overlap rule and the parts' tests travel with the labels (paint_order reads it).
        lset = dataclasses.replace(label_set(mesh, options.labels, stacklevel=5),
                                   overlap=options.overlap, methods=tuple(methods))
        return cls(set=lset, fractions=bool(options.fractions), dtype=options.density_dtype,
                   supersample=int(options.supersample), option=str(options.labels))

    @property
    def by_parts(self) -> bool:
        """Whether the parts give the occupancy, each by its own inside test (not materials)."""
        return self.set.source != LabelSource.MATERIAL

    def working_bytes(self) -> float:
        """Bytes a voxel of a labelled block takes beside the occupancy, at its peak.

        The labels (1 or 2 bytes), the voxels seen once and twice, and a part's
        box of toggles and occupancy (at most the block's size): 4 more bytes.
        Fractions add one value per label (1 or 4 bytes) and the union coverage
        (float32) with its two rounded int16 copies. Slab planning counts these.
        """
        per = self.set.dtype.itemsize + 4.0
        if self.fractions:
            per += len(self.set.names) * (4.0 if self.dtype == "float32" else 1.0) + 8.0
        return per

    def classify(self, mesh: Mesh, grid, *, cast_mesh, axis: int, jobs: int,
                 within=None, surface=None) -> Classified:
        """The block's occupancy by parts (see :func:`classify`)."""
        return classify(mesh, grid, self.set, cast_mesh=cast_mesh, axis=axis, jobs=jobs,
                        within=within, surface=surface)

    def fields(self, mesh: Mesh, grid, occupancy, classified, *, run, timings, step) -> dict:
        """A block's label fields for its Volume: ``labels``, ``label_table``, ``contested``,
        ``fractions`` (material labels and fractions are made here, timed into ``timings``).

        ``run`` is the block's :class:`BlockRun`: its engine, axis, threads,
        frame and the ray start of the whole grid.
        """
        import time

        if classified is not None:
            lab = classified.labels
        else:
            t = time.perf_counter()
            step("labels")
            lab = material_labels(mesh, grid, occupancy, self.set, jobs=run.jobs, frame=run.frame)
            timings["labels"] = time.perf_counter() - t
        fracs = None
        if self.fractions:
            step("fractions")
            t = time.perf_counter()
            fracs = label_fractions(mesh, grid, self.set, run, supersample=self.supersample,
                                    dtype=self.dtype)
            timings["fractions"] = time.perf_counter() - t
        return {"labels": lab, "label_table": table(self.set, lab, grid.spacing),
                "contested": 0 if classified is None else classified.contested, "fractions": fracs}

    def meta(self, grid) -> dict:
        """What the writers lay out before any block exists: the labels' dtype and table
        (counts 0 until every block is made), and the fractions' count and dtype."""
        n = len(self.set.names)
        return {"labels": self.set.dtype,
                "label_table": table(self.set, None, grid.spacing, counts=np.zeros(n + 1, np.int64)),
                "fractions": (n, np.dtype(np.float32 if self.dtype == "float32" else np.uint8))
                if self.fractions else None}

    def lines(self, labels_table: list, contested: int) -> list:
        """The summary's line on the labels made (the table, the contested voxels)."""
        return [f"labels {self.option}: {len(labels_table) - 1:,} "
                f"({', '.join(e['name'] for e in labels_table[1:][:6])}"
                f"{', ...' if len(labels_table) > 7 else ''}), "
                f"{contested:,} contested voxels (overlap rule {self.set.overlap})"]


@dataclass(frozen=True)
class BlockRun:
    """What a label stage needs of the block it runs on, beside the block's grid.

    Attributes
    ----------
    engine : geovox.backends.Backend
    axis : int
        The block's ray axis.
    jobs : int
    frame : (lo, spacing, z0)
        The whole grid's low corner and voxel size, and the block's first layer.
    start : float
        Where the whole grid's rays along ``axis`` start.
    within : (Grid, (z0, z1)) or None
        The whole grid and the block's layers (None: the block is the whole grid).
    """

    engine: object
    axis: int
    jobs: int
    frame: tuple
    start: float
    within: tuple | None = None


class LabelTally:
    """The label table's voxel counts and the contested voxels, summed over the blocks.

    A block equals that part of the whole grid, so the whole grid's counts
    are the sums of the blocks' (and a voxel is contested in one block only).
    ``approximate`` sums the blocks' approximate voxels (with or without labels).
    """

    def __init__(self, stage: LabelStage | None):
        self.stage = stage
        self.counts = None if stage is None else np.zeros(len(stage.set.names) + 1, np.int64)
        self.contested = 0
        self.approximate = 0
        self.inside = None  # the inside tests the parts ran (the same in every block)
        self.counts_of_surface = None  # surface and inside voxels, summed (Volume.counts)

    @staticmethod
    def of(vol):
        """``(counts, contested, inside)`` of a block's Volume, or None without labels."""
        if vol.label_table is None:
            return None
        return (np.array([e["voxels"] for e in vol.label_table], np.int64), int(vol.contested),
                vol.inside)

    def add_counts(self, counts) -> None:
        """Sum one block's surface and inside counts (its ``Volume.counts``; None without)."""
        if counts is None:
            return
        total = self.counts_of_surface or {}
        self.counts_of_surface = {k: total.get(k, 0) + v for k, v in counts.items()}

    def add(self, labelled) -> None:
        """Count one block's ``of(vol)``."""
        if labelled is None:
            return
        counts, contested, inside = labelled
        self.counts += counts
        self.contested += contested
        self.inside = self.inside or inside

    def table(self, spacing) -> list:
        """The whole grid's label table (:func:`table`)."""
        return table(self.stage.set, None, spacing, counts=self.counts)
