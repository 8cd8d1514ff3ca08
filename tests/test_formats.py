"""Every format round-trips, through geovox's readers and independent ones."""

from __future__ import annotations

import os
import struct

import h5py
import numpy as np
import pytest

import geovox
import geovox.formats as F
from geovox.errors import GeovoxWarning, OutputError
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


@pytest.mark.parametrize("ext", [".raw", ".h5", ".vtkhdf", ".hdf", ".nrrd", ".npz", ".vox", ".zarr"])
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


@pytest.mark.parametrize("ext", [".raw", ".h5", ".vtkhdf", ".nrrd", ".npy", ".npz", ".vox", ".zarr"])
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
    for name in ("raw", "hdf5", "vtkhdf", "nrrd", "npy", "npz", "binvox", "vox"):
        assert name in out
    for ext in (".vtkhdf .hdf", ".binvox"):
        assert ext in out


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


# --- VTK-HDF for ParaView, opened by name --------------------------------------------------

@pytest.fixture(scope="module")
def fields():
    """Colour, coverage density and signed distance: every array a format can carry."""
    # Cubic voxels keep the distance quick; 19 x 34 x 35 still has distinct sides.
    return geovox.voxelize(SPOT, voxel_size=0.05, color=True, density="coverage", sdf=True,
                           backend="numpy")


def _vtk_messages(reader):
    """Collect the warnings and errors a VTK reader raises (ParaView prints them)."""
    from vtkmodules.vtkCommonCore import vtkCommand

    said = []
    for event in (vtkCommand.WarningEvent, vtkCommand.ErrorEvent):
        reader.AddObserver(event, lambda obj, ev: said.append(ev))
    return said


@pytest.mark.parametrize("ext", [".vtkhdf", ".hdf"])
def test_vtkhdf_file_is_read_by_vtk_silently(tmp_path, fields, ext):
    hdf = pytest.importorskip("vtkmodules.vtkIOHDF")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    path = tmp_path / f"v{ext}"
    assert F.write(fields, path) == [str(path)]
    with h5py.File(path) as f:
        np.testing.assert_array_equal(f["VTKHDF"].attrs["Version"], [1, 0])
    r = hdf.vtkHDFReader()
    said = _vtk_messages(r)
    r.SetFileName(str(path))
    r.Update()
    assert said == []
    img = r.GetOutput()
    assert img.GetExtent() == (0, fields.shape[0] - 1, 0, fields.shape[1] - 1, 0, fields.shape[2] - 1)
    np.testing.assert_allclose(img.GetSpacing(), fields.spacing)
    np.testing.assert_allclose(img.GetOrigin(), origin(fields))
    pd = img.GetPointData()

    def xyz(name, tail=()):
        a = vtk_to_numpy(pd.GetArray(name)).reshape(fields.shape[::-1] + tail)
        return a.transpose(2, 1, 0, *range(3, 3 + len(tail)))

    np.testing.assert_array_equal(xyz("occupancy") == 1, fields.occupancy)
    assert pd.GetArray("color").GetNumberOfComponents() == 4
    np.testing.assert_array_equal(xyz("color", (4,)), fields.colors)
    np.testing.assert_array_equal(xyz("density"), fields.density)
    np.testing.assert_array_equal(xyz("sdf"), fields.sdf)
    back = F.read(path)
    np.testing.assert_array_equal(back.sdf, fields.sdf)
    np.testing.assert_array_equal(back.density, fields.density)


def test_vtkhdf_header_function():
    from geovox.formats.vtkhdf import image_attributes

    a = image_attributes((4, 5, 6), (0.5, 1, 2), (1, 2, 3))
    assert a["Type"] == b"ImageData" and list(a["Version"]) == [1, 0]
    assert list(a["WholeExtent"]) == [0, 3, 0, 4, 0, 5]
    assert list(a["Spacing"]) == [0.5, 1, 2] and list(a["Origin"]) == [1, 2, 3]


