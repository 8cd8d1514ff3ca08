"""Surface voxels (issue 35): the exact rule, held to a rational reference, and its invariances.

The rule (geovox/surface.py): voxel ``(i, j, k)`` is on when the surface meets
its box ``[x_i, x_i+1) x [y_j, y_j+1) x [z_k, z_k+1)``, each interval closed
at the grid's far face. The judge is tests/surface_reference.py: each
triangle clipped against each voxel's closed box in rational arithmetic,
then the half-open rule; it shares nothing with the kernels' method.

On a dyadic grid (corner and spacing dyadic) every voxel face is exactly
representable and vertices on a fine dyadic lattice snap exactly, so the
kernels must give the reference's voxels for the real triangles, 0 voxels
apart. Every such test runs on both kernels (the compiled one where it is
built, and the NumPy twin) through the ``kernel`` fixture; further tests hold
them to each other, to every block split and to every thread count.
"""

from __future__ import annotations

from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import geovox
from conftest import SPOT, corpus
from geovox.errors import MeshError, ParameterError
from geovox.grid import Grid, make_grid
from geovox.kernels import chosen, compiled
import geovox.surface as surface_module
from geovox.surface import MAX_SUB_BITS, snap_bits, surface_points, surface_voxels, word_count
from surface_reference import reference_index_voxels, reference_voxels

COMPILED = compiled("_surface", "surface-voxel", "auto") is not None
KERNELS = ["numpy"] + (["compiled"] if COMPILED else [])
needs_compiled = pytest.mark.skipif(not COMPILED, reason="the compiled surface kernel is not built")


@pytest.fixture(params=KERNELS)
def kernel(request):
    return request.param


@pytest.fixture
def threads_always(monkeypatch):
    """The compiled kernel runs the threads asked for, however small the work (its own
    rule keeps small meshes on one thread), so that tests of thread counts run threads."""
    monkeypatch.setattr(surface_module, "_THREADS_TRIANGLES", 0)
    monkeypatch.setattr(surface_module, "_THREADS_SIDE", 0)


def voxels(tris, grid, kernel, **kw):
    with chosen(kernel):
        return surface_voxels(np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3), grid, **kw)


#: A dyadic grid with unequal voxels: every face ``lo + i * h`` is exact.
LO = np.array([-1.0, 0.5, -2.0])
H = np.array([0.5, 0.25, 1.0])


def dyadic_grid(shape=(6, 5, 7)):
    return Grid(lo=LO, hi=LO + H * np.array(shape), shape=tuple(shape))


def world(f):
    """Index-space coordinates (voxel units, dyadic) to the dyadic grid's frame, exactly."""
    return LO + np.asarray(f, dtype=np.float64) * H


def check(f, kernel, shape=(6, 5, 7)):
    """The kernel's voxels for index-space triangles ``f`` on the dyadic grid, held to the reference."""
    grid = dyadic_grid(shape)
    tris = world(np.asarray(f, dtype=np.float64).reshape(-1, 3, 3))
    got = voxels(tris, grid, kernel)
    ref = reference_voxels(tris, grid.lo, grid.spacing, grid.shape)
    assert np.array_equal(got, ref), (
        f"{int((got != ref).sum())} voxels differ, e.g. {np.argwhere(got != ref)[:4].tolist()} "
        f"(kernel {int(got.sum())}, reference {int(ref.sum())})")
    return got


def on(v):
    return {tuple(map(int, x)) for x in np.argwhere(v)}


# ---- held to the reference ------------------------------------------------------

