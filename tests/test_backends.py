"""Cross-backend consistency and the backend registry."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import trimesh

import geovox
from geovox import backends
from geovox.errors import BackendUnavailableError, ParameterError
from geovox.block import ray_start

from conftest import SPOT, corpus, from_tm

needs_two = pytest.mark.skipif(len(geovox.available_backends()) < 2,
                               reason="needs both backends installed")

CLOSED_CORPUS = [
    ("spot", "spot/spot.obj"),
    ("bunny_oded", "bunny_watertight/bunny_oded.obj"),
    ("fuze", "fuze/fuze.obj"),
    ("quadknot", "trimesh_edge_cases/quadknot.obj"),
    ("box", "trimesh_edge_cases/box.obj"),
    ("negative_indices", "trimesh_edge_cases/negative_indices.obj"),
    ("textured_tetrahedron", "trimesh_edge_cases/textured_tetrahedron.obj"),
    ("rabbit", "trimesh_edge_cases/rabbit.obj"),
]


def t_junction_box() -> geovox.Mesh:
    """Unit cube whose top and bottom faces have T-junctions along their diagonal.

    Each of the two faces is one triangle on one side of the diagonal and a
    fan of three on the other, whose middle triangle shares no vertex with the
    big one but touches it along the diagonal. A z-ray through the diagonal
    crosses both faces at the depth of triangles that hide each other, twice,
    so a lost crossing would not even show as odd parity.
    """
    a, b = 1 / 3, 2 / 3
    v = []
    f = []
    for z, flip in ((0.0, True), (1.0, False)):
        o = len(v)
        v += [(0, 0, z), (1, 0, z), (1, 1, z), (0, 1, z), (a, a, z), (b, b, z)]
        tris = [(0, 1, 2), (0, 4, 3), (4, 5, 3), (5, 2, 3)]
        f += [tuple(o + i for i in (t[::-1] if flip else t)) for t in tris]
    # Side walls (quads split in two), outward.
    for i0, i1 in ((0, 1), (1, 2), (2, 3), (3, 0)):
        f += [(i0, i1, 6 + i1), (i0, 6 + i1, 6 + i0)]
    return geovox.Mesh(np.asarray(v, float), np.asarray(f, np.int64), source="t_junctions")


def _closed_synthetic():
    ico = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    yield "icosphere", from_tm(ico, "icosphere")
    tor = trimesh.creation.torus(major_radius=1.0, minor_radius=0.3)
    yield "torus", from_tm(tor, "torus")
    cap = trimesh.creation.capsule(height=1.0, radius=0.4)
    yield "capsule", from_tm(cap, "capsule")
    two = trimesh.util.concatenate([trimesh.creation.box((1, 1, 1)),
                                    trimesh.creation.box((1, 1, 1)).apply_translation((0.5, 0.5, 0.5))])
    yield "overlapping_boxes", from_tm(two, "overlapping_boxes")
    # Parts whose faces overlap in the same planes: a restart past one hides
    # the other from a naive multi-hit loop.
    coplanar = trimesh.util.concatenate([trimesh.creation.box((1, 1, 1)),
                                         trimesh.creation.box((1, 1, 1)).apply_translation((0.5, 0, 0))])
    yield "coplanar_overlap", from_tm(coplanar, "coplanar_overlap")
    # The same, tilted: the shared faces' normals are no longer axis-aligned.
    tilted = coplanar.copy()
    tilted.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 4, (0, 0, 1)))
    yield "coplanar_overlap_tilted", from_tm(tilted, "coplanar_overlap_tilted")
    yield "t_junctions", t_junction_box()
    dup = trimesh.creation.icosphere(subdivisions=2)
    yield "duplicated_faces", geovox.Mesh(np.asarray(dup.vertices),
                                          np.concatenate([dup.faces, dup.faces[:40]]), source="dup")


SYNTHETIC = list(_closed_synthetic())


def _both(mesh, **kw):
    return [geovox.voxelize(mesh, backend=b, **kw) for b in ("numpy", "embree")]


@needs_two
@pytest.mark.parametrize("name,rel", CLOSED_CORPUS, ids=[c[0] for c in CLOSED_CORPUS])
@pytest.mark.parametrize("res", [17, 64])
def test_backends_agree_on_corpus(name, rel, res):
    path = corpus(rel)
    a, b = _both(path, resolution=res)
    assert a.inside_count > 0
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@needs_two
@pytest.mark.parametrize("name,mesh", SYNTHETIC, ids=[s[0] for s in SYNTHETIC])
@pytest.mark.parametrize("res", [1, 2, 31, 96])
@pytest.mark.parametrize("axis", [0, 2])
# At 1 voxel the centre can miss a torus or a pair of boxes: an empty volume, with its warning.
@pytest.mark.filterwarnings("ignore:.*the volume is empty:geovox.errors.GeovoxWarning")
def test_backends_agree_on_synthetic(name, mesh, res, axis):
    a, b = _both(mesh, resolution=res, axis=axis, inside="parity")
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@needs_two
@pytest.mark.parametrize("bounds", [
    (-0.2, -0.3, -0.1, 0.3, 0.4, 0.5),  # cuts through the middle
    (0.0, 0.0, 0.0, 2.0, 2.0, 2.0),     # overhangs one corner
    (-0.05, -0.7, -0.6, 0.05, 0.9, 1.0),  # a thin slab
])
def test_backends_agree_on_subsections(bounds):
    a, b = _both(SPOT, shape=(40, 33, 27), bounds=bounds)
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@needs_two
def test_backends_agree_with_anisotropic_voxels():
    a, b = _both(SPOT, shape=(7, 90, 41))
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


# Even crossings on closed meshes and hits that lie on their rays: the
# contract of every backend, in tests/test_conformance.py (webgpu included).


def test_available_backends_lists_numpy_first_fallback():
    names = geovox.available_backends()
    assert "numpy" in names
    assert names == [n for n in backends.PREFERENCE if n in names]


def test_usable_backends_add_webgpu_where_an_adapter_exists(monkeypatch):
    import geovox.backends.webgpu as W

    names = geovox.usable_backends()
    assert names[:len(geovox.available_backends())] == geovox.available_backends()
    assert ("webgpu" in names) == W.describe().startswith("available")
    # No adapter: webgpu leaves the list, the others stay.
    monkeypatch.setattr(W, "describe", lambda: "missing: no GPU adapter; needs lavapipe")
    assert geovox.usable_backends() == [n for n in names if n != "webgpu"]
    monkeypatch.setattr(W, "describe", lambda: "available: test adapter (CPU, Vulkan)")
    assert geovox.usable_backends()[-1] == "webgpu"


def test_auto_picks_numpy_the_faster_for_column_rays():
    vol = geovox.voxelize(SPOT, resolution=8)
    assert vol.backend == geovox.available_backends()[0] == "numpy"


@pytest.fixture
def no_embreex(monkeypatch):
    """Make embreex (and trimesh's module that wraps it) fail to import."""
    monkeypatch.setitem(sys.modules, "embreex", None)
    monkeypatch.setitem(sys.modules, "trimesh.ray.ray_pyembree", None)
    monkeypatch.setattr(backends, "_instances", {})
    monkeypatch.setattr(backends, "_present", lambda m: m != "embreex")


def test_explicit_embree_without_embreex_names_the_package(no_embreex):
    with pytest.raises(BackendUnavailableError, match="embreex") as info:
        geovox.voxelize(SPOT, resolution=8, backend="embree")
    assert isinstance(info.value, ImportError)
    assert "pip install embreex" in str(info.value)


def test_auto_without_embreex_uses_numpy(no_embreex):
    assert geovox.available_backends() == ["numpy"]
    assert geovox.voxelize(SPOT, resolution=8).backend == "numpy"


def test_unknown_backend_is_a_parameter_error():
    with pytest.raises(ParameterError, match="`backend`.*'optix'"):
        geovox.voxelize(SPOT, resolution=8, backend="optix")


@pytest.mark.parametrize("chunk", [7, 1 << 19])
def test_box_pairs_match_brute_force(chunk):
    from geovox.backends.embree import box_pair_chunks

    rng = np.random.default_rng(5)
    lo = rng.random((400, 3))
    size = rng.random((400, 3)) * 0.05
    size[:3] = 0.9  # a few huge boxes, as a large triangle under small ones
    hi = lo + size
    lo[10:20] = lo[0]  # and some identical boxes
    hi[10:20] = hi[0]
    got = [tuple(p) for part in box_pair_chunks(lo, hi, chunk=chunk) for p in part]
    assert len(got) == len(set(got))  # each pair once, across chunks
    over = np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)
    want = {(i, j) for i, j in zip(*np.nonzero(np.triu(over, 1)))}
    assert set(got) == want


