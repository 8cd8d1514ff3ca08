"""Colour: every inside voxel takes the colour of its nearest surface point.

| module | holds |
|---|---|
| :mod:`geovox.colour.shading` | shading, the six-crossing method, ``colour_volume``, ``exact_colours`` |
| :mod:`geovox.colour.nearest` | the exact nearest-surface search (NumPy, and the compiled kernel's driver) |

Every name of :mod:`geovox.colour.shading` is also this package's
(``geovox.colour.colour_volume``, ``from geovox.colour import shade``), as
when this package was the module ``geovox/colour.py``; set (or patch) such a
name on ``geovox.colour.shading``, where the code reads it (see
:mod:`geovox._forward`).
"""

import sys

from .. import _forward
from . import shading

_forward.forward(sys.modules[__name__], shading)