def test_random_triangles_match_the_reference(kernel):
    rng = np.random.default_rng(35)
    shape = np.array([6, 5, 7])
    for trial in range(150):
        m = int(rng.integers(1, 4))
        f = rng.integers(-2 * 64, (shape + 2) * 64, size=(m, 3, 3)) / 64.0
        if trial % 3 == 0:  # onto voxel planes, edges and corners
            f = np.floor(f * rng.choice([1, 2], size=f.shape)) / rng.choice([1, 2], size=f.shape)
        if trial % 5 == 0:  # small triangles
            f[:, 1:] = f[:, :1] + rng.integers(-40, 40, size=(m, 2, 3)) / 64
        if trial % 7 == 0:  # a repeated vertex: a segment
            f[:, 2] = f[:, 1]
        if trial % 11 == 0:  # collinear vertices
            f[:, 2] = f[:, 0] + (f[:, 1] - f[:, 0]) * 3 / 4
        check(f, kernel)


def test_large_triangles_and_segments_walked_match_the_reference(kernel):
    # Triangles spanning many voxels take the kernels' column and segment walks.
    rng = np.random.default_rng(7)
    shape = np.array([14, 11, 13])
    for trial in range(16):
        f = rng.integers(-3 * 16, (shape + 3) * 16, size=(2, 3, 3)) / 16.0
        if trial % 3 == 0:
            f = np.floor(f)
        if trial % 4 == 0:  # in an axis plane
            f[:, :, trial % 3] = f[:, :1, trial % 3]
        if trial % 5 == 0:
            f[:, 2] = f[:, 0] + (f[:, 1] - f[:, 0]) * 3 / 4
        check(f, kernel, shape)


SHAPE = (5, 4, 6)
# Coordinates in voxel units: multiples of 2**-6, or voxel planes, around the grid.
coordinate = st.one_of(st.integers(-2 * 64, 8 * 64).map(lambda x: x / 64),
                       st.integers(-2, 8).map(float))
point = st.tuples(coordinate, coordinate, coordinate)


@st.composite
def triangle(draw):
    a = draw(point)
    kind = draw(st.sampled_from(["any", "any", "small", "point", "segment"]))
    if kind == "point":
        return [a, a, a]
    if kind == "segment":
        b = draw(point)
        return [a, b, draw(st.sampled_from([a, b]))]
    if kind == "small":
        step = st.integers(-48, 48).map(lambda x: x / 64)
        return [a] + [tuple(x + draw(step) for x in a) for _ in range(2)]
    return [a, draw(point), draw(point)]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(triangle(), min_size=1, max_size=3))
def test_property_every_kernel_gives_the_reference(tris):
    f = np.array(tris, dtype=np.float64)
    for kernel in KERNELS:
        check(f, kernel, SHAPE)


# ---- the adversarial cases ---------------------------------------------------------

def sheet(z, lo=(-0.5, -0.5), hi=(5.5, 4.5)):
    """Two triangles: the rectangle lo..hi (x, y) at height z (index space)."""
    (x0, y0), (x1, y1) = lo, hi
    return [[(x0, y0, z), (x1, y0, z), (x1, y1, z)], [(x0, y0, z), (x1, y1, z), (x0, y1, z)]]


@pytest.mark.parametrize("z, layer", [(3.0, 3), (3.5, 3), (0.0, 0), (7.0, 6)],
                         ids=["on-a-voxel-plane", "between", "on-the-low-face", "on-the-far-face"])
def test_face_on_a_voxel_plane_lights_one_layer_the_one_above(kernel, z, layer):
    got = check(sheet(z), kernel)
    expect = np.zeros_like(got)
    expect[:, :, layer] = True
    assert np.array_equal(got, expect)


def test_edge_along_a_voxel_edge(kernel):
    # In the plane x = 2, with an edge along the voxel edge x = 2, y = 3: the
    # layer i = 2 only, and no voxel below y = 3; at y = 4 it spans z in [2, 3].
    got = check([[(2, 3, 1), (2, 3, 4), (2, 4.5, 2.5)]], kernel)
    assert on(got) == {(2, 3, k) for k in (1, 2, 3, 4)} | {(2, 4, 2), (2, 4, 3)}


