"""What a short conversion pays for before and after its work (issue 27, section 3).

On the 100k-triangle model at 256³ the work itself is about a quarter of
the whole process; the rest is Python, NumPy and imports. These tests hold
the default path to importing only what it uses (no trimesh for the formats
geovox reads itself, no thread pool module, no tempfile, no XML or ZIP
reader for an OBJ), and the two stand-ins that made that possible --
plain threads in :func:`geovox.parallel.for_blocks` and an exclusive
create in :func:`geovox.formats.atomic_output` -- to what they replaced.
No timing is asserted.
"""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import threading

import numpy as np
import pytest

from geovox.errors import OutputError
from geovox.formats import atomic_output, atomic_outputs
from geovox.parallel import for_blocks

from conftest import corpus

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: Modules the default conversion of an OBJ, PLY or STL must not import.
NOT_IMPORTED = ("trimesh", "scipy", "PIL", "h5py", "concurrent.futures", "tempfile",
                "xml.etree.ElementTree", "zipfile", "difflib", "uuid", "geovox.io.threemf",
                "geovox.colour")

PROBE = r"""
import json, runpy, sys
sys.argv = ["geovox", "convert", sys.argv[1], "-r", "32", "-o", sys.argv[2]]
try:
    runpy.run_module("geovox", run_name="__main__")
except SystemExit as exc:
    assert not exc.code, exc.code
print(json.dumps({"modules": sorted(sys.modules),
                  "blas": __import__("os").environ.get("OPENBLAS_NUM_THREADS")}))
"""


def _probe(model, out, env=None):
    """A fresh ``geovox convert`` at 32³: the modules it imported and OPENBLAS_NUM_THREADS after."""
    r = subprocess.run([sys.executable, "-c", PROBE, model, out], cwd=ROOT, capture_output=True,
                       text=True, env=dict(env or os.environ, PYTHONPATH=ROOT), check=True)
    return json.loads(r.stdout.strip().splitlines()[-1])


def _modules(model, out):
    return set(_probe(model, out)["modules"])


def _plain_ply(path):
    """The bunny as a binary PLY of x, y, z and triangles: what geovox/ply.py reads itself."""
    from geovox.io.obj import read_obj

    mesh = read_obj(corpus("bunny_watertight", "bunny_oded.obj"))
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(mesh.vertices)}\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"element face {len(mesh.faces)}\nproperty list uchar int vertex_indices\n"
            "end_header\n").encode()
    faces = np.zeros(len(mesh.faces), dtype=[("n", "u1"), ("v", "<i4", 3)])
    faces["n"], faces["v"] = 3, mesh.faces
    with open(path, "wb") as f:
        f.write(head + mesh.vertices.astype("<f4").tobytes() + faces.tobytes())
    return str(path)


