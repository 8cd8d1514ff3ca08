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
