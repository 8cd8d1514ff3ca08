"""Labels and fractions slab by slab: the same bytes as in memory, whatever the route.

The truth is the in-memory volume (``geovox.voxelize``, whose labels
test_labels.py checks against each part voxelised alone). Here slabs are
forced with a small ``budget``; every streamed file is read back by an
independent reader (h5py, pynrrd, slicerio, zarr with ome-zarr-models) and
compared with it byte for byte: labels, fractions, the label table's counts
and the contested count.
"""

from __future__ import annotations

import dataclasses

import hashlib
import json
import os
import warnings

import numpy as np
import pytest
import trimesh

import geovox
from geovox import formats
from geovox import labels as L
from geovox.mesh import Mesh
from geovox.planner import Route

from conftest import dask_client
from test_labels import assembly

GEARS = os.path.join(os.path.dirname(__file__), "data", "assimp", "cube_gears_prod_req.3mf")
CORNELL = os.path.join(os.path.dirname(__file__), "data", "cornell_box", "cornell_box.obj")


def inclusion() -> Mesh:
    """A small box inside a big one, and a box that cuts through the big one's side."""
    pieces = [trimesh.creation.box(extents=(2.0, 1.6, 2.4)),
              trimesh.creation.box(extents=(0.5, 0.4, 0.6)),
              trimesh.creation.box(extents=(0.8, 0.8, 0.9))]
    pieces[1].apply_translation((0.3, -0.2, 0.45))
    pieces[2].apply_translation((1.0, 0.3, -0.7))
    verts, faces, part, off = [], [], [], 0
    for k, g in enumerate(pieces):
        verts.append(np.asarray(g.vertices, float))
        faces.append(np.asarray(g.faces, np.int64) + off)
        part.append(np.full(len(g.faces), k))
        off += len(g.vertices)
    return Mesh(np.concatenate(verts), np.concatenate(faces), source="inclusion",
                face_part=np.concatenate(part), parts=["big", "small", "side"])


MODELS = {
    "assembly": (lambda: assembly(open_part=True), (37, 26, 150)),
    "inclusion": (inclusion, (31, 27, 140)),
    "gears": (lambda: GEARS, (36, 36, 130)),
}


