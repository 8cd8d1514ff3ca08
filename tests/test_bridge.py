"""The winding number's small caps (geovox.inside.bridge), and the winding path on adversarial open meshes.

The caps change what the winding path sums, never what it decides: every
voxel must be the brute-force winding number's of the repaired mesh (every
triangle summed exactly at the voxel centre), with either kernel, and with
fans or small caps alike.
"""

from __future__ import annotations

import itertools
import warnings
from pathlib import Path

import numpy as np
import pytest
import trimesh

import geovox
from geovox.inside import bridge
from geovox import inside
from geovox.inside import caps, winding
from geovox.errors import GeovoxWarning
from geovox.kernels import chosen

from test_cap_winding import MESH, brute_winding_number

DATA = Path(__file__).parent / "data"
with chosen("auto"):
    _BUILT = inside.winding_kernel() is not None
KERNELS = ["numpy", pytest.param("compiled", marks=pytest.mark.skipif(
    not _BUILT, reason="the compiled winding kernel is not built"))]


def all_triangulations(i, j):
    """Every triangulation of the polygon's vertices i..j, as lists of (i, k, j)."""
    if j - i < 2:
        return [[]]
    return [left + right + [(i, k, j)] for k in range(i + 1, j)
            for left in all_triangulations(i, k) for right in all_triangulations(k, j)]


def area(poly, t):
    a, b, c = poly[list(t)]
    return 0.5 * np.linalg.norm(np.cross(b - a, c - a))


@pytest.mark.parametrize("n", [3, 4, 5, 6, 7])
def test_min_area_triangulation_is_the_least_of_all(n):
    # Random non-planar polygons: the programme's choice is the least total
    # area among every triangulation (Catalan(n - 2) of them).
    rng = np.random.default_rng(n)
    poly = rng.normal(size=(4, n, 3))
    got = bridge.min_area_triangles(poly)
    assert got.shape == (4, n - 2, 3)
    for p, t in zip(poly, got):
        assert np.all((t[:, 0] < t[:, 1]) & (t[:, 1] < t[:, 2]))
        best = min(sum(area(p, x) for x in tri) for tri in all_triangulations(0, n - 1))
        assert sum(area(p, x) for x in t) == pytest.approx(best, rel=1e-12)
        # A triangulation: every polygon side once, every diagonal twice.
        sides = [tuple(sorted(e)) for x in t for e in itertools.combinations(x, 2)]
        for e in set(sides):
            want = 1 if e[1] - e[0] in (1, n - 1) else 2
            assert sides.count(e) == want


def test_a_slit_is_zipped_shut():
    # Two nearly coincident polylines joined at their ends (the truck's
    # loops along open seams): the fan from the centroid spans the whole
    # width, the triangulation only the slit.
    x = np.linspace(0, 1, 12)
    top = np.stack([x, 0.01 * np.ones_like(x), np.sin(3 * x)], axis=1)
    poly = np.concatenate([top, top[::-1] * [1, -1, 1]])
    t = bridge.min_area_triangles(poly[None])[0]
    zipped = sum(area(poly, x) for x in t)
    c = poly.mean(axis=0)
    fan = sum(0.5 * np.linalg.norm(np.cross(poly[i] - c, poly[(i + 1) % len(poly)] - c))
              for i in range(len(poly)))
    strip = 0.02 * np.linalg.norm(np.diff(top, axis=0), axis=1).sum()  # width times length
    assert zipped < 1.05 * strip
    assert fan > 5 * zipped


