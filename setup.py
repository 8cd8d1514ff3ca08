"""Build the optional compiled kernel (geovox/_nearest.pyx); everything else is in pyproject.toml.

The extension is ``optional``: without a C compiler (or without OpenMP, or
without Cython) the install still succeeds and geovox uses its NumPy search
(:mod:`geovox.nearest`), which gives the same answers.
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
# A tree without the .pyx (an old source distribution) installs without the kernel.
if cythonize is not None and os.path.exists("geovox/_nearest.pyx"):
    ext = cythonize(
        [Extension("geovox._nearest", ["geovox/_nearest.pyx"], extra_compile_args=flags,
                   extra_link_args=link)],
        compiler_directives={"language_level": 3}, quiet=True)
    for e in ext:
        # cythonize does not carry `optional` over: set it on what it returns.
        # A failed compile is then a warning and geovox uses its NumPy search.
        e.optional = True

setup(ext_modules=ext)
