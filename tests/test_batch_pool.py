"""A batch's unit of work and its local process pool (geovox.batch, geovox.pool).

The grid is made once per model; a pool worker imports the conversion stack
before its first model's clock starts; SIGTERM and SIGINT end the workers
and leave no partial file.
"""

from __future__ import annotations

import os
import time

from conftest import SPOT

from geovox import batch
from geovox.options import Options


def _task(out, ext=".npy", **options):
    return dict(input=SPOT, shown=SPOT, stem="spot", out=str(out),
                options=Options.from_kwargs(resolution=16, **options).replace(jobs=1), ext=ext,
                overwrite=True, write_options={}, versions=None, started=time.time())


def test_the_batch_makes_each_models_grid_once(tmp_path, monkeypatch):
    """The grid that names the file is the plan's: make_grid runs once per model."""
    import geovox.pipeline

    real, made = geovox.pipeline.make_grid, []

    def counting(*args, **kwargs):
        made.append(args)
        return real(*args, **kwargs)

    monkeypatch.setattr(geovox.pipeline, "make_grid", counting)
    for ext in (".npy", ".binvox"):
        made.clear()
        r = batch._convert_one(_task(tmp_path / ext[1:], ext))
        assert r.status == "ok", r.error
        assert len(made) == 1, ext
    monkeypatch.undo()
    # The same bytes as a plan that makes its own grid.
    from geovox.pipeline import load, plan, run

    o = _task(tmp_path)["options"]
    for ext in (".npy", ".binvox"):
        name = os.path.basename(batch._convert_one(_task(tmp_path / ext[1:], ext)).outputs[0])
        mesh = load(SPOT, o)
        own = tmp_path / ("own" + ext)
        run(mesh, plan(mesh, o, str(own)))
        assert (tmp_path / ext[1:] / name).read_bytes() == own.read_bytes()


# --- the pool ----------------------------------------------------------------

def _cli_process(code, args, **env):
    """``code``, then the CLI on ``args``, in a fresh process of its own session (Popen)."""
    import subprocess
    import sys

    from conftest import ROOT

    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""), **env)
    return subprocess.Popen([sys.executable, "-c", code + "\nfrom geovox.cli import main\n"
                             f"sys.exit(main({args!r}))"], cwd=ROOT, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            start_new_session=True)


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
real = geovox.batch._convert_one
def spy(task):
    mods = ("geovox.pipeline", "geovox.inside.winding", "geovox.inside.repair",
            "geovox.formats.binvox", "geovox._lattice", "geovox.backends.numpy")
    rec = dict(pid=os.getpid(), warmed=geovox.pool.WARMED, start=time.perf_counter(),
               present=[m for m in mods if m in sys.modules])
    with open(os.environ["SPY_LOG"], "a") as f:
        f.write(json.dumps(rec) + "\\n")
    return real(task)
geovox.batch._convert_one = spy
"""


def test_pool_workers_import_the_stack_before_their_first_model(tmp_path):
    import json

    models = _models(tmp_path / "in", ["a.obj", "b.obj", "c.obj", "d.obj"])
    log = tmp_path / "spy.jsonl"
    p = _cli_process(SPY, ["convert", str(models), "-o", str(tmp_path / "out"), "-j", "2",
                           "-r", "16", "--format", "binvox", "-q", "--manifest",
                           str(tmp_path / "m.jsonl")], SPY_LOG=str(log))
    out, err = p.communicate(timeout=300)
    assert p.returncode == 0, err
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
