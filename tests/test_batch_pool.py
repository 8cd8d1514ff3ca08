"""A batch's unit of work and its local process pool (geovox.batch, geovox.pool).

The grid is made once per model; a pool worker imports the conversion stack
before its first model's clock starts; SIGTERM and SIGINT end the workers
and leave no partial file.
"""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest
from conftest import SPOT

from geovox import batch
from geovox.options import Options


def _task(out, ext=".npy", **options):
    return dict(input=SPOT, shown=SPOT, stem="spot", out=str(out),
                options=Options.from_kwargs(resolution=16, **options).replace(jobs=1), ext=ext,
                overwrite=True, write_options={}, versions=None, started=time.time())


def test_the_batch_makes_each_models_grid_once(tmp_path, monkeypatch):
    """The grid that names the file is the plan's: make_grid runs once per model."""
    import geovox.planner

    real, made = geovox.planner.make_grid, []

    def counting(*args, **kwargs):
        made.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(geovox.planner, "make_grid", counting)
    for ext in (".npy", ".binvox"):
        made.clear()
        r = batch.convert_one(_task(tmp_path / ext[1:], ext))
        assert r.status == "ok", r.error
        assert len(made) == 1, ext
    monkeypatch.undo()
    # The same bytes as a plan that makes its own grid.
    from geovox.planner import load, plan
    from geovox.runners import run

    o = _task(tmp_path)["options"]
    for ext in (".npy", ".binvox"):
        name = os.path.basename(batch.convert_one(_task(tmp_path / ext[1:], ext)).outputs[0])
        mesh = load(SPOT, o)
        own = tmp_path / ("own" + ext)
        run(mesh, plan(mesh, o, str(own)))
        assert (tmp_path / ext[1:] / name).read_bytes() == own.read_bytes()


# --- the pool ----------------------------------------------------------------

def _cli_process(code, args, log, **env):
    """``code``, then the CLI on ``args``, in a fresh process of its own session (Popen).

    Its output goes to the file ``log`` (not a pipe, which a worker left
    running would hold open).
    """
    import subprocess
    import sys

    from conftest import ROOT

    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""), **env)
    with open(log, "w") as f:
        return subprocess.Popen([sys.executable, "-c", code + "\nfrom geovox.cli import main\n"
                                 f"sys.exit(main({args!r}))"], cwd=ROOT, env=env, text=True,
                                stdout=f, stderr=f, start_new_session=True)


def _models(folder, names):
    import shutil

    folder.mkdir()
    for n in names:
        shutil.copy(SPOT, folder / n)
    return folder


#: Records, for every model a worker starts, whether the pool's initializer had
#: run and which of the modules a conversion needs were imported already.
SPY = """
import json, os, sys, time
import geovox.batch, geovox.pool
real = geovox.batch.convert_one
def spy(task):
    mods = ("geovox.planner", "geovox.inside.winding", "geovox.inside.repair",
            "geovox.formats.binvox", "geovox._lattice", "geovox.backends.numpy")
    rec = dict(pid=os.getpid(), warmed=geovox.pool.WARMED, start=time.perf_counter(),
               present=[m for m in mods if m in sys.modules])
    with open(os.environ["SPY_LOG"], "a") as f:
        f.write(json.dumps(rec) + "\\n")
    return real(task)
geovox.batch.convert_one = spy
"""


def test_pool_workers_import_the_stack_before_their_first_model(tmp_path):
    import json

    models = _models(tmp_path / "in", ["a.obj", "b.obj", "c.obj", "d.obj"])
    log = tmp_path / "spy.jsonl"
    p = _cli_process(SPY, ["convert", str(models), "-o", str(tmp_path / "out"), "-j", "2",
                           "-r", "16", "--format", "binvox", "-q", "--manifest",
                           str(tmp_path / "m.jsonl")], tmp_path / "cli.txt", SPY_LOG=str(log))
    assert p.wait(timeout=300) == 0, (tmp_path / "cli.txt").read_text()
    recs = [json.loads(x) for x in log.read_text().splitlines()]
    assert len(recs) == 4 and p.pid not in {r["pid"] for r in recs}
    for r in recs:
        # The initializer had finished before the model's clock started, and
        # had imported what a model needs (the parent loads no mesh, so a
        # forked worker does not inherit them).
        assert r["warmed"] is not None and r["warmed"] <= r["start"], r
        assert len(r["present"]) == 6, r
    manifest = [json.loads(x) for x in (tmp_path / "m.jsonl").read_text().splitlines()]
    assert sorted(m["status"] for m in manifest) == ["ok"] * 4


