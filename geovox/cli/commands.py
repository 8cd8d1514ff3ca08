"""Command-line interface: a thin layer over the library.

One function that adds its arguments and one that runs it, per subcommand
(:data:`COMMANDS`); ``choices`` come from the registries; a conversion is
:class:`~geovox.Options` from the arguments, a plan and a run, its warnings
printed by :func:`collecting` and its summary by :meth:`geovox.volume.Report.summary`.

Only :func:`main` turns exceptions into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import sys
import time

from ..errors import GeovoxError, ParameterError
from ..version import __version__

EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 2, 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line, exit status 2."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"geovox: error: {message} (see `geovox {self.prog.split()[-1]} --help`)\n"
                  if " " in self.prog else f"geovox: error: {message}\n")


def _int_at_least(low: int, what: str):
    """argparse type: an integer >= ``low``, refused as "must be ``what``, got ..."."""
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            value = low - 1
        if value < low:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return value
    return parse


_positive_int = _int_at_least(1, "a positive integer")
_non_negative_int = _int_at_least(0, "a non-negative integer")


def _non_empty(text):
    """argparse type: a string that is not blank (an empty `--scheduler ""`, say from an
    unset shell variable, would otherwise silently mean "no cluster")."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must not be empty, got {text!r}")
    return text


def _number(positive: bool):
    """argparse type: a finite float, positive if asked."""
    what = "a positive number" if positive else "a finite number"

    def parse(text):
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}") from None
        if not math.isfinite(value) or (positive and value <= 0):
            raise argparse.ArgumentTypeError(f"must be {what}, got {text!r}")
        return value

    return parse


_positive_float = _number(positive=True)
_finite_float = _number(positive=False)


