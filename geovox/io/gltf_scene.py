"""A glTF scene: its nodes, their transforms, and the copies of meshes they place.

:func:`placements` counts what a scene places from its JSON alone (per node,
in topological order), so :func:`geovox.io.gltf.read_gltf` can hold the
copies to the memory available (:func:`geovox.io.limits.scene_limit`)
before it decodes a copy's transform or places one; :func:`instances` then
walks the scene as trimesh does and gives each copy's world matrix.
``doc`` is a :class:`geovox.io.gltf.Document` (its ``listed``, ``item``,
``accessor`` and ``damaged``); this module does not import it.
"""

from __future__ import annotations

import numpy as np

from .names import unique_name

__all__ = ["instances", "placements", "transform_points", "copy_size", "is_int",
           "PER_VERTEX", "PER_FACE", "PER_COPY"]


def is_int(x) -> bool:
    """Whether a JSON value is a whole number (not a bool)."""
    return isinstance(x, int) and not isinstance(x, bool)


# --------------------------------------------------------------------- the scene


def _local(node: dict, where: str, doc) -> np.ndarray:
    """(4, 4) float64: a node's own transform, ``matrix`` x T x R x S as trimesh composes it."""
    matrix = np.eye(4)
    if "matrix" in node:
        m = _floats(node["matrix"], 16, where + "'s matrix", doc)
        matrix = m.reshape(4, 4).T
    if "translation" in node:
        t = np.eye(4)
        t[:3, 3] = _floats(node["translation"], 3, where + "'s translation", doc)
        matrix = matrix @ t
    if "rotation" in node:
        matrix = matrix @ _quaternion(_floats(node["rotation"], 4, where + "'s rotation", doc))
    if "scale" in node:
        matrix = matrix @ np.diag(np.append(_floats(node["scale"], 3, where + "'s scale", doc),
                                            1.0))
    return matrix


def _floats(value, n: int, what: str, doc) -> np.ndarray:
    if (not isinstance(value, list) or len(value) != n
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value)):
        raise doc.damaged(f"{what} is not {n} numbers")
    out = np.asarray(value, dtype=np.float64)
    if not np.isfinite(out).all():
        raise doc.damaged(f"{what} is not finite")
    return out


def _quaternion(xyzw: np.ndarray) -> np.ndarray:
    """(4, 4): trimesh's ``quaternion_matrix`` of glTF's (x, y, z, w), the same arithmetic."""
    q = xyzw[[3, 0, 1, 2]].astype(np.float64)
    n = float(np.dot(q, q))
    if n < np.finfo(float).eps * 4.0:
        return np.eye(4)
    q = q * np.sqrt(2.0 / n)
    q = np.outer(q, q)
    return np.array([
        [1.0 - q[2, 2] - q[3, 3], q[1, 2] - q[3, 0], q[1, 3] + q[2, 0], 0.0],
        [q[1, 2] + q[3, 0], 1.0 - q[1, 1] - q[3, 3], q[2, 3] - q[1, 0], 0.0],
        [q[1, 3] - q[2, 0], q[2, 3] + q[1, 0], 1.0 - q[1, 1] - q[2, 2], 0.0],
        [0.0, 0.0, 0.0, 1.0]])


def _check_acyclic(doc, nodes: list) -> None:
    """Refuse a node graph with a cycle (a node its own ancestor)."""
    state = [0] * len(nodes)  # 0 new, 1 on the path, 2 done
    for start in range(len(nodes)):
        if state[start]:
            continue
        stack = [(start, iter(_children(doc, nodes, start)))]
        state[start] = 1
        while stack:
            node, todo = stack[-1]
            child = next(todo, None)
            if child is None:
                state[node] = 2
                stack.pop()
            elif state[child] == 1:
                raise doc.damaged(f"node {child} is its own ancestor (the node graph has a "
                                  f"cycle)")
            elif state[child] == 0:
                state[child] = 1
                stack.append((child, iter(_children(doc, nodes, child))))


def _children(doc, nodes: list, i: int) -> list:
    node = nodes[i] if isinstance(nodes[i], dict) else {}
    kids = node.get("children", [])
    if not isinstance(kids, list) or not all(is_int(k) and 0 <= k < len(nodes) for k in kids):
        raise doc.damaged(f"node {i}'s children name nodes that do not exist")
    return kids


