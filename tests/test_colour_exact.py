"""Exact colour (``color="exact"``): every inside voxel against a brute-force nearest point.

The reference here tries every triangle for every inside voxel (no pruning,
its own closest-point code, broadcasting points against blocks of
triangles) and applies the documented tie rule: of the triangles within
1e-9 voxel sizes of the smallest distance, the smallest index. A voxel where
two *different* surface points are that close to equidistant is a near-tie:
counted, shown to be rare, and not held to the colour check.
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
import trimesh
from hypothesis import given, settings
from hypothesis import strategies as st

import geovox
from geovox.colour import Shading, load_textures, shade
from geovox.kernels import chosen
from geovox.errors import GeovoxWarning
from geovox.mesh import Mesh
from geovox.nearest.search import TIE, nearest_inside
from geovox.api import convert_to
import geovox.formats as F

from conftest import SPOT, corpus
from test_colour import write_quadrant_texture, write_tetrahedron, write_two_material_cube


def reference_nearest(triangles, points, h, block=64):
    """Brute force: nearest triangle, barycentrics and near-tie flag of each point.

    Every triangle is measured against every point, a block of triangles at
    a time; the candidates within rounding of the smallest distance are then
    measured again with Ericson's closest point, and the tie rule applied.

    Parameters
    ----------
    triangles : (t, 3, 3) float64
    points : (n, 3) float64
    h : float
        Voxel size (the tie rule's unit).

    Returns
    -------
    tri : (n,) int64
        Smallest index among the triangles within TIE * h of the nearest.
    bary : (n, 2) float64
        Weights of vertices 1 and 2 of the closest point on ``tri``.
    dist : (n,) float64
    tie : (n,) bool
        Another triangle within TIE * h has its closest point elsewhere
        (farther than 1e-6 voxel sizes from the chosen one).
    """
    n, nt = len(points), len(triangles)
    d2 = np.empty((n, nt), np.float32)  # kept to find the candidates afterwards
    best = np.full(n, np.inf)
    for s in range(0, nt, block):
        d = _distance_sq(points, triangles[s:s + block])
        d2[:, s:s + block] = d
        np.minimum(best, d.min(axis=1), out=best)
    dmin = np.sqrt(best)
    # Candidates: within float32 rounding (and the tie) of the smallest.
    lim = (dmin * (1 + 1e-5) + 2 * TIE * h) ** 2
    pi, ti = np.nonzero(d2 <= lim[:, None])
    q = _closest_points(points[pi], triangles[ti])
    dq = np.linalg.norm(q - points[pi], axis=1)
    exact_min = np.full(n, np.inf)
    np.minimum.at(exact_min, pi, dq)
    near = dq <= exact_min[pi] + TIE * h
    # Pairs are in point-then-triangle order: the first near one per point wins.
    first = np.full(n, -1)
    w = np.flatnonzero(near)[::-1]
    first[pi[w]] = w
    tri = ti[first]
    qbest = q[first]
    tie = np.zeros(n, bool)
    apart = near & (np.linalg.norm(q - qbest[pi], axis=1) > 1e-6 * h)
    tie[pi[apart]] = True
    bary = trimesh.triangles.points_to_barycentric(triangles[tri], qbest)[:, 1:]
    return tri, bary, exact_min, tie


def _distance_sq(p, T):
    """(n, k) squared distance of each point to each triangle: face, or nearest edge."""
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    ab, ac, bc = b - a, c - a, c - b
    nrm = np.cross(ab, ac)
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
    # In-plane coordinates from the dual basis of (ab, ac).
    g = np.linalg.pinv(np.stack([ab, ac], axis=2))  # (k, 2, 3)
    ap = [p[:, None, i] - a[None, :, i] for i in range(3)]

    def dot(u, v):  # u: list of (n, k) components, v: (k, 3)
        return u[0] * v[:, 0] + u[1] * v[:, 1] + u[2] * v[:, 2]

    s = dot(ap, g[:, 0])
    t = dot(ap, g[:, 1])
    face = (s >= 0) & (t >= 0) & (s + t <= 1)
    out = np.where(face, dot(ap, nrm) ** 2, np.inf)
    for start, e in ((ap, ab), (ap, ac), ([ap[i] - ab[:, i] for i in range(3)], bc)):
        w = np.clip(dot(start, e) / np.einsum("ij,ij->i", e, e), 0, 1)
        d = sum((start[i] - w * e[:, i]) ** 2 for i in range(3))
        out = np.minimum(out, d)
    return out


def _closest_points(p, T):
    """(m, 3) closest point on triangle ``T[i]`` to point ``p[i]`` (Ericson 5.1.5)."""
    a, b, c = T[:, 0], T[:, 1], T[:, 2]
    ab, ac, ap = b - a, c - a, p - a

    def dot(x, y):
        return np.sum(x * y, axis=-1, keepdims=True)

    d1, d2 = dot(ab, ap), dot(ac, ap)
    bp = p - b
    d3, d4 = dot(ab, bp), dot(ac, bp)
    cp = p - c
    d5, d6 = dot(ab, cp), dot(ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        denom = 1.0 / (va + vb + vc)
        out = a + ab * (vb * denom) + ac * (vc * denom)
        # Regions, later ones taking precedence in Ericson's order.
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        out = np.where((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0), b + t * (c - b), out)
        t = d2 / (d2 - d6)
        out = np.where((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + t * ac, out)
        out = np.where((d6 >= 0) & (d5 <= d6), c, out)
        t = d1 / (d1 - d3)
        out = np.where((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + t * ab, out)
        out = np.where((d3 >= 0) & (d4 <= d3), b, out)
        out = np.where((d1 <= 0) & (d2 <= 0), a, out)
    return out


def _centres(vol, idx):
    return np.stack([vol.grid.centres(a)[idx[:, a]] for a in range(3)], axis=1)


def _check_against_reference(path_or_mesh, res, exact_ties=False, **kw):
    """Colours of every inside voxel against the reference.

    Near-ties are exempt but must be rare (under 1 %), unless
    ``exact_ties``: shapes built with symmetric planes have many exact ties
    (medial planes through voxel centres), all settled by the same tie rule,
    so every voxel is checked.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)  # suzanne is open: repaired, and said so
        vol = geovox.voxelize(path_or_mesh, resolution=res, color="exact", backend="numpy", **kw)
    mesh = geovox.load_mesh(path_or_mesh)
    idx = np.argwhere(vol.occupancy)
    h = float(min(vol.spacing))
    load_textures(mesh)
    tri, bary, dist, tie = reference_nearest(mesh.triangles, _centres(vol, idx), h)
    ref = np.rint(shade(mesh, tri, bary, Shading(**kw)) * 255)
    got = vol.colors[tuple(idx.T)]
    assert np.all(got[:, 3] == 255)
    err = np.abs(got[:, :3].astype(int) - ref).max(axis=1)
    bad = (err > 2) & (exact_ties | ~tie)
    assert not bad.any(), (f"{bad.sum()} of {len(idx)} voxels off by up to {err[bad].max()} levels "
                           f"(first at {idx[bad][0]}, {dist[bad][0] / h:.2f} voxels deep)")
    if not exact_ties:
        assert tie.mean() < 0.01, tie.mean()
    return vol, err, tie