def _band(text):
    """argparse type: the distance's band, a positive number of voxels or ``inf``."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0:  # nan, 0 and below
        raise argparse.ArgumentTypeError(f"must be a positive number of voxels or inf, "
                                         f"got {text!r}")
    return value


def _sdf_kind(text):
    """argparse type: ``signed`` or ``unsigned``."""
    if text not in ("signed", "unsigned"):
        raise argparse.ArgumentTypeError(f"must be 'signed' or 'unsigned', got {text!r}")
    return text


class _Choices:
    """argparse ``choices`` read from a registry only when first needed.

    Parsing ``geovox --help`` or ``geovox formats`` must not import the
    backends (NumPy) to list the names a ``convert`` option takes. (An
    argument with these choices needs a ``metavar``: argparse lists the
    choices of one without it as soon as it is added; its help shows them
    through ``%(choices)s``, formatted only when that help is printed.)
    """

    def __init__(self, names):
        self._names, self._list = names, None

    def _get(self):
        if self._list is None:
            self._list = list(self._names())
        return self._list

    def __contains__(self, item):
        return item in self._get()

    def __iter__(self):
        return iter(self._get())

    def __len__(self):
        return len(self._get())

    def __str__(self):
        return ", ".join(self._get())


def _backend_names():
    from ..backends import REGISTRY

    return ["auto", *REGISTRY]


def _inside_names():
    from ..options import Inside

    return [m.value for m in Inside]


def _label_sources():
    from ..options import LabelSource

    return [m.value for m in LabelSource]


def _overlap_rules():
    from ..options import Overlap

    return [m.value for m in Overlap]


def _occupancy_kinds():
    from ..options import Occupancy

    return [m.value for m in Occupancy]


def _format_names():
    from ..formats import formats

    return [f.name for f in formats()]


def add_grid_arguments(c, *, grid_only=False):
    """The conversion options (one argument per :class:`geovox.Options` field the CLI sets)."""
    res = c.add_mutually_exclusive_group()
    res.add_argument("-r", "--resolution", type=_positive_int, metavar="N",
                     help="N voxels on every axis (default 128)")
    res.add_argument("--shape", type=_positive_int, nargs=3, metavar=("NX", "NY", "NZ"),
                     help="voxels along x, y, z")
    res.add_argument("--voxel-size", type=_positive_float, metavar="S",
                     help="edge of a cubic voxel; the region grows to fit whole voxels")
    cube = c.add_mutually_exclusive_group()
    cube.add_argument("--cube", dest="fit", action="store_const", const="cube",
                      help="with -r N: an N³ cube of cubic voxels whose edge is the box's longest "
                           "side, at its minimum corner (binvox -d N; what -r means for .binvox)")
    cube.add_argument("--cube-center", "--cube-centre", dest="fit", action="store_const",
                      const="cube-center", help="the same cube, centred on the box (binvox -cb)")
    c.add_argument("--bounds", type=_finite_float, nargs=6,
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="region of interest (default: the mesh's bounding box)")
    c.add_argument("--like", metavar="IMAGE",
                   help="voxelise onto this image's grid (NIfTI .nii/.nii.gz, NRRD .nrrd/.seg.nrrd/"
                        ".nhdr, MetaImage .mhd/.mha, or a volume geovox wrote): its shape, spacing, "
                        "origin and direction, oblique included; excludes the grid options")
    c.add_argument("--mesh-space", choices=["lps", "ras"], type=str.lower, default=None,
                   help="with --like: the mesh's coordinate frame, overriding its 3D Slicer "
                        "SPACE= mark (default: the mark, else LPS)")
    c.add_argument("--occupancy", default="solid", choices=_Choices(_occupancy_kinds),
                   metavar="KIND",
                   help="which voxels are on: %(choices)s (default solid: the voxels whose centre "
                        "is inside; surface: every voxel the surface passes through; both: "
                        "either, which keeps open sheets and thin parts)")
    _references_argument(c)
    if grid_only:
        return
    c.add_argument("--backend", default="auto", choices=_Choices(_backend_names), metavar="NAME",
                   help="ray-casting backend: %(choices)s (default: auto = numpy, the faster one "
                        "for these column rays; all give the same volume)")
    c.add_argument("--inside", default="auto", choices=_Choices(_inside_names), metavar="TEST",
                   help="inside test: %(choices)s (default: auto = parity for closed meshes, "
                        "winding number otherwise)")
    # One of the two: both share `color`, and argparse would let the last one win silently.
    colour = c.add_mutually_exclusive_group()
    colour.add_argument("--color", "--colour", dest="color", action="store_true",
                        help="also colour the voxels from the model's materials and textures, "
                        "every voxel from its exact nearest surface point")
    colour.add_argument("--exact-color", "--exact-colour", dest="color", action="store_const",
                        const="exact", help="the same as --color (exact is its method)")
    colour.add_argument("--fast-color", "--fast-colour", dest="color", action="store_const",
                        const="fast", help="as --color, from the nearest of the six axis "
                        "crossings around each voxel (a nearby surface point, not always the "
                        "nearest; faster without the compiled kernel)")
    c.add_argument("--no-diffuse", dest="diffuse", action="store_false",
                   help="with --color: do not multiply by the material's Kd")
    c.add_argument("--ambient", action="store_true",
                   help="with --color: add the material's Ka")
    c.add_argument("--density", choices=["coverage"], default=None,
                   help="also compute each voxel's inside fraction (anti-aliased density)")
    c.add_argument("--supersample", type=_positive_int, default=4, metavar="K",
                   help="with --density: K x K rays per voxel column (default 4)")
    c.add_argument("--density-float", action="store_true",
                   help="with --density: store float32 0..1 instead of uint8 0..255")
    c.add_argument("--sdf", nargs="?", const="signed", default=False, type=_sdf_kind,
                   metavar="signed|unsigned",
                   help="also compute the distance to the surface (float32): signed, negative "
                        "inside (the default), or unsigned, for open sheets and scans")
    c.add_argument("--band", type=_band, default=3.0, metavar="VOXELS",
                   help="with --sdf: half-width of the exact band, in voxels (default 3); inf: "
                        "every voxel exact")
    c.add_argument("-j", "--jobs", type=int, default=None, metavar="N",
                   help="threads to use (default: one per core); with several models, worker "
                        "processes; the result does not depend on it")
    c.add_argument("--labels", default=None, choices=_Choices(_label_sources), metavar="SOURCE",
                   help="also label each voxel (%(choices)s): the model's parts (OBJ objects or "
                        "groups, scene nodes), connected components, the nearest surface's "
                        "material, or the input file (several inputs: one scene on one grid)")
    c.add_argument("--overlap", default="last", choices=_Choices(_overlap_rules), metavar="RULE",
                   help="with --labels: which part a voxel inside several takes: %(choices)s "
                        "(default: the last in file order)")
    c.add_argument("--fractions", action="store_true",
                   help="with --labels: each label's coverage fraction per voxel")


def _size(text):
    """argparse type: a size in bytes (``500M``, ``2G``; :func:`geovox.io.limits.parse_size`).

    Imported when an argument is given, not when the parser is built: ``geovox --help`` reads
    no reader's module.
    """
    from ..io.limits import parse_size

    return parse_size(text)


def _references_argument(c):
    c.add_argument("--references", choices=["anywhere", "folder"], default="anywhere",
                   help="files the model names (materials, textures, glTF buffers): read from "
                        "anywhere (default), or only from under the model's own folder, for "
                        "files you did not make; URLs are never fetched")
    c.add_argument("--max-input-size", type=_size, default=None, metavar="BYTES",
                   help="refuse an input that holds more than this once read or inflated "
                        "(500M, 2G; default: 100 x its size, at most half the memory)")


def add_convert(sub):
    c = sub.add_parser("convert", help="voxelise a mesh and write the volume")
    c.add_argument("input", nargs="+",
                   help="mesh files (OBJ, STL, PLY, GLB, ... anything trimesh reads) or folders of "
                        "them; several inputs, or a folder, convert each into the -o folder")
    c.add_argument("-o", "--output", default=None,
                   help="output file, format from its extension (see `geovox formats`); or a "
                        "folder, or nothing for the current one, to get a name with the grid "
                        "size and type such as spot_128x128x128_uint8.raw; either may be an "
                        "fsspec URL (s3://bucket/spot.zarr, gs://bucket/out/; the cloud extra), "
                        "written here first and then copied up")
    add_grid_arguments(c)
    c.add_argument("--format", dest="fmt", choices=_Choices(_format_names), metavar="FORMAT",
                   help="output format, overriding the extension: %(choices)s (see "
                        "`geovox formats`)")
    c.add_argument("--shell", action="store_true",
                   help=".vox: keep only the voxels with a face on the outside")
    c.add_argument("--pack-bits", action="store_true",
                   help=".npz: store occupancy as np.packbits bits (occupancy_bits, shape)")
    c.add_argument("--sparse", action="store_true",
                   help=".npz: the occupied voxels alone (with --sdf, the band's too): coords "
                        "(N, 3) int32 and colors, labels, sdf ... aligned with it (a .ply is always "
                        "sparse: the voxel centres)")
    c.add_argument("--preview", metavar="PNG", help="also write a preview picture")
    c.add_argument("--overwrite", action="store_true",
                   help="with several inputs: convert even where the output exists (and "
                        "whatever --manifest says was done)")
    many = c.add_argument_group("many models (a folder, or several inputs, into -o FOLDER or URL), "
                                "or one volume into -o NAME.zarr, on a Dask cluster")
    where = many.add_mutually_exclusive_group()
    where.add_argument("--scheduler", type=_non_empty, metavar="ADDRESS",
                       help="run one task per model (or per .zarr slab) on this Dask scheduler "
                            "(tcp://HOST:8786; "
                            "default: $DASK_SCHEDULER_ADDRESS if set); needs geovox[distributed]")
    where.add_argument("--scheduler-file", type=_non_empty, metavar="FILE",
                       help="the scheduler's address from the JSON file `dask scheduler "
                            "--scheduler-file` (or dask-jobqueue) wrote")
    where.add_argument("--local-cluster", type=_positive_int, metavar="N",
                       help="start a Dask cluster of N worker processes here, to try it out")
    many.add_argument("--retries", type=_non_negative_int, default=2, metavar="N",
                      help="on a cluster: send a model again up to N times when its worker "
                           "dies (default 2)")
    many.add_argument("--manifest", metavar="FILE",
                      help="append one JSON line per finished model; a re-run converts only "
                           "what it does not list as done")
    many.add_argument("--shard", metavar="K/N",
                      help="convert only part K of N (K from 1) of the inputs, for array jobs")
    c.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")


def add_preview(sub):
    pv = sub.add_parser("preview", help="write a PNG picture of a volume (or of a mesh, voxelised)")
    pv.add_argument("input", help="any file geovox wrote (a volume, its .json sidecar or .mhd/.nhdr "
                    "header), or a mesh")
    pv.add_argument("-o", "--output", required=True, help="PNG file to write")
    add_grid_arguments(pv)


def add_view(sub):
    vw = sub.add_parser("view", help="interactive 3D view of a volume (needs the 'view' extra), "
                                     "or with --html one self-contained page for any browser")
    vw.add_argument("input", help="any file geovox wrote (a volume, its .json sidecar or .mhd/.nhdr "
                    "header), or a mesh")
    vw.add_argument("--mesh", help="show this mesh beside the volume")
    vw.add_argument("--screenshot", metavar="PNG", help="render off-screen into PNG instead")
    vw.add_argument("--html", metavar="OUT.html",
                    help="write one self-contained page that shows the volume in any browser "
                         "(WebGL2; no PyVista, no network) instead of opening a window")
    vw.add_argument("--max-side", type=_positive_int, default=None, metavar="N",
                    help="with --html: show a volume with a side above N voxels downsampled "
                         "(default 256)")
    add_grid_arguments(vw)


def add_info(sub):
    info = sub.add_parser("info", help="what a mesh is like, and what a grid would cost")
    info.add_argument("input", help="mesh file")
    add_grid_arguments(info, grid_only=True)


def add_backends(sub):
    sub.add_parser("backends", help="list the ray-casting backends and whether each can run")


def add_formats(sub):
    sub.add_parser("formats", help="list the output formats")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="geovox", description="Turn polygon meshes into voxel volumes.")
    p.add_argument("--version", action="version", version=f"geovox {__version__}")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = p.add_subparsers(dest="command", parser_class=_Parser)
    for add, _ in COMMANDS.values():
        add(sub)
    return p


# --- what every handler shares --------------------------------------------

def _options(args):
    """The :class:`geovox.Options` the arguments set (imported here: ``--help`` needs none)."""
    from ..options import Options

    return Options.from_args(args)


@contextlib.contextmanager
def collecting():
    """Print geovox's warnings of the block as ``geovox: warning: ...`` lines when it ends.

    The one place the CLI reads warnings: :func:`geovox.errors.collect_warnings`
    for this thread, plus the GeovoxWarnings said on the library's worker
    threads (which the collector, being per thread, does not see). Other
    warnings pass through as Python shows them.
    """
    import warnings

    from ..errors import GeovoxWarning, collect_warnings

    with warnings.catch_warnings(record=True) as caught, collect_warnings() as said:
        warnings.simplefilter("always", GeovoxWarning)
        try:
            yield said
        finally:
            lines = list(said)
    for w in caught:
        if issubclass(w.category, GeovoxWarning):
            lines.append(str(w.message))
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    for line in lines:
        print(f"geovox: warning: {line}", file=sys.stderr)


def _progress_bar(args, options):
    """``(bar, progress)``: a bar over the stages or the slabs, on a terminal only (tqdm)."""
    if getattr(args, "quiet", False) or not sys.stderr.isatty():
        return None, None
    try:
        from tqdm import tqdm
    except ImportError:
        return None, None
    stages = ["load", "rays"] + [s for s, on in (("colour", options.color),
                                                 ("density", options.density),
                                                 ("sdf", options.sdf)) if on]
    bar = tqdm(total=len(stages) + 1, file=sys.stderr, leave=False,
               bar_format="{desc:<8} {bar} {n_fmt}/{total_fmt} {elapsed}")
    started = []

    def progress(event):
        if event.stage == "slab":
            bar.total = event.total
            bar.update(event.done - bar.n)
            return
        if started:
            bar.update(1)
        started.append(event.stage)
        bar.set_description_str(event.stage)

    return bar, progress


def _volume_or_mesh(args, path, largest=None):
    """A file geovox wrote (volume, header or sidecar) is read; anything else is voxelised.

    A ``.zarr`` is read from its finest pyramid level with every side at most ``largest``.
    """
    from .. import formats

    if formats.is_volume_file(path):
        return formats.read_volume(path, max_side=largest)
    return _voxelize(path, _options(args))


def _voxelize(mesh, options):
    """The volume of ``mesh`` in memory (a plan and a run), its warnings printed."""
    from ..planner import load, plan
    from ..runners import run

    with collecting():
        m = load(mesh, options)
        return run(m, plan(m, options)).volume


def _write_options(args, fmt) -> dict:
    """The writer's keyword options the CLI sets (``--shell`` for .vox, ``--pack-bits`` for .npz)."""
    from ..errors import ParameterError

    if args.pack_bits and fmt.name != "npz":
        raise ParameterError(f"--pack-bits is for .npz output, not {fmt.name}")
    if args.sparse and fmt.name != "npz":
        raise ParameterError(f"--sparse is for .npz output (a .ply is always sparse), "
                             f"not {fmt.name}")
    if args.sparse and args.pack_bits:
        raise ParameterError("--sparse and --pack-bits are two ways to write the occupancy; "
                             "give one")
    return {**({"shell": True} if args.shell and fmt.name == "vox" else {}),
            **({"pack_bits": True} if args.pack_bits else {}),
            **({"sparse": True} if args.sparse else {})}


