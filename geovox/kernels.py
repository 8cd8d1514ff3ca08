"""Which compiled kernels this process uses: the one switch, ``GEOVOX_KERNEL``.

geovox's compiled code is optional (setup.py builds it where a C compiler
exists) and every kernel has a NumPy twin that gives the same answers bit for
bit: ``geovox._nearest`` (the exact nearest-surface search of colour, chosen
by :func:`geovox.nearest.kernel_module`) and ``geovox._lattice`` (the column
rays' lattice search and the inside test's mesh checks, :func:`lattice`).
``GEOVOX_KERNEL=numpy`` runs the NumPy code everywhere; ``compiled``
insists on the compiled kernels; ``auto`` (the default) uses them where
they import.
"""

from __future__ import annotations

import os

#: Environment variable choosing compiled kernels or their NumPy twins.
KERNEL_ENV = "GEOVOX_KERNEL"


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
    choice = kernel if kernel is not None else (os.environ.get(KERNEL_ENV) or "auto")
    if choice == "numpy":
        return None
    if choice not in ("auto", "compiled"):
        from .errors import ParameterError

        raise ParameterError(f"the compiled kernels must be auto, compiled or numpy "
                             f"({KERNEL_ENV}), got {choice!r}")
    try:
        from . import _lattice
    except ImportError:
        if choice == "compiled":
            from .errors import ParameterError

            raise ParameterError("the compiled lattice search is not built "
                                 "(pip install . with a C compiler builds it)") from None
        return None
    return _lattice
