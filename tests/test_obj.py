"""The OBJ reader: the same results as the plain line-by-line reading it
replaced (kept here as the reference), on real models, on a file for every
feature, on random OBJ text; odd files; bad input in one line."""

from __future__ import annotations

import glob
import os
from decimal import Decimal
import tempfile
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import geovox
from geovox.cli import main
from geovox.errors import GeovoxWarning, MeshError
from geovox.io.load import load_mesh
from geovox.mesh import Material, Mesh
from geovox.io.mtl import read_mtl, resolve_path, rest_of
from geovox.io.obj import read_obj

from conftest import DATA, SPOT, corpus


# ---------------------------------------------------------------------------
# The reference: geovox 0.1's reader, one Python loop per line, unchanged but
# for its name. The new reader must give exactly its results wherever it read
# a file; it differs on purpose only where it refused one (see the tests of
# odd files below) and on NaN vertex colours.

def reference_read_obj(path: str) -> Mesh:
    with open(path, "rb") as f:
        data = f.read()
    if b"\0" in data[:4096]:
        raise MeshError(f"{path}: is a binary file, not a text OBJ mesh")
    text = data.decode("utf-8", errors="replace")
    text = text.replace("\\\r\n", " ").replace("\\\n", " ")
    folder = os.path.dirname(os.path.abspath(path))
    v, vc, vt = [], [], []
    tri_v, tri_t, tri_m = [], [], []
    mat_index: dict = {}
    mat_names: list = []
    libs: list = []
    current = -1
    has_vc = False
    for lineno, line in enumerate(text.splitlines(), 1):
        if not line or line[0] == "#":
            continue
        parts = line.split()
        if not parts:
            continue
        key = parts[0]
        try:
            if key == "v":
                v.append((float(parts[1]), float(parts[2]), float(parts[3])))
                if len(parts) >= 7:
                    vc.append((float(parts[4]), float(parts[5]), float(parts[6])))
                    has_vc = True
                else:
                    vc.append((1.0, 1.0, 1.0))
            elif key == "vt":
                vt.append((float(parts[1]), float(parts[2]) if len(parts) > 2 else 0.0))
            elif key == "f":
                nv, nt = len(v), len(vt)
                corners_v, corners_t = [], []
                for tok in parts[1:]:
                    s = tok.split("/")
                    i = int(s[0])
                    corners_v.append(i - 1 if i > 0 else nv + i)
                    if len(s) > 1 and s[1]:
                        j = int(s[1])
                        corners_t.append(j - 1 if j > 0 else nt + j)
                    else:
                        corners_t.append(-1)
                if len(corners_v) < 3:
                    continue
                for k in range(1, len(corners_v) - 1):  # fan
                    tri_v.append((corners_v[0], corners_v[k], corners_v[k + 1]))
                    tri_t.append((corners_t[0], corners_t[k], corners_t[k + 1]))
                    tri_m.append(current)
            elif key == "usemtl":
                name = rest_of(line, "usemtl")
                if name not in mat_index:
                    mat_index[name] = len(mat_names)
                    mat_names.append(name)
                current = mat_index[name]
            elif key == "mtllib":
                libs.append(rest_of(line, "mtllib"))
        except (ValueError, IndexError):
            raise MeshError(f"{path}: line {lineno} is not valid OBJ: {line.strip()[:60]!r}") from None
    if not v and not tri_v:
        raise MeshError(f"{path}: cannot be read as a mesh (no OBJ vertices or faces)")
    faces = np.array(tri_v, dtype=np.int64).reshape(-1, 3)
    tex = np.array(tri_t, dtype=np.int64).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(v)):
        bad = faces[(faces < 0) | (faces >= len(v))][0]
        raise MeshError(f"{path}: faces index vertex {bad + 1} but the file has {len(v)} vertices")
    if tex.size and tex.max() >= len(vt):
        raise MeshError(f"{path}: faces index texture coordinate {tex.max() + 1} "
                        f"but the file has {len(vt)}")

    problems: list = []
    library: dict = {}
    missing_lib = False
    for lib in libs:
        found = resolve_path(lib, folder)
        if found is None:
            problems.append(f"material file not found: {lib!r} (named in {path}); "
                            f"using default colours")
            missing_lib = True
            continue
        library.update(read_mtl(found, problems))
    materials = []
    for name in mat_names:
        if name in library:
            materials.append(library[name])
        else:
            if libs and not missing_lib:
                problems.append(f"material {name!r} is not defined in {', '.join(libs)}; "
                                f"using the default colour")
            materials.append(Material(name=name, defined=False))

    uv = None
    if vt and (tex >= 0).any():
        vt_arr = np.array(vt, dtype=np.float64)
        uv = np.where((tex >= 0)[..., None], vt_arr[np.maximum(tex, 0)], np.nan)
    return Mesh(
        vertices=np.array(v, dtype=np.float64).reshape(-1, 3),
        faces=faces,
        source=path,
        face_material=np.array(tri_m, dtype=np.int64),
        materials=materials,
        corner_uv=uv,
        vertex_colors=np.array(vc, dtype=np.float64) if has_vc else None,
        problems=problems,
    )