def _cluster(args):
    """``client_from_options`` for the cluster arguments ($DASK_SCHEDULER_ADDRESS included)."""
    from ..cluster import client_from_options

    return client_from_options(getattr(args, "scheduler", None),
                               getattr(args, "scheduler_file", None),
                               getattr(args, "local_cluster", None))


# --- convert --------------------------------------------------------------

def _batch(args, target) -> int:
    from ..batch import convert_many, find_inputs, parse_shard, summary_table

    inputs = find_inputs(args.input)
    shard = parse_shard(args.shard)
    if args.preview:
        raise ParameterError("--preview takes one input; run geovox preview on each output instead")
    write_options = _write_options(args, target.fmt)
    options = _options(args)
    with _cluster(args) as client:
        bar = None
        if not args.quiet and sys.stderr.isatty():
            try:
                from tqdm import tqdm

                total = len(inputs) if shard is None else len(range(shard[0] - 1, len(inputs),
                                                                    shard[1]))
                bar = tqdm(total=total, unit="model", file=sys.stderr)
            except ImportError:
                bar = None
        failed = []

        def progress(event):
            failed.append(event.result.status == "failed")
            bar.update(1)
            bar.set_postfix_str(f"{sum(failed)} failed")

        from ..parallel import resolve_jobs

        try:
            # -j is processes here: each model runs single-threaded.
            results = convert_many(args.input, target.path, client=client, fmt=target.fmt.name,
                                   overwrite=args.overwrite, workers=resolve_jobs(args.jobs),
                                   retries=args.retries, manifest=args.manifest, shard=args.shard,
                                   progress=progress if bar else None,
                                   write_options=write_options,
                                   **{k: v for k, v in options.given_kwargs().items()
                                      if k != "jobs"})
        finally:
            if bar:
                bar.close()
    if not args.quiet or any(r.status == "failed" for r in results):
        print(summary_table(results))
    return EXIT_ERROR if any(r.status == "failed" for r in results) else EXIT_OK


