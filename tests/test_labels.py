"""Labelled volumes (geovox.labels): parts, components, files, and the overlap rules.

The truth for parts: each part voxelised alone on the same grid, then the
overlap rule applied voxel by voxel.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

import geovox
from geovox import labels as L
from geovox.errors import MeshError, ParameterError
from geovox.grid import make_grid
from geovox.io.load import load_mesh
from geovox.mesh import Mesh
from geovox.block import voxelize_block


def assembly(open_part=False) -> Mesh:
    """Overlapping closed bodies: a box, a sphere cutting through it, an
    inclusion inside the box, a separate box; optionally an open cup."""
    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    cut = trimesh.creation.icosphere(subdivisions=3, radius=0.7)
    cut.apply_translation((0.9, 0.1, 0.05))
    inner = trimesh.creation.icosphere(subdivisions=2, radius=0.4)
    inner.apply_translation((-0.4, -0.3, -0.2))
    apart = trimesh.creation.box(extents=(0.9, 1.1, 0.7))
    apart.apply_translation((2.3, 0.2, -0.1))
    pieces = [("box", box), ("cut", cut), ("inner", inner), ("apart", apart)]
    if open_part:
        cup = trimesh.creation.icosphere(subdivisions=3, radius=0.6)
        cup.apply_translation((0.0, 1.2, 0.9))
        keep = cup.triangles_center[:, 2] < 1.2  # cut off the cap: an open cup
        cup.update_faces(keep)
        cup.remove_unreferenced_vertices()
        pieces.append(("cup", cup))
    verts, faces, part, off = [], [], [], 0
    for k, (_, g) in enumerate(pieces):
        verts.append(np.asarray(g.vertices, float))
        faces.append(np.asarray(g.faces, np.int64) + off)
        part.append(np.full(len(g.faces), k))
        off += len(g.vertices)
    return Mesh(np.concatenate(verts), np.concatenate(faces), source="assembly",
                face_part=np.concatenate(part), parts=[n for n, _ in pieces])


def alone(mesh: Mesh, grid, backend, axis=2, inside="auto") -> list:
    """Each part's occupancy, voxelised alone on ``grid``."""
    out = []
    for k, name in enumerate(mesh.parts):
        part = L.part_mesh(mesh, np.flatnonzero(mesh.face_part == k), name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            v = geovox.voxelize(part, shape=grid.shape, bounds=np.r_[grid.lo, grid.hi],
                                backend=backend, axis=axis, inside=inside)
        out.append(v.occupancy)
    return out


def expected(occs, order) -> np.ndarray:
    """The label volume the rule gives: ``order`` paints the winner last."""
    lab = np.zeros(occs[0].shape, np.uint8)
    for k in order:
        lab[occs[k]] = k + 1
    return lab


def volumes(mesh):
    return [L.enclosed_volume(L.part_mesh(mesh, np.flatnonzero(mesh.face_part == k), n))
            for k, n in enumerate(mesh.parts)]


def rule_order(mesh, overlap):
    n = len(mesh.parts)
    if overlap == "last":
        return list(range(n))
    if overlap == "first":
        return list(range(n))[::-1]
    v = volumes(mesh)
    return sorted(range(n), key=lambda k: (-v[k], k))


@pytest.mark.parametrize("overlap", L.OVERLAPS)
@pytest.mark.parametrize("axis", [0, 2])
def test_label_is_the_part_alone_inside_and_no_winner(backend, overlap, axis):
    m = assembly(open_part=True)
    grid = make_grid(m.bounds, shape=(41, 29, 23))
    occs = alone(m, grid, backend, axis)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        v = geovox.voxelize(m, shape=grid.shape, backend=backend, axis=axis, labels="part",
                            overlap=overlap)
    want = expected(occs, rule_order(m, overlap))
    assert all(o.any() for o in occs)
    np.testing.assert_array_equal(v.labels, want)
    np.testing.assert_array_equal(v.occupancy, np.logical_or.reduce(occs))
    stack = np.stack(occs).sum(axis=0)
    assert v.contested == int(np.count_nonzero(stack >= 2))
    assert np.count_nonzero(stack >= 2) > 0  # the overlaps are there to be settled
    assert "winding" in v.inside and "parity" in v.inside  # the open cup ran winding


def test_overlap_rules_differ_where_they_should():
    m = assembly()
    got = {o: geovox.voxelize(m, resolution=32, labels="part", overlap=o).labels
           for o in L.OVERLAPS}
    # The inclusion is inside the box: "last" and "smallest" keep it, "first" hides it.
    assert (got["last"] == 3).any() and (got["smallest"] == 3).any()
    assert not (got["first"] == 3).any()


def test_slabs_give_the_whole_grid_labels(backend):
    m = assembly(open_part=True)
    grid = make_grid(m.bounds, shape=(30, 22, 27))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p = geovox.plan(m, dict(shape=grid.shape, backend=backend, axis=1, labels="part",
                                overlap="smallest"))
        whole = voxelize_block(m, p)
        parts = [voxelize_block(m, p, b) for b in [(0, 7), (7, 8), (8, 27)]]
    np.testing.assert_array_equal(np.concatenate([p.labels for p in parts], axis=2),
                                  whole.labels)


def test_table_counts_and_volumes():
    m = assembly()
    v = geovox.voxelize(m, resolution=24, labels="part")
    t = v.label_table
    assert [e["value"] for e in t] == list(range(len(m.parts) + 1))
    assert t[0]["name"] == "background" and t[0]["color"][3] == 0
    assert [e["name"] for e in t[1:]] == m.parts
    cell = np.prod(v.spacing)
    for e in t:
        assert e["voxels"] == int(np.count_nonzero(v.labels == e["value"]))
        assert e["volume"] == pytest.approx(e["voxels"] * cell)
        assert len(e["color"]) == 4 and e["source"] == "part"
    assert sum(e["voxels"] for e in t) == v.labels.size
    assert v.labels.dtype == np.uint8


def test_obj_objects_and_groups(tmp_path):
    box = "\n".join(f"v {x} {y} {z}" for x in (0, 1) for y in (0, 1) for z in (0, 1))
    faces = ("f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n")
    shifted = "\n".join(f"v {x + 2} {y} {z}" for x in (0, 1) for y in (0, 1) for z in (0, 1))
    faces2 = "".join("f " + " ".join(str(int(i) + 8) for i in line.split()[1:]) + "\n"
                     for line in faces.splitlines())
    p = tmp_path / "two.obj"
    p.write_text(f"{box}\n{shifted}\no left\ng second\n{faces}o right\n{faces2}")
    m = load_mesh(str(p))
    # Objects win over groups.
    assert m.parts == ["left", "right"]
    np.testing.assert_array_equal(np.bincount(m.face_part), [12, 12])
    # Faces before the first object are a part of their own.
    p.write_text(f"{box}\n{shifted}\n{faces}o right\n{faces2}")
    m = load_mesh(str(p))
    assert m.parts == ["right", "(unnamed)"]
    np.testing.assert_array_equal(m.face_part, np.repeat([1, 0], 12))
    q = tmp_path / "groups.obj"
    q.write_text(f"{box}\n{shifted}\ng a\n{faces}g b\n{faces2}g a\n")
    m = load_mesh(str(q))
    assert m.parts == ["a", "b"]
    v = geovox.voxelize(str(q), resolution=12, labels="part")
    assert set(np.unique(v.labels)) == {0, 1, 2}
    assert [e["name"] for e in v.label_table] == ["background", "a", "b"]


def test_no_parts_falls_back_to_components_with_a_warning():
    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.apply_translation((3, 0, 0))
    both = trimesh.util.concatenate([a, b])
    m = Mesh(np.asarray(both.vertices), np.asarray(both.faces), source="two boxes")
    with pytest.warns(UserWarning, match="names no parts"):
        v = geovox.voxelize(m, resolution=20, labels="part")
    assert [e["name"] for e in v.label_table[1:]] == ["component 1", "component 2"]
    assert v.label_table[1]["source"] == "component"
    assert (v.labels[: 5] == 1).any() and (v.labels[-5:] == 2).any()


def test_components_merge_vertices_by_position():
    # A box whose faces are all separate (no shared vertex index) is one component.
    box = trimesh.creation.box()
    tris = box.triangles.reshape(-1, 3)
    m = Mesh(tris, np.arange(len(tris)).reshape(-1, 3), source="soup")
    assert set(L.components(m)) == {0}


def test_file_scene(tmp_path):
    a = trimesh.creation.box(extents=(1, 1, 1))
    b = trimesh.creation.icosphere(radius=0.4)
    b.apply_translation((1.5, 0, 0))
    pa, pb = tmp_path / "liver.stl", tmp_path / "kidney.stl"
    a.export(pa)
    b.export(pb)
    v = geovox.voxelize([str(pa), str(pb)], resolution=30, labels="file")
    assert [e["name"] for e in v.label_table] == ["background", "liver", "kidney"]
    lo = np.minimum(a.bounds[0], b.bounds[0])
    hi = np.maximum(a.bounds[1], b.bounds[1])
    np.testing.assert_allclose(v.grid.lo, lo)
    np.testing.assert_allclose(v.grid.hi[v.grid.shape.index(30)], hi[v.grid.shape.index(30)])
    ref = geovox.voxelize(str(pb), shape=v.shape, bounds=np.r_[v.grid.lo, v.grid.hi])
    np.testing.assert_array_equal(v.labels == 2, ref.occupancy)
    one = geovox.voxelize([str(pa)], resolution=10, labels="file")
    assert [e["name"] for e in one.label_table] == ["background", "liver"]
    single = geovox.voxelize(str(pa), resolution=10, labels="file")
    assert [e["name"] for e in single.label_table] == ["background", "liver"]


def test_file_scene_names_a_file_that_is_not_a_mesh(tmp_path):
    a = tmp_path / "a.stl"
    trimesh.creation.box().export(a)
    bad = tmp_path / "notes.stl"
    bad.write_text("hello")
    with pytest.raises(MeshError, match="notes.stl"):
        geovox.voxelize([str(a), str(bad)], labels="file")


@pytest.mark.parametrize("kwargs, match", [
    (dict(labels="colour"), "`labels` must be one of"),
    (dict(labels="part", overlap="biggest"), "`overlap` must be one of"),
    (dict(fractions=True), "`fractions` needs `labels`"),
])
def test_bad_options(kwargs, match):
    with pytest.raises(ParameterError, match=match):
        geovox.voxelize(assembly(), resolution=8, **kwargs)


def test_several_meshes_without_labels_is_refused():
    with pytest.raises(ParameterError, match="several meshes"):
        geovox.voxelize([assembly(), assembly()], resolution=8)


def test_too_many_labels():
    n = L.MAX_LABELS + 1
    m = Mesh(np.zeros((3, 3)) + np.arange(3)[:, None] * [1, 0, 0] + [[0, 0, 0], [0, 1, 0], [0, 0, 0]],
             np.zeros((n, 3), np.int64) + [0, 1, 2], source="many",
             face_part=np.arange(n), parts=[str(k) for k in range(n)])
    with pytest.raises(ParameterError, match="at most 65,535"):
        L.label_set(m, "part")


def test_uint16_above_255_labels():
    cubes = [trimesh.creation.box(extents=(0.5, 0.5, 0.5)) for _ in range(300)]
    for k, c in enumerate(cubes):
        c.apply_translation((k % 20, (k // 20) % 15, 0))
    both = trimesh.util.concatenate(cubes)
    part = np.repeat(np.arange(300), 12)
    m = Mesh(np.asarray(both.vertices), np.asarray(both.faces), source="many",
             face_part=part, parts=[f"c{k}" for k in range(300)])
    v = geovox.voxelize(m, shape=(40, 30, 2), labels="part")
    assert v.labels.dtype == np.uint16
    assert len(np.unique(v.labels)) == 301


def die() -> Mesh:
    """A cube whose six faces each have their own material."""
    from geovox.mesh import Material

    box = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    normals = np.asarray(box.face_normals)
    side = np.argmax(np.abs(normals), axis=1) * 2 + (normals.max(axis=1) > 0.5)
    mats = [Material(name=f"face{k}", kd=np.array([k / 6, 0.5, 1 - k / 6])) for k in range(6)]
    return Mesh(np.asarray(box.vertices), np.asarray(box.faces), source="die",
                face_material=side.astype(np.int64), materials=mats)


def brute_material(mesh, vol, lset):
    """(labels, ties): the brute-force nearest face's material per inside voxel, and the
    number of voxels where faces of different materials are equally near."""
    from geovox.geometry import closest_on_triangles

    idx = np.argwhere(vol.occupancy)
    pts = vol.grid.lo + (idx + 0.5) * np.asarray(vol.spacing)
    tris = mesh.triangles
    d = np.empty((len(pts), len(tris)))
    for t in range(len(tris)):
        uv = closest_on_triangles(pts, np.broadcast_to(tris[t], (len(pts), 3, 3)))
        a, b, c = tris[t]
        q = a + uv[:, :1] * (b - a) + uv[:, 1:] * (c - a)
        d[:, t] = np.sum((q - pts) ** 2, axis=1)
    best = d.min(axis=1)
    near = d <= best[:, None] * (1 + 1e-9) + 1e-18
    lab = lset.face_label[np.argmin(d, axis=1)] + 1
    n_mats = np.array([len(set(lset.face_label[np.flatnonzero(r)])) for r in near])
    return idx, lab, near, n_mats > 1


@pytest.mark.parametrize("model", ["die", "cornell"])
def test_material_labels_are_the_brute_force_nearest_surface(model):
    from conftest import corpus

    if model == "die":
        m = die()
        kw = dict(shape=(13, 11, 9))
    else:
        m = load_mesh(corpus("cornell_box", "cornell_box.obj"))
        kw = dict(resolution=14)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        v = geovox.voxelize(m, labels="material", **kw)
    lset = L.label_set(m, "material")
    idx, lab, near, tie = brute_material(m, v, lset)
    got = v.labels[tuple(idx.T)]
    assert len(idx) > 100
    # Where one material is nearest, it is the label; at ties, one of the nearest faces'.
    np.testing.assert_array_equal(got[~tie], lab[~tie])
    for row in np.flatnonzero(tie):
        assert got[row] - 1 in set(lset.face_label[np.flatnonzero(near[row])])
    if model == "die":
        assert set(np.unique(v.labels)) == set(range(1, 7))  # six regions, the grid all inside
        assert tie.sum() > 0  # the cube's diagonal planes are ties, counted here
    assert [e["name"] for e in v.label_table[1:len(m.materials) + 1]] == \
        [x.name for x in m.materials]
    assert np.array_equal(v.occupancy, v.labels > 0)


@pytest.mark.parametrize("overlap", L.OVERLAPS)
def test_fractions_sum_to_the_union_and_match_coverage(overlap):
    m = assembly()
    grid = make_grid(m.bounds, shape=(30, 19, 17))
    kw = dict(shape=grid.shape, supersample=3)
    v = geovox.voxelize(m, labels="part", fractions=True, overlap=overlap,
                        density_dtype="float32", **kw)
    assert v.fractions.shape == grid.shape + (4,) and v.fractions.dtype == np.float32
    total = v.fractions.sum(axis=3)
    assert total.max() <= 1 + 1e-6 and v.fractions.min() >= 0
    union = trimesh.util.concatenate([trimesh.Trimesh(m.vertices, m.faces)])
    occs = alone(m, grid, "numpy")
    # The far box is alone: its fraction is its own coverage, value for value.
    far = L.part_mesh(m, np.flatnonzero(m.face_part == 3), "apart")
    own = geovox.voxelize(far, bounds=np.r_[grid.lo, grid.hi], density="coverage",
                          density_dtype="float32", **kw).density
    np.testing.assert_array_equal(v.fractions[..., 3], own)
    # Voxels deep inside one part alone hold all of it.
    deep = occs[0] & ~occs[1] & ~occs[2] & (v.fractions[..., 0] > 0.999)
    assert deep.sum() > 50
    # The winner of an overlap takes the shared voxels whole.
    both = occs[0] & occs[2]  # the inclusion inside the box
    winner = 2 if overlap in ("last", "smallest") else 0
    inner = both & (total > 0.999) & (v.fractions[..., 2 - winner] == 0)
    assert inner.sum() > 0
    del union
    u8 = geovox.voxelize(m, labels="part", fractions=True, overlap=overlap, **kw)
    assert u8.fractions.dtype == np.uint8
    assert int(u8.fractions.astype(int).sum(axis=3).max()) <= 255


def test_convert_to_with_labels_writes_them(tmp_path):
    from geovox import formats

    out = geovox.convert_to(assembly(), tmp_path / "a.h5", resolution=16, labels="part",
                            overlap="first")
    ref = geovox.voxelize(assembly(), resolution=16, labels="part", overlap="first")
    assert out["labels"] == 4 and out["contested"] == ref.contested
    np.testing.assert_array_equal(formats.read(tmp_path / "a.h5").labels, ref.labels)
    with pytest.raises(ParameterError, match="does not hold labels"):
        geovox.convert_to(assembly(), tmp_path / "a.binvox", resolution=8, labels="part")


def test_scene_nodes_are_parts_a_mesh_used_twice_is_two(tmp_path):
    box = trimesh.creation.box(extents=(1, 1, 1))
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="left", geom_name="cube")
    scene.add_geometry(box, node_name="right", geom_name="cube",
                       transform=trimesh.transformations.translation_matrix((2, 0, 0)))
    path = tmp_path / "two.glb"
    scene.export(path)
    m = load_mesh(str(path))
    # Named after node and mesh (trimesh's order of the scene's nodes).
    assert sorted(p.split(" ")[0] for p in m.parts) == ["left", "right"]
    assert all("(cube" in p for p in m.parts)
    v = geovox.voxelize(str(path), shape=(30, 10, 10), labels="part")
    name = {e["value"]: e["name"].split(" ")[0] for e in v.label_table}
    assert {name[int(x)] for x in np.unique(v.labels[:10])} == {"left"}
    assert {name[int(x)] for x in np.unique(v.labels[-10:])} == {"right"}
