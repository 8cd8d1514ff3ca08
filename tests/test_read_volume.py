"""`geovox.formats.read_volume`: every file geovox writes, data or header, reads back.

`geovox preview` and `geovox view` read through it, so `geovox preview spot.json`
(or `.mhd`, `.nhdr`, `_rgba.raw`, ...) draws what `geovox preview spot.raw` does.
"""

from __future__ import annotations

import importlib.util
import json
import os

import numpy as np
import pytest

import geovox
import geovox.formats as F
from conftest import SPOT
from geovox.cli import main
from geovox.errors import GeovoxWarning, InputNotFoundError, MeshError


@pytest.fixture(scope="module")
def full():
    """A small spot with every field, on an uneven grid."""
    return geovox.voxelize(SPOT, shape=(11, 13, 9), color=True, density="coverage", sdf=True,
                           backend="numpy")


@pytest.fixture(scope="module")
def cube():
    return geovox.voxelize(SPOT, resolution=12, fit="cube", color=True, backend="numpy")


def _same(back, vol, fields=("colors", "density", "sdf"), bounds=True):
    np.testing.assert_array_equal(back.occupancy, vol.occupancy)
    if bounds:
        np.testing.assert_allclose(np.asarray(back.bounds), np.asarray(vol.bounds), rtol=0,
                                   atol=1e-9)
    for name in fields:
        np.testing.assert_array_equal(getattr(back, name), getattr(vol, name), err_msg=name)


RAW_FILES = ["v.json"] + [f"v{field}{ext}" for field in ("", "_rgba", "_density", "_sdf")
                          for ext in (".raw", ".mhd", ".nhdr")]


def test_every_file_of_a_raw_output_reads_the_whole_volume(tmp_path, full):
    written = F.write(full, tmp_path / "v.raw")
    assert sorted(os.path.basename(p) for p in written) == sorted(RAW_FILES)
    for name in RAW_FILES:
        _same(F.read_volume(tmp_path / name), full)


def test_nrrd_and_its_companions(tmp_path, full):
    F.write(full, tmp_path / "w.nrrd")
    for name in ("w.nrrd", "w_rgba.nrrd", "w_density.nrrd", "w_sdf.nrrd"):
        _same(F.read_volume(tmp_path / name), full)


@pytest.mark.parametrize("ext,fields,bounds", [
    (".h5", ("colors", "density", "sdf"), True),
    (".vtkhdf", ("colors", "density", "sdf"), True),
    (".hdf", ("colors", "density", "sdf"), True),
    (".npz", ("colors",), True),
    (".npy", (), False),          # the bare array: no grid
    (".vdb", ("density", "sdf"), True),
])
def test_single_file_formats(tmp_path, full, ext, fields, bounds):
    F.write(full, tmp_path / f"v{ext}")
    _same(F.read_volume(tmp_path / f"v{ext}"), full, fields, bounds)


def test_binvox_and_vox(tmp_path, cube):
    F.write(cube, tmp_path / "c.binvox")
    _same(F.read_volume(tmp_path / "c.binvox"), cube, (), True)
    F.write(cube, tmp_path / "c.vox")
    back = F.read_volume(tmp_path / "c.vox")  # unit voxels; colours quantised to a palette
    np.testing.assert_array_equal(back.occupancy, cube.occupancy)


@pytest.mark.skipif(importlib.util.find_spec("zarr") is None, reason="zarr is not installed "
                    "(pip install 'geovox[distributed]')")
def test_zarr(tmp_path, full):
    from geovox.api import convert_to

    convert_to(SPOT, tmp_path / "v.zarr", shape=(11, 13, 9), color=True, backend="numpy")
    ref = geovox.voxelize(SPOT, shape=(11, 13, 9), color=True, backend="numpy", axis=1)
    _same(F.read_volume(tmp_path / "v.zarr", max_side=64), ref, ("colors",))
    _same(F.read_volume(str(tmp_path / "v.zarr") + "/"), ref, ("colors",))


