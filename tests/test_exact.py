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
from geovox.block import ray_start

from conftest import box_mesh, from_tm, reference_occupancy


def _crossings_per_column(mesh, grid, backend, axis):
    columns = grid.columns(axis, start=ray_start(mesh, grid, axis))
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


# --- The Embree backend's coplanar check: its pairing loses no pair the exact
# pair test would flag (the check decides which triangles the exact rasteriser
# takes over, so a lost pair is a lost crossing), for every lattice at once and
# for the rays of one lattice.

def _tilted_pairs(rng, count, size=0.5):
    """Pairs of triangles in (nearly) one plane: every vertex within a few
    restart steps of the other's plane, some wound the other way; in a cube of
    side 20 centred on the origin (whose corners the caller adds, to fix the
    mesh's centre and size)."""
    from geovox.backends.embree import STEP

    tris = []
    for k in range(count):
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        u = np.cross(n, rng.normal(size=3))
        u /= np.linalg.norm(u)
        w = np.cross(n, u)
        centre = rng.uniform(-5, 5, 3)
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


def _coplanar_cases(seed=7, count=45):
    """Small meshes of flat patches, folds, duplicates, T-junctions and
    reversed copies, tilted and placed anywhere; and soups of nearly coplanar
    pairs."""
    from geovox.mesh import Mesh

    rng = np.random.default_rng(seed)
    cases = []
    for k in range(count):
        if k % 3 == 0:
            cases.append(_with_corners(_tilted_pairs(rng, 15, size=3.0))[0])
            continue
        # A flat triangulated grid patch, some faces duplicated, reversed or
        # folded over, a second patch laid on part of it.
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
        if k % 4 == 1:
            # Lying in a grid plane, so that rays run through its edges and
            # vertices (the lattices below have centres at half-integers).
            cases.append(Mesh(np.round(v * 2) / 2 + 0.5, f))
            continue
        rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        cases.append(Mesh(v @ rot.T + rng.normal(size=3), f))
    return cases


def _all_pairs(lo, hi, *args, **kwargs):
    """A stand-in for the box hash: every pair, once."""
    return iter([np.argwhere(np.triu(np.ones((len(lo),) * 2, bool), 1))])


def test_box_hash_loses_no_coplanar_pair(monkeypatch):
    # For every lattice at once: the box hash keeps every pair the pair test
    # flags (the same flags as settling every pair).
    from geovox.backends import embree as E

    flagged = 0
    for mesh in _coplanar_cases():
        got = E.coplanar_overlaps(mesh)
        with monkeypatch.context() as m:
            m.setattr(E, "box_pair_chunks", _all_pairs)
            want = E.coplanar_overlaps(mesh)
        np.testing.assert_array_equal(got, want)
        flagged += want.any()
    assert flagged > 15


def _lattices(mesh, rng, count):
    """Random lattices over the mesh: any axis, 1-24 columns a side, some
    with centres on the grid planes' half-integers."""
    for k in range(count):
        axis = int(rng.integers(0, 3))
        if k % 2:
            lo = np.floor(mesh.bounds[0]) - 1
            shape = np.ceil(mesh.bounds[1] - lo).astype(int) + 1
            grid = make_grid(mesh.bounds, bounds=np.r_[lo, lo + shape], shape=tuple(shape))
        else:
            grid = make_grid(mesh.bounds, resolution=int(rng.integers(1, 25)))
        yield grid.columns(axis, start=ray_start(mesh, grid, axis))