def _convert_to_url(args, target) -> int:
    """One model into an fsspec URL: written into a local scratch folder, then copied up.

    The copy is :func:`geovox.output.upload`, as a batch's outputs' is: the
    volume (a folder output's root file) last, so nothing half-written is
    taken for a volume. What the local run prints is reprinted with the URL.
    """
    import io
    import shutil
    import tempfile

    from ..output import check_url, resolve_output, upload

    url = target.path
    parent, name = url.rsplit("/", 1)
    check_url(url)
    tmp = tempfile.mkdtemp(prefix="geovox-")
    try:
        local = resolve_output(os.path.join(tmp, name), args.fmt)
        said = io.StringIO()
        with contextlib.redirect_stdout(said):
            rc = _convert_one_model(args, local)
        if rc == EXIT_OK:
            files = sorted(os.path.join(tmp, f) for f in os.listdir(tmp))
            upload(files, local.path, parent)
        print(said.getvalue().replace(tmp + os.sep, parent + "/"), end="")
        return rc
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _many(args) -> bool:
    """Many models: several inputs (not one scene), a folder, a manifest or a shard."""
    if args.labels is not None and len(args.input) > 1:
        return False  # several files with --labels: one scene on one grid
    return bool(len(args.input) > 1 or os.path.isdir(args.input[0]) or args.manifest
                or args.shard)


