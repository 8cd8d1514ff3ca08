"""glTF materials as geovox colours them (``--color``) and labels them (``--labels material``).

What a material gives: its base colour factor (``baseColorFactor``, white
by default, as the specification says; the ``diffuseFactor`` of a
``KHR_materials_pbrSpecularGlossiness`` material), its base colour texture
with the texture coordinate set it names (``texCoord``), its sampler's wrap
modes and ``KHR_texture_transform``, and ``COLOR_0`` multiplying both. A
primitive with ``COLOR_0`` and no material takes glTF's default material
(white). Images are embedded (a buffer view), in ``data:`` URIs or files
found under the references rule (:mod:`geovox.io.references`); an image
that cannot be read leaves its material the factor, said in one line.

These are the materials geovox made from trimesh's reading before it read
glTF itself (it then rewrote the file's JSON for trimesh to keep them):
the same names, factors, wrap modes, texel arrays and order of first use.
"""

from __future__ import annotations

import io
import os
import urllib.parse

import numpy as np

from ..mesh import WRAP_MODES, Material, texels
from .references import data_uri, instead, locate, why_not_read

__all__ = ["Materials", "uv_transform", "numbers"]


def numbers(value, n: int):
    """``value`` as n floats if it is a list of n finite numbers, else None."""
    if not isinstance(value, list) or len(value) != n:
        return None
    if not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in value):
        return None
    out = np.asarray(value, dtype=np.float64)
    return out if np.all(np.isfinite(out)) else None


def uv_transform(tt: dict) -> np.ndarray:
    """(3, 3) float64: KHR_texture_transform's offset x rotation x scale."""
    offset = numbers(tt.get("offset"), 2)
    scale = numbers(tt.get("scale"), 2)
    rotation = tt.get("rotation", 0.0)
    ox, oy = offset if offset is not None else (0.0, 0.0)
    sx, sy = scale if scale is not None else (1.0, 1.0)
    r = (float(rotation) if isinstance(rotation, (int, float)) and not isinstance(rotation, bool)
         and np.isfinite(rotation) else 0.0)
    c, s = np.cos(r), np.sin(r)
    translate = np.array([[1, 0, ox], [0, 1, oy], [0, 0, 1.0]])
    rotate = np.array([[c, s, 0], [-s, c, 0], [0, 0, 1.0]])
    return translate @ rotate @ np.diag([sx, sy, 1.0])


def _dicts(header: dict, key: str) -> list:
    value = header.get(key)
    return [x if isinstance(x, dict) else {} for x in value] if isinstance(value, list) else []


