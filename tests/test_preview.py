"""Pictures: the headless PNG preview and the 3D viewer's off-screen screenshot."""

from __future__ import annotations

import sys

import numpy as np
import pytest
from PIL import Image

import geovox
from geovox import preview
from geovox.cli import main

from conftest import SPOT


def one_voxel_volume(colour=True):
    """8 x 6 x 4 grid with one inside voxel at (2, 4, 1), red when coloured."""
    occ = np.zeros((8, 6, 4), bool, order="F")
    occ[2, 4, 1] = True
    colors = None
    if colour:
        base = np.zeros((4, 6, 8, 4), np.uint8)
        colors = base.transpose(2, 1, 0, 3)
        colors[2, 4, 1] = (255, 0, 0, 255)
    grid = geovox.Grid(np.zeros(3), np.array([8.0, 6.0, 4.0]), (8, 6, 4))
    return geovox.Volume(occupancy=occ, grid=grid, backend="test", colors=colors)


def test_composite_pixels_of_a_known_volume():
    v = one_voxel_volume()
    bg = np.array(preview.BACKGROUND, float)
    # Along z: x right, y up -> row = ny - 1 - y, column = x.
    img = preview.composite(v, 2)
    assert img.shape == (6, 8, 3)
    r, c = 6 - 1 - 4, 2
    a = preview.ALPHA
    shade = 0.55 + 0.45 * (1 - (4 - 1 - 1) / 3)  # depth of z = 1 seen from z = 3
    np.testing.assert_allclose(img[r, c], a * shade * np.array([255, 0, 0]) + (1 - a) * bg)
    mask = np.ones((6, 8), bool)
    mask[r, c] = False
    np.testing.assert_allclose(img[mask], np.broadcast_to(bg, (mask.sum(), 3)))
    # Along x: y right, z up; along y: x right, z up.
    assert preview.composite(v, 0).shape == (4, 6, 3)
    assert np.argwhere(preview.composite(v, 0)[..., 0] > bg[0] + 1).tolist() == [[4 - 1 - 1, 4]]
    assert np.argwhere(preview.composite(v, 1)[..., 0] > bg[0] + 1).tolist() == [[4 - 1 - 1, 2]]


def test_grey_composite_and_slices_without_colour():
    v = one_voxel_volume(colour=False)
    img = preview.composite(v, 2)
    px = img[1, 2]
    assert px[0] == px[1] and np.all(px > np.array(preview.BACKGROUND))
    s = preview.middle_slice(v, 2)  # z = 2: empty
    assert np.all(s == np.array(preview.BACKGROUND))
    s = preview.middle_slice(v, 0)  # x = 4: empty
    assert np.all(s == np.array(preview.BACKGROUND))
    occ = v.occupancy.copy()
    occ[4, 4, 1] = True
    v2 = geovox.Volume(occupancy=occ, grid=v.grid, backend="test")
    s = preview.middle_slice(v2, 0)
    assert np.all(s[4 - 1 - 1, 4] == 255)


def test_preview_png_has_the_panels_and_text(tmp_path):
    vol = geovox.voxelize(SPOT, resolution=32, color=True)
    out = preview.write_preview(vol, tmp_path / "p.png", panel=120)
    with Image.open(out) as im:
        img = np.asarray(im.convert("RGB"))
    assert img.shape[1] == 3 * 120 + 4 * 10
    # spot's colours appear (white body, dark patches) and the footer text is white
    assert (img.reshape(-1, 3) == 255).all(axis=1).any()
    assert len(np.unique(img.reshape(-1, 3), axis=0)) > 50


def test_preview_command_on_mesh_and_volume(tmp_path, capsys):
    assert main(["preview", SPOT, "-o", str(tmp_path / "m.png"), "-r", "24"]) == 0
    assert main(["convert", SPOT, "-o", str(tmp_path / "v.h5"), "-r", "24", "--color", "-q",
                 "--preview", str(tmp_path / "c.png")]) == 0
    assert main(["preview", str(tmp_path / "v.h5"), "-o", str(tmp_path / "v.png")]) == 0
    for name in ("m.png", "c.png", "v.png"):
        with Image.open(tmp_path / name) as im:
            assert im.size[0] > 500


def test_default_output_name_carries_grid_and_type(tmp_path, capsys):
    assert main(["convert", SPOT, "-o", str(tmp_path), "--shape", "12", "10", "8", "-q"]) == 0
    names = sorted(p.name for p in tmp_path.iterdir())
    assert "spot_12x10x8_uint8.raw" in names and "spot_12x10x8_uint8.mhd" in names
    sub = tmp_path / "vox"
    sub.mkdir()
    assert main(["convert", SPOT, "-o", str(sub), "-r", "9", "--format", "vox", "-q", "--shell"]) == 0
    assert [p.name for p in sub.iterdir()] == ["spot_9x9x9_uint8.vox"]


def test_view_screenshot_off_screen(tmp_path, capsys):
    pytest.importorskip("pyvista")
    shot = tmp_path / "view.png"
    assert main(["view", SPOT, "-r", "24", "--color", "--mesh", SPOT, "--screenshot", str(shot)]) == 0
    with Image.open(shot) as im:
        img = np.asarray(im.convert("RGB"))
    assert img.shape[0] > 100 and len(np.unique(img.reshape(-1, 3), axis=0)) > 20
    assert main(["convert", SPOT, "-o", str(tmp_path / "v.npz"), "-r", "16", "-q"]) == 0
    assert main(["view", str(tmp_path / "v.npz"), "--screenshot", str(tmp_path / "v2.png")]) == 0
    with Image.open(tmp_path / "v2.png") as im:
        assert im.size[0] > 100


def test_view_without_pyvista_says_how_to_install(tmp_path, monkeypatch, capsys):
    monkeypatch.setitem(sys.modules, "pyvista", None)
    assert main(["view", SPOT, "-r", "8", "--screenshot", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "pip install -e '.[view]'" in err and err.count("\n") == 1
