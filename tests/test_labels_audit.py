"""Issue 22's "done means" and bad-input list, where test_labels*.py left a case out.

* slabs give the whole grid's labels under every overlap rule, on every backend (the exact
  voxel-for-voxel test of each rule is test_labels.py's, on every backend too);
* on the command line each bad input is one line on stderr, exit status 2, nothing written:
  more than 65,535 labels, fractions of materials, an unknown overlap rule without labels;
  and ``--labels file`` with one input gives one label named after the file.
"""

from __future__ import annotations

import struct
import warnings

import numpy as np
import pytest
import trimesh
from test_labels import assembly

import geovox
from geovox import formats
from geovox import labels as L
from geovox.cli import main
from geovox.grid import make_grid
from geovox.block import voxelize_block


@pytest.mark.parametrize("overlap", L.OVERLAPS)
def test_slabs_give_the_whole_grid_labels_under_every_rule(backend, overlap):
    m = assembly(open_part=True)
    grid = make_grid(m.bounds, shape=(24, 20, 21))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        p = geovox.plan(m, dict(shape=grid.shape, backend=backend, labels="part",
                                overlap=overlap))
        whole = voxelize_block(m, p)
        slabs = [voxelize_block(m, p, b) for b in [(0, 5), (5, 6), (6, 13), (13, 21)]]
    np.testing.assert_array_equal(np.concatenate([s.labels for s in slabs], axis=2),
                                  whole.labels)
    assert sum(s.contested for s in slabs) == whole.contested > 0


def _many_triangles_stl(path, n):
    """A binary STL of ``n`` separate triangles (``n`` connected components)."""
    k = np.arange(n)
    base = np.stack([k % 256, k // 256, np.zeros(n)], axis=1).astype(np.float32) * 2
    rec = np.zeros(n, dtype=[("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
    rec["v"][:, 0] = base
    rec["v"][:, 1] = base + np.float32([1, 0, 0])
    rec["v"][:, 2] = base + np.float32([0, 1, 0])
    with open(path, "wb") as f:
        f.write(b"\0" * 80 + struct.pack("<I", n) + rec.tobytes())
    return str(path)


def _one_line_status_2(capsys, argv, words, out):
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and "Traceback" not in err[0], err
    assert not out.exists()


def test_cli_more_than_65535_labels(tmp_path, capsys):
    stl = _many_triangles_stl(tmp_path / "many.stl", L.MAX_LABELS + 1)
    out = tmp_path / "many.npz"
    _one_line_status_2(capsys, ["convert", stl, "--labels", "component", "-r", "8", "-o",
                                str(out)], "holds at most 65,535", out)


def test_cli_fractions_of_materials_and_overlap_choices(tmp_path, capsys):
    a = tmp_path / "a.stl"
    trimesh.creation.box().export(a)
    out = tmp_path / "x.h5"
    _one_line_status_2(capsys, ["convert", str(a), "-o", str(out), "--labels", "material",
                                "--fractions"], "`fractions` are per part", out)
    _one_line_status_2(capsys, ["convert", str(a), "-o", str(out), "--overlap", "largest"],
                       "invalid choice", out)


def test_cli_labels_file_with_one_input_is_one_label(tmp_path, capsys):
    a = tmp_path / "liver.stl"
    trimesh.creation.box().export(a)
    out = tmp_path / "one.seg.nrrd"
    assert main(["convert", str(a), "--labels", "file", "-r", "12", "-o", str(out)]) == 0
    assert "labels file: 1 (liver)" in capsys.readouterr().out
    back = formats.read(out)
    assert [e["name"] for e in back.label_table] == ["background", "liver"]
    np.testing.assert_array_equal(back.labels, back.occupancy.astype(np.uint8))
