"""The package's shape, as CONTRIBUTING's architecture page draws it (issue 34's "Done means").

- Layers whose imports all point down: the contract in ``pyproject.toml``
  (``[tool.importlinter]``), checked with import-linter, whose graph (grimp)
  counts the imports made inside functions too.
- No import circle among geovox's modules, counting those imports.
- One way to import each name: no import machinery (``sys.meta_path``,
  ``sys.modules`` writes, ``__class__`` swaps) in ``geovox/``.
- A private name (``_x``) is private to its module: none is imported from
  another geovox module, nor read off one.
- No module over 1,000 lines, and every package says what it exports (``__all__``).
- ``requires-python`` is what the code needs: vermin finds no more.
"""

from __future__ import annotations

import ast
import os
import re
import subprocess
import sys

import pytest

ROOT = os.path.normpath(os.path.join(os.path.dirname(__file__), ".."))
PACKAGE = os.path.join(ROOT, "geovox")

#: The most lines a module may have.
MOST_LINES = 1000


def _modules():
    """``(dotted name, path)`` of every module in geovox/."""
    for d, dirs, files in os.walk(PACKAGE):
        dirs[:] = sorted(x for x in dirs if not x.startswith((".", "__")))
        for f in sorted(files):
            if f.endswith(".py"):
                p = os.path.join(d, f)
                rel = os.path.relpath(p, ROOT)[:-3].replace(os.sep, ".")
                yield rel[:-len(".__init__")] if rel.endswith(".__init__") else rel, p


def _tree(path):
    with open(path, encoding="utf-8") as f:
        return ast.parse(f.read())


def _absolute(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute module an ``ImportFrom`` names."""
    if not node.level:
        return node.module or ""
    base = module.split(".")
    if not is_package:
        base = base[:-1]
    base = base[:len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def test_the_layers_hold():
    """import-linter's contract: every import points down the layers (lazy ones included)."""
    pytest.importorskip("importlinter")
    exe = os.path.join(os.path.dirname(sys.executable), "lint-imports")
    cmd = [exe] if os.path.exists(exe) else [sys.executable, "-m", "importlinter.cli"]
    p = subprocess.run(cmd + ["--no-cache"], cwd=ROOT, capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr


def test_no_import_circle_counting_imports_inside_functions():
    grimp = pytest.importorskip("grimp")
    graph = grimp.build_graph("geovox", cache_dir=None)
    edges = {m: set(graph.find_modules_directly_imported_by(m)) for m in graph.modules}
    # Tarjan's strongly connected components: a component of more than one module is a circle.
    index, low, stack, on, circles, counter = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10_000))
    for m in sorted(edges):
        if m not in index:
            visit(m)
    assert circles == []


def test_no_import_machinery():
    found = []
    for name, path in _modules():
        for node in ast.walk(_tree(path)):
            if isinstance(node, ast.Attribute) and node.attr == "meta_path":
                found.append((name, node.lineno, "sys.meta_path"))
            targets = node.targets if isinstance(node, ast.Assign) else \
                [node.target] if isinstance(node, (ast.AugAssign, ast.AnnAssign)) else []
            for t in targets:
                if isinstance(t, ast.Subscript) and isinstance(t.value, ast.Attribute) \
                        and t.value.attr == "modules":
                    found.append((name, node.lineno, "sys.modules[...] ="))
                if isinstance(t, ast.Attribute) and t.attr == "__class__":
                    found.append((name, node.lineno, "__class__ ="))
    assert found == []


def test_no_private_name_crosses_a_module():
    """``from geovox.x import _y`` and ``x._y`` on an imported geovox module, anywhere in geovox/."""
    modules = dict(_modules())
    found = []
    for name, path in modules.items():
        tree = _tree(path)
        is_package = path.endswith("__init__.py")
        aliases = {}  # local name -> geovox module it stands for
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                source = _absolute(name, is_package, node)
                if not source.startswith("geovox"):
                    continue
                for a in node.names:
                    full = f"{source}.{a.name}"
                    if full in modules:
                        aliases[a.asname or a.name] = full
                    elif a.name.startswith("_") and a.name != "__version__":
                        found.append(f"{name}:{node.lineno} from {source} import {a.name}")
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("geovox"):
                        aliases[a.asname or a.name] = a.name
        for node in ast.walk(tree):
            if (isinstance(node, ast.Attribute) and node.attr.startswith("_")
                    and not node.attr.startswith("__") and isinstance(node.value, ast.Name)
                    and node.value.id in aliases and aliases[node.value.id] != name):
                found.append(f"{name}:{node.lineno} {node.value.id}.{node.attr}")
    assert found == []


def test_no_module_is_over_1000_lines():
    long = {}
    for name, path in _modules():
        with open(path, encoding="utf-8") as f:
            n = sum(1 for _ in f)
        if n > MOST_LINES:
            long[name] = n
    assert long == {}


def test_every_package_says_what_it_exports():
    missing = [name for name, path in _modules() if path.endswith("__init__.py")
               and not any(isinstance(n, ast.Assign)
                           and any(getattr(t, "id", None) == "__all__" for t in n.targets)
                           for n in _tree(path).body)]
    assert missing == []


def _declared_minimum() -> tuple:
    with open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8") as f:
        text = f.read()
    m = re.search(r'^requires-python\s*=\s*">=\s*(\d+)\.(\d+)"', text, re.MULTILINE)
    assert m, "pyproject.toml has no requires-python >= X.Y"
    return int(m.group(1)), int(m.group(2))


def test_requires_python_is_what_the_code_needs():
    """vermin reads every module (and its features) and names the oldest Python it runs on."""
    pytest.importorskip("vermin")
    major, minor = _declared_minimum()
    exe = os.path.join(os.path.dirname(sys.executable), "vermin")
    cmd = [exe] if os.path.exists(exe) else [sys.executable, "-c",
                                             "import sys, vermin.main; sys.exit(vermin.main.main())"]
    p = subprocess.run(cmd + ["--no-tips", "--violations", f"--target={major}.{minor}-",
                              "--eval-annotations", "--backport", "typing", PACKAGE],
                       capture_output=True, text=True)
    assert p.returncode == 0, p.stdout + p.stderr


def test_requires_python_is_the_readme_s_and_the_classifiers():
    major, minor = _declared_minimum()
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as f:
        readme = f.read()
    assert f"Python ≥ {major}.{minor}" in readme
    with open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8") as f:
        text = f.read()
    assert f'"Programming Language :: Python :: {major}.{minor}"' in text
    older = [f"{major}.{m}" for m in range(minor)]
    assert not any(f"Python :: {v}\"" in text for v in older)


def test_every_format_geovox_formats_prints_is_on_the_formats_page(capsys):
    """``geovox formats`` in aligned columns, and every name it prints documented by name."""
    from geovox.cli import main

    assert main(["formats"]) == 0
    lines = capsys.readouterr().out.splitlines()
    with open(os.path.join(ROOT, "docs", "formats.md"), encoding="utf-8") as f:
        page = f.read()
    starts = {line.index(line.split()[1]) for line in lines}
    assert len(starts) == 1, lines  # the extensions start in one column
    for line in lines:
        assert f"`{line.split()[0]}`" in page, line


def test_the_layers_picture_is_the_contract_s():
    """docs/img/layers.svg is what docs/layers.py draws of pyproject.toml's contract."""
    sys.path.insert(0, os.path.join(ROOT, "docs"))
    try:
        import layers
    finally:
        sys.path.pop(0)
    assert layers.main(["--check"]) == 0, "run python docs/layers.py"
