"""MTL material libraries: colours, texture maps and their options, for the OBJ reader.

``Kd``/``Ka`` colours take one number (grey) or three, as the MTL
specification writes them; another count, or a word (``Kd spectral
file.rfl``, ``Kd xyz ...``), is a problem naming the line, and the material
keeps its default. Texture files are found under the ``references`` rule
(:mod:`geovox.io.references`).
"""

from __future__ import annotations

import os
import re

import numpy as np

from ..mesh import Material
from .references import instead, locate, why_not_read

__all__ = ["read_mtl", "used_materials", "resolve_path", "rest_of", "colour_line"]


# Texture map options of the MTL specification ("Options for texture map
# statements") and the most arguments each takes.
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-bm": 1, "-boost": 1, "-cc": 1, "-clamp": 1,
                "-imfchan": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-type": 1}
# Options geovox does not apply, with what they would change. Values for
# which an option changes nothing (the specification's defaults) say nothing.
_NOT_APPLIED = {
    "-blendu": "blending along u turned off", "-blendv": "blending along v turned off",
    "-bm": "a bump multiplier, for bump maps only", "-boost": "mip-map sharpening",
    "-cc": "colour correction", "-imfchan": "the channel of a scalar or bump texture",
    "-mm": "a base and gain for the texture's values", "-t": "turbulence",
    "-texres": "resampling to a power-of-two size", "-type": "a reflection map's type",
}
_NEUTRAL = {"-blendu": ("on",), "-blendv": ("on",), "-cc": ("off",), "-mm": (0.0, 1.0),
            "-t": (0.0, 0.0, 0.0)}


def rest_of(line: str, key: str) -> str:
    """Everything after the keyword, keeping inner spaces (file names have them)."""
    return line.strip()[len(key):].strip()


def resolve_path(name: str, folder: str, rule: str = "anywhere", root: str | None = None):
    """Find a file named in an OBJ/MTL: backslashes, relative folders, case.

    ``rule`` and ``root`` (the model's folder) are as for
    :func:`geovox.io.references.locate`; returns the path or None.
    """
    return locate(name, folder, rule, root)[0]


def _is_option_value(token: str) -> bool:
    if token.lower() in ("on", "off", "r", "g", "b", "m", "l", "z"):
        return True
    try:
        float(token)
        return True
    except ValueError:
        return False


def _is_option(token: str) -> bool:
    """``-word``: an option (known or not), not a negative number or a lone dash."""
    return len(token) > 1 and token[0] == "-" and token[1].isalpha()


def _map_statement(args: str, folder: str, rule: str = "anywhere", root=None) -> tuple:
    """The file name and the options of a ``map_Kd [options] file`` statement.

    Options come before the file name; each takes up to its number of values
    (``-o u [v [w]]``); an option the specification does not list takes the
    values that follow it. The name is the rest of the line, inner spaces
    kept. Where that names no file but giving back the last option's
    trailing numbers does (``-o 0.5 0.5 12 monkeys.png``), or starting the
    name at one of the options' dashes does (``-o 1 -x.png``), that reading
    is taken.

    Returns
    -------
    name : str
    options : list of (str, list of str)
        Each option (lower case) and its values, in the order written.
    """
    spans = [(m.start(), m.group()) for m in re.finditer(r"\S+", args)]
    options, starts, i = [], [], 0
    while i < len(spans) - 1 and _is_option(spans[i][1]):
        key = spans[i][1].lower()
        starts.append(i)
        most = _MAP_OPTIONS.get(key, len(spans))
        i += 1
        values = []
        while (len(values) < most and i < len(spans) - 1
               and (_is_option_value(spans[i][1]) or key == "-type" and not values)):
            values.append(spans[i][1])
            i += 1
        options.append((key, values))
    if i >= len(spans):
        return "", options
    # Readings in order of preference: as parsed; the last option's trailing
    # values given back to the name; the name starting at an option's dash.
    readings = [(i, options)]
    if options and len(options[-1][1]) > 1:
        key, values = options[-1]
        readings += [(i - (len(values) - keep), options[:-1] + [(key, values[:keep])])
                     for keep in range(len(values) - 1, 0, -1)]
    readings += [(starts[k], options[:k]) for k in range(len(options) - 1, -1, -1)]
    for first, opts in readings:
        name = args[spans[first][0]:].strip()
        if resolve_path(name, folder, rule, root) is not None:
            return name, opts
    return args[spans[i][0]:].strip(), options


def _numbers(values, defaults) -> tuple | None:
    """Floats of an option's values, missing ones from ``defaults``; None if not numbers."""
    try:
        out = [float(v) for v in values]
    except ValueError:
        return None
    if not all(np.isfinite(out)):
        return None
    return tuple(out + list(defaults[len(out):]))


def _apply_map_options(material: Material, options: list) -> list:
    """Set a material's UV transform and clamping from its ``map_Kd`` options.

    ``-o u v w`` and ``-s u v w`` give the transform ``uv -> s * uv + o`` (per
    axis; ``w`` is for 3-D textures and not used), as Blender's and three.js's
    OBJ importers read them; ``-clamp on`` maps one copy of the texture
    (see :attr:`Material.wrap`). Returns the options that are not applied:
    ``(option, values, why)``.
    """
    offset, scale = (0.0, 0.0), (1.0, 1.0)
    ignored = []
    for key, values in options:
        if key in ("-o", "-s"):
            got = _numbers(values, (0.0, 0.0) if key == "-o" else (1.0, 1.0))
            if got is None or not values:
                ignored.append((key, values, "its values are not numbers"))
            elif key == "-o":
                offset = got[:2]
            else:
                scale = got[:2]
        elif key == "-clamp":
            state = values[0].lower() if values else ""
            if state in ("on", "off"):
                material.wrap = ("border", "border") if state == "on" else ("repeat", "repeat")
            else:
                ignored.append((key, values, "its value is not on or off"))
        elif key in _NOT_APPLIED:
            neutral = _NEUTRAL.get(key)
            if neutral is not None:
                lowered = tuple(v.lower() for v in values)
                nums = _numbers(values, neutral)
                if lowered == neutral[:len(lowered)] or nums == neutral:
                    continue
            ignored.append((key, values, _NOT_APPLIED[key]))
        else:
            ignored.append((key, values, "not an option of the MTL specification"))
    if offset != (0.0, 0.0) or scale != (1.0, 1.0):
        material.uv_transform = np.array([[scale[0], 0.0, offset[0]],
                                          [0.0, scale[1], offset[1]],
                                          [0.0, 0.0, 1.0]])
    else:
        material.uv_transform = None
    return ignored