def _bits_equal(a, b) -> bool:
    """Same shape and the same float64 bits (NaN and -0.0 included)."""
    if a is None or b is None:
        return a is None and b is None
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind == "f":
        return np.array_equal(a.view(np.uint64), b.view(np.uint64))
    return np.array_equal(a, b)


def _material_facts(m: Material):
    return (m.name, None if m.kd is None else m.kd.tolist(), m.ka.tolist(), m.texture_file,
            m.defined)


def assert_same(new: Mesh, ref: Mesh):
    assert _bits_equal(new.vertices, ref.vertices), "vertices"
    assert _bits_equal(new.faces, ref.faces), "faces"
    assert _bits_equal(new.face_material, ref.face_material), "face_material"
    assert _bits_equal(new.corner_uv, ref.corner_uv), "corner_uv"
    assert _bits_equal(new.vertex_colors, ref.vertex_colors), "vertex_colors"
    assert [_material_facts(m) for m in new.materials] == \
        [_material_facts(m) for m in ref.materials], "materials"
    assert new.problems == ref.problems, "problems"


def _write(folder, name, text, encoding="utf-8", newline="\n"):
    path = os.path.join(str(folder), name)
    with open(path, "wb") as f:
        f.write(text.replace("\n", newline).encode(encoding))
    return path


# ---------------------------------------------------------------------------
# Real models.

REAL = sorted(glob.glob(os.path.join(DATA, "**", "*.obj"), recursive=True)) + [SPOT]
# Files the reference refused or read differently on purpose (see below).
CHANGED = {"cubevt.obj", "nancolor.obj"}


@pytest.mark.parametrize("path", [p for p in REAL if os.path.basename(p) not in CHANGED],
                         ids=lambda p: os.path.relpath(p, DATA))
def test_real_models_read_as_before(path):
    assert_same(read_obj(path), reference_read_obj(path))


# ---------------------------------------------------------------------------
# One file with every feature, in several spellings.

MTL_A = """newmtl red
Kd 1 0 0
Ka 0.1 0 0
newmtl textured
Kd 0.5 0.5 0.5
map_Kd -s 1 1 1 tex.png
"""
MTL_B = "newmtl blue\nKd 0 0 1\n"

FEATURES = """# every feature the reader knows
mtllib a.mtl
mtllib b.mtl
mtllib missing.mtl
o first
v 0 0 0
v 1 0 0 1 0 0
v 1 1 0
v\t0 1 0   0.5 0.5 0.5
v 0.5 0.5 1
   v 0.25 0.25 -1
vt 0 0
vt 1 0 0
vt 1 1
vt 0.5
vn 0 0 1

usemtl red
f 1 2 3
f 1/1 3/3 4/4
f 1//1 2//1 5//1
f 2/2/1 3/3/1 5/1/1
g second group
usemtl blue
f 1 2 3 4
f -6 -5 -4 -3 -2 -1
f -6/-4 -5/-3 -4/-2
usemtl undefined here
f 1 2\\
 3 4  5   
f 4 3 2 1 \t
usemtl textured
f 1/1/1 2//1 3/2 4
f 1 2
s off
l 1 2 3
"""


def _features_text() -> str:
    return FEATURES


