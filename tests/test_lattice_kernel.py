"""The compiled lattice search and mesh checks (geovox/_lattice.pyx) against their NumPy twins.

The compiled scan must return the NumPy scan's hits array for array (same
rays, same float64 depths and weights bit for bit, same order), on the
adversarial fixtures of test_exact.py (rays through edges and vertices, fans
on a column, diagonals on column centres) and on real models; the compiled
mesh checks must answer as the NumPy code of geovox.inside does, on closed,
open, non-manifold, duplicated and split meshes, with buckets past the
small-bucket shortcut.
"""

from __future__ import annotations

import os
import shutil
import sysconfig

import numpy as np
import pytest
import trimesh

import geovox
import geovox.inside as inside
from geovox.backends.numpy import rasterise
from geovox.errors import ParameterError
from geovox.exact import Projection
from geovox.grid import make_grid
from geovox.kernels import chosen, lattice
from geovox.mesh import Mesh
from geovox.block import ray_start

from conftest import box_mesh, corpus, from_tm
from test_exact import CASES

FIELDS = ("ray", "depth", "triangle", "bary")


def _have_compiler():
    cc = sysconfig.get_config_var("CC")
    return bool(shutil.which(cc.split()[0] if cc else "cc")) and os.path.exists(
        os.path.join(sysconfig.get_paths()["include"], "Python.h"))


@pytest.fixture(scope="module")
def kernel():
    """The compiled module: a failure where it should have been built, a skip elsewhere."""
    try:
        with chosen("compiled"):
            return lattice()
    except ParameterError:
        if _have_compiler():
            pytest.fail("a C compiler and Python's headers are here, but geovox._lattice "
                        "was not built (pip install -e . builds it)")
        pytest.skip("no C compiler: the compiled lattice search is optional")


def test_the_lattice_kernel_is_built_where_a_compiler_exists(kernel):
    assert kernel.__name__ == "geovox._lattice"


def test_kernel_choice_is_checked(monkeypatch):
    with pytest.raises(ParameterError, match="auto, compiled or numpy"), chosen("fast"):
        lattice()
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    assert lattice() is None
    monkeypatch.setenv("GEOVOX_KERNEL", "nonsense")
    with pytest.raises(ParameterError, match="GEOVOX_KERNEL"):
        lattice()


def _both(proj, monkeypatch, **kw):
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    a = rasterise(proj, block=997, **kw)  # several NumPy blocks, odd size
    monkeypatch.setenv("GEOVOX_KERNEL", "compiled")
    b = rasterise(proj, **kw)
    monkeypatch.delenv("GEOVOX_KERNEL")
    return a, b


def _assert_same(a, b):
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape, f
        # Bit for bit, zeros' signs included.
        assert np.array_equal(x.view(np.uint8), y.view(np.uint8)), f


@pytest.mark.parametrize("name,mesh,bounds,n", CASES, ids=[c[0] for c in CASES])
@pytest.mark.parametrize("axis", [0, 1, 2])
def test_compiled_scan_is_the_numpy_scan_on_edges_and_vertices(name, mesh, bounds, n, axis, kernel,
                                                               monkeypatch):
    grid = make_grid(mesh.bounds, bounds=bounds, resolution=n)
    proj = Projection(mesh.triangles, grid.columns(axis, start=ray_start(mesh, grid, axis)))
    a, b = _both(proj, monkeypatch)
    assert len(a) > 0
    _assert_same(a, b)
    # Masks, as the Embree backend passes them.
    rng = np.random.default_rng(axis)
    cols = rng.random(proj.columns.count) < 0.5
    tris = rng.random(len(proj)) < 0.5
    _assert_same(*_both(proj, monkeypatch, column_mask=cols))
    _assert_same(*_both(proj, monkeypatch, triangle_mask=tris))
    _assert_same(*_both(proj, monkeypatch, column_mask=cols, triangle_mask=tris))


@pytest.mark.parametrize("path,res", [(("bunny_watertight", "bunny_oded.obj"), 96),
                                      (("suzanne", "suzanne.obj"), 64),
                                      (("fuze", "fuze.obj"), 80),
                                      (("spot",), 128)])