def run_convert(args) -> int:
    """``geovox convert``: one model a plan and a run; many models a batch.

    The output (``-o``) is resolved once (:func:`geovox.output.resolve_output`):
    a file, a folder of named files, or a URL. One model sent to a cluster
    with a folder output, or to a URL folder, runs as a batch of one.
    """
    from ..output import Kind, resolve_output

    if args.fractions and not args.labels:
        raise ParameterError("--fractions needs --labels (part, component, file or feature)")
    args.input = args.input if isinstance(args.input, list) else [args.input]
    many = _many(args)
    if many:
        from ..batch import find_inputs

        find_inputs(args.input)  # a missing input or an empty folder says so before anything else
    target = resolve_output(args.output, args.fmt, many=many)
    cluster = args.scheduler or args.scheduler_file or args.local_cluster
    if many or (target.kind == Kind.FOLDER and (cluster or target.url)):
        return _batch(args, target)
    if target.url:
        return _convert_to_url(args, target)
    return _convert_one_model(args, target)


def _convert_one_model(args, target) -> int:
    """One model (or one scene of several files) into ``target``: a plan and a run."""
    from ..planner import load, plan
    from ..runners import run

    inputs = args.input
    t0 = time.perf_counter()
    target.check()  # before any work
    if args.preview:
        from .. import formats

        formats.check_writable(args.preview)
    options = _options(args)
    # Several files with --labels: one scene on one grid (--labels file names them).
    mesh = load(inputs if len(inputs) > 1 else inputs[0], options)
    stem = "scene" if len(inputs) > 1 else os.path.splitext(os.path.basename(inputs[0]))[0]
    t_read = time.perf_counter() - t0
    target = target.named(stem)
    write_options = _write_options(args, target.fmt)  # a bad combination fails before any work
    cluster = args.scheduler or args.scheduler_file or args.local_cluster
    if cluster and not target.fmt.can.cluster:
        raise ParameterError(f"a cluster writes one volume only into .zarr, not {target.fmt.name}; "
                             f"give -o a folder to send models to it as tasks")
    bar, progress = _progress_bar(args, options)
    # Only a format that can runs on a cluster ($DASK_SCHEDULER_ADDRESS included).
    client_of = _cluster(args) if target.fmt.can.cluster else contextlib.nullcontext()
    with collecting(), client_of as client:
        # The plan makes the grid (once) and names a folder's file after it.
        p = plan(mesh, options, target, cluster=client is not None)
        report = run(mesh, p, progress=progress, client=client, write_options=write_options)
        if bar is not None:
            bar.close()
        if args.preview:
            from ..preview import write_preview

            vol = report.volume
            if vol is None:
                # The preview of a grid this size is drawn from a 256³ conversion of the same model.
                small = options.replace(resolution=256, shape=None, voxel_size=None)
                vol = run(mesh, plan(mesh, small)).volume
            report.files.append(write_preview(vol, args.preview))
    if not args.quiet:
        print("\n".join(report.summary(time.perf_counter() - t0, t_read)))
    return EXIT_OK


