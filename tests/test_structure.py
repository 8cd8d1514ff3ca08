"""Rules of the code's shape, read from the source with ``ast`` (issue 21's "Done means").

- Options are not threaded by hand: apart from the public keyword signatures
  of ``voxelize``, ``convert_to`` and ``convert_many``, no :class:`Options`
  field is a parameter of more than two functions in ``geovox/``; the stages
  take the plan, the options or a small per-stage record
  (``colour.Shading``) instead.
- No function in ``geovox/`` is longer than 100 lines of code, docstring
  excluded (the Cython kernels, ``.pyx``, are not read).
"""

from __future__ import annotations

import ast
import collections
import dataclasses
import os

import pytest

from geovox.options import Options

ROOT = os.path.join(os.path.dirname(__file__), "..", "geovox")

#: The public signatures that spell every option out (checked against Options
#: in tests/test_options.py).
PUBLIC = {"voxelize", "convert_to", "convert_many"}

#: At most this many functions besides PUBLIC may take an option by its name.
MOST = 2

#: ``(option, function) -> why``: a function that may take a parameter named
#: as an option although it is not an option threaded by hand (a public
#: function of the API reference keeping its keyword, say). Keyed by the
#: function's qualified name, without its module (moving a module keeps the
#: list). None needed today: keep it so.
ALLOWED: dict = {}

#: Parameters that share an option's name but are another thing: the name is
#: the ordinary one for it (NumPy's ``axis``, an array's ``shape``, a thread
#: count handed to a primitive), so they are not counted.
HOMONYMS = {
    "shape": "an array's shape (headers, writers, levels, index volumes), not the grid option",
    "axis": "an array axis or a ray direction handed to a geometric primitive",
    "occupancy": "an occupancy array ((nx, ny, nz) bool) handed to a stage, not the option "
                 "saying which voxels are on",
    "jobs": "the thread count handed to a parallel primitive (parallel.py, the writers' pools, "
            "Backend.cast): one int, already resolved by the plan (Plan.jobs)",
}


def _functions():
    """``(path, qualname, node)`` for every function and method in geovox/."""
    for d, _, names in os.walk(ROOT):
        for name in sorted(names):
            if not name.endswith(".py"):
                continue
            path = os.path.join(d, name)
            with open(path, encoding="utf-8") as f:
                tree = ast.parse(f.read(), path)
            yield from _walk(tree, path, "")


def _walk(node, path, prefix):
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
            qual = prefix + child.name
            yield path, qual, child
            yield from _walk(child, path, qual + ".")
        elif isinstance(child, ast.ClassDef):
            yield from _walk(child, path, prefix + child.name + ".")
        else:
            yield from _walk(child, path, prefix)


def _parameters(fn) -> list:
    a = fn.args
    return [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs]


def _option_like(fn) -> list:
    """The parameters of ``fn`` that could be options: an array (annotated ``np.ndarray``,
    such as a label volume ``labels``) is not one."""
    a = fn.args
    return [p.arg for p in a.posonlyargs + a.args + a.kwonlyargs
            if p.annotation is None or "ndarray" not in ast.unparse(p.annotation)]


def option_parameters() -> dict:
    """``option -> [(path, qualname)]``: the functions outside PUBLIC taking it by name."""
    options = {f.name for f in dataclasses.fields(Options)}
    out = collections.defaultdict(list)
    for path, qual, fn in _functions():
        if qual in PUBLIC:
            continue
        for p in _option_like(fn):
            if p in options and p not in HOMONYMS and (p, qual) not in ALLOWED:
                out[p].append((os.path.relpath(path, os.path.dirname(ROOT)), qual))
    return out


def test_the_rule_reads_real_functions():
    # The walk sees methods and nested functions, and the public signatures it leaves out.
    found = {qual for _, qual, _ in _functions()}
    assert {"voxelize", "convert_to", "convert_many", "Options.from_kwargs",
            "Projection.__init__"} <= found
    assert len(found) > 500


def test_no_option_is_a_parameter_of_more_than_two_functions():
    threaded = {k: v for k, v in option_parameters().items() if len(v) > MOST}
    assert not threaded, "\n".join(
        f"{k} ({len(v)}): " + ", ".join(f"{p}:{q}" for p, q in v) for k, v in threaded.items())


def code_lines(fn) -> int:
    """Lines of ``fn`` from its first statement after the docstring to its end.

    As the project's before-stop check counts them: every line, blank and
    comment lines included.
    """
    first = fn.body[0]
    doc = (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
           and isinstance(first.value.value, str))
    start = first.end_lineno + 1 if doc and len(fn.body) > 1 else first.lineno
    return fn.end_lineno - start + 1


def test_no_function_is_longer_than_100_lines():
    long = [f"{os.path.relpath(p, ROOT)}:{fn.lineno} {q} ({code_lines(fn)} lines)"
            for p, q, fn in _functions() if code_lines(fn) > 100]
    assert not long, "\n".join(long)


@pytest.mark.parametrize("source, lines", [
    ('def f():\n    """Doc\n    more."""\n    a = 1\n\n    # why\n    return a\n', 4),
    ("def f():\n    return 1\n", 1),
    ('def f():\n    """Only a docstring."""\n', 1),
])
def test_code_lines_counts_after_the_docstring(source, lines):
    assert code_lines(ast.parse(source).body[0]) == lines


#: ``(function called, module) -> why`` a module other than the plan's calls it.
DECIDED_ELSEWHERE: dict = {}


def test_the_grid_the_streaming_and_the_inside_test_are_decided_in_the_plan():
    """``make_grid``, ``streams`` and ``inside.choose`` are called from planner.py alone."""
    decisions = {"make_grid", "streams", "choose"}
    callers = collections.defaultdict(set)
    for d, _, names in os.walk(ROOT):
        for name in names:
            if name.endswith(".py"):
                with open(os.path.join(d, name), encoding="utf-8") as f:
                    tree = ast.parse(f.read())
                for node in ast.walk(tree):
                    if isinstance(node, ast.Call):
                        fn = node.func
                        called = fn.attr if isinstance(fn, ast.Attribute) else \
                            getattr(fn, "id", None)
                        if called in decisions:
                            callers[called].add(name)
    assert callers["make_grid"] and callers["choose"] and callers["streams"]
    elsewhere = {(c, m) for c, ms in callers.items() for m in ms if m != "planner.py"}
    assert elsewhere == set(DECIDED_ELSEWHERE), elsewhere
