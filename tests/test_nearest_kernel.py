"""The compiled nearest-surface kernel (geovox/_nearest.pyx) against the NumPy reference.

The kernel must give what :func:`geovox.nearest.search.brute_force` gives -- every
triangle measured with :func:`geovox.nearest.search.closest`'s float64 formula, the
tie rule of :func:`geovox.nearest.search.pick` -- bit for bit: the same triangle and
the same barycentrics for every inside voxel, and so the same colours as the
NumPy search and :func:`geovox.colour.shade`. CI builds the kernel (``pip
install -e .``, gcc is there): these tests fail, not skip, where a C
compiler exists and the kernel was not built.
"""

from __future__ import annotations

import os
import shutil
import sysconfig
import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

import geovox
from geovox.colour import Shading, exact_colours, load_textures, shade
from geovox.kernels import chosen
from geovox.errors import GeovoxWarning, ParameterError
from geovox.mesh import Material, Mesh
from geovox.nearest.search import brute_force, kernel_module, nearest_inside, prepare, run_kernel
from geovox.api import convert_to
import geovox.formats as F

from conftest import SPOT, corpus
from test_colour import write_quadrant_texture, write_tetrahedron, write_two_material_cube


def _have_compiler():
    return bool(shutil.which(sysconfig.get_config_var("CC").split()[0] if sysconfig.get_config_var(
        "CC") else "cc")) and os.path.exists(os.path.join(sysconfig.get_paths()["include"],
                                                          "Python.h"))


@pytest.fixture(scope="module")
def kernel():
    """The compiled module: a failure where it should have been built, a skip elsewhere."""
    try:
        with chosen("compiled"):
            return kernel_module()
    except ParameterError:
        if _have_compiler():
            pytest.fail("a C compiler and Python's headers are here, but geovox._nearest "
                        "was not built (pip install -e . builds it)")
        pytest.skip("no C compiler: the compiled kernel is optional")


def test_the_kernel_is_built_where_a_compiler_exists(kernel):
    assert kernel.__name__ == "geovox._nearest"


def test_kernel_choice_is_checked(monkeypatch):
    with pytest.raises(ParameterError, match="auto, compiled or numpy"), chosen("fast"):
        kernel_module()
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")
    assert kernel_module() is None
    monkeypatch.setenv("GEOVOX_KERNEL", "nonsense")
    with pytest.raises(ParameterError):
        kernel_module()


def _kernel_answers(triangles, occupancy, spacing, origin, z0=0, jobs=1, kernel="compiled"):
    """(tri, uv) of every inside voxel (in argwhere order) from nearest_inside."""
    got = np.full(occupancy.shape, -1, np.int64)
    uv = np.full(occupancy.shape + (2,), np.nan)

    def emit(vox, t, b):
        assert np.all(got[tuple(vox.T)] == -1)  # every voxel once
        got[tuple(vox.T)] = t
        uv[tuple(vox.T)] = b

    with chosen(kernel):
        nearest_inside(triangles, occupancy, spacing, origin=origin, z0=z0, jobs=jobs, emit=emit)
    assert np.all(got[occupancy] >= 0) and np.all(got[~occupancy] == -1)
    idx = np.argwhere(occupancy)
    return got[tuple(idx.T)], uv[tuple(idx.T)]


def _brute(triangles, occupancy, spacing, origin, z0=0):
    idx = np.argwhere(occupancy)
    pts = (idx + [0.5, 0.5, 0.5] + [0, 0, z0]) * spacing
    return brute_force(pts, prepare(np.asarray(triangles, float), origin), float(min(spacing)))


def _check_mesh(mesh, res=None, shape=None, jobs=1):
    vol = geovox.voxelize(mesh, resolution=res, shape=shape)
    args = (mesh.triangles, vol.occupancy, vol.grid.spacing, vol.grid.lo)
    tri, uv = _kernel_answers(*args, jobs=jobs)
    ref_t, ref_uv = _brute(*args)
    np.testing.assert_array_equal(tri, ref_t)
    np.testing.assert_array_equal(uv, ref_uv)  # the same formula: bit for bit
    return vol


