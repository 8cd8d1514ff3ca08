"""OFF files: the colours trimesh's reader skips, and the polygons it cannot fan.

trimesh reads an OFF file's vertices and faces (:mod:`geovox.io.adaptor`);
:func:`read_off` then adds its colours, or reads the whole file where
trimesh's reader stopped (polygons of five corners or more).
"""

from __future__ import annotations

import itertools
import re

import numpy as np

from ..errors import MeshError
from ..mesh import Material, Mesh, build_mesh

__all__ = ["read_off", "off_faces"]


_OFF_HEADER = re.compile(r"(ST)?(C)?(N)?(4)?(n)?OFF")


def read_off(path: str, mesh: Mesh | None) -> Mesh | None:
    """An OFF file's colours, which trimesh's reader skips, and its polygons.

    ``mesh`` is what trimesh read from the file, returned as it is when the
    file has no colours; None where trimesh failed (its OFF reader stops on
    polygons of more than four corners), and then the file is read here.
    Colours: ``COFF`` vertex colours (``x y z [nx ny nz] r g b [a]``) and
    face colours (``n i1 ... in r g b [a]``), each as integers 0-255 or as
    numbers 0-1 (0-255 when any exceeds 1). Polygons are fanned here, so
    each triangle knows its face; a face without a colour in a file with
    face colours takes the default. Face colours are looked for when the
    first face has one. Returns None when the file cannot be read here either.
    """
    with open(path, "rb") as f:
        text = f.read().decode("utf-8", errors="replace")
    if "#" in text:
        text = re.sub(r"#[^\n]*", "", text)
    # Non-blank lines, as an iterator (C-level: an uncoloured file costs one
    # pass over its lines, not a split of each).
    content = filter(None, map(str.strip, text.splitlines()))
    first = next(content, "").split()
    head = _OFF_HEADER.fullmatch(first[0]) if first else None
    if head is None:
        return mesh
    try:
        counts = first[1:3] if len(first) > 1 else next(content, "").split()[:2]
        nv, nf = int(counts[0]), int(counts[1])
    except (IndexError, ValueError):
        return mesh
    if mesh is not None and len(mesh.vertices) != nv:
        return mesh
    if head.group(2) or mesh is None:
        vlines = [ln.split() for ln in itertools.islice(content, nv)]
    else:
        vlines = None
        next(itertools.islice(content, nv, nv), None)  # skip the vertices
    face = next(content, "").split()
    face_colours = bool(face) and face[0].isdigit() and len(face) >= 4 + int(face[0])
    if mesh is not None and vlines is None and not face_colours:
        return mesh
    flines = [face] + [ln.split() for ln in itertools.islice(content, nf - 1)] if face else []
    if mesh is None and (len(vlines) != nv or len(flines) != nf):
        raise MeshError(f"{path}: the OFF header announces {nv:,} vertices and {nf:,} faces, "
                        f"but the file has {len(vlines):,} and {len(flines):,}; it is cut short")

    problems = mesh.problems if mesh is not None else []

    def unit(rows):
        """(k, 3) float64 in [0, 1] and (k,) bool: which rows were finite.

        A NaN or infinite row becomes white (no colour, as in an OBJ) and
        does not decide the 0-255 scale; a word raises ValueError.
        """
        c = np.array(rows, dtype=np.float64)
        ok = np.isfinite(c).all(axis=1) if c.ndim == 2 else np.ones(len(c), dtype=bool)
        scale = 255.0 if c[ok].size and c[ok].max() > 1.0 else 1.0
        c[~ok] = scale
        return np.clip(c / scale, 0.0, 1.0), ok

    try:
        if mesh is None:
            vertices = np.array([ln[:3] for ln in vlines], dtype=np.float64).reshape(nv, 3)
        else:
            vertices = mesh.vertices
        faces = fm = None
        materials = []
        if mesh is None or face_colours:
            faces, fm, materials = off_faces(flines, unit, face_colours, problems, path)
            if mesh is not None and fm is None:
                faces = None  # face colours unreadable: trimesh's faces, as without colours
    except ValueError:  # what cannot be read here: trimesh's result or its error
        return mesh
    vc = None
    if head.group(2):
        at = 3 + (1 if head.group(4) else 0) + (3 if head.group(3) else 0)
        try:
            vc, ok = unit([ln[at:at + 3] for ln in vlines])
        except ValueError:  # unreadable colours (words, or rows cut short): none
            vc = None
            problems.append(f"{path}: cannot read the COFF vertex colours; the vertices "
                            f"count as having none")
        if vc is not None and vc.shape != (nv, 3):
            vc = None  # fewer than three numbers after the position: no colours stated
        elif vc is not None and not ok.any():
            # no vertex states a colour: the file has none (the default), as for a PLY
            vc = None
            problems.append(f"{path}: NaN or infinite colour on all {nv:,} vertices; the file "
                            f"states no vertex colours, so the default colour is used")
        elif vc is not None and not ok.all():
            n = int((~ok).sum())
            problems.append(f"{path}: NaN or infinite colour on {n:,} "
                            f"{'vertex' if n == 1 else 'vertices'}; they count as having no "
                            f"colour (white)")
    if mesh is not None and vc is None and faces is None:
        return mesh
    return build_mesh(vertices, mesh.faces if faces is None else faces, path,
                      face_material=fm, materials=materials, vertex_colors=vc,
                      problems=problems)


def off_faces(flines, unit, coloured_file: bool, problems: list, path: str):
    """Fanned faces (m, 3) of OFF face lines, face materials (m,) and their materials.

    A face colour that cannot be read (a word, NaN) leaves its face without
    one (the default colour) and is appended to ``problems``.

    Raises
    ------
    ValueError
        A face line whose indices cannot be read.
    """
    sizes = np.array([int(ln[0]) for ln in flines], dtype=np.int64)
    if np.any(sizes < 0) or any(len(ln) < 1 + k for ln, k in zip(flines, sizes.tolist())):
        raise ValueError("a face with fewer indices than it says")
    keep = sizes >= 3
    corners = np.array([int(i) for ln, k, ok in zip(flines, sizes.tolist(), keep) if ok
                        for i in ln[1:1 + k]], dtype=np.int64)
    first = np.r_[0, np.cumsum(sizes[keep])[:-1]]
    n_tri = sizes[keep] - 2
    poly = np.repeat(np.arange(len(first)), n_tri)
    j = np.arange(len(poly)) - np.repeat(np.cumsum(n_tri) - n_tri, n_tri) + 1
    c0 = first[poly]
    faces = corners[np.stack([c0, c0 + j, c0 + j + 1], axis=1)]
    if not coloured_file:
        return faces, None, []
    rest = [ln[1 + k:1 + k + 3] for ln, k in zip(flines, sizes.tolist())]
    has = np.array([len(r) == 3 for r in rest])
    try:
        fc, ok = unit([r if len(r) == 3 else ["0", "0", "0"] for r in rest])
    except ValueError:
        problems.append(f"{path}: cannot read the face colours; the faces count as having none")
        return faces, None, []
    if not ok.all():
        n = int((~ok).sum())
        problems.append(f"{path}: NaN or infinite colour on {n:,} face{'' if n == 1 else 's'}; "
                        f"{'it takes' if n == 1 else 'they take'} the default colour")
    fc, has = fc[keep][poly], (has & ok)[keep][poly]
    uniq, inverse = np.unique(fc, axis=0, return_inverse=True)
    materials = [Material(name="face colour", kd=c) for c in uniq]
    return faces, np.where(has, inverse.reshape(-1), -1), materials
