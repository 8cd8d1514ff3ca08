"""Labelled volumes in the viewers: `geovox view` (PyVista, off-screen) and `view --html`.

The volumes are real conversions (the overlapping assembly of test_labels.py, written as an
OBJ with one ``o`` object per part), not hand-made label arrays: what the viewers get is what
`geovox convert --labels part` makes, through the files it writes.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from test_labels import assembly
from test_view_html import browser, decode_page, open_page, share, snapshot  # noqa: F401

import geovox
from geovox.cli import main


def write_obj(mesh, path):
    """``mesh`` as an OBJ with one ``o`` object per part (the part's name)."""
    lines, off = [], 0
    for k, name in enumerate(mesh.parts):
        faces = mesh.faces[mesh.face_part == k]
        used, inverse = np.unique(faces, return_inverse=True)
        lines.append(f"o {name}")
        lines += [f"v {a!r} {b!r} {c!r}" for a, b, c in mesh.vertices[used].tolist()]
        lines += [f"f {a + off + 1} {b + off + 1} {c + off + 1}"
                  for a, b, c in inverse.reshape(-1, 3)]
        off += len(used)
    path.write_text("\n".join(lines) + "\n")
    return str(path)


@pytest.fixture()
def labelled(tmp_path):
    """(obj path, the in-memory labelled volume at 40³)."""
    obj = write_obj(assembly(open_part=True), tmp_path / "asm.obj")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        vol = geovox.voxelize(obj, resolution=40, labels="part")
    return obj, vol


def drawn_table(vol):
    """The table entries a viewer draws: every label but the background, value/name/colour."""
    return [{"value": e["value"], "name": e["name"], "color": e["color"]}
            for e in vol.label_table if e["value"] > 0]


def test_html_page_of_a_labelled_conversion_carries_its_labels_and_table(labelled, tmp_path,
                                                                         capsys):
    obj, vol = labelled
    # A mesh voxelised by `view` itself, and the .h5 / .seg.nrrd that convert writes.
    h5, seg = tmp_path / "asm.h5", tmp_path / "asm.seg.nrrd"
    for out in (h5, seg):
        assert main(["convert", obj, "-r", "40", "--labels", "part", "-o", str(out), "-q"]) == 0
    for src in (obj, h5, seg):
        page = tmp_path / "asm.html"
        extra = ["-r", "40", "--labels", "part"] if src == obj else []
        assert main(["view", str(src), *extra, "--html", str(page)]) == 0, capsys.readouterr()
        meta, fields = decode_page(page.read_text(encoding="utf-8"))
        np.testing.assert_array_equal(fields["labels"], vol.labels)
        assert fields["labels"].dtype == np.uint8
        np.testing.assert_array_equal(fields["occupancy"], vol.occupancy)
        # geovox's own table (background first) is drawn without its background entry.
        assert meta["label_table"] == drawn_table(vol), src
        assert [e["name"] for e in meta["label_table"]] == ["box", "cut", "inner", "apart", "cup"]


def test_html_page_draws_the_labels_in_their_colours_with_a_legend(labelled, browser,  # noqa: F811
                                                                  tmp_path):
    obj, vol = labelled
    page = tmp_path / "asm.html"
    assert main(["view", obj, "-r", "40", "--labels", "part", "--html", str(page)]) == 0
    assert open_page(browser, page) is None
    legend = browser.find_element("id", "gv-legend").text
    for e in drawn_table(vol):
        assert f"{e['name']} ({e['value']})" in legend
    img = snapshot(browser).astype(int)
    # The box (blue 31, 119, 180) and the far box (red 214, 39, 40) face the camera, lit:
    # pixels whose hue is their table colour's.
    blue = (img[..., 2] > img[..., 1] + 30) & (img[..., 1] > img[..., 0] + 30)
    red = (img[..., 0] > 2 * img[..., 1] + 40) & (img[..., 0] > 2 * img[..., 2] + 40)
    assert share(blue) > 0.05 and share(red) > 0.005
    # Hiding the box hides its colour.
    assert browser.execute_script("return window.geovoxViewer.toggleLabel(1)") is False
    img = snapshot(browser).astype(int)
    blue = (img[..., 2] > img[..., 1] + 30) & (img[..., 1] > img[..., 0] + 30)
    assert share(blue) < 0.001


def close_to(img, rgb, tol=6):
    return int(np.count_nonzero(np.abs(img - np.asarray(rgb)).sum(axis=-1) <= tol))


def test_pyvista_view_draws_the_labels_in_their_colours_with_a_legend(labelled, tmp_path,
                                                                      capsys):
    pytest.importorskip("pyvista")
    from PIL import Image

    obj, vol = labelled
    h5 = tmp_path / "asm.h5"
    assert main(["convert", obj, "-r", "40", "--labels", "part", "-o", str(h5), "-q"]) == 0
    shots = {}
    for name, argv in (("labels", [str(h5)]), ("plain", [obj, "-r", "40"])):
        png = tmp_path / f"{name}.png"
        assert main(["view", *argv, "--screenshot", str(png)]) == 0
        with Image.open(png) as im:
            shots[name] = np.asarray(im.convert("RGB")).astype(int)
    capsys.readouterr()
    img, plain = shots["labels"], shots["plain"]
    # The legend's squares and names are in the table's exact colours (unlit), every label
    # listed, the hidden inclusion too; the plain view has none of them.
    for e in drawn_table(vol):
        assert close_to(img, e["color"][:3]) > 50, e
        assert close_to(plain, e["color"][:3]) == 0, e
    # The voxels are lit: the box's faces are shades of its blue, the far box's of its red.
    blue = (img[..., 2] > img[..., 1] + 20) & (img[..., 1] > img[..., 0] + 20)
    red = (img[..., 0] > 2 * img[..., 1] + 30) & (img[..., 0] > 2 * img[..., 2] + 30)
    assert share(blue) > 0.05 and share(red) > 0.01


def test_pyvista_legend_is_shortened_past_its_most():
    pytest.importorskip("pyvista")
    from geovox.view import LEGEND_MOST, _labelled

    vol = geovox.voxelize(assembly(), resolution=8, labels="part")
    table = [dict(vol.label_table[1], value=k + 1, name=f"p{k + 1}") for k in range(30)]
    vol.label_table = [vol.label_table[0], *table]
    shown, legend = _labelled(vol)
    assert len(legend) == LEGEND_MOST + 1 and legend[-1][0] == f"... {30 - LEGEND_MOST} more"
    assert shown.colors is not None and shown.density is None and shown.sdf is None
    # A volume without labels is drawn as it is.
    plain = geovox.voxelize(assembly(), resolution=8)
    same, none = _labelled(plain)
    assert same is plain and none == []
