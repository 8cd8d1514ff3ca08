"""Options once, decisions once: the Options record, the plan, and what every entry point shares."""

from __future__ import annotations

import dataclasses
import inspect
import os
import pickle
import warnings

import numpy as np
import pytest

import geovox
from geovox.cli import main
from geovox.cli.commands import build_parser
from geovox.errors import GeovoxWarning, ParameterError
from geovox.options import KERNEL_ENV, Colour, Inside, Options
from geovox.planner import Route, plan
from geovox.block import voxelize_block

from conftest import DATA, SPOT

#: The fourteen options manifests have always recorded (the command line's).
RECORDED = {"ambient", "backend", "band", "bounds", "color", "density", "density_dtype", "diffuse",
            "inside", "resolution", "sdf", "shape", "supersample", "voxel_size"}


def _keywords(fn):
    return {n: p for n, p in inspect.signature(fn).parameters.items()
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}


def test_voxelize_signature_is_the_options():
    params = _keywords(geovox.voxelize)
    assert set(params) - {"mesh", "progress"} == set(Options.names())
    docs = Options.docs()
    for name, p in params.items():
        if name in ("mesh", "progress", "kernel"):
            continue
        assert p.default == docs[name][0], name
    # kernel=None means "the field's default", which reads the environment.
    assert params["kernel"].default is None
    # Every option is documented in voxelize's docstring.
    for name in Options.names():
        assert f"\n    {name} :" in geovox.voxelize.__doc__, name


def test_convert_to_and_convert_many_take_every_option():
    to = _keywords(geovox.convert_to)
    many = _keywords(geovox.convert_many)
    # Their own parameters never shadow an option (but jobs: threads for
    # convert_to, the deprecated name of workers for convert_many).
    assert set(to) & set(Options.names()) == {"jobs"}
    assert set(many) & set(Options.names()) == {"jobs"}
    for fn in (geovox.convert_to, geovox.convert_many):
        kinds = [p.kind for p in inspect.signature(fn).parameters.values()]
        assert inspect.Parameter.VAR_KEYWORD in kinds  # **options, checked by Options.from_kwargs


def test_the_command_line_sets_every_option_but_axis_and_kernel():
    parser = build_parser()
    convert = parser._subparsers._group_actions[0].choices["convert"]
    dests = {a.dest for a in convert._actions}
    assert set(Options.names()) - dests == {"axis", "kernel", "density_dtype"}
    assert "density_float" in dests
    args = parser.parse_args(["convert", SPOT, "--fast-color", "--density", "coverage",
                              "--density-float", "-r", "9"])
    o = Options.from_args(args)
    assert (o.color, o.density, o.density_dtype, o.resolution) == ("fast", "coverage", "float32", 9)
    # The record a manifest holds is the one it always held: the fourteen options.
    assert set(o.to_record()) == RECORDED


def test_cli_choices_come_from_the_registries():
    from geovox.backends import REGISTRY
    from geovox.formats import formats

    convert = build_parser()._subparsers._group_actions[0].choices["convert"]
    choices = {a.dest: a.choices for a in convert._actions if a.choices is not None}
    assert list(choices["backend"]) == ["auto", *REGISTRY]
    assert list(choices["inside"]) == [m.value for m in Inside]
    assert list(choices["fmt"]) == [f.name for f in formats()]


@pytest.mark.parametrize("kw,closest", [
    (dict(colour=True), "color"),
    (dict(resolutoin=8), "resolution"),
    (dict(voxelsize=0.1), "voxel_size"),
    (dict(super_sample=2), "supersample"),
])
def test_a_misspelt_option_names_the_closest(kw, closest):
    with pytest.raises(ParameterError, match=f"did you mean `{closest}`") as e:
        Options.from_kwargs(**kw)
    assert isinstance(e.value, ValueError) and f"`{next(iter(kw))}=`" in str(e.value)
    with pytest.raises(ParameterError, match="known: resolution, bounds"):
        Options.from_kwargs(zzzz=1)