@pytest.mark.parametrize("corner, voxel", [((2, 3, 4), (2, 3, 4)), ((0, 0, 0), (0, 0, 0)),
                                           ((6, 5, 7), (5, 4, 6)), ((6, 2, 3), (5, 2, 3))],
                         ids=["inside", "low-corner", "far-corner", "far-face"])
def test_vertex_on_a_voxel_corner_lights_one_voxel(kernel, corner, voxel):
    assert on(check([[corner, corner, corner]], kernel)) == {voxel}


def test_triangle_touching_a_corner_from_below_lights_the_voxel_above_it(kernel):
    # Inside voxel (1, 1, 1) but for one vertex on its far corner, which is
    # voxel (2, 2, 2)'s point.
    got = check([[(1.25, 1.5, 1.5), (1.5, 1.25, 1.75), (2, 2, 2)]], kernel)
    assert on(got) == {(1, 1, 1), (2, 2, 2)}


def test_slivers(kernel):
    eps = 1 / 64
    check([[(0.5, 0.5, 0.5), (4.5, 3.5, 5.5), (4.5 + eps, 3.5, 5.5)],   # a needle across many voxels
           [(1, 0.25, 2), (5, 0.25, 2), (3, 0.25 + eps, 2)],              # flat on z = 2, thin in y
           [(2, 1, 0.5), (2, 4, 6.5), (2 + eps, 2.5, 3.5)]], kernel)      # almost in the plane x = 2


def test_degenerate_triangles(kernel):
    check([[(1, 1, 1), (1, 1, 1), (1, 1, 1)],                  # points
           [(0.5, 0.5, 0.5), (0.5, 0.5, 0.5), (0.5, 0.5, 0.5)],
           [(0.5, 1.5, 0.5), (4.5, 1.5, 0.5), (4.5, 1.5, 0.5)],   # a segment along x
           [(0.5, 0.5, 0.5), (5.5, 4.5, 6.5), (3, 2.5, 3.5)],     # collinear, across the grid
           [(1, 1, 1), (4, 3, 5), (4, 3, 5)]], kernel)            # corner to corner
    # A segment along a voxel edge lights the row above and right of it only.
    got = check([[(2, 3, 0.5), (2, 3, 3.5), (2, 3, 2)]], kernel)
    assert on(got) == {(2, 3, k) for k in range(4)}


def test_triangle_across_the_whole_grid(kernel):
    check([[(-3, -3, -3), (30, -1, 4), (-2, 30, 9)]], kernel)
    check([[(-100, -100, 3.5), (200, -100, 3.5), (-100, 200, 3.5)]], kernel)


