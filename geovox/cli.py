"""Command-line interface: a thin layer over the library.

Only :func:`main` turns exceptions into one line on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from . import __version__
from .errors import GeovoxError

EXIT_OK, EXIT_ERROR, EXIT_USAGE = 0, 2, 2


class _Parser(argparse.ArgumentParser):
    """argparse that reports usage errors in one line, exit status 2."""

    def error(self, message):
        self.exit(EXIT_USAGE, f"geovox: error: {message} (see `geovox {self.prog.split()[-1]} --help`)\n"
                  if " " in self.prog else f"geovox: error: {message}\n")


def _positive_int(text):
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text!r}")
    return value


def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}") from None
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def _finite_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if value != value or value in (float("inf"), float("-inf")):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="geovox", description="Turn polygon meshes into voxel volumes.")
    p.add_argument("--version", action="version", version=f"geovox {__version__}")
    p.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = p.add_subparsers(dest="command", parser_class=_Parser)

    c = sub.add_parser("convert", help="voxelise a mesh and write the volume")
    c.add_argument("input", help="mesh file (OBJ, STL, PLY, GLB, ... anything trimesh reads)")
    c.add_argument("-o", "--output", required=True,
                   help="output file; the format comes from its extension (.raw, .h5, .hdf5)")
    res = c.add_mutually_exclusive_group()
    res.add_argument("-r", "--resolution", type=_positive_int, metavar="N",
                     help="N voxels on every axis (default 128)")
    res.add_argument("--shape", type=_positive_int, nargs=3, metavar=("NX", "NY", "NZ"),
                     help="voxels along x, y, z")
    res.add_argument("--voxel-size", type=_positive_float, metavar="S",
                     help="edge of a cubic voxel; the region grows to fit whole voxels")
    c.add_argument("--bounds", type=_finite_float, nargs=6,
                   metavar=("XMIN", "YMIN", "ZMIN", "XMAX", "YMAX", "ZMAX"),
                   help="region of interest (default: the mesh's bounding box)")
    c.add_argument("--backend", default="auto", choices=["auto", "embree", "numpy"],
                   help="ray-casting backend (default: auto = embree if installed, else numpy)")
    c.add_argument("--color", "--colour", dest="color", action="store_true",
                   help="also colour the voxels from the model's materials and textures")
    c.add_argument("--no-diffuse", dest="diffuse", action="store_false",
                   help="with --color: do not multiply by the material's Kd")
    c.add_argument("--ambient", action="store_true",
                   help="with --color: add the material's Ka")
    c.add_argument("-j", "--jobs", type=int, default=None, metavar="N",
                   help="threads to use (default: one per core); the result does not depend on it")
    c.add_argument("--format", dest="fmt", help="output format, overriding the extension")
    c.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")

    sub.add_parser("backends", help="list the ray-casting backends and whether each can run")
    sub.add_parser("formats", help="list the output formats")
    return p


def _convert(args) -> int:
    from . import formats
    from .pipeline import voxelize

    formats.format_for(args.output, args.fmt)  # unknown extension: fail before work
    formats.check_writable(args.output)
    t0 = time.perf_counter()
    import warnings

    from .errors import GeovoxWarning

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", GeovoxWarning)
        vol = voxelize(args.input, resolution=args.resolution, shape=args.shape,
                       voxel_size=args.voxel_size, bounds=args.bounds, backend=args.backend,
                       color=args.color, diffuse=args.diffuse, ambient=args.ambient,
                       jobs=args.jobs)
    for w in caught:
        if issubclass(w.category, GeovoxWarning):
            print(f"geovox: warning: {w.message}", file=sys.stderr)
        else:
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    t1 = time.perf_counter()
    written = formats.write(vol, args.output, fmt=args.fmt)
    t2 = time.perf_counter()
    if not args.quiet:
        nx, ny, nz = vol.shape
        dx, dy, dz = vol.spacing
        lo, hi = vol.bounds
        inside = vol.inside_count
        t = vol.timings
        print(f"{os.path.basename(vol.source)}: grid {nx} x {ny} x {nz} "
              f"over ({lo[0]:.6g}, {lo[1]:.6g}, {lo[2]:.6g})..({hi[0]:.6g}, {hi[1]:.6g}, {hi[2]:.6g})")
        print(f"voxel size {dx:.6g} x {dy:.6g} x {dz:.6g}, backend {vol.backend}")
        print(f"inside {inside:,} of {nx * ny * nz:,} voxels ({100.0 * inside / (nx * ny * nz):.2f}%)")
        colour = f", colour {t['colour']:.2f}" if "colour" in t else ""
        print(f"time {t2 - t0:.2f} s (load {t['load']:.2f}, rays {t['rays']:.2f}, "
              f"fill {t['fill']:.2f}{colour}, write {t2 - t1:.2f})")
        print("wrote " + ", ".join(written))
    return EXIT_OK


def _backends(args) -> int:
    from .backends import PREFERENCE, REGISTRY, available_backends

    have = available_backends()
    for name in PREFERENCE:
        status = "available" if name in have else f"missing (pip install {REGISTRY[name][1]})"
        print(f"{name:8s} {status}")
    return EXIT_OK


def _formats(args) -> int:
    from .formats import formats

    for f in formats():
        print(f"{f.name:6s} {' '.join(f.extensions):12s} {f.description}")
    return EXIT_OK


def main(argv=None) -> int:
    """Run the CLI; returns the exit status instead of exiting."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # argparse exits on --help and usage errors
        return int(exc.code or 0)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    handler = {"convert": _convert, "backends": _backends, "formats": _formats}[args.command]
    try:
        return handler(args)
    except GeovoxError as exc:
        if args.debug:
            raise
        print(f"geovox: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except KeyboardInterrupt:
        if args.debug:
            raise
        print("geovox: interrupted; no output was written", file=sys.stderr)
        return 130
    except MemoryError:
        if args.debug:
            raise
        print("geovox: error: out of memory; use a smaller resolution", file=sys.stderr)
        return EXIT_ERROR


def main_exit() -> None:
    """Console-script entry point."""
    sys.exit(main())