@pytest.mark.parametrize("newline", ["\n", "\r\n"])
@pytest.mark.parametrize("missing_lib", [True, False])
def test_every_feature_reads_as_before(tmp_path, newline, missing_lib):
    _write(tmp_path, "a.mtl", MTL_A)
    _write(tmp_path, "b.mtl", MTL_B)
    (tmp_path / "tex.png").write_bytes(b"")
    text = _features_text() if missing_lib else _features_text().replace("mtllib missing.mtl\n", "")
    path = _write(tmp_path, "features.obj", text, newline=newline)
    new, ref = read_obj(path), reference_read_obj(path)
    assert_same(new, ref)
    assert len(new.faces) == 1 + 1 + 1 + 1 + 2 + 4 + 1 + 3 + 2 + 2
    assert new.vertex_colors is not None and new.corner_uv is not None
    assert [m.name for m in new.materials] == ["red", "blue", "undefined here", "textured"]
    # With a material file missing, an unknown name may be in it: no "not defined" then.
    assert any("missing.mtl" in p for p in new.problems) == missing_lib
    assert any("'undefined here' is not defined" in p for p in new.problems) != missing_lib


def test_line_ends_lone_cr_read_as_before(tmp_path):
    # The reference splits lone CR lines too, but does not join "\\\r": no continuation here.
    text = _features_text().replace("f 1 2\\\n 3 4  5   ", "f 1 2 3 4  5   ")
    _write(tmp_path, "a.mtl", MTL_A)
    _write(tmp_path, "b.mtl", MTL_B)
    path = _write(tmp_path, "cr.obj", text, newline="\r")
    assert_same(read_obj(path), reference_read_obj(path))
    lf = _write(tmp_path, "lf.obj", text)
    assert _bits_equal(read_obj(path).faces, read_obj(lf).faces)


def test_mixed_colours_and_many_objects(tmp_path):
    """Vertex colours on some vertices only, across many o/g blocks with
    relative indices, the Cornell box's layout."""
    rng = np.random.default_rng(3)
    lines = []
    for block in range(50):
        lines.append(f"o part{block}" if block % 2 else f"g part{block}")
        for _ in range(4):
            xyz = " ".join(f"{x:.6f}" for x in rng.normal(size=3))
            rgb = " " + " ".join(f"{c:.3f}" for c in rng.random(3)) if block % 3 == 0 else ""
            lines.append(f"v {xyz}{rgb}")
        lines.append(f"usemtl m{block % 5}")
        lines.append("f -4 -3 -2 -1")
        lines.append("f -4 -2 -1")
    path = _write(tmp_path, "blocks.obj", "\n".join(lines) + "\n")
    new = read_obj(path)
    assert_same(new, reference_read_obj(path))
    assert len(new.faces) == 150 and np.all(new.vertex_colors[4:12] == 1.0)


# ---------------------------------------------------------------------------
# Numbers: every spelling float() accepts, bit for bit.

def _spellings(x: float, rng) -> list:
    out = [repr(x), f"{x:.6f}", f"{x:.8f}", f"{x:.3e}", f"{x:g}", f"{x:.17g}", f"{x:.20f}",
           f"{x:E}", str(int(x)) if abs(x) < 1e15 else "7"]
    extra = []
    for s in out:
        if not s.startswith("-"):
            extra.append("+" + s)
        if s.startswith(("0.", "-0.")):
            extra.append(s.replace("0.", ".", 1))
        if "." in s and "e" not in s.lower():
            extra.append(s + "e+00")
    return out + extra