@pytest.mark.parametrize("rel,res", [
    ("spot/spot.obj", 14),
    ("fuze/fuze.obj", 18),
    ("suzanne/suzanne.obj", 28),
    ("cornell_box/cornell_box.obj", 32),
    ("trimesh_edge_cases/textured_tetrahedron.obj", 32),
])
def test_every_inside_voxel_is_the_brute_force_answer(kernel, rel, res):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)  # suzanne is open
        mesh = geovox.load_mesh(corpus(*rel.split("/")))
        vol = _check_mesh(mesh, res)
    assert vol.inside_count > 500


def _mesh(m, name):
    return Mesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), source=name)


@pytest.mark.parametrize("name", ["cube", "cube_odd", "sphere", "slab", "sliver", "duplicates",
                                  "coplanar"])
def test_adversarial_fixtures(kernel, name):
    # cube: medial planes through voxel centres (exact ties, smallest index
    # wins); sphere: the centre equidistant from everything; slab: thin, the
    # far side 3 voxels away; sliver: a near-zero-area triangle along the
    # box's edge; duplicates: every face twice (the lower index must win);
    # coplanar: the top face split into many thin triangles.
    if name in ("cube", "cube_odd"):
        mesh, res = _mesh(trimesh.creation.box(extents=(2, 2, 2)), name), (12 if name == "cube"
                                                                           else 9)
    elif name == "sphere":
        mesh, res = _mesh(trimesh.creation.icosphere(subdivisions=2), name), 21
    elif name == "slab":
        mesh, res = _mesh(trimesh.creation.box(extents=(4, 4, 0.3)), name), 40
    else:
        m = trimesh.creation.box(extents=(2, 2, 2))
        v, f = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
        if name == "sliver":
            # A degenerate triangle on an edge of the box (zero area) and a
            # needle nearly on it.
            v = np.r_[v, [[1, 1, 0.0], [1, 1, 1e-7 * 2 - 1]]]
            e = np.flatnonzero((np.abs(v[:, 0] - 1) < 1e-12) & (np.abs(v[:, 1] - 1) < 1e-12))
            f = np.r_[f, [[e[0], e[1], len(v) - 2], [e[0], len(v) - 1, e[1]]]]
        elif name == "duplicates":
            f = np.r_[f, f[::-1]]
        else:
            top = np.linspace(-1, 1, 9)
            v = np.r_[v, np.c_[top, np.full(9, -1.0), np.ones(9)],
                      np.c_[top, np.full(9, 1.0), np.ones(9)]]
            fan = [(len(m.vertices) + i, len(m.vertices) + i + 1, len(m.vertices) + 9 + i)
                   for i in range(8)]
            f = np.r_[f, np.array(fan)]
        mesh, res = Mesh(v, f, source=name), 12
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        _check_mesh(mesh, res)


@pytest.mark.parametrize("limit", [0, 3])
def test_cells_of_2_give_the_same_answers(kernel, limit):
    # Cells of 4 voxels with long lists go down to cells of 2 measured voxel by
    # voxel (rare on real models): forced here, all or most of the time.
    mesh = geovox.load_mesh(corpus("fuze", "fuze.obj"))
    vol = geovox.voxelize(mesh, resolution=20)
    n = vol.occupancy.size
    tri = np.full(n, -1, np.int32)
    uv = np.zeros((n, 2))

    def output(k):
        k.raw_output(tri, uv)
        k.limit_leaf4(limit)

    run_kernel(kernel, mesh.triangles, vol.occupancy, vol.grid.spacing, origin=vol.grid.lo,
               output=output)
    inside = np.argwhere(vol.occupancy)
    lin = np.ravel_multi_index(inside.T, vol.shape, order="F")
    ref_t, ref_uv = _brute(mesh.triangles, vol.occupancy, vol.grid.spacing, vol.grid.lo)
    np.testing.assert_array_equal(tri[lin], ref_t)
    np.testing.assert_array_equal(uv[lin], ref_uv)


