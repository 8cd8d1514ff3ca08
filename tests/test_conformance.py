"""The backend contract: one test class that every backend that can run here passes.

A backend has one job (axis-parallel column rays -> every crossing, with its
triangle, depth and barycentrics, under the shared tie rules of
geovox.exact). The class runs on every name of the registry, webgpu included,
and each backend `geovox backends` reports as unable to run here is skipped
with that line as the reason (webgpu runs through lavapipe, Mesa's software
Vulkan, where no GPU exists). The fixtures are small, so lavapipe adds
seconds, not minutes; the wider tests of the pipeline run on the CPU backends
through the shared `backend` fixture in conftest.py.
"""

from __future__ import annotations

import functools

import numpy as np
import pytest
import trimesh

import geovox
from geovox.backends import REGISTRY, backend_report, get_backend
from geovox.errors import GeovoxWarning
from geovox.grid import make_grid
from geovox.block import voxelize_block
from geovox.block import ray_start

from conftest import SPOT, box_mesh, from_tm, reference_occupancy
from test_backends import t_junction_box
from test_exact import CASES


@functools.lru_cache(maxsize=None)
def _report():
    return backend_report()


@pytest.fixture(scope="module", params=list(REGISTRY))
def engine(request):
    """Each backend of the registry that can run here; the rest skip, saying why."""
    ok, line = _report()[request.param]
    if not ok:
        pytest.skip(f"backend {request.param!r} cannot run here: {line}")
    return request.param


def _cast(mesh, grid, engine, axis):
    columns = grid.columns(axis, start=ray_start(mesh, grid, axis))
    return columns, get_backend(engine).cast(mesh, columns)


def _open_spot():
    """spot with a band of faces removed: open, so `auto` repairs and caps it."""
    m = geovox.load_mesh(SPOT)
    keep = np.ones(len(m.faces), bool)
    keep[100:160] = False
    return geovox.Mesh(m.vertices, m.faces[keep], source="open spot")


def _adversarial():
    yield "spot", geovox.load_mesh(SPOT), 20
    yield "t_junctions", t_junction_box(), 13
    box = trimesh.creation.box((1, 1, 1))
    yield "coplanar_overlap", from_tm(trimesh.util.concatenate(
        [box, box.copy().apply_translation((0.5, 0, 0))]), "coplanar"), 15
    ico = trimesh.creation.icosphere(subdivisions=2)
    yield "duplicated_faces", geovox.Mesh(np.asarray(ico.vertices),
                                          np.concatenate([ico.faces, ico.faces[:40]])), 11


ADVERSARIAL = list(_adversarial())