@pytest.mark.skipif(not _BUILT, reason="the compiled winding kernel is not built")
@pytest.mark.parametrize("n", [3, 4, 5, 8, 13, 31, 64, 200])
def test_the_compiled_triangulation_is_the_numpy_one(n):
    # The same triangles in the same order (the caps' order is the tree's
    # and the exact sum's): random polygons, polygons of many equal areas
    # (ties go to the lowest middle vertex), a regular planar one, all
    # vertices at one point, and a NaN and an infinity (NumPy's min and
    # argmin: a NaN wins).
    import geovox._winding as kernel

    rng = np.random.default_rng(n)
    ring = np.stack([np.cos(2 * np.pi * np.arange(n) / n), np.sin(2 * np.pi * np.arange(n) / n),
                     np.zeros(n)], axis=1)
    bad = rng.normal(size=(2, n, 3))
    bad[0, n // 2, 1], bad[1, n - 1, 0] = np.nan, np.inf
    with np.errstate(invalid="ignore"):
        for poly in (rng.normal(size=(6, n, 3)), np.round(rng.normal(size=(6, n, 3))) / 2,
                     np.stack([ring, 3 * ring + 1]), np.zeros((1, n, 3)), bad):
            want = bridge.min_area_triangles(poly)
            assert np.array_equal(kernel.min_area_triangles(np.ascontiguousarray(poly)), want)


def test_loop_order_runs_each_loop_edge_after_edge():
    vid = np.array([[0, 1], [1, 2], [2, 3], [3, 0],      # loop A
                    [0, 4], [4, 5], [5, 6], [6, 0],      # loop B, through corner 0
                    [7, 8], [8, 9]])                     # an open path: no loop
    piece = caps.loops(vid, np.array([0] * 8 + [1] * 2))
    rank = bridge.loop_order(vid, piece)
    path = piece[8]
    assert np.all(rank[piece == path] == -1)
    for p in set(piece.tolist()) - {path}:
        e = np.flatnonzero(piece == p)
        e = e[np.argsort(rank[e])]
        assert sorted(rank[e]) == list(range(len(e)))
        assert np.array_equal(vid[e, 1], np.roll(vid[e, 0], -1))


def shuffled_loops(seed=3):
    """Many loops of several lengths, edges shuffled, for loop_order."""
    rng = np.random.default_rng(seed)
    vid, piece, start = [], [], 0
    for p, n in enumerate(rng.integers(3, 30, 40)):
        v = start + np.arange(n)
        vid.append(np.stack([v, np.roll(v, -1)], axis=1))
        piece.append(np.full(n, p))
        start += n
    vid, piece = np.concatenate(vid), np.concatenate(piece)
    order = rng.permutation(len(vid))
    return vid[order], piece[order]


def test_loop_order_on_shuffled_loops():
    vid, piece = shuffled_loops()
    rank = bridge.loop_order(vid, piece)
    for p in np.unique(piece):
        e = np.flatnonzero(piece == p)
        e = e[np.argsort(rank[e])]
        assert np.array_equal(np.sort(rank[e]), np.arange(len(e)))
        assert np.array_equal(vid[e, 1], np.roll(vid[e, 0], -1))


def test_small_caps_close_the_model_with_less_area():
    tm = inside.target(MESH)[0]
    fans = inside.capped(tm)[1]
    closed, small, _ = inside.bridged(tm)
    assert len(inside.boundary_edges(closed)) == 0

    def total(t):
        return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1).sum()

    assert total(small) < total(fans)


def test_the_truck_is_closed_by_its_small_caps():
    m = geovox.load_mesh(DATA / "wild" / "truck.obj")
    tm = inside.target(m)[0]
    closed, small, _ = inside.bridged(tm)
    assert len(inside.boundary_edges(closed)) == 0
    area_small = 0.5 * np.linalg.norm(np.cross(small[:, 1] - small[:, 0],
                                               small[:, 2] - small[:, 0]), axis=1).sum()
    fans = inside.capped(tm)[1]
    area_fans = 0.5 * np.linalg.norm(np.cross(fans[:, 1] - fans[:, 0],
                                              fans[:, 2] - fans[:, 0]), axis=1).sum()
    assert area_small < 0.5 * area_fans


def _open(m, keep):
    return np.asarray(m.vertices), np.asarray(m.faces)[keep]


def nested_open_shells():
    """Three concentric spheres, each with a cap cut off, the openings facing different ways."""
    V, F, off = [], [], 0
    for r, d in ((1.0, [0, 0, 1]), (0.6, [1, 0, 0]), (0.3, [0, -1, -1])):
        s = trimesh.creation.icosphere(subdivisions=2, radius=r)
        d = np.asarray(d, float) / np.linalg.norm(d)
        v, f = _open(s, s.triangles_center @ d < 0.55 * r)
        V.append(v)
        F.append(f + off)
        off += len(v)
    return geovox.Mesh(np.concatenate(V), np.concatenate(F), source="nested")


def window_frame_cube():
    """A cube whose six faces each have a square window: its inside is bounded by caps over half its area."""
    g = np.linspace(-1, 1, 4)
    V, F = [], []
    for axis in range(3):
        for side in (-1.0, 1.0):
            for i in range(3):
                for j in range(3):
                    if i == 1 and j == 1:
                        continue  # the window
                    q = np.array([[g[i], g[j]], [g[i + 1], g[j]], [g[i + 1], g[j + 1]], [g[i], g[j + 1]]])
                    p = np.insert(q, axis, side, axis=1)
                    base = len(V) * 4
                    V.append(p)
                    a, b, c, d = base, base + 1, base + 2, base + 3
                    F += [[a, b, c], [a, c, d]]
    V = np.concatenate(V)
    tm = trimesh.Trimesh(V, np.array(F), process=True)
    tm.fix_normals()
    return geovox.Mesh(np.asarray(tm.vertices), np.asarray(tm.faces), source="frame")