def test_the_centre_of_a_cube_goes_to_triangle_0(kernel):
    mesh = _mesh(trimesh.creation.box(extents=(2, 2, 2)), "cube")
    vol = geovox.voxelize(mesh, resolution=9)
    occ = np.zeros_like(vol.occupancy)
    occ[4, 4, 4] = True  # equidistant from all 12 triangles
    tri, _ = _kernel_answers(mesh.triangles, occ, vol.grid.spacing, vol.grid.lo)
    assert tri.tolist() == [0]


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), res=st.integers(5, 26), jobs=st.sampled_from([1, 2, 3]))
def test_random_hulls(kernel, seed, res, jobs):
    # Convex hulls of random, stretched point sets: slivers, needles, many
    # unlike triangles, grids from 5 to 26 voxels.
    rng = np.random.default_rng(seed)
    hull = trimesh.convex.convex_hull(rng.normal(size=(int(rng.integers(5, 40)), 3))
                                      * rng.uniform(0.2, 3.0, size=3))
    # A flat hull on a coarse grid may hold no voxel centre (seed 790 at 5 voxels): an
    # empty volume, said as a warning, with nothing for the search to answer.
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*the volume is empty", category=GeovoxWarning)
        _check_mesh(_mesh(hull, "hull"), res, jobs=jobs)


def test_a_block_of_a_grid_is_the_whole_grids_answers(kernel):
    mesh = geovox.load_mesh(SPOT)
    vol = geovox.voxelize(mesh, shape=(20, 18, 40))
    occ = vol.occupancy
    whole = _kernel_answers(mesh.triangles, occ, vol.grid.spacing, vol.grid.lo)
    tri = np.full(occ.shape, -1)
    uv = np.zeros(occ.shape + (2,))
    for z0, z1 in ((0, 7), (7, 25), (25, 40)):
        block = occ[:, :, z0:z1]
        t, b = _kernel_answers(mesh.triangles, block, vol.grid.spacing, vol.grid.lo, z0=z0,
                               jobs=2)
        idx = np.argwhere(block) + [0, 0, z0]
        tri[tuple(idx.T)] = t
        uv[tuple(idx.T)] = b
    idx = np.argwhere(occ)
    np.testing.assert_array_equal(tri[tuple(idx.T)], whole[0])
    np.testing.assert_array_equal(uv[tuple(idx.T)], whole[1])


def _coloured_meshes(tmp_path):
    """Meshes that use every branch of shade(): textures with each wrap mode, vertex
    colours (replaced by, or tinting, the texture), Ka, undefined and missing materials."""
    out = {}
    obj, _, _ = write_tetrahedron(tmp_path)
    write_quadrant_texture(tmp_path / "quad.png")
    out["tetrahedron"] = geovox.load_mesh(obj)
    out["two_material"] = geovox.load_mesh(write_two_material_cube(tmp_path))
    out["spot"] = geovox.load_mesh(SPOT)
    out["fuze"] = geovox.load_mesh(corpus("fuze", "fuze.obj"))
    # An icosphere with UVs far outside [0, 1], a texture, vertex colours and
    # four materials: repeat, mirror, clamp (tinted by the vertex colours), and
    # one that no file defines; some faces without a material, some without UVs.
    s = trimesh.creation.icosphere(subdivisions=2)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, size=(7, 5, 3), dtype=np.uint8)
    mats = [Material(name="rep", kd=np.array([0.9, 0.5, 0.7]), ka=np.array([0.1, 0.0, 0.2]),
                     image=img, texture_file="x.png"),
            Material(name="mir", image=img, texture_file="x.png", wrap=("mirror", "repeat")),
            Material(name="clamp", image=img[::-1].copy(), texture_file="x.png",
                     wrap=("clamp", "mirror"), vertex_tint=True, ka=np.array([0.3, 0.3, 0.3])),
            Material(name="nowhere", defined=False)]
    fm = rng.integers(-1, 4, size=len(f))
    uv = rng.normal(size=(len(f), 3, 2)) * 3
    uv[rng.random(len(f)) < 0.1] = np.nan
    vc = rng.random((len(v), 3))
    out["sphere_vc"] = Mesh(v, f, source="s", face_material=fm, materials=mats, corner_uv=uv,
                            vertex_colors=vc)
    out["sphere"] = Mesh(v, f, source="s2", face_material=fm, materials=mats, corner_uv=uv)
    out["plain"] = Mesh(v, f, source="s3")
    return out


def _exact(kernel, mesh, vol, shading=Shading()):
    """exact_colours of ``vol``'s inside voxels with the ``kernel`` search."""
    with chosen(kernel):
        return exact_colours(mesh, vol.grid, vol.occupancy, shading=shading)


