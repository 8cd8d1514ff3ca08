"""Converting many models in one command: folders searched, one task per model
on local processes or on a Dask cluster, existing outputs skipped, failures
reported without stopping the rest, a manifest to resume from.

Every model runs the same function, :func:`convert_one`, single-threaded,
whether in this process, a local process pool or a Dask worker; so the files
are the same byte for byte however the run is spread. Dask is imported only
when a client is given, fsspec only when the output is a URL.
"""

from __future__ import annotations

import datetime
import json
import os
import tempfile
import time
from dataclasses import dataclass, field

from .errors import GeovoxError, InputNotFoundError, OutputError, ParameterError
from .output import Kind, Target, is_url, make_folder, output_exists, upload
from .volume import Progress

#: File types searched for in folders. Archives (.zip, .tar.gz) are read when
#: named, but not searched for: a downloaded zip often holds several models or
#: none, and would be voxelised as one scene.
MESH_EXTENSIONS = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf", ".3mf", ".dae", ".zae")


@dataclass
class Result:
    """What became of one input.

    ``status`` is ``"ok"`` (converted), ``"skipped"`` (its output existed, or
    the manifest says it was done) or ``"failed"`` (``error`` says why, in
    one line). ``outputs`` lists every file written, the volume first (local
    paths, or URLs where the output folder is one). ``seconds`` is the time
    the model took where it ran; ``note`` the inside count and, in a few
    words, any warning (the summary table's cell); ``warnings`` every
    warning in full; ``inside_test`` the inside test that ran (``parity``,
    ``winding``, ...; empty unless converted).

    Attributes
    ----------
    input : str
        The input path, as found.
    status : {"ok", "skipped", "failed"}
    outputs : list of str
        Files written, the volume first.
    error : str
        One line; empty unless failed.
    seconds : float
        The model's own time, where it ran.
    note : str
        Inside count and warnings, in a few words.
    warnings : list of str
        Every warning in full.
    inside_test : str
        The inside test that ran (``Report.inside_test``); empty unless ``"ok"``.
    approximate : int
        Voxels left to an estimate of the winding number (``Report.approximate``:
        its work budget ran out); 0 where every voxel is exact or proven.
    """

    input: str
    status: str
    outputs: list = field(default_factory=list)
    error: str = ""
    seconds: float = 0.0
    note: str = ""
    warnings: list = field(default_factory=list)
    inside_test: str = ""
    approximate: int = 0

    @property
    def output(self):
        """The volume file (the first of ``outputs``), or None."""
        return self.outputs[0] if self.outputs else None


def find_inputs(paths) -> list:
    """Mesh files named directly or found (recursively, sorted) in the folders given.

    Raises
    ------
    InputNotFoundError
        A path does not exist, or a folder holds no file with a mesh extension.
    """
    found = []
    for p in paths:
        p = os.fspath(p)
        if os.path.isdir(p):
            before = len(found)
            for root, dirs, files in os.walk(p):
                dirs.sort()
                for name in sorted(files):
                    if name.lower().endswith(MESH_EXTENSIONS):
                        found.append(os.path.join(root, name))
            if len(found) == before:
                raise InputNotFoundError(f"no meshes found in {p} (looked for "
                                         f"{' '.join(MESH_EXTENSIONS)}, in every subfolder)")
        elif os.path.exists(p):
            found.append(p)
        else:
            raise InputNotFoundError(f"input file not found: {p}")
    return found


def parse_shard(shard):
    """``"K/N"`` or ``(K, N)`` -> ``(K, N)`` with ``1 <= K <= N`` (K counts from 1).

    Raises
    ------
    ParameterError
        Anything else.
    """
    if shard is None:
        return None
    try:
        k, n = (int(x) for x in (shard.split("/") if isinstance(shard, str) else shard))
    except (ValueError, TypeError, AttributeError):
        raise ParameterError(f"`shard` must be K/N with 1 <= K <= N, got {shard!r}") from None
    if not 1 <= k <= n:
        raise ParameterError(f"`shard` must be K/N with 1 <= K <= N, got {shard!r}")
    return k, n