def test_numbers_are_read_exactly_as_float_reads_them(tmp_path):
    rng = np.random.default_rng(7)
    values = np.concatenate([rng.normal(size=300), rng.normal(size=100) * 1e-5,
                             rng.normal(size=100) * 1e6, rng.random(50) * 1e-25,
                             rng.random(50) * 1e25, [0.0, -0.0, 1.0, 0.1, 2 ** 53, 2 ** 53 + 2]])
    tokens = [s for x in values for s in _spellings(float(x), rng)]
    # Decimal midpoints between neighbouring doubles, cut to 17-19 digits: where
    # rounding twice (through x87 extended precision) could go wrong.
    for x in np.abs(rng.normal(size=300)) * 10.0 ** rng.integers(-8, 8, 300):
        mid = (Decimal(float(x)) + Decimal(float(np.nextafter(x, np.inf)))) / 2
        tokens += [format(mid, f".{digits - 1}e") for digits in (17, 18, 19)]
    tokens += ["1e+2", "2.e+1", "-.5", "+3", "1.", ".5", "-0", "+0.0", "1E5", "1e-0",
               "0000123.4500", "9007199254740993", "1.7976931348623157e308", "5e-324",
               "nan", "-inf", "Infinity", "1_000.5"]
    tokens += [""] * (-len(tokens) % 3)
    tokens = [t or "0" for t in tokens]
    text = "".join(f"v {a} {b} {c}\n" for a, b, c in zip(*[iter(tokens)] * 3)) + "f 1 2 3\n"
    path = _write(tmp_path, "numbers.obj", text)
    got = read_obj(path).vertices.ravel()
    want = np.array([float(t) for t in tokens])
    assert _bits_equal(got, want)


def test_issue_12_number_spellings(tmp_path):
    path = _write(tmp_path, "n.obj", "v 1e+2 2.e+1 -.5\nv +3 0 0\nv 0 1E-2 7\nf 1 2 3\n")
    np.testing.assert_array_equal(read_obj(path).vertices,
                                  [[100, 20, -0.5], [3, 0, 0], [0, 0.01, 7]])


# ---------------------------------------------------------------------------
# Random OBJ text: both readers agree.

_SEPARATORS = st.sampled_from([" ", " ", " ", "  ", "\t", " \t ", "\u00a0", "\x1f"])


@st.composite
def _number(draw):
    x = draw(st.one_of(st.floats(-1e6, 1e6, allow_nan=False),
                       st.integers(-1000, 1000).map(float),
                       st.floats(allow_nan=False, allow_infinity=False)))
    style = draw(st.sampled_from(["repr", ".6f", ".8f", ".3e", "g", ".17g", "int", "sign", "dot"]))
    if style == "repr":
        s = repr(x)
    elif style == "int":
        s = str(int(x)) if abs(x) < 1e18 else repr(x)
    elif style == "sign":
        s = repr(x) if repr(x).startswith("-") else "+" + repr(x)
    elif style == "dot":
        s = f"{x:.5f}".replace("0.", ".", 1) if abs(x) < 1 else f"{x:.0f}."
    else:
        s = format(x, style)
    return s


@st.composite
def obj_files(draw):
    """Valid OBJ text of every statement, spelling and index form."""
    sep = draw(_SEPARATORS)
    lines, nv, nt = [], 0, 0
    colours = draw(st.sampled_from(["none", "all", "some"]))
    for _ in range(3):
        lines.append(("v", [draw(_number()) for _ in range(3)]))
        nv += 1
    steps = draw(st.lists(st.sampled_from(
        ["v", "v", "v", "vt", "vt", "f", "f", "f", "usemtl", "o", "g", "#", "", "vn", "s", "l",
         "junk", "indent"]), min_size=1, max_size=30))
    for step in steps:
        if step == "v":
            words = [draw(_number()) for _ in range(3)]
            if colours == "all" or (colours == "some" and draw(st.booleans())):
                words += [repr(draw(st.floats(0, 1))) for _ in range(3)]
            elif draw(st.integers(0, 5)) == 0:
                words += [draw(_number())]  # a weight, not read
            lines.append(("v", words))
            nv += 1
        elif step == "vt":
            lines.append(("vt", [draw(_number()) for _ in range(draw(st.integers(1, 3)))]))
            nt += 1
        elif step == "f":
            k = draw(st.sampled_from([1, 2, 3, 3, 3, 4, 4, 5, 9, 40]))
            form = draw(st.sampled_from(["v", "v/t", "v//n", "v/t/n", "v/t/", "mixed"]))
            corners = []
            for _ in range(k):
                i = draw(st.integers(1, nv))
                vi = str(i) if draw(st.booleans()) else str(i - nv - 1)  # or relative
                f = form if form != "mixed" else draw(st.sampled_from(["v", "v/t", "v//n", "v/t/n"]))
                if "t" in f and nt == 0:
                    f = "v"
                if "t" in f:
                    j = draw(st.integers(1, nt))
                    ti = str(j) if draw(st.booleans()) else str(j - nt - 1)
                    corners.append(f.replace("v", vi, 1).replace("t", ti).replace("n", "1"))
                else:
                    corners.append(f.replace("v", vi, 1).replace("n", "7"))
            lines.append(("f", corners))
        elif step == "usemtl":
            lines.append(("usemtl", [draw(st.sampled_from(["red", "green", "two words", ""]))]))
        elif step in ("o", "g"):
            lines.append((step, [draw(st.sampled_from(["a", "b c", "f 1 2 3"]))]))
        elif step == "#":
            lines.append(("#", ["v 1 2 3 f 1 2 3"]))
        elif step == "":
            lines.append(("", []))
        elif step == "vn":
            lines.append(("vn", ["0", "0", "1"]))
        elif step == "s":
            lines.append(("s", ["off"]))
        elif step == "l":
            lines.append(("l", ["1", "2"]))
        elif step == "junk":
            lines.append(("vp", ["0.5"]))
        elif step == "indent":
            lines.append((" v", [draw(_number()) for _ in range(3)]))
            nv += 1
    lines.append(("f", ["-1", "-2", "-3"]))
    if draw(st.booleans()):
        lines.insert(0, ("mtllib", ["missing.mtl"]))
    out = []
    for key, words in lines:
        line = sep.join([key] + words) if key else ""
        if draw(st.integers(0, 9)) == 0:
            line += draw(st.sampled_from([" ", "\t", "  "]))  # trailing spaces
        if words and key in ("v", "f") and draw(st.integers(0, 9)) == 0:
            line = line.replace(sep, " \\\n ", 1)  # a continued line
        out.append(line)
    newline = draw(st.sampled_from(["\n", "\r\n"]))
    return "\n".join(out).replace("\n", newline) + draw(st.sampled_from(["", newline]))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(obj_files())