@pytest.mark.parametrize("rel,res", [
    ("spot/spot.obj", 24),
    ("fuze/fuze.obj", 28),
    ("suzanne/suzanne.obj", 32),
    ("cornell_box/cornell_box.obj", 40),
])
def test_every_inside_voxel_matches_brute_force(rel, res):
    vol, err, tie = _check_against_reference(corpus(rel), res)
    assert vol.inside_count > 1000


def test_textured_tetrahedron_and_two_material_box(tmp_path):
    obj, _, _ = write_tetrahedron(tmp_path)
    write_quadrant_texture(tmp_path / "quad.png")
    _check_against_reference(obj, 40, exact_ties=True)
    _check_against_reference(write_two_material_cube(tmp_path), 32, exact_ties=True, ambient=True)


def test_corpus_textured_tetrahedron():
    _check_against_reference(corpus("trimesh_edge_cases", "textured_tetrahedron.obj"), 40,
                             exact_ties=True)


def _nearest_triangles(mesh, res, kernel="auto"):
    """Nearest triangle of every inside voxel, from nearest_inside, and the reference."""
    vol = geovox.voxelize(mesh, resolution=res)
    got = np.full(vol.shape, -1)
    uv = np.zeros(vol.shape + (2,))

    def emit(vox, t, b):
        assert np.all(got[tuple(vox.T)] == -1)  # every voxel once
        got[tuple(vox.T)] = t
        uv[tuple(vox.T)] = b

    with chosen(kernel):
        nearest_inside(mesh.triangles, vol.occupancy, vol.grid.spacing, origin=vol.grid.lo,
                       emit=emit)
    idx = np.argwhere(vol.occupancy)
    assert np.all(got[vol.occupancy] >= 0) and np.all(got[~vol.occupancy] == -1)
    ref = reference_nearest(mesh.triangles, _centres(vol, idx), float(min(vol.spacing)))
    return got[tuple(idx.T)], uv[tuple(idx.T)], ref


