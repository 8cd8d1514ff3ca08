"""Build the optional compiled kernels; everything else is in pyproject.toml.

geovox/_nearest.pyx (the exact nearest surface, colour) and
geovox/_winding.pyx (the caps' winding number of open models). The
extensions are ``optional``: without a C compiler (or without OpenMP, or
without Cython) the install still succeeds and geovox uses its NumPy code
(:mod:`geovox.nearest`, :func:`geovox.inside.cap_winding`), which gives the
same answers (the winding number's wherever a bound or the exact sum decides).
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

ext = []
# A tree without a .pyx (an old source distribution) installs without that kernel.
names = [n for n in ("_nearest", "_winding") if os.path.exists(f"geovox/{n}.pyx")]
if cythonize is not None and names:
    ext = cythonize(
        [Extension(f"geovox.{n}", [f"geovox/{n}.pyx"], extra_compile_args=flags,
                   extra_link_args=link) for n in names],
        compiler_directives={"language_level": 3}, quiet=True)
    for e in ext:
        # cythonize does not carry `optional` over: set it on what it returns.
        # A failed compile is then a warning and geovox uses its NumPy search.
        e.optional = True

setup(ext_modules=ext)