def test_colour_nrrd_is_read_whole_by_vtk(tmp_path, fields):
    # VTK's reader (ParaView's) used to open the RGBA NRRD as one z-slice, and
    # inflates only one value per voxel of a gzip-encoded file.
    io = pytest.importorskip("vtkmodules.vtkIOImage")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    F.write(fields, tmp_path / "w.nrrd")
    F.write(fields, tmp_path / "v.raw")
    for name, want, comps in [("w_rgba.nrrd", fields.colors, 4), ("v_rgba.nhdr", fields.colors, 4),
                              ("w_sdf.nrrd", fields.sdf, 1), ("w_density.nrrd", fields.density, 1)]:
        r = io.vtkNrrdReader()
        r.SetFileName(str(tmp_path / name))
        r.Update()
        img = r.GetOutput()
        assert img.GetDimensions() == fields.shape, name
        np.testing.assert_allclose(img.GetOrigin(), origin(fields))
        a = vtk_to_numpy(img.GetPointData().GetArray(0))
        tail = (comps,) if comps > 1 else ()
        got = a.reshape(fields.shape[::-1] + tail).transpose(2, 1, 0, *range(3, 3 + len(tail)))
        np.testing.assert_array_equal(got, want, err_msg=name)


# --- binvox ----------------------------------------------------------------------------

def _binvox_by_definition(data: bytes):
    """binvox as its definition reads: header lines, then (value, count) pairs, y fastest, then z, then x."""
    lines, pos = [], 0
    while True:
        end = data.index(b"\n", pos)
        lines.append(data[pos:end].decode())
        pos = end + 1
        if lines[-1] == "data":
            break
    assert lines[0] == "#binvox 1"
    head = {line.split()[0]: line.split()[1:] for line in lines[1:-1]}
    d, e, f = (int(v) for v in head["dim"])
    assert d == e == f
    values, counts = data[pos::2], data[pos + 1::2]
    assert len(values) == len(counts) and min(counts) >= 1
    occ = np.zeros((d, d, d), dtype=bool)
    index = 0
    for value, count in zip(values, counts):
        for n in range(index, index + count):
            x, rest = divmod(n, d * d)
            z, y = divmod(rest, d)
            occ[x, y, z] = value == 1
        index += count
    assert index == d ** 3
    return occ, np.array([float(v) for v in head["translate"]]), float(head["scale"][0])


@pytest.fixture(scope="module")
def cubic():
    """spot in cubic voxels: 19 x 34 x 35, so binvox pads x and y."""
    return geovox.voxelize(SPOT, voxel_size=0.05, backend="numpy")


def test_binvox_follows_the_definition(tmp_path, cubic):
    with pytest.warns(GeovoxWarning, match="padded with empty voxels to 35³"):
        F.write(cubic, tmp_path / "s.binvox")
    occ, translate, scale = _binvox_by_definition((tmp_path / "s.binvox").read_bytes())
    d = 35
    assert occ.shape == (d, d, d)
    nx, ny, nz = cubic.shape
    np.testing.assert_array_equal(occ[:nx, :ny, :nz], cubic.occupancy)
    assert occ.sum() == cubic.inside_count  # the padding is empty
    np.testing.assert_allclose(translate, cubic.bounds[0])
    np.testing.assert_allclose(scale, 0.05 * d)
    # voxel centre = translate + scale * (i + 0.5) / dim, the grid's own centres
    i = np.arange(nx)
    np.testing.assert_allclose(translate[0] + scale * (i + 0.5) / d,
                               cubic.bounds[0][0] + (i + 0.5) * cubic.spacing[0], atol=1e-12)
    back = F.read(tmp_path / "s.binvox")
    np.testing.assert_array_equal(back.occupancy, occ)
    np.testing.assert_allclose(back.spacing, cubic.spacing)
    np.testing.assert_allclose(back.bounds[0], cubic.bounds[0])


