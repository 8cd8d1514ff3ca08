"""Labels alongside colour, density and distance: the same bytes as without labels.

Labels add fields; they do not change the others. On real multi-part models (the
overlapping assembly of test_labels.py written as an OBJ of objects, with an open cup;
trimesh's two_objects.obj; the Cornell box, eight OBJ objects with materials):

* ``colors`` (exact and fast) equal the no-labels colours byte for byte;
* ``density`` equals the no-labels density (the whole mesh's coverage, whichever label
  source; a part's share of it is ``fractions``);
* ``sdf`` is the signed distance of the union of the labels (``labels != 0``), which is the
  no-labels distance wherever that union is the whole mesh's inside.

The Cornell box is the case where it is not: its walls are open single-sided planes, each a
part with no inside of its own, while the whole mesh's winding number fills the room; by part
only the two blocks are inside (the union), by component the walls merged into one room whose
own winding number fills the grid. There colours are compared where both are inside and the
distance is the union's.
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest
from conftest import corpus
from test_labels import assembly
from test_labels_view import write_obj

import geovox
from geovox import formats
from geovox.cli import main
from geovox.density import signed_distance
from geovox.io.load import load_mesh

KW = dict(resolution=24, density="coverage", sdf=True, supersample=2)


@pytest.fixture(scope="module")
def asm_obj(tmp_path_factory):
    return write_obj(assembly(open_part=True), tmp_path_factory.mktemp("asm") / "asm.obj")


def _voxelize(model, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return geovox.voxelize(model, **KW, **kw)


@pytest.mark.parametrize("color", [True, "fast"])
@pytest.mark.parametrize("source", ["part", "component", "material"])
@pytest.mark.parametrize("model", ["asm", "two_objects", "cornell"])
def test_colour_density_and_sdf_are_the_same_with_labels(backend, model, source, color,
                                                         asm_obj):
    path = {"asm": asm_obj, "two_objects": corpus("trimesh_edge_cases", "two_objects.obj"),
            "cornell": corpus("cornell_box", "cornell_box.obj")}[model]
    ref = _voxelize(path, color=color, backend=backend)
    got = _voxelize(path, color=color, backend=backend, labels=source)
    assert got.labels is not None and got.labels.any()
    np.testing.assert_array_equal(got.occupancy, got.labels != 0)
    np.testing.assert_array_equal(got.density, ref.density)
    union = got.occupancy
    if model == "cornell" and source != "material":
        # The parts' union is not the whole mesh's room: by part the two blocks alone, by
        # component the walls' merged room under its own winding number.
        assert not np.array_equal(union, ref.occupancy)
        both = union & ref.occupancy
        assert both.sum() > 500
        np.testing.assert_array_equal(got.colors[both], ref.colors[both])
        assert not got.colors[~union].any()
        mesh = load_mesh(path)
        np.testing.assert_array_equal(got.sdf, signed_distance(mesh, got.grid, union, band=3.0))
    else:
        np.testing.assert_array_equal(union, ref.occupancy)
        assert got.colors.tobytes() == ref.colors.tobytes()
        assert got.sdf.tobytes() == ref.sdf.tobytes()


#: What each label format keeps of a conversion with labels, colour, density, distance and
#: fractions (the rest of the fields go to the formats that hold them).
HOLDS = {
    "h5": {"labels", "colors", "density", "sdf", "fractions"},
    "npz": {"labels", "colors", "density", "sdf", "fractions"},
    "vtkhdf": {"labels", "colors", "density", "sdf"},
    "zarr": {"labels", "colors", "density", "sdf"},
    "nrrd": {"labels", "colors", "density", "sdf"},
    "raw": {"labels", "colors", "density", "sdf"},
    "nii.gz": {"labels", "colors", "density", "sdf"},
    "seg.nrrd": {"labels"},
    "vox": {"labels"},
}


@pytest.fixture(scope="module")
def everything(asm_obj):
    return _voxelize(asm_obj, color=True, labels="part", fractions=True)


def _labels_of(path, ext, back, table):
    if ext == "zarr":
        zarr = pytest.importorskip("zarr")
        return zarr.open_group(path, mode="r")["labels/labels/0"][...].transpose(2, 1, 0)
    if ext == "vox":
        # One palette entry per label, in its table colour: the labels come back as colours
        # (the volume's colours are not written: the .vox has one palette).
        lut = {tuple(e["color"]): e["value"] for e in table[1:]}
        flat = back.colors.reshape(-1, 4, order="F").tolist()
        return np.array([lut.get(tuple(c), 0) for c in flat], np.uint8).reshape(
            back.shape, order="F")
    return back.labels


@pytest.mark.parametrize("ext", sorted(HOLDS))
def test_cli_writes_labels_colour_density_sdf_and_fractions_together(ext, asm_obj, everything,
                                                                     tmp_path, capsys):
    out = str(tmp_path / f"all.{ext}")
    assert main(["convert", asm_obj, "-r", "24", "--labels", "part", "--color", "--density",
                 "coverage", "--sdf", "--supersample", "2", "--fractions", "-o", out, "-q"]) == 0
    capsys.readouterr()
    back = formats.read_volume(out)
    np.testing.assert_array_equal(back.occupancy, everything.occupancy)
    np.testing.assert_array_equal(_labels_of(out, ext, back, everything.label_table),
                                  everything.labels)
    for field in ("colors", "density", "sdf"):
        if field in HOLDS[ext]:
            assert np.asarray(getattr(back, field)).tobytes() == \
                getattr(everything, field).tobytes(), field
    if "fractions" in HOLDS[ext]:
        if ext == "h5":
            h5py = pytest.importorskip("h5py")
            with h5py.File(out) as f:
                frac = f["fractions"][...]
        else:
            with np.load(out) as z:
                frac = z["fractions"]
        np.testing.assert_array_equal(frac, everything.fractions)
    assert os.path.exists(out)