def instances(doc) -> list:
    """``[(node index, node name, mesh index, (4, 4) world matrix)]`` in trimesh's scene order.

    trimesh walks the scene with a stack: the roots pushed in order and
    popped from the end, each node's children pushed in order after it.
    ``EXT_mesh_gpu_instancing`` gives a node one matrix per instance.
    """
    nodes = doc.listed("nodes")
    _check_acyclic(doc, nodes)
    names, counts = {}, {}
    for i, n in enumerate(nodes):
        own = n.get("name") if isinstance(n, dict) and isinstance(n.get("name"), str) else str(i)
        names[unique_name(own, names, counts)] = i
    names = {i: name for name, i in names.items()}
    world = next((i for i, name in names.items() if name == "world"), None)
    if world is not None:  # trimesh's base frame is "world": a node of that name is renamed
        names[world] = unique_name("world", set(names.values()))
    roots = _roots(doc, nodes)
    if roots is None:
        # No scene: every mesh once where it stands (trimesh reads nothing).
        return [(None, None, k, np.eye(4)) for k in range(len(doc.listed("meshes")))]
    out, stack = [], [(np.eye(4), r) for r in roots]
    while stack:
        parent, b = stack.pop()
        node = nodes[b] if isinstance(nodes[b], dict) else {}
        local = _local(node, f"node {b}", doc)
        world = local if parent is None else _product(parent, local)
        stack.extend((world, c) for c in _children(doc, nodes, b))
        if "mesh" in node:
            out.extend((b, names[b], node["mesh"], matrix)
                       for matrix in _instancing(doc, node, b, world))
    return out


def _roots(doc, nodes: list):
    """The scene's root nodes, or None for a file without scenes."""
    if not doc.listed("scenes"):
        return None
    scene = doc.item("scenes", doc.header.get("scene", 0), "the file's scene")
    roots = scene.get("nodes", [])
    if not isinstance(roots, list) or not all(is_int(r) and 0 <= r < len(nodes) for r in roots):
        raise doc.damaged("the scene names nodes that do not exist")
    return roots


def _own_copies(doc, node: dict, b: int) -> int:
    """How many copies of its mesh a node places: its ``EXT_mesh_gpu_instancing`` count, or 1."""
    ext = (node.get("extensions") or {}).get("EXT_mesh_gpu_instancing") \
        if isinstance(node.get("extensions"), dict) else None
    attrs = ext.get("attributes") if isinstance(ext, dict) else None
    if not isinstance(attrs, dict) or not attrs:
        return 1
    counts = [doc.item("accessors", attrs[k], f"node {b}'s instance {k}").get("count")
              for k in ("TRANSLATION", "ROTATION", "SCALE") if k in attrs]
    # the accessors' own checks (and _instancing's) say what is wrong with a bad count
    return max((c for c in counts if is_int(c) and c > 0), default=0)


def placements(doc) -> tuple:
    """What the scene places, from its JSON alone, before anything is decoded or placed.

    A node's mesh is placed once for each path from a root to the node
    (glTF allows one; a file with a node under two parents gets as many,
    as :func:`instances` walks it) times its ``EXT_mesh_gpu_instancing``
    count. Counted per node in topological order, never by walking the
    copies, so a file claiming a billion copies is counted as fast as one
    claiming two.

    Returns
    -------
    meshes : list of int
        The meshes placed, in the order :func:`instances` first reaches them.
    copies : dict
        ``{mesh: copies placed}`` (Python ints: a claim may be astronomic).
    """
    nodes = doc.listed("nodes")
    _check_acyclic(doc, nodes)
    roots = _roots(doc, nodes)
    if roots is None:
        return list(range(len(doc.listed("meshes")))), dict.fromkeys(
            range(len(doc.listed("meshes"))), 1)
    # The walk of instances() with each node entered once: the first time it
    # reaches a node, it goes through all that node's subtree before going
    # on, so this gives the same first-reached order of meshes.
    seen, meshes, found, stack = set(), [], set(), list(roots)
    parents = {}  # node -> how many times it is listed as a child of a reachable node
    while stack:
        b = stack.pop()
        if b in seen:
            continue
        seen.add(b)
        node = nodes[b] if isinstance(nodes[b], dict) else {}
        kids = _children(doc, nodes, b)
        for c in kids:
            parents[c] = parents.get(c, 0) + 1
        stack.extend(kids)
        if "mesh" in node:
            mesh = node["mesh"]
            doc.item("meshes", mesh, f"node {b}")
            if mesh not in found:
                found.add(mesh)
                meshes.append(mesh)
    # Times each node is reached, parents before children (Kahn's order).
    reached = dict.fromkeys(seen, 0)
    for r in roots:
        reached[r] += 1
    waiting = dict(parents)
    ready = [b for b in seen if not waiting.get(b)]
    copies = dict.fromkeys(meshes, 0)
    while ready:
        b = ready.pop()
        node = nodes[b] if isinstance(nodes[b], dict) else {}
        for c in _children(doc, nodes, b):
            reached[c] += reached[b]
            waiting[c] -= 1
            if not waiting[c]:
                ready.append(c)
        if "mesh" in node:
            copies[node["mesh"]] += reached[b] * _own_copies(doc, node, b)
    return meshes, copies