def read_mtl(path: str, problems: list, rule: str = "anywhere", root: str | None = None) -> dict:
    """Materials of an MTL file by name. Problems are appended to ``problems``.

    Textures are found under ``rule`` (see :mod:`geovox.io.references`);
    ``root`` is the model's folder (default: the MTL's).
    """
    try:
        with open(path, "r", encoding="utf-8", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError as exc:
        problems.append(f"cannot read material file {path}: {exc.strerror or exc}")
        return {}
    folder = os.path.dirname(path)
    out, cur = {}, None
    for number, line in enumerate(lines, 1):
        parts = line.split()
        if not parts or parts[0].startswith("#"):
            continue
        key = parts[0]
        if key == "newmtl":
            cur = Material(name=rest_of(line, "newmtl"))
            out[cur.name] = cur
        elif cur is None:
            continue
        elif key in ("Kd", "Ka") and len(parts) >= 2:
            rgb = colour_line(parts[1:], f"{path}, line {number}: {key} of material "
                                         f"{cur.name!r} ({line.strip()!r})", problems)
            if rgb is None:
                continue
            if key == "Kd":
                cur.kd = rgb
            else:
                cur.ka = rgb
        elif key.lower() == "map_ka":
            cur.ambient_map = rest_of(line, key) or None
        elif key.lower() == "map_kd":
            name, options = _map_statement(rest_of(line, key), folder, rule, root)
            cur.ignored_options = _apply_map_options(cur, options)
            found, refused = locate(name, folder, rule, root) if name else (None, False)
            if refused and found is not None:
                problems.append(f"texture of material {cur.name!r} in {path}: "
                                f"{instead(name, found)}")
            elif refused:
                problems.append(f"texture {name!r} (material {cur.name!r} in {path}) is not "
                                f"read: {why_not_read(name)}; using its Kd colour")
            elif found is None:
                problems.append(f"texture not found: {name!r} (material {cur.name!r} in {path}); "
                                f"using its Kd colour")
            cur.texture_file = found
    return out


def used_materials(libs, names, folder, path, problems, rule="anywhere") -> list:
    """The materials named by ``usemtl``, in order of first use."""
    library: dict = {}
    missing_lib = False
    for lib in libs:
        # One statement may name several files ("mtllib a.mtl b.mtl", as the
        # format allows); a name with spaces in it is tried whole first.
        names_in = ([lib] if resolve_path(lib, folder, rule) or len(lib.split()) < 2
                    else lib.split())
        for name in names_in:
            found, refused = locate(name, folder, rule)
            if refused and found is not None:
                problems.append(f"material file named in {path}: {instead(name, found)}")
            elif refused:
                problems.append(f"material file {name!r} (named in {path}) is not read: "
                                f"{why_not_read(name)}; using default colours")
            elif found is None:
                problems.append(f"material file not found: {name!r} (named in {path}); "
                                f"using default colours")
            if found is None:
                missing_lib = True
                continue
            library.update(read_mtl(found, problems, rule, folder))
    materials = []
    ignored: dict = {}
    for name in names:
        if name in library:
            materials.append(library[name])
            for key, values, why in library[name].ignored_options:
                ignored.setdefault((key, why), []).append((name, values))
        else:
            if libs and not missing_lib:
                problems.append(f"material {name!r} is not defined in {', '.join(libs)}; "
                                f"using the default colour")
            materials.append(Material(name=name, defined=False))
    # One line per option geovox does not apply, naming the materials it is on.
    for (key, why), uses in ignored.items():
        shown = ", ".join(repr(n) for n, _ in uses[:3]) + (", ..." if len(uses) > 3 else "")
        written = " ".join([key] + uses[0][1])
        problems.append(f"{path}: map_Kd option {written!r} of material"
                        f"{'s' if len(uses) > 1 else ''} {shown} is not applied ({why}); the "
                        f"texture is sampled without it")
    return materials


def colour_line(values, where: str, problems: list):
    """(3,) float64 of a ``Kd``/``Ka`` line's numbers (one: grey; three: RGB), or None.

    Anything else -- two numbers, a word, NaN or infinity -- appends a line
    naming ``where`` to ``problems`` and gives None (the material keeps its
    default). Numbers after the third are said and not used.
    """
    try:
        rgb = [float(x) for x in values]
    except ValueError:
        problems.append(f"cannot read {where}: a colour is one number (grey) or three; "
                        f"using the default")
        return None
    if len(rgb) == 2 or not np.all(np.isfinite(rgb[:3])):
        problems.append(f"cannot read {where}: a colour is one number (grey) or three "
                        f"finite numbers; using the default")
        return None
    if len(rgb) > 3:
        problems.append(f"{where}: a colour is one number (grey) or three; the numbers after "
                        f"the third are not used")
    return np.array((rgb * 3)[:3] if len(rgb) == 1 else rgb[:3], dtype=np.float64)
