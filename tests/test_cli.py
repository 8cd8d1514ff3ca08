"""The CLI, in-process: outputs read back, bad input gives one line and exit 2."""

from __future__ import annotations

import json
import os

import h5py
import numpy as np
import pytest

import geovox
from geovox.cli import main
from geovox.formats.raw import read_raw_volume

from conftest import SPOT


@pytest.fixture(scope="module")
def spot32():
    return geovox.voxelize(SPOT, resolution=32, backend="numpy")


def test_convert_raw_reads_back(tmp_path, spot32, capsys):
    out = tmp_path / "spot.raw"
    assert main(["convert", SPOT, "-o", str(out), "-r", "32", "--backend", "numpy"]) == 0
    raw = np.fromfile(out, dtype=np.uint8)
    assert raw.size == 32**3
    assert set(np.unique(raw)) == {0, 255}
    meta = json.loads((tmp_path / "spot.json").read_text())
    assert meta["shape"] == [32, 32, 32] and meta["dtype"] == "uint8"
    np.testing.assert_allclose(meta["spacing"], spot32.spacing)
    # x fastest: Fortran-order reshape gives [x, y, z].
    np.testing.assert_array_equal(raw.reshape(meta["shape"], order="F") == 255, spot32.occupancy)
    np.testing.assert_array_equal(read_raw_volume(out).occupancy, spot32.occupancy)
    text = capsys.readouterr().out
    assert "32 x 32 x 32" in text and "voxel size" in text and "backend numpy" in text
    assert f"inside {spot32.inside_count:,}" in text
    assert os.stat(out).st_mode & 0o044  # readable by others, like a plain open()


@pytest.mark.parametrize("ext", [".h5", ".hdf5"])
def test_convert_hdf5_reads_back(tmp_path, spot32, ext):
    out = tmp_path / f"spot{ext}"
    assert main(["convert", SPOT, "-o", str(out), "-r", "32", "--backend", "numpy", "-q"]) == 0
    with h5py.File(out, "r") as f:
        d = f["occupancy"]
        assert d.dtype == np.uint8 and d.compression == "gzip" and d.chunks is not None
        np.testing.assert_array_equal(d[...] == 1, spot32.occupancy)
        np.testing.assert_allclose(d.attrs["spacing"], spot32.spacing)
        np.testing.assert_allclose(d.attrs["bounds"], spot32.bounds)
        assert list(d.attrs["shape"]) == [32, 32, 32]
        assert d.attrs["axis_order"] == "xyz"
        assert d.attrs["backend"] == "numpy"
        assert d.attrs["source"].endswith("spot.obj")


def test_convert_options(tmp_path):
    out = tmp_path / "v.h5"
    args = ["convert", SPOT, "-o", str(out), "--shape", "8", "9", "10",
            "--bounds", "-0.5", "-0.8", "-0.7", "0.5", "1", "1.1", "-q"]
    assert main(args) == 0
    with h5py.File(out) as f:
        assert f["occupancy"].shape == (8, 9, 10)
        np.testing.assert_allclose(f["occupancy"].attrs["bounds"], [[-0.5, -0.8, -0.7], [0.5, 1, 1.1]])
    assert main(["convert", SPOT, "-o", str(out), "--voxel-size", "0.05", "-q"]) == 0
    with h5py.File(out) as f:
        np.testing.assert_allclose(f["occupancy"].attrs["spacing"], 0.05)


def _backend_lines(capsys) -> dict:
    assert main(["backends"]) == 0
    return {line.split()[0]: line.split(None, 1)[1] for line in capsys.readouterr().out.splitlines()}