@pytest.mark.parametrize("opts", [{}, {"diffuse": False, "ambient": True}])
def test_both_kernels_give_the_same_colours(kernel, tmp_path, opts):
    for name, mesh in _coloured_meshes(tmp_path).items():
        load_textures(mesh)
        vol = geovox.voxelize(mesh, resolution=16)
        a = _exact("compiled", mesh, vol, Shading(**opts))
        b = _exact("numpy", mesh, vol, Shading(**opts))
        assert vol.inside_count > 100
        np.testing.assert_array_equal(a, b, err_msg=name)
        if len(mesh.faces) > 400:
            continue  # the corpus models' nearest points are checked above
        # And both are shade() at the brute-force nearest point.
        idx = np.argwhere(vol.occupancy)
        t, uv = _brute(mesh.triangles, vol.occupancy, vol.grid.spacing, vol.grid.lo)
        ref = np.rint(shade(mesh, t, uv, Shading(**opts)) * 255)
        np.testing.assert_array_equal(a[tuple(idx.T)][:, :3], ref, err_msg=name)


def test_colours_do_not_depend_on_jobs_or_slabs(kernel, tmp_path):
    opts = dict(shape=(12, 10, 140), color="exact")
    ref = geovox.voxelize(SPOT, axis=1, jobs=1, **opts)
    for jobs in (2, 3):
        np.testing.assert_array_equal(geovox.voxelize(SPOT, axis=1, jobs=jobs, **opts).colors,
                                      ref.colors)
    info = convert_to(SPOT, tmp_path / "s.h5", budget=12 * 10 * 64 * 22, **opts)
    assert info["slabs"] == 3
    back = F.read(tmp_path / "s.h5")
    np.testing.assert_array_equal(back.colors, ref.colors)


def test_the_numpy_search_is_used_when_asked(monkeypatch, tmp_path):
    # GEOVOX_KERNEL=numpy: the fallback (what an install without a compiler
    # runs) gives the same colours, and is what runs (the compiled run_kernel
    # is never called).
    import geovox.nearest.search as nearest

    ref = geovox.voxelize(SPOT, resolution=16, color="exact")
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")

    def refuse(*a, **k):
        raise AssertionError("the compiled kernel ran")

    monkeypatch.setattr(nearest, "run_kernel", refuse)
    got = geovox.voxelize(SPOT, resolution=16, color="exact")
    np.testing.assert_array_equal(got.colors, ref.colors)


def test_kernel_checks_its_arrays(kernel):
    t = prepare(np.zeros((1, 3, 3)), np.zeros(3))
    occ = np.ones(8, np.uint8)
    k = kernel.Kernel(np.ascontiguousarray(t["crow"].T), t["flat"].view(np.uint8), occ,
                      (2, 2, 2), 0, (1.0, 1.0, 1.0), 1e-6, 1e-9)
    with pytest.raises(ValueError, match="one row per voxel"):
        k.raw_output(np.zeros(7, np.int32), np.zeros((7, 2)))
    with pytest.raises(ValueError, match="no output"):
        k.run(np.zeros((1, 3), np.int64), 3, 1)
    k.raw_output(np.zeros(8, np.int32), np.zeros((8, 2)))
    with pytest.raises(ValueError, match="no clusters"):
        k.run(np.zeros((1, 3), np.int64), 3, 1)
    with pytest.raises(ValueError, match="bad clusters"):
        k.clusters(t["lo"], t["hi"], t["lo"], t["hi"], np.zeros(1, np.int64),
                   np.zeros(1, np.int64), t["lo"])
    with pytest.raises(ValueError, match="size does not match"):
        kernel.Kernel(np.ascontiguousarray(t["crow"].T), t["flat"].view(np.uint8), occ,
                      (2, 2, 3), 0, (1.0, 1.0, 1.0), 1e-6, 1e-9)
    # run_kernel with nothing inside does nothing.
    run_kernel(kernel, np.zeros((1, 3, 3)), np.zeros((2, 2, 2), bool), np.ones(3),
               origin=np.zeros(3), output=lambda k: None)