@pytest.mark.parametrize("n", [64, 200])
def test_big_sheet_lights_exactly_its_layer(kernel, n):
    # An analytic check far beyond the reference's reach: the walks over a
    # triangle of n x n voxels give exactly one full layer.
    grid = Grid(lo=np.zeros(3), hi=np.full(3, float(n)), shape=(n, n, n))
    for z, layer in ((17.0, 17), (17.25, 17), (n, n - 1)):
        tris = [[(-5, -5, z), (3 * n, -5, z), (-5, 3 * n, z)]]
        got = voxels(tris, grid, kernel)
        assert got[:, :, layer].all() and got.sum() == n * n
    # Tilted: z = 5 + (x + y) / 8. Over the half-open column of cell (i, j)
    # it takes [lo, hi), hi = lo + 1/4 attained only in the grid's last column
    # on both axes: voxels floor(lo) .. ceil(hi) - 1 (.. floor(hi) there).
    top = 5 + n / 4
    tris = [[(0, 0, 5), (n, 0, top - n / 8), (0, n, top - n / 8)],
            [(n, 0, top - n / 8), (n, n, top), (0, n, top - n / 8)]]
    got = voxels(tris, grid, kernel)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    first = (40 + i + j) // 8
    last = np.where((i == n - 1) & (j == n - 1), (42 + i + j) // 8, (41 + i + j) // 8)
    k = np.arange(n)
    expect = (k >= first[..., None]) & (k <= last[..., None])
    assert np.array_equal(got, expect)


def test_triangles_partly_and_wholly_outside(kernel):
    check([[(-4, 1, 1), (2.5, 2, 3), (-1, 4, 6)],     # partly below x = 0
           [(5, 3, 6), (9, 7, 11), (6, 8, 7.5)],      # partly beyond the far corner
           [(6, 0, 0), (6, 5, 0), (6, 0, 7)],         # on the far face x = 6: the last layer
           [(6.25, 0, 0), (6.25, 5, 0), (6.25, 0, 7)],  # just beyond it: nothing
           [(-9, -9, -9), (-8, -9, -9), (-9, -8, -9)],  # wholly outside
           [(1, 1, -3), (2, 2, -3), (1, 2, -0.25)]], kernel)
    got = voxels(world([[(-9, -9, -9), (-8, -9, -9), (-9, -8, -9)]]), dyadic_grid(), kernel)
    assert not got.any()


def test_cad_box_on_grid_planes_has_walls_one_voxel_thick(kernel):
    # A box from the voxel planes (1, 1, 2) to (4, 3, 7): its faces on x = 1
    # and x = 4 light layers 1 and 4 (each the one above its plane), so the
    # walls are one voxel thick; z = 7 is the grid's far face: the last layer.
    import trimesh

    box = trimesh.creation.box(bounds=[(1, 1, 2), (4, 3, 7)])
    got = check(box.triangles, kernel)
    shell = {(i, j, k) for i in range(1, 5) for j in range(1, 4) for k in range(2, 7)
             if i in (1, 4) or j in (1, 3) or k in (2, 6)}
    assert on(got) == shell


def test_open_sheet_gives_exactly_one_layer(kernel):
    # A sheet across the whole grid, in general position and on a voxel
    # plane, on a grid fitted to a thin box around it: one voxel per column.
    for z in (0.3, 0.5):
        tris = np.array(sheet(z, (0, 0), (1, 1)), dtype=np.float64)
        grid = make_grid([[0, 0, 0], [1, 1, 1]], resolution=32)
        got = voxels(tris, grid, kernel)
        assert (got.sum(axis=2) == 1).all()


# ---- real models ------------------------------------------------------------------

def _sample(path, count, seed=0):
    mesh = geovox.load_mesh(path)
    tris = np.ascontiguousarray(mesh.triangles)
    pick = np.random.default_rng(seed).choice(len(tris), size=min(count, len(tris)), replace=False)
    return mesh, tris, np.sort(pick)


@pytest.mark.parametrize("model", ["spot", "bunny"])
def test_real_model_matches_the_reference_on_its_snapped_vertices(kernel, model):
    # A real model on a non-dyadic grid: the kernel decides for the snapped
    # triangles (q / 2**s voxels), exactly.
    path = SPOT if model == "spot" else corpus("bunny_watertight", "bunny_oded.obj")
    mesh, tris, pick = _sample(path, 250)
    grid = make_grid(mesh.bounds, resolution=20)
    s = snap_bits(tris, grid)  # from the whole mesh, as the kernel's
    got = voxels(tris[pick], grid, kernel)
    assert snap_bits(tris[pick], grid) == s == MAX_SUB_BITS
    q = np.rint((tris[pick] - grid.lo) / grid.spacing * float(2**s)).astype(np.int64)
    index = [[[Fraction(int(x), 2**s) for x in p] for p in t] for t in q]
    assert np.array_equal(got, reference_index_voxels(index, grid.shape))
    # Snapping moved no vertex across a tie here: the real triangles' voxels too.
    assert np.array_equal(got, reference_voxels(tris[pick], grid.lo, grid.spacing, grid.shape))


@needs_compiled
@pytest.mark.parametrize("model, res", [("spot", 64), ("bunny", 96), ("spot", 257)])
def test_compiled_and_numpy_agree_on_real_models(model, res):
    path = SPOT if model == "spot" else corpus("bunny_watertight", "bunny_oded.obj")
    mesh = geovox.load_mesh(path)
    grid = make_grid(mesh.bounds, resolution=res)
    a = voxels(mesh.triangles, grid, "compiled", jobs=2)
    b = voxels(mesh.triangles, grid, "numpy")
    assert a.any() and np.array_equal(a, b)


@needs_compiled
def test_compiled_and_numpy_agree_on_random_meshes():
    # Triangles of every size, far outside and degenerate, on a grid whose
    # corner and spacing are not dyadic.
    rng = np.random.default_rng(3)
    grid = Grid(lo=np.array([-1.3, 0.7, 2.1]), hi=np.array([2.9, 3.1, 5.3]), shape=(37, 29, 41))
    size = rng.choice([0.01, 0.1, 1.0, 6.0], size=(600, 1, 1))
    centre = rng.uniform(-2, 6, size=(600, 1, 3))
    tris = centre + size * rng.normal(size=(600, 3, 3))
    tris[::17, 2] = tris[::17, 1]
    tris[5::23, 2] = (tris[5::23, 0] + tris[5::23, 1]) / 2
    assert np.array_equal(voxels(tris, grid, "compiled"), voxels(tris, grid, "numpy"))


# ---- invariances ------------------------------------------------------------------

@needs_compiled
def test_the_answer_does_not_depend_on_jobs(threads_always):
    mesh = geovox.load_mesh(corpus("bunny_watertight", "bunny_oded.obj"))
    grid = make_grid(mesh.bounds, resolution=80)
    one = voxels(mesh.triangles, grid, "compiled", jobs=1)
    for jobs in (2, 4, 0):
        assert np.array_equal(voxels(mesh.triangles, grid, "compiled", jobs=jobs), one)


def test_every_block_split_equals_the_whole_grid(kernel):
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=40)
    whole = voxels(mesh.triangles, grid, kernel, jobs=2)
    nz = grid.shape[2]
    rng = np.random.default_rng(1)
    for cuts in ([0, 1, nz], [0, nz - 1, nz], sorted({0, nz, *rng.integers(1, nz, size=6)})):
        buffer = np.ones((grid.shape[0], grid.shape[1], nz), dtype=bool, order="F")
        for z0, z1 in zip(cuts[:-1], cuts[1:]):
            out = buffer[:, :, : z1 - z0]  # a reused buffer, full of stale voxels
            if not out.flags.f_contiguous:
                out = np.ones((grid.shape[0], grid.shape[1], z1 - z0), dtype=bool, order="F")
            got = voxels(mesh.triangles, grid, kernel, block=(z0, z1), jobs=2, out=out)
            assert got is out
            assert np.array_equal(got, whole[:, :, z0:z1]), (z0, z1)