def test_compiled_scan_is_the_numpy_scan_on_real_models(path, res, kernel, monkeypatch):
    p = corpus(*path) if len(path) > 1 else corpus("spot", "spot.obj")
    mesh = geovox.load_mesh(p)
    grid = make_grid(mesh.bounds, resolution=res)
    for axis in range(3):
        proj = Projection(mesh.triangles, grid.columns(axis, start=ray_start(mesh, grid, axis)))
        a, b = _both(proj, monkeypatch)
        assert len(a) > 0
        _assert_same(a, b)


def test_both_kernels_give_the_same_volume_bytes(kernel, monkeypatch):
    mesh = geovox.load_mesh(corpus("spot", "spot.obj"))
    out = {}
    for k in ("numpy", "compiled"):
        monkeypatch.setenv("GEOVOX_KERNEL", k)
        out[k] = geovox.voxelize(mesh, resolution=72, backend="numpy").occupancy
    assert out["numpy"].any() and np.array_equal(out["numpy"], out["compiled"])


def test_triangles_that_enclose_no_column_centre_are_not_active():
    # A fine sphere on a coarse lattice: most triangles lie between centres.
    s = trimesh.creation.icosphere(subdivisions=5, radius=3.0)
    mesh = from_tm(s, "ico5")
    grid = make_grid(mesh.bounds, resolution=8)
    columns = grid.columns(2, start=ray_start(mesh, grid, 2))
    proj = Projection(mesh.triangles, columns)
    assert 0 < len(proj) < len(mesh.faces) // 10
    # Every triangle left out has no column centre in its closed box (in
    # column units, a centre at i + 0.5), so no ray can cross it.
    out = np.setdiff1d(np.arange(len(mesh.faces)), proj.tri)
    t = mesh.triangles[out]
    u = (t[:, :, 0] - columns.u0) / columns.du
    v = (t[:, :, 1] - columns.v0) / columns.dv
    i_lo, i_hi = np.ceil(u.min(1) - 0.5 - 1e-6), np.floor(u.max(1) - 0.5 + 1e-6)
    j_lo, j_hi = np.ceil(v.min(1) - 0.5 - 1e-6), np.floor(v.max(1) - 0.5 + 1e-6)
    a, b = t[:, 1, :2] - t[:, 0, :2], t[:, 2, :2] - t[:, 0, :2]
    flat = np.abs(a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]) < 1e-12
    assert np.all((i_lo > i_hi) | (j_lo > j_hi) | flat)


# --- the mesh checks -------------------------------------------------------------------------

def _numpy_answers(mesh, monkeypatch):
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    m = Mesh(mesh.vertices, mesh.faces, source=mesh.source)
    g = m.geometric_faces
    g = g[(g[:, 0] != g[:, 1]) & (g[:, 1] != g[:, 2]) & (g[:, 2] != g[:, 0])]
    out = (len(inside.boundary_edges(m)) == 0, inside.non_manifold(m), inside.consistent(m),
           inside.edges.vertex_connected(g) if len(g) else True, inside.overlapping_pieces(m),
           inside.choose(m, "auto") if len(inside.boundary_edges(m)) == 0 else None)
    monkeypatch.delenv("GEOVOX_KERNEL")
    return out


def _compiled_answers(mesh, kernel, monkeypatch):
    monkeypatch.setenv("GEOVOX_KERNEL", "compiled")
    m = Mesh(mesh.vertices, mesh.faces, source=mesh.source)
    pf = kernel.merge_positions(m.vertices)[m.faces]
    closed = len(inside.boundary_edges(m)) == 0
    g = pf[(pf[:, 0] != pf[:, 1]) & (pf[:, 1] != pf[:, 2]) & (pf[:, 2] != pf[:, 0])]
    out = (closed, inside.non_manifold(m), inside.consistent(m),
           kernel.vertex_connected(g) if len(g) else True, inside.overlapping_pieces(m),
           inside.choose(m, "auto") if closed else None)
    monkeypatch.delenv("GEOVOX_KERNEL")
    return out


