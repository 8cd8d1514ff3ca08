"""The warning a messy model prints: at most two short lines, the details in `geovox info`.

The model: libigl's truck (tests/data/wild/truck.obj, SHREC 2009 by way of
libigl's tutorial data), 50 components, 1,388 open edges, 54 non-manifold:
it used to print one line of about 600 characters.
"""

from __future__ import annotations

import os
import re

import numpy as np
import pytest

import geovox
from geovox.cli import main
from geovox.errors import GeovoxWarning
from geovox.inside import captree

from conftest import DATA, SPOT

TRUCK = os.path.join(DATA, "wild", "truck.obj")
#: "short": a line a terminal shows whole, with the model's path in it.
SHORT = 145 + len(TRUCK)


def _warnings(err: str) -> list:
    return [line for line in err.splitlines() if line.startswith("geovox: warning: ")]


def test_the_truck_gets_one_short_line_pointing_to_info(tmp_path, capsys):
    assert main(["convert", TRUCK, "-o", str(tmp_path / "t.raw"), "-r", "12", "-q"]) == 0
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 1 and len(lines[0]) <= SHORT, lines
    line = lines[0]
    # What was wrong, what geovox did, where the details are.
    assert "truck.obj: not closed (1,388 open edges, 54 non-manifold)" in line
    assert "; inside by the winding number of a repaired copy; " in line
    assert line.endswith(f"; see geovox info {TRUCK}")
    # ... which prints them.
    assert main(["info", TRUCK]) == 0
    out = capsys.readouterr().out
    assert "3,290 faces flipped" in out and "66 pieces (6 closed, 50 turned outward" in out
    assert "1,440 edges without a partner" in out


def test_approximate_voxels_are_the_second_line(tmp_path, capsys, monkeypatch):
    # No time for the caps (the work budget of either traversal, processor seconds): the
    # estimate decides.
    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)
    assert main(["convert", TRUCK, "-o", str(tmp_path / "t.raw"), "-r", "12", "-q"]) == 0
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 2 and all(len(x) <= SHORT for x in lines), lines
    assert "not closed (1,388 open edges" in lines[0]
    m = re.fullmatch(r"geovox: warning: ([0-9,]+) of 1,728 voxels \(([0-9.]+) %\) are approximate; "
                     r"the holes' caps passed the work budget \(--inside vote is faster\)", lines[1])
    assert m, lines[1]
    n = int(m.group(1).replace(",", ""))
    assert 0 < n <= 1728 and float(m.group(2)) == pytest.approx(100 * n / 1728, abs=0.1)


def test_a_closed_copy_says_exact_and_an_unnamed_mesh_no_command():
    import trimesh

    from conftest import from_tm

    ball = trimesh.creation.icosphere(subdivisions=2)
    ball.faces[:30] = ball.faces[:30, ::-1]  # wound the wrong way, still closed
    with pytest.warns(GeovoxWarning) as record:
        geovox.voxelize(from_tm(ball, "ball"), resolution=8)
    (line,) = [str(r.message) for r in record]
    assert line == ("ball: not consistently wound (30 faces wound the wrong way); "
                    "inside by the winding number of a repaired, closed copy (exact)")


def test_batch_summary_gives_the_warning_one_short_cell(tmp_path, monkeypatch):
    from geovox.batch import CELL, summary_table

    monkeypatch.setattr(captree, "WORK_SECONDS", 0.0)  # either traversal's budget, of time
    results = geovox.convert_many([TRUCK, SPOT], tmp_path / "out", resolution=12)
    truck, spot = results
    assert truck.status == spot.status == "ok"
    cell = truck.note.split("; warning: ", 1)[1]
    assert len(cell) <= CELL
    assert cell.startswith("not closed (1,388 open edges, 54 non-manifold); ")
    assert re.search(r"[0-9,]+ of 1,728 voxels \([0-9.]+ %\) are approximate", cell)
    assert "warning" not in spot.note
    # The full text stays with the result.
    assert len(truck.warnings) == 2 and truck.warnings[0].endswith(f"geovox info {TRUCK}")
    row = next(x for x in summary_table(results).splitlines() if x.startswith("truck.obj"))
    assert row.count("\n") == 0 and len(row) < 250


def test_long_warnings_are_cut_in_the_cell():
    from geovox.batch import CELL, warning_cell

    cell = warning_cell(["m.obj: " + "x" * 200 + "; rest"], "/a/m.obj")
    assert len(cell) == CELL and cell.endswith("…") and not cell.startswith("m.obj")
    assert warning_cell(["a; b", "c"], "") == "a; c"
    np.testing.assert_equal(warning_cell([], "m.obj"), "")
