"""The compiled OBJ reading (geovox/_objtext.pyx) against its NumPy twin in geovox/obj.py.

tests/test_obj.py holds the reader (compiled where it is built) to the
plain line-by-line reference; here the two fast readings are held to each
other, mesh for mesh and error for error: on the real models, on the file
with every feature, on every spelling of a number float() accepts or
refuses, on corners of every form and malformation, on random OBJ text and
on damaged bytes. A test that replaces the kernel's float reading by
something else fails (see test_a_wrong_number_is_noticed).
"""

from __future__ import annotations

import os
import tempfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from geovox.errors import MeshError, ParameterError
from geovox.kernels import chosen, obj_text
from geovox.io.obj import read_obj

from test_lattice_kernel import _have_compiler
from test_obj import (MTL_A, MTL_B, REAL, _features_text, _spellings, _write, assert_same,
                      obj_files)


@pytest.fixture(scope="module")
def kernel():
    """The compiled module: a failure where it should have been built, a skip elsewhere."""
    try:
        with chosen("compiled"):
            return obj_text()
    except ParameterError:
        if _have_compiler():
            pytest.fail("a C compiler and Python's headers are here, but geovox._objtext "
                        "was not built (pip install -e . builds it)")
        pytest.skip("no C compiler: the compiled OBJ reading is optional")


def _read(path, choice):
    """read_obj under GEOVOX_KERNEL=choice: the Mesh, or the MeshError's text."""
    old = os.environ.get("GEOVOX_KERNEL")
    os.environ["GEOVOX_KERNEL"] = choice
    try:
        return read_obj(path)
    except MeshError as exc:
        return str(exc)
    finally:
        if old is None:
            del os.environ["GEOVOX_KERNEL"]
        else:
            os.environ["GEOVOX_KERNEL"] = old


def _assert_twins(path):
    a, b = _read(path, "numpy"), _read(path, "compiled")
    if isinstance(a, str) or isinstance(b, str):
        assert a == b
    else:
        assert_same(b, a)
    return b


def test_the_obj_kernel_is_built_where_a_compiler_exists(kernel):
    assert kernel.__name__ == "geovox._objtext"


@pytest.mark.parametrize("path", REAL, ids=os.path.basename)
def test_real_models(kernel, path):
    _assert_twins(path)


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_every_feature(kernel, tmp_path, newline):
    _write(tmp_path, "a.mtl", MTL_A)
    _write(tmp_path, "b.mtl", MTL_B)
    (tmp_path / "tex.png").write_bytes(b"")
    mesh = _assert_twins(_write(tmp_path, "features.obj", _features_text(), newline=newline))
    assert mesh.vertex_colors is not None and mesh.corner_uv is not None


NUMBERS = ["1e+2", "2.e+1", "-.5", "+3", "1.", ".5", "-0", "+0.0", "-0.0", "1E5", "1e-0",
           "0000123.4500", "9007199254740992", "9007199254740993", "1.7976931348623157e308",
           "1.8e308", "-1e400", "5e-324", "2e-324", "1e-400", "123456789012345678901234567890",
           "0.1e-22", "1e22", "1e23", "12345678901234567e-5", "1e00000001", "1e000001",
           "4.9406564584124654e-324", "2.2250738585072011e-308"]
#: float() reads these, the fast readings leave them to it (a letter, an underscore).
PLAIN = ["nan", "-inf", "Infinity", "1_000.5"]
REFUSED = ["1e", "1e+", "e5", ".", "-", "+-1", "1.2.3",
           "1e5e5", "1-2", "1e5.0", "--1", "1.5E+-3", "0x10", "1,5", ".e1", "+.", "1e1-"]


