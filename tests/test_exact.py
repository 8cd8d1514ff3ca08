"""Rays through edges and vertices: the tie rules of geovox.exact.

Every mesh here is closed, and the grids are chosen so that column rays run
exactly through vertices, along edges and across face diagonals. A closed
mesh must give an even number of crossings on every column (no streaks),
the backends must agree voxel for voxel, and both must equal an independent
float reference evaluated at perturbed centres.
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import geovox
from geovox.backends import get_backend
from geovox.exact import Projection
from geovox.grid import make_grid

from conftest import box_mesh, from_tm, reference_occupancy


def _crossings_per_column(mesh, grid, backend, axis):
    columns = grid.columns(axis, start=mesh.bounds[0, axis] - 1.0)
    hits = get_backend(backend).cast(mesh, columns)
    return np.bincount(hits.ray, minlength=columns.count), hits


def _edge_case_meshes():
    # Box with faces, edges and vertices exactly on the lines through voxel centres.
    yield "box_on_centres", box_mesh((1.5, 2.5, 0.5), (5.5, 4.5, 6.5)), (0, 0, 0, 8, 8, 8), 8
    # A cube whose face diagonals run through column centres (y = x).
    yield "cube_diagonals", box_mesh((0.5, 0.5, 0.5), (4.5, 4.5, 4.5)), (0, 0, 0, 6, 6, 6), 6
    # Same, other diagonal direction on alternate faces and a finer grid.
    yield "cube_diagonals_fine", box_mesh((0.25, 0.25, 0.25), (2.25, 2.25, 2.25), "same"), (0, 0, 0, 3, 3, 3), 12
    # UV sphere centred on a column: both poles are vertex fans on that column.
    s = trimesh.creation.uv_sphere(radius=3.0, count=[16, 16])
    s.apply_translation([4.5, 4.5, 4.5])
    yield "uv_sphere_poles", from_tm(s, "uv_sphere"), (0, 0, 0, 9, 9, 9), 9
    # Icosphere with vertices at (0, +-1, +-phi)-type positions on centre lines.
    ico = trimesh.creation.icosphere(subdivisions=2, radius=4.0)
    ico.apply_translation([5.0, 5.0, 5.0])
    yield "icosphere", from_tm(ico, "icosphere"), (0, 0, 0, 10, 10, 10), 10
    # Torus centred on a column: the hole's rim ring passes through many columns.
    tor = trimesh.creation.torus(major_radius=3.0, minor_radius=1.0, major_sections=24, minor_sections=12)
    tor.apply_translation([4.5, 4.5, 2.5])
    yield "torus", from_tm(tor, "torus"), (0, 0, 0, 9, 9, 5), 9
    # Cone whose tip is a vertex fan exactly on a column.
    cone = trimesh.creation.cone(radius=3.0, height=5.0, sections=12)
    cone.apply_translation([4.5, 4.5, 0.5])
    yield "cone_tip", from_tm(cone, "cone"), (0, 0, 0, 9, 9, 7), 9


CASES = list(_edge_case_meshes())


@pytest.mark.parametrize("name,mesh,bounds,n", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_closed_mesh_has_even_crossings_on_every_column(name, mesh, bounds, n, axis, backend):
    grid = make_grid(mesh.bounds, bounds=bounds, resolution=n)
    counts, _ = _crossings_per_column(mesh, grid, backend, axis)
    assert counts.sum() > 0
    assert np.all(counts % 2 == 0), f"odd crossing count on {np.count_nonzero(counts % 2)} columns"


@pytest.mark.parametrize("name,mesh,bounds,n", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_edge_cases_match_float_reference(name, mesh, bounds, n, axis, backend):
    vol = geovox.voxelize(mesh, resolution=n, bounds=bounds, backend=backend, axis=axis)
    ref = reference_occupancy(mesh, vol.grid, axis=axis)
    assert vol.inside_count > 0
    diff = np.argwhere(vol.occupancy != ref)
    assert len(diff) == 0, f"{len(diff)} voxels differ, first {diff[:5].tolist()}"


def test_box_on_centres_is_half_open_on_every_axis(backend):
    # Faces at x = 1.5, 5.5; y = 2.5, 4.5; z = 0.5, 6.5, all on voxel centres.
    mesh = box_mesh((1.5, 2.5, 0.5), (5.5, 4.5, 6.5))
    expected = np.zeros((8, 8, 8), bool)
    expected[1:5, 2:4, 0:6] = True  # centres c with lo <= c < hi
    for axis in range(3):
        vol = geovox.voxelize(mesh, resolution=8, bounds=(0, 0, 0, 8, 8, 8), backend=backend, axis=axis)
        np.testing.assert_array_equal(vol.occupancy, expected)


def test_shared_edge_through_column_counts_once():
    # Two triangles of one flat square share the diagonal, which runs
    # through column centres: each such column crosses exactly one of them.
    verts = np.array([[0, 0, 1.0], [4, 0, 1.0], [4, 4, 1.0], [0, 4, 1.0]])
    tris = verts[np.array([[0, 1, 2], [0, 2, 3]])]
    grid = make_grid(None, bounds=(0, 0, 0, 4, 4, 2), shape=(4, 4, 1))
    proj = Projection(tris, grid.columns(2))
    i, j = np.meshgrid(np.arange(4), np.arange(4), indexing="ij")
    i, j = i.ravel(), j.ravel()
    both = []
    for t in (0, 1):
        hit, depth, bary, _ = proj.crossings(np.full(16, proj.local[t]), i, j)
        both.append(hit)
        np.testing.assert_array_equal(depth[hit], 1.0)  # flat face: exact depth
    np.testing.assert_array_equal(both[0].astype(int) + both[1].astype(int), 1)


def test_vertex_fan_on_column_counts_once():
    # Eight triangles around a vertex that sits exactly on a column centre.
    n = 8
    ang = np.arange(n) * 2 * np.pi / n
    rim = np.stack([1.5 + np.cos(ang), 1.5 + np.sin(ang), np.full(n, 0.3)], axis=1)
    centre = np.array([1.5, 1.5, 1.0])
    tris = np.stack([np.repeat(centre[None], n, 0), rim, np.roll(rim, -1, 0)], axis=1)
    grid = make_grid(None, bounds=(0, 0, 0, 3, 3, 2), shape=(3, 3, 1))
    proj = Projection(tris, grid.columns(2))
    hit, depth, bary, _ = proj.crossings(proj.local[np.arange(n)], np.ones(n, np.int64), np.ones(n, np.int64))
    assert hit.sum() == 1
    assert depth[hit][0] == 1.0


def test_ray_touching_a_ridge_counts_zero_or_two(backend):
    # A tent: two faces meet at a ridge along y at x = 2.5 (a column line);
    # a ray along z through the ridge touches the surface from below twice
    # or not at all, never once.
    verts = np.array([[0.5, 0.5, 0.0], [4.5, 0.5, 0.0], [4.5, 4.5, 0.0], [0.5, 4.5, 0.0],
                      [2.5, 0.5, 2.0], [2.5, 4.5, 2.0]])
    faces = np.array([[0, 2, 1], [0, 3, 2],  # floor
                      [0, 1, 4], [3, 5, 2],  # gables
                      [1, 2, 5], [1, 5, 4],  # right roof
                      [0, 4, 5], [0, 5, 3]])  # left roof
    mesh = geovox.Mesh(verts, faces, source="tent")
    grid = make_grid(mesh.bounds, bounds=(0, 0, -1, 5, 5, 3), resolution=5)
    counts, _ = _crossings_per_column(mesh, grid, backend, 2)
    assert np.all(counts % 2 == 0)
    vol = geovox.voxelize(mesh, resolution=5, bounds=(0, 0, -1, 5, 5, 3), backend=backend, axis=2)
    np.testing.assert_array_equal(vol.occupancy, reference_occupancy(mesh, vol.grid, axis=2))


def test_snapping_keeps_far_away_mesh_exact(backend):
    # A box far from the origin: float32 would lose the sub-voxel detail.
    off = np.array([1e5, -2e5, 3e5])
    mesh = box_mesh(off + (1.5, 2.5, 0.5), off + (5.5, 4.5, 6.5))
    vol = geovox.voxelize(mesh, resolution=8, bounds=np.r_[off, off + 8], backend=backend)
    assert vol.inside_count == 4 * 2 * 6


# --- The Embree backend's coplanar check: its filters drop no pair the exact
# tests would flag (the check decides which triangles the exact rasteriser
# takes over, so a lost pair is a lost crossing).

def _tilted_pairs(rng, side, count, size=0.5):
    """Pairs of triangles in (nearly) one plane, each plane's 4-D point
    ``(normal, offset / 20 sqrt 3)`` within a hair of the hyperplane
    ``side . p = 0`` that splits the two orientations, every other pair wound
    the other way; in a cube of side 20 centred on the origin (whose corners
    the caller adds, to fix the mesh's centre and size)."""
    from geovox.backends.embree import STEP

    s3, s4 = side[:3], side[3]
    hat = s3 / np.linalg.norm(s3)
    tris = []
    for k in range(count):
        offset = rng.uniform(-0.2, 0.2)
        # side . (n, offset) = 0 up to noise of 1e-5, by n's part along s3.
        along = (-offset * s4 + rng.normal() * 1e-5) / np.linalg.norm(s3)
        perp = np.cross(hat, rng.normal(size=3))
        perp /= np.linalg.norm(perp)
        n = along * hat + np.sqrt(1 - along**2) * perp
        u = np.cross(n, rng.normal(size=3))
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        centre = offset * 20 * np.sqrt(3) * n + rng.uniform(-1, 1) * u
        for j in range(2):
            p = rng.uniform(-size, size, (3, 2))
            tri = centre + p[:, :1] * u + p[:, 1:] * w + rng.uniform(-1, 1, (3, 1)) * 10 * STEP * n
            tris.append(tri[::-1] if (j and k % 2) else tri)
    return np.array(tris)


def _with_corners(t):
    """A soup mesh of triangles ``t`` plus one whose box spans the cube [-10, 10]³."""
    from geovox.mesh import Mesh

    t = np.concatenate([t, np.array([[[-10, -10, -10], [10, 10, 10], [10, -10, -10.0]]])])
    return Mesh(t.reshape(-1, 3), np.arange(len(t) * 3).reshape(-1, 3)), t


def test_plane_filter_finds_neighbours_across_the_orientation_split():
    # Each triangle is entered in the k-d search on one side of PLANE_SIDE;
    # a neighbour whose point lies on the other side (the same plane wound the
    # other way, or a normal tilted across the split) is reached through its
    # mirror. Without the mirrors, some of these pairs are lost.
    from geovox.backends import embree as E

    rng = np.random.default_rng(3)
    mesh, t = _with_corners(_tilted_pairs(rng, E.PLANE_SIDE, 300))
    assert np.allclose(mesh.bounds, [[-10] * 3, [10] * 3]) and np.isclose(mesh.scale, 20 * np.sqrt(3))
    plane = 2 * E.STEP * mesh.scale
    n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
    length = np.linalg.norm(n, axis=1)
    unit = n / length[:, None]
    pairs = np.arange(len(t) - 1).reshape(-1, 2)

    def near(x, y):
        return all(abs(np.dot(t[x, v] - t[y, 0], unit[y])) <= plane for v in range(3))

    pairs = np.array([(a, b) for a, b in pairs if near(a, b) and near(b, a)])
    assert len(pairs) > 150  # most constructed pairs pass the exact test
    found = E._plane_neighbours(t, unit, length, mesh, plane)
    assert found[pairs].all()
    # Many pairs have their points on opposite sides of the split (so their
    # entered points are about 2 apart): only the mirrors bring them together.
    p = np.column_stack([unit, np.einsum("ij,ij->i", unit, t[:, 0]) / mesh.scale])
    q = p * np.where(p @ E.PLANE_SIDE < 0, -1.0, 1.0)[:, None]
    assert (np.linalg.norm(q[pairs[:, 0]] - q[pairs[:, 1]], axis=1) > 1).sum() > 50


def _flags_without_filters(mesh, monkeypatch):
    """coplanar_overlaps with every pair of triangles settled by the exact
    tests: no plane filter, no box hash, no clean vertex."""
    from geovox.backends import embree as E

    with monkeypatch.context() as m:
        m.setattr(E, "_plane_neighbours", lambda t, *a: np.ones(len(t), bool))
        m.setattr(E, "_clean_vertices", lambda t, unit, g: np.zeros(int(g.max()) + 1, bool))
        m.setattr(E, "box_pair_chunks",
                  lambda lo, hi, *a, **k: iter([np.argwhere(np.triu(np.ones((len(lo),) * 2, bool), 1))]))
        mesh._cache.pop("coplanar", None)
        flags = E.coplanar_overlaps(mesh)
        mesh._cache.pop("coplanar", None)
    return flags


def test_coplanar_filters_lose_no_pair(monkeypatch):
    # Small meshes of flat patches, folds, duplicates, T-junctions and
    # reversed copies, some with planes at the orientation split: the filters
    # (plane search, box hash kept once per pair, clean vertices) must give
    # exactly the flags of settling every pair.
    from geovox.backends import embree as E
    from geovox.mesh import Mesh

    rng = np.random.default_rng(7)
    cases = []
    for k in range(60):
        if k % 3 == 0:
            mesh = _with_corners(_tilted_pairs(rng, E.PLANE_SIDE, 20, size=3.0))[0]
        else:
            # A flat triangulated grid patch, some faces duplicated, reversed
            # or folded over, a second patch laid on part of it.
            nx = int(rng.integers(2, 5))
            xy = np.stack(np.meshgrid(np.arange(nx + 1), np.arange(nx + 1), indexing="ij"), -1).reshape(-1, 2)
            v = np.c_[xy + rng.normal(size=xy.shape) * 0.1, np.zeros(len(xy))]
            q = np.arange(nx * (nx + 1)).reshape(nx, nx + 1)[:, :nx].reshape(-1)
            f = np.r_[np.c_[q, q + nx + 1, q + 1], np.c_[q + 1, q + nx + 1, q + nx + 2]]
            extra = f[rng.choice(len(f), int(rng.integers(0, 4)))]
            f = np.r_[f, extra[:, ::-1] if k % 2 else extra]
            shifted = v[:, :2] * rng.uniform(0.3, 1.0) + rng.uniform(0, nx / 2, 2)
            v = np.r_[v, np.c_[shifted, np.zeros(len(v))]]
            f = np.r_[f, f[: int(rng.integers(0, len(f)))] + len(xy)]
            # Tilt and place the whole thing anywhere.
            rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
            mesh = Mesh(v @ rot.T + rng.normal(size=3), f)
        cases.append(mesh)
    flagged = 0
    for mesh in cases:
        got = E.coplanar_overlaps(mesh)
        want = _flags_without_filters(mesh, monkeypatch)
        np.testing.assert_array_equal(got, want)
        flagged += want.any()
    assert flagged > 20


def test_plane_filter_passes_flat_patch_meshes_whole(monkeypatch):
    # A subdivided box (every face has coplanar siblings) passes whole, by a
    # sample, without a search per face; the flags are those of the full
    # search. A smooth sphere is filtered face by face.
    from geovox.backends import embree as E

    box = trimesh.creation.box((1, 1, 1))
    for _ in range(5):
        box = box.subdivide()
    faces = np.concatenate([box.faces, box.faces[:40], box.faces[100:120, ::-1]])
    mesh = geovox.Mesh(np.asarray(box.vertices), faces)
    sphere = from_tm(trimesh.creation.icosphere(subdivisions=4), "sphere")
    assert len(mesh.faces) > 4096 and len(sphere.faces) > 4096
    for m, whole in ((mesh, True), (sphere, False)):
        t = m.triangles
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        length = np.linalg.norm(n, axis=1)
        found = E._plane_neighbours(t, n / length[:, None], length, m, 2 * E.STEP * m.scale)
        assert found.all() if whole else found.mean() < 0.01
    monkeypatch.setattr(E, "MAX_RUN", 10**9)  # no cell flagged wholesale: exact flags
    got = E.coplanar_overlaps(mesh)
    mesh._cache.pop("coplanar")
    monkeypatch.setattr(E, "PASS_ALL", 2.0)  # never pass whole
    np.testing.assert_array_equal(E.coplanar_overlaps(mesh), got)
    assert got.sum() == 120  # the duplicated faces and their originals