def test_cli_color_is_exact_and_fast_color_is_the_crossings(tmp_path):
    from geovox.cli import main

    path = corpus("fuze", "fuze.obj")
    got = {}
    for flag in ("--color", "--exact-color", "--fast-color", "--fast-colour"):
        out = tmp_path / f"t{flag}.npz"
        assert main(["convert", path, "-r", "16", flag, "-q", "-o", str(out)]) == 0
        got[flag] = np.load(out)["colors"]
    exact = geovox.voxelize(path, resolution=16, color="exact")
    fast = geovox.voxelize(path, resolution=16, color="fast")
    np.testing.assert_array_equal(got["--color"], exact.colors)
    np.testing.assert_array_equal(got["--exact-color"], exact.colors)
    np.testing.assert_array_equal(got["--fast-color"], fast.colors)
    np.testing.assert_array_equal(got["--fast-colour"], fast.colors)
    np.testing.assert_array_equal(geovox.voxelize(path, resolution=16, color=True).colors,
                                  exact.colors)
    assert not np.array_equal(exact.colors, fast.colors)  # deep voxels differ
    assert main(["convert", path, "--color", "--fast-color", "-o", str(tmp_path / "x.npz")]) == 2


def _sphere_with(material, uv_scale, uv_shift):
    s = trimesh.creation.icosphere(subdivisions=2)
    v, f = np.asarray(s.vertices, float), np.asarray(s.faces, np.int64)
    rng = np.random.default_rng(7)
    uv = rng.random((len(f), 3, 2)) * uv_scale + uv_shift
    return Mesh(v, f, source="s", face_material=np.zeros(len(f), np.int64),
                materials=[material], corner_uv=uv)


def test_border_wrap_mode(kernel):
    # MTL `-clamp on` ("border", from main's materials work): sampled as
    # clamp on the texture, untextured (Kd alone) off it.
    import geovox.colour.shading as colour

    img = np.random.default_rng(3).integers(0, 256, size=(6, 9, 3), dtype=np.uint8)
    kd = np.array([0.5, 0.25, 1.0])

    def colours(mesh):
        vol = geovox.voxelize(mesh, resolution=12)
        return vol, _exact("compiled", mesh, vol)

    # All UVs off the texture: every inside voxel is Kd.
    off = _sphere_with(Material(kd=kd, image=img, texture_file="x.png", wrap=("border", "border")),
                       0.5, 1.2)
    vol, got = colours(off)
    np.testing.assert_array_equal(got[vol.occupancy][:, :3],
                                  np.broadcast_to(np.rint(kd * 255), (vol.inside_count, 3)))
    # All on it: the same as clamp.
    on = _sphere_with(Material(kd=kd, image=img, texture_file="x.png", wrap=("border", "border")),
                      0.8, 0.1)
    clamp = _sphere_with(Material(kd=kd, image=img, texture_file="x.png", wrap=("clamp", "clamp")),
                         0.8, 0.1)
    np.testing.assert_array_equal(colours(on)[1], colours(clamp)[1])
    if hasattr(colour, "on_texture"):  # NumPy's shade knows "border" (main since 2026-11-30)
        mixed = _sphere_with(Material(kd=kd, image=img, texture_file="x.png",
                                      wrap=("border", "repeat")), 1.6, -0.3)
        vol = geovox.voxelize(mixed, resolution=16)
        np.testing.assert_array_equal(_exact("compiled", mixed, vol), _exact("numpy", mixed, vol))


def test_a_material_the_kernel_does_not_know_is_shaded_by_numpy(kernel, monkeypatch):
    # A wrap mode the tables have no code for: the NumPy search and shade()
    # colour the voxels instead of a wrong or failed kernel run.
    import geovox.colour.shading as colour

    mesh = _sphere_with(Material(image=np.zeros((4, 4, 3), np.uint8), texture_file="x.png",
                                 wrap=("spiral", "repeat")), 1.0, 0.0)
    assert colour.shading_tables(mesh) is None
    import geovox.colour.exact as exact

    def refuse(*a, **k):
        raise AssertionError("the compiled kernel ran")

    monkeypatch.setattr(exact, "run_kernel", refuse)
    monkeypatch.setattr(colour, "_texel_axis", lambda t, n, mode: colour_axis(t, n))
    vol = geovox.voxelize(mesh, resolution=10)
    got = exact_colours(mesh, vol.grid, vol.occupancy)
    assert np.all(got[vol.occupancy][:, 3] == 255)


