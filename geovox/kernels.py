"""Which compiled kernels this process uses: the one switch, ``GEOVOX_KERNEL``.

geovox's compiled code is optional (setup.py builds it where a C compiler
exists) and every kernel has a NumPy twin that gives the same answers bit for
bit: ``geovox._nearest`` (the exact nearest-surface search of colour, chosen
by :func:`geovox.nearest.kernel_module`), ``geovox._lattice`` (the column
rays' lattice search and the inside test's mesh checks, :func:`lattice`) and
``geovox._winding`` (the caps' winding number of open models, chosen by
:func:`geovox.inside.winding_kernel`) and ``geovox._objtext`` (the OBJ
reader's numbers and corners, :func:`obj_text`), each chosen by :func:`compiled`.
``GEOVOX_KERNEL=numpy`` runs the NumPy code everywhere; ``compiled``
insists on the compiled kernels; ``auto`` (the default) uses them where
they import.
"""

from __future__ import annotations

import os

#: Environment variable choosing compiled kernels or their NumPy twins.
KERNEL_ENV = "GEOVOX_KERNEL"


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
        None reads :data:`KERNEL_ENV` (default ``auto``).

    Raises
    ------
    ParameterError
        An unknown choice, or ``compiled`` where the module was not built.
    """
    import importlib

    from .errors import ParameterError

    choice = kernel if kernel is not None else (os.environ.get(KERNEL_ENV) or "auto")
    if choice not in ("auto", "compiled", "numpy"):
        where = f" (${KERNEL_ENV})" if kernel is None else ""
        raise ParameterError(f"the {what} kernel{where} must be auto, compiled or numpy, "
                             f"got {choice!r}")
    if choice == "numpy":
        return None
    try:
        return importlib.import_module(f"geovox.{name}")
    except ImportError:
        if choice == "compiled":
            raise ParameterError(f"the compiled {what} kernel is not built "
                                 "(pip install . with a C compiler builds it)") from None
        return None


def lattice(kernel=None):
    """The compiled lattice search and mesh checks (``geovox._lattice``), or None for NumPy.

    Parameters
    ----------
    kernel : {None, "auto", "compiled", "numpy"}
        None reads :data:`KERNEL_ENV` (default ``auto``).

    Raises
    ------
    ParameterError
        An unknown choice, or ``compiled`` where the module was not built.
    """
    return compiled("_lattice", "lattice-search", kernel)


def obj_text(kernel=None):
    """The compiled OBJ number and corner reading (``geovox._objtext``), or None for NumPy.

    Parameters
    ----------
    kernel : {None, "auto", "compiled", "numpy"}
        None reads :data:`KERNEL_ENV` (default ``auto``).

    Raises
    ------
    ParameterError
        An unknown choice, or ``compiled`` where the module was not built.
    """
    return compiled("_objtext", "OBJ reading", kernel)