def _l_prism():
    """A closed L-shaped prism (concave), 12 vertices."""
    outline = np.array([[0, 0], [3, 0], [3, 1], [1, 1], [1, 3], [0, 3.0]])
    v = np.r_[np.c_[outline, np.zeros(6)], np.c_[outline, np.ones(6)]]
    caps = [(0, 2, 1), (0, 3, 2), (0, 5, 3), (3, 5, 4)]
    faces = [f for f in caps] + [(a + 6, c + 6, b + 6) for a, b, c in caps]
    for i in range(6):
        j = (i + 1) % 6
        faces += [(i, j, j + 6), (i, j + 6, i + 6)]
    return Mesh(v, np.array(faces), source="L")


@pytest.mark.parametrize("name", ["slab", "sphere", "L", "cube"])
def test_adversarial_shapes_pick_the_reference_triangle(name):
    if name == "slab":  # thin: the far side is 3 voxels away everywhere
        m = trimesh.creation.box(extents=(4, 4, 0.3))
    elif name == "sphere":  # the centre is equidistant from everything
        m = trimesh.creation.icosphere(subdivisions=2)
    elif name == "cube":  # medial planes: exact ties
        m = trimesh.creation.box(extents=(2, 2, 2))
    if name == "L":
        mesh = _l_prism()
    else:
        mesh = Mesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), source=name)
    got, uv, (tri, bary, dist, tie) = _nearest_triangles(mesh, 24 if name != "slab" else 40)
    assert np.all((got == tri) | tie)
    same = got == tri
    np.testing.assert_allclose(uv[same], bary[same], atol=1e-9)
    if name in ("cube", "L"):
        # Centres on the medial planes are exact ties between faces,
        # settled the same way: the smallest triangle index.
        assert tie.sum() > 0
        np.testing.assert_array_equal(got, tri)
    else:
        assert tie.mean() < 0.01


def test_cube_medial_ties_go_to_the_smallest_triangle():
    m = trimesh.creation.box(extents=(2, 2, 2))
    mesh = Mesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), source="cube")
    got, _, (tri, _, dist, _) = _nearest_triangles(mesh, 9)
    np.testing.assert_array_equal(got, tri)
    # The centre voxel is equidistant from all 12 triangles: triangle 0 wins.
    vol = geovox.voxelize(mesh, resolution=9)
    centre = np.flatnonzero((np.argwhere(vol.occupancy) == 4).all(axis=1))
    assert got[centre] == 0


@pytest.mark.skipif(len(geovox.available_backends()) < 2, reason="needs both backends")
def test_backends_give_the_same_exact_colours():
    a = geovox.voxelize(corpus("fuze", "fuze.obj"), resolution=32, color="exact", backend="numpy")
    b = geovox.voxelize(corpus("fuze", "fuze.obj"), resolution=32, color="exact", backend="embree")
    np.testing.assert_array_equal(a.occupancy, b.occupancy)
    np.testing.assert_array_equal(a.colors, b.colors)


def test_exact_colours_do_not_depend_on_jobs():
    one = geovox.voxelize(SPOT, resolution=24, color="exact", jobs=1)
    three = geovox.voxelize(SPOT, resolution=24, color="exact", jobs=3)
    np.testing.assert_array_equal(one.colors, three.colors)


def test_slab_by_slab_exact_colours_equal_the_whole_grid(tmp_path):
    opts = dict(shape=(12, 10, 140), color="exact")
    ref = geovox.voxelize(SPOT, axis=1, **opts)  # slabs cast along y
    info = convert_to(SPOT, tmp_path / "s.h5", budget=12 * 10 * 64 * 22, **opts)
    assert info["slabs"] == 3
    back = F.read(tmp_path / "s.h5")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    np.testing.assert_array_equal(back.colors, ref.colors)


def test_cli_exact_color(tmp_path):
    from geovox.cli import main

    out = tmp_path / "t.npz"
    assert main(["convert", corpus("fuze", "fuze.obj"), "-r", "16", "--exact-color", "-q",
                 "-o", str(out)]) == 0
    d = np.load(out)
    ref = geovox.voxelize(corpus("fuze", "fuze.obj"), resolution=16, color="exact")
    np.testing.assert_array_equal(d["colors"], ref.colors)