def _written_since(target, started) -> bool:
    """Whether the local file ``target`` was written after the wall-clock time ``started``.

    Only the word in the summary depends on it ("ok" rather than "skipped"
    for a task the scheduler ran twice), so clocks a few milliseconds apart
    across a cluster, or a file system that stores whole seconds, do no harm.
    """
    if started is None or is_url(target):
        return False
    try:
        return os.stat(target).st_mtime >= started
    except OSError:
        return False


def convert_one(task) -> Result:
    """Convert one model; the unit of work of every batch (never raises for a bad model).

    A plan (:func:`geovox.plan`, streaming by the one rule) and its run.
    ``task`` is a dict: ``input``, ``stem``, ``out`` (folder or URL),
    ``options`` (an :class:`~geovox.Options`, single-threaded), ``ext``,
    ``overwrite``, ``write_options`` and ``versions`` (the client's geovox
    and NumPy, which a worker that joined a cluster late must match).
    """
    from .errors import collect_warnings

    t0 = time.perf_counter()
    path, out_dir, options = task["input"], task["out"], task["options"]
    try:
        _check_worker(task)
        from .formats import format_for
        from .planner import as_options, grid_of, load, plan
        from .runners import run

        options = as_options(options)
        remote = is_url(out_dir)
        folder = Target(Kind.FOLDER, out_dir, format_for("x" + task["ext"])).named(task["stem"])
        # geovox's own collector, not warnings.catch_warnings: tasks may run
        # side by side on threads of one worker (see geovox.errors.warn).
        with collect_warnings() as said:
            mesh = load(path, options)
            # .binvox: a resolution is binvox's -d N cube (see geovox.grid.fit_for).
            grid = grid_of(mesh, options, folder.fmt)
            target = folder.file_for(grid.shape)
            name = os.path.basename(target)
            if not task["overwrite"] and output_exists(target):
                if _written_since(target, task.get("started")):
                    # Written by this very run: its result was lost with the worker
                    # that held it, and the scheduler ran the task again.
                    return Result(path, "ok", [target], "", time.perf_counter() - t0,
                                  "written earlier in this run")
                return Result(path, "skipped", [target], "", time.perf_counter() - t0,
                              "output exists (use --overwrite)")
            with _scratch(remote) as tmp:
                if remote:
                    local = os.path.join(tmp, name)
                else:
                    os.makedirs(out_dir, exist_ok=True)  # a worker of a shared file system
                    local = target
                # The grid that named the file, not a second one made by the plan.
                report = run(mesh, plan(mesh, options, local, grid=grid),
                             write_options=task["write_options"])
                written = [local] + [f for f in report.files if f != local]
                outputs = upload(written, local, out_dir) if remote else written
        note = f"{report.inside:,} inside" + (f"; warning: {warning_cell(said, path)}" if said
                                               else "")
        return Result(path, "ok", outputs, "", time.perf_counter() - t0, note, list(said),
                      report.inside_test, report.approximate)
    except (GeovoxError, MemoryError) as exc:
        return Result(path, "failed", [], _line(str(exc)), time.perf_counter() - t0)
    except Exception as exc:  # a model must not stop the batch; say what happened
        return Result(path, "failed", [], _line(f"{type(exc).__name__}: {exc}"),
                      time.perf_counter() - t0)


def _check_worker(task) -> None:
    """A ClusterError where this worker's geovox or NumPy is not the client's."""
    from .cluster import versions

    mine = versions()
    if task.get("versions") and mine != task["versions"]:
        from .errors import ClusterError

        raise ClusterError(f"this worker has geovox {mine['geovox']} and NumPy {mine['numpy']}, "
                           f"the client geovox {task['versions']['geovox']} and NumPy "
                           f"{task['versions']['numpy']}")


