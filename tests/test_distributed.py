"""Many models on a Dask cluster (geovox.batch with a client, geovox.cluster).

Most tests share one in-process LocalCluster (threads, no worker processes:
quick to start); one test starts worker processes so that a task can kill
its worker. Outputs are compared byte for byte with the local path.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import ROOT, SPOT, corpus, dask_client

distributed = pytest.importorskip("distributed")
fsspec = pytest.importorskip("fsspec")

import geovox  # noqa: E402
from geovox import cluster as cluster_mod  # noqa: E402
from geovox.batch import convert_many, summary_table  # noqa: E402
from geovox.cli import main  # noqa: E402

RES = 12


@pytest.fixture(scope="module")
def client():
    with dask_client(n_workers=2, threads_per_worker=1, processes=False,
                     dashboard_address=":0") as c:
        yield c


@pytest.fixture()
def models(tmp_path):
    """Two good models (one name twice, in two folders) and one that fails."""
    folder = tmp_path / "models"
    (folder / "sub").mkdir(parents=True)
    for f in os.listdir(os.path.dirname(SPOT)):
        shutil.copy(os.path.join(os.path.dirname(SPOT), f), folder / f)
    shutil.copy(corpus("fuze", "fuze.obj"), folder / "fuze.obj")
    shutil.copy(SPOT, folder / "sub" / "spot.obj")
    (folder / "broken.obj").write_bytes(b"\x00\x01 not a mesh")
    return folder


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(Path(folder).iterdir())
            if not p.name.startswith(".")}


def test_cluster_gives_the_local_files_byte_for_byte(client, models, tmp_path):
    local = convert_many([models], tmp_path / "local", resolution=RES, color=True)
    remote = convert_many([models], tmp_path / "remote", client=client, resolution=RES,
                          color=True)
    # One result per input, in input order, whatever order they finished in.
    assert [r.input for r in remote] == [r.input for r in local]
    assert [os.path.basename(r.input) for r in remote] == ["broken.obj", "fuze.obj", "spot.obj",
                                                          "spot.obj"]
    assert [r.status for r in remote] == ["failed", "ok", "ok", "ok"], [r.error for r in remote]
    broken = remote[0]
    assert broken.outputs == [] and broken.error and "\n" not in broken.error
    assert remote[1].output.endswith("fuze_12x12x12_uint8.raw") and remote[1].seconds > 0
    assert remote[3].output.endswith("spot_2_12x12x12_uint8.raw")
    assert all(os.path.exists(p) for r in remote for p in r.outputs)
    a, b = _files(tmp_path / "local"), _files(tmp_path / "remote")
    assert len(a) > 6 and a.keys() == b.keys()
    for name in a:
        if not name.endswith(".json"):  # the sidecar names the folder it was written to
            assert a[name] == b[name], name
    # Existing outputs are skipped unless overwrite.
    again = convert_many([models], tmp_path / "remote", client=client, resolution=RES, color=True)
    assert [r.status for r in again] == ["failed", "skipped", "skipped", "skipped"]
    assert "skipped" in summary_table(again)


def test_cli_scheduler_address_runs_on_the_cluster(client, models, tmp_path, capsys, monkeypatch):
    (models / "broken.obj").unlink()
    assert main(["convert", str(models), "-o", str(tmp_path / "a"), "-r", str(RES), "-q"]) == 0
    address = client.scheduler.address
    assert main(["convert", str(models), "-o", str(tmp_path / "b"), "-r", str(RES),
                 "--scheduler", address]) == 0
    out = capsys.readouterr().out
    assert "3 converted, 0 skipped, 0 failed" in out
    assert _files(tmp_path / "a").keys() == _files(tmp_path / "b").keys()
    for name, data in _files(tmp_path / "a").items():
        if name.endswith(".raw"):
            assert (tmp_path / "b" / name).read_bytes() == data
    # The environment variable counts as asking.
    monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", address)
    assert main(["convert", str(models), "-o", str(tmp_path / "c"), "-r", str(RES), "-q"]) == 0
    assert _files(tmp_path / "c").keys() == _files(tmp_path / "a").keys()


def test_manifest_resumes_with_only_what_is_missing(client, models, tmp_path):
    out, log = tmp_path / "out", tmp_path / "run.jsonl"
    # An interrupted run: only part 1 of 2 was done, and the run was killed
    # while writing one more line.
    part = convert_many([models], out, client=client, manifest=log, shard="1/2", resolution=RES)
    assert [os.path.basename(r.input) for r in part] == ["broken.obj", "spot.obj"]
    lines = log.read_text().splitlines()
    assert len(lines) == 2
    rec = json.loads(lines[1])
    assert rec["status"] == "ok" and rec["options"]["options"] == {"resolution": RES}
    assert rec["input"] == str(models / "spot.obj") and rec["outputs"][0].endswith(".raw")
    assert {"input", "options", "status", "outputs", "error", "seconds", "inside_test",
            "time"} <= rec.keys()
    assert rec["inside_test"] == "parity"  # spot is closed
    with open(log, "a") as f:
        f.write('{"input": "cut sho')
    whole = convert_many([models], out, client=client, manifest=log, resolution=RES)
    assert [r.status for r in whole] == ["failed", "ok", "skipped", "ok"]
    assert whole[2].note == "done (manifest)" and whole[2].output == rec["outputs"][0]
    new = [json.loads(x) for x in log.read_text().splitlines()[3:]]
    # The failed model is tried again; the one done is not.
    assert sorted(os.path.basename(r["input"]) for r in new) == ["broken.obj", "fuze.obj",
                                                                 "spot.obj"]
    assert str(models / "spot.obj") not in [r["input"] for r in new]
    # Other options are another run: nothing is taken from the manifest.
    other = convert_many([models], out, client=client, manifest=log, resolution=RES + 1)
    assert [r.status for r in other] == ["failed", "ok", "ok", "ok"]


def test_shards_split_the_inputs_and_keep_the_whole_runs_names(models, tmp_path):
    (models / "broken.obj").unlink()
    whole = convert_many([models], tmp_path / "whole", resolution=8)
    parts = [convert_many([models], tmp_path / f"p{k}", shard=f"{k}/2", resolution=8)
             for k in (1, 2)]
    names = [os.path.basename(r.output) for p in parts for r in p]
    assert sorted(names) == sorted(os.path.basename(r.output) for r in whole)
    assert [os.path.basename(r.output) for r in parts[1]] == ["spot_8x8x8_uint8.raw"]
    assert [os.path.basename(r.output) for r in parts[0]] == ["fuze_8x8x8_uint8.raw",
                                                              "spot_2_8x8x8_uint8.raw"]
    assert convert_many([models], tmp_path / "p4", shard="4/4", resolution=8) == []  # 3 inputs
    for bad in ("0/2", "3/2", "a/b", "1"):
        with pytest.raises(geovox.ParameterError, match="K/N"):
            convert_many([models], tmp_path / "x", shard=bad)


def test_memory_urls_get_complete_files_only(client, models, tmp_path):
    (models / "broken.obj").unlink()
    url = "memory://geovox-test/out"
    local = convert_many([models], tmp_path / "local", resolution=RES)
    remote = convert_many([models], url, client=client, resolution=RES)
    assert [r.status for r in remote] == ["ok"] * 3
    fs = fsspec.filesystem("memory")
    assert all(o.startswith("memory://geovox-test/out/") for r in remote for o in r.outputs)
    names = sorted(os.path.basename(p) for p in fs.ls("/geovox-test/out", detail=False))
    assert names == sorted(_files(tmp_path / "local"))  # no temporary names left
    for r in local:
        for p in r.outputs:
            if not p.endswith(".json"):
                assert fs.cat(f"/geovox-test/out/{os.path.basename(p)}") == Path(p).read_bytes()
    assert [r.status for r in convert_many([models], url, resolution=RES)] == ["skipped"] * 3
    # file:// goes through a temporary name and a rename.
    [r] = convert_many([SPOT], "file://" + str(tmp_path / "viafile"), resolution=RES)
    assert r.output == "file://" + str(tmp_path / "viafile" / "spot_12x12x12_uint8.raw")
    assert sorted(os.listdir(tmp_path / "viafile")) == sorted(
        os.path.basename(p) for p in local[1].outputs)
    fs.rm("/geovox-test", recursive=True)


def test_zarr_folders_go_up_whole_through_urls(tmp_path):
    """A .zarr is a folder: every file of it is copied, its root zarr.json last."""
    pytest.importorskip("zarr")
    from geovox import formats
    from geovox.cli import main

    want = geovox.voxelize(SPOT, resolution=RES).occupancy
    fs = fsspec.filesystem("memory")
    [r] = convert_many([SPOT], "memory://geovox-zarr/out", fmt="zarr", resolution=RES)
    assert r.status == "ok" and r.output.endswith("/spot_12x12x12_uint8.zarr")
    keys = fs.find("/geovox-zarr/out/spot_12x12x12_uint8.zarr")
    local = tmp_path / "back.zarr"
    fs.get("/geovox-zarr/out/spot_12x12x12_uint8.zarr", str(local), recursive=True)
    assert len(keys) >= 3 and (formats.read(str(local)).occupancy == want).all()
    # Skipping looks at the root zarr.json, which a cut-short upload lacks.
    assert convert_many([SPOT], "memory://geovox-zarr/out", fmt="zarr",
                        resolution=RES)[0].status == "skipped"
    fs.rm("/geovox-zarr/out/spot_12x12x12_uint8.zarr/zarr.json")
    assert convert_many([SPOT], "memory://geovox-zarr/out", fmt="zarr",
                        resolution=RES)[0].status == "ok"
    fs.rm("/geovox-zarr", recursive=True)
    # One model into a URL that names its file: a .zarr and a .raw with its headers.
    for name in ("one.zarr", "one.raw"):
        url = "file://" + str(tmp_path / "up" / name)
        (tmp_path / "up").mkdir(exist_ok=True)
        assert main(["convert", SPOT, "-r", str(RES), "-o", url, "-q"]) == 0
        assert (formats.read(str(tmp_path / "up" / name)).occupancy == want).all()
    assert main(["convert", SPOT, "-r", str(RES), "-o", "file://" + str(tmp_path / "up" / "one.zarr"),
                 "-q"]) == 0  # replaced whole, not nested inside the old one
    assert sorted(os.listdir(tmp_path / "up" / "one.zarr")) == ["0", "zarr.json"]
    assert not [n for n in os.listdir(tmp_path / "up") if n.startswith(".")]


def test_an_unknown_url_protocol_is_one_line(tmp_path, capsys):
    from geovox.cli import main

    assert main(["convert", SPOT, "-r", "8", "-o", "nosuch://bucket/x.raw"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "nosuch://bucket/x.raw" in err


def test_unknown_option_and_bad_retries_are_refused(models, tmp_path):
    with pytest.raises(geovox.ParameterError, match="resolutoin"):
        convert_many([models], tmp_path, resolutoin=8)
    with pytest.raises(geovox.ParameterError, match="retries"):
        convert_many([models], tmp_path, retries=-1)


#: The run of :func:`test_a_worker_killed_mid_model_fails_that_model_after_retries`, in a
#: process of its own: a hung cluster there is killed, not left to hang the suite.
KILLED_WORKER_RUN = """
import faulthandler, json, os, sys