def wavy_tube():
    """An open cylinder cut by wavy rims: non-planar loops whose fans and triangulations differ."""
    n, h = 24, 12
    t = np.linspace(0, 2 * np.pi, n, endpoint=False)
    z = np.linspace(0, 3, h)[:, None] + 0.25 * np.sin(3 * t)[None] * np.array([[1.0]] * h)
    V = np.stack([np.broadcast_to(np.cos(t), z.shape), np.broadcast_to(np.sin(t), z.shape), z],
                 axis=-1).reshape(-1, 3)
    F = []
    for r in range(h - 1):
        for c in range(n):
            a, b = r * n + c, r * n + (c + 1) % n
            F += [[a, b, b + n], [a, b + n, a + n]]
    return geovox.Mesh(V, np.array(F), source="wavy")


FIXTURES = {"nested open shells": (nested_open_shells, None),
            "enclosed by caps": (window_frame_cube, (-1.6, -1.6, -1.6, 1.6, 1.6, 1.6)),
            # (Bounds off the model's symmetry: on its own box, a voxel centre
            # lies exactly on a fan's spoke; see test_a_voxel_centre_on_a_cap.)
            "wavy rims": (wavy_tube, (-1.03, -1.01, -0.27, 1.02, 1.04, 3.26)),
            # The grid cuts through the mesh: the open boundary and part of
            # the surface lie outside it, part inside.
            "boundary crossing the grid": (nested_open_shells, (-0.4, -0.9, -0.7, 0.95, 0.5, 0.6))}


@pytest.fixture(scope="module", params=list(FIXTURES))
def case(request):
    make, bounds = FIXTURES[request.param]
    mesh = make()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)  # parity may find nothing: only its grid is used
        grid = geovox.voxelize(mesh, resolution=18, bounds=bounds, inside="parity").grid
    return mesh, bounds, grid, brute_winding_number(inside.target(mesh)[0], grid)


@pytest.mark.parametrize("kernel", KERNELS)
def test_adversarial_open_meshes_are_the_brute_force(case, monkeypatch, kernel):
    mesh, bounds, grid, w = case
    assert len(inside.boundary_edges(inside.target(mesh)[0])) > 0
    monkeypatch.setenv("GEOVOX_KERNEL", kernel)
    with warnings.catch_warnings():
        warnings.simplefilter("error", GeovoxWarning)  # nothing approximate
        warnings.filterwarnings("ignore", ".*(not closed|not consistently)", GeovoxWarning)
        vol = geovox.voxelize(mesh, resolution=18, bounds=bounds, inside="winding")
    assert vol.grid.shape == grid.shape
    assert np.abs(w - 0.5).min() > 1e-6  # no tie for the brute force's float64 sum
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)
    assert 0 < np.count_nonzero(vol.occupancy) < vol.occupancy.size


@pytest.mark.parametrize("kernel", KERNELS)
def test_fans_and_small_caps_decide_the_same(case, monkeypatch, kernel):
    mesh, bounds, grid, w = case
    monkeypatch.setenv("GEOVOX_KERNEL", kernel)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        small = geovox.voxelize(mesh, resolution=18, bounds=bounds, inside="winding").occupancy
        monkeypatch.setattr(winding, "bridged", inside.capped)
        fans = geovox.voxelize(mesh, resolution=18, bounds=bounds, inside="winding").occupancy
    np.testing.assert_array_equal(small, fans)


def test_the_truck_at_16_is_the_brute_force(monkeypatch):
    # The cap-heavy model of issue 27 itself (50 parts, 1,388 open edges),
    # every voxel against every triangle of its repaired copy.
    m = geovox.load_mesh(DATA / "wild" / "truck.obj")
    grid = geovox.voxelize(m, resolution=16, inside="parity").grid
    w = brute_winding_number(inside.target(m)[0], grid)
    assert np.abs(w - 0.5).min() > 1e-6
    for kernel in ("numpy", "auto"):
        monkeypatch.setenv("GEOVOX_KERNEL", kernel)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", GeovoxWarning)
            vol = geovox.voxelize(geovox.load_mesh(DATA / "wild" / "truck.obj"), resolution=16)
        np.testing.assert_array_equal(vol.occupancy, w > 0.5)