#: A .npy writer that stops half-way: it writes part of its temporary file,
#: says so (a file named after its process id) and waits.
STALL = """
import os, sys, time
import geovox.formats.numpy_files as numpy_files
from geovox.formats import atomic_output
real = numpy_files.write_npy
def stall(volume, path, **kw):
    if os.path.basename(path).startswith("a_quick"):
        return real(volume, path, **kw)
    with atomic_output(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(b"half a file")
        open(os.path.join(os.environ["MARKS"], str(os.getpid())), "w").close()
        time.sleep(300)
    return [path]
numpy_files.write_npy = stall
"""


def _wait_for(what, test, seconds=120.0):
    """Poll ``test()`` until it is true; fail naming ``what`` after ``seconds``."""
    end = time.monotonic() + seconds
    while not test():
        if time.monotonic() > end:
            pytest.fail(f"gave up after {seconds:.0f} s waiting for {what}")
        time.sleep(0.1)


def _gone(pid: int) -> bool:
    """Whether process ``pid`` has ended (a zombie waiting to be reaped counts)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except (FileNotFoundError, ProcessLookupError):
        return True


def _children(pid: int) -> list:
    """The process ids whose parent is ``pid`` (from /proc)."""
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as f:
                    if int(f.read().rsplit(")", 1)[1].split()[1]) == pid:
                        out.append(int(d))
            except (OSError, ValueError, IndexError):
                pass
    return out


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="reads /proc to find the workers")
@pytest.mark.parametrize("how", ["SIGTERM", "SIGINT to the group"])
def test_a_stopped_batch_ends_its_workers_and_leaves_no_partial_file(tmp_path, how):
    models = _models(tmp_path / "in", ["a_quick.obj", "b.obj", "c.obj", "d.obj"])
    marks, out = tmp_path / "marks", tmp_path / "out"
    marks.mkdir()
    manifest = tmp_path / "run.jsonl"
    p = _cli_process(STALL, ["convert", str(models), "-o", str(out), "-j", "2", "-r", "16",
                             "--format", "npy", "--manifest", str(manifest)], tmp_path / "cli.txt",
                     MARKS=str(marks))
    try:
        # a_quick is written whole (and recorded); then both workers are half-way through a file.
        _wait_for("two workers half-way through a file", lambda: len(os.listdir(marks)) == 2)
        _wait_for("a_quick's record", lambda: manifest.exists() and manifest.read_text())
        workers = sorted(int(m) for m in os.listdir(marks))
        assert set(workers) <= set(_children(p.pid))
        assert len([n for n in os.listdir(out) if n.endswith(".tmp")]) == 2
        if how == "SIGTERM":
            p.send_signal(signal.SIGTERM)
        else:  # Ctrl-C: the terminal signals every process of the group
            os.killpg(p.pid, signal.SIGINT)
        p.wait(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    signum = signal.SIGTERM if how == "SIGTERM" else signal.SIGINT
    err = (tmp_path / "cli.txt").read_text()
    assert p.returncode == 128 + signum, err
    assert err.strip().splitlines() == [
        f"geovox: stopped by {signum.name}: 1 of 4 models done, no partial file left (the same "
        f"command converts the rest)"], err
    _wait_for("the workers to end", lambda: all(_gone(w) for w in workers), 30.0)
    # The model written before the signal is whole; nothing else is there.
    left = os.listdir(out)
    assert len(left) == 1 and left[0].startswith("a_quick_") and left[0].endswith(".npy"), left
    assert np.load(out / left[0]).any()


def test_sigterm_to_one_conversion_leaves_no_partial_file(tmp_path):
    marks = tmp_path / "marks"
    marks.mkdir()
    p = _cli_process(STALL, ["convert", SPOT, "-r", "16", "-o", str(tmp_path / "spot.npy")],
                     tmp_path / "cli.txt", MARKS=str(marks))
    try:
        _wait_for("the conversion half-way through its file", lambda: os.listdir(marks))
        assert [n for n in os.listdir(tmp_path) if n.endswith(".tmp")]
        p.send_signal(signal.SIGTERM)
        p.wait(timeout=60)
    finally:
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()
    assert p.returncode == 128 + signal.SIGTERM
    assert (tmp_path / "cli.txt").read_text().splitlines() == [
        "geovox: stopped by SIGTERM; no output was written"]
    assert sorted(os.listdir(tmp_path)) == ["cli.txt", "marks"]
