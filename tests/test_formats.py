"""Every format round-trips, through geovox's readers and independent ones."""

from __future__ import annotations

import os
import struct

import h5py
import numpy as np
import pytest

import geovox
import geovox.formats as F
from geovox.errors import OutputError
from geovox.formats import headers, vox

from conftest import SPOT

SHAPE = (23, 31, 17)  # distinct sizes catch any axis mix-up


@pytest.fixture(scope="module")
def vol():
    return geovox.voxelize(SPOT, shape=SHAPE, color=True, backend="numpy")


@pytest.fixture(scope="module")
def plain():
    return geovox.voxelize(SPOT, shape=SHAPE, backend="numpy")


def origin(v):
    return np.asarray(v.bounds[0]) + 0.5 * np.asarray(v.spacing)


@pytest.mark.parametrize("ext", [".raw", ".h5", ".nrrd", ".npz", ".vox"])
def test_round_trip_through_geovox_readers(tmp_path, vol, ext):
    written = F.write(vol, tmp_path / f"v{ext}")
    assert all(os.path.exists(p) for p in written)
    back = F.read(tmp_path / f"v{ext}")
    np.testing.assert_array_equal(back.occupancy, vol.occupancy)
    if ext == ".vox":  # 255 quantised colours, unit voxels
        assert np.abs(back.colors.astype(int) - vol.colors.astype(int)).max() <= 40
        np.testing.assert_array_equal(back.colors[..., 3], vol.colors[..., 3])
        return
    np.testing.assert_allclose(back.spacing, vol.spacing)
    np.testing.assert_allclose(back.bounds, vol.bounds)
    np.testing.assert_array_equal(back.colors, vol.colors)


def test_npy(tmp_path, plain):
    F.write(plain, tmp_path / "v.npy")
    a = np.load(tmp_path / "v.npy")
    assert a.dtype == np.uint8 and a.shape == SHAPE
    np.testing.assert_array_equal(a == 1, plain.occupancy)


def test_npz_holds_grid(tmp_path, vol):
    F.write(vol, tmp_path / "v.npz")
    with np.load(tmp_path / "v.npz") as z:
        np.testing.assert_allclose(z["spacing"], vol.spacing)
        np.testing.assert_allclose(z["origin"], origin(vol))
        np.testing.assert_array_equal(z["colors"], vol.colors)


def test_raw_headers_are_read_by_vtk(tmp_path, vol):
    io = pytest.importorskip("vtkmodules.vtkIOImage")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    F.write(vol, tmp_path / "v.raw")
    for reader, name, comps in [(io.vtkMetaImageReader, "v.mhd", 1), (io.vtkNrrdReader, "v.nhdr", 1),
                                (io.vtkMetaImageReader, "v_rgba.mhd", 4)]:
        r = reader()
        r.SetFileName(str(tmp_path / name))
        r.Update()
        img = r.GetOutput()
        assert img.GetDimensions() == SHAPE, name
        np.testing.assert_allclose(img.GetSpacing(), vol.spacing)
        np.testing.assert_allclose(img.GetOrigin(), origin(vol))
        a = vtk_to_numpy(img.GetPointData().GetArray(0))
        if comps == 1:
            got = a.reshape(SHAPE[::-1]).transpose(2, 1, 0) == 255
            np.testing.assert_array_equal(got, vol.occupancy)
        else:
            np.testing.assert_array_equal(a.reshape(SHAPE[::-1] + (4,)).transpose(2, 1, 0, 3), vol.colors)


def test_nrrd_files_are_read_by_pynrrd(tmp_path, vol):
    import nrrd

    F.write(vol, tmp_path / "v.raw")
    F.write(vol, tmp_path / "w.nrrd")
    for name in ("v.nhdr", "w.nrrd"):
        data, h = nrrd.read(str(tmp_path / name))
        np.testing.assert_array_equal(data == 255, vol.occupancy)
        np.testing.assert_allclose(np.diag(h["space directions"]), vol.spacing)
        np.testing.assert_allclose(h["space origin"], origin(vol))
    data, h = nrrd.read(str(tmp_path / "v_rgba.nhdr"))
    assert h["kinds"][0] == "RGBA-color"
    np.testing.assert_array_equal(np.moveaxis(data, 0, 3), vol.colors)


