"""Parts of 3MF and COLLADA files (``labels="part"``): how many, named how, which voxels.

The fixtures are small real files written here, as the formats' specifications lay them
out: unit cubes and half cubes on a grid of 0.25 voxels whose faces lie on voxel faces, so
each part's voxels are known exactly (a cube is 4³ = 64 voxels, a half cube 2³ = 8) and so is
where they are.
"""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

import geovox
from geovox.io.load import load_mesh

# A cube [0, s]³ (corners numbered dx * 4 + dy * 2 + dz), wound outwards.
_TRIS = [(0, 2, 6), (0, 6, 4), (1, 5, 7), (1, 7, 3), (0, 4, 5), (0, 5, 1), (2, 3, 7), (2, 7, 6),
         (0, 1, 3), (0, 3, 2), (4, 6, 7), (4, 7, 5)]


def _corners(s):
    return [(dx * s, dy * s, dz * s) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]


def _shift(x, y=0.0, z=0.0):
    return f"1 0 0 0 1 0 0 0 1 {x} {y} {z}"


def write_3mf(path):
    """Objects ``block`` (unit cube) and ``peg`` (half cube), ``pair`` made of both as
    components; build items: block, peg at x=2, peg at x=3 with partnumber ``spare peg``,
    and pair (block at y=2, peg at (2, 2, 0))."""
    def mesh_object(oid, name, s):
        v = "".join(f'<vertex x="{a}" y="{b}" z="{c}"/>' for a, b, c in _corners(s))
        t = "".join(f'<triangle v1="{a}" v2="{b}" v3="{c}"/>' for a, b, c in _TRIS)
        return (f'<object id="{oid}" name="{name}" type="model"><mesh><vertices>{v}</vertices>'
                f"<triangles>{t}</triangles></mesh></object>")

    model = (
        '<?xml version="1.0" encoding="UTF-8"?>\n<model unit="millimeter" '
        'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02"><resources>'
        + mesh_object(1, "block", 1.0) + mesh_object(2, "peg", 0.5)
        + '<object id="3" name="pair" type="model"><components>'
        f'<component objectid="1" transform="{_shift(0, 2)}"/>'
        f'<component objectid="2" transform="{_shift(2, 2)}"/></components></object>'
        "</resources><build>"
        f'<item objectid="1"/><item objectid="2" transform="{_shift(2)}"/>'
        f'<item objectid="2" transform="{_shift(3)}" partnumber="spare peg"/>'
        '<item objectid="3"/></build></model>')
    types = ('<?xml version="1.0" encoding="UTF-8"?><Types xmlns="http://schemas.openxmlformats'
             '.org/package/2006/content-types"><Default Extension="rels" ContentType="application/'
             'vnd.openxmlformats-package.relationships+xml"/><Default Extension="model" '
             'ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/></Types>')
    rels = ('<?xml version="1.0" encoding="UTF-8"?><Relationships xmlns="http://schemas.'
            'openxmlformats.org/package/2006/relationships"><Relationship Target="/3D/3dmodel.'
            'model" Id="rel0" Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/'
            '3dmodel"/></Relationships>')
    with zipfile.ZipFile(path, "w") as z:
        z.writestr("[Content_Types].xml", types)
        z.writestr("_rels/.rels", rels)
        z.writestr("3D/3dmodel.model", model)
    return str(path)


def write_dae(path):
    """Geometries ``slab`` (unit cube, its faces in two <triangles> of two materials) and
    ``peg`` (half cube); nodes ``base`` (slab), ``pegA`` at x=2 and ``pegB`` at x=3 (peg), and
    a group node ``rack`` at y=2 holding node ``pegC`` (peg at x=1 within it)."""
    def geometry(gid, name, s, splits):
        pos = " ".join(str(c) for p in _corners(s) for c in p)
        prims = "".join(
            f'<triangles count="{b - a}" material="m{k}"><input semantic="VERTEX" '
            f'source="#{gid}-vtx" offset="0"/><p>{" ".join(str(i) for t in _TRIS[a:b] for i in t)}'
            f"</p></triangles>" for k, (a, b) in enumerate(splits))
        return (f'<geometry id="{gid}" name="{name}"><mesh><source id="{gid}-pos"><float_array '
                f'id="{gid}-arr" count="24">{pos}</float_array><technique_common><accessor '
                f'source="#{gid}-arr" count="8" stride="3"><param name="X" type="float"/><param '
                f'name="Y" type="float"/><param name="Z" type="float"/></accessor>'
                f'</technique_common></source><vertices id="{gid}-vtx"><input semantic="POSITION" '
                f'source="#{gid}-pos"/></vertices>{prims}</mesh></geometry>')

    def node(name, url, x=0.0, y=0.0, inner=""):
        body = f'<instance_geometry url="#{url}"/>' if url else inner
        return (f'<node id="{name}-id" name="{name}" type="NODE"><matrix sid="transform">1 0 0 {x} '
                f"0 1 0 {y} 0 0 1 0 0 0 0 1</matrix>{body}</node>")

    doc = ('<?xml version="1.0" encoding="utf-8"?>\n<COLLADA xmlns="http://www.collada.org/2005/'
           '11/COLLADASchema" version="1.4.1"><asset><unit name="meter" meter="1"/><up_axis>Z_UP'
           "</up_axis></asset><library_geometries>"
           + geometry("slab-mesh", "slab", 1.0, [(0, 6), (6, 12)])
           + geometry("peg-mesh", "peg", 0.5, [(0, 12)])
           + '</library_geometries><library_visual_scenes><visual_scene id="Scene" name="Scene">'
           + node("base", "slab-mesh") + node("pegA", "peg-mesh", 2) + node("pegB", "peg-mesh", 3)
           + node("rack", None, 0, 2, inner=node("pegC", "peg-mesh", 1))
           + "</visual_scene></library_visual_scenes><scene><instance_visual_scene "
           'url="#Scene"/></scene></COLLADA>')
    with open(path, "w", encoding="utf-8") as f:
        f.write(doc)
    return str(path)