# --- the other subcommands ------------------------------------------------

def run_preview(args) -> int:
    from .. import formats
    from ..preview import LARGEST, write_preview

    formats.check_writable(args.output)
    if args.like is not None:
        from ..preview import write_preview_like
        from ..reference import load_reference
        from ..volume import reference_line

        ref, image = load_reference(args.like, with_data=True)
        vol = _volume_or_mesh(args, args.input)
        note = "" if vol.mesh_space is None else reference_line(ref, vol.mesh_space).split("; ")[1]
        print(f"wrote {write_preview_like(vol, image, ref, args.output, note)}")
        return EXIT_OK
    vol = _volume_or_mesh(args, args.input, LARGEST)
    print(f"wrote {write_preview(vol, args.output)}")
    return EXIT_OK


def _view_html(args) -> int:
    from .. import formats
    from ..errors import ParameterError
    from ..view import LARGEST
    from ..view.html import MAX_SIDE, to_html

    if args.mesh or args.screenshot:
        raise ParameterError("--html writes a page on its own: drop --mesh and --screenshot")
    formats.check_writable(args.html)
    t0 = time.perf_counter()
    max_side = args.max_side or MAX_SIDE
    vol = _volume_or_mesh(args, args.input, max(LARGEST, max_side))
    out = to_html(vol, args.html, max_side=max_side, source=args.input)
    size = os.path.getsize(out)
    print(f"wrote {out} ({size / 1e6:.2f} MB, {time.perf_counter() - t0:.2f} s); open it in a browser")
    return EXIT_OK