def test_crowded_cells_are_reported_not_paired(monkeypatch):
    import geovox.backends.embree as E

    monkeypatch.setattr(E, "MAX_RUN", 5)
    lo = np.zeros((8, 3))
    hi = np.ones((8, 3))  # eight boxes in one cell
    crowded = []
    assert list(E.box_pair_chunks(lo, hi, crowded=crowded)) == []
    np.testing.assert_array_equal(np.concatenate(crowded), np.arange(8))


def test_coplanar_overlaps_flags_only_what_a_restart_can_hide():
    from geovox.backends.embree import coplanar_overlaps
    from geovox.mesh import Mesh

    box = trimesh.creation.box((1, 1, 1))
    # Pieces of flat faces that only meet at shared vertices and edges: none.
    fine = box.subdivide().subdivide()
    assert not coplanar_overlaps(from_tm(fine, "fine")).any()
    # Duplicated faces and folded-over faces: both partners.
    dup = Mesh(np.asarray(box.vertices), np.concatenate([box.faces, box.faces[:2]]))
    assert coplanar_overlaps(dup).sum() == 4
    # A fold: two triangles on one edge, both on the same side of it; and the
    # two halves of a square (sides apart), which must not count.
    v = np.array([[0, 0, 0], [1, 0, 0], [0.3, 1, 0], [0.6, 0.8, 0], [0.5, -1, 0.0]])
    fold = Mesh(v, np.array([[0, 1, 2], [1, 0, 3], [0, 4, 1]]))
    assert list(coplanar_overlaps(fold)) == [True, True, False]
    # T-junction: the fan's middle triangle and the big one touch, sharing no vertex.
    flags = coplanar_overlaps(t_junction_box())
    assert set(np.flatnonzero(flags)) == {0, 2, 4, 6}


