"""The WebGPU backend: exact like the others, on any adapter (lavapipe on CI).

Skipped with a reason where ``wgpu`` is missing or no adapter exists; CI
installs both (``.ci/run``: ``geovox[gpu]`` and Debian's mesa-vulkan-drivers).
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
import trimesh

import geovox
from geovox.backends import get_backend
from geovox.cli import main
from geovox.errors import BackendUnavailableError, GeovoxWarning
from geovox.exact import Projection
from geovox.grid import Grid, make_grid
from geovox.mesh import Mesh
from geovox.block import ray_start

from conftest import SPOT, box_mesh, corpus, from_tm
from test_backends import CLOSED_CORPUS, SYNTHETIC, t_junction_box

# With both a Vulkan and an OpenGL driver installed, wgpu can list the same
# device twice; the tests run on Vulkan where that is the platform's API.
if sys.platform.startswith("linux"):
    os.environ.setdefault("WGPU_BACKEND_TYPE", "Vulkan")

W = pytest.importorskip("geovox.backends.webgpu")


def _adapter_or_skip():
    pytest.importorskip("wgpu", reason="the `gpu` extra (wgpu) is not installed")
    try:
        return W.adapter()
    except BackendUnavailableError as exc:
        pytest.skip(f"no WebGPU adapter here: {exc}")


@pytest.fixture(scope="module")
def gpu():
    a = _adapter_or_skip()
    info = a.info
    # Never the OpenGL path the backend avoids; Vulkan on Linux.
    assert info["backend_type"] in ("Vulkan", "Metal", "D3D12")
    if sys.platform.startswith("linux"):
        assert info["backend_type"] == "Vulkan"
    return get_backend("webgpu")


def _hits_table(hits):
    """Hits as rows sorted by (ray, triangle): order-free comparison."""
    order = np.lexsort((hits.triangle, hits.ray))
    return (hits.ray[order], hits.triangle[order], hits.depth[order], hits.bary[order])


def _same_hits(a, b):
    for x, y in zip(_hits_table(a), _hits_table(b)):
        np.testing.assert_array_equal(x, y)  # exact: same integers, same float64 bits


# --- the emulated 64-bit arithmetic -----------------------------------------

def test_int64_emulation_carries_and_signs(gpu):
    # add64 and positive, run on the device over pairs chosen to carry out
    # of the low half, borrow through zero and sit on the sign boundaries.
    import wgpu

    edges = [0, 1, -1, 2, -2, 0xFFFFFFFF, 0x100000000, -0x100000000, 0x7FFFFFFF, 0x80000000,
             -0x80000000, (1 << 59) + 0xFFFFFFFF, -(1 << 59) - 1, (1 << 62) - 1, -(1 << 62)]
    rng = np.random.default_rng(3)
    a = np.array([x for x in edges for _ in edges] + list(rng.integers(-(1 << 61), 1 << 61, 4000)),
                 np.int64)
    b = np.array([y for _ in edges for y in edges] + list(rng.integers(-(1 << 61), 1 << 61, 4000)),
                 np.int64)
    # And long chains of +1 / -1 steps around zero and around 2**32 (as the
    # search steps along a row).
    a = np.r_[a, np.arange(-300, 300), np.arange(-300, 300) + (1 << 32)].astype(np.int64)
    b = np.r_[b, np.ones(600, np.int64), -np.ones(600, np.int64)]
    n = len(a)
    code = W.WGSL_INT64 + """
