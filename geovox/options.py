"""Options: every conversion option once, parsed at the boundary and then trusted.

In the manner of zarr's frozen ``ArrayConfig``: :class:`Options` holds each
option with its type, default and one line of doc (the ``doc`` metadata of
its field), validated once in ``__post_init__``. Everything below the public
functions -- :func:`geovox.plan`, the block function, the writers, a cluster
task -- takes an ``Options`` (or the :class:`~geovox.planner.Plan` made from
one) and checks nothing again.

A new option is one field here; the public keyword signatures of
:func:`geovox.voxelize`, :func:`geovox.convert_to` and
:func:`geovox.convert_many` are checked against these fields by a test
(``tests/test_options.py``), and the CLI's arguments build an ``Options``
through :meth:`Options.from_args`.
"""

from __future__ import annotations

import enum
import math
from dataclasses import MISSING, dataclass, field, fields, replace

from .errors import ParameterError
from .kernels import CHOICES as KERNELS
from .kernels import KERNEL_ENV, kernel_default


class Inside(enum.StrEnum):
    """An inside/outside test (see :mod:`geovox.inside`); a ``str``, so ``Inside.PARITY == "parity"``."""

    AUTO = "auto"
    PARITY = "parity"
    VOTE = "vote"
    WINDING = "winding"


class Colour(enum.StrEnum):
    """How voxels are coloured (see :mod:`geovox.colour`)."""

    EXACT = "exact"  #: from each voxel's exact nearest surface point
    FAST = "fast"  #: from the nearest of the six axis crossings around it


class Occupancy(enum.StrEnum):
    """Which voxels are on (``occupancy=``; the rule of each: :mod:`geovox.surface`, :mod:`geovox.inside`)."""

    SOLID = "solid"  #: the voxels whose centre is inside the closed surface
    SURFACE = "surface"  #: the voxels the surface passes through
    BOTH = "both"  #: either: the solid with its thin parts and open sheets kept


class LabelSource(enum.StrEnum):
    """What a voxel's label says (``labels=``; see :mod:`geovox.labels`)."""

    PART = "part"  #: the model's own parts: OBJ objects or groups, scene nodes
    COMPONENT = "component"  #: its connected components
    MATERIAL = "material"  #: the material of the voxel's exact nearest surface point
    FILE = "file"  #: the input file (several files, one scene)
    FEATURE = "feature"  #: the feature ID of glTF's EXT_mesh_features (3D Tiles, BIM)


class Overlap(enum.StrEnum):
    """Which part a voxel inside several takes (``overlap=``)."""

    LAST = "last"  #: the later in file order
    FIRST = "first"  #: the earlier
    SMALLEST = "smallest"  #: the one with the smaller enclosed volume


class References(enum.StrEnum):
    """Where the files a model names may be read from (``references=``; see :mod:`geovox.io.references`)."""

    ANYWHERE = "anywhere"  #: anywhere on this machine (URLs are never fetched)
    FOLDER = "folder"  #: only under the model's own folder, for files you did not make