def colour_axis(t, n):
    """A stand-in _texel_axis for a made-up wrap mode: texel 0 always."""
    z = np.zeros(len(t), np.int64)
    return z, z, np.zeros(len(t))


@pytest.mark.parametrize("jobs", [1, 4])
def test_a_failed_allocation_on_any_thread_is_an_error(kernel, jobs):
    # A cell whose lists could not be allocated leaves its voxels unanswered:
    # that must raise, whichever thread met it (a prange's plain assignment to
    # the flag kept only the value of the thread that ran the last cell).
    mesh = geovox.load_mesh(corpus("fuze", "fuze.obj"))
    vol = geovox.voxelize(mesh, resolution=64)
    n = vol.occupancy.size
    tri = np.full(n, -1, np.int32)
    uv = np.zeros((n, 2))

    def output(k):
        k.raw_output(tri, uv)
        k.fail_allocation_at(0)  # the first top cell, not the last one

    with pytest.raises(MemoryError, match="could not allocate"):
        run_kernel(kernel, mesh.triangles, vol.occupancy, vol.grid.spacing,
                   origin=vol.grid.lo, jobs=jobs, output=output)


def _colour_in_child():
    vol = geovox.voxelize(corpus("fuze", "fuze.obj"), resolution=24, color=True, jobs=2)
    os._exit(0 if (vol.colors[..., 3][vol.occupancy] == 255).all() else 1)


def test_a_process_forked_after_the_kernel_ran_on_threads_does_not_hang(kernel):
    # GNU OpenMP is not fork-safe: a child forked after the parent started
    # the kernel's threads hung at its first parallel region (a batch's
    # process pool after a colour run in the same process).
    import multiprocessing

    geovox.voxelize(corpus("fuze", "fuze.obj"), resolution=24, color=True, jobs=2)
    child = multiprocessing.get_context("fork").Process(target=_colour_in_child)
    child.start()
    child.join(60)
    if child.is_alive():
        child.kill()
        child.join()
        pytest.fail("the forked child hung in the compiled kernel")
    assert child.exitcode == 0


def test_the_source_distribution_carries_the_kernel_source(tmp_path):
    # setup.py cythonizes geovox/_nearest.pyx; setuptools puts only the
    # generated .c in an sdist by itself, and installing that sdist failed
    # ("'geovox/_nearest.pyx' doesn't match any files"). MANIFEST.in adds it.
    import subprocess
    import sys
    import tarfile

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    if not os.path.exists(os.path.join(root, "setup.py")):
        pytest.skip("not run from a source tree")
    subprocess.run([sys.executable, "setup.py", "-q", "sdist", "-d", str(tmp_path)], cwd=root,
                   check=True, capture_output=True)
    (archive,) = tmp_path.glob("*.tar.gz")
    with tarfile.open(archive) as tar:
        names = tar.getnames()
    assert any(n.endswith("/geovox/_nearest.pyx") for n in names)
    assert any(n.endswith("/MANIFEST.in") for n in names)


def _kernel_colours(kernel, mesh, vol, key, key_rgba):
    """The compiled colour search by hand, with ``key_rgba`` as the constant colours."""
    from geovox.colour.shading import shading_tables

    g = vol.grid
    flat = np.zeros(vol.occupancy.size, np.uint32)

    def output(k):
        k.colour_output(flat, *shading_tables(mesh))
        k.same_colours(key, key_rgba)

    run_kernel(kernel, mesh.triangles, vol.occupancy, g.spacing, origin=g.lo, output=output)
    return flat.reshape(vol.occupancy.shape, order="F")


