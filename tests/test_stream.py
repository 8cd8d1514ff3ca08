"""Slab-by-slab conversion: the file equals the one made in one piece."""

from __future__ import annotations

import numpy as np
import pytest

import geovox
import geovox.formats as F
from geovox.cli import main
from geovox.api import convert_to
from geovox.planner import slab_plan

from conftest import SPOT


def test_slab_plan_is_chunk_aligned():
    grid = geovox.grid.make_grid(np.array([[0, 0, 0], [1, 1, 1.0]]), shape=(100, 90, 300))
    plan = slab_plan(grid, 1.0, budget=100 * 90 * 130)
    assert plan == [(0, 128), (128, 256), (256, 300)]
    assert slab_plan(grid, 1.0, budget=1e12) == [(0, 300)]


@pytest.mark.parametrize("ext", [".h5", ".raw"])
def test_streamed_file_equals_in_memory_volume(tmp_path, ext, backend):
    opts = dict(shape=(16, 16, 150), color=True, density="coverage", supersample=2, sdf=True, band=1)
    ref = geovox.voxelize(SPOT, backend=backend, axis=1, **opts)  # several slabs cast along y
    info = convert_to(SPOT, tmp_path / f"s{ext}", budget=16 * 16 * 64 * 40, backend=backend, **opts)
    assert info["slabs"] == 3 and info["inside"] == ref.inside_count
    back = F.read(tmp_path / f"s{ext}")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    np.testing.assert_array_equal(back.colors, ref.colors)
    # A slab's coordinates are its own: density may round one step apart,
    # distances differ in the last bits.
    assert np.abs(back.density.astype(int) - ref.density.astype(int)).max() <= 1
    np.testing.assert_allclose(back.sdf, ref.sdf, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(back.spacing, ref.spacing)


def test_streamed_hdf5_opens_in_vtk(tmp_path):
    hdf = pytest.importorskip("vtkmodules.vtkIOHDF")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    ref = geovox.voxelize(SPOT, shape=(20, 30, 140), axis=1)
    convert_to(SPOT, tmp_path / "s.h5", shape=(20, 30, 140), budget=20 * 30 * 64 * 1)
    r = hdf.vtkHDFReader()
    r.SetFileName(str(tmp_path / "s.h5"))
    r.Update()
    a = vtk_to_numpy(r.GetOutput().GetPointData().GetArray("occupancy"))
    np.testing.assert_array_equal(a.reshape(140, 30, 20).transpose(2, 1, 0) == 1, ref.occupancy)


def test_cli_streams_big_grids(tmp_path, capsys, monkeypatch):
    import geovox.planner as planner

    monkeypatch.setattr(planner, "SLAB_BUDGET", 24 * 24 * 64)
    assert main(["convert", SPOT, "-o", str(tmp_path / "s.h5"), "--shape", "24", "24", "200"]) == 0
    out = capsys.readouterr().out
    assert "in 4 slabs" in out
    back = F.read(tmp_path / "s.h5")
    ref = geovox.voxelize(SPOT, shape=(24, 24, 200), axis=1)
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)


def test_failed_stream_leaves_nothing(tmp_path, monkeypatch):
    import geovox.runners.slabs as stream

    real = stream.voxelize_block
    calls = {"n": 0}

    def fail_on_second_slab(*a, **k):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(*a, **k)

    monkeypatch.setattr(stream, "voxelize_block", fail_on_second_slab)
    for ext in (".h5", ".raw"):
        calls["n"] = 0
        with pytest.raises(KeyboardInterrupt):
            convert_to(SPOT, tmp_path / f"s{ext}", shape=(16, 16, 200), budget=16 * 16 * 64)
        assert list(tmp_path.iterdir()) == []