def test_a_slab_from_the_triangles_that_reach_it_with_the_whole_meshs_bits(kernel):
    # Streaming: each slab made from only its triangles, snapped at the whole
    # mesh's scale (here lowered by one far triangle), is the whole grid's slice.
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=32)
    far = grid.lo + np.array([[(0.1, 0.1, 0.1), (5000.0, 0.2, 0.1), (0.1, 0.3, 0.2)]]) * grid.spacing
    tris = np.concatenate([mesh.triangles, far])
    bits = snap_bits(tris, grid)
    assert bits == 29 - 13 < snap_bits(mesh.triangles, grid)
    whole = voxels(tris, grid, kernel)
    zmin = (tris[:, :, 2].min(axis=1) - grid.lo[2]) / grid.spacing[2]
    zmax = (tris[:, :, 2].max(axis=1) - grid.lo[2]) / grid.spacing[2]
    for z0, z1 in ((0, 7), (7, 20), (20, 32)):
        near = (zmax >= z0 - 1) & (zmin <= z1 + 1)
        got = voxels(tris[near], grid, kernel, block=(z0, z1), bits=bits)
        assert np.array_equal(got, whole[:, :, z0:z1])
    with pytest.raises(ParameterError, match="bits"):
        voxels(mesh.triangles, grid, kernel, bits=MAX_SUB_BITS + 1)