def test_vtkhdf_group_is_read_by_vtk(tmp_path, vol):
    hdf = pytest.importorskip("vtkmodules.vtkIOHDF")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    F.write(vol, tmp_path / "v.h5")
    with h5py.File(tmp_path / "v.h5") as f:
        g = f["VTKHDF"]
        assert g.attrs["Type"] == b"ImageData"
        assert f["VTKHDF/PointData/color"].compression == "gzip"
        np.testing.assert_array_equal(f["occupancy"][...] == 1, vol.occupancy)
    r = hdf.vtkHDFReader()
    r.SetFileName(str(tmp_path / "v.h5"))
    r.Update()
    img = r.GetOutput()
    assert img.GetDimensions() == SHAPE
    np.testing.assert_allclose(img.GetSpacing(), vol.spacing)
    np.testing.assert_allclose(img.GetOrigin(), origin(vol))
    pd = img.GetPointData()
    occ = vtk_to_numpy(pd.GetArray("occupancy")).reshape(SHAPE[::-1]).transpose(2, 1, 0)
    np.testing.assert_array_equal(occ == 1, vol.occupancy)
    rgba = vtk_to_numpy(pd.GetArray("color"))
    assert rgba.shape == (np.prod(SHAPE), 4) and rgba.dtype == np.uint8
    np.testing.assert_array_equal(rgba.reshape(SHAPE[::-1] + (4,)).transpose(2, 1, 0, 3), vol.colors)


def test_header_functions():
    mhd = headers.mhd_header((4, 5, 6), (0.5, 1, 2), (1, 2, 3), "uint8", "a.raw")
    assert "DimSize = 4 5 6" in mhd and "ElementType = MET_UCHAR" in mhd
    assert "ElementSpacing = 0.5 1.0 2.0" in mhd and "Offset = 1.0 2.0 3.0" in mhd
    assert mhd.rstrip().endswith("ElementDataFile = a.raw")
    rgba = headers.mhd_header((4, 5, 6), (1, 1, 1), (0, 0, 0), "uint8", "c.raw", components=4)
    assert "ElementNumberOfChannels = 4" in rgba
    nhdr = headers.nhdr_header((4, 5, 6), (0.5, 1, 2), (1, 2, 3), "float32", "a.raw")
    assert nhdr.startswith("NRRD0004\n") and "sizes: 4 5 6" in nhdr and "type: float" in nhdr
    assert "space directions: (0.5,0,0) (0,1.0,0) (0,0,2.0)" in nhdr
    assert headers.default_name("spot", (128, 64, 32)) == "spot_128x64x32_uint8.raw"


def _parse_vox_by_spec(data: bytes):
    """Walk the chunks as the format specification lays them out."""
    assert data[:4] == b"VOX " and struct.unpack_from("<i", data, 4)[0] == 150
    assert data[8:12] == b"MAIN"
    n_content, n_children = struct.unpack_from("<ii", data, 12)
    assert n_content == 0 and 20 + n_children == len(data)
    pos, ids = 20, []
    sizes, counts = [], []
    while pos < len(data):
        cid = data[pos:pos + 4]
        nc, nch = struct.unpack_from("<ii", data, pos + 4)
        ids.append(cid)
        if cid == b"SIZE":
            sizes.append(struct.unpack_from("<iii", data, pos + 12))
        if cid == b"XYZI":
            (n,) = struct.unpack_from("<i", data, pos + 12)
            assert nc == 4 + 4 * n
            counts.append(n)
            xyzi = np.frombuffer(data, np.uint8, 4 * n, pos + 16).reshape(n, 4)
            assert xyzi[:, 3].min(initial=1) >= 1  # palette index 0 means empty
        if cid == b"RGBA":
            assert nc == 1024
        pos += 12 + nc + nch
    return ids, sizes, counts


def test_vox_matches_the_specification(tmp_path, vol):
    F.write(vol, tmp_path / "v.vox")
    ids, sizes, counts = _parse_vox_by_spec((tmp_path / "v.vox").read_bytes())
    assert ids[:2] == [b"SIZE", b"XYZI"] and ids[-1] == b"RGBA"
    assert sizes == [SHAPE] and counts == [vol.inside_count]


def test_vox_splits_large_grids_into_placed_models(tmp_path):
    occ = np.zeros((300, 20, 520), bool, order="F")
    occ[5:295, 3:17, 10:510] = True
    v = geovox.Volume(occupancy=occ, grid=geovox.Grid(np.zeros(3), np.array(occ.shape, float), occ.shape),
                      backend="test")
    F.write(v, tmp_path / "big.vox")
    data = (tmp_path / "big.vox").read_bytes()
    ids, sizes, counts = _parse_vox_by_spec(data)
    assert len(sizes) == 2 * 1 * 3 and all(max(s) <= 256 for s in sizes)
    assert b"nTRN" in ids and b"nGRP" in ids and b"nSHP" in ids
    assert sum(counts) == occ.sum()
    back = F.read(tmp_path / "big.vox")
    np.testing.assert_array_equal(back.occupancy, occ)


def test_vox_shell_keeps_only_visible_voxels(tmp_path, plain):
    F.write(plain, tmp_path / "full.vox")
    F.write(plain, tmp_path / "shell.vox", shell=True)
    shell = F.read(tmp_path / "shell.vox").occupancy
    mask = vox.shell_mask(plain.occupancy)
    np.testing.assert_array_equal(shell, mask)
    assert shell.sum() < 0.8 * plain.inside_count
    assert os.path.getsize(tmp_path / "shell.vox") < os.path.getsize(tmp_path / "full.vox")


