"""geovox.io.stl: STL read without trimesh, into the Mesh trimesh's path makes, indexed.

Every case compares :func:`read_stl` with the trimesh path it replaces
(``_trimesh_load``: ``trimesh.load(path, process=False)`` then
``from_trimesh``, with the problems trimesh logged) field by field and bit
for bit -- but for a single solid's vertices, which geovox merges where they
are equal (:func:`geovox.io.stl.indexed`): there the triangles are the same
bit for bit, and the vertices distinct and in order of first appearance --
or checks that the file is left to trimesh (None) and that ``load_mesh``
then reads it, or fails, exactly as trimesh's path does.
"""

from __future__ import annotations

import glob
import os
import re
import struct

import numpy as np
import pytest
import trimesh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import geovox
from geovox.errors import MeshError
from geovox.io.adaptor import from_trimesh, trimesh_load
from geovox.io.stl import read_stl

from conftest import corpus

MODELS = sorted(glob.glob(os.path.join(os.path.dirname(corpus("trimesh_stl", "README.md")), "*")))
MODELS = [p for p in MODELS if p.lower().endswith(".stl")]
#: trimesh's model that is left to trimesh: one solid of no facets.
LEFT = {"empty.stl"}


def _indexed_as(a, b):
    """``a`` is ``b`` (three corners a facet) with equal corners merged, in order of first appearance."""
    assert a.triangles.dtype == b.triangles.dtype and a.triangles.tobytes() == b.triangles.tobytes()
    ids = a.faces.reshape(-1)
    top = np.maximum.accumulate(ids)
    new = np.r_[True, top[1:] > top[:-1]]
    assert np.array_equal(ids[new], np.arange(len(a.vertices)))  # first appearance order
    v = b.vertices
    if np.signbit(v[v == 0]).any():  # -0.0 somewhere: nothing merged
        assert len(a.vertices) == len(b.vertices)
    else:
        assert len(np.unique(a.vertices, axis=0)) == len(a.vertices)  # every corner merged


def _same(a, b, indexed=False):
    """Field by field, bit for bit (-0.0 is not 0.0 here); with ``indexed``, ``a``'s vertices
    are ``b``'s merged (:func:`_indexed_as`)."""
    assert a.source == b.source
    if indexed and a.parts == []:
        _indexed_as(a, b)
    fields = ("face_material",) if indexed and a.parts == [] else \
        ("vertices", "faces", "face_material")
    for f in fields:
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), f
    assert a.materials == b.materials and a.problems == b.problems
    assert a.parts == b.parts
    if a.face_part is None or b.face_part is None:
        assert a.face_part is None and b.face_part is None
    else:
        assert a.face_part.dtype == b.face_part.dtype and np.array_equal(a.face_part, b.face_part)
    for f in ("corner_uv", "vertex_colors"):
        assert getattr(a, f) is None and getattr(b, f) is None, f


def _as_trimesh_reads_it(path, accepted=True):
    """read_stl's Mesh is trimesh's path's (or it is None and load_mesh is trimesh's path)."""
    path = str(path)
    fast = read_stl(path)
    assert (fast is not None) == accepted, path
    try:
        slow = trimesh_load(path)
    except MeshError as exc:
        assert fast is None, path  # what trimesh cannot read, read_stl must leave to it
        with pytest.raises(MeshError) as got:
            geovox.load_mesh(path)
        assert str(got.value) == str(exc)
        return None
    if fast is None:
        _same(geovox.load_mesh(path), slow)
        return slow
    _same(fast, slow, indexed=True)
    _same(fast, from_trimesh(trimesh.load(path, process=False), source=path), indexed=True)
    _same(geovox.load_mesh(path), fast)
    return fast


@pytest.mark.parametrize("path", MODELS, ids=os.path.basename)
def test_trimesh_models_read_as_trimesh_reads_them(path):
    mesh = _as_trimesh_reads_it(path, accepted=os.path.basename(path) not in LEFT)
    if os.path.basename(path) in ("multibody.stl", "two_objects_mixed_case_names.stl"):
        assert len(mesh.parts) == 2  # trimesh's scene of two solids, as before