@pytest.mark.parametrize("name,res", [("cornell_box", 40), ("two_material", 24), ("sphere", 24)])
def test_cells_of_one_constant_colour_skip_the_search(kernel, tmp_path, name, res):
    # Where every triangle left in a cell has the same constant colour, the
    # kernel gives the cell that colour without finding the nearest one.
    # Marked constant colours (alpha 0: no shaded colour has it) show where
    # it did: there, the nearest triangle's own key; elsewhere, the shaded
    # colour of the nearest point. And with the true constant colours, the
    # answer is the shaded nearest point everywhere (the NumPy search's).
    from geovox.colour.shading import constant_colours

    if name == "cornell_box":
        mesh = geovox.load_mesh(corpus("cornell_box", "cornell_box.obj"))
    else:
        mesh = _coloured_meshes(tmp_path)[name]
    load_textures(mesh)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)  # cornell_box is open: winding number
        vol = geovox.voxelize(mesh, resolution=res)
    key, key_rgba = constant_colours(mesh)
    assert (key >= 0).any()
    occ = vol.occupancy
    tri, uv = _kernel_answers(mesh.triangles, occ, vol.grid.spacing, vol.grid.lo)
    shaded = np.rint(shade(mesh, tri, uv) * 255).astype(np.uint8)
    with chosen("compiled"):
        got = exact_colours(mesh, vol.grid, occ)
    np.testing.assert_array_equal(got[occ][:, :3], shaded)
    with chosen("numpy"):
        np.testing.assert_array_equal(got, exact_colours(mesh, vol.grid, occ))
    marks = np.arange(1, len(key_rgba) + 1, dtype=np.uint32)  # alpha byte 0
    marked = _kernel_colours(kernel, mesh, vol, key, marks)[occ]
    skipped = (marked >> 24) == 0
    true = got[occ].copy().view(np.uint32).reshape(-1)
    np.testing.assert_array_equal(marked[skipped], marks[key[tri[skipped]]])
    np.testing.assert_array_equal(marked[~skipped], true[~skipped])
    # It does happen: in most of the box's volume, in some of the cube's (the
    # sphere's faces take materials at random: neighbours seldom share one).
    least = {"cornell_box": 0.5, "two_material": 0.05, "sphere": 0.0}[name]
    assert skipped.mean() >= least, skipped.mean()
    # Outside, nothing is written.
    assert not _kernel_colours(kernel, mesh, vol, key, marks)[~occ].any()


def test_the_kernel_checks_its_constant_colours(kernel):
    occ = np.ones(8, np.uint8)
    k = kernel.Kernel(np.zeros((1, 21)), np.zeros(1, np.uint8), occ, (2, 2, 2), 0,
                      (1.0, 1.0, 1.0), 1e-6, 1e-9)
    with pytest.raises(ValueError, match="colour output"):
        k.same_colours(np.zeros(1, np.int64), np.zeros(1, np.uint32))
    k.colour_output(np.zeros(8, np.uint32), np.zeros(1, np.int32), None, None, np.ones((1, 3)),
                    np.zeros((1, 3)), np.zeros((1, 7), np.int32), np.zeros(1, np.int64),
                    np.zeros(1, np.uint8))
    with pytest.raises(ValueError, match="one entry per face"):
        k.same_colours(np.zeros(2, np.int64), np.zeros(1, np.uint32))
    with pytest.raises(ValueError, match="beyond"):
        k.same_colours(np.ones(1, np.int64), np.zeros(1, np.uint32))
    k.same_colours(np.zeros(1, np.int64), np.zeros(1, np.uint32))


@pytest.mark.parametrize("shape,p", [((37, 5, 70), 0.01), ((16, 16, 16), 0.5), ((1, 1, 1), 1.0),
                                     ((100, 3, 33), 0.001), ((65, 64, 63), 0.2)])
