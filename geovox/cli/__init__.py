"""The command line (``geovox``, ``python -m geovox``): :mod:`geovox.cli.commands`.

Every name of :mod:`geovox.cli.commands` is also this package's
(``from geovox.cli import main``; the console script is
``geovox.cli:main_exit``), as when this package was the module
``geovox/cli.py``; set (or patch) such a name on ``geovox.cli.commands``,
where the code reads it (see :mod:`geovox._forward`).
"""

import sys

from .. import _forward
from . import commands

_forward.forward(sys.modules[__name__], commands)