def rim_box(heights, floor=1.9375):
    """An open box hanging down from a rim whose four corners are at ``heights`` (z), its floor below.

    The unit square's corners (0, 0), (1, 0), (1, 1), (0, 1): a rim that is
    not planar, so its caps fold and a voxel centre on them is no tie of
    the winding number (a flat cap's points all have w = 1/2 exactly).
    """
    corners = [(0, 0), (1, 0), (1, 1), (0, 1)]
    V = [(x, y, floor) for x, y in corners] + [(x, y, h) for (x, y), h in zip(corners, heights)]
    F = [[0, 1, 2], [0, 2, 3]]
    for i in range(4):
        j = (i + 1) % 4
        F += [[i, 4 + j, j], [i, 4 + i, 4 + j]]
    return geovox.Mesh(np.array(V, float), np.array(F), source="rim")


#: Voxel centres exactly on a cap (dyadic coordinates: exact in float64, on
#: no face of the model itself): (mesh, shape, bounds, fans instead of small caps).
ON_A_CAP = {
    # The wavy tube on its own box: the centre of voxel (7, 7, 16) lies
    # exactly on a spoke of the top rim's fan (z = 3 - 1/24 both); the
    # crossings counted the cap on one side, its solid angle (atan2(0, 0)
    # there) took neither, and 3 voxels went against the brute force
    # (0.4934 there), with either kernel.
    "a fan's spoke": (wavy_tube, (18, 18, 18), None, True),
    # The minimum-area caps' diagonal of a saddle-shaped rim (z = 1 at two
    # corners, 0.75 at the others) through the centres (t, t, 1).
    "a diagonal of small caps": (lambda: rim_box((1.0, 0.75, 1.0, 0.75)), (6, 6, 12),
                                 (-0.25, -0.25, 0.5625, 1.25, 1.25, 2.0625), False),
    # A fan's own vertex, the centroid (0.5, 0.5, 0.75) of an uneven rim, is
    # a voxel centre; (0.875, 0.125, 0.75) lies on a spoke.
    "a fan's vertex": (lambda: rim_box((0.875, 0.75, 1.0, 0.375)), (4, 4, 6),
                       (-0.4375, -0.4375, -0.1875, 1.0625, 1.0625, 2.0625), True),
}


@pytest.mark.parametrize("kernel", KERNELS)
@pytest.mark.parametrize("name", list(ON_A_CAP))
def test_a_voxel_centre_on_a_cap(monkeypatch, name, kernel):
    # Each term of w_M = w_{M+K} - w_K must see the centre on the same side
    # of the cap: the rays' side (winding.settle_ties). Before, these cases
    # decided 3, 2 and 2 voxels against the brute force.
    make, shape, bounds, fans = ON_A_CAP[name]
    mesh = make()
    monkeypatch.setenv("GEOVOX_KERNEL", kernel)
    if fans:
        monkeypatch.setattr(winding, "bridged", inside.capped)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        vol = geovox.voxelize(mesh, shape=shape, bounds=bounds, inside="winding")
    grid = vol.grid
    tris = winding.bridged(inside.target(mesh)[0])[1]  # as patched
    # Some centre lies exactly on a cap triangle: in its plane, within it.
    c = np.stack(np.meshgrid(*[grid.centres(a) for a in range(3)], indexing="ij"), -1)
    a, b, t = tris[:, 0], tris[:, 1], tris[:, 2]
    n = np.cross(b - a, t - a)
    on = np.zeros(grid.shape, bool)
    for k in range(len(tris)):
        d = c - a[k]
        plane = np.einsum("...i,i->...", d, n[k]) == 0
        w0 = np.einsum("...i,i->...", np.cross(b[k] - a[k], d), n[k])
        w1 = np.einsum("...i,i->...", np.cross(t[k] - b[k], c - b[k]), n[k])
        w2 = np.einsum("...i,i->...", np.cross(a[k] - t[k], c - t[k]), n[k])
        on |= plane & (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
    assert on.any()
    w = brute_winding_number(inside.target(mesh)[0], grid)
    assert np.abs(w - 0.5).min() > 1e-6  # no tie for the brute force
    np.testing.assert_array_equal(vol.occupancy, w > 0.5)
    assert vol.approximate == 0