def test_random_obj_text_reads_as_before(text):
    with tempfile.TemporaryDirectory() as folder:
        path = os.path.join(folder, "random.obj")
        with open(path, "w", encoding="utf-8", newline="") as f:
            f.write(text)
        assert_same(read_obj(path), reference_read_obj(path))


# ---------------------------------------------------------------------------
# Odd files (issue 12).

PLAIN = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\nvt 1 0\nvt 0 1\n" \
        "f 1/1 2/2 3/3\nf 1/1 3/3 4/1\nf 1 4 2\nf 2 4 3\n"


@pytest.mark.parametrize("encoding, bom", [
    ("utf-8", b"\xef\xbb\xbf"), ("utf-16-le", b"\xff\xfe"), ("utf-16-be", b"\xfe\xff"),
    ("utf-16-le", b""), ("utf-16-be", b""), ("utf-32-le", b"\xff\xfe\x00\x00")])
@pytest.mark.parametrize("newline", ["\n", "\r\n", "\r"])
def test_encodings_and_line_ends(tmp_path, encoding, bom, newline):
    plain = read_obj(_write(tmp_path, "plain.obj", PLAIN))
    path = tmp_path / "odd.obj"
    path.write_bytes(bom + PLAIN.replace("\n", newline).encode(encoding))
    odd = read_obj(str(path))
    for name in ("vertices", "faces", "corner_uv", "face_material"):
        assert _bits_equal(getattr(odd, name), getattr(plain, name)), name


def test_very_long_face_line(tmp_path):
    n = 5000
    angle = np.linspace(0, 2 * np.pi, n, endpoint=False)
    text = "".join(f"v {np.cos(a):.9f} {np.sin(a):.9f} 0\n" for a in angle)
    text += "v 0 0 1\nf " + " ".join(str(i) for i in range(n, 0, -1)) + "\n"  # a cone's base
    text += "".join(f"f {i} {i % n + 1} {n + 1}\n" for i in range(1, n + 1))
    path = _write(tmp_path, "long.obj", text)
    mesh = read_obj(path)
    assert_same(mesh, reference_read_obj(path))
    assert len(mesh.faces) == (n - 2) + n
    np.testing.assert_array_equal(mesh.faces[: n - 2, 0], n - 1)
    vol = geovox.voxelize(path, resolution=16, backend="numpy")
    assert vol.inside_count > 0


