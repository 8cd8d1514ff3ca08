"""Inside/outside tests: the automatic choice, parity, vote and winding, repair.

| module | holds |
|---|---|
| :mod:`geovox.inside.winding` | ``choose``, the winding number, the caps and their tree |
| :mod:`geovox.inside.repair` | the repaired copy a winding test of a broken mesh works on |

Every name of :mod:`geovox.inside.winding` is also this package's
(``geovox.inside.choose``, ``from geovox.inside import boundary_edges``), as
when this package was the module ``geovox/inside.py``; set (or patch) such a
name on ``geovox.inside.winding``, where the code reads it (see
:mod:`geovox._forward`).
"""

import sys

from .. import _forward
from . import winding

_forward.forward(sys.modules[__name__], winding)