class Materials:
    """The file's materials, made into :class:`~geovox.mesh.Material` on first use.

    Parameters
    ----------
    doc : geovox.io.gltf.Document
        The file (its JSON, buffer views and references rule).
    """

    def __init__(self, doc):
        self.doc = doc
        self.made: list = []
        self._index: dict = {}
        self._problems: list = []
        self._missing: set = set()
        header = doc.header
        self._textures = _dicts(header, "textures")
        self._samplers = _dicts(header, "samplers")
        self._images = _dicts(header, "images")
        raw = header.get("materials") if isinstance(header.get("materials"), list) else []
        self.facts = [self._fact(i, m if isinstance(m, dict) else {}) for i, m in enumerate(raw)]

    # -- what each material states ----------------------------------------

    def _fact(self, i: int, mat: dict) -> dict:
        name = mat.get("name") if isinstance(mat.get("name"), str) else f"material {i}"
        ext = mat.get("extensions")
        sg = ext.get("KHR_materials_pbrSpecularGlossiness") if isinstance(ext, dict) else None
        if isinstance(sg, dict):
            # The diffuse colour is this model's base colour.
            pbr = {"baseColorFactor": sg.get("diffuseFactor", [1, 1, 1, 1])}
            if "diffuseTexture" in sg:
                pbr["baseColorTexture"] = sg["diffuseTexture"]
        else:
            pbr = mat.get("pbrMetallicRoughness")
            pbr = pbr if isinstance(pbr, dict) else {}
        factor = numbers(pbr.get("baseColorFactor", [1, 1, 1, 1]), 4)
        if factor is None:
            self._problems.append(f"material {name!r} has a baseColorFactor that is not 4 "
                                  f"finite numbers ({pbr.get('baseColorFactor')!r}); using white")
            factor = np.ones(4)
        fact = {"name": name, "kd": np.clip(factor[:3], 0.0, 1.0), "wrap": ("repeat", "repeat"),
                "transform": None, "texture": None, "uri": None, "file": None, "set": None,
                "image": None}
        self._texture(fact, pbr.get("baseColorTexture"))
        return fact

    def _texture(self, fact: dict, ref) -> None:
        index = ref.get("index") if isinstance(ref, dict) else None
        if not (isinstance(index, int) and 0 <= index < len(self._textures)):
            if index is not None:
                # trimesh took -1 as Python does: the last texture
                self._problems.append(f"material {fact['name']!r} names base colour texture "
                                      f"{index!r}, which does not exist; using its base colour "
                                      f"factor")
            return
        tex = self._textures[index]
        sampler = tex.get("sampler")
        if isinstance(sampler, int) and 0 <= sampler < len(self._samplers):
            codes = (self._samplers[sampler].get(k, 10497) for k in ("wrapS", "wrapT"))
            fact["wrap"] = tuple(WRAP_MODES.get(c, "repeat") if isinstance(c, int)
                                 else "repeat" for c in codes)
        source = tex.get("source")
        for e in (tex.get("extensions") or {}).values() if isinstance(tex.get("extensions"),
                                                                    dict) else ():
            if source is None and isinstance(e, dict):
                source = e.get("source")  # EXT_texture_webp and kin
        image = (self._images[source] if isinstance(source, int)
                 and 0 <= source < len(self._images) else None)
        uri = image.get("uri") if image is not None else None
        external = isinstance(uri, str) and not uri.startswith("data:")
        fact["texture"] = repr(uri) if external else f"(image {source}, embedded)"
        if external:
            plain = urllib.parse.unquote(uri)
            if (plain != uri and not os.path.exists(os.path.join(self.doc.folder, uri))
                    and os.path.exists(os.path.join(self.doc.folder, plain))):
                uri = plain  # `my%20map.png` names `my map.png`
            fact["uri"] = uri
            fact["file"] = locate(uri, self.doc.folder, self.doc.rule)[0]
        fact["image"] = image
        n = ref.get("texCoord", 0)
        tt = (ref.get("extensions") or {}).get("KHR_texture_transform") \
            if isinstance(ref.get("extensions"), dict) else None
        if isinstance(tt, dict):
            fact["transform"] = uv_transform(tt)
            n = tt.get("texCoord", n)
        fact["set"] = n if isinstance(n, int) and not isinstance(n, bool) else 0

    # -- what the reader asks ----------------------------------------------

    def _of(self, i):
        return self.facts[i] if isinstance(i, int) and 0 <= i < len(self.facts) else None

    def texcoord(self, i) -> tuple:
        """``(TEXCOORD set or None, (3, 3) transform or None)`` of material ``i``'s texture."""
        fact = self._of(i)
        if fact is None or fact["set"] is None:
            return None, None
        return fact["set"], fact["transform"]

    def missing_set(self, i, n: int) -> None:
        """A primitive of material ``i`` lacks the TEXCOORD set its texture reads (said once)."""
        if (i, n) not in self._missing:
            self._missing.add((i, n))
            self._problems.append(
                f"material {self.facts[i]['name']!r} takes its base colour texture's "
                f"coordinates from TEXCOORD_{n}, which a primitive using it does not have; "
                f"those faces take the base colour factor")

    def index(self, i, coloured: bool):
        """Index into :attr:`made` of material ``i`` (made now on first use), or None.

        A primitive without a material takes glTF's default material (white)
        where it has ``COLOR_0``, and none (geovox's default grey) otherwise;
        a material index that names no material counts as none.
        """
        fact = self._of(i)
        key = i if fact is not None else "default"
        if fact is None:
            if not coloured:
                return None
            fact = {"name": "glTF default material", "kd": np.ones(3),
                    "wrap": ("repeat", "repeat"), "texture": None, "image": None,
                    "file": None, "uri": None}
        if key not in self._index:
            self._index[key] = len(self.made)
            self.made.append(self._material(fact))
        return self._index[key]

    def plain(self) -> int:
        """Index of a plain ``default`` material (no colour stated) for parts without one."""
        if "plain" not in self._index:
            self._index["plain"] = len(self.made)
            self.made.append(Material(name="default"))
        return self._index["plain"]

    def problems(self) -> list:
        return list(self._problems)

    # -- images -----------------------------------------------------------------

    def _material(self, fact: dict) -> Material:
        m = Material(name=fact["name"], kd=fact["kd"], wrap=fact["wrap"], vertex_tint=True)
        if fact["texture"] is None:
            return m
        blob, why = self._image_bytes(fact)
        if blob is None:
            self._problems.append(self._no_texture(fact, why))
            return m
        try:
            from PIL import Image

            with Image.open(io.BytesIO(blob)) as image:
                m.image = texels(image)
            m.texture_file = fact["file"]
        except Exception as exc:  # Pillow raises several types for bad images
            self._problems.append(self._no_texture(fact, f"{type(exc).__name__}: {exc}"))
        return m

    def _image_bytes(self, fact: dict) -> tuple:
        """``(bytes, None)`` of a material's base colour image, or ``(None, why not)``."""
        image = fact["image"]
        if image is None or image.get("mimeType") == "image/ktx2":
            return None, "it could not be loaded"
        try:
            if image.get("bufferView") is not None:
                return bytes(self.doc.view(image["bufferView"])[0]), None
            uri = image.get("uri")
            if isinstance(uri, str) and uri.startswith("data:"):
                return data_uri(uri), None
        except Exception:  # a damaged image view leaves the factor, as trimesh's did
            return None, "it could not be loaded"
        uri = fact["uri"]
        found, refused = locate(uri, self.doc.folder, self.doc.rule)
        if refused and found is None:
            return None, why_not_read(uri)
        if found is None:
            return None, "it could not be loaded"
        if refused:
            self.doc.refused.append((uri, instead(uri, found)))
        with open(found, "rb") as f:
            return f.read(), None

    @staticmethod
    def _no_texture(fact: dict, why: str) -> str:
        return (f"cannot read the base colour texture {fact['texture']} of material "
                f"{fact['name']!r} ({why}); using its base colour factor")
