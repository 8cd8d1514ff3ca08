"""Surface voxels as a stage of a conversion (``occupancy="surface"`` / ``"both"``, ``--occupancy``).

The kernel's exactness is tests/test_surface.py's; here everything else composes
with it: ``both`` is solid | surface voxel for voxel, slabs and threads change
nothing, colour is the solid run's colour, labels by part keep thin parts,
``like`` works in index space, every writer takes a surface volume, the sparse
outputs (``.ply``, ``.npz --sparse``) read back, and bad input is one line.
"""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import trimesh

import geovox
from geovox import formats
from geovox.cli import main
from geovox.errors import GeovoxWarning
from geovox.mesh import Mesh

from conftest import SPOT, corpus

CORNELL = corpus("cornell_box", "cornell_box.obj")


def quiet(fn, *a, **k):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)
        return fn(*a, **k)


def sheet(z=0.5) -> Mesh:
    """An open square sheet at height ``z`` in the unit cube (two triangles)."""
    v = np.array([[0.1, 0.1, z], [0.9, 0.1, z], [0.9, 0.9, z], [0.1, 0.9, z]])
    return Mesh(vertices=v, faces=np.array([[0, 1, 2], [0, 2, 3]]), source="sheet")


def test_defaults_are_the_solid():
    a = geovox.voxelize(SPOT, resolution=24)
    b = geovox.voxelize(SPOT, resolution=24, occupancy="solid")
    np.testing.assert_array_equal(a.occupancy, b.occupancy)
    assert a.counts is None and b.counts is None
    assert geovox.Options().occupancy == "solid"


@pytest.mark.parametrize("model", [SPOT, CORNELL, corpus("trimesh_edge_cases", "wallhole.obj")])
def test_both_is_solid_or_surface(model):
    solid = quiet(geovox.voxelize, model, resolution=40)
    surface = quiet(geovox.voxelize, model, resolution=40, occupancy="surface")
    both = quiet(geovox.voxelize, model, resolution=40, occupancy="both")
    np.testing.assert_array_equal(both.occupancy, solid.occupancy | surface.occupancy)
    assert surface.counts == {"surface": surface.inside_count}
    assert both.counts == {"surface": surface.inside_count, "inside": solid.inside_count}
    assert surface.inside == "surface" and both.inside.endswith("+surface")


def test_an_open_sheet_is_one_layer():
    # The sheet lies inside layer 12 of a 24-voxel grid over the unit cube (z = 0.52).
    grid = dict(bounds=(0, 0, 0, 1, 1, 1), resolution=24)
    vol = geovox.voxelize(sheet(0.52), occupancy="surface", **grid)
    layers = np.flatnonzero(vol.occupancy.any(axis=(0, 1)))
    assert list(layers) == [12]
    # A sheet exactly on a voxel plane (z = 0.5 = 12 / 24): one layer, the one above it.
    vol = geovox.voxelize(sheet(0.5), occupancy="surface", **grid)
    assert list(np.flatnonzero(vol.occupancy.any(axis=(0, 1)))) == [12]
    # Solid: an open sheet holds nothing, and says so.
    import warnings

    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always", GeovoxWarning)
        assert geovox.voxelize(sheet(0.52), **grid).inside_count == 0
    assert any("empty" in str(w.message) for w in said)


def test_threads_and_slabs_change_nothing(tmp_path):
    opts = dict(shape=(20, 18, 150), occupancy="both", color=True)
    whole = geovox.voxelize(SPOT, jobs=1, **opts)
    np.testing.assert_array_equal(geovox.voxelize(SPOT, jobs=3, **opts).occupancy,
                                  whole.occupancy)
    for ext in ("h5", "ply", "raw"):
        info = geovox.convert_to(SPOT, tmp_path / f"s.{ext}", budget=20 * 18 * 64 * 30, **opts)
        assert info.slabs == 3 and info.counts == whole.counts
        back = formats.read_volume(tmp_path / f"s.{ext}")
        np.testing.assert_array_equal(back.occupancy, whole.occupancy)
        np.testing.assert_array_equal(back.colors[whole.occupancy],
                                      whole.colors[whole.occupancy])


