"""Property-based tests (hypothesis) on random closed meshes, grids and inputs."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import geovox  # noqa: E402
from geovox.errors import GeovoxError  # noqa: E402

# Random regions may miss the mesh; that warning is tested elsewhere.
pytestmark = pytest.mark.filterwarnings("ignore::geovox.errors.GeovoxWarning")

SETTINGS = settings(max_examples=25, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])


@st.composite
def closed_meshes(draw):
    kind = draw(st.sampled_from(["hull", "box", "sphere"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**31)))
    if kind == "hull":
        m = trimesh.convex.convex_hull(rng.normal(size=(draw(st.integers(5, 40)), 3)))
    elif kind == "box":
        m = trimesh.creation.box(extents=rng.uniform(0.2, 2.0, 3))
    else:
        m = trimesh.creation.icosphere(subdivisions=draw(st.integers(0, 2)),
                                       radius=float(rng.uniform(0.3, 2.0)))
    m.apply_translation(rng.uniform(-1, 1, 3))
    return geovox.Mesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64), source=kind)


@st.composite
def grids(draw, mesh):
    lo, hi = mesh.bounds
    ext = hi - lo
    shape = tuple(draw(st.integers(1, 20)) for _ in range(3))
    if draw(st.booleans()):
        return {"shape": shape}
    a = lo + ext * np.array([draw(st.floats(-0.3, 0.6)) for _ in range(3)])
    b = a + ext * np.array([draw(st.floats(0.1, 1.2)) for _ in range(3)])
    return {"shape": shape, "bounds": np.r_[a, b]}


needs_two = pytest.mark.skipif(len(geovox.available_backends()) < 2, reason="needs both backends")


@needs_two
@SETTINGS
@given(data=st.data())
def test_backends_agree_on_random_closed_meshes(data):
    mesh = data.draw(closed_meshes())
    kw = data.draw(grids(mesh))
    axis = data.draw(st.integers(0, 2))
    a = geovox.voxelize(mesh, backend="numpy", axis=axis, inside="parity", **kw)
    b = geovox.voxelize(mesh, backend="embree", axis=axis, inside="parity", **kw)
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@SETTINGS
@given(data=st.data())
def test_no_inside_voxel_outside_the_mesh_box(data):
    mesh = data.draw(closed_meshes())
    kw = data.draw(grids(mesh))
    vol = geovox.voxelize(mesh, inside="parity", **kw)
    lo, hi = mesh.bounds
    for a in range(3):
        c = vol.grid.centres(a)
        outside = (c < lo[a]) | (c > hi[a])
        idx = [slice(None)] * 3
        idx[a] = outside
        assert not vol.occupancy[tuple(idx)].any()


@SETTINGS
@given(seed=st.integers(0, 2**31), shift=st.tuples(*[st.integers(-20, 20)] * 3),
       n=st.integers(4, 24))
def test_translating_by_whole_voxels_translates_the_volume(seed, shift, n):
    # Dyadic coordinates make every translation exact in floating point.
    rng = np.random.default_rng(seed)
    pts = rng.integers(-16, 17, (12, 3)) / 8.0
    try:
        m = trimesh.convex.convex_hull(pts)
    except Exception:
        return
    if m.volume <= 0:
        return
    mesh = geovox.Mesh(np.asarray(m.vertices, float), np.asarray(m.faces, np.int64))
    h = 4.0 / n if n in (4, 8, 16) else 0.25
    lo = np.array([-2.0, -2.0, -2.0])
    shape = (int(round(4.0 / h)),) * 3
    t = np.asarray(shift) * h
    moved = geovox.Mesh(mesh.vertices + t, mesh.faces)
    a = geovox.voxelize(mesh, shape=shape, bounds=np.r_[lo, lo + 4.0], inside="parity")
    b = geovox.voxelize(moved, shape=shape, bounds=np.r_[lo + t, lo + t + 4.0], inside="parity")
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.one_of(
    st.binary(max_size=400),
    st.lists(st.sampled_from(["v 0 0 0", "v 1 2", "v nan 1 1", "f 1 2 3", "f 1 2", "f -1 -2 -3",
                              "f 0 1 2", "f 1/1 2/2 3/3", "vt 0.5", "usemtl x", "mtllib y.mtl",
                              "f 1//1 2//2 3//3", "v 1e400 0 0", "#", "", "o a", "f 4 5 6 7"]),
             max_size=30).map(lambda lines: "\n".join(lines).encode()),
))
def test_obj_reader_only_raises_geovox_errors(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("fuzz") / "m.obj"
    path.write_bytes(data)
    try:
        geovox.voxelize(str(path), resolution=3)
    except GeovoxError:
        pass