#: Longest warning cell of a batch's summary row (the full text is in ``Result.warnings``).
CELL = 100


def warning_cell(messages, path="") -> str:
    """A model's warnings in a few words, for its row of a batch's summary.

    Each warning's first clause (up to ``"; "``: what was wrong, or how many
    voxels are approximate), without the model's own name, which the row
    already shows; cut to :data:`CELL` characters.

    Parameters
    ----------
    messages : list of str
        The warnings, in full.
    path : str
        The model's file.
    """
    prefix = os.path.basename(os.fspath(path)) + ": " if path else None
    heads = []
    for m in messages:
        head = m.split("; ", 1)[0]
        if prefix and head.startswith(prefix):
            head = head[len(prefix):]
        heads.append(head)
    cell = "; ".join(heads)
    return cell if len(cell) <= CELL else cell[:CELL - 1].rstrip() + "…"


def _scratch(wanted: bool):
    """A temporary folder (removed afterwards) where ``wanted``, else a null context."""
    import contextlib

    if not wanted:
        return contextlib.nullcontext(None)
    return tempfile.TemporaryDirectory(prefix="geovox-")


def _line(text: str) -> str:
    """One line: errors go into a table row and a JSONL record."""
    return " ".join(str(text).split())


def _canonical(value):
    """JSON-ready copy of an options dict (tuples and arrays as lists)."""
    if isinstance(value, dict):
        return {k: _canonical(v) for k, v in sorted(value.items())}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    return value


def _read_manifest(path) -> dict:
    """The last record of each input in a JSONL manifest ({} if there is none).

    Raises
    ------
    OutputError
        The file cannot be read, or is not UTF-8 text (so not a manifest).
    """
    done = {}
    if path is None or not os.path.exists(path):
        return done
    try:
        with open(path, encoding="utf-8") as f:
            for n, line in enumerate(f, 1):
                if not line.strip():
                    continue
                try:
                    rec = json.loads(line)
                    done[rec["input"]] = rec
                except (ValueError, KeyError, TypeError):
                    # A run killed while writing leaves a cut line (the next
                    # run starts a fresh line after it): ignore it, that model
                    # is simply done again. A line geovox did not begin (every
                    # record starts with "{") means some other text file,
                    # which appending would spoil.
                    if not line.lstrip().startswith("{"):
                        raise OutputError(f"cannot use {path} as the manifest: line {n} is not "
                                          f"a geovox manifest record") from None
    except OSError as exc:
        raise OutputError(f"cannot read the manifest {path}: {exc.strerror or exc}") from None
    except UnicodeDecodeError:
        # geovox writes ASCII JSON: this is some other file, which appending would spoil.
        raise OutputError(f"cannot use {path} as the manifest: it is not a geovox manifest "
                          f"(not UTF-8 text)") from None
    return done


def _submit_local(tasks, workers, on_result):
    if workers > 1 and len(tasks) > 1:
        from . import pool

        # Workers that import before their first model and end with the batch.
        extensions = tuple(sorted({os.path.splitext(t["input"])[1].lower() for t in tasks}))
        pool.run(convert_one, tasks, workers, on_result, initializer=warm,
                 initargs=(tasks[0]["ext"], extensions, tasks[0]["options"]))
    else:
        for i, t in enumerate(tasks):
            on_result(i, convert_one(t))


#: geovox modules every conversion may import on its way (loaders, inside
#: tests, slab streaming, the manifest's version check).
STACK = ("geovox.planner", "geovox.block", "geovox.runners", "geovox.io.load", "geovox.io.obj",
         "geovox.io.references", "geovox.mesh", "geovox.inside", "geovox.inside.choice",
         "geovox.inside.winding", "geovox.inside.caps", "geovox.inside.captree",
         "geovox.inside.edges", "geovox.inside.repair", "geovox.inside.bridge", "geovox.exact",
         "geovox.parity", "geovox.formats.headers", "geovox.cluster", "geovox.batch")


