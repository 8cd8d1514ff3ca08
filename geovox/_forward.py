"""A package that shows the names of one of its modules as its own, live.

``geovox.inside``, ``geovox.colour`` and ``geovox.cli`` were modules before
they were packages (issue 21); ``geovox.inside.choose`` and the like keep
working because each package forwards a name it lacks to the module that
defines it (``geovox.inside.winding``, ``geovox.colour.shading``,
``geovox.cli.commands``). The forwarding is live, not a copy made at import:
a patch of ``geovox.inside.winding.choose`` is what ``geovox.inside.choose``
gives, to the code that reads it there (``pipeline``) and to the module's own
functions alike. Setting such a name on the package is refused with an
AttributeError that says where to set it, since the module's code would
never see a copy on the package (a test's patch that silently misses).
"""

from types import ModuleType


class ForwardingPackage(ModuleType):
    """A package module whose missing attributes are its ``_source`` module's."""

    def __getattr__(self, name):
        source = self.__dict__.get("_source")
        if source is not None and not name.startswith("__"):
            try:
                return getattr(source, name)
            except AttributeError:
                pass
        raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")

    def __setattr__(self, name, value):
        if self._owned(name):
            if value is getattr(self._source, name):
                return  # the value it already shows (a patch's undo): nothing to copy
            raise AttributeError(self._refusal(name))
        super().__setattr__(name, value)

    def __delattr__(self, name):
        if self._owned(name):
            raise AttributeError(self._refusal(name))
        super().__delattr__(name)

    def __dir__(self):
        return sorted(set(super().__dir__()) | {n for n in dir(self._source) if not n.startswith("__")})

    def _owned(self, name) -> bool:
        """Whether ``name`` is forwarded: the source module's and not the package's own."""
        source = self.__dict__.get("_source")
        return (source is not None and not name.startswith("__") and name not in self.__dict__
                and name in vars(source))

    def _refusal(self, name) -> str:
        return (f"{self.__name__}.{name} is {self._source.__name__}.{name}: set it there, "
                f"where the code reads it")


def forward(package: ModuleType, source: ModuleType) -> None:
    """Make ``package`` (a ``sys.modules`` entry) forward missing names to ``source``."""
    package.__class__ = ForwardingPackage
    package._source = source
