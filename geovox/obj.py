"""A Wavefront OBJ + MTL reader that keeps what colouring needs.

trimesh's OBJ loader merges materials into one atlas when forced into a
single mesh and misreads some files (relative indices across ``o`` blocks,
see the Cornell box in the corpus), so geovox reads OBJ itself: every face
keeps its own material, its corners keep their UVs, ``v x y z r g b`` vertex
colours are kept, polygons are fan-triangulated, negative (relative) indices
work, and MTL/texture paths written with backslashes or in other folders are
found. Missing or unreadable material files and textures are recorded (and
reported as warnings when colour is asked for), never fatal.
"""

from __future__ import annotations

import os

import numpy as np

from .errors import MeshError
from .mesh import Material, Mesh

# map_Kd options and how many arguments each takes (at most).
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1,
                "-imfchan": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-type": 1}


def _rest(line: str, key: str) -> str:
    """Everything after the keyword, keeping inner spaces (file names have them)."""
    return line.strip()[len(key):].strip()


def resolve_path(name: str, folder: str) -> str | None:
    """Find a file named in an OBJ/MTL: backslashes, relative folders, case."""
    name = name.strip().strip('"').replace("\\", "/")
    candidates = [name] if os.path.isabs(name) else []
    candidates += [os.path.join(folder, name), os.path.join(folder, os.path.basename(name))]
    for c in candidates:
        if os.path.isfile(c):
            return c
    try:
        lower = os.path.basename(name).lower()
        for entry in os.listdir(folder):
            if entry.lower() == lower and os.path.isfile(os.path.join(folder, entry)):
                return os.path.join(folder, entry)
    except OSError:
        pass
    return None


def _is_option_value(token: str) -> bool:
    if token.lower() in ("on", "off", "r", "g", "b", "m", "l", "z"):
        return True
    try:
        float(token)
        return True
    except ValueError:
        return False


def _texture_name(args: str) -> str:
    """The file name in a ``map_Kd [options] file`` statement."""
    tokens = args.split()
    i = 0
    while i < len(tokens) - 1 and tokens[i] in _MAP_OPTIONS:
        n = _MAP_OPTIONS[tokens[i]]
        i += 1
        for _ in range(n):
            if i < len(tokens) - 1 and _is_option_value(tokens[i]):
                i += 1
            else:
                break
    return " ".join(tokens[i:])


def read_mtl(path: str, problems: list) -> dict:
    """Materials of an MTL file by name. Problems are appended to ``problems``."""
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError as exc:
        problems.append(f"cannot read material file {path}: {exc.strerror or exc}")
        return {}
    folder = os.path.dirname(path)
    out, cur = {}, None
    for line in lines:
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        key = parts[0]
        if key == "newmtl":
            cur = Material(name=_rest(line, "newmtl"))
            out[cur.name] = cur
        elif cur is None:
            continue
        elif key in ("Kd", "Ka") and len(parts) >= 2:
            try:
                rgb = [float(x) for x in parts[1:4]]
            except ValueError:
                problems.append(f"{path}: cannot read {key} of material {cur.name!r}: {line.strip()!r}")
                continue
            rgb = (rgb * 3)[:3] if len(rgb) == 1 else rgb
            if key == "Kd":
                cur.kd = np.array(rgb, dtype=np.float64)
            else:
                cur.ka = np.array(rgb, dtype=np.float64)
        elif key.lower() == "map_kd":
            name = _texture_name(_rest(line, key))
            found = resolve_path(name, folder) if name else None
            if found is None:
                problems.append(f"texture not found: {name!r} (material {cur.name!r} in {path}); "
                                f"using its Kd colour")
            cur.texture_file = found
    return out


def read_obj(path: str) -> Mesh:
    """Read an OBJ file into a :class:`Mesh` with materials, UVs and vertex colours."""
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as exc:
        raise MeshError(f"{path}: cannot be read ({exc.strerror or exc})") from exc
    if b"\0" in data[:4096]:
        raise MeshError(f"{path}: is a binary file, not a text OBJ mesh")
    text = data.decode("utf-8", errors="replace")
    # A trailing backslash continues a statement on the next line.
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
                name = _rest(line, "usemtl")
                if name not in mat_index:
                    mat_index[name] = len(mat_names)
                    mat_names.append(name)
                current = mat_index[name]
            elif key == "mtllib":
                libs.append(_rest(line, "mtllib"))
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
    mesh = Mesh(
        vertices=np.array(v, dtype=np.float64).reshape(-1, 3),
        faces=faces,
        source=path,
        face_material=np.array(tri_m, dtype=np.int64),
        materials=materials,
        corner_uv=uv,
        vertex_colors=np.array(vc, dtype=np.float64) if has_vc else None,
        problems=problems,
    )
    return mesh
