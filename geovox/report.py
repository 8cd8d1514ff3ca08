"""What a mesh is like, before converting it: ``geovox info``."""

from __future__ import annotations

import os

import numpy as np

from .grid import make_grid
from .inside import boundary_edges, edge_counts
from .mesh import Mesh


def mesh_report(mesh: Mesh) -> dict:
    """Facts about a mesh that decide how it will voxelise.

    Returns
    -------
    dict with ``triangles``, ``vertices``, ``bounds``, ``closed``,
    ``open_edges``, ``non_manifold_edges``, ``components``, ``degenerate_faces``,
    ``duplicate_faces``, ``materials`` (name, Kd, texture, status) and
    ``problems``.
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
        "uv": mesh.corner_uv is not None,
        "vertex_colors": mesh.vertex_colors is not None,
        "materials": materials,
        "problems": list(mesh.problems),
    }


def grid_cost(mesh: Mesh, **grid_options) -> dict:
    """Grid shape and the memory a conversion needs, without allocating it."""
    grid = make_grid(mesh.bounds, **grid_options)
    n = grid.size
    return {"shape": list(grid.shape), "spacing": grid.spacing.tolist(), "voxels": n,
            "occupancy_bytes": n, "with_colour_bytes": n * 21}


def format_report(rep: dict, cost: dict) -> str:
    def mib(b):
        return f"{b / 2**20:,.1f} MiB" if b < 2**30 else f"{b / 2**30:,.2f} GiB"

    lo, hi = rep["bounds"]
    lines = [
        f"{os.path.basename(rep['source'])}: {rep['triangles']:,} triangles, "
        f"{rep['vertices']:,} vertices (merged by position), {rep['components']} component(s)",
        "bounds (" + ", ".join(f"{v:.6g}" for v in lo) + ") .. (" + ", ".join(f"{v:.6g}" for v in hi) + ")",
        ("closed: yes (parity is exact)" if rep["closed"] else
         f"closed: no - {rep['open_edges']:,} open edges; --inside auto will use the winding number"),
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
