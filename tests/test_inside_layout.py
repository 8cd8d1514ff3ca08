"""geovox.inside as layers: no import circle among its modules, no private name crossing one.

Counted as a reader counts them: every ``import`` and ``from ... import``
in a module, also those inside functions. inside/ reaches only the layers
below it (issue 34): errors, grid, mesh, parallel, kernels, options,
geometry, backends.base, parity and memory.
"""

from __future__ import annotations

import ast
import os

import pytest

INSIDE = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "geovox",
                      "inside")
#: What geovox.inside may import from the rest of geovox (the lower layers).
BELOW = {"errors", "grid", "mesh", "parallel", "kernels", "options", "geometry", "backends",
         "backends.base", "parity", "memory"}
#: The order of the layers inside the package: each imports only modules after it.
ORDER = ["winding", "choice", "caps", "bridge", "captree", "repair", "edges"]
LIMIT = 1000


def _modules():
    return sorted(n[:-3] for n in os.listdir(INSIDE) if n.endswith(".py") and n != "__init__.py")


def _imports(name):
    """``(module, names)`` of every import in ``geovox/inside/<name>.py``, relative ones resolved."""
    with open(os.path.join(INSIDE, name + ".py"), encoding="utf-8") as f:
        tree = ast.parse(f.read())
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level == 1:
                base = "geovox.inside" + (f".{node.module}" if node.module else "")
            elif node.level == 2:
                base = "geovox" + (f".{node.module}" if node.module else "")
            else:
                base = node.module or ""
            names = [a.name for a in node.names]
            if node.module is None:  # from . import x: modules
                out += [(f"{base}.{n}", []) for n in names]
            else:
                out.append((base, names))
        elif isinstance(node, ast.Import):
            out += [(a.name, []) for a in node.names]
    return out


def test_every_module_is_in_the_layer_order_and_under_the_limit():
    assert sorted(ORDER) == _modules()
    for name in _modules():
        with open(os.path.join(INSIDE, name + ".py"), encoding="utf-8") as f:
            assert len(f.read().splitlines()) <= LIMIT, name


@pytest.mark.parametrize("name", ORDER)
def test_imports_point_down_and_stay_in_the_lower_layers(name):
    below = ORDER[ORDER.index(name) + 1:]
    for module, names in _imports(name):
        if module.startswith("geovox.inside."):
            assert module.split(".")[2] in below, (name, module)
        elif module.startswith("geovox."):
            assert module[len("geovox."):] in BELOW, (name, module)
        assert not [n for n in names if n.startswith("_")], (name, module, names)
