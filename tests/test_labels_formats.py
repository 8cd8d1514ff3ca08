"""Labelled volumes written and read back through independent readers."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import geovox
from geovox import formats
from geovox.errors import ParameterError

from test_labels import assembly


@pytest.fixture(scope="module")
def vol():
    v = geovox.voxelize(assembly(), shape=(26, 17, 21), labels="part")
    assert len(np.unique(v.labels)) == 5
    return v


def _table_matches(got, want, keys=("value", "name", "color")):
    assert [{k: e[k] for k in keys} for e in got] == [{k: e[k] for k in keys} for e in want]


def test_seg_nrrd_opens_in_slicerio(vol, tmp_path):
    slicerio = pytest.importorskip("slicerio")
    p = tmp_path / "scene.seg.nrrd"
    assert formats.write(vol, p) == [str(p)]
    seg = slicerio.read_segmentation(str(p))
    np.testing.assert_array_equal(seg["voxels"], vol.labels)
    assert seg["masterRepresentation"] == "Binary labelmap"
    assert seg["containedRepresentationNames"] == ["Binary labelmap"]
    assert [s["name"] for s in seg["segments"]] == [e["name"] for e in vol.label_table[1:]]
    for s, e in zip(seg["segments"], vol.label_table[1:]):
        assert s["labelValue"] == e["value"] and s["layer"] == 0
        assert s["id"] == f"Segment_{e['value']}"
        np.testing.assert_allclose(s["color"], np.asarray(e["color"][:3]) / 255, atol=1e-6)
        idx = np.argwhere(vol.labels == e["value"])
        assert s["extent"] == [int(x) for a in range(3) for x in (idx[:, a].min(), idx[:, a].max())]
    # The geometry: voxel centres, spacing.
    np.testing.assert_allclose(seg["ijkToLPS"][:3, 3], vol.grid.lo + 0.5 * np.asarray(vol.spacing))
    np.testing.assert_allclose(np.diag(seg["ijkToLPS"])[:3], vol.spacing)
    back = formats.read(p)
    np.testing.assert_array_equal(back.labels, vol.labels)
    _table_matches(back.label_table, vol.label_table)


def test_seg_nrrd_empty_segment_extent(tmp_path):
    slicerio = pytest.importorskip("slicerio")
    m = assembly()
    # A region holding only the first body: the far box's segment is empty.
    v = geovox.voxelize(m, shape=(10, 10, 10), bounds=(-1, -1, -1, 0.5, 1, 1), labels="part")
    p = tmp_path / "cut.seg.nrrd"
    formats.write(v, p)
    seg = slicerio.read_segmentation(str(p), skip_voxels=True)
    assert seg["segments"][3]["extent"] == [0, -1, 0, -1, 0, -1]


def test_seg_nrrd_without_labels_is_one_segment(tmp_path):
    """A volume without labels is one segment, label value 1, named after its source."""
    slicerio = pytest.importorskip("slicerio")
    v = geovox.voxelize(assembly(), resolution=8)
    v.source = "liver.obj"
    p = tmp_path / "x.seg.nrrd"
    formats.write(v, p)
    seg = slicerio.read_segmentation(str(p))
    assert [(s["name"], s["labelValue"]) for s in seg["segments"]] == [("liver", 1)]
    np.testing.assert_array_equal(seg["voxels"] == 1, v.occupancy)


def test_nrrd_label_map_with_key_values(vol, tmp_path):
    nrrd = pytest.importorskip("nrrd")
    p = tmp_path / "scene.nrrd"
    written = formats.write(vol, p)
    lpath = str(tmp_path / "scene_labels.nrrd")
    assert lpath in written
    data, header = nrrd.read(lpath)
    np.testing.assert_array_equal(data, vol.labels)
    assert header["label2"] == "cut|" + " ".join(str(c) for c in vol.label_table[2]["color"])
    _table_matches(json.loads(header["geovox_label_table"]), vol.label_table)


def test_h5_labels_and_table(vol, tmp_path):
    h5py = pytest.importorskip("h5py")
    p = tmp_path / "scene.h5"
    formats.write(vol, p)
    with h5py.File(p) as f:
        np.testing.assert_array_equal(f["labels"][...], vol.labels)
        assert f["labels"].dtype == np.uint8
        assert json.loads(f["labels"].attrs["label_table"]) == vol.label_table
        np.testing.assert_array_equal(f["VTKHDF/PointData/labels"][...].transpose(2, 1, 0),
                                      vol.labels)


def test_npz_labels_and_table(vol, tmp_path):
    p = tmp_path / "scene.npz"
    formats.write(vol, p)
    with np.load(p) as z:
        np.testing.assert_array_equal(z["labels"], vol.labels)
        assert json.loads(str(z["label_table"])) == vol.label_table


def test_raw_labels_and_table_in_the_json(vol, tmp_path):
    p = tmp_path / "scene.raw"
    formats.write(vol, p)
    meta = json.loads((tmp_path / "scene.json").read_text())
    assert meta["labels"]["dtype"] == "uint8"
    assert meta["labels"]["label_table"] == vol.label_table
    raw = np.fromfile(tmp_path / meta["labels"]["data_file"], dtype=np.uint8)
    np.testing.assert_array_equal(raw.reshape(vol.shape, order="F"), vol.labels)


def test_vtkhdf_point_data_and_field_data(vol, tmp_path):
    p = tmp_path / "scene.vtkhdf"
    formats.write(vol, p)
    code = f"""