def test_output_is_a_fortran_ordered_bool_array(kernel):
    got = voxels([[(0.1, 0.2, 0.3), (0.4, 0.2, 0.3), (0.1, 0.6, 0.3)]], dyadic_grid(), kernel)
    assert got.dtype == np.bool_ and got.flags.f_contiguous and got.shape == (6, 5, 7)


# ---- the snapping scale -------------------------------------------------------------

def test_snap_bits_is_chosen_from_the_grid_and_the_triangles_that_reach_it():
    tri = np.array([[(0.1, 0.2, 0.3), (0.4, 0.2, 0.3), (0.1, 0.6, 0.3)]])
    unit = lambda n: Grid(lo=np.zeros(3), hi=np.ones(3), shape=(n, n, n))  # noqa: E731
    # s = min(20, 29 - e) with M + 1 < 2**e, M = the largest side (or coordinate) in voxels.
    assert snap_bits(tri, unit(256)) == 20
    assert snap_bits(tri, unit(1024)) == 29 - 11
    assert snap_bits(tri, unit(4096)) == 29 - 13
    # A triangle that cannot reach the grid changes nothing, however far.
    far = np.array([[(1e9, 0, 0), (1e9 + 1, 0, 0), (1e9, 1, 0)]])
    assert snap_bits(np.concatenate([tri, far]), unit(256)) == 20
    # One that reaches it from 1e5 voxels away lowers s: 1e5 + 1 < 2**17.
    reach = np.array([[(0.5, 0.5, 0.5), (400.0, 0.5, 0.5), (0.5, 0.6, 0.5)]])
    assert snap_bits(np.concatenate([tri, reach]), unit(256)) == 29 - 17
    with pytest.raises(ParameterError, match="too small"):
        surface_voxels(np.array([[(0.5, 0.5, 0.5), (2.0**21, 0.5, 0.5), (0.5, 0.6, 0.5)]]), unit(256))


@needs_compiled
def test_both_kernels_choose_the_same_snapping():
    rng = np.random.default_rng(11)
    grid = Grid(lo=np.array([-1.3, 0.7, 2.1]), hi=np.array([2.9, 3.1, 5.3]), shape=(370, 290, 410))
    for scale in (1.0, 30.0, 3e4):
        tris = rng.normal(size=(5000, 3, 3)) * scale
        tris[::97, 1, 2] = np.nan
        with chosen("numpy"):
            a = snap_bits(tris, grid)
        with chosen("compiled"):
            b = snap_bits(tris, grid, jobs=2)
        assert a == b


def test_non_finite_triangles_are_skipped(kernel):
    tris = world([[(1, 1, 1), (2, 1, 1), (1, 2, 1)], [(1, 1, 1), (np.nan, 1, 1), (1, 2, 1)],
                  [(1, 1, 3), (np.inf, 1, 3), (1, 2, 3)]])
    got = voxels(tris, dyadic_grid(), kernel)
    assert on(got) == on(voxels(tris[:1], dyadic_grid(), kernel)) == {(1, 1, 1), (2, 1, 1), (1, 2, 1)}


def test_bad_arguments_are_refused():
    grid = dyadic_grid()
    tri = world([[(1, 1, 1), (2, 1, 1), (1, 2, 1)]])
    with pytest.raises(MeshError, match="triangles"):
        surface_voxels(np.zeros((2, 3)), grid)
    with pytest.raises(ParameterError, match="grid"):
        surface_voxels(tri, (LO, LO + 1))
    for block in ((3, 3), (-1, 2), (0, 8), "ab"):
        with pytest.raises(ParameterError, match="block"):
            surface_voxels(tri, grid, block)
    for out in (np.zeros((6, 5, 7), bool), np.zeros((6, 5, 6), bool, order="F"),
                np.zeros((6, 5, 7), np.uint8, order="F")):
        with pytest.raises(ParameterError, match="out"):
            surface_voxels(tri, grid, out=out)
    with pytest.raises(ParameterError, match="jobs"):
        surface_voxels(tri, grid, jobs=-1)