def test_backends_command(capsys, monkeypatch):
    import importlib
    import sys

    from geovox import backends

    lines = _backend_lines(capsys)
    assert list(lines) == ["numpy", "embree", "webgpu"]
    assert lines["numpy"] == "available"
    # Each line says what Python says: geovox.usable_backends() lists exactly the available ones.
    assert [n for n, text in lines.items() if text.startswith("available")] == \
        geovox.usable_backends()
    try:  # embree's line is decided by whether embreex imports, checked here on its own
        importlib.import_module("embreex")
        assert lines["embree"] == "available"
    except ImportError:
        assert lines["embree"] == "missing (pip install embreex)"
    # Without embreex: the line says so, and Python agrees.
    monkeypatch.setitem(sys.modules, "embreex", None)
    monkeypatch.setitem(sys.modules, "trimesh.ray.ray_pyembree", None)
    monkeypatch.setattr(backends, "_instances", {})
    lines = _backend_lines(capsys)
    assert lines["embree"] == "missing (pip install embreex)"
    assert "embree" not in geovox.usable_backends()


def test_python_dash_m(tmp_path):
    import subprocess
    import sys

    r = subprocess.run([sys.executable, "-m", "geovox", "backends"], capture_output=True, text=True)
    assert r.returncode == 0 and "numpy" in r.stdout


def _bad_inputs(tmp_path):
    empty = tmp_path / "empty.obj"
    empty.write_bytes(b"")
    text = tmp_path / "notes.txt"
    text.write_text("hello\n")
    garbage = tmp_path / "garbage.obj"
    garbage.write_bytes(bytes(range(256)) * 40)
    verts_only = tmp_path / "verts.obj"
    verts_only.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\n")
    nan = tmp_path / "nan.obj"
    nan.write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    return {
        "missing input": ([str(tmp_path / "nope.obj")], "not found"),
        "folder as input": ([str(tmp_path)], "folder"),
        "empty file": ([str(empty)], "empty"),
        "not a mesh": ([str(text)], "cannot be read as a mesh"),
        "binary garbage": ([str(garbage)], "garbage.obj"),
        "vertices only": ([str(verts_only)], "verts.obj"),
        "nan vertices": ([str(nan)], "nan.obj"),
        "bounds min >= max": ([SPOT, "--bounds", "0", "0", "0", "0", "1", "1"], "min < max"),
        "resolution zero": ([SPOT, "-r", "0"], "positive integer, got '0'"),
        "resolution negative": ([SPOT, "-r", "-3"], "positive integer, got '-3'"),
        "resolution not a number": ([SPOT, "-r", "abc"], "positive integer, got 'abc'"),
        "voxel size zero": ([SPOT, "--voxel-size", "0"], "positive number"),
        "unknown extension": ([SPOT, "-o", str(tmp_path / "x.xyz")], "output format"),
        "missing output folder": ([SPOT, "-o", str(tmp_path / "no" / "x.raw")], "does not exist"),
        "color and exact color": ([SPOT, "--exact-color", "--color"], "not allowed with"),
        "empty scheduler": ([SPOT, SPOT, "--scheduler", " "], "--scheduler: must not be empty"),
    }


CASES = ["missing input", "folder as input", "empty file", "not a mesh", "binary garbage",
         "vertices only", "nan vertices", "bounds min >= max", "resolution zero",
         "resolution negative", "resolution not a number", "voxel size zero",
         "unknown extension", "missing output folder", "color and exact color",
         "empty scheduler"]


@pytest.mark.parametrize("case", CASES)
def test_bad_input_one_line_exit_2_nothing_written(case, tmp_path, capsys):
    args, needle = _bad_inputs(tmp_path)[case]
    outdir = tmp_path / "out"
    outdir.mkdir()
    if "-o" not in args:
        args = args + ["-o", str(outdir / "v.raw")]
    before = sorted(os.listdir(tmp_path))
    status = main(["convert"] + args)
    err = capsys.readouterr().err
    assert status == 2
    assert err.count("\n") == 1 and err.startswith("geovox: error:"), err
    assert "Traceback" not in err
    assert needle in err
    assert os.listdir(outdir) == []
    assert sorted(os.listdir(tmp_path)) == before


def test_debug_shows_the_traceback(tmp_path):
    with pytest.raises(geovox.InputNotFoundError):
        main(["--debug", "convert", str(tmp_path / "nope.obj"), "-o", str(tmp_path / "x.raw")])


