"""``labels="feature"``: glTF ``EXT_mesh_features`` feature IDs as labels (3D Tiles, BIM).

The files are boxes side by side, each a primitive with its own feature ID set, so the
label of every voxel is known: a box's voxels carry its feature, and the volume of each
label is the box's.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import geovox
from geovox.cli import main
from geovox.errors import MeshError

from test_gltf_reader import Builder, _box, draco_with_features

R = 30


def _boxes(path, sets, extra_accessor=None):
    """Boxes along x, box i over [2i, 2i+1]; ``sets[i]``: (ids per vertex or None, featureIds entry)."""
    b = Builder()
    for i, (ids, entry) in enumerate(sets):
        v, f = _box((2.0 * i, 0.0, 0.0), (2.0 * i + 1, 1.0, 1.0))
        attrs = {"POSITION": b.accessor(v.astype("f4"))}
        if ids is not None:
            attrs["_FEATURE_ID_0"] = b.accessor(np.broadcast_to(ids, len(v)).copy())
        ext = {} if entry is None else {"EXT_mesh_features": {"featureIds": [entry]}}
        b.mesh(attrs, b.accessor(f.reshape(-1).astype("u4")), extensions=ext)
    b.h["extensionsUsed"] = ["EXT_mesh_features"]
    b.write(path)
    return str(path)


def _names(vol):
    return [e["name"] for e in vol.label_table[1:]]


def test_each_feature_is_a_label_with_its_box_inside(tmp_path):
    path = _boxes(tmp_path / "f.glb", [
        (np.uint16(7), {"featureCount": 1, "attribute": 0}),
        (np.uint8(3), {"featureCount": 1, "attribute": 0}),
        (np.float32(9), {"featureCount": 1, "attribute": 0, "nullFeatureId": 9}),
        (None, None),
    ])
    mesh = geovox.load_mesh(path)
    box = (mesh.triangles[:, :, 0].mean(axis=1) // 2).astype(int)  # parts in trimesh's order
    np.testing.assert_array_equal(mesh.face_feature, np.array([7, 3, -1, -1])[box])
    vol = geovox.voxelize(path, resolution=R, labels="feature")
    # in ID order; the null ID and the primitive without a set are "(no feature)"
    assert _names(vol) == ["feature 3", "feature 7", "(no feature)"]
    assert [e["source"] for e in vol.label_table[1:]] == ["feature"] * 3
    x = vol.grid.centres(0)
    expect = np.zeros(vol.labels.shape, np.uint8)
    for k, label in enumerate((2, 1, 3, 3)):
        expect[(x > 2 * k) & (x < 2 * k + 1)] = label
    # the grid's y and z centres are all inside [0, 1]: a box fills its columns
    np.testing.assert_array_equal(vol.labels, expect)
    vols = {e["name"]: e["volume"] for e in vol.label_table[1:]}
    assert vols["feature 3"] == pytest.approx(vols["feature 7"]) and \
        vols["(no feature)"] == pytest.approx(2 * vols["feature 3"])


def test_implicit_ids_are_vertex_indices(tmp_path):
    # neither attribute nor texture: the ID is the vertex index, so a face takes its
    # first corner's index; the box's faces then give several features.
    path = _boxes(tmp_path / "i.glb", [(None, {"featureCount": 8})])
    mesh = geovox.load_mesh(path)
    v, f = _box()
    np.testing.assert_array_equal(mesh.face_feature, f[:, 0])


def test_ids_in_a_texture_are_not_read_and_said(tmp_path):
    path = _boxes(tmp_path / "t.glb", [(None, {"featureCount": 1, "texture": {"index": 0}})])
    mesh = geovox.load_mesh(path)
    assert (mesh.face_feature == -1).all()
    assert any("feature IDs are in a texture" in p for p in mesh.problems)
    with pytest.warns(UserWarning, match="feature IDs are in a texture"):
        geovox.voxelize(path, resolution=8, labels="feature")


def test_a_missing_feature_attribute_is_damage_in_one_line(tmp_path, capsys):
    path = _boxes(tmp_path / "m.glb", [(None, {"featureCount": 1, "attribute": 2})])
    with pytest.raises(MeshError, match="_FEATURE_ID_2|attribute 2"):
        geovox.load_mesh(path)
    assert main(["convert", path, "-o", str(tmp_path / "m.npy"), "-r", "8"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "feature IDs" in err[0]
    assert not (tmp_path / "m.npy").exists()


def test_fractional_ids_are_damage(tmp_path):
    path = _boxes(tmp_path / "h.glb", [(np.float32(1.5), {"featureCount": 1, "attribute": 0})])
    with pytest.raises(MeshError, match="not whole"):
        geovox.load_mesh(path)


def test_without_feature_ids_falls_back_to_components(tmp_path):
    path = _boxes(tmp_path / "n.glb", [(None, None), (None, None)])
    assert geovox.load_mesh(path).face_feature is None
    with pytest.warns(UserWarning, match="no feature IDs"):
        vol = geovox.voxelize(path, resolution=R, labels="feature")
    assert _names(vol) == ["component 1", "component 2"]


def test_draco_primitive_with_a_feature_accessor(tmp_path):
    # a feature accessor outside the Draco stream and without a buffer view: zeros,
    # as the specification says; one feature.
    out = draco_with_features(tmp_path)
    mesh = geovox.load_mesh(out)
    assert (mesh.face_feature == 0).all() and len(mesh.faces) == 320
    vol = geovox.voxelize(out, resolution=16, labels="feature")
    assert _names(vol) == ["feature 0"] and vol.label_table[1]["voxels"] == vol.occupancy.sum()


def test_cli_writes_the_feature_labels_and_info_lists_them(tmp_path, capsys):
    path = _boxes(tmp_path / "c.glb", [
        (np.uint16(1), {"featureCount": 1, "attribute": 0}),
        (np.uint16(2), {"featureCount": 1, "attribute": 0})])
    out = tmp_path / "c.seg.nrrd"
    assert main(["convert", path, "--labels", "feature", "-r", "16", "-o", str(out), "-q"]) == 0
    assert out.exists()
    assert main(["info", path]) == 0
    text = capsys.readouterr().out
    assert "labels feature: 2" in text and "feature 1: 12 triangles, closed" in text


def test_a_scene_of_files_keeps_each_files_features(tmp_path):
    a = _boxes(tmp_path / "a.glb", [(np.uint16(5), {"featureCount": 1, "attribute": 0})])
    b = tmp_path / "b.obj"
    v, f = _box((3, 0, 0), (4, 1, 1))
    b.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v)
                 + "".join(f"f {i + 1} {j + 1} {k + 1}\n" for i, j, k in f))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        vol = geovox.voxelize([a, str(b)], resolution=R, labels="feature")
    assert _names(vol) == ["feature 5", "(no feature)"]


def _open_boxes(path):
    """Two boxes without their top faces, features 1 and 2."""
    b = Builder()
    for i in range(2):
        v, f = _box((2.0 * i, 0.0, 0.0), (2.0 * i + 1, 1.0, 1.0))
        top = v[f].mean(axis=1)[:, 2] > 0.99
        attrs = {"POSITION": b.accessor(v.astype("f4")),
                 "_FEATURE_ID_0": b.accessor(np.full(len(v), i + 1, np.uint16))}
        b.mesh(attrs, b.accessor(f[~top].reshape(-1).astype("u4")),
               extensions={"EXT_mesh_features": {"featureIds": [{"featureCount": 1,
                                                                 "attribute": 0}]}})
    b.write(path)
    return str(path)


def test_surface_labels_choose_no_inside_test_and_say_surface(tmp_path, capsys):
    # Surface voxels alone need no part's inside test: no repair, no warning about one,
    # and the summary says what ran.
    path = _open_boxes(tmp_path / "o.glb")
    out = tmp_path / "o.ply"
    assert main(["convert", path, "--labels", "feature", "--occupancy", "surface", "-r", "16",
                 "-o", str(out)]) == 0
    said = capsys.readouterr()
    text = said.out + said.err
    assert "not closed" not in text and "repaired" not in text
    assert "occupancy surface (the voxels the surface passes through)" in text
    assert "inside test" not in text


def test_open_parts_are_said_in_one_line(tmp_path, capsys):
    # The plan's choice of each part's inside test is said once for all the parts (the
    # command line used to print one warning per open part, the library none).
    path = _open_boxes(tmp_path / "p.glb")
    assert main(["convert", path, "--labels", "feature", "-r", "16",
                 "-o", str(tmp_path / "p.npz")]) == 0
    said = capsys.readouterr()
    assert "labels feature: 2" in said.out + said.err
    assert "[feature 1]" not in said.err and "[feature 2]" not in said.err
    assert said.err.count("warning") == 1
    assert "2 of 2 feature labels are not closed or not consistently wound" in said.err
    with pytest.warns(UserWarning, match="2 of 2 feature labels are not closed"):
        geovox.voxelize(path, resolution=8, labels="feature")
