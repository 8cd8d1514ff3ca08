"""Which compiled kernels a conversion uses: :attr:`Options.kernel <geovox.Options.kernel>`.

geovox's compiled code is optional (setup.py builds it where a C compiler
exists) and every kernel has a NumPy twin that gives the same answers bit for
bit: ``geovox._nearest`` (the exact nearest-surface search of colour,
:func:`geovox.nearest.search.kernel_module`), ``geovox._lattice`` (the column rays'
lattice search and the inside test's mesh checks, :func:`lattice`) and
``geovox._winding`` (the caps' winding number of open models,
:func:`geovox.inside.winding_kernel`) and ``geovox._objtext`` (the OBJ
reader's numbers and corners, :func:`obj_text`) and ``geovox._blocks`` (the
.vdb writer's per-block extrema), each chosen by :func:`compiled`.
``numpy`` runs the NumPy code everywhere; ``compiled`` insists on the
compiled kernels; ``auto`` (the default) uses them where they import.

The choice is an option (``voxelize(..., kernel="numpy")``, whose default is
``$GEOVOX_KERNEL``, read by :class:`geovox.Options`); the plan and the block
function run under it (:func:`chosen`, :func:`follows_plan`), so the stages
deep below them -- the lattice search inside a backend's ``cast``, the mesh
checks of the inside test -- ask :func:`compiled` and take no parameter.
"""

from __future__ import annotations

import contextlib
import contextvars
import functools
import os

#: Environment variable that is the default of :attr:`Options.kernel <geovox.Options.kernel>`.
KERNEL_ENV = "GEOVOX_KERNEL"
#: The kernel choices.
CHOICES = ("auto", "compiled", "numpy")


def kernel_default() -> str:
    """The kernel choice when none is given: ``$GEOVOX_KERNEL``, else ``auto``."""
    return os.environ.get(KERNEL_ENV) or "auto"

#: The kernel choice of the conversion running in this context (None: none
#: runs; Options' default then decides).
_CHOICE = contextvars.ContextVar("geovox_kernel", default=None)


@contextlib.contextmanager
def chosen(kernel):
    """Run the enclosed code with the kernel choice ``kernel`` (``auto``, ``compiled``, ``numpy``).

    A context variable: each thread (a Dask worker's, a caller's) has its own;
    a thread pool's workers start with none (see :func:`follows_plan`).
    """
    token = _CHOICE.set(kernel)
    try:
        yield
    finally:
        _CHOICE.reset(token)


def follows_plan(fn):
    """Decorate ``fn(mesh, plan, ...)`` to run under ``plan.options.kernel`` (see :func:`chosen`)."""

    @functools.wraps(fn)
    def under_plan(mesh, plan, *args, **kw):
        with chosen(plan.options.kernel):
            return fn(mesh, plan, *args, **kw)

    return under_plan


def compiled(name: str, what: str, kernel=None):
    """The compiled module ``geovox.<name>``, or None for its NumPy twin.

    The one rule of every kernel choice: ``numpy`` gives None; ``compiled``
    gives the module or refuses where it was not built; ``auto`` gives it
    where it imports.

    Parameters
    ----------
    name : str
        The extension's module name, e.g. ``"_lattice"``.
    what : str
        How messages name the kernel, e.g. ``"lattice search"``.
    kernel : {None, "auto", "compiled", "numpy"}
        None: the choice of the conversion running (:func:`chosen`), or
        outside one, :class:`~geovox.Options`' default (``$GEOVOX_KERNEL``,
        else ``auto``).

    Raises
    ------
    ParameterError
        An unknown choice, or ``compiled`` where the module was not built.
    """
    from .errors import ParameterError

    choice = kernel if kernel is not None else _CHOICE.get()
    where = ""
    if choice is None:
        choice, where = kernel_default(), f" (${KERNEL_ENV})"
    if choice not in CHOICES:
        raise ParameterError(f"the {what} kernel{where} must be auto, compiled or numpy, "
                             f"got {choice!r}")
    if choice == "numpy":
        return None
    try:
        return _load(name)
    except ImportError:
        if choice == "compiled":
            raise ParameterError(f"the compiled {what} kernel is not built "
                                 "(pip install . with a C compiler builds it)") from None
        return None


def _load(name: str):
    """Import ``geovox.<name>`` (the one place a compiled kernel is loaded)."""
    import importlib

    return importlib.import_module(f"geovox.{name}")


def lattice():
    """The compiled lattice search and mesh checks (``geovox._lattice``), or None for NumPy.

    As the running conversion's kernel choice says (see :func:`compiled`).

    Raises
    ------
    ParameterError
        An unknown choice, or ``compiled`` where the module was not built.
    """
    return compiled("_lattice", "lattice-search")


def obj_text():
    """The compiled OBJ number and corner reading (``geovox._objtext``), or None for NumPy.

    Loading comes before the plan, so outside a conversion this follows the
    default (``$GEOVOX_KERNEL``, else ``auto``), as :func:`compiled` says.

    Raises
    ------
    ParameterError
        An unknown choice, or ``compiled`` where the module was not built.
    """
    return compiled("_objtext", "OBJ reading")


#: Whether this process has started OpenMP threads in a compiled kernel, and
#: whether it is a fork of one that had (see :func:`_after_fork`).
_threads_started = False
_forked_after_threads = False


def _after_fork():
    # GNU OpenMP is not fork-safe: a child forked after the parent's threads
    # started hangs forever at its first parallel region (a batch's process
    # pool, or any multiprocessing "fork" pool, after a colour run in the
    # same process). Such a child runs the kernels on one thread, which never
    # enters the inherited thread pool.
    global _forked_after_threads
    _forked_after_threads = _forked_after_threads or _threads_started


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork)


def openmp_threads(jobs: int) -> int:
    """The threads a compiled kernel's OpenMP region may use for ``jobs`` asked for.

    Every compiled kernel that runs OpenMP threads asks here first: 1 in a
    process forked after this one's threads started (GNU OpenMP would hang
    there), else ``jobs``, noting that threads have started.
    """
    global _threads_started
    if _forked_after_threads:
        return 1
    if jobs > 1:
        _threads_started = True
    return jobs


def forked_after_threads() -> bool:
    """Whether this process is a fork of one whose OpenMP threads had started."""
    return _forked_after_threads
