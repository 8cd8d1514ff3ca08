"""3MF files trimesh cannot read whole: production parts, beam lattices, slices.

trimesh reads a 3MF's root model part (``3D/3dmodel.model``) and its
triangles. Three extensions of the format put geometry elsewhere:

* **Production** (``p:path``): build items and components name objects in
  other model parts of the archive, and each part numbers its objects from
  1 again. trimesh reads no build item's ``p:path`` at all (*id 1 included
  but not defined*) and merges every mesh of a component's part into one
  object. geovox follows the references itself: every object a build item
  reaches, in whatever part, is copied into one root model under a new id,
  and trimesh reads that.
* **Beam Lattice** (``<b:beamlattice>``): cylinders between vertices, not
  triangles. An object with beams is refused in one line (a volume without
  them would be missing part of the model).
* **Slice** (``s:slicestackid``): a stack of 2-D polygons. An object given
  only as slices, or whose mesh is marked low-resolution, is refused in one
  line; an object with a full-resolution mesh beside its slices is read
  from its mesh.

Files that use none of these are left to trimesh as they are. Every part
lives inside the archive, so the ``references`` rule (files beside the
model) does not apply to 3MF.
"""

from __future__ import annotations

import copy
import io
import xml.etree.ElementTree as ET
import zipfile

from ..errors import MeshError

__all__ = ["flatten"]

_CORE = "http://schemas.microsoft.com/3dmanufacturing/core/2015/02"
_PROD = "http://schemas.microsoft.com/3dmanufacturing/production/2015/06"
_BEAM = "http://schemas.microsoft.com/3dmanufacturing/beamlattice/2017/02"
_SLICE = "http://schemas.microsoft.com/3dmanufacturing/slice/2015/07"
_PATH = f"{{{_PROD}}}path"
_MARKERS = (_PROD.encode(), _BEAM.encode(), _SLICE.encode())
#: Components nested deeper than this are taken for a loop.
_DEPTH = 64


def _tag(element) -> str:
    """An element's name without its namespace."""
    return element.tag.rsplit("}", 1)[-1]


def _children(element, name: str) -> list:
    return [c for c in element if _tag(c) == name]


class _Package:
    """The model parts of one 3MF archive, parsed when first asked for."""

    def __init__(self, source: str, archive: zipfile.ZipFile):
        self.source = source
        self.archive = archive
        self.names = {n.lower().lstrip("/"): n for n in archive.namelist()}
        self.parts: dict = {}

    def model(self, part: str):
        key = part.lower().lstrip("/")
        if key not in self.parts:
            name = self.names.get(key)
            if name is None:
                raise MeshError(f"{self.source}: refers to the model part {part!r}, which the "
                                f"3MF archive does not contain")
            try:
                self.parts[key] = ET.fromstring(self.archive.read(name))
            except ET.ParseError as exc:
                raise MeshError(f"{self.source}: the model part {part!r} is not readable "
                                f"XML ({exc})") from None
        return self.parts[key]

    def object(self, part: str, oid: str):
        resources = _children(self.model(part), "resources")
        for obj in (o for r in resources for o in _children(r, "object")):
            if obj.get("id") == oid:
                return obj
        raise MeshError(f"{self.source}: refers to object {oid} of the model part {part!r}, "
                        f"which that part does not define")


def _not_triangles(source: str, obj, part: str):
    """One line refusing an object whose geometry is not (all) triangles, or None."""
    name = repr(obj.get("name")) if obj.get("name") else f"id {obj.get('id')} in {part!r}"
    meshes = _children(obj, "mesh")
    triangles = sum(len(_children(t, "triangle")) for m in meshes
                    for t in _children(m, "triangles"))
    beams = sum(len(_children(b, "beam")) for m in meshes for lat in _children(m, "beamlattice")
                for b in _children(lat, "beams"))
    if beams:
        return (f"{source}: object {name} holds {beams:,} beams (3MF Beam Lattice extension), "
                f"cylinders that are not triangles; geovox voxelises triangle surfaces only and "
                f"does not read beams" + (f", so the {triangles:,} triangles beside them alone "
                                          f"would be an incomplete volume" if triangles else ""))
    if obj.get(f"{{{_SLICE}}}slicestackid") is not None:
        if not triangles:
            return (f"{source}: object {name} is given only as slices (3MF Slice extension), "
                    f"2-D polygons that are not triangles; geovox voxelises triangle surfaces "
                    f"only and does not read slices")
        if obj.get(f"{{{_SLICE}}}meshresolution") == "lowres":
            return (f"{source}: object {name} has slices (3MF Slice extension) and a mesh marked "
                    f"low-resolution (meshresolution='lowres'), a preview, not the part; geovox "
                    f"voxelises triangle surfaces only and does not read slices")
    return None