class _FullDisk:
    """A binary file whose third write fails with ENOSPC, as on a full disk."""

    def __init__(self, f):
        self.f, self.writes = f, 0

    def write(self, data):
        self.writes += 1
        if self.writes > 2:
            raise OSError(28, "No space left on device")
        return self.f.write(data)

    def close(self):
        self.f.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.f.close()


def test_full_disk_leaves_existing_file_untouched(tmp_path, monkeypatch, capsys):
    import geovox.formats.raw as raw

    out = tmp_path / "v.raw"
    out.write_bytes(b"previous")
    monkeypatch.setattr(raw, "SLAB_VOXELS", 1)  # one write per z slice
    monkeypatch.setattr(raw, "open", lambda p, mode="r": _FullDisk(open(p, mode)), raising=False)
    status = main(["convert", SPOT, "-o", str(out), "-r", "8", "-q"])
    assert status == 2
    assert "disk full" in capsys.readouterr().err
    assert out.read_bytes() == b"previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.raw"]


def test_interrupt_while_writing_leaves_nothing(tmp_path, monkeypatch):
    import geovox.formats.chunks as chunks

    calls = {"n": 0}
    real = chunks.compress

    def interrupt_on_second_chunk(data):
        calls["n"] += 1
        if calls["n"] == 2:
            raise KeyboardInterrupt
        return real(data)

    monkeypatch.setattr(chunks, "compress", interrupt_on_second_chunk)
    vol = geovox.voxelize(SPOT, resolution=70, backend="numpy")
    with pytest.raises(KeyboardInterrupt):
        geovox.formats.write(vol, tmp_path / "v.h5")
    assert calls["n"] >= 2
    assert list(tmp_path.iterdir()) == []


