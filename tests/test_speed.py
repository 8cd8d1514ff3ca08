"""The fast paths of issue 11 give the same results as the plain ones.

No timings here (benchmarks/bench_cli.py measures them): these tests check
that the slab-by-slab fill, the bit-wise chunk transpose, the one-sort
closedness test and the lazy imports change nothing a user can see.
"""

from __future__ import annotations

import collections
import os
import subprocess
import sys

import numpy as np
import pytest

import geovox
import geovox.formats as F
from geovox import inside, parity
from geovox.backends import get_backend
from geovox.formats.chunks import _transpose_binary
from geovox.grid import make_grid
from geovox.mesh import Mesh
from geovox.block import ray_start
from geovox.api import convert_to

from conftest import ROOT, SPOT, box_mesh


@pytest.mark.parametrize("shape,thick", [((16, 24, 150), 64), ((13, 7, 64), 64),
                                         ((9, 16, 33), 7), ((8, 8, 3), 64)])
def test_fill_slabs_equals_fill(shape, thick, backend):
    m = geovox.load_mesh(SPOT)
    g = make_grid(m.bounds, shape=shape)
    cols = g.columns(2, start=ray_start(m, g, 2))
    hits = get_backend(backend).cast(m, cols)
    ref = parity.fill(hits, cols, g)
    got = [(z0, occ.copy()) for z0, occ in parity.fill_slabs(hits, cols, g, thick=thick)]
    assert [z0 for z0, _ in got] == list(range(0, shape[2], thick))
    np.testing.assert_array_equal(np.concatenate([o for _, o in got], axis=2), ref)
    assert ref.any() and not ref.all()


def test_fill_slabs_two_buffers_keep_the_last_slab():
    m = geovox.load_mesh(SPOT)
    g = make_grid(m.bounds, shape=(16, 16, 200))
    cols = g.columns(2, start=ray_start(m, g, 2))
    ref = parity.fill(get_backend("numpy").cast(m, cols), cols, g)
    slabs = parity.fill_slabs(get_backend("numpy").cast(m, cols), cols, g, thick=64, buffers=2)
    last = None
    for z0, occ in slabs:
        if last is not None:  # the slab before is still intact while this one exists
            np.testing.assert_array_equal(last[1], ref[:, :, last[0]:last[0] + last[1].shape[2]])
        last = (z0, occ)
    np.testing.assert_array_equal(last[1], ref[:, :, last[0]:])


@pytest.mark.parametrize("shape", [(64, 64, 64), (8, 3, 5), (16, 64, 1)])
def test_transpose_binary_equals_transpose(shape):
    data = (np.random.default_rng(1).random(shape) < 0.4).astype(np.uint8)
    out = _transpose_binary(data)
    np.testing.assert_array_equal(out, data.transpose(2, 1, 0))
    assert out.flags.c_contiguous


@pytest.mark.parametrize("ext", [".h5", ".raw"])
@pytest.mark.parametrize("shape", [(20, 17, 150), (24, 16, 64)])
def test_one_piece_stream_equals_voxelize(tmp_path, ext, shape, backend):
    ref = geovox.voxelize(SPOT, shape=shape, backend=backend)
    info = convert_to(SPOT, tmp_path / f"s{ext}", shape=shape, backend=backend)
    assert info["slabs"] == 1 and info["inside"] == ref.inside_count
    back = F.read(tmp_path / f"s{ext}")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    if ext == ".h5":
        import h5py

        with h5py.File(tmp_path / f"s{ext}") as f:
            vtk = f["VTKHDF/PointData/occupancy"][...]
        np.testing.assert_array_equal(vtk, ref.occupancy.T.view(np.uint8))


def _open_directed_edges(faces):
    """Reference: directed edges left over after cancelling each against a reversed one."""
    count = collections.Counter()
    for a, b, c in faces:
        for u, v in ((a, b), (b, c), (c, a)):
            if u != v:
                count[(u, v)] += 1
    left = collections.Counter()
    for (u, v), n in count.items():
        net = n - count.get((v, u), 0)
        if net > 0:
            left[(u, v)] = net
    return left


def _cases():
    box = box_mesh((0, 0, 0), (1, 1, 1))
    f = box.faces
    yield "closed box", box
    yield "one face missing", Mesh(box.vertices, f[1:])
    yield "face doubled", Mesh(box.vertices, np.r_[f, f[:1]])
    yield "face doubled both ways", Mesh(box.vertices, np.r_[f, f[:1], f[:1, ::-1]])
    yield "one face flipped", Mesh(box.vertices, np.r_[f[:1, ::-1], f[1:]])
    yield "degenerate face added", Mesh(box.vertices, np.r_[f, [[0, 0, 1]]])
    # A seam: the same positions under other indices are merged.
    v2 = np.r_[box.vertices, box.vertices]
    yield "split seam", Mesh(v2, np.where(np.arange(len(f))[:, None] % 2 == 0, f, f + 8))