def test_convert_to_refuses_a_misspelt_option_before_any_work(tmp_path):
    # Before: a TypeError from deep inside, after the mesh was loaded and the
    # writer opened. Now: the closest name, before the mesh is even read.
    with pytest.raises(ParameterError, match="did you mean `color`"):
        geovox.convert_to(str(tmp_path / "missing.obj"), tmp_path / "v.h5", colour=True)
    with pytest.raises(ParameterError, match="did you mean `color`"):
        geovox.convert_many([SPOT], tmp_path / "out", colour=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == []


@pytest.mark.parametrize("kw,message", [
    (dict(resolution=-3), "`resolution` must be a positive integer, got -3"),
    (dict(resolution=True), "`resolution` must be a positive integer, got True"),
    (dict(shape=(4, 4)), "`shape` must be three positive integers, got (4, 4)"),
    (dict(shape=(4, 0, 4)), "`shape` must be a positive integer, got 0"),
    (dict(voxel_size=0), "`voxel_size` must be a positive number, got 0"),
    (dict(resolution=8, shape=(2, 2, 2)), "give only one of `resolution`, `shape`, `voxel_size`"),
    (dict(bounds=(0, 0, 0, 1, 1)), "`bounds` must be 6 numbers"),
    (dict(bounds=(0, 0, 0, 1, 1, 0)), "`bounds` needs min < max on every axis; not so on z"),
    (dict(axis=3), "`axis` must be 0, 1 or 2, got 3"),
    (dict(color="red"), "`color` must be True, False, 'exact' or 'fast', got 'red'"),
    (dict(inside="odd"), "`inside` must be one of auto, parity, vote, winding; got 'odd'"),
    (dict(density="mean"), "`density` must be None or 'coverage', got 'mean'"),
    (dict(density_dtype="int8"), "`density_dtype` must be 'uint8' or 'float32'"),
    (dict(density="coverage", supersample=0), "`supersample` must be a positive integer, got 0"),
    (dict(sdf=True, band=-1), "`band` must be a positive number of voxels or math.inf, got -1"),
    (dict(sdf=True, band=0), "`band` must be a positive number of voxels or math.inf, got 0"),
    (dict(sdf=True, band=float("nan")), "`band` must be a positive number of voxels or math.inf, "
                                        "got nan"),
    (dict(sdf="unsigned", band="3"), "`band` must be a positive number of voxels or math.inf, "
                                     "got '3'"),
    (dict(sdf="sideways"), "`sdf` must be True, False, 'signed' or 'unsigned', got 'sideways'"),
    (dict(jobs=-1), "`jobs` must be a non-negative integer, got -1"),
    (dict(kernel="gpu"), "kernel must be auto, compiled or numpy, got 'gpu'"),
    (dict(backend="optix"), "`backend` must be one of auto, embree, numpy, webgpu; got 'optix'"),
])
def test_bad_values_keep_their_messages(kw, message):
    with pytest.raises(ParameterError) as e:
        Options(**kw)
    assert message in str(e.value)
    # The same message from the public functions.
    with pytest.raises(ParameterError) as e2:
        geovox.voxelize(SPOT, **kw)
    assert message in str(e2.value)


def test_options_are_frozen_values():
    o = Options(bounds=np.array([0, 0, 0, 1, 1, 1]), shape=[4, 5, 6])
    assert o.bounds == (0.0, 0.0, 0.0, 1.0, 1.0, 1.0) and o.shape == (4, 5, 6)
    with pytest.raises(dataclasses.FrozenInstanceError):
        o.resolution = 3
    assert o == Options(bounds=(0, 0, 0, 1, 1, 1), shape=(4, 5, 6)) and hash(o)
    assert o.replace(color="fast").color == "fast" and o.color is False
    with pytest.raises(ParameterError):
        o.replace(color="red")
    assert pickle.loads(pickle.dumps(o)) == o
    # Every option has one line of doc.
    assert all(doc and "\n" not in doc for _, doc in Options.docs().values())


def test_kernel_default_reads_the_environment(monkeypatch):
    monkeypatch.delenv(KERNEL_ENV, raising=False)
    assert Options().kernel == "auto"
    monkeypatch.setenv(KERNEL_ENV, "numpy")
    assert Options().kernel == "numpy" and Options(kernel="compiled").kernel == "compiled"
    monkeypatch.setenv(KERNEL_ENV, "gpu")
    with pytest.raises(ParameterError, match="got 'gpu'"):
        Options()


#: Every compiled kernel: the nearest-surface search, the lattice search and
#: mesh checks, the caps' winding number, the OBJ reader's numbers.
COMPILED = {"_nearest", "_lattice", "_winding", "_objtext"}


def _built():
    from geovox import kernels

    try:
        return all(kernels._load(n) for n in COMPILED)
    except ImportError:
        return False


#: A real model of each path: occupancy and exact colour (spot, closed), fast
#: colour, and the winding number of a leaky one (suzanne's open eyes).
KERNEL_CASES = {
    "occupancy": (SPOT, dict(resolution=40)),
    "exact colour": (SPOT, dict(resolution=40, color=True)),
    "fast colour": (SPOT, dict(resolution=40, color="fast")),
    "winding": (os.path.join(DATA, "suzanne", "suzanne.obj"), dict(resolution=40)),
}


def _voxelize_quietly(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", GeovoxWarning)  # suzanne is open, and said so
        return geovox.voxelize(path, **kw)


@pytest.mark.skipif(not _built(), reason="the compiled kernels are not built")
@pytest.mark.parametrize("case", KERNEL_CASES)
def test_kernel_option_chooses_every_compiled_kernel(case, monkeypatch):
    """kernel="numpy" never loads a compiled module, "compiled" uses them; the same bytes."""
    from geovox import kernels

    path, kw = KERNEL_CASES[case]
    real = kernels._load
    loaded = []

    def refuse(name):
        raise AssertionError(f"geovox.{name} loaded with kernel='numpy'")

    # The environment says the opposite each time: the option decides.
    monkeypatch.setenv(KERNEL_ENV, "compiled")
    monkeypatch.setattr(kernels, "_load", refuse)
    a = _voxelize_quietly(path, kernel="numpy", **kw)
    monkeypatch.setenv(KERNEL_ENV, "numpy")
    monkeypatch.setattr(kernels, "_load", lambda name: loaded.append(name) or real(name))
    b = _voxelize_quietly(path, kernel="compiled", **kw)
    assert a.inside == b.inside == ("winding" if case == "winding" else "parity")
    assert a.inside_count > 1000
    for field in ("occupancy", "colors"):
        x, y = getattr(a, field), getattr(b, field)
        assert (x is None) == (y is None) == (field == "colors" and "color" not in kw)
        if x is not None:
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes()
    # The OBJ reading and the lattice search always run; the nearest search
    # only for exact colour, the winding kernel only for the leaky model.
    want = {"_objtext", "_lattice"} | ({"_nearest"} if kw.get("color") is True else set()) \
        | ({"_winding"} if case == "winding" else set())
    assert set(loaded) == want, loaded
    assert kernels._CHOICE.get() is None  # the choice ends with the conversion


@pytest.mark.skipif(not _built(), reason="the compiled kernels are not built")
def test_kernel_option_reaches_slabs_and_files(tmp_path, monkeypatch):
    # Streamed slabs (the rays cast on the colour step's threads too): still the option's choice.
    from geovox import kernels

    monkeypatch.setattr(kernels, "_load", lambda name: pytest.fail(f"geovox.{name} loaded"))
    r = geovox.convert_to(SPOT, tmp_path / "a.raw", shape=(20, 20, 150), color="fast", jobs=2,
                          budget=20 * 20 * 64 * 25, kernel="numpy")
    assert r.slabs == 3
    monkeypatch.undo()
    b = geovox.convert_to(SPOT, tmp_path / "b.raw", shape=(20, 20, 150), color="fast", jobs=2,
                          budget=20 * 20 * 64 * 25, kernel="compiled")
    for name in ("a.raw", "a_rgba.raw"):  # the headers name their own files
        assert str(tmp_path / name) in r.files
        assert (tmp_path / name).read_bytes() == (tmp_path / name.replace("a", "b", 1)).read_bytes()


def test_outside_a_conversion_the_default_is_the_environment(monkeypatch):
    from geovox import kernels
    from geovox.nearest.search import kernel_module

    monkeypatch.setenv(KERNEL_ENV, "numpy")
    assert kernel_module() is None and kernels.lattice() is None
    with kernels.chosen("auto"):
        assert kernels.lattice() is kernels.compiled("_lattice", "lattice", "auto")


def test_engine_is_a_deprecated_name_of_backend(tmp_path):
    with pytest.warns(DeprecationWarning, match="backend"):
        o = Options.from_kwargs(engine="numpy")
    assert o.backend == "numpy"
    with pytest.warns(DeprecationWarning, match="backend"):
        r = geovox.convert_to(SPOT, tmp_path / "v.h5", engine="numpy", resolution=8)
    assert r.backend == "numpy"


def test_convert_many_jobs_is_a_deprecated_name_of_workers(tmp_path):
    with pytest.warns(DeprecationWarning, match="workers"):
        [a] = geovox.convert_many([SPOT], tmp_path / "a", jobs=1, resolution=8)
    [b] = geovox.convert_many([SPOT], tmp_path / "b", workers=1, resolution=8)
    assert a.status == b.status == "ok"
    with pytest.raises(ParameterError, match="`workers` must be a non-negative integer"):
        geovox.convert_many([SPOT], tmp_path / "c", workers=-2, resolution=8)


def test_manifest_records_match_old_and_new(tmp_path):
    from geovox.batch import _canonical, _record, _same_options

    new = _record(Options.from_kwargs(resolution=8, backend="auto"), ".raw", {})
    # A record of the Python API before Options: only what was named.
    old = _canonical(dict(options={"resolution": 8}, format="raw", write_options={}))
    assert new != old and _same_options(old, new)
    assert not _same_options(old, _record(Options.from_kwargs(resolution=9), ".raw", {}))
    assert not _same_options(old, _record(Options.from_kwargs(resolution=8), ".h5", {}))
    assert not _same_options({"options": {"colour": 1}}, new)  # not a record we wrote


def test_plan_takes_every_decision(tmp_path):
    m = geovox.load_mesh(SPOT)
    p = plan(m, Options(resolution=20, color=True))
    assert p.route == Route.MEMORY and p.blocks == ((0, 20),) and p.format is None
    assert p.inside is Inside.PARITY and p.inside == "parity" and p.colour is Colour.EXACT
    assert p.backend.name == "numpy" and p.axis == 2 and p.jobs >= 1
    # A file: the format from the registry, the route by the streaming rule.
    h5 = plan(m, dict(resolution=20, color="fast"), tmp_path / "v.h5")
    assert h5.format.name == "hdf5" and h5.route == Route.MEMORY
    zarr = plan(m, dict(resolution=20), tmp_path / "v.zarr")
    assert zarr.route == Route.SLABS and zarr.chunk_slab == 64 and zarr.blocks == ((0, 20),)
    # Slab by slab when asked (convert_to), several slabs within a budget.
    slabs = plan(m, dict(shape=(16, 16, 150), color="fast"), tmp_path / "v.raw", stream=True,
                 budget=16 * 16 * 64 * 25)
    assert slabs.route == Route.SLABS and slabs.axis == 1 and slabs.reuse_z
    assert slabs.blocks == ((0, 64), (64, 128), (128, 150))
    fill = plan(m, dict(shape=(16, 16, 150)), tmp_path / "v.raw", stream=True)
    assert fill.route == Route.FILL and fill.axis == 2
    assert plan(m, dict(resolution=20), tmp_path / "v.zarr", cluster=True).route == Route.CLUSTER
    # The format decides the grid's fit (.binvox: binvox's -d N cube) and checks it.
    cube = plan(m, dict(resolution=20), tmp_path / "v.binvox")
    assert np.ptp(cube.grid.spacing) == 0 and cube.grid.shape == (20, 20, 20)
    with pytest.raises(ParameterError, match="cubic voxels"):
        plan(m, dict(shape=(20, 30, 20)), tmp_path / "v.binvox")
    assert any("route: in memory" in line for line in p.describe())


def test_a_plan_travels_to_a_worker(tmp_path):
    m = geovox.load_mesh(SPOT)
    p = plan(m, Options(resolution=16, color="fast", density="coverage", supersample=2),
             tmp_path / "v.zarr")
    q = pickle.loads(pickle.dumps(p.for_task()))
    assert q.backend is p.backend  # by name: the worker's own instance
    assert q.jobs == 1 and q.format is None and q.options == p.options
    a, b = voxelize_block(m, p), voxelize_block(m, q)
    for k in ("occupancy", "colors", "density"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))


def test_one_report_and_one_progress_event(tmp_path):
    seen = []
    vol = geovox.voxelize(SPOT, resolution=12, color="fast", sdf=True, progress=seen.append)
    assert [e.stage for e in seen] == ["load", "rays", "colour", "sdf"]
    assert vol.colors is not None and vol.sdf is not None
    assert all(isinstance(e, geovox.Progress) and e.done is None for e in seen)
    seen.clear()
    r = geovox.convert_to(SPOT, tmp_path / "v.h5", shape=(8, 8, 150), budget=8 * 8 * 64 * 1.5,
                          progress=seen.append)
    assert isinstance(r, geovox.Report) and r.route == "slabs" and r.slabs == 3
    assert [(e.stage, e.done, e.total) for e in seen] == [("slab", 1, 3), ("slab", 2, 3),
                                                         ("slab", 3, 3)]
    # Read as the dict convert_to returned before.
    assert r["files"] == [str(tmp_path / "v.h5")] and r["shape"] == (8, 8, 150)
    assert r["inside_test"] == "parity" and r.get("nothing") is None
    assert set(r.keys()) >= {"shape", "spacing", "bounds", "inside", "slabs", "files", "timings"}
    seen.clear()
    res = geovox.convert_many([SPOT, SPOT], tmp_path / "out", resolution=8, progress=seen.append)
    assert [(e.stage, e.total) for e in seen] == [("model", 2), ("model", 2)]
    assert sorted(e.done for e in seen) == [1, 2] and {e.result.status for e in seen} == {"ok"}
    assert [r.status for r in res] == ["ok", "ok"]


def test_info_prints_the_plan(capsys):
    assert main(["info", SPOT, "-r", "64"]) == 0
    out = capsys.readouterr().out
    assert "plan: backend numpy, inside test parity" in out
    assert "route: in memory, one block; rays along z" in out


def test_no_hand_copied_signature_of_voxelize():
    """The reference shows voxelize's signature generated from the code; nothing copies it by hand.

    (The README and the user guide once kept it by hand in three places, which drifted.)
    """
    import os

    root = os.path.join(os.path.dirname(__file__), "..")
    pages = [os.path.join(root, "README.md")] + [
        os.path.join(d, f) for d, _, fs in os.walk(os.path.join(root, "docs")) for f in fs
        if f.endswith(".md")]
    for page in pages:
        with open(page, encoding="utf-8") as f:
            copied = [x for x in f.read().splitlines() if x.lstrip("`").startswith("voxelize(mesh,")]
        assert not copied, (page, copied)
    with open(os.path.join(root, "docs", "api", "voxelize.md"), encoding="utf-8") as f:
        assert "::: geovox.api.voxelize" in f.read()


def test_convert_to_loads_plans_and_chooses_once(tmp_path, monkeypatch):
    import geovox.inside
    import geovox.io.load
    import geovox.planner

    calls = {"load": 0, "plan": 0, "choose": 0, "grid": 0}

    def counting(name, fn):
        def f(*a, **k):
            # A loaded Mesh handed to load_mesh passes through: not a load.
            calls[name] += not (name == "load" and isinstance(a[0], geovox.Mesh))
            return fn(*a, **k)
        return f

    import geovox.api

    monkeypatch.setattr(geovox.io.load, "load_mesh", counting("load", geovox.io.load.load_mesh))
    monkeypatch.setattr(geovox.api, "plan", counting("plan", geovox.api.plan))
    monkeypatch.setattr(geovox.inside, "choose", counting("choose", geovox.inside.choose))
    monkeypatch.setattr(geovox.planner, "make_grid", counting("grid", geovox.planner.make_grid))
    r = geovox.convert_to(SPOT, tmp_path / "v.raw", shape=(8, 8, 150), color="fast",
                          budget=8 * 8 * 64 * 25)
    assert r.slabs == 3
    # Every slab is a block of the one plan: one load, one plan, one grid, one inside choice.
    assert calls == {"load": 1, "plan": 1, "choose": 1, "grid": 1}