def test_top_cells_are_the_cells_holding_an_inside_voxel(kernel, shape, p):
    # The kernel's scan skips the rest of a cell's run once it is marked.
    occ = np.random.default_rng(len(shape) + int(1000 * p)).random(shape) < p
    flat = np.ascontiguousarray(occ.reshape(-1, order="F")).view(np.uint8)
    for level in (0, 1, 3, 5):
        s = 1 << level
        pad = [(0, -n % s) for n in shape]
        cells = np.pad(occ, pad).reshape(
            [n for k in shape for n in (-(-k // s), s)]).any(axis=(1, 3, 5))
        np.testing.assert_array_equal(kernel.top_cells(flat, shape, level, 2).astype(bool), cells)


def _raw_run(kernel, triangles, occ, spacing, lo, setup=lambda k: None, jobs=1):
    """(tri, uv) of the inside voxels (argwhere order) from the kernel, ``setup(k)`` first."""
    n = occ.size
    tri = np.full(n, -1, np.int32)
    uv = np.zeros((n, 2))

    def output(k):
        k.raw_output(tri, uv)
        setup(k)

    run_kernel(kernel, triangles, occ, spacing, origin=lo, jobs=jobs, output=output)
    lin = np.ravel_multi_index(np.argwhere(occ).T, occ.shape, order="F")
    return tri[lin], uv[lin]


@pytest.mark.parametrize("rel,res", [("spot/spot.obj", 24), ("fuze/fuze.obj", 20)])
@pytest.mark.parametrize("level", [0, 2, 3])
def test_cells_finished_by_tangent_planes(kernel, rel, res, level):
    # Cells of 2**level voxels finish by the tangent planes of their
    # candidates at the centre (leaf_planes; 2 is the default, 3 has bounds
    # four times as loose sideways, 0 never: the interpolated corners of
    # leaf4): the brute-force answers bit for bit either way, and the NumPy
    # search's.
    mesh = geovox.load_mesh(corpus(*rel.split("/")))
    vol = geovox.voxelize(mesh, resolution=res)
    args = (mesh.triangles, vol.occupancy, vol.grid.spacing, vol.grid.lo)
    tri, uv = _raw_run(kernel, *args, setup=lambda k: k.planes_at(level), jobs=2)
    ref_t, ref_uv = _brute(*args)
    np.testing.assert_array_equal(tri, ref_t)
    np.testing.assert_array_equal(uv, ref_uv)
    num_t, num_uv = _kernel_answers(*args, kernel="numpy")
    np.testing.assert_array_equal(tri, num_t)
    np.testing.assert_array_equal(uv, num_uv)


def _grid_frame(n, h=0.25):
    return np.full(3, h), np.zeros(3), np.ones((n, n, n), bool)


@pytest.mark.parametrize("plane", [2.0, 2.5, 2.0 + 1e-12])
def test_one_triangle_and_centres_on_its_plane(kernel, plane):
    # One triangle (every cell's list is that one), and a second, parallel
    # one, in the plane through cell centres (x = 2 voxel sizes: the centre
    # of every 4-voxel cell at i = 0..3, where the distance is 0 and the
    # tangent plane has no direction), through voxel centres, and just off
    # the cells' centres (a direction from rounding alone): every voxel's
    # answer is the brute force's.
    spacing, lo, occ = _grid_frame(12)
    x = plane * spacing[0]
    big = np.array([[[x, -5.0, -5.0], [x, 9.0, -5.0], [x, -5.0, 9.0]]])
    tri, uv = _raw_run(kernel, big, occ, spacing, lo)
    assert (tri == 0).all()
    np.testing.assert_array_equal(uv, _brute(big, occ, spacing, lo)[1])
    two = np.concatenate([big, big + [2.3 * spacing[0], 0, 0]])
    tri, uv = _raw_run(kernel, two, occ, spacing, lo)
    ref = _brute(two, occ, spacing, lo)
    np.testing.assert_array_equal(tri, ref[0])
    np.testing.assert_array_equal(uv, ref[1])
    assert set(np.unique(tri)) == {0, 1}


def test_tied_candidates_in_a_cell(kernel):
    # A fan of triangles around one vertex, each twice (indices below k: the
    # fan in reverse order; from k: the same triangles again): near the
    # vertex every triangle of the fan ties, and everywhere a copy ties its
    # original; the lowest index must win, as brute force and the NumPy
    # search say.
    spacing, lo, occ = _grid_frame(16)
    c = np.array([2.0, 2.0, 2.0])  # the middle of the grid, on voxel corners
    k = 7
    ring = [c + [1.5 * np.cos(a), 1.5 * np.sin(a), -1.0]
            for a in np.linspace(0, 2 * np.pi, k, endpoint=False)]
    fan = np.array([[c, ring[i], ring[(i + 1) % k]] for i in range(k)])
    tris = np.concatenate([fan[::-1], fan])
    tri, uv = _raw_run(kernel, tris, occ, spacing, lo)
    ref_t, ref_uv = _brute(tris, occ, spacing, lo)
    np.testing.assert_array_equal(tri, ref_t)
    np.testing.assert_array_equal(uv, ref_uv)
    assert (tri < k).all()  # never the second copy
    num_t, num_uv = _kernel_answers(tris, occ, spacing, lo, kernel="numpy")
    np.testing.assert_array_equal(tri, num_t)
    np.testing.assert_array_equal(uv, num_uv)
