"""The choice of inside test, and the mesh whose winding number decides it.

``parity``  odd/even crossings along one axis: exact for closed meshes.
``vote``    parity along x, y and z; the majority decides.
``winding`` the generalised winding number, computed exactly and fast, of
            the mesh itself when it is closed and consistently wound, else
            of a repaired copy (:mod:`geovox.inside.repair`: vertices merged,
            degenerate and duplicate faces dropped, faces oriented across
            manifold edges, pieces turned outward).

``auto`` uses parity when the mesh is closed and consistently wound and its
pieces' boxes do not overlap; ``winding`` otherwise (with a warning that says
what was repaired, unless the mesh only had overlapping closed pieces).
"""

from __future__ import annotations

import os

from ..errors import ParameterError, warn
from ..memory import check_mesh_memory
from ..mesh import Mesh
from ..options import Inside
from .edges import boundary_edges, consistent, edge_counts, overlapping_pieces
from .repair import repair


#: The names of the inside tests, ``auto`` first (the values of :class:`~geovox.options.Inside`).
METHODS = tuple(m.value for m in Inside)


def target(mesh: Mesh):
    """The mesh whose winding number decides the inside, and the repair that made it.

    Returns
    -------
    mesh : Mesh
        ``mesh`` itself when it is :func:`consistent`; else its repaired
        copy (see :mod:`geovox.inside.repair`).
    repair : geovox.inside.repair.Repair or None
    """
    if "target" not in mesh._cache:
        if consistent(mesh):
            mesh._cache["target"] = (mesh, None)
        else:
            n_open = edge_counts(mesh)[0]
            name = os.path.basename(mesh.source) if isinstance(mesh.source, str) and mesh.source \
                else "the mesh"
            check_mesh_memory(
                working_memory(len(mesh.faces), mesh._cache.get("positions", len(mesh.vertices)),
                               n_open),
                f"{name}: the winding number of a repaired copy ({len(mesh.faces):,} triangles, "
                f"{n_open:,} open edges)",
                "use --inside parity or vote (no repair), or a machine with more memory")
            rep = repair(mesh)
            mesh._cache["target"] = (rep.mesh, rep)
    return mesh._cache["target"]


def working_memory(faces: int, positions: int, open_edges: int) -> float:
    """Bytes the winding number of an open or broken mesh needs beside the mesh, at its peak.

    From counts known before the work (the closedness check gives them):
    the repair (the faces over merged positions, their edge table and the
    copy: about 120 bytes a face and 64 a position at its peak), then the
    copy closed by its caps and the rays cast through it (about 150 bytes a
    face), and the caps with their tree (a cap triangle for every two or
    three open edges, some 300 bytes an open edge in all). Measured on the
    scans of ``benchmarks/bench_triangles.py`` (1.6 to 25.7 million triangles
    with 5 % of them removed) the peak stays a quarter to a third below this.
    The grid's own arrays are checked apart (:func:`geovox.memory.check_memory`).

    Parameters
    ----------
    faces, positions, open_edges : int
        The mesh's triangles, distinct vertex positions and open edges.
    """
    return 150.0 * faces + 64.0 * positions + 300.0 * open_edges


def choose(mesh: Mesh, method: str) -> Inside:
    """The method to run for ``method`` (resolving ``auto``), warning when it had to repair.

    ``auto`` is parity for a closed, consistently wound mesh whose pieces do
    not overlap (exact, and the fastest); ``winding`` for one whose pieces'
    boxes overlap (signed crossings count the shared space; silent, nothing
    was guessed); and ``winding`` on a repaired copy otherwise, with a
    warning saying what was repaired and what is left open. ``winding``
    asked for by name warns only when the repair changed faces.

    Parameters
    ----------
    mesh : Mesh
    method : Inside or str
        ``auto``, ``parity``, ``vote`` or ``winding``.

    Returns
    -------
    Inside
        Never ``Inside.AUTO`` (a ``str``: ``choose(m, "auto") == "parity"`` holds).

    Raises
    ------
    ParameterError
        ``method`` is none of those.
    """
    if method not in METHODS:
        raise ParameterError(f"`inside` must be one of {', '.join(METHODS)}; got {method!r}")
    method = Inside(method)
    if method in (Inside.PARITY, Inside.VOTE):
        return method
    if consistent(mesh):
        if method == Inside.AUTO and not overlapping_pieces(mesh):
            return Inside.PARITY
        return Inside.WINDING
    tmesh, rep = target(mesh)
    if method == Inside.WINDING and not rep.changed:
        return Inside.WINDING
    n_open, n_nonmanifold = edge_counts(mesh)
    warn(repair_warning(mesh.source, n_open, n_nonmanifold, rep,
                        closed=not len(boundary_edges(tmesh))), stacklevel=3)
    return Inside.WINDING


def repair_warning(source, n_open: int, n_nonmanifold: int, rep, closed: bool) -> str:
    """The first of at most two short lines a messy model gets: what was wrong, what geovox did.

    The full account (every repair, the pieces, what is left open) is
    ``geovox info MODEL``'s, which the line points to; a second line comes
    from the winding number only where voxels are approximate.

    Parameters
    ----------
    source : str
        The mesh's source (a path where it came from a file).
    n_open, n_nonmanifold : int
        Open and non-manifold edges, after merging vertices by position.
    rep : geovox.inside.repair.Repair
        What the repair of the copy did.
    closed : bool
        Whether the repaired copy is closed (its winding number is then exact).
    """
    found = [(n_open, "open edges"), (n_nonmanifold, "non-manifold"),
             (rep.flipped, "faces wound the wrong way"),
             (rep.duplicates + rep.opposite, "duplicate faces"), (rep.degenerate, "degenerate faces")]
    found = [f"{n:,} {what}" for n, what in found if n][:2]  # the two that matter most
    wrong = ("not closed" if n_open else "not consistently wound") + (
        f" ({', '.join(found)})" if found else "")
    did = ("inside by the winding number of a repaired, closed copy (exact)" if closed else
           "inside by the winding number of a repaired copy")
    where = f"; see geovox info {source}" if isinstance(source, str) and \
        os.path.isfile(source) else ""
    name = os.path.basename(source) if isinstance(source, str) and source else "the mesh"
    return f"{name}: {wrong}; {did}{where}"