def test_binvox_box_is_exact(tmp_path):
    from conftest import box_mesh

    # A box of 6 x 3 x 4 voxels of edge 0.25, offset inside a 10³ region.
    box = box_mesh((0.5, 1.0, 0.25), (2.0, 1.75, 1.25))
    vol = geovox.voxelize(box, bounds=(0, 0, 0, 2.5, 2.5, 2.5), voxel_size=0.25, backend="numpy")
    assert vol.shape == (10, 10, 10) and vol.inside_count == 6 * 3 * 4
    F.write(vol, tmp_path / "b.binvox")
    occ, translate, scale = _binvox_by_definition((tmp_path / "b.binvox").read_bytes())
    idx = np.argwhere(occ)
    centres = translate + scale * (idx + 0.5) / 10
    assert centres.min(axis=0).tolist() == pytest.approx([0.625, 1.125, 0.375])
    assert centres.max(axis=0).tolist() == pytest.approx([1.875, 1.625, 1.125])
    assert len(idx) == 72


def test_binvox_through_trimesh(tmp_path, cubic):
    from trimesh.exchange.binvox import load_binvox

    with pytest.warns(GeovoxWarning):
        F.write(cubic, tmp_path / "s.binvox")
    with open(tmp_path / "s.binvox", "rb") as f:
        grid = load_binvox(f)
    d = 35
    nx, ny, nz = cubic.shape
    m = np.asarray(grid.matrix)
    assert m.shape == (d, d, d)
    np.testing.assert_array_equal(m[:nx, :ny, :nz], cubic.occupancy)
    assert m.sum() == cubic.inside_count
    # trimesh reads translate as voxel 0's centre and scale as pitch * (dim - 1):
    # the difference the README states.
    np.testing.assert_allclose(grid.transform[:3, 3], cubic.bounds[0])
    np.testing.assert_allclose(np.diag(grid.transform)[:3], 0.05 * d / (d - 1))


def test_binvox_needs_cubic_voxels(tmp_path, plain):
    from geovox.errors import ParameterError

    with pytest.raises(ParameterError, match="cubic voxels.*--voxel-size"):
        F.write(plain, tmp_path / "s.binvox")
    assert list(tmp_path.iterdir()) == []


def test_binvox_empty_and_full(tmp_path):
    for value in (False, True):
        occ = np.full((300, 300, 3), value, order="F")  # runs far longer than 255
        v = geovox.Volume(occupancy=occ, grid=geovox.Grid(np.zeros(3), np.array([3.0, 3, 0.03]), occ.shape),
                          backend="test")
        with pytest.warns(GeovoxWarning):
            F.write(v, tmp_path / "e.binvox")
        back = F.read(tmp_path / "e.binvox").occupancy
        assert back.shape == (300, 300, 300)
        assert back[:, :, :3].all() == value and not back[:, :, 3:].any()


def test_run_lengths_property():
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from geovox.formats.binvox import run_lengths

    @settings(max_examples=60, deadline=None)
    @given(st.lists(st.tuples(st.integers(0, 1), st.integers(1, 700)), max_size=12))
    def check(runs):
        flat = np.concatenate([np.full(n, v, np.uint8) for v, n in runs] or [np.zeros(0, np.uint8)])
        pairs = run_lengths(flat)
        values, counts = pairs[0::2], pairs[1::2]
        assert counts.min(initial=1) >= 1 and counts.max(initial=1) <= 255
        np.testing.assert_array_equal(np.repeat(values, counts), flat)

    check()


# --- packed bits in .npz ------------------------------------------------------------------

def test_npz_pack_bits_follows_the_onet_idiom(tmp_path, vol):
    F.write(vol, tmp_path / "p.npz", pack_bits=True)
    F.write(vol, tmp_path / "u.npz")
    with np.load(tmp_path / "p.npz") as d:
        assert "occupancy" not in d and d["occupancy_bits"].dtype == np.uint8
        got = np.unpackbits(d["occupancy_bits"])[:np.prod(d["shape"])].reshape(d["shape"])
        np.testing.assert_array_equal(got == 1, vol.occupancy)
        np.testing.assert_allclose(d["spacing"], vol.spacing)
        np.testing.assert_allclose(d["origin"], origin(vol))
        np.testing.assert_array_equal(d["colors"], vol.colors)
    back = F.read(tmp_path / "p.npz")
    np.testing.assert_array_equal(back.occupancy, vol.occupancy)
    assert back.occupancy.flags.f_contiguous


