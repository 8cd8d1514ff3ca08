"""What a mesh is like, before converting it: ``geovox info``."""

from __future__ import annotations

import os

import numpy as np

from .inside import boundary_edges, consistent, edge_counts, overlapping_pieces, target
from .mesh import Mesh


def mesh_report(mesh: Mesh) -> dict:
    """Facts about a mesh that decide how it will voxelise.

    Returns
    -------
    dict with ``triangles``, ``vertices``, ``bounds``, ``closed``,
    ``open_edges``, ``non_manifold_edges``, ``components``, ``degenerate_faces``,
    ``duplicate_faces``, ``consistent`` (closed and consistently wound, no
    face stored twice), ``overlapping_pieces``, ``repair`` (None, or what
    ``--inside auto`` repairs on a copy: ``flipped``, ``duplicates``,
    ``opposite``, ``degenerate``, ``pieces``, ``closed_pieces``,
    ``outward``, ``open_edges_after``, ``summary``), ``materials`` (name,
    Kd, texture, status) and ``problems``.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    f = mesh.geometric_faces
    n_open, n_nonmanifold = edge_counts(mesh)
    used = np.unique(f)
    remap = np.zeros(int(f.max()) + 1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    g = remap[f]
    rows = np.concatenate([g[:, 0], g[:, 1]])
    cols = np.concatenate([g[:, 1], g[:, 2]])
    graph = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(len(used), len(used)))
    components = connected_components(graph, directed=False)[0]
    t = mesh.triangles
    area2 = np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)
    repeated = (f[:, 0] == f[:, 1]) | (f[:, 1] == f[:, 2]) | (f[:, 0] == f[:, 2])
    degenerate = int(np.count_nonzero(repeated | (area2 == 0)))
    _, counts = np.unique(np.sort(f, axis=1), axis=0, return_counts=True)
    duplicates = int((counts - 1).sum())
    is_consistent = consistent(mesh)
    repair = None
    if not is_consistent:
        tmesh, rep = target(mesh)
        repair = {"flipped": rep.flipped, "duplicates": rep.duplicates, "opposite": rep.opposite,
                  "degenerate": rep.degenerate, "pieces": rep.pieces,
                  "closed_pieces": rep.closed_pieces, "outward": rep.outward,
                  "open_edges_after": int(len(boundary_edges(tmesh))), "summary": rep.describe()}
    materials = []
    for m in mesh.materials:
        if m.texture_file:
            status = "texture found"
        elif m.image is not None:
            status = "texture embedded in the file"
        elif not m.defined:
            status = "not defined in any material file"
        else:
            status = "no texture"
        materials.append({"name": m.name, "kd": None if m.kd is None else list(map(float, m.kd)),
                          "texture": m.texture_file, "status": status})
    return {
        "source": mesh.source,
        "triangles": int(len(mesh.faces)),
        "vertices": int(len(used)),
        "bounds": mesh.bounds.tolist(),
        "closed": len(boundary_edges(mesh)) == 0,
        "open_edges": n_open,
        "non_manifold_edges": n_nonmanifold,
        "components": int(components),
        "degenerate_faces": degenerate,
        "duplicate_faces": duplicates,
        "consistent": is_consistent,
        "overlapping_pieces": bool(is_consistent and overlapping_pieces(mesh)),
        "repair": repair,
        "uv": mesh.corner_uv is not None,
        "vertex_colors": mesh.vertex_colors is not None,
        "materials": materials,
        "problems": list(mesh.problems),
    }


#: Voxels of the surface voxels' slabs :func:`surface_count` makes at a time.
COUNT_SLAB_VOXELS = 1 << 26


def surface_count(mesh: Mesh, plan) -> int:
    """How many voxels of the plan's grid the surface passes through, counted slab by slab.

    Parameters
    ----------
    mesh : Mesh
        The loaded mesh (with ``like``, :meth:`~geovox.planner.Plan.mesh_for` moves it).
    plan : geovox.planner.Plan
        Its grid, threads and snapping scale (``surface_bits``).
    """
    from .surface import surface_voxels

    m = plan.mesh_for(mesh)
    nx, ny, nz = plan.grid.shape
    thick = max(1, min(nz, COUNT_SLAB_VOXELS // max(1, nx * ny)))
    out = np.empty((nx, ny, thick), dtype=bool, order="F")
    count = 0
    for z0 in range(0, nz, thick):
        z1 = min(nz, z0 + thick)
        got = surface_voxels(m.triangles, plan.grid, (z0, z1), jobs=plan.jobs,
                             bits=plan.surface_bits, out=out[:, :, :z1 - z0])
        count += int(np.count_nonzero(got))
    return count


def grid_cost(grid) -> dict:
    """Grid shape and the memory a conversion needs, without allocating it.

    Parameters
    ----------
    grid : geovox.grid.Grid
        The plan's grid (:attr:`geovox.planner.Plan.grid`).
    """
    n = grid.size
    return {"shape": list(grid.shape), "spacing": grid.spacing.tolist(), "voxels": n,
            "occupancy_bytes": n, "with_colour_bytes": n * 21}


def _inside_line(rep: dict) -> str:
    """What ``--inside auto`` will do, and what it repairs first."""
    if rep["consistent"] and not rep["overlapping_pieces"]:
        return "closed: yes (parity is exact)"
    if rep["consistent"]:
        return ("closed: yes, with pieces that overlap; --inside auto counts their shared space "
                "as inside (the winding number, from signed crossings)")
    r = rep["repair"]
    head = "closed: no" if rep["open_edges"] else "closed: yes, but not consistently wound"
    then = (f"the copy has {r['open_edges_after']:,} edges without a partner, so the winding number "
            f"bridges its holes" if r["open_edges_after"] else
            "the copy is closed, so its winding number is exact from signed crossings")
    return (f"{head} - {rep['open_edges']:,} open edges; --inside auto repairs a copy: "
            f"{r['summary']}; {then}")


def format_report(rep: dict, cost: dict) -> str:
    def mib(b):
        return f"{b / 2**20:,.1f} MiB" if b < 2**30 else f"{b / 2**30:,.2f} GiB"

    lo, hi = rep["bounds"]
    lines = [
        f"{os.path.basename(rep['source'])}: {rep['triangles']:,} triangles, "
        f"{rep['vertices']:,} vertices (merged by position), {rep['components']} component(s)",
        "bounds (" + ", ".join(f"{v:.6g}" for v in lo) + ") .. (" + ", ".join(f"{v:.6g}" for v in hi) + ")",
        _inside_line(rep),
        f"non-manifold edges: {rep['non_manifold_edges']:,}; degenerate faces: "
        f"{rep['degenerate_faces']:,}; duplicate faces: {rep['duplicate_faces']:,}",
        f"texture coordinates: {'yes' if rep['uv'] else 'no'}; vertex colours: "
        f"{'yes' if rep['vertex_colors'] else 'no'}",
    ]
    if rep["materials"]:
        lines.append(f"materials ({len(rep['materials'])}):")
        for m in rep["materials"]:
            kd = "" if m["kd"] is None else " Kd " + " ".join(f"{v:.3g}" for v in m["kd"])
            tex = f" {m['texture']}" if m["texture"] else ""
            lines.append(f"  {m['name']}:{kd} - {m['status']}{tex}")
    else:
        lines.append("materials: none (colour would be neutral grey or vertex colours)")
    for p in rep["problems"]:
        lines.append(f"problem: {p}")
    nx, ny, nz = cost["shape"]
    dx, dy, dz = cost["spacing"]
    lines.append(f"grid {nx} x {ny} x {nz} = {cost['voxels']:,} voxels of {dx:.4g} x {dy:.4g} x {dz:.4g}: "
                 f"occupancy {mib(cost['occupancy_bytes'])}, with colour about "
                 f"{mib(cost['with_colour_bytes'])} while converting")
    return "\n".join(lines)