def test_headers_without_the_sidecar(tmp_path, full):
    F.write(full, tmp_path / "v.raw")
    os.remove(tmp_path / "v.json")  # the headers alone: what ITK, Slicer and ParaView read
    for name in ("v.mhd", "v.nhdr", "v.raw"):
        _same(F.read_volume(tmp_path / name), full, ())
    for name in ("v_rgba.mhd", "v_rgba.nhdr"):
        rgba = F.read_volume(tmp_path / name)
        np.testing.assert_array_equal(rgba.colors, full.colors)
        np.testing.assert_array_equal(rgba.occupancy, full.occupancy)
        np.testing.assert_allclose(np.asarray(rgba.bounds), np.asarray(full.bounds), atol=1e-9)
    for name in ("v_sdf.nhdr", "v_sdf.mhd"):
        np.testing.assert_array_equal(F.read_volume(tmp_path / name).sdf, full.sdf)
    dens = F.read_volume(tmp_path / "v_density.mhd")
    np.testing.assert_array_equal(dens.density, full.density)
    np.testing.assert_array_equal(dens.occupancy, full.density >= 128)


def test_bad_and_missing_files_say_so(tmp_path, full):
    with pytest.raises(InputNotFoundError):
        F.read_volume(tmp_path / "nothing.raw")
    (tmp_path / "x.json").write_text(json.dumps({"hello": 1}))
    with pytest.raises(MeshError, match="not a geovox sidecar"):
        F.read_volume(tmp_path / "x.json")
    F.write(full, tmp_path / "v.raw")
    os.remove(tmp_path / "v.raw")
    with pytest.raises(InputNotFoundError, match="v.raw"):
        F.read_volume(tmp_path / "v.json")
    (tmp_path / "lone.raw").write_bytes(b"\0" * 8)
    with pytest.raises(MeshError, match="no sidecar lone.json"):
        F.read_volume(tmp_path / "lone.raw")


@pytest.mark.parametrize("name", ["s.json", "s.mhd", "s.nhdr", "s_rgba.raw"])
def test_preview_reads_the_sidecar_and_headers(tmp_path, capsys, name):
    assert main(["convert", SPOT, "-o", str(tmp_path / "s.raw"), "-r", "24", "--color", "-q"]) == 0
    assert main(["preview", str(tmp_path / "s.raw"), "-o", str(tmp_path / "raw.png")]) == 0
    assert main(["preview", str(tmp_path / name), "-o", str(tmp_path / "other.png")]) == 0
    assert (tmp_path / "other.png").read_bytes() == (tmp_path / "raw.png").read_bytes()


def test_preview_of_a_foreign_json_is_one_line(tmp_path, capsys):
    (tmp_path / "x.json").write_text("[1, 2]")
    assert main(["preview", str(tmp_path / "x.json"), "-o", str(tmp_path / "p.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not a geovox sidecar" in err
    assert not (tmp_path / "p.png").exists()


def test_view_reads_through_the_same_function(tmp_path, monkeypatch, full):
    import geovox.view as view

    F.write(full, tmp_path / "v.raw")
    seen = {}
    monkeypatch.setattr(view, "show", lambda vol, mesh=None, screenshot=None: seen.update(vol=vol))
    assert main(["view", str(tmp_path / "v.nhdr")]) == 0
    _same(seen["vol"], full)


def test_a_segmentation_reads_with_its_labels(tmp_path):
    """A .seg.nrrd is one file (not a .nrrd's companion): its labels and table come back."""
    from test_labels import assembly

    vol = geovox.voxelize(assembly(), resolution=12, labels="part")
    path = str(tmp_path / "scene.seg.nrrd")
    F.write(vol, path)
    back = F.read_volume(path)
    np.testing.assert_array_equal(back.labels, vol.labels)
    assert [e["name"] for e in back.label_table] == [e["name"] for e in vol.label_table]