def _doc(text: str, default=MISSING, *, factory=None, record=True, new=False):
    """A dataclass field with its one line of doc.

    ``record``: whether manifests record it; ``new``: an option added after
    manifests existed, recorded only where it is not its default (so older
    records still match).
    """
    meta = {"doc": text, "record": record, "new": new}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class Options:
    """Every option of one conversion (see :func:`geovox.voxelize` for the full account).

    Build it with keywords (``Options(resolution=256, color=True)``), from a
    dict that may hold anything (:meth:`from_kwargs`: an unknown key is a
    ParameterError naming the closest option) or from the command line's
    arguments (:meth:`from_args`). Frozen: derive another with
    :meth:`replace`.

    Raises
    ------
    ParameterError
        A value out of range, with the message the option always gave.
    """

    resolution: int | None = _doc("voxels on every axis (default 128 when no shape or voxel size)",
                                  None)
    bounds: tuple | None = _doc("region (xmin, ymin, zmin, xmax, ymax, zmax); default the mesh's "
                                "bounding box", None)
    backend: object = _doc("ray-casting backend: auto, embree, numpy, webgpu (or a Backend)", "auto")
    shape: tuple | None = _doc("voxels along x, y, z (instead of resolution)", None)
    voxel_size: float | None = _doc("edge of a cubic voxel (instead of resolution); the region "
                                    "grows to whole voxels", None)
    fit: str | None = _doc("how resolution covers the region: 'box' (None), 'cube' (binvox -d N) "
                           "or 'cube-center' (binvox -cb); .binvox defaults to 'cube'", None,
                           new=True)
    axis: int = _doc("direction of the column rays: 0, 1 or 2 (z)", 2)
    occupancy: str = _doc("which voxels are on: 'solid' (centre inside), 'surface' (the surface "
                          "passes through) or 'both'", "solid", new=True)
    color: object = _doc("colour the voxels: False, True or 'exact', or 'fast'", False)
    diffuse: bool = _doc("with color: multiply by the material's Kd", True)
    ambient: bool = _doc("with color: add the material's Ka", False)
    inside: str = _doc("inside test: auto, parity, vote or winding", "auto")
    density: str | None = _doc("also the inside fraction of each voxel: None or 'coverage'", None)
    supersample: int = _doc("with density: rays per voxel column across the ray, per axis", 4)
    density_dtype: str = _doc("with density: 'uint8' (255 x fraction) or 'float32'", "uint8")
    sdf: object = _doc("also the distance to the surface (float32): False, True or 'signed' "
                       "(negative inside), or 'unsigned' (open sheets and scans)", False)
    band: float = _doc("with sdf: half-width of the exact band, in voxels (a positive number "
                       "or math.inf: every voxel exact)", 3.0)
    jobs: int | None = _doc("threads for the array work (None or 0: one per core); the result "
                            "does not depend on it", None, record=False)
    kernel: str = _doc("exact colour's nearest-surface search: auto, compiled or numpy "
                       f"(default ${KERNEL_ENV}, else auto)", factory=kernel_default,
                       new=True)
    references: str = _doc("files a model names (materials, textures, buffers): read from "
                           "'anywhere', or only under the model's own 'folder'", "anywhere",
                           new=True)
    labels: str | None = _doc("also label each voxel: None, 'part', 'component', 'material' or "
                              "'file' (see geovox.labels)", None, new=True)
    overlap: str = _doc("with labels: which part a voxel inside several takes: 'last', 'first' "
                        "or 'smallest'", "last", new=True)
    fractions: bool = _doc("with labels: each label's coverage fraction per voxel", False,
                           new=True)
    like: object = _doc("voxelise onto this reference grid (an image path, a Reference, or "
                        "(affine, shape)) instead of one over the mesh", None, new=True)
    mesh_space: str | None = _doc("with like: the mesh's frame, 'lps' or 'ras' (default: its "
                                  "file's SPACE= mark, else LPS)", None, new=True)
    # issue 36 (readers): the size limit of geovox.io.limits
    max_input_size: int | None = _doc("the most bytes an input may hold once read or inflated "
                                      "(default: 100 x its size, at most half the memory)", None,
                                      record=False)

    def __post_init__(self):
        _validate(self)
        # Plain tuples, so that options compare, hash and pickle as values.
        if self.bounds is not None:
            import numpy as np

            object.__setattr__(self, "bounds", tuple(
                float(x) for x in np.asarray(self.bounds, dtype=np.float64).reshape(-1)))
        if self.shape is not None:
            object.__setattr__(self, "shape", tuple(self.shape))

    # --- building ---------------------------------------------------------

    @classmethod
    def names(cls) -> tuple:
        """Every option's name, in field order."""
        return tuple(f.name for f in fields(cls))

    @classmethod
    def from_kwargs(cls, **kw) -> "Options":
        """Options from keywords; an unknown one is refused with the closest valid name.

        ``backend`` may also come as ``engine`` (DeprecationWarning).
        """
        if "engine" in kw:
            import warnings

            warnings.warn("`engine=` is now `backend=`", DeprecationWarning, stacklevel=3)
            engine = kw.pop("engine")
            kw.setdefault("backend", engine)
        unknown = [k for k in kw if k not in cls.names()]
        if unknown:
            raise ParameterError(unknown_option_message(unknown[0], cls.names()))
        return cls(**kw)._given_as(kw)

    @classmethod
    def from_args(cls, args) -> "Options":
        """Options from the command line's parsed arguments (an ``argparse.Namespace``).

        Only the options the subcommand defines are read (``geovox info`` has
        the grid's alone); ``--density-float`` is ``density_dtype='float32'``.
        """
        given = {n: getattr(args, n) for n in cls.names() if hasattr(args, n)}
        if hasattr(args, "density_float"):
            given["density_dtype"] = "float32" if args.density_float else "uint8"
        return cls(**given)._given_as(given)

    def replace(self, **changes) -> "Options":
        """A copy with ``changes`` (validated like any other)."""
        new = replace(self, **changes)
        given = getattr(self, "_given", None)
        return new if given is None else new._given_as(given | set(changes))

    def _given_as(self, names) -> "Options":
        # Which options the caller named: what a manifest records (see to_record).
        object.__setattr__(self, "_given", frozenset(names))
        return self

    # --- reading ----------------------------------------------------------

    def to_kwargs(self) -> dict:
        """Every option as a keyword (``Options(**o.to_kwargs()) == o``)."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def given_kwargs(self) -> dict:
        """The options the caller named (all of them for Options built directly), as keywords."""
        given = getattr(self, "_given", None)
        return {k: v for k, v in self.to_kwargs().items() if given is None or k in given}

    def grid_options(self, fmt_name=None) -> dict:
        """The keywords of :func:`geovox.grid.make_grid` for output format ``fmt_name``.

        ``fit`` resolved by :func:`geovox.grid.fit_for` (``.binvox``: the cube).
        """
        from .grid import fit_for

        return {"bounds": self.bounds, "resolution": self.resolution, "shape": self.shape,
                "voxel_size": self.voxel_size,
                "fit": fit_for(self.fit, fmt_name, shape=self.shape, voxel_size=self.voxel_size)}

    def to_record(self, full: bool = False) -> dict:
        """The JSON-ready form a batch manifest stores (tuples as lists, keys sorted).

        The options the caller named (all of the command line's; those given
        to :meth:`from_kwargs`), as manifests have always recorded them;
        ``jobs`` never (the files do not depend on it). With ``full``, or
        for Options built directly, every option that decides the files:
        all but ``jobs``, with ``axis`` and ``kernel`` only where they are
        not their defaults -- the canonical form two records are compared
        in (:func:`geovox.batch._same_options`).
        """
        given = None if full else getattr(self, "_given", None)
        defaults = {n: d for n, (d, _) in self.docs().items()}
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if not f.metadata["record"] or (given is not None and f.name not in given):
                continue
            if ((f.metadata["new"] or (given is None and f.name == "axis"))
                    and value == defaults[f.name]):
                continue
            if f.name == "backend" and not isinstance(value, str):
                value = value.name
            out[f.name] = _json(value)
        return dict(sorted(out.items()))

    @classmethod
    def docs(cls) -> dict:
        """``name -> (default, one line of doc)`` for every option."""
        out = {}
        for f in fields(cls):
            default = f.default if f.default_factory is MISSING else f.default_factory()
            out[f.name] = (default, f.metadata["doc"])
        return out


def unknown_option_message(name: str, known) -> str:
    """``"unknown option `colour=`; did you mean `color`?"`` (difflib's closest), or the list."""
    import difflib  # only for a misspelt name

    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.5)
    hint = f"did you mean `{close[0]}`?" if close else f"known: {', '.join(known)}"
    return f"unknown option `{name}=`; {hint}"