def _product(parent: np.ndarray, local: np.ndarray) -> np.ndarray:
    # trimesh leaves identities out of its products: the same rounding.
    if np.abs(local - np.eye(4)).max() <= 1e-8:
        return parent
    if np.abs(parent - np.eye(4)).max() <= 1e-8:
        return local
    return parent @ local


def _instancing(doc, node: dict, b: int, world: np.ndarray) -> list:
    ext = (node.get("extensions") or {}).get("EXT_mesh_gpu_instancing") \
        if isinstance(node.get("extensions"), dict) else None
    attrs = ext.get("attributes") if isinstance(ext, dict) else None
    if not isinstance(attrs, dict) or not attrs:
        return [world]
    got = {k: doc.accessor(attrs[k], f"node {b}'s instance {k}").astype(np.float64)
           for k in ("TRANSLATION", "ROTATION", "SCALE") if k in attrs}
    counts = {len(a) for a in got.values()}
    if len(counts) != 1:
        raise doc.damaged(f"node {b}'s instance attributes have different counts")
    n = counts.pop()
    out = []
    for k in range(n):
        m = np.eye(4)
        if "TRANSLATION" in got:
            m[:3, 3] = got["TRANSLATION"][k, :3]
        if "ROTATION" in got:
            m = m @ _quaternion(got["ROTATION"][k, :4])
        if "SCALE" in got:
            m = m @ np.diag(np.append(got["SCALE"][k, :3], 1.0))
        out.append(world @ m)
    return out


def transform_points(points: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """trimesh's ``transform_points``: the same arithmetic, so the same coordinates."""
    if np.abs(matrix - np.eye(4)).max() < 1e-8:
        return points
    stack = np.column_stack((points, np.ones(len(points))))
    with np.errstate(invalid="ignore", over="ignore"):  # build_mesh names the NaN vertices
        return np.dot(matrix, stack.T).T[:, :3]


#: Bytes :func:`geovox.io.gltf.read_gltf` keeps for each placed copy of a primitive, per vertex
#: (its positions, and build_mesh's finite check) and per face (its vertex
#: indices, material and part); corner texture coordinates, vertex colours and
#: feature IDs add theirs where the primitive has them (:func:`_copy_size`).
#: tracemalloc's peak while reading a scene of copies stays within this
#: (tests/test_gltf_reader.py).
PER_VERTEX, PER_FACE = 28, 40
#: Bytes of one copy's transform, its entry in the scene and its part's label.
PER_COPY = 512


def copy_size(p) -> int:
    """Bytes one more placed copy of primitive ``p`` takes in the Mesh.

    ``p`` is a :class:`geovox.io.gltf.Primitive`; the Mesh is
    :func:`geovox.io.gltf.read_gltf`'s, every copy written in place.
    """
    if p.kind != "triangles":
        return 0
    n, m = len(p.positions), len(p.faces)
    return (n * (PER_VERTEX + (24 if p.colours is not None else 0))
            + m * (PER_FACE + (48 if p.uv is not None else 0)
                   + (8 if p.features is not None else 0)))