def run_view(args) -> int:
    if args.html:
        return _view_html(args)
    if args.max_side is not None:
        from ..errors import ParameterError

        raise ParameterError("--max-side is for --html")
    from ..io.load import load_mesh
    from ..view import LARGEST, show

    vol = _volume_or_mesh(args, args.input, LARGEST)
    mesh = (load_mesh(args.mesh, references=args.references,
                      max_input_size=args.max_input_size) if args.mesh else None)
    out = show(vol, mesh=mesh, screenshot=args.screenshot)
    if out:
        print(f"wrote {out}")
    return EXIT_OK


def run_info(args) -> int:
    from ..errors import collect_warnings
    from ..planner import load, plan
    from ..report import format_report, grid_cost, mesh_report

    options = _options(args)
    mesh = load(args.input, options)
    with collect_warnings(drop=True):  # the report says what a repair does
        p = plan(mesh, options)
    cost = grid_cost(p.grid)  # the plan's grid: made once
    if options.like is not None:
        from ..reference import field_of_view, format_field_of_view, load_reference

        ref = load_reference(options.like)
        cost["spacing"] = ref.spacing.tolist()
        print(format_report(mesh_report(mesh), cost))
        print(format_field_of_view(ref, field_of_view(mesh, ref, options)))
    else:
        print(format_report(mesh_report(mesh), cost))
    from ..labels import parts_report

    print(parts_report(mesh))
    if p.surface_bits is not None:
        from ..report import surface_count

        print(f"surface voxels: {surface_count(mesh, p):,} of {p.grid.size:,}")
    print("\n".join(p.describe()))
    return EXIT_OK


def run_backends(args) -> int:
    from ..backends import backend_report

    # The same answer as geovox.usable_backends(); webgpu with its adapter.
    for name, (_, line) in backend_report().items():
        print(f"{name:8s} {line}")
    return EXIT_OK


def run_formats(args) -> int:
    from ..formats import formats

    rows = [(f.name, " ".join(f.extensions), f.description) for f in formats()]
    width = [max(len(r[k]) for r in rows) for k in (0, 1)]  # columns as wide as their longest
    for name, ext, description in rows:
        print(f"{name:{width[0]}s}  {ext:{width[1]}s}  {description}")
    return EXIT_OK


#: subcommand -> (adds its arguments, runs it)
COMMANDS = {
    "convert": (add_convert, run_convert),
    "preview": (add_preview, run_preview),
    "view": (add_view, run_view),
    "info": (add_info, run_info),
    "backends": (add_backends, run_backends),
    "formats": (add_formats, run_formats),
}


def single_threaded_blas() -> None:
    """Ask NumPy's BLAS for one thread, when NumPy is not imported yet and the user set none.

    OpenBLAS starts a thread per core when NumPy is imported and keeps them
    spinning after each call: on a 2-core machine 0.1 s of processor time of
    a 0.26 s conversion (bunny105k at 256³), a core taken from other work or
    from the compiled kernels' own threads while it spins. geovox's BLAS
    calls are 3 x 3 and 4 x 4 transforms, as fast on one thread; its
    parallel work is its own (OpenMP kernels, threads, processes). The
    pool's workers and a local cluster's inherit the setting.
    """
    if "numpy" not in sys.modules:
        os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def main(argv=None) -> int:
    """Run the CLI; returns the exit status instead of exiting."""
    single_threaded_blas()
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits on --help and usage errors
        return int(exc.code or 0)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    from ..pool import sigterm_raises

    try:
        with sigterm_raises():  # SIGTERM unwinds as Ctrl-C does: no partial file, one line
            return COMMANDS[args.command][1](args)
    except GeovoxError as exc:
        if args.debug:
            raise
        print(f"geovox: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt as exc:  # Ctrl-C, or SIGTERM (geovox.pool.Stopped)
        if args.debug:
            raise
        import signal

        signum = getattr(exc, "signum", signal.SIGINT)
        said = getattr(exc, "message", "") or (
            f"{'interrupted' if signum == signal.SIGINT else 'stopped by SIGTERM'}; no output "
            f"was written")
        print(f"geovox: {said}", file=sys.stderr)
        return 128 + signum
    except MemoryError:
        if args.debug:
            raise
        print("geovox: error: out of memory; use a smaller resolution", file=sys.stderr)
        return EXIT_ERROR
    except OSError as exc:  # last resort: a file problem no check foresaw
        if args.debug:
            raise
        where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
        print(f"geovox: error: {exc.strerror or exc}{where}", file=sys.stderr)
        return EXIT_ERROR


def main_exit() -> None:
    """Console-script entry point."""
    sys.exit(main())