# ---- a mesh's faces, and the voxels as points (bits) ---------------------------------

def in_memory_order(dense):
    """(m, 3) [i, j, k] of a volume's voxels, x fastest, then y, then z (the file order)."""
    return np.argwhere(dense.transpose(2, 1, 0))[:, ::-1]


def points(tris, grid, kernel, **kw):
    with chosen(kernel):
        return surface_points(np.asarray(tris, dtype=np.float64), grid, **kw)


def random_mesh(seed=3, count=600):
    """Triangles of every size, far outside and degenerate, on a non-dyadic grid."""
    rng = np.random.default_rng(seed)
    grid = Grid(lo=np.array([-1.3, 0.7, 2.1]), hi=np.array([2.9, 3.1, 5.3]), shape=(37, 29, 41))
    size = rng.choice([0.01, 0.1, 1.0, 6.0], size=(count, 1, 1))
    tris = rng.uniform(-2, 6, size=(count, 1, 3)) + size * rng.normal(size=(count, 3, 3))
    tris[::17, 2] = tris[::17, 1]
    tris[5::23, 2] = (tris[5::23, 0] + tris[5::23, 1]) / 2
    return tris, grid


def test_faces_give_the_voxels_of_their_triangles(kernel):
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=48)
    whole = voxels(mesh.triangles, grid, kernel)
    with chosen(kernel):
        got = surface_voxels(mesh.vertices, grid, faces=mesh.faces)
        assert snap_bits(mesh.vertices, grid, faces=mesh.faces) == snap_bits(mesh.triangles, grid)
    assert whole.any() and np.array_equal(got, whole)


def test_a_far_vertex_no_reaching_triangle_uses_changes_no_scale(kernel):
    # The scale's quick bound takes every vertex; one that only far or unused triangles
    # touch must not lower it (the pass over the reaching triangles decides then).
    grid = Grid(lo=np.zeros(3), hi=np.ones(3), shape=(256, 256, 256))
    verts = np.array([(0.1, 0.2, 0.3), (0.4, 0.2, 0.3), (0.1, 0.6, 0.3), (1e9, 0, 0),
                      (1e9 + 1, 0, 0), (1e9, 1, 0), (400.0, 0.5, 0.5)])
    with chosen(kernel):
        assert snap_bits(verts, grid, faces=np.array([[0, 1, 2], [3, 4, 5]])) == 20
        assert snap_bits(verts, grid, faces=np.array([[0, 1, 2], [0, 1, 6]])) == 29 - 17


def test_bad_faces_are_refused():
    grid = dyadic_grid()
    verts = world([(1, 1, 1), (2, 1, 1), (1, 2, 1)])
    with pytest.raises(MeshError, match="faces"):
        surface_voxels(verts, grid, faces=np.array([[0, 1, 3]]))
    with pytest.raises(MeshError, match="faces"):
        surface_voxels(verts, grid, faces=np.array([0, 1, 2]))
    with pytest.raises(MeshError, match="triangles"):
        surface_voxels(verts.reshape(1, 3, 3), grid, faces=np.array([[0, 1, 2]]))


@pytest.mark.parametrize("model", ["spot", "random"])
def test_points_are_the_voxels_in_memory_order(kernel, model):
    if model == "spot":
        mesh = geovox.load_mesh(SPOT)
        tris, grid = mesh.triangles, make_grid(mesh.bounds, resolution=40)
    else:
        tris, grid = random_mesh()
    got = points(tris, grid, kernel)
    assert got.dtype == np.int32 and got.shape[1] == 3 and len(got) > 100
    assert np.array_equal(got, in_memory_order(voxels(tris, grid, "numpy")))