def test_the_models_cover_both_kinds():
    binary = [p for p in MODELS if _is_binary(p)]
    solid_header = [p for p in binary if _bytes(p)[:5].lower() == b"solid"]
    assert len(binary) >= 10 and len(solid_header) >= 3 and len(MODELS) - len(binary) == 3


def _bytes(path):
    with open(path, "rb") as f:
        return f.read()


def _is_binary(path):
    data = _bytes(path)
    return len(data) >= 84 and struct.unpack("<I", data[80:84])[0] * 50 == len(data) - 84


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(subdivisions=2)
    # off-centre, so float32 rounding and signs show in every coordinate
    return np.asarray(s.vertices) * [1.5, 1.0, 0.75] + [1e3, -2.0, 0.5], np.asarray(s.faces)


def _binary(path, triangles, header=b"", count=None, tail=b"", attribute=0):
    rec = np.zeros(len(triangles), [("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    rec["v"], rec["a"] = triangles, attribute
    rec["n"] = 1.0 if len(triangles) else 0.0
    head = header.ljust(80, b" ")[:80] + struct.pack("<I", len(triangles) if count is None else count)
    path.write_bytes(head + rec.tobytes() + tail)
    return path


def _ascii(path, triangles, upper=False, **layout):
    text = _ascii_text(triangles, **layout)
    path.write_bytes((text.upper() if upper else text).encode())
    return path


def _ascii_text(triangles, name="sphere", fmt="{:.9e}", newline="\n", indent="  ", sep=" ",
                normal="0 0 1"):
    lines = [f"solid {name}".rstrip()]
    for t in triangles:
        lines += [f"{indent}facet normal {normal}", f"{indent * 2}outer loop"]
        lines += [f"{indent * 3}vertex" + "".join(sep + fmt.format(float(c)) for c in p) for p in t]
        lines += [f"{indent * 2}endloop", f"{indent}endfacet"]
    lines.append(f"endsolid {name}".rstrip())
    return newline.join(lines) + newline


def test_binary_export_reads_as_trimesh_reads_it(tmp_path, sphere):
    path = tmp_path / "s.stl"
    trimesh.Trimesh(*sphere, process=False).export(str(path))
    mesh = _as_trimesh_reads_it(path)
    # the sphere's own vertices, each once, as the corners first use them
    assert len(mesh.faces) == len(sphere[1]) and len(mesh.vertices) == len(sphere[0])


@pytest.mark.parametrize("header", [b"solid sphere", b"SOLID", b"solid\nfacet normal 0 0 1\n",
                                    b"\xff\xfe not text", b"COLOR=\x10\x20\x30\xff"])
def test_binary_with_any_header_is_binary(tmp_path, sphere, header):
    v, f = sphere
    _as_trimesh_reads_it(_binary(tmp_path / "s.STL", v[f], header=header, attribute=0x801F))


def test_zero_area_and_repeated_facets_are_kept(tmp_path, sphere):
    v, f = sphere
    t = v[f]
    flat = np.repeat(t[:1, :1], 3, axis=1)  # one point three times
    line = np.stack([t[0, 0], t[0, 1], (t[0, 0] + t[0, 1]) / 2])[None]
    tri = np.concatenate([t, flat, line, t[:5]])
    mesh = _as_trimesh_reads_it(_binary(tmp_path / "z.stl", tri))
    assert len(mesh.faces) == len(tri)
    mesh = _as_trimesh_reads_it(_ascii(tmp_path / "z_ascii.stl", tri))
    assert len(mesh.faces) == len(tri)


ASCII_LAYOUTS = {
    "exported": {},
    "crlf": dict(newline="\r\n"),
    "upper": dict(upper=True),
    "tabs": dict(indent="\t", sep="\t"),
    "odd_spacing": dict(indent="   ", sep="  \t "),
    "no_name": dict(name=""),
    "name_with_spaces": dict(name="Part 1 (copy) - body"),
    "repr_numbers": dict(fmt="{!r}"),
    "plain_numbers": dict(fmt="{:g}"),
    "signed_numbers": dict(fmt="{:+.6E}"),
    "fixed_numbers": dict(fmt="{:.4f}"),
    "no_indent": dict(indent=""),
    "blank_normal": dict(normal=""),
    "word_normal": dict(normal="nan nan nan"),
}


@pytest.mark.parametrize("layout", list(ASCII_LAYOUTS), ids=str)
def test_ascii_layouts_read_as_trimesh_reads_them(tmp_path, sphere, layout):
    v, f = sphere
    _as_trimesh_reads_it(_ascii(tmp_path / "s.stl", v[f], **ASCII_LAYOUTS[layout]))


def test_ascii_export_and_surroundings(tmp_path, sphere):
    v, f = sphere
    text = trimesh.Trimesh(v, f, process=False).export(file_type="stl_ascii")
    variants = {
        "export": text,
        "leading_blank_lines": "\n\n  \t\n" + text,
        "trailing_text": text + "\n\nthat was the sphere\n",
        "endsolid_without_name": text.replace("endsolid", "endsolid\n"),
        "trailing_spaces": text.replace("\n", "   \n"),
        "numbers_to_the_end_of_file": text.rstrip("\n"),
        "empty_solid_before": "solid nothing\nendsolid nothing\n" + text,
        "empty_solid_after": text + "\nsolid nothing\nendsolid nothing\n",
        "utf8_name": text.replace("solid", "solid Würfel \u00e9", 1),
        "loop_and_vertex_one_line": text.replace("loop\n", "loop ", 5),
        "blank_vertex_line": text.replace("outer loop", "outer loop\nvertex   ", 1),
    }
    for name, body in variants.items():
        path = tmp_path / f"{name}.stl"
        path.write_bytes(body.encode())
        _as_trimesh_reads_it(path)


def _solid(name, triangles, fmt="{!r}"):
    return _ascii_text(triangles, name=name, fmt=fmt)


def test_several_solids_read_as_trimesh_reads_them(tmp_path, sphere):
    v, f = sphere
    t = v[f]
    a, b, c = _solid("first", t[:40]), _solid("second", t[40:]), _solid("Third Body", t[:3])
    bare = _solid("", t[:2])
    cases = {
        "two": a + b,
        "three": a + b + c,
        "same_name": a + a + a,
        "upper": (a + b).upper(),
        "no_names": bare + bare + bare,
        "numbered_names": _solid("x_3", t[:2]) + _solid("x_3", t[2:4]) + _solid("x", t[4:6]),
        "taken_number": _solid("geometry_1", t[:2]) + bare,
        "empty_solid_between": a + "solid nothing\nendsolid nothing\n" + b,
        "crlf": (a + b).replace("\n", "\r\n"),
    }
    for name, body in cases.items():
        path = tmp_path / f"{name}.stl"
        path.write_text(body)
        mesh = _as_trimesh_reads_it(path)
        assert len(mesh.parts) == body.lower().count("endsolid") - ("nothing" in body), name
    # a sphere's shared corners are merged within each solid, not across solids
    assert len(_as_trimesh_reads_it(tmp_path / "two.stl").vertices) < len(t) * 3


def test_several_solids_merge_vertices_as_trimesh_does(tmp_path):
    # corners equal to 8 decimals merge (the first one's coordinates kept), -0.0 and 0.0 too
    tri = np.array([[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
                    [[-0.0, 0.0, 1e-9], [1.0 + 4e-9, 0.0, 0.0], [0.0, 0.0, 1.0]],
                    [[0.0, 0.0, 6e-9], [1.0 + 6e-9, 0.0, 0.0], [0.0, 1.0 - 1e-12, 0.0]],
                    [[0.5, 0.5, 0.5]] * 3])
    path = tmp_path / "m.stl"
    path.write_text(_solid("a", tri) + _solid("b", tri[::-1]))
    mesh = _as_trimesh_reads_it(path)
    assert len(mesh.vertices) < 2 * 12


def test_solids_named_world_are_left_to_trimesh(tmp_path, sphere):
    v, f = sphere
    path = tmp_path / "w.stl"
    path.write_text(_solid("world_1", v[f][:3]) + _solid("world", v[f][3:6]))
    assert _as_trimesh_reads_it(path, accepted=False).parts == ["world_1", "world_2 (world)"]


def test_damaged_and_odd_files_are_left_to_trimesh(tmp_path, sphere):
    v, f = sphere
    t = v[f]
    good = _binary(tmp_path / "good.stl", t).read_bytes()
    text = _ascii(tmp_path / "good_ascii.stl", t).read_text()
    nan = t.copy()
    nan[3, 1, 2] = np.nan
    inf = t.copy()
    inf[0, 0, 0] = np.inf
    cases = {
        "truncated": good[:-7],
        "one_byte_long": good + b"\0",
        "count_too_high": good[:80] + struct.pack("<I", len(t) + 1) + good[84:],
        "count_too_low": good[:80] + struct.pack("<I", len(t) - 1) + good[84:],
        "no_facets_binary": good[:80] + struct.pack("<I", 0),
        "header_only_short": good[:60],
        "nan_binary": _binary(tmp_path / "nan.stl", nan).read_bytes(),
        "inf_binary": _binary(tmp_path / "inf.stl", inf).read_bytes(),
        "truncated_ascii": text[: len(text) // 2].encode(),
        "nan_ascii": _ascii(tmp_path / "na.stl", nan, fmt="{!r}").read_bytes(),
        "inf_word": text.replace("vertex ", "vertex inf ", 1).encode(),
        "word_in_vertex_line": text.replace("vertex ", "vertex x ", 1).encode(),
        "two_vertices_one_line": re.sub(r"(vertex [^\n]*)\n\s*vertex", r"\1 vertex", text,
                                        count=1).encode(),
        "four_numbers": text.replace("vertex ", "vertex 1.0 ", 1).encode(),
        "bad_number": text.replace("vertex ", "vertex 1-2 ", 1).encode(),
        "lone_dot": text.replace("vertex ", "vertex . ", 1).encode(),
        "vertex_in_name": text.replace("solid sphere", "solid vertex_test", 1).encode(),
        "endsolid_first": ("endsolid x\n" + text).encode(),
        "no_endsolid": text.replace("endsolid", "").encode(),
        "classic_mac_lines": text.replace("\n", "\r").encode(),
        "latin1_name": text.replace("solid sphere", "solid W\xfcrfel", 1).encode("latin-1"),
        "no_solid_keyword": text.replace("solid", "thing").encode(),
        "nothing_but_text": b"this is not an STL file at all\n" * 5,
        "binary_noise": np.random.default_rng(1).integers(0, 256, 1000, dtype=np.uint8).tobytes(),
    }
    for name, data in cases.items():
        path = tmp_path / f"{name}.stl"
        path.write_bytes(data)
        assert read_stl(str(path)) is None, name
        _as_trimesh_reads_it(path, accepted=False)


def test_an_empty_file_says_so(tmp_path):
    path = tmp_path / "empty.stl"
    path.write_bytes(b"")
    with pytest.raises(MeshError, match="the file is empty"):
        geovox.load_mesh(str(path))


def test_upper_case_extension_and_voxels(tmp_path, sphere):
    v, f = sphere
    path = str(_binary(tmp_path / "s.STL", v[f], header=b"solid s"))
    a = geovox.voxelize(path, resolution=24).occupancy
    b = geovox.voxelize(trimesh_load(path), resolution=24).occupancy
    assert a.sum() > 100 and np.array_equal(a, b)


_coordinate = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False, width=32)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(triangles=st.lists(st.lists(_coordinate, min_size=9, max_size=9), min_size=1, max_size=12),
       fmt=st.sampled_from(["{:.9e}", "{!r}", "{:g}", "{:+.3E}", "{:.2f}", "{:.17g}"]),
       newline=st.sampled_from(["\n", "\r\n"]), sep=st.sampled_from([" ", "\t", "   ", " \t"]),
       upper=st.booleans(), binary=st.booleans(), header=st.sampled_from([b"", b"solid x"]))
def test_property_any_triangles_read_as_trimesh_reads_them(tmp_path, triangles, fmt, newline,
                                                          sep, upper, binary, header):
    t = np.asarray(triangles, np.float64).reshape(-1, 3, 3)
    path = tmp_path / "p.stl"
    if binary:
        _binary(path, t, header=header)
    else:
        _ascii(path, t, fmt=fmt, newline=newline, sep=sep, upper=upper)
    mesh = _as_trimesh_reads_it(path)
    if binary:
        assert np.array_equal(mesh.triangles, t.astype(np.float32))


# Coordinates on a coarse grid, some nudged by less than the 8 decimals trimesh merges at,
# so that corners of a solid often merge, and names that collide.
_near = st.builds(lambda k, nudge: k * 0.25 + nudge, st.integers(-4, 4),
                  st.sampled_from([0.0, -0.0, 3e-9, -4e-9, 6e-9, 1e-7]))
_solid_strategy = st.tuples(st.sampled_from(["", "a", "a", "a_1", "b_2", "Body 1", "geometry_1"]),
                            st.lists(st.lists(_near, min_size=9, max_size=9), min_size=1,
                                     max_size=6))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(solids=st.lists(_solid_strategy, min_size=1, max_size=4),
       fmt=st.sampled_from(["{!r}", "{:.9e}", "{:.17g}"]), upper=st.booleans())
def test_property_several_solids_read_as_trimesh_reads_them(tmp_path, solids, fmt, upper):
    text = "".join(_solid(name, np.asarray(t, np.float64).reshape(-1, 3, 3), fmt)
                   for name, t in solids)
    path = tmp_path / "p.stl"
    path.write_bytes((text.upper() if upper else text).encode())
    mesh = _as_trimesh_reads_it(path)
    assert len(mesh.parts) == (len(solids) if len(solids) > 1 else 0)


def test_equal_corners_are_one_vertex_and_minus_zero_merges_nothing(tmp_path, sphere):
    v, f = sphere
    t = v[f].astype(np.float32).astype(np.float64)
    mesh = read_stl(str(_binary(tmp_path / "m.stl", t)))
    assert len(mesh.vertices) == len(v)
    np.testing.assert_array_equal(mesh.triangles, t)
    t[0, 0, 0] = -0.0  # equal to 0.0 but not its bits: the file's corners are kept as they are
    t[1, 1, 1] = 0.0
    mesh = read_stl(str(_binary(tmp_path / "z.stl", t)))
    assert len(mesh.vertices) == 3 * len(f)
    assert mesh.triangles.tobytes() == t.tobytes()


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(*[st.sampled_from([0.0, 1.0, -2.5, 3.0])] * 3), min_size=3,
                max_size=60).filter(lambda c: len(c) % 3 == 0))
def test_numpy_merge_numbers_corners_as_the_compiled_one(corners):
    from geovox.io.stl import _merge_positions, indexed

    c = np.array(corners, np.float64)
    ids = _merge_positions(c)
    lattice = pytest.importorskip("geovox._lattice")
    np.testing.assert_array_equal(ids, lattice.merge_positions(c))
    v, faces = indexed(c)
    np.testing.assert_array_equal(v[faces].reshape(-1, 3), c)
    assert len(v) == len({tuple(p) for p in corners})