def test_surface_alone_into_a_point_cloud_goes_as_bits(tmp_path, monkeypatch):
    # Slabs of bits handed to the writer as points: the same file as the volume
    # written whole, in one slab or several.
    import geovox.planner as planner

    opts = dict(shape=(40, 36, 150), occupancy="surface")
    whole = geovox.voxelize(SPOT, **opts)
    formats.write(whole, tmp_path / "whole.ply")
    expected = (tmp_path / "whole.ply").read_bytes()
    p = planner.plan(geovox.load_mesh(SPOT), opts, tmp_path / "s.ply")
    assert p.surface_points and p.route == planner.Route.SLABS and len(p.blocks) == 1
    assert not planner.plan(geovox.load_mesh(SPOT), dict(opts, occupancy="both"),
                            tmp_path / "s.ply").surface_points
    assert not planner.plan(geovox.load_mesh(SPOT), opts, tmp_path / "s.ply",
                            stream=False).surface_points
    assert not planner.plan(geovox.load_mesh(SPOT), opts, tmp_path / "s.h5").surface_points
    for budget, slabs in ((planner.POINTS_SLAB_BUDGET, 1), (40 * 36 * 64 // 8, 3)):
        monkeypatch.setattr(planner, "POINTS_SLAB_BUDGET", budget)
        info = geovox.convert_to(SPOT, tmp_path / "s.ply", **opts)
        assert info.slabs == slabs and info.counts == whole.counts
        assert info.inside_test == "surface"
        assert (tmp_path / "s.ply").read_bytes() == expected
    assert main(["convert", SPOT, "-o", str(tmp_path / "c.ply"), "--shape", "40", "36", "150",
                 "--occupancy", "surface", "-q"]) == 0
    assert (tmp_path / "c.ply").read_bytes() == expected


@pytest.mark.parametrize("color", [False, True])
def test_surface_alone_in_reused_slabs(tmp_path, color):
    # Dense outputs: the surface arrays serve every slab (SlabArrays' surface_out;
    # two in turn where exact colour writes a slab while the next is made).
    opts = dict(shape=(20, 18, 150), occupancy="surface", color=color)
    whole = geovox.voxelize(SPOT, **opts)
    per = 22 if color else 2
    for ext in ("h5", "raw"):
        info = geovox.convert_to(SPOT, tmp_path / f"s.{ext}", budget=20 * 18 * 64 * per, **opts)
        assert info.slabs == 3 and info.counts == whole.counts
        back = formats.read_volume(tmp_path / f"s.{ext}")
        np.testing.assert_array_equal(back.occupancy, whole.occupancy)
        if color:
            np.testing.assert_array_equal(back.colors[whole.occupancy],
                                          whole.colors[whole.occupancy])


def test_a_surface_voxels_colour_is_the_solid_runs(tmp_path):
    solid = geovox.voxelize(SPOT, resolution=48, color=True)
    both = geovox.voxelize(SPOT, resolution=48, color=True, occupancy="both")
    shared = solid.occupancy & both.occupancy
    assert shared.sum() > 1000 and (both.occupancy & ~solid.occupancy).sum() > 100
    np.testing.assert_array_equal(both.colors[shared], solid.colors[shared])
    assert (both.colors[both.occupancy][:, 3] == 255).all()


def test_labels_by_part_keep_the_open_parts():
    """Cornell box: open walls vanish from a solid, and are their own labels as surfaces."""
    solid = quiet(geovox.voxelize, CORNELL, resolution=48, labels="part")
    both = quiet(geovox.voxelize, CORNELL, resolution=48, labels="part", occupancy="both")
    surface = quiet(geovox.voxelize, CORNELL, resolution=48, labels="part", occupancy="surface")
    names = [e["name"] for e in both.label_table]
    wall = names.index("red_wall")
    assert (solid.labels == wall).sum() < 10 and (both.labels == wall).sum() > 300
    np.testing.assert_array_equal(both.labels != 0, both.occupancy)
    np.testing.assert_array_equal(surface.labels != 0, surface.occupancy)
    plain = quiet(geovox.voxelize, CORNELL, resolution=48, occupancy="surface")
    np.testing.assert_array_equal(surface.occupancy, plain.occupancy)
    # Material labels take every occupied voxel's nearest material.
    mat = quiet(geovox.voxelize, CORNELL, resolution=48, labels="material", occupancy="surface")
    np.testing.assert_array_equal(mat.labels != 0, mat.occupancy)


@pytest.mark.parametrize("overlap", ["first", "last", "smallest"])
def test_the_overlap_rule_settles_shared_surface_voxels(overlap):
    vol = quiet(geovox.voxelize, CORNELL, resolution=32, labels="part", occupancy="surface",
                overlap=overlap)
    assert vol.contested > 0  # walls meet at edges
    np.testing.assert_array_equal(vol.labels != 0, vol.occupancy)


def test_like_works_in_index_space():
    """Onto an oblique reference grid: the mesh moved into index space by hand, on the unit grid."""
    c, s = np.cos(0.5), np.sin(0.5)
    affine = np.eye(4)
    affine[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) * [0.04, 0.05, 0.06]
    affine[:3, 3] = [-0.6, -0.4, -0.7]
    shape = (30, 34, 30)
    vol = geovox.voxelize(SPOT, like=(affine, shape), occupancy="surface")
    m = geovox.load_mesh(SPOT)
    inv = np.linalg.inv(affine)
    moved = Mesh(vertices=m.vertices @ inv[:3, :3].T + inv[:3, 3], faces=m.faces)
    n = np.asarray(shape, dtype=float)
    truth = geovox.voxelize(moved, shape=shape, bounds=(-0.5, -0.5, -0.5, *(n - 0.5)),
                            occupancy="surface")
    assert truth.inside_count > 500
    np.testing.assert_array_equal(vol.occupancy, truth.occupancy)


def test_a_point_cloud_onto_an_oblique_grid(tmp_path):
    # Its centres mix the axes (no per-axis lookup): the slabs hand the writer indices.
    c, s = np.cos(0.5), np.sin(0.5)
    affine = np.eye(4)
    affine[:3, :3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) * [0.04, 0.05, 0.06]
    affine[:3, 3] = [-0.6, -0.4, -0.7]
    opts = dict(like=(affine, (30, 34, 30)), occupancy="surface")
    formats.write(geovox.voxelize(SPOT, **opts), tmp_path / "whole.ply")
    info = geovox.convert_to(SPOT, tmp_path / "s.ply", **opts)
    assert info.counts["surface"] > 500
    assert (tmp_path / "s.ply").read_bytes() == (tmp_path / "whole.ply").read_bytes()


@pytest.mark.parametrize("fmt", [f.name for f in formats.formats()])
def test_every_writer_takes_a_surface_volume(tmp_path, fmt):
    if fmt == "nifti":
        pytest.importorskip("nibabel")
    if fmt == "zarr":
        pytest.importorskip("zarr")
    f = formats.format_for("", fmt)
    grid = dict(resolution=24, fit="cube") if fmt == "binvox" else dict(shape=(24, 24, 24))
    vol = geovox.voxelize(SPOT, occupancy="both", **grid)
    path = tmp_path / ("v" + f.extensions[0])
    formats.write(vol, path)
    back = formats.read_volume(path)
    occ = back.occupancy
    if fmt == "binvox":  # read back as its whole padded cube
        occ = occ[:24, :24, :24]
    np.testing.assert_array_equal(occ, vol.occupancy)


def test_the_ply_point_cloud(tmp_path):
    out = tmp_path / "s.ply"
    assert main(["convert", SPOT, "-o", str(out), "-r", "40", "--occupancy", "surface",
                 "--color", "-q"]) == 0
    vol = geovox.voxelize(SPOT, resolution=40, occupancy="surface", color=True)
    pc = trimesh.load(out)
    assert isinstance(pc, trimesh.PointCloud) and len(pc.vertices) == vol.inside_count
    # Each point is its voxel's centre, in model units; colours are the voxels'.
    ijk = np.argwhere(vol.occupancy)
    order = np.lexsort((ijk[:, 0], ijk[:, 1], ijk[:, 2]))  # x fastest, then y, then z
    ijk = ijk[order]
    centres = np.asarray(vol.grid.lo) + (ijk + 0.5) * vol.grid.spacing
    np.testing.assert_allclose(pc.vertices, centres, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(pc.colors[:, :3], vol.colors[tuple(ijk.T)][:, :3])
    # A mesh PLY is still a mesh: preview voxelises it.
    mesh_ply = tmp_path / "mesh.ply"
    trimesh.creation.box().export(mesh_ply)
    assert not formats.is_volume_file(mesh_ply) and formats.is_volume_file(out)


def test_the_ply_carries_labels(tmp_path):
    out = tmp_path / "cb.ply"
    vol = quiet(geovox.voxelize, CORNELL, resolution=32, labels="part", occupancy="surface")
    formats.write(vol, out)
    head = out.read_bytes()[:4000].split(b"end_header")[0].decode()
    assert "property int label" in head
    back = formats.read_volume(out)
    np.testing.assert_array_equal(back.labels, vol.labels)
    assert [e["name"] for e in back.label_table] == [e["name"] for e in vol.label_table]


def test_the_sparse_npz(tmp_path):
    out = tmp_path / "s.npz"
    assert main(["convert", CORNELL, "-o", str(out), "-r", "32", "--occupancy", "both",
                 "--labels", "part", "--color", "--sparse", "-q"]) == 0
    vol = quiet(geovox.voxelize, CORNELL, resolution=32, occupancy="both", labels="part",
                color=True)
    with np.load(out) as z:
        coords = z["coords"]
        assert coords.dtype == np.int32 and coords.shape == (vol.inside_count, 3)
        assert z["colors"].shape == (vol.inside_count, 4) and z["labels"].shape == (vol.inside_count,)
        np.testing.assert_array_equal(vol.labels[tuple(coords.T)], z["labels"])
        np.testing.assert_array_equal(vol.colors[tuple(coords.T)], z["colors"])
        assert {"origin", "spacing", "shape", "bounds"} <= set(z.files)
    back = formats.read_volume(out)
    np.testing.assert_array_equal(back.occupancy, vol.occupancy)
    # Solid volumes too.
    formats.write(geovox.voxelize(SPOT, resolution=16), tmp_path / "solid.npz", sparse=True)
    assert formats.read_volume(tmp_path / "solid.npz").inside_count == \
        geovox.voxelize(SPOT, resolution=16).inside_count


@pytest.mark.parametrize("argv, words", [
    (["--occupancy", "hollow"], "invalid choice: 'hollow'"),
    (["--sparse"], "--sparse is for .npz"),
    (["--sparse", "--pack-bits", "-o", "{out}.npz"], "give one"),
])
def test_bad_combinations_are_one_line(tmp_path, capsys, argv, words):
    out = str(tmp_path / "x")
    argv = [a.replace("{out}", out) for a in argv]
    if "-o" not in argv:
        argv += ["-o", out + ".raw"]
    assert main(["convert", SPOT, "-r", "8", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and words in err
    assert list(tmp_path.iterdir()) == []


def test_the_summary_and_info_count_surface_voxels(tmp_path, capsys):
    assert main(["convert", SPOT, "-o", str(tmp_path / "s.raw"), "-r", "32",
                 "--occupancy", "both"]) == 0
    out = capsys.readouterr().out
    vol = geovox.voxelize(SPOT, resolution=32, occupancy="both")
    assert f"occupied {vol.inside_count:,} of" in out
    assert f"surface {vol.counts['surface']:,}" in out and "occupancy both" in out
    with open(tmp_path / "s.json") as f:
        assert json.load(f)["shape"] == [32, 32, 32]
    assert main(["info", SPOT, "-r", "32", "--occupancy", "surface"]) == 0
    out = capsys.readouterr().out
    assert f"surface voxels: {vol.counts['surface']:,}" in out


def test_a_batch_of_surfaces_runs_on_processes(tmp_path):
    from geovox.batch import convert_many

    results = convert_many([SPOT, CORNELL], tmp_path / "out", resolution=24,
                           occupancy="surface", fmt="ply", workers=2)
    assert [r.status for r in results] == ["ok", "ok"]
    for r in results:
        assert r.output.endswith(".ply") and os.path.getsize(r.output) > 1000