def test_vox_quantises_to_255_colours():
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (20000, 3)).astype(np.uint8)
    palette, index = vox.quantise(rgb)
    assert len(palette) <= 255 and index.max() < len(palette)
    err = np.abs(palette[index].astype(int) - rgb).mean()
    assert err < 20  # random colours are the worst case for any palette
    few = np.array([[1, 2, 3], [250, 0, 0], [1, 2, 3]], np.uint8)
    p, i = vox.quantise(few)
    np.testing.assert_array_equal(p[i], few)


@pytest.mark.parametrize("ext", [".raw", ".h5", ".nrrd", ".npy", ".npz", ".vox"])
def test_failed_write_leaves_nothing(tmp_path, vol, ext, monkeypatch):
    def fail(src, dst):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(F.os, "replace", fail)
    with pytest.raises(OutputError, match="disk full"):
        F.write(vol, tmp_path / f"v{ext}")
    assert list(tmp_path.iterdir()) == []


def test_formats_command_lists_everything(capsys):
    from geovox.cli import main

    assert main(["formats"]) == 0
    out = capsys.readouterr().out
    for name in ("raw", "hdf5", "nrrd", "npy", "npz", "vox"):
        assert name in out


def test_multi_file_output_appears_together_or_not_at_all(tmp_path, vol, monkeypatch):
    import json as _json

    def boom(*a, **k):
        raise OSError(28, "No space left on device")

    # The sidecar is written last: when it fails, no RAW or header may remain.
    monkeypatch.setattr(_json, "dump", boom)
    with pytest.raises(OutputError, match="disk full"):
        F.write(vol, tmp_path / "v.raw")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("tail", [(), (4,)])
def test_chunk_writer_fills_both_layouts_exactly(tmp_path, tail):
    # Chunks that are zero, uniform non-zero, mixed, and cut short by the
    # edge, written as two slabs: both layouts must read back as the array.
    from geovox.formats.chunks import write_both

    rng = np.random.default_rng(3)
    nz, ny, nx = 40, 21, 19
    vol = np.zeros((nz, ny, nx) + tail, dtype=np.uint8)
    vol[:16, :8, :8] = 7                              # one uniform full chunk
    vol[16:32, 8:16] = rng.integers(0, 3, (16, 8, nx) + tail)  # mixed
    vol[32:, 16:, 16:] = 5                            # uniform but cut short
    with h5py.File(tmp_path / "c.h5", "w") as f:
        kw = dict(dtype=np.uint8, compression="gzip", fillvalue=0)
        v = f.create_dataset("v", shape=vol.shape, chunks=(16, 8, 8) + tail, **kw)
        p = f.create_dataset("p", shape=(nx, ny, nz) + tail, chunks=(8, 8, 16) + tail, **kw)
        write_both(vol[:16], v, p, z0=0, jobs=2)
        write_both(vol[16:], v, p, z0=16, jobs=1)
    with h5py.File(tmp_path / "c.h5") as f:
        np.testing.assert_array_equal(f["v"][...], vol)
        np.testing.assert_array_equal(f["p"][...], vol.transpose((2, 1, 0) + tuple(range(3, vol.ndim))))


def test_chunk_writer_keeps_float_fields(tmp_path):
    from geovox.formats.chunks import write_both

    vol = np.linspace(-1, 1, 30 * 20 * 10, dtype=np.float32).reshape(30, 20, 10)
    vol[:16] = 0.5
    with h5py.File(tmp_path / "f.h5", "w") as f:
        v = f.create_dataset("v", shape=vol.shape, dtype=np.float32, chunks=(16, 16, 10),
                             compression="gzip", fillvalue=0)
        write_both(vol, v, None)
    with h5py.File(tmp_path / "f.h5") as f:
        np.testing.assert_array_equal(f["v"][...], vol)


def test_chunk_writer_falls_back_to_zlib(tmp_path, monkeypatch):
    # Where isal is not installed, the standard library's zlib writes the chunks.
    import zlib

    import geovox.formats.chunks as chunks

    monkeypatch.setattr(chunks, "_deflate", zlib)
    vol = np.zeros((20, 20, 20), dtype=np.uint8)
    vol[3:17, 5:9] = 1
    with h5py.File(tmp_path / "z.h5", "w") as f:
        v = f.create_dataset("v", shape=vol.shape, dtype=np.uint8, chunks=(8, 8, 8),
                             compression="gzip", fillvalue=0)
        chunks.write_both(vol, v, None)
    with h5py.File(tmp_path / "z.h5") as f:
        np.testing.assert_array_equal(f["v"][...], vol)