@group(0) @binding(0) var<storage, read> inp: array<u32>;
@group(0) @binding(1) var<storage, read_write> res: array<u32>;
@compute @workgroup_size(64)
fn main(@builtin(global_invocation_id) gid: vec3<u32>) {
    let k = gid.x;
    if (k >= arrayLength(&inp) / 4u) { return; }
    let x = vec2<u32>(inp[4u * k], inp[4u * k + 1u]);
    let y = vec2<u32>(inp[4u * k + 2u], inp[4u * k + 3u]);
    let s = add64(x, y);
    res[4u * k] = s.x;
    res[4u * k + 1u] = s.y;
    res[4u * k + 2u] = select(0u, 1u, positive(x));
    res[4u * k + 3u] = select(0u, 1u, positive(s));
}
"""
    device, _ = W._device()
    inp = np.stack([a, b], 1).view(np.uint32)
    src = device.create_buffer_with_data(data=inp, usage=wgpu.BufferUsage.STORAGE)
    dst = device.create_buffer(size=n * 16, usage=wgpu.BufferUsage.STORAGE | wgpu.BufferUsage.COPY_SRC)
    pipe = device.create_compute_pipeline(
        layout="auto", compute={"module": device.create_shader_module(code=code), "entry_point": "main"})
    bind = device.create_bind_group(layout=pipe.get_bind_group_layout(0), entries=[
        {"binding": 0, "resource": {"buffer": src}}, {"binding": 1, "resource": {"buffer": dst}}])
    enc = device.create_command_encoder()
    cp = enc.begin_compute_pass()
    cp.set_pipeline(pipe)
    cp.set_bind_group(0, bind)
    cp.dispatch_workgroups(-(-n // 64))
    cp.end()
    device.queue.submit([enc.finish()])
    out = np.frombuffer(device.queue.read_buffer(dst), np.uint32).reshape(n, 4)
    total = out[:, :2].copy().view(np.int64)[:, 0]
    np.testing.assert_array_equal(total, a + b)  # no operand pair here overflows int64
    np.testing.assert_array_equal(out[:, 2] == 1, a > 0)
    np.testing.assert_array_equal(out[:, 3] == 1, a + b > 0)


# --- the search against the exact int64 reference ---------------------------

def test_one_triangle_covering_the_whole_lattice(gpu):
    # 300 x 300 columns inside one triangle: 90,000 candidates, past the
    # 65,535 loop iterations after which llvmpipe silently stops an
    # invocation. Tiling must keep every invocation under it.
    tri = np.array([[-10.0, -10.0, 0.5], [40.0, -10.0, 0.5], [-10.0, 40.0, 0.5]])
    mesh = Mesh(tri, np.array([[0, 1, 2]]))
    grid = Grid(np.zeros(3), np.array([10.0, 10.0, 1.0]), (300, 300, 1))
    cols = grid.columns(2, start=-1.0)
    hits = gpu.cast(mesh, cols)
    assert len(hits) == 300 * 300
    np.testing.assert_array_equal(np.sort(hits.ray), np.arange(300 * 300))
    np.testing.assert_array_equal(hits.depth, 0.5)


def test_output_is_chunked_past_one_binding(gpu, monkeypatch):
    # A square of two triangles over 1,500 x 1,500 columns: each triangle's
    # bounding box is the whole lattice, so the tiles' summed area (4.5
    # million) exceeds the 4,194,304 crossings one 128 MiB binding holds.
    # Every ray crosses exactly one of the two (the shared diagonal is
    # settled by the tie rule), and the hits equal the NumPy backend's.
    v = np.array([[0, 0, 0.25], [1, 0, 0.25], [1, 1, 0.75], [0, 1, 0.75]], float)
    mesh = Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]))
    n = 1500
    grid = Grid(np.zeros(3), np.ones(3), (n, n, 1))
    cols = grid.columns(2, start=-1.0)
    calls = []
    chunks = W._chunks
    monkeypatch.setattr(W, "_chunks", lambda *a: calls.extend(chunks(*a)) or iter(calls))
    hits = gpu.cast(mesh, cols)
    assert len(calls) >= 2
    assert len(hits) == n * n
    assert np.all(np.bincount(hits.ray, minlength=n * n) == 1)
    proj = Projection(mesh.triangles, cols)
    w = proj.edge_values(proj.local[hits.triangle], hits.ray % n, hits.ray // n)
    assert np.all(w > 0)


def test_small_chunks_give_the_same_crossings(gpu, monkeypatch):
    # Many dispatches of at most 1,000 crossings each, and buffers reused
    # across calls of different sizes.
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=70)
    cols = grid.columns(0, start=ray_start(mesh, grid, 0))
    proj = Projection(mesh.triangles, cols)
    many = W.search(proj, max_hits=1000)
    np.testing.assert_array_equal(W.search(proj), many)
    _same_hits(W.to_hits(proj, many, jobs=2), get_backend("numpy").cast(mesh, cols))


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_hits_equal_the_numpy_backend_bit_for_bit(gpu, axis):
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=57)
    cols = grid.columns(axis, start=ray_start(mesh, grid, axis))
    _same_hits(gpu.cast(mesh, cols, jobs=2), get_backend("numpy").cast(mesh, cols))


def test_casts_from_several_threads(gpu):
    # The colour step casts two axes at once from two threads: the device
    # buffers are shared, so searches must not interleave.
    from concurrent.futures import ThreadPoolExecutor

    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=45)
    cols = [grid.columns(a, start=ray_start(mesh, grid, a)) for a in (0, 1, 2, 0, 1, 2)]
    with ThreadPoolExecutor(max_workers=3) as pool:
        got = list(pool.map(lambda c: gpu.cast(mesh, c, jobs=2), cols))
    for c, hits in zip(cols, got):
        _same_hits(hits, get_backend("numpy").cast(mesh, c))


def test_crossings_come_in_the_same_order_every_run(gpu):
    mesh = geovox.load_mesh(SPOT)
    grid = make_grid(mesh.bounds, resolution=64)
    cols = grid.columns(2, start=ray_start(mesh, grid, 2))
    proj = Projection(mesh.triangles, cols)
    first = W.search(proj)
    np.testing.assert_array_equal(first, W.search(proj))
    np.testing.assert_array_equal(first, W.search(proj, max_hits=2000))
    # Tile order: by active triangle.
    assert np.all(np.diff(first[:, 0] >> 32) >= 0)


@pytest.mark.parametrize("spread", [1.0, 3e4])
def test_triangle_soup_on_column_centres(gpu, spread):
    # Vertices exactly on column centres (so edges run through centres and
    # ties are everywhere), and with spread=3e4 triangles reaching far past
    # the lattice, whose edge values fill the high halves and carry often.
    rng = np.random.default_rng(int(spread))
    n = 48
    grid = Grid(np.zeros(3), np.array([n, n, 1.0]), (n, n, 1))
    cols = grid.columns(2, start=-1e6)
    c = rng.integers(0, n, (300, 3, 2)) + 0.5
    c[::3] = (c[::3] - n / 2) * spread + n / 2  # every third triangle huge
    tris = np.concatenate([c, rng.random((300, 3, 1))], axis=2)
    mesh = Mesh(tris.reshape(-1, 3), np.arange(900).reshape(-1, 3))
    _same_hits(gpu.cast(mesh, cols), get_backend("numpy").cast(mesh, cols))


def test_random_meshes_and_lattices_give_the_numpy_hits(gpu):
    # Property test: triangles with coordinates on a coarse set of values
    # (many on column centres and edges, many shared), random lattices and
    # axes; the crossings must equal the NumPy backend's bit for bit.
    hypothesis = pytest.importorskip("hypothesis")
    from hypothesis import given, settings
    from hypothesis import strategies as st

    coord = st.integers(-4, 12).map(lambda k: k / 4)
    tri = st.tuples(*[st.tuples(coord, coord, st.floats(-2, 2))] * 3)

    @settings(max_examples=25, deadline=None, derandomize=True)
    @given(st.lists(tri, min_size=1, max_size=30), st.integers(1, 13), st.integers(1, 13),
           st.integers(0, 2))
    def check(tris, nu, nv, axis):
        t = np.array(tris, float)[:, :, [2, 0, 1]] if axis == 0 else np.array(tris, float)
        if axis == 1:
            t = t[:, :, [0, 2, 1]]
        mesh = Mesh(t.reshape(-1, 3), np.arange(3 * len(t)).reshape(-1, 3))
        shape = [4, 4, 4]
        shape[[a for a in range(3) if a != axis][0]] = nu
        shape[[a for a in range(3) if a != axis][1]] = nv
        grid = Grid(np.zeros(3), np.full(3, 2.0), tuple(shape))
        cols = grid.columns(axis, start=-10.0)
        _same_hits(gpu.cast(mesh, cols), get_backend("numpy").cast(mesh, cols))

    check()


# --- volumes against the NumPy backend ---------------------------------------

def _both(mesh, **kw):
    return [geovox.voxelize(mesh, backend=b, **kw) for b in ("numpy", "webgpu")]


@pytest.mark.parametrize("name,mesh", SYNTHETIC, ids=[s[0] for s in SYNTHETIC])
@pytest.mark.parametrize("res", [1, 2, 31, 96])
@pytest.mark.parametrize("axis", [0, 2])
@pytest.mark.filterwarnings("ignore:.*the volume is empty:geovox.errors.GeovoxWarning")
def test_agrees_with_numpy_on_adversarial_meshes(gpu, name, mesh, res, axis):
    a, b = _both(mesh, resolution=res, axis=axis, inside="parity")
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@pytest.mark.parametrize("name,rel", CLOSED_CORPUS, ids=[c[0] for c in CLOSED_CORPUS])
@pytest.mark.parametrize("res", [17, 64])
def test_agrees_with_numpy_on_corpus(gpu, name, rel, res):
    a, b = _both(corpus(rel), resolution=res)
    assert a.inside_count > 0
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@pytest.mark.parametrize("rel", ["suzanne/suzanne.obj", "trimesh_edge_cases/wallhole.obj",
                                 "cornell_box/cornell_box.obj"])
@pytest.mark.filterwarnings("ignore:.*the volume is empty:geovox.errors.GeovoxWarning")
@pytest.mark.filterwarnings("ignore:.*of a repaired:geovox.errors.GeovoxWarning")
def test_agrees_with_numpy_on_open_models(gpu, rel):
    # Not closed: the winding test casts the mesh with its holes capped.
    a, b = _both(corpus(rel), resolution=40, inside="winding")
    np.testing.assert_array_equal(a.occupancy, b.occupancy)


@pytest.mark.parametrize("seed", range(4))
def test_agrees_with_numpy_on_boxes_with_centres_on_faces(gpu, seed):
    # Box faces exactly on voxel centres and edges on column centres.
    rng = np.random.default_rng(seed)
    lo = rng.integers(0, 5, 3).astype(float)
    hi = lo + rng.integers(1, 6, 3)
    mesh = box_mesh(lo - 0.5, hi - 0.5, diagonals="alternate" if seed % 2 else "same")
    for axis in range(3):
        a, b = _both(mesh, shape=(12, 12, 12), bounds=(-1, -1, -1, 11, 11, 11), axis=axis,
                     inside="parity")
        np.testing.assert_array_equal(a.occupancy, b.occupancy)


@pytest.mark.parametrize("inside", ["parity", "winding"])
def test_agrees_with_numpy_through_t_junctions(gpu, inside):
    mesh = t_junction_box()
    for res in range(1, 40, 3):
        a, b = _both(mesh, shape=(res, res, 4), bounds=(0, 0, -0.5, 1, 1, 1.5), inside=inside)
        np.testing.assert_array_equal(a.occupancy, b.occupancy, err_msg=str(res))


def test_colours_density_and_distance_equal_numpy(gpu):
    kw = dict(resolution=28, color=True, density="coverage", sdf=True)
    a, b = _both(corpus("fuze", "fuze.obj"), **kw)
    np.testing.assert_array_equal(a.occupancy, b.occupancy)
    np.testing.assert_array_equal(a.colors, b.colors)
    np.testing.assert_array_equal(a.density, b.density)
    np.testing.assert_array_equal(a.sdf, b.sdf)


def test_empty_region_and_no_triangles(gpu):
    tor = from_tm(trimesh.creation.torus(major_radius=1.0, minor_radius=0.3), "torus")
    with pytest.warns(GeovoxWarning):
        vol = geovox.voxelize(tor, resolution=8, bounds=(5, 5, 5, 6, 6, 6), backend="webgpu")
    assert vol.inside_count == 0


# --- CLI and errors -----------------------------------------------------------

def test_backends_command_shows_the_adapter(gpu, capsys):
    assert main(["backends"]) == 0
    line = [x for x in capsys.readouterr().out.splitlines() if x.startswith("webgpu")]
    info = W.adapter().info
    assert len(line) == 1 and "available" in line[0]
    assert info["device"] in line[0] and info["backend_type"] in line[0]
    assert info["adapter_type"] in line[0]


def test_convert_with_webgpu(gpu, tmp_path, capsys):
    out = tmp_path / "spot.raw"
    assert main(["convert", SPOT, "-o", str(out), "-r", "24", "--backend", "webgpu", "-q"]) == 0
    ref = geovox.voxelize(SPOT, resolution=24, backend="numpy")
    raw = np.fromfile(out, np.uint8).reshape(ref.shape, order="F")
    np.testing.assert_array_equal(raw == 255, ref.occupancy)


def test_no_adapter_is_one_line_naming_the_driver(monkeypatch, capsys, tmp_path):
    pytest.importorskip("wgpu")

    class NoAdapters:
        @staticmethod
        def enumerate_adapters_sync():
            return []

    import wgpu

    monkeypatch.setattr(wgpu, "gpu", NoAdapters())
    monkeypatch.setattr(W, "_state", {})
    monkeypatch.setattr("geovox.backends._instances", {})
    out = tmp_path / "x.raw"
    assert main(["convert", SPOT, "-o", str(out), "-r", "8", "--backend", "webgpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "no GPU adapter" in err[0] and "Vulkan" in err[0] and "mesa-vulkan-drivers" in err[0]
    assert not out.exists()
    assert "missing" in W.describe() and "mesa-vulkan-drivers" in W.describe()


def test_device_failure_is_one_line(gpu, monkeypatch, capsys, tmp_path):
    import wgpu

    def fail(*args):
        raise wgpu.GPUOutOfMemoryError("Out of memory\n  more detail")

    monkeypatch.setattr(W, "_dispatch", fail)
    assert main(["convert", SPOT, "-o", str(tmp_path / "x.raw"), "-r", "8",
                 "--backend", "webgpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["geovox: error: backend 'webgpu' failed on the device (GPUOutOfMemoryError: "
                   "Out of memory); use --backend numpy"]


def test_no_wgpu_is_one_line_naming_the_package(monkeypatch, capsys, tmp_path):
    from geovox import backends

    monkeypatch.setitem(sys.modules, "wgpu", None)
    monkeypatch.setattr(backends, "_instances", {})
    monkeypatch.setattr(W, "_state", {})
    assert main(["convert", SPOT, "-o", str(tmp_path / "x.raw"), "-r", "8",
                 "--backend", "webgpu"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'wgpu'" in err[0] and "pip install" in err[0]
    assert "missing" in W.describe() and "geovox[gpu]" in W.describe()
    with pytest.raises(BackendUnavailableError, match="wgpu"):
        get_backend("webgpu")