def quiet(fn, *args, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(*args, **kw)


def slab_budget(mesh, **kw) -> float:
    """A slab budget that takes 64-layer slabs of this conversion (its plan's bytes a voxel)."""
    p = quiet(geovox.plan, mesh, kw, "x.h5", stream=True)
    nx, ny, _ = p.grid.shape
    return nx * ny * 64 * p.per_voxel * 1.01


def table_key(table):
    return [(e["value"], e["name"], list(e["color"]), e["voxels"], e["volume"]) for e in table]


def tree(path) -> dict:
    """Every file under a folder and its SHA-256."""
    out = {}
    for d, _, names in os.walk(path):
        for n in names:
            q = os.path.join(d, n)
            with open(q, "rb") as f:
                out[os.path.relpath(q, path)] = hashlib.sha256(f.read()).hexdigest()
    return out


@pytest.mark.parametrize("overlap", L.OVERLAPS)
@pytest.mark.parametrize("model", sorted(MODELS))
def test_slabs_give_the_in_memory_labels_and_fractions(model, overlap, backend, tmp_path):
    make, shape = MODELS[model]
    m = make()
    kw = dict(shape=shape, labels="part", overlap=overlap, fractions=True, supersample=2,
              backend=backend)
    ref = quiet(geovox.voxelize, m, **kw)
    assert len(np.unique(ref.labels)) >= 3
    if model != "gears":
        assert ref.contested > 0  # overlaps to settle
    out = tmp_path / "s.h5"
    report = quiet(geovox.convert_to, m, out, budget=slab_budget(m, **kw), **kw)
    assert report.route == "slabs" and report.slabs >= 2
    back = formats.read(out)
    np.testing.assert_array_equal(back.labels, ref.labels)
    assert back.fractions.dtype == ref.fractions.dtype
    np.testing.assert_array_equal(back.fractions, ref.fractions)
    assert report["contested"] == ref.contested
    assert table_key(report.label_table) == table_key(ref.label_table)
    assert table_key(back.label_table) == table_key(ref.label_table)
    assert report["labels"] == len(ref.label_table) - 1


@pytest.mark.parametrize("model", ["inclusion", "gears"])
def test_float32_fractions_and_other_axes(model, tmp_path):
    """Rays along z (the default): float32 fractions bit for bit. Along x or y a slab casts
    its own rays, placed from its own low face: the labels are the same, the fractions
    within float32 rounding (a ray may move by a unit in the last place)."""
    make, shape = MODELS[model]
    m = make()
    for axis in (2, 0, 1):
        kw = dict(shape=shape, labels="part", overlap="smallest", fractions=True, supersample=2,
                  density_dtype="float32", axis=axis)
        ref = quiet(geovox.voxelize, m, **kw)
        report = quiet(geovox.convert_to, m, tmp_path / "f.h5", budget=slab_budget(m, **kw),
                       **kw)
        assert report.slabs >= 2
        back = formats.read(tmp_path / "f.h5")
        assert back.fractions.dtype == np.float32
        np.testing.assert_array_equal(back.labels, ref.labels)
        if axis == 2:
            np.testing.assert_array_equal(back.fractions, ref.fractions)
        else:
            np.testing.assert_allclose(back.fractions, ref.fractions, rtol=0, atol=1e-5)


def test_open_parts_stream_too(tmp_path):
    """The Cornell box's walls are open: each runs the winding number, block by block."""
    shape = (30, 30, 140)
    kw = dict(shape=shape, labels="part", overlap="last")
    ref = quiet(geovox.voxelize, CORNELL, **kw)
    assert "winding" in ref.inside
    report = quiet(geovox.convert_to, CORNELL, tmp_path / "c.h5",
                   budget=slab_budget(CORNELL, **kw), **kw)
    assert report.slabs >= 2 and report.inside_test == ref.inside
    np.testing.assert_array_equal(formats.read(tmp_path / "c.h5").labels, ref.labels)
    assert report["contested"] == ref.contested


def test_smallest_is_decided_before_the_blocks_from_the_mesh_volumes():
    """The paint order of ``smallest`` comes from each part's enclosed mesh volume: no block's
    voxels enter it, so every block paints in the same order as the whole grid."""
    m = inclusion()
    parts = [L.part_mesh(m, np.flatnonzero(m.face_part == k), n) for k, n in enumerate(m.parts)]
    vols = [L.enclosed_volume(p) for p in parts]
    np.testing.assert_allclose(vols, [2.0 * 1.6 * 2.4, 0.5 * 0.4 * 0.6, 0.8 * 0.8 * 0.9])
    lset = dataclasses.replace(L.label_set(m, "part"), overlap="smallest")
    assert L.paint_order(lset, parts) == [0, 2, 1]  # the largest first
    # The small box inside the big one keeps its label only by "smallest" (or "last").
    lab = {o: quiet(geovox.voxelize, m, shape=(31, 27, 40), labels="part", overlap=o).labels
           for o in L.OVERLAPS}
    assert (lab["smallest"] == 2).any() and not (lab["first"] == 2).any()


@pytest.fixture(scope="module")
def streamed(tmp_path_factory):
    """The assembly in memory, and written slab by slab to every format that streams."""
    d = tmp_path_factory.mktemp("streamed")
    shape = (37, 26, 150)
    kw = dict(shape=shape, labels="part", overlap="smallest")
    m = assembly(open_part=True)
    ref = quiet(geovox.voxelize, m, **kw)
    reports = {}
    for ext in (".h5", ".vtkhdf", ".raw", ".seg.nrrd", ".zarr"):
        reports[ext] = quiet(geovox.convert_to, m, d / f"s{ext}", budget=slab_budget(m, **kw),
                             **kw)
        assert reports[ext].slabs >= 2, ext
    return d, ref, reports


def test_streamed_seg_nrrd_is_the_in_memory_file_and_opens_in_slicerio(streamed, tmp_path):
    slicerio = pytest.importorskip("slicerio")
    d, ref, _ = streamed
    formats.write(ref, tmp_path / "m.seg.nrrd")
    with open(d / "s.seg.nrrd", "rb") as a, open(tmp_path / "m.seg.nrrd", "rb") as b:
        assert a.read() == b.read()  # the header's extents merged over the slabs
    seg = slicerio.read_segmentation(str(d / "s.seg.nrrd"))
    names = [s["name"] for s in seg["segments"]]
    assert names == [e["name"] for e in ref.label_table[1:]]
    ext = {s["labelValue"]: s.get("extent") for s in seg["segments"]}
    for e in ref.label_table[1:]:
        where = np.argwhere(ref.labels == e["value"])
        want = [int(x) for lo, hi in zip(where.min(0), where.max(0)) for x in (lo, hi)]
        assert list(ext[e["value"]]) == want
    np.testing.assert_array_equal(seg["voxels"], ref.labels)


def test_streamed_raw_nrrd_headers_and_sidecar(streamed):
    nrrd = pytest.importorskip("nrrd")
    d, ref, _ = streamed
    info = json.loads((d / "s.json").read_text())
    lab = np.fromfile(d / info["labels"]["data_file"], dtype=info["labels"]["dtype"])
    np.testing.assert_array_equal(lab.reshape(ref.shape, order="F"), ref.labels)
    assert table_key(info["labels"]["label_table"]) == table_key(ref.label_table)
    data, _ = nrrd.read(str(d / "s_labels.nhdr"))
    np.testing.assert_array_equal(data, ref.labels)


def test_streamed_h5_and_vtkhdf(streamed):
    h5py = pytest.importorskip("h5py")
    d, ref, reports = streamed
    with h5py.File(d / "s.h5", "r") as f:
        np.testing.assert_array_equal(f["labels"][...], ref.labels)
        np.testing.assert_array_equal(f["occupancy"][...], ref.occupancy)
        assert table_key(json.loads(f.attrs["label_table"])) == table_key(ref.label_table)
        np.testing.assert_array_equal(f["VTKHDF/PointData/labels"][...], ref.labels.T)
    back = formats.read(d / "s.vtkhdf")
    np.testing.assert_array_equal(back.labels, ref.labels)
    assert [e["name"] for e in back.label_table] == [e["name"] for e in ref.label_table]
    assert reports[".h5"]["contested"] == ref.contested


def test_streamed_zarr_image_label_counts(streamed, tmp_path):
    zarr = pytest.importorskip("zarr")
    pytest.importorskip("ome_zarr_models.v05")
    from ome_zarr_models.v05.image import Image
    from ome_zarr_models.v05.image_label import ImageLabel

    d, ref, _ = streamed
    root = zarr.open_group(str(d / "s.zarr"), mode="r")
    g = root["labels/labels"]
    np.testing.assert_array_equal(g["0"][...].transpose(2, 1, 0), ref.labels)
    props = g.attrs["ome"]["image-label"]["properties"]
    assert [(q["label-value"], q["voxels"]) for q in props] == \
        [(e["value"], e["voxels"]) for e in ref.label_table[1:]]
    Image.from_zarr(root)
    ImageLabel.from_zarr(g)
    back = formats.read(d / "s.zarr")
    np.testing.assert_array_equal(back.labels, ref.labels)
    # The same folder as from memory, with slabs as thick.
    formats.zarr_format.ZarrWriter(tmp_path / "m.zarr", ref, thick=64).write_whole(ref)
    assert tree(d / "s.zarr") == tree(tmp_path / "m.zarr")


def test_jobs_give_the_same_files(tmp_path):
    m = inclusion()
    shape = (31, 27, 140)
    kw = dict(shape=shape, labels="part", overlap="smallest", fractions=True, supersample=2)
    ref = quiet(geovox.voxelize, m, **kw)
    for jobs in (1, 2):
        quiet(geovox.convert_to, m, tmp_path / f"j{jobs}.h5", budget=slab_budget(m, **kw),
              jobs=jobs, **kw)
        quiet(geovox.convert_to, m, tmp_path / f"j{jobs}.seg.nrrd",
              budget=slab_budget(m, **kw), jobs=jobs, **kw)
        back = formats.read(tmp_path / f"j{jobs}.h5")
        np.testing.assert_array_equal(back.labels, ref.labels)
        np.testing.assert_array_equal(back.fractions, ref.fractions)
    assert (tmp_path / "j1.seg.nrrd").read_bytes() == (tmp_path / "j2.seg.nrrd").read_bytes()


def test_cli_jobs_2_streams_labels(tmp_path, capsys, monkeypatch):
    import geovox.planner as stream
    from geovox.cli import main

    shape = (31, 27, 140)
    monkeypatch.setattr(stream, "SLAB_BUDGET", slab_budget(inclusion(), shape=shape,
                                                           labels="part"))
    mesh = tmp_path / "m.glb"
    scene = trimesh.Scene()
    m = inclusion()
    for k, name in enumerate(m.parts):
        part = L.part_mesh(m, np.flatnonzero(m.face_part == k), name)
        scene.add_geometry(trimesh.Trimesh(part.vertices, part.faces), node_name=name,
                           geom_name=name)
    scene.export(mesh)
    out = tmp_path / "cli.seg.nrrd"
    rc = main(["convert", str(mesh), "-o", str(out), "--shape", *map(str, shape), "--labels",
               "part", "--overlap", "smallest", "--jobs", "2"])
    said = capsys.readouterr().out
    assert rc == 0 and "in 3 slabs" in said and "contested voxels" in said
    ref = quiet(geovox.voxelize, str(mesh), shape=shape, labels="part", overlap="smallest")
    np.testing.assert_array_equal(formats.read(out).labels, ref.labels)
    assert f"{ref.contested:,} contested" in said


def test_dask_cluster_slab_tasks_give_the_same_bytes(tmp_path):
    pytest.importorskip("distributed")
    m = assembly(open_part=True)
    kw = dict(shape=(37, 26, 300), labels="part", overlap="smallest", fractions=True,
              supersample=2)
    ref = quiet(geovox.voxelize, m, **kw)
    local = quiet(geovox.convert_to, m, tmp_path / "local.zarr", slab=64, **kw)
    with dask_client(set_as_default=True, n_workers=2, threads_per_worker=1, processes=False,
                     dashboard_address=None) as client:
        report = quiet(geovox.convert_to, m, tmp_path / "cluster.zarr", client=client, slab=64,
                       **kw)
        results = quiet(geovox.convert_many, [GEARS], tmp_path / "many", client=client,
                        fmt="zarr", shape=(36, 36, 130), labels="part", overlap="smallest")
    assert report.route == "cluster" and report.slabs == 5
    assert tree(tmp_path / "cluster.zarr") == tree(tmp_path / "local.zarr")
    back = formats.read(tmp_path / "cluster.zarr")
    np.testing.assert_array_equal(back.labels, ref.labels)
    np.testing.assert_array_equal(back.fractions, ref.fractions)
    assert report["contested"] == ref.contested == local["contested"]
    assert table_key(report.label_table) == table_key(ref.label_table)
    (result,) = results
    assert result.status == "ok", result
    gears = quiet(geovox.voxelize, GEARS, shape=(36, 36, 130), labels="part", overlap="smallest")
    np.testing.assert_array_equal(formats.read(result.outputs[0]).labels, gears.labels)


def test_a_grid_too_big_for_memory_streams_its_labels(monkeypatch, tmp_path):
    """With 1 GiB available, a 400 x 400 x 2048 labelled grid (2.6 GB of working arrays whole)
    is planned in slabs; the label and fraction bytes count in the budget (thinner slabs with
    fractions); a format written whole refuses it before allocating anything."""
    from geovox import memory
    from geovox.errors import GridTooLargeError

    monkeypatch.setattr(memory, "available_memory", lambda: 1 << 30)
    m = assembly()
    big = dict(shape=(400, 400, 2048), labels="part")
    lset = L.label_set(m, "part")
    p = quiet(geovox.plan, m, big, "big.h5")
    assert p.route == Route.SLABS and len(p.blocks) > 1
    assert p.per_voxel >= 1.0 + p.labels.working_bytes()
    assert 400 * 400 * 2048 * p.per_voxel > memory.MEMORY_FRACTION * (1 << 30)
    assert 400 * 400 * p.thick * p.per_voxel <= 0.5 * (1 << 30)  # slab_budget: half
    pf = quiet(geovox.plan, m, dict(big, fractions=True), "big.seg.nrrd")
    assert pf.route == Route.SLABS and len(pf.blocks) > len(p.blocks)
    assert pf.per_voxel - p.per_voxel == pf.labels.working_bytes() - p.labels.working_bytes()
    assert pf.labels.working_bytes() == p.labels.working_bytes() + len(lset.names) + 8.0
    assert quiet(geovox.plan, m, big, "big.zarr").route == Route.SLABS
    with pytest.raises(GridTooLargeError):
        quiet(geovox.convert_to, m, tmp_path / "big.npz", **big)
    assert not list(tmp_path.iterdir())


def test_small_labelled_grids_stay_in_memory():
    m = assembly()
    assert quiet(geovox.plan, m, dict(resolution=32, labels="part"), "a.h5").route == Route.MEMORY
    assert quiet(geovox.plan, m, dict(resolution=32, labels="part"),
                 "a.npz").route == Route.MEMORY


def test_unlabelled_seg_nrrd_streams_to_the_same_file(tmp_path):
    """A .seg.nrrd without labels (one segment) now has a slab writer: the same bytes."""
    m = assembly()
    ref = quiet(geovox.voxelize, m, shape=(30, 20, 150), axis=1)
    formats.write(ref, tmp_path / "m.seg.nrrd")
    report = quiet(geovox.convert_to, m, tmp_path / "s.seg.nrrd", shape=(30, 20, 150),
                   budget=30 * 20 * 64 * 2)
    assert report.slabs >= 2
    assert (tmp_path / "s.seg.nrrd").read_bytes() == (tmp_path / "m.seg.nrrd").read_bytes()


def test_material_labels_stream(tmp_path):
    """Material labels: each slab's nearest-surface search, in the whole grid's frame."""
    kw = dict(shape=(30, 30, 140), labels="material")
    ref = quiet(geovox.voxelize, CORNELL, **kw)
    assert len(np.unique(ref.labels)) >= 4
    report = quiet(geovox.convert_to, CORNELL, tmp_path / "m.h5",
                   budget=slab_budget(CORNELL, **kw), **kw)
    assert report.slabs >= 2
    back = formats.read(tmp_path / "m.h5")
    np.testing.assert_array_equal(back.labels, ref.labels)
    assert table_key(back.label_table) == table_key(ref.label_table)


@pytest.mark.parametrize("dtype", ["uint8", "float32"])
def test_streamed_raw_fractions_open_in_pynrrd(dtype, tmp_path):
    """NAME_fractions.raw: one value per label interleaved per voxel, with .nhdr and .mhd."""
    nrrd = pytest.importorskip("nrrd")
    m = inclusion()
    kw = dict(shape=(31, 27, 140), labels="part", fractions=True, supersample=2,
              density_dtype=dtype)
    ref = quiet(geovox.voxelize, m, **kw)
    report = quiet(geovox.convert_to, m, tmp_path / "s.raw", budget=slab_budget(m, **kw), **kw)
    assert report.slabs >= 2
    back = formats.read(tmp_path / "s.raw")
    assert back.fractions.dtype == np.dtype(dtype)
    np.testing.assert_array_equal(back.fractions, ref.fractions)
    data, header = nrrd.read(str(tmp_path / "s_fractions.nhdr"))
    assert data.shape == (3,) + ref.shape
    np.testing.assert_array_equal(np.moveaxis(data, 0, 3), ref.fractions)
    assert "ElementNumberOfChannels = 3" in (tmp_path / "s_fractions.mhd").read_text()
    formats.write(ref, tmp_path / "m.raw")
    assert (tmp_path / "m_fractions.raw").read_bytes() == (tmp_path / "s_fractions.raw").read_bytes()


def test_streamed_zarr_fractions_one_channel_a_label(tmp_path):
    """``fractions/``: an OME-Zarr image with one channel per label; its coarser levels are
    the mean of the children, label by label (the density rule)."""
    zarr = pytest.importorskip("zarr")
    pytest.importorskip("ome_zarr_models.v05")
    from ome_zarr_models.v05.image import Image

    from geovox.formats.zarr import downsample

    m = inclusion()
    kw = dict(shape=(31, 27, 300), labels="part", fractions=True, supersample=2)
    ref = quiet(geovox.voxelize, m, **kw)
    report = quiet(geovox.convert_to, m, tmp_path / "f.zarr", slab=64, **kw)
    assert report.slabs == 5
    back = formats.read(tmp_path / "f.zarr")
    np.testing.assert_array_equal(back.fractions, ref.fractions)
    g = zarr.open_group(str(tmp_path / "f.zarr"), mode="r")
    assert g["fractions/0"].shape == (3, 300, 27, 31)
    coarse = downsample(ref.fractions.transpose(3, 2, 1, 0), "fractions")
    np.testing.assert_array_equal(g["fractions/1"][...], coarse)
    one = downsample(ref.fractions[..., 1].T, "density")
    np.testing.assert_array_equal(coarse[1], one)
    Image.from_zarr(g)
    Image.from_zarr(g["fractions"])