import distributed

from geovox import cluster as cluster_mod
from geovox.batch import convert_many


class DieOn(distributed.WorkerPlugin):
    # Defined in __main__ so that cloudpickle sends it by value to the workers.
    def setup(self, worker):
        import geovox.io.load

        real = geovox.io.load.load_mesh

        def load(path, *args, **kwargs):
            if os.path.basename(str(path)) == "die.obj":
                os._exit(3)
            return real(path, *args, **kwargs)

        geovox.io.load.load_mesh = load


if __name__ == "__main__":
    models, out, manifest, limit = sys.argv[1:5]
    # Past the limit: every thread's stack on stderr (where it waits), then exit 1.
    faulthandler.dump_traceback_later(float(limit), exit=True)
    with cluster_mod.client_from_options(local_cluster=2) as client:
        client.register_plugin(DieOn(), name="geovox-test-die")
        results = convert_many([models], out, client=client, retries=1, resolution=%d,
                               manifest=manifest)
    faulthandler.cancel_dump_traceback_later()
    print(json.dumps([[os.path.basename(r.input), r.status, r.error] for r in results]))
"""

#: Seconds the killed-worker run may take (it takes 10-30 s; two restarts of a
#: worker process under heavy load take longer, never this long).
KILLED_WORKER_LIMIT = 240


def test_a_worker_killed_mid_model_fails_that_model_after_retries(models, tmp_path):
    """Worker processes; a task calls os._exit in the middle of one model.

    The run is a process of its own with a bounded wait: a cluster that
    stops answering fails this test with every thread's stack, instead of
    hanging the suite.
    """
    import signal

    (models / "broken.obj").unlink()
    shutil.copy(SPOT, models / "die.obj")
    script = tmp_path / "killed_worker.py"
    script.write_text(KILLED_WORKER_RUN % RES)
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    p = subprocess.Popen([sys.executable, str(script), str(models), str(tmp_path / "out"),
                          str(tmp_path / "run.jsonl"), str(KILLED_WORKER_LIMIT)], cwd=ROOT,
                         env=env, text=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                         start_new_session=True)
    try:
        out, err = p.communicate(timeout=KILLED_WORKER_LIMIT + 60)
    except subprocess.TimeoutExpired:
        out, err = "", "(no answer, even to faulthandler)"
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)  # the cluster's nannies and workers with it
        p.wait()
    assert p.returncode == 0 and out.strip(), (
        f"the run did not finish within {KILLED_WORKER_LIMIT} s (status {p.returncode}); "
        f"where it waited:\n{err[-6000:]}")
    results = json.loads(out.strip().splitlines()[-1])
    got = {name: (status, error) for name, status, error in results}
    assert [name for name, _, _ in results] == ["die.obj", "fuze.obj", "spot.obj", "spot.obj"]
    assert got["die.obj"][0] == "failed"
    assert "worker died" in got["die.obj"][1] and "tried 2 times" in got["die.obj"][1]
    assert [status for _, status, _ in results[1:]] == ["ok"] * 3, results
    recs = [json.loads(x) for x in (tmp_path / "run.jsonl").read_text().splitlines()]
    assert sorted(r["status"] for r in recs) == ["failed", "ok", "ok", "ok"]


def test_a_local_cluster_with_no_worker_left_fails_its_models_in_bounded_time(tmp_path,
                                                                             monkeypatch):
    """A local worker that never comes back (its nanny gave up) must not hang the batch."""
    import threading

    key = "distributed.scheduler.no-workers-timeout"
    assert cluster_mod.LOCAL_CLUSTER_CONFIG.get(key) is not None  # a local cluster's own bound
    monkeypatch.setitem(cluster_mod.LOCAL_CLUSTER_CONFIG, key, "2s")  # shortened for the test
    done = {}
    with cluster_mod.client_from_options(local_cluster=1) as client:
        client.retire_workers(list(client.scheduler_info()["workers"]))  # closes its nanny too
        deadline = time.monotonic() + 60
        while client.nthreads() and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not client.nthreads(), "the worker was not retired"

        def batch():
            done["results"] = convert_many([SPOT], tmp_path / "out", client=client, retries=1,
                                           resolution=RES)

        t = threading.Thread(target=batch, daemon=True)
        t.start()
        t.join(120)
        assert not t.is_alive(), "the batch still waits for a worker after 120 s"
    [r] = done["results"]
    assert r.status == "failed" and "lost" in r.error and "tried 2 times" in r.error, r.error
    assert not (tmp_path / "out").exists() or not os.listdir(tmp_path / "out")


# --- bad set-ups: one line, exit status 2 -----------------------------------

def _cli(args, pre=""):
    """Run the CLI in a fresh process; (exit status, stderr lines, modules loaded)."""
    code = (f"import sys; {pre}\nfrom geovox.cli import main\nrc = main({args!r})\n"
            "import json; print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('dask', 'distributed', 'fsspec', 'zarr'))))\nsys.exit(rc)")
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("DASK_SCHEDULER_ADDRESS", None)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env,
                       timeout=60)
    mods = json.loads(p.stdout.strip().splitlines()[-1]) if p.stdout.strip() else None
    return p.returncode, p.stderr.strip().splitlines(), mods


def test_without_a_scheduler_dask_is_never_imported(models, tmp_path):
    (models / "broken.obj").unlink()
    rc, err, mods = _cli(["convert", str(models), "-o", str(tmp_path / "o"), "-r", "8", "-q",
                          "--manifest", str(tmp_path / "m.jsonl"), "--shard", "1/1"])
    assert rc == 0 and err == [] and mods == []
    assert len((tmp_path / "m.jsonl").read_text().splitlines()) == 3


@pytest.mark.parametrize("how", ["refused", "scheduler file", "not dask"])
def test_bad_scheduler_is_one_line(tmp_path, how):
    import socket

    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    port = server.getsockname()[1]
    if how == "refused":  # bound, never listening: refused
        args = ["--scheduler", f"tcp://127.0.0.1:{port}"]
    elif how == "scheduler file":
        args = ["--scheduler-file", str(tmp_path / "nope.json")]
    else:  # something listens and answers, but not Dask (a web server)
        import threading

        server.listen()

        def answer():
            import contextlib

            for _ in range(2):  # a first probe of the port, then Dask's hello
                with contextlib.suppress(OSError):
                    conn, _ = server.accept()
                    with conn:
                        conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n" * 4)

        threading.Thread(target=answer, daemon=True).start()
        args = ["--scheduler", f"127.0.0.1:{port}"]
    try:
        rc, err, _ = _cli(["convert", SPOT, SPOT, "-o", str(tmp_path / "o"), "-r", "8", *args])
    finally:
        server.close()
    assert rc == 2 and len(err) == 1 and err[0].startswith("geovox: error: "), err
    if how == "scheduler file":
        assert "scheduler file not found" in err[0] and "nope.json" in err[0]
    elif how == "not dask":
        assert f"127.0.0.1:{port} answered, but not as a Dask scheduler" in err[0]
    else:
        assert f"no Dask scheduler answered at tcp://127.0.0.1:{port}" in err[0]
    assert not (tmp_path / "o").exists() or not os.listdir(tmp_path / "o")


def test_the_environment_variable_asks_for_a_cluster(tmp_path, monkeypatch, capsys):
    import socket

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{server.getsockname()[1]}"
        monkeypatch.setenv("DASK_SCHEDULER_ADDRESS", address)
        assert main(["convert", SPOT, SPOT, "-o", str(tmp_path / "o"), "-r", "8"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"geovox: error: no Dask scheduler answered at {address} (Connection refused)"]


def test_missing_extra_says_what_to_install(tmp_path):
    rc, err, _ = _cli(["convert", SPOT, SPOT, "-o", str(tmp_path / "o"), "--scheduler",
                       "tcp://127.0.0.1:8786"], pre="sys.modules['distributed'] = None")
    assert rc == 2 and len(err) == 1
    assert "pip install 'geovox[distributed]'" in err[0]


def test_workers_with_other_versions_are_refused(client, monkeypatch, tmp_path, capsys):
    real = cluster_mod.versions

    def versions(dask_worker=None):  # dask_worker is given only on a worker
        v = real()
        if dask_worker is not None:
            v["numpy"] = "1.0.0"
        return v

    monkeypatch.setattr(cluster_mod, "versions", versions)
    address = client.scheduler.address
    with pytest.raises(geovox.ClusterError, match="2 of 2 workers differ.*NumPy 1.0.0"):
        with cluster_mod.client_from_options(scheduler=address):
            pass
    assert main(["convert", SPOT, SPOT, "-o", str(tmp_path / "o"), "--scheduler", address]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "install the same versions on every worker" in err[0]


def test_one_cluster_option_at_a_time():
    with pytest.raises(geovox.ParameterError, match="not scheduler and local_cluster"):
        with cluster_mod.client_from_options(scheduler="tcp://x:1", local_cluster=1):
            pass
    with pytest.raises(geovox.ParameterError, match="local_cluster"):
        with cluster_mod.client_from_options(local_cluster=0):
            pass


def test_a_task_on_a_worker_with_other_versions_fails_its_model(tmp_path):
    # Workers that join after the check at connection: each task checks too.
    from geovox.batch import convert_one
    from geovox.cluster import versions as cluster_versions

    task = dict(input=SPOT, stem="spot", out=str(tmp_path), options=geovox.Options(resolution=8,
                                                                                  jobs=1), ext=".raw",
                overwrite=False, write_options={}, versions=dict(cluster_versions(), geovox="0.0.1"))
    r = convert_one(task)
    assert r.status == "failed" and "the client geovox 0.0.1" in r.error
    assert os.listdir(tmp_path) == []
    task["versions"] = cluster_versions()
    assert convert_one(task).status == "ok"


def test_manifest_holds_absolute_paths(models, tmp_path, monkeypatch):
    (models / "broken.obj").unlink()
    monkeypatch.chdir(tmp_path)
    first = convert_many(["models"], "out", manifest="run.jsonl", resolution=8)
    assert [r.status for r in first] == ["ok"] * 3
    rec = json.loads((tmp_path / "run.jsonl").read_text().splitlines()[0])
    assert rec["out"] == str(tmp_path / "out") and os.path.isabs(rec["outputs"][0])
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    again = convert_many([models], tmp_path / "out", manifest=tmp_path / "run.jsonl", resolution=8)
    assert [r.note for r in again] == ["done (manifest)"] * 3


def test_geovox_warnings_are_gathered_per_thread_not_process_wide():
    """Tasks on threads of one worker each get their own warnings (no catch_warnings race)."""
    import threading
    import warnings

    from geovox.errors import GeovoxWarning, collect_warnings, warn

    both = threading.Barrier(2)
    got = {}

    def task(k):
        with collect_warnings() as said:
            both.wait()
            warn(f"from task {k}")  # the suite turns warnings into errors: this must not raise
            both.wait()
        with collect_warnings(drop=True) as dropped:
            warn("said once elsewhere")
        got[k] = (said, dropped)

    threads = [threading.Thread(target=task, args=(k,)) for k in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert got == {0: (["from task 0"], []), 1: (["from task 1"], [])}
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        warn("outside any collector")
    assert [(w.category, str(w.message)) for w in caught] == [(GeovoxWarning, "outside any collector")]


def test_workers_that_do_not_answer_the_version_check_are_an_error_in_bounded_time(
        client, monkeypatch):
    import threading
    import time

    real = cluster_mod.versions

    def slow():  # on the workers only: the client answers at once
        if threading.current_thread() is not threading.main_thread():
            time.sleep(1.5)
        return real()

    monkeypatch.setattr(cluster_mod, "versions", slow)
    monkeypatch.setattr(cluster_mod, "VERSION_TIMEOUT", 0.3)
    # Had it waited, the workers would have answered (same versions) and nothing raised.
    with pytest.raises(geovox.errors.ClusterError, match="did not say their versions within 0.3 s"):
        cluster_mod.check_versions(client)
    monkeypatch.setattr(cluster_mod, "versions", real)
    time.sleep(1.5)  # let the workers finish before the next test uses them


def test_cluster_tasks_read_references_under_the_rule_given(client, tmp_path):
    # model/obj/box.obj names ../textures/red.png: read by default, not under
    # references="folder", on the cluster's workers as in a local run.
    from PIL import Image

    (tmp_path / "model" / "textures").mkdir(parents=True)
    (tmp_path / "model" / "obj").mkdir()
    Image.new("RGB", (2, 2), (255, 0, 0)).save(tmp_path / "model" / "textures" / "red.png")
    v = ["0 0 0", "1 0 0", "1 1 0", "0 1 0", "0 0 1", "1 0 1", "1 1 1", "0 1 1"]
    quads = [(1, 4, 3, 2), (5, 6, 7, 8), (1, 2, 6, 5), (2, 3, 7, 6), (3, 4, 8, 7), (4, 1, 5, 8)]
    (tmp_path / "model" / "obj" / "box.obj").write_text(
        "mtllib box.mtl\n" + "".join(f"v {p}\n" for p in v) + "vt 0.5 0.5\nusemtl m\n"
        + "".join("f " + " ".join(f"{i}/1" for i in q) + "\n" for q in quads))
    (tmp_path / "model" / "obj" / "box.mtl").write_text(
        "newmtl m\nKd 1 1 1\nmap_Kd ../textures/red.png\n")
    box = str(tmp_path / "model" / "obj" / "box.obj")
    for rule, note in (("anywhere", False), ("folder", True)):
        results = convert_many([box], tmp_path / rule, client=client, resolution=4, color=True,
                               fmt="npz", references=rule)
        assert results[0].status == "ok"
        assert ("'../textures/red.png' (material 'm'" in results[0].note) == note, results[0].note
        import numpy as np

        with np.load(results[0].outputs[0]) as z:
            colours = z["colors"][z["occupancy"].astype(bool)][:, :3]
        red = np.all(colours == (255, 0, 0), axis=-1)
        assert red.all() if rule == "anywhere" else not red.any()