def test_missing_texture_coordinates_drop_uvs_keep_geometry():
    path = corpus("trimesh_models", "cubevt.obj")  # trimesh's: faces name vt 1-24, none exist
    mesh = read_obj(path)
    assert mesh.faces.shape == (12, 3) and mesh.corner_uv is None
    assert len(mesh.problems) == 1
    assert "12 faces" in mesh.problems[0] and "texture coordinates that do not exist" \
        in mesh.problems[0] and "line 50" in mesh.problems[0]
    np.testing.assert_array_equal(mesh.faces, reference_read_obj_geometry(path))
    vol = geovox.voxelize(path, resolution=8, backend="numpy")
    assert vol.inside_count == 8 ** 3  # a cube filling its own box


def reference_read_obj_geometry(path):
    """The reference's faces of a file with its texture indices taken out."""
    with open(path) as f:
        text = f.read()
    stripped = "\n".join(
        " ".join([w.split("/")[0] for w in line.split()]) if line.startswith("f ") else line
        for line in text.splitlines())
    with tempfile.TemporaryDirectory() as folder:
        p = os.path.join(folder, "geometry.obj")
        with open(p, "w") as f:
            f.write(stripped + "\n")
        return reference_read_obj(p).faces


def test_missing_texture_coordinates_only_on_some_faces(tmp_path):
    text = PLAIN + "f 1/9 2/1 4/2\nf 2/-9 3/1 4/1\nf 1/0 2/1 3/2\n"
    mesh = read_obj(_write(tmp_path, "some.obj", text))
    assert len(mesh.faces) == 7 and mesh.corner_uv is not None
    assert np.isnan(mesh.corner_uv[4:]).all() and not np.isnan(mesh.corner_uv[:2]).any()
    assert "3 faces" in mesh.problems[0] and "line 12" in mesh.problems[0]


def test_nan_vertex_colours_count_as_none():
    path = corpus("trimesh_models", "nancolor.obj")  # trimesh's: vertex 7 is "nan nan nan"
    mesh = read_obj(path)
    assert np.isfinite(mesh.vertex_colors).all()
    np.testing.assert_array_equal(mesh.vertex_colors[6], [1.0, 1.0, 1.0])
    ref = reference_read_obj(path)
    np.testing.assert_array_equal(mesh.vertex_colors[:6], ref.vertex_colors[:6])
    assert len(mesh.problems) == 1 and "NaN" in mesh.problems[0]
    # pytest turns a NumPy RuntimeWarning into an error: only the problem is warned.
    with pytest.warns(GeovoxWarning, match="NaN"):
        vol = geovox.voxelize(path, resolution=8, backend="numpy", color=True)
    assert vol.colors is not None


@pytest.mark.parametrize("text, needle", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\n", "has 3 vertices but no faces"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2 3\nl 3 1\n", "has 3 vertices and 2 polylines (l) but no faces"),
    ("v 0 0 0\nv 1 0 0\nf 1 2\n", "has 2 vertices and 1 face statement with fewer than 3 corners"),
])
def test_point_clouds_and_lines_say_there_are_no_faces(tmp_path, text, needle):
    path = _write(tmp_path, "points.obj", text)
    with pytest.raises(MeshError, match="nothing to voxelise") as info:
        read_obj(path)
    assert needle in str(info.value) and str(info.value).startswith(path)


@pytest.mark.parametrize("text, needle", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", "line 4: a face names vertex 9, but the file has 3 vertices"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -5 -1 -2\n", "line 4: a face names vertex -5 (counting back), but only 3 vertices come before it"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "line 4: a face names vertex 0 (OBJ indices start at 1)"),
    ("v 0 0 0\nv 1 abc 0\nv 0 1 0\nf 1 2 3\n", "line 2: 'abc' is not a number: 'v 1 abc 0'"),
    ("v 0 0 0\nv 1 0\nv 0 1 0\nf 1 2 3\n", "line 2: a vertex needs three coordinates"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3x\n", "line 4: '3x' is not a face corner"),
    ("v 0 0 0\r\nv 1 \\\r\n 0 0\r\nv 0 1 0\r\nf 1 2 x\r\n", "line 5: 'x' is not a face corner"),
    ("vt 0 0\nvt\nv 0 0 0\n", "line 2: a texture coordinate needs a number"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999999\n", "line 4: index 99999999999999999999999 is out of range"),
    ("v 1 2 3\nv 1 2 3\nf 1 2 1.5\nv 1.2.3 0 0\n", "line 3: '1.5' is not a face corner"),
])
def test_bad_statements_name_file_and_line(tmp_path, text, needle):
    path = _write(tmp_path, "bad.obj", text)
    with pytest.raises(MeshError) as info:
        read_obj(path)
    message = str(info.value)
    assert message == f"{path}: {needle}" or message.startswith(f"{path}: {needle}")
    assert "\n" not in message