def _json(value):
    if isinstance(value, (list, tuple)):
        return [_json(v) for v in value]
    if hasattr(value, "tolist"):
        return value.tolist()
    return value


def _validate(o: Options) -> None:
    """Today's checks and messages, once (values are kept as given: the plan reads them)."""
    from .grid import check_bounds, check_positive_int

    given = [n for n in ("resolution", "shape", "voxel_size") if getattr(o, n) is not None]
    if len(given) > 1:
        raise ParameterError(
            f"give only one of `resolution`, `shape`, `voxel_size`; got {', '.join(given)}")
    if o.resolution is not None:
        check_positive_int("resolution", o.resolution)
    if o.shape is not None:
        try:
            items = list(o.shape)
        except TypeError:
            raise ParameterError(f"`shape` must be three positive integers, got {o.shape!r}") \
                from None
        if len(items) != 3:
            raise ParameterError(f"`shape` must be three positive integers, got {o.shape!r}")
        for x in items:
            check_positive_int("shape", x)
    if o.voxel_size is not None:
        try:
            s = float(o.voxel_size)
        except (TypeError, ValueError):
            raise ParameterError(f"`voxel_size` must be a positive number, got {o.voxel_size!r}") \
                from None
        if not (math.isfinite(s) and s > 0):
            raise ParameterError(f"`voxel_size` must be a positive number, got {o.voxel_size!r}")
    if o.bounds is not None:
        check_bounds(o.bounds)
    if o.fit is not None:
        from .grid import FITS

        if o.fit not in FITS:
            raise ParameterError(f"`fit` must be one of {', '.join(map(repr, FITS))}, "
                                 f"got {o.fit!r}")
    if o.axis not in (0, 1, 2):
        raise ParameterError(f"`axis` must be 0, 1 or 2, got {o.axis!r}")
    if o.occupancy not in tuple(Occupancy):
        raise ParameterError(f"`occupancy` must be one of {', '.join(Occupancy)}, "
                             f"got {o.occupancy!r}")
    colour_of(o.color)
    if o.inside not in tuple(Inside):
        raise ParameterError(f"`inside` must be one of {', '.join(Inside)}; got {o.inside!r}")
    _validate_fields(o)