def _seen_hiding(mesh, columns):
    """(m,) bool, by brute force: triangles of pairs that the pair test flags
    and that some column centre lies in both (closed, with a hair to spare)
    at depths within a restart step."""
    from geovox.backends import embree as E

    t = mesh.triangles
    n = E._normals(mesh)
    length = np.linalg.norm(n, axis=1)
    unit = n / np.where(length > 0, length, 1)[:, None]
    ok = np.flatnonzero(length > 0)
    a, b = np.triu_indices(len(ok), 1)
    a, b = ok[a], ok[b]
    hide = E._hiding(mesh, a, b, unit, 2 * E.STEP * mesh.scale, 1e-9 * mesh.scale)
    flags = np.zeros(len(t), bool)
    cu, cv = np.meshgrid(columns.centres_u(), columns.centres_v(), indexing="ij")
    p = np.c_[cu.ravel(), cv.ravel()]
    ua, va, ax = columns.u_axis, columns.v_axis, columns.axis

    def inside(x):  # (columns,) bool: centres in triangle x's projection, and its depth there
        q = t[x][:, [ua, va]]

        def cross(e, r):
            return e[0] * r[..., 1] - e[1] * r[..., 0]

        d = [cross(q[(i + 1) % 3] - q[i], p - q[i]) for i in range(3)]
        s = cross(q[1] - q[0], q[2] - q[0])
        hair = 1e-9 * mesh.scale * np.linalg.norm(q[1] - q[0])
        ins = np.all([di * np.sign(s) >= -hair for di in d], axis=0) if s != 0 else np.zeros(len(p), bool)
        with np.errstate(divide="ignore", invalid="ignore"):
            across = n[x, ua] * (p[:, 0] - t[x, 0, ua]) + n[x, va] * (p[:, 1] - t[x, 0, va])
            depth = t[x, 0, ax] - across / n[x, ax]
        return ins, depth

    for x, y in zip(a[hide], b[hide]):
        ix, dx = inside(x)
        iy, dy = inside(y)
        with np.errstate(invalid="ignore"):  # triangles along the rays: no depth, never inside
            close = np.abs(dx - dy) <= E.STEP * mesh.scale
        if np.any(ix & iy & close):
            flags[x] = flags[y] = True
    return flags


@pytest.mark.parametrize("pairing", ["by rays", "by boxes", "every pair"])
def test_lattice_flags_hold_every_pair_its_rays_see(pairing, monkeypatch):
    # For one lattice, only pairs that its rays can see are settled: the flags
    # must hold every flagged pair that a ray meets at one depth, and never
    # more than the flags for every lattice. Each pairing: ray by ray
    # (coarse lattices), column boxes (fine ones), every pair (tiny meshes).
    from geovox.backends import embree as E

    monkeypatch.setattr(E, "FEW", 10**9 if pairing == "every pair" else 0)
    if pairing == "by boxes":
        monkeypatch.setattr(E, "COLUMN_ENTRIES", -10**9)
    rng = np.random.default_rng(11)
    seen = 0
    for mesh in _coplanar_cases(seed=5, count=24):
        every = E.coplanar_overlaps(mesh)
        for columns in _lattices(mesh, rng, 4):
            got = E.coplanar_overlaps(mesh, columns)
            want = _seen_hiding(mesh, columns)
            assert not (want & ~got).any()
            assert not (got & ~every).any()
            seen += want.any()
    assert seen > 20


def test_t_junctions_flagged_for_a_lattice_through_them(monkeypatch):
    from geovox.backends import embree as E
    from geovox.backends.embree import coplanar_overlaps

    from test_backends import t_junction_box

    monkeypatch.setattr(E, "FEW", 0)  # the lattice's own pairing, not every pair

    mesh = t_junction_box()
    grid = make_grid(mesh.bounds, bounds=(0, 0, -0.5, 1, 1, 1.5), shape=(3, 3, 4))
    flags = coplanar_overlaps(mesh, grid.columns(2, start=-1.0))
    assert set(np.flatnonzero(flags)) == {0, 2, 4, 6}


