"""The OpenVDB writer, checked by OpenVDB's own reader.

Debian's ``python3-openvdb`` gives ``pyopenvdb`` to the system Python only,
so ``openvdb_dump.py`` runs there in a subprocess and hands the grids back
as arrays. Where no interpreter has it, those tests are skipped with the
reason; geovox's own reader and the byte-level checks run everywhere.
"""

from __future__ import annotations

import os
import struct
import subprocess
import zlib

import numpy as np
import pytest

import geovox
import geovox.formats as F
from geovox.errors import OutputError
from geovox.formats import vdb

from conftest import HERE, SPOT, box_mesh

#: The interpreter that has pyopenvdb (Debian's python3-openvdb is for the system Python).
OPENVDB_PYTHON = os.environ.get("GEOVOX_OPENVDB_PYTHON", "/usr/bin/python3")


def _has_openvdb() -> bool:
    try:
        return subprocess.run([OPENVDB_PYTHON, "-c", "import pyopenvdb"],
                              capture_output=True, timeout=60).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


needs_openvdb = pytest.mark.skipif(
    not _has_openvdb(),
    reason=f"OpenVDB's reader is not installed for {OPENVDB_PYTHON} "
           "(Debian/Ubuntu: apt install python3-openvdb; or set GEOVOX_OPENVDB_PYTHON)")


def openvdb_read(path, shape) -> dict:
    """Every grid of ``path`` as OpenVDB reads it: ``{name: {values, active, count, ...}}``."""
    out = str(path) + ".dump.npz"
    subprocess.run([OPENVDB_PYTHON, os.path.join(HERE, "openvdb_dump.py"), str(path), out,
                    *(str(n) for n in shape)], check=True, capture_output=True, timeout=300)
    grids = {}
    with np.load(out) as z:
        for key in z.files:
            if "/" in key:
                name, field = key.split("/")
                grids.setdefault(name, {})[field] = z[key]
        grids["_order"] = list(z["grid_names"])
    os.unlink(out)
    return grids


def centre0(v):
    return np.asarray(v.bounds[0]) + 0.5 * np.asarray(v.spacing)


def check_transform(grid, volume):
    world = grid["world"]
    np.testing.assert_allclose(world[0], centre0(volume), rtol=0, atol=1e-12)
    np.testing.assert_allclose(world[1:] - world[0], np.diag(volume.spacing), rtol=1e-12, atol=1e-15)


def check_stats(grid):
    assert grid["count"] == grid["active"].sum() == grid["meta_count"]
    if grid["count"]:
        np.testing.assert_array_equal(grid["meta_bbox"], grid["bbox"])


@pytest.fixture(scope="module")
def spot():
    """Colour, coverage density (uint8) and signed distance on a grid of distinct sides (19 x 34 x 35)."""
    return geovox.voxelize(SPOT, voxel_size=0.05, color=True, density="coverage", sdf=True,
                           backend="numpy")


@needs_openvdb
def test_spot_every_grid_as_openvdb_reads_it(tmp_path, spot):
    F.write(spot, tmp_path / "s.vdb")
    g = openvdb_read(tmp_path / "s.vdb", spot.shape)
    assert sorted(g["_order"]) == ["color", "density", "sdf"]

    d = g["density"]
    assert str(d["class"]) == "fog volume" and str(d["type"]) == "float"
    np.testing.assert_array_equal(d["values"], spot.density.astype(np.float32) / np.float32(255))
    np.testing.assert_array_equal(d["active"], spot.density > 0)
    assert d["background"] == 0

    c = g["color"]
    assert str(c["type"]) == "vec3s"
    inside = spot.colors[..., 3] > 0
    np.testing.assert_array_equal(c["active"], inside)
    want = np.where(inside[..., None], spot.colors[..., :3].astype(np.float32) / np.float32(255), 0)
    np.testing.assert_array_equal(c["values"], want)

    s = g["sdf"]
    assert str(s["class"]) == "level set"
    band = np.abs(spot.sdf).max()
    assert s["background"] == band
    np.testing.assert_array_equal(s["values"], spot.sdf)  # inside tiles read back as -band
    np.testing.assert_array_equal(s["active"], np.abs(spot.sdf) < band)
    for grid in (d, c, s):
        check_transform(grid, spot)
        check_stats(grid)


