"""binvox's `-d N` cube: `-r N` for .binvox, `--cube` / `fit="cube"` for any format.

binvox's own definition (its file-format page): the model's bounding box is
translated to the origin and scaled by 1 / (its longest side), the unit cube is
voxelised at `dim`³, and the header's `translate` and `scale` undo that, so the
centre of voxel (i, j, k) is `translate + scale * ((i, j, k) + 0.5) / dim`.
`-cb` centres the model in the cube instead.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import geovox
from conftest import SPOT, box_mesh
from geovox.cli import main
from geovox.errors import ParameterError


def read_binvox(data: bytes):
    """``(occupancy [x, y, z], dim, translate, scale)`` read from the definition alone."""
    end = data.index(b"data\n") + len(b"data\n")
    lines = data[:end].decode("ascii").splitlines()
    assert lines[0] == "#binvox 1" and lines[-1] == "data"
    head = {line.split()[0]: line.split()[1:] for line in lines[1:-1]}
    d, e, f = (int(v) for v in head["dim"])
    assert d == e == f
    pairs = np.frombuffer(data, np.uint8, offset=end)
    flat = np.repeat(pairs[0::2], pairs[1::2])
    assert flat.size == d ** 3
    # y fastest, then z, then x
    occ = flat.reshape(d, d, d).transpose(0, 2, 1) == 1
    return occ, d, np.array([float(v) for v in head["translate"]]), float(head["scale"][0])


def _mesh_box(path=SPOT):
    from geovox.io.load import load_mesh

    return np.asarray(load_mesh(path).bounds, dtype=np.float64)


@pytest.mark.parametrize("centre", [False, True])
def test_r_for_binvox_is_binvox_d(tmp_path, centre):
    out = tmp_path / "spot.binvox"
    assert main(["convert", SPOT, "-o", str(out), "-r", "24", "-q",
                 *(["--cube-center"] if centre else [])]) == 0
    occ, dim, translate, scale = read_binvox(out.read_bytes())
    lo, hi = _mesh_box()
    edge = (hi - lo).max()
    assert dim == 24
    assert scale == pytest.approx(edge, rel=1e-12)
    want = (lo + hi) / 2 - edge / 2 if centre else lo
    np.testing.assert_allclose(translate, want, rtol=0, atol=1e-12)
    # The model fills the longest axis exactly and sits inside the cube.
    longest = int(np.argmax(hi - lo))
    assert translate[longest] == pytest.approx(lo[longest], abs=1e-12)
    vol = geovox.voxelize(SPOT, resolution=24, fit="cube-center" if centre else "cube",
                          backend="numpy")
    np.testing.assert_array_equal(occ, vol.occupancy)
    # The format's voxel centres are the grid's, on every axis.
    i = np.arange(dim)
    for a in range(3):
        np.testing.assert_allclose(translate[a] + scale * (i + 0.5) / dim,
                                   vol.grid.centres(a), rtol=0, atol=1e-12)
    # And the same voxels as a plain box grid over that cube: fit only chooses the region.
    plain = geovox.voxelize(SPOT, resolution=24, bounds=(*translate, *(translate + scale)),
                            backend="numpy")
    np.testing.assert_array_equal(occ, plain.occupancy)
    assert occ.sum() == vol.inside_count > 0


def test_cube_of_a_box_is_exact():
    # A 2 x 1 x 0.5 box: -r 8 gives voxels of 0.25 and a 2-unit cube.
    box = box_mesh((1.0, 2.0, 3.0), (3.0, 3.0, 3.5))
    vol = geovox.voxelize(box, resolution=8, fit="cube", backend="numpy")
    np.testing.assert_allclose(vol.spacing, 0.25)
    np.testing.assert_allclose(vol.bounds, [(1, 2, 3), (3, 4, 5)])
    idx = np.argwhere(vol.occupancy)
    assert len(idx) == 8 * 4 * 2
    assert idx.min(axis=0).tolist() == [0, 0, 0] and idx.max(axis=0).tolist() == [7, 3, 1]
    # -cb: centred in y and z (the cube starts at 1.5 and 2.25), x unchanged.
    cen = geovox.voxelize(box, resolution=8, fit="cube-center", backend="numpy")
    np.testing.assert_allclose(cen.bounds, [(1, 1.5, 2.25), (3, 3.5, 4.25)])
    idx = np.argwhere(cen.occupancy)
    assert len(idx) == 64
    assert idx.min(axis=0).tolist() == [0, 2, 3] and idx.max(axis=0).tolist() == [7, 5, 4]


def test_binvox_cube_through_trimesh(tmp_path):
    from trimesh.exchange.binvox import load_binvox

    out = tmp_path / "spot.binvox"
    assert main(["convert", SPOT, "-o", str(out), "-r", "20", "-q"]) == 0
    occ, dim, translate, scale = read_binvox(out.read_bytes())
    with open(out, "rb") as f:
        grid = load_binvox(f)
    np.testing.assert_array_equal(np.asarray(grid.matrix), occ)
    # trimesh reads `translate` as voxel 0's centre and `scale` as pitch * (dim - 1)
    # (see the README): the same numbers, another reading.
    np.testing.assert_allclose(grid.transform[:3, 3], translate)
    np.testing.assert_allclose(np.diag(grid.transform)[:3], scale / (dim - 1))
    # And geovox reads what trimesh writes: the same voxels.
    from trimesh.exchange.binvox import export_binvox
    from trimesh.voxel import VoxelGrid

    # (From a dense grid: re-encoding the loaded run-length grid overflows
    # trimesh's uint8 run lengths.)
    (tmp_path / "t.binvox").write_bytes(export_binvox(VoxelGrid(np.asarray(grid.matrix),
                                                                transform=grid.transform)))
    back = geovox.formats.read(tmp_path / "t.binvox")
    np.testing.assert_array_equal(back.occupancy, occ)


def test_cube_for_any_format(tmp_path):
    out = tmp_path / "spot.raw"
    assert main(["convert", SPOT, "-o", str(out), "-r", "16", "--cube", "-q"]) == 0
    meta = json.loads((tmp_path / "spot.json").read_text())
    lo, hi = _mesh_box()
    edge = (hi - lo).max()
    assert meta["shape"] == [16, 16, 16]
    np.testing.assert_allclose(meta["bounds"], [lo, lo + edge], atol=1e-12)
    np.testing.assert_allclose(meta["spacing"], edge / 16)
    vol = geovox.voxelize(SPOT, resolution=16, fit="cube", backend="numpy")
    np.testing.assert_array_equal(geovox.formats.read(out).occupancy, vol.occupancy)
    # Without --cube a .raw keeps N voxels per axis over the box.
    assert main(["convert", SPOT, "-o", str(tmp_path / "box.raw"), "-r", "16", "-q"]) == 0
    box = json.loads((tmp_path / "box.json").read_text())
    np.testing.assert_allclose(box["bounds"], [lo, hi], atol=1e-12)


def test_cube_through_convert_to_and_batch(tmp_path):
    from geovox.api import convert_to

    ref = geovox.voxelize(SPOT, resolution=16, fit="cube", backend="numpy")
    convert_to(SPOT, tmp_path / "s.h5", resolution=16, fit="cube", budget=16 * 16 * 4 * 30)
    np.testing.assert_array_equal(geovox.formats.read(tmp_path / "s.h5").occupancy, ref.occupancy)
    results = geovox.convert_many([SPOT], tmp_path / "out", fmt="binvox", resolution=16)
    assert [r.status for r in results] == ["ok"]
    assert results[0].output.endswith("spot_16x16x16_uint8.binvox")
    with open(results[0].output, "rb") as f:
        occ, dim, translate, _ = read_binvox(f.read())
    np.testing.assert_array_equal(occ, ref.occupancy)
    np.testing.assert_allclose(translate, ref.bounds[0], atol=1e-12)


def test_centred_cube_in_a_batch_and_over_given_bounds(tmp_path, capsys):
    # IM-NET asks binvox for `-bb ... -d 64`: the cube over the given box's longest side.
    bounds = (-1.0, -0.9, -0.8, 1.0, 0.5, 0.4)
    out = tmp_path / "b.binvox"
    assert main(["convert", SPOT, "-o", str(out), "-r", "10", "--bounds", *map(str, bounds),
                 "-q"]) == 0
    _, dim, translate, scale = read_binvox(out.read_bytes())
    assert dim == 10 and scale == pytest.approx(2.0)
    np.testing.assert_allclose(translate, bounds[:3], atol=1e-12)
    ref = geovox.voxelize(SPOT, resolution=12, fit="cube-center", backend="numpy")
    results = geovox.convert_many([SPOT], tmp_path / "out", fmt="npz", resolution=12,
                                  fit="cube-center")
    back = geovox.formats.read_volume(results[0].output)
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
    np.testing.assert_allclose(np.asarray(back.bounds), np.asarray(ref.bounds), atol=1e-12)
    # geovox info costs the same cube.
    assert main(["info", SPOT, "-r", "16", "--cube"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("grid"))
    edge = (_mesh_box()[1] - _mesh_box()[0]).max() / 16
    assert line.startswith(f"grid 16 x 16 x 16 = 4,096 voxels of {edge:.4g} x {edge:.4g} x {edge:.4g}")


def test_cube_options_are_checked():
    with pytest.raises(ParameterError, match="`fit` must be one of"):
        geovox.voxelize(SPOT, resolution=8, fit="sphere")
    with pytest.raises(ParameterError, match="cannot take `voxel_size`"):
        geovox.voxelize(SPOT, voxel_size=0.1, fit="cube")
    with pytest.raises(ParameterError, match="cannot take `shape`"):
        geovox.voxelize(SPOT, shape=(4, 5, 6), fit="cube")


def test_binvox_voxel_size_still_pads_and_shape_is_refused(tmp_path, capsys):
    assert main(["convert", SPOT, "-o", str(tmp_path / "v.binvox"), "--voxel-size", "0.1",
                 "-q"]) == 0
    assert "padded with empty voxels" in capsys.readouterr().err
    occ, dim, translate, scale = read_binvox((tmp_path / "v.binvox").read_bytes())
    assert scale == pytest.approx(0.1 * dim)
    assert main(["convert", SPOT, "-o", str(tmp_path / "s.binvox"), "--shape", "8", "9", "10"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "binvox needs cubic voxels" in err and "-r N" in err
    assert main(["convert", SPOT, "-o", str(tmp_path / "c.binvox"), "--shape", "8", "8", "8",
                 "--cube"]) == 2
    assert "cannot take `shape`" in capsys.readouterr().err


def test_formats_list_says_what_r_does(capsys):
    assert main(["formats"]) == 0
    line = next(x for x in capsys.readouterr().out.splitlines() if x.startswith("binvox"))
    assert "-d N" in line and "padded to a cube" not in line.split(";")[0]
