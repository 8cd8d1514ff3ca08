"""One way to do a block: ``voxelize_block`` on slabs of a grid gives the whole grid's volume."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import geovox
from geovox.errors import ParameterError
from geovox.grid import make_grid
from geovox.io.load import load_mesh
from geovox.options import Options
from geovox.planner import Route, plan
from geovox.block import block_grid, voxelize_block

from conftest import SPOT


@pytest.mark.parametrize("inside", ["parity", "vote"])
def test_blocks_put_together_are_the_whole_grid(inside, backend):
    opts = dict(color=True, density="coverage", supersample=2, sdf=True, band=1.0)
    m = load_mesh(SPOT)
    # A region reaching below the mesh on y, and blocks of uneven thickness
    # (a block need not be 64-aligned).
    grid = make_grid(m.bounds, shape=(14, 12, 37),
                     bounds=np.r_[m.bounds[0] - [0.0, 0.1, 0.0], m.bounds[1]])
    ref = geovox.voxelize(m, shape=grid.shape, bounds=np.r_[grid.lo, grid.hi], axis=1,
                          backend=backend, inside=inside, jobs=1, **opts)
    p = plan(m, Options(shape=grid.shape, bounds=np.r_[grid.lo, grid.hi], backend=backend,
                        inside=inside, axis=1, jobs=1, **opts))
    assert p.grid.shape == grid.shape and np.array_equal(p.grid.lo, grid.lo)
    parts = [voxelize_block(m, p, b) for b in [(0, 5), (5, 20), (20, 37)]]
    assert [p.occupancy.shape[2] for p in parts] == [5, 15, 17]
    np.testing.assert_allclose(parts[-1].grid.hi, grid.hi, rtol=0, atol=0)
    join = {k: np.concatenate([getattr(p, k) for p in parts], axis=2)
            for k in ("occupancy", "colors", "density", "sdf")}
    assert ref.inside_count > 0
    np.testing.assert_array_equal(join["occupancy"], ref.occupancy)
    np.testing.assert_array_equal(join["colors"], ref.colors)
    # A block's voxel centres are computed from its own low face: density may
    # round one step apart, distances differ in the last bits.
    assert np.abs(join["density"].astype(int) - ref.density.astype(int)).max() <= 1
    np.testing.assert_allclose(join["sdf"], ref.sdf, rtol=1e-5, atol=1e-7)


def test_whole_grid_block_is_voxelize(backend):
    m = load_mesh(SPOT)
    p = plan(m, Options(resolution=20, backend=backend, color=True))
    vol = voxelize_block(m, p)
    ref = geovox.voxelize(m, resolution=20, backend=backend, color=True)
    grid = p.grid
    assert vol.grid is grid and block_grid(grid, (0, 20)) is grid
    np.testing.assert_array_equal(vol.occupancy, ref.occupancy)
    np.testing.assert_array_equal(vol.colors, ref.colors)
    assert vol.inside == ref.inside == "parity"


@pytest.mark.parametrize("block", [(0, 0), (-1, 3), (5, 21), (7, 3)])
def test_bad_block_is_refused(block):
    grid = make_grid(np.array([[0, 0, 0], [1, 1, 1.0]]), resolution=20)
    with pytest.raises(ParameterError, match="0 <= z0 < z1 <= 20"):
        block_grid(grid, block)


def test_batch_streams_by_the_cli_rule(tmp_path, monkeypatch):
    import geovox.formats as F
    import geovox.runners as runners
    from geovox.batch import convert_many

    calls = []
    real = runners.run_slabs
    monkeypatch.setattr(runners, "run_slabs", lambda m, p, **k: calls.append(p) or real(m, p, **k))
    opts = dict(shape=(16, 16, 150))
    [r] = convert_many([SPOT], tmp_path / "mem", **opts)  # one slab: in memory
    assert r.status == "ok" and calls == []
    import geovox.planner
    monkeypatch.setattr(geovox.planner, "SLAB_BUDGET", 16 * 16 * 64)  # three slabs: streamed
    [s] = convert_many([SPOT], tmp_path / "slabs", **opts)
    assert s.status == "ok" and len(calls) == 1
    assert calls[0].route == Route.SLABS and calls[0].blocks == ((0, 64), (64, 128), (128, 150))
    ref = geovox.voxelize(SPOT, axis=1, **opts)  # several slabs cast along y
    np.testing.assert_array_equal(F.read(s.output).occupancy, ref.occupancy)
    monkeypatch.setattr(geovox.planner, "SLAB_BUDGET", 1 << 30)
    monkeypatch.setattr(geovox.planner, "streams_whole", lambda grid, *a: True)  # one piece, streamed
    [w] = convert_many([SPOT], tmp_path / "whole", **opts)
    assert len(calls) == 2 and calls[1].route == Route.FILL
    assert Path(w.output).read_bytes() == Path(r.output).read_bytes()