def _check_meshes():
    box = box_mesh((0, 0, 0), (1, 1, 1))
    yield "closed_box", box
    yield "open_box", Mesh(box.vertices, box.faces[1:], source="open")
    yield "flipped_face", Mesh(box.vertices, np.r_[box.faces[:1, ::-1], box.faces[1:]], source="f")
    yield "extra_face", Mesh(box.vertices, np.r_[box.faces, box.faces[3:4, [1, 2, 0]]],
                             source="extra")
    # A face twice, once each way: closed, but not consistently wound.
    yield "duplicate_pair", Mesh(box.vertices, np.r_[box.faces, box.faces[3:4, [1, 2, 0]],
                                                     box.faces[3:4, ::-1]], source="dup")
    two = np.r_[box.faces, box.faces + 8]
    yield "two_apart", Mesh(np.r_[box.vertices, box.vertices + 3.0], two, source="apart")
    yield "two_overlapping", Mesh(np.r_[box.vertices, box.vertices + 0.5], two, source="over")
    # Two boxes sharing an edge: four faces on it (non-manifold), closed.
    other = box.vertices + np.array([1.0, 1.0, 0.0])
    yield "shared_edge", Mesh(np.r_[box.vertices, other], two, source="edge")
    # Split vertices (a seam): merged by position, -0.0 and 0.0 as one.
    v = box.vertices.copy()
    seam = np.r_[v, v[:1] * -1.0]  # corner 0 is (0, 0, 0): its copy is (-0, -0, -0)
    f = box.faces.copy()
    f[f == 0] = np.where(np.arange(np.count_nonzero(f == 0)) % 2, 0, 8)
    yield "seam_signed_zero", Mesh(seam, f, source="seam")
    # A cone of 64 sections: apex and base centre of valence 64, past SMALL.
    yield "cone64", from_tm(trimesh.creation.cone(radius=1.0, height=1.0, sections=64), "cone")
    cone = trimesh.creation.cone(radius=1.0, height=1.0, sections=64)
    yield "cone64_open", Mesh(cone.vertices, cone.faces[:-1], source="cone_open")
    yield "cone64_duplicate", Mesh(cone.vertices, np.r_[cone.faces, cone.faces[-1:], cone.faces[-1:, ::-1]],
                                   source="cone_dup")
    yield "degenerate_face", Mesh(box.vertices, np.r_[box.faces, [[0, 0, 1], [1, 0, 1]]],
                                  source="degenerate")
    yield "bunny", geovox.load_mesh(corpus("bunny_watertight", "bunny_oded.obj"))
    yield "suzanne", geovox.load_mesh(corpus("suzanne", "suzanne.obj"))
    yield "joined_tetrahedra", geovox.load_mesh(corpus("trimesh_edge_cases",
                                                       "joined_tetrahedra.obj"))


CHECKS = list(_check_meshes())


@pytest.mark.filterwarnings("ignore::geovox.errors.GeovoxWarning")
@pytest.mark.parametrize("name,mesh", CHECKS, ids=[c[0] for c in CHECKS])
def test_compiled_mesh_checks_answer_as_numpy(name, mesh, kernel, monkeypatch):
    assert _compiled_answers(mesh, kernel, monkeypatch) == _numpy_answers(mesh, monkeypatch)


@pytest.mark.filterwarnings("ignore::geovox.errors.GeovoxWarning")
def test_mesh_check_fixtures_cover_each_answer(kernel, monkeypatch):
    answers = {name: _numpy_answers(mesh, monkeypatch) for name, mesh in CHECKS}
    assert answers["closed_box"][:5] == (True, False, True, True, False)
    assert not answers["open_box"][0] and not answers["flipped_face"][0]
    assert answers["extra_face"][0] is False  # an extra face leaves edges unpaired
    assert answers["duplicate_pair"][:3] == (True, True, False)
    assert answers["cone64_duplicate"][:3] == (True, True, False)
    assert answers["two_apart"][3] is False and answers["two_apart"][4] is False
    assert answers["two_overlapping"][4] is True
    assert answers["shared_edge"][1] is True
    assert answers["seam_signed_zero"][:3] == (True, False, True)
    assert answers["cone64"][:3] == (True, False, True)
    assert answers["degenerate_face"][0] is True  # degenerate edges are no edges


