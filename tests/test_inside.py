"""Inside/outside methods on open, leaky and self-intersecting meshes."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import trimesh

import geovox
from geovox.errors import GeovoxWarning, ParameterError
from geovox.inside import boundary_edges, captree, solid_angles

from conftest import SPOT, box_mesh, corpus, from_tm


def brute_winding(mesh, grid):
    """Generalised winding number > 1/2 at every voxel centre, summed over all triangles."""
    c = [grid.centres(a) for a in range(3)]
    p = np.stack(np.meshgrid(*c, indexing="ij"), -1).reshape(-1, 3)
    return (solid_angles(mesh.triangles, p) > 0.5).reshape(grid.shape)


def holed_sphere(cut=0.6):
    m = trimesh.creation.icosphere(subdivisions=2)
    keep = m.triangles_center[:, 2] < cut
    return geovox.Mesh(np.asarray(m.vertices), np.asarray(m.faces)[keep], source="holed sphere")


def open_box():
    b = box_mesh((0, 0, 0), (1, 1, 1))
    top = b.triangles.mean(axis=1)[:, 2] > 0.999
    return geovox.Mesh(b.vertices, b.faces[~top], source="open box")


def many_holes():
    m = trimesh.creation.icosphere(subdivisions=3)
    rng = np.random.default_rng(3)
    keep = np.ones(len(m.faces), bool)
    keep[rng.choice(len(m.faces), 40, replace=False)] = False
    return geovox.Mesh(np.asarray(m.vertices), np.asarray(m.faces)[keep], source="many holes")


OPEN = [("holed_sphere", holed_sphere(), 20), ("big_hole", holed_sphere(0.0), 20),
        ("open_box", open_box(), 12), ("many_holes", many_holes(), 24)]


@pytest.mark.parametrize("direct", [True, False], ids=["direct", "passes"])
@pytest.mark.parametrize("name,mesh,res", OPEN, ids=[o[0] for o in OPEN])
def test_winding_equals_brute_force_generalised_winding_number(name, mesh, res, backend, direct,
                                                               monkeypatch):
    if not direct:  # every refining pass runs, no shortcut to the exact sum
        monkeypatch.setattr(geovox.inside.captree, "DIRECT", 0)
    assert len(boundary_edges(mesh)) > 0
    vol = geovox.voxelize(mesh, resolution=res, inside="winding", backend=backend,
                          bounds=np.r_[mesh.bounds[0] - 0.13, mesh.bounds[1] + 0.11])
    np.testing.assert_array_equal(vol.occupancy, brute_winding(mesh, vol.grid))


def test_winding_on_suzanne_matches_brute_force(backend):
    mesh = geovox.load_mesh(corpus("suzanne", "suzanne.obj"))
    vol = geovox.voxelize(mesh, resolution=28, inside="winding", backend=backend)
    ref = brute_winding(mesh, vol.grid)
    assert np.count_nonzero(vol.occupancy != ref) == 0
    parity = geovox.voxelize(mesh, resolution=28, inside="parity", backend=backend)
    assert np.count_nonzero(parity.occupancy != ref) > 0  # parity leaks here


def test_winding_fills_small_holes_like_the_closed_mesh(backend):
    closed = from_tm(trimesh.creation.icosphere(subdivisions=3), "sphere")
    holes = many_holes()
    a = geovox.voxelize(closed, resolution=40, backend=backend)
    b = geovox.voxelize(holes, resolution=40, inside="winding", backend=backend,
                        bounds=np.r_[closed.bounds[0], closed.bounds[1]])
    # The winding number of a holed mesh dips below 1/2 right next to a hole,
    # so a few voxels there may differ from the closed mesh, and then the
    # brute-force winding number agrees with geovox, not with the closed mesh.
    diff = np.argwhere(a.occupancy != b.occupancy)
    assert len(diff) <= 1e-3 * a.inside_count
    if len(diff):
        p = np.stack([b.grid.centres(k)[diff[:, k]] for k in range(3)], axis=1)
        np.testing.assert_array_equal(solid_angles(holes.triangles, p) > 0.5, b.occupancy[tuple(diff.T)])


def test_winding_equals_parity_on_closed_meshes(backend):
    a = geovox.voxelize(SPOT, resolution=40, inside="parity", backend=backend)
    b = geovox.voxelize(SPOT, resolution=40, inside="winding", backend=backend)
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


def test_overlapping_parts_are_inside_with_winding_not_parity(backend):
    two = trimesh.util.concatenate([trimesh.creation.box((1, 1, 1)),
                                    trimesh.creation.box((1, 1, 1)).apply_translation((0.5, 0, 0))])
    mesh = from_tm(two, "overlap")
    bounds = (-0.6, -0.6, -0.6, 1.1, 0.6, 0.6)
    w = geovox.voxelize(mesh, resolution=17, inside="winding", backend=backend, bounds=bounds)
    p = geovox.voxelize(mesh, resolution=17, inside="parity", backend=backend, bounds=bounds)
    centre_x = w.grid.centres(0)
    overlap = (centre_x > 0.0) & (centre_x < 0.5)
    assert w.occupancy[overlap, 8, 8].all()
    assert not p.occupancy[overlap, 8, 8].any()
    np.testing.assert_array_equal(w.occupancy, brute_winding(mesh, w.grid))


def test_vote_is_the_majority_of_three_axes(backend):
    mesh = holed_sphere()
    kw = dict(resolution=18, backend=backend)
    axes = [geovox.voxelize(mesh, inside="parity", axis=a, **kw).occupancy.astype(int) for a in range(3)]
    vote = geovox.voxelize(mesh, inside="vote", **kw)
    np.testing.assert_array_equal(vote.occupancy, sum(axes) >= 2)
    assert vote.inside == "vote"


def test_auto_uses_parity_for_closed_meshes_silently():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        vol = geovox.voxelize(SPOT, resolution=16)
    assert vol.inside == "parity"


def test_auto_warns_and_uses_winding_for_open_meshes():
    with pytest.warns(GeovoxWarning, match=r"not closed \(4 open edges\); inside by the winding number"):
        vol = geovox.voxelize(open_box(), resolution=8)
    assert vol.inside == "winding"


def test_unknown_inside_method():
    with pytest.raises(ParameterError, match="`inside` must be one of"):
        geovox.voxelize(SPOT, resolution=8, inside="magic")


def test_colour_works_with_every_inside_method(backend):
    mesh = holed_sphere()
    for method in ("vote", "winding"):
        vol = geovox.voxelize(mesh, resolution=16, inside=method, color=True, backend=backend)
        np.testing.assert_array_equal(vol.colors[..., 3] == 255, vol.occupancy)
        assert np.all(vol.colors[vol.occupancy, :3] == 204)


def test_info_command(capsys):
    from geovox.cli import main

    assert main(["info", corpus("suzanne", "suzanne.obj"), "-r", "64"]) == 0
    out = capsys.readouterr().out
    assert "967 triangles" in out and "44 open edges" in out and "non-manifold edges: 1" in out
    assert "Gold" in out and "Plastic" in out and "grid 64 x 64 x 64" in out
    assert main(["info", SPOT]) == 0
    out = capsys.readouterr().out
    assert "closed: yes" in out and "texture found" in out and "duplicate faces: 0" in out


def test_triangle_angles_componentwise_match_the_vector_formula():
    # triangle_angles is written component by component for speed; it must
    # give what the einsum/np.cross form of the same formula gives,
    # including at a triangle's own vertices and in its plane.
    rng = np.random.default_rng(5)
    tris = rng.normal(size=(300, 3, 3))
    pts = np.concatenate([rng.normal(size=(297, 3)), tris[:3, 0]])
    pts[:4] = tris[:4].mean(axis=1)  # centroids: in the plane, on the triangle
    got = captree.triangle_angles(tris, pts)
    ref = np.array([solid_angles(t[None], p[None])[0] for t, p in zip(tris, pts)])
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-12)


def test_winding_of_a_triangle_soup_matches_brute_force():
    # Loose, large triangles (each its own piece, three open edges): the caps
    # pass near most voxels, so most pairs are one voxel and one triangle,
    # summed by the shortcut past the traversal's tests.
    rng = np.random.default_rng(11)
    v = rng.random((24, 3))
    mesh = geovox.Mesh(v, np.arange(24).reshape(8, 3), source="soup")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        vol = geovox.voxelize(mesh, resolution=14, inside="winding")
        ref = brute_winding(geovox.inside.target(mesh)[0], vol.grid)
    np.testing.assert_array_equal(vol.occupancy, ref)


def test_argwhere_helper_matches_numpy():
    rng = np.random.default_rng(2)
    for shape in [(1, 1, 1), (5, 7, 3), (16, 9, 33)]:
        for m in (rng.random(shape) < 0.1, np.zeros(shape, bool), np.ones(shape, bool)):
            for a in (m, np.asfortranarray(m)):
                np.testing.assert_array_equal(captree._argwhere(a), np.argwhere(a))


def test_voxel_sums_merged_in_many_parts_give_the_same_volume(monkeypatch):
    # The voxel-level sums of the caps' winding number are kept sparse and
    # merged whenever MERGE_AT pairs are pending; merging after every few
    # must change nothing, and both must match the brute force.
    mesh = many_holes()
    kw = dict(resolution=26, inside="winding", bounds=np.r_[mesh.bounds[0] - 0.1, mesh.bounds[1] + 0.1])
    once = geovox.voxelize(mesh, **kw)
    monkeypatch.setattr(captree, "MERGE_AT", 7)
    parts = geovox.voxelize(mesh, **kw)
    np.testing.assert_array_equal(parts.occupancy, once.occupancy)
    np.testing.assert_array_equal(once.occupancy, brute_winding(mesh, once.grid))
    merged = captree._merge([(np.array([5, 2, 5]), np.array([1.0, 2.0, 3.0]), np.zeros(3),
                             np.array([0.0, 0.5, 0.25]), None),
                            (np.array([2]), np.array([0.5]), np.ones(1), np.ones(1), np.array([4]))])
    for got, ref in zip(merged, ([2, 5], [2.5, 4.0], [1.0, 0.0], [1.5, 0.25], [5, 2])):
        np.testing.assert_array_equal(got, ref)


def test_far_field_bounds_hold_the_exact_value():
    # _clamp narrows a dipole's interval with |w| <= A / (4 pi g²); the
    # narrowed interval must still hold the exact sum, also where the
    # dipole's own bound is loose (opening ratio near 1).
    rng = np.random.default_rng(7)
    for _ in range(200):
        tris = rng.normal(scale=0.3, size=(6, 3, 3)) + rng.normal(size=3)
        lo, hi = tris.reshape(-1, 3).min(axis=0), tris.reshape(-1, 3).max(axis=0)
        c, h = (lo + hi) / 2, (hi - lo) / 2
        p = c + rng.normal(size=3) * rng.uniform(0.5, 4)
        gap = np.linalg.norm(np.maximum(np.abs(c - p) - h, 0))
        if gap <= 0:
            continue
        S = 0.5 * np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
        area = np.linalg.norm(S, axis=1).sum()
        exact = captree.triangle_angles(tris, np.repeat(p[None], 6, axis=0)).sum()
        vec = c - p
        val = S.sum(axis=0) @ vec / (4 * np.pi * np.linalg.norm(vec) ** 3)
        r = np.linalg.norm(h)
        bound = area * r / (2 * np.pi * gap ** 3)
        below, above = captree._clamp(np.array([val]), np.array([bound]), np.array([area]), np.array([gap]))
        assert val - below[0] - 1e-12 <= exact <= val + above[0] + 1e-12
        assert below[0] + above[0] <= 2 * bound + 1e-12


def test_brick_pyramid_is_the_same_dense_or_sparse():
    # _pyramid builds coarse levels from indices when the mask is sparse and
    # by any over 2³ blocks when it is dense: both must give the same levels.
    rng = np.random.default_rng(0)
    for shape in [(5, 7, 3), (16, 9, 33), (40, 33, 17)]:
        for share in (0.001, 0.05, 0.5):
            m = rng.random(shape) < share
            idx = np.argwhere(m)
            for k, level in enumerate(captree._pyramid(m, 4)):
                ref = np.zeros(tuple(-(-np.array(shape) // (1 << k))), bool)
                ref[tuple((idx >> k).T)] = True
                np.testing.assert_array_equal(level, ref)


@pytest.mark.parametrize("shape", [(33, 20, 11), (17, 35, 9), (5, 3, 40)])
def test_winding_on_grids_of_odd_shapes_matches_brute_force(shape):
    # The brick levels are padded to exact multiples of each other, past the
    # grid; every step must read only the grid's part (found by the full suite
    # on a 33 x 33 x 4 grid).
    mesh = holed_sphere()
    vol = geovox.voxelize(mesh, shape=shape, inside="winding",
                          bounds=np.r_[mesh.bounds[0] - 0.07, mesh.bounds[1] + 0.05])
    np.testing.assert_array_equal(vol.occupancy, brute_winding(mesh, vol.grid))