def test_bad_obj_through_the_cli_is_one_line(tmp_path, capsys):
    path = _write(tmp_path, "bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 nope\nf 1 2 3\n")
    assert main(["convert", path, "-o", str(tmp_path / "o.raw")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "bad.obj: line 4: 'nope' is not a number" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.obj"]


def test_binary_file_is_refused(tmp_path):
    path = tmp_path / "binary.obj"
    path.write_bytes(bytes(range(256)) * 20)
    with pytest.raises(MeshError, match="binary file"):
        read_obj(str(path))


def test_load_mesh_checks_what_read_obj_gives(tmp_path):
    mesh = load_mesh(_write(tmp_path, "plain.obj", PLAIN))
    assert mesh.faces.shape == (4, 3) and mesh.corner_uv.shape == (4, 3, 2)
    np.testing.assert_array_equal(mesh.bounds, [[0, 0, 0], [1, 1, 1]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        geovox.voxelize(mesh, resolution=8, backend="numpy")


def test_reading_in_small_pieces_changes_nothing(tmp_path, monkeypatch):
    """Sections are read in pieces of 256 KB; pieces of a few lines give the same."""
    import geovox.io.obj as obj

    _write(tmp_path, "a.mtl", MTL_A)
    _write(tmp_path, "b.mtl", MTL_B)
    paths = [_write(tmp_path, "features.obj", _features_text()), SPOT,
             corpus("cornell_box", "cornell_box.obj")]
    whole = [read_obj(p) for p in paths]
    pieces = obj._pieces
    monkeypatch.setattr(obj, "_pieces", lambda starts, ends, lines: pieces(starts, ends, lines, 64))
    assert len(obj._pieces(*[np.arange(0, 1000, 10), np.arange(9, 1000, 10),
                             np.arange(100)])) > 10
    for p, w in zip(paths, whole):
        assert_same(read_obj(p), w)


def test_one_mtllib_statement_naming_several_files(tmp_path):
    _write(tmp_path, "a.mtl", MTL_A)
    _write(tmp_path, "b.mtl", MTL_B)
    _write(tmp_path, "c d.mtl", "newmtl spaced\nKd 0 1 0\n")
    (tmp_path / "tex.png").write_bytes(b"")
    text = "mtllib a.mtl b.mtl\nmtllib c d.mtl\nmtllib b.mtl gone.mtl\n" + PLAIN.replace(
        "f 1 4 2", "usemtl red\nf 1 4 2\nusemtl blue\nf 1 4 2\nusemtl spaced")
    mesh = read_obj(_write(tmp_path, "libs.obj", text))
    assert [m.name for m in mesh.materials] == ["red", "blue", "spaced"]
    assert all(m.defined for m in mesh.materials)
    assert [p.split(" (")[0] for p in mesh.problems] == ["material file not found: 'gone.mtl'"]


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 10 ** 6), st.sampled_from(["set", "insert", "delete"]),
                          st.sampled_from(list(b"0123456789 \t\n\r/-+.eEvtfn#\\\x00\xa0\xc2\xff"))),
                min_size=1, max_size=6))
def test_damaged_files_read_or_fail_in_one_line(edits):
    """Bytes changed, added or removed anywhere: a Mesh or one MeshError line, nothing else."""
    data = bytearray(b"mtllib none.mtl\nv 0 0 0\nv 1 0 0 1 0 0\nv 0 1 0\nv 0 0 1\nvt 0 0\n"
                     b"vt 1 0\nusemtl a\nf 1/1 2/2 3/1\nf -4//1 -2//1 -1//1\nf 2 4 3 1\n")
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
        try:
            read_obj(path)
        except MeshError as exc:
            assert "\n" not in str(exc) and str(exc).startswith(path)