def _stl(path, binary):
    """The bunny as a binary or an ASCII STL: what geovox/io/stl.py reads itself."""
    from geovox.io.obj import read_obj

    mesh = read_obj(corpus("bunny_watertight", "bunny_oded.obj"))
    corners = mesh.vertices[mesh.faces].astype("<f4")
    if binary:
        rec = np.zeros(len(corners), [("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
        rec["v"] = corners
        data = b"solid bunny".ljust(80) + np.uint32(len(rec)).tobytes() + rec.tobytes()
    else:
        facets = ("facet normal 0 0 0\nouter loop\n" + "vertex {} {} {}\n" * 3
                  + "endloop\nendfacet\n") * len(corners)
        data = ("solid bunny\n" + facets.format(*corners.reshape(-1).tolist())
                + "endsolid bunny\n").encode()
    with open(path, "wb") as f:
        f.write(data)
    return str(path)


@pytest.mark.parametrize("model", ["bunny_oded.obj", "fuze.obj", "plain.ply", "binary.stl",
                                   "ascii.stl"])
def test_a_default_conversion_imports_only_what_it_uses(tmp_path, model):
    path = (_plain_ply(tmp_path / model) if model.endswith(".ply") else
            _stl(tmp_path / model, model == "binary.stl") if model.endswith(".stl") else
            corpus("bunny_watertight" if "bunny" in model else "fuze", model))
    mods = _modules(path, str(tmp_path / "out.raw"))
    assert "numpy" in mods and "geovox.planner" in mods  # the probe ran the conversion
    assert not mods & set(NOT_IMPORTED), sorted(mods & set(NOT_IMPORTED))


def test_for_blocks_covers_every_block_once_for_any_jobs():
    for jobs in (1, 2, 3, 8):
        for n, block in ((0, 4), (1, 4), (10, 3), (100, 7), (64, 64)):
            seen = np.zeros(n, dtype=np.int64)
            lock = threading.Lock()

            def fn(s, e):
                with lock:
                    seen[s:e] += 1

            for_blocks(fn, n, block, jobs)
            assert np.all(seen == 1), (jobs, n, block)


def test_for_blocks_runs_every_block_and_raises_the_first_error():
    done = []
    lock = threading.Lock()

    def fn(s, e):
        with lock:
            done.append(s)
        if s in (30, 70):
            raise ValueError(f"block {s}")

    with pytest.raises(ValueError, match="block 30"):
        for_blocks(fn, 100, 10, jobs=3)
    assert sorted(done) == list(range(0, 100, 10))  # the others still ran, as a pool's did


def test_for_blocks_threads_really_run_side_by_side():
    # Two blocks that each wait for the other: only two threads at once finish.
    barrier = threading.Barrier(2, timeout=10)
    for_blocks(lambda s, e: barrier.wait(), 2, 1, jobs=2)


def test_atomic_output_gives_a_plain_open_s_permissions(tmp_path):
    target = tmp_path / "out.bin"
    with atomic_output(target) as tmp:
        assert os.path.dirname(tmp) == str(tmp_path) and not os.path.exists(target)
        assert os.path.basename(tmp).startswith(".out.bin.") and tmp.endswith(".tmp")
        with open(tmp, "wb") as f:
            f.write(b"x")
    plain = tmp_path / "plain.bin"
    plain.write_bytes(b"x")
    assert stat.S_IMODE(os.stat(target).st_mode) == stat.S_IMODE(os.stat(plain).st_mode)
    assert sorted(os.listdir(tmp_path)) == ["out.bin", "plain.bin"]  # nothing left behind


def test_atomic_outputs_take_distinct_names_and_clean_up(tmp_path):
    with pytest.raises(RuntimeError):
        with atomic_outputs() as group:
            names = {group.add(tmp_path / "same.bin") for _ in range(50)}
            assert len(names) == 50 and all(os.path.isfile(n) for n in names)
            raise RuntimeError("interrupted")
    assert os.listdir(tmp_path) == []


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0,
                    reason="needs a folder the user cannot write (root can write anywhere)")
def test_atomic_output_in_a_read_only_folder(tmp_path):
    folder = tmp_path / "ro"
    folder.mkdir()
    folder.chmod(0o500)
    try:
        with pytest.raises(OutputError, match="cannot write in"):
            with atomic_output(folder / "x.bin"):
                pass
    finally:
        folder.chmod(0o700)


@pytest.mark.parametrize("given, expected", [(None, "1"), ("2", "2")])
def test_the_cli_asks_numpys_blas_for_one_thread_unless_told(tmp_path, given, expected):
    # OpenBLAS's own spinning threads cost a 2-core machine 0.1 s of processor
    # time in a short conversion (single_threaded_blas); a value the user set is theirs.
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given
    got = _probe(corpus("suzanne", "suzanne.obj"), str(tmp_path / "s.raw"), env)
    assert got["blas"] == expected


def test_blas_threads_are_left_alone_once_numpy_is_imported(monkeypatch):
    # In a process that already imported NumPy (a library user, these tests)
    # the variable would change nothing but what its children inherit.
    from geovox.cli import commands

    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    assert "numpy" in sys.modules
    commands.single_threaded_blas()
    assert "OPENBLAS_NUM_THREADS" not in os.environ