def test_a_region_that_cuts_the_mesh_and_unequal_voxels():
    # The cut face's voxels take the colour of the nearest surface point,
    # which may lie outside the region; voxels are not cubes here.
    m = geovox.load_mesh(SPOT)
    lo, hi = m.bounds
    mid = (lo + hi) / 2
    bounds = (*lo, hi[0], hi[1], mid[2])
    vol = geovox.voxelize(SPOT, shape=(14, 22, 11), bounds=bounds, color="exact")
    load_textures(m)
    idx = np.argwhere(vol.occupancy)
    h = float(min(vol.spacing))
    tri, bary, _, tie = reference_nearest(m.triangles, _centres(vol, idx), h)
    ref = np.rint(shade(m, tri, bary) * 255)
    err = np.abs(vol.colors[tuple(idx.T)][:, :3].astype(int) - ref).max(axis=1)
    assert len(idx) > 300 and not np.any((err > 2) & ~tie)


def test_colour_option_is_checked():
    with pytest.raises(geovox.ParameterError, match="`color` must be"):
        geovox.voxelize(SPOT, resolution=8, color="exactly")


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), res=st.integers(6, 24))
def test_random_hulls_pick_the_reference_triangle(seed, res):
    # Convex hulls of random points: many unlike triangles, slivers among them.
    rng = np.random.default_rng(seed)
    hull = trimesh.convex.convex_hull(rng.normal(size=(int(rng.integers(5, 40)), 3))
                                      * rng.uniform(0.2, 3.0, size=3))
    mesh = Mesh(np.asarray(hull.vertices, float), np.asarray(hull.faces, np.int64), source="hull")
    # The NumPy search (tests/test_nearest_kernel.py checks the compiled one).
    got, uv, (tri, bary, dist, tie) = _nearest_triangles(mesh, res, kernel="numpy")
    assert np.all((got == tri) | tie)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), squash=st.sampled_from([1.0, 1e-2, 1e-4]))
def test_lower_bound_is_below_the_distance_and_exact_on_acute_triangles(seed, squash):
    # The pruning bound (plane, then the half-strip along each edge): never
    # above the exact distance, whatever the triangle (obtuse, needles,
    # slivers by ``squash``), and equal to it on acute triangles, vertex
    # regions included (so ties and near-ties are measured, and little else).
    from geovox.nearest.search import lower_bound_sq, prepare
    rng = np.random.default_rng(seed)
    T = rng.normal(size=(200, 3, 3)) * rng.uniform(0.1, 3.0, size=(200, 1, 3))
    T[:, :, 2] *= squash
    p = rng.normal(size=(200, 3)) * 3
    tris = prepare(T, np.zeros(3))
    low = lower_bound_sq(p, np.arange(200), tris)
    exact = np.diagonal(_distance_sq(p, T)).copy()
    ok = ~tris["flat"]
    assert np.all(low[ok] <= exact[ok] * (1 + 1e-9) + 1e-12)
    assert np.all(low[~ok] == 0)
    # Acute: every vertex angle below 89 degrees.
    e = [T[:, (k + 1) % 3] - T[:, k] for k in range(3)]
    cos = [np.einsum("ij,ij->i", -e[k - 1], e[k])
           / np.linalg.norm(e[k - 1], axis=1) / np.linalg.norm(e[k], axis=1) for k in range(3)]
    acute = ok & (np.min(cos, axis=0) > np.cos(np.radians(89)))
    assert acute.sum() > 5
    np.testing.assert_allclose(low[acute], exact[acute], rtol=1e-9, atol=1e-12)


def test_small_chunks_never_split_a_voxels_candidates(monkeypatch):
    # Pairs are handled CHUNK at a time; a cell can hold more than that, and
    # the last step must still see every candidate of a voxel at once (with
    # chunks of 64 pairs, splitting them coloured voxels from a partial list).
    import geovox.nearest.search as nearest
    monkeypatch.setattr(nearest, "CHUNK", 64)
    monkeypatch.setenv("GEOVOX_KERNEL", "numpy")  # chunks are the NumPy search's
    _check_against_reference(SPOT, 16)