import json, numpy as np, vtk
from vtk.util.numpy_support import vtk_to_numpy
r = vtk.vtkHDFReader(); r.SetFileName({str(p)!r}); r.Update()
o = r.GetOutput()
lab = vtk_to_numpy(o.GetPointData().GetArray("labels"))
fd = o.GetFieldData()
names = bytes(vtk_to_numpy(fd.GetArray("label_names"))).decode().split(chr(10))[:-1]
print(json.dumps({{"dims": o.GetDimensions(), "labels": lab.tolist(), "names": names,
                   "values": vtk_to_numpy(fd.GetArray("label_values")).tolist()}}))
"""
    pytest.importorskip("vtk")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    got = json.loads(out.stdout.strip().splitlines()[-1])
    assert tuple(got["dims"]) == vol.shape
    np.testing.assert_array_equal(np.asarray(got["labels"]).reshape(vol.shape, order="F"),
                                  vol.labels)
    assert got["names"] == [e["name"] for e in vol.label_table]
    assert got["values"] == [e["value"] for e in vol.label_table]


def test_fractions_in_h5_and_npz(tmp_path):
    h5py = pytest.importorskip("h5py")
    v = geovox.voxelize(assembly(), shape=(12, 9, 8), labels="part", fractions=True,
                        supersample=2)
    formats.write(v, tmp_path / "f.h5")
    formats.write(v, tmp_path / "f.npz")
    with h5py.File(tmp_path / "f.h5") as f:
        np.testing.assert_array_equal(f["fractions"][...], v.fractions)
    with np.load(tmp_path / "f.npz") as z:
        np.testing.assert_array_equal(z["fractions"], v.fractions)


def test_preview_draws_labels_in_their_colours_with_a_legend(vol, tmp_path):
    from PIL import Image

    from geovox.preview import write_preview

    p = write_preview(vol, tmp_path / "p.png")
    with Image.open(p) as im:
        img = np.asarray(im.convert("RGB")).reshape(-1, 3)
        height = im.height
    colours = {tuple(c) for c in np.unique(img, axis=0)}
    for e in vol.label_table[1:]:
        assert tuple(e["color"][:3]) in colours  # in the slices and the legend's swatches
    plain = geovox.voxelize(assembly(), shape=vol.shape)
    q = write_preview(plain, tmp_path / "q.png")
    with Image.open(q) as im:
        assert im.height < height  # the legend's row


def test_info_lists_the_parts_each_source_gives(capsys, tmp_path):
    from geovox.cli import main

    from conftest import corpus

    assert main(["info", corpus("cornell_box", "cornell_box.obj"), "-r", "8"]) == 0
    out = capsys.readouterr().out
    assert "labels part: 8" in out and "tall_block: 10 triangles, open, materials white" in out
    assert "labels component: 4" in out and "component 2: 12 triangles, closed" in out
    assert "labels material: 5" in out and "red: 2 triangles" in out


def test_cli_scene_of_files_into_a_segmentation(tmp_path, capsys):
    import trimesh

    from geovox.cli import main

    a, b = tmp_path / "liver.stl", tmp_path / "tumour.stl"
    trimesh.creation.box(extents=(1, 1, 1)).export(a)
    trimesh.creation.icosphere(radius=0.2).export(b)
    out = tmp_path / "scene.seg.nrrd"
    assert main(["convert", str(a), str(b), "--labels", "file", "--overlap", "smallest",
                 "-r", "20", "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "labels file: 2 (liver, tumour)" in text and "contested voxels" in text
    back = formats.read(out)
    assert [e["name"] for e in back.label_table[1:]] == ["liver", "tumour"]
    assert (back.labels == 2).sum() > 0 and (back.labels == 1).sum() > 0
    # Without --labels, several inputs are still a batch into a folder.
    folder = tmp_path / "batch"
    folder.mkdir()
    assert main(["convert", str(a), str(b), "-r", "8", "-o", str(folder) + "/", "-q"]) == 0
    assert len(list(folder.glob("*.raw"))) == 2


@pytest.mark.parametrize("argv, match", [
    (["--fractions"], "--fractions needs --labels"),
    (["--labels", "colour"], "invalid choice"),
    (["--labels", "part", "--overlap", "big"], "invalid choice"),
])
def test_cli_bad_label_options(tmp_path, capsys, argv, match):
    import trimesh

    from geovox.cli import main

    a = tmp_path / "a.stl"
    trimesh.creation.box().export(a)
    assert main(["convert", str(a), "-o", str(tmp_path / "x.npz")] + argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and match in err[0]
    assert not (tmp_path / "x.npz").exists()


def test_cli_scene_names_the_file_that_is_not_a_mesh(tmp_path, capsys):
    import trimesh

    from geovox.cli import main

    a = tmp_path / "a.stl"
    trimesh.creation.box().export(a)
    bad = tmp_path / "notes.stl"
    bad.write_text("hello")
    assert main(["convert", str(a), str(bad), "--labels", "file", "-o",
                 str(tmp_path / "s.seg.nrrd")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "notes.stl" in err[0]


@pytest.mark.parametrize("ext", ["vdb", "binvox", "npy"])
def test_formats_without_labels_refuse_them(vol, tmp_path, ext):
    with pytest.raises(ParameterError, match="does not hold labels"):
        formats.write(vol, tmp_path / f"x.{ext}")
    assert not list(tmp_path.iterdir())


def test_vox_one_palette_entry_per_label(vol, tmp_path):
    from geovox.formats.vox import decode

    p = tmp_path / "scene.vox"
    formats.write(vol, p)
    models, transforms, palette = decode(p.read_bytes())
    assert len(models) == 1  # a grid under 256 on every axis is one model
    size, xyzi = models[0]
    for e in vol.label_table[1:]:
        assert tuple(palette[e["value"] - 1][:3]) == tuple(e["color"][:3])
    got = np.zeros(vol.shape, np.uint8)
    got[xyzi[:, 0], xyzi[:, 1], xyzi[:, 2]] = xyzi[:, 3]
    np.testing.assert_array_equal(got, vol.labels)


def test_zarr_ome_labels_group(vol, tmp_path):
    zarr = pytest.importorskip("zarr")
    models = pytest.importorskip("ome_zarr_models.v05")
    p = tmp_path / "scene.zarr"
    formats.write(vol, p)
    root = zarr.open_group(str(p), mode="r")
    assert root["labels"].attrs["ome"]["labels"] == ["labels"]
    g = root["labels/labels"]
    np.testing.assert_array_equal(g["0"][...].transpose(2, 1, 0), vol.labels)
    meta = g.attrs["ome"]["image-label"]
    assert meta["source"] == {"image": "../../"}
    assert [c["rgba"] for c in meta["colors"]] == [e["color"] for e in vol.label_table[1:]]
    assert [q["name"] for q in meta["properties"]] == [e["name"] for e in vol.label_table[1:]]
    # Validated by ome-zarr-models: the image and its label image.
    from ome_zarr_models.v05.image import Image
    from ome_zarr_models.v05.image_label import ImageLabel

    Image.from_zarr(root)
    ImageLabel.from_zarr(g)
    # Coarser levels keep labels (the largest child).
    from geovox.formats.zarr import downsample

    a = np.zeros((4, 4, 4), np.uint8)
    a[0, 0, 1], a[3, 3, 3], a[2, 2, 2] = 2, 5, 7
    np.testing.assert_array_equal(downsample(a, "labels"),
                                  [[[2, 0], [0, 0]], [[0, 0], [0, 7]]])


def test_nifti_label_map_opens_in_nibabel_and_itk(vol, tmp_path):
    """NAME_labels.nii.gz: the labels with intent label, on the mask's affine, the table kept."""
    nibabel = pytest.importorskip("nibabel")
    p = str(tmp_path / "scene.nii.gz")
    files = formats.write(vol, p)
    lp = str(tmp_path / "scene_labels.nii.gz")
    assert files == [p, lp]
    img = nibabel.load(lp)
    assert img.header.get_intent()[0] == "label"
    np.testing.assert_array_equal(np.asarray(img.dataobj), vol.labels)
    np.testing.assert_allclose(img.affine, nibabel.load(p).affine)
    back = formats.read(p)
    np.testing.assert_array_equal(back.labels, vol.labels)
    _table_matches(back.label_table, vol.label_table)
    sitk = pytest.importorskip("SimpleITK")
    arr = sitk.GetArrayFromImage(sitk.ReadImage(lp))  # z, y, x
    np.testing.assert_array_equal(arr.transpose(2, 1, 0), vol.labels)
