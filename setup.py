"""Build the optional compiled kernels; everything else is in pyproject.toml.

``geovox/_nearest.pyx`` is the exact nearest-surface search (colour),
``geovox/_lattice.pyx`` the column rays' lattice search and the linear mesh
checks of the inside test, ``geovox/_winding.pyx`` the caps' winding number of
open models, ``geovox/_objtext.pyx`` the OBJ reader's numbers and corners,
``geovox/_blocks.pyx`` the .vdb writer's per-block extrema. The extensions are ``optional``: without a C compiler (or without
OpenMP, or without Cython) the install still succeeds and geovox uses its NumPy
code (:mod:`geovox.nearest`, :func:`geovox.backends.numpy.rasterise`,
:mod:`geovox.inside`, :func:`geovox.inside.cap_winding`, :mod:`geovox.obj`), which gives the same
answers (the winding number's wherever a bound or the exact sum decides).
"""

import os
import sys

from setuptools import Extension, setup

try:
    from Cython.Build import cythonize
except ImportError:  # pip installs Cython first (pyproject's [build-system]); a bare setup.py may not
    cythonize = None

if sys.platform == "win32":
    flags, link = ["/O2", "/openmp", "/fp:precise"], []
else:
    # -ffp-contract=off: no fused multiply-adds, so every distance rounds as
    # NumPy's separate operations do (the exact search's tie rule and the
    # colours must match the NumPy reference bit for bit); no -ffast-math.
    # -fno-math-errno changes no value (sqrt is correctly rounded either way),
    # it only spares each sqrt a branch for errno (6 % of the kernel's time).
    flags = ["-O3", "-fopenmp", "-ffp-contract=off", "-fno-fast-math", "-fno-math-errno"]
    link = ["-fopenmp"]

# The lattice search runs on one thread: no OpenMP (nothing to make fork-safe).
serial = [f for f in flags if "openmp" not in f]
sources = [("geovox._nearest", "geovox/_nearest.pyx", flags, link),
           ("geovox._lattice", "geovox/_lattice.pyx", serial, []),
           ("geovox._winding", "geovox/_winding.pyx", flags, link),
           ("geovox._objtext", "geovox/_objtext.pyx", serial, []),
           ("geovox._surface", "geovox/_surface.pyx", flags, link),
           ("geovox._blocks", "geovox/_blocks.pyx", flags, link)]
ext = []
# A tree without a .pyx (an old source distribution) installs without that kernel.
if cythonize is not None:
    ext = cythonize(
        [Extension(name, [src], extra_compile_args=cflags, extra_link_args=lflags)
         for name, src, cflags, lflags in sources if os.path.exists(src)],
        compiler_directives={"language_level": 3}, quiet=True)
    for e in ext:
        # cythonize does not carry `optional` over: set it on what it returns.
        # A failed compile is then a warning and geovox uses its NumPy search.
        e.optional = True

setup(ext_modules=ext)
