"""COLLADA scene nodes as parts (``labels="part"``).

trimesh's COLLADA reader (:mod:`trimesh.exchange.dae`, through pycollada)
makes one scene geometry per triangle primitive of each ``<instance_geometry>``
it meets, named after the ``<geometry>``'s id (``cube-mesh``, ``cube-mesh_1``,
...), and drops the ``<node>`` that placed it. So a geometry two nodes
instance gives two parts named after the geometry, and a geometry of two
materials (two primitives) two parts of one node.

:func:`node_parts` walks the document as trimesh does (the same pycollada
scene, the same order, the same unique names) and gives each of trimesh's
geometries the node it came from; :func:`regroup` then makes one part per
instanced geometry, named ``node (geometry)`` as glTF parts are.
"""

from __future__ import annotations

import numpy as np

__all__ = ["node_parts", "regroup"]


def _primitives(geometry):
    """The primitives of ``geometry`` that trimesh turns into meshes, in its order."""
    import collada

    for primitive in geometry.primitives:
        if isinstance(primitive, collada.polylist.Polylist):
            primitive = primitive.triangleset()
        if isinstance(primitive, collada.triangleset.TriangleSet) and primitive.vertex is not None:
            yield primitive


def node_parts(path: str) -> dict:
    """trimesh's geometry name -> ``(instance, node name, geometry name)`` for a COLLADA file.

    ``instance`` counts the ``<instance_geometry>`` elements met, in
    trimesh's order; the node is the nearest enclosing ``<node>`` (its
    ``name``, else its ``id``).
    """
    import collada
    from trimesh.util import unique_name

    ignore = [collada.common.DaeError, collada.common.DaeIncompleteError,
              collada.common.DaeMalformedError, collada.common.DaeBrokenRefError,
              collada.common.DaeUnsupportedError]  # trimesh's (load_collada, ignore_broken)
    with open(path, "rb") as fh:  # pycollada leaves a file it opens itself open
        c = collada.Collada(fh, ignore=ignore)
    names, counts, out = {}, {}, {}
    instance = 0

    def walk(node, owner):
        nonlocal instance
        if isinstance(node, collada.scene.GeometryNode):
            g = node.geometry
            for _ in _primitives(g):
                key = unique_name(g.id, contains=names, counts=counts)
                names[key] = None
                out[key] = (instance, owner, g.name or g.id)
            instance += 1
        elif isinstance(node, collada.scene.Node):
            name = getattr(node, "name", None) or node.id or owner
            for child in node.children or ():
                walk(child, name)

    if c.scene is not None:
        for top in c.scene.nodes:
            walk(top, None)
    return out


def regroup(mesh, path: str) -> None:
    """Make ``mesh``'s parts (trimesh's geometries) its COLLADA nodes' instances, in place.

    Each ``<instance_geometry>`` is one part, named ``node (geometry)`` (the
    node alone where they are the same name); a name used twice gets `` #2``,
    `` #3``... A mesh whose geometries cannot all be traced to a node keeps
    trimesh's parts.
    """
    if mesh.face_part is None:
        return
    try:
        found = node_parts(path)
    except Exception:  # noqa: BLE001 - trimesh read it; the names are a nicety
        return
    if not all(p in found for p in mesh.parts):
        return
    instances = sorted({found[p][0] for p in mesh.parts})
    new_index = {inst: k for k, inst in enumerate(instances)}
    names, seen = [], {}
    for inst in instances:
        node, geom = next(found[p][1:] for p in mesh.parts if found[p][0] == inst)
        name = geom if not node or node == geom else f"{node} ({geom})"
        seen[name] = seen.get(name, 0) + 1
        names.append(name if seen[name] == 1 else f"{name} #{seen[name]}")
    old_to_new = np.array([new_index[found[p][0]] for p in mesh.parts], dtype=np.int64)
    mesh.face_part = old_to_new[mesh.face_part]
    mesh.parts = names