@needs_compiled
def test_compiled_points_are_the_numpy_twins(threads_always):
    tris, grid = random_mesh(seed=5, count=900)
    twin = points(tris, grid, "numpy")
    for jobs in (1, 2, 3):
        assert np.array_equal(points(tris, grid, "compiled", jobs=jobs), twin)


def test_points_of_slabs_are_the_whole_grids(kernel, threads_always):
    # One buffer of bits for every slab, handed back all zero each time.
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, shape=(30, 26, 40))
    whole = points(mesh.triangles, grid, kernel, jobs=2)
    bits = snap_bits(mesh.triangles, grid)
    words = np.zeros(word_count((30, 26, 13)), dtype=np.uint64)
    parts = []
    for z0, z1 in ((0, 13), (13, 14), (14, 27), (27, 40)):
        parts.append(points(mesh.vertices, grid, kernel, faces=mesh.faces, block=(z0, z1),
                            jobs=2, bits=bits, words=words))
        assert not words.any()
        assert ((parts[-1][:, 2] >= z0) & (parts[-1][:, 2] < z1)).all()
    assert np.array_equal(np.concatenate(parts), whole)


@needs_compiled
def test_the_answer_does_not_depend_on_threads_in_any_mode(threads_always):
    mesh = geovox.load_mesh(corpus("bunny_watertight", "bunny_oded.obj"))
    grid = make_grid(mesh.bounds, resolution=70)
    one = voxels(mesh.triangles, grid, "compiled", jobs=1)
    order = in_memory_order(one)
    for jobs in (2, 4):
        assert np.array_equal(voxels(mesh.triangles, grid, "compiled", jobs=jobs), one)
        assert np.array_equal(points(mesh.triangles, grid, "compiled", jobs=jobs), order)
        with chosen("compiled"):
            assert snap_bits(mesh.triangles, grid, jobs=jobs) == snap_bits(mesh.triangles, grid)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_points_as_values(kernel, threads_always, dtype):
    # Per-axis values looked up as the bits are read: the values of the indices.
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, shape=(30, 26, 40))
    values = [(np.arange(n) * 0.37 - a).astype(dtype) for a, n in enumerate(grid.shape)]
    ijk = points(mesh.triangles, grid, kernel, jobs=2)
    for block in (None, (7, 29)):
        got = points(mesh.triangles, grid, kernel, jobs=2, block=block, values=values)
        want = ijk if block is None else ijk[(ijk[:, 2] >= 7) & (ijk[:, 2] < 29)]
        assert got.dtype == dtype and len(got) > 100
        assert np.array_equal(got, np.stack([values[a][want[:, a]] for a in range(3)], axis=1))
    for bad in ([values[0], values[1]], [values[0], values[1], values[2][:-1]],
                [values[0], values[1], values[2].astype(np.int32)],
                [values[0], values[1], values[2].astype(np.float16)]):
        with pytest.raises(ParameterError, match="values"):
            points(mesh.triangles, grid, kernel, values=bad)


def test_bad_words_and_bits_are_refused(kernel):
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=16)
    need = word_count(grid.shape)
    for words in (np.zeros(need - 1, np.uint64), np.zeros(need, np.int64),
                  np.zeros((need, 1), np.uint64), [0] * need):
        with pytest.raises(ParameterError, match="words"):
            points(mesh.triangles, grid, kernel, words=words)
    # A scale above the triangles' (a far vertex lowers it): refused, the words left all zero.
    far = np.array([[(0.1, 0.1, 0.1), (5000.0, 0.2, 0.1), (0.1, 0.3, 0.2)]])
    tris = np.concatenate([mesh.triangles, grid.lo + far * grid.spacing])
    words = np.zeros(need, np.uint64)
    with pytest.raises(ParameterError, match="bits"):
        points(tris, grid, kernel, bits=MAX_SUB_BITS, words=words)
    assert not words.any()
    with pytest.raises(ParameterError, match="bits"):
        points(tris, grid, kernel, bits=0)