def test_duplicate_faces_in_a_large_bucket(kernel):
    # A closed fan of many faces around one vertex, then the same face twice
    # with its vertices in another order: found past the small-bucket path.
    cone = trimesh.creation.cone(radius=1.0, height=1.0, sections=200)
    f = np.asarray(cone.faces)
    assert not kernel.duplicate_faces(f)
    assert kernel.duplicate_faces(np.r_[f, f[7:8, [2, 0, 1]]])
    assert kernel.duplicate_faces(np.r_[f, f[7:8, ::-1]])


def test_merge_positions_numbers_equal_positions_once(kernel):
    rng = np.random.default_rng(3)
    v = rng.integers(0, 4, size=(500, 3)).astype(np.float64)
    v[rng.random(500) < 0.2] *= -1.0  # some -0.0
    ids = kernel.merge_positions(v)
    # Same number exactly when same position (by value: -0.0 == 0.0).
    same_id = ids[:, None] == ids[None, :]
    same_pos = np.all(v[:, None, :] == v[None, :, :], axis=2)
    assert np.array_equal(same_id, same_pos)
    assert ids.max() + 1 == len(np.unique(v + 0.0, axis=0))


PROJECTION = ("tri", "imin", "imax", "jmin", "jmax", "coef", "tie", "area", "edge_len", "z", "local")


@pytest.mark.parametrize("name,mesh,bounds,n", CASES[:4], ids=[c[0] for c in CASES[:4]])
def test_projection_is_the_same_with_either_kernel(name, mesh, bounds, n, kernel, monkeypatch):
    grid = make_grid(mesh.bounds, bounds=bounds, resolution=n)
    for axis in range(3):
        columns = grid.columns(axis, start=ray_start(mesh, grid, axis))
        got = {}
        for k in ("numpy", "compiled"):
            monkeypatch.setenv("GEOVOX_KERNEL", k)
            got[k] = Projection(mesh.triangles, columns)
        a, b = got["numpy"], got["compiled"]
        assert len(a) > 0 and a.sub_bits == b.sub_bits and a.scale == b.scale
        for f in PROJECTION:
            x, y = getattr(a, f), getattr(b, f)
            assert x.dtype == y.dtype and np.array_equal(x.view(np.uint8), y.view(np.uint8)), f


def test_projection_is_the_same_with_either_kernel_on_a_real_model(kernel, monkeypatch):
    mesh = geovox.load_mesh(corpus("bunny_watertight", "bunny_oded.obj"))
    for res in (16, 200):
        grid = make_grid(mesh.bounds, resolution=res)
        columns = grid.columns(1, start=ray_start(mesh, grid, 1))
        got = {}
        for k in ("numpy", "compiled"):
            monkeypatch.setenv("GEOVOX_KERNEL", k)
            got[k] = Projection(mesh.triangles, columns)
        for f in PROJECTION:
            assert np.array_equal(getattr(got["numpy"], f), getattr(got["compiled"], f)), f


@pytest.mark.parametrize("k", ["numpy", "auto"])
def test_projection_of_vertices_and_faces_is_that_of_the_triangles(k, monkeypatch):
    monkeypatch.setenv("GEOVOX_KERNEL", k)
    mesh = geovox.load_mesh(corpus("suzanne", "suzanne.obj"))
    grid = make_grid(mesh.bounds, resolution=48)
    for axis in range(3):
        columns = grid.columns(axis, start=ray_start(mesh, grid, axis))
        a = Projection(mesh.triangles, columns)
        b = Projection(mesh.vertices, columns, faces=mesh.faces)
        assert len(a) > 0
        for f in PROJECTION:
            assert np.array_equal(getattr(a, f), getattr(b, f)), f