def test_unwritable_folder(tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root can write anywhere")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    assert main(["convert", SPOT, "-o", str(ro / "v.raw")]) == 2
    assert "not writable" in capsys.readouterr().err


def test_convert_with_colour_writes_rgba_raw_and_hdf5(tmp_path):
    vol = geovox.voxelize(SPOT, resolution=24, color=True, backend="numpy")
    out = tmp_path / "c.raw"
    assert main(["convert", SPOT, "-o", str(out), "-r", "24", "--color", "--backend", "numpy", "-q"]) == 0
    meta = json.loads((tmp_path / "c.json").read_text())
    assert meta["color"]["data_file"] == "c_rgba.raw" and meta["color"]["components"] == 4
    rgba = np.fromfile(tmp_path / "c_rgba.raw", np.uint8).reshape(24, 24, 24, 4).transpose(2, 1, 0, 3)
    np.testing.assert_array_equal(rgba, vol.colors)
    h5 = tmp_path / "c.h5"
    assert main(["convert", SPOT, "-o", str(h5), "-r", "24", "--color", "--backend", "numpy", "-q"]) == 0
    with h5py.File(h5) as f:
        np.testing.assert_array_equal(f["color"][...], vol.colors)
        assert f["color"].attrs["components"] == "RGBA"


def test_convert_colour_options_and_warnings(tmp_path, capsys):
    obj = tmp_path / "m.obj"
    tet = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n"
    obj.write_text("mtllib missing.mtl\n" + tet)
    out = tmp_path / "m.h5"
    assert main(["convert", str(obj), "-o", str(out), "-r", "8", "--color", "-q"]) == 0
    err = capsys.readouterr().err
    assert err.startswith("geovox: warning: material file not found: 'missing.mtl'")
    # A material with both factors: Kd multiplies the base colour (white
    # here), --no-diffuse drops it, --ambient adds Ka (clipped at 1).
    (tmp_path / "k.mtl").write_text("newmtl k\nKd 0.5 0.25 0.125\nKa 0.25 0.5 0.125\n")
    lit = tmp_path / "k.obj"
    lit.write_text("mtllib k.mtl\nusemtl k\n" + tet)
    expect = {(): (0.5, 0.25, 0.125), ("--ambient",): (0.75, 0.75, 0.25),
              ("--no-diffuse",): (1, 1, 1), ("--no-diffuse", "--ambient"): (1, 1, 1)}
    for flags, rgb in expect.items():
        assert main(["convert", str(lit), "-o", str(out), "-r", "8", "--color", *flags,
                     "-q"]) == 0, flags
        with h5py.File(out) as f:
            c = f["color"][...]
            occ = f["occupancy"][...] == 1
        assert occ.sum() > 5
        got = c[occ, :3].astype(int)
        assert np.abs(got - np.round(255 * np.array(rgb))).max() <= 1, (flags, np.unique(got, axis=0))
    assert capsys.readouterr().err == ""


def test_faces_indexing_missing_vertices(tmp_path, capsys):
    obj = tmp_path / "bad.obj"
    obj.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    assert main(["convert", str(obj), "-o", str(tmp_path / "o.raw")]) == 2
    err = capsys.readouterr().err
    assert "bad.obj" in err and "vertex 9" in err and "3 vertices" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.obj"]


def test_grid_too_large_is_refused_before_allocating(tmp_path, capsys, monkeypatch):
    import geovox.memory as memory

    monkeypatch.setattr(memory, "available_memory", lambda: 64 * 2**20)
    assert main(["convert", SPOT, "-o", str(tmp_path / "o.h5"), "-r", "1024"]) == 2
    err = capsys.readouterr().err
    assert "1024 x 1024 x 1024" in err and "GiB" in err and "smaller resolution" in err
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(MemoryError):
        geovox.voxelize(SPOT, resolution=1024)


def test_output_folder_not_writable(tmp_path, capsys, monkeypatch):
    import geovox.formats as formats

    monkeypatch.setattr(formats.os, "access", lambda path, mode: False)
    assert main(["convert", SPOT, "-o", str(tmp_path / "o.raw")]) == 2
    assert "not writable" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []


def test_region_missing_the_mesh_warns_and_writes_an_empty_volume(tmp_path, capsys):
    out = tmp_path / "o.npy"
    assert main(["convert", SPOT, "-o", str(out), "-r", "4", "--bounds", "5", "5", "5", "6", "6", "6",
                 "-q"]) == 0
    assert "misses the mesh" in capsys.readouterr().err
    assert not np.load(out).any()


def test_input_is_never_touched(tmp_path):
    import shutil

    src = tmp_path / "spot.obj"
    shutil.copy(SPOT, src)
    before = (src.read_bytes(), os.stat(src).st_mtime_ns)
    main(["convert", str(src), "-o", str(tmp_path / "x.raw"), "-r", "8", "-q"])
    main(["convert", str(src), "-o", str(tmp_path / "nope" / "x.raw"), "-r", "8"])
    main(["convert", str(src), "-o", str(src), "-r", "8"])  # unknown output format: refused
    assert (src.read_bytes(), os.stat(src).st_mtime_ns) == before


@pytest.mark.parametrize("call,exc,builtin,needle", [
    (lambda: geovox.voxelize("/nonexistent/x.obj"), geovox.InputNotFoundError, FileNotFoundError,
     "/nonexistent/x.obj"),
    (lambda: geovox.voxelize(SPOT, resolution=-3), geovox.ParameterError, ValueError,
     "`resolution` must be a positive integer, got -3"),
    (lambda: geovox.voxelize(SPOT, bounds=(1, 0, 0, 0, 1, 1)), geovox.ParameterError, ValueError,
     "`bounds`"),
    (lambda: geovox.voxelize(SPOT, backend="cuda"), geovox.ParameterError, ValueError, "'cuda'"),
    (lambda: geovox.voxelize(SPOT, jobs=-1), geovox.ParameterError, ValueError, "`jobs`"),
    (lambda: geovox.voxelize(12345), geovox.MeshError, ValueError, "int"),
    (lambda: geovox.formats.write(geovox.voxelize(SPOT, resolution=2), "/nonexistent/dir/x.raw"),
     geovox.OutputError, OSError, "/nonexistent/dir"),
])
def test_library_errors_are_one_hierarchy_and_builtins(call, exc, builtin, needle):
    with pytest.raises(exc) as info:
        call()
    assert isinstance(info.value, geovox.GeovoxError) and isinstance(info.value, builtin)
    assert needle in str(info.value)


def _batch_folder(root):
    import shutil

    models = root / "models"
    (models / "sub").mkdir(parents=True)
    for f in os.listdir(os.path.dirname(SPOT)):
        shutil.copy(os.path.join(os.path.dirname(SPOT), f), models / f)
    shutil.copy(SPOT, models / "sub" / "spot.obj")  # same name, other folder
    (models / "broken.obj").write_bytes(b"\x00\x01 not a mesh")
    (models / "sub" / "noface.obj").write_text("v 0 0 0\nv 1 0 0\n")
    (models / "notes.txt").write_text("ignored: not a mesh extension")
    return models


def test_batch_converts_good_models_and_reports_bad_ones(tmp_path, capsys):
    models = _batch_folder(tmp_path)
    out = tmp_path / "out"
    assert main(["convert", str(models), "-o", str(out), "-r", "12"]) == 2
    text = capsys.readouterr().out
    assert "broken.obj" in text and "noface.obj" in text and "failed" in text
    assert "2 converted, 0 skipped, 2 failed" in text
    names = sorted(p.name for p in out.iterdir() if p.suffix == ".raw")
    assert names == ["spot_12x12x12_uint8.raw", "spot_2_12x12x12_uint8.raw"]
    # Existing outputs are skipped unless --overwrite.
    assert main(["convert", str(models), "-o", str(out), "-r", "12"]) == 2
    assert "0 converted, 2 skipped, 2 failed" in capsys.readouterr().out
    assert main(["convert", str(models / "spot.obj"), str(models / "sub"), "-o", str(out), "-r", "12",
                 "--overwrite"]) == 2
    assert "2 converted, 0 skipped, 1 failed" in capsys.readouterr().out


def test_batch_results_do_not_depend_on_jobs(tmp_path, capsys):
    models = _batch_folder(tmp_path)
    (models / "broken.obj").unlink()
    (models / "sub" / "noface.obj").unlink()
    assert main(["convert", str(models), "-o", str(tmp_path / "a"), "-r", "10", "-j", "1", "-q"]) == 0
    assert main(["convert", str(models), "-o", str(tmp_path / "b"), "-r", "10", "-j", "2", "-q"]) == 0
    for name in sorted(os.listdir(tmp_path / "a")):
        if name.endswith(".raw"):
            assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_batch_needs_a_folder_output(tmp_path, capsys):
    assert main(["convert", SPOT, SPOT, "-o", str(tmp_path / "x.raw")]) == 2
    assert "-o must be a folder" in capsys.readouterr().err


@pytest.mark.parametrize("where", ["missing folder", "a folder", "not text", "not text, --overwrite",
                                   "other text", "other text, --overwrite"])
def test_batch_bad_manifest_is_one_line_and_makes_no_output_folder(tmp_path, capsys, where):
    manifest = {"missing folder": tmp_path / "no" / "m.jsonl", "a folder": tmp_path,
                "not text": tmp_path / "model.bin", "not text, --overwrite": tmp_path / "model.bin",
                "other text": tmp_path / "notes.txt",
                "other text, --overwrite": tmp_path / "notes.txt"}[where]
    # Some other file named by mistake: never appended to, --overwrite or not.
    content = {"not text": bytes(range(256)),
               "other text": b'my notes\n{"input": 1}\n'}.get(where.split(",")[0])
    if content is not None:
        manifest.write_bytes(content)
    out = tmp_path / "out"
    assert main(["convert", SPOT, SPOT, "-o", str(out), "-r", "8", "--manifest", str(manifest)]
                + (["--overwrite"] if "overwrite" in where else [])) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("geovox: error: cannot ")
    assert "manifest" in err and "Traceback" not in err
    assert not out.exists()
    if content is not None:
        assert manifest.read_bytes() == content


def test_manifest_with_a_cut_last_line_still_resumes(tmp_path, capsys):
    manifest = tmp_path / "m.jsonl"
    out = tmp_path / "out"
    assert main(["convert", SPOT, "-o", str(out), "-r", "8", "--manifest", str(manifest), "-q"]) == 0
    [volume] = out.glob("*.raw")
    before = volume.stat().st_mtime_ns
    with open(manifest, "a") as f:
        f.write('{"input": "/half')  # a run killed mid-line
    capsys.readouterr()
    assert main(["convert", SPOT, "-o", str(out), "-r", "8", "--manifest", str(manifest)]) == 0
    printed = capsys.readouterr().out
    # The model the whole first line records is not converted again.
    assert "done (manifest)" in printed and "0 converted, 1 skipped, 0 failed" in printed
    assert volume.stat().st_mtime_ns == before
    lines = manifest.read_text().splitlines()
    assert len(lines) == 2 and lines[1] == '{"input": "/half'
    assert json.loads(lines[0])["status"] == "ok"


def test_manifest_and_results_record_the_inside_test(tmp_path):
    # A data set's slow models are mostly the open ones: the manifest says which test ran.
    opened = tmp_path / "open_box.obj"
    opened.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 0 0 1\nv 1 0 1\nv 1 1 1\nv 0 1 1\n"
                      "f 1 3 2\nf 1 4 3\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\n"
                      "f 3 8 7\nf 4 1 5\nf 4 5 8\n")  # a box without its top
    missing = tmp_path / "empty.obj"
    missing.write_text("# nothing\n")
    manifest = tmp_path / "m.jsonl"
    results = geovox.convert_many([SPOT, str(opened), str(missing)], tmp_path / "out",
                                  manifest=manifest, resolution=8)
    assert [(r.status, r.inside_test) for r in results] == [("ok", "parity"), ("ok", "winding"),
                                                            ("failed", "")]
    records = [json.loads(line) for line in manifest.read_text().splitlines()]
    assert {os.path.basename(r["input"]): r["inside_test"] for r in records} == {
        "spot.obj": "parity", "open_box.obj": "winding", "empty.obj": ""}


