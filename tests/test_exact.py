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