@pytest.mark.parametrize("res,axis", [(7, 2), (40, 0), (130, 1)])
def test_column_entries_hold_every_crossing(res, axis):
    # The entries a coarse lattice is paired from, and the triangles a subset
    # scene holds, include every (ray, triangle) crossing the exact
    # rasteriser finds; and the reach holds every column range it scans.
    from geovox.backends import embree as E
    from geovox.backends.numpy import rasterise

    from conftest import SPOT

    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=res)
    columns = grid.columns(axis, start=ray_start(mesh, grid, axis))
    proj = Projection(mesh.triangles, columns)
    i0, i1, j0, j1 = E.reach(mesh, columns)
    assert np.all((i0[proj.tri] <= proj.imin) & (proj.imax <= i1[proj.tri]))
    assert np.all((j0[proj.tri] <= proj.jmin) & (proj.jmax <= j1[proj.tri]))
    hits = rasterise(proj)
    ok = np.flatnonzero((i0 <= i1) & (j0 <= j1))
    tri, col = E._column_entries(mesh, columns, (i0, i1, j0, j1), ok)
    entries = set(zip(ok[tri].tolist(), col.tolist()))
    assert len(hits) > 50
    assert set(zip(hits.triangle.tolist(), hits.ray.tolist())) <= entries
    assert len(entries) < 3 * ((i1 - i0 + 1) * (j1 - j0 + 1))[ok].sum()  # most box columns go
    near = E._check(mesh, columns)[1]
    assert near[hits.triangle].all()


def test_column_pairs_match_brute_force():
    from geovox.backends import embree as E

    rng = np.random.default_rng(2)
    n = 300
    lo = rng.uniform(0, 10, n)
    hi = lo + rng.exponential(0.3, n)
    hi[:5] = lo[:5]  # some points
    tri = rng.integers(0, n, 2000)
    col = rng.integers(0, 40, 2000)
    key = np.unique(tri * 40 + col)  # a triangle is entered once per column
    tri, col = key // 40, key % 40
    got = set()
    for chunk in (7, 1 << 19):
        pairs = np.concatenate(list(E._column_pair_chunks(tri, col, lo, hi, [], chunk=chunk)))
        assert np.all(pairs[:, 0] < pairs[:, 1])
        got.add(frozenset(map(tuple, pairs.tolist())))
    assert len(got) == 1
    cols = {}
    for t_, c in zip(tri.tolist(), col.tolist()):
        cols.setdefault(c, []).append(t_)
    want = {(min(a, b), max(a, b)) for members in cols.values() for a in members for b in members
            if a != b and lo[a] <= hi[b] and lo[b] <= hi[a]}
    assert set(got.pop()) == want


def test_crowded_columns_are_flagged_not_paired(monkeypatch):
    from geovox.backends import embree as E

    monkeypatch.setattr(E, "MAX_RUN", 5)
    crowded = []
    tri = np.arange(8)
    pairs = list(E._column_pair_chunks(tri, np.zeros(8, np.int64), np.zeros(8), np.ones(8), crowded))
    # The first entries have 7, 6 partners: not paired; the last ones are.
    assert {tuple(p) for c in pairs for p in c} <= {(a, b) for a in range(2, 8) for b in range(a + 1, 8)}
    np.testing.assert_array_equal(np.concatenate(crowded), np.arange(8))


@pytest.mark.skipif("embree" not in geovox.available_backends(), reason="needs embreex")
def test_coarse_lattice_scene_holds_only_the_triangles_near_its_rays():
    # A coarse lattice gets a scene of the triangles some ray passes near
    # (fewer to copy into Embree and to build), a fine one the whole mesh's,
    # shared; both give the NumPy backend's volume.
    from conftest import SPOT

    embree = get_backend("embree")
    mesh = geovox.load_mesh(SPOT)
    for res, whole in ((9, False), (200, True)):
        grid = make_grid(mesh.bounds, resolution=res)
        _, faces, _ = embree.setup(mesh, grid.columns(2, start=ray_start(mesh, grid, 2)))
        assert (faces is None) == whole
        if not whole:
            assert 0 < len(faces) < len(mesh.faces) / 2
        a = geovox.voxelize(mesh, resolution=res, backend="numpy")
        b = geovox.voxelize(mesh, resolution=res, backend="embree")
        np.testing.assert_array_equal(a.occupancy, b.occupancy)