def voxels_by_name(path):
    """``name -> (count, low corner index, high corner index)`` of each label's voxels."""
    v = geovox.voxelize(path, voxel_size=0.25, labels="part")
    np.testing.assert_allclose(v.grid.lo, 0.0, atol=1e-12)  # the cubes' faces on voxel faces
    out = {}
    for e in v.label_table[1:]:
        idx = np.argwhere(v.labels == e["value"])
        out[e["name"]] = (e["voxels"], tuple(int(i) for i in idx.min(axis=0)),
                          tuple(int(i) + 1 for i in idx.max(axis=0)))
    assert v.contested == 0
    return out


def test_3mf_build_items_and_components_are_parts(tmp_path):
    path = write_3mf(tmp_path / "items.3mf")
    m = load_mesh(path)
    # One part per mesh object each build item reaches (through components): the block and
    # the peg once each as items, the peg again as the spare (named by its partnumber), and
    # both again within `pair`. Named after the object, a second instance of an object by
    # trimesh's node name ("block_1 (block)"); which instance gets the plain name follows
    # trimesh's walk of the build graph, not the file's order (said in the labels guide).
    assert sorted(m.parts) == ["block", "block_1 (block)", "peg", "peg_1 (peg)",
                               "spare peg (peg)"]
    assert np.bincount(m.face_part).tolist() == [12] * 5
    got = voxels_by_name(path)
    assert got.pop("spare peg (peg)") == (8, (12, 0, 0), (14, 2, 2))  # item at x = 3
    assert sorted(got.values()) == sorted([
        (64, (0, 0, 0), (4, 4, 4)),     # the block item
        (64, (0, 8, 0), (4, 12, 4)),    # pair's block, y = 2
        (8, (8, 0, 0), (10, 2, 2)),     # the peg item at x = 2
        (8, (8, 8, 0), (10, 10, 2)),    # pair's peg at (2, 2)
    ])
    assert {n for n, (c, _, _) in got.items() if c == 64} == {"block", "block_1 (block)"}


def test_collada_nodes_are_parts_named_after_node_and_geometry(tmp_path):
    pytest.importorskip("collada", reason="trimesh reads COLLADA through pycollada")
    path = write_dae(tmp_path / "nodes.dae")
    m = load_mesh(path)
    # One part per <instance_geometry>: the slab's two primitives (materials) stay one part;
    # the peg used by three nodes is three parts; the nested node is named, not its group.
    assert m.parts == ["base (slab)", "pegA (peg)", "pegB (peg)", "pegC (peg)"]
    assert np.bincount(m.face_part).tolist() == [12, 12, 12, 12]
    got = voxels_by_name(path)
    assert got == {
        "base (slab)": (64, (0, 0, 0), (4, 4, 4)),
        "pegA (peg)": (8, (8, 0, 0), (10, 2, 2)),
        "pegB (peg)": (8, (12, 0, 0), (14, 2, 2)),
        "pegC (peg)": (8, (4, 8, 0), (6, 10, 2)),   # rack at y = 2, pegC at x = 1 within it
    }


def test_collada_node_named_as_its_geometry_and_one_used_twice(tmp_path):
    pytest.importorskip("collada")
    from conftest import corpus

    # A real file: node "Cube" holds geometry "Cube" (one name, said once).
    assert load_mesh(corpus("wild", "cube_invalid_shininess.dae")).parts == ["Cube"]
    # Two nodes of the same name: told apart.
    with open(write_dae(tmp_path / "n.dae"), encoding="utf-8") as f:
        text = f.read()
    text = text.replace('name="pegB"', 'name="pegA"')
    (tmp_path / "same.dae").write_text(text, encoding="utf-8")
    assert load_mesh(str(tmp_path / "same.dae")).parts == \
        ["base (slab)", "pegA (peg)", "pegA (peg) #2", "pegC (peg)"]
