"""The command line (``geovox``, ``python -m geovox``): :mod:`geovox.cli.commands`.

The console script is ``geovox.cli:main_exit``.
"""

from .commands import main, main_exit

__all__ = ["main", "main_exit"]