#: Compiled kernels (each optional: the NumPy twins run where one is missing).
KERNELS = ("geovox._lattice", "geovox._winding", "geovox._objtext", "geovox._nearest")


#: Loaders by input extension (OBJ, STL, PLY, glTF and GLB are geovox's own; the rest
#: goes through trimesh).
LOADERS = {".ply": "geovox.io.ply", ".gltf": "geovox.io.gltf_materials",
           ".glb": "geovox.io.gltf_materials", ".stl": "geovox.io.stl",
           ".3mf": "geovox.io.threemf", ".dae": "geovox.io.dae", ".zae": "geovox.io.dae"}


def warm(ext: str, extensions: tuple, options) -> None:
    """A batch's pool initializer: import what the batch's models will use.

    Parameters
    ----------
    ext : str
        The output extension (``".binvox"``): its writer and the packages it uses.
    extensions : tuple of str
        The lower-case extensions of the batch's inputs: their loaders (and
        trimesh for all but ``.obj``).
    options : Options
        The batch's options: the backend they name, colour's modules.
    """
    import importlib

    from .io.kinds import NATIVE

    wanted = list(STACK) + list(KERNELS)
    if options.color:
        wanted += ["geovox.colour.shading", "geovox.nearest.search"]
    if options.labels is not None:
        wanted.append("geovox.labels")
    for e in extensions:
        wanted += [LOADERS[e]] if e in LOADERS else []
        wanted += ["trimesh", "geovox.io.adaptor"] if e not in NATIVE else []
    for name in dict.fromkeys(wanted):
        try:
            importlib.import_module(name)
        except Exception:  # optional, or broken: the model says so where it matters
            pass
    from . import formats
    from .backends import get_backend

    try:
        formats.format_for("x" + ext).load()
        get_backend(options.backend)  # embree's first use imports trimesh and embreex
    except Exception:  # never the pool's failure: each model reports its own
        pass


#: Tasks out per worker thread on a cluster (see :func:`_submit_dask`).
IN_FLIGHT_PER_THREAD = 1


def _submit_dask(client, tasks, retries, on_result):
    """One task per model; a task lost with its worker is sent again up to ``retries`` times.

    Dask's own ``retries`` covers a task that raises, which ours never does;
    a worker that dies instead ends in ``KilledWorker`` once the scheduler's
    ``allowed-failures`` are spent, and is resubmitted here.

    Only as many tasks as the cluster has threads are out at a time (the
    count is refreshed as workers come and go). A worker that dies then
    takes down only the model it was running: had the scheduler handed it
    more, they would be blamed too (Dask queues only large groups of tasks
    on its side). It also keeps a run of 100,000 models from putting them
    all on the scheduler at once; the cost is one message round trip between
    two models on a thread (a few ms, see docs/benchmarks.md).
    """
    from asyncio import CancelledError
    from collections import deque

    from distributed import as_completed

    if not tasks:
        return

    from .cluster import one_line

    meta = {}
    queue = deque((i, 0) for i in range(len(tasks)))
    ac = as_completed([], loop=client.loop)

    def threads():
        try:
            return max(1, IN_FLIGHT_PER_THREAD * sum(client.nthreads().values()))
        except Exception:  # the scheduler is busy or gone; the futures will say so
            return 1

    limit, checked, out = threads(), time.monotonic(), 0

    def fill():
        nonlocal out
        while queue and out < limit:
            i, attempt = queue.popleft()
            f = client.submit(convert_one, tasks[i], pure=False,
                              key=f"geovox_convert-{i}-{attempt}-{os.urandom(4).hex()}")
            meta[f.key] = (i, attempt)
            ac.add(f)
            out += 1

    fill()
    for f in ac:
        out -= 1
        i, attempt = meta.pop(f.key)
        try:
            # A finished task's result can still be lost with its worker before
            # it is fetched; then result() raises like a task that erred.
            r = f.result() if f.status == "finished" else None
            exc = None if r is not None else f.exception()
        except (Exception, CancelledError) as e:  # lost, or cancelled by the scheduler
            r, exc = None, e
        if r is None:
            if attempt < retries:
                queue.appendleft((i, attempt + 1))
            else:
                worker = getattr(getattr(exc, "last_worker", None), "address", None)
                why = (f"its worker died ({worker})" if worker else
                       f"its task was lost ({one_line(exc)})")
                r = Result(tasks[i]["input"], "failed", [], f"{why}; tried {attempt + 1} time"
                           f"{'s' if attempt else ''} (retries={retries})")
        f.release()
        if r is not None:
            on_result(i, r)
        if time.monotonic() - checked > 2.0:
            limit, checked = threads(), time.monotonic()
        fill()