@pytest.mark.parametrize("name,mesh", list(_cases()))
def test_closedness_matches_reference(name, mesh):
    ref = _open_directed_edges(mesh.geometric_faces.tolist())
    got = inside.boundary_edges(mesh)
    merged = mesh.geometric_faces.reshape(-1)
    rep = {}
    for g, o in zip(merged, mesh.faces.reshape(-1)):
        rep.setdefault(int(o), int(g))
    got_merged = collections.Counter((rep[int(a)], rep[int(b)]) for a, b in got)
    assert got_merged == ref, name


def test_geometric_faces_number_like_unique():
    rng = np.random.default_rng(3)
    v = rng.integers(0, 3, size=(200, 3)).astype(np.float64)
    v[::7] *= -1.0  # -0.0 and 0.0 are one position
    faces = rng.integers(0, len(v), size=(300, 3))
    _, inverse = np.unique(v, axis=0, return_inverse=True)
    np.testing.assert_array_equal(Mesh(v, faces).geometric_faces, inverse.reshape(-1)[faces])


def _modules_after(code):
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", code + "\nimport sys\nprint(' '.join(sys.modules))"],
                         capture_output=True, text=True, env=env, cwd=ROOT, check=True)
    return set(out.stdout.splitlines()[-1].split())


HEAVY = {"trimesh", "scipy", "h5py", "PIL", "tqdm", "embreex", "isal"}


def test_import_geovox_imports_no_heavy_module():
    mods = _modules_after("import geovox")
    assert not (HEAVY | {"numpy"}) & mods


def test_help_imports_no_heavy_module():
    mods = _modules_after("from geovox.cli import main\ntry:\n    main(['--help'])\n"
                          "except SystemExit:\n    pass")
    assert not (HEAVY | {"numpy"}) & mods


def test_default_convert_to_raw_imports_only_what_it_uses(tmp_path):
    out = tmp_path / "s.raw"
    mods = _modules_after(f"from geovox.cli import main\nassert main(['convert', {SPOT!r}, '-o', "
                          f"{str(out)!r}, '-r', '16', '-q']) == 0")
    assert out.exists()
    assert not HEAVY & mods, HEAVY & mods


def test_streams_whole_only_for_big_occupancy_grids(tmp_path):
    from geovox.grid import Grid
    from geovox.planner import Route, plan
    from geovox.planner import WHOLE_STREAM_VOXELS, streams_whole

    def grid(nx, ny, nz):
        return Grid(np.zeros(3), np.ones(3), (nx, ny, nz))

    # At the threshold and one voxel layer short of it, whatever its value.
    side = 2 * round(WHOLE_STREAM_VOXELS ** (1 / 3) / 2)
    nz = -(-WHOLE_STREAM_VOXELS // (side * side))
    at, short = grid(side, side, nz), grid(side, side, nz - 1)
    assert at.size >= WHOLE_STREAM_VOXELS > short.size and nz - 1 > 64
    assert streams_whole(at) and not streams_whole(short)
    for extra in (dict(color=True), dict(color="fast"), dict(density="coverage"), dict(sdf=True)):
        assert not streams_whole(at, geovox.Options(**extra)), extra
    # 64 layers or fewer are one slice of the fill: nothing to gain.
    flat = grid(-(-WHOLE_STREAM_VOXELS // (64 * 4096)) * 2, 4096, 64)
    assert flat.size >= WHOLE_STREAM_VOXELS and not streams_whole(flat)
    # The plan applies the rule: such a grid to .h5 takes the 64-slice fill,
    # with colour (or below the threshold) it is made in memory.
    m = geovox.load_mesh(SPOT)
    shape = at.shape
    assert plan(m, dict(shape=shape), tmp_path / "a.h5").route == Route.FILL
    assert plan(m, dict(shape=short.shape), tmp_path / "a.h5").route == Route.MEMORY
    assert plan(m, dict(shape=shape), tmp_path / "a.npy").route == Route.MEMORY
    assert plan(m, dict(shape=shape, color="fast"), tmp_path / "a.h5").route != Route.FILL


def test_cli_fills_big_occupancy_in_slabs(tmp_path, capsys, monkeypatch):
    import geovox.planner
    from geovox.cli import main

    # The size threshold lowered, so a small grid takes the big grids' path.
    monkeypatch.setattr(geovox.planner, "streams_whole", lambda grid, *a: True)
    out = tmp_path / "s.h5"
    assert main(["convert", SPOT, "-o", str(out), "--shape", "24", "16", "150"]) == 0
    printed = capsys.readouterr().out
    assert "in 64-slice slabs" in printed and "load " in printed
    ref = geovox.voxelize(SPOT, shape=(24, 16, 150))
    np.testing.assert_array_equal(F.read(out).occupancy, ref.occupancy)
