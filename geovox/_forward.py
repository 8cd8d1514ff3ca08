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

``geovox.mesh`` does the same for the loader's names (``geovox.mesh.load_mesh``,
from when geovox/mesh.py was the loader; the module is now the data model and
the loader :mod:`geovox.io.load`), with one difference: its source is named,
not imported, until a name the module lacks is asked for, since the loader
imports the data model (a cycle) and the modules that need only ``Mesh``
should not pay for the loader.
"""

from types import ModuleType


class ForwardingPackage(ModuleType):
    """A package (or module) whose missing attributes are its ``_source`` module's."""

    def __getattr__(self, name):
        source = None if name.startswith("__") else self._origin()
        if source is not None:
            try:
                return getattr(source, name)
            except AttributeError:
                pass
        raise AttributeError(f"module {self.__name__!r} has no attribute {name!r}")

    def __setattr__(self, name, value):
        if self._owned(name):
            if value is getattr(self._origin(), name):
                return  # the value it already shows (a patch's undo): nothing to copy
            raise AttributeError(self._refusal(name))
        super().__setattr__(name, value)

    def __delattr__(self, name):
        if self._owned(name):
            raise AttributeError(self._refusal(name))
        super().__delattr__(name)

    def __dir__(self):
        return sorted(set(super().__dir__()) | {n for n in dir(self._origin()) if not n.startswith("__")})

    def _origin(self):
        """The source module: ``_source``, or the module named ``_source_name``, imported now."""
        d = self.__dict__
        if d.get("_source") is None and "_source_name" in d:
            import importlib

            # While the source is being imported (it imports this module), this is the
            # partly run module: a name it has not yet defined is missing, not a loop.
            return importlib.import_module(d["_source_name"])
        return d.get("_source")

    def _owned(self, name) -> bool:
        """Whether ``name`` is forwarded: the source module's and not the package's own."""
        if name.startswith("__") or name in self.__dict__:
            return False
        source = self._origin()
        return source is not None and name in vars(source)

    def _refusal(self, name) -> str:
        return (f"{self.__name__}.{name} is {self._origin().__name__}.{name}: set it there, "
                f"where the code reads it")


def forward(package: ModuleType, source) -> None:
    """Make ``package`` (a ``sys.modules`` entry) forward missing names to ``source``.

    ``source`` is a module, or a module's name: then it is imported the first time a
    name ``package`` lacks is asked for (or set, or listed), not before.
    """
    key = "_source_name" if isinstance(source, str) else "_source"
    package.__dict__[key] = source  # before the class: its __setattr__ would look the name up
    package.__class__ = ForwardingPackage