def convert_many(inputs, out, *, client=None, fmt=None, overwrite=False, workers=None, retries=2,
                 manifest=None, shard=None, progress=None, write_options=None, jobs=None,
                 **options) -> list:
    """Convert every model into the folder ``out``; one :class:`Result` per model, in input order.

    Each model is a plan and a run (:func:`convert_one`), single-threaded.

    Parameters
    ----------
    inputs : path or list of paths
        Mesh files, or folders searched (sorted, with subfolders) for them.
    out : path or URL
        Output folder, created if needed; or an fsspec URL (``s3://bucket/x``,
        ``gs://``, ``file://``, ``memory://``): each file is written locally
        and copied up complete.
    client : distributed.Client, optional
        Run one task per model on this Dask cluster; without it, ``workers``
        local processes (Dask is not imported).
    fmt : str, optional
        Output format name (``"raw"``, ``"h5"``, ...; default ``"raw"``).
        Files are named like ``spot_128x128x128_uint8.raw``; models with the
        same file name get ``_2``, ``_3``, ... in input order.
    overwrite : bool
        Convert even where the output exists (otherwise ``"skipped"``), and
        ignore what ``manifest`` says was done.
    workers : int, optional
        Local processes (no client; default 1). Each model runs
        single-threaded, so the files never depend on ``workers`` nor on the
        cluster.
    retries : int
        With a client: times a model is sent again after its worker died
        under it (a model that fails by itself is not retried: it would fail
        again).
    manifest : path, optional
        JSONL file; one record per finished model (``input``, ``options``,
        ``status``, ``outputs``, ``error``, ``seconds``, ``time``) is
        appended as it arrives. Inputs it records as done with the same
        options and output folder, whose files still exist, are not
        submitted again (they come back ``"skipped"``).
    shard : "K/N" or (K, N), optional
        Convert only the K-th of N parts (K from 1 to N) of the inputs, for
        array jobs: input ``i`` (0-based, in the order found) belongs to part
        ``i % N + 1``. Every part must be given the same inputs.
    progress : callable, optional
        ``progress(Progress("model", done, total, result))`` with each
        :class:`Result` as it arrives (any order).
    write_options : dict, optional
        Passed to the writer (``shell`` for ``.vox``, ``pack_bits`` for ``.npz``).
    jobs : int, optional
        Deprecated name of ``workers`` (``jobs`` means threads elsewhere).
    **options
        Any field of :class:`geovox.Options` but ``jobs``: resolution,
        shape, voxel_size, bounds, backend, inside, color, density, sdf, ...

    Returns
    -------
    list of Result
        In the order of the inputs (of this shard).

    Raises
    ------
    InputNotFoundError, ParameterError, OutputError
        Before any model runs; a model's own failure is its Result.
    """
    from .formats import format_for
    from .options import Options

    workers = _workers(workers, jobs)
    if "jobs" in options or "workers" in options:
        raise ParameterError("convert_many's models run single-threaded; give `workers` for "
                             "processes")
    opts = Options.from_kwargs(**options).replace(jobs=1)
    if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
        raise ParameterError(f"`retries` must be a non-negative integer, got {retries!r}")
    shard = parse_shard(shard)
    ext = format_for("x.raw", fmt).extensions[0]
    if isinstance(inputs, (str, os.PathLike)):
        inputs = [inputs]  # one file or folder, not a list of characters
    found = find_inputs(inputs)
    _check_manifest_path(manifest)
    # Read even with overwrite: it also refuses a file that is not a manifest
    # before anything is appended to it.
    done = _read_manifest(manifest)
    if overwrite:
        done = {}
    out = os.fspath(out)
    make_folder(out)
    tasks = _tasks(found, shard, out, opts, ext, overwrite, write_options, client)
    recorded = _record(opts, ext, write_options)
    # The manifest holds absolute paths: a re-run from another folder still matches.
    out_key = out if is_url(out) else os.path.abspath(out)
    results = [None] * len(tasks)
    todo = []
    for i, t in enumerate(tasks):
        rec = done.get(t["input"])
        if (rec and rec.get("status") in ("ok", "skipped") and rec.get("out") == out_key
                and _same_options(rec.get("options"), recorded) and rec.get("outputs")
                and all(output_exists(o) for o in rec["outputs"][:1])):
            results[i] = Result(t["shown"], "skipped", list(rec["outputs"]), "", 0.0,
                                "done (manifest)")
            if progress:
                progress(Progress("model", sum(r is not None for r in results), len(tasks),
                                  results[i]))
        else:
            todo.append(i)
    log = _open_log(manifest)

    def on_result(j, r):
        i = todo[j]
        r.input = tasks[i]["shown"]
        results[i] = r
        if log is not None:
            log.write(json.dumps(dict(
                input=tasks[i]["input"], out=out_key, options=recorded, status=r.status,
                outputs=[o if is_url(o) else os.path.abspath(o) for o in r.outputs],
                error=r.error, seconds=round(r.seconds, 4), inside_test=r.inside_test,
                approximate=r.approximate,
                time=datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")))
                + "\n")
            log.flush()  # the record survives the run being killed
        if progress:
            progress(Progress("model", sum(x is not None for x in results), len(tasks), r))

    try:
        sub = [tasks[i] for i in todo]
        if client is not None:
            _submit_dask(client, sub, retries, on_result)
        else:
            from .pool import sigterm_raises

            with sigterm_raises():  # the models in this process unwind too
                _submit_local(sub, workers, on_result)
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM (geovox.pool.Stopped)
        raise _stopped(exc, results, local=client is None) from None
    finally:
        if log is not None:
            log.close()
    return results


def _stopped(exc, results, local=True):
    """The :class:`geovox.pool.Stopped` that says how far a stopped batch got.

    Only local models are known to leave no partial file: a Dask worker is
    ended by its nanny, not unwound.
    """
    import signal

    from .pool import Stopped, signal_name

    signum = getattr(exc, "signum", signal.SIGINT)
    done = sum(r is not None for r in results)
    return Stopped(signum, f"stopped by {signal_name(signum)}: {done} of {len(results)} models "
                           f"done{', no partial file left' if local else ''} (the same command "
                           f"converts the rest)")


def _workers(workers, jobs) -> int:
    """Local processes, from ``workers`` or the deprecated ``jobs``."""
    if jobs is not None:
        import warnings

        warnings.warn("convert_many's `jobs=` (processes) is now `workers=`; `jobs` means threads "
                      "elsewhere", DeprecationWarning, stacklevel=3)
        if workers is None:
            workers = jobs
    if workers is None:
        return 1
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 0:
        raise ParameterError(f"`workers` must be a non-negative integer, got {workers!r}")
    from .parallel import resolve_jobs

    return resolve_jobs(workers)


def _check_manifest_path(manifest) -> None:
    """Checked before the output folder is made, so a bad manifest path leaves nothing behind.

    (The open in :func:`_open_log` still has the last word.)
    """
    if manifest is None:
        return
    folder = os.path.dirname(os.path.abspath(manifest))
    why = ("No such file or directory" if not os.path.isdir(folder) else
           "Is a directory" if os.path.isdir(manifest) else
           "Permission denied" if not os.access(folder, os.W_OK)
           or (os.path.exists(manifest) and not os.access(manifest, os.W_OK)) else None)
    if why:
        raise OutputError(f"cannot write the manifest {manifest}: {why}")


def _tasks(found, shard, out, opts, ext, overwrite, write_options, client) -> list:
    """One task dict per model of this shard (see :func:`convert_one`)."""
    # Names are given over all inputs before sharding, so every part names a
    # model as the whole run would.
    stems, seen = [], {}
    for p in found:
        stem = os.path.splitext(os.path.basename(p))[0]
        seen[stem] = seen.get(stem, 0) + 1
        stems.append(stem if seen[stem] == 1 else f"{stem}_{seen[stem]}")
    picked = range(len(found)) if shard is None else range(shard[0] - 1, len(found), shard[1])
    versions, task_out = None, out
    if client is not None:
        from .cluster import versions

        versions = versions()
        # A worker's working folder is not ours: it gets the absolute path.
        task_out = out if is_url(out) else os.path.abspath(out)
    return [dict(input=os.path.abspath(found[i]) if not is_url(found[i]) else found[i],
                 shown=found[i], stem=stems[i], out=task_out, options=opts, ext=ext,
                 overwrite=bool(overwrite), write_options=dict(write_options or {}),
                 versions=versions, started=time.time()) for i in picked]


def _record(opts, ext, write_options) -> dict:
    """What a manifest record says the model was made with."""
    return _canonical(dict(options=opts.to_record(), format=ext.lstrip("."),
                           write_options=write_options or {}))


def _same_options(old, recorded) -> bool:
    """Whether a manifest's ``options`` record asks for what ``recorded`` does.

    A record holds the options the run named; two are the same where they
    are with the others at their defaults (``resolution=8`` and
    ``resolution=8, backend="auto"`` make the same files).
    """
    if old == recorded:
        return True
    try:
        from .options import Options

        def full(rec):
            return _canonical(dict(rec, options=Options.from_kwargs(**rec["options"])
                                   .to_record(full=True)))

        return full(old) == full(recorded)
    except (GeovoxError, TypeError, KeyError, AttributeError):
        return False


def _open_log(manifest):
    """The manifest opened for appending, on a fresh line (None without one)."""
    if manifest is None:
        return None
    try:
        log = open(manifest, "a", encoding="utf-8")
        if log.tell() > 0:
            with open(manifest, "rb") as f:
                f.seek(-1, os.SEEK_END)
                if f.read(1) != b"\n":  # a run killed mid-line: start a fresh line
                    log.write("\n")
    except OSError as exc:
        raise OutputError(f"cannot write the manifest {manifest}: {exc.strerror or exc}") from None
    return log


def summary_table(results) -> str:
    """The table the CLI prints: model, status, time, output or error; counts at the end."""
    width = max([len(os.path.basename(r.input)) for r in results] + [5])
    lines = [f"{'model':<{width}}  {'status':<7}  {'time':>7}  details"]
    for r in results:
        detail = (f"{r.output} ({r.note})" if r.status == "ok" else
                  r.error if r.status == "failed" else f"{r.note}: {r.output}")
        lines.append(f"{os.path.basename(r.input):<{width}}  {r.status:<7}  {r.seconds:6.2f}s  {detail}")
    n = {s: sum(r.status == s for r in results) for s in ("ok", "skipped", "failed")}
    lines.append(f"{n['ok']} converted, {n['skipped']} skipped, {n['failed']} failed")
    return "\n".join(lines)


__all__ = ["Result", "convert_many", "convert_one", "find_inputs", "parse_shard", "summary_table",
           "warm"]