@needs_openvdb
def test_occupancy_without_density_is_a_zero_one_fog(tmp_path):
    v = geovox.voxelize(SPOT, shape=(40, 9, 70), backend="numpy")
    F.write(v, tmp_path / "o.vdb")
    g = openvdb_read(tmp_path / "o.vdb", v.shape)
    assert g["_order"] == ["density"]
    np.testing.assert_array_equal(g["density"]["values"], v.occupancy.astype(np.float32))
    np.testing.assert_array_equal(g["density"]["active"], v.occupancy)
    check_transform(g["density"], v)
    check_stats(g["density"])


def _box_volume(shape, lo, hi):
    occ = np.zeros(shape, bool, order="F")
    occ[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] = True
    return geovox.Volume(occupancy=occ, grid=geovox.Grid(np.array([-1.0, 2.0, 0.5]),
                                                         np.array([-1.0, 2.0, 0.5]) + 0.25 * np.array(shape),
                                                         shape), backend="test")


@needs_openvdb
def test_box_on_leaf_boundaries_is_all_tiles(tmp_path):
    # Faces on multiples of 8 (and 128): every 8³ block is uniform, so no leaf is stored.
    v = _box_volume((300, 136, 136), (8, 0, 128), (264, 136, 136))
    F.write(v, tmp_path / "b.vdb")
    g = openvdb_read(tmp_path / "b.vdb", v.shape)["density"]
    assert g["leaves"] == 0
    assert g["count"] == v.inside_count == 256 * 136 * 8
    np.testing.assert_array_equal(g["active"], v.occupancy)
    check_transform(g, v)
    check_stats(g)
    assert os.path.getsize(tmp_path / "b.vdb") < 20_000