@pytest.mark.parametrize("kd", [None, (0.2, 0.4, 0.6)])
def test_one_colour_over_the_whole_surface_needs_no_search(monkeypatch, kd):
    # An uncoloured mesh (the default grey) or one untextured material: every
    # inside voxel takes that colour at once, the same as the search gives.
    import geovox.colour.exact as C
    from geovox.mesh import Material

    box = trimesh.creation.icosphere(subdivisions=2)
    mesh = Mesh(vertices=np.asarray(box.vertices), faces=np.asarray(box.faces))
    if kd is not None:
        mesh.materials = [Material(name="m", kd=np.array(kd))]
        mesh.face_material = np.zeros(len(mesh.faces), np.int64)
    fast = geovox.voxelize(mesh, resolution=24, color="exact")
    expect = (204, 204, 204) if kd is None else (51, 102, 153)
    inside = fast.occupancy
    assert inside.sum() > 1000
    assert (fast.colors[inside] == expect + (255,)).all() and (fast.colors[~inside] == 0).all()
    called = []

    def no_shortcut(*a, **k):  # every face "varies": the search runs
        called.append(1)
        return np.full(len(mesh.faces), -1, np.int64), np.zeros(0, np.uint32)

    monkeypatch.setattr(C, "constant_colours", no_shortcut)
    searched = geovox.voxelize(mesh, resolution=24, color="exact")
    assert called
    np.testing.assert_array_equal(searched.colors, fast.colors)


def _coloured_sphere(scale):
    m = trimesh.creation.icosphere(2)
    m.apply_scale(scale)
    rng = np.random.default_rng(0)
    return Mesh(m.vertices, m.faces, vertex_colors=rng.random((len(m.vertices), 3)),
                source="sphere")


@pytest.mark.parametrize("kernel", ["numpy", "auto"])
@pytest.mark.parametrize("scale", [1e100, 1e-100])
def test_exact_colour_refuses_lengths_its_formulas_cannot_hold(monkeypatch, kernel, scale):
    # Fourth powers of 1e100 overflow and of 1e-100 underflow: wrong nearest
    # points (from 1e150 the distances were NaN: the NumPy search left every
    # inside voxel uncoloured, the compiled one read before its buffers).
    monkeypatch.setenv("GEOVOX_KERNEL", kernel)
    with pytest.raises(geovox.errors.ParameterError, match="exact colour needs lengths"):
        geovox.voxelize(_coloured_sphere(scale), resolution=8, color=True)


def test_exact_colour_holds_wide_scales(monkeypatch):
    ref = geovox.voxelize(_coloured_sphere(1.0), resolution=10, color=True).colors
    for scale in (1e50, 1e-50):
        vol = geovox.voxelize(_coloured_sphere(scale), resolution=10, color=True)
        np.testing.assert_array_equal(vol.colors, ref)


def test_cli_exact_colour_of_a_huge_mesh_is_one_line(tmp_path, capsys):
    from geovox.cli import main

    m = _coloured_sphere(1e100)
    lines = [f"v {x:.17g} {y:.17g} {z:.17g} {r:.3f} {g:.3f} {b:.3f}"
             for (x, y, z), (r, g, b) in zip(m.vertices, m.vertex_colors)]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in m.faces]
    (tmp_path / "huge.obj").write_text("\n".join(lines) + "\n")
    out = tmp_path / "huge.npz"
    assert main(["convert", str(tmp_path / "huge.obj"), "-o", str(out), "--color", "-r", "8",
                 "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("geovox: error: exact colour needs lengths")
    assert "Traceback" not in "\n".join(err)
    assert not out.exists()


@pytest.mark.parametrize("ext", [".raw", ".h5"])
def test_slab_writes_on_a_thread_equal_the_whole_grid_and_fail_cleanly(tmp_path, monkeypatch, ext):
    # Exact colour writes each slab on a thread while the next is computed:
    # the file equals the whole grid, and a failed write (the disk full at
    # the second slab) stops the conversion and leaves no file behind.
    import errno

    from geovox.errors import OutputError

    opts = dict(shape=(12, 10, 140), color="exact")
    ref = geovox.voxelize(SPOT, axis=1, **opts)
    info = convert_to(SPOT, tmp_path / f"s{ext}", budget=12 * 10 * 64 * 22, jobs=2, **opts)
    assert info["slabs"] == 3
    back = F.read(tmp_path / f"s{ext}")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    np.testing.assert_array_equal(back.colors, ref.colors)

    writer = {".raw": "geovox.formats.raw.RawWriter", ".h5": "geovox.formats.hdf5.HDF5Writer"}[ext]
    module, name = writer.rsplit(".", 1)
    cls = getattr(__import__(module, fromlist=[name]), name)
    original, calls = cls.write, []

    def full_at_second(self, z0, vol):
        calls.append(z0)
        if len(calls) == 2:
            raise OSError(errno.ENOSPC, "No space left on device")
        return original(self, z0, vol)

    monkeypatch.setattr(cls, "write", full_at_second)
    out = tmp_path / "full"
    out.mkdir()
    with pytest.raises((OutputError, OSError)):
        convert_to(SPOT, out / f"s{ext}", budget=12 * 10 * 64 * 22, jobs=2, **opts)
    assert len(calls) == 2 and os.listdir(out) == []
