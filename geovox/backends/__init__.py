"""Backend registry.

``name -> (module that must be importable, install hint, loader)``, checked
with :func:`importlib.util.find_spec` so listing backends imports nothing.
``"auto"`` walks :data:`PREFERENCE`; a backend asked for by name that cannot
run is an error that says what to install, never a silent fallback.

Why ``auto`` is NumPy: every ray geovox casts is an axis-parallel column
ray on a regular lattice, which the NumPy backend scan-converts directly
(cost ~ triangles + candidate pairs, no set-up), while the Embree backend
first imports trimesh and embreex (0.3-0.8 s in a fresh process), builds a
scene and checks for coplanar overlapping triangles, and even warm is no
faster than NumPy on these rays. Measured over every corpus model at
64³-1024³, first call in a fresh process (``benchmarks/bench_cli.py --only
auto-rule``; the decision in ``benchmarks/results/history.md``), Embree took 1.5-35× as
long as NumPy, so ``auto`` picks NumPy whenever it imports; ``embree``
stays available by name and gives identical volumes.
"""

from __future__ import annotations

import importlib
import importlib.util

from ..errors import BackendUnavailableError, ParameterError
from .base import Backend, Hits

#: name -> (required module, pip package, "module:Class")
REGISTRY = {
    "embree": ("embreex", "embreex", "geovox.backends.embree:EmbreeBackend"),
    "numpy": ("numpy", "numpy", "geovox.backends.numpy:NumpyBackend"),
    # Not in PREFERENCE: `auto` never picks it (see README, "WebGPU backend").
    "webgpu": ("wgpu", "wgpu", "geovox.backends.webgpu:WebgpuBackend"),
}
#: Order tried by ``backend="auto"`` (see the module docstring for the measurement).
PREFERENCE = ("numpy", "embree")

_instances: dict = {}


def _present(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except (ImportError, ValueError):
        return False


def available_backends() -> list:
    """Names of the backends whose packages are installed, in preference order.

    Nothing is imported: each backend's package is looked up with
    :func:`importlib.util.find_spec`. ``geovox backends`` also says whether
    each can run here (the WebGPU backend needs an adapter as well).

    Returns
    -------
    list of str
        E.g. ``["numpy", "embree", "webgpu"]``: first those ``"auto"`` tries,
        in its order, then the others.
    """
    return [name for name in PREFERENCE if _present(REGISTRY[name][0])]


def backend_report() -> dict:
    """Whether each backend can run here, and the line ``geovox backends`` prints for it.

    A backend can run when its package imports and, for ``webgpu``, a GPU
    adapter (or lavapipe, Mesa's software Vulkan) is found. Checking imports
    the packages (trimesh and embreex for ``embree``, wgpu for ``webgpu``)
    and opens the adapter: a few seconds on lavapipe, once per process.

    Returns
    -------
    dict
        ``name -> (can_run: bool, line: str)``, in :data:`PREFERENCE` order,
        then ``webgpu``.
    """
    report = {}
    for name in (*PREFERENCE, *(n for n in REGISTRY if n not in PREFERENCE)):
        module, package, _ = REGISTRY[name]
        if name == "webgpu":
            from .webgpu import describe

            line = describe()  # the adapter, or what is missing
            report[name] = (line.startswith("available"), line)
            continue
        try:
            ok = _present(module) and _load(name) is not None
        except ImportError:
            ok = False
        report[name] = (ok, "available" if ok else f"missing (pip install {package})")
    return report


def usable_backends() -> list:
    """Names of every backend that can run here: ``geovox backends``' answer.

    Unlike :func:`available_backends` (the order in which ``backend="auto"``
    tries the installed ones), this includes ``webgpu`` wherever an adapter
    exists, and checks that each backend imports rather than that its
    package is installed.

    Returns
    -------
    list of str
        E.g. ``["numpy", "embree", "webgpu"]``: :data:`PREFERENCE` order, then
        ``webgpu``.
    """
    return [name for name, (ok, _) in backend_report().items() if ok]


def _load(name: str) -> Backend:
    if name not in _instances:
        module, cls = REGISTRY[name][2].split(":")
        _instances[name] = getattr(importlib.import_module(module), cls)()
    return _instances[name]


def get_backend(name: str = "auto") -> Backend:
    """Return a ready backend instance.

    Parameters
    ----------
    name : {"auto", "numpy", "embree", "webgpu"}
        A name of :data:`REGISTRY`, or ``"auto"`` for the first of
        :data:`PREFERENCE` that imports.

    Returns
    -------
    Backend
        One shared instance per name.

    Raises
    ------
    ParameterError
        Unknown name.
    BackendUnavailableError
        The named backend's package is missing or fails to import.
    """
    if not isinstance(name, str):
        raise ParameterError(f"`backend` must be one of auto, {', '.join(REGISTRY)}; got {name!r}")
    name = name.lower()
    if name == "auto":
        for candidate in PREFERENCE:
            if _present(REGISTRY[candidate][0]):
                try:
                    return _load(candidate)
                except ImportError:
                    continue
        raise BackendUnavailableError("no ray-casting backend can run: install numpy")
    if name not in REGISTRY:
        raise ParameterError(f"`backend` must be one of auto, {', '.join(REGISTRY)}; got {name!r}")
    module, package, _ = REGISTRY[name]
    try:
        if not _present(module):
            raise ImportError(f"No module named {module!r}")
        return _load(name)
    except ImportError as exc:
        raise BackendUnavailableError(
            f"backend {name!r} needs the {package!r} package, which is not installed "
            f"or does not import here ({exc}); install it with `pip install {package}` "
            f"or use --backend numpy"
        ) from exc


__all__ = ["Backend", "Hits", "available_backends", "usable_backends", "backend_report",
           "get_backend", "REGISTRY", "PREFERENCE"]
