"""The format registry imports a writer's module only when its format is used."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from conftest import ROOT, SPOT

from geovox import formats

#: Third-party packages that only some writers need.
WRITER_LIBRARIES = ("h5py", "zarr", "nibabel", "nrrd", "PIL")


def _modules_after(args):
    """The writer modules and writer libraries a fresh ``geovox`` CLI run imported."""
    code = ("import sys, json\nfrom geovox.cli import main\nrc = main(%r)\n"
            "print(json.dumps(sorted(m for m in sys.modules if m.startswith('geovox.formats.') "
            "or m.split('.')[0] in %r)))\nsys.exit(rc)" % (args, WRITER_LIBRARIES))
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       cwd=ROOT, timeout=120)
    assert p.returncode == 0, p.stderr
    return set(json.loads(p.stdout.strip().splitlines()[-1]))


def test_a_npy_conversion_imports_no_other_writer(tmp_path):
    got = _modules_after(["convert", SPOT, "-r", "16", "-o", str(tmp_path / "s.npy"), "-q"])
    writers = {m.split(".")[2] for m in got if m.startswith("geovox.formats.")}
    assert writers & set(formats._MODULES) == {"numpy_files"}, got
    assert not {m for m in got if m.split(".")[0] in WRITER_LIBRARIES}, got
    assert (tmp_path / "s.npy").stat().st_size > 0


def test_an_h5_conversion_imports_its_writer_and_h5py_only(tmp_path):
    pytest.importorskip("h5py")
    got = _modules_after(["convert", SPOT, "-r", "16", "-o", str(tmp_path / "s.h5"), "-q"])
    writers = {m.split(".")[2] for m in got if m.startswith("geovox.formats.")}
    assert writers & set(formats._MODULES) == {"hdf5"}, got
    assert {m.split(".")[0] for m in got if m.split(".")[0] in WRITER_LIBRARIES} == {"h5py"}


def test_the_parts_are_the_modules_functions_looked_up_at_each_use(monkeypatch):
    import geovox.formats.binvox as binvox
    import geovox.formats.hdf5 as hdf5

    f = formats.format_for("x.h5")
    assert f.writer is hdf5.write_hdf5 and f.reader is hdf5.read_hdf5
    assert formats.format_for("x.binvox").check is binvox.check_grid
    assert formats.format_for("x.npy").slab_writer is None
    stand_in = object()
    monkeypatch.setattr(hdf5, "write_hdf5", stand_in)
    assert formats.format_for("x.hdf5").writer is stand_in


def test_slab_writers_make_the_modules_class(tmp_path):
    make = formats.format_for("x.raw").slab_writer
    assert make.__name__ == "slab_writer_RawWriter"
    assert formats.format_for("x.zarr").slab_writer is formats.zarr_format.ZarrWriter


def test_the_writer_modules_are_attributes_of_the_package():
    import geovox.formats.vdb as vdb

    assert formats.vdb is vdb and formats.zarr_format is sys.modules["geovox.formats.zarr"]
    with pytest.raises(AttributeError, match="no_such"):
        formats.no_such


def test_load_imports_the_writer_and_its_libraries():
    code = ("import sys\nfrom geovox import formats\nformats.format_for('x.h5').load()\n"
            "print('geovox.formats.hdf5' in sys.modules, 'h5py' in sys.modules, "
            "'geovox.formats.zarr' in sys.modules)")
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       cwd=ROOT, timeout=120)
    assert p.stdout.split() == ["True", "True", "False"], p.stderr


def test_formats_compare_and_hash_by_name():
    assert formats.format_for("a.h5") == formats.format_for("b.hdf5", "hdf5")
    assert formats.format_for("a.h5") != formats.format_for("a.npy")
    assert len({formats.format_for("a.npy"), formats.format_for("b.npy")}) == 1
    assert "npy" in repr(formats.format_for("a.npy"))