class TestBackendConformance:
    """What every backend must do, the same way, voxel for voxel."""

    def test_closed_meshes_cross_every_column_an_even_number_of_times(self, engine):
        for name, mesh, bounds, n in CASES:
            grid = make_grid(mesh.bounds, bounds=bounds, resolution=n)
            for axis in range(3):
                columns, hits = _cast(mesh, grid, engine, axis)
                counts = np.bincount(hits.ray, minlength=columns.count)
                assert counts.sum() > 0 and np.all(counts % 2 == 0), (name, axis)

    def test_edge_cases_equal_the_float_reference(self, engine):
        # Rays through vertices, along edges and across face diagonals.
        for name, mesh, bounds, n in CASES:
            for axis in range(3):
                vol = geovox.voxelize(mesh, resolution=n, bounds=bounds, backend=engine, axis=axis)
                ref = reference_occupancy(mesh, vol.grid, axis=axis)
                assert vol.inside_count > 0
                np.testing.assert_array_equal(vol.occupancy, ref, err_msg=f"{name} axis {axis}")

    def test_hits_lie_on_their_rays(self, engine):
        # The point rebuilt from (triangle, barycentrics) is on the ray, at `depth`.
        m = geovox.load_mesh(SPOT)
        columns, hits = _cast(m, make_grid(m.bounds, resolution=24), engine, 1)
        tri = m.triangles[hits.triangle]
        u, v = hits.bary[:, 0:1], hits.bary[:, 1:2]
        p = (1 - u - v) * tri[:, 0] + u * tri[:, 1] + v * tri[:, 2]
        assert len(hits.ray) > 0
        assert np.all(hits.bary >= 0) and np.all(hits.bary.sum(axis=1) <= 1 + 1e-12)
        np.testing.assert_allclose(p[:, 1], columns.w0 + hits.depth, atol=1e-9)
        np.testing.assert_allclose(p[:, 0], columns.centres_u()[hits.ray % columns.nu], atol=1e-6)
        np.testing.assert_allclose(p[:, 2], columns.centres_v()[hits.ray // columns.nu], atol=1e-6)

    @pytest.mark.parametrize("name,mesh,n", ADVERSARIAL, ids=[a[0] for a in ADVERSARIAL])
    def test_crossings_are_the_numpy_backends(self, engine, name, mesh, n):
        # T-junctions, coplanar overlaps and duplicated faces: where a ray
        # engine's restarts lose or double crossings.
        grid = make_grid(mesh.bounds, resolution=n)
        for axis in (0, 2):
            _, a = _cast(mesh, grid, engine, axis)
            _, b = _cast(mesh, grid, "numpy", axis)
            a, b = a.sorted(), b.sorted()
            np.testing.assert_array_equal(a.ray, b.ray, err_msg=f"{name} axis {axis}")
            np.testing.assert_array_equal(a.triangle, b.triangle)
            np.testing.assert_allclose(a.depth, b.depth, rtol=0, atol=1e-12)
            np.testing.assert_allclose(a.bary, b.bary, rtol=0, atol=1e-12)

    def test_boxes_are_exact_and_half_open(self, engine):
        # Faces on voxel centres: a centre c is inside where lo <= c < hi.
        mesh = box_mesh((1.5, 2.5, 0.5), (5.5, 4.5, 6.5))
        expected = np.zeros((8, 8, 8), bool)
        expected[1:5, 2:4, 0:6] = True
        for axis in range(3):
            vol = geovox.voxelize(mesh, resolution=8, bounds=(0, 0, 0, 8, 8, 8), backend=engine,
                                  axis=axis)
            np.testing.assert_array_equal(vol.occupancy, expected)
        rng = np.random.default_rng(3)
        for seed in range(3):
            lo = rng.uniform(-1, 0, 3)
            hi = lo + rng.uniform(0.2, 1.5, 3)
            region = np.r_[lo - rng.uniform(0, 0.5, 3), hi + rng.uniform(0, 0.5, 3)]
            shape = tuple(int(k) for k in rng.integers(5, 30, 3))
            vol = geovox.voxelize(box_mesh(lo, hi), shape=shape, bounds=region, backend=engine)
            inside = [(c >= lo[a]) & (c < hi[a]) for a, c in
                      enumerate(vol.grid.centres(a) for a in range(3))]
            np.testing.assert_array_equal(
                vol.occupancy, inside[0][:, None, None] & inside[1][None, :, None]
                & inside[2][None, None, :])

    def test_far_from_the_origin_and_a_ridge_on_a_column(self, engine):
        off = np.array([1e5, -2e5, 3e5])
        far = box_mesh(off + (1.5, 2.5, 0.5), off + (5.5, 4.5, 6.5))
        vol = geovox.voxelize(far, resolution=8, bounds=np.r_[off, off + 8], backend=engine)
        assert vol.inside_count == 4 * 2 * 6
        # A tent whose ridge runs along a column line: touched twice or not at all.
        verts = np.array([[0.5, 0.5, 0.0], [4.5, 0.5, 0.0], [4.5, 4.5, 0.0], [0.5, 4.5, 0.0],
                          [2.5, 0.5, 2.0], [2.5, 4.5, 2.0]])
        faces = np.array([[0, 2, 1], [0, 3, 2], [0, 1, 4], [3, 5, 2], [1, 2, 5], [1, 5, 4],
                          [0, 4, 5], [0, 5, 3]])
        tent = geovox.Mesh(verts, faces, source="tent")
        columns, hits = _cast(tent, make_grid(tent.bounds, bounds=(0, 0, -1, 5, 5, 3),
                                              resolution=5), engine, 2)
        assert np.all(np.bincount(hits.ray, minlength=columns.count) % 2 == 0)

    def test_subsections_and_ray_axes(self, engine):
        full = geovox.voxelize(SPOT, resolution=32, backend=engine)
        lo, h = np.asarray(full.bounds[0]), np.asarray(full.spacing)
        a, b = np.array([3, 8, 13]), np.array([20, 27, 28])
        sub = geovox.voxelize(SPOT, shape=tuple(b - a), bounds=np.r_[lo + a * h, lo + b * h],
                              backend=engine)
        np.testing.assert_array_equal(sub.occupancy, full.occupancy[a[0]:b[0], a[1]:b[1], a[2]:b[2]])
        for axis in (0, 1):
            other = geovox.voxelize(SPOT, resolution=32, backend=engine, axis=axis)
            assert np.count_nonzero(other.occupancy != full.occupancy) <= 2
        ref = geovox.voxelize(SPOT, resolution=32, backend="numpy")
        np.testing.assert_array_equal(full.occupancy, ref.occupancy)

    @pytest.mark.parametrize("inside", ["auto", "vote"])
    @pytest.mark.filterwarnings("ignore::geovox.errors.GeovoxWarning")  # auto: "... of a repaired copy"
    def test_inside_tests_on_an_open_mesh_are_the_numpy_backends(self, engine, inside):
        # auto on an open mesh: the winding number of a repaired, hole-capped copy.
        mesh = _open_spot()
        a = geovox.voxelize(mesh, resolution=20, inside=inside, backend=engine)
        b = geovox.voxelize(mesh, resolution=20, inside=inside, backend="numpy")
        assert a.inside_count > 0 and a.inside == b.inside == ("winding" if inside == "auto"
                                                                else "vote")
        np.testing.assert_array_equal(a.occupancy, b.occupancy)

    def test_colour_density_and_distance_are_the_numpy_backends(self, engine):
        kw = dict(resolution=16, color=True, density="coverage", supersample=2, sdf=True, band=1.0)
        a = geovox.voxelize(SPOT, backend=engine, **kw)
        b = geovox.voxelize(SPOT, backend="numpy", **kw)
        for name in ("occupancy", "colors", "density", "sdf"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
        fast = [geovox.voxelize(SPOT, backend=e, resolution=16, color="fast") for e in (engine, "numpy")]
        np.testing.assert_array_equal(fast[0].colors, fast[1].colors)

    def test_blocks_and_streamed_slabs_are_the_whole_grid(self, engine, tmp_path):
        m = geovox.load_mesh(SPOT)
        grid = make_grid(m.bounds, shape=(12, 10, 23))
        ref = geovox.voxelize(m, shape=grid.shape, axis=1, backend=engine, color=True)
        p = geovox.plan(m, dict(shape=grid.shape, backend=engine, axis=1, color=True))
        parts = [voxelize_block(m, p, blk) for blk in [(0, 7), (7, 23)]]
        np.testing.assert_array_equal(np.concatenate([p.occupancy for p in parts], axis=2),
                                      ref.occupancy)
        np.testing.assert_array_equal(np.concatenate([p.colors for p in parts], axis=2), ref.colors)
        from geovox.api import convert_to

        # Slabs are at least 64 layers: 150 layers in three.
        info = convert_to(SPOT, tmp_path / "s.raw", shape=(6, 5, 150), backend=engine,
                          budget=6 * 5 * 64)
        assert info["slabs"] > 1 and info["backend"] == engine
        whole = geovox.voxelize(SPOT, shape=(6, 5, 150), axis=1, backend="numpy")
        np.testing.assert_array_equal(geovox.formats.read_volume(tmp_path / "s.raw").occupancy,
                                      whole.occupancy)

    def test_a_region_that_misses_the_mesh_is_empty(self, engine):
        with pytest.warns(GeovoxWarning, match="misses the mesh"):
            vol = geovox.voxelize(SPOT, resolution=8, bounds=(5, 5, 5, 6, 6, 6), backend=engine)
        assert vol.inside_count == 0 and vol.backend == engine


def test_the_class_reaches_every_backend_that_can_run():
    # The parameters are the registry's names: none is left out because `auto`
    # does not try it (webgpu), and each skipped one is one `geovox backends`
    # reports as unable to run.
    assert "webgpu" in REGISTRY and "webgpu" not in geovox.available_backends()
    assert [n for n, (ok, _) in _report().items() if ok] == geovox.usable_backends()