def test_review_regressions_give_one_line(tmp_path, capsys):
    # A batch whose -o is an existing file.
    target = tmp_path / "plainfile"
    target.write_text("x")
    assert main(["convert", SPOT, SPOT, "-o", str(target), "-r", "8"]) == 2
    # A voxel size so small the grid count overflows.
    assert main(["convert", SPOT, "-o", str(tmp_path / "v.raw"), "--voxel-size", "1e-300"]) == 2
    # Files that are not what their extension says, given to preview.
    (tmp_path / "junk.nrrd").write_bytes(b"not nrrd")
    assert main(["preview", str(tmp_path / "junk.nrrd"), "-o", str(tmp_path / "p.png")]) == 2
    (tmp_path / "cut.vox").write_bytes(b"VOX \x96\x00\x00\x00MAIN")
    assert main(["preview", str(tmp_path / "cut.vox"), "-o", str(tmp_path / "p.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("geovox: error:") == 4 and "Traceback" not in err
    assert "voxel_size" in err and "junk.nrrd" in err and "cut.vox" in err


def test_vox_without_a_palette_reads_in_grey(tmp_path):
    from geovox.formats import vox

    occ = np.zeros((3, 3, 3), bool, order="F")
    occ[1, 1, 1] = True
    data = vox.encode(occ, None)
    cut = data[:data.index(b"RGBA")]
    # Fix the MAIN chunk's children size after dropping the palette.
    import struct

    cut = cut[:16] + struct.pack("<i", len(cut) - 20) + cut[20:]
    (tmp_path / "np.vox").write_bytes(cut)
    back = geovox.formats.read(tmp_path / "np.vox")
    assert back.occupancy.sum() == 1 and tuple(back.colors[1, 1, 1, :3]) == (200, 200, 200)


def test_streaming_reports_missing_textures_once(tmp_path):
    import shutil

    from geovox.errors import GeovoxWarning

    for name in ("spot.obj", "spot.mtl"):
        shutil.copy(os.path.join(os.path.dirname(SPOT), name), tmp_path / name)
    with pytest.warns(GeovoxWarning, match="spot_texture.png") as record:
        geovox.convert_to(str(tmp_path / "spot.obj"), tmp_path / "s.h5", shape=(8, 8, 140),
                          color=True, budget=8 * 8 * 64 * 21)
    assert sum("spot_texture.png" in str(w.message) for w in record) == 1