class _Flatten:
    """Every object the build reaches, copied into one root model under new ids."""

    def __init__(self, package: _Package, root: str, first_id: int):
        self.package, self.root = package, root
        self.ids: dict = {}  # (part, id) -> new id
        self.objects: list = []
        self.next = first_id
        self.moved = False  # whether any reference crossed into another part

    def reach(self, part: str, oid: str, depth: int = 0) -> str:
        key = (part.lower().lstrip("/"), oid)
        if key in self.ids:
            return self.ids[key]
        if depth > _DEPTH:
            raise MeshError(f"{self.package.source}: its components nest more than {_DEPTH} deep "
                            f"(a loop of components referring to each other?)")
        obj = self.package.object(part, oid)
        refused = _not_triangles(self.package.source, obj, part)
        if refused:
            raise MeshError(refused)
        out = copy.deepcopy(obj)
        if key[0] != self.root.lower().lstrip("/"):
            # Property ids (pid) point into that part's own resources,
            # which are not copied; trimesh reads no 3MF materials anyway.
            for e in out.iter():
                e.attrib.pop("pid", None)
                e.attrib.pop("pindex", None)
        for group in _children(out, "components"):
            for c in _children(group, "component"):
                target = c.attrib.pop(_PATH, part)
                self.moved |= target.lower().lstrip("/") != key[0]
                c.set("objectid", self.reach(target, c.get("objectid", ""), depth + 1))
        new = str(self.next)
        self.next += 1
        out.set("id", new)
        self.ids[key] = new
        self.objects.append(out)
        return new


def flatten(path: str):
    """A 3MF archive trimesh can read whole, or None where it reads the file as it is.

    Returns
    -------
    bytes or None
        A new archive whose root model holds every object the build reaches
        (production parts followed), or None for a file without
        production references (or not a readable archive: trimesh then says
        what is wrong).

    Raises
    ------
    MeshError
        A beam lattice or a slice-only object (see the module's text), or a
        reference to a part or object the archive does not have.
    """
    try:
        archive = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError):
        return None
    with archive:
        names = [n for n in archive.namelist() if "3d/3dmodel.model" in n.lower()]
        if not names:
            return None
        root = names[0]
        data = archive.read(root)
        if not any(m in data for m in _MARKERS):
            return None
        package = _Package(path, archive)
        try:
            model = package.model(root)
        except MeshError:
            return None  # trimesh says what is wrong with the root part
        resources = _children(model, "resources")
        taken = [int(e.get("id")) for r in resources for e in r if (e.get("id") or "").isdigit()]
        walk = _Flatten(package, root, max(taken, default=0) + 1)
        items = [i for b in _children(model, "build") for i in _children(b, "item")]
        for item in items:
            target = item.attrib.pop(_PATH, root)
            walk.moved |= target.lower().lstrip("/") != root.lower().lstrip("/")
            item.set("objectid", walk.reach(target, item.get("objectid", "")))
        if not walk.moved:
            return None  # beams and slices checked; one part: trimesh reads it as it is
        if not resources:
            resources = [ET.SubElement(model, f"{{{_CORE}}}resources")]
        for r in resources:
            for obj in _children(r, "object"):
                r.remove(obj)
        resources[0].extend(walk.objects)
        text = ET.tostring(model, encoding="utf-8", xml_declaration=True)
        out = io.BytesIO()
        with zipfile.ZipFile(out, "w", zipfile.ZIP_STORED) as z:
            for info in archive.infolist():
                if info.filename == root:
                    z.writestr(root, text)
                elif info.filename.lower().endswith(".model"):
                    continue  # the other model parts: all they held is in the root now
                else:
                    z.writestr(info, archive.read(info))
        return out.getvalue()