@needs_openvdb
def test_box_off_the_boundaries_stores_only_its_faces(tmp_path):
    v = _box_volume((90, 70, 80), (3, 10, 21), (85, 61, 77))
    F.write(v, tmp_path / "b.vdb")
    g = openvdb_read(tmp_path / "b.vdb", v.shape)["density"]
    np.testing.assert_array_equal(g["values"], v.occupancy.astype(np.float32))
    np.testing.assert_array_equal(g["active"], v.occupancy)
    # Exactly the 8³ blocks the faces cut are leaves (beyond the grid counts as empty).
    padded = np.zeros([-(-n // 8) * 8 for n in v.shape], bool)
    padded[:90, :70, :80] = v.occupancy
    blocks = padded.reshape(12, 8, 9, 8, 10, 8).sum(axis=(1, 3, 5))
    assert g["leaves"] == np.count_nonzero((blocks > 0) & (blocks < 512))
    check_stats(g)


@needs_openvdb
def test_voxelised_box_is_exact(tmp_path):
    box = box_mesh((0.5, 1.0, 0.25), (2.0, 1.75, 1.25))
    v = geovox.voxelize(box, bounds=(0, 0, 0, 2.5, 2.5, 2.5), voxel_size=0.25, backend="numpy",
                        sdf=True)
    F.write(v, tmp_path / "b.vdb")
    g = openvdb_read(tmp_path / "b.vdb", v.shape)
    assert g["density"]["count"] == 6 * 3 * 4
    idx = np.argwhere(g["density"]["active"])
    world = g["density"]["world"]
    centres = world[0] + idx * 0.25
    assert centres.min(axis=0).tolist() == pytest.approx([0.625, 1.125, 0.375])
    assert centres.max(axis=0).tolist() == pytest.approx([1.875, 1.625, 1.125])
    np.testing.assert_array_equal(g["sdf"]["values"], v.sdf)


@needs_openvdb
def test_empty_volume(tmp_path):
    v = _box_volume((20, 30, 40), (0, 0, 0), (0, 0, 0))
    F.write(v, tmp_path / "e.vdb")
    g = openvdb_read(tmp_path / "e.vdb", v.shape)["density"]
    assert g["count"] == 0 and g["leaves"] == 0 and not g["values"].any()
    back = F.read(tmp_path / "e.vdb")
    assert back.shape == v.shape and not back.occupancy.any()


def test_large_solid_takes_little_space(tmp_path):
    # A 192³ grid with a box whose faces cut the leaves:
    # only the face leaves are stored (a 1024³ one takes about 11 MB).
    v = _box_volume((192, 192, 192), (37, 5, 100), (190, 181, 171))
    F.write(v, tmp_path / "big.vdb")
    assert os.path.getsize(tmp_path / "big.vdb") < 512_000  # 28 MiB as dense float32
    back = F.read(tmp_path / "big.vdb")
    np.testing.assert_array_equal(back.occupancy, v.occupancy)


def test_geovox_reader_gets_every_array_back(tmp_path, spot):
    F.write(spot, tmp_path / "s.vdb")
    back = F.read(tmp_path / "s.vdb")
    np.testing.assert_array_equal(back.occupancy, spot.occupancy)
    np.testing.assert_array_equal(back.density, spot.density)
    np.testing.assert_array_equal(back.sdf, spot.sdf)
    np.testing.assert_array_equal(back.colors, spot.colors)
    np.testing.assert_allclose(back.bounds, spot.bounds)
    assert back.occupancy.flags.f_contiguous


def test_header_and_descriptor_bytes(tmp_path, spot):
    F.write(spot, tmp_path / "s.vdb")
    data = (tmp_path / "s.vdb").read_bytes()
    magic, version, major, minor, offsets = struct.unpack_from("<qIIIB", data)
    assert (magic, version, offsets) == (0x56444220, 224, 1)
    uid = data[21:57].decode()
    assert len(uid) == 36 and uid.count("-") == 4
    # Each descriptor's end offset points at the next descriptor.
    assert data.count(b"Tree_float_5_4_3") == 2 and data.count(b"Tree_vec3s_5_4_3") == 1


def test_compressed_values_follow_the_reader_rules():
    bg = np.float32(3.0)
    vals = np.array([1.0, 3.0, -3.0, 2.0], np.float32)
    act = np.array([True, False, False, True])
    out = vdb._values(vals, act, bg)
    assert out[0] == vdb.MASK_AND_NO_INACTIVE_VALS
    selection = np.unpackbits(np.frombuffer(out[1:2], np.uint8), bitorder="little")[:4]
    np.testing.assert_array_equal(selection, [0, 1, 0, 0])  # +background where set
    size = struct.unpack_from("<q", out, 1 + 1)[0]  # a 4-slot mask is one byte here
    payload = out[10:]
    data = payload if size < 0 else zlib.decompress(payload)
    np.testing.assert_array_equal(np.frombuffer(data, np.float32), [1.0, 2.0])
    assert vdb._values(np.zeros(4, np.float32), np.zeros(4, bool), np.float32(0))[0] == \
        vdb.NO_MASK_OR_INACTIVE_VALS
    assert vdb._values(np.array([5, 1, 1, 1], np.float32), act, bg)[0] == vdb.NO_MASK_AND_ALL_VALS


def test_the_map_says_whether_voxels_are_cubic(tmp_path, spot):
    F.write(spot, tmp_path / "c.vdb")
    assert b"UniformScaleTranslateMap" in (tmp_path / "c.vdb").read_bytes()
    flat = geovox.voxelize(SPOT, shape=(40, 9, 70), backend="numpy")
    F.write(flat, tmp_path / "s.vdb")
    data = (tmp_path / "s.vdb").read_bytes()
    assert b"ScaleTranslateMap" in data and b"UniformScaleTranslateMap" not in data


def test_preview_and_view_read_the_new_formats(tmp_path, capsys):
    from PIL import Image

    from geovox.cli import main

    for ext in (".vdb", ".binvox", ".hdf"):
        out = tmp_path / f"v{ext}"
        assert main(["convert", SPOT, "-o", str(out), "--voxel-size", "0.08", "--color", "-q",
                     "--backend", "numpy"]) == 0
        assert main(["preview", str(out), "-o", str(tmp_path / f"{ext[1:]}.png")]) == 0
        with Image.open(tmp_path / f"{ext[1:]}.png") as im:
            assert im.size[0] > 500
    pytest.importorskip("pyvista")
    assert main(["view", str(tmp_path / "v.vdb"), "--screenshot", str(tmp_path / "view.png")]) == 0
    with Image.open(tmp_path / "view.png") as im:
        assert len(np.unique(np.asarray(im.convert("RGB")).reshape(-1, 3), axis=0)) > 20


def test_vdb_writer_bad_output(tmp_path, spot, monkeypatch, capsys):
    import builtins

    from geovox.cli import main

    class Full:
        def __init__(self, f):
            self.f, self.n = f, 0

        def write(self, data):
            self.n += 1
            if self.n > 1:
                raise OSError(28, "No space left on device")
            return self.f.write(data)

        def __getattr__(self, name):
            return getattr(self.f, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    out = tmp_path / "s.vdb"
    out.write_bytes(b"previous")
    monkeypatch.setattr(vdb, "open", lambda p, mode="r": Full(builtins.open(p, mode)), raising=False)
    with pytest.raises(OutputError, match="disk full"):
        F.write(spot, out)
    assert out.read_bytes() == b"previous" and [p.name for p in tmp_path.iterdir()] == ["s.vdb"]
    monkeypatch.setattr(vdb, "_tree", lambda g: (_ for _ in ()).throw(KeyboardInterrupt()))
    with pytest.raises(KeyboardInterrupt):
        F.write(spot, tmp_path / "t.vdb")
    assert [p.name for p in tmp_path.iterdir()] == ["s.vdb"]
    monkeypatch.undo()
    assert main(["convert", SPOT, "-o", str(tmp_path / "no" / "x.vdb"), "-r", "8"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "output folder does not exist" in err


@needs_openvdb
def test_float_density_is_stored_as_is(tmp_path):
    v = geovox.voxelize(SPOT, shape=(20, 24, 28), density="coverage", density_dtype="float32",
                        backend="numpy")
    F.write(v, tmp_path / "f.vdb")
    g = openvdb_read(tmp_path / "f.vdb", v.shape)["density"]
    np.testing.assert_array_equal(g["values"], v.density)
    np.testing.assert_array_equal(g["active"], v.density > 0)
    back = F.read(tmp_path / "f.vdb")
    assert back.density.dtype == np.float32
    np.testing.assert_array_equal(back.density, v.density)


@pytest.mark.parametrize("dtype", [np.float32, np.uint8, np.bool_])
@pytest.mark.parametrize("shape", [(37, 21, 19), (64, 64, 64), (8, 8, 9), (1, 1, 1)])
def test_block_extrema_compiled_and_numpy_agree(dtype, shape):
    from geovox.kernels import chosen

    rng = np.random.default_rng(sum(shape))
    raw = rng.random(shape) > 0.5 if dtype == np.bool_ else (rng.random(shape) * 4).astype(dtype)
    raw = np.asfortranarray(raw)
    pad = np.float32(3) if dtype == np.float32 else 0
    with chosen("numpy"):
        lo0, hi0 = vdb._block_extrema(raw, 8, pad)
    try:
        with chosen("compiled"):
            lo1, hi1 = vdb._block_extrema(raw, 8, pad)
    except geovox.errors.ParameterError:
        pytest.skip("the compiled kernels are not built")
    assert lo0.dtype == lo1.dtype and lo0.shape == lo1.shape
    np.testing.assert_array_equal(lo0, lo1)
    np.testing.assert_array_equal(hi0, hi1)