@needs_two
@pytest.mark.parametrize("inside", ["parity", "winding"])
def test_backends_agree_through_t_junctions(inside, monkeypatch):
    # Column centres on the T-junction diagonal at many resolutions. The
    # mesh is closed only geometrically, so `winding` caps its "holes" with
    # flat fans along the diagonal: without flagging triangles that touch
    # without sharing a vertex, Embree lost crossings there (17 of these 78
    # grids differed). Each lattice's own pairing, not the tiny meshes' every pair.
    from geovox.backends import embree as E

    monkeypatch.setattr(E, "FEW", 0)
    mesh = t_junction_box()
    for res in range(1, 40):
        for bounds in [(0, 0, -0.5, 1, 1, 1.5), (-0.01, -0.01, -0.5, 1.01, 1.01, 1.5)]:
            a, b = _both(mesh, shape=(res, res, 4), bounds=bounds, inside=inside)
            np.testing.assert_array_equal(a.occupancy, b.occupancy, err_msg=f"{res} {bounds}")


@needs_two
def test_backends_agree_on_parts_stacked_with_a_hairline_gap():
    # Faces 3e-8 of the mesh size apart pass the coplanarity test but their
    # bounding boxes do not touch: the pairing must pad boxes by as much as
    # the test allows, or Embree loses both crossings of every ray.
    parts = [trimesh.creation.box((1, 1, 1)).apply_translation((0.5, 0.5, 0.5 + k * (1 + 1e-7)))
             for k in range(3)]
    mesh = from_tm(trimesh.util.concatenate(parts), "stacked")
    a, b = _both(mesh, shape=(8, 8, 24), inside="parity")
    assert a.inside_count == 1536
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@needs_two
def test_backends_agree_on_big_fans():
    # Caps of a 1,500-sided cylinder: every cap triangle meets every other at
    # the hub, so they are flagged wholesale instead of paired (and found by
    # the exact rasteriser).
    from geovox.backends.embree import coplanar_overlaps

    mesh = from_tm(trimesh.creation.cylinder(radius=1, height=2, sections=1500), "fan")
    assert coplanar_overlaps(mesh).sum() >= 3000
    a, b = _both(mesh, resolution=40, inside="parity")
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


