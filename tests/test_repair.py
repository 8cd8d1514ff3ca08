"""Repair before winding: flipped, doubled, duplicated, overlapping and many-piece models."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
import trimesh
from scipy import ndimage

import geovox
from geovox import inside
from geovox.inside import captree
from geovox.errors import GeovoxWarning, GridTooLargeError
from geovox.inside.repair import repair
from geovox.block import ray_start

from conftest import box_mesh, from_tm


def brute_winding(mesh, grid):
    """Generalised winding number > 1/2 at every voxel centre, summed over all triangles."""
    c = [grid.centres(a) for a in range(3)]
    p = np.stack(np.meshgrid(*c, indexing="ij"), -1).reshape(-1, 3)
    return (inside.solid_angles(mesh.triangles, p) > 0.5).reshape(grid.shape)


def sphere(subdivisions=3):
    return from_tm(trimesh.creation.icosphere(subdivisions=subdivisions), "sphere")


def flipped(mesh, share=0.3, seed=0):
    rng = np.random.default_rng(seed)
    sel = rng.random(len(mesh.faces)) < share
    f = mesh.faces.copy()
    f[sel] = f[sel][:, ::-1]
    return geovox.Mesh(mesh.vertices, f, source="flipped"), sel


def open_boxes(n, seed=0, share=0.3):
    """``n`` small boxes without their top, placed and turned at random, faces flipped at random."""
    rng = np.random.default_rng(seed)
    b = trimesh.creation.box((1, 1, 1))
    f0 = np.asarray(b.faces)[b.triangles_center[:, 2] < 0.49]
    V, F = [], []
    for i in range(n):
        R = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
        V.append(np.asarray(b.vertices) * rng.uniform(0.1, 0.25) @ R.T + rng.uniform(0, 1, 3))
        F.append(f0 + 8 * i)
    F = np.concatenate(F)
    sel = rng.random(len(F)) < share
    F[sel] = F[sel][:, ::-1]
    return geovox.Mesh(np.concatenate(V), F, source="open boxes")


def test_repair_undoes_random_flips_exactly():
    clean = sphere()
    bad, sel = flipped(clean)
    rep = repair(bad)
    np.testing.assert_array_equal(rep.swapped, sel)
    assert rep.flipped == sel.sum() and rep.pieces == 1 and rep.closed_pieces == 1
    assert len(inside.boundary_edges(rep.mesh)) == 0


def test_repair_counts_degenerate_and_duplicate_faces():
    m = sphere(1)
    f = m.faces
    extra = np.array([[0, 0, 1], [2, 3, 3]])  # repeated vertices
    faces = np.concatenate([f, f[:5], f[5:8][:, ::-1], f[8:9][:, [1, 2, 0]], extra])
    rep = repair(geovox.Mesh(m.vertices, faces, source="dups"))
    assert rep.degenerate == 2
    assert rep.duplicates == 6  # five copies and one rotated copy
    assert rep.opposite == 3
    assert len(rep.mesh.faces) == len(f)
    assert len(inside.boundary_edges(rep.mesh)) == 0


def test_repair_turns_an_inside_out_open_piece_outward():
    b = box_mesh((0, 0, 0), (1, 1, 1))
    top = b.triangles.mean(axis=1)[:, 2] > 0.999
    good = geovox.Mesh(b.vertices, b.faces[~top], source="open box")
    inverted = geovox.Mesh(b.vertices, b.faces[~top][:, ::-1], source="inverted open box")
    assert repair(good).outward == 0 and repair(inverted).outward == 1
    with pytest.warns(GeovoxWarning):
        a = geovox.voxelize(good, resolution=10)
    with pytest.warns(GeovoxWarning, match=r"10 faces wound the wrong way"):
        c = geovox.voxelize(inverted, resolution=10)
    # The warning's details are geovox info's.
    from geovox.report import mesh_report

    assert "1 turned outward as a whole" in mesh_report(inverted)["repair"]["summary"]
    np.testing.assert_array_equal(a.occupancy, c.occupancy)
    assert a.inside_count > 0


@pytest.mark.parametrize("variant", ["flipped", "doubled_reversed", "doubled", "repeated_236"])
def test_broken_variants_of_a_closed_model_give_its_exact_volume(variant, backend):
    clean = sphere(2 if variant == "repeated_236" else 3)
    if variant == "flipped":
        bad = flipped(clean)[0]
    elif variant == "doubled_reversed":
        bad = geovox.Mesh(clean.vertices, np.concatenate([clean.faces, clean.faces[:, ::-1]]))
    elif variant == "doubled":
        bad = geovox.Mesh(clean.vertices, np.concatenate([clean.faces, clean.faces]))
    else:  # every face repeated, as an OBJ face line that repeats its indices makes it
        bad = geovox.Mesh(clean.vertices, np.repeat(clean.faces, 236, axis=0)[:, [1, 2, 0]])
    ref = geovox.voxelize(clean, resolution=24, backend=backend)
    assert ref.inside == "parity"
    with pytest.warns(GeovoxWarning, match="of a repaired"):
        vol = geovox.voxelize(bad, resolution=24, backend=backend)
    assert vol.inside == "winding"
    np.testing.assert_array_equal(vol.occupancy, ref.occupancy)


def test_overlapping_closed_parts_count_their_shared_space_silently(backend):
    two = trimesh.util.concatenate([trimesh.creation.box((1, 1, 1)),
                                    trimesh.creation.box((1, 1, 1)).apply_translation((0.5, 0, 0))])
    mesh = from_tm(two, "overlap")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        vol = geovox.voxelize(mesh, resolution=17, backend=backend)
    assert vol.inside == "winding"
    assert vol.occupancy.all()  # the two boxes fill their bounding box
    apart = from_tm(trimesh.util.concatenate(
        [trimesh.creation.box((1, 1, 1)),
         trimesh.creation.box((1, 1, 1)).apply_translation((1.5, 0, 0))]), "apart")
    assert geovox.voxelize(apart, resolution=17, backend=backend).inside == "parity"


def test_a_cavity_inside_an_inward_shell_stays_empty(backend):
    outer = trimesh.creation.box((2, 2, 2))
    inner = trimesh.creation.box((1, 1, 1))
    inner.invert()
    mesh = from_tm(trimesh.util.concatenate([outer, inner]), "hollow")
    vol = geovox.voxelize(mesh, resolution=16, backend=backend)
    assert vol.inside == "winding"
    np.testing.assert_array_equal(
        vol.occupancy, geovox.voxelize(mesh, resolution=16, inside="parity", backend=backend).occupancy)
    assert not vol.occupancy[8, 8, 8]


def test_flipped_overlapping_parts_match_brute_force_of_the_repaired_copy(backend):
    a = sphere(2)
    b = geovox.Mesh(a.vertices + [0.7, 0.2, 0.1], a.faces)
    both = geovox.Mesh(np.concatenate([a.vertices, b.vertices]),
                       np.concatenate([a.faces, b.faces + len(a.vertices)]))
    bad = flipped(both, seed=5)[0]
    assert "2 pieces" in inside.target(bad)[1].describe()  # what geovox info reports
    with pytest.warns(GeovoxWarning, match="of a repaired, closed copy"):
        vol = geovox.voxelize(bad, resolution=18, backend=backend)
    np.testing.assert_array_equal(vol.occupancy, brute_winding(inside.target(bad)[0], vol.grid))
    np.testing.assert_array_equal(vol.occupancy, brute_winding(both, vol.grid))


def test_many_small_holes_match_brute_force(backend):
    m = sphere(3)
    rng = np.random.default_rng(1)
    keep = np.ones(len(m.faces), bool)
    keep[rng.choice(len(m.faces), 150, replace=False)] = False
    holed = geovox.Mesh(m.vertices, m.faces[keep], source="holes")
    bad = flipped(holed, seed=2)[0]
    with pytest.warns(GeovoxWarning):
        vol = geovox.voxelize(bad, resolution=16, backend=backend,
                              bounds=(-1.1, -1.05, -1.2, 1.1, 1.15, 1.05))
    rep = inside.target(bad)[1]
    np.testing.assert_array_equal(vol.occupancy, brute_winding(rep.mesh, vol.grid))
    # Pieces cut off by the holes (faces that touch the rest at vertices only)
    # carry no orientation of their own: a flat one keeps what it had. All
    # the rest is turned back as it was.
    sel = flipped(holed, seed=2)[1]
    wrong = rep.swapped != sel[rep.face]
    size = np.bincount(rep.piece)
    assert rep.pieces > 1 and np.all(size[rep.piece[wrong]] <= 2)


@pytest.mark.parametrize("direct", [True, False], ids=["direct", "passes"])
def test_many_piece_open_assembly_matches_brute_force_of_the_repaired_copy(backend, direct,
                                                                           monkeypatch):
    # "passes": no shortcut to the exact sum, so every refining pass runs.
    if not direct:
        monkeypatch.setattr(captree, "DIRECT", 0)
    mesh = open_boxes(40)
    assert "40 pieces" in inside.target(mesh)[1].describe()  # what geovox info reports
    with pytest.warns(GeovoxWarning, match="not closed .* of a repaired copy"):
        vol = geovox.voxelize(mesh, resolution=22, backend=backend)
    rep = inside.target(mesh)[0]
    np.testing.assert_array_equal(vol.occupancy, brute_winding(rep, vol.grid))
    assert vol.inside_count > 0


def test_crossings_of_the_copy_are_crossings_of_the_original_triangles():
    from geovox.backends.numpy import NumpyBackend

    bad, _ = flipped(sphere(2), seed=3)
    rep = repair(bad)
    grid = geovox.grid.make_grid(bad.bounds, resolution=12)
    cols = grid.columns(2, start=ray_start(bad, grid, 2))
    hits = NumpyBackend().cast(rep.mesh, cols)
    mapped = rep.original_hits(hits)

    def points(mesh, h):
        t = mesh.triangles[h.triangle]
        u, v = h.bary[:, 0:1], h.bary[:, 1:2]
        return (1 - u - v) * t[:, 0] + u * t[:, 1] + v * t[:, 2]

    np.testing.assert_allclose(points(bad, mapped), points(rep.mesh, hits), atol=1e-12)


def test_colour_follows_a_repaired_copy(backend):
    bad, _ = flipped(sphere(2), seed=4)
    with pytest.warns(GeovoxWarning):
        vol = geovox.voxelize(bad, resolution=14, color=True, backend=backend)
    np.testing.assert_array_equal(vol.colors[..., 3] == 255, vol.occupancy)
    assert vol.inside_count > 0


def test_winding_that_cannot_fit_says_so_before_allocating(monkeypatch):
    from geovox import memory

    mesh = open_boxes(3)
    grid_voxels = 40 ** 3
    # Enough for the occupancy grid, not for the winding number's working arrays.
    monkeypatch.setattr(memory, "available_memory", lambda: int(grid_voxels * 4))  # 16 needed
    with pytest.warns(GeovoxWarning), pytest.raises(GridTooLargeError, match="needs"):
        geovox.voxelize(mesh, resolution=40, inside="auto")


def test_info_says_what_auto_repairs(tmp_path, capsys):
    from geovox.cli import main

    bad, sel = flipped(sphere(2), seed=6)
    path = tmp_path / "flipped.stl"
    trimesh.Trimesh(bad.vertices, bad.faces, process=False).export(path)
    assert main(["info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "not consistently wound" in out
    assert f"{sel.sum():,} faces flipped" in out and "the copy is closed" in out


def test_streamed_winding_of_a_repaired_copy_equals_the_volume_in_one_piece(tmp_path):
    import geovox.formats as F
    from geovox.api import convert_to

    mesh = open_boxes(12, seed=3)
    with pytest.warns(GeovoxWarning, match="of a repaired"):
        ref = geovox.voxelize(mesh, shape=(16, 16, 150), axis=1)
    with pytest.warns(GeovoxWarning, match="of a repaired"):
        # 16 bytes a voxel: the winding number's working arrays count in the plan.
        info = convert_to(mesh, tmp_path / "s.h5", shape=(16, 16, 150), budget=16 * 16 * 64 * 17)
    assert info["slabs"] == 3 and info["inside_test"] == "winding"
    np.testing.assert_array_equal(F.read(tmp_path / "s.h5").occupancy, ref.occupancy)


def test_past_the_work_budget_the_estimate_decides_with_a_warning(monkeypatch):
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")  # the NumPy traversal's budget, of time
    mesh = open_boxes(40)
    with pytest.warns(GeovoxWarning):
        exact = geovox.voxelize(mesh, resolution=22)
    assert exact.approximate == 0
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    with pytest.warns(GeovoxWarning) as record:
        rough = geovox.voxelize(mesh, resolution=22)
    said = [re.search("([0-9,]+) of 10,648 voxels .* are approximate; the holes' caps passed the "
                      "work budget", str(r.message)) for r in record]
    (n,) = [int(m.group(1).replace(",", "")) for m in said if m]
    assert rough.approximate == n > 0
    # The first pass's estimate (error bound up to its opening ratio) still
    # decides nearly every voxel as the exact sum does.
    assert np.mean(rough.occupancy == exact.occupancy) >= 0.99


@pytest.mark.filterwarnings("ignore:.*the volume is empty:geovox.errors.GeovoxWarning")
def test_a_mesh_of_degenerate_faces_only_gives_an_empty_volume(backend):
    # Found by hypothesis: the repair drops every face, and nothing may break after it.
    v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 1.0]])
    mesh = geovox.Mesh(v, np.array([[0, 1, 2], [0, 0, 3]]), source="degenerate")
    assert len(repair(mesh).mesh.faces) == 0
    with pytest.warns(GeovoxWarning, match="2 degenerate faces"):
        vol = geovox.voxelize(mesh, resolution=4, color=True, backend=backend)
    assert vol.inside_count == 0


@pytest.mark.parametrize("sub", [0, 2, 4])
def test_vertex_connectivity_without_scipy_matches_csgraph(sub):
    # The closed-mesh fast path searches the vertex graph in NumPy so the
    # default conversion never imports scipy; check it against csgraph.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from geovox.inside.edges import vertex_connected

    def one_component(g):
        nv = int(g.max()) + 1
        rows, cols = np.r_[g[:, 0], g[:, 1]], np.r_[g[:, 1], g[:, 2]]
        graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(nv, nv))
        return connected_components(graph, directed=False)[0] - (nv - len(np.unique(g))) == 1

    rng = np.random.default_rng(sub)
    f = np.asarray(trimesh.creation.icosphere(subdivisions=sub).faces, dtype=np.int64)
    n = int(f.max()) + 1
    cases = [f, np.vstack([f, f + n]), f[rng.permutation(len(f))[: max(1, len(f) // 3)]],
             f[rng.permutation(len(f))], np.vstack([f, f[:1] + n])]
    for g in cases:
        assert vertex_connected(g) == one_component(g)


def test_a_refining_pass_sure_to_pass_the_budget_is_not_started(monkeypatch):
    # The pairs the first pass ended at on unsure voxels are a lower bound on
    # the next pass's work: past the budget, it is skipped (same result).
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    mesh = open_boxes(40)
    calls = []
    real = captree.cap_winding
    monkeypatch.setattr(captree, "cap_winding", lambda *a, **k: calls.append(k) or real(*a, **k))
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    with pytest.warns(GeovoxWarning) as record:
        geovox.voxelize(mesh, resolution=22)
    assert len(calls) == 1
    assert any("work budget" in str(r.message) for r in record)


@pytest.mark.parametrize("mesh,res", [(open_boxes(40), 22), (open_boxes(12, seed=2), 30)])
def test_the_next_pass_handles_at_least_the_work_bound(mesh, res, monkeypatch):
    # _sure_work is a lower bound on the next pass's pairs: given a budget
    # one below it, that pass must give up (cap_winding gives up exactly when
    # it handles more than its budget), and given the bound it may not.
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    seen = []
    real = captree._sure_work
    monkeypatch.setattr(captree, "_sure_work", lambda *a: seen.append((real(*a), a[3])) or 0.0)
    monkeypatch.setattr(captree, "PASSES", captree.PASSES[:2])  # stop after the second pass
    monkeypatch.setattr(captree, "DIRECT", 0)  # no shortcut to the exact sum
    calls = []
    real_cw = captree.cap_winding
    monkeypatch.setattr(captree, "cap_winding", lambda *a, **k: calls.append(a) or real_cw(*a, **k))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        geovox.voxelize(mesh, resolution=res)
    bound, active = seen[0]
    grid, tris = calls[0][0], calls[0][1]
    theta, eps = captree.PASSES[1]
    assert bound > 1000  # the bound says something
    assert real_cw(grid, tris, active, theta=theta, eps=eps, budget=int(np.ceil(bound)) - 1) is None
    assert real_cw(grid, tris, active, theta=theta, eps=eps, budget=None) is not None


@pytest.mark.parametrize("seed", range(6))
def test_components_and_parities_without_scipy_match_csgraph(seed):
    # repair.components replaces scipy's csgraph on the winding path (whose
    # import alone costs 0.2-0.4 s): same pieces, numbered the same way, and
    # parities that satisfy every edge of a consistent graph.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from geovox.inside.edges import components

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    e = int(rng.integers(0, 2 * n))
    a, b = rng.integers(0, n, e), rng.integers(0, n, e)
    if seed == 0:  # a long path numbered at random: many hooking rounds
        perm = rng.permutation(n)
        a, b = perm[:-1], perm[1:]
    flip = rng.random(n) < 0.5  # a hidden truth the edge parities come from
    count, label, parity = components(n, a, b, flip[a] != flip[b])
    ref_count, ref_label = connected_components(
        coo_matrix((np.ones(len(a)), (a, b)), shape=(n, n)), directed=False)
    assert count == ref_count
    np.testing.assert_array_equal(label, ref_label)
    first = np.unique(label, return_index=True)[1]
    np.testing.assert_array_equal(parity, flip ^ flip[first[label]])


@pytest.mark.parametrize("seed", range(4))
def test_close_pairs_match_a_kd_tree(seed):
    from scipy.spatial import cKDTree

    from geovox.inside.repair import close_pairs

    rng = np.random.default_rng(seed)
    tol = 0.05
    # Clusters, points on cell boundaries, exact duplicates and far ones.
    p = rng.random((300, 3))
    p = np.concatenate([p, p[:40] + rng.normal(scale=tol / 2, size=(40, 3)),
                        np.round(p[:30] / tol) * tol, p[:5], [[1e3, -2e3, 5.0]]])
    got = close_pairs(p, tol)
    ref = np.sort(cKDTree(p).query_pairs(tol, output_type="ndarray"), axis=1)
    assert len(got) > 40
    assert sorted(map(tuple, got)) == sorted(map(tuple, ref))


def _pyramid_halves(gap=0.0):
    """Two closed square pyramids sharing their base (apexes up and down), each with its own base."""
    base = np.array([[1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0.0]])
    up = np.vstack([base, [[0, 0, 1.0]]])
    down = np.vstack([base + [0, 0, -gap], [[0, 0, -1.0]]])
    sides = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    top = from_tm(trimesh.Trimesh(up, np.vstack([sides, [[0, 3, 2], [0, 2, 1]]])), "top")
    bottom = from_tm(trimesh.Trimesh(down, np.vstack([sides[:, ::-1], [[0, 1, 2], [0, 2, 3]]])),
                     "bottom")
    for m in (top, bottom):
        assert inside.consistent(m)
    return geovox.Mesh(np.concatenate([top.vertices, bottom.vertices]),
                       np.concatenate([top.faces, bottom.faces + len(top.vertices)]), source="die")


def test_an_inner_wall_between_two_closed_parts_goes_on_both_sides(backend):
    # Found by bench_wild (trimesh's TestScene.gltf): a die made of two closed
    # halves, each with its own copy of the cut. Keeping one copy left a sheet
    # inside the solid, and with a ground plane beside it the die came out empty.
    die = _pyramid_halves()
    rep = inside.target(die)[1]
    assert (rep.opposite, rep.inner, rep.pieces, rep.closed_pieces) == (2, 2, 1, 1)
    octahedron = from_tm(trimesh.Trimesh(
        np.r_[die.vertices[:4], [[0, 0, 1.0], [0, 0, -1.0]]],
        [[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 0, 5], [2, 1, 5], [3, 2, 5], [0, 3, 5]]),
        "octahedron")
    assert inside.consistent(octahedron)
    kw = dict(resolution=20, backend=backend, bounds=(-1.1, -1.1, -1.1, 1.1, 1.1, 1.1))
    assert "inner walls" in rep.describe()  # what geovox info reports
    with pytest.warns(GeovoxWarning, match="2 duplicate faces"):
        vol = geovox.voxelize(die, **kw)
    np.testing.assert_array_equal(vol.occupancy, geovox.voxelize(octahedron, **kw).occupancy)
    # With a ground sheet under it (facing up), as in the scene, a wall left
    # inside would take voxels out of the die.
    plane = np.array([[-9, -9, -1.02], [9, -9, -1.02], [9, 9, -1.02], [-9, 9, -1.02]])
    scene = geovox.Mesh(np.r_[die.vertices, plane],
                        np.r_[die.faces, len(die.vertices) + np.array([[0, 1, 2], [0, 2, 3]])])
    assert "inner walls" in inside.target(scene)[1].describe()
    with pytest.warns(GeovoxWarning, match="of a repaired"):
        vol = geovox.voxelize(scene, **kw)
    sheet = geovox.Mesh(plane, np.array([[0, 1, 2], [0, 2, 3]]))
    ref = brute_winding(geovox.Mesh(np.r_[octahedron.vertices, plane], np.r_[
        octahedron.faces, len(octahedron.vertices) + sheet.faces]), vol.grid)
    np.testing.assert_array_equal(vol.occupancy, ref)
    wall = die.faces[4:6]  # the top half's copy of the cut, kept alone
    leaky = brute_winding(geovox.Mesh(np.r_[octahedron.vertices, plane, die.vertices], np.r_[
        octahedron.faces, 6 + sheet.faces, 10 + wall]), vol.grid)
    assert np.count_nonzero(leaky != ref) > 0
    # A double-sided shell or sheet has no such rim: one side stays.
    doubled = geovox.Mesh(die.vertices[:5], np.r_[die.faces[:6], die.faces[:6, ::-1]])
    rep = inside.target(doubled)[1]
    assert (rep.opposite, rep.inner, len(rep.mesh.faces)) == (6, 0, 6)


def test_coverage_of_overlapping_parts_follows_the_winding_number(backend):
    # Two overlapping spheres: the density counts their shared space as the
    # occupancy does (the winding number, 2 there), not parity (outside).
    two = trimesh.util.concatenate([trimesh.creation.icosphere(3),
                                    trimesh.creation.icosphere(3).apply_translation((0.8, 0.1, 0))])
    mesh = from_tm(two, "overlap")
    vol = geovox.voxelize(mesh, resolution=24, backend=backend, density="coverage",
                          density_dtype="float32", supersample=2)
    assert vol.inside == "winding"
    # Voxels deep inside (no surface within them) are full, and those well
    # outside empty, in the shared space too.
    deep = ndimage.binary_erosion(vol.occupancy, iterations=2)
    assert np.count_nonzero(deep) > 1000
    assert np.all(vol.density[deep] >= 1 - 1e-5)  # float32 running sums
    assert np.all(vol.density[~ndimage.binary_dilation(vol.occupancy, iterations=2)] <= 1e-5)
    # The shared space alone: the middle of the overlap.
    g = vol.grid
    i, j, k = (np.searchsorted(g.centres(a), c) for a, c in enumerate((0.4, 0.05, 0.0)))
    assert vol.occupancy[i, j, k] and vol.density[i, j, k] >= 1 - 1e-5
    # Parity along the rays (the signs left out) has it empty.
    from geovox.density import coverage, sub_columns
    from geovox.block import ray_start

    sub = sub_columns(g.columns(2, start=ray_start(mesh, g, 2)), 2)
    hits = geovox.backends.get_backend(backend).cast(mesh, sub)
    assert coverage(hits, sub, g, 2)[i, j, k] <= 1e-5