def test_numbers_every_spelling(kernel, tmp_path):
    rng = np.random.default_rng(11)
    values = np.concatenate([rng.normal(size=200), rng.normal(size=100) * 1e-7,
                             rng.normal(size=100) * 1e9, [2.0 ** 53, 2.0 ** 53 + 2, 0.1, 1e22]])
    tokens = [s for x in values for s in _spellings(float(x), rng)] + NUMBERS
    tokens += ["0"] * (-len(tokens) % 3)
    text = "".join(f"v {a} {b} {c}\n" for a, b, c in zip(*[iter(tokens)] * 3)) + "f 1 2 3\n"
    mesh = _assert_twins(_write(tmp_path, "numbers.obj", text))
    want = np.array([float(t) for t in tokens])
    assert np.array_equal(mesh.vertices.ravel().view(np.uint64), want.view(np.uint64))


@pytest.mark.parametrize("token", REFUSED + PLAIN)
def test_numbers_float_refuses(kernel, tmp_path, token):
    # One bad number: the same one-line error from both (the plain reading says it).
    text = f"v 0 0 0\nv 1 0 0\nv 0 1 {token}\nvt {token} 0\nf 1 2 3\n"
    got = _assert_twins(_write(tmp_path, "bad.obj", text))
    assert isinstance(got, str) == (token in REFUSED)


CORNERS = ["1", "+1", "-3", "1/1", "1/-1", "1/+1", "1//1", "1/1/1", "1/1/", "1//", "1/",
           "2/1/1/1", "0001/0002", "1/1/-1", "1//+1"]
BAD_CORNERS = ["/1", "1-", "1/1-", "1/-", "-+1", "1/2/3-4", "a", "1.0", "1/x", "12345678901234567",
               "1/12345678901234567", "//", "+", "-"]


@pytest.mark.parametrize("corner", CORNERS + BAD_CORNERS)
def test_corners_every_form(kernel, tmp_path, corner):
    text = ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\n"
            f"f 1 2 3\nf {corner} 2 4\nf 2\t3  4 \nf 1/1 2/2 3/1\n")
    _assert_twins(_write(tmp_path, "corners.obj", text))


def test_a_wrong_number_is_noticed(kernel, tmp_path, monkeypatch):
    """The comparison above can fail: a kernel one ulp off is caught."""
    import geovox.io.obj as obj

    path = _write(tmp_path, "one.obj", "v 0.1 0.2 0.3\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    real = kernel.number_lines

    def off(*args):
        values, first, count, slow = real(*args)
        return np.nextafter(values, np.inf), first, count, slow

    wrong = type("K", (), {"number_lines": staticmethod(off),
                           "corner_lines": staticmethod(kernel.corner_lines)})
    monkeypatch.setattr(obj, "obj_text", lambda: None if os.environ.get("GEOVOX_KERNEL") ==
                        "numpy" else wrong)
    with pytest.raises(AssertionError):
        _assert_twins(path)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(obj_files())
def test_random_obj_text(text):
    if obj_text() is None:
        pytest.skip("the compiled OBJ reading is not built")
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "random.obj")
        with open(path, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        _assert_twins(path)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), st.sampled_from(["set", "insert", "delete"]),
                          st.sampled_from(list(b"0123456789 \t\n\r/-+.eEvtfn#\\\x00\xa0\xc2\xff"))),
                min_size=1, max_size=8))
def test_damaged_files(edits):
    if obj_text() is None:
        pytest.skip("the compiled OBJ reading is not built")
    data = bytearray(b"v 0 0 0\nv 1 0 0 1 0 0\nv 0 1 0\nv 0 0 1.5e-3\nvt 0 0\n"
                     b"vt 1 0\nf 1/1 2/2 3/1\nf -4//1 -2//1 -1//1\nf 2 4 3 1\n")
    for where, op, byte in edits:
        at = where % (len(data) + 1)
        if op == "set" and at < len(data):
            data[at] = byte
        elif op == "insert":
            data.insert(at, byte)
        elif op == "delete" and at < len(data):
            del data[at]
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "damaged.obj")
        with open(path, "wb") as f:
            f.write(bytes(data))
        _assert_twins(path)
