"""OME-Zarr output: the metadata, the pyramid's rules, and slabs -- here or on a Dask cluster --
equal to the volume made in one piece."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

zarr = pytest.importorskip("zarr")
distributed = pytest.importorskip("dask.distributed")
ome = pytest.importorskip("ome_zarr_models.v05")

import geovox  # noqa: E402
import geovox.formats as F  # noqa: E402
from geovox.cli import main  # noqa: E402
from geovox.errors import ParameterError  # noqa: E402
from geovox.formats import zarr as Z  # noqa: E402
from geovox.api import convert_to  # noqa: E402

from conftest import SPOT, dask_client  # noqa: E402

# Distinct sizes catch an axis mix-up; 150 layers make 3 slabs of 64 or 2 of 128.
OPTS = dict(shape=(40, 36, 150), color=True, density="coverage", supersample=2, sdf=True, band=1.0)
FIELDS = {"occupancy": "", "color": "color/", "density": "density/", "sdf": "sdf/"}
#: A small top level, so that these small grids have a pyramid of four levels.
TOP = 32


@pytest.fixture(scope="module")
def small_top():
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Z, "TOP", TOP)
        yield


@pytest.fixture(scope="module")
def client():
    # Workers are threads of this process; TCP so that the CLI can reach the
    # scheduler by its address as it would a remote one.
    with dask_client(set_as_default=True, n_workers=2, processes=False, threads_per_worker=1,
                     protocol="tcp", dashboard_address=":0") as c:
        yield c


@pytest.fixture(scope="module")
def ref():
    return geovox.voxelize(SPOT, axis=1, **OPTS)  # several slabs cast along y


@pytest.fixture(scope="module")
def outputs(tmp_path_factory, small_top, client):
    """The same conversion in 64- and 128-layer slabs here, and in 128-layer slabs on the cluster."""
    d = tmp_path_factory.mktemp("zarr")
    out = {}
    for name, kw in [("local64", dict(slab=64)), ("local128", dict(slab=128)),
                     ("cluster128", dict(slab=128, client=client))]:
        out[name] = d / f"{name}.zarr"
        info = convert_to(SPOT, out[name], **kw, **OPTS)
        assert info["slabs"] == (3 if name == "local64" else 2)
    return out


def arrays(path) -> dict:
    g = zarr.open_group(str(path), mode="r")
    return {key: a[...] for key, a in g.arrays()} | {
        f"{sub}/{key}": a[...] for sub in ("color", "density", "sdf") if sub in g
        for key, a in g[sub].arrays()}


def test_slabs_equal_the_volume_in_one_piece(outputs, ref):
    for name in ("local64", "cluster128"):
        back = F.read(outputs[name])
        np.testing.assert_array_equal(back.occupancy, ref.occupancy)
        np.testing.assert_array_equal(back.colors, ref.colors)
        # A slab's coordinates are its own: density may round one step apart,
        # distances differ in the last bits (as for .h5, tests/test_stream.py).
        assert np.abs(back.density.astype(int) - ref.density.astype(int)).max() <= 1
        np.testing.assert_allclose(back.sdf, ref.sdf, rtol=1e-5, atol=1e-7)
        np.testing.assert_allclose(back.bounds, ref.bounds)
    assert ref.inside_count > 1000


def test_cluster_writes_what_the_local_path_writes(outputs, client):
    from geovox.runners.on_cluster import PLUGIN

    # The workers' slab buffers went with their plugin when the conversion ended.
    assert not any(client.run(lambda dask_worker: PLUGIN in dask_worker.plugins).values())
    here, there = arrays(outputs["local128"]), arrays(outputs["cluster128"])
    assert sorted(here) == sorted(there) and len(here) == 16  # 4 fields x 4 levels
    for key in here:
        np.testing.assert_array_equal(here[key], there[key], err_msg=key)


def _brute_halve(a, rule):
    """One pyramid step from the 8 children listed one by one (what downsample must equal)."""
    nz, ny, nx = a.shape[-3:]
    pad = [(0, 0)] * (a.ndim - 3) + [(0, n % 2) for n in (nz, ny, nx)]
    big = np.pad(a, pad)
    there = np.pad(np.ones((nz, ny, nx), bool), pad[-3:])
    # Children in the order x, then y, then z (the tie order of the colour rule).
    offsets = [(dz, dy, dx) for dx in (0, 1) for dy in (0, 1) for dz in (0, 1)]
    kids = [big[..., dz::2, dy::2, dx::2] for dz, dy, dx in offsets]
    has = [there[dz::2, dy::2, dx::2] for dz, dy, dx in offsets]
    if rule == "occupancy":
        return np.any([k > 0 for k in kids], axis=0).astype(a.dtype)
    if rule == "sdf":
        return np.min([np.where(h, k, np.inf) for k, h in zip(kids, has)], axis=0).astype(a.dtype)
    if rule == "density":
        total = np.sum([np.where(h, k.astype(np.float64), 0) for k, h in zip(kids, has)], axis=0)
        mean = total / np.sum(has, axis=0)
        return np.floor(mean + 0.5).astype(a.dtype) if a.dtype == np.uint8 else mean
    best = kids[0].copy()
    for k in kids[1:]:  # the first child with the highest alpha
        best = np.where(k[3:4] > best[3:4], k, best)
    return best


def test_pyramid_keeps_thin_parts_and_averages_density(outputs):
    a = arrays(outputs["local64"])
    for field, prefix in FIELDS.items():
        for k in range(1, 4):
            fine, coarse = a[f"{prefix}{k - 1}"], a[f"{prefix}{k}"]
            want = _brute_halve(fine, field)
            if field == "occupancy":
                want = want * np.uint8(255)
            np.testing.assert_array_equal(coarse, want, err_msg=f"{field} level {k}")
    # Thin parts: every level has inside voxels wherever the level above has.
    assert all(np.count_nonzero(a[str(k)]) > 0 for k in range(4))
    # The sign of the distance agrees with occupancy at every level.
    for k in range(4):
        np.testing.assert_array_equal(a[f"sdf/{k}"] < 0, a[str(k)] > 0)


@pytest.mark.parametrize("shape", [(1, 1, 1), (3, 5, 2), (7, 4, 9)])
def test_downsample_rules_on_odd_sizes(shape):
    rng = np.random.default_rng(sum(shape))
    occ = (rng.random(shape) < 0.3).astype(np.uint8) * np.uint8(255)
    np.testing.assert_array_equal(Z.downsample(occ, "occupancy"), _brute_halve(occ, "occupancy"))
    dens = rng.integers(0, 256, shape).astype(np.uint8)
    np.testing.assert_array_equal(Z.downsample(dens, "density"), _brute_halve(dens, "density"))
    densf = rng.random(shape).astype(np.float32)
    np.testing.assert_allclose(Z.downsample(densf, "density"), _brute_halve(densf, "density"),
                               rtol=1e-6)
    sdf = rng.normal(size=shape).astype(np.float32)
    np.testing.assert_array_equal(Z.downsample(sdf, "sdf"), _brute_halve(sdf, "sdf"))
    rgba = rng.integers(0, 256, (4,) + shape).astype(np.uint8)
    rgba[3] = rng.choice([0, 255], shape)
    np.testing.assert_array_equal(Z.downsample(rgba, "color"), _brute_halve(rgba, "color"))


def test_metadata_is_ome_zarr_0_5(outputs, ref):
    path = outputs["cluster128"]
    g = zarr.open_group(str(path), mode="r")
    h = np.asarray(ref.spacing)[::-1]
    lo = np.asarray(ref.bounds[0])[::-1]
    for field, prefix in FIELDS.items():
        group = g if field == "occupancy" else g[field]
        image = ome.Image.from_zarr(group)  # validates the multiscales against the schema
        ms = group.attrs["ome"]["multiscales"][0]
        assert group.attrs["ome"]["version"] == "0.5" and image is not None
        lead = 1 if field == "color" else 0
        assert [a["name"] for a in ms["axes"]] == ["c"] * lead + ["z", "y", "x"]
        assert [a["type"] for a in ms["axes"][lead:]] == ["space"] * 3
        for k, ds in enumerate(ms["datasets"]):
            assert ds["path"] == str(k)
            scale, shift = (t[t["type"]] for t in ds["coordinateTransformations"])
            np.testing.assert_allclose(scale[lead:], h * 2**k)
            np.testing.assert_allclose(shift[lead:], lo + h * 2**k / 2)  # centre of voxel 0
            arr = g[f"{prefix}{k}"]
            assert arr.chunks == (4,) * lead + (64, 64, 64)
            # Level 0's shard rows are the slabs; level 1 is still written by the slabs.
            want_z = {0: 128, 1: 64}.get(k, 64)
            assert arr.shards[lead] == want_z
        shapes = [g[f"{prefix}{k}"].shape[lead:] for k in range(len(ms["datasets"]))]
        assert shapes[0] == tuple(OPTS["shape"][::-1]) and max(shapes[-1]) <= TOP < max(shapes[-2])
        assert all(s == tuple(-(-n // 2) for n in p) for p, s in zip(shapes, shapes[1:]))
    assert g["0"].dtype == np.uint8 and set(np.unique(g["0"][...])) == {0, 255}
    assert g.attrs["geovox"]["shape"] == list(OPTS["shape"])


def test_misaligned_slabs_are_refused(tmp_path, client):
    with pytest.raises(ParameterError, match="multiple of 64"):
        convert_to(SPOT, tmp_path / "a.zarr", slab=100, shape=(8, 8, 200))
    with pytest.raises(ParameterError, match="multiple of 64"):
        convert_to(SPOT, tmp_path / "b.zarr", slab=32, client=client, shape=(8, 8, 200))
    with pytest.raises(ParameterError, match="for .zarr output"):
        convert_to(SPOT, tmp_path / "c.h5", slab=64, shape=(8, 8, 200))
    assert list(tmp_path.iterdir()) == []
    vol = geovox.voxelize(SPOT, shape=(8, 9, 200))
    w = Z.ZarrWriter(tmp_path / "d.zarr", vol, thick=128)
    # Two writers on one shard: a slab starting inside another's shard row.
    with pytest.raises(ParameterError, match="multiple of 128"):
        w.write(64, Z._slab_of(vol, 64, 192))
    with pytest.raises(ParameterError, match="whole shards"):
        Z.write_block(w.layout.root, w.layout.fields[0].levels[0],
                      np.zeros((128, 9, 8), np.uint8), (0, 64, 0))
    w.abort()
    assert list(tmp_path.iterdir()) == []


def test_failed_conversion_keeps_the_old_zarr(tmp_path, monkeypatch):
    out = tmp_path / "v.zarr"
    convert_to(SPOT, out, shape=(8, 8, 140), slab=64)
    before = (out / "zarr.json").read_text()
    calls = []

    def fail_second(*args, **kw):
        calls.append(1)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return real(*args, **kw)

    real = Z.write_slab
    monkeypatch.setattr(Z, "write_slab", fail_second)
    with pytest.raises(geovox.errors.OutputError, match="disk full"):
        convert_to(SPOT, out, shape=(8, 8, 150), slab=64)
    assert (out / "zarr.json").read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["v.zarr"]


def test_cli_on_a_scheduler_and_bad_set_ups(tmp_path, client, capsys):
    out = tmp_path / "s.zarr"
    grid = ["--shape", "20", "18", "70"]
    assert main(["convert", SPOT, "-o", str(out), *grid, "--scheduler", client.scheduler.address,
                 "-q"]) == 0
    np.testing.assert_array_equal(F.read(out).occupancy, geovox.voxelize(SPOT, shape=(20, 18, 70)).occupancy)
    # Converting again replaces it (a .zarr is a folder, not an output folder), here or there.
    assert main(["convert", SPOT, "-o", str(out), *grid, "-q"]) == 0
    assert main(["convert", SPOT, "-o", str(out), *grid, "--scheduler", client.scheduler.address,
                 "-q"]) == 0
    assert sorted(os.listdir(tmp_path)) == ["s.zarr"]
    # Nothing written inside it: only its own levels (how many depends on Z.TOP,
    # which the module-scoped small_top fixture may have lowered by now).
    levels = [str(k) for k in range(len(Z.level_shapes((70, 18, 20))))]
    assert sorted(os.listdir(out)) == sorted(levels + ["zarr.json"])
    for argv, words in [
            (["--local-cluster", "2", "-o", str(tmp_path / "v.h5")], ".zarr"),
            (["--scheduler-file", str(tmp_path / "none.json"), "-o", str(tmp_path / "v.zarr")],
             "scheduler file not found"),
            (["-o", str(tmp_path / "missing" / "v.zarr")], "output folder does not exist")]:
        assert main(["convert", SPOT, *grid, *argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and words in err, err
    assert sorted(os.listdir(tmp_path)) == ["s.zarr"]


def test_preview_and_view_read_the_level_that_fits(outputs, tmp_path, monkeypatch):
    import geovox.preview
    import geovox.view

    path = str(outputs["local64"])
    assert F.read(path).shape == OPTS["shape"]
    assert F.read(path, max_side=75).shape == (20, 18, 75)  # level 1
    assert F.read(path, max_side=5).shape == (5, 5, 19)  # none fits: the coarsest
    monkeypatch.setattr(geovox.preview, "LARGEST", 40)
    assert main(["preview", path, "-o", str(tmp_path / "p.png")]) == 0
    from PIL import Image

    with Image.open(tmp_path / "p.png") as im:
        assert im.size[0] > 300
    shown = []
    monkeypatch.setattr(geovox.view, "LARGEST", 80)
    monkeypatch.setattr(geovox.view, "show", lambda vol, **kw: shown.append(vol))
    assert main(["view", path]) == 0
    assert shown[0].shape == (20, 18, 75) and shown[0].colors is not None
    # The level's grid overlays level 0's: same low corner, twice the voxel.
    np.testing.assert_allclose(shown[0].bounds[0], F.read(path).bounds[0])
    np.testing.assert_allclose(shown[0].spacing, 2 * np.asarray(F.read(path).spacing))
    info = json.loads((outputs["local64"] / "zarr.json").read_text())
    assert info["attributes"]["geovox"]["values"] == "0 outside, 255 inside"


def test_own_shard_reader_equals_zarr_python(outputs):
    g = zarr.open_group(str(outputs["local64"]), mode="r")
    for prefix in FIELDS.values():
        a = g[prefix + "0"]
        level = Z.Level(prefix + "0", a.shape, a.shards)
        got = Z.read_block(str(outputs["local64"]), level, a.dtype, (5, 3, 7), (100, 20, 64))
        np.testing.assert_array_equal(got, a[..., 5:105, 3:23, 7:71], err_msg=prefix)


def test_a_worker_that_cannot_see_the_output_says_so(tmp_path):
    from geovox.runners.on_cluster import slab_task

    vol = geovox.voxelize(SPOT, shape=(8, 8, 64))
    layout = Z.make_layout(str(tmp_path / "elsewhere"), vol, 64)
    m = geovox.load_mesh(SPOT)
    p = geovox.plan(m, geovox.Options(shape=(8, 8, 64))).for_task()
    with pytest.raises(geovox.errors.OutputError, match="share"):
        slab_task(m, p, (0, 64), layout)


def test_levels_from_full_and_empty_chunks(tmp_path, small_top):
    from geovox.grid import Grid
    from geovox.volume import Volume

    # Whole chunks of 255 (reused bytes, never decompressed), absent chunks
    # and mixed ones, on sides that are not multiples of 64.
    occ = np.zeros((70, 66, 140), dtype=bool, order="F")
    occ[:, :, :100] = True
    occ[3, 5, 120] = True  # a lone voxel survives to the top
    vol = Volume(occupancy=occ, grid=Grid(np.zeros(3), np.ones(3), occ.shape), backend="numpy")
    Z.ZarrWriter(tmp_path / "v.zarr", vol, thick=64).write_whole(vol)
    a = arrays(tmp_path / "v.zarr")
    assert sorted(a) == ["0", "1", "2", "3"]  # occupancy only
    for k in range(1, 4):
        np.testing.assert_array_equal(a[str(k)], _brute_halve(a[str(k - 1)], "occupancy") * 255)
    assert a["3"][120 // 8, 5 // 8, 3 // 8] == 255 and a["3"][17].max() == 0


def test_scheduler_variable_is_only_for_zarr(tmp_path, monkeypatch, capsys):
    import geovox.cluster
    import geovox.planner

    # A big .h5 streams here even with a scheduler in the environment: no
    # client is asked for (the address answers nothing), the file is the
    # in-memory volume's.
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", "tcp://127.0.0.1:1")
    monkeypatch.setattr(geovox.planner, "streams", lambda *a, **k: True)
    asked = []
    monkeypatch.setattr(geovox.cluster, "client_from_options", lambda *a: asked.append(a))
    out = tmp_path / "v.h5"
    capsys.readouterr()
    assert main(["convert", SPOT, "-o", str(out), "-r", "16"]) == 0
    printed = capsys.readouterr().out
    assert asked == [] and "in 64-slice slabs" in printed
    np.testing.assert_array_equal(geovox.formats.read(out).occupancy,
                                  geovox.voxelize(SPOT, resolution=16).occupancy)
    # A .zarr does ask for it.
    with pytest.raises(TypeError):  # the stand-in above is no context manager
        main(["convert", SPOT, "-o", str(tmp_path / "v.zarr"), "-r", "16", "-q"])
    assert len(asked) == 1


def test_surface_voxels_on_the_cluster_are_the_volume_s(tmp_path, client):
    """occupancy="both" slab by slab as cluster tasks: the in-memory volume, counts included."""
    opts = dict(shape=(40, 36, 200), occupancy="both", color="fast")
    ref = geovox.voxelize(SPOT, **opts)
    info = convert_to(SPOT, tmp_path / "b.zarr", slab=64, client=client, **opts)
    assert info.slabs == 4 and info.counts == ref.counts
    back = F.read(tmp_path / "b.zarr")
    np.testing.assert_array_equal(back.occupancy, ref.occupancy)