def test_fans_flagged_where_they_overlap(monkeypatch):
    # Flat fans wound round more than once (triangles overlapping in pairs
    # that share only the hub), with folds, duplicated and nearly coplanar
    # faces: the box hash gives the flags of settling every pair, and each
    # lattice's flags lie between what its rays see and those.
    from geovox.backends import embree as E
    from geovox.mesh import Mesh

    from test_exact import _all_pairs, _seen_hiding

    rng = np.random.default_rng(5)
    ring = np.linspace(0, 4 * np.pi, 13)[:-1]
    v = np.r_[[[0, 0, 0]], np.c_[np.cos(ring), np.sin(ring), np.zeros(12)]]
    meshes = [Mesh(v, np.array([[0, i, i % 12 + 1] for i in range(1, 13)]))]
    for k in range(60):
        nv = int(rng.integers(4, 12))
        v = np.c_[rng.normal(size=(nv, 2)), rng.normal(size=nv) * (1e-7 if k % 3 == 0 else 0.0)]
        f = [[0, i, i + 1] for i in range(1, nv - 1)]
        f += [list(rng.choice(nv, 3, replace=False)) for _ in range(int(rng.integers(0, 4)))]
        meshes.append(Mesh(v, np.array(f)))
    monkeypatch.setattr(E, "FEW", 0)  # each lattice's own pairing
    got = [E.coplanar_overlaps(m) for m in meshes]
    assert got[0].all()
    assert sum(g.any() for g in got) > 20
    for m, g in zip(meshes, got):
        grid = geovox.grid.make_grid(m.bounds, resolution=int(rng.integers(3, 30)))
        columns = grid.columns(2, start=ray_start(m, grid, 2))
        lattice = E.coplanar_overlaps(m, columns)
        assert not (_seen_hiding(m, columns) & ~lattice).any()
        assert not (lattice & ~g).any()
    monkeypatch.setattr(E, "box_pair_chunks", _all_pairs)
    for m, g in zip(meshes, got):
        np.testing.assert_array_equal(E.coplanar_overlaps(m), g)


@needs_two
@pytest.mark.filterwarnings("ignore:.*the volume is empty:geovox.errors.GeovoxWarning")
def test_backends_agree_where_no_ray_passes_near_a_triangle(monkeypatch):
    # The one column centre lies in the triangles' boxes but outside the
    # tetrahedron's shadow: Embree's scene for this lattice holds nothing
    # (with the lattice's own pairing, not the tiny meshes' every pair).
    from geovox.backends import embree as E

    monkeypatch.setattr(E, "FEW", 0)
    tet = geovox.Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                      np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]), source="tet")
    kw = dict(shape=(1, 1, 4), bounds=(0.8, 0.8, -0.5, 1.0, 1.0, 1.5), inside="parity")
    a, b = _both(tet, **kw)
    assert a.inside_count == 0
    np.testing.assert_array_equal(a.occupancy, b.occupancy)
    from geovox.backends.embree import EmbreeBackend

    grid = geovox.grid.make_grid(tet.bounds, bounds=kw["bounds"], shape=kw["shape"])
    assert len(EmbreeBackend().setup(tet, grid.columns(2, start=-1.0))[1]) == 0