def _validate_fields(o: Options) -> None:
    """Density, distance, threads, kernel and backend name."""
    from .grid import check_positive_int

    if o.density not in (None, "coverage"):
        raise ParameterError(f"`density` must be None or 'coverage', got {o.density!r}")
    if o.density_dtype not in ("uint8", "float32"):
        raise ParameterError(f"`density_dtype` must be 'uint8' or 'float32', "
                             f"got {o.density_dtype!r}")
    if o.density is not None:
        check_positive_int("supersample", o.supersample)
    if sdf_of(o.sdf) is not None:
        try:
            band = float(o.band)
        except (TypeError, ValueError):
            band = math.nan
        if isinstance(o.band, (bool, str)) or not band > 0:  # nan is not > 0
            raise ParameterError(f"`band` must be a positive number of voxels or math.inf, "
                                 f"got {o.band!r}")
    if o.jobs is not None and (isinstance(o.jobs, bool) or not isinstance(o.jobs, int)
                               or o.jobs < 0):
        raise ParameterError(f"`jobs` must be a non-negative integer, got {o.jobs!r}")
    if o.references not in tuple(References):
        raise ParameterError(f"`references` must be 'anywhere' or 'folder', got {o.references!r}")
    if o.max_input_size is not None and (isinstance(o.max_input_size, bool) or not isinstance(
            o.max_input_size, int) or o.max_input_size <= 0):  # issue 36 (readers)
        raise ParameterError(f"`max_input_size` must be a positive number of bytes, "
                             f"got {o.max_input_size!r}")
    _validate_labels(o)
    if o.mesh_space is not None:
        if o.like is None:
            raise ParameterError("`mesh_space` (--mesh-space) applies only onto a reference grid "
                                 "(`like`, --like)")
        if str(o.mesh_space).upper() not in ("LPS", "RAS"):
            raise ParameterError(f"`mesh_space` must be 'lps' or 'ras', got {o.mesh_space!r}")
    if o.kernel not in KERNELS:
        raise ParameterError(f"the nearest-surface kernel must be auto, compiled or numpy, "
                             f"got {o.kernel!r}")
    if isinstance(o.backend, str) or not hasattr(o.backend, "cast"):
        from .backends import REGISTRY

        if not isinstance(o.backend, str) or o.backend.lower() not in ("auto", *REGISTRY):
            raise ParameterError(f"`backend` must be one of auto, {', '.join(REGISTRY)}; "
                                 f"got {o.backend!r}")


def _validate_labels(o: Options) -> None:
    """An unknown label source or overlap rule, or fractions without part labels."""
    sources = tuple(LabelSource)
    if o.labels is not None and o.labels not in sources:
        raise ParameterError(f"`labels` must be one of {', '.join(sources)} or None, "
                             f"got {o.labels!r}")
    if o.overlap not in tuple(Overlap):
        raise ParameterError(f"`overlap` must be one of {', '.join(Overlap)}, got {o.overlap!r}")
    if o.fractions and o.labels is None:
        raise ParameterError("`fractions` needs `labels` (a label source: "
                             + ", ".join(sources) + ")")
    if o.fractions and o.labels == LabelSource.MATERIAL:
        raise ParameterError("`fractions` are per part (labels='part', 'component', 'file' or "
                             "'feature'); a material's share of a voxel is not defined by its "
                             "nearest point")


def colour_of(color):
    """The :class:`Colour` that ``color`` asks for, or None (True is ``EXACT``).

    Raises
    ------
    ParameterError
        Anything but None, a bool, an int, ``"exact"`` or ``"fast"``.
    """
    import numbers

    import numpy as np

    if color is None or isinstance(color, (bool, np.bool_, numbers.Integral)) \
            and not isinstance(color, str):
        return Colour.EXACT if color else None
    if color in ("exact", "fast"):
        return Colour(color)
    raise ParameterError(f"`color` must be True, False, 'exact' or 'fast', got {color!r}")


def sdf_of(sdf):
    """The distance ``sdf`` asks for: None, ``"signed"`` (True) or ``"unsigned"``.

    Raises
    ------
    ParameterError
        Anything but None, a bool, ``"signed"`` or ``"unsigned"``.
    """
    import numbers

    import numpy as np

    if sdf is None or isinstance(sdf, (bool, np.bool_, numbers.Integral)) \
            and not isinstance(sdf, str):
        return "signed" if sdf else None
    if sdf in ("signed", "unsigned"):
        return sdf
    raise ParameterError(f"`sdf` must be True, False, 'signed' or 'unsigned', got {sdf!r}")


__all__ = ["Options", "Inside", "Colour", "LabelSource", "Occupancy", "Overlap", "References",
           "colour_of", "sdf_of",
           "unknown_option_message", "KERNEL_ENV"]