def test_cli_pack_bits(tmp_path, capsys):
    from geovox.cli import main

    out = tmp_path / "p.npz"
    assert main(["convert", SPOT, "-o", str(out), "-r", "16", "--pack-bits", "-q",
                 "--backend", "numpy"]) == 0
    with np.load(out) as d:
        assert d["occupancy_bits"].size == 16 ** 3 // 8
    assert main(["convert", SPOT, "-o", str(tmp_path / "p.h5"), "-r", "16", "--pack-bits"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--pack-bits is for .npz" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.npz"]


# --- bad input for the new writers: full disk, interrupt, unwritable folder ---------------------

class _FailingFile:
    """A file whose second write raises ``exc`` (ENOSPC as on a full disk, or an interrupt)."""

    def __init__(self, f, exc):
        self.f, self.exc, self.writes = f, exc, 0

    def write(self, data):
        self.writes += 1
        if self.writes > 1:
            raise self.exc
        return self.f.write(data)

    def __getattr__(self, name):
        return getattr(self.f, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


def _break_writes(monkeypatch, ext, exc):
    """Make the writer of ``ext`` fail part-way through its file."""
    import builtins

    import geovox.formats.binvox as binvox_module
    import geovox.formats.chunks as chunks
    import geovox.formats.nrrd as nrrd_module
    import geovox.formats.numpy_files as numpy_files

    if ext in (".vtkhdf", ".hdf"):
        # The file is open and laid out when the first array is written.
        def write_both(*args, **kw):
            raise exc

        monkeypatch.setattr(chunks, "write_both", write_both)
        return
    module = {".binvox": binvox_module, ".nrrd": nrrd_module, ".npz": numpy_files}.get(ext)
    if module is None:
        import geovox.formats.vdb as module
    monkeypatch.setattr(module, "open", lambda p, mode="r": _FailingFile(builtins.open(p, mode), exc),
                        raising=False)


NEW = [".vtkhdf", ".nrrd", ".npz", ".binvox"]


@pytest.mark.parametrize("ext", NEW)
def test_new_writers_full_disk_keeps_the_old_file(tmp_path, cubic, monkeypatch, ext):
    import warnings

    out = tmp_path / f"v{ext}"
    out.write_bytes(b"previous")
    _break_writes(monkeypatch, ext, OSError(28, "No space left on device"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        with pytest.raises(OutputError, match="disk full"):
            F.write(cubic, out, **({"pack_bits": True} if ext == ".npz" else {}))
    assert out.read_bytes() == b"previous"
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


@pytest.mark.parametrize("ext", NEW)
def test_new_writers_interrupted_leave_nothing(tmp_path, cubic, monkeypatch, ext):
    import warnings

    _break_writes(monkeypatch, ext, KeyboardInterrupt())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        with pytest.raises(KeyboardInterrupt):
            F.write(cubic, tmp_path / f"v{ext}")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("ext", NEW)
def test_new_writers_cli_one_line_for_bad_output(tmp_path, monkeypatch, capsys, ext):
    from geovox.cli import main

    grid = ["--voxel-size", "0.1"]
    assert main(["convert", SPOT, "-o", str(tmp_path / "missing" / f"v{ext}"), *grid]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "output folder does not exist" in err
    monkeypatch.setattr(F.os, "access", lambda path, mode: False)
    assert main(["convert", SPOT, "-o", str(tmp_path / f"v{ext}"), *grid]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not writable" in err
    monkeypatch.undo()
    _break_writes(monkeypatch, ext, OSError(28, "No space left on device"))
    assert main(["convert", SPOT, "-o", str(tmp_path / f"v{ext}"), *grid, "-q"]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith("geovox: error: disk full") and len(err) <= 2  # binvox's padding warning
    assert list(tmp_path.iterdir()) == []


def test_vtkhdf_streams_slab_by_slab(tmp_path):
    from geovox.api import convert_to

    opts = dict(shape=(16, 16, 150), color=True, backend="numpy")
    info = convert_to(SPOT, tmp_path / "s.vtkhdf", budget=16 * 16 * 64 * 25, **opts)
    assert info["slabs"] == 3
    ref = geovox.voxelize(SPOT, axis=1, **opts)
    back = F.read(tmp_path / "s.vtkhdf")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    np.testing.assert_array_equal(back.colors, ref.colors)
    np.testing.assert_allclose(back.bounds, ref.bounds)


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 5, 7), (40, 9, 33), (64, 2, 8)])
def test_packbits_in_pieces_equals_the_idiom(shape):
    from geovox.formats.numpy_files import packbits_c

    occ = np.asfortranarray(np.random.default_rng(sum(shape)).random(shape) < 0.4)
    np.testing.assert_array_equal(packbits_c(occ), np.packbits(occ.ravel(order="C")))


def test_paraview_opens_the_files_by_name(tmp_path):
    # ParaView picks a reader by extension only; 5.10-5.11 read VTK-HDF as .hdf,
    # 5.12+ as .vtkhdf too. Runs where ParaView's pvpython is installed.
    import json
    import shutil
    import subprocess

    pvpython = shutil.which("pvpython")
    if pvpython is None:
        pytest.skip("ParaView's pvpython is not installed (Debian: apt install paraview python3-paraview)")
    v = geovox.voxelize(SPOT, shape=(11, 13, 9), color=True, sdf=True, backend="numpy")
    for name in ("v.vtkhdf", "v.hdf", "w.nrrd"):
        F.write(v, tmp_path / name)
    names = [str(tmp_path / n) for n in ("v.vtkhdf", "v.hdf", "w.nrrd", "w_rgba.nrrd", "w_sdf.nrrd")]
    run = subprocess.run([pvpython, os.path.join(os.path.dirname(__file__), "paraview_open.py"), *names],
                         capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    # ParaView logs "WARN| ... File version: 2.1 is higher than this reader supports 1.0".
    assert not any(word in run.stderr for word in ("WARN", "ERR", "Warning", "Error")), run.stderr
    report = json.loads(run.stdout.strip().splitlines()[-1])
    files = report["files"]
    extent = [0, 10, 0, 12, 0, 8]
    if tuple(report["version"]) < (5, 12):
        assert "No reader" in files[names[0]]["error"]
        names = names[1:]
    lo = origin(v)
    for path in names:
        f = files[path]
        assert f["extent"] == extent, path
        np.testing.assert_allclose(f["bounds"][::2], lo)
    hdf = files[str(tmp_path / "v.hdf")]["arrays"]
    np.testing.assert_array_equal(np.asarray(hdf["color"]), v.colors.transpose(2, 1, 0, 3).reshape(-1, 4))
    np.testing.assert_array_equal(np.asarray(hdf["sdf"], np.float32), v.sdf.reshape(-1, order="F"))
    rgba = next(iter(files[str(tmp_path / "w_rgba.nrrd")]["arrays"].values()))
    np.testing.assert_array_equal(np.asarray(rgba), v.colors.transpose(2, 1, 0, 3).reshape(-1, 4))


def test_cli_refuses_binvox_with_unequal_voxels_before_work(tmp_path, capsys, monkeypatch):
    from geovox.cli import main
    import geovox.runners as runners

    def never(*a, **k):
        raise AssertionError("voxelised before the grid was checked")

    monkeypatch.setattr(runners, "voxelize_block", never)
    assert main(["convert", SPOT, "-o", str(tmp_path / "s.binvox"), "--shape", "16", "16", "16"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "binvox needs cubic voxels" in err and "--voxel-size" in err
    assert list(tmp_path.iterdir()) == []
